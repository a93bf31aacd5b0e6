//! Occupancy-guided sampling: a grid over the scene's bounds that says where the model's density
//! is worth sampling, kept up to date from the model's own densities during training.
//!
//! The grid is an accelerator, not part of the model: with every cell occupied the sampler is the
//! paper's (stratified between near and far, bit for bit). Otherwise each ray is cut to the
//! occupied cells it crosses ([`OccupancyGrid::ray_segments`], a voxel traversal); the coarse
//! samples are stratified inside those segments ([`crate::sampling::sample_along_segments`]), the
//! fine level resamples from the coarse weights as always, and a ray that meets no occupied cell
//! runs no MLP at all and renders the background.
//!
//! How the grid learns (as nerfacc's `OccupancyGrid`): every `update_every` steps the density of
//! every candidate cell is evaluated at a random point inside the cell, at the cell's own scale (an
//! isotropic Gaussian of the cell's variance, encoded by IPE), turned into the opacity of one cell
//! length, `1 - exp(-σ h)`, and kept as `max(decay · old, new)`. A cell is occupied when that
//! exceeds `min(threshold, mean)`. During the warm-up every candidate cell counts as occupied.
//! For data with alpha masks the grid can be seeded with the visual hull of the training masks
//! ([`OccupancyGrid::carve_with_masks`]): a cell whose footprint is transparent in some view that
//! sees all of it is never a candidate.
//!
//! In an unbounded scene ([`crate::contract`]) the grid lies over the contracted space, the cube
//! `[-2, 2]³` around the ball that holds all of it (`contracted`): a point is looked up at its
//! contraction, a cell's density probed with its Gaussian there, and a ray, which is a curve in
//! that space, is walked in even steps of its normalised distance `s` rather than cell by cell.

use glam::Vec3;
use rayon::prelude::*;

use crate::cone::Ray;
use crate::data::Dataset;
use crate::mip::Gaussian;
use crate::rng::{RayRng, Stream};

/// What a grid update probes: the density (after its activation) at each of a batch of
/// Gaussians in the grid's space. The grid depends on the model only through this;
/// [`crate::model::Model::density_field`] is a model's, with its parameters.
pub trait DensityField: Sync {
    /// The density at each of `probes`; `contracted`: they lie in an unbounded scene's
    /// contracted space, to be encoded as they are.
    fn densities(&self, probes: &[Gaussian], contracted: bool) -> Vec<f32>;
}

/// A cell's stored value meaning "outside the visual hull of the masks: never occupied".
pub const CARVED: f32 = -1.0;

/// How the grid is laid out and updated. Defaults follow nerfacc's occupancy grid at the
/// resolution a 2-core CPU updates in a fraction of a step.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OccupancyConfig {
    /// Cells along each axis.
    pub resolution: usize,
    /// Half the side of the cube the grid covers, centred on the origin (world units); space
    /// outside it is empty.
    pub bound: f32,
    /// Steps between updates of the grid from the model's densities.
    pub update_every: u64,
    /// Steps during which every candidate cell counts as occupied.
    pub warmup_steps: u64,
    /// Decay of a cell's remembered opacity at each update.
    pub decay: f32,
    /// A cell is occupied when its opacity over one cell length exceeds this (or the mean of the
    /// candidate cells, if lower).
    pub threshold: f32,
    /// The grid lies over an unbounded scene's contracted space ([`crate::contract`]), with
    /// `bound` [`CONTRACTED_BOUND`]; the cells outside the ball of radius 2 are never candidates.
    pub contracted: bool,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        Self {
            resolution: 64,
            bound: 1.5,
            update_every: 16,
            warmup_steps: 256,
            decay: 0.95,
            threshold: 0.01,
            contracted: false,
        }
    }
}

/// The half side of a contracted grid's cube: the contraction maps all of space into the ball of
/// radius 2.
pub const CONTRACTED_BOUND: f32 = 2.0;

/// A ray is walked through a contracted grid in this many even steps of `s` per cell along an
/// axis (`2 · resolution` steps from near to far): a step of `s` moves a ray from a camera inside
/// the unit ball by about `2 Δs` in the contracted space, a quarter of a cell.
pub const CONTRACTED_STEPS_PER_CELL: usize = 2;

/// An occupancy grid: `resolution³` cells over `[-bound, bound]³`, x fastest.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    /// Layout and update settings.
    pub config: OccupancyConfig,
    /// Per cell: the remembered opacity (`>= 0`), or [`CARVED`].
    pub opacity: Vec<f32>,
    /// Whether the warm-up is over (cells are then occupied by their opacity, not all).
    pub warmed_up: bool,
    occupied: Vec<bool>,
    /// `dilated[k - 1]`: a cell is set when an occupied cell lies within `k` cells of it (along
    /// each axis), for the cones that are wider than a cell.
    dilated: Vec<Vec<bool>>,
}

/// [`OccupancyGrid::carve_unreached`] walks the rays of every this-many-th pixel along each axis.
pub const UNREACHED_STRIDE: u32 = 4;

/// The widest dilation (in cells) a cone's footprint is given.
pub const MAX_DILATION: usize = 4;

/// Errors in occupancy settings or state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("occupancy grid: {0}")]
pub struct OccupancyError(pub String);

impl OccupancyGrid {
    /// A grid whose cells are all candidates (nothing carved), in warm-up: every cell occupied.
    ///
    /// # Errors
    /// A resolution outside `2..=256`, a non-positive or non-finite bound, decay or threshold.
    pub fn new(config: OccupancyConfig) -> Result<Self, OccupancyError> {
        let r = config.resolution;
        if !(2..=256).contains(&r) {
            return Err(OccupancyError(format!("resolution must be between 2 and 256, got {r}")));
        }
        for (name, v) in [("bound", config.bound), ("threshold", config.threshold)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(OccupancyError(format!("{name} must be a positive number, got {v}")));
            }
        }
        if !(config.decay.is_finite() && (0.0..=1.0).contains(&config.decay)) {
            return Err(OccupancyError(format!("decay must be in [0, 1], got {}", config.decay)));
        }
        if config.update_every == 0 {
            return Err(OccupancyError("update_every must be at least 1".into()));
        }
        if config.contracted && config.bound != CONTRACTED_BOUND {
            return Err(OccupancyError(format!(
                "a grid over contracted space has bound {CONTRACTED_BOUND}, got {}",
                config.bound
            )));
        }
        let n = r * r * r;
        let dilated = vec![vec![true; n]; MAX_DILATION];
        let mut g = Self { config, opacity: vec![0.0; n], warmed_up: false, occupied: vec![true; n], dilated };
        if config.contracted {
            // The corners of the cube lie outside the ball that holds all of contracted space.
            let reach = CONTRACTED_BOUND + 0.5 * 3f32.sqrt() * g.cell_size();
            for i in 0..n {
                if g.cell_center(i).length() > reach {
                    g.opacity[i] = CARVED;
                }
            }
            g.refresh();
        }
        Ok(g)
    }

    /// A grid restored from saved state (see [`opacity`](Self::opacity) and
    /// [`warmed_up`](Self::warmed_up)).
    ///
    /// # Errors
    /// As [`new`](Self::new), a length that is not `resolution³`, or a value that is neither a
    /// finite opacity nor [`CARVED`].
    pub fn from_state(config: OccupancyConfig, opacity: Vec<f32>, warmed_up: bool) -> Result<Self, OccupancyError> {
        let mut g = Self::new(config)?;
        if opacity.len() != g.opacity.len() {
            return Err(OccupancyError(format!("{} cells, the layout needs {}", opacity.len(), g.opacity.len())));
        }
        if let Some(v) = opacity.iter().find(|v| !(v.is_finite() && (**v >= 0.0 || **v == CARVED))) {
            return Err(OccupancyError(format!("a cell holds {v}, neither an opacity nor the carved mark")));
        }
        g.opacity = opacity;
        g.warmed_up = warmed_up;
        g.refresh();
        Ok(g)
    }

    /// Cells along each axis.
    #[must_use]
    pub fn resolution(&self) -> usize {
        self.config.resolution
    }

    /// The side of one cell (world units).
    #[must_use]
    pub fn cell_size(&self) -> f32 {
        2.0 * self.config.bound / self.config.resolution as f32
    }

    /// Whether every cell is occupied: the sampler is then exactly the paper's.
    #[must_use]
    pub fn is_full(&self) -> bool {
        self.occupied.iter().all(|&o| o)
    }

    /// The fraction of cells occupied.
    #[must_use]
    pub fn occupied_fraction(&self) -> f32 {
        self.occupied.iter().filter(|&&o| o).count() as f32 / self.occupied.len() as f32
    }

    /// Whether cell `(x, y, z)` is occupied.
    #[must_use]
    pub fn is_occupied(&self, x: usize, y: usize, z: usize) -> bool {
        let r = self.config.resolution;
        self.occupied[(z * r + y) * r + x]
    }

    /// Whether the point `p` (world units) lies in an occupied cell (a contracted grid's at its
    /// contraction); outside the grid's cube, space is empty.
    #[must_use]
    pub fn is_occupied_at(&self, p: Vec3) -> bool {
        let p = if self.config.contracted { crate::contract::contract(p) } else { p };
        let b = self.config.bound;
        let r = self.config.resolution;
        let cell = (p + b) / self.cell_size();
        if !(cell.min_element() >= 0.0 && cell.max_element() < r as f32) {
            return false;
        }
        self.is_occupied(cell.x as usize, cell.y as usize, cell.z as usize)
    }

    /// The centre of cell `i` (x fastest), in world space (in contracted space for a contracted
    /// grid).
    #[must_use]
    pub fn cell_center(&self, i: usize) -> Vec3 {
        let r = self.config.resolution;
        let (x, y, z) = (i % r, (i / r) % r, i / (r * r));
        let h = self.cell_size();
        let b = self.config.bound;
        Vec3::new(-b + (x as f32 + 0.5) * h, -b + (y as f32 + 0.5) * h, -b + (z as f32 + 0.5) * h)
    }

    /// The occupied cells and their dilations as bits, what the GPU sampler reads
    /// (`shaders/occupancy.wgsl`): layer 0 is the occupied cells, layer `k` (1 to
    /// [`MAX_DILATION`]) the cells within `k` cells of an occupied one; cell `i` (x fastest) of
    /// layer `k` is bit `j % 32` of word `j / 32`, with `j = k · resolution³ + i`.
    #[must_use]
    pub fn packed_layers(&self) -> Vec<u32> {
        let n = self.occupied.len();
        let mut words = vec![0u32; ((MAX_DILATION + 1) * n).div_ceil(32)];
        let bits = std::iter::once(&self.occupied).chain(&self.dilated).flat_map(|layer| layer.iter());
        for (j, &b) in bits.enumerate() {
            words[j / 32] |= u32::from(b) << (j % 32);
        }
        words
    }

    /// Recomputes which cells are occupied from the stored opacities.
    fn refresh(&mut self) {
        let candidates: Vec<f32> = self.opacity.iter().copied().filter(|&v| v != CARVED).collect();
        let mean = if candidates.is_empty() {
            0.0
        } else {
            (candidates.iter().map(|&v| f64::from(v)).sum::<f64>() / candidates.len() as f64) as f32
        };
        let thr = self.config.threshold.min(mean);
        let warm = self.warmed_up;
        for (o, &v) in self.occupied.iter_mut().zip(&self.opacity) {
            *o = v != CARVED && (!warm || v > thr);
        }
        let r = self.config.resolution;
        let mut prev = self.occupied.clone();
        for d in &mut self.dilated {
            *d = dilate(&prev, r);
            prev.clone_from(d);
        }
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

    /// Whether step `step` updates the grid (every `update_every` steps).
    #[must_use]
    pub fn updates_at(&self, step: u64) -> bool {
        step.is_multiple_of(self.config.update_every)
    }

    /// Updates every candidate cell from the density `field` gives at a random point of the cell
    /// (from `(seed, step)`), at the cell's scale, and ends the warm-up once
    /// `step >= warmup_steps`. A model's field: [`crate::model::Model::density_field`].
    ///
    /// # Panics
    /// If the field panics (a model's, when its parameters do not fit it).
    pub fn update(&mut self, field: &impl DensityField, seed: u32, step: u64) {
        let cells: Vec<usize> = (0..self.opacity.len()).filter(|&i| self.opacity[i] != CARVED).collect();
        let dens = self.densities(field, &cells, seed, step as u32);
        let h = self.cell_size();
        let decay = self.config.decay;
        for (&i, &sigma) in cells.iter().zip(&dens) {
            let alpha = 1.0 - (-sigma.max(0.0) * h * self.world_stretch(i)).exp();
            let alpha = if alpha.is_finite() { alpha } else { 1.0 };
            self.opacity[i] = (self.opacity[i] * decay).max(alpha);
        }
        self.end_update(step);
    }

    /// Ends an update whose opacities were computed elsewhere: the GPU backend's
    /// (`shaders/occupancy_update.wgsl`), which keeps `max(decay · old, new)` for each candidate
    /// cell as [`update`](Self::update) does, from the same random points. Then as
    /// [`update`](Self::update): the warm-up ends once `step >= warmup_steps`, and the occupied
    /// cells follow from the opacities.
    ///
    /// # Errors
    /// Opacities of another length, a carved cell that is not carved in `opacity` (or the
    /// reverse), or a candidate's opacity that is negative or not a number.
    pub fn update_with_opacity(&mut self, opacity: Vec<f32>, step: u64) -> Result<(), OccupancyError> {
        if opacity.len() != self.opacity.len() {
            return Err(OccupancyError(format!(
                "{} opacities for a grid of {} cells",
                opacity.len(),
                self.opacity.len()
            )));
        }
        let bad = self
            .opacity
            .iter()
            .zip(&opacity)
            .position(|(&old, &new)| if old == CARVED { new != CARVED } else { new.is_nan() || new < 0.0 });
        if let Some(i) = bad {
            return Err(OccupancyError(format!(
                "cell {i}: opacity {} after an update of {} (a carved cell stays carved, a candidate's is at least 0)",
                opacity[i], self.opacity[i]
            )));
        }
        self.opacity = opacity;
        self.end_update(step);
        Ok(())
    }

    /// An update's end: the warm-up over once `step >= warmup_steps`, the occupied cells from
    /// the opacities.
    fn end_update(&mut self, step: u64) {
        if step >= self.config.warmup_steps {
            self.warmed_up = true;
        }
        self.refresh();
    }

    /// How many world units one unit of cell `i`'s space spans along a ray through it: 1 in a
    /// world grid; in a contracted grid, outside the unit ball, the contraction's radial stretch
    /// `r²` at the cell's centre (`r` its world distance, `1/(2 - ρ)` at contracted radius `ρ`),
    /// the largest of its stretches, so a cell's opacity is never underestimated.
    fn world_stretch(&self, i: usize) -> f32 {
        let rho = self.cell_center(i).length();
        if !self.config.contracted || rho <= 1.0 {
            return 1.0;
        }
        let r = 1.0 / (CONTRACTED_BOUND - rho).max(1e-6);
        r * r
    }

    /// The field's density at a random point of each of `cells`, with the cell's variance
    /// (`h² / 12` per axis, a uniform cube's); in a contracted grid the probe is a Gaussian of
    /// the contracted space.
    fn densities(&self, field: &impl DensityField, cells: &[usize], seed: u32, step: u32) -> Vec<f32> {
        const CHUNK: usize = 1024;
        let h = self.cell_size();
        let var = h * h / 12.0;
        cells
            .par_chunks(CHUNK)
            .flat_map_iter(|chunk| {
                let probes: Vec<Gaussian> = chunk
                    .iter()
                    .map(|&i| {
                        let rng = RayRng::new(seed, step, Stream::OccupancyUpdate, i as u32);
                        let jitter = Vec3::new(rng.uniform(0), rng.uniform(1), rng.uniform(2)) - 0.5;
                        Gaussian { mean: self.cell_center(i) + h * jitter, cov_diag: Vec3::splat(var) }
                    })
                    .collect();
                field.densities(&probes, self.config.contracted)
            })
            .collect()
    }

    /// The indices (ascending) of the `rays` that meet an occupied cell: those that
    /// [`ray_segments`](Self::ray_segments) gives a span, the only ones guided sampling runs the
    /// MLP on (the others render the background).
    #[must_use]
    pub fn active_rays(&self, rays: &[Ray]) -> Vec<u32> {
        use rayon::prelude::*;
        let hit: Vec<bool> = rays
            .par_iter()
            .map_init(Vec::new, |spans, r| {
                spans.clear();
                self.ray_segments(r, spans);
                !spans.is_empty()
            })
            .collect();
        hit.iter().enumerate().filter(|(_, h)| **h).map(|(i, _)| i as u32).collect()
    }

    /// The parts of `ray` (`origin + t direction`, `t` in `[near, far]`, in units of the
    /// direction, which need not be unit length) that its cone may see occupied, as sorted,
    /// disjoint `[t0, t1]` spans: a voxel traversal (Amanatides and Woo) of the cells the ray's
    /// axis crosses inside the grid's cube, consecutive hits merged. Space outside the cube is
    /// empty. Appends to `out`.
    ///
    /// A cone is wider than its axis: a cell counts as hit when an occupied cell lies within `k`
    /// cells of it, with `k = ceil(2 r / h)` for the cone's radius `r` (`radius · t`) where it
    /// leaves the cube and the cell side `h` (at most [`MAX_DILATION`]; `k = 0`, the axis alone,
    /// for a ray of zero radius). So a coarse pixel whose footprint covers the object but whose
    /// centre line misses it still samples it.
    pub fn ray_segments(&self, ray: &Ray, out: &mut Vec<[f32; 2]>) {
        if self.config.contracted {
            self.contracted_ray_segments(ray, out);
            return;
        }
        let (origin, direction, near, far) = (ray.origin, ray.direction, ray.near, ray.far);
        let b = self.config.bound;
        let r = self.config.resolution as i32;
        let h = self.cell_size();
        // The slab test: where the ray is inside the cube.
        let (mut t0, mut t1) = (near, far);
        for a in 0..3 {
            let (o, d) = (origin[a], direction[a]);
            if d == 0.0 {
                if o < -b || o > b {
                    return;
                }
                continue;
            }
            let (ta, tb) = ((-b - o) / d, (b - o) / d);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        // Nothing inside the cube (or a NaN from a degenerate ray).
        if t0.partial_cmp(&t1) != Some(std::cmp::Ordering::Less) {
            return;
        }
        let reach = 2.0 * ray.radius * t1.abs() / h;
        let occupied = match reach.ceil() {
            k if k >= 1.0 => &self.dilated[(k as usize).min(MAX_DILATION) - 1],
            _ => &self.occupied,
        };
        // The entry cell; a point on a face rounds to the cell inside through the clamp.
        let p = origin + direction * t0;
        let mut cell = [0i32; 3];
        let mut step = [0i32; 3];
        let mut t_max = [f32::INFINITY; 3];
        let mut t_delta = [f32::INFINITY; 3];
        for a in 0..3 {
            cell[a] = (((p[a] + b) / h).floor() as i32).clamp(0, r - 1);
            let d = direction[a];
            if d > 0.0 {
                step[a] = 1;
                t_max[a] = (-b + (cell[a] + 1) as f32 * h - origin[a]) / d;
                t_delta[a] = h / d;
            } else if d < 0.0 {
                step[a] = -1;
                t_max[a] = (-b + cell[a] as f32 * h - origin[a]) / d;
                t_delta[a] = -h / d;
            }
        }
        let mut t = t0;
        let mut open: Option<f32> = None;
        let res = r as usize;
        while t < t1 {
            let a = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
                0
            } else if t_max[1] <= t_max[2] {
                1
            } else {
                2
            };
            let t_next = t_max[a].min(t1).max(t);
            let occ = occupied[((cell[2] as usize * res) + cell[1] as usize) * res + cell[0] as usize];
            match (occ, open) {
                (true, None) => open = Some(t),
                (false, Some(s)) => {
                    if t > s {
                        out.push([s, t]);
                    }
                    open = None;
                }
                _ => {}
            }
            t = t_next;
            cell[a] += step[a];
            t_max[a] += t_delta[a];
            if cell[a] < 0 || cell[a] >= r {
                break;
            }
        }
        if let Some(s) = open
            && t > s
        {
            out.push([s, t]);
        }
    }
}

impl OccupancyGrid {
    /// [`ray_segments`](Self::ray_segments) in a contracted grid: the ray walked from `near` to
    /// `far` in `CONTRACTED_STEPS_PER_CELL · resolution` even steps of its normalised distance
    /// `s` ([`crate::contract::ray_distance_to_s`]), each step looked up at the contraction of its
    /// middle point, occupied steps joined into spans between their ends (`near` and `far` at the
    /// ends of the walk). The cone's footprint there, its radius `radius · t` scaled by the
    /// contraction across the ray from the origin (`(2 - 1/r)/r`), picks the dilation as in a
    /// world grid.
    fn contracted_ray_segments(&self, ray: &Ray, out: &mut Vec<[f32; 2]>) {
        use crate::contract::{contract, ray_distance_to_s, s_to_ray_distance};
        let (s0, s1) = (ray_distance_to_s(ray.near), ray_distance_to_s(ray.far));
        if s0.partial_cmp(&s1) != Some(std::cmp::Ordering::Less) {
            return;
        }
        let n = CONTRACTED_STEPS_PER_CELL * self.config.resolution;
        let ds = (s1 - s0) / n as f32;
        let edge = |k: usize| match k {
            0 => ray.near,
            k if k == n => ray.far,
            k => s_to_ray_distance(s0 + k as f32 * ds),
        };
        let (b, h, r) = (self.config.bound, self.cell_size(), self.config.resolution);
        let mut open: Option<f32> = None;
        for k in 0..n {
            let t = s_to_ray_distance(s0 + (k as f32 + 0.5) * ds);
            let x = ray.origin + ray.direction * t;
            let dist = x.length();
            let across = if dist > 1.0 { (2.0 - 1.0 / dist) / dist } else { 1.0 };
            let reach = (2.0 * ray.radius * t * across / h).ceil();
            let layer =
                if reach >= 1.0 { &self.dilated[(reach as usize).min(MAX_DILATION) - 1] } else { &self.occupied };
            let cell = (contract(x) + b) / h;
            let occ = cell.min_element() >= 0.0
                && cell.max_element() < r as f32
                && layer[(cell.z as usize * r + cell.y as usize) * r + cell.x as usize];
            match (occ, open) {
                (true, None) => open = Some(edge(k)),
                (false, Some(start)) => {
                    out.push([start, edge(k)]);
                    open = None;
                }
                _ => {}
            }
        }
        if let Some(start) = open {
            out.push([start, edge(n)]);
        }
    }
}

/// `cells` (`r³`, x fastest) dilated by one cell along each axis: a 3x3x3 maximum, as three
/// passes of a 3-tap maximum, each made of whole slices shifted by one cell (x) or one row or
/// plane of cells (y, z), which the compiler vectorises.
fn dilate(cells: &[bool], r: usize) -> Vec<bool> {
    let n = cells.len();
    let mut cur = cells.to_vec();
    let mut src = cells.to_vec();
    let or_into = |out: &mut [bool], from: &[bool]| out.iter_mut().zip(from).for_each(|(o, &v)| *o |= v);
    // Along x, within each line of `r` cells.
    for (c, s) in cur.chunks_exact_mut(r).zip(src.chunks_exact(r)) {
        or_into(&mut c[1..], &s[..r - 1]);
        or_into(&mut c[..r - 1], &s[1..]);
    }
    // Along y and z: each row (plane) of `stride` cells takes its neighbours' whole.
    for stride in [r, r * r] {
        src.copy_from_slice(&cur);
        for block in (0..n).step_by(stride * r) {
            for pos in 0..r {
                let row = block + pos * stride;
                if pos > 0 {
                    or_into(&mut cur[row..row + stride], &src[row - stride..row]);
                }
                if pos + 1 < r {
                    or_into(&mut cur[row..row + stride], &src[row + stride..row + 2 * stride]);
                }
            }
        }
    }
    cur
}

fn sign(bit: usize) -> f32 {
    if bit != 0 { 1.0 } else { -1.0 }
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
    fn of_view(v: &crate::data::View) -> Option<Self> {
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

#[cfg(test)]
mod tests {
    use super::dilate;

    /// The line-by-line dilation is the 3x3x3 maximum, cell by cell, on a sparse random grid
    /// of an odd size (lines of every axis end inside it).
    #[test]
    fn dilation_is_the_3x3x3_maximum() {
        let r = 7;
        let mut state = 99u32;
        let cells: Vec<bool> = (0..r * r * r)
            .map(|_| {
                state = crate::rng::pcg_hash(state);
                state.is_multiple_of(13)
            })
            .collect();
        let at = |x: i64, y: i64, z: i64| {
            let inside = |c: i64| (0..r as i64).contains(&c);
            inside(x) && inside(y) && inside(z) && cells[((z * r as i64 + y) * r as i64 + x) as usize]
        };
        let mut expected = vec![false; cells.len()];
        for (i, e) in expected.iter_mut().enumerate() {
            let (x, y, z) = ((i % r) as i64, ((i / r) % r) as i64, (i / (r * r)) as i64);
            *e = (-1..=1).any(|dz| (-1..=1).any(|dy| (-1..=1).any(|dx| at(x + dx, y + dy, z + dz))));
        }
        assert!(cells.iter().any(|&c| c) && expected.iter().any(|&e| !e), "a grid the test can tell apart");
        assert_eq!(dilate(&cells, r), expected);
    }
}
