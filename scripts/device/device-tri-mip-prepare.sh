#!/usr/bin/env bash
# Prepares what scripts/device/device-tri-mip.sh carries to a GPU device machine (which has no Rust
# toolchain and reaches no network), into the ignored folders `.dev` and `.gl`:
#
#   .gl/*.deb              the Vulkan loader (Debian's libvulkan1, `apt-get download`)
#   .dev/tri-mip.tar.xz    stripped release builds: `mipnerf`, the mipnerf-gpu test binaries that
#                          prove the field (tri_mip, backend, kernel_mlp, kernel_occupancy, shaders, occupancy_update)
#                          and the grid_update bench, by target name
#   .dev/fern/             ../shared/data/llff/fern's images_8 and poses_bounds.npy
#
# Then: the device tool's `run` with carry [".dev", ".gl"] and `bash scripts/device/device-tri-mip.sh`.
set -euo pipefail
mkdir -p .gl .dev/bin
(cd .gl && apt-get download libvulkan1 >/dev/null)
cargo build --release -p mipnerf-cli
cp target/release/mipnerf .dev/bin/
# The test binaries, named by target (cargo's names carry a hash).
cargo test --release -p mipnerf-gpu --no-run --message-format=json 2>/dev/null |
    python3 -c '
import json, shutil, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["kind"] == ["test"]:
        if m["target"]["name"] in ("tri_mip", "backend", "kernel_mlp", "kernel_occupancy", "shaders", "occupancy_update"):
            shutil.copy(m["executable"], ".dev/bin/" + m["target"]["name"])
'
# The grid update's bench (the host's update against the device's).
cargo bench -p mipnerf-gpu --bench grid_update --no-run --message-format=json 2>/dev/null |
    python3 -c '
import json, shutil, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["kind"] == ["bench"]:
        shutil.copy(m["executable"], ".dev/bin/" + m["target"]["name"])
'
strip .dev/bin/*
tar -C .dev -cJf .dev/tri-mip.tar.xz bin
rm -rf .dev/bin
mkdir -p .dev/fern
cp -r ../shared/data/llff/fern/images_8 ../shared/data/llff/fern/poses_bounds.npy .dev/fern/
du -sh .gl .dev
