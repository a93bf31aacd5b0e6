#!/usr/bin/env python3
"""Puts every k-th frame of a path render side by side in one picture, for the README.

    python3 docs/results/ethiopian-head/orbit-strip.py RENDER_DIR STEP OUT.png

RENDER_DIR is what `mipnerf render --path orbit` wrote (frame_0000.png, ...). Needs pillow.
"""
import glob
import sys

from PIL import Image

frames = sorted(glob.glob(sys.argv[1] + "/frame_[0-9][0-9][0-9][0-9].png"))[:: int(sys.argv[2])]
ims = [Image.open(f).convert("RGB") for f in frames]
w, h = ims[0].size
strip = Image.new("RGB", (w * len(ims), h), "white")
for k, im in enumerate(ims):
    strip.paste(im, (w * k, 0))
strip.save(sys.argv[3])
