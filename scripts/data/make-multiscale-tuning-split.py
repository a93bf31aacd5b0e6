#!/usr/bin/env python3
"""A tuning copy of a multiscale Blender dataset (as `mipnerf convert` writes it): the test views
removed, and every 11th training view (0, 11, 22, ...; 8 of lego's 87) moved to the test split at
all its scales, so that evaluation reads views held out from the training photos. Tune on it,
report on the original's test views (which the tuning copy never contains).

Usage: python3 scripts/data/make-multiscale-tuning-split.py /tmp/lego256 /tmp/lego256-tune
(the converted dataset, the output folder). Standard library only.
"""
import json
import os
import shutil
import sys

EVERY = 11


def main(src, dst):
    meta = json.load(open(os.path.join(src, "metadata.json")))
    train = meta["train"]
    keys = list(train.keys())
    out = {"train": {k: [] for k in keys}, "test": {k: [] for k in keys}}
    for i, path in enumerate(train["file_path"]):
        view = int(os.path.basename(path).split("_")[0])
        split = "test" if view % EVERY == 0 else "train"
        name = f"images_{split}/{os.path.basename(path)}"
        os.makedirs(os.path.join(dst, f"images_{split}"), exist_ok=True)
        shutil.copyfile(os.path.join(src, path), os.path.join(dst, name))
        for k in keys:
            out[split][k].append(name if k == "file_path" else train[k][i])
    with open(os.path.join(dst, "metadata.json"), "w") as f:
        json.dump(out, f)
    print(f"{dst}: {len(out['train']['file_path'])} training images, {len(out['test']['file_path'])} held out")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
