#!/usr/bin/env bash
# bench_cubes_copies.sh - the shape of Chamberlain Fig. 5: colour cubes
# (policy cubes, docs/cubes.md) on a forest made by instancing one tree
# at the top.  A benchmark, not a test: it prints a table and writes one
# CSV.
#
#   bash tests/bench/bench_cubes_copies.sh OUTDIR
#
# The tree is the paper's (hlod-gen-scene --kind tree --tris 52470),
# built once with --method cubes --leaf-tris 64 (another colour-cube store
# put at OUTDIR/tree.hlod beforehand is used instead).  At level N it is drawn
# as 2^N x 2^N copies held once (--set cube_copies=N): 4^N trees, 16,384
# (8.6 x 10^8 triangles) at N = 7.  The eye stands still outside the
# forest's corner, looking at its middle from a distance and height that
# grow with the forest (2^N tree widths), so every level fills the same
# part of the picture with more, smaller trees (the scene's projected
# area constant, as for Wand Fig. 6).  VIEW=edge keeps the eye at the
# corner of the first tree instead, so each level adds trees farther off.
# 320x240, FRAMES frames with every wanted node read before the
# frame (--deterministic), then the frozen frame drawn JITTER times: its
# p50 and p99 are the level's time.  Two rows a level: cubes (cube_px 1)
# and full (every node of every copy: cubes with splats=0), full up to
# FULL_MAX levels.  The table ends with the fit of cubes' time to
# a + b ln(trees) and the break-even: the fewest trees from which cubes
# stays faster than full.
#
# Env: BIN (build/bin), LEVELS ("0 1 2 3 4 5 6 7"), FULL_MAX (4),
# FRAMES (10), JITTER (30), CUBE_PX (1), VIEW (scaled or edge).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
out=$(realpath -m "${1:?usage: bench_cubes_copies.sh OUTDIR}")
LEVELS=${LEVELS:-0 1 2 3 4 5 6 7}
FULL_MAX=${FULL_MAX:-4}
FRAMES=${FRAMES:-10}
JITTER=${JITTER:-30}
CUBE_PX=${CUBE_PX:-1}
VIEW=${VIEW:-scaled}
mkdir -p "$out" || exit 1
if [ ! -s "$out/tree.hlod" ]; then
    "$BIN/hlod-gen-scene" --kind tree --tris 52470 -o "$out/tree.obj" --quiet &&
        "$BIN/hlod-build" "$out/tree.obj" -o "$out/tree.hlod" --method cubes --leaf-tris 64 --quiet ||
        { echo "bench_cubes_copies: building the tree failed" >&2; exit 1; }
fi
. "$ROOT/tests/bench/summary_key.sh"
"$BIN/hlod-info" "$out/tree.hlod" --json >"$out/info.json" || exit 1
# view N: the path of level N.  scaled: the eye 1.2 forest widths back
# from the forest's low corner along the diagonal and 0.9 widths up,
# looking at the middle of its ground; edge: at the first tree's corner,
# 1.5 heights up, looking along the diagonal at the far ground
view() {
    perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
        my ($k, $how) = (2 ** $ARGV[0], $ARGV[1]); my ($lo, $hi) = ($j->{bbox_min}, $j->{bbox_max});
        my @s = map { $hi->[$_] - $lo->[$_] } 0 .. 2; my (@e, @a);
        if ($how eq "edge") {
            @e = ($lo->[0] - $s[0], $lo->[1] - $s[1], $lo->[2] + 1.5 * $s[2]);
            @a = ($lo->[0] + 100 * $s[0], $lo->[1] + 100 * $s[1], $lo->[2]);
        } else {
            @a = ($lo->[0] + $k * $s[0] / 2, $lo->[1] + $k * $s[1] / 2, $lo->[2]);
            @e = ($lo->[0] - 0.7 * $k * $s[0], $lo->[1] - 0.7 * $k * $s[1], $lo->[2] + 0.9 * $k * $s[0]);
        }
        printf "%g %.9g %.9g %.9g %.9g %.9g %.9g\n", $_, @e, @a for (0, 100)' "$1" "$VIEW" <"$out/info.json"
}
# the model's triangles (the paper's tree's, or whatever OUTDIR/tree.hlod holds)
tris1=$(key tris_total "$out/info.json")
[ -n "$tris1" ] || { echo "bench_cubes_copies: no tris_total in $out/info.json" >&2; exit 1; }
csv="$out/cubes_copies.csv"
echo "levels,trees,tris,policy,p50_ms,p99_ms,tris_mean,cubes_mean,missing_last" >"$csv"
for n in $LEVELS; do
    trees=$(perl -e "print 4 ** $n")
    for pol in cubes full; do
        [ "$pol" = full ] && [ "$n" -gt "$FULL_MAX" ] && continue
        how=(--set "cube_px=$CUBE_PX")
        [ "$pol" = full ] && how=(--set splats=0)
        dir="$out/L$n-$pol"
        view "$n" >"$out/L$n.path" || exit 1
        "$BIN/hlod-bench" "$out/tree.hlod" --path "$out/L$n.path" --frames "$FRAMES" \
            --width 320 --height 240 --target-ms 33 --no-plots --jitter-frames "$JITTER" \
            --near "$(perl -e "print 0.25 * 2 ** $n")" \
            --deterministic --set deterministic_load_bytes=4000000000 --set max_inflight=1000000 \
            --policy cubes --set "cube_copies=$n" "${how[@]}" --out "$dir" >/dev/null 2>"$dir.err" ||
            { echo "bench_cubes_copies: $dir failed (see $dir.err)" >&2; continue; }
        missing=$(tail -1 "$dir/frames.csv" | perl -e 'my @h = split /,/, $ARGV[0]; my @r = split /,/, <STDIN>;
            my ($i) = grep { $h[$_] eq "wanted_missing" } 0 .. $#h; print $r[$i]' "$(head -1 "$dir/frames.csv")")
        echo "$n,$trees,$((trees * tris1)),$pol,$(key machine_p50_ms "$dir/summary.json"),$(key machine_p99_ms "$dir/summary.json"),$(key tris_mean "$dir/summary.json"),$(key splats_mean "$dir/summary.json"),$missing" >>"$csv"
    done
done
column -s, -t "$csv"
perl -e 'my (%c, %f); <STDIN>; while (<STDIN>) { chomp; my @r = split /,/; ($r[3] eq "cubes" ? \%c : \%f)->{$r[1]} = $r[4] }
    my @n = sort { $a <=> $b } keys %c; my ($sx, $sy, $sxx, $sxy, $syy) = (0) x 5;
    for (@n) { my ($x, $y) = (log($_), $c{$_}); $sx += $x; $sy += $y; $sxx += $x * $x; $sxy += $x * $y; $syy += $y * $y }
    my $k = @n; exit 0 if $k < 3; my $b = ($k * $sxy - $sx * $sy) / ($k * $sxx - $sx ** 2); my $a = ($sy - $b * $sx) / $k;
    my $ss = 0; my $m = $sy / $k; my $st = 0; for (@n) { my $e = $c{$_} - ($a + $b * log($_)); $ss += $e * $e; $st += ($c{$_} - $m) ** 2 }
    printf "cubes: p50 = %.2f + %.2f ln(trees) ms, R^2 %.3f over %d levels\n", $a, $b, $st > 0 ? 1 - $ss / $st : 1, $k;
    my @both = grep { exists $f{$_} } @n; my $be;
    for my $i (reverse 0 .. $#both) { last unless $c{$both[$i]} < $f{$both[$i]}; $be = $both[$i] }
    printf "break-even: %s\n", defined $be ? "cubes faster than full from $be trees on (as far as full ran)" : "cubes slower than full at the largest level full ran"' <"$csv"
