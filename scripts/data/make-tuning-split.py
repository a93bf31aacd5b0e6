#!/usr/bin/env python3
"""A tuning copy of an LLFF capture: the test photos (every 8th: 0, 8, 16, ...) removed, so that the
loader's every-8th hold-out now picks photos from the training set. Tune on it, report on the
original's test photos (which the tuning copy never contains).

Usage: python3 scripts/data/make-tuning-split.py ../shared/data/llff/fern 8 /tmp/fern-tune
(the capture, the image factor whose folder is copied, the output folder). Standard library only.
"""
import os
import shutil
import struct
import sys


def read_npy(path):
    with open(path, "rb") as f:
        magic = f.read(6)
        assert magic == b"\x93NUMPY", f"{path}: not a .npy file"
        major, _minor = f.read(2)
        (hlen,) = struct.unpack("<H" if major == 1 else "<I", f.read(2 if major == 1 else 4))
        header = eval(f.read(hlen).decode("latin1"))  # a Python dict literal, by the format's definition
        assert header["descr"] == "<f8" and not header["fortran_order"], f"{path}: {header}"
        rows, cols = header["shape"]
        data = struct.unpack(f"<{rows * cols}d", f.read(8 * rows * cols))
        return [list(data[r * cols:(r + 1) * cols]) for r in range(rows)]


def write_npy(path, rows):
    cols = len(rows[0])
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, %d), }" % (len(rows), cols)
    header += " " * (63 - (10 + len(header)) % 64) + "\n"
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode("latin1"))
        f.write(struct.pack(f"<{len(rows) * cols}d", *[x for r in rows for x in r]))


def main():
    src, factor, out = sys.argv[1], sys.argv[2], sys.argv[3]
    rows = read_npy(os.path.join(src, "poses_bounds.npy"))
    folder = f"images_{factor}"
    names = sorted(os.listdir(os.path.join(src, folder)))
    assert len(names) == len(rows), f"{len(names)} images, {len(rows)} poses"
    keep = [i for i in range(len(rows)) if i % 8 != 0]
    os.makedirs(os.path.join(out, folder), exist_ok=True)
    for i in keep:
        shutil.copy(os.path.join(src, folder, names[i]), os.path.join(out, folder, names[i]))
    write_npy(os.path.join(out, "poses_bounds.npy"), [rows[i] for i in keep])
    held = [names[i] for k, i in enumerate(keep) if k % 8 == 0]
    print(f"{out}: {len(keep)} of {len(rows)} photos (the test photos removed); held out for tuning: {', '.join(held)}")


if __name__ == "__main__":
    main()
