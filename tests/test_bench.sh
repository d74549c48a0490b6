#!/usr/bin/env bash
# test_bench.sh - hlod-bench's command line and outputs on a tiny store.
#
# Builds a tiny city store, then checks: --help; bad flags exit 2 naming the
# flag; a missing store or path exits 1 naming the file and leaves no
# output; a run writes frames.csv (one row per frame), summary.json with
# every key scripts rely on, and the plots; --deterministic gives identical
# selection columns twice; a policy x target sweep writes sweep.csv (one
# row per run) and pareto.png; --reference fills psnr/ssim; the keys of
# issue 17 (deadline_met, the machine's jitter from the frozen-selection
# replay, estimate error, occlusion, toggles after frame 60) exist and are
# sane, and the replay changes no selection; frames.csv's new columns come
# last; --save-frames writes the frames (and the reference's) as PNG; the
# 2x2 supersampled reference differs from the plain one; --occlusion-check
# fills its columns and keys and changes no selection; all six policies
# sweep, and two without a reference write no pareto.png; --cone-check on
# a closed model's orbit (bunny00.off) and on the city finds no pixel the
# culled nodes would change; and the EGL
# backend draws the frame OSMesa draws (PSNR >= 40 dB; both images are kept
# in a folder the failure names).
set -u
BIN=${HLOD_BIN_DIR:-build/bin}
SRC=${HLOD_SOURCE_DIR:-.}
T=$(mktemp -d /tmp/hlod-test-bench-XXXXXX)
trap 'rm -rf "$T"' EXIT
. "$(dirname "$0")/lib.sh" # pass, fail, ok()

# the non-empty values of column K (by name) of DIR/frames.csv
col() { awk -F, -v k="$2" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == k) c = i; next }
    c && $c != "" && $c != "nan" { print $c }' "$1/frames.csv"; }

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
# without --memory-mb a store that fits is given its whole size, and is
# loaded once (each node at most once, nothing evicted)
mem=$("$BIN/hlod-info" "$T/city.hlod" --json | sed -n 's/.*"memory_bytes":\([0-9]*\).*/\1/p')
nodes=$("$BIN/hlod-info" "$T/city.hlod" --json | sed -n 's/.*"nodes":\([0-9]*\).*/\1/p')
perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    exit !($j->{memory_budget_bytes} == $ARGV[0] && $j->{evictions} == 0 && $j->{loads} > 0 &&
           $j->{loads} <= $ARGV[1])' "$mem" "$nodes" <"$T/run/summary.json"
ok $? "default budget: the whole store ($mem bytes), loaded once ($nodes nodes at most, no eviction)"
missing=""
for k in deadline_met margin_cap_frames margin_cap_run_max machine_p50_ms machine_p99_ms machine_p99_over_p50 estimate_err_p50 \
    estimate_err_p95 occlusion_culled_mean toggles_after_60; do
    grep -q "\"$k\":" "$T/run/summary.json" || missing="$missing $k"
done
[ -z "$missing" ]
ok $? "summary.json keys of issue 17${missing:+ (missing:$missing)}"
perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    my $bad = "";
    my $num = sub { defined $_[0] && !ref $_[0] && $_[0] =~ /^-?[\d.]+(e[-+]?\d+)?$/i };
    $bad .= " deadline_met" unless $num->($j->{deadline_met}) && $j->{deadline_met} >= 0 &&
        $j->{deadline_met} <= 1;
    $bad .= " margin_cap" unless $num->($j->{margin_cap_frames}) &&
        $num->($j->{margin_cap_run_max}) && $j->{margin_cap_run_max} <= $j->{margin_cap_frames} &&
        $j->{margin_cap_frames} <= $j->{frames};
    $bad .= " machine_p50_ms" unless $num->($j->{machine_p50_ms}) && $j->{machine_p50_ms} > 0;
    $bad .= " machine_p99_ms" unless $num->($j->{machine_p99_ms}) &&
        $j->{machine_p99_ms} >= $j->{machine_p50_ms};
    $bad .= " machine_p99_over_p50" unless $num->($j->{machine_p99_over_p50}) &&
        abs($j->{machine_p99_over_p50} - $j->{machine_p99_ms} / $j->{machine_p50_ms}) < 1e-9;
    $bad .= " estimate_err" unless $num->($j->{estimate_err_p50}) && $j->{estimate_err_p50} >= 0 &&
        $num->($j->{estimate_err_p95}) && $j->{estimate_err_p95} >= $j->{estimate_err_p50};
    $bad .= " occlusion_culled_mean" unless $num->($j->{occlusion_culled_mean}) &&
        $j->{occlusion_culled_mean} >= 0;
    $bad .= " toggles_after_60" unless defined $j->{toggles_after_60} &&
        $j->{toggles_after_60} =~ /^\d+$/;
    $bad .= " machine_frame" unless $j->{machine_frame} == 20 && $j->{machine_replays} == 120;
    print STDERR "bad:$bad\n" if $bad; exit($bad ne "")' <"$T/run/summary.json"
ok $? "issue 17 keys sane (deadline_met in [0,1], machine p99 >= p50 > 0, errors >= 0, ...)"
# deadline_met and toggles_after_60 recomputed from frames.csv
awk -F, -v t=33 'NR == 1 { for (i = 1; i <= NF; i++) at[$i] = i; next }
    { n++; met += $at["measured_ms"] <= t; if ($1 >= 60) late += $at["toggles_up"] + $at["toggles_down"] }
    END { printf "%.6f %d\n", met / n, late }' "$T/run/frames.csv" >"$T/csv_keys"
perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    my ($met, $late) = split " ", $ARGV[0];
    exit !(abs($j->{deadline_met} - $met) < 1e-5 && $j->{toggles_after_60} == $late)' \
    "$(cat "$T/csv_keys")" <"$T/run/summary.json"
ok $? "deadline_met and toggles_after_60 agree with frames.csv"
[ "$(($(wc -l <"$T/run/jitter.csv") - 1))" -eq 120 ] && head -1 "$T/run/jitter.csv" | grep -qx "i,ms"
ok $? "jitter.csv: one row per replay (120)"
head -1 "$T/run/frames.csv" |
    grep -q ",toggles_up_ma35,toggles_down_ma35,pixels_drawn,margin,occlusion_hidden,occlusion_tested,occlusion_culled,occlusion_ms,occlusion_check_psnr,occlusion_check_differing,cone_culled,cone_check_differing,splats,splat_px,res_scale,cone_culled_tris,lumi_bytes,lumi_missing,gl_draws$"
ok $? "frames.csv: the new columns come last, in order"
# dyn_res's keys agree with the frames (all at full size without it)
scaled=$(awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) at[$i] = i; next }
    { n += $at["res_scale"] < 1 } END { print n + 0 }' "$T/run/frames.csv")
perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    exit !($j->{res_scaled_frames} == $ARGV[0] && $ARGV[0] == 0 && $j->{res_scale_mean} == 1 &&
           $j->{res_scale_min} == 1)' "$scaled" <"$T/run/summary.json"
ok $? "res_scale_mean, res_scale_min, res_scaled_frames agree with frames.csv (no dyn_res: 1, 1, 0)"
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
# the replay (at frame 20 of 40) changes nothing: without it, the same selection
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/det0" --target-ms 33 "${COMMON[@]}" \
    --deterministic --set v_time=0.002 --set fixed_ms=5 --io-mbps 20 --no-plots \
    --jitter-frames 0 2>/dev/null && sel "$T/det0" >"$T/sel0" && cmp -s "$T/sel0" "$T/sel1" &&
    [ ! -e "$T/det0/jitter.csv" ] && grep -q '"machine_p50_ms": null' "$T/det0/summary.json"
ok $? "--jitter-frames 0: no replay, same selection as with it, machine_p50_ms null"
# --occlusion-check replays each frame without occlusion culling and
# compares: the columns are filled, the keys set, the selection unchanged
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/detocc" --target-ms 33 "${COMMON[@]}" \
    --deterministic --set v_time=0.002 --set fixed_ms=5 --io-mbps 20 --no-plots \
    --occlusion-check 2>/dev/null && sel "$T/detocc" >"$T/selocc" && cmp -s "$T/selocc" "$T/sel1" &&
    [ "$(col "$T/detocc" occlusion_check_differing | wc -l)" -eq 40 ] &&
    perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
        exit !(defined $j->{occlusion_check_psnr_min} && $j->{occlusion_check_psnr_min} > 0 &&
               defined $j->{occlusion_check_bad_frames} && $j->{occlusion_check_bad_frames} >= 0 &&
               $j->{overhead_ms_mean} >= 0 && $j->{overhead_ms_max} >= $j->{overhead_ms_mean})' \
        <"$T/detocc/summary.json" && grep -q '"occlusion_check_psnr_min": null' "$T/det1/summary.json"
ok $? "--occlusion-check: a PSNR and differing pixels per frame, summary keys, same selection"

POLICIES=lakhia,nohyst,sse,fs93,counter,okamoto
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/sweep" "${COMMON[@]}" --reference \
    --reference-every 10 --policy $POLICIES --sweep target_ms=10,30 2>/dev/null
[ $? -eq 0 ] && [ "$(($(wc -l <"$T/sweep/sweep.csv") - 1))" -eq 12 ] && [ -s "$T/sweep/pareto.png" ] &&
    [ -s "$T/sweep/nohyst-target_ms=30/summary.json" ] &&
    [ "$(cut -d, -f1 "$T/sweep/sweep.csv" | sed 1d | sort -u | wc -l)" -eq 6 ] &&
    grep -q "'lakhia nohyst sse fs93 counter okamoto'" "$T/sweep/sweep.gp"
ok $? "sweep: 6 policies x 2 targets in sweep.csv, pareto.png plots each"
head -1 "$T/sweep/sweep.csv" | grep -q ",run_dir,deadline_met,machine_p50_ms,machine_p99_ms,machine_p99_over_p50,estimate_err_p50,estimate_err_p95,occlusion_culled_mean,toggles_after_60,cone_culled_mean$"
ok $? "sweep.csv: the issue 17 keys, then cone_culled_mean, as trailing columns"
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/noref" "${COMMON[@]}" --policy fs93,counter 2>"$T/err"
[ $? -eq 0 ] && [ ! -e "$T/noref/pareto.png" ] && [ -s "$T/noref/sweep_frame_time.png" ]
ok $? "two policies without a reference: exit 0, no pareto.png (no PSNR), the frame-time plot ($(head -c 200 "$T/err"))"

# ---- normal cones (docs/runtime.md, "Normal cones") ----
# A closed model (bunny00.off) on an orbit: culled nodes drawn again over
# the frame change no pixel, and most culled nodes are checked so (kept
# loaded for it); okamoto culls by cones whatever the setting; without
# cone_cull, lakhia culls nothing.
BUNNY=$SRC/data/meshes/bunny00.off
if [ -r "$BUNNY" ]; then
    # leaves cut as orientation classes (--cone-split on): issue 39's
    # target, at least 20 % of the triangles culled on this orbit
    "$BIN/hlod-build" "$BUNNY" -o "$T/bunny.hlod" --desired-tris 450 --cone-split on --quiet &&
        perl -e 'for my $i (0 .. 20) { my $t = $i * 0.5; my $a = 6.283185307 * $t / 10;
            printf "%g %.6f %.6f 0.5 0 0 0\n", $t, 1.6 * cos($a), 1.6 * sin($a) }' >"$T/orbit.path"
    ok $? "bunny store and orbit path"
    # deterministic: lakhia's front, and so what cones cull, is the same on
    # a loaded machine (timed, it coarsened there and culled 0.09 a frame)
    CONE=(--path "$T/orbit.path" --target-ms 33 --width 320 --height 180 --frames 300 --memory-mb 64 --no-plots
        --jitter-frames 0 --cone-check --deterministic --set v_time=0.0001 --set fixed_ms=2 --io-mbps 200)
    "$BIN/hlod-bench" "$T/bunny.hlod" "${CONE[@]}" --out "$T/cone" --policy lakhia,okamoto \
        --set cone_cull=1 2>"$T/err" &&
        "$BIN/hlod-bench" "$T/bunny.hlod" "${CONE[@]}" --out "$T/nocone" 2>>"$T/err"
    rc=$?
    for r in cone/lakhia cone/okamoto nocone; do
        echo "REPORT cones $r: $(perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
            print join " ", map { "$_=" . ($j->{$_} // "null") } qw(cone_culled_mean cone_culled_tris_share cone_check_differing_max
            cone_check_nodes cone_check_unchecked tris_mean render_waits)' <"$T/$r/summary.json" 2>/dev/null)"
    done
    good=$((rc == 0))
    for r in cone/lakhia cone/okamoto; do
        perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
            exit !($j->{cone_culled_mean} > 1 && $j->{cone_culled_tris_share} >= 0.2 &&
                   $j->{cone_check_differing_max} == 0 &&
                   $j->{cone_check_nodes} >= 0.9 * ($j->{cone_check_nodes} + $j->{cone_check_unchecked}) &&
                   $j->{render_waits} == 0)' <"$T/$r/summary.json" 2>/dev/null || good=0
    done
    perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
        exit !($j->{cone_culled_mean} == 0 && $j->{cone_culled_tris_share} == 0 &&
               $j->{cone_check_differing_max} == 0)' \
        <"$T/nocone/summary.json" 2>/dev/null || good=0
    [ $good -eq 1 ]
    ok $? "--cone-check on the bunny's orbit (--cone-split on): lakhia (cone_cull=1) and okamoto cull >= 20% of the triangles, 0 differing pixels, >= 90% of culled nodes drawn in the check; cone_cull=0 culls none ($(head -c 200 "$T/err"))"
else
    skip "normal cones: $BUNNY missing (data/fetch-meshes.sh)"
fi

# ---- far cubes (docs/cubes.md, "Cubes as stand-ins") ----
# The bunny built with its nodes' cubes: hlod-info says so; far off, its
# small nodes are drawn as cubes and no frame draws nothing; a store
# without cubes, or a sample tree asked for them, is refused.
if [ -r "$BUNNY" ]; then
    "$BIN/hlod-build" "$BUNNY" -o "$T/bunnyfc.hlod" --desired-tris 450 --far-cubes on --quiet &&
        "$BIN/hlod-info" "$T/bunnyfc.hlod" --json | grep -q '"cubes":true' &&
        "$BIN/hlod-info" "$T/bunny.hlod" --json | grep -q '"cubes":false'
    ok $? "--far-cubes on: hlod-info says the nodes carry cubes, and not without"
    "$BIN/hlod-build" "$BUNNY" -o "$T/bunnyst.hlod" --method sampletree --far-cubes on 2>"$T/err"
    [ $? -eq 2 ] && grep -q -- '--far-cubes' "$T/err" && [ ! -e "$T/bunnyst.hlod" ]
    ok $? "--far-cubes on with --method sampletree: exit 2, the flag named, nothing written"
    perl -e 'for my $i (0 .. 10) { my $t = $i * 0.5; my $a = 6.283185307 * $t / 10;
        printf "%g %.6f %.6f 2 0 0 0\n", $t, 12 * cos($a), 12 * sin($a) }' >"$T/far.path"
    FAR=(--path "$T/far.path" --target-ms 33 --width 320 --height 180 --memory-mb 64 --no-plots
        --jitter-frames 0 --deterministic --set v_time=0.0001 --set fixed_ms=2 --reference)
    "$BIN/hlod-bench" "$T/bunnyfc.hlod" "${FAR[@]}" --out "$T/far1" --set far_cubes=1 \
        --set cube_px=8 2>"$T/err" &&
        "$BIN/hlod-bench" "$T/bunnyfc.hlod" "${FAR[@]}" --out "$T/far0" 2>>"$T/err"
    rc=$?
    for r in far0 far1; do
        echo "REPORT far cubes $r: $(perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
            print join " ", map { "$_=" . ($j->{$_} // "null") } qw(splats_mean tris_mean psnr_mean psnr_min)' \
            <"$T/$r/summary.json" 2>/dev/null)"
    done
    [ $rc -eq 0 ] && perl -MJSON::PP -e 'local $/; open my $a, "<", $ARGV[0]; open my $b, "<", $ARGV[1];
        my ($c, $m) = map { JSON::PP->new->decode(scalar <$_>) } $a, $b;
        exit !($c->{splats_mean} > 0 && $m->{splats_mean} == 0 && $c->{tris_mean} < $m->{tris_mean} &&
               $c->{psnr_min} > 10)' "$T/far1/summary.json" "$T/far0/summary.json"
    ok $? "far_cubes=1 on the bunny 12 units off: cubes drawn, fewer triangles than without, no empty frame ($(head -c 200 "$T/err"))"
    "$BIN/hlod-bench" "$T/bunny.hlod" "${FAR[@]}" --out "$T/farno" --set far_cubes=1 2>"$T/err"
    [ $? -eq 1 ] && grep -q 'far_cubes' "$T/err"
    ok $? "far_cubes=1 on a store without cubes: exit 1, named ($(head -c 200 "$T/err"))"
else
    skip "far cubes: $BUNNY missing (data/fetch-meshes.sh)"
fi
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/citycone" "${COMMON[@]}" --set cone_cull=1 \
    --cone-check --no-plots 2>/dev/null &&
    [ "$(col "$T/citycone" cone_check_differing | sort -u)" = 0 ] &&
    grep -q '"cone_check_differing_max": 0' "$T/citycone/summary.json"
ok $? "--cone-check on the city: 0 differing pixels in every frame ($(grep -o '"cone_culled_mean": [^,]*' "$T/citycone/summary.json" 2>/dev/null))"

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
[ $rc -eq 0 ] && [ "$(col "$T/refpair/nohyst" psnr | wc -l)" -ge 5 ] &&
    [ "$(col "$T/refpair/nohyst" psnr)" = "$(col "$T/refone" psnr)" ] &&
    [ "$(col "$T/refpair/nohyst" ssim)" = "$(col "$T/refone" ssim)" ]
ok $? "cached reference frames score a later run exactly as a run of its own"

# --save-frames: PNGs of the frames, with the reference's; frames past the
# end are not written and said; a list that is not frame numbers is a
# usage error
is_png() { head -c 8 "$1" 2>/dev/null | od -An -tx1 | grep -q "89 50 4e 47"; }
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/save" --target-ms 33 "${COMMON[@]}" \
    --no-plots --reference --reference-every 10 --save-frames 0,7,39,500 2>"$T/err"
rc=$?
missing=""
for f in 00000 00007 00039; do
    is_png "$T/save/frame_$f.png" || missing="$missing frame_$f.png"
    is_png "$T/save/frame_${f}_ref.png" || missing="$missing frame_${f}_ref.png"
done
[ $rc -eq 0 ] && [ -z "$missing" ] && [ ! -e "$T/save/frame_00500.png" ] && grep -q "500" "$T/err" &&
    [ "$(ls "$T/save" | grep -c '^frame_.*png$')" -eq 6 ]
ok $? "--save-frames writes frame and reference PNGs${missing:+ (missing:$missing)}, says 500 is past the end"
# frame 7 is not a scored reference frame (every 10): saving it adds no PSNR
[ "$(col "$T/save" psnr | wc -l)" -eq 4 ]
ok $? "--save-frames: a saved frame's reference does not add a PSNR sample"
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" --save-frames 1,x 2>"$T/err"
[ $? -eq 2 ] && grep -q -- "--save-frames" "$T/err"
ok $? "--save-frames 1,x exits 2 naming the flag"
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" --save-frames 1,,2 2>/dev/null
[ $? -eq 2 ]
ok $? "--save-frames 1,,2 exits 2"
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" --policy rzb --set rzb_copies=2 \
    --reference 2>"$T/err"
[ $? -eq 2 ] && grep -q -- "--reference" "$T/err" && grep -q "rzb_copies" "$T/err"
ok $? "--reference with rzb_copies exits 2 naming both"
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" --policy rzb --set rzb_copies=25 \
    --frames 2 2>"$T/err"
[ $? -eq 1 ] && grep -q "rzb_copies 25 is not in" "$T/err"
ok $? "rzb_copies=25 is refused by the engine, named"
for bad in "--reference-ss 3" "--backend vulkan" "--jitter-frames -1"; do
    # shellcheck disable=SC2086
    "$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/x" $bad 2>"$T/err"
    [ $? -eq 2 ] && grep -q -- "${bad%% *}" "$T/err"
    ok $? "$bad exits 2 naming the flag"
done

# --reference-ss: the supersampled reference is not the plain one, and
# scores close to it
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/ss1" --target-ms 33 "${COMMON[@]}" \
    --no-plots --reference --reference-every 10 --reference-ss 1 --save-frames 30 2>/dev/null &&
    "$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/ss2" --target-ms 33 "${COMMON[@]}" \
        --no-plots --reference --reference-every 10 --reference-ss 2 --save-frames 30 2>/dev/null &&
    "$BIN/hlod-bench" --compare "$T/ss1/frame_00030_ref.png" "$T/ss2/frame_00030_ref.png" >"$T/cmp"
rc=$?
[ $rc -eq 0 ] && perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    exit !($j->{differing_pixels} > 0 && $j->{psnr} > 20)' <"$T/cmp" &&
    grep -q '"reference_ss": 2' "$T/ss2/summary.json" && grep -q '"reference_ss": 1' "$T/ss1/summary.json"
ok $? "--reference-ss 2 draws a different (antialiased) reference than 1 ($(cat "$T/cmp" 2>/dev/null))"
"$BIN/hlod-bench" --compare "$T/ss1/frame_00030.png" "$T/ss1/frame_00030.png" | grep -q '"psnr": 99'
ok $? "--compare: an image against itself is 99 dB"
"$BIN/hlod-bench" --compare "$T/ss1/frame_00030.png" "$T/none.png" 2>"$T/err"
[ $? -eq 1 ] && grep -q "none.png" "$T/err"
ok $? "--compare: a missing image exits 1 naming it"

# --backend egl (Mesa's surfaceless platform: llvmpipe here) draws what
# OSMesa draws: the same frames, compared; both kept on failure
FRAMES=0,20,39
"$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/osm" --target-ms 33 "${COMMON[@]}" \
    --no-plots --deterministic --set v_time=0.002 --set fixed_ms=5 --io-mbps 20 \
    --save-frames "$FRAMES" 2>"$T/err_osm" &&
    "$BIN/hlod-bench" "$T/city.hlod" --path "$P" --out "$T/egl" --target-ms 33 "${COMMON[@]}" \
        --no-plots --deterministic --set v_time=0.002 --set fixed_ms=5 --io-mbps 20 \
        --save-frames "$FRAMES" --backend egl 2>"$T/err_egl"
rc=$?
[ $rc -eq 0 ] && grep -q '"backend": "egl"' "$T/egl/summary.json"
ok $? "--backend egl runs ($(grep -o '"gl_renderer": "[^"]*"' "$T/egl/summary.json" 2>/dev/null || cat "$T/err_egl"))"
worst=""
for f in 00000 00020 00039; do
    "$BIN/hlod-bench" --compare "$T/osm/frame_$f.png" "$T/egl/frame_$f.png" >"$T/cmp" 2>&1 &&
        perl -MJSON::PP -e 'local $/; exit !(JSON::PP->new->decode(<STDIN>)->{psnr} >= 40)' \
            <"$T/cmp" || worst="$worst frame_$f.png: $(cat "$T/cmp")"
done
if [ -n "$worst" ]; then
    KEEP=$(mktemp -d /tmp/hlod-test-bench-egl-XXXXXX)
    cp -r "$T/osm" "$KEEP/osmesa"
    cp -r "$T/egl" "$KEEP/egl"
    echo "EGL vs OSMesa:$worst; both runs kept in $KEEP"
fi
[ $rc -eq 0 ] && [ -z "$worst" ] && cmp -s <(sel "$T/osm") <(sel "$T/egl")
ok $? "--backend egl: the same frames as OSMesa within 40 dB PSNR, the same selection"

echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
