#!/usr/bin/env bash
# The second GPU lease's script: what the first (scripts/device/device-h100.sh) found on an NVIDIA H100.
# - The kernels tests ran past 60 s there with none finishing (15 s on lavapipe): each test alone
#   here, 10 s at most, and when one runs over, every thread's stack (cuda-gdb attaches to a CPU
#   program too) before it is killed.
# - supersampled_nerf_trains_and_renders_alike differed from the CPU by 1.2e-3 and 2.3e-3 in its
#   fine level's loss: three runs with each step's differences printed, to tell rounding (the same
#   each time) from a race (different each time).
# Carried: .gl (the Vulkan loader) and .dev/bin2.tar.xz (the two test binaries with symbols).
set -u
OUT=${OUT:?set OUT to the folder results go to}
. scripts/device/device-lib.sh
device_setup .dev/bin2.tar.xz
B=/tmp/dev/bin
cd crates/mipnerf-gpu || exit 1

{
    for t in $("$B/kernels" --list --format terse 2>/dev/null | sed 's/: test$//'); do
        stamp "kernels $t"
        CI=true "$B/kernels" --exact "$t" --nocapture --test-threads=1 >/tmp/one.log 2>&1 &
        wait_or_stacks $! 10 2000
        echo "exit status $?"
        grep -E "max \||test result|panicked|values out of|: gpu|: the kernel" /tmp/one.log | head -30
    done
} >"$OUT/kernels.log" 2>&1
grep -E "^== |RAN OVER|exit status|test result" "$OUT/kernels.log"

{
    for i in 1 2 3; do
        stamp "supersampled run $i"
        CI=true timeout 30 "$B/backend" --exact supersampled_nerf_trains_and_renders_alike --nocapture 2>&1 | grep -E "supersampled NeRF|test result|: gpu"
    done
    stamp "kernels all at once, 30 s"
    CI=true timeout 30 "$B/kernels" >/tmp/all.log 2>&1
    echo "exit status $?"
    tail -25 /tmp/all.log
} >"$OUT/backend.log" 2>&1
cat "$OUT/backend.log"
stamp done
