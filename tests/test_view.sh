#!/usr/bin/env bash
# test_view.sh - bin/hlod-view under Xvfb (ctest: cli_view).
#
# Builds a tiny store, renders a few frames into a virtual display and checks
# the screenshot is a PNG that is not blank (hlod-view prints the fraction of
# non-sky pixels as "coverage=X"; no image decoder is assumed here), that a
# recorded path reads back, and the exit codes of --help, bad flags, a missing
# store and a missing display.  Xvfb (xvfb-run) comes from data/setup.sh;
# Mesa's llvmpipe serves OpenGL 3.3 core there.
#
# Environment: HLOD_BIN_DIR (default build/bin), HLOD_SOURCE_DIR (default .).
set -uo pipefail

SRC=${HLOD_SOURCE_DIR:-.}
BIN=${HLOD_BIN_DIR:-$SRC/build/bin}
VIEW=$BIN/hlod-view

T=$(mktemp -d "${TMPDIR:-/tmp}/hlod-test-view.XXXXXX")
trap 'rm -rf "$T"' EXIT

failed=0
passed=0
pass() { passed=$((passed + 1)); echo "ok   $1"; }
fail() { failed=$((failed + 1)); echo "FAIL $1"; }

# run NAME ARGS...: stdout -> $T/NAME.out, stderr -> $T/NAME.err, status -> $rc
run() {
    local name=$1
    shift
    timeout 300 "$@" >"$T/$name.out" 2>"$T/$name.err" </dev/null
    rc=$?
}
# xrun NAME ARGS...: hlod-view ARGS on a fresh virtual display.  Leak
# checking is off for these runs in sanitizer builds: Mesa's GLX driver
# (swrast_dri.so) leaks about 100 bytes and is unloaded when the display
# closes, so LeakSanitizer cannot suppress it by library name as
# tests/lsan.supp does for OSMesa.  ASan and UBSan errors still fail, and the
# runs without a window below keep leak checking.
xrun() {
    local name=$1
    shift
    run "$name" env ASAN_OPTIONS="${ASAN_OPTIONS:-}${ASAN_OPTIONS:+:}detect_leaks=0" \
        xvfb-run -a -s "-screen 0 800x600x24" "$VIEW" "$@"
}

for tool in hlod-view hlod-gen-city hlod-build; do
    if [ ! -x "$BIN/$tool" ]; then
        echo "FAIL $BIN/$tool not built"
        exit 1
    fi
done
if ! command -v xvfb-run >/dev/null 2>&1; then
    echo "FAIL xvfb-run not installed (bash data/setup.sh installs xvfb and xauth)"
    exit 1
fi

# --help
run help "$VIEW" --help
if [ $rc -eq 0 ] && grep -q 'usage: hlod-view' "$T/help.out"; then pass "--help exits 0 and prints usage"
else fail "--help (rc=$rc)"; fi

# bad flags
run badflag "$VIEW" "$T/city.hlod" --no-such-flag
if [ $rc -eq 2 ] && grep -q -- '--no-such-flag' "$T/badflag.err"; then pass "an unknown flag exits 2 and names it"
else fail "unknown flag (rc=$rc): $(cat "$T/badflag.err")"; fi
run badpolicy "$VIEW" "$T/city.hlod" --policy full
if [ $rc -eq 2 ] && grep -q "full" "$T/badpolicy.err"; then pass "--policy full exits 2"
else fail "--policy full (rc=$rc): $(cat "$T/badpolicy.err")"; fi

# a missing store names the file (before any display is needed)
run missing "$VIEW" "$T/no-such-store.hlod"
if [ $rc -eq 1 ] && grep -q 'no-such-store.hlod' "$T/missing.err"; then pass "a missing store exits 1 and names the file"
else fail "missing store (rc=$rc): $(cat "$T/missing.err")"; fi

# a tiny store
if ! "$BIN/hlod-gen-city" --preset tiny -o "$T/city.obj" --quiet ||
   ! "$BIN/hlod-build" "$T/city.obj" -o "$T/city.hlod" --desired-tris 300 --quiet; then
    echo "FAIL could not build the tiny store"
    exit 1
fi

# no display
run nodisplay env -u DISPLAY -u WAYLAND_DISPLAY "$VIEW" "$T/city.hlod" --frames 1
if [ $rc -eq 1 ] && grep -qi 'display' "$T/nodisplay.err"; then pass "no display exits 1 and says so"
else fail "no display (rc=$rc): $(cat "$T/nodisplay.err")"; fi

# a screenshot after 30 frames: a PNG that is not all sky
xrun shot "$T/city.hlod" --width 320 --height 240 --frames 30 --screenshot "$T/shot.png"
coverage=$(sed -n 's/^coverage=//p' "$T/shot.out")
magic=$(head -c 8 "$T/shot.png" 2>/dev/null | od -An -tx1 | tr -d ' \n')
if [ $rc -eq 0 ]; then pass "30 frames under Xvfb exit 0"
else fail "screenshot run (rc=$rc): $(cat "$T/shot.err")"; fi
if [ "$magic" = "89504e470d0a1a0a" ]; then pass "the screenshot is a PNG"
else fail "screenshot is not a PNG (magic '$magic')"; fi
if [ -n "$coverage" ] && awk -v c="$coverage" 'BEGIN { exit !(c > 0.1) }'; then
    pass "the screenshot is not blank (coverage=$coverage)"
else fail "screenshot blank or no coverage line (coverage='$coverage')"; fi

# --record writes a path that hlod-view plays back
xrun rec "$T/city.hlod" --width 160 --height 120 --frames 30 --record "$T/rec.path"
keys=$(grep -cE '^[-0-9.e+]+( [-0-9.e+]+){6}$' "$T/rec.path" 2>/dev/null)
if [ $rc -eq 0 ] && [ "${keys:-0}" -ge 2 ]; then pass "--record writes $keys keyframes"
else fail "--record (rc=$rc, keyframes=${keys:-0}): $(cat "$T/rec.err")"; fi
xrun play "$T/city.hlod" --width 160 --height 120 --frames 5 --path "$T/rec.path"
if [ $rc -eq 0 ]; then pass "the recorded path plays back"
else fail "playing the recording (rc=$rc): $(cat "$T/play.err")"; fi

# an unwritable screenshot folder fails before the window opens
xrun nodir "$T/city.hlod" --frames 1 --screenshot "$T/no/such/folder/shot.png"
if [ $rc -eq 1 ] && grep -q 'shot.png' "$T/nodir.err" && [ ! -e "$T/no" ]
then pass "a screenshot into a missing folder exits 1 and names the file"
else fail "screenshot into a missing folder (rc=$rc): $(cat "$T/nodir.err")"; fi

echo "$passed passed, $failed failed"
[ $failed -eq 0 ]
