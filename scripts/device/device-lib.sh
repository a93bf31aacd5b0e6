#!/usr/bin/env bash
# Shared by the scripts/device-h100*.sh scripts (sourced): what a bare GPU lease machine needs
# before the carried binaries run, and stacks of a program that runs too long.

# A timestamped heading in a log.
stamp() { echo "== $(date -u +%T) $*"; }

# Unpacks the carried Vulkan loader (.gl/*.deb) and the carried binaries ($1, a .tar.xz of bin/)
# into /tmp/dev/bin, and links /work/main to this checkout: the test binaries find their data
# through the CARGO_MANIFEST_DIR they were built with here.
device_setup() {
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    mkdir -p /tmp/dev && tar -C /tmp/dev -xJf "$1"
    mkdir -p /work
    [ -e /work/main ] || ln -s "$PWD" /work/main
}

# Waits up to $2 seconds for process $1; if it still runs, prints every thread's stack (cuda-gdb
# attaches to a CPU program too; at most $3 lines) and kills it. Returns its exit status.
wait_or_stacks() {
    local pid=$1 quarters=$(($2 * 4))
    for _ in $(seq "$quarters"); do
        sleep 0.25
        kill -0 "$pid" 2>/dev/null || break
    done
    if kill -0 "$pid" 2>/dev/null; then
        echo "RAN OVER $2 s: stacks"
        timeout 45 cuda-gdb -p "$pid" -batch -ex "info threads" -ex "thread apply all bt 24" 2>&1 |
            grep -vE "^\[New Thread|^warning: " | head -"$3"
        kill -9 "$pid"
    fi
    wait "$pid"
}

# Writes what the machine is to $OUT/machine.txt (the GPU, the CPU, the adapters `$1/mipnerf`
# sees) and prints it; where no NVIDIA adapter shows, points the Vulkan loader at the NVIDIA
# driver's manifest and lists the adapters again.
machine_info() {
    local bin=$1
    {
        stamp machine
        nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv 2>&1
        lscpu | grep -E "Model name|^CPU\(s\)"
        stamp adapters
        "$bin/mipnerf" info
    } >"$OUT/machine.txt" 2>&1
    if ! grep -qi "nvidia" "$OUT/machine.txt"; then
        for icd in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json; do
            [ -f "$icd" ] && export VK_DRIVER_FILES=$icd && break
        done
        { stamp "adapters again, VK_DRIVER_FILES=${VK_DRIVER_FILES:-none found}"; "$bin/mipnerf" info; } >>"$OUT/machine.txt" 2>&1
    fi
    cat "$OUT/machine.txt"
}
