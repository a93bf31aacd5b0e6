#!/bin/bash
# Scratch experiment of docs/results/fern/tune-coarse-mlp: /tmp/s56-coarse is 18dae2a with scratch.patch applied,
# /tmp/fern-tune the tuning copy of fern (scripts/data/make-tuning-split.py); both rows at once, one core each.
cd /tmp/coarse-exp
export RAYON_NUM_THREADS=1
common="--data /tmp/fern-tune --llff-factor 8 --preset fast --seed 0 --backend cpu --time-budget 16m --snapshots 5m --checkpoint-every 200 --log-every 50 --quiet"
taskset -c 0 /tmp/s56-coarse train $common --out A > A.log 2>&1 &
MIPNERF_SCRATCH_COARSE=2,64,32,0,1 taskset -c 1 /tmp/s56-coarse train $common --two-mlps --out B > B.log 2>&1 &
wait
echo done > done.txt
