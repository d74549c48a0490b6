#!/usr/bin/env bash
# bench_textures.sh - what block-coded textures (store format 5,
# docs/store-format.md "Block-coded textures") cost and save against JPEG
# textures, measured side by side in one run.  A benchmark, not a test.
#
#   bash tests/bench/bench_textures.sh CITY.obj OUTDIR [PATHS_DIR] [HLOD_BUILD_FLAGS...]
#
# 1. Builds CITY.obj with JPEG textures (--texture-blocks off, store
#    version 4's textures) and with blocks (the default), alternating, ROUNDS
#    times each, and times them; sizes each against its decoded payload
#    (hlod-info's memory_bytes).
# 2. Fidelity: the full-detail reference of every EVERY-th frame of `walk`
#    from each store (hlod-bench --reference, not supersampled), the
#    blocks' frame against the JPEG store's (PSNR per frame).
# 3. Loading, for each moving path in MOVING (fly, walk-drive, walk-to-fly)
#    at 33 ms: the JPEG store, and the blocks store with texture_upload=1
#    (expanded) and 2 (blocks); the loader's finishing share of its CPU
#    time, and the deadline misses of frames with loads queued against
#    those without (frames.csv: measured_ms > target, queued > 0).
# 4. `still` at 66 ms, STILL_RUNS runs per store (expanded): the last
#    frame with a wanted node missing (the front is loaded from the frame
#    after it).
#
# Env: BIN (default build/bin), EVERY (10), ROUNDS (2), WIDTH/HEIGHT
# (1280x720), MOVING, STILL_RUNS (3), MEMORY_MB (the loading and still
# runs' budget; default hlod-bench's, the whole store where it fits, so
# nothing streams after the start: give one under the store's size; at a
# quarter of the default city the moving paths still load little after the
# pinned top).  Prints tables and writes OUTDIR/textures.json.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
usage="usage: bench_textures.sh CITY.obj OUTDIR [PATHS_DIR] [hlod-build flags]"
city=${1:?$usage}
out=${2:?$usage}
paths=${3:-$ROOT/data/paths/default}
shift $(( $# >= 3 ? 3 : $# ))
EVERY=${EVERY:-10}
ROUNDS=${ROUNDS:-2}
W=${WIDTH:-1280}
H=${HEIGHT:-720}
MOVING=${MOVING:-fly walk-drive walk-to-fly}
STILL_RUNS=${STILL_RUNS:-3}
budget=()
[ -n "${MEMORY_MB:-}" ] && budget=(--memory-mb "$MEMORY_MB")
mkdir -p "$out"
. "$ROOT/tests/bench/ref_psnr.sh"

now() { date +%s.%N; }
declare -A secs=([jpeg]=0 [blocks]=0)
for _ in $(seq "$ROUNDS"); do
    for s in jpeg blocks; do
        flag=()
        [ $s = jpeg ] && flag=(--texture-blocks off)
        t0=$(now)
        "$BIN/hlod-build" "$city" -o "$out/$s.hlod" --quiet --json "${flag[@]}" "$@" >"$out/$s.build.json"
        secs[$s]=$(echo "${secs[$s]} + $(now) - $t0" | bc -l)
    done
done
info() { "$BIN/hlod-info" "$out/$1.hlod" --json | sed -n "s/.*\"$2\":\([0-9.e+-]*\).*/\1/p"; }
bkey() { sed -n "s/.*\"$2\": *\([0-9.e+-]*\).*/\1/p" "$out/$1.build.json"; }
key() { sed -n "s/.*\"$2\": *\"\{0,1\}\([0-9a-z.e+-]*\).*/\1/p" "$out/$1/summary.json"; }

echo "== size and build ($ROUNDS builds each, alternated)"
printf '%-8s %12s %12s %7s %8s %6s %6s %6s %9s\n' store bytes decoded ratio build_s bc1 jpeg raw psnr_min
for s in jpeg blocks; do
    b=$(info $s bytes)
    m=$(info $s memory_bytes)
    printf '%-8s %12d %12d %7.3f %8.1f %6d %6d %6d %9.2f\n' $s "$b" "$m" "$(echo "$b / $m" | bc -l)" \
        "$(echo "${secs[$s]} / $ROUNDS" | bc -l)" "$(bkey $s textures_bc1)" "$(bkey $s textures_jpeg)" \
        "$(bkey $s textures_raw)" "$(bkey $s texture_psnr_min)"
done

# fidelity: walk at full detail, blocks against JPEG
frames=$("$BIN/hlod-bench" "$out/jpeg.hlod" --path walk --paths-dir "$paths" --target-ms 1000 \
    --out "$out/count" --width 16 --height 16 --jitter-frames 0 --no-plots --json 2>/dev/null |
    sed -n 's/.*"frames": *\([0-9]*\).*/\1/p')
list=$(seq -s, 0 "$EVERY" $((frames - 1)))
for s in jpeg blocks; do
    "$BIN/hlod-bench" "$out/$s.hlod" --path walk --paths-dir "$paths" --target-ms 1000 \
        --width "$W" --height "$H" --reference --reference-every "$EVERY" --reference-ss 1 \
        --save-frames "$list" --jitter-frames 0 --no-plots --out "$out/walk-$s" >/dev/null 2>"$out/walk-$s.log"
done
read -r min mean n < <(ref_psnr "$BIN" "$out/walk-jpeg" "$out/walk-blocks")
printf '== fidelity: walk at full detail, %d frames (every %d): blocks vs JPEG store PSNR min %.2f dB, mean %.2f dB\n' \
    "$n" "$EVERY" "$min" "$mean"

# loading on the moving paths
split() {   # split RUN_DIR TARGET: misses with loads queued, frames, misses without, frames
    awk -F, -v t="$2" 'NR == 1 { for (i = 1; i <= NF; i++) c[$i] = i; next }
        { q = $c["queued"] > 0; f[q]++; if ($c["measured_ms"] > t) m[q]++ }
        END { printf "%d %d %d %d\n", m[1], f[1], m[0], f[0] }' "$1/frames.csv"
}
echo "== loading at 33 ms"
printf '%-12s %-9s %9s %8s %8s %13s %13s %8s %7s\n' path store upload finish busy_ms miss_queued miss_idle ratio waits
json_rows=""
for p in $MOVING; do
    for v in jpeg:1 blocks:1 blocks:2; do
        s=${v%:*}
        u=${v#*:}
        d="$out/$p-$s-$u"
        "$BIN/hlod-bench" "$out/$s.hlod" --path "$p" --paths-dir "$paths" --target-ms 33 \
            --width "$W" --height "$H" --jitter-frames 0 --no-plots --set "texture_upload=$u" "${budget[@]}" \
            --out "$d" >/dev/null 2>"$d.log"
        read -r mq fq mi fi < <(split "$d" 33)
        rq=$(echo "if ($fq > 0) $mq / $fq else 0" | bc -l)
        ri=$(echo "if ($fi > 0) $mi / $fi else 0" | bc -l)
        ratio=$(echo "if ($ri > 0) $rq / $ri else 0" | bc -l)
        printf '%-12s %-9s %9s %8.3f %8.0f %6d/%-6d %6d/%-6d %8.2f %7s\n' "$p" "$s" "$(key "${d#"$out"/}" texture_upload)" \
            "$(key "${d#"$out"/}" loader_finish_share)" "$(key "${d#"$out"/}" loader_busy_ms)" "$mq" "$fq" "$mi" "$fi" \
            "$ratio" "$(key "${d#"$out"/}" render_waits)"
        json_rows="$json_rows{\"path\": \"$p\", \"store\": \"$s\", \"texture_upload\": \"$(key "${d#"$out"/}" texture_upload)\", \"loader_finish_share\": $(key "${d#"$out"/}" loader_finish_share), \"miss_queued\": $mq, \"frames_queued\": $fq, \"miss_idle\": $mi, \"frames_idle\": $fi, \"render_waits\": $(key "${d#"$out"/}" render_waits)},"
    done
done

# still at 66 ms: when the front is loaded
echo "== still at 66 ms: the last frame with a wanted node missing"
still_rows=""
for s in jpeg blocks; do
    for r in $(seq "$STILL_RUNS"); do
        d="$out/still-$s-$r"
        "$BIN/hlod-bench" "$out/$s.hlod" --path still --paths-dir "$paths" --target-ms 66 \
            --width "$W" --height "$H" --jitter-frames 0 --no-plots "${budget[@]}" --out "$d" \
            >/dev/null 2>"$d.log"
        last=$(awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) c[$i] = i; next }
            $c["wanted_missing"] > 0 { l = $c["frame"] } END { print l == "" ? -1 : l }' "$d/frames.csv")
        printf '%-8s run %d: %s\n' $s "$r" "$last"
        still_rows="$still_rows{\"store\": \"$s\", \"run\": $r, \"last_missing_frame\": $last},"
    done
done

cat >"$out/textures.json" <<EOF
{"jpeg_bytes": $(info jpeg bytes), "blocks_bytes": $(info blocks bytes),
 "jpeg_memory_bytes": $(info jpeg memory_bytes), "blocks_memory_bytes": $(info blocks memory_bytes),
 "jpeg_build_s": $(echo "${secs[jpeg]} / $ROUNDS" | bc -l), "blocks_build_s": $(echo "${secs[blocks]} / $ROUNDS" | bc -l),
 "textures_bc1": $(bkey blocks textures_bc1), "textures_jpeg": $(bkey blocks textures_jpeg),
 "texture_psnr_min": $(bkey blocks texture_psnr_min),
 "walk_frames": $n, "walk_psnr_min": $min, "walk_psnr_mean": $mean,
 "loading": [${json_rows%,}],
 "still": [${still_rows%,}]}
EOF
echo "wrote $out/textures.json"
