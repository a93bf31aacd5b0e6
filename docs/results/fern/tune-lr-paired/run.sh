#!/bin/bash
# Paired runs (both at once, one core each) on the tuning copy of fern: the fast preset at its
# learning rate (5e-3) against 1e-2. Binary: /tmp/s56-acc, built from the code of 18dae2a.
cd /tmp/lr-exp
export RAYON_NUM_THREADS=1
common="--data /tmp/fern-tune --llff-factor 8 --preset fast --seed 0 --backend cpu --time-budget 16m --snapshots 5m --checkpoint-every 200 --log-every 50 --quiet"
taskset -c 1 /tmp/s56-acc train $common --out A > A.log 2>&1 &
taskset -c 0 /tmp/s56-acc train $common --lr-init 1e-2 --out B > B.log 2>&1 &
wait
echo done > done.txt
