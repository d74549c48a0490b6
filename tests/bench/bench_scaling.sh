#!/usr/bin/env bash
# bench_scaling.sh - frame time against triangles on Klein's chessboard
# (Klein Fig. 11; docs/sampletree.md).  A benchmark, not a test.
#
#   bash tests/bench/bench_scaling.sh OUTDIR [SIZES...]
#
# For each size N (default 80000 800000 8000000) writes the board
# (hlod-gen-scene --kind chessboard; textured for the HLOD row), builds it
# with each method and runs one fixed low-altitude path at 640x480 with
# hlod-bench, each run beside the machine's own jitter (the run's frozen
# selection drawn again, machine_p50_ms and machine_p99_ms):
#   klein-1, klein-4  the sample tree, policy klein, splat_px 1 and 4;
#   full              the same sample tree, every node drawn (klein with
#                     splats 0: the reference walk, no splats);
#   hlod              cutplane on the textured board, lakhia at TARGET ms;
#   rzb-2             Wand's randomized z-buffer (policy rzb, d = 2, the C
#                     splatter; docs/rzb.md) over cutplane on the
#                     two-colour board (rzb draws corner colours, so not
#                     the textured one);
#   cubes             Chamberlain's colour cubes (hlod-build --method
#                     cubes, policy cubes; docs/cubes.md).
# Every path run is scored against the board's analytic reference (the
# 64 x 64-quad board built into a store, hlod-bench --reference-store,
# supersampled) every 20th frame: psnr_mean.
# Each method runs twice: the low path (FRAMES frames: a moving camera,
# whose loads a big store does not finish), and a still view from the
# path's start (VIEW_FRAMES frames, enough for the loads to settle: its
# frozen selection at frame VIEW_FRAMES / 2 drawn again gives the
# converged frame time, view_p50_ms, and its spread, view_p99_ms).
# Writes OUTDIR/scaling.csv (method, tris, build_s, store_bytes,
# frame_ms_mean, frame_ms_p50, machine_p50_ms, machine_p99_ms, tris_mean,
# splats_mean, view_p50_ms, view_p99_ms, view_tris, view_missing,
# psnr_mean), and
# OUTDIR/scaling.png (log-log converged frame time against triangles per
# method, error bars from the machine's p50 to p99, from the per-method
# rows in OUTDIR/scaling-METHOD.dat) when gnuplot is there.
# Boards and stores are kept in OUTDIR/N/.
# Env: BIN (build/bin), FRAMES (120), VIEW_FRAMES (400 below 4 x 10^6
# triangles, 1,600 from there: a sample tree of 8 x 10^6 settles its
# loads for the still view at about frame 480), TARGET (33),
# JITTER (60), MEMORY_MB (0: build in core; else hlod-build --memory-mb).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
out=$(realpath -m "${1:?usage: bench_scaling.sh OUTDIR [SIZES...]}")
shift
SIZES=("$@")
[ ${#SIZES[@]} -gt 0 ] || SIZES=(80000 800000 8000000)
FRAMES=${FRAMES:-120}
MEMORY_MB=${MEMORY_MB:-0}
TARGET=${TARGET:-33}
JITTER=${JITTER:-60}
mkdir -p "$out" || exit 1
# the path: 6 m over the 256 m board, from one corner towards the other,
# looking ahead and down
perl -e 'for my $i (0 .. 40) { my $t = $i * 0.5; my $x = 20 + 4 * $i; my $y = 10 + 5 * $i;
    printf "%.2f %.3f %.3f 6 %.3f %.3f 0\n", $t, $x, $y, $x + 12, $y + 30 }' >"$out/low.path"
printf "0 20 10 6 32 40 0\n100 20 10 6 32 40 0\n" >"$out/view.path"
csv="$out/scaling.csv"
echo "method,tris,build_s,store_bytes,frame_ms_mean,frame_ms_p50,machine_p50_ms,machine_p99_ms,tris_mean,splats_mean,view_p50_ms,view_p99_ms,view_tris,view_missing,psnr_mean" >"$csv"
. "$ROOT/tests/bench/summary_key.sh"
row() { # METHOD N BUILD_JSON STORE RUN_DIR
    local s="$5/summary.json" v="$5-view/summary.json" last
    last=$(tail -n 1 "$5-view/frames.csv" | cut -d, -f1)
    echo "$1,$(key tris_in "$3"),$(key seconds "$3"),$(stat -c %s "$4"),$(key frame_ms_mean "$s")," \
        "$(key frame_ms_p50 "$s"),$(key machine_p50_ms "$s"),$(key machine_p99_ms "$s")," \
        "$(key tris_mean "$s"),$(key splats_mean "$s"),$(key machine_p50_ms "$v")," \
        "$(key machine_p99_ms "$v"),$(mid "$5-view" tris_drawn),$(mid "$5-view" wanted_missing)," \
        "$(key psnr_mean "$s")" |
        tr -d ' ' >>"$csv"
}
# mid DIR COLUMN: COLUMN of DIR/frames.csv at the frame the jitter replays
mid() {
    perl -e 'my ($f, $c) = @ARGV; open my $h, "<", $f or die; my @n = split /,/, scalar <$h>;
        my ($i) = grep { $n[$_] eq $c } 0 .. $#n; my @r = map { [split /,/] } <$h>;
        print $r[int(@r / 2)][$i]' "$1/frames.csv" "$2"
}
bench() { # STORE RUN_DIR ARGS...: the low path, then the still view
    local st=$1 dir=$2
    shift 2
    "$BIN/hlod-bench" "$st" --path "$out/low.path" --target-ms "$TARGET" --out "$dir" \
        --width 640 --height 480 --frames "$FRAMES" --jitter-frames "$JITTER" --no-plots \
        --memory-mb 8192 --set max_inflight=256 --reference --reference-every 20 \
        --reference-store "$ref" "$@" 2>"$dir.err" >/dev/null &&
        "$BIN/hlod-bench" "$st" --path "$out/view.path" --target-ms "$TARGET" --out "$dir-view" \
            --width 640 --height 480 --frames "$view_frames" --jitter-frames "$JITTER" \
            --no-plots --memory-mb 8192 --set max_inflight=256 "$@" 2>"$dir-view.err" >/dev/null ||
        { echo "failed: $dir (see $dir.err)"; return 1; }
}
for n in "${SIZES[@]}"; do
    view_frames=${VIEW_FRAMES:-$([ "$n" -ge 4000000 ] && echo 1600 || echo 400)}
    d="$out/$n"
    mkdir -p "$d"
    echo "== $n triangles"
    "$BIN/hlod-gen-scene" --kind chessboard --tris "$n" -o "$d/board.obj" --quiet &&
        "$BIN/hlod-gen-scene" --kind chessboard --tris "$n" -o "$d/tboard.obj" --textured --quiet ||
        exit 1
    "$BIN/hlod-build" "$d/board.obj" -o "$d/st.hlod" --method sampletree --memory-mb "$MEMORY_MB" \
        --json --quiet >"$d/st.json" ||
        exit 1
    "$BIN/hlod-build" "$d/tboard.obj" -o "$d/hlod.hlod" --json --quiet >"$d/hlod.json" || exit 1
    "$BIN/hlod-build" "$d/board.obj" -o "$d/flat.hlod" --json --quiet >"$d/flat.json" || exit 1
    "$BIN/hlod-build" "$d/board.obj" -o "$d/cubes.hlod" --method cubes --memory-mb "$MEMORY_MB" \
        --json --quiet >"$d/cubes.json" || exit 1
    ref="$d/ref.hlod"
    "$BIN/hlod-build" "$d/board-reference.obj" -o "$ref" --quiet || exit 1
    for i in 1 4; do
        bench "$d/st.hlod" "$d/klein-$i" --policy klein --set splat_px=$i &&
            row "klein-$i" "$n" "$d/st.json" "$d/st.hlod" "$d/klein-$i"
    done
    bench "$d/st.hlod" "$d/full" --policy klein --set splats=0 &&
        row full "$n" "$d/st.json" "$d/st.hlod" "$d/full"
    bench "$d/hlod.hlod" "$d/hlod" --policy lakhia &&
        row hlod "$n" "$d/hlod.json" "$d/hlod.hlod" "$d/hlod"
    bench "$d/flat.hlod" "$d/rzb-2" --policy rzb --set splat_px=2 &&
        row rzb-2 "$n" "$d/flat.json" "$d/flat.hlod" "$d/rzb-2"
    bench "$d/cubes.hlod" "$d/cubes" --policy cubes &&
        row cubes "$n" "$d/cubes.json" "$d/cubes.hlod" "$d/cubes"
    column -s, -t <"$csv"
done
if command -v gnuplot >/dev/null; then
    # one file per method, its rows in size order, so each line joins its points
    methods="klein-1 klein-4 full hlod rzb-2 cubes"
    for m in $methods; do
        awk -F, -v m="$m" 'NR > 1 && $1 == m' "$csv" | sort -t, -k2,2n >"$out/scaling-$m.dat"
    done
    gnuplot <<GP
set terminal pngcairo size 900,600
set output "$out/scaling.png"
set datafile separator ","
set logscale xy
set key top left
set xlabel "triangles"
set ylabel "frame time of the still view once loaded, ms (bars: p50 to p99)"
set title "Chessboard at 640x480 (Klein Fig. 11)"
plot for [m in "$methods"] "$out/scaling-".m.".dat" using 2:11:11:12 with yerrorlines title m
GP
fi
echo "wrote $csv"
