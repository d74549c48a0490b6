#!/usr/bin/env bash
# demo.sh - THE main job (for now): simplify real meshes and print a table,
# then generate the default city and build its HLOD store.
#
#   bash data/demo.sh              (as root on Debian 12; safe to run again)
#   HLOD_DEMO_CITY=small bash data/demo.sh    (a 50k-triangle city, quick)
#
# Installs missing packages (data/setup.sh), fetches the real meshes
# (data/fetch-meshes.sh), builds build/, runs bin/hlod-simplify on each mesh
# at 10 % and 1 % of its triangles and prints
#   mesh | target | tris_in | tris_out | seconds | error | error % diag
# where error is the measured two-sided Hausdorff distance in model units.
# Results: out/demo/ (simplified meshes, one JSON per run, table.txt,
# simplify.csv).  Then runs build/bin/hlod-bench-simplify when it was built
# (ours vs meshoptimizer; writes out/bench-simplify/).  Finally generates
# the city (hlod-gen-city --preset default: 200 blocks, 7M triangles,
# textured; out/demo/city/, kept between runs), builds its store with
# hlod-build (cut-plane method) and prints hlod-info's tree statistics.
# The fly-through and its report come with the runtime.
# Exits non-zero if anything failed.
set -uo pipefail

cd "$(dirname "$0")/.." || exit 1
ROOT=$(pwd)
OUT=$ROOT/out/demo
TOOL=$ROOT/build/bin/hlod-simplify
MESHES="bunny00.off fandisk.off mech-holes-shark.off elephant.off spider.obj Wuson.ply 2CylinderEngine.glb"

bash "$ROOT/data/setup.sh" || exit 1
sh "$ROOT/data/fetch-meshes.sh" || exit 1
echo "==> building build/"
{ cmake -S "$ROOT" -B "$ROOT/build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DHLOD_SANITIZE= -DHLOD_BENCH=ON >/dev/null &&
    make -C "$ROOT/build" -j2 --no-print-directory >/dev/null; } || {
    echo "demo: error: the build failed; run 'make -C build' to see why" >&2
    exit 1
}

mkdir -p "$OUT"
rm -f "$OUT"/*.json
failed=0
jsons=()
for mesh in $MESHES; do
    in=$ROOT/data/meshes/$mesh
    stem=${mesh%.*}
    for pct in 10 1; do
        ratio=$(awk -v p="$pct" 'BEGIN { printf "%g", p / 100 }')
        base=$OUT/$stem-$pct
        echo "==> $mesh to $pct %"
        if "$TOOL" "$in" -o "$base.obj" --ratio "$ratio" --json >"$base.json.tmp"; then
            mv "$base.json.tmp" "$base.json"
            jsons+=("$mesh" "$pct%" "$base.json")
        else
            rm -f "$base.json.tmp"
            echo "demo: error: hlod-simplify failed on $in" >&2
            failed=1
            jsons+=("$mesh" "$pct%" "-")
        fi
    done
done

# Table from the JSON records (perl's core JSON::PP: perl comes with
# build-essential, python3 does not).
perl -MJSON::PP -e '
    my ($txt, $csv) = splice(@ARGV, 0, 2);
    open my $t, ">", "$txt.tmp" or die "$txt: $!\n";
    open my $c, ">", "$csv.tmp" or die "$csv: $!\n";
    my $fmt = "%-22s %6s %10s %10s %9s %13s %12s\n";
    my $head = sprintf $fmt, "mesh", "target", "tris_in", "tris_out", "seconds", "error", "error % diag";
    print $head; print $t $head;
    print $c "mesh,target,tris_in,tris_out,seconds,error,error_pct_diag,bbox_diag\n";
    while (my ($mesh, $target, $file) = splice(@ARGV, 0, 3)) {
        my $line;
        if ($file eq "-") {
            $line = sprintf $fmt, $mesh, $target, ("FAILED") x 5;
        } else {
            local $/; open my $f, "<", $file or die "$file: $!\n";
            my $j = JSON::PP->new->decode(<$f>);
            my $err = $j->{error};
            my $pct = (defined $err && $j->{bbox_diag} > 0) ? 100 * $err / $j->{bbox_diag} : undef;
            $line = sprintf $fmt, $mesh, $target, $j->{tris_in}, $j->{tris_out},
                sprintf("%.3f", $j->{seconds}),
                defined $err ? sprintf("%.6g", $err) : "n/a",
                defined $pct ? sprintf("%.4f", $pct) : "n/a";
            printf $c "%s,%s,%d,%d,%.6f,%s,%s,%.17g\n", $mesh, $target, $j->{tris_in},
                $j->{tris_out}, $j->{seconds}, $err // "", $pct // "", $j->{bbox_diag};
        }
        print $line; print $t $line;
    }
    close $t or die; close $c or die;
    rename "$txt.tmp", $txt or die; rename "$csv.tmp", $csv or die;
' "$OUT/table.txt" "$OUT/simplify.csv" "${jsons[@]}" || failed=1
echo "(error: two-sided Hausdorff distance, model units; results in out/demo/)"

BENCH=$ROOT/build/bin/hlod-bench-simplify
if [ -x "$BENCH" ]; then
    echo
    echo "==> hlod-bench-simplify (ours vs meshoptimizer)"
    "$BENCH" || { echo "demo: error: hlod-bench-simplify failed" >&2; failed=1; }
fi

PRESET=${HLOD_DEMO_CITY:-default}
CITY=$OUT/city/$PRESET
mkdir -p "$OUT/city"
echo
if [ -s "$CITY.obj" ]; then
    echo "==> city: $CITY.obj exists (delete it to generate again)"
else
    echo "==> hlod-gen-city --preset $PRESET"
    "$ROOT/build/bin/hlod-gen-city" --preset "$PRESET" -o "$CITY.obj" ||
        { echo "demo: error: hlod-gen-city failed" >&2; exit 1; }
fi
echo "==> hlod-build $CITY.obj (cutplane)"
"$ROOT/build/bin/hlod-build" "$CITY.obj" -o "$CITY.hlod" --json ||
    { echo "demo: error: hlod-build failed" >&2; exit 1; }
echo "==> hlod-info $CITY.hlod"
"$ROOT/build/bin/hlod-info" "$CITY.hlod" || failed=1

exit $failed
