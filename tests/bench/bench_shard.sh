#!/usr/bin/env bash
# bench_shard.sh - a big city built in shards on this machine (docs/sharded-builds.md;
# issue 20, item 5).  A benchmark, not a test: it takes
# about an hour at the default size.
#
#   bash tests/bench/bench_shard.sh [--tiles K] [--blocks-per-tile B]
#        [--tris-per-block M] [--shards N] [--jobs J] [--single-file]
#        [--single] [--out DIR] [--bin DIR]
#
# --single-file: one OBJ of K x B blocks instead of K tiles (each shard
# streams it object by object).  --single: also the single-machine build
# (2 threads): its time and peak RSS, and whether the merge is
# byte-identical to it.
#
# The city is K generated cities ("tiles", hlod-gen-city --blocks B
# --tris-per-block M, seeds 1..K) laid edge to edge on a square grid, one
# OBJ each, as real city data comes in tiles; the default 16 x 175 blocks x
# 35,000 triangles is about 100M triangles (2,800 blocks, 1024^2 textures).
# The N shards (default 4) run through GNU parallel, J at a time (default
# 2, one build thread each: this machine has 2 cores), then hlod-merge.
# It prints, and writes to OUT/bench_shard.json:
#   - generation time; build wall time (shards + merge) and each shard's and
#     the merge's own time and peak RSS (their --json); the store's size;
#   - hlod-bench on 'fly' and 'walk-drive' over the centre tile (its own
#     camera paths, hlod-gen-city --paths) at 33 ms with a 1 GiB budget
#     (--memory-mb 1024): mean and p99 frame time, deadline, render waits.
# Without --single the single build is not run (at 100M from tiles it
# peaks at 4.7 GB); the merge's bytes against it are what cli_shard checks.
set -euo pipefail
TILES=16
BPT=175
TPB=35000
SHARDS=4
JOBS=2
OUT=out/bench-shard
BIN=build/bin
SINGLE_FILE=0
SINGLE=0
while [ $# -gt 0 ]; do
    case $1 in
    --tiles) TILES=$2; shift 2 ;;
    --blocks-per-tile) BPT=$2; shift 2 ;;
    --tris-per-block) TPB=$2; shift 2 ;;
    --shards) SHARDS=$2; shift 2 ;;
    --jobs) JOBS=$2; shift 2 ;;
    --out) OUT=$2; shift 2 ;;
    --single-file) SINGLE_FILE=1; shift ;;
    --single) SINGLE=1; shift ;;
    --bin) BIN=$2; shift 2 ;;
    -h|--help) sed -n '2,25p' "$0"; exit 0 ;;
    *) echo "bench_shard.sh: unknown option $1" >&2; exit 2 ;;
    esac
done
BIN=$(cd "$BIN" && pwd)
command -v parallel >/dev/null || { echo "bench_shard.sh: GNU parallel is not installed" >&2; exit 1; }
mkdir -p "$OUT/tiles" "$OUT/parts" "$OUT/paths"
OUT=$(cd "$OUT" && pwd)

# the tiles' grid: a tile of B blocks is ceil(sqrt(B)) x ceil(B / cols)
# street cells of 80 x 64 m (preprocess/city.c), centred on its origin
cols=$(python3 -c "import math; print(math.ceil(math.sqrt($BPT)))")
rows=$(( (BPT + cols - 1) / cols ))
side=$(python3 -c "import math; print(math.ceil(math.sqrt($TILES)))")
tw=$((cols * 80))
th=$((rows * 64))
centre=$(( (side / 2) * side + side / 2 ))
[ $centre -lt $TILES ] || centre=0

t0=$(date +%s.%N)
inputs=()
if [ "$SINGLE_FILE" = 1 ]; then
    inputs=("$OUT/tiles/city.obj")
    [ -s "$OUT/tiles/city.obj" ] || "$BIN/hlod-gen-city" -o "$OUT/tiles/city.obj" \
        --blocks $((TILES * BPT)) --tris-per-block "$TPB" --seed 1 --quiet
    [ -s "$OUT/paths/fly.path" ] || "$BIN/hlod-gen-city" --paths "$OUT/paths" --blocks $((TILES * BPT))
    BPT=$((TILES * BPT))
    TILES=1
fi
for k in $(seq 0 $((TILES - 1))); do
    [ "$SINGLE_FILE" = 1 ] && break
    x=$(( (k % side) * tw ))
    y=$(( (k / side) * th ))
    f=$OUT/tiles/tile$k.obj
    inputs+=("$f")
    [ -s "$f" ] && continue
    "$BIN/hlod-gen-city" -o "$f" --blocks "$BPT" --tris-per-block "$TPB" --seed $((k + 1)) \
        --origin "$x" "$y" 0 --quiet
    if [ $k -eq $centre ]; then
        "$BIN/hlod-gen-city" --paths "$OUT/paths" --blocks "$BPT" --origin "$x" "$y" 0
    fi
done
[ -s "$OUT/paths/fly.path" ] || "$BIN/hlod-gen-city" --paths "$OUT/paths" --blocks "$BPT" \
    --origin $(( (centre % side) * tw )) $(( (centre / side) * th )) 0
t1=$(date +%s.%N)

rm -f "$OUT"/parts/*.part
parallel -j "$JOBS" --halt now,fail=1 "$BIN/hlod-build" "${inputs[@]}" -o "$OUT/parts/{}.part" \
    --threads 1 --quiet --json --shard "{}/$SHARDS" ">" "$OUT/parts/{}.json" ::: $(seq 1 "$SHARDS")
t2=$(date +%s.%N)
"$BIN/hlod-merge" "$OUT"/parts/*.part -o "$OUT/city.hlod" --quiet --json >"$OUT/merge.json"
t3=$(date +%s.%N)
echo '{}' >"$OUT/single.json"
if [ "$SINGLE" = 1 ]; then
    "$BIN/hlod-build" "${inputs[@]}" -o "$OUT/single.hlod" --threads 2 --quiet --json >"$OUT/single.json"
    if cmp -s "$OUT/single.hlod" "$OUT/city.hlod"; then same=True; else same=False; fi
    python3 -c "import json,sys; j=json.load(open(sys.argv[1])); j['merge_identical']=$same; json.dump(j,open(sys.argv[1],'w'))" "$OUT/single.json"
    rm -f "$OUT/single.hlod"
fi

for p in fly walk-drive; do
    "$BIN/hlod-bench" "$OUT/city.hlod" --path "$p" --paths-dir "$OUT/paths" --target-ms 33 \
        --memory-mb 1024 --out "$OUT/bench-$p" --no-plots >/dev/null
done

python3 - "$OUT" "$t0" "$t1" "$t2" "$t3" "$TILES" "$BPT" "$TPB" "$SHARDS" "$JOBS" <<'EOF'
import json, os, sys
out = sys.argv[1]
t0, t1, t2, t3 = map(float, sys.argv[2:6])
tiles, bpt, tpb, shards, jobs = map(int, sys.argv[6:11])
parts = [json.load(open(f"{out}/parts/{i}.json")) for i in range(1, shards + 1)]
merge = json.load(open(f"{out}/merge.json"))
single = json.load(open(f"{out}/single.json"))
runs = {}
for p in ("fly", "walk-drive"):
    s = json.load(open(f"{out}/bench-{p}/summary.json"))
    r = s["runs"][0] if "runs" in s else s
    runs[p] = r
res = {
    "tiles": tiles, "blocks_per_tile": bpt, "tris_per_block": tpb, "shards": shards, "jobs": jobs,
    "tris_in": parts[0]["tris_in"] if "tris_in" in parts[0] else None,
    "generate_seconds": t1 - t0,
    "build_seconds": t3 - t1, "shards_seconds": t2 - t1, "merge_seconds": t3 - t2,
    "shard_seconds": [p["seconds"] for p in parts],
    "shard_peak_rss_bytes": [p["peak_rss_bytes"] for p in parts],
    "merge_peak_rss_bytes": merge["peak_rss_bytes"],
    "store_bytes": merge["bytes"], "nodes": merge["nodes"], "blocks": merge["blocks"],
    "bench": runs,
    "single": single,
}
json.dump(res, open(f"{out}/bench_shard.json", "w"), indent=1)
gib = 1 << 30
print(f"city: {tiles} tiles x {bpt} blocks x {tpb} triangles = {res['tris_in']} triangles, {merge['blocks']} blocks")
print(f"generate {res['generate_seconds']:.0f} s; build {res['build_seconds']:.0f} s "
      f"(shards {res['shards_seconds']:.0f} s, {jobs} at a time; merge {res['merge_seconds']:.1f} s, "
      f"{100 * res['merge_seconds'] / max(res['build_seconds'], 1e-9):.1f}% of the build)")
for i, p in enumerate(parts, 1):
    print(f"  shard {i}/{shards}: {p['blocks']} blocks, {p['seconds']:.0f} s, peak RSS {p['peak_rss_bytes'] / gib:.2f} GiB")
print(f"  merge: {merge['nodes_copied']} nodes copied, {merge['groups_built']} groups built, peak RSS {merge['peak_rss_bytes'] / gib:.2f} GiB")
print(f"store: {merge['bytes'] / 1e9:.2f} GB, {merge['nodes']} nodes")
if single:
    print(f"single build: {single['seconds']:.0f} s, peak RSS {single['peak_rss_bytes'] / gib:.2f} GiB, "
          f"merge byte-identical: {single['merge_identical']}")
for p, r in runs.items():
    keys = [k for k in ("frame_ms_mean", "frame_ms_p50", "frame_ms_p99", "deadline_met", "machine_p50_ms",
                        "machine_p99_ms", "render_waits", "peak_resident_bytes", "loads", "tris_mean") if k in r]
    print(f"  {p}: " + ", ".join(f"{k} {r[k]}" for k in keys))
EOF
