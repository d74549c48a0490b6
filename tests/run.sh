#!/usr/bin/env bash
# run.sh - THE test command: install, build and run every test.
#
#   bash tests/run.sh        (as root on Debian 12; safe to run again)
#
# 1. data/setup.sh installs missing Debian packages;
# 2. npm ci installs the node packages pinned in package-lock.json into
#    node_modules/ (the tiles test's readers and browser driver,
#    meshoptimizer for hlod-bench-simplify);
# 3. data/fetch-meshes.sh puts the real test meshes into data/meshes/;
# 4. configures and builds build/ (normal, with benchmarks) and runs ctest;
# 5. configures and builds build-asan/ (ASan + UBSan, no benchmarks) and
#    runs ctest again;
# 6. builds the threaded tools and their tests with ThreadSanitizer
#    (build-tsan/) and runs those tests;
# 7. builds the libFuzzer harnesses with clang (build-fuzz/), replays their
#    corpora and fuzzes each for 20 s (tests/fuzz/run.sh).
# Prints a summary and exits non-zero if any step or any test failed.
# .ci/run calls exactly this script.
set -uo pipefail

cd "$(dirname "$0")/.." || exit 1
ROOT=$(pwd)
JOBS=2
mkdir -p "$ROOT/out/test-logs"

# Everything a test needs is installed here: a test that would skip fails
# (tests/check.h, tests/test_build_safety.sh).
export HLOD_TEST_STRICT=1

# Sanitizer reports must fail the test that triggered them.
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
# Mesa's OSMesa keeps ~200 bytes per context until exit; only that library
# is suppressed, our own leaks still fail the tests.
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$ROOT/tests/lsan.supp}

summary=()
failed=0
note=""   # set by a step to add to its summary line
start_all=$(date +%s)

# step NAME COMMAND...: runs a step, records "ok"/"FAIL" and its duration.
step() {
    local name=$1
    shift
    local t0 rc
    t0=$(date +%s)
    echo "==> $name"
    "$@"
    rc=$?
    local dt=$(($(date +%s) - t0))
    if [ $rc -eq 0 ]; then
        summary+=("$(printf '%-20s ok    %4ds  %s' "$name" "$dt" "$note")")
    else
        summary+=("$(printf '%-20s FAIL  %4ds  %s' "$name" "$dt" "${note:-exit $rc}")")
        failed=1
    fi
    note=""
    return $rc
}

finish() {
    echo
    echo "==> summary"
    for line in "${summary[@]}"; do
        echo "  $line"
    done
    echo "  total $(($(date +%s) - start_all))s"
    if [ $failed -eq 0 ]; then
        echo "ALL TESTS PASSED"
        exit 0
    fi
    echo "FAILED (logs in out/test-logs/)"
    exit 1
}

# build DIR CMAKE_ARGS...: configure and build one tree.
build() {
    local dir=$1
    shift
    cmake -S "$ROOT" -B "$ROOT/$dir" "$@" &&
        make -C "$ROOT/$dir" -j"$JOBS"
}

# run_ctest DIR: all tests of one tree; the tail of the log gives the count.
run_ctest() {
    local dir=$1 log="$ROOT/out/test-logs/ctest-$1.log"
    (cd "$ROOT/$dir" && ctest --output-on-failure -j"$JOBS") 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    note=$(grep -E 'tests passed|tests failed' "$log" | tail -n 1)
    note=${note:-no test summary, see $log}
    return "$rc"
}

step "setup packages" bash "$ROOT/data/setup.sh" || finish
# Not fatal to the run: without node_modules the tests that need it fail,
# naming the package; the rest still build and run.
npm_ci() { (cd "$ROOT" && npm ci --no-audit --no-fund); }
step "npm ci" npm_ci
step "fetch meshes" sh "$ROOT/data/fetch-meshes.sh" || finish

if step "build build/" build build -DCMAKE_BUILD_TYPE=RelWithDebInfo -DHLOD_SANITIZE= -DHLOD_BENCH=ON; then
    step "ctest build/" run_ctest build
fi
if step "build build-asan/" build build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo \
        "-DHLOD_SANITIZE=address,undefined" -DHLOD_BENCH=OFF -DHLOD_SELFCHECK=ON; then
    step "ctest build-asan/" run_ctest build-asan
fi
# ThreadSanitizer over the code that runs threads: hlod-build's workers,
# hlod-export-3dtiles' workers (test_tiles),
# the store writer/readers, the engine's loader thread and two engines in
# two threads, the loader under injected faults and the soak, the
# Grid-Lumigraph client's fetch thread (test_lumigraph).  OpenImageIO
# is not instrumented; its internal synchronisation is suppressed
# (tests/tsan.supp), ours is checked.
TSAN_TESTS="test_build|test_city_levels|test_store\$|test_metis|test_engine\$|test_loader|test_faults|test_soak|test_bad_roots|test_tiles|test_lumigraph"
build_tsan() {
    cmake -S "$ROOT" -B "$ROOT/build-tsan" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DHLOD_SANITIZE=thread \
        -DHLOD_BENCH=OFF >/dev/null &&
        make -C "$ROOT/build-tsan" -j"$JOBS" hlod-build hlod-gen-city hlod-info test_build test_city_levels test_store test_metis \
            test_engine test_loader test_faults test_soak test_bad_roots test_tiles \
            hlod-lumigraph-bake test_lumigraph
}
run_tsan() {
    local log="$ROOT/out/test-logs/ctest-build-tsan.log"
    (cd "$ROOT/build-tsan" &&
        TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$ROOT/tests/tsan.supp" \
            ctest --output-on-failure -j"$JOBS" -R "$TSAN_TESTS") 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    note=$(grep -E 'tests passed|tests failed' "$log" | tail -n 1)
    note=${note:-no test summary, see $log}
    return "$rc"
}
if step "build build-tsan/" build_tsan; then
    step "ctest build-tsan/" run_tsan
fi
# libFuzzer (clang, ASan + UBSan) over the parsers of untrusted bytes: the
# store reader, the camera path parser and the OBJ/PLY/OFF import; each
# harness replays its corpus, then fuzzes for FUZZ_SECONDS (default 20).
run_fuzz() {
    local log="$ROOT/out/test-logs/fuzz.log"
    FUZZ_JOBS=$JOBS bash "$ROOT/tests/fuzz/run.sh" 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    note=$(grep -E '^fuzz: .* execs' "$log" | tail -n 1)
    note=${note:-no fuzz summary, see $log}
    return "$rc"
}
step "fuzz build-fuzz/" run_fuzz
finish
