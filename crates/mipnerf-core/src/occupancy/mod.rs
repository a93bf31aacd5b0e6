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

mod carve;
mod probes;
mod traversal;

pub use carve::{Carved, GridPlan, NDC_BOUND_MARGIN, auto_bound, ndc_bound};

use glam::Vec3;

use crate::mip::Gaussian;

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

/// -1 or 1: the side of a cell's centre that corner bit `bit` is on.
fn sign(bit: usize) -> f32 {
    if bit != 0 { 1.0 } else { -1.0 }
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
