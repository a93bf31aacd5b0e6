#!/usr/bin/env bash
# Behaviour fingerprint of a mipnerf binary: the SHA-256 of the checkpoints of 20-step runs on the
# demo scene (Mip-NeRF tiny, fast, small and paper presets in f32, fast, small and paper in bf16 on each kernel the CPU
# has, and the NeRF baseline on the CPU, tiny and fast on the
# GPU backend where an adapter is found, lavapipe included), and of the demo's rendered PNGs. A refactor that must not change
# behaviour gives the same lines before and after:
#   scripts/dev/fingerprint.sh OLD_BINARY > before.txt; scripts/dev/fingerprint.sh target/release/mipnerf > after.txt
#   diff before.txt after.txt
set -euo pipefail
bin=$(realpath "${1:-target/release/mipnerf}")
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
q=(--quiet)
"$bin" demo --out "$dir/demo" --steps 20 --size 32 --views 8 --preset tiny --backend cpu --seed 0 >/dev/null 2>&1
data="$dir/demo/data"
run() { # name, then train flags
    local name=$1; shift
    "$bin" train --data "$data" --out "$dir/$name" --steps 20 --batch-rays 256 --seed 0 "${q[@]}" "$@" >/dev/null 2>&1
    echo "$name $(sha256sum < "$dir/$name/checkpoint.safetensors" | cut -d' ' -f1)"
}
echo "demo-mipnerf $(sha256sum < "$dir/demo/checkpoint.safetensors" | cut -d' ' -f1)"
echo "demo-nerf $(sha256sum < "$dir/demo/nerf/checkpoint.safetensors" | cut -d' ' -f1)"
# The demo's renders of the test views (colour and depth PNGs) and of its orbit.
echo "demo-renders $(cd "$dir/demo" && find render render_orbit -name '*.png' | sort | xargs sha256sum | sha256sum | cut -d' ' -f1)"
run tiny-cpu --preset tiny --backend cpu
run fast-cpu --preset fast --backend cpu --precision f32
run small-cpu --preset small --backend cpu --precision f32
run paper-cpu --preset paper --backend cpu --precision f32
run nerf-cpu --model nerf --preset tiny --backend cpu
# bf16 on each kernel this CPU has (AMX, then AVX-512 BF16 with AMX switched off): the hashes
# depend on the kernel (its order of f32 additions), so compare them on one machine.
flags=$(grep -o -w -E "amx_tile|amx_bf16|avx512_bf16" /proc/cpuinfo | sort -u | tr '\n' ' ')
if [[ $flags == *avx512_bf16* ]]; then
    for preset in fast small paper; do run "$preset-bf16" --preset "$preset" --backend cpu --precision bf16; done
    if [[ $flags == *amx_bf16* && $flags == *amx_tile* ]]; then
        for preset in fast small; do
            MIPNERF_DISABLE_AMX=1 run "$preset-bf16-avx512" --preset "$preset" --backend cpu --precision bf16
        done
    fi
else
    echo "no avx512_bf16 on this CPU: bf16 runs skipped" >&2
fi
adapters=$("$bin" info 2>/dev/null || true)
if grep -q "^  \[0\]" <<<"$adapters"; then
    run tiny-gpu --preset tiny --backend gpu
    run fast-gpu --preset fast --backend gpu
else
    echo "no GPU adapter: GPU runs skipped" >&2
fi
