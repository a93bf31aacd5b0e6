//! The Mip-NeRF MLP on the GPU: the same forward and backward passes as
//! `mipnerf_core::mlp::MlpShape`, over the same flat parameter layout, as a sequence of tiled
//! matrix products (`matmul.wgsl`) and small auxiliary passes (`mlp_aux.wgsl`).
//!
//! The one difference in method: the view encoding is broadcast to every sample and multiplied
//! as part of the first colour layer's input, where the CPU multiplies it once per ray. The
//! results agree to rounding.

use mipnerf_core::mlp::{DenseLayer, MlpShape};

use crate::kernels::matmul::{Epilogue, MatmulKernel, MatmulVariant, Operand};
use crate::kernels::mlp_aux::MlpAuxKernels;
use crate::{GpuContext, GpuError};

/// The buffers of one batch: inputs, kept activations, outputs, scratch.
#[derive(Debug)]
pub struct MlpBuffers {
    /// Samples.
    pub n: usize,
    /// Rays.
    pub n_rays: usize,
    /// Sample encodings, `n x x_dim`.
    pub x: wgpu::Buffer,
    /// View encodings, `n_rays x view_dim`.
    pub view: wgpu::Buffer,
    /// View encodings broadcast to samples, `n x view_dim`.
    pub view_b: wgpu::Buffer,
    trunk: Vec<wgpu::Buffer>,
    bottleneck: wgpu::Buffer,
    cond: Vec<wgpu::Buffer>,
    /// Raw colours, `n x 3`.
    pub raw_rgb: wgpu::Buffer,
    /// Raw densities, `n`.
    pub raw_density: wgpu::Buffer,
    grad: [wgpu::Buffer; 3],
    col_scratch: wgpu::Buffer,
}

fn storage(ctx: &GpuContext, label: &str, len: usize) -> wgpu::Buffer {
    // Filled with NaN so that anything a kernel forgets to write is visible.
    ctx.storage_buffer(label, &vec![f32::NAN; len.max(1)], true)
}

impl MlpBuffers {
    /// Buffers for `n_rays * samples_per_ray` samples of `shape`.
    #[must_use]
    pub fn new(ctx: &GpuContext, shape: &MlpShape, n_rays: usize, samples_per_ray: usize) -> Self {
        let c = &shape.config;
        let n = n_rays * samples_per_ray;
        let widest = c.net_width.max(c.net_width_condition).max(3);
        Self {
            n,
            n_rays,
            x: storage(ctx, "mlp x", n * c.x_dim),
            view: storage(ctx, "mlp view", n_rays * c.view_dim),
            view_b: storage(ctx, "mlp view per sample", n * c.view_dim),
            trunk: (0..c.net_depth).map(|i| storage(ctx, &format!("mlp trunk {i}"), n * c.net_width)).collect(),
            bottleneck: storage(ctx, "mlp bottleneck", n * c.net_width),
            cond: (0..c.net_depth_condition)
                .map(|j| storage(ctx, &format!("mlp condition {j}"), n * c.net_width_condition))
                .collect(),
            raw_rgb: storage(ctx, "mlp raw rgb", n * 3),
            raw_density: storage(ctx, "mlp raw density", n),
            grad: std::array::from_fn(|i| storage(ctx, &format!("mlp gradient scratch {i}"), n * widest)),
            col_scratch: storage(ctx, "mlp bias gradient partial sums", MlpAuxKernels::col_sums_scratch_len(n, widest)),
        }
    }

    /// Makes the next passes use the first `n_rays` rays' samples (at most the capacity, which
    /// the caller checks).
    pub(crate) fn set_active(&mut self, n_rays: usize) {
        let s = self.samples_per_ray();
        self.n_rays = n_rays;
        self.n = n_rays * s;
    }

    /// Device bytes these buffers take.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        let all = [&self.x, &self.view, &self.view_b, &self.bottleneck, &self.raw_rgb, &self.raw_density];
        let mut b: u64 = all.iter().map(|x| x.size()).sum();
        b += self.trunk.iter().chain(&self.cond).chain(&self.grad).map(wgpu::Buffer::size).sum::<u64>();
        b += self.col_scratch.size();
        b
    }

    fn samples_per_ray(&self) -> usize {
        self.n / self.n_rays.max(1)
    }
}

/// The kernels of the GPU MLP.
#[derive(Debug)]
pub struct GpuMlp {
    matmul: MatmulKernel,
    aux: MlpAuxKernels,
}

/// One input part of a dense layer: a buffer and its width (kernel rows, in order).
type Part<'a> = (&'a wgpu::Buffer, usize);

impl GpuMlp {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self { matmul: MatmulKernel::new(ctx)?, aux: MlpAuxKernels::new(ctx)? })
    }

    /// Compiles the kernels with the matrix products of `variant`.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn with_variant(ctx: &GpuContext, variant: MatmulVariant) -> Result<Self, GpuError> {
        Ok(Self { matmul: MatmulKernel::with_variant(ctx, variant)?, aux: MlpAuxKernels::new(ctx)? })
    }

    /// `out = act(sum_p part_p · kernel_rows_p + bias)`.
    fn dense(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        params: &wgpu::Buffer,
        l: &DenseLayer,
        parts: &[Part<'_>],
        n: usize,
        out: &wgpu::Buffer,
        relu: bool,
    ) {
        let mut r0 = 0;
        for (k, &(input, width)) in parts.iter().enumerate() {
            let last = k + 1 == parts.len();
            let epi = Epilogue { accumulate: k > 0, bias: last.then_some(l.bias), relu: last && relu };
            let b = Operand::new(params, l.kernel + r0 * l.fan_out);
            self.matmul.encode(ctx, enc, (n, width, l.fan_out), Operand::new(input, 0), b, Operand::new(out, 0), epi);
            r0 += width;
        }
    }

    /// Adds the layer's weight and bias gradients for output gradient `dz` to `grads`, and writes
    /// (or adds, with `accumulate_d`) the gradient of the first input part to `d_first`.
    #[allow(clippy::too_many_arguments)]
    fn dense_backward(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        params: &wgpu::Buffer,
        grads: &wgpu::Buffer,
        l: &DenseLayer,
        parts: &[Part<'_>],
        n: usize,
        dz: &wgpu::Buffer,
        d_first: Option<(&wgpu::Buffer, bool)>,
        col_scratch: &wgpu::Buffer,
    ) {
        let mut r0 = 0;
        for &(input, width) in parts {
            let c = Operand::new(grads, l.kernel + r0 * l.fan_out);
            let epi = Epilogue { accumulate: true, ..Epilogue::default() };
            self.matmul.encode(ctx, enc, (width, n, l.fan_out), Operand::t(input, 0), Operand::new(dz, 0), c, epi);
            r0 += width;
        }
        self.aux.col_sums(ctx, enc, (dz, 0), (grads, l.bias), n, l.fan_out, true, col_scratch);
        if let Some((d, accumulate)) = d_first {
            let width = parts[0].1;
            let epi = Epilogue { accumulate, ..Epilogue::default() };
            self.matmul.encode(
                ctx,
                enc,
                (n, l.fan_out, width),
                Operand::new(dz, 0),
                Operand::t(params, l.kernel),
                Operand::new(d, 0),
                epi,
            );
        }
    }

    /// Records the forward pass: fills `bufs.raw_rgb` and `bufs.raw_density` from `bufs.x` and
    /// `bufs.view`.
    pub fn forward(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        bufs: &MlpBuffers,
    ) {
        let c = &shape.config;
        let (n, d) = (bufs.n, c.net_depth);
        let ls = &shape.layers;
        self.aux.broadcast_rows(ctx, enc, &bufs.view, &bufs.view_b, bufs.n_rays, c.view_dim, bufs.samples_per_ray());
        for i in 0..d {
            let parts: Vec<Part<'_>> = if i == 0 {
                vec![(&bufs.x, c.x_dim)]
            } else if shape.concat_after(i - 1) {
                vec![(&bufs.trunk[i - 1], c.net_width), (&bufs.x, c.x_dim)]
            } else {
                vec![(&bufs.trunk[i - 1], c.net_width)]
            };
            self.dense(ctx, enc, params, &ls[i], &parts, n, &bufs.trunk[i], true);
        }
        let top = self.top_parts(shape, bufs);
        self.dense(ctx, enc, params, &ls[d], &top, n, &bufs.raw_density, false);
        self.dense(ctx, enc, params, &ls[d + 1], &top, n, &bufs.bottleneck, false);
        for j in 0..c.net_depth_condition {
            let parts: Vec<Part<'_>> = if j == 0 {
                vec![(&bufs.bottleneck, c.net_width), (&bufs.view_b, c.view_dim)]
            } else {
                vec![(&bufs.cond[j - 1], c.net_width_condition)]
            };
            self.dense(ctx, enc, params, &ls[d + 2 + j], &parts, n, &bufs.cond[j], true);
        }
        let last = &bufs.cond[c.net_depth_condition - 1];
        self.dense(ctx, enc, params, &ls[ls.len() - 1], &[(last, c.net_width_condition)], n, &bufs.raw_rgb, false);
    }

    fn top_parts<'a>(&self, shape: &MlpShape, bufs: &'a MlpBuffers) -> Vec<Part<'a>> {
        let c = &shape.config;
        let top = (&bufs.trunk[c.net_depth - 1], c.net_width);
        if shape.concat_after(c.net_depth - 1) { vec![top, (&bufs.x, c.x_dim)] } else { vec![top] }
    }

    /// Records the backward pass of the last forward pass: **adds** every parameter's gradient for
    /// the output gradients `d_raw_rgb` (`n x 3`) and `d_raw_density` (`n`) to `grads`.
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        bufs: &MlpBuffers,
        d_raw_rgb: &wgpu::Buffer,
        d_raw_density: &wgpu::Buffer,
        grads: &wgpu::Buffer,
    ) {
        let c = &shape.config;
        let (n, d, dc) = (bufs.n, c.net_depth, c.net_depth_condition);
        let (w, wc) = (c.net_width, c.net_width_condition);
        let ls = &shape.layers;
        let g = &bufs.grad;
        // Indices into g: `a` holds the gradient of the current layer's output.
        let (mut a, mut b) = (0usize, 1usize);
        let last = &bufs.cond[dc - 1];
        self.dense_backward(
            ctx,
            enc,
            params,
            grads,
            &ls[ls.len() - 1],
            &[(last, wc)],
            n,
            d_raw_rgb,
            Some((&g[a], false)),
            &bufs.col_scratch,
        );
        for j in (0..dc).rev() {
            self.aux.relu_backward(ctx, enc, (&bufs.cond[j], 0), (&g[a], 0), n * wc);
            if j > 0 {
                self.dense_backward(
                    ctx,
                    enc,
                    params,
                    grads,
                    &ls[d + 2 + j],
                    &[(&bufs.cond[j - 1], wc)],
                    n,
                    &g[a],
                    Some((&g[b], false)),
                    &bufs.col_scratch,
                );
                std::mem::swap(&mut a, &mut b);
            } else {
                let parts = [(&bufs.bottleneck, w), (&bufs.view_b, c.view_dim)];
                self.dense_backward(
                    ctx,
                    enc,
                    params,
                    grads,
                    &ls[d + 2],
                    &parts,
                    n,
                    &g[a],
                    Some((&g[b], false)),
                    &bufs.col_scratch,
                );
            }
        }
        // g[b] = d bottleneck; heads read the top parts; their input gradient goes to g[z].
        let z = 3 - a - b;
        let top = self.top_parts(shape, bufs);
        self.dense_backward(
            ctx,
            enc,
            params,
            grads,
            &ls[d + 1],
            &top,
            n,
            &g[b],
            Some((&g[z], false)),
            &bufs.col_scratch,
        );
        self.dense_backward(
            ctx,
            enc,
            params,
            grads,
            &ls[d],
            &top,
            n,
            d_raw_density,
            Some((&g[z], true)),
            &bufs.col_scratch,
        );
        let (mut cur, mut other) = (z, a);
        for i in (0..d).rev() {
            self.aux.relu_backward(ctx, enc, (&bufs.trunk[i], 0), (&g[cur], 0), n * w);
            if i == 0 {
                self.dense_backward(
                    ctx,
                    enc,
                    params,
                    grads,
                    &ls[0],
                    &[(&bufs.x, c.x_dim)],
                    n,
                    &g[cur],
                    None,
                    &bufs.col_scratch,
                );
            } else {
                let parts: Vec<Part<'_>> = if shape.concat_after(i - 1) {
                    vec![(&bufs.trunk[i - 1], w), (&bufs.x, c.x_dim)]
                } else {
                    vec![(&bufs.trunk[i - 1], w)]
                };
                self.dense_backward(
                    ctx,
                    enc,
                    params,
                    grads,
                    &ls[i],
                    &parts,
                    n,
                    &g[cur],
                    Some((&g[other], false)),
                    &bufs.col_scratch,
                );
                std::mem::swap(&mut cur, &mut other);
            }
        }
    }
}
