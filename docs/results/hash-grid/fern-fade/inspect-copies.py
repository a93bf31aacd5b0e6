#!/usr/bin/env python3
"""What the hash grid's copies hold along a run: each sixth level's root-mean-square feature, the
small MLP's density head (its weights' root mean square and its bias), the trunk's and the
colour branch's weights, and the occupancy grid's cells above the threshold. Reads safetensors
with the standard library only; the grid's levels are the recipe's (16 levels of 2 features from
16 to 512 cells, tables of 2^17). Run from the repository root:
`python3 docs/results/hash-grid/fern-fade/inspect-copies.py runs/hash-grid-fern-fade/hash-grid snapshots/00120s snapshots/00300s snapshots/00600s snapshots/00900s snapshots/01200s .`"""
import array, json, math, struct, sys
def load(path):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    header = json.loads(b[8 : 8 + n])
    out = {}
    for k, v in header.items():
        if k == "__metadata__" or v["dtype"] != "F32": continue
        s, e = v["data_offsets"]
        a = array.array("f"); a.frombytes(b[8 + n + s : 8 + n + e]); out[k] = a
    return out
run=sys.argv[1]
names=sys.argv[2:]
# level sizes of the recipe grid: 16 levels, 16..512 cells, 2^17 tables, 2 features
import math as m
levels=[]
for l in range(16):
    g=math.log(512/16)/15
    n=int(16*math.exp(g*l)+1e-6)
    e=min((n+1)**3, 1<<17)
    levels.append(e*2)
print("| copy | grid rms by level (0, 3, 6, 9, 12, 15) | density head (Dense_2) weight rms, bias | trunk rms (Dense_0, Dense_1) | colour rms (Dense_4, Dense_5) | cells > 0.01 |")
print("|---|---|---|---|---|---|")
for name in names:
    t=load(f"{run}/{name}/checkpoint.safetensors")
    g=t["hash_grid/tables"]
    off=0; rms=[]
    for l,sz in enumerate(levels):
        a=g[off:off+sz]; off+=sz
        rms.append(math.sqrt(sum(x*x for x in a)/len(a)))
    r=lambda k: math.sqrt(sum(x*x for x in t[k])/len(t[k]))
    occ=t["occupancy/opacity"]
    print(f"| {name} | {' '.join(f'{rms[i]:.3f}' for i in (0,3,6,9,12,15))} | {r('MLP_0/Dense_2/kernel'):.3f}, {t['MLP_0/Dense_2/bias'][0]:.3f} | {r('MLP_0/Dense_0/kernel'):.3f}, {r('MLP_0/Dense_1/kernel'):.3f} | {r('MLP_0/Dense_4/kernel'):.3f}, {r('MLP_0/Dense_5/kernel'):.3f} | {sum(1 for x in occ if x > 0.01) / len(occ):.3f} |")
