#!/bin/bash
# The README's backend-parity rows, remade: the demo scene at 32 px (10 views), Mip-NeRF's fast
# preset in f32 with IEEE subnormals on both backends, 300 steps of 256 rays from one seed, then
# eval on the same backend. (`mipnerf demo` itself trains bf16 on a CPU with AMX, so it is not used.)
B=/work/main/target/release/mipnerf
# The scene: the data/ folder that `mipnerf demo --out cpu --size 32 --views 10 --steps 300 --batch-rays 256 --backend cpu`
# wrote (demo-scene.log: its first lines; its own training is not used here).
D=/tmp/demo-par/cpu/data
for be in cpu gpu; do
  rm -rf run-$be
  { echo "\$ mipnerf train --data data --out run-$be --preset fast --precision f32 --keep-subnormals --steps 300 --batch-rays 256 --seed 0 --backend $be"; $B --version
    s=$(date +%s.%N)
    $B train --data $D --out run-$be --preset fast --precision f32 --keep-subnormals --steps 300 --batch-rays 256 --seed 0 --backend $be --quiet
    echo "wall time of train: $(echo "$(date +%s.%N) - $s" | bc) s"
    echo "\$ mipnerf eval --run run-$be --backend $be --no-lpips"
    $B eval --run run-$be --backend $be --no-lpips; } > run-$be.log 2>&1
done
echo done > done2.txt
