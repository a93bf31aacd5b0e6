#!/usr/bin/env python3
"""Compares two mipnerf checkpoints tensor by tensor: how many values differ, and how many of the
first one's are subnormal (nonzero, below f32's smallest normal 1.18e-38). Subnormals: a run with
subnormals flushed against the same run with them kept.

Usage: scripts/bench/compare-checkpoints.py A/checkpoint.safetensors B/checkpoint.safetensors
"""
import json
import struct
import sys

import numpy as np


def load(path):
    raw = open(path, "rb").read()
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8 : 8 + n])
    tensors = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        start, end = info["data_offsets"]
        dtype = np.float32 if info["dtype"] == "F32" else np.uint8
        tensors[name] = np.frombuffer(raw[8 + n + start : 8 + n + end], dtype=dtype)
    return tensors


def main():
    a, b = load(sys.argv[1]), load(sys.argv[2])
    if a.keys() != b.keys():
        sys.exit("the checkpoints hold different tensors")
    print("| tensor | values | differ | subnormal in the first |")
    print("|---|---|---|---|")
    totals = {}
    for name in sorted(a):
        x, y = a[name], b[name]
        differ = int(np.sum(x.view(np.uint8) != y.view(np.uint8)) if x.dtype != np.float32 else np.sum(x.view(np.uint32) != y.view(np.uint32)))
        sub = int(np.sum((np.abs(x) < np.finfo(np.float32).tiny) & (x != 0))) if x.dtype == np.float32 else 0
        group = name.split("/")[0] if name.startswith(("adam_m", "adam_v", "occupancy")) else "parameters"
        t = totals.setdefault(group, [0, 0, 0])
        t[0] += x.size
        t[1] += differ
        t[2] += sub
        if differ or sub:
            print(f"| {name} | {x.size} | {differ} | {sub} |")
    print()
    print("| group | values | differ | subnormal in the first |")
    print("|---|---|---|---|")
    for group, (n, d, s) in totals.items():
        print(f"| {group} | {n} | {d} | {s} |")


if __name__ == "__main__":
    main()
