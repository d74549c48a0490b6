#!/usr/bin/env bash
# bench_cubes.sh - Chamberlain's colour cubes (policy cubes, docs/cubes.md)
# against full detail on the paper's two kinds of model: the shape of
# Chamberlain et al.'s Table 2 (speed-up over the geometry at 1.75 to 14
# radii, 124 x 124 pixels, the view turned 30 degrees about the vertical
# axis from a sampled direction).
# A benchmark, not a test: it prints a table and writes one CSV.
#
#   bash tests/bench/bench_cubes.sh OUTDIR
#
# Models (hlod-gen-scene): a tree of TREE_TRIS triangles (52470, the
# paper's tree) and a molecule of MOL_TRIS (5000000: spheres of 800),
# each built with hlod-build --method cubes.  Each distance runs a still
# camera for FRAMES frames (default 120) under full (every node, no cubes)
# and under cubes, side by side, then the jitter of the machine in the
# same run (--jitter-frames); frame_ms_p50 is the median of the settled
# frames, those after the last with a wanted node missing (empty when
# fewer than 10 are left: raise FRAMES).  PSNR: each against the full-detail reference (hlod-bench
# --reference, supersampled) every 10th frame.  "full" is klein's
# reference walk (--set splats=0: every node drawn).  Env: BIN (build/bin), TREE_TRIS, MOL_TRIS, FRAMES, DISTANCES
# ("1.75 3.5 7 14"), MODELS ("tree molecule"), LEAF_TRIS (hlod-build
# --leaf-tris, 64; MOL_LEAF_TRIS for the molecule, the same by default).
# missing_half and missing_last: wanted nodes not resident at the half
# and at the end.
#
# Three runs per distance: "geometry", the model as geometry alone (the
# same builder with one leaf: every triangle in one node, drawn by one
# call), the paper's "Geometric Time"; "full", the cubes store with every
# node drawn; and "cubes".  Speed-ups are over geometry (and over full).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
out=$(realpath -m "${1:?usage: bench_cubes.sh OUTDIR}")
TREE_TRIS=${TREE_TRIS:-52470}
MOL_TRIS=${MOL_TRIS:-5000000}
FRAMES=${FRAMES:-120}
DISTANCES=${DISTANCES:-1.75 3.5 7 14}
MODELS=${MODELS:-tree molecule}
LEAF_TRIS=${LEAF_TRIS:-64}
MOL_LEAF_TRIS=${MOL_LEAF_TRIS:-$LEAF_TRIS}
mkdir -p "$out" || exit 1
csv="$out/cubes.csv"
echo "model,tris,radii,policy,frame_ms_p50,settled_frames,frame_ms_mean,tris_mean,cubes_mean,psnr_mean,machine_p50_ms,machine_p99_ms,missing_half,missing_last" >"$csv"
key() { perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
    my $v = $j->{$ARGV[0]}; print defined $v ? (ref $v ? join(" ", @$v) : $v) : ""' "$1" <"$2"; }
for model in $MODELS; do
    tris=$TREE_TRIS leaf=$LEAF_TRIS
    [ "$model" = molecule ] && tris=$MOL_TRIS leaf=$MOL_LEAF_TRIS
    dir="$out/$model"
    mkdir -p "$dir" || exit 1
    if [ ! -s "$dir/$model.hlod" ]; then
        "$BIN/hlod-gen-scene" --kind "$model" --tris "$tris" -o "$dir/$model.obj" --quiet &&
            "$BIN/hlod-build" "$dir/$model.obj" -o "$dir/$model.hlod" --method cubes --leaf-tris "$leaf" --json \
                --quiet >"$dir/build.json" ||
            { echo "bench_cubes: cannot build the $model" >&2; exit 1; }
    fi
    if [ ! -s "$dir/geometry.hlod" ]; then
        "$BIN/hlod-build" "$dir/$model.obj" -o "$dir/geometry.hlod" --method cubes \
            --leaf-tris 1073741824 --quiet ||
            { echo "bench_cubes: cannot build the $model as one node" >&2; exit 1; }
    fi
    "$BIN/hlod-info" "$dir/$model.hlod" --json >"$dir/info.json" || exit 1
    lo=$(key bbox_min "$dir/info.json") hi=$(key bbox_max "$dir/info.json")
    for r in $DISTANCES; do
        # the eye r radii (half the box's diagonal) from the box's centre,
        # 20 degrees up, turned 30 degrees about z from the +x axis
        perl -e 'my ($r, @v) = @ARGV; my @lo = @v[0..2]; my @hi = @v[3..5];
            my @c = map { ($lo[$_] + $hi[$_]) / 2 } 0..2;
            my $rad = sqrt(($hi[0]-$lo[0])**2 + ($hi[1]-$lo[1])**2 + ($hi[2]-$lo[2])**2) / 2;
            my ($az, $el) = (30 * 3.14159265 / 180, 20 * 3.14159265 / 180);
            my @e = ($c[0] + $r * $rad * cos($el) * cos($az), $c[1] + $r * $rad * cos($el) * sin($az),
                     $c[2] + $r * $rad * sin($el));
            printf "%.3f %.9g %.9g %.9g %.9g %.9g %.9g\n", $_, @e, @c for (0, 100)' \
            "$r" $lo $hi >"$dir/r$r.path"
        for pol in geometry full cubes; do
            run="$dir/r$r-$pol"
            # full detail: klein's reference walk (every node, no splats)
            how=(--policy cubes)
            [ "$pol" = cubes ] || how=(--policy klein --set splats=0)
            store="$dir/$model.hlod"
            [ "$pol" = geometry ] && store="$dir/geometry.hlod"
            "$BIN/hlod-bench" "$store" --path "$dir/r$r.path" --frames "$FRAMES" \
                --width 124 --height 124 --target-ms 1000 --no-plots --memory-mb 8192 \
                --set max_inflight=256 "${how[@]}" --reference --reference-every 10 --out "$run" \
                >/dev/null 2>"$run.err" ||
                { echo "bench_cubes: $model $r $pol failed: $(head -c 300 "$run.err")" >&2; continue; }
            s="$run/summary.json"
            # the median over the settled frames: after the last frame with a
            # wanted node missing (at least 10 of them, else none), and
            # the wanted nodes still missing at the half and at the end
            read -r p50 settled miss < <(perl -e 'my $hdr = <STDIN>; chomp $hdr; my @h = split /,/, $hdr;
                my ($c) = grep { $h[$_] eq "wanted_missing" } 0 .. $#h; my (@rows, $last, $half, $end);
                while (<STDIN>) { my @f = split /,/; push @rows, [$f[0], $f[2], $f[$c]];
                    $last = $#rows if $f[$c] > 0; $half = $f[$c] if $f[0] == int($ARGV[0] / 2); $end = $f[$c] }
                my @t = sort { $a <=> $b } map { $_->[1] } @rows[(defined $last ? $last + 1 : 0) .. $#rows];
                printf "%s %d %s,%s\n", @t >= 10 ? $t[int(@t / 2)] : "-", scalar @t, $half // "", $end // ""' \
                "$FRAMES" <"$run/frames.csv")
            [ "$p50" = - ] && p50=
            echo "$model,$tris,$r,$pol,$p50,$settled,$(key frame_ms_mean "$s"),$(key tris_mean "$s"),$(key splats_mean "$s"),$(key psnr_mean "$s"),$(key machine_p50_ms "$s"),$(key machine_p99_ms "$s"),$miss" >>"$csv"
        done
    done
done
column -s, -t "$csv"
# the speed-up per distance: geometry's median (and full's) over cubes'
perl -F, -lane 'next if $. == 1; $t{"$F[0] $F[2]"}{$F[3]} = $F[4];
    END { for my $k (sort keys %t) { my ($g, $f, $c) = @{$t{$k}}{qw(geometry full cubes)};
        printf "%-16s speed-up over geometry %s, over full %s\n", $k,
            ($g && $c) ? sprintf("%.2f", $g / $c) : "n/a", ($f && $c) ? sprintf("%.2f", $f / $c) : "n/a" } }' "$csv"
echo "bench_cubes: $csv"
