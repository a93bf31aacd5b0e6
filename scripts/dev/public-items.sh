#!/usr/bin/env bash
# Public items of each library crate (mipnerf-core, mipnerf-data, mipnerf-gpu, the facade mipnerf), hidden ones
# included, from rustdoc's JSON (an unstable rustdoc output, enabled on the stable toolchain with
# RUSTC_BOOTSTRAP=1; it builds into target/public-items, not the normal target folder). Counts
# every item reachable from the crate root through public modules, re-exports, inherent methods,
# fields and variants, each once (scripts/dev/public-items.py). Compare them before and after an API change.
set -euo pipefail
cd "$(dirname "$0")/../.."
export CARGO_TARGET_DIR=target/public-items
for p in mipnerf-core mipnerf-data mipnerf-gpu mipnerf; do
    RUSTC_BOOTSTRAP=1 cargo rustdoc -q -p "$p" --lib -- -Z unstable-options --output-format json --document-hidden-items
done
echo "# public items ($(git rev-parse --short HEAD)$(git diff --quiet HEAD || echo -dirty)): scripts/dev/public-items.sh"
python3 scripts/dev/public-items.py "$CARGO_TARGET_DIR"/doc/mipnerf_core.json "$CARGO_TARGET_DIR"/doc/mipnerf_gpu.json "$CARGO_TARGET_DIR"/doc/mipnerf.json
