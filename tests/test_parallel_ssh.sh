#!/usr/bin/env bash
# test_parallel_ssh.sh - a sharded build run by GNU parallel over ssh
# (--sshlogin) with a shared folder (docs/sharded-builds.md; issue 20):
# the test starts its own OpenSSH server (Debian openssh-server) on
# 127.0.0.1 with a host key, a client key and a config it writes in a
# temporary folder (no system file is touched), and stops it at the end.
# Checks:
#   - the server is up: ssh runs a command through it;
#   - parallel -S '2/ssh -p PORT -i KEY ... user@127.0.0.1' runs its jobs
#     over ssh: each sees SSH_CONNECTION (a local job would not);
#   - the small city in 3 shards as such jobs (--wd the shared folder,
#     --halt now,fail=1), each asserting it runs over ssh, then hlod-merge:
#     byte-identical (cmp) to hlod-build without --shard;
#   - a shard that fails over ssh (a missing input) fails parallel (exit
#     non-zero), and leaves no part.
# The server's log is printed on a failure.
# Env: HLOD_BIN_DIR (the tools), HLOD_SOURCE_DIR.
set -uo pipefail
BIN=${HLOD_BIN_DIR:-build/bin}
BIN=$(cd "$BIN" && pwd)
. "$(dirname "$0")/lib.sh"

SSHD=$(command -v sshd || echo /usr/sbin/sshd)
for cmd in "$SSHD" ssh ssh-keygen parallel; do
    command -v "$cmd" >/dev/null 2>&1 || {
        echo "FAIL $cmd is not installed (data/setup.sh installs openssh-server, openssh-client, parallel)"
        exit 1
    }
done
T=$(mktemp -d "${TMPDIR:-/tmp}/hlod-test-pssh.XXXXXX")
chmod 755 "$T"
cleanup() {
    [ -f "$T/sshd.pid" ] && kill "$(cat "$T/sshd.pid")" 2>/dev/null
    rm -rf "$T"
}
trap cleanup EXIT

port=$(free_port 1)
ME=$(id -un)
ssh-keygen -q -t ed25519 -N '' -f "$T/host_key" &&
    ssh-keygen -q -t ed25519 -N '' -f "$T/client_key" &&
    cp "$T/client_key.pub" "$T/authorized_keys" && chmod 600 "$T/authorized_keys"
# the privilege separation folder sshd insists on (Debian's is /run/sshd)
[ -d /run/sshd ] || mkdir -p /run/sshd 2>/dev/null
cat >"$T/sshd_config" <<EOF
Port $port
ListenAddress 127.0.0.1
HostKey $T/host_key
AuthorizedKeysFile $T/authorized_keys
PubkeyAuthentication yes
PasswordAuthentication no
KbdInteractiveAuthentication no
PermitRootLogin prohibit-password
StrictModes no
UsePAM no
PidFile $T/sshd.pid
EOF
"$SSHD" -f "$T/sshd_config" -E "$T/sshd.log"
SSH="ssh -p $port -i $T/client_key -o StrictHostKeyChecking=no -o UserKnownHostsFile=/dev/null -o BatchMode=yes -o LogLevel=ERROR"
up=1
for i in $(seq 40); do
    [ "$($SSH "$ME@127.0.0.1" echo up 2>/dev/null)" = up ] && { up=0; break; }
    sleep 0.25
done
ok $up "OpenSSH server on 127.0.0.1:$port: ssh runs a command through it"
if [ $up -ne 0 ]; then
    tail -20 "$T/sshd.log"
    echo "$pass passed, $fail failed"
    exit 1
fi
LOGIN="2/$SSH $ME@127.0.0.1"

over=$(parallel -S "$LOGIN" 'echo ${SSH_CONNECTION:-local}' ::: 1 2 3 | grep -vc local)
[ "$over" = 3 ]
ok $? "parallel --sshlogin runs its jobs over ssh ($over of 3 saw SSH_CONNECTION)"

# the shared folder: every "machine" sees the input and writes its part there
S=$T/shared
mkdir -p "$S/parts"
"$BIN/hlod-gen-city" --preset small -o "$S/city.obj" >/dev/null 2>&1 &&
    "$BIN/hlod-build" "$S/city.obj" -o "$T/single.hlod" --desired-tris 450 --quiet
ok $? "the small city and its single build"

parallel -S "$LOGIN" --wd "$S" --halt now,fail=1 \
    "[ -n \"\$SSH_CONNECTION\" ] && $BIN/hlod-build city.obj -o parts/{}.part --desired-tris 450 --threads 1 --quiet --shard {}/3" \
    ::: 1 2 3 &&
    "$BIN/hlod-merge" "$S"/parts/*.part -o "$S/city.hlod" --quiet &&
    cmp -s "$T/single.hlod" "$S/city.hlod"
ok $? "3 shards as parallel jobs over ssh (--wd the shared folder), merged: byte-identical to the single build"

rm -f "$S"/parts/*.part
parallel -S "$LOGIN" --wd "$S" --halt now,fail=1 \
    "$BIN/hlod-build {} -o parts/bad.part --desired-tris 450 --quiet --shard 1/1" ::: missing.obj \
    >/dev/null 2>&1
rc=$?
[ $rc -ne 0 ] && [ ! -e "$S/parts/bad.part" ]
ok $? "a shard failing over ssh (a missing input) fails parallel (exit $rc), no part"

[ $fail -eq 0 ] || tail -20 "$T/sshd.log"
echo "$pass passed, $fail failed"
[ $fail -eq 0 ]
