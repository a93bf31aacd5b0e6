//! Lens undistortion of COLMAP's camera models, so that photos taken through a real lens become
//! the pinhole images NeRF's cameras assume.
//!
//! The maths is COLMAP's (`colmap/src/colmap/sensor/models.h`, `image/undistortion.cc`,
//! `image/warp.cc`), checked against pycolmap's own functions in `mipnerf-data/tests/undistort.rs`:
//! - a camera maps a point `(u, v)` in normalised coordinates (`x / z`, `y / z`) to pixels by
//!   adding the model's distortion `(du, dv)` and then `x = fx (u + du) + cx`,
//!   `y = fy (v + dv) + cy`; pixel centres are at `i + 0.5` (the top-left corner of the image is
//!   `(0, 0)`);
//! - the inverse (pixels to normalised coordinates) solves the distortion by Newton's method
//!   with a numerical Jacobian, as COLMAP's `IterativeUndistortion`;
//! - an undistorted image is warped pixel by pixel: the output pixel's centre through the
//!   pinhole's inverse, then through the distorted camera, sampled bilinearly.
//!
//! Where this module differs from COLMAP's undistorter on purpose: the output is the pinhole NeRF
//! and the LLFF format want, one focal length (the larger of `fx`, `fy`, so neither axis loses
//! resolution) and the principal point at the image centre, cropped to the largest such image
//! with no blank pixels (COLMAP keeps `fx != fy` and the principal point where it was).

use crate::colmap::{CameraModel, ColmapCamera, intrinsics, model_name, model_of, model_param_count};

/// COLMAP's lens distortion models, with their coefficients.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Distortion {
    /// No distortion (SIMPLE_PINHOLE, PINHOLE).
    None,
    /// SIMPLE_RADIAL: `k`.
    SimpleRadial {
        /// Radial coefficient of r².
        k: f64,
    },
    /// RADIAL: `k1, k2`.
    Radial {
        /// Radial coefficient of r².
        k1: f64,
        /// Radial coefficient of r⁴.
        k2: f64,
    },
    /// OPENCV: `k1, k2, p1, p2`.
    Opencv {
        /// Radial coefficient of r².
        k1: f64,
        /// Radial coefficient of r⁴.
        k2: f64,
        /// Tangential coefficient.
        p1: f64,
        /// Tangential coefficient.
        p2: f64,
    },
}

impl Distortion {
    /// The offset `(du, dv)` the lens adds to the normalised point `(u, v)` (COLMAP's
    /// `Distortion` functions).
    #[must_use]
    pub fn offset(self, u: f64, v: f64) -> (f64, f64) {
        let (u2, v2) = (u * u, v * v);
        let r2 = u2 + v2;
        match self {
            Self::None => (0.0, 0.0),
            Self::SimpleRadial { k } => (u * k * r2, v * k * r2),
            Self::Radial { k1, k2 } => {
                let radial = k1 * r2 + k2 * r2 * r2;
                (u * radial, v * radial)
            }
            Self::Opencv { k1, k2, p1, p2 } => {
                let uv = u * v;
                let radial = k1 * r2 + k2 * r2 * r2;
                (u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2), v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2))
            }
        }
    }

    /// The distorted normalised point of `(u, v)`.
    #[must_use]
    pub fn distort(self, u: f64, v: f64) -> (f64, f64) {
        let (du, dv) = self.offset(u, v);
        (u + du, v + dv)
    }

    /// The undistorted point whose distortion is `(x, y)`: Newton's method with a central
    /// numerical Jacobian, COLMAP's `IterativeUndistortion` (at most 100 iterations, stopping when
    /// a step is below 1e-10). Where the model folds over (far outside the image), the result is
    /// the iteration's last point.
    #[must_use]
    pub fn undistort(self, x: f64, y: f64) -> (f64, f64) {
        if self == Self::None {
            return (x, y);
        }
        const ITERATIONS: usize = 100;
        const MAX_STEP: f64 = 1e-10;
        const REL_STEP: f64 = 1e-6;
        let (mut u, mut v) = (x, y);
        for _ in 0..ITERATIONS {
            let hu = (REL_STEP * u.abs()).max(f64::EPSILON);
            let hv = (REL_STEP * v.abs()).max(f64::EPSILON);
            let (fx, fy) = self.distort(u, v);
            let (ru, rv) = (fx - x, fy - y);
            let (a1, a2) = self.distort(u - hu, v);
            let (b1, b2) = self.distort(u + hu, v);
            let (c1, c2) = self.distort(u, v - hv);
            let (d1, d2) = self.distort(u, v + hv);
            let (j00, j10) = ((b1 - a1) / (2.0 * hu), (b2 - a2) / (2.0 * hu));
            let (j01, j11) = ((d1 - c1) / (2.0 * hv), (d2 - c2) / (2.0 * hv));
            let det = j00 * j11 - j01 * j10;
            if det == 0.0 || !det.is_finite() {
                break;
            }
            let su = (j11 * ru - j01 * rv) / det;
            let sv = (-j10 * ru + j00 * rv) / det;
            u -= su;
            v -= sv;
            if su * su + sv * sv < MAX_STEP * MAX_STEP {
                break;
            }
        }
        (u, v)
    }
}

/// A camera through a real lens: focal lengths and principal point in pixels, image size, and
/// the lens's distortion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensCamera {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (pixel centres at `i + 0.5`).
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// The lens's distortion.
    pub distortion: Distortion,
}

impl LensCamera {
    /// The camera of a COLMAP camera record.
    ///
    /// # Errors
    /// A model this module does not undistort (the fisheye and exotic ones: its name, and which
    /// are supported), a parameter count that does not fit the model, or a size or focal length
    /// that is not positive and finite.
    pub fn from_colmap(c: &ColmapCamera) -> Result<Self, String> {
        const MAX_DISTORTION: f64 = 2.0;
        let name = model_name(c.model_id);
        let Some(model) = model_of(c.model_id) else {
            return Err(format!(
                "camera {} is {name}, which mipnerf cannot undistort (supported: SIMPLE_PINHOLE, PINHOLE, \
                 SIMPLE_RADIAL, RADIAL, OPENCV); undistort it with COLMAP first (colmap image_undistorter)",
                c.id
            ));
        };
        let want = model_param_count(c.model_id).unwrap_or(0);
        if c.params.len() != want {
            return Err(format!("camera {} ({name}) has {} parameters, the model has {want}", c.id, c.params.len()));
        }
        let (fx, fy, cx, cy, k) = intrinsics(model, &c.params);
        let distortion = match model {
            CameraModel::SimplePinhole | CameraModel::Pinhole => Distortion::None,
            CameraModel::SimpleRadial => Distortion::SimpleRadial { k: k[0] },
            CameraModel::Radial => Distortion::Radial { k1: k[0], k2: k[1] },
            CameraModel::Opencv => Distortion::Opencv { k1: k[0], k2: k[1], p1: k[2], p2: k[3] },
        };
        let (width, height) = (u32::try_from(c.width).unwrap_or(0), u32::try_from(c.height).unwrap_or(0));
        if !(fx > 0.0 && fy > 0.0 && fx.is_finite() && fy.is_finite() && width > 0 && height > 0)
            || !(cx.is_finite() && cy.is_finite())
        {
            return Err(format!(
                "camera {}: focal lengths {fx}, {fy} and size {}x{} must be positive and finite",
                c.id, c.width, c.height
            ));
        }
        // Lens values no photo has: a field of view outside what the loaders take, a principal
        // point outside the picture, a distortion that folds the picture over itself.
        let (lo, hi) = (mipnerf_core::camera::MIN_FIELD_OF_VIEW_DEG, mipnerf_core::camera::MAX_FIELD_OF_VIEW_DEG);
        for (axis, focal, side) in [("horizontal", fx, f64::from(width)), ("vertical", fy, f64::from(height))] {
            let fov = 2.0 * (side / (2.0 * focal)).atan().to_degrees();
            if !(lo..=hi).contains(&fov) {
                return Err(format!(
                    "camera {}: a focal length of {} px gives a {axis} field of view of {} degrees over {side} px; \
                     photos have {lo} to {hi}",
                    c.id,
                    crate::show(focal),
                    crate::show(fov),
                ));
            }
        }
        if !((0.0..=f64::from(width)).contains(&cx) && (0.0..=f64::from(height)).contains(&cy)) {
            return Err(format!(
                "camera {}: the principal point ({}, {}) lies outside the {width}x{height} picture",
                c.id,
                crate::show(cx),
                crate::show(cy)
            ));
        }
        if let Some(&bad) = k.iter().find(|x| !(x.is_finite() && x.abs() <= MAX_DISTORTION)) {
            return Err(format!(
                "camera {} ({name}): a distortion coefficient of {} is beyond any lens's (at most {MAX_DISTORTION} in \
                 size)",
                c.id,
                crate::show(bad)
            ));
        }
        Ok(Self { fx, fy, cx, cy, width, height, distortion })
    }

    /// The pixel of the normalised point `(u, v)` (COLMAP's `ImgFromCam`).
    #[must_use]
    pub fn img_from_cam(&self, u: f64, v: f64) -> (f64, f64) {
        let (x, y) = self.distortion.distort(u, v);
        (self.fx * x + self.cx, self.fy * y + self.cy)
    }

    /// The normalised point of the pixel `(x, y)` (COLMAP's `CamFromImg`).
    #[must_use]
    pub fn cam_from_img(&self, x: f64, y: f64) -> (f64, f64) {
        self.distortion.undistort((x - self.cx) / self.fx, (y - self.cy) / self.fy)
    }
}

/// A pinhole camera with one focal length and its principal point at the image centre, what
/// NeRF and the LLFF format assume.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pinhole {
    /// Focal length in pixels.
    pub focal: f64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl Pinhole {
    /// The normalised point of the pixel `(x, y)`.
    #[must_use]
    pub fn cam_from_img(&self, x: f64, y: f64) -> (f64, f64) {
        ((x - f64::from(self.width) / 2.0) / self.focal, (y - f64::from(self.height) / 2.0) / self.focal)
    }
}

/// The pinhole `lens`'s photos undistort to: focal `max(fx, fy)`, centred, and the largest size
/// whose every pixel sees inside the photo (no blank pixels), found from the undistorted image
/// of the photo's border as COLMAP's undistorter finds it; at most twice and at least a fifth of
/// the photo's size along each axis (COLMAP's default scale limits).
#[must_use]
pub fn undistorted_pinhole(lens: &LensCamera) -> Pinhole {
    let focal = lens.fx.max(lens.fy);
    let (w, h) = (lens.width, lens.height);
    if lens.distortion == Distortion::None && lens.fx == lens.fy {
        // Only a re-centring would change: the same size when the principal point is central.
        let half_w = lens.cx.min(f64::from(w) - lens.cx);
        let half_h = lens.cy.min(f64::from(h) - lens.cy);
        return Pinhole {
            focal,
            width: ((2.0 * half_w).floor() as u32).max(1),
            height: ((2.0 * half_h).floor() as u32).max(1),
        };
    }
    // The photo's border (pixel centres along its edges) in normalised coordinates.
    let (mut left, mut right, mut top, mut bottom) =
        (f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY);
    for y in 0..h {
        let yc = f64::from(y) + 0.5;
        left = left.max(lens.cam_from_img(0.5, yc).0);
        right = right.min(lens.cam_from_img(f64::from(w) - 0.5, yc).0);
    }
    for x in 0..w {
        let xc = f64::from(x) + 0.5;
        top = top.max(lens.cam_from_img(xc, 0.5).1);
        bottom = bottom.min(lens.cam_from_img(xc, f64::from(h) - 0.5).1);
    }
    // Centred on the optical axis, so the half-extent is the nearer side's; the pixel centres of
    // the output's outermost pixels lie half a pixel inside its edge.
    let half_u = (-left).min(right).max(0.0);
    let half_v = (-top).min(bottom).max(0.0);
    let clip = |n: f64, orig: u32| -> u32 {
        let lo = (f64::from(orig) * 0.2).ceil();
        let hi = f64::from(orig) * 2.0;
        n.floor().clamp(lo.max(1.0), hi.max(1.0)) as u32
    };
    Pinhole { focal, width: clip(2.0 * (half_u * focal + 0.5), w), height: clip(2.0 * (half_v * focal + 0.5), h) }
}

impl From<Pinhole> for LensCamera {
    /// The pinhole as a lens without distortion, the target of [`warp`].
    fn from(p: Pinhole) -> Self {
        Self {
            fx: p.focal,
            fy: p.focal,
            cx: f64::from(p.width) / 2.0,
            cy: f64::from(p.height) / 2.0,
            width: p.width,
            height: p.height,
            distortion: Distortion::None,
        }
    }
}

/// Pixels: how far outside the outermost pixel centres a sample may fall from rounding alone and
/// still be taken from them.
const EDGE_SLACK: f64 = 1e-6;

/// Warps a photo taken through `lens` (interleaved 8-bit pixels, `channels` a pixel, `lens`'s
/// size) into the camera `target` (a pinhole: [`undistorted_pinhole`]'s, or COLMAP's undistorted
/// camera with its own focal lengths and principal point): every target pixel centre through the pinhole's inverse and
/// `lens`'s projection, sampled bilinearly (COLMAP's `WarpImageBetweenCameras`); a pixel whose
/// sample falls outside the photo is 0. Rounds to the nearest 8-bit value.
///
/// # Panics
/// If `pixels` is shorter than `lens`'s size times `channels`.
#[must_use]
pub fn warp(pixels: &[u8], channels: usize, lens: &LensCamera, target: &LensCamera) -> Vec<u8> {
    let (sw, sh) = (lens.width as usize, lens.height as usize);
    assert!(pixels.len() >= sw * sh * channels, "warp: {} bytes for {sw}x{sh}x{channels}", pixels.len());
    let (tw, th) = (target.width as usize, target.height as usize);
    let mut out = vec![0u8; tw * th * channels];
    let at = |x: usize, y: usize, c: usize| f64::from(pixels[(y * sw + x) * channels + c]);
    for y in 0..th {
        for x in 0..tw {
            let (u, v) = target.cam_from_img(x as f64 + 0.5, y as f64 + 0.5);
            let (px, py) = lens.img_from_cam(u, v);
            // A position within rounding error of the outermost pixel centres is on them (a
            // centred pinhole maps x to x + 1e-13 or so).
            let snap = |s: f64, last: f64| {
                if s < 0.0 && s > -EDGE_SLACK {
                    0.0
                } else if s > last && s < last + EDGE_SLACK {
                    last
                } else {
                    s
                }
            };
            let (sx, sy) = (snap(px - 0.5, (sw - 1) as f64), snap(py - 0.5, (sh - 1) as f64));
            // COLMAP's InterpolateBilinear: inside when both neighbours exist.
            if !(sx >= 0.0 && sy >= 0.0 && sx <= (sw - 1) as f64 && sy <= (sh - 1) as f64) {
                continue;
            }
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(sw - 1), (y0 + 1).min(sh - 1));
            let (fx, fy) = (sx - x0 as f64, sy - y0 as f64);
            let o = (y * tw + x) * channels;
            for c in 0..channels {
                let top = at(x0, y0, c) * (1.0 - fx) + at(x1, y0, c) * fx;
                let bottom = at(x0, y1, c) * (1.0 - fx) + at(x1, y1, c) * fx;
                out[o + c] = (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}
