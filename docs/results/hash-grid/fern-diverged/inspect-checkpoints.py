#!/usr/bin/env python3
"""What the hash grid's copies hold before and after its loss climbed on fern: the grid's largest
and root-mean-square feature, each MLP layer's largest weight, and the occupancy grid's cells
above the threshold and carved. Reads safetensors with the standard library only. Run from the
repository root, on the run folder of the second run (grid at 2x; its copies at 5, 10 and 15
minutes and its last checkpoint at step 26,225):
`python3 docs/results/hash-grid/fern-diverged/inspect-checkpoints.py runs/hash-grid-fern-diverged-x2/hash-grid`"""
import array, json, math, struct, sys


def load(path):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    header = json.loads(b[8 : 8 + n])
    out = {}
    for k, v in header.items():
        if k == "__metadata__" or v["dtype"] != "F32":
            continue
        s, e = v["data_offsets"]
        a = array.array("f")
        a.frombytes(b[8 + n + s : 8 + n + e])
        out[k] = a
    return out


run = sys.argv[1]
print("| copy | grid max abs | grid rms | largest weight per MLP layer | cells above 0.01 | carved |")
print("|---|---|---|---|---|---|")
for name in ["snapshots/00300s", "snapshots/00600s", "snapshots/00900s", "."]:
    t = load(f"{run}/{name}/checkpoint.safetensors")
    g = t["hash_grid/tables"]
    layers = [f"{max(abs(x) for x in a):.2f}" for k, a in t.items() if k.startswith("MLP_0/") and k.endswith("kernel")]
    occ = t["occupancy/opacity"]
    print(
        f"| {name} | {max(abs(x) for x in g):.2f} | {math.sqrt(sum(x * x for x in g) / len(g)):.3f} | "
        f"{', '.join(layers)} | {sum(1 for x in occ if x > 0.01) / len(occ):.3f} | {sum(1 for x in occ if x < 0) / len(occ):.3f} |"
    )
