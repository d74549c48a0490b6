#!/usr/bin/env bash
# bench_loader_ab.sh - the loader thread against the renderer on the same
# cores: settings A/B on the moving paths, and the deadline misses of the
# frames with loads queued against those without.  A benchmark, not a
# test: it prints a table and writes one CSV.
#
#   bash tests/bench/bench_loader_ab.sh STORE OUTDIR [PATHS_DIR]
#
# For ROUNDS rounds, each path of MOVING, each entry of SETS in turn (so
# the machine's drift falls on every entry alike): hlod-bench at TARGET ms,
# WIDTH x HEIGHT, MEMORY_MB of memory (default a quarter of the store's
# decoded size, as the demo streams), the frozen replay of 60 frames
# beside it.  An entry of SETS is one or more KEY=VALUE joined by '+',
# each passed as --set (default "loader_idle=0 loader_idle=1").
#
# Per path and entry, pooled over the rounds: deadline_met, render_waits,
# missing_wanted_frames, the machine's replay p50 / p99 (ranges over the
# rounds), and the misses of frames with loads queued (frames.csv
# queued > 0, measured_ms > TARGET) against those of the others, over all
# frames and from frame 45 on (past the cost model's warm-up: frame 0
# compiles shaders and faults pages in with the first loads queued).
#
# Env: BIN (build/bin), ROUNDS (3), MOVING (fly walk-drive walk-to-fly),
# SETS, MEMORY_MB, TARGET (33), WIDTH (1280), HEIGHT (720).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
usage="usage: bench_loader_ab.sh STORE OUTDIR [PATHS_DIR]"
store=${1:?$usage}
out=$(realpath -m "${2:?$usage}")
paths=${3:-$ROOT/data/paths/default}
ROUNDS=${ROUNDS:-3}
MOVING=${MOVING:-fly walk-drive walk-to-fly}
SETS=${SETS:-loader_idle=0 loader_idle=1}
TARGET=${TARGET:-33}
W=${WIDTH:-1280}
H=${HEIGHT:-720}
if [ -z "${MEMORY_MB:-}" ]; then
    MEMORY_MB=$("$BIN/hlod-info" "$store" --json | perl -MJSON::PP -e 'local $/;
        printf "%.0f", JSON::PP->new->decode(<STDIN>)->{memory_bytes} / 4 / 1048576') ||
        { echo "bench_loader_ab: $store: hlod-info failed" >&2; exit 1; }
fi
mkdir -p "$out" || exit 1
. "$ROOT/tests/bench/summary_key.sh"
csv="$out/loader_ab.csv"
echo "path,set,round,deadline_met,render_waits,missing_wanted_frames,machine_p50_ms,machine_p99_ms,miss_queued,frames_queued,miss_idle,frames_idle,miss_queued_45,frames_queued_45,miss_idle_45,frames_idle_45" >"$csv"
for r in $(seq "$ROUNDS"); do
    for p in $MOVING; do
        for set in $SETS; do
            sets=()
            IFS=+ read -r -a kv <<<"$set"
            for x in "${kv[@]}"; do sets+=(--set "$x"); done
            dir="$out/$p-$set-$r"
            "$BIN/hlod-bench" "$store" --path "$p" --paths-dir "$paths" --target-ms "$TARGET" \
                --width "$W" --height "$H" --jitter-frames 60 --no-plots --memory-mb "$MEMORY_MB" \
                "${sets[@]}" --out "$dir" >/dev/null 2>"$dir.err" ||
                { echo "bench_loader_ab: $p $set failed: $(head -c 300 "$dir.err")" >&2; continue; }
            s="$dir/summary.json"
            split=$(awk -F, -v t="$TARGET" 'NR == 1 { for (i = 1; i <= NF; i++) c[$i] = i; next }
                { q = $c["queued"] > 0; f[q]++; if ($c["measured_ms"] > t) m[q]++
                  if ($c["frame"] >= 45) { g[q]++; if ($c["measured_ms"] > t) n[q]++ } }
                END { printf "%d,%d,%d,%d,%d,%d,%d,%d", m[1], f[1], m[0], f[0], n[1], g[1], n[0], g[0] }' \
                "$dir/frames.csv")
            echo "$p,$set,$r,$(key deadline_met "$s"),$(key render_waits "$s"),$(key missing_wanted_frames "$s"),$(key machine_p50_ms "$s"),$(key machine_p99_ms "$s"),$split" >>"$csv"
        done
    done
done
perl -e '
    open my $h, "<", $ARGV[0] or die; <$h>;
    my (%a, @order, %seen);
    while (<$h>) { chomp; my @f = split /,/; my $id = "$f[0] $f[1]";
        push @order, $id unless $seen{$id}++; push @{$a{$id}}, \@f; }
    sub rng { my @v = sort { $a <=> $b } @_; return sprintf(@v > 1 ? "%.3g-%.3g" : "%.3g", $v[0], $v[-1]) }
    sub ratio { my ($mq, $fq, $mi, $fi) = @_; my $rq = $fq ? $mq / $fq : 0; my $ri = $fi ? $mi / $fi : 0;
        return sprintf "%d/%d vs %d/%d: %s", $mq, $fq, $mi, $fi,
            $ri > 0 ? sprintf("%.1fx", $rq / $ri) : $rq > 0 ? "inf" : "-" }
    printf "%-30s %-13s %-7s %-11s %-22s %-32s %s\n", "path set", "deadline_met", "waits", "missing", "replay p50 / p99 ms",
        "misses queued vs idle, all", "from frame 45";
    for my $id (@order) {
        my @r = @{$a{$id}}; my @s = (0) x 16;
        for my $f (@r) { $s[$_] += $f->[$_] for 3 .. 15 }
        printf "%-30s %-13s %-7d %-11d %-22s %-32s %s\n", $id, rng(map { $_->[3] } @r), $s[4], $s[5],
            rng(map { $_->[6] } @r) . " / " . rng(map { $_->[7] } @r),
            ratio(@s[8 .. 11]), ratio(@s[12 .. 15]);
    }' "$csv"
echo "wrote $csv"
