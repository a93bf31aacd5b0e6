//! The built-in demo scene written to disk in the multiscale Blender format (train and test
//! splits, 4 scales each): the scene and its ray tracer are `mipnerf_core::demo`'s.

use std::path::Path;

use mipnerf_core::camera::{Camera, focal_from_camera_angle_x};
use mipnerf_core::dataset::{DataError, Split};
use mipnerf_core::demo::{CAMERA_ANGLE_X, render_view, view_poses};

use crate::multiscale;

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

/// Generates the demo scene into `dir` in the multiscale Blender format (train and test splits,
/// 4 scales each, `metadata.json`).
///
/// # Errors
/// [`DataError`] for an invalid size or unwritable files.
pub fn write_demo_scene(dir: &Path, cfg: &DemoConfig) -> Result<(), DataError> {
    if cfg.size == 0 || !cfg.size.is_multiple_of(16) {
        return Err(DataError::invalid(
            dir,
            format!("demo scene: the image size must be a positive multiple of 16, got {}", cfg.size),
        ));
    }
    if cfg.train_views == 0 || cfg.test_views == 0 {
        return Err(DataError::invalid(
            dir,
            format!(
                "demo scene: both splits need views, got {} training and {} test views",
                cfg.train_views, cfg.test_views
            ),
        ));
    }
    // One split's images are held at once, in f32 RGBA, before they are written.
    let views = cfg.train_views.max(cfg.test_views) as u64;
    let need = views.saturating_mul(u64::from(cfg.size).pow(2)).saturating_mul(16);
    mipnerf_core::memory::check(need, &format!("rendering {views} demo views of {0}x{0} pixels", cfg.size))
        .map_err(|e| DataError::invalid(dir, format!("demo scene: {e}; choose a smaller size or fewer views")))?;
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
        let scales = multiscale::Scales { focal, n_scales: multiscale::NUM_SCALES, near: 2.0, far: 6.0 };
        let meta = multiscale::write_split(dir, split, &images, scales)?;
        all.insert(split.name().to_string(), meta);
    }
    multiscale::write_metadata(dir, &serde_json::Value::Object(all))
}
