#!/bin/bash
# Rebuilds tests/data/nerfstudio_capture with nerfstudio's own colmap_to_json (PyPI's nerfstudio
# 1.1.5, without its dependencies; see make-nerfstudio-capture.py for the stand-ins), or, given
# WORKSPACE and OUT, writes the capture of another COLMAP workspace to OUT. Needs network access to
# PyPI; takes a minute. Usage: scripts/data/make-nerfstudio-capture.sh [WORKSPACE OUT]
set -euo pipefail
ws=$(realpath "${1:-$(dirname "$0")/../../tests/data/colmap_workspaces/opencv}")
out=$(realpath -m "${2:-$(dirname "$0")/../../tests/data/nerfstudio_capture}")
cd "$(dirname "$0")/../.."
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install -q numpy rich appdirs opencv-python-headless imageio requests packaging
"$work/venv/bin/pip" download -q --no-deps "nerfstudio==1.1.5" -d "$work"
python3 -m zipfile -e "$work"/nerfstudio-1.1.5-py3-none-any.whl "$work/pkg"
"$work/venv/bin/python" scripts/data/make-nerfstudio-capture.py "$work/pkg" "$ws" "$out"
