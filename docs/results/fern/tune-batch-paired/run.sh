#!/bin/bash
# Paired runs (both at once, one core each) on the tuning copy of fern: the fast preset at its
# 1024 rays a step against 512. Binary: /tmp/s56-acc, built from the code of 18dae2a.
cd /tmp/b512-exp
export RAYON_NUM_THREADS=1
common="--data /tmp/fern-tune --llff-factor 8 --preset fast --seed 0 --backend cpu --time-budget 16m --snapshots 5m --checkpoint-every 200 --log-every 50 --quiet"
taskset -c 0 /tmp/s56-acc train $common --out A > A.log 2>&1 &
taskset -c 1 /tmp/s56-acc train $common --batch-rays 512 --out B > B.log 2>&1 &
wait
echo done > done.txt
