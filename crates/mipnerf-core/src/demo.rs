//! The built-in demo scene: a procedural scene with fine, high-frequency detail that aliases when
//! undersampled, rendered by an analytic ray tracer with supersampled ground truth. It needs no files and
//! generates in well under a second: in memory here ([`dataset`]), in the multiscale Blender format
//! on disk by `mipnerf_data::demo::write_demo_scene`.
//!
//! The scene (world units, `z` up, inside the radius-1.3 ball that the Blender scenes use): a
//! sphere with fine horizontal bands, a disc floor with a fine plaid, and a box with fine stripes.
//! Every pattern is a square wave along one world axis at a frequency of the positional encoding,
//! so that a small model learns it in minutes at full resolution, and every one is finer than a
//! pixel at 1/8 scale, where NeRF's point samples alias. Misses are transparent (alpha 0), as Blender renders
//! are, so the scene composites on white. Cameras sit on the upper hemisphere at distance 4, looking
//! at the origin, with the lego scene's field of view.

use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::dataset::{DataError, Dataset, Pixels, Split, View};

/// Horizontal field of view of the demo cameras (the lego scene's).
pub const CAMERA_ANGLE_X: f64 = 0.691_111_207;

/// The camera-to-world pose of a demo camera at azimuth `az` and elevation `el` (radians),
/// distance 4 from the origin, looking at it, `z` up (OpenGL axes: the camera looks down its -z).
#[must_use]
pub fn camera_pose(az: f64, el: f64) -> [[f64; 4]; 3] {
    let pos = DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * 4.0;
    let back = pos.normalize();
    let right = DVec3::Z.cross(back).normalize();
    let up = back.cross(right);
    std::array::from_fn(|r| [right[r], up[r], back[r], pos[r]])
}

/// Poses of `n` views: azimuths on a golden-angle spiral, elevations between 15 and 55 degrees;
/// `offset` shifts the sequence so that test views differ from training views.
#[must_use]
pub fn view_poses(n: usize, offset: f64) -> Vec<[[f64; 4]; 3]> {
    (0..n)
        .map(|i| {
            let u = (i as f64 + 0.5 + offset) / n as f64;
            let az = (i as f64 + offset) * 2.399_963_229_728_653;
            let el = (15.0 + 40.0 * u.fract()).to_radians();
            camera_pose(az, el)
        })
        .collect()
}

/// `n` training views of the demo scene held in memory, `side x side` pixels each, on the orbit
/// of [`view_poses`] with a horizontal field of view of 0.69 rad (bounds 2 to 6, composited on
/// white): data that needs no files, for examples, checks and tests.
///
/// # Errors
/// [`DataError::Invalid`] when `n` or `side` is 0.
pub fn dataset(n: usize, side: u32) -> Result<Dataset, DataError> {
    let views = view_poses(n, 0.0)
        .into_iter()
        .enumerate()
        .map(|(i, pose)| {
            let camera = Camera::from_camera_angle_x(side, side, 0.69, pose)
                .map_err(|e| DataError::invalid(Path::new("<demo scene>"), e.to_string()))?;
            let pixels = Pixels::RgbaF32(render_view(&camera, 1));
            Ok(View::in_memory(&format!("demo view {i}"), camera, pixels, 2.0, 6.0))
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    Dataset::from_views(Split::Train, views, true)
}

/// A `side x side` camera at a fixed oblique pose, 4 units from the scene's centre and looking
/// at it (not one of the orbit's): the view the GPU kernel checks cast their rays from.
///
/// # Panics
/// If `side` is 0.
#[must_use]
pub fn oblique_camera(side: u32) -> Camera {
    let c2w = [[0.8, 0.0, 0.6, 2.4], [0.36, 0.8, -0.48, -1.92], [-0.48, 0.6, 0.64, 2.56]];
    Camera::from_camera_angle_x(side, side, 0.69, c2w)
        .unwrap_or_else(|e| panic!("oblique camera of {side} pixels: {e}"))
}

/// Period (world units) of the sphere's horizontal bands: `2 pi / 32`, one of the frequencies of
/// the positional encoding, so a small MLP learns the bands in a minute. The camera sees about 44
/// px per world unit at 128 px: a band is about 4 px wide there and half a pixel at 1/8, where it
/// aliases.
const SPHERE_BAND: f64 = std::f64::consts::TAU / 32.0;
/// Period of the floor's stripes along `x` and along `y` (`2 pi / 16`): crossed, they make a plaid
/// whose far side, foreshortened, is finer than a pixel at 1/4 and 1/8.
const FLOOR_STRIPE: f64 = std::f64::consts::TAU / 16.0;
/// Period of the box's stripes along `x`.
const BOX_STRIPE: f64 = std::f64::consts::TAU / 32.0;
const LIGHT: DVec3 = DVec3::new(0.408_248, -0.408_248, 0.816_497);
const SPHERE_C: DVec3 = DVec3::new(0.0, 0.0, 0.15);
const SPHERE_R: f64 = 0.7;
const FLOOR_Z: f64 = -0.55;
const FLOOR_R: f64 = 1.25;
const BOX_MIN: DVec3 = DVec3::new(0.55, -0.95, -0.55);
const BOX_MAX: DVec3 = DVec3::new(0.95, -0.55, -0.15);

/// 1 on the first half of every period of `x`, 0 on the second: a square wave.
fn stripe(x: f64, period: f64) -> f64 {
    if (x / period).rem_euclid(1.0) < 0.5 { 1.0 } else { 0.0 }
}

/// Colour (straight RGBA) seen along one ray.
fn trace(o: DVec3, d: DVec3) -> [f64; 4] {
    let d = d.normalize();
    let mut best = (f64::INFINITY, [0.0; 3], DVec3::Z);
    // Sphere.
    let oc = o - SPHERE_C;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - SPHERE_R * SPHERE_R);
    if disc > 0.0 {
        let t = -b - disc.sqrt();
        if t > 0.0 && t < best.0 {
            let p = o + t * d;
            let c = if stripe(p.z, SPHERE_BAND) > 0.5 { [0.85, 0.15, 0.1] } else { [0.95, 0.85, 0.2] };
            best = (t, c, (p - SPHERE_C) / SPHERE_R);
        }
    }
    // Floor disc.
    if d.z.abs() > 1e-12 {
        let t = (FLOOR_Z - o.z) / d.z;
        let p = o + t * d;
        let r = (p.x * p.x + p.y * p.y).sqrt();
        if t > 0.0 && t < best.0 && r < FLOOR_R {
            // A plaid: x stripes add yellow, y stripes add blue (dark navy where neither,
            // near white where both).
            let (sx, sy) = (stripe(p.x, FLOOR_STRIPE), stripe(p.y, FLOOR_STRIPE));
            let c = [0.05 + 0.8 * sx + 0.05 * sy, 0.08 + 0.65 * sx + 0.2 * sy, 0.2 + 0.7 * sy];
            best = (t, c, DVec3::Z);
        }
    }
    // Box (slab method).
    let inv = DVec3::ONE / d;
    let t1 = (BOX_MIN - o) * inv;
    let t2 = (BOX_MAX - o) * inv;
    let (tmin, tmax) = (t1.min(t2).max_element(), t1.max(t2).min_element());
    if tmax > tmin.max(0.0) && tmin > 0.0 && tmin < best.0 {
        let p = o + tmin * d;
        let c = (BOX_MIN + BOX_MAX) * 0.5;
        let q = (p - c) / ((BOX_MAX - BOX_MIN) * 0.5);
        let n = if q.x.abs() > q.y.abs().max(q.z.abs()) {
            DVec3::X * q.x.signum()
        } else if q.y.abs() > q.z.abs() {
            DVec3::Y * q.y.signum()
        } else {
            DVec3::Z * q.z.signum()
        };
        let col = if stripe(p.x, BOX_STRIPE) > 0.5 { [0.1, 0.1, 0.1] } else { [0.3, 0.75, 0.9] };
        best = (tmin, col, n);
    }
    if best.0.is_infinite() {
        return [0.0; 4];
    }
    let shade = 0.35 + 0.65 * best.2.dot(LIGHT).max(0.0);
    [best.1[0] * shade, best.1[1] * shade, best.1[2] * shade, 1.0]
}

/// Renders `camera`'s view with `ss x ss` rays per pixel (a regular sub-pixel grid), averaging
/// straight RGBA; returns `width * height * 4` values in `[0, 1]`.
#[must_use]
pub fn render_view(camera: &Camera, ss: u32) -> Vec<f32> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let o = DVec3::from_array(camera.origin());
    let ss = ss.max(1);
    let mut out = vec![0.0f32; w * h * 4];
    out.par_chunks_mut(w * 4).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let mut acc = [0.0f64; 4];
            for sy in 0..ss {
                for sx in 0..ss {
                    let px = x as f64 + (f64::from(sx) + 0.5) / f64::from(ss);
                    let py = y as f64 + (f64::from(sy) + 0.5) / f64::from(ss);
                    let c = trace(o, DVec3::from_array(camera.direction_f64(px, py)));
                    for k in 0..4 {
                        acc[k] += c[k];
                    }
                }
            }
            let n = f64::from(ss * ss);
            for k in 0..4 {
                row[x * 4 + k] = (acc[k] / n) as f32;
            }
        }
    });
    out
}
