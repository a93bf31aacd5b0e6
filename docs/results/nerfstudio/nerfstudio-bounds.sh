#!/bin/bash
# The depth bounds `mipnerf colmap` measures on the test capture in nerfstudio's form
# (tests/data/nerfstudio_capture, with the photos of tests/data/colmap_workspaces/opencv) against
# those of the COLMAP workspace it was made from. Usage: docs/results/nerfstudio/nerfstudio-bounds.sh [BINARY]
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
bin=$(realpath "${1:-target/release/mipnerf}")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/capture"
cp tests/data/nerfstudio_capture/transforms.json tests/data/nerfstudio_capture/sparse_pc.ply "$work/capture/"
cp -r tests/data/colmap_workspaces/opencv/images "$work/capture/images"
echo "commit $(git rev-parse --short HEAD); $("$bin" --version)"
for route in "capture $work/capture" "workspace tests/data/colmap_workspaces/opencv"; do
    set -- $route
    line=$("$bin" colmap --input "$2" --output "$work/out-$1" --max-size 0 | grep '^scene bounds')
    echo "$1: $line"
done | tee "$work/lines"
near() { grep "^$1:" "$work/lines" | sed -E 's/.*near ([0-9.]+).*/\1/'; }
far() { grep "^$1:" "$work/lines" | sed -E 's/.*far ([0-9.]+).*/\1/'; }
python3 -c "print(f'capture/workspace: near {$(near capture)/$(near workspace):.4f}, far {$(far capture)/$(far workspace):.4f}')"
