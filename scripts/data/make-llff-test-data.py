#!/usr/bin/env python3
"""tests/data/llff_fern_tiny: the LLFF fern capture at 63x47 for tests (forward-facing, NDC).

Box-averages the authors' images_8 (504x378) by 8x8 into images_64 (63x47; one row cropped at the
top and one at the bottom so the principal point stays at the centre), and copies poses_bounds.npy
(whose focal length is given at 4032x3024, so --llff-factor 64 reads it). Needs Pillow and numpy
(test data only; nothing at run time).

Usage: python3 scripts/data/make-llff-test-data.py ../shared/data/llff/fern tests/data/llff_fern_tiny
"""
import os
import shutil
import sys

import numpy as np
from PIL import Image


def main():
    src, out = sys.argv[1], sys.argv[2]
    os.makedirs(os.path.join(out, "images_64"), exist_ok=True)
    shutil.copy(os.path.join(src, "poses_bounds.npy"), os.path.join(out, "poses_bounds.npy"))
    names = sorted(os.listdir(os.path.join(src, "images_8")))
    for name in names:
        a = np.asarray(Image.open(os.path.join(src, "images_8", name)).convert("RGB"), dtype=np.float64)
        a = a[1:-1]  # 376 rows: 47 blocks of 8
        h, w = a.shape[0] // 8, a.shape[1] // 8
        small = a[: h * 8, : w * 8].reshape(h, 8, w, 8, 3).mean(axis=(1, 3))
        Image.fromarray(np.clip(np.round(small), 0, 255).astype(np.uint8)).save(os.path.join(out, "images_64", name))
    print(f"{out}: {len(names)} images at {w}x{h}")


if __name__ == "__main__":
    main()
