"""Camera poses for a folder of photos with PyPI's pycolmap, exactly as the README's "Train on your
own photos" step 1 (SIFT with one shared camera, exhaustive matching, incremental mapping), for
the own-photos route of a real capture (docs/results/fern/colmap).

Usage (through scripts/colmap-photos.sh, which makes the virtual environment):
  bash scripts/colmap-photos.sh ../shared/data/llff/fern/photos_1008 WORKSPACE
The photos are copied to WORKSPACE/images; the models go to WORKSPACE/sparse/N.
"""

import os
import shutil
import sys
import time

import pycolmap


def main():
    photos, ws = sys.argv[1], sys.argv[2]
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
    pycolmap.extract_features(db, f"{ws}/images", camera_mode=pycolmap.CameraMode.SINGLE, extraction_options=ex)
    pycolmap.match_exhaustive(db)
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.mapper.init_min_num_inliers = 50
    mapping.mapper.abs_pose_min_num_inliers = 15
    models = pycolmap.incremental_mapping(db, f"{ws}/images", f"{ws}/sparse", options=mapping)
    sizes = {k: m.num_reg_images() for k, m in models.items()}
    print(f"{ws}: models {sizes} (registered photos per model) in {time.time() - t:.0f} s")


if __name__ == "__main__":
    main()
