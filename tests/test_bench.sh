#!/usr/bin/env bash
# test_bench.sh - hlod-bench's command line and outputs on a tiny store.
#
# Builds a tiny city store, then checks: --help; bad flags exit 2 naming the
# flag; a missing store or path exits 1 naming the file and leaves no
# output; a run writes frames.csv (one row per frame), summary.json with
# every key scripts rely on, and the plots; --deterministic gives identical
# selection columns twice; a policy x target sweep writes sweep.csv (one
# row per run) and pareto.png; --reference fills psnr/ssim.
set -u
BIN=${HLOD_BIN_DIR:-build/bin}
SRC=${HLOD_SOURCE_DIR:-.}
T=$(mktemp -d /tmp/hlod-test-bench-XXXXXX)
trap 'rm -rf "$T"' EXIT
pass=0
fail=0
ok() {
    if [ "$1" -eq 0 ]; then
        pass=$((pass + 1))
        echo "ok   $2"
    else
        fail=$((fail + 1))
        echo "FAIL $2"
    fi
}

"$BIN/hlod-gen-city" --preset tiny -o "$T/city.obj" --quiet &&
    "$BIN/hlod-build" "$T/city.obj" -o "$T/city.hlod" --desired-tris 300 --quiet
ok $? "tiny store built"
P=$SRC/data/paths/small/walk-to-fly.path
COMMON=(--width 160 --height 96 --frames 40)

"$BIN/hlod-bench" --help | grep -q "summary.json keys"
ok $? "--help"

"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" --target-ms nope 2>"$T/err"
[ $? -eq 2 ] && grep -q -- "--target-ms" "$T/err"
ok $? "bad --target-ms exits 2 naming the flag"

"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" --set c_bogus=1 2>"$T/err"
[ $? -eq 2 ] && grep -q "c_bogus" "$T/err"
ok $? "unknown --set key exits 2"

"$BIN/hlod-bench" "$T/missing.hlod" --path "$P" --out "$T/m" 2>"$T/err"
[ $? -eq 1 ] && grep -q "missing.hlod" "$T/err" && [ ! -e "$T/m/summary.json" ]
ok $? "missing store exits 1 naming it, no output"

"$BIN/hlod-bench" "$T/city.hlod" --path "$T/none.path" --out "$T/m" 2>"$T/err"
[ $? -eq 1 ] && grep -q "none.path" "$T/err"
ok $? "missing path exits 1 naming it"

"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/run" --target-ms 33 "${COMMON[@]}" \
    --reference --reference-every 4 2>"$T/err"
ok $? "a run with a reference"
rows=$(($(wc -l <"$T/run/frames.csv") - 1))
[ "$rows" -eq 40 ]
ok $? "frames.csv has one row per frame ($rows)"
missing=""
for k in frames target_ms frame_ms_mean frame_ms_p50 frame_ms_p95 frame_ms_p99 frame_ms_max \
    within_10pct over_target_frac toggles_up toggles_down toggles_per_frame oscillations \
    psnr_mean psnr_min ssim_mean tris_mean loads evictions bytes_read peak_resident_bytes \
    memory_budget_bytes missing_wanted_frames render_waits traversal_ms_mean; do
    grep -q "\"$k\":" "$T/run/summary.json" || missing="$missing $k"
done
[ -z "$missing" ]
ok $? "summary.json keys${missing:+ (missing:$missing)}"
perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    exit !($j->{frames} == 40 && $j->{psnr_mean} > 10 && $j->{ssim_mean} > 0.3 &&
           $j->{peak_resident_bytes} <= $j->{memory_budget_bytes})' <"$T/run/summary.json"
ok $? "summary values: 40 frames, PSNR and SSIM filled, resident within budget"
for png in frame_time nodes_per_depth toggles memory psnr; do
    head -c 8 "$T/run/$png.png" 2>/dev/null | od -An -tx1 | grep -q "89 50 4e 47" || missing="$missing $png"
done
[ -z "$missing" ]
ok $? "plots written${missing:+ (missing:$missing)}"

for i in 1 2; do
    "$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/det$i" --target-ms 33 "${COMMON[@]}" \
        --deterministic --set v_time=0.002 --set fixed_ms=5 --io-mbps 20 --no-plots 2>/dev/null
done
# selection columns, picked by name from the header (a column moved or
# missing fails): frame, estimate, nodes per depth, tris, toggles, loads
sel() {
    awk -F, 'NR == 1 {
            n = split("frame estimated_ms nodes_drawn depth0 tris_drawn cost_drawn toggles_up " \
                      "toggles_down oscillations loads", want, " ")
            for (i = 1; i <= NF; i++) at[$i] = i
            for (i = 1; i <= NF; i++) if ($i ~ /^depth[0-9]+$/) d[++nd] = i
            for (k = 1; k <= n; k++) if (!(want[k] in at)) { print "no column " want[k]; exit 1 }
            next }
        { line = ""
          for (k = 1; k <= n; k++) if (want[k] != "depth0") line = line $at[want[k]] ","
          for (k = 1; k <= nd; k++) line = line $d[k] ","
          print line }' "$1/frames.csv"
}
[ -s "$T/det1/frames.csv" ] && sel "$T/det1" >"$T/sel1" && sel "$T/det2" >"$T/sel2" &&
    [ "$(wc -l <"$T/sel1")" -gt 1 ] && cmp -s "$T/sel1" "$T/sel2"
ok $? "--deterministic: identical selection columns in two runs"

"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/sweep" "${COMMON[@]}" --reference \
    --reference-every 10 --policy lakhia,nohyst,sse --sweep target_ms=10,30 2>/dev/null
[ $? -eq 0 ] && [ "$(($(wc -l <"$T/sweep/sweep.csv") - 1))" -eq 6 ] && [ -s "$T/sweep/pareto.png" ] &&
    [ -s "$T/sweep/nohyst-target_ms=30/summary.json" ]
ok $? "sweep: 3 policies x 2 targets in sweep.csv, pareto.png"

# Reference frames are rendered once per invocation and reused by later
# runs: a deterministic nohyst run after a lakhia run must score exactly as
# the same nohyst run alone.
DET=(--deterministic --set v_time=0.002 --set fixed_ms=5 --io-mbps 20 --no-plots --reference
    --reference-every 5)
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/refpair" --target-ms 33 "${COMMON[@]}" \
    "${DET[@]}" --policy lakhia,nohyst 2>/dev/null &&
    "$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/refone" --target-ms 33 "${COMMON[@]}" \
        "${DET[@]}" --policy nohyst 2>/dev/null
rc=$?
col() { awk -F, -v k="$2" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == k) c = i; next }
    c && $c != "" && $c != "nan" { print $c }' "$1/frames.csv"; }
[ $rc -eq 0 ] && [ "$(col "$T/refpair/nohyst" psnr | wc -l)" -ge 5 ] &&
    [ "$(col "$T/refpair/nohyst" psnr)" = "$(col "$T/refone" psnr)" ] &&
    [ "$(col "$T/refpair/nohyst" ssim)" = "$(col "$T/refone" ssim)" ]
ok $? "cached reference frames score a later run exactly as a run of its own"

echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
