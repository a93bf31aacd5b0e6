#!/usr/bin/env bash
# One lease of a GPU device machine for the Tri-Mip field's GPU backend, as one prepared script
# (what scripts/device/device-tri-mip-prepare.sh made travels in `.dev` and `.gl`): the field's GPU tests
# on the hardware adapter, `mipnerf bench` of both fields there at 1,024 and 4,096 rays a step,
# the occupancy grid's update on the host against the device's, and fern's curve towards NeRF's 25.17 dB with `--backend gpu --field tri-mip`
# (experiments/tri-mip-fern-gpu, its 4,096-ray row: 5 minutes, copies each minute). About 8
# minutes; results go to $OUT.
#
# DRY=1: a rehearsal on this machine (no loader unpacked, the tests and bench cut short, the
# fern row's budget as it is but interrupted after 60 s).
set -u
OUT=${OUT:?set OUT to the folder results go to}
. scripts/device/device-lib.sh
if [ -z "${DRY:-}" ]; then
    device_setup .dev/tri-mip.tar.xz
    limit=1
else
    mkdir -p /tmp/dev && tar -C /tmp/dev -xJf .dev/tri-mip.tar.xz
    limit=0
fi
B=/tmp/dev/bin
cap() { if [ "$limit" = 1 ]; then echo "$1"; else echo 20; fi; }
[ -e /work/shared/data/llff/fern ] || { mkdir -p /work/shared/data/llff && ln -s "$PWD/.dev/fern" /work/shared/data/llff/fern; }

machine_info "$B"

# The field's GPU tests as CI runs them (CI=true: no adapter is a failure), from the package's
# folder as cargo would; 120 s in all at most.
{
    for t in shaders tri_mip kernel_mlp kernel_occupancy backend occupancy_update; do
        stamp "test $t"
        (cd crates/mipnerf-gpu && CI=true timeout "$(cap 40)" "$B/$t" 2>&1)
        echo "exit status of $t: $?"
    done
} >"$OUT/tests.log" 2>&1
grep -E "^== |test result|exit status|FAILED|panicked" "$OUT/tests.log"

# Both fields, both batches; the dispatch table comes with each.
{
    for rays in 1024 4096; do
        stamp "bench $rays"
        timeout "$(cap 45)" "$B/mipnerf" bench --backend gpu --preset fast --field mip-nerf,tri-mip --batch-rays "$rays" --steps 20 --render-side 128
    done
} >"$OUT/bench.md" 2>&1
cat "$OUT/bench.md"

# The occupancy grid's update: the host's (parameters read back, the CPU's field) against the
# device's (docs/results/tri-mip/gpu/grid-update-lavapipe.txt is lavapipe's).
stamp "grid update"
(cd crates/mipnerf-gpu && timeout "$(cap 60)" "$B/grid_update" --bench) >"$OUT/grid-update.md" 2>&1
cat "$OUT/grid-update.md"

stamp "fern"
timeout "$(cap 400)" "$B/mipnerf" experiment experiments/tri-mip-fern-gpu --only tri-mip-b4096 \
    --data /work/shared/data/llff/fern --out runs/tri-mip-fern-gpu --no-lpips >"$OUT/fern.log" 2>&1
echo "experiment exit status: $?" >>"$OUT/fern.log"
grep -E "^== |psnr|PSNR|exit status|error" "$OUT/fern.log" | tail -20
# The run's logs, curves and evaluations; not its checkpoints (38 MB each, over what a lease
# returns: 16 MiB a file).
[ -d runs/tri-mip-fern-gpu ] && tar -cf "$OUT/run-tri-mip-b4096.tar" --exclude='*.safetensors' runs/tri-mip-fern-gpu
tar -cf "$OUT/results.tar" docs/results/tri-mip/fern-gpu 2>/dev/null
stamp done
ls -la "$OUT"
