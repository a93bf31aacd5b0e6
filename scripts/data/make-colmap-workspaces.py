"""Makes COLMAP workspaces (photos + sparse/N) with real pycolmap reconstructions, for the process
step `mipnerf colmap`: its tests (tests/data/colmap_workspaces/, committed) and the first-run
measurement of docs/results/own-photos (a 400 px workspace, not committed).

Run with `bash scripts/data/make-colmap-workspaces.sh [fixtures|bar OUT]` (it makes a virtual environment
with PyPI's pycolmap, numpy and pillow). Steps, per camera model:

1. 40 of ../shared/data/nerf_synthetic/lego's training images (every other one of the first 80 in
   transforms_train.json), composited on white, resized (Lanczos) and, for the fixtures, passed
   through a known lens distortion of that model (so that undistortion has something to undo),
   written as JPEG (quality 92), as a camera writes them.
2. pycolmap: SIFT features with one shared camera of that model, exhaustive matching,
   incremental mapping. Every model the mapper makes is kept as sparse/N.
3. For the fixtures, COLMAP's own undistortion of three photos (pycolmap.undistort_image with the
   largest model's camera): reference/ holds the undistorted PNGs and the undistorted camera, and
   camera_golden.json holds pycolmap's img_from_cam and cam_from_img on a grid of points, for the
   Rust undistortion to be checked against.
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
COUNT = 40
SIZE = 320  # the fixtures' photos

# The known distortion applied to the fixtures' photos, per model: (params at size s, as a function of
# the pinhole focal f and the size s).
DISTORTIONS = {
    "SIMPLE_RADIAL": lambda f, s: [f, s / 2, s / 2, -0.12],
    "RADIAL": lambda f, s: [f, s / 2, s / 2, -0.15, 0.05],
    "OPENCV": lambda f, s: [f, 1.02 * f, s / 2 + 3, s / 2 - 2, -0.1, 0.02, 0.002, -0.001],
}


def bilinear(img, x, y):
    """img (h, w, c) sampled at pixel coordinates x, y (pixel centres at integers), edges clamped."""
    h, w = img.shape[:2]
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def photos(out_dir, size, model):
    """Writes the 40 photos (distorted by `model`'s known distortion, or not when None)."""
    with open(os.path.join(LEGO, "transforms_train.json")) as fh:
        meta = json.load(fh)
    frames = {os.path.basename(fr["file_path"]): fr for fr in meta["frames"]}
    names = list(frames)[0 : 2 * COUNT : 2]
    focal = 0.5 * size / np.tan(0.5 * meta["camera_angle_x"])
    camera = None
    if model is not None:
        camera = pycolmap.Camera(model=model, width=size, height=size, params=DISTORTIONS[model](focal, size))
        ys, xs = np.mgrid[0:size, 0:size].astype(np.float64)
        pix = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)
        cam = camera.cam_from_img(pix)  # normalised, undistorted
        src_x = (focal * cam[:, 0] + size / 2 - 0.5).reshape(size, size)
        src_y = (focal * cam[:, 1] + size / 2 - 0.5).reshape(size, size)
    os.makedirs(out_dir)
    for n in names:
        rgba = Image.open(os.path.join(LEGO, "train", n + ".png")).convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        rgb = Image.alpha_composite(white, rgba).convert("RGB").resize((size, size), Image.LANCZOS)
        if camera is not None:
            arr = np.asarray(rgb).astype(np.float64)
            rgb = Image.fromarray(np.clip(bilinear(arr, src_x, src_y) + 0.5, 0, 255).astype(np.uint8))
        rgb.save(os.path.join(out_dir, n + ".jpg"), quality=92)
    return names


def reconstruct(work, images, model):
    if model == "RADIAL":
        return reconstruct_radial(work, images)
    db = os.path.join(work, "database.db")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = model
    # The settings the README gives for a few dozen small photos: more, affine-adapted SIFT
    # features and a mapper that accepts fewer inliers (37 of the 40 400 px photos register with
    # them, 20 with COLMAP's defaults).
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.domain_size_pooling = True
    extraction.sift.estimate_affine_shape = True
    extraction.sift.peak_threshold = 0.004
    pycolmap.extract_features(
        db, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader, extraction_options=extraction
    )
    pycolmap.match_exhaustive(db)
    sparse = os.path.join(work, "sparse")
    os.makedirs(sparse)
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.mapper.init_min_num_inliers = 50
    mapping.mapper.abs_pose_min_num_inliers = 15
    maps = pycolmap.incremental_mapping(db, images, sparse, options=mapping)
    print(f"{model}: models {{ {', '.join(f'{k}: {maps[k].num_reg_images()} images' for k in maps)} }}")
    os.remove(db)
    return sparse, maps


def reconstruct_radial(work, images):
    """RADIAL: COLMAP's mapper started with a RADIAL camera diverges on these few small photos (k2
    runs to magnitudes of 2 to 50 from the initial pair, and only that pair registers, in 8 of 9
    runs), so the scene is mapped with SIMPLE_RADIAL and every model's camera is then refined as
    RADIAL (k2 from 0) by COLMAP's bundle adjustment, with the model's points and poses."""
    sparse, maps = reconstruct(work, images, "SIMPLE_RADIAL")
    for k, rec in maps.items():
        for cid in list(rec.cameras.keys()):
            cam = rec.cameras[cid]
            p = list(cam.params)
            rec.cameras[cid] = pycolmap.Camera(
                model="RADIAL", width=cam.width, height=cam.height, params=p + [0.0], camera_id=cid
            )
        pycolmap.bundle_adjustment(rec, pycolmap.BundleAdjustmentOptions())
        folder = os.path.join(sparse, str(k))
        shutil.rmtree(folder)
        os.makedirs(folder)
        rec.write_binary(folder)
    print(f"RADIAL (refined): { {k: list(maps[k].cameras[sorted(maps[k].cameras.keys())[0]].params) for k in maps} }")
    return sparse, maps


def fixture(model, out, size):
    work = tempfile.mkdtemp(prefix="colmap_ws_")
    ws = os.path.join(out, model.lower())
    if os.path.isdir(ws):
        shutil.rmtree(ws)
    os.makedirs(ws)
    images = os.path.join(ws, "images")
    photos(images, size, model)
    # COLMAP's mapper is multi-threaded and not deterministic: on these few small photos a run
    # sometimes registers only the initial pair; such runs are repeated (at most four more times).
    for attempt in range(5):
        sparse, maps = reconstruct(work, images, model)
        if max(m.num_reg_images() for m in maps.values()) >= 25 or attempt == 4:
            break
        shutil.rmtree(work)
        work = tempfile.mkdtemp(prefix="colmap_ws_")
    shutil.copytree(sparse, os.path.join(ws, "sparse"))
    shutil.rmtree(work)
    references(ws, model, size)


def references(ws, model, size):
    """reference/ and camera_golden.json from the workspace's largest model (deterministic)."""
    recs = {int(k): pycolmap.Reconstruction(os.path.join(ws, "sparse", k)) for k in os.listdir(os.path.join(ws, "sparse"))}
    best = max(recs, key=lambda k: (recs[k].num_reg_images(), -k))
    rec = recs[best]
    images = os.path.join(ws, "images")
    cam = rec.cameras[sorted(rec.cameras.keys())[0]]
    # pycolmap's own camera maths on a grid, for the Rust distortion to match.
    grid = np.linspace(-0.45, 0.45, 7)
    normalised = np.array([[x, y] for y in grid for x in grid])
    pixels = np.array([[x, y] for y in np.linspace(0.5, cam.height - 0.5, 7) for x in np.linspace(0.5, cam.width - 0.5, 7)])
    golden = {
        "source": f"pycolmap {pycolmap.__version__}: Camera.img_from_cam and Camera.cam_from_img",
        "model": cam.model.name,
        "width": cam.width,
        "height": cam.height,
        "params": list(cam.params),
        "normalised": normalised.tolist(),
        "img_from_cam": cam.img_from_cam(np.concatenate([normalised, np.ones((len(normalised), 1))], 1)).tolist(),
        "pixels": pixels.tolist(),
        "cam_from_img": cam.cam_from_img(pixels).tolist(),
    }
    # COLMAP's undistortion of three registered photos, the reference for the Rust one; with each,
    # the photo as COLMAP decoded it (JPEG decoders differ by a level or two at some pixels).
    ref = os.path.join(ws, "reference")
    if os.path.isdir(ref):
        shutil.rmtree(ref)
    os.makedirs(ref)
    registered = sorted(rec.images[k].name for k in rec.images)
    opts = pycolmap.UndistortCameraOptions()
    undistorted = []
    for name in registered[:3]:
        bitmap = pycolmap.Bitmap.read(os.path.join(images, name), True)
        stem = os.path.splitext(name)[0]
        bitmap.write(os.path.join(ref, stem + ".decoded.png"))
        und, und_cam = pycolmap.undistort_image(opts, bitmap, cam)
        und.write(os.path.join(ref, stem + ".png"))
        undistorted.append(name)
    golden["undistorted_camera"] = {
        "model": und_cam.model.name,
        "width": und_cam.width,
        "height": und_cam.height,
        "params": list(und_cam.params),
    }
    golden["undistorted_images"] = undistorted
    golden["applied_distortion"] = DISTORTIONS[model](0.5 * size / np.tan(0.5 * 0.6911112070083618), size)
    with open(os.path.join(ws, "camera_golden.json"), "w") as fh:
        json.dump(golden, fh, indent=1)
    print(f"wrote {ws}: {rec.num_reg_images()} of {COUNT} registered in sparse/{best}; {cam.model.name} {list(cam.params)}")


def bar(out, size):
    """The measurement workspace: the 40 photos as they are (no added distortion), SIMPLE_RADIAL."""
    work = tempfile.mkdtemp(prefix="colmap_bar_")
    if os.path.isdir(out):
        shutil.rmtree(out)
    os.makedirs(out)
    images = os.path.join(out, "images")
    photos(images, size, None)
    sparse, _ = reconstruct(work, images, "SIMPLE_RADIAL")
    shutil.copytree(sparse, os.path.join(out, "sparse"))
    shutil.rmtree(work)


def main():
    if not os.path.isdir(LEGO):
        sys.exit(f"{LEGO} is absent")
    what = sys.argv[1] if len(sys.argv) > 1 else "fixtures"
    if what == "fixtures":
        out = os.path.join(ROOT, "tests", "data", "colmap_workspaces")
        for model in sys.argv[2:] or list(DISTORTIONS):
            fixture(model, out, SIZE)
    elif what == "references":
        out = os.path.join(ROOT, "tests", "data", "colmap_workspaces")
        for model in sys.argv[2:] or list(DISTORTIONS):
            references(os.path.join(out, model.lower()), model, SIZE)
    elif what == "bar":
        bar(sys.argv[2], 400)
    else:
        sys.exit("usage: make-colmap-workspaces.py [fixtures [MODEL...] | references [MODEL...] | bar OUT]")


if __name__ == "__main__":
    main()
