//! The field a model reads its samples from ([`Field`]): the seam between the Mip-NeRF MLP on
//! the IPE and the Tri-Mip planes before a small MLP. `Model::run_chunk` calls
//! [`Model::encode_samples`] where the paper encodes its Gaussians, and `field_backward` after
//! the MLP's backward pass; the occupancy probes and export call [`Model::encode_probe`].

use super::{Field, Model, Workspace};
use crate::bf16::Precision;
use crate::cone::{Ray, RayShape};
use crate::mip::Gaussian;
use crate::mlp::MlpShape;
use crate::stages;
use crate::tri_mip::{self, Pyramid};

/// What a pass reads of the field's parameters besides the MLP: for the Tri-Mip field, the
/// planes' mip pyramid, built from the parameters once a pass ([`Model::field_state`]).
#[derive(Clone, Debug, Default)]
pub struct FieldState {
    pyramid: Option<Pyramid>,
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
            Field::TriMip { planes, .. } => {
                let mut pyramid = Pyramid::zeros(planes);
                pyramid.build(&params[..self.field_params]);
                FieldState { pyramid: Some(pyramid) }
            }
        }
    }

    /// The chunk's samples (`ws.t`'s intervals of `rays`) encoded into `ws.x`: the IPE of
    /// their Gaussians (Mip-NeRF), or the Tri-Mip planes read at each frustum's footprint (its
    /// taps kept in `ws.taps` for the backward pass).
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
        let Field::TriMip { planes, half_side, pre_filtered } = c.field else {
            let (encoding, degrees) = ((c.point_encoding, precision), (c.min_deg_point, c.max_deg_point));
            stages::cast_and_encode(rays, &ws.t, (s, c.unbounded), c.ray_shape, encoding, degrees, &mut ws.x);
            return;
        };
        let pyramid = field.pyramid.as_ref().expect("the Tri-Mip field's pass has its pyramid");
        let (dim, side) = (planes.encoding_dim(), 2.0 * half_side);
        ws.taps.resize(rays.len() * s, tri_mip::taps(&planes, glam::Vec3::ZERO, 0.0));
        for (r, ray) in rays.iter().enumerate() {
            let t = &ws.t[r * (s + 1)..(r + 1) * (s + 1)];
            for j in 0..s {
                let m = match c.ray_shape {
                    RayShape::Cone => crate::mip::conical_frustum_moments(t[j], t[j + 1], ray.radius),
                    RayShape::Cylinder => crate::mip::cylinder_moments(t[j], t[j + 1], ray.radius),
                };
                let at = (ray.origin + ray.direction * m.t_mean + half_side) / side;
                let radius = tri_mip::footprint_radius(&m) * ray.direction.length() / side;
                let level = if pre_filtered { tri_mip::level_of(radius, &planes) } else { 0.0 };
                let k = r * s + j;
                ws.taps[k] = tri_mip::taps(&planes, at, level);
                tri_mip::encode(
                    &planes,
                    &params[..self.field_params],
                    pyramid,
                    &ws.taps[k],
                    &mut ws.x[k * dim..(k + 1) * dim],
                );
            }
        }
    }

    /// After the MLP's backward pass of a level: the gradient of its input into the Tri-Mip
    /// planes (level 0 in `grads`, the levels above in `ws.grad_pyramid`); nothing for Mip-NeRF,
    /// whose encoding has no parameters.
    pub(super) fn field_backward(
        &self,
        params: &[f32],
        mlp: &MlpShape,
        n: usize,
        ws: &mut Workspace,
        grads: &mut [f32],
    ) {
        let Field::TriMip { planes, .. } = self.config.field else { return };
        let dim = planes.encoding_dim();
        ws.d_x.resize(n * dim, 0.0);
        mlp.input_gradient(params, &ws.cache, &mut ws.d_x);
        let grad_pyramid = ws.grad_pyramid.get_or_insert_with(|| Pyramid::zeros(planes));
        if grad_pyramid.config() != planes {
            *grad_pyramid = Pyramid::zeros(planes);
        }
        tri_mip::encode_backward_batch(&planes, &ws.taps[..n], &ws.d_x, &mut grads[..self.field_params], grad_pyramid);
    }

    /// At the end of a chunk's backward pass: the Tri-Mip pyramid's gradient pushed into the
    /// planes' level 0 (in `grads`), and cleared for the next chunk.
    pub(super) fn field_backward_finish(&self, ws: &mut Workspace, grads: &mut [f32]) {
        if let (Field::TriMip { .. }, Some(grad_pyramid)) = (self.config.field, ws.grad_pyramid.as_mut()) {
            grad_pyramid.push_down(&mut grads[..self.field_params]);
            grad_pyramid.clear();
        }
    }

    /// One Gaussian (world space) encoded by the model's field into `dst` (`x_dim` values): the
    /// Mip-NeRF field's [`encode_point`](Self::encode_point), or the Tri-Mip planes (of `params`,
    /// their pyramid in `field`) read at its mean and at the level of its footprint, `2σ` for
    /// its mean per-axis variance `σ²` (an occupancy cell's or a point's). Inlined, as
    /// [`encode_point`](Self::encode_point) is.
    #[inline(always)]
    pub fn encode_probe(&self, params: &[f32], field: &FieldState, g: &Gaussian, dst: &mut [f32]) {
        let Field::TriMip { planes, half_side, pre_filtered } = self.config.field else {
            self.encode_point(g, dst);
            return;
        };
        let pyramid = field.pyramid.as_ref().expect("the Tri-Mip field's pass has its pyramid");
        let side = 2.0 * half_side;
        let radius = 2.0 * (g.cov_diag.element_sum() / 3.0).max(0.0).sqrt() / side;
        let level = if pre_filtered { tri_mip::level_of(radius, &planes) } else { 0.0 };
        let taps = tri_mip::taps(&planes, (g.mean + half_side) / side, level);
        tri_mip::encode(&planes, &params[..self.field_params], pyramid, &taps, dst);
    }
}
