"""An independent numpy LPIPS (float64) for non-square crops of the golden pairs; writes nonsquare_cases.json."""
import json
import struct
import sys

import numpy as np
from PIL import Image

SHIFT = np.array([-0.030, -0.088, -0.188])
SCALE = np.array([0.458, 0.448, 0.450])


def load_safetensors(path):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    header = json.loads(b[8 : 8 + n])
    out = {}
    for k, v in header.items():
        if k == "__metadata__":
            continue
        s, e = v["data_offsets"]
        out[k] = np.frombuffer(b[8 + n + s : 8 + n + e], dtype="<f4").reshape(v["shape"]).astype(np.float64)
    return out


def conv(x, k, b, stride, pad):
    x = np.pad(x, ((pad, pad), (pad, pad), (0, 0)))
    kh, kw, _, _ = k.shape
    ho = (x.shape[0] - kh) // stride + 1
    wo = (x.shape[1] - kw) // stride + 1
    out = np.zeros((ho, wo, k.shape[3]))
    for dy in range(kh):
        for dx in range(kw):
            patch = x[dy : dy + stride * (ho - 1) + 1 : stride, dx : dx + stride * (wo - 1) + 1 : stride]
            out += patch @ k[dy, dx]
    return np.maximum(out + b, 0)


def pool(x, k, s):
    ho, wo = (x.shape[0] - k) // s + 1, (x.shape[1] - k) // s + 1
    return np.max([x[dy : dy + s * (ho - 1) + 1 : s, dx : dx + s * (wo - 1) + 1 : s] for dy in range(k) for dx in range(k)], axis=0)


def features(w, net, img):
    x = (img * 2 - 1 - SHIFT) / SCALE
    taps = []
    if net == "vgg16":
        i = 0
        for block, n in enumerate([2, 2, 3, 3, 3]):
            if block:
                x = pool(x, 2, 2)
            for _ in range(n):
                x = conv(x, w[f"VGG16_0/Conv_{i}/kernel"], w[f"VGG16_0/Conv_{i}/bias"], 1, 1)
                i += 1
            taps.append(x)
    else:
        spec = [(4, 2, True), (1, 2, True), (1, 1, False), (1, 1, False), (1, 1, False)]
        for i, (stride, pad, then_pool) in enumerate(spec):
            x = conv(x, w[f"AlexNet_0/Conv_{i}/kernel"], w[f"AlexNet_0/Conv_{i}/bias"], stride, pad)
            taps.append(x)
            if then_pool:
                x = pool(x, 3, 2)
    return [t / (np.sqrt((t * t).sum(-1, keepdims=True)) + 1e-10) for t in taps]


def lpips(w, net, a, b):
    fa, fb = features(w, net, a), features(w, net, b)
    return sum(((x - y) ** 2 @ w[f"NetLinLayer_{l}/Conv_0/kernel"][0, 0, :, 0]).mean() for l, (x, y) in enumerate(zip(fa, fb)))


def main():
    weights = {n: load_safetensors(f"{sys.argv[1]}/{n}.safetensors") for n in ["vgg16", "alexnet"]}
    cases = []
    for side, (h, w) in [(64, (40, 64)), (200, (136, 200))]:
        ref = np.asarray(Image.open(f"ref_{side}.png").convert("RGB"), dtype=np.float64)[:h, :w] / 255
        for other in ["blur", "other_view"]:
            img = np.asarray(Image.open(f"{other}_{side}.png").convert("RGB"), dtype=np.float64)[:h, :w] / 255
            case = {"reference": f"ref_{side}.png", "distorted": f"{other}_{side}.png", "width": w, "height": h}
            for net in ["vgg16", "alexnet"]:
                case[net] = float(lpips(weights[net], net, ref, img))
            cases.append(case)
            print(case)
    json.dump({"crop": "the top-left width x height pixels of both images", "cases": cases}, open("nonsquare_cases.json", "w"), indent=1)


if __name__ == "__main__":
    main()
