#!/usr/bin/env bash
# test_cli.sh - command-line behaviour of bin/hlod-simplify and
# bin/hlod-export-3dtiles (ctest: cli_simplify).
#
# Checks exit codes (exactly 1 for a file that cannot be read or written, 2
# for a bad command line: a crash, 134 or 139, is neither), error messages naming the file or flag, the --json
# record, and that a failing run never leaves a file at the output path nor
# touches an existing one.  JSON is checked with perl's core JSON::PP (perl is
# on every Debian system that has build-essential; python3 may not be).
#
# Environment: HLOD_BIN_DIR (default build/bin), HLOD_SOURCE_DIR (default .).
set -uo pipefail

SRC=${HLOD_SOURCE_DIR:-.}
BIN=${HLOD_BIN_DIR:-$SRC/build/bin}
TOOL=$BIN/hlod-simplify
MESH=$SRC/data/meshes/fandisk.off

T=$(mktemp -d "${TMPDIR:-/tmp}/hlod-test-cli.XXXXXX")
trap 'rm -rf "$T"' EXIT

failed=0
passed=0
pass() { passed=$((passed + 1)); echo "ok   $1"; }
fail() { failed=$((failed + 1)); echo "FAIL $1"; }

# run NAME ARGS...: runs the tool, stdout -> $T/NAME.out, stderr -> $T/NAME.err, status -> $rc
run() {
    local name=$1
    shift
    "$TOOL" "$@" >"$T/$name.out" 2>"$T/$name.err" </dev/null
    rc=$?
}

# json_get FILE KEY: prints the value (or exits non-zero when FILE is not one
# JSON object or KEY is missing).
json_get() {
    perl -MJSON::PP -e '
        local $/; open my $f, "<", $ARGV[0] or die "$ARGV[0]: $!\n";
        my $j = JSON::PP->new->decode(<$f>);
        ref $j eq "HASH" or die "not a JSON object\n";
        exists $j->{$ARGV[1]} or die "missing key $ARGV[1]\n";
        my $v = $j->{$ARGV[1]};
        print defined $v ? $v : "null";' "$1" "$2"
}

no_stray_files() { # DIR: no temporary .tmp- files left behind
    ! ls "$1" | grep -q '\.tmp-'
}

if [ ! -x "$TOOL" ]; then
    echo "FAIL $TOOL not built"
    exit 1
fi

# --help
run help --help
if [ $rc -eq 0 ] && grep -q 'usage: hlod-simplify' "$T/help.out"; then pass "--help exits 0 and prints usage"
else fail "--help (rc=$rc)"; fi

# missing input names the file
run missing "$T/no-such-mesh.off" -o "$T/missing-out.off" --ratio 0.5
if [ $rc -eq 1 ] && grep -q 'no-such-mesh.off' "$T/missing.err" && [ ! -e "$T/missing-out.off" ]
then pass "missing input fails and names the file"
else fail "missing input (rc=$rc): $(cat "$T/missing.err")"; fi

# bad flag values: exit 2 (bad command line, as the README says) and the
# flag named
check_bad() { # NAME WANT_IN_STDERR ARGS...
    local name=$1 want=$2
    shift 2
    run "$name" "$@"
    if [ $rc -eq 2 ] && grep -q -e "$want" "$T/$name.err" && [ ! -s "$T/$name.out" ]
    then pass "rejects: $*"
    else fail "should reject: $* (rc=$rc): $(cat "$T/$name.err")"; fi
}
check_bad ratio0 --ratio "$MESH" -o "$T/bad.off" --ratio 0
check_bad ratio2 --ratio "$MESH" -o "$T/bad.off" --ratio 2
check_bad ratioabc --ratio "$MESH" -o "$T/bad.off" --ratio abc
check_bad ratio12abc --ratio "$MESH" -o "$T/bad.off" --ratio 12abc
check_bad tris_neg --target-tris "$MESH" -o "$T/bad.off" --target-tris -5
check_bad err0 --target-error "$MESH" -o "$T/bad.off" --target-error 0
check_bad exclusive --ratio "$MESH" -o "$T/bad.off" --ratio 0.5 --target-tris 10
check_bad no_out "output" "$MESH" --ratio 0.5
check_bad no_target "target" "$MESH" -o "$T/bad.off"
check_bad unknown "--frobnicate" "$MESH" -o "$T/bad.off" --ratio 0.5 --frobnicate
if [ ! -e "$T/bad.off" ]; then pass "rejected runs wrote nothing"; else fail "rejected run wrote $T/bad.off"; fi

# corrupt input: fails, names the file, leaves no output
printf 'OFF\n3 1 0\n0 0 0\n1 0\n' >"$T/corrupt.off"
run corrupt "$T/corrupt.off" -o "$T/corrupt-out.off" --ratio 0.5
if [ $rc -eq 1 ] && grep -q 'corrupt.off' "$T/corrupt.err" && [ ! -e "$T/corrupt-out.off" ]
then pass "corrupt input fails, names the file, no output"
else fail "corrupt input (rc=$rc): $(cat "$T/corrupt.err")"; fi

# an existing output is not damaged by a failing run
echo "precious" >"$T/keep.off"
run keep "$T/corrupt.off" -o "$T/keep.off" --ratio 0.5
if [ $rc -eq 1 ] && [ "$(cat "$T/keep.off")" = "precious" ]
then pass "failing run leaves an existing output untouched"
else fail "existing output damaged or run succeeded (rc=$rc)"; fi

if [ ! -f "$MESH" ]; then
    fail "$MESH missing: run data/fetch-meshes.sh first"
    echo "$passed passed, $failed failed"
    exit 1
fi

# the real run: fandisk to 10 %
run real "$MESH" -o "$T/fandisk-10.off" --ratio 0.1 --json
if [ $rc -eq 0 ]; then pass "fandisk --ratio 0.1 --json exits 0"
else
    fail "fandisk --ratio 0.1 (rc=$rc): $(cat "$T/real.err")"
    echo "$passed passed, $failed failed (skipped the checks that need this run)"
    exit 1
fi
keys_ok=1
for k in tris_in tris_out seconds error error_estimate bbox_diag vertices_in vertices_out \
         degenerate_dropped duplicate_dropped; do
    v=$(json_get "$T/real.out" "$k" 2>"$T/json.err") || { keys_ok=0; echo "  $k: $(cat "$T/json.err")"; continue; }
    # every key above is a finite number >= 0
    if ! [[ $v =~ ^[0-9]+(\.[0-9]+)?([eE][-+]?[0-9]+)?$ ]]; then keys_ok=0; echo "  $k = '$v' is not a number >= 0"; fi
done
if [ $keys_ok -eq 1 ]; then pass "JSON has every key as a number"; else fail "JSON keys: $(cat "$T/real.out")"; fi

tin=$(json_get "$T/real.out" tris_in 2>/dev/null || echo 0)
tout=$(json_get "$T/real.out" tris_out 2>/dev/null || echo 999999999)
if [ "$tin" -gt 0 ] && [ "$tout" -gt 0 ] && [ "$tout" -le $((tin / 10 + 2)) ]
then pass "tris_out $tout <= 10% of tris_in $tin"
else fail "tris_out $tout vs tris_in $tin"; fi

if [ -s "$T/fandisk-10.off" ]; then
    run reread "$T/fandisk-10.off" -o "$T/reread.off" --ratio 1 --json
    back=$(json_get "$T/reread.out" tris_read 2>/dev/null || echo -1)
    if [ $rc -eq 0 ] && [ "$back" = "$tout" ]
    then pass "output re-imports with the same $tout triangles"
    else fail "re-import of the output (rc=$rc, tris_read=$back, want $tout): $(cat "$T/reread.err")"; fi
else
    fail "output $T/fandisk-10.off missing or empty"
fi

# output into a folder that does not exist
run nodir "$MESH" -o "$T/no/such/folder/out.off" --ratio 0.1
if [ $rc -eq 1 ] && grep -q 'out.off' "$T/nodir.err" && [ ! -e "$T/no" ]
then pass "output into a missing folder fails and names the file"
else fail "output into a missing folder (rc=$rc): $(cat "$T/nodir.err")"; fi

# a failing write (unknown output format) after a good read: an existing
# file at the output path survives, and no temporary file is left
echo "precious" >"$T/keep.nosuchformat"
run badext "$MESH" -o "$T/keep.nosuchformat" --ratio 0.1
if [ $rc -eq 1 ] && [ "$(cat "$T/keep.nosuchformat")" = "precious" ] && grep -q 'keep.nosuchformat' "$T/badext.err"
then pass "failing export leaves an existing output untouched"
else fail "failing export (rc=$rc): $(cat "$T/badext.err")"; fi

if no_stray_files "$T"; then pass "no temporary files left behind"
else fail "temporary files left: $(ls "$T" | grep '\.tmp-')"; fi

# ---- hlod-export-3dtiles: its exit codes (docs/hlod-export-3dtiles.md) ----
X=$BIN/hlod-export-3dtiles
xrun() { # NAME ARGS...: like run, for the exporter
    local name=$1
    shift
    "$X" "$@" >"$T/$name.out" 2>"$T/$name.err" </dev/null
    rc=$?
}
"$BIN/hlod-gen-city" --preset tiny -o "$T/tiny.obj" --quiet &&
    "$BIN/hlod-build" "$T/tiny.obj" -o "$T/tiny.hlod" --desired-tris 300 --quiet
[ -f "$T/tiny.hlod" ] && pass "a tiny store to export" || fail "a tiny store to export"
xrun x-ok "$T/tiny.hlod" -o "$T/tiles" --json
if [ $rc -eq 0 ] && [ -f "$T/tiles/tileset.json" ] && [ "$(json_get "$T/x-ok.out" tiles)" -gt 1 ]
then pass "export: exit 0, tileset.json and a JSON record"
else fail "export (rc=$rc): $(cat "$T/x-ok.err")"; fi
xrun x-exists "$T/tiny.hlod" -o "$T/tiles"
if [ $rc -eq 1 ] && grep -q 'tiles: exists (--force replaces it)' "$T/x-exists.err" &&
    [ -f "$T/tiles/tileset.json" ]
then pass "export over an existing folder without --force: exit 1, the folder kept"
else fail "export over an existing folder (rc=$rc): $(cat "$T/x-exists.err")"; fi
xrun x-missing "$T/no-such.hlod" -o "$T/tiles2"
if [ $rc -eq 1 ] && grep -q 'no-such.hlod' "$T/x-missing.err" && [ ! -e "$T/tiles2" ]
then pass "export of a missing store: exit 1, names it, writes nothing"
else fail "export of a missing store (rc=$rc): $(cat "$T/x-missing.err")"; fi
: >"$T/x-file"
xrun x-notdir "$T/tiny.hlod" -o "$T/x-file" --force
if [ $rc -eq 1 ] && grep -q 'exists and is not a folder' "$T/x-notdir.err" && [ ! -s "$T/x-file" ]
then pass "export onto a file, even with --force: exit 1, the file kept"
else fail "export onto a file (rc=$rc): $(cat "$T/x-notdir.err")"; fi
for bad in "--meshopt sometimes" "--jpeg-quality 101" "--jpeg-quality 0" "--threads 65" \
    "--no-such-flag" "-o"; do
    # shellcheck disable=SC2086 # the words are the flags
    xrun x-bad "$T/tiny.hlod" -o "$T/tiles3" $bad
    flag=${bad%% *}
    if [ $rc -eq 2 ] && grep -q -- "$flag" "$T/x-bad.err" && [ ! -e "$T/tiles3" ]
    then pass "export $bad: exit 2, names $flag"
    else fail "export $bad (rc=$rc): $(cat "$T/x-bad.err")"; fi
done
xrun x-noout "$T/tiny.hlod"
if [ $rc -eq 2 ] && grep -q -- '-o' "$T/x-noout.err"
then pass "export without -o: exit 2"
else fail "export without -o (rc=$rc): $(cat "$T/x-noout.err")"; fi
xrun x-two "$T/tiny.hlod" "$T/tiny.hlod" -o "$T/tiles4"
if [ $rc -eq 2 ] && [ ! -e "$T/tiles4" ]
then pass "export of two stores: exit 2"
else fail "export of two stores (rc=$rc): $(cat "$T/x-two.err")"; fi

echo "$passed passed, $failed failed"
[ $failed -eq 0 ]
