#!/usr/bin/env bash
# test_sampletree.sh - the sample tree's tools (docs/sampletree.md,
# docs/hlod-gen-scene.md).
#
#   - hlod-gen-scene: the chessboard's triangle count (2 g^2, g the multiple
#     of 8 nearest sqrt(N / 2)), its tiles, both variants, the
#     64 x 64-quad reference; city copies (3 x the city's triangles); bad command lines
#     exit 2, an unwritable folder exits 1, and neither leaves a file;
#   - hlod-build --method sampletree on the board and on the small city:
#     every triangle stored once (tris_total = tris_in), hlod-info says
#     refine add and method sampletree, --verify passes, the same bytes on
#     1 and 2 threads, --sample-c changes the store; --shard is refused;
#     with --memory-mb 1, built out of core (buckets, a spill file that is
#     removed), every triangle once, verified;
#   - hlod-export-3dtiles writes refine ADD for it;
#   - hlod-build --method cubes: every triangle once, the same bytes on 1
#     and 2 threads, out of core with --memory-mb 1, hlod-info says method
#     cubes and refine add, --shard refused;
#   - damaged (40 bytes flipped in the payloads) and truncated stores:
#     --verify exits 1 naming the store; hlod-bench over the damaged one
#     runs walk to its end, exit 0, bad nodes counted, render_waits 0
#     (sanitizers: lib.sh waits_ok); the truncated one exits 1 naming it.
set -u
BIN=${HLOD_BIN_DIR:-build/bin}
SRC=${HLOD_SOURCE_DIR:-.}
T=$(mktemp -d /tmp/hlod-test-sampletree-XXXXXX)
trap 'rm -rf "$T"' EXIT
. "$(dirname "$0")/lib.sh" # pass, fail, ok()

key() { perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    my $v = $j->{$ARGV[0]}; print defined $v ? $v : "NaN"' "$1"; }

# ---- hlod-gen-scene ----
"$BIN/hlod-gen-scene" --kind chessboard --tris 20000 -o "$T/cb.obj" --quiet --tile-tris 2000
ok $? "chessboard written"
faces=$(grep -c '^f ' "$T/cb.obj") objs=$(grep -c '^o ' "$T/cb.obj")
# sqrt(10000) = 100 -> g = 104: 21632 triangles; tiles of 31 x 31 quads: 4 x 4, two objects each
[ "$faces" -eq 21632 ] && [ "$objs" -eq 32 ]
ok $? "21632 triangles in 32 objects (got $faces in $objs)"
[ "$(grep -c '^f ' "$T/cb-reference.obj")" -eq 8192 ] && [ -s "$T/cb_chess.png" ] && [ -s "$T/cb.mtl" ]
ok $? "the reference is 64 x 64 quads; the texture and the materials are beside it"
"$BIN/hlod-gen-scene" --kind chessboard --tris 20000 -o "$T/cbt.obj" --textured --quiet
[ "$(grep -c '^vt ' "$T/cbt.obj")" -eq "$(grep -c '^v ' "$T/cbt.obj")" ] &&
    [ "$(grep -c '^usemtl chess' "$T/cbt.obj")" -gt 0 ]
ok $? "the textured board maps every vertex onto the chess texture"
for bad in "--kind city --tris 100 -o $T/x.obj" "--kind chessboard -o $T/x.obj" \
    "--kind chessboard --tris 100 -o $T/x.obj" "--kind chessboard --tris 1000 -o $T/x.ply" \
    "--kind chessboard --tris 1000" "--kind chessboard --tris 1000 -o $T/x.obj --size -1"; do
    "$BIN/hlod-gen-scene" $bad --quiet 2>"$T/err"
    rc=$?
    [ $rc -eq 2 ] && grep -q '^hlod-gen-scene: error:' "$T/err" && ! ls "$T"/x* >/dev/null 2>&1
    ok $? "bad command line '$bad': exit 2 (got $rc), named, nothing written: $(head -1 "$T/err")"
done
# Chamberlain's models (colour cubes): the molecule's spheres of 800
# triangles, the tree's bark and leaves, bad combinations refused
"$BIN/hlod-gen-scene" --kind molecule --tris 8000 -o "$T/mol.obj" --quiet &&
    "$BIN/hlod-gen-scene" --kind tree --tris 10000 -o "$T/tree.obj" --quiet
ok $? "molecule and tree written"
mf=$(grep -c '^f ' "$T/mol.obj") tf=$(grep -c '^f ' "$T/tree.obj")
[ "$mf" -eq 8000 ] && [ "$(grep -c '^newmtl' "$T/mol.mtl")" -eq 4 ] &&
    [ "$tf" -ge 9999 ] && [ "$tf" -le 10000 ] && grep -q '^o bark' "$T/tree.obj" &&
    grep -q '^o leaves_0' "$T/tree.obj"
ok $? "10 spheres of 800 triangles ($mf), a tree of 10000 ($tf) with bark and leaves"
for bad in "--kind tree -o $T/y.obj" "--kind molecule --tris 8000 --textured -o $T/y.obj" \
    "--kind tree --tris 5000 --copies 2 -o $T/y.obj"; do
    "$BIN/hlod-gen-scene" $bad --quiet 2>"$T/err"
    rc=$?
    [ $rc -eq 2 ] && ! ls "$T"/y* >/dev/null 2>&1
    ok $? "bad command line '$bad': exit 2 (got $rc): $(head -1 "$T/err")"
done
"$BIN/hlod-gen-scene" --kind city --copies 3 --preset tiny -o "$T/c3.obj" --quiet
rc=$?
one=$("$BIN/hlod-gen-city" --preset tiny -o "$T/one.obj" --json --quiet | key tris)
[ $rc -eq 0 ] && [ "$(grep -c '^f ' "$T/c3.obj")" -eq $((3 * one)) ] &&
    [ "$(grep -c '^o .*_c2$' "$T/c3.obj")" -gt 0 ] && [ -d "$T/c3_tex" ]
ok $? "three copies of the tiny city: $((3 * one)) triangles, objects NAME_cK, textures once"
mkdir -p "$T/ro" && chmod 555 "$T/ro"
if [ "$(id -u)" != 0 ]; then
    "$BIN/hlod-gen-scene" --kind chessboard --tris 1000 -o "$T/ro/x.obj" --quiet 2>"$T/err"
    rc=$?
    [ $rc -eq 1 ] && [ -z "$(ls "$T/ro")" ]
    ok $? "an unwritable folder: exit 1 (got $rc), nothing left: $(head -1 "$T/err")"
else
    # root writes anywhere: a folder that does not exist instead
    "$BIN/hlod-gen-scene" --kind chessboard --tris 1000 -o "$T/none/x.obj" --quiet 2>"$T/err"
    rc=$?
    [ $rc -eq 1 ] && [ ! -e "$T/none" ] && grep -q "$T/none" "$T/err"
    ok $? "a missing folder: exit 1 (got $rc), named, nothing left: $(head -1 "$T/err")"
fi

# ---- hlod-build --method sampletree ----
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cb.hlod" --method sampletree --threads 1 --json --quiet >"$T/b1.json"
ok $? "board built"
[ "$(key tris_in <"$T/b1.json")" = 21632 ] && [ "$(key tris_total <"$T/b1.json")" = 21632 ] &&
    [ "$(key method <"$T/b1.json")" = sampletree ]
ok $? "every triangle stored once: $(tr -d '\n' <"$T/b1.json" | cut -c1-160)"
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cb2.hlod" --method sampletree --threads 2 --quiet &&
    cmp -s "$T/cb.hlod" "$T/cb2.hlod"
ok $? "the same bytes on 1 and 2 threads"
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cb3.hlod" --method sampletree --sample-c 2 --quiet &&
    ! cmp -s "$T/cb.hlod" "$T/cb3.hlod"
ok $? "--sample-c 2 builds another store"
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cb4.hlod" --method sampletree --shard 1/2 --quiet 2>"$T/err"
rc=$?
[ $rc -ne 0 ] && [ ! -e "$T/cb4.hlod" ] && grep -q "shards" "$T/err"
ok $? "--shard is refused (exit $rc): $(head -1 "$T/err")"
# out of core: a memory limit small enough for many buckets and a spill file
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cbm.hlod" --method sampletree --memory-mb 1 --json --quiet \
    >"$T/bm.json" && "$BIN/hlod-info" "$T/cbm.hlod" --verify >/dev/null
ok $? "built out of core and verified"
[ "$(key tris_total <"$T/bm.json")" = 21632 ] && [ "$(key buckets <"$T/bm.json")" -gt 1 ] &&
    [ "$(key spill_bytes <"$T/bm.json")" -gt 0 ] && [ "$(key buckets <"$T/b1.json")" = 1 ] &&
    [ "$(key spill_bytes <"$T/b1.json")" = 0 ] && ! ls "$T"/cbm.hlod.spill-* >/dev/null 2>&1
ok $? "every triangle once in $(key buckets <"$T/bm.json") buckets, $(key spill_bytes <"$T/bm.json") bytes spilled and removed"
"$BIN/hlod-info" "$T/cb.hlod" --json >"$T/info.json"
[ "$(key refine <"$T/info.json")" = add ] && [ "$(key method <"$T/info.json")" = sampletree ]
ok $? "hlod-info: refine add, method sampletree"
"$BIN/hlod-info" "$T/cb.hlod" --verify >"$T/verify.txt"
ok $? "hlod-info --verify passes"
"$BIN/hlod-export-3dtiles" "$T/cb.hlod" -o "$T/tiles" --quiet &&
    grep -q '"refine":[[:space:]]*"ADD"' "$T/tiles/tileset.json" &&
    ! grep -q '"REPLACE"' "$T/tiles/tileset.json"
ok $? "3D Tiles: refine ADD"

# ---- hlod-build --method cubes (docs/cubes.md) ----
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cc.hlod" --method cubes --threads 1 --json --quiet >"$T/c1.json" &&
    "$BIN/hlod-build" "$T/cb.obj" -o "$T/cc2.hlod" --method cubes --threads 2 --quiet &&
    cmp -s "$T/cc.hlod" "$T/cc2.hlod"
ok $? "colour cubes built, the same bytes on 1 and 2 threads"
[ "$(key tris_total <"$T/c1.json")" = 21632 ] && [ "$(key method <"$T/c1.json")" = cubes ]
ok $? "colour cubes: every triangle stored once: $(tr -d '\n' <"$T/c1.json" | cut -c1-120)"
"$BIN/hlod-build" "$T/cb.obj" -o "$T/ccm.hlod" --method cubes --memory-mb 1 --json --quiet \
    >"$T/cm.json" && "$BIN/hlod-info" "$T/ccm.hlod" --verify >/dev/null &&
    [ "$(key tris_total <"$T/cm.json")" = 21632 ] && [ "$(key buckets <"$T/cm.json")" -gt 1 ]
ok $? "colour cubes out of core: $(key buckets <"$T/cm.json") buckets, verified"
"$BIN/hlod-info" "$T/cc.hlod" --json >"$T/cinfo.json" && "$BIN/hlod-info" "$T/cc.hlod" >"$T/cinfo.txt"
[ "$(key refine <"$T/cinfo.json")" = add ] && [ "$(key method <"$T/cinfo.json")" = cubes ] &&
    grep -q "^build: method cubes, leaf cells of at most 64 triangles" "$T/cinfo.txt"
ok $? "hlod-info: refine add, method cubes: $(sed -n 2p "$T/cinfo.txt")"
"$BIN/hlod-build" "$T/cb.obj" -o "$T/cc4.hlod" --method cubes --shard 1/2 --quiet 2>"$T/err"
rc=$?
[ $rc -ne 0 ] && [ ! -e "$T/cc4.hlod" ]
ok $? "colour cubes: --shard is refused (exit $rc): $(head -1 "$T/err")"

# ---- damaged and truncated ----
"$BIN/hlod-gen-city" --preset small -o "$T/city.obj" --paths "$T/paths" --quiet &&
    "$BIN/hlod-build" "$T/city.obj" -o "$T/city.hlod" --method sampletree --quiet
ok $? "small city sample tree built"
cp "$T/city.hlod" "$T/damaged.hlod"
# 40 bytes of the payload area (after the header, before the node table at
# header byte 56), positions from a seeded LCG, each XORed with 0x5a
perl -e 'my ($f) = @ARGV; open(my $h, "+<:raw", $f) or die "$f: $!";
    read($h, my $hd, 64); my $end = unpack "Q<", substr($hd, 56, 8);
    die "bad node table offset $end\n" unless $end > 4096;
    my $x = 7; for (1 .. 40) { $x = (1664525 * $x + 1013904223) % 4294967296;
    my $o = 256 + $x % ($end - 256); seek($h, $o, 0); read($h, my $b, 1);
    seek($h, $o, 0); print $h chr(ord($b) ^ 0x5a); } close $h' "$T/damaged.hlod"
"$BIN/hlod-info" "$T/damaged.hlod" --verify >/dev/null 2>"$T/err"
rc=$?
[ $rc -eq 1 ] && grep -q "damaged.hlod" "$T/err"
ok $? "a damaged sample tree: --verify exits 1 (got $rc) naming it: $(head -1 "$T/err")"
"$BIN/hlod-bench" "$T/damaged.hlod" --path walk --paths-dir "$T/paths" --out "$T/dmg" \
    --width 160 --height 90 --dt 0.25 --jitter-frames 0 --no-plots 2>"$T/dmg.err" >/dev/null
rc=$?
frames=$(key frames <"$T/dmg/summary.json" 2>/dev/null) bad=$(key bad_nodes <"$T/dmg/summary.json" 2>/dev/null)
waits=$(key render_waits <"$T/dmg/summary.json" 2>/dev/null)
"$BIN/hlod-bench" "$T/city.hlod" --path walk --paths-dir "$T/paths" --out "$T/good" \
    --width 160 --height 90 --dt 0.25 --jitter-frames 0 --no-plots 2>/dev/null >/dev/null
gframes=$(key frames <"$T/good/summary.json" 2>/dev/null)
[ $rc -eq 0 ] && [ "$frames" = "$gframes" ] && [ "$bad" -gt 0 ] 2>/dev/null && waits_ok "$waits" "$frames"
ok $? "hlod-bench (klein) over it: exit $rc, $frames of $gframes frames, bad_nodes $bad, render_waits $waits"
# colour cubes of the small city, drawn by hlod-bench's default for them (cubes)
"$BIN/hlod-build" "$T/city.obj" -o "$T/cityc.hlod" --method cubes --quiet &&
    "$BIN/hlod-bench" "$T/cityc.hlod" --path walk --paths-dir "$T/paths" --out "$T/cub" \
        --width 160 --height 90 --dt 0.25 --jitter-frames 0 --no-plots 2>"$T/cub.err" >/dev/null
rc=$?
cframes=$(key frames <"$T/cub/summary.json" 2>/dev/null) cpol=$(key policy <"$T/cub/summary.json" 2>/dev/null)
[ $rc -eq 0 ] && [ "$cframes" = "$gframes" ] && [ "$cpol" = cubes ]
ok $? "hlod-bench over the city's colour cubes: exit $rc, policy $cpol, $cframes of $gframes frames: $(head -1 "$T/cub.err")"
size=$(stat -c %s "$T/city.hlod")
head -c $((size / 2)) "$T/city.hlod" >"$T/cut.hlod"
"$BIN/hlod-info" "$T/cut.hlod" --verify >/dev/null 2>"$T/err"
rc=$?
[ $rc -eq 1 ] && grep -q "cut.hlod" "$T/err"
ok $? "a truncated sample tree: hlod-info exits 1 (got $rc) naming it: $(head -1 "$T/err")"
"$BIN/hlod-bench" "$T/cut.hlod" --path walk --paths-dir "$T/paths" --out "$T/cut" \
    --width 160 --height 90 --jitter-frames 0 --no-plots 2>"$T/err" >/dev/null
rc=$?
[ $rc -eq 1 ] && grep -q "cut.hlod" "$T/err"
ok $? "hlod-bench over it: exit 1 (got $rc) naming it: $(head -1 "$T/err")"
echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
