# Sourced by scripts/bench/bench-alternate.sh and scripts/bench/train-alternate.sh: `alternate BEFORE AFTER
# OUT ROUNDS RUN` writes OUT/lscpu.txt (the CPU and its bf16 features), then calls `RUN BINARY
# OUT_FILE` for the before and the after binary in turn, ROUNDS times, so that a shared machine's
# drift falls on both alike; OUT_FILE is OUT/{before,after}-N.txt.
alternate() {
    local before=$1 after=$2 out=$3 rounds=$4 run=$5 i which bin
    lscpu | grep -E "^(Model name|CPU\(s\)|Vendor ID)" > "$out/lscpu.txt"
    grep -o -w -E "avx512_bf16|amx_tile|amx_bf16" /proc/cpuinfo | sort -u >> "$out/lscpu.txt" || true
    for i in $(seq 1 "$rounds"); do
        local order="before after"
        [ $((i % 2)) = 0 ] && order="after before"
        for which in $order; do
            bin=$before; [ "$which" = after ] && bin=$after
            echo "$(date -u +%H:%M:%S) $which $i" >&2
            "$run" "$bin" "$out/$which-$i.txt"
        done
    done
}
