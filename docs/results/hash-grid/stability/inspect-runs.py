#!/usr/bin/env python3
"""The stability rows' training curves and what their last checkpoints hold: the training PSNR
averaged over each 1,000 steps (from metrics.csv), the grid's root-mean-square feature, and the
occupancy grid's cells above the threshold. Reads safetensors with the standard library only.
Run from the repository root after `experiments/hash-grid-stability`, and on other run folders
to compare (the decay rows of `experiments/hash-grid-decay-fern-tune`):
`python3 docs/results/hash-grid/stability/inspect-runs.py runs/hash-grid-stability/* runs/hash-grid-decay-fern-tune/*`"""
import array, csv, json, math, struct, sys


def load(path, keys):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    header = json.loads(b[8 : 8 + n])
    out = {}
    for k in keys:
        v = header[k]
        s, e = v["data_offsets"]
        a = array.array("f")
        a.frombytes(b[8 + n + s : 8 + n + e])
        out[k] = a
    return out


print("| run | training PSNR, each 1,000 steps | grid rms | occupied cells |")
print("|---|---|---|---|")
for run in sys.argv[1:]:
    windows = {}
    with open(f"{run}/metrics.csv") as f:
        for row in csv.DictReader(f):
            windows.setdefault(int(row["step"]) // 1000, []).append(float(row["psnr"]))
    curve = " ".join(f"{sum(v) / len(v):.2f}" for _, v in sorted(windows.items()))
    b = open(f"{run}/checkpoint.safetensors", "rb").read()
    names = json.loads(b[8 : 8 + struct.unpack("<Q", b[:8])[0]])
    with_grid = "occupancy/opacity" in names
    t = load(f"{run}/checkpoint.safetensors", ["hash_grid/tables"] + (["occupancy/opacity"] if with_grid else []))
    g = t["hash_grid/tables"]
    rms = math.sqrt(sum(x * x for x in g) / len(g))
    # A run without an occupancy grid has no occupied cells to count.
    occupied = f"{sum(1 for x in t['occupancy/opacity'] if x > 0.01) / len(t['occupancy/opacity']):.3f}" if with_grid else "no grid"
    print(f"| {run} | {curve} | {rms:.3f} | {occupied} |")
