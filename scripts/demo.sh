#!/usr/bin/env bash
# The main job: build mipnerf, show the adapters it sees, and prove the GPU kernels against the CPU
# reference on this machine. (Training and rendering the built-in demo scene join here as the
# `mipnerf demo` command lands.) Installs a Vulkan driver first if none is present.
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
bash scripts/ensure-vulkan.sh
cargo build --release --locked -p mipnerf-cli
./target/release/mipnerf info
./target/release/mipnerf check --backend gpu
