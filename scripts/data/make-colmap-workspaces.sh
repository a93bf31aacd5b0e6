#!/bin/bash
# Rebuilds tests/data/colmap_workspaces (or, with `bar OUT`, the 400 px measurement workspace) with
# real COLMAP reconstructions (PyPI's pycolmap, on the CPU). Needs ../shared/data/nerf_synthetic/lego
# and network access to PyPI; takes a few minutes per camera model.
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV="${VENV:-$(mktemp -d)/venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/pip" install -q "pycolmap==4.2.1" numpy pillow
GLOG_minloglevel="${GLOG_minloglevel:-1}" "$VENV/bin/python" scripts/data/make-colmap-workspaces.py "$@"
