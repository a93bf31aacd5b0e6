#!/usr/bin/env python3
"""The roofline of one training step of the paper preset (docs/gpu-performance.md).

Counts each kernel's FLOPs and device bytes for a batch of 4096 rays of 128 + 128 samples, from
the shapes the GPU backend runs (mipnerf_core's paper config; the kernels in shaders/), and turns
them into an expected time on an H100-class GPU: time = max(FLOPs / (peak * efficiency),
bytes / bandwidth), summed over kernels, plus the host's recording cost per dispatch. The
efficiencies before and after the hardware-GPU kernels are estimates from the kernels' inner loops (see the
document), not measurements: no hardware GPU was reachable from this project's machines.
Prints markdown. Run: python3 scripts/bench/roofline.py
"""

R, S, LEVELS = 4096, 128, 2
N = R * S  # samples per level
X, V, W, WC = 96, 27, 256, 128
PEAK = 67e12  # H100 SXM FP32 (non-tensor) FLOP/s
BW = 3.35e12  # H100 SXM HBM3 bytes/s
HOST_PER_DISPATCH_BEFORE = 20e-6  # uniform buffer + bind group + compute pass, recorded per dispatch
HOST_PER_DISPATCH_AFTER = 1e-6  # cached bind group, one pass: set_pipeline/bind/dispatch only
SMS = 132

# (name, fan_in, fan_out, has_relu_input): the dense layers, input order as the kernels run them.
layers = [("trunk 0", X, W)] + [(f"trunk {i}", W + (X if i == 5 else 0), W) for i in range(1, 8)]
layers += [("density head", W, 1), ("bottleneck", W, W), ("colour 0", W + V, WC), ("rgb", WC, 3)]

def tiles(m, n, t):
    return -(-m // t) * -(-n // t)

rows = []
def add(name, flops, bytes_, eff_before, eff_after):
    rows.append((name, flops, bytes_, eff_before, eff_after))

# Products. Before: 16x16 tiles, one output per invocation, two shared-memory loads per FMA:
# bound by shared-memory bandwidth at 1/8 of the FMA rate. After: 4x4 outputs per invocation,
# two vec4 shared loads per 16 FMAs (one broadcast): assumed half the FP32 peak.
fwd_f = sum(2 * N * i * o for _, i, o in layers)
fwd_b = sum(4 * N * (i + o) for _, i, o in layers)
add("forward products", fwd_f, fwd_b, 0.125, 0.5)
ig = [(n, i, o) for n, i, o in layers if n != "trunk 0"]
ig_f = sum(2 * N * i * o for _, i, o in ig)
# Input gradients read dz and write d input; before, a separate ReLU-backward pass read the
# activation and the gradient and wrote it again (folded into the epilogue after).
relu_b = sum(4 * N * 3 * o for n, _, o in layers if n.startswith("trunk") or n == "colour 0")
ig_b = sum(4 * N * (i + o) for _, i, o in ig)
add("input-gradient products", ig_f, ig_b + relu_b, 0.125, 0.5)
rows_before_relu = ("ReLU backward passes (before only)", 0, relu_b)
wg_f = sum(2 * N * i * o for _, i, o in layers)
wg_b = sum(4 * N * (i + o) for _, i, o in layers)
# Weight gradients before: one workgroup per 16x16 tile of the m x n kernel, each looping over
# all N rows: a layer with fewer tiles than SMs leaves SMs idle.
def wg_eff_before():
    t = 0.0
    for _, i, o in layers:
        busy = min(1.0, tiles(i, o, 16) / SMS)
        t += 2 * N * i * o / (PEAK * 0.125 * busy)
    return wg_f / (PEAK * t)
add("weight-gradient products", wg_f, wg_b, wg_eff_before(), 0.5)
# Bias gradients (column sums, two passes), both before and after.
cs_b = sum(4 * N * o for _, _, o in layers)
add("bias gradients", sum(N * o for _, _, o in layers), cs_b, 1.0, 1.0)
# Encoding: per sample read 2 edges and the ray, write X floats (sin/exp ~ 20 flops per feature).
add("cast + IPE", 20 * N * X, 4 * N * (X + 2), 1.0, 1.0)
# Before, the view encoding was also broadcast to every sample (N x V written and read); after,
# the first colour layer multiplies it once per ray (in the forward products above).
add("view encoding", 10 * R * V, 4 * (R * V + R * 3), 1.0, 1.0)
# Rendering + loss gradient: per sample read 4 raw + 2 edges, write weight, 4 gradients.
add("render + loss gradient", 60 * N, 4 * N * (4 + 2 + 1 + 4 + 4), 1.0, 1.0)
add("sample / resample", 30 * N, 4 * (N + R) * 3, 1.0, 1.0)
P = 612_740
add("Adam + clipping (once per step)", 20 * P / LEVELS, 4 * P * 8 / LEVELS, 1.0, 1.0)

def t(f, b, e):
    return max(f / (PEAK * e) if f else 0.0, b / BW)

print("| kernel (per level; x2 per step) | GFLOP | MB | before: ms | after: ms |")
print("|---|---|---|---|---|")
tb = ta = 0.0
for name, f, b, eb, ea in rows:
    b_before = b
    b_after = b - (relu_b if name == "input-gradient products" else 0)
    x, y = t(f, b_before, eb), t(f, b_after, ea)
    tb += x
    ta += y
    print(f"| {name} | {f / 1e9:.0f} | {b_after / 1e6:.0f} | {x * 1e3:.2f} | {y * 1e3:.2f} |")
# Dispatches per step of the paper preset, as `mipnerf bench --preset paper` counts them: 156
# after; about 156 before too (no split second passes, but separate ReLU-backward, broadcast and
# head passes).
disp_before, disp_after = 156, 156
host_b, host_a = disp_before * HOST_PER_DISPATCH_BEFORE, disp_after * HOST_PER_DISPATCH_AFTER
total_f = sum(r[1] for r in rows) * LEVELS
print()
print(f"Per step (2 levels): {total_f / 1e12:.2f} TFLOP; device time before {2 * tb * 1e3:.0f} ms, after {2 * ta * 1e3:.0f} ms;")
print(f"host recording before {host_b * 1e3:.1f} ms, after {host_a * 1e3:.2f} ms (overlapped with the device after: steps are queued).")
print(f"Training samples/s (2 levels x 128 samples x 4096 rays): before {R * S * LEVELS / (2 * tb + host_b):.3g}, after {R * S * LEVELS / (2 * ta):.3g}.")
print(f"Share of FP32 peak: before {total_f / PEAK / (2 * tb + host_b):.0%}, after {total_f / PEAK / (2 * ta):.0%}.")
