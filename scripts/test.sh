#!/usr/bin/env bash
# The whole test suite, as CI runs it: formatting, lints, and every test (GPU tests included, on
# lavapipe where there is no hardware GPU). Installs a Vulkan driver first if none is present, and
# in CI headless Chromium for the browser test of eval's page.
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
start=$(date +%s)
# Tests that need a CPU feature this machine lacks (AMX-BF16, AVX-512 BF16) append a line here
# (mipnerf_core::test_support); the summary at the end counts them by feature.
export MIPNERF_SKIP_LOG="$(mktemp -t mipnerf-skips.XXXXXX)"
summarise_skips() {
    if [ -s "$MIPNERF_SKIP_LOG" ]; then
        echo "== skipped for missing CPU features ($(lscpu | sed -n 's/^Model name: *//p')):"
        cut -f1 "$MIPNERF_SKIP_LOG" | sort | uniq -c | while read -r count feature; do
            echo "   $count test(s) need $feature: $(awk -F'\t' -v f="$feature" '$1 == f { print $2 }' "$MIPNERF_SKIP_LOG" | sort -u | paste -sd, - | sed 's/,/, /g')"
        done
    else
        echo "== no test skipped for a missing CPU feature"
    fi
    rm -f "$MIPNERF_SKIP_LOG"
}
trap summarise_skips EXIT
bash scripts/ensure-vulkan.sh
bash scripts/ensure-chromium.sh
echo "== cargo fmt --check"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test"
cargo test --workspace --all-targets --locked
echo "== the CLI and the GPU crate as an app builds them (without the tests' test-support feature)"
cargo clippy -p mipnerf-cli -p mipnerf-gpu --locked -- -D warnings
echo "== the CPU-only facade (mipnerf without its gpu feature: no wgpu compiled)"
cargo clippy -p mipnerf --no-default-features --all-targets --locked -- -D warnings
cargo test -p mipnerf --no-default-features --locked
echo "== cargo doc (warnings are errors)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --locked
echo "== doc tests"
cargo test --workspace --doc --locked
echo "== test suite finished in $(( $(date +%s) - start )) s"
