#!/usr/bin/env bash
# bench_rzb_copies.sh - the shape of Wand Fig. 6: the randomized z-buffer
# (policy rzb, docs/rzb.md) on a chessboard of growing complexity whose
# picture stays the same.  A benchmark, not a test: it prints a table and
# writes one CSV (and a plot where gnuplot is installed).
#
#   bash tests/bench/bench_rzb_copies.sh OUTDIR
#
# The board is the scaling kit's vertex-coloured chessboard of 2,048
# triangles (hlod-gen-scene --kind chessboard --tris 2048, 256 units a
# side), built once.  At level N it is drawn as 2^N x 2^N copies of itself
# held once (--set rzb_copies=N): a board of 2048 x 4^N triangles, 10^14
# at N = 18 (1.4 x 10^14).  The eye, its target and the near plane are
# scaled by 2^N with it, so every level shows the same picture (the
# paper: "the projected area and other geometric parameters remained
# constant"): a slow arc 60 units x 2^N above the board's corner, looking
# at its middle, 640x480, FRAMES frames.
#
# Two rows a level: rzb_raster=0 (points only, as the paper measured: no
# rasterised faces, no caches) and rzb_raster=1 (the default: faces that
# project over d^2 / ln v pixels rasterised).  ROUNDS rounds, the levels
# alternated within each, so the machine's drift falls on every level
# alike; the machine's own jitter is the spread of a level's rounds (a
# replay of rzb samples the frame again, so it would double the run).
#
# Env: BIN (build/bin), LEVELS ("0 1 2 ... 18"), FRAMES (20), ROUNDS (2),
# SPLAT_PX (1).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
out=$(realpath -m "${1:?usage: bench_rzb_copies.sh OUTDIR}")
LEVELS=${LEVELS:-$(seq -s ' ' 0 18)}
FRAMES=${FRAMES:-20}
ROUNDS=${ROUNDS:-2}
SPLAT_PX=${SPLAT_PX:-1}
mkdir -p "$out" || exit 1
if [ ! -s "$out/board.hlod" ]; then
    "$BIN/hlod-gen-scene" --kind chessboard --tris 2048 -o "$out/board.obj" --quiet &&
        "$BIN/hlod-build" "$out/board.obj" -o "$out/board.hlod" --quiet ||
        { echo "bench_rzb_copies: building the board failed" >&2; exit 1; }
fi
. "$ROOT/tests/bench/summary_key.sh"
csv="$out/rzb_copies.csv"
echo "levels,tris,raster,round,frame_ms_mean,frame_ms_p50,frame_ms_p99,splats_mean,tris_mean" >"$csv"
for r in $(seq "$ROUNDS"); do
    for n in $LEVELS; do
        k=$(perl -e "print 2 ** $n")
        path="$out/arc-$n.path"
        # 21 keys over 10 s: the eye on an arc of 20 degrees round the
        # board's middle (128, 128) x k, 60 x k up, at 240 x k from it
        perl -e 'my $k = $ARGV[0]; for my $i (0 .. 20) { my $a = (215 + $i) * 3.14159265358979 / 180;
            printf "%.2f %.17g %.17g %.17g %.17g %.17g 0\n", $i * 0.5, $k * (128 + 240 * cos $a),
                $k * (128 + 240 * sin $a), 60 * $k, 128 * $k, 128 * $k }' "$k" >"$path"
        for raster in 0 1; do
            dir="$out/L$n-r$raster-$r"
            "$BIN/hlod-bench" "$out/board.hlod" --path "$path" --frames "$FRAMES" \
                --width 640 --height 480 --target-ms 33 --no-plots --jitter-frames 0 \
                --near "$(perl -e "print 0.25 * $k")" --policy rzb --set "rzb_copies=$n" \
                --set "rzb_raster=$raster" --set "splat_px=$SPLAT_PX" --out "$dir" \
                >/dev/null 2>"$dir.err" ||
                { echo "bench_rzb_copies: level $n failed: $(head -c 300 "$dir.err")" >&2; continue; }
            s="$dir/summary.json"
            echo "$n,$(perl -e "print 2048 * 4 ** $n"),$raster,$r,$(key frame_ms_mean "$s"),$(key frame_ms_p50 "$s"),$(key frame_ms_p99 "$s"),$(key splats_mean "$s"),$(key tris_mean "$s")" >>"$csv"
        done
    done
done
# the table: per level and raster, the mean of the rounds' frame means and
# its ratio to level 0's
perl -e '
    open my $h, "<", $ARGV[0] or die; <$h>;
    my (%sum, %cnt, %min, %max, %pts, %tris);
    while (<$h>) { chomp; my @f = split /,/; my $id = "$f[0],$f[2]";
        $sum{$id} += $f[4]; $cnt{$id}++; $min{$id} = $f[4] if !defined $min{$id} || $f[4] < $min{$id};
        $max{$id} = $f[4] if !defined $max{$id} || $f[4] > $max{$id};
        $tris{$f[0]} = $f[1]; $pts{$id} = $f[7]; }
    printf "%6s %10s  %-40s %-40s\n", "levels", "triangles", "points only: ms (rounds), x level 0, points",
        "large faces rasterised: the same";
    for my $n (sort { $a <=> $b } keys %tris) {
        my @c;
        for my $r (0, 1) { my $id = "$n,$r"; next unless $cnt{$id};
            my $m = $sum{$id} / $cnt{$id}, my $b = $sum{"0,$r"} / ($cnt{"0,$r"} || 1);
            push @c, sprintf "%6.1f (%.1f-%.1f) x%.2f %.2fM", $m, $min{$id}, $max{$id}, $b ? $m / $b : 0, $pts{$id} / 1e6; }
        printf "%6d %10.3g  %-40s %-40s\n", $n, $tris{$n}, @c; }' "$csv"
if command -v gnuplot >/dev/null; then
    # one point a level: the mean of its rounds
    for raster in 0 1; do
        awk -F, -v r=$raster 'NR > 1 && $3 == r { s[$1] += $5; n[$1]++; t[$1] = $2 }
            END { for (l in s) printf "%d,%s,%.6g\n", l, t[l], s[l] / n[l] }' "$csv" |
            sort -t, -k1,1n >"$out/copies-r$raster.dat"
    done
    gnuplot <<GP
set terminal pngcairo size 900,600
set output "$out/rzb_copies.png"
set datafile separator ","
set logscale x
set key top left
set xlabel "triangles (2,048 x 4^N, as 2^N x 2^N copies)"
set ylabel "mean frame time, ms (mean of the rounds)"
set title "Randomized z-buffer on a chessboard of growing complexity, same picture (Wand Fig. 6), 640x480"
plot "$out/copies-r0.dat" using 2:3 with linespoints title "points only", \
     "$out/copies-r1.dat" using 2:3 with linespoints title "large faces rasterised"
GP
fi
echo "wrote $csv"
