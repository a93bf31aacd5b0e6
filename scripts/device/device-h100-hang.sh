#!/usr/bin/env bash
# The fourth GPU lease's script: the kernels test binary, its 15 tests in parallel as cargo runs
# them, hung on an NVIDIA H100 in two runs of four (a cold and a warm shader cache alike) and
# finished in 3 to 4 s in the others. Up to six runs; the first that runs past 20 s has every
# thread's stack printed (cuda-gdb attaches to a CPU program too) before it is killed.
# Carried: .gl (the Vulkan loader) and .dev/bin3.tar.xz (the test binaries, with symbols).
set -u
OUT=${OUT:?set OUT to the folder results go to}
. scripts/device/device-lib.sh
device_setup .dev/bin3.tar.xz
B=/tmp/dev/bin
cd crates/mipnerf-gpu || exit 1
{
    for i in 1 2 3 4 5 6; do
        CI=true "$B/kernels" >"/tmp/run$i.log" 2>&1 &
        wait_or_stacks $! 20 2000
        status=$?
        echo "run $i: exit status $status, $(grep -c ' ok$' "/tmp/run$i.log") tests ok"
        [ "$status" = 137 ] && break
    done
} >"$OUT/hang.log" 2>&1
grep -E "^run |RAN OVER" "$OUT/hang.log"
grep -cE "^#|^Thread" "$OUT/hang.log"
