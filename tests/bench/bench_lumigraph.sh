#!/usr/bin/env bash
# bench_lumigraph.sh - Okamoto's Grid-Lumigraph client (policy lumigraph,
# docs/lumigraph.md) beside okamoto drawing the mesh, on cities of growing
# size: the shape of Okamoto et al.'s Fig. 9 (client frame time, its
# coefficient of variation and PSNR against the supersampled reference per
# model, with the bake's time and size), and the slope of a log fit of the
# client's frame time against the model's triangles.
# A benchmark, not a test: it prints a table and writes CSV and JSON.
#
#   bash tests/bench/bench_lumigraph.sh OUTDIR
#
# Env: BLOCKS ("8 24 72": cities of hlod-gen-city's blocks, TPB triangles
# each, 35000 by default, textures TEX^2, 256), GRID (8; the paper's 16
# and 32 take hours here: about 10 ms a view on the 50k-triangle city, so
# G = 16 is 24576 views), SIZE (512: the views and the frames), PATHS
# ("orbit fly"), FRAMES (300), REF_EVERY (10: PSNR every 10th frame),
# MESH_PX (lumi_mesh_px, 8), BIN (build/bin).  Models are built once with
# --method metis and baked once into OUTDIR/B/ (kept between runs).
#
# The grid's box (--box): twice the city across, from the ground to 10 m
# over its paths' highest eye (OUTDIR/B/box.txt).
#
# Columns: model (blocks), tris (the store's leaves), path, policy,
# frame_ms_mean, frame_ms_cv (standard deviation / mean over the frames
# after the first 30), psnr_mean, bytes_per_frame (view bytes fetched,
# mean), answer_bytes_max, lumi_missing_frames, tris_mean, machine_p50_ms
# and machine_p99_ms (the frozen replay: this machine's jitter in the same
# run), bake_seconds, bake_bytes, views.  Then per path the log-log slope
# of lumigraph's and okamoto's mean frame time against tris.
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
out=$(realpath -m "${1:?usage: bench_lumigraph.sh OUTDIR}")
BLOCKS=${BLOCKS:-8 24 72}
TPB=${TPB:-35000}
TEX=${TEX:-256}
GRID=${GRID:-8}
SIZE=${SIZE:-512}
PATHS=${PATHS:-orbit fly}
FRAMES=${FRAMES:-300}
REF_EVERY=${REF_EVERY:-10}
MESH_PX=${MESH_PX:-8}
mkdir -p "$out" || exit 1
csv="$out/lumigraph.csv"
echo "model,tris,path,policy,frame_ms_mean,frame_ms_cv,psnr_mean,bytes_per_frame,answer_bytes_max,lumi_missing_frames,tris_mean,machine_p50_ms,machine_p99_ms,bake_seconds,bake_bytes,views" >"$csv"
. "$ROOT/tests/bench/summary_key.sh"
# col_stats CSV COLUMN SKIP: "mean cv" of COLUMN over the rows after SKIP
col_stats() {
    awk -F, -v col="$2" -v skip="$3" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == col) c = i; next }
        NR - 2 >= skip { n++; s += $c; q += $c * $c }
        END { if (!n) { print "nan nan"; exit } m = s / n; v = q / n - m * m; if (v < 0) v = 0;
              printf "%.4f %.4f\n", m, (m > 0 ? sqrt(v) / m : 0) }' "$1"
}
for b in $BLOCKS; do
    dir="$out/$b"
    mkdir -p "$dir" || exit 1
    if [ ! -s "$dir/city.hlod" ]; then
        "$BIN/hlod-gen-city" --blocks "$b" --tris-per-block "$TPB" --texture-size "$TEX" \
            -o "$dir/city.obj" --paths "$dir/paths" --quiet &&
            "$BIN/hlod-build" "$dir/city.obj" -o "$dir/city.hlod" --method metis --quiet ||
            { echo "bench_lumigraph: cannot build the $b-block city" >&2; exit 1; }
        rm -rf "$dir/city.obj" "$dir/city.mtl" "$dir/city_tex"
    fi
    if [ ! -s "$dir/bake.json" ]; then
        # the grid's box: twice the city across, from the ground to 10 m
        # over the highest eye of its paths (the paper's box, twice the
        # model, stops at twice a city's height, far under its paths)
        box=$("$BIN/hlod-info" "$dir/city.hlod" --json | perl -MJSON::PP -e 'local $/;
            my $j = JSON::PP->new->decode(<STDIN>); my ($lo, $hi) = ($j->{bbox_min}, $j->{bbox_max});
            my $top = $ARGV[0]; my @c = map { ($lo->[$_] + $hi->[$_]) / 2 } 0 .. 1;
            my @h = map { $hi->[$_] - $lo->[$_] } 0 .. 1;
            printf "%.3f,%.3f,%.3f,%.3f,%.3f,%.3f", $c[0] - $h[0], $c[1] - $h[1], $lo->[2] - 1,
                $c[0] + $h[0], $c[1] + $h[1], $top + 10' \
            "$(awk '!/^#/ && NF >= 7 && $4 > m { m = $4 } END { print m + 0 }' "$dir"/paths/*.path)")
        echo "$box" >"$dir/box.txt"
        "$BIN/hlod-lumigraph-bake" "$dir/city.hlod" -o "$dir/repo" --grid "$GRID" --size "$SIZE" \
            --box "$box" --json --quiet >"$dir/bake.json" ||
            { echo "bench_lumigraph: cannot bake the $b-block city" >&2; exit 1; }
    fi
    tris=$("$BIN/hlod-info" "$dir/city.hlod" --json | perl -MJSON::PP -e 'local $/;
        my $j = JSON::PP->new->decode(<STDIN>); print $j->{tris_leaf} // $j->{leaf_tris} // ""')
    for p in $PATHS; do
        run="$dir/run-$p"
        "$BIN/hlod-bench" "$dir/city.hlod" --path "$p" --paths-dir "$dir/paths" \
            --policy lumigraph,okamoto --repo "$dir/repo" --set lumi_mesh_px="$MESH_PX" \
            --width "$SIZE" --height "$SIZE" --frames "$FRAMES" --reference \
            --reference-every "$REF_EVERY" --out "$run" --no-plots 2>"$run.err" >/dev/null ||
            { echo "bench_lumigraph: hlod-bench failed on $b/$p (see $run.err)" >&2; exit 1; }
        for pol in lumigraph okamoto; do
            s="$run/$pol/summary.json"
            [ -s "$s" ] || s="$run/summary.json"
            read -r mean cv < <(col_stats "$run/$pol/frames.csv" measured_ms 30)
            read -r bpf _ < <(col_stats "$run/$pol/frames.csv" lumi_bytes 0)
            echo "$b,$tris,$p,$pol,$mean,$cv,$(key psnr_mean "$s"),$bpf,$(key answer_bytes_max "$s"),$(key lumi_missing_frames "$s"),$(key tris_mean "$s"),$(key machine_p50_ms "$s"),$(key machine_p99_ms "$s"),$(key seconds "$dir/bake.json"),$(key bytes "$dir/bake.json"),$(key views "$dir/bake.json")" >>"$csv"
        done
    done
done
column -s, -t "$csv"
# log-log slope of the mean frame time against tris, per path and policy
awk -F, 'NR > 1 { k = $3 " " $4; n[k]++; x = log($2); y = log($5); sx[k] += x; sy[k] += y;
        sxx[k] += x * x; sxy[k] += x * y }
    END { for (k in n) { d = n[k] * sxx[k] - sx[k] * sx[k];
            printf "slope %s: %.3f\n", k, (d > 0 ? (n[k] * sxy[k] - sx[k] * sy[k]) / d : 0) } }' \
    "$csv" | sort | tee "$out/slopes.txt"
