//! The built-in demo scene: a procedural scene with fine, high-frequency detail that aliases when
//! undersampled, rendered by an analytic ray tracer with supersampled ground truth, written in the
//! multiscale Blender format. It needs no files and generates in well under a second.
//!
//! The scene (world units, `z` up, inside the radius-1.3 ball that the Blender scenes use): a
//! sphere with a latitude-longitude checkerboard, a disc floor with fine concentric rings and
//! radial spokes, and a box with a fine grid. Misses are transparent (alpha 0), as Blender renders
//! are, so the scene composites on white. Cameras sit on the upper hemisphere at distance 4, looking
//! at the origin, with the lego scene's field of view.

use std::path::Path;

use glam::DVec3;
use rayon::prelude::*;

use super::{DataError, Split, multiscale};
use crate::camera::{Camera, focal_from_camera_angle_x};

/// Horizontal field of view of the demo cameras (the lego scene's).
pub const CAMERA_ANGLE_X: f64 = 0.691_111_207;

/// Settings of the demo scene.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DemoConfig {
    /// Full-resolution image size (square; divisible by 16).
    pub size: u32,
    /// Training views.
    pub train_views: usize,
    /// Test views.
    pub test_views: usize,
    /// Rays per pixel along each axis for the ground truth at full resolution (coarser scales are
    /// box filtered from it, so they are supersampled `2^j` times more).
    pub supersample: u32,
}

impl Default for DemoConfig {
    fn default() -> Self {
        Self { size: 64, train_views: 40, test_views: 8, supersample: 4 }
    }
}

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

/// Checker cells of the sphere per half turn of latitude and of longitude (about 5 px a cell at
/// 128 px, less than a pixel at 1/8: it aliases there).
const SPHERE_CELLS: f64 = 12.0;
/// Rings of the floor per world unit of radius, and spokes per half turn.
const FLOOR_RINGS: f64 = 40.0;
const FLOOR_SPOKES: f64 = 24.0;
/// Grid lines of the box per world unit.
const BOX_GRID: f64 = 30.0;
const LIGHT: DVec3 = DVec3::new(0.408_248, -0.408_248, 0.816_497);
const SPHERE_C: DVec3 = DVec3::new(0.0, 0.0, 0.15);
const SPHERE_R: f64 = 0.7;
const FLOOR_Z: f64 = -0.55;
const FLOOR_R: f64 = 1.25;
const BOX_MIN: DVec3 = DVec3::new(0.55, -0.95, -0.55);
const BOX_MAX: DVec3 = DVec3::new(0.95, -0.55, -0.15);

fn checker(a: f64, b: f64) -> bool {
    ((a.floor() as i64) + (b.floor() as i64)).rem_euclid(2) == 0
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
            let n = (o + t * d - SPHERE_C) / SPHERE_R;
            let lat = n.z.asin() / std::f64::consts::PI * SPHERE_CELLS;
            let lon = n.y.atan2(n.x) / std::f64::consts::PI * SPHERE_CELLS;
            let c = if checker(lat, lon) { [0.85, 0.15, 0.1] } else { [0.95, 0.85, 0.2] };
            best = (t, c, n);
        }
    }
    // Floor disc.
    if d.z.abs() > 1e-12 {
        let t = (FLOOR_Z - o.z) / d.z;
        let p = o + t * d;
        let r = (p.x * p.x + p.y * p.y).sqrt();
        if t > 0.0 && t < best.0 && r < FLOOR_R {
            let rings = (r * FLOOR_RINGS).floor() as i64 % 2 == 0;
            let spokes = (p.y.atan2(p.x) / std::f64::consts::PI * FLOOR_SPOKES).floor() as i64 % 2 == 0;
            let c = match (rings, spokes) {
                (true, true) => [0.1, 0.3, 0.8],
                (true, false) => [0.9, 0.9, 0.95],
                (false, true) => [0.15, 0.6, 0.3],
                (false, false) => [0.05, 0.05, 0.1],
            };
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
        let g = p * BOX_GRID;
        let grid = (g.x.fract().abs() < 0.15) || (g.y.fract().abs() < 0.15) || (g.z.fract().abs() < 0.15);
        let col = if grid { [0.1, 0.1, 0.1] } else { [0.3, 0.75, 0.9] };
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

/// Generates the demo scene into `dir` in the multiscale Blender format (train and test splits,
/// 4 scales each, `metadata.json`).
///
/// # Errors
/// [`DataError`] for an invalid size or unwritable files.
pub fn write_demo_scene(dir: &Path, cfg: &DemoConfig) -> Result<(), DataError> {
    if cfg.size == 0 || !cfg.size.is_multiple_of(16) || cfg.train_views == 0 || cfg.test_views == 0 {
        return Err(DataError::invalid(
            dir,
            format!("demo scene: size must be a positive multiple of 16 and both splits non-empty, got {cfg:?}"),
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
    let focal = focal_from_camera_angle_x(cfg.size, CAMERA_ANGLE_X);
    let mut all = serde_json::Map::new();
    for (split, n, offset) in [(Split::Train, cfg.train_views, 0.0), (Split::Test, cfg.test_views, 0.37)] {
        let images: Vec<multiscale::SourceImage> = view_poses(n, offset)
            .into_iter()
            .map(|pose| {
                let cam = Camera::from_camera_angle_x(cfg.size, cfg.size, CAMERA_ANGLE_X, pose)
                    .unwrap_or_else(|e| unreachable!("demo camera: {e}"));
                multiscale::SourceImage {
                    width: cfg.size,
                    height: cfg.size,
                    rgba: render_view(&cam, cfg.supersample),
                    cam2world: pose,
                }
            })
            .collect();
        let meta = multiscale::write_split(dir, split, &images, focal, multiscale::NUM_SCALES, 2.0, 6.0)?;
        all.insert(split.name().to_string(), meta);
    }
    multiscale::write_metadata(dir, &serde_json::Value::Object(all))
}
