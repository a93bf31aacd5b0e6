#!/bin/bash
# The whole-scene sampler of ethiopian_head compared at equal steps on photos held out
# from the *training* photos (never the 9 test photos): a tuning copy without the test photos
# (scripts/data/make-tuning-split.py), whose own every-8th photos are held out. Each row trains the fast
# preset for 2000 steps and is evaluated without LPIPS; the PSNR lands in docs/results/ethiopian-head/tune/ROW.json.
# Equal steps, not equal time, so a busy machine changes the wall time and not the numbers.
#
# Rows ending in 6k train 6000 steps instead (the distortion loss acts against floaters, which
# grow late).
#
# Usage: bash docs/results/ethiopian-head/tune/ethiopian-head-tune.sh [ROW ...]
#   rows: before ub16 ubocc ubdist ubdist10 ubocc6k ubdist6k; default: the first three
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
data=../shared/data/real/ethiopian_head
[ -d "$data" ] || { echo "skipped: $data is absent"; exit 0; }
tune=${TMPDIR:-/tmp}/eh-tune
[ -d "$tune" ] || python3 scripts/data/make-tuning-split.py "$data" 4 "$tune"
cargo build --release -p mipnerf-cli
mkdir -p runs/eh-tune docs/results/ethiopian-head/tune
row() {
    local name=$1; shift
    local steps=2000
    [[ $name == *6k ]] && steps=6000
    rm -rf "runs/eh-tune/$name"
    target/release/mipnerf train --data "$tune" --llff-factor 4 --preset fast --backend cpu --seed 0 --steps $steps "$@" \
        --out "runs/eh-tune/$name"
    target/release/mipnerf eval --run "runs/eh-tune/$name" --backend cpu --no-lpips --quiet
    cp "runs/eh-tune/$name/eval/metrics.json" "docs/results/ethiopian-head/tune/$name.json"
}
rows=("$@")
[ ${#rows[@]} -gt 0 ] || rows=(before ub16 ubocc)
for name in "${rows[@]}"; do
    case $name in
        before) row before --spherify ;;
        ub16) row ub16 --unbounded --no-occupancy ;;
        ubocc|ubocc6k) row "$name" --unbounded ;;
        ubdist|ubdist6k) row "$name" --unbounded --distortion-loss 0.01 ;;
        ubdist10) row ubdist10 --unbounded --distortion-loss 0.1 ;;
        *) echo "unknown row $name"; exit 2 ;;
    esac
done
