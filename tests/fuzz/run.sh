#!/usr/bin/env bash
# run.sh - build the libFuzzer harnesses, replay their corpora, then fuzz
# each one for a fixed time.
#
#   bash tests/fuzz/run.sh                      every harness, 20 s each
#   FUZZ_SECONDS=3600 bash tests/fuzz/run.sh    the hour-long run (each)
#   bash tests/fuzz/run.sh store mesh           only these harnesses
#   bash tests/fuzz/run.sh --seeds              rewrite corpus/store/*.hlod
#
# Harnesses (tests/fuzz/fuzz_<name>.c, built with clang
# -fsanitize=fuzzer,address,undefined into build-fuzz/ by CMake's
# HLOD_FUZZ=ON):
#   store  the store reader: open + every payload read (store_read.c)
#   path   the camera path parser (engine/common/path.c)
#   mesh   OBJ/PLY/OFF import + validation (preprocess/io/)
#   lumi   the Grid-Lumigraph index and view parsers (lumigraph_repo.c)
#
# The committed corpus is tests/fuzz/corpus/<name>/: hand-made and real
# seeds, regression inputs (crash-*, hang-*) and found/, a coverage-minimal
# set kept from long runs (refresh it with `fuzz_<name> -merge=1
# -use_counters=0 NEWDIR tests/fuzz/corpus/<name> build-fuzz/corpus/<name>`).
# What a run discovers goes to build-fuzz/corpus/<name>/ (kept between runs,
# never committed) and a crashing input to build-fuzz/artifacts/<run>/.  A
# crash fails the run: reproduce it with `build-fuzz/bin/fuzz_<name>
# ARTIFACT`, fix the code, then copy the artifact into
# tests/fuzz/corpus/<name>/ as crash-<what>, so every later run replays it.
#
# Prints a table (executions, exec/s, corpus, crashes per harness) and a
# last line "fuzz: ..." that tests/run.sh shows in its summary.  Exits
# non-zero on any crash, leak, timeout or build failure.
# Environment: FUZZ_SECONDS (20), FUZZ_JOBS (make -j and harnesses run at
# once, 2), CC/CXX (clang).
set -uo pipefail

cd "$(dirname "$0")/../.." || exit 1
ROOT=$(pwd)
BUILD=$ROOT/build-fuzz
SECONDS_EACH=${FUZZ_SECONDS:-20}
JOBS=${FUZZ_JOBS:-2}
ALL=(store path mesh lumi)

seeds=0
harnesses=()
for a in "$@"; do
    case $a in
    --seeds) seeds=1 ;;
    store | path | mesh | lumi) harnesses+=("$a") ;;
    -h | --help) sed -n '2,30p' "$0"; exit 0 ;;
    *) echo "fuzz: unknown argument '$a' (store, path, mesh, lumi, --seeds)" >&2; exit 2 ;;
    esac
done
[ ${#harnesses[@]} -gt 0 ] || harnesses=("${ALL[@]}")
if ! [[ $SECONDS_EACH =~ ^[1-9][0-9]*$ ]]; then
    echo "fuzz: FUZZ_SECONDS must be a whole number of seconds >= 1, not '$SECONDS_EACH'" >&2
    exit 2
fi

CC=${CC:-clang}
CXX=${CXX:-clang++}
if ! command -v "$CC" >/dev/null 2>&1; then
    echo "fuzz: $CC not found (data/setup.sh installs clang and libclang-rt-14-dev)" >&2
    exit 1
fi

# Sanitizer reports are failures; leaks too (libFuzzer checks them per input).
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}

echo "fuzz: building build-fuzz/ with $CC"
targets=()
for h in "${harnesses[@]}"; do targets+=("fuzz_$h"); done
[ $seeds -eq 1 ] && targets+=(fuzz_seed_store)
if ! cmake -S "$ROOT" -B "$BUILD" -DCMAKE_C_COMPILER="$CC" -DCMAKE_CXX_COMPILER="$CXX" \
        -DCMAKE_BUILD_TYPE=RelWithDebInfo -DHLOD_FUZZ=ON -DHLOD_BENCH=OFF >"$BUILD.cmake.log" 2>&1; then
    cat "$BUILD.cmake.log" >&2
    echo "fuzz: cmake failed (is libclang-rt-14-dev installed?)" >&2
    exit 1
fi
rm -f "$BUILD.cmake.log"
make -C "$BUILD" -j"$JOBS" "${targets[@]}" || { echo "fuzz: build failed" >&2; exit 1; }

if [ $seeds -eq 1 ]; then
    "$BUILD/bin/fuzz_seed_store" "$ROOT/tests/fuzz/corpus/store" || exit 1
fi

# This run's crashing inputs (earlier runs' stay in their own folders).
ART=$BUILD/artifacts/$(date +%Y%m%d-%H%M%S)
mkdir -p "$ART"
# fuzz_one H: replays H's corpus, fuzzes it, and writes its table row to
# $BUILD/row-H ("CRASHES EXECS ROW...").  Harnesses run FUZZ_JOBS at a
# time, each libFuzzer process on one core.
fuzz_one() {
    local h=$1 bin=$BUILD/bin/fuzz_$1 seed_dir=$ROOT/tests/fuzz/corpus/$1
    local work=$BUILD/corpus/$1 log=$BUILD/fuzz-$1.log replay_rc fuzz_rc=0
    mkdir -p "$work"
    # 1. every committed input once (the regression inputs among them)
    echo "==> fuzz $h: replaying $(find "$seed_dir" -type f | wc -l) corpus inputs"
    "$bin" -runs=0 -timeout=10 -rss_limit_mb=2048 -artifact_prefix="$ART/$h-" \
        "$seed_dir" >"$log" 2>&1
    replay_rc=$?
    # 2. a time-boxed run: new inputs go to $work, seeds are read only
    if [ $replay_rc -eq 0 ]; then
        echo "==> fuzz $h: ${SECONDS_EACH}s"
        "$bin" -max_total_time="$SECONDS_EACH" -timeout=10 -rss_limit_mb=2048 \
            -print_final_stats=1 -artifact_prefix="$ART/$h-" \
            "$work" "$seed_dir" >>"$log" 2>&1
        fuzz_rc=$?
    fi
    local execs rate corpus crashes status=ok
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | tail -n 1 | grep -o '[0-9]*$')
    rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | tail -n 1 | grep -o '[0-9]*$')
    corpus=$(ls "$work" | wc -l)
    crashes=$(ls "$ART" | grep -c "^$h-" || true)
    if [ $replay_rc -ne 0 ] || [ $fuzz_rc -ne 0 ] || [ "$crashes" -gt 0 ]; then
        status=FAIL
        [ "$crashes" -gt 0 ] || crashes=1
        echo "fuzz $h FAILED (replay exit $replay_rc, fuzz exit $fuzz_rc); log: $log" >&2
        grep -E '^(==[0-9]+==ERROR|SUMMARY|.*runtime error)|Test unit written' "$log" | head -n 20 >&2
    fi
    printf '%s %s %-8s %12s %9s %8s %8s  %s\n' "$crashes" "${execs:-0}" "$h" "${execs:-0}" \
        "${rate:-0}" "$corpus" "$crashes" "$status" >"$BUILD/row-$h"
}

running=0
for h in "${harnesses[@]}"; do
    rm -f "$BUILD/row-$h"
    fuzz_one "$h" &
    running=$((running + 1))
    if [ $running -ge "$JOBS" ]; then
        wait -n
        running=$((running - 1))
    fi
done
wait

rows=()
total_execs=0
total_crashes=0
failed=0
for h in "${harnesses[@]}"; do
    if ! read -r crashes execs row <"$BUILD/row-$h"; then
        crashes=1 execs=0 row=$(printf '%-8s %12s %9s %8s %8s  %s' "$h" 0 0 0 1 FAIL)
        echo "fuzz $h: no result (the harness's shell died)" >&2
    fi
    [ "$crashes" -gt 0 ] && failed=1
    total_execs=$((total_execs + execs))
    total_crashes=$((total_crashes + crashes))
    rows+=("$row")
done

echo
printf '%-8s %12s %9s %8s %8s  %s\n' harness execs exec/s corpus crashes result
for r in "${rows[@]}"; do echo "$r"; done
echo "fuzz: ${#harnesses[@]} harnesses x ${SECONDS_EACH}s, $total_execs execs, $total_crashes crashes"
rmdir "$ART" 2>/dev/null
exit $failed
