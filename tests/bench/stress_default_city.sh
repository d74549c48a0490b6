#!/usr/bin/env bash
# stress_default_city.sh - the long variant of the numerical stress test at
# scale (issue 6): the DEFAULT generated city (7M triangles) at the origin,
# at (5e5, 4.1e6, 0) and at (6e6, 6e6, 0) metres, each built with
# hlod-build --desired-tris 400, replayed along data/paths/default/
# walk-to-fly.path (100 frames, shifted by each origin) through the engine in
# deterministic mode on OSMesa: every far frame must match the origin frame
# (PSNR > 50 dB) and draw the same nodes.  It is tests/test_offset_cities
# (the quick version on the small city, run by ctest) with the default
# city; not run by the test suite: generating takes about 90 s per city and
# building several minutes on 2 cores.
#
#   bash tests/bench/stress_default_city.sh [--out DIR] [--frames N]
#        [--size WxH] [--path FILE] [--preset P]
#
# The stores stay in DIR (default out/stress-default-city) and are reused
# by the next run; delete DIR to rebuild.  Prints the test's REPORT lines and
# exits non-zero when a frame differs.  Needs a build with the tools and
# test_offset_cities (HLOD_BUILD_DIR, default build/).
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$(pwd)
BUILD=${HLOD_BUILD_DIR:-$ROOT/build}
OUT=$ROOT/out/stress-default-city
FRAMES=100
SIZE=320x180
PRESET=default
PATH_FILE=
while [ $# -gt 0 ]; do
    case $1 in
    --out) OUT=$2; shift 2 ;;
    --frames) FRAMES=$2; shift 2 ;;
    --size) SIZE=$2; shift 2 ;;
    --path) PATH_FILE=$2; shift 2 ;;
    --preset) PRESET=$2; shift 2 ;;
    -h | --help) sed -n '2,19p' "$0"; exit 0 ;;
    *) echo "stress_default_city.sh: unknown option $1" >&2; exit 2 ;;
    esac
done
for t in bin/hlod-gen-city bin/hlod-build bin/test_offset_cities; do
    [ -x "$BUILD/$t" ] || {
        echo "stress_default_city.sh: $BUILD/$t missing: build it first" \
            "(make -C $BUILD hlod-gen-city hlod-build test_offset_cities)" >&2
        exit 1
    }
done
mkdir -p "$OUT"
echo "stress_default_city: $PRESET city in $OUT ($FRAMES frames at $SIZE)" >&2
# fixed_v_time scales with the city: the default city's leaves hold ~50x the
# small city's triangles, so a smaller v_time keeps the selection refining
# along the path instead of clamping at the roots.
export HLOD_SOURCE_DIR=$ROOT HLOD_BIN_DIR=$BUILD/bin HLOD_OFFSET_PRESET=$PRESET \
    HLOD_OFFSET_TRIS=400 HLOD_OFFSET_DIR=$OUT HLOD_OFFSET_FRAMES=$FRAMES \
    HLOD_OFFSET_SIZE=$SIZE HLOD_OFFSET_V_TIME=${HLOD_OFFSET_V_TIME:-2e-4}
[ -z "$PATH_FILE" ] || export HLOD_OFFSET_PATH=$PATH_FILE
time "$BUILD/bin/test_offset_cities"
