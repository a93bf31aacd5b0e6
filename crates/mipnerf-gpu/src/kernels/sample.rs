//! `shaders/sample.wgsl`: stratified interval edges and inverse-CDF resampling per ray.
//!
//! CPU reference: [`mipnerf_core::stages::sample_intervals`] and [`mipnerf_core::stages::resample_intervals`].

use mipnerf_core::model::Mode;
use mipnerf_core::sampling::Spacing;
use mipnerf_core::stages::{Resample, Sample};

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of these kernels.
pub const SOURCE: super::Shader = super::shader!("sample.wgsl", [SampleParams]);

/// Most samples per ray the resampling kernel handles (its CDF lives in private memory).
pub const MAX_SAMPLES: usize = 1024;

/// The uniform block of `sample.wgsl` (`struct Params`), 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SampleParams {
    /// Rays.
    pub n_rays: u32,
    /// Samples per ray.
    pub n_samples: u32,
    /// How edges are spaced ([`mipnerf_core::sampling::Spacing::code`]): 0 linear in depth, 1 in
    /// disparity, 2 unbounded (the contraction's normalised distance, resampled in it too).
    pub spacing: u32,
    /// 1: training (jitter, stratified offsets).
    pub randomized: u32,
    /// Run seed.
    pub seed: u32,
    /// Step.
    pub step: u32,
    /// Level of the resampled edges (picks the random stream).
    pub level: u32,
    /// Added to the blurred weights.
    pub resample_padding: f32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// Padding.
    pub _pad: [u32; 3],
}

/// The level a resampling draws from: its edges and its weights.
#[derive(Clone, Copy, Debug)]
pub struct CoarseLevel<'a> {
    /// The level's edges, `n_samples + 1` per ray.
    pub t: &'a wgpu::Buffer,
    /// The level's weights, `n_samples` per ray.
    pub weights: &'a wgpu::Buffer,
}

impl SampleParams {
    /// The uniform block for `n_rays` rays of `n_samples` intervals spaced as `spacing` says,
    /// jittered in training (`mode`); the level and padding are the resampling's.
    #[must_use]
    pub fn new(n_rays: usize, n_samples: usize, spacing: Spacing, mode: Mode) -> Self {
        let (seed, step, train) = kernels::mode_uniforms(mode);
        Self {
            n_rays: n_rays as u32,
            n_samples: n_samples as u32,
            spacing: spacing.code(),
            randomized: u32::from(train),
            seed,
            step,
            ..Self::default()
        }
    }
}

/// How the fine edges are resampled. Both give the same edges up to the rounding of the sums
/// over a ray's weights (grouped by block in `Wide`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResampleVariant {
    /// `resample`: one invocation per ray, for software adapters.
    PerRay,
    /// `resample_wide`: a workgroup of 32 invocations per ray (blocks of weights and outputs,
    /// binary searches in a CDF held in workgroup memory), for hardware GPUs.
    Wide,
}

impl ResampleVariant {
    /// The variant for `ctx`'s adapter.
    #[must_use]
    #[cfg(feature = "test-support")]
    pub fn for_adapter(ctx: &GpuContext) -> Self {
        if ctx.adapter().is_software { Self::PerRay } else { Self::Wide }
    }
}

/// The pipelines of `sample.wgsl`.
#[derive(Debug)]
pub struct SampleKernels {
    stratified: wgpu::ComputePipeline,
    resample: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    variant: ResampleVariant,
}

impl SampleKernels {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    #[cfg(feature = "test-support")]
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Self::with_variant(ctx, ResampleVariant::for_adapter(ctx))
    }

    /// Compiles the kernels with the resampling of `variant`.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn with_variant(ctx: &GpuContext, variant: ResampleVariant) -> Result<Self, GpuError> {
        let entry = match variant {
            ResampleVariant::PerRay => "resample",
            ResampleVariant::Wide => "resample_wide",
        };
        let ([stratified, resample], layout) =
            kernels::build_entries(ctx, "sample", SOURCE, &[true, true, false, true], ["stratified", entry])?;
        Ok(Self { stratified, resample, layout, variant })
    }

    fn run(
        &self,
        rec: &mut Recorder<'_>,
        which: &wgpu::ComputePipeline,
        mut params: SampleParams,
        bufs: [&wgpu::Buffer; 4],
    ) -> Result<(), GpuError> {
        if params.n_samples == 0 || params.n_samples as usize > MAX_SAMPLES {
            return Err(GpuError::InvalidInput(format!(
                "sample: {} samples per ray (1..={MAX_SAMPLES})",
                params.n_samples
            )));
        }
        // The wide resampling has one workgroup per ray; the rest one invocation per ray.
        let wide = self.variant == ResampleVariant::Wide && std::ptr::eq(which, &self.resample);
        let per_group = if wide { 1 } else { kernels::WORKGROUP };
        let (gx, gy) = kernels::dispatch_grid(u64::from(params.n_rays), per_group)?;
        params.groups_x = gx;
        rec.dispatch("sample", which, &self.layout, &params, &bufs, (gx, gy, 1));
        Ok(())
    }

    /// Records the coarse edges of `n_rays` rays from `bounds` ((near, far) per ray) into `t_out`,
    /// jittered (in training) by the streams of the rays' batch indices `ray_ids`:
    /// [`mipnerf_core::stages::sample_intervals`] with the same `how`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a sample count out of range.
    pub fn stratified(
        &self,
        rec: &mut Recorder<'_>,
        n_rays: usize,
        how: Sample,
        bounds: &wgpu::Buffer,
        ray_ids: &wgpu::Buffer,
        t_out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let params = SampleParams::new(n_rays, how.n_samples, how.spacing, how.mode);
        self.run(rec, &self.stratified, params, [bounds, bounds, t_out, ray_ids])
    }

    /// Records the edges of level `how.level` of `n_rays` rays from the `coarse` level's edges and
    /// weights into `t_out`, with (in training) the offsets of the rays' batch indices `ray_ids`:
    /// [`mipnerf_core::stages::resample_intervals`] with the same `how`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a sample count out of range.
    pub fn resample(
        &self,
        rec: &mut Recorder<'_>,
        n_rays: usize,
        how: Resample,
        coarse: CoarseLevel<'_>,
        ray_ids: &wgpu::Buffer,
        t_out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let CoarseLevel { t: t_coarse, weights } = coarse;
        let params = SampleParams {
            level: how.level as u32,
            resample_padding: how.padding,
            ..SampleParams::new(n_rays, how.n_samples, how.spacing, how.mode)
        };
        self.run(rec, &self.resample, params, [t_coarse, weights, t_out, ray_ids])
    }
}

super::wgsl_struct!(
    SampleParams,
    "Params",
    [n_rays, n_samples, spacing, randomized, seed, step, level, resample_padding, groups_x, _pad]
);
