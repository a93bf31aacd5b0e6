#!/usr/bin/env bash
# The main job: build mipnerf, then generate the built-in demo scene, train on it, evaluate and
# render it (mipnerf demo), in a few minutes on 2 cores. Outputs go to runs/demo (or $1).
# Installs a Vulkan driver first if none is present (the GPU self-check uses it).
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
out="${1:-runs/demo}"
bash scripts/ensure-vulkan.sh
cargo build --release --locked -p mipnerf-cli
./target/release/mipnerf info
./target/release/mipnerf check --backend gpu
./target/release/mipnerf demo --out "$out"
