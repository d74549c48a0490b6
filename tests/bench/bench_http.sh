#!/usr/bin/env bash
# bench_http.sh - a store streamed from nginx against the same store read
# from the local file, side by side in one run (docs/http.md).  A benchmark, not a test: as
# root, in a network namespace of
# its own (unshare -n) with a tc tbf of RATE on its loopback, nginx
# limit_rate RATE per connection, and LATENCY ms added to every request by
# the reader's hook (HLOD_HTTP_LATENCY_MS).
#
#   bash tests/bench/bench_http.sh STORE OUTDIR [PATHS_DIR] [hlod-bench flags...]
#
# For each path in PATHS (default "walk-drive fly") runs hlod-bench on the
# file, then on the URL, at TARGET ms (33) and prints render_waits,
# missing_wanted_frames and bytes_read of each, and their ratios.
# Env: BIN (build/bin), PATHS, TARGET, RATE_MBIT (100), LATENCY (40).
set -uo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin}
store=$(realpath "${1:?usage: bench_http.sh STORE OUTDIR [PATHS_DIR] [flags]}")
out=$(realpath -m "${2:?usage: bench_http.sh STORE OUTDIR [PATHS_DIR] [flags]}")
paths_dir=${3:-$ROOT/data/paths/default}
shift $(($# >= 3 ? 3 : $#))
PATHS=${PATHS:-walk-drive fly}
TARGET=${TARGET:-33}
RATE_MBIT=${RATE_MBIT:-100}
LATENCY=${LATENCY:-40}

if [ -z "${HLOD_BENCH_IN_NETNS:-}" ]; then
    export HLOD_BENCH_IN_NETNS=1
    exec unshare -n bash "$0" "$store" "$out" "$paths_dir" "$@"
fi
ip link set lo up && ip link set lo mtu 1500 &&
    tc qdisc add dev lo root tbf rate "${RATE_MBIT}mbit" burst 64kb latency 100ms || exit 1

mkdir -p "$out/www" "$out/logs" "$out/tmp"
ln -sf "$store" "$out/www/store.hlod"
PORT=28080
cat >"$out/nginx.conf" <<EOF
worker_processes 1;
daemon off;
pid $out/nginx.pid;
error_log $out/logs/error.log warn;
user root;
events { worker_connections 256; }
http {
    access_log off;
    client_body_temp_path $out/tmp/body;
    proxy_temp_path $out/tmp/proxy;
    fastcgi_temp_path $out/tmp/fastcgi;
    uwsgi_temp_path $out/tmp/uwsgi;
    scgi_temp_path $out/tmp/scgi;
    server {
        listen 127.0.0.1:$PORT;
        root $out/www;
        limit_rate $((RATE_MBIT * 125))k;
    }
}
EOF
nginx -p "$out" -c "$out/nginx.conf" &
ngx=$!
trap 'kill $ngx 2>/dev/null; wait $ngx 2>/dev/null' EXIT
for _ in $(seq 50); do (: </dev/tcp/127.0.0.1/$PORT) 2>/dev/null && break; sleep 0.1; done

key() { sed -n "s/.*\"$2\": *\([0-9.e+-]*\).*/\1/p" "$1/summary.json"; }
printf '%-11s %-5s %7s %8s %14s %8s %10s\n' path src waits missing bytes_read frames finish_ms
for p in $PATHS; do
    for src in file http; do
        s=$store
        [ $src = http ] && s=http://127.0.0.1:$PORT/store.hlod
        HLOD_HTTP_LATENCY_MS=$LATENCY "$BIN/hlod-bench" "$s" --path "$p" --paths-dir "$paths_dir" \
            --target-ms "$TARGET" --jitter-frames 0 --no-plots --out "$out/$p-$src" "$@" \
            >/dev/null 2>"$out/$p-$src.err"
        d=$out/$p-$src
        printf '%-11s %-5s %7s %8s %14s %8s %10.1f\n' "$p" $src "$(key "$d" render_waits)" \
            "$(key "$d" missing_wanted_frames)" "$(key "$d" bytes_read)" "$(key "$d" frames)" \
            "$(key "$d" loader_finish_ms)"
    done
    f=$out/$p-file h=$out/$p-http
    echo "$p: missing http/file $(echo "$(key "$h" missing_wanted_frames) / ($(key "$f" missing_wanted_frames) + 0.000001)" | bc -l | cut -c1-6), bytes http/file $(echo "$(key "$h" bytes_read) / $(key "$f" bytes_read)" | bc -l | cut -c1-6)"
done
