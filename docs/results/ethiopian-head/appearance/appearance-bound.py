#!/usr/bin/env python3
"""What a per-photo appearance code could give at most, measured on an evaluated run (would a per-photo appearance code pay?).

For each held-out photo of `mipnerf eval`'s output folder (NAME.png the render, NAME_gt.png the
photo), the PSNR as rendered, and the PSNR after the best per-channel affine colour map fitted to
the photo itself (photo ~ a * render + b per channel, least squares): an oracle, since it sees the
photo it is scored on. A per-photo exposure or white-balance difference between the photos is a
map of that kind, so this bounds what a per-photo code that corrects it can add. Also prints each
photo's fitted gains, to show whether the photos differ in exposure or white balance at all.

With `--photos DIR`, first counts the photos' exposure settings from their EXIF (exposure time,
f-number, ISO, white balance mode, exposure program, exposure bias).

Usage: docs/results/ethiopian-head/appearance/appearance-bound.py RUN/eval [--photos DIR] > report.txt
"""
import glob
import os
import sys

import numpy as np
from PIL import Image


def psnr(a, b):
    return -10.0 * np.log10(np.mean((a - b) ** 2))


def exif_settings(folder):
    from collections import Counter

    from PIL.ExifTags import TAGS

    keys = ["ExposureTime", "FNumber", "ISOSpeedRatings", "WhiteBalance", "ExposureProgram", "ExposureBiasValue"]
    seen = Counter()
    files = sorted(f for f in glob.glob(os.path.join(folder, "*")) if f.lower().endswith((".jpg", ".jpeg")))
    for f in files:
        exif = Image.open(f).getexif()
        tags = {TAGS.get(k, k): v for k, v in list(exif.items()) + list(exif.get_ifd(0x8769).items())}
        seen[tuple(str(tags.get(k)) for k in keys)] += 1
    print(f"EXIF of {len(files)} photos in {folder} (WhiteBalance 0 = auto, 1 = manual; ExposureProgram 1 = manual):")
    print("| photos | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for values, count in seen.most_common():
        print(f"| {count} | " + " | ".join(values) + " |")
    print()


def main():
    folder = sys.argv[1]
    if "--photos" in sys.argv:
        exif_settings(sys.argv[sys.argv.index("--photos") + 1])
    gts = sorted(glob.glob(os.path.join(folder, "*_gt.png")))
    if not gts:
        sys.exit(f"{folder}: no *_gt.png (run `mipnerf eval` first)")
    print("| photo | PSNR as rendered | PSNR, best per-channel affine map | gain | gains a (R, G, B) | offsets b (R, G, B) |")
    print("|---|---|---|---|---|---|")
    before, after = [], []
    for gt_path in gts:
        name = os.path.basename(gt_path)[: -len("_gt.png")]
        gt = np.asarray(Image.open(gt_path).convert("RGB"), dtype=np.float64) / 255.0
        render = np.asarray(Image.open(os.path.join(folder, name + ".png")).convert("RGB"), dtype=np.float64) / 255.0
        fitted = np.empty_like(render)
        gains, offsets = [], []
        for c in range(3):
            x, y = render[..., c].ravel(), gt[..., c].ravel()
            design = np.stack([x, np.ones_like(x)], axis=1)
            (a, b), *_ = np.linalg.lstsq(design, y, rcond=None)
            fitted[..., c] = np.clip(a * render[..., c] + b, 0.0, 1.0)
            gains.append(a)
            offsets.append(b)
        p0, p1 = psnr(render, gt), psnr(fitted, gt)
        before.append(p0)
        after.append(p1)
        print(
            f"| {name} | {p0:.2f} | {p1:.2f} | {p1 - p0:+.2f} | "
            + ", ".join(f"{g:.3f}" for g in gains)
            + " | "
            + ", ".join(f"{o:+.3f}" for o in offsets)
            + " |"
        )
    print(f"| **mean** | **{np.mean(before):.2f}** | **{np.mean(after):.2f}** | **{np.mean(after) - np.mean(before):+.2f}** | | |")


if __name__ == "__main__":
    main()
