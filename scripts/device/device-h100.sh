#!/usr/bin/env bash
# One lease of a GPU device machine (an NVIDIA H100 through Vulkan), as one prepared script: the
# GPU test suite on the hardware adapter, `mipnerf bench` on it and on its CPU, and
# experiments/fern-gpu trained there. The machine has no Rust toolchain and reaches no network, so
# everything it runs is built here and travels in the ignored folders `.dev` and `.gl`:
#
#   .gl/*.deb          the Vulkan loader (Debian's libvulkan1 and friends, `apt-get download`)
#   .dev/bin.tar.xz    stripped release builds: `mipnerf` and the test binaries of mipnerf-gpu
#                      (`cargo test --release -p mipnerf-gpu --no-run`), named by test target
#   .dev/fern/         ../shared/data/llff/fern's images_8 and poses_bounds.npy
#
# The binaries carry this checkout's absolute paths (the tests find their data through
# CARGO_MANIFEST_DIR, experiment runs store their data's path), so the script links /work/main
# and /work/shared/data/llff/fern to the copies there. Results go to $OUT (at most 8 files).
set -u
OUT=${OUT:?set OUT to the folder results go to}
stamp() { echo "== $(date -u +%T) $*"; }

# DRY=1: a rehearsal on this machine (no loader unpacked, every step cut to 15 s).
if [ -z "${DRY:-}" ]; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
else
    timeout() { shift; command timeout 15 "$@"; }
fi
mkdir -p /tmp/dev && tar -C /tmp/dev -xJf .dev/bin.tar.xz
B=/tmp/dev/bin
mkdir -p /work /work/shared/data/llff
[ -e /work/main ] || ln -s "$PWD" /work/main
[ -e /work/shared/data/llff/fern ] || ln -s "$PWD/.dev/fern" /work/shared/data/llff/fern

{
    stamp machine
    nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.max.sm --format=csv
    lscpu | grep -E "Model name|^CPU\(s\)|Flags" | sed 's/Flags:.*\(avx512_bf16\).*/Flags: ... avx512_bf16 .../'
    nproc
    stamp adapters
    "$B/mipnerf" info
} >"$OUT/machine.txt" 2>&1
if ! grep -qi "nvidia" "$OUT/machine.txt"; then
    for icd in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json /etc/vulkan/icd.d/nvidia_icd.json; do
        [ -f "$icd" ] && export VK_DRIVER_FILES=$icd && break
    done
    { stamp "adapters again, VK_DRIVER_FILES=${VK_DRIVER_FILES:-none found}"; "$B/mipnerf" info; } >>"$OUT/machine.txt" 2>&1
fi
cat "$OUT/machine.txt"

# The GPU tests, as CI runs them (CI=true: a test that finds no adapter fails), each from its
# package's folder as cargo would; 150 s in all at most.
{
    for t in shaders select robustness kernel_cast_ipe kernel_mlp kernel_render kernel_adam kernel_sample kernel_model kernel_occupancy backend both_backends; do
        stamp "test $t"
        (cd crates/mipnerf-gpu && CI=true timeout 60 "$B/$t" 2>&1)
        echo "exit status of $t: $?"
    done
} >"$OUT/tests.log" 2>&1
grep -E "^== |test result|exit status|FAILED|panicked" "$OUT/tests.log"

# Throughput: the GPU at a batch that fills more of it, and GPU beside this machine's CPU at the
# README's small-preset batch.
{
    stamp "bench gpu 4096"
    timeout 90 "$B/mipnerf" bench --backend gpu --preset tiny,small,paper,fast --batch-rays 4096 --steps 20 --render-side 256
    stamp "bench both 1024"
    timeout 60 "$B/mipnerf" bench --backend both --preset small --batch-rays 1024 --steps 10 --render-side 64
} >"$OUT/bench.md" 2>&1
cat "$OUT/bench.md"

# Fern: the two rows of experiments/fern-gpu, 2.5 minutes each, evaluated on the GPU without LPIPS.
stamp "fern"
timeout 420 "$B/mipnerf" experiment experiments/fern-gpu --data /work/shared/data/llff/fern --out runs/fern-gpu --no-lpips \
    >"$OUT/fern.log" 2>&1
echo "experiment exit status: $?" >>"$OUT/fern.log"
grep -E "^== |table|exit status|error" "$OUT/fern.log"
for row in fast fast-b8192; do
    [ -d "runs/fern-gpu/$row" ] && tar -cf - "runs/fern-gpu/$row" | xz -1 >"$OUT/run-$row.tar.xz"
done
tar -cf "$OUT/results.tar" docs/results/fern/gpu-h100 2>/dev/null
stamp done
ls -la "$OUT"
