# lib.sh - what the shell tests share (sourced): the pass and fail counts
# and ok(), which prints one check.
pass=0
fail=0

# ok STATUS TEXT: one check, passed when STATUS is 0; returns STATUS.
ok() {
    if [ "$1" -eq 0 ]; then
        pass=$((pass + 1))
        echo "ok   $2"
    else
        fail=$((fail + 1))
        echo "FAIL $2"
    fi
    return "$1"
}

# free_port N: prints a TCP port P such that P .. P + N - 1 are free on
# this machine (0 when 50 tries found none).
free_port() {
    local n=${1:-1} p k busy
    for try in $(seq 50); do
        p=$((20000 + RANDOM % 30000))
        busy=0
        for k in $(seq 0 $((n - 1))); do
            ss -ltn | awk '{print $4}' | grep -Eq ":$((p + k))\$" && busy=1
        done
        [ $busy -eq 0 ] && { echo "$p"; return 0; }
    done
    echo 0
}

# waits_ok N FRAMES: a run's render_waits N over FRAMES frames is allowed:
# 0, or under the sanitizers (HLOD_SANITIZED=1) 1 + FRAMES / 200, their
# allocator's locks (docs/testing.md).  A missing or non-numeric N fails.
waits_ok() {
    case $1 in '' | *[!0-9]*) return 1 ;; esac
    case $2 in '' | *[!0-9]*) return 1 ;; esac
    if [ "${HLOD_SANITIZED:-0}" = 1 ]; then
        [ "$1" -le $((1 + $2 / 200)) ]
    else
        [ "$1" -eq 0 ]
    fi
}
