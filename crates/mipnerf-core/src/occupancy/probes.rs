//! An update's density probes: a random point of each candidate cell at the cell's scale, and
//! the stretch that turns a density into a cell's opacity.

use glam::Vec3;
use rayon::prelude::*;

use super::{CONTRACTED_BOUND, DensityField, OccupancyGrid};
use crate::mip::Gaussian;
use crate::rng::{RayRng, Stream};

impl OccupancyGrid {
    /// How many world units one unit of cell `i`'s space spans along a ray through it: 1 in a
    /// world grid; in a contracted grid, outside the unit ball, the contraction's radial stretch
    /// `r²` at the cell's centre (`r` its world distance, `1/(2 - ρ)` at contracted radius `ρ`),
    /// the largest of its stretches, so a cell's opacity is never underestimated.
    pub(super) fn world_stretch(&self, i: usize) -> f32 {
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
    pub(super) fn densities(&self, field: &impl DensityField, cells: &[usize], seed: u32, step: u32) -> Vec<f32> {
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
}
