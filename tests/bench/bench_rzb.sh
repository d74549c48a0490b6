#!/usr/bin/env bash
# bench_rzb.sh - Wand's randomized z-buffer (policy rzb, docs/rzb.md) on
# chessboards of growing size, against lakhia on the same stores: the
# shape of Wand's Table 1 (d = 1, 2, 5; fresh points and from the cache;
# GL points and the C splatter) and of Fig. 7 (frame time over rzb_eps).
# A benchmark, not a test: it prints a table and writes one CSV.
#
#   bash tests/bench/bench_rzb.sh OUTDIR [SIZES...]
#
# SIZES: board triangles (default 800000).  Each board is the scaling
# kit's vertex-coloured chessboard (hlod-gen-scene --kind chessboard),
# built with hlod-build (cutplane), run over the kit's low path (41 key
# frames over 20 s) at 640x480, FRAMES frames (default 120), PSNR
# against the full-detail reference every 10th frame.
# Env: BIN (build/bin), FRAMES, CACHE_MB (256), EPS ("1.1 1.2 1.4 1.7 2.0").
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
out=$(realpath -m "${1:?usage: bench_rzb.sh OUTDIR [SIZES...]}")
shift
SIZES=("$@")
[ ${#SIZES[@]} -gt 0 ] || SIZES=(800000)
FRAMES=${FRAMES:-120}
CACHE_MB=${CACHE_MB:-256}
EPS=${EPS:-1.1 1.2 1.4 1.7 2.0}
mkdir -p "$out" || exit 1
perl -e 'for my $i (0 .. 40) { my $t = $i * 0.5; my $x = 20 + 4 * $i; my $y = 10 + 5 * $i;
    printf "%.2f %.3f %.3f 6 %.3f %.3f 0\n", $t, $x, $y, $x + 12, $y + 30 }' >"$out/low.path"
csv="$out/rzb.csv"
echo "tris,run,policy,splat_px,splat_c,cache_mb,rzb_eps,frame_ms_mean,frame_ms_p50,psnr_mean,tris_mean,splats_mean" >"$csv"
. "$ROOT/tests/bench/summary_key.sh"
# run N NAME POLICY [--set k=v ...]: one hlod-bench run, one CSV row
run() {
    local n=$1 name=$2 pol=$3
    shift 3
    local dir="$out/$n/$name" d=1 c=1 cache=0 eps=1.4 a
    for a in "$@"; do
        case $a in
        splat_px=*) d=${a#*=} ;;
        rzb_splat_c=*) c=${a#*=} ;;
        rzb_cache_mb=*) cache=${a#*=} ;;
        rzb_eps=*) eps=${a#*=} ;;
        esac
    done
    local sets=()
    for a in "$@"; do sets+=(--set "$a"); done
    "$BIN/hlod-bench" "$out/$n/board.hlod" --path "$out/low.path" --frames "$FRAMES" \
        --width 640 --height 480 --target-ms 33 --no-plots --jitter-frames 0 \
        --memory-mb 4096 --reference --reference-every 10 --policy "$pol" "${sets[@]}" \
        --out "$dir" >/dev/null 2>"$dir.err" || { echo "bench_rzb: $name failed: $(head -c 300 "$dir.err")" >&2; return 1; }
    local s="$dir/$pol/summary.json"
    [ -f "$s" ] || s="$dir/summary.json"
    [ "$pol" = lakhia ] && { d=; c=; cache=; eps=; }
    echo "$n,$name,$pol,$d,$c,$cache,$eps,$(key frame_ms_mean "$s"),$(key frame_ms_p50 "$s"),$(key psnr_mean "$s"),$(key tris_mean "$s"),$(key splats_mean "$s")" >>"$csv"
}
for n in "${SIZES[@]}"; do
    mkdir -p "$out/$n" || exit 1
    if [ ! -s "$out/$n/board.hlod" ]; then
        "$BIN/hlod-gen-scene" --kind chessboard --tris "$n" -o "$out/$n/board.obj" --quiet &&
            "$BIN/hlod-build" "$out/$n/board.obj" -o "$out/$n/board.hlod" --quiet ||
            { echo "bench_rzb: cannot build the $n board" >&2; exit 1; }
    fi
    run "$n" lakhia lakhia
    for d in 1 2 5; do
        run "$n" "rzb-d$d-gl" rzb "splat_px=$d" rzb_splat_c=0
        run "$n" "rzb-d$d-c" rzb "splat_px=$d" rzb_splat_c=1
        run "$n" "rzb-d$d-cache" rzb "splat_px=$d" rzb_splat_c=1 "rzb_cache_mb=$CACHE_MB"
    done
    for e in $EPS; do
        run "$n" "rzb-eps$e" rzb splat_px=2 rzb_splat_c=1 "rzb_eps=$e"
    done
done
column -s, -t "$csv"
echo "bench_rzb: $csv"
