#!/usr/bin/env bash
# test_lumi_serve.sh - hlod-lumigraph-serve, the Grid-Lumigraph's server,
# and the client's answer protocol (docs/lumigraph.md, issue 44).
#
# Bakes the tiny city (G = 3, 64^2 views), serves it on loopback, and
# checks:
#   - the index and a view come back byte for byte;
#   - an answer at a grid point holds the candidates the client lacks, each
#     once, each a baked view, in the candidates' order, within 300 KB; a
#     second request from the same place holding them fetches nothing;
#     --answer-kb 1 sends exactly one view;
#   - bad requests (a key missing or repeated, NaN, junk, an unknown key, a
#     long query, a body, POST, a path outside the repository) are refused
#     with 4xx, and the server still serves afterwards (0 crashes);
#   - hlod-bench --answers over orbit at the viewer's pace: every frame,
#     render_waits 0, views fetched, every answer within 300 KB;
#   - the server killed mid-run and back 1 s later on the same port (one
#     view an answer, 200 ms before each request, so requests go on over
#     the run): every frame, render_waits 0, the outage said once and its
#     end, views fetched after the restart;
#   - a half-baked repository (one shard of two) served with --store: an
#     answer brings a view the index listed as missing, rendered on demand
#     and then on disk and in the index;
#   - hlod-bench's grid_point_psnr_min at the middle grid point: >= 38 dB
#     over its baked axes;
#   - a folder without an index: exit 1 naming the file.
set -u
BIN=${HLOD_BIN_DIR:-build/bin}
SRC=${HLOD_SOURCE_DIR:-.}
. "$SRC/tests/lib.sh"
T=$(mktemp -d /tmp/hlod-test-lumi-serve.XXXXXX)
SPID=""
stop_server() { [ -n "$SPID" ] && kill "-${1:-TERM}" "$SPID" 2>/dev/null && wait "$SPID" 2>/dev/null; SPID=""; }
trap 'stop_server KILL; [ "${KEEP_T:-0}" = 1 ] || rm -rf "$T"' EXIT

"$BIN/hlod-gen-city" --preset tiny -o "$T/city.obj" --paths "$T/paths" --quiet &&
    "$BIN/hlod-build" "$T/city.obj" -o "$T/city.hlod" --desired-tris 300 --quiet &&
    "$BIN/hlod-lumigraph-bake" "$T/city.hlod" -o "$T/repo" --grid 3 --size 64 --quiet &&
    "$BIN/hlod-lumigraph-bake" "$T/city.hlod" -o "$T/half" --grid 3 --size 64 --shard 1/2 --quiet
ok $? "the tiny city baked (G = 3), whole and one shard of two"

# start_server REPO [ARGS...]: on PORT (a free one the first time, the same
# one on a restart), waits until it listens
PORT=""
start_server() {
    local repo=$1 i
    shift
    [ -n "$PORT" ] || PORT=$(free_port 1)
    "$BIN/hlod-lumigraph-serve" "$repo" --port "$PORT" --quiet "$@" >"$T/serve.out" 2>>"$T/serve.err" &
    SPID=$!
    for i in $(seq 1 100); do
        grep -q "listening on" "$T/serve.out" 2>/dev/null && return 0
        kill -0 "$SPID" 2>/dev/null || return 1
        sleep 0.05
    done
    return 1
}
start_server "$T/repo"
ok $? "the server listens ($(head -1 "$T/serve.out"))"
URL=http://127.0.0.1:$PORT

curl -sf "$URL/repo.hlg" -o "$T/got.hlg" && cmp -s "$T/got.hlg" "$T/repo/repo.hlg" &&
    v=$(cd "$T/repo" && ls views/*/*.hlv | head -1) && curl -sf "$URL/$v" -o "$T/got.hlv" &&
    cmp -s "$T/got.hlv" "$T/repo/$v"
ok $? "the index and a view ($v) come back byte for byte"

# records FILE: "id length" per record of an answer, or "bad" when it does
# not parse to its end
records() {
    python3 - "$1" <<'EOF'
import struct, sys
b = open(sys.argv[1], 'rb').read()
pos = 0
while pos + 8 <= len(b):
    i, n = struct.unpack_from('<II', b, pos)
    if pos + 8 + n > len(b):
        break
    print(i, n)
    pos += 8 + n
if pos != len(b):
    print('bad')
EOF
}
# the middle grid point (box of the index), looking along +x
read -r MID <<<"$(python3 - "$T/repo/repo.hlg" <<'EOF'
import struct, sys
b = open(sys.argv[1], 'rb').read()
lo = struct.unpack_from('<3d', b, 24); hi = struct.unpack_from('<3d', b, 48)
print(','.join(repr((l + h) / 2) for l, h in zip(lo, hi)))
EOF
)"
curl -sf "$URL/answer?p=$MID&d=1,0,0&have=0" -o "$T/a1" && records "$T/a1" >"$T/a1.txt"
n1=$(wc -l <"$T/a1.txt")
ids_ok=$(awk '{ if ($1 in seen) d = 1; seen[$1] = 1 } END { print d ? "dup" : "unique" }' "$T/a1.txt")
size1=$(stat -c %s "$T/a1")
! grep -q bad "$T/a1.txt" && [ "$n1" -ge 1 ] && [ "$ids_ok" = unique ] && [ "$size1" -le 307200 ]
ok $? "an answer at the middle grid point: $n1 views, $ids_ok, $size1 bytes <= 300 KB"
# every record is the view file of its id
all_files=0
while read -r id n; do
    f=$(python3 -c "
g = 3; p = $id // 6; print('views/%d/%d_%d_%d.hlv' % (p % g, p // g % g, p // g // g, $id % 6))")
    [ "$(stat -c %s "$T/repo/$f" 2>/dev/null)" = "$n" ] || all_files=1
done <"$T/a1.txt"
ok $all_files "each record is its view's file (sizes match)"
curl -sf "$URL/answer?p=$MID&d=1,0,0&have=ffffffffffff" -o "$T/a2"
[ $? -eq 0 ] && [ "$(stat -c %s "$T/a2")" = 0 ]
ok $? "a second request from the same place, holding them all: an empty answer"

stop_server
start_server "$T/repo" --answer-kb 1 &&
    curl -sf "$URL/answer?p=$MID&d=1,0,0&have=0" -o "$T/a3" && [ "$(records "$T/a3" | wc -l)" = 1 ]
ok $? "--answer-kb 1: exactly one view"
stop_server
start_server "$T/repo"

bad=0
for q in "d=1,0,0&have=0" "p=$MID&d=1,0,0" "p=$MID&p=$MID&d=1,0,0&have=0" "p=nan,0,0&d=1,0,0&have=0" \
    "p=1,2&d=1,0,0&have=0" "p=$MID&d=0,0,0&have=0" "p=$MID&d=1,0,0&have=zz" \
    "p=$MID&d=1,0,0&have=0&x=1" "p=$MID&d=1,0,0&have=1234567890abc" "p=$MID&d=1,0,0&have=$(head -c 700 /dev/zero | tr '\0' 1)" \
    "p=1,2,3junk&d=1,0,0&have=0"; do
    code=$(curl -s -o /dev/null -w '%{http_code}' "$URL/answer?$q")
    case $code in 4??) ;; *) echo "  $q: $code"; bad=1 ;; esac
done
code_post=$(curl -s -o /dev/null -w '%{http_code}' -X POST -d x "$URL/answer?p=$MID&d=1,0,0&have=0")
code_path=$(curl -s --path-as-is -o /dev/null -w '%{http_code}' "$URL/views/../repo.hlg")
code_view=$(curl -s -o /dev/null -w '%{http_code}' "$URL/views/9/0_0_0.hlv")
[ $bad = 0 ] && [ "${code_post:0:1}" = 4 ] && [ "${code_path:0:1}" = 4 ] && [ "${code_view:0:1}" = 4 ] &&
    kill -0 "$SPID" && curl -sf "$URL/repo.hlg" -o /dev/null
ok $? "bad requests refused with 4xx (POST $code_post, a path outside $code_path, no such view $code_view), the server still serves"

# the client over the answer protocol
bench() { # OUT ARGS...
    local o=$1
    shift
    rm -rf "$o"
    "$BIN/hlod-bench" "$T/city.hlod" --path orbit --paths-dir "$T/paths" --method lumigraph \
        --repo "$URL" --answers --realtime --width 160 --height 120 --frames 150 --jitter-frames 0 \
        --no-plots --out "$o" "$@" 2>"$o.err" >/dev/null
}
key() {
    perl -MJSON::PP -e 'local $/; my $j = JSON::PP->new->decode(<STDIN>);
        print defined $j->{$ARGV[0]} ? $j->{$ARGV[0]} : "NaN"' "$2" <"$1/summary.json" 2>/dev/null
}
last_col() {
    awk -F, -v col="$2" 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == col) c = i; next }
        { m = c ? $c : "none" } END { print m }' "$1/frames.csv"
}
bench "$T/run"
rc=$?
[ $rc -eq 0 ] && [ "$(key "$T/run" frames)" = 150 ] && waits_ok "$(key "$T/run" render_waits)" 150 &&
    [ "$(key "$T/run" bytes_fetched)" -gt 0 ] && [ "$(key "$T/run" answer_bytes_max)" -le 307200 ]
ok $? "hlod-bench --answers: exit $rc, $(key "$T/run" frames) frames, render_waits $(key "$T/run" render_waits), $(key "$T/run" bytes_fetched) bytes, the largest answer $(key "$T/run" answer_bytes_max) B"

# one view an answer and 200 ms before each request (the reader's latency
# hook), so that requests go on over the run and the kill meets them
stop_server
start_server "$T/repo" --answer-kb 1
HLOD_HTTP_LATENCY_MS=200 bench "$T/kill" &
b=$!
sleep 1
stop_server KILL
sleep 1
start_server "$T/repo" --answer-kb 1
wait $b
rc=$?
# frames start after the index is read; the restart is 2 s (60 frames) after
# the start at the latest: bytes fetched from frame 75 on came after it
after=$(awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) if ($i == "lumi_bytes") c = i; next }
    NR - 2 >= 75 { s += $c } END { print s + 0 }' "$T/kill/frames.csv" 2>/dev/null)
[ $rc -eq 0 ] && [ "$(key "$T/kill" frames)" = 150 ] && waits_ok "$(key "$T/kill" render_waits)" 150 &&
    [ "${after:-0}" -gt 0 ] &&
    [ "$(grep -c 'does not answer' "$T/kill.err")" = 1 ] && grep -q 'answers again' "$T/kill.err"
ok $? "the server killed mid-run and back 1 s later: exit $rc, render_waits $(key "$T/kill" render_waits), the outage said once ($(grep -c 'does not answer' "$T/kill.err")) and its end, $after bytes fetched after the restart"
stop_server

# summary.json grid_point_psnr_min: a still path at the middle grid point,
# looking along +x; the check renders each of the point's baked axes there
# and compares them with the baked views (the issue's bound: 38 dB)
python3 - "$MID" >"$T/mid.path" <<'EOF'
import sys
x, y, z = (float(v) for v in sys.argv[1].split(','))
for t in (0, 1):
    print(t, repr(x), repr(y), repr(z), repr(x + 1), repr(y), repr(z))
EOF
rm -rf "$T/gp"
"$BIN/hlod-bench" "$T/city.hlod" --path "$T/mid.path" --method lumigraph --repo "$T/repo" \
    --width 160 --height 120 --frames 30 --jitter-frames 0 --no-plots --out "$T/gp" 2>"$T/gp.err" >/dev/null
rc=$?
gp=$(key "$T/gp" grid_point_psnr_min) gn=$(key "$T/gp" grid_point_checks)
[ $rc -eq 0 ] && [ "${gn:-0}" -ge 3 ] && perl -e 'exit !($ARGV[0] >= 38)' "$gp"
ok $? "grid_point_psnr_min: $gp dB over $gn views at the middle grid point (exit $rc)"

# on demand: the half repository, views of shard 2 missing
start_server "$T/half" --store "$T/city.hlod"
before=$(find "$T/half/views" -name '*.hlv' | wc -l)
curl -sf "$URL/answer?p=$MID&d=1,0,0&have=0" -o "$T/a4" && records "$T/a4" >"$T/a4.txt"
after=$(find "$T/half/views" -name '*.hlv' | wc -l)
missing_now=$(python3 - "$T/half/repo.hlg" <<'EOF'
import sys
b = open(sys.argv[1], 'rb').read()
print(sum(1 for s in b[112:] if s == 0))
EOF
)
! grep -q bad "$T/a4.txt" && [ "$after" -gt "$before" ] && [ "$(wc -l <"$T/a4.txt")" -ge "$n1" ]
ok $? "--store: views missing from the repository rendered on demand ($before files before, $after after; $missing_now views still missing in the index)"
stop_server

mkdir -p "$T/empty"
"$BIN/hlod-lumigraph-serve" "$T/empty" --port 0 >/dev/null 2>"$T/empty.err"
rc=$?
[ $rc = 1 ] && grep -q "repo.hlg" "$T/empty.err"
ok $? "a folder without an index: exit $rc, $(head -1 "$T/empty.err" | cut -c1-100)"

echo "$pass passed, $fail failed"
[ "$fail" -eq 0 ]
