//! The field a model reads its samples from ([`Field`]): the seam between the Mip-NeRF MLP on
//! the IPE and the Tri-Mip planes before a small MLP. `Model::run_chunk` calls
//! [`Model::encode_samples`] where the paper encodes its Gaussians, and `field_backward` after
//! the MLP's backward pass (keeping the chunk's encoding gradients), and the training step
//! `field_backward_chunks` after every chunk; the occupancy probes and export call
//! [`Model::encode_probe`].

use super::{Field, Model, Workspace};
use crate::bf16::Precision;
use crate::cone::{Ray, RayShape};
use crate::hash_grid;
use crate::mip::Gaussian;
use crate::mlp::MlpShape;
use crate::stages;
use crate::tri_mip::{self, Pyramid};

/// A chunk's share of the field's gradient in a training step, kept until every chunk has run:
/// each sample's Tri-Mip taps and the gradient of its encoding, level after level. The planes
/// stay out of the chunks' dense gradients, which then hold the MLP's parameters alone.
#[derive(Clone, Debug, Default)]
pub(super) struct FieldGrads {
    taps: Vec<tri_mip::Taps>,
    grid_samples: Vec<hash_grid::GridSample>,
    d_x: Vec<f32>,
}

impl FieldGrads {
    pub(super) fn clear(&mut self) {
        self.taps.clear();
        self.grid_samples.clear();
        self.d_x.clear();
    }
}

/// What a pass reads of the field's parameters besides the MLP: for the Tri-Mip field, the
/// planes' mip pyramid, built from the parameters once a pass ([`Model::field_state`]).
#[derive(Clone, Debug, Default)]
pub struct FieldState {
    pyramid: Option<Pyramid>,
    grid: Option<hash_grid::Levels>,
    /// The floor under the samples' footprints in this pass, in the box's units
    /// ([`ModelConfig::footprint_floor_at`](crate::config::ModelConfig::footprint_floor_at)):
    /// 0 but in a coarse-to-fine run's first training steps.
    footprint_floor: f32,
}

impl FieldState {
    /// This pass's state with every sample's footprint read as at least `floor` wide (a radius
    /// in the box's units, combined with the sample's own in quadrature; 0: as it is).
    #[must_use]
    pub fn with_footprint_floor(self, floor: f32) -> Self {
        Self { footprint_floor: floor, ..self }
    }
}

impl Model {
    /// The parameters before the MLPs' (the Tri-Mip planes' level 0; none for Mip-NeRF).
    #[must_use]
    pub fn field_params(&self) -> usize {
        self.field_params
    }

    /// What a pass over `params` reads besides them: the Tri-Mip planes' pyramid, built here.
    #[must_use]
    pub fn field_state(&self, params: &[f32]) -> FieldState {
        match self.config.field {
            Field::MipNerf => FieldState::default(),
            Field::HashGrid { grid, .. } => {
                FieldState { grid: Some(hash_grid::Levels::new(grid)), ..FieldState::default() }
            }
            Field::TriMip { planes, .. } => {
                let mut pyramid = Pyramid::zeros(planes);
                pyramid.build(&params[..self.field_params]);
                FieldState { pyramid: Some(pyramid), ..FieldState::default() }
            }
        }
    }

    /// The chunk's samples (`ws.t`'s intervals of `rays`) encoded into `ws.x`: the IPE of
    /// their Gaussians (Mip-NeRF), the Tri-Mip planes read at each frustum's footprint (its
    /// taps kept in `ws.taps` for the backward pass), or the hash grid down-weighted at it (its
    /// points and footprints kept in `ws.grid_samples`).
    pub(super) fn encode_samples(
        &self,
        params: &[f32],
        field: &FieldState,
        rays: &[Ray],
        precision: Precision,
        ws: &mut Workspace,
    ) {
        let c = &self.config;
        let s = c.num_samples;
        let Some(half_side) = c.field.half_side() else {
            let stage = stages::CastIpe {
                n_samples: s,
                shape: c.ray_shape,
                unbounded: c.unbounded,
                encoding: c.point_encoding,
                min_deg: c.min_deg_point,
                max_deg: c.max_deg_point,
            };
            stages::cast_and_encode(rays, &ws.t, stage, precision, &mut ws.x);
            return;
        };
        let side = 2.0 * half_side;
        // Each sample's frustum in the grid's box: its mean, and the radius of its cone's
        // cross-section there (an unbounded scene's grid covers its contracted space, where the
        // cross-section shrinks with the contraction across the ray).
        let in_box = |ray: &Ray, t0: f32, t1: f32| {
            let m = match c.ray_shape {
                RayShape::Cone => crate::mip::conical_frustum_moments(t0, t1, ray.radius),
                RayShape::Cylinder => crate::mip::cylinder_moments(t0, t1, ray.radius),
            };
            let mut x = ray.origin + ray.direction * m.t_mean;
            let mut radius = tri_mip::footprint_radius(&m) * ray.direction.length() / side;
            if c.unbounded {
                radius *= crate::contract::contraction_across(x);
                x = crate::contract::contract(x);
            }
            // A coarse-to-fine run's floor, only where there is one (the bits are otherwise
            // the sample's own radius).
            if field.footprint_floor > 0.0 {
                radius = radius.hypot(field.footprint_floor);
            }
            ((x + half_side) / side, radius)
        };
        let params = &params[..self.field_params];
        match c.field {
            Field::MipNerf => unreachable!("the Mip-NeRF field has no box"),
            Field::TriMip { planes, pre_filtered, .. } => {
                let pyramid = field.pyramid.as_ref().expect("the Tri-Mip field's pass has its pyramid");
                let dim = planes.encoding_dim();
                ws.taps.resize(rays.len() * s, tri_mip::taps(&planes, glam::Vec3::ZERO, 0.0));
                for (r, ray) in rays.iter().enumerate() {
                    let t = &ws.t[r * (s + 1)..(r + 1) * (s + 1)];
                    for j in 0..s {
                        let (at, radius) = in_box(ray, t[j], t[j + 1]);
                        let level = if pre_filtered { tri_mip::level_of(radius, &planes) } else { 0.0 };
                        let k = r * s + j;
                        ws.taps[k] = tri_mip::taps(&planes, at, level);
                        tri_mip::encode(&planes, params, pyramid, &ws.taps[k], &mut ws.x[k * dim..(k + 1) * dim]);
                    }
                }
            }
            Field::HashGrid { grid, .. } => {
                ws.grid_samples.clear();
                for (r, ray) in rays.iter().enumerate() {
                    let t = &ws.t[r * (s + 1)..(r + 1) * (s + 1)];
                    // The footprint as a standard deviation: half the cross-section's radius.
                    ws.grid_samples.extend(
                        (0..s)
                            .map(|j| in_box(ray, t[j], t[j + 1]))
                            .map(|(at, radius)| hash_grid::GridSample { at, scale: 0.5 * radius }),
                    );
                }
                let levels = field.grid.as_ref().expect("the hash grid's pass has its levels");
                let n = ws.grid_samples.len() * grid.encoding_dim();
                levels.encode_many(params, &ws.grid_samples, &mut ws.x[..n]);
            }
        }
    }

    /// The encodings of `rays`' intervals (`t_vals`: `num_samples + 1` edges a ray) as the
    /// field hands them to the MLP, `rays.len() · num_samples · x_dim` values, sample after
    /// sample: the reference the GPU's encoding kernels are checked against.
    ///
    /// # Panics
    /// If `params` is not the model's or `t_vals` is not `num_samples + 1` edges a ray.
    #[must_use]
    pub fn encode_intervals(&self, params: &[f32], rays: &[Ray], t_vals: &[f32]) -> Vec<f32> {
        self.encoded_intervals(params, rays, t_vals).x
    }

    /// The adjoint of [`encode_intervals`](Self::encode_intervals): the gradient of the field's
    /// own parameters ([`field_params`](Self::field_params) values, the Tri-Mip planes' level
    /// 0; none for Mip-NeRF) for `d_x`, the gradient of those encodings, through the pyramid
    /// as a training step carries it.
    ///
    /// # Panics
    /// As [`encode_intervals`](Self::encode_intervals), and `d_x` of another length.
    #[must_use]
    pub fn encode_intervals_backward(&self, params: &[f32], rays: &[Ray], t_vals: &[f32], d_x: &[f32]) -> Vec<f32> {
        let ws = self.encoded_intervals(params, rays, t_vals);
        assert_eq!(d_x.len(), ws.x.len(), "encode_intervals_backward: d_x");
        let mut grad = vec![0.0; self.field_params];
        let n = d_x.len() / self.mlps()[0].config.x_dim.max(1);
        let chunk = FieldGrads {
            taps: ws.taps[..n.min(ws.taps.len())].to_vec(),
            grid_samples: ws.grid_samples[..n.min(ws.grid_samples.len())].to_vec(),
            d_x: d_x.to_vec(),
        };
        self.field_backward_chunks(std::slice::from_ref(&chunk), &mut None, &mut grad);
        grad
    }

    fn encoded_intervals(&self, params: &[f32], rays: &[Ray], t_vals: &[f32]) -> Workspace {
        assert_eq!(params.len(), self.num_params(), "encode_intervals: parameters");
        let s = self.config.num_samples;
        assert_eq!(t_vals.len(), rays.len() * (s + 1), "encode_intervals: edges");
        let mut ws = Workspace::default();
        ws.t.extend_from_slice(t_vals);
        ws.x.resize(rays.len() * s * self.mlps()[0].config.x_dim, 0.0);
        self.encode_samples(params, &self.field_state(params), rays, Precision::F32, &mut ws);
        ws
    }

    /// After the MLP's backward pass of a level: the gradient of its input (the Tri-Mip
    /// encoding of each sample) kept with the samples' taps in the chunk's `field_grads`, for
    /// [`field_backward_chunks`](Self::field_backward_chunks); nothing for Mip-NeRF, whose
    /// encoding has no parameters.
    pub(super) fn field_backward(
        &self,
        params: &[f32],
        mlp: &MlpShape,
        n: usize,
        ws: &Workspace,
        field_grads: &mut FieldGrads,
    ) {
        if self.config.field.is_mip_nerf() {
            return;
        }
        let (dim, start) = (self.config.x_dim(), field_grads.d_x.len());
        field_grads.d_x.resize(start + n * dim, 0.0);
        mlp.input_gradient(params, &ws.cache, &mut field_grads.d_x[start..]);
        match self.config.field {
            Field::TriMip { .. } => field_grads.taps.extend_from_slice(&ws.taps[..n]),
            Field::HashGrid { .. } => field_grads.grid_samples.extend_from_slice(&ws.grid_samples[..n]),
            Field::MipNerf => {}
        }
    }

    /// After every chunk of a step: the chunks' encoding gradients scattered through their taps
    /// into the planes, in chunk order (the same sums whatever the number of threads), level 0
    /// into `grad_level0` and the levels above into `grad_pyramid`, which is then pushed down
    /// into level 0 once. Nothing for Mip-NeRF.
    pub(super) fn field_backward_chunks(
        &self,
        chunks: &[FieldGrads],
        grad_pyramid: &mut Option<Pyramid>,
        grad_level0: &mut [f32],
    ) {
        let planes = match self.config.field {
            Field::MipNerf => return,
            Field::HashGrid { grid, .. } => {
                let batches: Vec<(&[hash_grid::GridSample], &[f32])> =
                    chunks.iter().map(|c| (&c.grid_samples[..], &c.d_x[..])).collect();
                hash_grid::Levels::new(grid).encode_backward_batch(&batches, grad_level0);
                return;
            }
            Field::TriMip { planes, .. } => planes,
        };
        let pyramid = grad_pyramid.get_or_insert_with(|| Pyramid::zeros(planes));
        if pyramid.config() != planes {
            *pyramid = Pyramid::zeros(planes);
        }
        let batches: Vec<(&[tri_mip::Taps], &[f32])> = chunks.iter().map(|c| (&c.taps[..], &c.d_x[..])).collect();
        tri_mip::encode_backward_batch(&planes, &batches, grad_level0, pyramid);
        pyramid.push_down(grad_level0);
        pyramid.clear();
    }

    /// The field regularisers' weights: each a positive number with its field (the planes'
    /// total variation with the Tri-Mip field, the weight decay with the hash grid), or 0; and
    /// a coarse-to-fine schedule with a grid field only.
    pub(super) fn check_regulariser_weights(config: &crate::config::ModelConfig) -> Result<(), super::ModelError> {
        if config.planes_tv_mult != 0.0
            && !(config.planes_tv_mult.is_finite()
                && config.planes_tv_mult > 0.0
                && matches!(config.field, Field::TriMip { .. }))
        {
            return Err(super::ModelError::Config(format!(
                "planes_tv_mult weighs the Tri-Mip planes' total variation: a positive number with the Tri-Mip \
                 field, got {} with the {:?} field",
                config.planes_tv_mult, config.field
            )));
        }
        if config.grid_decay_mult != 0.0
            && !(config.grid_decay_mult.is_finite()
                && config.grid_decay_mult > 0.0
                && matches!(config.field, Field::HashGrid { .. }))
        {
            return Err(super::ModelError::Config(format!(
                "grid_decay_mult weighs the hash grid's weight decay: a positive number with the hash-grid field, \
                 got {} with the {:?} field",
                config.grid_decay_mult, config.field
            )));
        }
        if config.coarse_to_fine_steps != 0 && config.field.half_side().is_none() {
            return Err(super::ModelError::Config(
                "coarse_to_fine_steps widens the footprints a grid field reads: the Tri-Mip planes or the hash grid, \
                 not the Mip-NeRF MLP, whose IPE reads every frequency at the cone's own scale"
                    .into(),
            ));
        }
        Ok(())
    }

    /// The field's regulariser with its gradient added to `grad_field`: the Tri-Mip planes' total
    /// variation weighted by `planes_tv_mult`, or the hash grid's weight decay weighted by
    /// `grid_decay_mult`; 0 when off or for Mip-NeRF.
    pub(super) fn field_regulariser(&self, params: &[f32], grad_field: &mut [f32]) -> f32 {
        let field = &params[..self.field_params];
        match self.config.field {
            Field::TriMip { planes, .. } if self.config.planes_tv_mult != 0.0 => {
                tri_mip::total_variation(&planes, field, self.config.planes_tv_mult, grad_field) as f32
            }
            Field::HashGrid { grid, .. } if self.config.grid_decay_mult != 0.0 => {
                grid.weight_decay(field, self.config.grid_decay_mult, grad_field) as f32
            }
            _ => 0.0,
        }
    }

    /// One Gaussian (world space) encoded by the model's field into `dst` (`x_dim` values): the
    /// Mip-NeRF field's [`encode_point`](Self::encode_point), or the Tri-Mip planes (of `params`,
    /// their pyramid in `field`) read at its mean and at the level of its footprint, `2σ` for
    /// its mean per-axis variance `σ²` (an occupancy cell's or a point's; contracted first in
    /// an unbounded scene, whose planes cover the contracted space). With `contracted`, `g` is
    /// already in the contracted space (a cell of a contracted occupancy grid) and is read as it
    /// is. The hash grid reads it at its mean, down-weighted for `σ` as a sample's footprint.
    /// Inlined, as [`encode_point`](Self::encode_point) is.
    #[inline(always)]
    pub fn encode_probe(&self, params: &[f32], field: &FieldState, g: &Gaussian, contracted: bool, dst: &mut [f32]) {
        let (Field::TriMip { half_side, .. } | Field::HashGrid { half_side, .. }) = self.config.field else {
            if contracted {
                let c = &self.config;
                stages::encode_gaussian(g, (c.point_encoding, Precision::F32), c.min_deg_point, c.max_deg_point, dst);
            } else {
                self.encode_point(g, dst);
            }
            return;
        };
        let side = 2.0 * half_side;
        let g = if self.config.unbounded && !contracted { crate::contract::contract_gaussian(g) } else { *g };
        let radius = 2.0 * (g.cov_diag.element_sum() / 3.0).max(0.0).sqrt() / side;
        let Field::TriMip { planes, pre_filtered, .. } = self.config.field else {
            let levels = field.grid.as_ref().expect("the hash grid's pass has its levels");
            let sample = hash_grid::GridSample { at: (g.mean + half_side) / side, scale: 0.5 * radius };
            levels.encode(&params[..self.field_params], &sample, dst);
            return;
        };
        let pyramid = field.pyramid.as_ref().expect("the Tri-Mip field's pass has its pyramid");
        let level = if pre_filtered { tri_mip::level_of(radius, &planes) } else { 0.0 };
        let taps = tri_mip::taps(&planes, (g.mean + half_side) / side, level);
        tri_mip::encode(&planes, &params[..self.field_params], pyramid, &taps, dst);
    }
}
