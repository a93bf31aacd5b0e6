#!/usr/bin/env python3
"""What the hash grid's run holds at each mark before and through its loss's climb: for every
checkpoint of `RUN/marks/*.safetensors`, each MLP layer's kernel (root mean square, largest
magnitude, and the median of Adam's sqrt(v)), and each level of the hash grid (root mean square,
largest magnitude, median sqrt(v)), beside the training PSNR of the 500 steps before the mark.
Standard library only. Run from the repository root:
`python3 docs/results/hash-grid/climb-watch/inspect-marks.py runs/climb-watch`"""
import array, csv, glob, json, math, os, struct, sys


def tensors(path):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    header = json.loads(b[8 : 8 + n])
    out = {}
    for k, v in header.items():
        if k == "__metadata__":
            continue
        s, e = v["data_offsets"]
        a = array.array("f")
        a.frombytes(b[8 + n + s : 8 + n + e])
        out[k] = a
    return out


def levels(levels=16, coarsest=16, finest=512, log2_table=17):
    """Each level's (cells a side, entries) as HashGridConfig lays them: dense where a level's
    vertices fit the table."""
    growth = math.exp((math.log(finest) - math.log(coarsest)) / (levels - 1))
    out = []
    for l in range(levels):
        n = int(math.floor(coarsest * growth**l + 1e-6)) if l < levels - 1 else finest
        out.append((n, min((n + 1) ** 3, 1 << log2_table)))
    return out


def stats(values):
    v = sorted(abs(x) for x in values)
    rms = math.sqrt(sum(x * x for x in values) / max(len(values), 1))
    return rms, v[-1] if v else 0.0, v[len(v) // 2] if v else 0.0


run = sys.argv[1]
psnr = {}
with open(f"{run}/metrics.csv") as f:
    for row in csv.DictReader(f):
        psnr[int(row["step"])] = float(row["psnr"])
marks = sorted(glob.glob(f"{run}/marks/*.safetensors"))
layout = levels()
print("| mark | training PSNR (500 steps before) | MLP kernels: rms / max, per layer | grid levels 0, 4, 8, 12, 15: rms / max |")
print("|---|---|---|---|")
rows_v = []
for path in marks:
    step = int(os.path.basename(path).split(".")[0])
    window = [p for s, p in psnr.items() if step - 500 < s <= step]
    t = tensors(path)
    layers = sorted(k for k in t if k.startswith("MLP_0/") and k.endswith("kernel"))
    mlp = " ".join(f"{stats(t[k])[0]:.3f}/{stats(t[k])[1]:.2f}" for k in layers)
    grid, grid_v = t["hash_grid/tables"], t["adam_v/hash_grid/tables"]
    at, per_level = 0, []
    for _, entries in layout:
        per_level.append((grid[2 * at : 2 * (at + entries)], grid_v[2 * at : 2 * (at + entries)]))
        at += entries
    assert 2 * at == len(grid), f"the grid's layout: {2 * at} values against {len(grid)}"
    g = " ".join(f"{stats(per_level[l][0])[0]:.3f}/{stats(per_level[l][0])[1]:.1f}" for l in (0, 4, 8, 12, 15))
    print(f"| {step} | {sum(window) / max(len(window), 1):.2f} | {mlp} | {g} |")
    v_mlp = " ".join(f"{math.sqrt(stats(t['adam_v/' + k])[2]):.1e}" for k in layers)
    v_grid = " ".join(f"{math.sqrt(stats(per_level[l][1])[2]):.1e}" for l in (0, 4, 8, 12, 15))
    rows_v.append(f"| {step} | {v_mlp} | {v_grid} |")
print()
print("| mark | median sqrt(v), MLP kernels per layer | median sqrt(v), grid levels 0, 4, 8, 12, 15 |")
print("|---|---|---|")
print("\n".join(rows_v))
