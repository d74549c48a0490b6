# ref_psnr.sh - sourced by the bench scripts (not run on its own).
#
# ref_psnr BIN DIR_A DIR_B: the PSNR of every reference frame DIR_A holds
# (frame_*_ref.png, as hlod-bench --save-frames writes them) against the
# frame of the same name in DIR_B (hlod-bench --compare; identical frames
# count as 99 dB).  Prints "MIN MEAN N".
ref_psnr() {
    local bin=$1 a=$2 b=$3 min=1000 sum=0 n=0 f p
    for f in "$a"/frame_*_ref.png; do
        p=$("$bin/hlod-bench" --compare "$f" "$b/$(basename "$f")" |
            sed -n 's/.*"psnr": *\([0-9.e+-]*\|inf\).*/\1/p')
        [ "$p" = inf ] && p=99
        sum=$(echo "$sum + $p" | bc -l)
        n=$((n + 1))
        min=$(echo "if ($p < $min) $p else $min" | bc -l)
    done
    printf '%.2f %.2f %d\n' "$min" "$(echo "$sum / $n" | bc -l)" "$n"
}
