//! The focal length, in pixels, that a photo's EXIF implies: what the process step checks
//! COLMAP's estimate against (a mapper started from a wrong focal length settles on a wrong one,
//! and every pose with it).
//!
//! Two routes, the first that the photo's EXIF allows:
//! 1. The lens's focal length (`FocalLength`, mm) over the sensor's pixel pitch
//!    (`FocalPlaneXResolution` and its unit), scaled from the size the camera recorded
//!    (`PixelXDimension`) to the photo's. Exact, but taken only when the recorded size has the
//!    photo's aspect ratio (else the photo was cropped or rotated after the camera wrote it, and
//!    which pixels the pitch refers to is unknown).
//! 2. The 35 mm-equivalent focal length (`FocalLengthIn35mmFilm`), which refers to the camera's
//!    whole frame, as 43.27 mm (the diagonal of 36 x 24 mm film) refers to film's
//!    ([`FILM_DIAGONAL_MM`]). A photo with a camera frame's aspect ratio ([`CAMERA_ASPECTS`]) is
//!    taken as the whole frame: `f = f35 · diagonal / 43.27`. Any other aspect ratio (a square, a
//!    panorama strip) is a crop of the frame, taken as keeping the frame's short side, as a
//!    centred crop does: `f = f35 · short side / 24` ([`FILM_SHORT_SIDE_MM`]; exact for a 3:2
//!    frame, 8% long for a 4:3 one).
//!
//! The 35 mm-equivalent is a whole number of millimetres, so route 2 is good to a few percent;
//! [`FOCAL_MISMATCH_FACTOR`] sits well above both routes' error and well below the factors a
//! wrong prior gives (a crop factor of 1.5 here).

use std::path::Path;

/// The diagonal of the 36 x 24 mm film frame (mm), which a 35 mm-equivalent focal length refers
/// to.
pub const FILM_DIAGONAL_MM: f64 = 43.266_615_305_567_87;

/// The short side of the 36 x 24 mm film frame (mm).
pub const FILM_SHORT_SIDE_MM: f64 = 24.0;

/// The aspect ratios (long over short side) of cameras' whole frames: 3:2, 4:3, 16:9.
pub const CAMERA_ASPECTS: [f64; 3] = [1.5, 4.0 / 3.0, 16.0 / 9.0];

/// A photo whose aspect ratio is within this relative distance of one of [`CAMERA_ASPECTS`] is
/// taken as the camera's whole frame (1% is 40 px of a 4000 px side).
pub const ASPECT_TOLERANCE: f64 = 0.01;

/// COLMAP's focal length and the one the photos' EXIF implies disagree when one exceeds the
/// other by more than this factor.
pub const FOCAL_MISMATCH_FACTOR: f64 = 1.25;

/// Where an EXIF focal length in pixels came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FocalSource {
    /// The lens's focal length over the sensor's pixel pitch.
    FocalPlane {
        /// `FocalLength`, mm.
        focal_mm: f64,
        /// The sensor's pixels per mm at the photo's size.
        pixels_per_mm: f64,
    },
    /// The 35 mm-equivalent focal length.
    Film35mm {
        /// `FocalLengthIn35mmFilm`, mm.
        focal_35mm: f64,
        /// Whether the photo was taken as a crop of the frame (its aspect ratio is no camera's).
        cropped: bool,
    },
}

/// The focal length a photo's EXIF implies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExifFocal {
    /// In pixels of the photo as it is.
    pub focal_px: f64,
    /// How it was found.
    pub source: FocalSource,
}

impl std::fmt::Display for ExifFocal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.source {
            FocalSource::FocalPlane { focal_mm, pixels_per_mm } => {
                write!(f, "{:.0} px (a {focal_mm} mm lens, the sensor's {pixels_per_mm:.1} px per mm)", self.focal_px)
            }
            FocalSource::Film35mm { focal_35mm, cropped: false } => {
                write!(f, "{:.0} px ({focal_35mm} mm in 35 mm terms, the photo the whole frame)", self.focal_px)
            }
            FocalSource::Film35mm { focal_35mm, cropped: true } => write!(
                f,
                "{:.0} px ({focal_35mm} mm in 35 mm terms; the photo's aspect ratio is no camera frame's, so it is taken \
                 as a crop keeping the frame's short side)",
                self.focal_px
            ),
        }
    }
}

/// The focal length, in pixels, that the EXIF of the photo `path` (`width x height` as it is)
/// implies (see the module docs), or `None` when it has no EXIF or no usable focal length: no
/// check, not an error.
#[must_use]
pub fn exif_focal(path: &Path, width: u32, height: u32) -> Option<ExifFocal> {
    use exif::{In, Tag, Value};
    let file = mipnerf_core::io::open_regular(path).ok()?;
    let data = exif::Reader::new().read_from_container(&mut std::io::BufReader::new(file)).ok()?;
    let real = |tag: Tag| -> Option<f64> {
        let field = data.get_field(tag, In::PRIMARY)?;
        let v = match &field.value {
            Value::Rational(r) => r.first()?.to_f64(),
            Value::SRational(r) => r.first()?.to_f64(),
            v => f64::from(v.get_uint(0)?),
        };
        (v.is_finite() && v > 0.0).then_some(v)
    };
    let (w, h) = (f64::from(width), f64::from(height));
    if width == 0 || height == 0 {
        return None;
    }
    // Route 1: the sensor's pixel pitch, at the size the camera recorded.
    let plane = || -> Option<ExifFocal> {
        let focal_mm = real(Tag::FocalLength)?;
        let resolution = real(Tag::FocalPlaneXResolution)?;
        // The unit: 2 inch (the default), 3 cm, 4 mm, 5 µm.
        let unit_mm = match data.get_field(Tag::FocalPlaneResolutionUnit, In::PRIMARY).and_then(|f| f.value.get_uint(0))
        {
            None | Some(2) => 25.4,
            Some(3) => 10.0,
            Some(4) => 1.0,
            Some(5) => 1e-3,
            Some(_) => return None,
        };
        let (rw, rh) = (real(Tag::PixelXDimension)?, real(Tag::PixelYDimension)?);
        if ((rw / rh) / (w / h) - 1.0).abs() > ASPECT_TOLERANCE {
            return None;
        }
        let pixels_per_mm = resolution / unit_mm * (w / rw);
        Some(ExifFocal {
            focal_px: focal_mm * pixels_per_mm,
            source: FocalSource::FocalPlane { focal_mm, pixels_per_mm },
        })
    };
    // Route 2: the 35 mm equivalent.
    let film = || -> Option<ExifFocal> {
        let focal_35mm = real(Tag::FocalLengthIn35mmFilm)?;
        let aspect = w.max(h) / w.min(h);
        let cropped = !CAMERA_ASPECTS.iter().any(|a| (aspect / a - 1.0).abs() <= ASPECT_TOLERANCE);
        let focal_px = if cropped {
            focal_35mm * w.min(h) / FILM_SHORT_SIDE_MM
        } else {
            focal_35mm * w.hypot(h) / FILM_DIAGONAL_MM
        };
        Some(ExifFocal { focal_px, source: FocalSource::Film35mm { focal_35mm, cropped } })
    };
    plane().or_else(film)
}

/// The process step's check of COLMAP's focal length against the photos' EXIF.
#[derive(Clone, Debug, PartialEq)]
pub struct FocalCheck {
    /// COLMAP's focal length, pixels (the geometric mean of `fx` and `fy`).
    pub colmap_px: f64,
    /// The median photo's EXIF focal length ([`exif_focal`]), and that photo's name.
    pub exif: ExifFocal,
    /// The photo it was read from.
    pub photo: String,
    /// How many of the registered photos had one.
    pub photos_with_exif: usize,
}

impl FocalCheck {
    /// The larger of the two focal lengths over the smaller.
    #[must_use]
    pub fn ratio(&self) -> f64 {
        let (a, b) = (self.colmap_px, self.exif.focal_px);
        a.max(b) / a.min(b)
    }

    /// Whether they disagree by more than [`FOCAL_MISMATCH_FACTOR`].
    #[must_use]
    pub fn disagrees(&self) -> bool {
        self.ratio() > FOCAL_MISMATCH_FACTOR
    }
}

/// Checks COLMAP's focal length `colmap_px` against the EXIF of `photos` (`(name, path)`, all
/// `width x height`): the median of the focal lengths their EXIF implies. `None` when no photo
/// has one.
#[must_use]
pub fn check_focal(
    colmap_px: f64,
    photos: &[(String, std::path::PathBuf)],
    width: u32,
    height: u32,
) -> Option<FocalCheck> {
    let mut found: Vec<(String, ExifFocal)> =
        photos.iter().filter_map(|(name, path)| exif_focal(path, width, height).map(|f| (name.clone(), f))).collect();
    if found.is_empty() {
        return None;
    }
    found.sort_by(|a, b| a.1.focal_px.total_cmp(&b.1.focal_px));
    let photos_with_exif = found.len();
    let (photo, exif) = found.swap_remove(photos_with_exif / 2);
    Some(FocalCheck { colmap_px, exif, photo, photos_with_exif })
}
