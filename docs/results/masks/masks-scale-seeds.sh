#!/usr/bin/env bash
# How often a masked real capture keeps its colours, spherified to the official unit
# sphere (--spherify-radius 1) or at the default radius 4: the ethiopian_head capture at 250 px
# (images_4 box-filtered by 4, its masks_4 resampled by the loader), the fast preset, 300 steps
# (step-matched: the machine's load does not change the result), seeds 0 to 5. Writes
# docs/results/masks/seeds.csv: per run, the held-out PSNR and the colour left in the renders
# (mean of max - min over RGB inside the masks) against the photos'.
# Needs python3 with numpy and pillow (to make the 250 px copy and measure the colour).
set -euo pipefail
cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
src=../shared/data/real/ethiopian_head
work=${WORK:-/tmp/masks-scale-seeds}
bin=${MIPNERF:-target/release/mipnerf}
mkdir -p "$work/data/images_16" docs/results/masks
cp "$src/poses_bounds.npy" "$work/data/"
python3 - "$src" "$work/data/images_16" <<'P'
import os, sys
from PIL import Image
src, out = sys.argv[1], sys.argv[2]
for f in sorted(os.listdir(src + '/images_4')):
    Image.open(src + '/images_4/' + f).convert('RGB').resize((250, 250), Image.BOX).save(out + '/' + f[:-4] + '.png')
P
csv=docs/results/masks/seeds.csv
echo "radius,seed,psnr_db,colour_render,colour_photos,cpu" > "$csv"
cpu=$(lscpu | sed -n 's/^Model name: *//p')
for radius in 1 4; do
  for seed in 0 1 2 3 4 5; do
    run="$work/run-r$radius-s$seed"
    rm -rf "$run"
    "$bin" train --data "$work/data" --llff-factor 16 --spherify --spherify-radius "$radius" \
      --masks "$src/masks_4" --preset fast --steps 300 --seed "$seed" --quiet --out "$run" >/dev/null
    psnr=$("$bin" eval --run "$run" --no-lpips --quiet 2>&1 | sed -n 's/.*scale 0 ([0-9]* images): PSNR \([0-9.]*\) dB.*/\1/p')
    colour=$(python3 - "$run" "$src/masks_4" <<'P'
import glob, os, sys
import numpy as np
from PIL import Image
run, masks = sys.argv[1], sys.argv[2]
k, t = [], []
for gt in sorted(glob.glob(run + '/eval/*_gt.png')):
    name = os.path.basename(gt)[:-7]
    r = np.asarray(Image.open(run + '/eval/' + name + '.png').convert('RGB')).astype(float) / 255
    g = np.asarray(Image.open(gt).convert('RGB')).astype(float) / 255
    m = np.asarray(Image.open(masks + '/' + name + '.png').convert('L').resize(r.shape[1::-1], Image.BOX)) == 255
    k.append((r.max(-1) - r.min(-1))[m].mean())
    t.append((g.max(-1) - g.min(-1))[m].mean())
print('%.4f,%.4f' % (np.mean(k), np.mean(t)))
P
)
    echo "$radius,$seed,$psnr,$colour,$cpu" | tee -a "$csv"
  done
done
