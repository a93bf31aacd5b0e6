"""Compares the poses of a dataset `mipnerf colmap` wrote (OURS: poses_bounds.npy and images_N/NNNN_<name>.png)
with a capture's own (REF: poses_bounds.npy over the sorted photos of REF/images_4), photo by photo
(matched by name): the best similarity transform (Umeyama) of our camera centres onto theirs, then
each photo's centre error (as a share of the cameras' mean distance from their centroid) and its
rotation error (degrees), and the focal lengths (at REF's image size). Prints one JSON object.

Usage: python3 docs/results/ethiopian-head/colmap/compare-poses.py OURS REF
"""

import glob
import json
import os
import sys

import numpy as np


def load(folder, pattern):
    rows = np.load(os.path.join(folder, "poses_bounds.npy"))
    names = sorted(glob.glob(os.path.join(folder, pattern)))
    names = [os.path.splitext(os.path.basename(n))[0] for n in names]
    assert len(names) == len(rows), (folder, len(names), len(rows))
    poses = rows[:, :15].reshape(-1, 3, 5)
    return names, poses


def main():
    ours_dir, ref_dir = sys.argv[1], sys.argv[2]
    ours_names, ours = load(ours_dir, "images_*/*.png")
    ours_names = [n[5:] for n in ours_names]  # NNNN_<name>
    ref_names, ref = load(ref_dir, "images_4/*")
    index = {n: i for i, n in enumerate(ref_names)}
    pairs = [(i, index[n]) for i, n in enumerate(ours_names) if n in index]
    a = np.array([ours[i][:, 3] for i, _ in pairs])
    b = np.array([ref[j][:, 3] for _, j in pairs])
    # Umeyama: b ~ s R a + t.
    ma, mb = a.mean(0), b.mean(0)
    ca, cb = a - ma, b - mb
    u, d, vt = np.linalg.svd(cb.T @ ca / len(a))
    sign = np.eye(3)
    sign[2, 2] = np.sign(np.linalg.det(u @ vt))
    r = u @ sign @ vt
    s = np.trace(np.diag(d) @ sign) / (ca ** 2).sum(1).mean()
    spread = np.linalg.norm(cb, axis=1).mean()
    centre = np.linalg.norm(s * (r @ ca.T).T - cb, axis=1) / spread
    rot = []
    for i, j in pairs:
        m = r @ ours[i][:, :3]
        cos = (np.trace(m.T @ ref[j][:, :3]) - 1) / 2
        rot.append(float(np.degrees(np.arccos(np.clip(cos, -1, 1)))))
    rot = np.array(rot)
    names = [ours_names[i] for i, _ in pairs]
    worst = np.argsort(-rot)[:5]
    scale = ref[0][0, 4] / ours[0][0, 4]
    print(json.dumps({
        "photos_compared": len(pairs),
        "centre_error_median": float(np.median(centre)),
        "centre_error_max": float(centre.max()),
        "rotation_error_median_deg": float(np.median(rot)),
        "rotation_error_max_deg": float(rot.max()),
        "worst_rotations": {names[k]: round(float(rot[k]), 2) for k in worst},
        "focal_ours_px_at_ref_size": float(ours[0][2, 4] * scale),
        "focal_ref_px": float(ref[0][2, 4]),
    }, indent=2))


if __name__ == "__main__":
    main()
