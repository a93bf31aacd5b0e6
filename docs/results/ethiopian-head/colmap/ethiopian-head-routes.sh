#!/bin/bash
# ethiopian_head trained at equal steps from the capture's own poses and from the README's
# COLMAP route (a dataset `mipnerf colmap --max-size 0` wrote from a workspace made by
# scripts/data/colmap-photos.sh), the fast preset --unbounded, seed 0, 3000 steps, evaluated on the 9
# held-out photos without LPIPS; each run's metrics land in docs/results/ethiopian-head/colmap/route-ROW.json.
#
# Usage: bash docs/results/ethiopian-head/colmap/ethiopian-head-routes.sh COLMAP_DATASET
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
data=../shared/data/real/ethiopian_head
[ -d "$data" ] || { echo "skipped: $data is absent"; exit 0; }
colmap=${1:?usage: bash docs/results/ethiopian-head/colmap/ethiopian-head-routes.sh COLMAP_DATASET}
cargo build --release -p mipnerf-cli
for row in capture colmap; do
    case $row in
        capture) args=(--data "$data" --llff-factor 4) ;;
        colmap) args=(--data "$colmap" --llff-factor 1) ;;
    esac
    rm -rf "runs/route-$row"
    target/release/mipnerf train "${args[@]}" --unbounded --preset fast --backend cpu --seed 0 --steps 3000 \
        --out "runs/route-$row"
    target/release/mipnerf eval --run "runs/route-$row" --backend cpu --no-lpips --quiet
    cp "runs/route-$row/eval/metrics.json" "docs/results/ethiopian-head/colmap/route-$row.json"
done
