"""Makes tests/data/colmap_lego: a real COLMAP reconstruction of 40 lego training views.

Run with `bash scripts/data/make-colmap-test-data.sh` (it makes a virtual environment with PyPI's
pycolmap, numpy and pillow). The steps are the ones a user runs on their own photos:

1. 40 of ../shared/data/nerf_synthetic/lego's training images (every other one of the first 80 in
   transforms_train.json), composited on white and resized to 400x400 (Lanczos), written as PNGs.
2. pycolmap: SIFT feature extraction (one shared SIMPLE_RADIAL camera, COLMAP's default model),
   exhaustive matching, incremental mapping; the largest model is kept.
3. pycolmap.undistort_images (at most 200 px a side): undistorted images and a PINHOLE model,
   what NeRF needs.
4. The model is written in both forms: sparse/0/*.bin and text/*.txt.
5. poses_bounds_expected.npy: LLFF's imgs2poses (llff/poses/pose_utils.py: load_colmap_data and
   save_poses) on that model, re-stated below with pycolmap's reader in place of LLFF's
   read_model.py; the Rust importer must reproduce it.
6. blender_centres.json: the Blender ground-truth camera centre of each image, for the Umeyama
   alignment test.

Only the sparse model, the small images and these two files are kept (well under 5 MB).
"""

import json
import os
import shutil
import sys
import tempfile

import numpy as np
import pycolmap
from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LEGO = os.path.join(ROOT, "..", "shared", "data", "nerf_synthetic", "lego")
OUT = os.path.join(ROOT, "tests", "data", "colmap_lego")
SFM_SIZE = 400  # the photos COLMAP reconstructs from
SIZE = 200  # the undistorted images kept (COLMAP's undistorter rescales the camera with them)
COUNT = 40


def llff_poses_bounds(model_dir):
    """LLFF's imgs2poses on a COLMAP model, as pose_utils.py computes it."""
    rec = pycolmap.Reconstruction(model_dir)
    # load_colmap_data: hwf of the first camera, params[0] as the focal length.
    cam = rec.cameras[sorted(rec.cameras.keys())[0]]
    h, w, f = cam.height, cam.width, cam.params[0]
    hwf = np.array([h, w, f]).reshape([3, 1])
    ids = sorted(rec.images.keys())
    names = [rec.images[k].name for k in ids]
    perm = np.argsort(names)
    w2c_mats = []
    bottom = np.array([0, 0, 0, 1.0]).reshape([1, 4])
    for k in ids:
        im = rec.images[k]
        m = np.concatenate([im.cam_from_world().matrix(), bottom], 0)
        w2c_mats.append(m)
    w2c_mats = np.stack(w2c_mats, 0)
    c2w_mats = np.linalg.inv(w2c_mats)
    poses = c2w_mats[:, :3, :4].transpose([1, 2, 0])
    poses = np.concatenate([poses, np.tile(hwf[..., np.newaxis], [1, 1, poses.shape[-1]])], 1)
    # must switch to [-u, r, -t] from [r, -u, t], NOT [r, u, -t]
    poses = np.concatenate(
        [poses[:, 1:2, :], poses[:, 0:1, :], -poses[:, 2:3, :], poses[:, 3:4, :], poses[:, 4:5, :]], 1
    )
    # save_poses indexes the visibility by image_id - 1, which is the image's position only when
    # the ids run 1..N in order (every image registered); mapped by id here, as the importer does.
    position = {k: i for i, k in enumerate(ids)}
    pts_arr, vis_arr = [], []
    for k in rec.points3D:
        p = rec.points3D[k]
        pts_arr.append(p.xyz)
        cams = [0] * poses.shape[-1]
        for el in p.track.elements:
            cams[position[el.image_id]] = 1
        vis_arr.append(cams)
    pts_arr = np.array(pts_arr)
    vis_arr = np.array(vis_arr)
    zvals = np.sum(-(pts_arr[:, np.newaxis, :].transpose([2, 0, 1]) - poses[:3, 3:4, :]) * poses[:3, 2:3, :], 0)
    save_arr = []
    for i in perm:
        vis = vis_arr[:, i]
        zs = zvals[:, i]
        zs = zs[vis == 1]
        close_depth, inf_depth = np.percentile(zs, 0.1), np.percentile(zs, 99.9)
        save_arr.append(np.concatenate([poses[..., i].ravel(), np.array([close_depth, inf_depth])], 0))
    return np.array(save_arr), [names[i] for i in perm]


def main():
    if not os.path.isdir(LEGO):
        sys.exit(f"{LEGO} is absent")
    work = tempfile.mkdtemp(prefix="colmap_lego_")
    images = os.path.join(work, "images")
    os.makedirs(images)
    with open(os.path.join(LEGO, "transforms_train.json")) as fh:
        frames = {os.path.basename(fr["file_path"]): fr for fr in json.load(fh)["frames"]}
    names = list(frames)[0 : 2 * COUNT : 2]
    centres = {}
    for n in names:
        rgba = Image.open(os.path.join(LEGO, "train", n + ".png")).convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        rgb = Image.alpha_composite(white, rgba).convert("RGB").resize((SFM_SIZE, SFM_SIZE), Image.LANCZOS)
        rgb.save(os.path.join(images, n + ".png"))
        m = np.array(frames[n]["transform_matrix"])
        centres[n + ".png"] = m[:3, 3].tolist()
    db = os.path.join(work, "database.db")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_RADIAL"
    pycolmap.extract_features(db, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader)
    pycolmap.match_exhaustive(db)
    sparse = os.path.join(work, "sparse")
    os.makedirs(sparse)
    maps = pycolmap.incremental_mapping(db, images, sparse)
    best = max(maps, key=lambda k: maps[k].num_reg_images())
    print(f"models: { {k: maps[k].num_reg_images() for k in maps} }, keeping {best}")
    und = os.path.join(work, "undistorted")
    opts = pycolmap.UndistortCameraOptions()
    opts.max_image_size = SIZE
    pycolmap.undistort_images(und, os.path.join(sparse, str(best)), images, undistort_options=opts)
    if os.path.isdir(OUT):
        shutil.rmtree(OUT)
    os.makedirs(os.path.join(OUT, "sparse", "0"))
    os.makedirs(os.path.join(OUT, "text"))
    shutil.copytree(os.path.join(und, "images"), os.path.join(OUT, "images"))
    rec = pycolmap.Reconstruction(os.path.join(und, "sparse"))
    rec.write_binary(os.path.join(OUT, "sparse", "0"))
    rec.write_text(os.path.join(OUT, "text"))
    print(rec.summary())
    rows, sorted_names = llff_poses_bounds(os.path.join(OUT, "sparse", "0"))
    np.save(os.path.join(OUT, "poses_bounds_expected.npy"), rows)
    with open(os.path.join(OUT, "poses_bounds_expected_names.json"), "w") as fh:
        json.dump(sorted_names, fh, indent=1)
    registered = {rec.images[k].name for k in rec.images}
    with open(os.path.join(OUT, "blender_centres.json"), "w") as fh:
        json.dump({k: v for k, v in centres.items() if k in registered}, fh, indent=1, sort_keys=True)
    shutil.rmtree(work)
    print(f"wrote {OUT}: {len(registered)} of {len(names)} images registered")


if __name__ == "__main__":
    main()
