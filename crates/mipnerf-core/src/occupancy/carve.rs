//! The cells no training view can show, carved before training: by the masks' visual hull
//! ([`OccupancyGrid::carve_with_masks`]) or where no training ray reaches
//! ([`OccupancyGrid::carve_unreached`]); and the cube a dataset's grid covers ([`auto_bound`],
//! [`ndc_bound`]).

use glam::Vec3;
use rayon::prelude::*;

use super::{CARVED, CONTRACTED_BOUND, OccupancyConfig, OccupancyError, OccupancyGrid, UNREACHED_STRIDE, dilate, sign};
use crate::dataset::Dataset;

/// How a run lays its grid over its data ([`OccupancyGrid::for_data`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridPlan {
    /// Cells along each axis.
    pub resolution: usize,
    /// The cube's half side; `None`: from the cameras ([`auto_bound`]). Not read for an
    /// unbounded scene, whose grid covers the contracted space.
    pub bound: Option<f32>,
    /// An unbounded scene: the grid over the contracted space ([`crate::contract`]).
    pub unbounded: bool,
    /// Seed the grid with the visual hull of the training masks, where the data has them.
    pub carve_masks: bool,
}

/// The cells carved before training ([`OccupancyGrid::for_data`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Carved {
    /// Outside the training masks' visual hull.
    pub by_masks: usize,
    /// Reached by no training ray (forward-facing data in NDC space).
    pub unreached: usize,
}

impl OccupancyGrid {
    /// A run's grid before training, what the CLI's `train` and the library's `Nerf` both lay:
    /// for an unbounded scene, over the contracted space, nothing carved; else over the plan's
    /// cube (or the cameras'), seeded with the visual hull of the training masks where the data
    /// has transparency and the plan asks, and for forward-facing data in NDC space with the
    /// cells no training ray reaches carved.
    ///
    /// # Errors
    /// No bound given and none from the cameras (a camera's near bound reaches the origin), or
    /// settings [`OccupancyGrid::new`] refuses.
    pub fn for_data(ds: &Dataset, plan: GridPlan) -> Result<(Self, Carved), OccupancyError> {
        let resolution = plan.resolution;
        if plan.unbounded {
            let config =
                OccupancyConfig { resolution, bound: CONTRACTED_BOUND, contracted: true, ..OccupancyConfig::default() };
            return Ok((Self::new(config)?, Carved::default()));
        }
        let bound = plan
            .bound
            .or_else(|| auto_bound(ds))
            .ok_or_else(|| OccupancyError("no cube fits the scene: a camera's near bound reaches the origin".into()))?;
        let mut grid = Self::new(OccupancyConfig { resolution, bound, ..OccupancyConfig::default() })?;
        let by_masks = if plan.carve_masks { grid.carve_with_masks(ds) } else { 0 };
        // An NDC grid's cube reaches past the cameras' frustums: the cells no training ray
        // reaches are never sampled nor updated.
        let unreached = if ds.ndc.is_some() { grid.carve_unreached(ds) } else { 0 };
        Ok((grid, Carved { by_masks, unreached }))
    }

    /// Marks as [`CARVED`] every cell that some training view with an alpha mask shows as
    /// entirely transparent: the cell's eight corners project in front of the camera and inside
    /// the image, and every pixel of the rectangle they span has alpha below `0.5 / 255`. Only
    /// full-resolution views (scale 0) are used. Returns the number of cells carved; a dataset
    /// without transparency, or in NDC space (whose grid is not in world units), carves nothing.
    pub fn carve_with_masks(&mut self, ds: &Dataset) -> usize {
        // (A contracted grid's cells are not boxes in the world.)
        if ds.ndc.is_some() || self.config.contracted {
            return 0;
        }
        let masks: Vec<Mask> = ds.views().iter().filter(|v| v.scale == 0).filter_map(Mask::of_view).collect();
        if masks.is_empty() {
            return 0;
        }
        let h = self.cell_size();
        let carved: Vec<bool> = (0..self.opacity.len())
            .into_par_iter()
            .map(|i| {
                let c = self.cell_center(i);
                let corners: [Vec3; 8] =
                    std::array::from_fn(|k| c + 0.5 * h * Vec3::new(sign(k & 1), sign(k & 2), sign(k & 4)));
                masks.iter().any(|m| m.transparent(&corners))
            })
            .collect();
        let mut n = 0;
        for (v, c) in self.opacity.iter_mut().zip(carved) {
            if c && *v != CARVED {
                *v = CARVED;
                n += 1;
            }
        }
        self.refresh();
        n
    }

    /// Marks as [`CARVED`] every cell that no training ray comes within a cell of: the rays of
    /// every [`UNREACHED_STRIDE`]-th pixel of every full-resolution view (along both axes, the
    /// last row and column included), walked between near and far in steps of half a cell, the
    /// cells they cross dilated by one. Such a cell is never trained, so its density is only the
    /// MLP's extrapolation: sampling it or updating it is wasted work. Returns the number of
    /// cells carved.
    ///
    /// An NDC grid needs this: its cube holds every training ray, so it reaches past the
    /// cameras' frustums (beyond `z = ±1` and the image's corners); a cube around an object seen
    /// from all round is crossed nearly everywhere, and the masks carve it better.
    pub fn carve_unreached(&mut self, ds: &Dataset) -> usize {
        if self.config.contracted {
            return 0;
        }
        let r = self.config.resolution;
        let (b, h) = (self.config.bound, self.cell_size());
        let views: Vec<usize> = (0..ds.views().len()).filter(|&v| ds.views()[v].scale == 0).collect();
        let along = |n: u32| -> Vec<u32> {
            let mut v: Vec<u32> = (0..n).step_by(UNREACHED_STRIDE as usize).collect();
            if n > 0 && v.last() != Some(&(n - 1)) {
                v.push(n - 1);
            }
            v
        };
        let reached = views
            .par_iter()
            .map(|&v| {
                let cam = &ds.views()[v].camera;
                let mut seen = vec![false; r * r * r];
                for y in along(cam.height) {
                    for x in along(cam.width) {
                        let ray = ds.ray(v, x, y);
                        let len = ray.direction.length();
                        if !(len > 0.0 && len.is_finite() && ray.far > ray.near) {
                            continue;
                        }
                        let dt = 0.5 * h / len;
                        let steps = ((ray.far - ray.near) / dt).ceil().min(1e6) as usize;
                        for k in 0..=steps {
                            let t = (ray.near + k as f32 * dt).min(ray.far);
                            let cell = (ray.origin + ray.direction * t + b) / h;
                            if cell.min_element() >= 0.0 && cell.max_element() < r as f32 {
                                seen[(cell.z as usize * r + cell.y as usize) * r + cell.x as usize] = true;
                            }
                        }
                    }
                }
                seen
            })
            .reduce(
                || vec![false; r * r * r],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x |= y);
                    a
                },
            );
        let reached = dilate(&reached, r);
        let mut n = 0;
        for (v, seen) in self.opacity.iter_mut().zip(reached) {
            if !seen && *v != CARVED {
                *v = CARVED;
                n += 1;
            }
        }
        self.refresh();
        n
    }
}

/// A view's transparency as a summed-area table of "pixel has alpha", with the camera's
/// world-to-pixel projection.
struct Mask {
    width: usize,
    height: usize,
    /// `(width + 1) x (height + 1)` prefix counts of opaque-ish pixels.
    sat: Vec<u32>,
    projection: crate::camera::Projection,
}

impl Mask {
    fn of_view(v: &crate::dataset::View) -> Option<Self> {
        let (w, h) = (v.camera.width as usize, v.camera.height as usize);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        let mut any_transparent = false;
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                let a = v.pixels.rgba(y * w + x)[3];
                let solid = a >= 0.5 / 255.0;
                any_transparent |= !solid;
                row += u32::from(solid);
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        if !any_transparent {
            return None;
        }
        Some(Self { width: w, height: h, sat, projection: v.camera.projection()? })
    }

    /// Whether the rectangle spanned by `corners`' projections lies inside the image, in front of
    /// the camera, and holds no opaque pixel.
    fn transparent(&self, corners: &[Vec3; 8]) -> bool {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for p in corners {
            let Some((x, y, _)) = self.projection.project(p.as_dvec3().to_array()) else {
                return false;
            };
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        if x0 < 0.0 || y0 < 0.0 || x1 >= self.width as f64 || y1 >= self.height as f64 {
            return false;
        }
        let (xa, ya, xb, yb) =
            (x0.floor() as usize, y0.floor() as usize, x1.floor() as usize + 1, y1.floor() as usize + 1);
        let w1 = self.width + 1;
        let count = self.sat[yb * w1 + xb] + self.sat[ya * w1 + xa] - self.sat[ya * w1 + xb] - self.sat[yb * w1 + xa];
        count == 0
    }
}

/// The cube's half side for a dataset: for cameras looking in at an object, the smallest
/// distance from the origin to a camera's centre, less its near bound, so that no camera's near
/// plane cuts into the cube; for a forward-facing dataset in NDC space, [`ndc_bound`]. `None`
/// when that is not positive (cameras inside the scene).
#[must_use]
pub fn auto_bound(ds: &Dataset) -> Option<f32> {
    if ds.ndc.is_some() {
        return ndc_bound(ds);
    }
    let b = ds
        .views()
        .iter()
        .map(|v| {
            let o = v.camera.origin();
            (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt() as f32 - v.near
        })
        .fold(f32::INFINITY, f32::min);
    (b.is_finite() && b > 0.0).then_some(b)
}

/// How far past the outermost training ray an NDC grid's cube reaches (a fraction of its half
/// side): the corner rays go through pixel centres, and the image's edge lies half a pixel out.
pub const NDC_BOUND_MARGIN: f32 = 0.01;

/// The cube's half side for a forward-facing dataset in NDC space: NDC maps the reference
/// camera's frustum from its near plane to infinity onto `[-1, 1]³` (depth included: `z = -1` at
/// the near plane, `1` at infinity), and the other cameras' rays reach a little past it in `x`
/// and `y`; the cube holds every training ray between its near and far (the rays through the
/// image corners bound them, as NDC keeps lines straight), plus [`NDC_BOUND_MARGIN`]. `None`
/// for a dataset that is not in NDC space, or a non-finite extent.
#[must_use]
pub fn ndc_bound(ds: &Dataset) -> Option<f32> {
    ds.ndc?;
    let mut b = 0.0f32;
    for (v, view) in ds.views().iter().enumerate() {
        let (w, h) = (view.camera.width.max(1) - 1, view.camera.height.max(1) - 1);
        for (x, y) in [(0, 0), (w, 0), (0, h), (w, h)] {
            let r = ds.ray(v, x, y);
            for t in [r.near, r.far] {
                b = b.max((r.origin + r.direction * t).abs().max_element());
            }
        }
    }
    let b = b * (1.0 + NDC_BOUND_MARGIN);
    (b.is_finite() && b > 0.0).then_some(b)
}
