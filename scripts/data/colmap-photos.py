"""Camera poses for a folder of photos with PyPI's pycolmap, exactly as the README's "Train on your
own photos" step 1 (SIFT with one shared camera, exhaustive matching, incremental mapping), for
the own-photos route of a real capture (docs/results/fern/colmap).

Usage (through scripts/data/colmap-photos.sh, which makes the virtual environment):
  bash scripts/data/colmap-photos.sh ../shared/data/llff/fern/photos_1008 WORKSPACE [FOCAL]
The photos are copied to WORKSPACE/images; the models go to WORKSPACE/sparse/N. With FOCAL (pixels),
the feature extractor is given the camera (SIMPLE_RADIAL, that focal length, the principal point at
the photos' centre, no distortion), as `mipnerf colmap` advises when COLMAP's focal length and the
photos' EXIF disagree, and the mapper keeps it (it refines the distortion and the poses, not the
focal length: on ethiopian_head a mapper refining it from 1917 px went back to 1335 px, trading
focal length for radial distortion).
"""

import os
import shutil
import sys
import time

import pycolmap


def main():
    photos, ws = sys.argv[1], sys.argv[2]
    reader = pycolmap.ImageReaderOptions()
    if len(sys.argv) > 3:
        from PIL import Image

        first = sorted(os.listdir(photos))[0]
        w, h = Image.open(os.path.join(photos, first)).size
        reader.camera_model = "SIMPLE_RADIAL"
        reader.camera_params = f"{float(sys.argv[3])},{w / 2},{h / 2},0"
    os.makedirs(f"{ws}/images", exist_ok=True)
    os.makedirs(f"{ws}/sparse", exist_ok=True)
    for name in sorted(os.listdir(photos)):
        shutil.copy(os.path.join(photos, name), os.path.join(ws, "images", name))
    db = f"{ws}/database.db"
    t = time.time()
    ex = pycolmap.FeatureExtractionOptions()
    ex.sift.domain_size_pooling = True
    ex.sift.estimate_affine_shape = True
    ex.sift.peak_threshold = 0.004
    pycolmap.extract_features(db, f"{ws}/images", camera_mode=pycolmap.CameraMode.SINGLE, extraction_options=ex,
                              reader_options=reader)
    pycolmap.match_exhaustive(db)
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.mapper.init_min_num_inliers = 50
    mapping.mapper.abs_pose_min_num_inliers = 15
    if len(sys.argv) > 3:
        mapping.ba_refine_focal_length = False
        mapping.mapper.abs_pose_refine_focal_length = False
    models = pycolmap.incremental_mapping(db, f"{ws}/images", f"{ws}/sparse", options=mapping)
    sizes = {k: m.num_reg_images() for k, m in models.items()}
    print(f"{ws}: models {sizes} (registered photos per model) in {time.time() - t:.0f} s")
    for k, m in models.items():
        print(f"  sparse/{k}: camera {[list(c.params) for c in m.cameras.values()]}")


if __name__ == "__main__":
    main()
