#!/bin/bash
# A COLMAP workspace through both of `mipnerf colmap`'s routes: directly, and as the capture that
# nerfstudio's own colmap_to_json makes of it (scripts/data/make-nerfstudio-capture.sh); prints both
# reports, how many written images differ, and the ratio of the scenes' bounds. Needs network
# access to PyPI.
# Usage: docs/results/nerfstudio/nerfstudio-route.sh WORKSPACE [BINARY]   (e.g. after scripts/data/colmap-photos.sh)
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
ws=$(realpath "$1")
bin=$(realpath "${2:-target/release/mipnerf}")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
bash scripts/data/make-nerfstudio-capture.sh "$ws" "$work/capture"
ln -s "$ws/images" "$work/capture/images"
echo "commit $(git rev-parse --short HEAD); $("$bin" --version)"
echo "## the capture (transforms.json and sparse_pc.ply by nerfstudio, the workspace's images/)"
"$bin" colmap --input "$work/capture" --output "$work/from-capture" 2>&1 | tee "$work/capture.txt"
echo "## the workspace"
"$bin" colmap --input "$ws" --output "$work/from-workspace" 2>&1 | tee "$work/workspace.txt"
differ=0 total=0
for f in "$work"/from-workspace/images_*/*.png; do
    total=$((total + 1))
    cmp -s "$f" "$work/from-capture/$(basename "$(dirname "$f")")/$(basename "$f")" || differ=$((differ + 1))
done
echo "## written images that differ between the routes: $differ of $total"
bound() { grep '^scene bounds' "$work/$1.txt" | sed -E "s/.*$2 ([0-9.]+).*/\\1/"; }
python3 -c "print(f'## bounds, capture/workspace: near {$(bound capture near)/$(bound workspace near):.4f}, far {$(bound capture far)/$(bound workspace far):.4f}')"
