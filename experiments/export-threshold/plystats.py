"""Distances of a PLY's vertices to the demo scene's sphere, or the count outside lego's box.

Usage: python3 plystats.py sphere FILE.ply | python3 plystats.py lego FILE.ply
Reads binary little-endian PLY as `mipnerf export` writes it (no dependencies beyond the stdlib).
"""
import math
import struct
import sys


def vertices(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + 11
    header = data[:end].decode().splitlines()
    n = int(next(l for l in header if l.startswith("element vertex")).split()[-1])
    props = [l.split() for l in header if l.startswith("property") and "list" not in l]
    fmt = "<" + "".join("f" if p[1] == "float" else "B" for p in props)
    size = struct.calcsize(fmt)
    return [struct.unpack_from(fmt, data, end + i * size)[:3] for i in range(n)]


def main():
    kind, path = sys.argv[1], sys.argv[2]
    v = vertices(path)
    if kind == "sphere":
        # mipnerf_core::data::demo: the sphere's centre and radius; above z = 0.1 only it.
        d = sorted(abs(math.dist(p, (0.0, 0.0, 0.15)) - 0.7) for p in v if p[2] > 0.1)
        s = sorted(math.dist(p, (0.0, 0.0, 0.15)) - 0.7 for p in v if p[2] > 0.1)
        print(f"{path}: {len(d)} sphere vertices; |distance| median {d[len(d) // 2]:.4f}, "
              f"max {d[-1]:.4f}; signed median {s[len(s) // 2]:+.4f}")
    else:
        # lego's extent in its Blender scene (world units), with a margin.
        box = ((-0.7, 0.7), (-1.2, 1.2), (-0.45, 1.05))
        out = sum(1 for p in v if any(not lo <= c <= hi for c, (lo, hi) in zip(p, box)))
        print(f"{path}: {len(v)} vertices, {out} outside lego's box")


main()
