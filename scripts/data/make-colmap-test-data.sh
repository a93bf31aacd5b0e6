#!/bin/bash
# Rebuilds tests/data/colmap_lego with a real COLMAP reconstruction (PyPI's pycolmap, on the CPU).
# Needs ../shared/data/nerf_synthetic/lego and network access to PyPI; takes a few minutes.
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV="${VENV:-$(mktemp -d)/venv}"
python3 -m venv "$VENV"
"$VENV/bin/pip" install -q "pycolmap==4.2.1" numpy pillow
"$VENV/bin/python" scripts/data/make-colmap-test-data.py
