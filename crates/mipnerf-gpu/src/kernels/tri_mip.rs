//! `shaders/tri_mip.wgsl`: the Tri-Mip field's planes on the device: the mip pyramid, each
//! sample's encoding (the cone's level and the trilinear taps of the three planes), its adjoint
//! into the planes' gradient, the pyramid's gradient pushed down to level 0, and the planes'
//! total variation.
//!
//! CPU reference: [`mipnerf_core::tri_mip`] (`Pyramid::build`, `taps`, `encode`,
//! `encode_backward`, `Pyramid::push_down`, `total_variation`) and the Tri-Mip arm of
//! `Model::encode_samples`.
//!
//! # The scatter's sums
//! Many samples read one texel, so the adjoint adds into shared gradients. WGSL's core has no
//! float atomics, so each addition is a compare-exchange loop on the f32's bits
//! (`atomic<u32>`), which every adapter runs. The sums' order is then the device's: equal to
//! the CPU's to rounding, not bit for bit (the tests bound it). Sorting the taps by texel and
//! reducing would be deterministic, at the price of a sort a step (several dispatches and the
//! taps written out, 8 bytes each of 24 a sample); with most of a step's samples reading
//! distinct texels of the finest levels, contention is low where the volume is, and the
//! coarsest levels (a few texels, many samples) are the hot spots. `SHADER_FLOAT32_ATOMIC`
//! (lavapipe and most hardware have it) would make each addition one instruction behind the
//! same interface; it is not used yet.

#[cfg(feature = "test-support")]
use mipnerf_core::Ray;
use mipnerf_core::RayShape;
use mipnerf_core::model::{Field, Model};
use mipnerf_core::tri_mip::{TriMipConfig, total_variation_scale};

use crate::kernels::{Recorder, WORKGROUP, dispatch_grid};
use crate::{GpuContext, GpuError};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("tri_mip.wgsl", [TriMipParams], includes["plane_taps.wgsl"]);

/// Most levels one dispatch of the pyramid makes (WGSL: `PYRAMID_GROUP_LEVELS`; each invocation
/// reads a block of `2^levels` texels a side, `PYRAMID_BLOCK_AREA` at most).
pub const PYRAMID_GROUP_LEVELS: u32 = 4;

/// The uniform block of `tri_mip.wgsl` (`struct Params`), 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TriMipParams {
    /// Rays.
    pub n_rays: u32,
    /// Samples (intervals) per ray.
    pub n_samples: u32,
    /// `RayShape` code (`RAY_SHAPE_CONE` or `RAY_SHAPE_CYLINDER`).
    pub ray_shape: u32,
    /// Workgroups along x of the 2-D dispatch grid.
    pub groups_x: u32,
    /// Texels along a side of level 0.
    pub resolution: u32,
    /// Features a texel.
    pub features: u32,
    /// Pyramid levels, level 0 included.
    pub levels: u32,
    /// 1: an unbounded scene (the planes cover the contracted space).
    pub unbounded: u32,
    /// The planes' box is `[-half_side, half_side]^3`.
    pub half_side: f32,
    /// 1: each sample read at its footprint's level; 0: at level 0 (the tri-plane baseline).
    pub pre_filtered: u32,
    /// The first level `build_levels` makes.
    pub level: u32,
    /// The total variation's weight over its number of neighbouring pairs.
    pub tv_scale: f32,
    /// The levels `build_levels` makes (at most `PYRAMID_GROUP_LEVELS`).
    pub group_levels: u32,
    /// 1: the rays buffer holds one Gaussian per sample, (mean, variance on each axis), in the
    /// planes' space (an occupancy grid's density probes); the edges are not read.
    pub probes: u32,
    /// Padding.
    pub pad1: u32,
    /// Padding.
    pub pad2: u32,
}

super::wgsl_struct!(
    TriMipParams,
    "Params",
    [
        n_rays,
        n_samples,
        ray_shape,
        groups_x,
        resolution,
        features,
        levels,
        unbounded,
        half_side,
        pre_filtered,
        level,
        tv_scale,
        group_levels,
        probes,
        pad1,
        pad2
    ]
);

/// A model's Tri-Mip planes as the kernels read them: their shape, their box, and how samples
/// reach them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneField {
    /// The planes' shape.
    pub planes: TriMipConfig,
    /// The planes' box is `[-half_side, half_side]^3` (of the contracted space when unbounded).
    pub half_side: f32,
    /// Samples read at their footprint's level (tri-mip) or at level 0 (tri-plane).
    pub pre_filtered: bool,
    /// The scene is unbounded: samples are contracted before they are read.
    pub unbounded: bool,
    /// Cones or cylinders.
    pub ray_shape: RayShape,
}

impl PlaneField {
    /// The planes of `model`'s field; `None` for the Mip-NeRF field.
    #[must_use]
    pub fn of(model: &Model) -> Option<Self> {
        let c = model.config();
        let Field::TriMip { planes, half_side, pre_filtered } = c.field else { return None };
        Some(Self { planes, half_side, pre_filtered, unbounded: c.unbounded, ray_shape: c.ray_shape })
    }

    fn params(&self, n_rays: usize, n_samples: usize) -> TriMipParams {
        let p = &self.planes;
        TriMipParams {
            n_rays: n_rays as u32,
            n_samples: n_samples as u32,
            ray_shape: self.ray_shape as u32,
            groups_x: 0,
            resolution: p.resolution as u32,
            features: p.features as u32,
            levels: p.levels as u32,
            unbounded: u32::from(self.unbounded),
            half_side: self.half_side,
            pre_filtered: u32::from(self.pre_filtered),
            level: 0,
            tv_scale: 0.0,
            group_levels: 0,
            probes: 0,
            pad1: 0,
            pad2: 0,
        }
    }

    /// Floats of the levels above 0, one after the other.
    #[must_use]
    pub fn pyramid_len(&self) -> usize {
        (1..self.planes.levels).map(|l| self.planes.level_len(l)).sum()
    }
}

/// The planes' own buffers beside the parameters and their gradient: the pyramid (levels
/// 1..), its gradient, the total variation's rows, and stand-ins for the bindings a dispatch
/// does not use.
#[derive(Debug)]
pub struct FieldBuffers {
    /// Levels 1.. of the planes, built from the parameters once a pass.
    pub pyramid: wgpu::Buffer,
    /// Their gradient in a training step (cleared before it, pushed down to level 0 after it).
    pub grad_pyramid: wgpu::Buffer,
    /// Per row of level 0: its sum of squared neighbour differences (the last step's).
    pub tv_rows: wgpu::Buffer,
    /// Read-only stand-in (rays, edges) for the dispatches that do not read samples.
    unused_read: wgpu::Buffer,
    /// Stand-in for the samples' encodings.
    unused_samples: wgpu::Buffer,
    /// Stand-in for the gradient outside training.
    unused_grads: wgpu::Buffer,
}

impl FieldBuffers {
    /// Buffers for `field`'s planes.
    #[must_use]
    pub fn new(ctx: &GpuContext, field: &PlaneField) -> Self {
        let len = field.pyramid_len().max(1);
        Self {
            pyramid: ctx.storage_buffer("tri-mip pyramid", &vec![f32::NAN; len], true),
            grad_pyramid: ctx.storage_buffer("tri-mip pyramid gradient", &vec![0.0f32; len], true),
            tv_rows: ctx.storage_buffer(
                "tri-mip total variation rows",
                &vec![0.0f32; 3 * field.planes.resolution],
                true,
            ),
            unused_read: ctx.storage_buffer("tri-mip unused input", &[0.0f32; 4], false),
            unused_samples: ctx.storage_buffer("tri-mip unused samples", &[0.0f32; 4], false),
            unused_grads: ctx.storage_buffer("tri-mip unused gradient", &[0.0f32; 4], false),
        }
    }

    /// Device bytes these buffers take.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        self.pyramid.size() + self.grad_pyramid.size() + self.tv_rows.size()
    }
}

/// A batch's samples as the kernels read them: `n_rays` rays (two vec4 each: (origin,
/// radius), (direction, anything)) of `n_samples` intervals (`n_samples + 1` edges a ray); or,
/// with `probes`, `n_rays * n_samples` Gaussians given one vec4 each in `rays` (mean, variance
/// on each axis), in the field's space: an occupancy grid's density probes.
#[derive(Clone, Copy, Debug)]
pub struct Samples<'a> {
    /// The rays (or the probes).
    pub rays: &'a wgpu::Buffer,
    /// Their edges (bound, not read, for probes).
    pub t_vals: &'a wgpu::Buffer,
    /// Rays.
    pub n_rays: usize,
    /// Intervals a ray.
    pub n_samples: usize,
    /// `rays` holds Gaussians, not rays.
    pub probes: bool,
}

/// The compiled entry points of `tri_mip.wgsl`.
#[derive(Debug)]
pub struct TriMipKernel {
    build: wgpu::ComputePipeline,
    encode: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    push_down: wgpu::ComputePipeline,
    total_variation: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

/// The dispatches that build a pyramid of `levels` levels (level 0 included): as few as
/// [`PYRAMID_GROUP_LEVELS`] allows, the levels above 0 shared out evenly, as (first level,
/// levels).
#[must_use]
pub fn pyramid_groups(levels: usize) -> Vec<(u32, u32)> {
    let above = levels.saturating_sub(1) as u32;
    let n = above.div_ceil(PYRAMID_GROUP_LEVELS);
    let mut first = 1;
    (0..n)
        .map(|k| {
            let take = (above - (first - 1)).div_ceil(n - k);
            let group = (first, take);
            first += take;
            group
        })
        .collect()
}

impl TriMipKernel {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let read_only = [true, true, true, false, false, false, false, false];
        let entries = ["build_levels", "encode_planes", "scatter_planes", "push_down", "total_variation"];
        let ([build, encode, scatter, push_down, total_variation], layout) =
            crate::kernels::build_entries(ctx, "tri_mip", SOURCE, &read_only, entries)?;
        Ok(Self { build, encode, scatter, push_down, total_variation, layout })
    }

    fn dispatch(
        &self,
        rec: &mut Recorder<'_>,
        (name, pipeline): (&str, &wgpu::ComputePipeline),
        mut p: TriMipParams,
        n_items: u64,
        buffers: [&wgpu::Buffer; 8],
    ) -> Result<(), GpuError> {
        let (gx, gy) = dispatch_grid(n_items, WORKGROUP)?;
        p.groups_x = gx;
        rec.dispatch(name, pipeline, &self.layout, &p, &buffers, (gx, gy, 1));
        Ok(())
    }

    /// Records the levels above 0 of the planes whose level 0 leads `params` into
    /// `bufs.pyramid`: one dispatch per group of [`pyramid_groups`], each making up to
    /// [`PYRAMID_GROUP_LEVELS`] levels.
    ///
    /// # Errors
    /// Planes too large for one dispatch.
    pub fn build_pyramid(
        &self,
        rec: &mut Recorder<'_>,
        field: &PlaneField,
        params: &wgpu::Buffer,
        bufs: &FieldBuffers,
    ) -> Result<(), GpuError> {
        let (r, s, g) = (&bufs.unused_read, &bufs.unused_samples, &bufs.unused_grads);
        for (first, levels) in pyramid_groups(field.planes.levels) {
            let p = TriMipParams { level: first, group_levels: levels, ..field.params(0, 0) };
            let n = field.planes.level_len((first + levels - 1) as usize) as u64;
            let buffers = [r, r, params, &bufs.pyramid, s, g, &bufs.grad_pyramid, &bufs.tv_rows];
            self.dispatch(rec, ("tri_mip build_levels", &self.build), p, n, buffers)?;
        }
        Ok(())
    }

    /// Records the encoding of every sample of `samples` into `out` (`3 · features` floats a
    /// sample), from level 0 in `params` and the pyramid in `bufs` (built first).
    ///
    /// # Errors
    /// A batch too large for one dispatch.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        field: &PlaneField,
        samples: Samples<'_>,
        params: &wgpu::Buffer,
        bufs: &FieldBuffers,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let p = TriMipParams { probes: u32::from(samples.probes), ..field.params(samples.n_rays, samples.n_samples) };
        let n = 3 * samples.n_rays as u64 * samples.n_samples as u64;
        let g = &bufs.unused_grads;
        let buffers = [samples.rays, samples.t_vals, params, &bufs.pyramid, out, g, &bufs.grad_pyramid, &bufs.tv_rows];
        self.dispatch(rec, ("tri_mip encode_planes", &self.encode), p, n, buffers)
    }

    /// Records the adjoint of [`encode`](Self::encode): `d_x` (the gradient of every sample's
    /// encoding) through each sample's taps, **added** to level 0's gradient (the first floats of
    /// `grads`) and to `bufs.grad_pyramid`. The pyramid (`bufs.pyramid`) is bound, not read.
    ///
    /// # Errors
    /// A batch too large for one dispatch.
    pub fn scatter(
        &self,
        rec: &mut Recorder<'_>,
        field: &PlaneField,
        samples: Samples<'_>,
        d_x: &wgpu::Buffer,
        grads: &wgpu::Buffer,
        bufs: &FieldBuffers,
    ) -> Result<(), GpuError> {
        let p = field.params(samples.n_rays, samples.n_samples);
        let n = 3 * samples.n_rays as u64 * samples.n_samples as u64;
        let r = &bufs.unused_read;
        let buffers = [samples.rays, samples.t_vals, r, &bufs.pyramid, d_x, grads, &bufs.grad_pyramid, &bufs.tv_rows];
        self.dispatch(rec, ("tri_mip scatter_planes", &self.scatter), p, n, buffers)
    }

    /// Records the push-down of `bufs.grad_pyramid` into level 0's gradient in `grads`, and with
    /// `planes_tv` (a weight and the parameters, level 0 first) that weight times the gradient of
    /// level 0's total variation added there too, in one dispatch (the pyramid's gradient is left
    /// as it is: clear it before the next step). The loss is [`total_variation`](Self::total_variation)'s.
    ///
    /// # Errors
    /// Planes too large for one dispatch.
    pub fn push_down(
        &self,
        rec: &mut Recorder<'_>,
        field: &PlaneField,
        planes_tv: Option<(f32, &wgpu::Buffer)>,
        grads: &wgpu::Buffer,
        bufs: &FieldBuffers,
    ) -> Result<(), GpuError> {
        let (r, s) = (&bufs.unused_read, &bufs.unused_samples);
        let n = field.planes.num_params() as u64;
        let (tv_scale, params) =
            planes_tv.map_or((0.0, r), |(w, params)| (total_variation_scale(&field.planes, w), params));
        let p = TriMipParams { tv_scale, ..field.params(0, 0) };
        let buffers = [r, r, params, &bufs.pyramid, s, grads, &bufs.grad_pyramid, &bufs.tv_rows];
        self.dispatch(rec, ("tri_mip push_down", &self.push_down), p, n, buffers)
    }

    /// Records the sums of squared neighbour differences of level 0 (in `params`), a row each,
    /// into `bufs.tv_rows`: the total variation's loss is [`total_variation_loss`] of them (its
    /// gradient is [`push_down`](Self::push_down)'s).
    ///
    /// # Errors
    /// Planes too large for one dispatch.
    pub fn total_variation(
        &self,
        rec: &mut Recorder<'_>,
        field: &PlaneField,
        params: &wgpu::Buffer,
        bufs: &FieldBuffers,
    ) -> Result<(), GpuError> {
        let (r, s, g) = (&bufs.unused_read, &bufs.unused_samples, &bufs.unused_grads);
        let n = 3 * field.planes.resolution as u64;
        let buffers = [r, r, params, &bufs.pyramid, s, g, &bufs.grad_pyramid, &bufs.tv_rows];
        self.dispatch(rec, ("tri_mip total_variation", &self.total_variation), field.params(0, 0), n, buffers)
    }
}

/// The total variation's loss from its rows (read back from `FieldBuffers::tv_rows`), summed
/// in f64 and scaled as the CPU does.
#[must_use]
pub fn total_variation_loss(planes: &TriMipConfig, weight: f32, rows: &[f32]) -> f64 {
    rows.iter().map(|&r| f64::from(r)).sum::<f64>() * f64::from(total_variation_scale(planes, weight))
}

/// Host-side runs of the kernels, for tests: each uploads its inputs, records, submits and reads
/// the result back.
impl TriMipKernel {
    /// The encodings of `rays`' intervals (`t_vals`, `n_samples + 1` edges a ray) read from the
    /// planes whose level 0 leads `params`: `rays.len() · n_samples · 3 · features` floats, as
    /// `Model::encode_samples` writes them.
    ///
    /// # Errors
    /// Inconsistent sizes; any error wgpu reports.
    #[cfg(feature = "test-support")]
    pub fn run_encode(
        &self,
        ctx: &GpuContext,
        field: &PlaneField,
        rays: &[Ray],
        t_vals: &[f32],
        params: &[f32],
    ) -> Result<Vec<f32>, GpuError> {
        let n_samples = samples_per_ray(rays, t_vals)?;
        if params.len() < field.planes.num_params() {
            return Err(GpuError::InvalidInput(format!(
                "tri_mip: {} parameters for planes of {}",
                params.len(),
                field.planes.num_params()
            )));
        }
        let bufs = FieldBuffers::new(ctx, field);
        let (ray_buf, t_buf) = (upload_rays(ctx, rays), ctx.storage_buffer("tri_mip t_vals", t_vals, false));
        let params_buf = ctx.storage_buffer("tri_mip params", params, false);
        let len = rays.len() * n_samples * field.planes.encoding_dim();
        let out = ctx.storage_buffer("tri_mip encoded", &vec![f32::NAN; len.max(1)], true);
        let samples = Samples { rays: &ray_buf, t_vals: &t_buf, n_rays: rays.len(), n_samples, probes: false };
        let mut rec = Recorder::new(ctx, "tri_mip encode");
        self.build_pyramid(&mut rec, field, &params_buf, &bufs)?;
        self.encode(&mut rec, field, samples, &params_buf, &bufs, &out)?;
        let _ = rec.submit();
        ctx.read_f32(&out, len)
    }

    /// The levels above 0 built from `params` (level 0 first in it), one after the other.
    ///
    /// # Errors
    /// Any error wgpu reports.
    #[cfg(feature = "test-support")]
    pub fn run_build(&self, ctx: &GpuContext, field: &PlaneField, params: &[f32]) -> Result<Vec<f32>, GpuError> {
        let bufs = FieldBuffers::new(ctx, field);
        let params_buf = ctx.storage_buffer("tri_mip params", params, false);
        let mut rec = Recorder::new(ctx, "tri_mip build");
        self.build_pyramid(&mut rec, field, &params_buf, &bufs)?;
        let _ = rec.submit();
        ctx.read_f32(&bufs.pyramid, field.pyramid_len())
    }

    /// The planes' gradient (level 0, `num_params` floats, the rest of the gradient left out)
    /// for `d_x`, the gradient of the encodings [`run_encode`](Self::run_encode) gives: scattered
    /// and pushed down.
    ///
    /// # Errors
    /// Inconsistent sizes; any error wgpu reports.
    #[cfg(feature = "test-support")]
    pub fn run_backward(
        &self,
        ctx: &GpuContext,
        field: &PlaneField,
        rays: &[Ray],
        t_vals: &[f32],
        d_x: &[f32],
    ) -> Result<Vec<f32>, GpuError> {
        let n_params = field.planes.num_params();
        let n_samples = samples_per_ray(rays, t_vals)?;
        if d_x.len() != rays.len() * n_samples * field.planes.encoding_dim() {
            return Err(GpuError::InvalidInput(format!("tri_mip: {} encoding gradients", d_x.len())));
        }
        let bufs = FieldBuffers::new(ctx, field);
        let (ray_buf, t_buf) = (upload_rays(ctx, rays), ctx.storage_buffer("tri_mip t_vals", t_vals, false));
        let d_x_buf = ctx.storage_buffer("tri_mip d_x", d_x, false);
        let grads = ctx.storage_buffer("tri_mip gradient", &vec![0.0f32; n_params], true);
        let samples = Samples { rays: &ray_buf, t_vals: &t_buf, n_rays: rays.len(), n_samples, probes: false };
        let mut rec = Recorder::new(ctx, "tri_mip backward");
        self.scatter(&mut rec, field, samples, &d_x_buf, &grads, &bufs)?;
        self.push_down(&mut rec, field, None, &grads, &bufs)?;
        let _ = rec.submit();
        ctx.read_f32(&grads, n_params)
    }

    /// `weight` times the planes' total variation of level 0 (`params`): the loss and its
    /// gradient (the push-down's, of a pyramid whose gradient is 0).
    ///
    /// # Errors
    /// Any error wgpu reports.
    #[cfg(feature = "test-support")]
    pub fn run_total_variation(
        &self,
        ctx: &GpuContext,
        field: &PlaneField,
        params: &[f32],
        weight: f32,
    ) -> Result<(f64, Vec<f32>), GpuError> {
        let bufs = FieldBuffers::new(ctx, field);
        let params_buf = ctx.storage_buffer("tri_mip params", params, false);
        let grads = ctx.storage_buffer("tri_mip gradient", &vec![0.0f32; params.len()], true);
        let mut rec = Recorder::new(ctx, "tri_mip total variation");
        self.push_down(&mut rec, field, Some((weight, &params_buf)), &grads, &bufs)?;
        self.total_variation(&mut rec, field, &params_buf, &bufs)?;
        let _ = rec.submit();
        let rows = ctx.read_f32(&bufs.tv_rows, 3 * field.planes.resolution)?;
        Ok((total_variation_loss(&field.planes, weight, &rows), ctx.read_f32(&grads, params.len())?))
    }
}

/// The rays as the kernels read them ([`super::packed_rays`]; at least one, checked by
/// [`samples_per_ray`]).
#[cfg(feature = "test-support")]
fn upload_rays(ctx: &GpuContext, rays: &[Ray]) -> wgpu::Buffer {
    ctx.storage_buffer("tri_mip rays", &super::packed_rays(rays), false)
}

/// Intervals a ray of `t_vals` for `rays` (at least one ray of at least one interval).
#[cfg(feature = "test-support")]
fn samples_per_ray(rays: &[Ray], t_vals: &[f32]) -> Result<usize, GpuError> {
    if rays.is_empty() || !t_vals.len().is_multiple_of(rays.len()) || t_vals.len() / rays.len() < 2 {
        return Err(GpuError::InvalidInput(format!("tri_mip: {} edges for {} rays", t_vals.len(), rays.len())));
    }
    Ok(t_vals.len() / rays.len() - 1)
}
