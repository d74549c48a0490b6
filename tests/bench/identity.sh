#!/bin/bash
# identity.sh - does a change alter any output?  Runs two builds' tools side
# by side and compares what they write, byte for byte:
#   - hlod-simplify on every test mesh at 10% and 1%;
#   - hlod-gen-city --preset small and tiny (meshes, textures, paths);
#   - hlod-build stores of the small city (and with --default the 7M
#     default city: about 25 min and 8 GB of disk; with --parts the
#     demo's second city, the same size as separate boxes at 500 km,
#     4,100 km), cutplane and metis;
#   - hlod-bench --deterministic on walk-to-fly and walk-drive, all three
#     policies: every column of frames.csv but the wall-clock ones
#     (measured_ms, traversal_ms, upload_ms, occlusion_ms, render_waits) and the image
#     ones (not rendered against a reference here).
#
#   bash tests/bench/identity.sh OLD_BIN NEW_BIN OUT [--default] [--parts]
#
# OLD_BIN and NEW_BIN are build/bin folders (copy one aside before
# rebuilding).  Prints "same X" or "DIFF X" per output; exit 1 on any DIFF.
set -eu
OLD=$1 NEW=$2 OUT=$3
CITIES="small"
for a in "${@:4}"; do
    case $a in
    --default) CITIES="$CITIES default" ;;
    --parts) CITIES="$CITIES parts" ;; # the default city's size as separate boxes, far out
    *) echo "identity.sh: unknown option $a" >&2; exit 2 ;;
    esac
done
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
M=$ROOT/data/meshes
mkdir -p "$OUT"

make_outputs() { # BIN DIR
    local B=$1 D=$2 m r c meth p extra
    mkdir -p "$D/simp" "$D/city"
    for m in bunny00.off fandisk.off mech-holes-shark.off elephant.off Wuson.ply spider.obj \
             2CylinderEngine.glb cube_uv.ply BoxTextured.glb; do
        for r in 0.1 0.01; do
            "$B/hlod-simplify" "$M/$m" -o "$D/simp/${m%.*}-$r.obj" --ratio $r --quiet
        done
    done
    for p in small tiny; do
        mkdir -p "$D/gen-$p"
        "$B/hlod-gen-city" --preset $p -o "$D/gen-$p/city.obj" --paths "$D/gen-$p/paths" --quiet
    done
    for c in $CITIES; do
        local C=$OUT/city-$c
        if [ ! -f "$C/city.obj" ]; then # the input, made once by OLD
            mkdir -p "$C"
            if [ $c = parts ]; then
                "$OLD/hlod-gen-city" --preset default --style parts --seed 2 \
                    --origin 500000 4100000 0 -o "$C/city.obj" --paths "$C/paths" --quiet
            else
                "$OLD/hlod-gen-city" --preset $c -o "$C/city.obj" --paths "$C/paths" --quiet
            fi
        fi
        for meth in cutplane metis; do
            extra=""
            [ $c != small ] && [ $meth = cutplane ] && extra="--desired-tris 450"
            "$B/hlod-build" "$C/city.obj" -o "$D/city/$c-$meth.hlod" --method $meth --threads 1 \
                --quiet $extra
            for p in walk-to-fly walk-drive; do
                "$B/hlod-bench" "$D/city/$c-$meth.hlod" --path "$C/paths/$p.path" \
                    --out "$D/bench-$c-$meth-$p" --deterministic --target-ms 3 --memory-mb 6 \
                    --set v_time=1e-4 --set fixed_ms=0.5 --no-plots --width 320 --height 180 \
                    --frames 300 --policy lakhia,nohyst,sse > /dev/null 2>&1
            done
        done
    done
}

selection() { # DIR: the selection columns of every frames.csv below it
    local f
    for f in $(find "$1" -name frames.csv | sort); do
        echo "== ${f#$1}"
        awk -F, 'NR==1{for(i=1;i<=NF;i++) if($i!~/^(measured_ms|traversal_ms|upload_ms|occlusion_ms|render_waits|psnr|ssim|luma_change|ref_luma_change)$/) keep[i]=1}
        {o="";for(i=1;i<=NF;i++) if(keep[i]) o=o $i ","; print o}' "$f"
    done
}

rm -rf "$OUT/old" "$OUT/new"
make_outputs "$OLD" "$OUT/old"
make_outputs "$NEW" "$OUT/new"
fail=0
for f in $(cd "$OUT/new" && find simp city gen-small gen-tiny -type f | sort); do
    if cmp -s "$OUT/old/$f" "$OUT/new/$f"; then echo "same $f"; else echo "DIFF $f"; fail=1; fi
done
for d in $(cd "$OUT/new" && ls -d bench-*); do
    if cmp -s <(selection "$OUT/old/$d") <(selection "$OUT/new/$d"); then
        echo "same $d: selection columns, $(selection "$OUT/new/$d" | wc -l) lines"
    else
        echo "DIFF $d: selection columns"
        fail=1
    fi
done
exit $fail
