#!/usr/bin/env bash
# bench_build.sh - hlod-build throughput, peak memory and store size for
# both methods on generated cities.  A benchmark, not a test: it prints a
# table and writes OUT/build.csv; the issue's targets are reported, never
# asserted.
#
#   bash tests/bench/bench_build.sh [--sizes 0.5,2,7] [--out DIR] [--threads T]
#
# Sizes are millions of triangles: cities of 35000-triangle blocks (the
# default city's density), 1024-pixel textures.  The 7M city takes minutes
# per method on 2 cores, so the default is 0.5,2; pass --sizes 0.5,2,7 for
# the full table.
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$(pwd)
BIN=${HLOD_BIN_DIR:-$ROOT/build/bin}
SIZES=0.5,2
OUT=$ROOT/out/bench-build
THREADS=$(nproc)
while [ $# -gt 0 ]; do
    case $1 in
    --sizes) SIZES=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    --threads) THREADS=$2; shift 2 ;;
    -h | --help) sed -n '2,13p' "$0"; exit 0 ;;
    *) echo "bench_build.sh: unknown option $1" >&2; exit 2 ;;
    esac
done
for t in hlod-gen-city hlod-build hlod-info; do
    [ -x "$BIN/$t" ] || { echo "bench_build.sh: $BIN/$t missing: build first" >&2; exit 1; }
done
mkdir -p "$OUT"
csv=$OUT/build.csv
echo "city_mtri,method,blocks,nodes,levels,tris_in,tris_total,seconds,ktri_per_s,peak_rss_mib,store_mib,leaf_payload_mib,store_over_leaf" > "$csv"
printf '%-6s %-9s %7s %7s %6s %10s %9s %9s %9s %10s %9s\n' city method blocks nodes levels tris_in seconds ktri/s rss_MiB store_MiB store/leaf
json() { sed -n "s/.*\"$2\": *\\([^,}]*\\).*/\\1/p" <<<"$1"; }
for size in ${SIZES//,/ }; do
    blocks=$(awk -v s="$size" 'BEGIN { b = int(s * 1e6 / 35000 + 0.5); print b < 1 ? 1 : b }')
    city=$OUT/city_${size}M
    if [ ! -s "$city.obj" ]; then
        "$BIN/hlod-gen-city" --blocks "$blocks" --tris-per-block 35000 --texture-size 1024 --quiet -o "$city.obj"
    fi
    for method in cutplane metis; do
        store=$OUT/city_${size}M_$method.hlod
        j=$("$BIN/hlod-build" "$city.obj" -o "$store" --method "$method" --threads "$THREADS" --quiet --json)
        info=$("$BIN/hlod-info" --json "$store")
        tris_in=$(json "$j" tris_in)
        secs=$(json "$j" seconds)
        rss=$(json "$j" peak_rss_bytes)
        bytes=$(json "$j" bytes)
        leaf=$(json "$info" leaf_payload_bytes)
        row=$(awk -v s="$size" -v m="$method" -v b="$(json "$j" blocks)" -v n="$(json "$j" nodes)" \
            -v l="$(json "$j" levels)" -v ti="$tris_in" -v tt="$(json "$j" tris_total)" -v sec="$secs" \
            -v rss="$rss" -v by="$bytes" -v leaf="$leaf" 'BEGIN {
                printf "%s,%s,%s,%s,%s,%s,%s,%.2f,%.1f,%.0f,%.1f,%.1f,%.2f", s, m, b, n, l, ti, tt, sec,
                    ti / sec / 1e3, rss / 1048576, by / 1048576, leaf / 1048576, by / leaf }')
        echo "$row" >> "$csv"
        IFS=, read -r c me b n l ti tt sec kt rssm sm lm ratio <<<"$row"
        printf '%-6s %-9s %7s %7s %6s %10s %9s %9s %9s %10s %9s\n' "${c}M" "$me" "$b" "$n" "$l" "$ti" "$sec" "$kt" "$rssm" "$sm" "$ratio"
    done
done
echo
echo "targets: 7M city in <= 120 s (cutplane) and <= 180 s (metis), peak RSS < 4096 MiB, store <= 1.7 x leaf payload"
echo "wrote $csv"
