//! `shaders/fused_mlp.wgsl`: a small MLP (the Tri-Mip field's) with each pass in one dispatch:
//! the forward pass and the per-sample backward pass one invocation a sample, all layers in
//! private arrays; the weight gradients of every layer one workgroup a tile, in one dispatch.
//!
//! CPU reference: [`mipnerf_core::mlp::MlpShape::forward`] and
//! [`mipnerf_core::mlp::MlpShape::backward`] (with `input_gradient`).
//!
//! # Why, and where it applies
//! The product kernels (`matmul.wgsl`) run a layer as one or more tiled products and the
//! backward pass as about four dispatches a layer: right for wide layers, where arithmetic
//! decides, but a step of the Tri-Mip field's 64-wide MLP then spends most of its dispatches
//! (and, on hardware, most of its time) on launches and round trips through memory. Here a
//! sample's whole forward pass is one invocation, the weights read from storage at addresses
//! that every invocation of a workgroup shares (one broadcast load on hardware), so a level's
//! MLP costs three dispatches whatever its depth. It takes shapes with no skip connection whose
//! layers and input are at most [`MAX_WIDTH`] wide ([`fits`]); every other shape (the Mip-NeRF
//! presets) keeps the product kernels and their bits.
//!
//! The weight gradients sum over all samples in one workgroup per tile, in sample order, so
//! they are deterministic; a batch of 16,384 samples gives the recipe's shape about 100
//! workgroups of 256 invocations. The view direction's part of the first colour layer is
//! multiplied per sample, not once per ray as the CPU and the product kernels do (27 x 64 more
//! multiply-adds a sample, one dispatch fewer); the sums differ from the CPU's by rounding.

use mipnerf_core::mlp::MlpShape;

use crate::kernels::{Binding, Recorder, WORKGROUP, dispatch_grid};
use crate::{GpuContext, GpuError};

/// The WGSL source of these kernels.
pub const SOURCE: super::Shader =
    super::shader!("fused_mlp.wgsl", [FusedMlpParams], includes["view_encoding.wgsl", "mlp_trunk.wgsl"]);

/// The widest layer (and input) the fused kernels take: the size of their two private arrays
/// of activations (WGSL: `MLP_MAX_WIDTH`).
pub const MAX_WIDTH: usize = 64;

/// Floats of one of the two uniform blocks the weights are copied to (the trunk and heads, the
/// colour branch): WebGPU's smallest `max_uniform_buffer_binding_size`, 64 KiB, which every
/// device allows (WGSL: `MLP_UNIFORM_VEC4S` vec4s).
pub const UNIFORM_FLOATS: usize = 16_384;

/// Samples one weight-gradient invocation sums before it adds its block to the gradient (WGSL:
/// `MLP_SPLIT_SAMPLES`): 32 runs for a step's level of 16,384 samples, so that the device has
/// invocations to spare while the compare-exchange additions stay few (16 per run and block).
pub const SPLIT_SAMPLES: u32 = 512;

/// The side of the blocks of a layer's kernel one weight-gradient invocation sums (WGSL: its
/// four vec4 accumulators).
pub const BLOCK: u32 = 4;

/// Words of one weight-gradient job in the table (WGSL: `MLP_JOB_WORDS`).
pub const JOB_WORDS: usize = 9;
/// A job without a bias row (WGSL: `MLP_NO_BIAS`).
pub const NO_BIAS: u32 = u32::MAX;
/// A job's inputs: the encodings (WGSL: `MLP_SOURCE_X`).
pub const SOURCE_X: u32 = 0;
/// A job's inputs: a part of the kept activations (WGSL: `MLP_SOURCE_ACTS`).
pub const SOURCE_ACTS: u32 = 1;
/// A job's inputs: the view encoding of the sample's ray (WGSL: `MLP_SOURCE_VIEW`).
pub const SOURCE_VIEW: u32 = 2;
/// A job's output gradients: a part of the kept pre-activation gradients (WGSL:
/// `MLP_SOURCE_D_ACTS`).
pub const SOURCE_D_ACTS: u32 = 0;
/// A job's output gradients: the raw colours' (WGSL: `MLP_SOURCE_D_RGB`).
pub const SOURCE_D_RGB: u32 = 1;

/// The uniform block of `fused_mlp.wgsl` (`struct Params`), 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FusedMlpParams {
    /// Samples.
    pub n: u32,
    /// Samples per ray (which view encoding a sample reads).
    pub samples_per_ray: u32,
    /// Encoding width.
    pub x_dim: u32,
    /// View encoding width.
    pub view_dim: u32,
    /// Trunk layers.
    pub net_depth: u32,
    /// Trunk width.
    pub net_width: u32,
    /// Colour layers.
    pub depth_condition: u32,
    /// Colour width.
    pub width_condition: u32,
    /// Floats per sample of the kept activations and their gradients ([`row_len`]).
    pub row: u32,
    /// Workgroups along x of the 2-D dispatch grid.
    pub groups_x: u32,
    /// Where the shape's parameters start in the parameters and their gradient.
    pub base: u32,
    /// Weight-gradient jobs in the table.
    pub jobs: u32,
    /// 1: the backward pass writes the encodings' gradient.
    pub input_gradient: u32,
    /// Weight-gradient blocks over all jobs.
    pub blocks: u32,
    /// Runs of [`SPLIT_SAMPLES`] samples.
    pub runs: u32,
    /// Padding to 16 bytes.
    pub pad0: u32,
}

super::wgsl_struct!(
    FusedMlpParams,
    "Params",
    [
        n,
        samples_per_ray,
        x_dim,
        view_dim,
        net_depth,
        net_width,
        depth_condition,
        width_condition,
        row,
        groups_x,
        base,
        jobs,
        input_gradient,
        blocks,
        runs,
        pad0
    ]
);

/// Whether the fused kernels run `shape`: no skip connection, every layer and the input at
/// most [`MAX_WIDTH`] wide, and each part of the weights ([`weight_parts`]) within one uniform
/// block of [`UNIFORM_FLOATS`].
#[must_use]
pub fn fits(shape: &MlpShape) -> bool {
    let c = &shape.config;
    let no_skip = (0..c.net_depth).all(|i| !shape.concat_after(i));
    let narrow = c.net_width.max(c.net_width_condition).max(c.x_dim).max(c.view_dim) <= MAX_WIDTH;
    no_skip && narrow && weight_parts(shape).iter().all(|&(_, len)| len <= UNIFORM_FLOATS)
}

/// The two parts of `shape`'s parameters that the forward and backward passes read from
/// uniform blocks, as (offset, floats): the trunk with both heads, then the colour branch.
#[must_use]
pub fn weight_parts(shape: &MlpShape) -> [(usize, usize); 2] {
    let ls = &shape.layers;
    let (start, colour) = (ls[0].kernel, ls[shape.config.net_depth + 2].kernel);
    let end = ls[ls.len() - 1].bias + 3;
    [(start, colour - start), (colour, end - colour)]
}

/// Floats per sample of the kept activations (and of their gradients): the raw density, the
/// bottleneck, the trunk's layers, the colour branch's layers.
#[must_use]
pub fn row_len(shape: &MlpShape) -> usize {
    let c = &shape.config;
    1 + c.net_width * (1 + c.net_depth) + c.net_depth_condition * c.net_width_condition
}

/// The table the kernels read for `shape`: each layer's kernel and bias offsets in its part of
/// the weights ([`weight_parts`]), then the weight-gradient jobs (offsets from the shape's
/// first parameter); and the number of jobs and of the weight-gradient blocks.
#[must_use]
pub fn table(shape: &MlpShape) -> (Vec<u32>, u32, u32) {
    let c = &shape.config;
    let (d, dc, w, wc) = (c.net_depth, c.net_depth_condition, c.net_width, c.net_width_condition);
    let base = shape.layers[0].kernel;
    let ls = &shape.layers;
    let [(trunk, _), (colour, _)] = weight_parts(shape);
    let mut table: Vec<u32> = ls
        .iter()
        .enumerate()
        .flat_map(|(i, l)| {
            let part = if i < d + 2 { trunk } else { colour };
            [(l.kernel - part) as u32, (l.bias - part) as u32]
        })
        .collect();
    let trunk_at = |i: usize| 1 + w * (1 + i);
    let colour_at = |j: usize| 1 + w * (1 + d) + j * wc;
    let rel = |off: usize| (off - base) as u32;
    // (input source, its offset, gradient source, its offset, rows, columns, kernel rows, bias)
    let mut jobs: Vec<[u32; 8]> = Vec::new();
    let mut job =
        |input: (u32, usize), dz: (u32, usize), rows: usize, cols: usize, kernel: usize, bias: Option<usize>| {
            let bias = bias.map_or(NO_BIAS, rel);
            jobs.push([input.0, input.1 as u32, dz.0, dz.1 as u32, rows as u32, cols as u32, rel(kernel), bias]);
        };
    for (i, l) in ls[..d].iter().enumerate() {
        let input = if i == 0 { (SOURCE_X, 0) } else { (SOURCE_ACTS, trunk_at(i - 1)) };
        job(input, (SOURCE_D_ACTS, trunk_at(i)), l.fan_in, w, l.kernel, Some(l.bias));
    }
    let top = (SOURCE_ACTS, trunk_at(d - 1));
    job(top, (SOURCE_D_ACTS, 0), w, 1, ls[d].kernel, Some(ls[d].bias));
    job(top, (SOURCE_D_ACTS, 1), w, w, ls[d + 1].kernel, Some(ls[d + 1].bias));
    let first = &ls[d + 2];
    job((SOURCE_ACTS, 1), (SOURCE_D_ACTS, colour_at(0)), w, wc, first.kernel, Some(first.bias));
    job((SOURCE_VIEW, 0), (SOURCE_D_ACTS, colour_at(0)), c.view_dim, wc, first.kernel + w * wc, None);
    for j in 1..dc {
        let l = &ls[d + 2 + j];
        job((SOURCE_ACTS, colour_at(j - 1)), (SOURCE_D_ACTS, colour_at(j)), wc, wc, l.kernel, Some(l.bias));
    }
    let out = &ls[ls.len() - 1];
    job((SOURCE_ACTS, colour_at(dc - 1)), (SOURCE_D_RGB, 0), wc, 3, out.kernel, Some(out.bias));
    let mut blocks = 0u32;
    for j in &jobs {
        let rows = j[4] + u32::from(j[7] != NO_BIAS);
        table.extend_from_slice(j);
        table.push(blocks);
        blocks += rows.div_ceil(BLOCK) * j[5].div_ceil(BLOCK);
    }
    debug_assert_eq!(table.len(), 2 * ls.len() + JOB_WORDS * jobs.len());
    (table, jobs.len() as u32, blocks)
}

/// The buffers a fused MLP keeps for a batch: the activations and their gradients, the table,
/// the two uniform blocks of weights, and stand-ins for the bindings a pass does not use.
#[derive(Debug)]
pub struct FusedBuffers {
    /// `n x row_len`: what the forward pass keeps.
    pub acts: wgpu::Buffer,
    /// `n x row_len`: the pre-activation gradients (the raw density's written by rendering).
    pub d_acts: wgpu::Buffer,
    table: wgpu::Buffer,
    jobs: u32,
    blocks: u32,
    /// The trunk's and heads' weights, then the colour branch's, copied from the parameters
    /// before each forward pass.
    weights: [wgpu::Buffer; 2],
    /// Floats per sample of `acts` and `d_acts`.
    pub row: usize,
    unused: [wgpu::Buffer; 3],
}

impl FusedBuffers {
    /// Buffers for `n` samples of `shape` (filled with NaN, so that anything a pass forgets to
    /// write is visible).
    #[must_use]
    pub fn new(ctx: &GpuContext, shape: &MlpShape, n: usize) -> Self {
        let row = row_len(shape);
        let (table, jobs, blocks) = table(shape);
        let uniform = |label: &str| {
            ctx.device().create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 4 * UNIFORM_FLOATS as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let nan = |label: &str, len: usize| ctx.storage_buffer(label, &vec![f32::NAN; len.max(1)], true);
        Self {
            acts: nan("fused mlp activations", n * row),
            d_acts: nan("fused mlp activation gradients", n * row),
            table: ctx.storage_buffer("fused mlp table", &table, false),
            jobs,
            blocks,
            weights: [uniform("fused mlp trunk weights"), uniform("fused mlp colour weights")],
            row,
            unused: std::array::from_fn(|i| ctx.storage_buffer(&format!("fused mlp unused {i}"), &[0f32], false)),
        }
    }

    /// Device bytes these buffers take.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        let own = [&self.acts, &self.d_acts, &self.table];
        own.into_iter().chain(&self.weights).chain(&self.unused).map(wgpu::Buffer::size).sum()
    }
}

/// The batch a fused pass runs on: its samples and the buffers of the MLP's inputs and outputs.
#[derive(Clone, Copy, Debug)]
pub struct FusedBatch<'a> {
    /// Samples.
    pub n: usize,
    /// Samples per ray.
    pub samples_per_ray: usize,
    /// The encodings, `n x x_dim`.
    pub x: &'a wgpu::Buffer,
    /// The rays' view directions, `n / samples_per_ray x 3` (their encoding is computed where
    /// it is read).
    pub view_dirs: &'a wgpu::Buffer,
    /// Raw colours, `n x 3`.
    pub raw_rgb: &'a wgpu::Buffer,
    /// The encodings' gradient, written where given.
    pub d_x: Option<&'a wgpu::Buffer>,
}

/// The three pipelines of `fused_mlp.wgsl`.
#[derive(Debug)]
pub struct FusedMlpKernel {
    forward: wgpu::ComputePipeline,
    backward_samples: wgpu::ComputePipeline,
    weight_gradients: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl FusedMlpKernel {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (read, write) = (Binding::Storage { read_only: true }, Binding::Storage { read_only: false });
        // table, the two blocks of weights, x, view directions, acts, raw_rgb, d_rgb, d_acts, d_x,
        // grads.
        let bindings = [read, Binding::Uniform, Binding::Uniform, read, read, write, write, read, write, write, write];
        let entries = ["forward", "backward_samples", "weight_gradients"];
        let ([forward, backward_samples, weight_gradients], layout) =
            super::build_entries_bound(ctx, "fused_mlp", SOURCE, &bindings, entries, true)?;
        Ok(Self { forward, backward_samples, weight_gradients, layout })
    }

    /// The uniform block of a pass over `batch`, and its grid of one invocation a sample.
    fn params(shape: &MlpShape, batch: &FusedBatch<'_>, bufs: &FusedBuffers) -> (FusedMlpParams, (u32, u32, u32)) {
        let c = &shape.config;
        // Sizes come from the buffers the caller made for this batch.
        let (gx, gy) = dispatch_grid(batch.n as u64, WORKGROUP).unwrap_or((1, 1));
        let p = FusedMlpParams {
            n: batch.n as u32,
            samples_per_ray: batch.samples_per_ray as u32,
            x_dim: c.x_dim as u32,
            view_dim: c.view_dim as u32,
            net_depth: c.net_depth as u32,
            net_width: c.net_width as u32,
            depth_condition: c.net_depth_condition as u32,
            width_condition: c.net_width_condition as u32,
            row: bufs.row as u32,
            groups_x: gx,
            base: shape.layers[0].kernel as u32,
            jobs: bufs.jobs,
            input_gradient: u32::from(batch.d_x.is_some()),
            blocks: bufs.blocks,
            runs: (batch.n as u32).div_ceil(SPLIT_SAMPLES),
            pad0: 0,
        };
        (p, (gx, gy, 1))
    }

    /// Records the forward pass: `bufs.acts` and `batch.raw_rgb` from `batch.x` and
    /// `batch.view_dirs`, the weights copied from `params` to the uniform blocks first.
    /// `params` must allow copies from it (`COPY_SRC`), as the trainer's parameters do.
    pub fn forward(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        batch: &FusedBatch<'_>,
        bufs: &FusedBuffers,
    ) {
        Self::copy_weights(rec, shape, params, bufs, 2);
        let (p, grid) = Self::params(shape, batch, bufs);
        let [u0, u1, u2] = &bufs.unused;
        let [wt, wc] = &bufs.weights;
        let buffers =
            [&bufs.table, wt, wc, batch.x, batch.view_dirs, &bufs.acts, batch.raw_rgb, u0, &bufs.d_acts, u1, u2];
        rec.dispatch("fused_mlp forward", &self.forward, &self.layout, &p, &buffers, grid);
    }

    /// Records the copy of `shape`'s weights from `params` into `bufs`' uniform blocks: the
    /// first `parts` of them (1: the trunk and heads, 2: the colour branch too).
    fn copy_weights(
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        bufs: &FusedBuffers,
        parts: usize,
    ) {
        for (&(offset, len), to) in weight_parts(shape).iter().zip(&bufs.weights).take(parts) {
            rec.encoder().copy_buffer_to_buffer(params, 4 * offset as u64, to, 0, 4 * len as u64);
        }
    }

    /// Records the copy of `shape`'s trunk and heads' weights from `params` into `bufs`, and
    /// returns what a pass that reads the trunk alone binds (`mlp_trunk.wgsl`'s `table` and
    /// `trunk_weights`): the occupancy grid's fused update.
    pub fn trunk_inputs<'a>(
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        bufs: &'a FusedBuffers,
    ) -> (&'a wgpu::Buffer, &'a wgpu::Buffer) {
        Self::copy_weights(rec, shape, params, bufs, 1);
        (&bufs.table, &bufs.weights[0])
    }

    /// Records the backward pass of the last forward pass (the weights it copied): from the raw
    /// colours' gradient `d_rgb` and the raw density's (column 0 of `bufs.d_acts`, written by
    /// rendering), every layer's pre-activation gradient (kept in `bufs.d_acts`), the encodings'
    /// gradient (to `batch.d_x` where given), and every weight and bias gradient **added** to
    /// `grads`.
    ///
    /// # Errors
    /// A batch too large for one dispatch.
    pub fn backward(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        batch: &FusedBatch<'_>,
        bufs: &FusedBuffers,
        d_rgb: &wgpu::Buffer,
        grads: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let (p, grid) = Self::params(shape, batch, bufs);
        let d_x = batch.d_x.unwrap_or(&bufs.unused[1]);
        let [wt, wc] = &bufs.weights;
        let buffers =
            [&bufs.table, wt, wc, batch.x, batch.view_dirs, &bufs.acts, batch.raw_rgb, d_rgb, &bufs.d_acts, d_x, grads];
        rec.dispatch("fused_mlp backward", &self.backward_samples, &self.layout, &p, &buffers, grid);
        let (gx, gy) = dispatch_grid(u64::from(p.blocks) * u64::from(p.runs), WORKGROUP)?;
        let p = FusedMlpParams { groups_x: gx, ..p };
        rec.dispatch("fused_mlp weight gradients", &self.weight_gradients, &self.layout, &p, &buffers, (gx, gy, 1));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mipnerf_core::mlp::MlpConfig;

    fn shape(net_depth: usize, w: usize, dc: usize, skip_layer: usize) -> MlpShape {
        let c = MlpConfig {
            net_depth,
            net_width: w,
            skip_layer,
            net_depth_condition: dc,
            net_width_condition: w,
            x_dim: 48,
            view_dim: 27,
        };
        MlpShape::new(c, 100).expect("shape")
    }

    #[test]
    fn the_table_covers_every_weight_and_bias_of_the_shape_once() {
        for s in [shape(2, 64, 1, 0), shape(3, 32, 2, 0), shape(1, 16, 1, 0)] {
            let (table, jobs, groups) = table(&s);
            let layers = s.layers.len();
            let mut seen = vec![0u32; s.num_params];
            let mut next_group = 0;
            for j in 0..jobs as usize {
                let w = &table[2 * layers + JOB_WORDS * j..][..JOB_WORDS];
                let (rows, cols) = (w[4] as usize, w[5] as usize);
                for k in 0..rows * cols {
                    seen[w[6] as usize + k] += 1;
                }
                if w[7] != NO_BIAS {
                    for c in 0..cols {
                        seen[w[7] as usize + c] += 1;
                    }
                }
                assert_eq!(w[8], next_group, "job {j}: its first block");
                next_group += (w[4] + u32::from(w[7] != NO_BIAS)).div_ceil(BLOCK) * w[5].div_ceil(BLOCK);
            }
            assert_eq!(next_group, groups);
            assert!(seen.iter().all(|&n| n == 1), "every parameter exactly once: {seen:?}");
        }
    }

    #[test]
    fn only_shapes_without_a_skip_and_at_most_the_widest_fit() {
        assert!(fits(&shape(2, 64, 1, 0)));
        assert!(!fits(&shape(2, 128, 1, 0)), "too wide");
        assert!(!fits(&shape(4, 64, 1, 2)), "a skip connection");
        assert_eq!(row_len(&shape(2, 64, 1, 0)), 1 + 64 * 3 + 64);
    }
}
