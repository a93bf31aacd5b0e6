#!/bin/bash
# Scratch experiment: /tmp/s56-coarse is 18dae2a with docs/results/fern/tune-coarse-mlp/scratch.patch applied,
# /tmp/eh-tune the tuning copy of ethiopian_head (scripts/data/make-tuning-split.py ... 4); both rows at once, one core each.
cd /tmp/eh-coarse
export RAYON_NUM_THREADS=1
common="--data /tmp/eh-tune --llff-factor 4 --preset fast --unbounded --seed 0 --backend cpu --time-budget 16m --snapshots 5m --checkpoint-every 200 --log-every 50 --quiet"
taskset -c 0 /tmp/s56-coarse train $common --out A > A.log 2>&1 &
MIPNERF_SCRATCH_COARSE=2,64,32,0,1 taskset -c 1 /tmp/s56-coarse train $common --two-mlps --out B > B.log 2>&1 &
wait
echo done > done.txt
