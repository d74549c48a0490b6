#!/usr/bin/env bash
# test_shard.sh - the sharded build (docs/sharded-builds.md; issue 20):
# hlod-build --shard I/N run through GNU parallel, then hlod-merge.
#
# Checks:
#   - the small city (9 blocks, one group level), N = 1, 3 and 8, cutplane
#     and metis: the shards run as GNU parallel jobs (parallel --halt
#     now,fail=1), hlod-merge (parts given in reverse order) writes a store
#     byte-identical (cmp) to hlod-build without --shard; hlod-info --verify
#     passes on it;
#   - a 30-block city (two group levels: with N = 1 the cut is level 1,
#     its 4 groups, and the merge builds the root from the shard's group
#     nodes): N = 1, 3 and 8, byte-identical likewise;
#   - --city-levels off (every block a root), N = 3: likewise, the merge
#     building no group;
#   - two input files (two 6-block cities side by side), N = 3: likewise;
#   - a model not generated here (data/meshes/2CylinderEngine.glb, 67
#     blocks), N = 3: likewise;
#   - an OBJ of the reader's corner cases (tests/obj_corner_cases.py, 17
#     blocks), which the shards stream one object at a time while the
#     single build reads it whole: N = 3 and 5, likewise; and a real OBJ
#     (data/meshes/spider.obj, 19 blocks), N = 3;
#   - refused, exit 1, naming the part or the shard, and no store written:
#     a missing part ("shard 2/3 is missing"), a part given twice ("given
#     twice"), a part of another build (metis's part among cutplane's), a
#     byte flipped in the part header, in a payload of the store inside,
#     in the node table and in the part section, a part cut short, a store
#     that is not a part; 60 random single-bit flips in a part: no crash
#     (exit 0 or 1), and an exit 0 only with the single build's bytes;
#   - a shard killed (SIGKILL) at 4 gates of its run (2 % of one build's
#     time, before any output; then 0, 20 and 40 % of the part's bytes
#     written; each must land before it ends): either no part at its path
#     (the merge says the shard is missing) or a complete one (the merge
#     gives the single build's bytes) - never a part the merge takes
#     wrongly; then that shard rerun alone and merged again: byte-identical;
#   - bad --shard values (0/3, 4/3, 3, 1/0, x/2): exit 2.
# HLOD_SHARD_QUICK=1 (the sanitizer build): the small city with cutplane
# and N = 3 and the 30-block city with N = 1 only (cut levels 0 and 1), no
# --city-levels off, the corner-case OBJ with N = 3, then every refusal
# (which use metis's and N = 8's parts: those are built, not merged), 20
# bit flips and the shard killed at 2 gates.
# Env: HLOD_BIN_DIR (the tools), HLOD_SOURCE_DIR.
set -uo pipefail
BIN=${HLOD_BIN_DIR:-build/bin}
BIN=$(cd "$BIN" && pwd)
T=$(mktemp -d "${TMPDIR:-/tmp}/hlod-test-shard.XXXXXX")
cleanup() { rm -rf "$T"; }
trap cleanup EXIT
. "$(dirname "$0")/lib.sh"

if ! command -v parallel >/dev/null 2>&1; then
    echo "FAIL GNU parallel is not installed (data/setup.sh installs parallel)"
    exit 1
fi
for tool in hlod-gen-city hlod-build hlod-merge hlod-info; do
    [ -x "$BIN/$tool" ] || { echo "FAIL $BIN/$tool not built"; exit 1; }
done

"$BIN/hlod-gen-city" --preset small -o "$T/small.obj" >/dev/null 2>&1 &&
    "$BIN/hlod-gen-city" --preset small --blocks 30 --tris-per-block 600 --texture-size 64 \
        -o "$T/c30.obj" >/dev/null 2>&1
ok $? "inputs: the small city and a 30-block city"

# sharded CITY METHOD N: the shards through GNU parallel, then the merge;
# the store is $T/CITY-METHOD-N.hlod
sharded() {
    local city=$1 method=$2 n=$3 pre=$T/$1-$2-$3
    local extra=()
    [ "$method" = cutplane ] && extra=(--desired-tris 450)
    parallel --halt now,fail=1 "$BIN/hlod-build" "$T/$city.obj" -o "$pre.{}.part" --method "$method" \
        "${extra[@]}" --threads 1 --quiet --shard "{}/$n" ::: $(seq 1 "$n") &&
        "$BIN/hlod-merge" $(ls -r "$pre".*.part) -o "$pre.hlod" --quiet --json >"$pre.json"
}

single() {
    local city=$1 method=$2
    local extra=()
    [ "$method" = cutplane ] && extra=(--desired-tris 450)
    "$BIN/hlod-build" "$T/$city.obj" -o "$T/$city-$method.hlod" --method "$method" "${extra[@]}" --quiet \
        --json >"$T/$city-$method.build.json"
}

# stages_add_up FILE: hlod-build --json's stage times: the stages within the
# run's wall time, the parts of a block tree within the tree, each part
# measured (> 0), and CPU time over the process
stages_add_up() {
    perl -MJSON::PP -e 'local $/; open my $f, "<", $ARGV[0] or die; my $j = JSON::PP->new->decode(<$f>);
        my ($s, $c) = ($j->{stage_seconds}, $j->{stage_cpu_seconds});
        my $sum = 0; $sum += $s->{$_} for qw(read blocks levels finish);
        my $parts = $c->{simplify} + $c->{error} + $c->{node_textures};
        printf "stages %.2f of %.2f s; tree %.2f cpu s (simplify %.2f, error %.2f, atlases %.2f), store %.2f, cpu %.2f\n",
            $sum, $j->{seconds}, $c->{tree}, $c->{simplify}, $c->{error}, $c->{node_textures}, $c->{store}, $j->{cpu_seconds};
        exit !($sum > 0.5 * $j->{seconds} && $sum <= $j->{seconds} + 0.01 && $c->{simplify} > 0 && $c->{error} > 0 &&
            $c->{store} > 0 && $parts <= $c->{tree} + 0.01 && $c->{tree} <= $j->{cpu_seconds} + 0.01)' "$1"
}

key() { sed -n "s/.*\"$2\": *\([0-9.]*\).*/\1/p" "$1"; }

# shards_match NAME N ARGS...: the inputs and flags ARGS built in N shards
# through GNU parallel and merged into $T/NAME-N.hlod (the merge's --json in
# $T/NAME-N.json), byte-identical to the single build $T/NAME.hlod
shards_match() {
    local name=$1 n=$2
    shift 2
    parallel --halt now,fail=1 "$BIN/hlod-build" "$@" -o "$T/$name.$n.{}.part" --threads 1 --quiet \
        --shard "{}/$n" ::: $(seq 1 "$n") &&
        "$BIN/hlod-merge" "$T/$name.$n".*.part -o "$T/$name-$n.hlod" --quiet --json >"$T/$name-$n.json" &&
        cmp -s "$T/$name.hlod" "$T/$name-$n.hlod"
}

QUICK=${HLOD_SHARD_QUICK:-0}
NS="1 3 8"
[ "$QUICK" = 1 ] && NS=3
for method in cutplane metis; do
    single small $method
    ok $? "single build, small city, $method"
    msg=$(stages_add_up "$T/small-$method.build.json")
    ok $? "--json stage times, $method: $msg"
    [ "$QUICK" = 1 ] && [ $method = metis ] && break
    # metis at N = 3 alone: N = 1 and 8 take the merge through the same
    # code for either method (cutplane's runs cover them)
    ns=$NS
    [ $method = metis ] && ns=3
    for n in $ns; do
        sharded small $method $n &&
            cmp -s "$T/small-$method.hlod" "$T/small-$method-$n.hlod" &&
            "$BIN/hlod-info" "$T/small-$method-$n.hlod" --verify --json | grep -q '"verified":true'
        ok $? "small city, $method, $n shards through GNU parallel: merge byte-identical to the single build (cut level $(key "$T/small-$method-$n.json" cut_level), $(key "$T/small-$method-$n.json" nodes_copied) nodes copied, $(key "$T/small-$method-$n.json" groups_built) groups built by the merge), verified"
    done
done

single c30 cutplane
ok $? "single build, 30-block city"
NS="1 3 8"
[ "$QUICK" = 1 ] && NS=1
for n in $NS; do
    sharded c30 cutplane $n && cmp -s "$T/c30-cutplane.hlod" "$T/c30-cutplane-$n.hlod"
    ok $? "30-block city, $n shards: merge byte-identical (cut level $(key "$T/c30-cutplane-$n.json" cut_level), $(key "$T/c30-cutplane-$n.json" groups_built) groups built by the merge)"
done

# far cubes: the parts' cubes copied, the merged levels' made by the merge
"$BIN/hlod-build" "$T/small.obj" -o "$T/fc.hlod" --desired-tris 450 --far-cubes on --quiet &&
    shards_match fc 3 "$T/small.obj" --desired-tris 450 --far-cubes on &&
    "$BIN/hlod-info" "$T/fc-3.hlod" --json | grep -q '"cubes":true'
ok $? "small city with --far-cubes on, 3 shards: merge byte-identical, the nodes carry cubes"

# no city levels: every block a root, nothing for the merge to build
# (not under the sanitizers: the plan's one level, no code of its own)
if [ "$QUICK" != 1 ]; then
    FLAT=("$T/small.obj" --desired-tris 450 --city-levels off)
    "$BIN/hlod-build" "${FLAT[@]}" -o "$T/flat.hlod" --quiet && shards_match flat 3 "${FLAT[@]}" &&
        [ "$(key "$T/flat-3.json" groups_built)" = 0 ]
    ok $? "--city-levels off, 3 shards: merge byte-identical, $(key "$T/flat-3.json" groups_built) groups built"
fi

# many input files (one per tile, as real city data comes): two cities side
# by side, each shard reading the files twice (boxes, then its own blocks)
"$BIN/hlod-gen-city" --preset small --blocks 6 --tris-per-block 600 --texture-size 64 --seed 2 \
    -o "$T/tile0.obj" >/dev/null 2>&1 &&
    "$BIN/hlod-gen-city" --preset small --blocks 6 --tris-per-block 600 --texture-size 64 --seed 3 \
        --origin 300 0 0 -o "$T/tile1.obj" >/dev/null 2>&1 &&
    "$BIN/hlod-build" "$T/tile0.obj" "$T/tile1.obj" -o "$T/tiles.hlod" --desired-tris 450 --quiet &&
    shards_match tiles 3 "$T/tile0.obj" "$T/tile1.obj" --desired-tris 450
ok $? "two input files (two 6-block cities side by side), 3 shards: merge byte-identical"

# a model nobody here made: Khronos' 2CylinderEngine (glTF, 67 blocks of
# real multi-part geometry; data/fetch-meshes.sh fetches it)
ENG=${HLOD_SOURCE_DIR:-.}/data/meshes/2CylinderEngine.glb
"$BIN/hlod-build" "$ENG" -o "$T/engine.hlod" --desired-tris 450 --quiet &&
    shards_match engine 3 "$ENG" --desired-tris 450
ok $? "2CylinderEngine.glb (67 blocks, not generated here), 3 shards: merge byte-identical"

# an OBJ with what the reader handles beyond the generated city (faces
# before any object, usemtl before mtllib, relative indices, an object using
# another's vertices, two textures in one object, duplicates, ...): a shard
# streams it one object at a time, the single build reads it whole
python3 "$(dirname "$0")/obj_corner_cases.py" "$T/cc" "$(ls "$T"/small_tex/*.png 2>/dev/null | head -1)" &&
    "$BIN/hlod-build" "$T/cc/corners.obj" -o "$T/cc.hlod" --desired-tris 60 --quiet 2>/dev/null
ok $? "an OBJ of the reader's corner cases (tests/obj_corner_cases.py): single build"
CCN="3 5"
[ "$QUICK" = 1 ] && CCN=3
for n in $CCN; do
    shards_match cc "$n" "$T/cc/corners.obj" --desired-tris 60 2>/dev/null
    ok $? "the corner-case OBJ, $n shards (streamed object by object): merge byte-identical"
done

# a real OBJ nobody here made (assimp's spider: 19 groups, 3 textures,
# data/fetch-meshes.sh), streamed likewise
SP=${HLOD_SOURCE_DIR:-.}/data/meshes/spider.obj
"$BIN/hlod-build" "$SP" -o "$T/spider.hlod" --desired-tris 450 --quiet && shards_match spider 3 "$SP" --desired-tris 450
ok $? "spider.obj (19 blocks, not made here), 3 streamed shards: merge byte-identical"

# ---- refusals ----
P=$T/small-cutplane-3
if [ "$QUICK" = 1 ]; then
    "$BIN/hlod-build" "$T/small.obj" -o "$T/small-metis-3.2.part" --method metis --quiet --shard 2/3 &&
        "$BIN/hlod-build" "$T/small.obj" -o "$T/small-cutplane-8.3.part" --desired-tris 450 --quiet \
            --shard 3/8
    ok $? "parts of other builds for the refusals (metis 2/3, cutplane 3/8)"
fi
# refused WHAT PATTERN PARTS...: exit 1, stderr matching PATTERN, no store
refused() {
    local what=$1 pat=$2
    shift 2
    rm -f "$T/bad.hlod"
    "$BIN/hlod-merge" "$@" -o "$T/bad.hlod" 2>"$T/bad.err" >/dev/null
    local rc=$?
    [ $rc -eq 1 ] && grep -q -- "$pat" "$T/bad.err" && [ ! -e "$T/bad.hlod" ] &&
        [ -z "$(ls "$T" | grep '^bad\.hlod\.tmp-')" ]
    ok $? "$what: exit $rc, no store ($(head -1 "$T/bad.err" | cut -c1-150))"
}
refused "a missing part" "shard 2/3 is missing" "$P.1.part" "$P.3.part"
refused "a part given twice" "given twice" "$P.1.part" "$P.2.part" "$P.2.part" "$P.3.part"
refused "a part of another build" "different builds" "$P.1.part" "$T/small-metis-3.2.part" "$P.3.part"
refused "a part of a build with another N" "not one build" "$P.1.part" "$P.2.part" "$T/small-cutplane-8.3.part"
refused "a store that is not a part" "$T/small-cutplane.hlod: not a part file" "$T/small-cutplane.hlod" "$P.2.part" "$P.3.part"

# flip OFFSET: a copy of part 2 with the byte at OFFSET inverted
flip() {
    cp "$P.2.part" "$T/flip.part"
    python3 - "$T/flip.part" "$1" <<'EOF'
import sys
p, off = sys.argv[1], int(sys.argv[2])
with open(p, "r+b") as f:
    f.seek(off)
    b = f.read(1)
    f.seek(off)
    f.write(bytes([b[0] ^ 0xFF]))
EOF
}
# the part's layout, from its header and its store's (part.h, store.h)
read -r store_off store_size sec_off sec_size table_off first_payload < <(python3 - "$P.2.part" <<'EOF'
import struct, sys
d = open(sys.argv[1], "rb").read()
# hlod_part_header: the offsets after magic(8) + 6 u32 + 8 u64 + 2 u32 = 104
store_off, store_size, sec_off, sec_size = struct.unpack_from("<4Q", d, 104)
table_off, = struct.unpack_from("<Q", d, store_off + 56)
first_payload, = struct.unpack_from("<Q", d, store_off + table_off + 160)
print(store_off, store_size, sec_off, sec_size, table_off, first_payload)
EOF
)
flip 20
refused "a byte flipped in the part header" "flip.part: part header checksum mismatch" "$P.1.part" "$T/flip.part" "$P.3.part"
flip $((store_off + first_payload + 40))
refused "a byte flipped in a payload of the part's store" "flip.part: store node .*: payload checksum mismatch" "$P.1.part" "$T/flip.part" "$P.3.part"
flip $((store_off + table_off + 200))
refused "a byte flipped in the part's node table" "flip.part: the shard's node table checksum" "$P.1.part" "$T/flip.part" "$P.3.part"
flip $((sec_off + sec_size / 2))
refused "a byte flipped in the part section" "flip.part: part section checksum" "$P.1.part" "$T/flip.part" "$P.3.part"
head -c $((sec_off + sec_size / 2)) "$P.2.part" >"$T/flip.part"
refused "a part cut short" "flip.part: .* bytes, its header says" "$P.1.part" "$T/flip.part" "$P.3.part"

# 60 random bytes flipped, one at a time (20 under the sanitizers): never
# a crash, never a wrong store
FLIPS=60
[ "$QUICK" = 1 ] && FLIPS=20
python3 - "$P.2.part" "$T/rand" "$FLIPS" <<'EOF2'
import os, random, sys
src, dst = sys.argv[1], sys.argv[2]
d = bytearray(open(src, "rb").read())
rng = random.Random(20)
os.makedirs(dst, exist_ok=True)
for i in range(int(sys.argv[3])):
    e = bytearray(d)
    k = rng.randrange(len(e))
    e[k] ^= 1 << rng.randrange(8)
    open(f"{dst}/{i}.part", "wb").write(e)
EOF2
crashes=0
wrong=0
took=0
for i in $(seq 0 $((FLIPS - 1))); do
    rm -f "$T/r.hlod"
    "$BIN/hlod-merge" "$P.1.part" "$T/rand/$i.part" "$P.3.part" -o "$T/r.hlod" --quiet 2>/dev/null
    rc=$?
    [ $rc -le 1 ] || crashes=$((crashes + 1))
    if [ $rc -eq 0 ]; then
        took=$((took + 1))
        cmp -s "$T/r.hlod" "$T/small-cutplane.hlod" || wrong=$((wrong + 1))
    fi
done
[ $crashes -eq 0 ] && [ $wrong -eq 0 ]
ok $? "$FLIPS single-bit flips in part 2/3: $crashes crashes, $took merged, $wrong of those wrong"

# ---- a shard killed ----
K=$T/kill
mkdir -p "$K"
cp "$P.1.part" "$K/p.1.part"
cp "$P.3.part" "$K/p.3.part"
kills=0
wrong=0
# Where each kill lands is a gate, not a clock: the build's output (the
# shard's store, then the part, each through a temporary file) must hold a
# given share of the whole part's bytes; the first kill comes before any
# output, while the blocks are simplified (2 % of one build's time).
"$BIN/hlod-build" "$T/small.obj" -o "$K/p.2.part" --desired-tris 450 --threads 1 --quiet --shard 2/3
full=$(wc -c <"$K/p.2.part")
t0=$(date +%s%N)
"$BIN/hlod-build" "$T/small.obj" -o "$K/p.2.part" --desired-tris 450 --threads 1 --quiet --shard 2/3
build_ms=$((($(date +%s%N) - t0) / 1000000))
# (the shard's store is 86 % of its part, the blocks' payloads stream into
# it over most of the build, and the group nodes and the part come in a
# burst at the end: a gate past 40 % could fall in the burst, which a
# poll on a loaded machine misses; 70 % did so once under ASan beside a
# make -j4)
GATES="time 0 20 40" # the first: 2 % of the time; the others: % of the part's bytes written
[ "$QUICK" = 1 ] && GATES="time 20"
written() { # bytes of the build's output files so far (one stat a poll)
    stat -c %s "$K"/p.2.part.* 2>/dev/null | awk '{ n += $1 } END { print n + 0 }'
}
echo "  shard 2/3: $build_ms ms, a part of $full bytes; kills at: $GATES"
runs=0
for gate in $GATES; do
    rm -f "$K/p.2.part" "$K"/p.2.part.*
    "$BIN/hlod-build" "$T/small.obj" -o "$K/p.2.part" --desired-tris 450 --threads 1 --quiet \
        --shard 2/3 &
    pid=$!
    if [ "$gate" = time ]; then
        sleep "$(awk -v ms="$build_ms" 'BEGIN { printf "%.3f", 0.02 * ms / 1000 }')"
    else
        want=$((full * gate / 100))
        until [ "$(written)" -gt "$want" ] || ! kill -0 $pid 2>/dev/null; do
            sleep 0.002
        done
    fi
    kill -9 $pid 2>/dev/null && kills=$((kills + 1))
    wait $pid 2>/dev/null
    runs=$((runs + 1))
    rm -f "$K/m.hlod"
    if [ -e "$K/p.2.part" ]; then
        # a part there must be the whole one
        "$BIN/hlod-merge" "$K"/p.1.part "$K"/p.2.part "$K"/p.3.part -o "$K/m.hlod" --quiet 2>/dev/null &&
            cmp -s "$K/m.hlod" "$T/small-cutplane.hlod" || wrong=$((wrong + 1))
    else
        "$BIN/hlod-merge" "$K"/p.1.part "$K"/p.3.part -o "$K/m.hlod" --quiet 2>"$K/err" &&
            wrong=$((wrong + 1))
        grep -q "shard 2/3 is missing" "$K/err" || wrong=$((wrong + 1))
    fi
done
[ $wrong -eq 0 ] && [ $kills -eq $runs ]
ok $? "shard 2/3 killed at $runs gates ($kills killed before it finished): never a part the merge takes wrongly ($wrong wrong)"
"$BIN/hlod-build" "$T/small.obj" -o "$K/p.2.part" --desired-tris 450 --quiet --shard 2/3 &&
    "$BIN/hlod-merge" "$K/p.1.part" "$K/p.2.part" "$K/p.3.part" -o "$K/m.hlod" --quiet &&
    cmp -s "$K/m.hlod" "$T/small-cutplane.hlod"
ok $? "the killed shard rerun alone, merged again: byte-identical"

# ---- the command line ----
bad=0
for s in 0/3 4/3 3 1/0 x/2 -1/3 "1/3x"; do
    "$BIN/hlod-build" "$T/small.obj" -o "$T/x.part" --shard "$s" --quiet 2>/dev/null
    [ $? -eq 2 ] || { bad=$((bad + 1)); echo "  --shard $s: not exit 2"; }
done
[ $bad -eq 0 ] && [ ! -e "$T/x.part" ]
ok $? "bad --shard values refused with exit 2"
"$BIN/hlod-merge" --help | grep -q "hlod-merge PART" && "$BIN/hlod-merge" -o "$T/x.hlod" 2>/dev/null
[ $? -eq 2 ]
ok $? "hlod-merge --help; no part: exit 2"

echo "$pass passed, $fail failed"
[ $fail -eq 0 ]
