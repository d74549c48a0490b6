#!/usr/bin/env bash
# reliability_report.sh - runs the reliability tests of issue 6 and prints
# one table: fuzz executions and crashes per harness, faults injected by
# kind with the frames rendered through them, the soak (frames, peak
# resident against the budget, RSS drift), degenerate views and the PSNR of
# the offset cities.
#
#   bash tests/reliability_report.sh [--long] [--fuzz] [--build DIR] [--out DIR]
#
#   (default)  the quick variants, as ctest runs them: test_faults,
#              test_soak (40000 frames), test_degenerate, test_offset_cities
#              (small city, 100 frames)
#   --long     test_soak with HLOD_SOAK_FRAMES=100000 and the default city
#              through tests/bench/stress_default_city.sh (stores kept in
#              out/stress-default-city; the first run builds them: long)
#   --fuzz     also runs tests/fuzz/run.sh (20 s per harness; an hour each
#              with --long) and keeps its output; without --fuzz the last
#              saved fuzz output (OUT/fuzz.out) or the harness logs in
#              build-fuzz/ are read, else the fuzz rows say "not run"
#   --build D  build folder with the tests and tools (default build/,
#              configured if needed; the targets are made with -j${JOBS:-2})
#   --out D    where outputs and logs go (default out/reliability)
#   --table    run nothing: print the table from the outputs already in OUT
#
# The test programs print machine-readable lines ("REPORT faults kind=eio
# injected=8 frames=320 ..."); this script only greps them.  Exits non-zero
# when a test program failed.
set -uo pipefail
cd "$(dirname "$0")/.." || exit 1
ROOT=$(pwd)
BUILD=$ROOT/build
OUT=$ROOT/out/reliability
LONG=0
FUZZ=0
TABLE_ONLY=0
while [ $# -gt 0 ]; do
    case $1 in
    --long) LONG=1; shift ;;
    --fuzz) FUZZ=1; shift ;;
    --build) BUILD=$(cd "$2" 2>/dev/null && pwd || echo "$2"); shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    --table) TABLE_ONLY=1; shift ;;
    -h | --help) sed -n '2,28p' "$0"; exit 0 ;;
    *) echo "reliability_report.sh: unknown option $1" >&2; exit 2 ;;
    esac
done
mkdir -p "$OUT"
failed=0
declare -A status secs
# kv LINE KEY: the value of KEY=VALUE in a REPORT line
kv() { sed -n "s/.* $2=\\([^ ]*\\).*/\\1/p" <<<"$1"; }

if [ $TABLE_ONLY -eq 1 ]; then
    # statuses from the saved outputs: a test program ends with "N passed, M failed"
    for f in "$OUT"/*.out; do
        [ -f "$f" ] || continue
        name=$(basename "$f" .out)
        if grep -qE '^[0-9]+ passed, 0 failed' "$f"; then status[$name]=ok
        elif [ "$name" = fuzz ]; then status[$name]=$(grep -q '^fuzz: .* 0 crashes' "$f" && echo ok || echo FAIL)
        else status[$name]=FAIL; fi
        [ "${status[$name]}" = ok ] || failed=1
    done
else
# ---- build ----
TARGETS=(test_faults test_soak test_degenerate test_offset_cities hlod-gen-city hlod-build)
if [ ! -f "$BUILD/CMakeCache.txt" ]; then
    cmake -S "$ROOT" -B "$BUILD" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DHLOD_BENCH=OFF \
        >"$OUT/cmake.log" 2>&1 || { cat "$OUT/cmake.log" >&2; exit 1; }
fi
echo "reliability: building ${TARGETS[*]} in $BUILD" >&2
make -C "$BUILD" -j"${JOBS:-2}" "${TARGETS[@]}" >"$OUT/make.log" 2>&1 ||
    { tail -n 30 "$OUT/make.log" >&2; echo "reliability: build failed" >&2; exit 1; }

export HLOD_SOURCE_DIR=$ROOT HLOD_BIN_DIR=$BUILD/bin
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$ROOT/tests/lsan.supp}

# run NAME COMMAND...: stdout to OUT/NAME.out, stderr to OUT/NAME.log;
# status[NAME] is ok or FAIL.
run() {
    local name=$1 t0 rc
    shift
    echo "reliability: $name ..." >&2
    t0=$(date +%s)
    "$@" >"$OUT/$name.out" 2>"$OUT/$name.log"
    rc=$?
    secs[$name]=$(($(date +%s) - t0))
    if [ $rc -eq 0 ]; then
        status[$name]=ok
    else
        status[$name]=FAIL
        failed=1
        echo "reliability: $name FAILED (exit $rc), see $OUT/$name.log" >&2
        grep -E 'CHECK failed|ERROR|FAIL' "$OUT/$name.log" | head -n 10 >&2
    fi
}

run test_faults "$BUILD/bin/test_faults"
if [ $LONG -eq 1 ]; then
    run test_soak env HLOD_SOAK_FRAMES=100000 "$BUILD/bin/test_soak"
else
    run test_soak "$BUILD/bin/test_soak"
fi
run test_degenerate "$BUILD/bin/test_degenerate"
run test_offset_cities "$BUILD/bin/test_offset_cities"
if [ $LONG -eq 1 ]; then
    run stress_default_city env HLOD_BUILD_DIR="$BUILD" bash "$ROOT/tests/bench/stress_default_city.sh"
fi
if [ $FUZZ -eq 1 ]; then
    fuzz_secs=20
    [ $LONG -eq 1 ] && fuzz_secs=3600
    run fuzz env FUZZ_SECONDS="${FUZZ_SECONDS:-$fuzz_secs}" bash "$ROOT/tests/fuzz/run.sh"
fi
fi # TABLE_ONLY

# ---- the table ----
row() { printf '%-8s %-30s %-92s %s\n' "$1" "$2" "$3" "$4"; }
res() { echo "${status[$1]:-not run}"; }

echo
if [ $TABLE_ONLY -eq 1 ]; then
    echo "hlod reliability report, from the outputs in $OUT"
else
    echo "hlod reliability report ($([ $LONG -eq 1 ] && echo long || echo quick)), $(date '+%Y-%m-%d %H:%M'), build $BUILD"
fi
row area item figures result
row ---- ---- ------- ------

# fuzzing: tests/fuzz/run.sh's table (harness execs exec/s corpus crashes result)
fuzz_src=""
if [ -s "$OUT/fuzz.out" ] && grep -q '^harness ' "$OUT/fuzz.out"; then
    fuzz_src=$OUT/fuzz.out
fi
for h in store path mesh; do
    fixed=$(ls "$ROOT/tests/fuzz/corpus/$h" 2>/dev/null | grep -c '^crash-' || true)
    line=""
    [ -n "$fuzz_src" ] && line=$(awk -v h="$h" '$1 == h && NF >= 6 { l = $0 } END { print l }' "$fuzz_src")
    if [ -n "$line" ]; then
        read -r _ execs rate corpus crashes result <<<"$line"
        row fuzz "$h" "$execs execs ($rate/s), corpus $corpus, $crashes crashes; $fixed crash inputs fixed and replayed" "$result"
    elif [ -s "$ROOT/build-fuzz/fuzz-$h.log" ]; then
        log=$ROOT/build-fuzz/fuzz-$h.log
        execs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "$log" | tail -n 1 | grep -o '[0-9]*$')
        crashes=$(grep -cE '^==[0-9]+==ERROR|Test unit written' "$log" || true)
        row fuzz "$h" "${execs:-0} execs, $crashes crashes (last build-fuzz/ log, $(date -r "$log" '+%Y-%m-%d %H:%M')); $fixed crash inputs fixed" \
            "$([ "$crashes" -eq 0 ] && echo ok || echo FAIL)"
    else
        row fuzz "$h" "not run (tests/fuzz/run.sh, or this script with --fuzz)" "not run"
    fi
done

# fault injection
while read -r line; do
    [ -n "$line" ] || continue
    kind=$(kv "$line" kind)
    extra=""
    for k in bad eintr recovered base_frames store_log_lines worst_frame_ms payloads; do
        v=$(kv "$line" $k)
        [ -n "$v" ] && extra="$extra, $k $v"
    done
    frames=$(kv "$line" frames)
    row fault "$kind" "$(kv "$line" injected) injected${frames:+ over $frames frames}$extra" "$(res test_faults)"
done < <(grep '^REPORT faults' "$OUT/test_faults.out" 2>/dev/null)
grep -q '^REPORT faults' "$OUT/test_faults.out" 2>/dev/null || row fault - "no output" "$(res test_faults)"

# soak
while read -r line; do
    [ -n "$line" ] || continue
    engines=$(kv "$line" engines)
    what="1 engine"
    [ "$engines" = 1 ] || what="$engines engines, 2 threads"
    peak=$(kv "$line" peak_resident) budget=$(kv "$line" budget)
    pct=$(awk -v p="$peak" -v b="$budget" 'BEGIN { x = 0; if (b > 0) x = 100 * p / b; printf("%.1f", x) }')
    r=$(res test_soak)
    row soak "$what" "$(kv "$line" frames) frames, $(kv "$line" invalid_rejected) NaN/Inf/bad inputs rejected, worst frame() $(kv "$line" worst_frame_ms) ms" "$r"
    row soak "  memory budget" "peak resident $peak of $budget B ($pct%), $(kv "$line" over_budget) frames over" "$r"
    if [ "$engines" = 1 ]; then
        checked="asserted <= 2048 KiB"
        [ "$(kv "$line" rss_checked)" = 1 ] || checked="not asserted under a sanitizer; LSan checks leaks"
        row soak "  RSS drift" "$(kv "$line" rss_warm_kb) KiB at 25% -> $(kv "$line" rss_end_kb) KiB at 100%: $(kv "$line" rss_drift_kb) KiB ($checked)" "$r"
        row soak "  render waits" "$(kv "$line" render_waits) counted by the engine, $(kv "$line" preempted_frames) frames preempted (not judged); $(kv "$line" blocked_frames) frames blocked (longest $(kv "$line" worst_blocked_ms) ms)" "$r"
    fi
done < <(grep '^REPORT soak' "$OUT/test_soak.out" 2>/dev/null)
grep -q '^REPORT soak' "$OUT/test_soak.out" 2>/dev/null || row soak - "no output" "$(res test_soak)"

# degenerate views
line=$(grep '^REPORT degenerate' "$OUT/test_degenerate.out" 2>/dev/null | tail -n 1)
row numeric "degenerate views" "${line:+$(kv "$line" frames) frames checked (no NaN/Inf, valid cut), $(kv "$line" slice_sums) sibling slice sums = parent}" "$(res test_degenerate)"

# offset cities
for name in test_offset_cities stress_default_city; do
    [ -f "$OUT/$name.out" ] || continue
    while read -r line; do
        [ -n "$line" ] || continue
        row numeric "$(kv "$line" preset) city @ $(kv "$line" origin)" \
            "$(kv "$line" frames) frames: PSNR min $(kv "$line" psnr_min) dB, mean $(kv "$line" psnr_mean) dB (> 50 required); $(kv "$line" selection_diffs) node-frames drawn differently; $(kv "$line" nodes_simplified_differently) nodes simplified differently" \
            "$(res $name)"
    done < <(grep '^REPORT offset' "$OUT/$name.out")
done
[ $LONG -eq 1 ] || row numeric "default city" "long variant: --long (or tests/bench/stress_default_city.sh)" "not run"

echo
for name in test_faults test_soak test_degenerate test_offset_cities stress_default_city fuzz; do
    [ -n "${secs[$name]:-}" ] && printf '%s %ss, ' "$name" "${secs[$name]}"
done
echo "outputs in $OUT"
exit $failed
