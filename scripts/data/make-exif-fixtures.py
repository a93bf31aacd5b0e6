"""Makes the EXIF fixtures of the process step's focal-length check (tests/data/exif/): tiny JPEGs
whose EXIF carries the tags `data::focal::exif_focal` reads, written by Pillow (an EXIF writer the
project does not share code with).

Run: `python3 scripts/data/make-exif-fixtures.py` (Pillow).
"""

import os

from PIL import Image
from PIL.TiffImagePlugin import IFDRational

OUT = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "tests", "data", "exif")
EXIF_IFD = 0x8769
FOCAL_LENGTH = 0x920A
FOCAL_35MM = 0xA405
PLANE_X_RES = 0xA20E
PLANE_Y_RES = 0xA20F
PLANE_UNIT = 0xA210
PIXEL_X = 0xA002
PIXEL_Y = 0xA003


def write(name, size, tags):
    img = Image.new("RGB", size, (90, 120, 150))
    exif = Image.Exif()
    exif[0x010F] = "NIKON CORPORATION"  # Make
    exif[0x0110] = "NIKON D3300"  # Model
    sub = exif.get_ifd(EXIF_IFD)
    for k, v in tags.items():
        sub[k] = v
    img.save(os.path.join(OUT, name), quality=90, exif=exif)


def main():
    os.makedirs(OUT, exist_ok=True)
    # ethiopian_head's tags: a 31 mm lens, 46 mm in 35 mm terms, recorded 4000x4000 (a square crop
    # of the D3300's 6000x4000 frame, later downscaled).
    crop = {FOCAL_LENGTH: IFDRational(31, 1), FOCAL_35MM: 46, PIXEL_X: 4000, PIXEL_Y: 4000}
    write("film35_square.jpg", (20, 20), crop)
    write("film35_whole.jpg", (30, 20), {FOCAL_LENGTH: IFDRational(31, 1), FOCAL_35MM: 46})
    # The D3300's sensor: 6000 px over 23.5 mm (2553.19 px per cm).
    plane = {
        FOCAL_LENGTH: IFDRational(31, 1),
        FOCAL_35MM: 46,
        PLANE_X_RES: IFDRational(600000, 235),
        PLANE_Y_RES: IFDRational(600000, 235),
        PLANE_UNIT: 3,
        PIXEL_X: 6000,
        PIXEL_Y: 4000,
    }
    write("focal_plane.jpg", (30, 20), plane)
    write("focal_plane_cropped.jpg", (20, 20), plane)
    Image.new("RGB", (20, 20), (90, 120, 150)).save(os.path.join(OUT, "no_exif.jpg"), quality=90)
    # For the fixture COLMAP workspace (320x320 lego photos, COLMAP's focal about 444 px): EXIF
    # that agrees (33 mm in 35 mm terms: 440 px for a square crop) and that does not (66 mm).
    write("square_33mm.jpg", (8, 8), {FOCAL_35MM: 33})
    write("square_66mm.jpg", (8, 8), {FOCAL_35MM: 66})


if __name__ == "__main__":
    main()
