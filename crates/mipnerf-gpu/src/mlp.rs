//! The Mip-NeRF MLP on the GPU: the same forward and backward passes as
//! `mipnerf_core::mlp::MlpShape`, over the same flat parameter layout, as a sequence of tiled
//! matrix products (`matmul.wgsl`) and small auxiliary passes (`mlp_aux.wgsl`).
//!
//! As on the CPU, the view-direction part of the first colour layer is multiplied once per ray
//! and added to each of the ray's samples in the product's epilogue; its weight gradient sums the
//! samples' gradients per ray first. The ReLU backward pass rides in the input-gradient
//! products' epilogue, and the weight gradients are split over blocks of samples.

use mipnerf_core::mlp::{DenseLayer, MlpShape};

use crate::kernels::Recorder;
use crate::kernels::fused_mlp::{self, FusedBatch, FusedBuffers, FusedMlpKernel};
use crate::kernels::matmul::{Epilogue, MAX_SPLITS, MIN_K_PER_SPLIT, MatmulKernel, MatmulVariant, Operand, Product};
use crate::kernels::mlp_aux::{ColSums, Heads, MlpAuxKernels};
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
    /// Raw colours, `n x 3`.
    pub raw_rgb: wgpu::Buffer,
    /// The gradient of the sample encodings, `n x x_dim`, written by the backward pass where
    /// the encodings have parameters of their own (the Tri-Mip planes; see
    /// [`with_input_gradient`](Self::with_input_gradient)).
    pub d_x: Option<wgpu::Buffer>,
    /// How the passes run, and what they keep.
    passes: Passes,
}

/// How a shape's passes run: as matrix products (any shape), or fused, one dispatch a pass
/// (`fused_mlp.wgsl`, for the small shapes [`fused_mlp::fits`]).
#[derive(Debug)]
enum Passes {
    Products(ProductBuffers),
    Fused(FusedBuffers),
}

/// What the product kernels keep and use.
#[derive(Debug)]
struct ProductBuffers {
    /// The view encodings times the first colour layer's view rows, `n_rays x net_width_condition`
    /// (forward), then the per-ray sums of that layer's output gradient (backward).
    view_rows: wgpu::Buffer,
    trunk: Vec<wgpu::Buffer>,
    /// Both heads, one product: `n x (1 + net_width)`, `[raw density | bottleneck]` per sample.
    heads: wgpu::Buffer,
    /// Their gradient, the same shape: the density part written by rendering, the bottleneck
    /// part by the colour branch's backward pass.
    d_heads: wgpu::Buffer,
    /// The two heads' kernels and biases packed as one `(top + 1) x (1 + net_width)` matrix, and
    /// its gradient.
    heads_w: wgpu::Buffer,
    heads_g: wgpu::Buffer,
    /// `1 + net_width`.
    heads_width: usize,
    cond: Vec<wgpu::Buffer>,
    grad: [wgpu::Buffer; 3],
    col_scratch: wgpu::Buffer,
    /// Partial products of the split weight-gradient products, and its length in floats.
    split_scratch: (wgpu::Buffer, usize),
}

fn storage(ctx: &GpuContext, label: &str, len: usize) -> wgpu::Buffer {
    // Filled with NaN so that anything a kernel forgets to write is visible.
    ctx.storage_buffer(label, &vec![f32::NAN; len.max(1)], true)
}

impl ProductBuffers {
    fn new(ctx: &GpuContext, shape: &MlpShape, n_rays: usize, samples_per_ray: usize) -> Self {
        let c = &shape.config;
        let n = n_rays * samples_per_ray;
        let widest = c.net_width.max(c.net_width_condition).max(3);
        let hw = c.net_width + 1;
        let top = shape.layers[c.net_depth].fan_in;
        Self {
            view_rows: storage(ctx, "mlp view rows per ray", n_rays * c.net_width_condition),
            trunk: (0..c.net_depth).map(|i| storage(ctx, &format!("mlp trunk {i}"), n * c.net_width)).collect(),
            heads: storage(ctx, "mlp heads (density, bottleneck)", n * hw),
            d_heads: storage(ctx, "mlp heads gradient", n * hw),
            heads_w: storage(ctx, "mlp heads packed kernel", (top + 1) * hw),
            heads_g: storage(ctx, "mlp heads packed gradient", (top + 1) * hw),
            heads_width: hw,
            cond: (0..c.net_depth_condition)
                .map(|j| storage(ctx, &format!("mlp condition {j}"), n * c.net_width_condition))
                .collect(),
            grad: std::array::from_fn(|i| storage(ctx, &format!("mlp gradient scratch {i}"), n * widest)),
            col_scratch: storage(
                ctx,
                "mlp bias gradient partial sums",
                MlpAuxKernels::col_sums_scratch_len(n, widest + 1),
            ),
            split_scratch: {
                let len = MlpBuffers::split_scratch_len(shape, n);
                (storage(ctx, "mlp weight gradient partial products", len), len)
            },
        }
    }

    fn bytes(&self) -> u64 {
        let all = [&self.view_rows, &self.heads, &self.d_heads, &self.heads_w, &self.heads_g];
        let mut b: u64 = all.iter().map(|x| x.size()).sum();
        b += self.trunk.iter().chain(&self.cond).chain(&self.grad).map(wgpu::Buffer::size).sum::<u64>();
        b + self.col_scratch.size() + self.split_scratch.0.size()
    }
}

impl MlpBuffers {
    /// Buffers for `n_rays * samples_per_ray` samples of `shape`.
    #[must_use]
    pub fn new(ctx: &GpuContext, shape: &MlpShape, n_rays: usize, samples_per_ray: usize) -> Self {
        let c = &shape.config;
        let n = n_rays * samples_per_ray;
        let passes = if fused_mlp::fits(shape) {
            Passes::Fused(FusedBuffers::new(ctx, shape, n))
        } else {
            Passes::Products(ProductBuffers::new(ctx, shape, n_rays, samples_per_ray))
        };
        Self {
            n,
            n_rays,
            x: storage(ctx, "mlp x", n * c.x_dim),
            view: storage(ctx, "mlp view", n_rays * c.view_dim),
            raw_rgb: storage(ctx, "mlp raw rgb", n * 3),
            d_x: None,
            passes,
        }
    }

    /// Whether `shape`'s passes run fused (`fused_mlp.wgsl`, one dispatch a pass) rather than
    /// as matrix products.
    #[must_use]
    pub fn runs_fused(shape: &MlpShape) -> bool {
        fused_mlp::fits(shape)
    }

    /// Whether these buffers' passes run fused.
    #[must_use]
    pub fn runs_fused_passes(&self) -> bool {
        matches!(self.passes, Passes::Fused(_))
    }

    /// Where the passes run fused: `shape`'s trunk weights copied from `params` (recorded) and
    /// what a kernel that runs the trunk alone binds, the layers' table and those weights
    /// ([`FusedMlpKernel::trunk_inputs`]). `None` for the product kernels.
    pub fn fused_trunk(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        params: &wgpu::Buffer,
    ) -> Option<(&wgpu::Buffer, &wgpu::Buffer)> {
        match &self.passes {
            Passes::Fused(f) => Some(FusedMlpKernel::trunk_inputs(rec, shape, params, f)),
            Passes::Products(_) => None,
        }
    }

    /// Floats per sample of these buffers for `shape` (the encodings' gradient aside): the
    /// encodings, what the passes keep, the raw colours, and the product kernels' gradient
    /// scratch.
    #[must_use]
    pub fn floats_per_sample(shape: &MlpShape) -> usize {
        let c = &shape.config;
        let kept = if Self::runs_fused(shape) {
            2 * fused_mlp::row_len(shape)
        } else {
            let widest = c.net_width.max(c.net_width_condition).max(3);
            c.net_depth * c.net_width
                + 2 * (c.net_width + 1)
                + c.net_depth_condition * c.net_width_condition
                + 3 * widest
        };
        c.x_dim + kept + 3
    }

    /// Floats per ray of `samples_per_ray` samples besides the samples' own: the view
    /// encoding, and for the product kernels its product rows and the bias gradients' partial
    /// sums (one row of `widest + 1` per 256 samples).
    #[must_use]
    pub fn floats_per_ray(shape: &MlpShape, samples_per_ray: usize) -> usize {
        let c = &shape.config;
        if Self::runs_fused(shape) {
            return c.view_dim;
        }
        let widest = c.net_width.max(c.net_width_condition).max(3);
        c.view_dim + c.net_width_condition + (samples_per_ray * (widest + 1)).div_ceil(MlpAuxKernels::BLOCK_ROWS)
    }

    /// Floats per sample of the widest per-sample buffer (what the binding size limits).
    #[must_use]
    pub fn widest_row(shape: &MlpShape) -> usize {
        let c = &shape.config;
        let kept = if Self::runs_fused(shape) {
            fused_mlp::row_len(shape)
        } else {
            (c.net_width + 1).max(c.net_width_condition).max(3)
        };
        c.x_dim.max(kept)
    }

    /// Floats these buffers take whatever the batch: the product kernels' packed heads and
    /// split partial products for `n` samples.
    #[must_use]
    pub fn fixed_floats(shape: &MlpShape, n: usize) -> usize {
        if Self::runs_fused(shape) {
            return 0;
        }
        let packed_heads = 2 * (shape.layers[shape.config.net_depth].fan_in + 1) * (shape.config.net_width + 1);
        Self::split_scratch_len(shape, n) + packed_heads
    }

    /// These buffers with room for the gradient of the sample encodings (`n x x_dim`), which
    /// [`GpuMlp::backward`] then writes: for a field whose encodings have parameters.
    #[must_use]
    pub fn with_input_gradient(mut self, ctx: &GpuContext, x_dim: usize) -> Self {
        self.d_x = Some(storage(ctx, "mlp input gradient", self.n * x_dim));
        self
    }

    /// The raw densities: the buffer and the elements between consecutive samples' values (they
    /// are column 0 of the fused heads).
    #[must_use]
    pub fn raw_density(&self) -> (&wgpu::Buffer, usize) {
        match &self.passes {
            Passes::Products(p) => (&p.heads, p.heads_width),
            Passes::Fused(f) => (&f.acts, f.row),
        }
    }

    /// Where [`GpuMlp::backward`] reads the gradient of the raw densities: the buffer and the
    /// elements between consecutive samples' values.
    #[must_use]
    pub fn d_raw_density(&self) -> (&wgpu::Buffer, usize) {
        match &self.passes {
            Passes::Products(p) => (&p.d_heads, p.heads_width),
            Passes::Fused(f) => (&f.d_acts, f.row),
        }
    }

    /// Floats of partial products the split weight gradients of `n` samples use: room for
    /// [`MAX_SPLITS`] of the largest product's output (a layer's kernel, or both heads' kernels)
    /// when `n` is long enough to split.
    #[must_use]
    pub fn split_scratch_len(shape: &MlpShape, n: usize) -> usize {
        let heads = shape.layers[shape.config.net_depth].fan_in * (shape.config.net_width + 1);
        let largest = shape.layers.iter().map(|l| l.fan_in * l.fan_out).max().unwrap_or(1).max(heads);
        largest * MAX_SPLITS.min(n / MIN_K_PER_SPLIT).max(1)
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
        let own: u64 = [&self.x, &self.view, &self.raw_rgb].iter().map(|b| b.size()).sum();
        let passes = match &self.passes {
            Passes::Products(p) => p.bytes(),
            Passes::Fused(f) => f.bytes(),
        };
        own + passes + self.d_x.as_ref().map_or(0, wgpu::Buffer::size)
    }

    fn fused_batch<'a>(&'a self, view_dirs: &'a wgpu::Buffer) -> FusedBatch<'a> {
        FusedBatch {
            n: self.n,
            samples_per_ray: self.samples_per_ray(),
            x: &self.x,
            view_dirs,
            raw_rgb: &self.raw_rgb,
            d_x: self.d_x.as_ref(),
        }
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
    fused: FusedMlpKernel,
}

/// One input part of a dense layer: a buffer and its width (kernel rows, in order).
type Part<'a> = (&'a wgpu::Buffer, usize);

/// One dense layer's pass: the layer, its input parts, and the samples.
#[derive(Clone, Copy)]
struct LayerRun<'a> {
    layer: &'a DenseLayer,
    parts: &'a [Part<'a>],
    n: usize,
}

impl<'a> LayerRun<'a> {
    const fn new(layer: &'a DenseLayer, parts: &'a [Part<'a>], n: usize) -> Self {
        Self { layer, parts, n }
    }
}

/// The model's parameters and their gradient, as a pass reads them and adds to it.
#[derive(Clone, Copy, Debug)]
pub struct ParamBuffers<'a> {
    /// The parameters.
    pub params: &'a wgpu::Buffer,
    /// Their gradient, added to.
    pub grads: &'a wgpu::Buffer,
}

/// Where a layer's backward pass puts the gradient of its first input part.
#[derive(Clone, Copy)]
struct InputGrad<'a> {
    /// The gradient buffer.
    out: &'a wgpu::Buffer,
    /// Add to it instead of overwriting it.
    accumulate: bool,
    /// The first input part is a ReLU output: apply the ReLU backward (after the sum).
    relu: bool,
}

impl GpuMlp {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    #[cfg(feature = "test-support")]
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self { matmul: MatmulKernel::new(ctx)?, aux: MlpAuxKernels::new(ctx)?, fused: FusedMlpKernel::new(ctx)? })
    }

    /// Compiles the kernels with the matrix products of `variant`.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn with_variant(ctx: &GpuContext, variant: MatmulVariant) -> Result<Self, GpuError> {
        Ok(Self {
            matmul: MatmulKernel::with_variant(ctx, variant)?,
            aux: MlpAuxKernels::new(ctx)?,
            fused: FusedMlpKernel::new(ctx)?,
        })
    }

    /// `out = act(sum_p part_p · kernel_rows_p + bias)`.
    fn dense(&self, rec: &mut Recorder<'_>, params: &wgpu::Buffer, run: LayerRun<'_>, out: &wgpu::Buffer, relu: bool) {
        let LayerRun { layer: l, parts, n } = run;
        let mut r0 = 0;
        for (k, &(input, width)) in parts.iter().enumerate() {
            let last = k + 1 == parts.len();
            let epi =
                Epilogue { accumulate: k > 0, bias: last.then_some(l.bias), relu: last && relu, ..Epilogue::default() };
            let b = Operand::new(params, l.kernel + r0 * l.fan_out);
            self.matmul.encode(
                rec,
                Product { shape: (n, width, l.fan_out), a: Operand::new(input, 0), b, c: Operand::new(out, 0), epi },
            );
            r0 += width;
        }
    }

    /// Adds the layer's weight and bias gradients for output gradient `dz` to `grads` (the
    /// weight gradients split over the samples), and writes (or adds, with `d.accumulate`) the
    /// gradient of the first input part to `d.out`, masked by the ReLU backward when `d.relu`
    /// (the first part is then a ReLU output, its own mask).
    fn dense_backward(
        &self,
        rec: &mut Recorder<'_>,
        pg: ParamBuffers<'_>,
        run: LayerRun<'_>,
        dz: &wgpu::Buffer,
        d_first: Option<InputGrad<'_>>,
        pb: &ProductBuffers,
    ) {
        let (ParamBuffers { params, grads }, LayerRun { layer: l, parts, n }) = (pg, run);
        let mut r0 = 0;
        for &(input, width) in parts {
            let c = Operand::new(grads, l.kernel + r0 * l.fan_out);
            let epi = Epilogue { accumulate: true, ..Epilogue::default() };
            let (scratch, len) = &pb.split_scratch;
            self.matmul.encode_split(
                rec,
                Product { shape: (width, n, l.fan_out), a: Operand::t(input, 0), b: Operand::new(dz, 0), c, epi },
                scratch,
                *len,
            );
            r0 += width;
        }
        let sums = ColSums { rows: n, cols: l.fan_out, accumulate: true };
        self.aux.col_sums(rec, (dz, 0), (grads, l.bias), sums, &pb.col_scratch);
        if let Some(d) = d_first {
            let (first, width) = parts[0];
            let epi = Epilogue { accumulate: d.accumulate, mask: d.relu.then_some((first, 0)), ..Epilogue::default() };
            self.matmul.encode(
                rec,
                Product {
                    shape: (n, l.fan_out, width),
                    a: Operand::new(dz, 0),
                    b: Operand::t(params, l.kernel),
                    c: Operand::new(d.out, 0),
                    epi,
                },
            );
        }
    }

    /// Records the forward pass: fills `bufs.raw_rgb` and the raw densities
    /// ([`MlpBuffers::raw_density`]) from `bufs.x` and the view encodings (the product kernels
    /// read `bufs.view`; the fused kernels encode the rays' directions `view_dirs` as they read
    /// them).
    pub fn forward(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        bufs: &MlpBuffers,
        view_dirs: &wgpu::Buffer,
    ) {
        match &bufs.passes {
            Passes::Products(pb) => self.forward_products(rec, shape, params, bufs, pb),
            Passes::Fused(f) => self.fused.forward(rec, shape, params, &bufs.fused_batch(view_dirs), f),
        }
    }

    fn forward_products(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        params: &wgpu::Buffer,
        bufs: &MlpBuffers,
        pb: &ProductBuffers,
    ) {
        let c = &shape.config;
        let (n, d) = (bufs.n, c.net_depth);
        let ls = &shape.layers;
        for i in 0..d {
            let parts: Vec<Part<'_>> = if i == 0 {
                vec![(&bufs.x, c.x_dim)]
            } else if shape.concat_after(i - 1) {
                vec![(&pb.trunk[i - 1], c.net_width), (&bufs.x, c.x_dim)]
            } else {
                vec![(&pb.trunk[i - 1], c.net_width)]
            };
            self.dense(rec, params, LayerRun::new(&ls[i], &parts, n), &pb.trunk[i], true);
        }
        // Both heads as one product: [density | bottleneck] = top · [K_d | K_b] + [b_d | b_b],
        // with the two layers' kernels and biases packed side by side first.
        let top = self.top_parts(shape, bufs, pb);
        let (hw, t) = (pb.heads_width, ls[d].fan_in);
        let heads = Heads { density: ls[d].kernel, bottleneck: ls[d + 1].kernel, rows: t + 1, cols: c.net_width };
        self.aux.pack_heads(rec, params, heads, &pb.heads_w);
        let mut r0 = 0;
        for (k, &(input, width)) in top.iter().enumerate() {
            let last = k + 1 == top.len();
            let epi = Epilogue { accumulate: k > 0, bias: last.then_some(t * hw), ..Epilogue::default() };
            let b = Operand::new(&pb.heads_w, r0 * hw);
            self.matmul.encode(
                rec,
                Product { shape: (n, width, hw), a: Operand::new(input, 0), b, c: Operand::new(&pb.heads, 0), epi },
            );
            r0 += width;
        }
        // The first colour layer: relu(bottleneck · W_b + (view · W_v)[ray] + b), the view part
        // once per ray.
        let (l, wc) = (&ls[d + 2], c.net_width_condition);
        let w_view = Operand::new(params, l.kernel + c.net_width * wc);
        let rows = Operand::new(&pb.view_rows, 0);
        let view = Operand::new(&bufs.view, 0);
        self.matmul.encode(
            rec,
            Product { shape: (bufs.n_rays, c.view_dim, wc), a: view, b: w_view, c: rows, epi: Epilogue::default() },
        );
        let epi = Epilogue {
            bias: Some(l.bias),
            relu: true,
            per_group: Some((&pb.view_rows, 0, bufs.samples_per_ray())),
            ..Epilogue::default()
        };
        let w_b = Operand::new(params, l.kernel);
        let cond0 = Operand::new(&pb.cond[0], 0);
        let bottleneck = Operand::strided(&pb.heads, 1, hw);
        self.matmul.encode(rec, Product { shape: (n, c.net_width, wc), a: bottleneck, b: w_b, c: cond0, epi });
        for j in 1..c.net_depth_condition {
            let parts = [(&pb.cond[j - 1], wc)];
            self.dense(rec, params, LayerRun::new(&ls[d + 2 + j], &parts, n), &pb.cond[j], true);
        }
        let last = &pb.cond[c.net_depth_condition - 1];
        self.dense(
            rec,
            params,
            LayerRun::new(&ls[ls.len() - 1], &[(last, c.net_width_condition)], n),
            &bufs.raw_rgb,
            false,
        );
    }

    fn top_parts<'a>(&self, shape: &MlpShape, bufs: &'a MlpBuffers, pb: &'a ProductBuffers) -> Vec<Part<'a>> {
        let c = &shape.config;
        let top = (&pb.trunk[c.net_depth - 1], c.net_width);
        if shape.concat_after(c.net_depth - 1) { vec![top, (&bufs.x, c.x_dim)] } else { vec![top] }
    }

    /// Records the backward pass of the last forward pass: **adds** every parameter's gradient for
    /// the output gradients `d_raw_rgb` (`n x 3`) and the raw densities' gradient, which the
    /// caller (rendering) has written to [`MlpBuffers::d_raw_density`], to `grads`; writes the
    /// gradient of the encodings to [`MlpBuffers::d_x`] where there is one (the encodings
    /// entering the first layer only: no skip connection).
    ///
    /// The view encodings are the forward pass's (`view_dirs` as there).
    ///
    /// # Errors
    /// A batch too large for one dispatch.
    pub fn backward(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        pg: ParamBuffers<'_>,
        bufs: &MlpBuffers,
        d_raw_rgb: &wgpu::Buffer,
        view_dirs: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        match &bufs.passes {
            Passes::Products(pb) => self.backward_products(rec, shape, pg, bufs, pb, d_raw_rgb),
            Passes::Fused(f) => {
                self.fused.backward(rec, shape, &bufs.fused_batch(view_dirs), f, d_raw_rgb, pg.grads)?;
            }
        }
        Ok(())
    }

    fn backward_products(
        &self,
        rec: &mut Recorder<'_>,
        shape: &MlpShape,
        pg: ParamBuffers<'_>,
        bufs: &MlpBuffers,
        pb: &ProductBuffers,
        d_raw_rgb: &wgpu::Buffer,
    ) {
        let ParamBuffers { params, grads } = pg;
        let c = &shape.config;
        let (n, d, dc) = (bufs.n, c.net_depth, c.net_depth_condition);
        let (w, wc, hw) = (c.net_width, c.net_width_condition, pb.heads_width);
        let ls = &shape.layers;
        let g = &pb.grad;
        let (scratch, len) = (&pb.split_scratch.0, pb.split_scratch.1);
        let add = Epilogue { accumulate: true, ..Epilogue::default() };
        // Indices into g: `a` holds the gradient of the current layer's output.
        let (mut a, mut b) = (0usize, 1usize);
        let to = |out, relu| Some(InputGrad { out, accumulate: false, relu });
        let last = &pb.cond[dc - 1];
        self.dense_backward(
            rec,
            pg,
            LayerRun::new(&ls[ls.len() - 1], &[(last, wc)], n),
            d_raw_rgb,
            to(&g[a], true),
            pb,
        );
        // g[a] holds the gradient of colour layer j's pre-activation (its ReLU backward done).
        for j in (0..dc).rev() {
            if j > 0 {
                let parts = [(&pb.cond[j - 1], wc)];
                self.dense_backward(rec, pg, LayerRun::new(&ls[d + 2 + j], &parts, n), &g[a], to(&g[b], true), pb);
                std::mem::swap(&mut a, &mut b);
            } else {
                // The first colour layer. Its bottleneck rows see every sample (the bottleneck is
                // columns 1.. of the heads); its view rows see each ray once, with the sum of the
                // ray's samples' gradients. The bottleneck has no activation: its gradient goes
                // to columns 1.. of the heads' gradient as it is.
                let l = &ls[d + 2];
                let bottleneck_t = Operand::strided_t(&pb.heads, 1, hw);
                let dz = Operand::new(&g[a], 0);
                let wb = Operand::new(grads, l.kernel);
                self.matmul.encode_split(
                    rec,
                    Product { shape: (w, n, wc), a: bottleneck_t, b: dz, c: wb, epi: add },
                    scratch,
                    len,
                );
                let sums = ColSums { rows: n, cols: wc, accumulate: true };
                self.aux.col_sums(rec, (&g[a], 0), (grads, l.bias), sums, &pb.col_scratch);
                let d_bottleneck = Operand::strided(&pb.d_heads, 1, hw);
                let kt = Operand::t(params, l.kernel);
                self.matmul.encode(
                    rec,
                    Product { shape: (n, wc, w), a: dz, b: kt, c: d_bottleneck, epi: Epilogue::default() },
                );
                self.aux.group_sums(rec, &g[a], &pb.view_rows, bufs.n_rays, wc, bufs.samples_per_ray());
                self.matmul.encode_split(
                    rec,
                    Product {
                        shape: (c.view_dim, bufs.n_rays, wc),
                        a: Operand::t(&bufs.view, 0),
                        b: Operand::new(&pb.view_rows, 0),
                        c: Operand::new(grads, l.kernel + w * wc),
                        epi: add,
                    },
                    scratch,
                    len,
                );
            }
        }
        // Both heads, one product: the gradient [d density | d bottleneck] (the density part
        // written by rendering) against the packed kernels; the packed gradient is added back to
        // the two layers'. The input gradient goes to g[z] with the ReLU backward of the trunk.
        let top = self.top_parts(shape, bufs, pb);
        let t = ls[d].fan_in;
        let dz = Operand::new(&pb.d_heads, 0);
        let mut r0 = 0;
        for &(input, width) in &top {
            let out = Operand::new(&pb.heads_g, r0 * hw);
            self.matmul.encode_split(
                rec,
                Product { shape: (width, n, hw), a: Operand::t(input, 0), b: dz, c: out, epi: Epilogue::default() },
                scratch,
                len,
            );
            r0 += width;
        }
        let sums = ColSums { rows: n, cols: hw, accumulate: false };
        self.aux.col_sums(rec, (&pb.d_heads, 0), (&pb.heads_g, t * hw), sums, &pb.col_scratch);
        let heads = Heads { density: ls[d].kernel, bottleneck: ls[d + 1].kernel, rows: t + 1, cols: w };
        self.aux.unpack_heads_add(rec, &pb.heads_g, grads, heads);
        let z = 0;
        let relu = Epilogue { mask: Some((top[0].0, 0)), ..Epilogue::default() };
        let kt = Operand::t(&pb.heads_w, 0);
        self.matmul.encode(rec, Product { shape: (n, hw, w), a: dz, b: kt, c: Operand::new(&g[z], 0), epi: relu });
        let (mut cur, mut other) = (z, 1);
        for i in (0..d).rev() {
            if i == 0 {
                let d_x = bufs.d_x.as_ref().map(|out| InputGrad { out, accumulate: false, relu: false });
                self.dense_backward(rec, pg, LayerRun::new(&ls[0], &[(&bufs.x, c.x_dim)], n), &g[cur], d_x, pb);
            } else {
                let parts: Vec<Part<'_>> = if shape.concat_after(i - 1) {
                    vec![(&pb.trunk[i - 1], w), (&bufs.x, c.x_dim)]
                } else {
                    vec![(&pb.trunk[i - 1], w)]
                };
                self.dense_backward(rec, pg, LayerRun::new(&ls[i], &parts, n), &g[cur], to(&g[other], true), pb);
                std::mem::swap(&mut cur, &mut other);
            }
        }
    }
}
