#!/usr/bin/env bash
# test_slurm.sh - a sharded build as a Slurm job array and a merge job that
# depends on it (docs/sharded-builds.md; issue 20), on a single-node
# cluster this test starts from Debian's packages (munge, slurmctld,
# slurmd, slurm-client) in a temporary folder: its own munge key and
# socket, a slurm.conf it writes (free ports, state, spool and logs in the
# folder, proctrack/linuxproc, no accounting), both daemons stopped at the
# end.  Checks:
#   - the cluster comes up: sinfo shows the node idle;
#   - sbatch --array=1-3 of a shard script (hlod-build --shard
#     $SLURM_ARRAY_TASK_ID/3) and sbatch --dependency=afterok of a merge
#     script (hlod-merge): every array task and the merge end COMPLETED, and
#     the store is byte-identical (cmp) to hlod-build without --shard;
#   - a failed array (task 2 given a missing input): its merge job never
#     runs (Reason=DependencyNeverSatisfied), no store is written.
# The daemons' logs are printed on a failure.
# Env: HLOD_BIN_DIR (the tools), HLOD_SOURCE_DIR.
set -uo pipefail
BIN=${HLOD_BIN_DIR:-build/bin}
BIN=$(cd "$BIN" && pwd)
. "$(dirname "$0")/lib.sh"

for cmd in munged slurmctld slurmd sbatch squeue scontrol sinfo; do
    if ! command -v "$cmd" >/dev/null 2>&1 && [ ! -x "/usr/sbin/$cmd" ]; then
        echo "FAIL $cmd is not installed (data/setup.sh installs munge, slurmctld, slurmd, slurm-client)"
        exit 1
    fi
done
export PATH=$PATH:/usr/sbin
T=$(mktemp -d "${TMPDIR:-/tmp}/hlod-test-slurm.XXXXXX")
chmod 755 "$T"
cleanup() {
    [ -f "$T/slurm.conf" ] && SLURM_CONF=$T/slurm.conf scontrol shutdown >/dev/null 2>&1
    for f in slurmctld.pid slurmd.pid munged.pid; do
        [ -f "$T/$f" ] && kill "$(cat "$T/$f")" 2>/dev/null
    done
    sleep 1
    for f in slurmctld.pid slurmd.pid munged.pid; do
        [ -f "$T/$f" ] && kill -9 "$(cat "$T/$f")" 2>/dev/null
    done
    rm -rf "$T"
}
trap cleanup EXIT
logs() {
    for f in "$T"/log/*; do
        echo "---- $f"
        tail -20 "$f"
    done
}

# a free TCP port pair: PORT and PORT + 1
port=$(free_port 2)
mkdir -p "$T/state" "$T/spool" "$T/log" "$T/parts" "$T/bad"
H=$(hostname -s)
ME=$(id -un)

# ---- the cluster ----
dd if=/dev/urandom of="$T/munge.key" bs=1024 count=1 2>/dev/null
chmod 600 "$T/munge.key"
munged -f --socket="$T/munge.sock" --key-file="$T/munge.key" --log-file="$T/log/munged.log" \
    --pid-file="$T/munged.pid" --seed-file="$T/munged.seed"
cat >"$T/slurm.conf" <<EOF
ClusterName=hlodtest
SlurmctldHost=$H(127.0.0.1)
SlurmUser=$ME
SlurmdUser=$ME
SlurmctldPort=$port
SlurmdPort=$((port + 1))
AuthType=auth/munge
AuthInfo=socket=$T/munge.sock
CredType=cred/munge
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/slurmctld.pid
SlurmdPidFile=$T/slurmd.pid
SlurmctldLogFile=$T/log/slurmctld.log
SlurmdLogFile=$T/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=600
KillWait=5
Waittime=0
NodeName=$H NodeAddr=127.0.0.1 CPUs=$(nproc) State=UNKNOWN
PartitionName=hlod Nodes=$H Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
EOF
export SLURM_CONF=$T/slurm.conf
slurmctld -c -f "$SLURM_CONF" && slurmd -f "$SLURM_CONF" -N "$H"
up=1
for i in $(seq 60); do
    sinfo -h -o "%t" 2>/dev/null | grep -q idle && { up=0; break; }
    sleep 0.5
done
ok $up "single-node Slurm cluster up on ports $port-$((port + 1)): $(sinfo -h -o '%P %t %N' 2>/dev/null)"
[ $up -eq 0 ] || { logs; echo "$pass passed, $fail failed"; exit 1; }

# ---- the build ----
"$BIN/hlod-gen-city" --preset small -o "$T/city.obj" >/dev/null 2>&1 &&
    "$BIN/hlod-build" "$T/city.obj" -o "$T/single.hlod" --desired-tris 450 --quiet
ok $? "the small city and its single build"

# jobs DIR INPUT2: the array job (task 2 reads INPUT2) and its merge job;
# prints "ARRAY MERGE"
jobs() {
    local dir=$1 input2=$2
    cat >"$dir/shard.sh" <<EOF
#!/bin/bash
#SBATCH --array=1-3
#SBATCH --output=$dir/shard-%a.out
in=$T/city.obj
[ "\$SLURM_ARRAY_TASK_ID" = 2 ] && in=$input2
exec "$BIN/hlod-build" "\$in" -o "$dir/\$SLURM_ARRAY_TASK_ID.part" --desired-tris 450 \\
    --threads 1 --quiet --shard "\$SLURM_ARRAY_TASK_ID/3"
EOF
    cat >"$dir/merge.sh" <<EOF
#!/bin/bash
#SBATCH --output=$dir/merge.out
exec "$BIN/hlod-merge" "$dir"/*.part -o "$dir/city.hlod" --quiet
EOF
    local a m
    a=$(sbatch --parsable "$dir/shard.sh") || return 1
    m=$(sbatch --parsable --dependency="afterok:$a" "$dir/merge.sh") || return 1
    echo "$a $m"
}
# state JOB: its JobState (each task's, one per line, for an array)
state() { scontrol show job "$1" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p'; }
reason() { scontrol show job "$1" 2>/dev/null | sed -n 's/.*Reason=\([A-Za-z_]*\).*/\1/p'; }
# wait_for JOB STATES: until the job is in one of STATES (a regex), 120 s at most
wait_for() {
    for i in $(seq 240); do
        state "$1" | grep -Eq "^($2)\$" && return 0
        sleep 0.5
    done
    return 1
}

read -r A M < <(jobs "$T/parts" "$T/city.obj")
wait_for "$M" "COMPLETED|FAILED|CANCELLED|TIMEOUT"
[ "$(state "$A" | sort -u)" = COMPLETED ] && [ "$(state "$A" | wc -l)" -eq 3 ] &&
    [ "$(state "$M")" = COMPLETED ] && cmp -s "$T/single.hlod" "$T/parts/city.hlod"
rc=$?
ok $rc "array job $A (3 tasks: $(state "$A" | sort | uniq -c | tr -s ' ' | tr '\n' ' ')) and merge job $M ($(state "$M")) after it: the store is byte-identical to the single build"
[ $rc -eq 0 ] || logs

read -r A M < <(jobs "$T/bad" "$T/missing.obj")
wait_for "$A" "FAILED"
ok_state=1
for i in $(seq 60); do
    [ "$(reason "$M")" = DependencyNeverSatisfied ] && { ok_state=0; break; }
    sleep 0.5
done
[ $ok_state -eq 0 ] && [ ! -e "$T/bad/city.hlod" ] && [ ! -e "$T/bad/2.part" ]
ok $? "a failed array task (2 given a missing input: $(state "$A" | sort | uniq -c | tr -s ' ' | tr '\n' ' ')): merge job $M never runs ($(state "$M"), $(reason "$M")), no store, no part 2"
scontrol cancel "$M" >/dev/null 2>&1 || scancel "$M" 2>/dev/null

echo "$pass passed, $fail failed"
[ $fail -eq 0 ]
