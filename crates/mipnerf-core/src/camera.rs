//! Pinhole cameras: pixels to world-space rays. The cone each ray stands for, and its Gaussians,
//! live in [`crate::cone`].
//!
//! Conventions are OpenGL/Blender's: the camera looks down `-z` with `y` up, and `cam2world` maps
//! camera coordinates to world coordinates. Directions are *not* normalised, so `t` along a ray is
//! depth along the camera axis; [`Ray::viewdir`] is the normalised direction.

use glam::Vec3;

use crate::Error;
use crate::cone::{Ray, radius_from_spacing};

/// Where a pixel's ray passes through the pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelCenters {
    /// Through the pixel's centre (`x + 0.5`): Mip-NeRF, and the "centered pixels" switch.
    #[default]
    Centered,
    /// Through the pixel's top-left corner (`x`): the NeRF baseline of the paper's table.
    Corner,
}

impl PixelCenters {
    /// The offset added to integer pixel coordinates.
    #[must_use]
    pub const fn offset(self) -> f64 {
        match self {
            Self::Centered => 0.5,
            Self::Corner => 0.0,
        }
    }
}

/// A pinhole camera: image size, intrinsics as a `pix2cam` matrix, and a camera-to-world pose.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Maps homogeneous pixel coordinates `(x, y, 1)` to camera-space directions (row-major 3x3).
    pub pix2cam: [[f64; 3]; 3],
    /// Camera-to-world transform, the top 3 rows of a 4x4 matrix (row-major).
    pub cam2world: [[f64; 4]; 3],
}

/// The focal length in pixels of a camera whose horizontal field of view is `camera_angle_x`
/// radians (Blender's `transforms.json`): `0.5 W / tan(0.5 camera_angle_x)`.
#[must_use]
pub fn focal_from_camera_angle_x(width: u32, camera_angle_x: f64) -> f64 {
    0.5 * f64::from(width) / (0.5 * camera_angle_x).tan()
}

/// The official `pix2cam` of a pinhole with focal length `focal` (pixels), principal point at the
/// image centre, OpenGL axes: `[[1/f, 0, -W/2f], [0, -1/f, H/2f], [0, 0, -1]]`.
#[must_use]
pub fn pinhole_pix2cam(width: u32, height: u32, focal: f64) -> [[f64; 3]; 3] {
    let (w, h) = (f64::from(width), f64::from(height));
    [[1.0 / focal, 0.0, -0.5 * w / focal], [0.0, -1.0 / focal, 0.5 * h / focal], [0.0, 0.0, -1.0]]
}

/// The narrowest horizontal or vertical field of view a camera may have, in degrees (a 1000 mm
/// lens on a full-frame sensor has 2 degrees; 0.01 is a telescope's).
pub const MIN_FIELD_OF_VIEW_DEG: f64 = 0.01;

/// The widest field of view a pinhole camera may have, in degrees (180 is a pinhole's limit).
pub const MAX_FIELD_OF_VIEW_DEG: f64 = 179.0;

/// The largest magnitude of a camera position or a near/far distance, in scene units. The
/// integrated positional encoding multiplies positions by up to 2^15 in `f32`; beyond this the
/// features carry no information and products of distances approach `f32`'s range.
pub const MAX_SCENE_COORDINATE: f64 = 1e6;

/// The lengths a ray direction may have at the image's corners (`pix2cam · [x, y, 1]`, camera
/// units): the directions scale every distance along the rays (near, far, the samples), and are
/// stored in f32, so a pix2cam that overflows or vanishes there is refused (a camera's own is
/// about 1 to 2).
pub const DIRECTION_LENGTH_RANGE: (f64, f64) = (1e-6, 1e6);

/// The accepted lengths of a pose's rotation columns (the camera axes in world units): a pose is
/// a rotation and a translation, so each is 1 up to rounding; these bounds allow sloppy exports.
pub const AXIS_LENGTH_RANGE: (f64, f64) = (0.5, 2.0);

fn check_finite(what: &str, values: impl IntoIterator<Item = f64>) -> Result<(), Error> {
    if values.into_iter().all(f64::is_finite) {
        Ok(())
    } else {
        Err(Error::InvalidCamera(format!("{what} has a non-finite entry")))
    }
}

impl Camera {
    /// A pinhole camera from Blender's horizontal field of view `camera_angle_x` (radians).
    ///
    /// # Errors
    /// [`Error::InvalidCamera`] for a zero size, a non-positive or non-finite angle, or a pose that
    /// is non-finite or whose rotation is singular.
    pub fn from_camera_angle_x(
        width: u32,
        height: u32,
        camera_angle_x: f64,
        cam2world: [[f64; 4]; 3],
    ) -> Result<Self, Error> {
        let (lo, hi) = (MIN_FIELD_OF_VIEW_DEG.to_radians(), MAX_FIELD_OF_VIEW_DEG.to_radians());
        if !(camera_angle_x.is_finite() && (lo..=hi).contains(&camera_angle_x)) {
            return Err(Error::InvalidCamera(format!(
                "camera_angle_x must be between {lo:.3e} and {hi:.4} radians ({MIN_FIELD_OF_VIEW_DEG} to \
                 {MAX_FIELD_OF_VIEW_DEG} degrees of horizontal field of view), got {camera_angle_x}"
            )));
        }
        let focal = focal_from_camera_angle_x(width, camera_angle_x);
        Self::from_pix2cam(width, height, pinhole_pix2cam(width, height, focal), cam2world)
    }

    /// A camera from a full `pix2cam` matrix (the multiscale format's intrinsics).
    ///
    /// # Errors
    /// [`Error::InvalidCamera`] for a zero size, a non-finite or singular matrix, a field of view
    /// outside [`MIN_FIELD_OF_VIEW_DEG`]..[`MAX_FIELD_OF_VIEW_DEG`], a camera position beyond
    /// [`MAX_SCENE_COORDINATE`], or rotation columns whose lengths are outside
    /// [`AXIS_LENGTH_RANGE`].
    pub fn from_pix2cam(
        width: u32,
        height: u32,
        pix2cam: [[f64; 3]; 3],
        cam2world: [[f64; 4]; 3],
    ) -> Result<Self, Error> {
        if width == 0 || height == 0 {
            return Err(Error::InvalidCamera(format!("image size {width}x{height} is empty")));
        }
        check_finite("pix2cam", pix2cam.iter().flatten().copied())?;
        check_finite("cam2world", cam2world.iter().flatten().copied())?;
        if det3(|r, c| pix2cam[r][c]).abs() < 1e-300 {
            return Err(Error::InvalidCamera("pix2cam is singular".into()));
        }
        let det = det3(|r, c| cam2world[r][c]);
        if det.abs() < 1e-6 {
            return Err(Error::InvalidCamera(format!("cam2world rotation is singular (determinant {det:e})")));
        }
        if pix2cam[2][2] == 0.0 {
            return Err(Error::InvalidCamera("pix2cam[2][2] is 0: not a pinhole camera's intrinsics".into()));
        }
        for (axis, side, p) in [("horizontal", width, pix2cam[0][0]), ("vertical", height, pix2cam[1][1])] {
            // The angle the image spans along this axis: 2 atan(side/2 / focal).
            let fov = (2.0 * (0.5 * f64::from(side) * (p / pix2cam[2][2]).abs()).atan()).to_degrees();
            if !(MIN_FIELD_OF_VIEW_DEG..=MAX_FIELD_OF_VIEW_DEG).contains(&fov) {
                let focal = (pix2cam[2][2] / p).abs();
                return Err(Error::InvalidCamera(format!(
                    "the {axis} field of view is {fov:.3e} degrees (focal length {focal:.4e} pixels for {side} \
                     pixels); accepted: {MIN_FIELD_OF_VIEW_DEG} to {MAX_FIELD_OF_VIEW_DEG} degrees"
                )));
            }
        }
        // Every ray within the image must point into the camera's half-space, no further from the
        // axis than half the widest field of view (off-diagonal intrinsics included).
        let max_tan = (0.5 * MAX_FIELD_OF_VIEW_DEG).to_radians().tan();
        for (x, y) in [(0, 0), (width, 0), (0, height), (width, height)] {
            let p = [f64::from(x), f64::from(y), 1.0];
            let d: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| pix2cam[r][c] * p[c]).sum::<f64>());
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if !(DIRECTION_LENGTH_RANGE.0..=DIRECTION_LENGTH_RANGE.1).contains(&len) {
                return Err(Error::InvalidCamera(format!(
                    "pix2cam sends the image corner ({x}, {y}) along a direction of length {len:.4e}; accepted: {:e} \
                     to {:e} (the directions scale every distance along the rays)",
                    DIRECTION_LENGTH_RANGE.0, DIRECTION_LENGTH_RANGE.1
                )));
            }
            let off = d[0].abs().max(d[1].abs()) / d[2].abs();
            if off.is_nan() || off > max_tan {
                return Err(Error::InvalidCamera(format!(
                    "pix2cam sends the image corner ({x}, {y}) {:.2} degrees off the camera axis; accepted: up to {}",
                    off.atan().to_degrees(),
                    0.5 * MAX_FIELD_OF_VIEW_DEG
                )));
            }
        }
        for (c, name) in ["x", "y", "z"].iter().enumerate() {
            let len = (0..3).map(|r| cam2world[r][c] * cam2world[r][c]).sum::<f64>().sqrt();
            if !(AXIS_LENGTH_RANGE.0..=AXIS_LENGTH_RANGE.1).contains(&len) {
                return Err(Error::InvalidCamera(format!(
                    "cam2world's {name} axis (column {c}) has length {len:.4e}; a pose's rotation columns are unit \
                     vectors (accepted lengths {} to {})",
                    AXIS_LENGTH_RANGE.0, AXIS_LENGTH_RANGE.1
                )));
            }
            let t = cam2world[c][3];
            if t.abs() > MAX_SCENE_COORDINATE {
                return Err(Error::InvalidCamera(format!(
                    "cam2world's position [{c}][3] is {t:e}; accepted: at most {MAX_SCENE_COORDINATE:e} in magnitude"
                )));
            }
        }
        Ok(Self { width, height, pix2cam, cam2world })
    }

    /// The camera centre in world space.
    #[must_use]
    pub fn origin(&self) -> [f64; 3] {
        [self.cam2world[0][3], self.cam2world[1][3], self.cam2world[2][3]]
    }

    /// The inverse of [`direction_f64`](Self::direction_f64): what projects world points into
    /// this camera's image. `None` for a singular `pix2cam`.
    #[must_use]
    pub fn projection(&self) -> Option<Projection> {
        let c2w = &self.cam2world;
        Some(Projection {
            rot_t: std::array::from_fn(|r| std::array::from_fn(|c| c2w[c][r])),
            origin: self.origin(),
            cam2pix: invert3(&self.pix2cam)?,
        })
    }

    /// The unnormalised world-space direction through pixel coordinates `(x, y)` (continuous, so
    /// pass `x + 0.5` for a pixel centre).
    #[must_use]
    pub fn direction_f64(&self, x: f64, y: f64) -> [f64; 3] {
        let p = [x, y, 1.0];
        let cam: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| self.pix2cam[r][c] * p[c]).sum::<f64>());
        std::array::from_fn(|r| (0..3).map(|c| self.cam2world[r][c] * cam[c]).sum::<f64>())
    }

    /// The ray through pixel `(x, y)` (integer pixel coordinates, `x` to the right, `y` down),
    /// as the official loaders make it.
    ///
    /// Computed in `f64` and rounded to `f32` once: this agrees with the official Blender loader
    /// (which works in `f32`) to within 1e-7 and with the multiscale loader (`f64`) exactly. The
    /// cone radius is the distance to the next row's direction times `2/sqrt(12)`; the last row
    /// reuses the difference of the row before the last, as the official code does (`dx[-2:-1]`;
    /// with two rows, the only difference; with one row, the column spacing).
    #[must_use]
    pub fn ray_at(&self, x: u32, y: u32, centers: PixelCenters, near: f32, far: f32, lossmult: f32) -> Ray {
        let off = centers.offset();
        let dir = |px: u32, py: u32| self.direction_f64(f64::from(px) + off, f64::from(py) + off);
        let d = dir(x, y);
        let dist =
            |a: [f64; 3], b: [f64; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        let spacing = if self.height == 1 {
            // No row below: the spacing of one pixel step along x.
            dist(self.direction_f64(off, off), self.direction_f64(off + 1.0, off))
        } else {
            let yy = if y + 1 < self.height { y } else { self.height.saturating_sub(3) };
            dist(dir(x, yy), dir(x, yy + 1))
        };
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let o = self.origin();
        Ray {
            origin: Vec3::new(o[0] as f32, o[1] as f32, o[2] as f32),
            direction: Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32),
            viewdir: Vec3::new((d[0] / n) as f32, (d[1] / n) as f32, (d[2] / n) as f32),
            radius: radius_from_spacing(spacing),
            lossmult,
            near,
            far,
        }
    }

    /// One ray per pixel, row-major (`y * width + x`): [`ray_at`](Self::ray_at) for every pixel.
    #[must_use]
    pub fn generate_rays(&self, centers: PixelCenters, near: f32, far: f32, lossmult: f32) -> Vec<Ray> {
        (0..self.height)
            .flat_map(|y| (0..self.width).map(move |x| (x, y)))
            .map(|(x, y)| self.ray_at(x, y, centers, near, far, lossmult))
            .collect()
    }

    /// This camera at `1 / 2^j` of its resolution (sizes halved `j` times, rounding down; focal
    /// length and principal point scaled by `2^-j`), as the multiscale dataset's levels are.
    #[must_use]
    pub fn downscaled(&self, j: u32) -> Self {
        let s = f64::from(1u32 << j);
        let mut p = self.pix2cam;
        // pix2cam maps pixel coordinates; pixels that are s times larger: scale the first two columns.
        for row in &mut p {
            row[0] *= s;
            row[1] *= s;
        }
        Self { width: self.width >> j, height: self.height >> j, pix2cam: p, cam2world: self.cam2world }
    }
}

/// The determinant of the 3x3 matrix whose entry in row `r`, column `c` is `m(r, c)`.
#[must_use]
pub fn det3(m: impl Fn(usize, usize) -> f64) -> f64 {
    m(0, 0) * (m(1, 1) * m(2, 2) - m(1, 2) * m(2, 1)) - m(0, 1) * (m(1, 0) * m(2, 2) - m(1, 2) * m(2, 0))
        + m(0, 2) * (m(1, 0) * m(2, 1) - m(1, 1) * m(2, 0))
}

/// World points to a camera's pixels: [`Camera::projection`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projection {
    /// World-to-camera rotation (the transpose of cam2world's).
    rot_t: [[f64; 3]; 3],
    origin: [f64; 3],
    /// The inverse of `pix2cam`.
    cam2pix: [[f64; 3]; 3],
}

impl Projection {
    /// The continuous pixel coordinates `(x, y)` of world point `p` and its ray parameter `t`
    /// (`p = origin + t direction_f64(x, y)`, so `t` is in the units of the camera's near and far
    /// bounds), or `None` when `p` is not in front of the camera.
    #[must_use]
    pub fn project(&self, p: [f64; 3]) -> Option<(f64, f64, f64)> {
        let d: [f64; 3] = std::array::from_fn(|k| p[k] - self.origin[k]);
        let cam: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| self.rot_t[r][c] * d[c]).sum());
        let pix: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| self.cam2pix[r][c] * cam[c]).sum());
        // pix2cam maps (x, y, 1) to a direction; in front of the camera the third pixel
        // coordinate comes back positive, and it is t.
        (pix[2] > 1e-9).then(|| (pix[0] / pix[2], pix[1] / pix[2], pix[2]))
    }
}

/// The inverse of a 3x3 matrix, `None` when singular.
fn invert3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |r: usize, k: usize| {
        m[(r + 1) % 3][(k + 1) % 3] * m[(r + 2) % 3][(k + 2) % 3]
            - m[(r + 1) % 3][(k + 2) % 3] * m[(r + 2) % 3][(k + 1) % 3]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    if det.abs() < 1e-300 {
        return None;
    }
    Some(std::array::from_fn(|r| std::array::from_fn(|k| c(k, r) / det)))
}

/// A similarity transform of world space, `x ↦ scale · rotation · x + translation`: what a loader
/// does to a dataset's own world frame (COLMAP's, a capture's `transforms.json`'s, LLFF's
/// `poses_bounds.npy`'s) to make the scene's (recentred, rescaled, spherified), so that cameras
/// given in the data's frame can be rendered (`Dataset::data_to_scene`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    /// The rotation (row-major, orthonormal, determinant 1).
    pub rotation: [[f64; 3]; 3],
    /// The scale, positive.
    pub scale: f64,
    /// The translation, applied last.
    pub translation: [f64; 3],
}

impl Similarity {
    /// The identity: the data's frame is the scene's.
    pub const IDENTITY: Self =
        Self { rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], scale: 1.0, translation: [0.0; 3] };

    /// The similarity of `scale` that takes the pose `from` to the pose `to` (camera to world,
    /// both with orthonormal axes): the rotation `to`'s axes times `from`'s transposed, the
    /// translation what then takes `from`'s centre to `to`'s.
    #[must_use]
    pub fn between(from: &[[f64; 4]; 3], to: &[[f64; 4]; 3], scale: f64) -> Self {
        let rotation =
            std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| to[i][k] * from[j][k]).sum::<f64>()));
        let mut s = Self { rotation, scale, translation: [0.0; 3] };
        let moved = s.point([from[0][3], from[1][3], from[2][3]]);
        s.translation = std::array::from_fn(|i| to[i][3] - moved[i]);
        s
    }

    /// The similarity that undoes this one.
    #[must_use]
    pub fn inverse(&self) -> Self {
        let rotation = std::array::from_fn(|i| std::array::from_fn(|j| self.rotation[j][i]));
        let back = Self { rotation, scale: 1.0 / self.scale, translation: [0.0; 3] };
        let t = back.point(self.translation);
        Self { translation: t.map(|x| -x), ..back }
    }

    /// The rigid transform `[R | t]` of a 3x4 matrix whose 3x3 part `R` is a rotation (within
    /// `tolerance` of orthonormal, determinant positive); `None` otherwise.
    #[must_use]
    pub fn rigid(m: &[[f64; 4]; 3], tolerance: f64) -> Option<Self> {
        let rotation: [[f64; 3]; 3] = std::array::from_fn(|i| [m[i][0], m[i][1], m[i][2]]);
        let off = (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| {
                let dot: f64 = (0..3).map(|k| rotation[k][i] * rotation[k][j]).sum();
                (dot - if i == j { 1.0 } else { 0.0 }).abs()
            })
            .fold(0.0, f64::max);
        (off <= tolerance && det3(|r, c| rotation[r][c]) > 0.0).then(|| Self {
            rotation,
            scale: 1.0,
            translation: [m[0][3], m[1][3], m[2][3]],
        })
    }

    /// The point `x` transformed.
    #[must_use]
    pub fn point(&self, x: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| {
            self.scale * (0..3).map(|k| self.rotation[i][k] * x[k]).sum::<f64>() + self.translation[i]
        })
    }

    /// The camera-to-world pose `cam2world` transformed: its axes turned (their lengths kept, so
    /// the camera's intrinsics still hold), its centre moved.
    #[must_use]
    pub fn pose(&self, cam2world: &[[f64; 4]; 3]) -> [[f64; 4]; 3] {
        let centre = self.point([cam2world[0][3], cam2world[1][3], cam2world[2][3]]);
        std::array::from_fn(|i| {
            let mut row = [0.0; 4];
            for (j, r) in row.iter_mut().take(3).enumerate() {
                *r = (0..3).map(|k| self.rotation[i][k] * cam2world[k][j]).sum();
            }
            row[3] = centre[i];
            row
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY_POSE: [[f64; 4]; 3] = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0]];

    #[test]
    fn centred_and_corner_pixels_differ_by_half_a_pixel() {
        let cam = Camera::from_camera_angle_x(4, 4, 0.9, IDENTITY_POSE).unwrap();
        let f = focal_from_camera_angle_x(4, 0.9);
        let centred = cam.generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0);
        let corner = cam.generate_rays(PixelCenters::Corner, 2.0, 6.0, 1.0);
        // Pixel (0, 0): centre at x = 0.5, corner at x = 0; direction x = (x - W/2) / f.
        assert!((f64::from(centred[0].direction.x) - (0.5 - 2.0) / f).abs() < 1e-7);
        assert!((f64::from(corner[0].direction.x) - (0.0 - 2.0) / f).abs() < 1e-7);
        assert_eq!(centred[0].direction.z, -1.0);
        assert!((centred[5].viewdir.length() - 1.0).abs() < 1e-6);
        // Radius: one pixel of direction spacing (1/f at unit depth) times 2/sqrt(12).
        let r = 1.0 / f * 2.0 / 12f64.sqrt();
        assert!(centred.iter().all(|ray| (f64::from(ray.radius) - r).abs() < 1e-7));
        assert_eq!(centred[0].origin, Vec3::new(0.0, 0.0, 4.0));
    }

    #[test]
    fn single_row_and_single_pixel_images_get_a_radius() {
        for (w, h) in [(3, 1), (1, 1), (1, 2)] {
            let cam = Camera::from_camera_angle_x(w, h, 0.9, IDENTITY_POSE).unwrap();
            let rays = cam.generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0);
            assert_eq!(rays.len(), (w * h) as usize);
            assert!(rays.iter().all(|r| r.radius > 0.0 && r.radius.is_finite()), "{w}x{h}");
        }
    }

    #[test]
    fn bad_cameras_are_errors_not_panics() {
        let nan_pose = [[f64::NAN, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
        let flat_pose = [[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
        let cases = [
            (Camera::from_camera_angle_x(4, 4, 0.9, nan_pose), "non-finite"),
            (Camera::from_camera_angle_x(4, 4, 0.9, flat_pose), "singular"),
            (Camera::from_camera_angle_x(0, 4, 0.9, IDENTITY_POSE), "empty"),
            (Camera::from_camera_angle_x(4, 4, f64::NAN, IDENTITY_POSE), "camera_angle_x"),
            (Camera::from_camera_angle_x(4, 4, 4.0, IDENTITY_POSE), "camera_angle_x"),
            (Camera::from_camera_angle_x(4, 4, 1e-30, IDENTITY_POSE), "camera_angle_x"),
            (Camera::from_pix2cam(4, 4, pinhole_pix2cam(4, 4, 1e-30), IDENTITY_POSE), "horizontal field of view"),
            (Camera::from_pix2cam(4, 4, pinhole_pix2cam(4, 4, 1e30), IDENTITY_POSE), "horizontal field of view"),
            (
                Camera::from_pix2cam(8, 4, [[0.1, 0.0, -0.4], [0.0, -1e-30, 0.2], [0.0, 0.0, -1.0]], IDENTITY_POSE),
                "vertical",
            ),
            (
                Camera::from_camera_angle_x(
                    4,
                    4,
                    0.9,
                    [[1e20, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
                ),
                "x axis",
            ),
            (
                Camera::from_camera_angle_x(
                    4,
                    4,
                    0.9,
                    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, -1e20], [0.0, 0.0, 1.0, 0.0]],
                ),
                "[1][3]",
            ),
        ];
        for (res, needle) in cases {
            let msg = res.unwrap_err().to_string();
            assert!(msg.contains(needle), "{msg:?} should mention {needle:?}");
        }
    }
}
