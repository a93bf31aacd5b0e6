#!/bin/bash
# Camera poses for a folder of photos with PyPI's pycolmap (the README's own-photos step 1), in a
# virtual environment it makes: bash scripts/data/colmap-photos.sh PHOTOS WORKSPACE [FOCAL]. Needs network
# access to PyPI.
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV="${VENV:-$(mktemp -d)/venv}"
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/pip" install -q "pycolmap==4.2.1" pillow
GLOG_minloglevel="${GLOG_minloglevel:-1}" "$VENV/bin/python" scripts/data/colmap-photos.py "$@"
