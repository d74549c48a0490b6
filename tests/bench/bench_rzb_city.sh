#!/usr/bin/env bash
# bench_rzb_city.sh - the shape of Wand's Table 1 on a replicated city:
# the randomized z-buffer (policy rzb, docs/rzb.md) at d = 1, 2 and 5,
# from fresh points and from the sample caches, over a city drawn as
# 2^COPIES x 2^COPIES copies of itself held once (--set rzb_copies), beside
# full detail on one copy (the conventional z-buffer).  A benchmark, not a
# test: it prints a table and writes one CSV.
#
#   bash tests/bench/bench_rzb_city.sh STORE OUTDIR [PATHS_DIR]
#
# STORE: a city's store (hlod-build, cutplane); PATHS_DIR its camera paths
# (default data/paths/default).  Each run: 640x480, FRAMES frames of each
# path in PATHS, the median frame time (a cache's first frame fills it;
# the median is the frames after).  Full detail is lakhia with a target of
# 100 s (every leaf it sees), the store in memory, the median of its
# frames with no wanted node missing (nan when none); it draws one copy, and the
# replicated city's conventional time is that times the copies (an
# estimate: it cannot be drawn here).  ROUNDS rounds, the runs alternated
# within each.
#
# Env: BIN (build/bin), COPIES (3: 8 x 8 copies), PATHS ("still fly"),
# FRAMES (30), FRAMES_FULL (300: full detail's run, which must load the
# leaves first), ROUNDS (2), CACHE_MB (1024).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
usage="usage: bench_rzb_city.sh STORE OUTDIR [PATHS_DIR]"
store=${1:?$usage}
out=$(realpath -m "${2:?$usage}")
paths=${3:-$ROOT/data/paths/default}
COPIES=${COPIES:-3}
PATHS=${PATHS:-still fly}
FRAMES=${FRAMES:-30}
ROUNDS=${ROUNDS:-2}
CACHE_MB=${CACHE_MB:-1024}
FRAMES_FULL=${FRAMES_FULL:-300}
mkdir -p "$out" || exit 1
. "$ROOT/tests/bench/summary_key.sh"
csv="$out/rzb_city.csv"
echo "path,run,round,copies,frame_ms_p50,frame_ms_mean,splats_mean,tris_mean" >"$csv"
# run PATH NAME COPIES ARGS...: one hlod-bench run, one CSV row
run() {
    local p=$1 name=$2 c=$3 dir="$out/$1-$2-$r"
    shift 3
    "$BIN/hlod-bench" "$store" --path "$p" --paths-dir "$paths" --frames "$FRAMES" \
        --width 640 --height 480 --no-plots --jitter-frames 0 "$@" \
        --out "$dir" >/dev/null 2>"$dir.err" ||
        { echo "bench_rzb_city: $p $name failed: $(head -c 300 "$dir.err")" >&2; return 1; }
    local s="$dir/summary.json" p50
    p50=$(key frame_ms_p50 "$s")
    [ "$name" = full ] && p50=$(perl -e 'open my $h, "<", $ARGV[0] or die; my @n = split /,/, scalar <$h>;
        my %c; @c{@n} = 0 .. $#n; my @t;
        while (<$h>) { my @f = split /,/; push @t, $f[$c{measured_ms}] if $f[$c{wanted_missing}] == 0 }
        @t = sort { $a <=> $b } @t; print @t ? $t[$#t / 2] : "nan"' "$dir/frames.csv")
    echo "$p,$name,$r,$c,$p50,$(key frame_ms_mean "$s"),$(key splats_mean "$s"),$(key tris_mean "$s")" >>"$csv"
}
for r in $(seq "$ROUNDS"); do
    for p in $PATHS; do
        run "$p" full 0 --policy lakhia --target-ms 100000 --frames "$FRAMES_FULL"
        for d in 1 2 5; do
            run "$p" "rzb-d$d" "$COPIES" --policy rzb --target-ms 33 --set "splat_px=$d" \
                --set "rzb_copies=$COPIES"
            run "$p" "rzb-d$d-cache" "$COPIES" --policy rzb --target-ms 33 --set "splat_px=$d" \
                --set "rzb_copies=$COPIES" --set "rzb_cache_mb=$CACHE_MB"
        done
    done
done
# the table: per path and run, the rounds' medians (their range), and
# fresh over cached
perl -e '
    my ($csv, $copies) = @ARGV;
    open my $h, "<", $csv or die; <$h>;
    my (%v, %pts, @paths, %seen);
    while (<$h>) { chomp; my @f = split /,/; push @{$v{"$f[0],$f[1]"}}, $f[4]; $pts{"$f[0],$f[1]"} = $f[6];
        push @paths, $f[0] unless $seen{$f[0]}++; }
    sub med { my @s = sort { $a <=> $b } @_; return @s % 2 ? $s[$#s / 2] : ($s[@s / 2 - 1] + $s[@s / 2]) / 2 }
    for my $p (@paths) {
        my $full = med(@{$v{"$p,full"}});
        printf "%s: full detail, one copy %.1f ms (x %d copies: %.0f ms, estimated)\n", $p, $full, 4 ** $copies, $full * 4 ** $copies;
        printf "  %-3s %-28s %-28s %s\n", "d", "fresh ms (rounds), points", "cached ms (rounds), points", "fresh / cached";
        for my $d (1, 2, 5) {
            my @f = @{$v{"$p,rzb-d$d"} || []}; my @c = @{$v{"$p,rzb-d$d-cache"} || []};
            next unless @f && @c;
            my ($mf, $mc) = (med(@f), med(@c));
            printf "  %-3d %-28s %-28s %.2f\n", $d,
                sprintf("%.1f (%s) %.2fM", $mf, join("/", map { sprintf "%.1f", $_ } @f), $pts{"$p,rzb-d$d"} / 1e6),
                sprintf("%.1f (%s) %.2fM", $mc, join("/", map { sprintf "%.1f", $_ } @c), $pts{"$p,rzb-d$d-cache"} / 1e6),
                $mc > 0 ? $mf / $mc : 0;
        }
    }' "$csv" "$COPIES"
echo "wrote $csv"
