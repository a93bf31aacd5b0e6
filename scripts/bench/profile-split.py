#!/usr/bin/env python3
"""Where a profile's samples go, from `perf script` output of a call-graph recording
(`perf record --call-graph dwarf`): the share of all samples whose stack holds FRAME, the share
spent in page faults or memset (first 8 frames), and the top leaf functions under FRAME and
elsewhere.

    perf record -F 199 --call-graph dwarf,16384 -o perf.data mipnerf train ...
    perf script -i perf.data > perf.txt
    python3 scripts/bench/profile-split.py perf.txt 'DensityField>::densities'
"""
import collections
import re
import sys


def main(path: str, frame: str, top: int = 12) -> None:
    total, under, faults = 0, 0, 0
    leaves_under, leaves_else = collections.Counter(), collections.Counter()
    for sample in open(path, errors="replace").read().split("\n\n"):
        lines = [line.strip() for line in sample.strip().split("\n")]
        if len(lines) < 2:
            continue
        total += 1
        frames = lines[1:]
        leaf = re.sub(r"^[0-9a-f]+ ", "", frames[0]).split("+")[0][:80]
        if any(k in f for f in frames[:8] for k in ("page_fault", "clear_page", "memset")):
            faults += 1
        if any(frame in f for f in frames):
            under += 1
            leaves_under[leaf] += 1
        else:
            leaves_else[leaf] += 1
    print(f"samples: {total}")
    print(f"under {frame}: {under} ({100 * under / total:.1f}%)")
    print(f"in page faults or memset: {faults} ({100 * faults / total:.1f}%)")
    for name, leaves in ((f"under {frame}", leaves_under), ("elsewhere", leaves_else)):
        print(f"\ntop leaves {name} (% of all samples):")
        for leaf, n in leaves.most_common(top):
            print(f"  {100 * n / total:5.1f}%  {leaf}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
