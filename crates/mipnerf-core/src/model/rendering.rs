//! Rendering a trained model: every pixel's outputs at the levels asked for ([`Levels`]), with
//! or without an occupancy grid, through the same chunks as training (`Model::run_chunk`).

use rayon::prelude::*;

use super::{CHUNK_RAYS, Chunk, Model, RayIds, WORKSPACE};
use crate::cone::Ray;
use crate::config::Mode;
use crate::occupancy::OccupancyGrid;

/// What one level renders for one pixel.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct LevelOutput {
    /// Colour.
    pub rgb: [f32; 3],
    /// Expected depth.
    pub distance: f32,
    /// Accumulated opacity.
    pub acc: f32,
}

/// Which sampling levels a render returns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Levels {
    /// Every level's colour, distance and opacity: `num_levels` outputs per pixel, pixel-major.
    #[default]
    All,
    /// The last level's alone, one output per pixel: the model's output, what images, depth maps
    /// and metrics show. The earlier levels run only as far as the resampling needs (their
    /// densities, hence their weights), skipping the MLP's colour layers; the last level's
    /// output is the same bits as under [`Levels::All`].
    Last,
}

impl Model {
    /// Renders every pixel at every level (evaluation mode). `rays` holds
    /// [`rays_per_pixel`](Self::rays_per_pixel) consecutive rays per pixel; returns
    /// `pixels x num_levels` outputs, pixel-major.
    ///
    /// # Panics
    /// If `rays.len()` is not a multiple of the rays per pixel, or `params` has the wrong length.
    #[must_use]
    pub fn render(&self, params: &[f32], rays: &[Ray]) -> Vec<LevelOutput> {
        self.render_guided(params, rays, None)
    }

    /// [`render`](Self::render) with occupancy-guided sampling: with a `grid` that is not full
    /// (and one ray per pixel), rays that meet no occupied cell render the background (opacity 0,
    /// distance `near`) without running the MLP, and the others sample only their occupied spans.
    /// A full grid, or none, renders exactly as [`render`](Self::render).
    ///
    /// # Panics
    /// As [`render`](Self::render).
    #[must_use]
    pub fn render_guided(&self, params: &[f32], rays: &[Ray], grid: Option<&OccupancyGrid>) -> Vec<LevelOutput> {
        self.render_levels(params, rays, grid, Levels::All)
    }

    /// [`render_guided`](Self::render_guided) returning the `levels` asked for: every level
    /// (`num_levels` outputs per pixel), or the last alone (one per pixel, its bits those of the
    /// last level under [`Levels::All`]), which skips the earlier levels' colour layers.
    ///
    /// # Panics
    /// As [`render`](Self::render).
    #[must_use]
    pub fn render_levels(
        &self,
        params: &[f32],
        rays: &[Ray],
        grid: Option<&OccupancyGrid>,
        which: Levels,
    ) -> Vec<LevelOutput> {
        let rpp = self.rays_per_pixel();
        assert_eq!(rays.len() % rpp, 0, "render: rays per pixel");
        assert_eq!(params.len(), self.num_params, "render: parameter count");
        let levels = match which {
            Levels::All => self.config.num_levels,
            Levels::Last => 1,
        };
        let field = self.field_state(params);
        let Some(guide) = self.guide(grid, rays) else {
            let chunk = CHUNK_RAYS.div_ceil(rpp) * rpp;
            return rays
                .par_chunks(chunk)
                .map(|rays| {
                    let mut out = vec![LevelOutput::default(); rays.len() / rpp * levels];
                    WORKSPACE.with(|ws| {
                        let ws = &mut ws.borrow_mut();
                        let out = Some((&mut out[..], which));
                        let chunk = Chunk { rays, ids: RayIds::From(0), spans: None, targets: None, mode: Mode::Eval };
                        self.run_chunk(params, &field, chunk, ws, None, out)
                    });
                    out
                })
                .collect::<Vec<_>>()
                .concat();
        };
        let active_rays: Vec<Ray> = guide.active.iter().map(|&i| rays[i as usize]).collect();
        let rendered: Vec<Vec<LevelOutput>> = active_rays
            .par_chunks(CHUNK_RAYS)
            .enumerate()
            .map(|(ci, chunk)| {
                let mut out = vec![LevelOutput::default(); chunk.len() * levels];
                let first = ci * CHUNK_RAYS;
                let ids = RayIds::List(&guide.active[first..first + chunk.len()]);
                let spans = guide.spans(first, chunk.len());
                WORKSPACE.with(|ws| {
                    let ws = &mut ws.borrow_mut();
                    let out = Some((&mut out[..], which));
                    let job = Chunk { rays: chunk, ids, spans: Some(spans), targets: None, mode: Mode::Eval };
                    self.run_chunk(params, &field, job, ws, None, out)
                });
                out
            })
            .collect();
        let mut out: Vec<LevelOutput> =
            rays.iter().flat_map(|r| std::iter::repeat_n(self.background_output(r), levels)).collect();
        for (&i, o) in guide.active.iter().zip(rendered.concat().chunks(levels)) {
            out[i as usize * levels..(i as usize + 1) * levels].copy_from_slice(o);
        }
        out
    }

    /// What a ray that meets no occupied cell renders at every level: the background, no
    /// opacity, and `near` as its distance (what [`render::volumetric_rendering`] reports for a
    /// ray with no opacity: its first edge).
    fn background_output(&self, ray: &Ray) -> LevelOutput {
        LevelOutput { rgb: self.ray_background(Mode::Eval, 0), distance: ray.near, acc: 0.0 }
    }
}
