#!/bin/bash
# Evaluate both rows of the pair and their 5-minute snapshots with LPIPS (the scratch binary reads B's two-MLP shape from the env).
cd /tmp/eh-coarse
export MIPNERF_LPIPS_WEIGHTS=/work/shared/models/lpips
for run in A/snapshots/00300s A; do /tmp/s56-coarse eval --run $run --backend cpu > eval-$(echo $run | tr / -).log 2>&1; done
for run in B/snapshots/00300s B; do MIPNERF_SCRATCH_COARSE=2,64,32,0,1 /tmp/s56-coarse eval --run $run --backend cpu > eval-$(echo $run | tr / -).log 2>&1; done
echo done > eval-done.txt
