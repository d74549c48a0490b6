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
