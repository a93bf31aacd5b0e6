#!/usr/bin/env python3
"""Medians of the `packing` bench's runs: `python3 summarise.py > summary.md` in this folder."""
import glob
import re
import statistics


def load(path):
    out, kernel = {}, None
    for line in open(path):
        if line.startswith(("AMX", "AVX")):
            kernel = line.split(":")[0]
        m = re.match(r"\| (\d+ x \d+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|", line)
        if m:
            out[(kernel, m.group(1))] = [float(m.group(i)) for i in (2, 3, 4)]
    return out


before = [load(f) for f in sorted(glob.glob("bench-before-*.txt"))]
after = [load(f) for f in sorted(glob.glob("bench-after-*.txt"))]
roles = ["activation (left, left transposed)", "gradient dz (left, right)", "weight (right)"]
print("Medians of the three runs of each binary's `packing` bench (bench-before-N.txt, bench-after-N.txt, run in turn),")
print("ns per value (each run's cell is the fastest of 40 rounds); before / after in brackets.\n")
for kernel in ["AMX-BF16", "AVX-512 BF16"]:
    print(f"{kernel}:\n")
    print("| rows x width | " + " | ".join(roles) + " |")
    print("|---|---|---|---|")
    for key in [k for k in before[0] if k[0] == kernel]:
        cells = []
        for r in range(3):
            mb = statistics.median(x[key][r] for x in before)
            ma = statistics.median(x[key][r] for x in after)
            cells.append(f"{mb:.3f} → {ma:.3f} ({mb / ma:.2f}x)")
        print(f"| {key[1]} | " + " | ".join(cells) + " |")
    print()
