#!/usr/bin/env bash
# The live viewer's frame latency and training stall, measured with `mipnerf bench
# --viewer` on lego256 runs of the fast and tiny presets after 10 and 5 minutes of training, on
# this machine's CPU. Writes docs/results/viewer/{fast,tiny}.txt, each headed by the commands
# and the binary's commit.
#
# Usage: experiments/viewer/run.sh [RUNS_DIR] (default runs/viewer; the data goes there too)
set -euo pipefail
cd "$(dirname "$0")/../.."
runs=${1:-runs/viewer}
bin=./target/release/mipnerf
out=docs/results/viewer
mkdir -p "$runs" "$out"
[ -d "$runs/lego256" ] || $bin convert --input ../shared/data/nerf_synthetic/lego --output "$runs/lego256" --size 256
for preset in fast tiny; do
    budget=$([ $preset = fast ] && echo 10m || echo 5m)
    stall=$([ $preset = fast ] && echo 2000 || echo 500)
    run="$runs/lego-$preset"
    train=(train --data "$runs/lego256" --out "$run" --preset $preset --time-budget $budget --backend cpu --quiet)
    bench=(bench --viewer "$run" --backend cpu --viewer-frames 10 --viewer-stall-steps $stall)
    [ -f "$run/train_seconds.txt" ] || $bin "${train[@]}"
    {
        echo "# $($bin --version); $(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
        echo "# mipnerf ${train[*]}"
        echo "# mipnerf ${bench[*]}"
        echo "# (experiments/viewer/run.sh; nothing else running)"
        $bin "${bench[@]}" 2>/dev/null
    } > "$out/$preset.txt.part"
    mv "$out/$preset.txt.part" "$out/$preset.txt"
done
