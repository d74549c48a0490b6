#!/usr/bin/env bash
# bench_store_codec.sh - what the packed store format (docs/store-format.md)
# costs and saves, measured side by side in one run.  A benchmark, not a test.
#
#   bash tests/bench/bench_store_codec.sh CITY.obj OUTDIR [PATHS_DIR] [HLOD_BUILD_FLAGS...]
#
# Builds CITY.obj three times with this build's hlod-build: --compress off
# (raw payloads, the layout of store versions 1-2), packed (the default) and
# packed with lossless textures (--jpeg-quality 0: geometry compression
# alone), alternating raw and packed builds twice to time them.  Then, for
# each store, renders the full-detail reference of every EVERY-th frame of
# the walk path (hlod-bench --reference, not supersampled) and compares the
# packed stores' references with the raw one's (PSNR per frame), and runs
# fly at 33 ms to compare bytes read and the loader's finishing (checksum,
# decode, validation) share of its CPU time.
#
# Env: BIN (default build/bin), EVERY (default 1), WIDTH/HEIGHT (1280x720),
# BASE_BUILD (an older hlod-build to time and size beside them, optional).
# Prints a table and writes OUTDIR/codec.json.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
city=${1:?usage: bench_store_codec.sh CITY.obj OUTDIR [PATHS_DIR] [hlod-build flags]}
out=${2:?usage: bench_store_codec.sh CITY.obj OUTDIR [PATHS_DIR] [hlod-build flags]}
paths=${3:-$ROOT/data/paths/default}
shift $(( $# >= 3 ? 3 : $# ))
EVERY=${EVERY:-1}
W=${WIDTH:-1280}
H=${HEIGHT:-720}
mkdir -p "$out"
. "$ROOT/tests/bench/ref_psnr.sh"

now() { date +%s.%N; }
build() {   # build NAME FLAGS...: store OUT/NAME.hlod, prints seconds
    local name=$1
    shift
    local t0
    t0=$(now)
    "$BIN/hlod-build" "$city" -o "$out/$name.hlod" --quiet "$@"
    echo "$(now) - $t0" | bc -l
}

declare -A secs
secs[raw]=0
secs[packed]=0
for round in 1 2; do
    s=$(build raw --compress off "$@")
    secs[raw]=$(echo "${secs[raw]} + $s" | bc -l)
    s=$(build packed "$@")
    secs[packed]=$(echo "${secs[packed]} + $s" | bc -l)
done
build geometry --jpeg-quality 0 "$@" >/dev/null
base_bytes=0
base_secs=0
if [ -n "${BASE_BUILD:-}" ]; then
    t0=$(now)
    "$BASE_BUILD" "$city" -o "$out/base.hlod" --quiet "$@"
    base_secs=$(echo "$(now) - $t0" | bc -l)
    base_bytes=$(stat -c %s "$out/base.hlod")
    rm -f "$out/base.hlod"
fi

frames=$("$BIN/hlod-bench" "$out/raw.hlod" --path walk --paths-dir "$paths" --target-ms 1000 \
    --out "$out/count" --width 16 --height 16 --jitter-frames 0 --no-plots --json |
    sed -n 's/.*"frames": *\([0-9]*\).*/\1/p')
list=$(seq -s, 0 "$EVERY" $((frames - 1)))
for s in raw packed geometry; do
    "$BIN/hlod-bench" "$out/$s.hlod" --path walk --paths-dir "$paths" --target-ms 1000 \
        --width "$W" --height "$H" --reference --reference-every "$EVERY" --reference-ss 1 \
        --save-frames "$list" --jitter-frames 0 --no-plots --out "$out/walk-$s" >/dev/null
    "$BIN/hlod-bench" "$out/$s.hlod" --path fly --paths-dir "$paths" --target-ms 33 \
        --width "$W" --height "$H" --jitter-frames 0 --no-plots --out "$out/fly-$s" >/dev/null
done

psnr() { # psnr STORE: min and mean PSNR of its references against raw's
    ref_psnr "$BIN" "$out/walk-raw" "$out/walk-$1"
}
key() { sed -n "s/.*\"$2\": *\([0-9.e+-]*\).*/\1/p" "$out/$1/summary.json"; }

read -r pmin pmean n < <(psnr packed)
read -r gmin gmean _ < <(psnr geometry)
raw_b=$(stat -c %s "$out/raw.hlod")
pk_b=$(stat -c %s "$out/packed.hlod")
geo_b=$(stat -c %s "$out/geometry.hlod")
printf '%-10s %14s %8s %10s %12s %12s %14s\n' store bytes ratio build_s walk_psnr_min walk_psnr_mean fly_bytes_read
printf '%-10s %14d %8.3f %10.1f %12s %12s %14s\n' raw "$raw_b" 1 "$(echo "${secs[raw]} / 2" | bc -l)" - - "$(key fly-raw bytes_read)"
printf '%-10s %14d %8.3f %10.1f %12.2f %12.2f %14s\n' packed "$pk_b" "$(echo "$pk_b / $raw_b" | bc -l)" \
    "$(echo "${secs[packed]} / 2" | bc -l)" "$pmin" "$pmean" "$(key fly-packed bytes_read)"
printf '%-10s %14d %8.3f %10s %12.2f %12.2f %14s\n' geometry "$geo_b" "$(echo "$geo_b / $raw_b" | bc -l)" - \
    "$gmin" "$gmean" "$(key fly-geometry bytes_read)"
[ "$base_bytes" != 0 ] && printf '%-10s %14d %8s %10.1f\n' base "$base_bytes" - "$base_secs"
echo "walk frames compared: $n (every $EVERY); fly loader finish share: raw $(key fly-raw loader_finish_share), packed $(key fly-packed loader_finish_share)"
cat >"$out/codec.json" <<EOF
{"raw_bytes": $raw_b, "packed_bytes": $pk_b, "geometry_bytes": $geo_b,
 "raw_build_s": $(echo "${secs[raw]} / 2" | bc -l), "packed_build_s": $(echo "${secs[packed]} / 2" | bc -l),
 "base_bytes": $base_bytes, "base_build_s": $base_secs,
 "walk_frames": $n, "packed_psnr_min": $pmin, "packed_psnr_mean": $pmean,
 "geometry_psnr_min": $gmin, "geometry_psnr_mean": $gmean,
 "fly_bytes_read_raw": $(key fly-raw bytes_read), "fly_bytes_read_packed": $(key fly-packed bytes_read),
 "fly_finish_share_raw": $(key fly-raw loader_finish_share), "fly_finish_share_packed": $(key fly-packed loader_finish_share),
 "fly_finish_ms_packed": $(key fly-packed loader_finish_ms), "fly_busy_ms_packed": $(key fly-packed loader_busy_ms)}
EOF
