#!/usr/bin/env bash
# The whole test suite, as CI runs it: formatting, lints, and every test (GPU tests included, on
# lavapipe where there is no hardware GPU). Installs a Vulkan driver first if none is present, and
# in CI headless Chromium for the browser test of eval's page.
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
start=$(date +%s)
bash scripts/ensure-vulkan.sh
bash scripts/ensure-chromium.sh
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --all-targets --locked
echo "== the CPU-only facade (mipnerf without its gpu feature: no wgpu compiled)"
cargo clippy -p mipnerf --no-default-features --all-targets --locked -- -D warnings
cargo test -p mipnerf --no-default-features --locked
echo "== cargo doc (warnings are errors)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked
echo "== doc tests"
cargo test --workspace --doc --locked
echo "== test suite finished in $(( $(date +%s) - start )) s"
