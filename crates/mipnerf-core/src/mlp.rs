//! The Mip-NeRF MLP on the CPU: batched forward and backward passes over one flat parameter buffer.
//!
//! # Architecture (the official `MLP` of `internal/models.py`)
//! - Trunk: `net_depth` dense layers of `net_width`, ReLU. After trunk layer `i` with
//!   `i % skip_layer == 0 && i > 0`, the encoded input is concatenated to the trunk's output
//!   (`[h, x]`), so the next layer (or the heads) takes `net_width + x_dim` inputs.
//! - Density head: one dense layer to 1 raw density (activation applied by the model).
//! - Colour: a `net_width` bottleneck with no activation, concatenated with the view-direction
//!   encoding (`[bottleneck, view]`), then `net_depth_condition` dense layers of
//!   `net_width_condition` with ReLU, then one dense layer to 3 raw colours.
//!
//! # Parameter layout
//! Dense layers are numbered in the official creation order: `Dense_0 ..= Dense_{D-1}` (trunk),
//! `Dense_D` (density), `Dense_{D+1}` (bottleneck), `Dense_{D+2} ..` (condition layers), and the
//! last one (rgb). For each layer, in that order, the flat buffer holds its kernel
//! (`fan_in x fan_out`, row-major, so `y = x · kernel + bias` as in flax) and then its bias
//! (`fan_out`). Where a layer's input is a concatenation, the kernel's rows follow the
//! concatenation order. The GPU backend and the checkpoints share this layout
//! ([`MlpShape::layers`] lists the names, offsets and shapes).

use std::ops::Range;

use rand::{Rng, SeedableRng, rngs::SmallRng};

use crate::bf16::{Bf16Matrix, Operand, Precision, Reads, matmul_bf16, uses_bf16};
use crate::linalg::{Layout, Product, matmul};
use crate::lines::Lines;
use crate::wide::wide;

/// The shape of the MLP. Defaults are the official ones (the paper's 612K-parameter network).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MlpConfig {
    /// Trunk depth (8).
    pub net_depth: usize,
    /// Trunk width (256).
    pub net_width: usize,
    /// Concatenate the input after every trunk layer `i > 0` with `i % skip_layer == 0` (4).
    pub skip_layer: usize,
    /// Depth of the view-conditioned colour branch (1); at least 1.
    pub net_depth_condition: usize,
    /// Width of the colour branch (128).
    pub net_width_condition: usize,
    /// Width of the encoded sample input (96 = IPE degrees 0..16).
    pub x_dim: usize,
    /// Width of the encoded view direction (27 = PE degrees 0..4 with the identity).
    pub view_dim: usize,
}

/// The paper's MLP (and `ModelConfig::default`'s): 8 layers of 256, the skip after the fourth,
/// one view layer of 128.
impl Default for MlpConfig {
    fn default() -> Self {
        Self {
            net_depth: 8,
            net_width: 256,
            skip_layer: 4,
            net_depth_condition: 1,
            net_width_condition: 128,
            x_dim: 96,
            view_dim: 27,
        }
    }
}

/// One dense layer's place in the flat parameter buffer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DenseLayer {
    /// `Dense_k`, the official (flax) name.
    pub name: String,
    /// Inputs.
    pub fan_in: usize,
    /// Outputs.
    pub fan_out: usize,
    /// Offset of the `fan_in x fan_out` row-major kernel.
    pub kernel: usize,
    /// Offset of the `fan_out` bias.
    pub bias: usize,
}

impl DenseLayer {
    /// The kernel's values in `params`.
    #[must_use]
    pub fn kernel<'a>(&self, params: &'a [f32]) -> &'a [f32] {
        &params[self.kernel..self.kernel + self.fan_in * self.fan_out]
    }
    /// Rows `r0..r0 + rows` of the kernel in `params`.
    #[must_use]
    pub fn kernel_rows<'a>(&self, params: &'a [f32], r0: usize, rows: usize) -> &'a [f32] {
        &params[self.kernel + r0 * self.fan_out..self.kernel + (r0 + rows) * self.fan_out]
    }
    /// The bias's values in `params`.
    #[must_use]
    pub fn bias<'a>(&self, params: &'a [f32]) -> &'a [f32] {
        &params[self.bias..self.bias + self.fan_out]
    }
}

/// An MLP's layers and their place in a flat parameter buffer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MlpShape {
    /// The configuration this shape was built from.
    pub config: MlpConfig,
    /// Every dense layer, in the official creation order.
    pub layers: Vec<DenseLayer>,
    /// Total number of parameters.
    pub num_params: usize,
    /// The precision of the matrix products ([`Precision::F32`] unless set).
    pub precision: Precision,
}

/// Errors in an MLP configuration.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid MLP configuration: {0}")]
pub struct MlpConfigError(pub String);

/// What a forward pass of the MLP read, which its backward pass reads again: the samples'
/// encodings (`x_dim` a sample), the rays' view encodings (`view_dim` a ray), and the samples a
/// ray.
#[derive(Clone, Copy, Debug)]
pub struct MlpInputs<'a> {
    /// The samples' encodings.
    pub x: &'a [f32],
    /// The rays' view encodings.
    pub view: &'a [f32],
    /// Samples a ray.
    pub samples_per_ray: usize,
}

/// The loss gradient with respect to the MLP's raw outputs: three colour values and a density
/// a sample.
#[derive(Clone, Copy, Debug)]
pub struct OutputGradients<'a> {
    /// `3 n` values.
    pub rgb: &'a [f32],
    /// `n` values.
    pub density: &'a [f32],
}

impl MlpShape {
    /// Lays out the MLP of `config`, starting at offset `base` of the flat buffer.
    ///
    /// # Errors
    /// If a size is zero or `net_depth_condition` is 0.
    pub fn new(config: MlpConfig, base: usize) -> Result<Self, MlpConfigError> {
        let c = config;
        if c.net_depth == 0 || c.net_width == 0 || c.net_width_condition == 0 || c.x_dim == 0 {
            return Err(MlpConfigError(format!("depth, widths and input width must be positive: {c:?}")));
        }
        if c.net_depth_condition == 0 {
            return Err(MlpConfigError("net_depth_condition must be at least 1".into()));
        }
        let mut layers = Vec::new();
        let mut off = base;
        let mut push = |fan_in: usize, fan_out: usize| {
            let name = format!("Dense_{}", layers.len());
            layers.push(DenseLayer { name, fan_in, fan_out, kernel: off, bias: off + fan_in * fan_out });
            off += fan_in * fan_out + fan_out;
        };
        let shape_tmp = |i: usize| config_concat_after(&c, i);
        for i in 0..c.net_depth {
            let fan_in = if i == 0 { c.x_dim } else { c.net_width + if shape_tmp(i - 1) { c.x_dim } else { 0 } };
            push(fan_in, c.net_width);
        }
        let top = c.net_width + if shape_tmp(c.net_depth - 1) { c.x_dim } else { 0 };
        push(top, 1);
        push(top, c.net_width);
        for j in 0..c.net_depth_condition {
            let fan_in = if j == 0 { c.net_width + c.view_dim } else { c.net_width_condition };
            push(fan_in, c.net_width_condition);
        }
        push(c.net_width_condition, 3);
        Ok(Self { config: c, layers, num_params: off - base, precision: Precision::F32 })
    }

    /// Whether the encoded input is concatenated after trunk layer `i`.
    #[must_use]
    pub fn concat_after(&self, i: usize) -> bool {
        config_concat_after(&self.config, i)
    }

    fn trunk(&self, i: usize) -> &DenseLayer {
        &self.layers[i]
    }
    fn density_head(&self) -> &DenseLayer {
        &self.layers[self.config.net_depth]
    }
    fn bottleneck(&self) -> &DenseLayer {
        &self.layers[self.config.net_depth + 1]
    }
    fn condition(&self, j: usize) -> &DenseLayer {
        &self.layers[self.config.net_depth + 2 + j]
    }
    fn rgb_head(&self) -> &DenseLayer {
        &self.layers[self.layers.len() - 1]
    }

    /// Glorot-uniform kernels (`U(±sqrt(6 / (fan_in + fan_out)))`) and zero biases, written into
    /// this MLP's slice of `params`, from `seed`.
    pub fn init_glorot(&self, params: &mut [f32], seed: u64) {
        let mut rng = SmallRng::seed_from_u64(seed);
        for l in &self.layers {
            let limit = (6.0 / (l.fan_in + l.fan_out) as f64).sqrt() as f32;
            for v in &mut params[l.kernel..l.kernel + l.fan_in * l.fan_out] {
                *v = rng.random_range(-limit..limit);
            }
            params[l.bias..l.bias + l.fan_out].fill(0.0);
        }
    }

    /// Floating-point operations of the matrix products per sample, forward and backward
    /// (2 per multiply-add; backward = input gradients + weight gradients = 2x forward; the first
    /// layer's input gradient is not computed).
    #[must_use]
    pub fn flops_per_sample(&self) -> f64 {
        let fwd: usize = self.layers.iter().map(|l| 2 * l.fan_in * l.fan_out).sum();
        let first = 2 * self.layers[0].fan_in * self.layers[0].fan_out;
        (3 * fwd - first) as f64
    }
}

fn config_concat_after(c: &MlpConfig, i: usize) -> bool {
    c.skip_layer > 0 && i > 0 && i.is_multiple_of(c.skip_layer)
}

/// Activations kept from the forward pass for the backward pass, and scratch space. Reused across
/// calls to avoid allocation.
#[derive(Default, Debug, Clone)]
pub struct MlpCache {
    n: usize,
    n_rays: usize,
    /// Post-ReLU outputs of each trunk layer, `n x net_width` each.
    trunk: Vec<Lines<f32>>,
    bottleneck: Lines<f32>,
    /// Per-ray projection of the view encoding through the first condition layer.
    view_proj: Lines<f32>,
    /// Post-ReLU outputs of each condition layer.
    cond: Vec<Lines<f32>>,
    /// Raw colour, `n x 3`.
    pub raw_rgb: Vec<f32>,
    /// Raw density, `n`.
    pub raw_density: Vec<f32>,
    grad_a: Lines<f32>,
    grad_b: Lines<f32>,
    grad_z: Lines<f32>,
    grad_ray: Lines<f32>,
    /// At [`Precision::Bf16`], the products' operands packed once each ([`Packed`]).
    packed: PackedOperands,
    /// Whether the next forward pass packs its activations for a backward pass too.
    training: bool,
    /// Whether each product packs its own bf16 operands (the way before [`PackedOperands`]).
    pack_in_each_product: bool,
    /// Whether the last forward pass was [`MlpShape::density`], which keeps no colour layers.
    density_only: bool,
}

impl MlpCache {
    /// Whether the next [`MlpShape::forward`] is followed by a [`MlpShape::backward`]. At
    /// [`Precision::Bf16`] the forward pass then packs each activation for the weight gradient
    /// too, in the same pass as for the next layer (without it the backward pass packs them
    /// itself). No effect on the results. `false` by default.
    pub fn set_training(&mut self, training: bool) {
        self.training = training;
    }

    /// At [`Precision::Bf16`], whether every product rounds and packs its own operands
    /// ([`crate::bf16::matmul_bf16`]) rather than reading each activation and gradient packed
    /// once for all its products (the default). The same bits either way; kept to measure what
    /// packing once saves (`benches/mlp_bf16.rs`).
    pub fn set_pack_in_each_product(&mut self, yes: bool) {
        self.pack_in_each_product = yes;
    }
}

/// The bf16 packings of the activations and gradients the MLP's products share.
#[derive(Default, Debug, Clone)]
struct PackedOperands {
    x: Packed,
    trunk: Vec<Packed>,
    bottleneck: Packed,
    cond: Vec<Packed>,
    /// The gradient `dz` of the layer the backward pass is at.
    dz: Packed,
}

/// A matrix's bf16 packing ([`Bf16Matrix`]) and the roles it was packed for this pass.
#[derive(Default, Debug, Clone)]
struct Packed {
    matrix: Bf16Matrix,
    reads: Reads,
}

impl Packed {
    /// Packs `values` (`rows x cols`) in the roles `reads` names ([`input_reads`],
    /// [`gradient_reads`]); nothing at f32.
    fn pack(&mut self, precision: Precision, values: &[f32], rows: usize, cols: usize, reads: Reads) {
        self.reads = if precision == Precision::Bf16 { reads } else { Reads::default() };
        if self.reads != Reads::default() {
            self.matrix.pack(values, rows, cols, self.reads);
        }
    }

    /// Lets `prepare` finish `values` (`rows x cols`) and packs them as [`pack`](Self::pack)
    /// does, block after block while each block is in the cache ([`Bf16Matrix::pack_after`]);
    /// at f32, or with no role to pack, `prepare` runs on all rows at once.
    fn pack_after(
        &mut self,
        precision: Precision,
        values: &mut [f32],
        rows: usize,
        cols: usize,
        reads: Reads,
        mut prepare: impl FnMut(&mut [f32], Range<usize>),
    ) {
        self.reads = if precision == Precision::Bf16 { reads } else { Reads::default() };
        if self.reads == Reads::default() {
            prepare(&mut values[..rows * cols], 0..rows);
        } else {
            self.matrix.pack_after(values, rows, cols, self.reads, prepare);
        }
    }

    /// `values` (the matrix packed) as an operand in `layout`, with its packing where the
    /// role was packed.
    fn operand<'a>(&'a self, values: &'a [f32], layout: Layout) -> Operand<'a> {
        let packed = match layout {
            Layout::Normal => self.reads.left,
            Layout::Transposed => self.reads.left_transposed,
        };
        Operand { values, layout, packed: packed.then_some(&self.matrix) }
    }

    /// `values` as the right operand, stored as it is read, with its packing if packed so.
    fn right<'a>(&'a self, values: &'a [f32]) -> Operand<'a> {
        Operand { values, layout: Layout::Normal, packed: self.reads.right.then_some(&self.matrix) }
    }
}

/// The roles a layer's input (`n x width`) plays, read by a layer of `fan_out` outputs: the
/// forward product, and with `training` the weight gradient, where these run in bf16.
fn input_reads(n: usize, width: usize, fan_out: usize, training: bool) -> Reads {
    let bf16 = uses_bf16(n, width, fan_out);
    Reads { left: bf16, left_transposed: bf16 && training, right: false }
}

/// The roles a layer's output gradient `dz` (`n x fan_out`, for a layer of `fan_in` inputs)
/// plays: the right operand of the weight gradient and, with `input_gradient`, the left
/// operand of the input gradient (to `width` columns), where these run in bf16.
fn gradient_reads(n: usize, fan_in: usize, fan_out: usize, width: usize, input_gradient: bool) -> Reads {
    Reads {
        left: input_gradient && uses_bf16(n, fan_out, width),
        left_transposed: false,
        right: uses_bf16(fan_in, n, fan_out),
    }
}

fn resize(v: &mut Lines<f32>, len: usize) {
    v.resize(len, 0.0);
}

/// `out (n x fan_out) = sum over parts of input_p · (the kernel rows of part p)`: a dense layer
/// without its bias, whose input is the concatenation of the parts (each `n x width`, the first
/// rows of the kernel, in order).
fn dense(p: Precision, params: &[f32], l: &DenseLayer, parts: &[(Operand<'_>, usize)], n: usize, out: &mut [f32]) {
    let mut r0 = 0;
    for (k, &(input, width)) in parts.iter().enumerate() {
        let rows = Operand::f32(l.kernel_rows(params, r0, width), Layout::Normal);
        product(p, out, input, rows, Product::of(n, width, l.fan_out, k > 0));
        r0 += width;
    }
}

/// [`matmul`] or [`matmul_bf16`], as `precision` says.
fn product(precision: Precision, c: &mut [f32], a: Operand<'_>, b: Operand<'_>, p: Product) {
    match precision {
        Precision::F32 => matmul(c, a.values, a.layout, b.values, b.layout, p),
        Precision::Bf16 => matmul_bf16(c, a, b, p, None),
    }
}

/// `out[row] += bias`, then ReLU if `relu`: one pass, vectorised along rows.
fn add_bias(out: &mut [f32], bias: &[f32], relu: bool) {
    wide(
        #[inline(always)]
        || {
            for row in out.chunks_exact_mut(bias.len()) {
                if relu {
                    for (o, &b) in row.iter_mut().zip(bias) {
                        *o = (*o + b).max(0.0);
                    }
                } else {
                    for (o, &b) in row.iter_mut().zip(bias) {
                        *o += b;
                    }
                }
            }
        },
    );
}

/// [`add_bias`] with ReLU where the bias is one row per ray (`ray_bias`, `rays x width`):
/// `rows` (`width` wide) are the samples from `first_sample` on, `samples_per_ray` per ray.
fn add_ray_bias_relu(rows: &mut [f32], first_sample: usize, ray_bias: &[f32], width: usize, samples_per_ray: usize) {
    let mut sample = first_sample;
    let mut rest = rows;
    while !rest.is_empty() {
        let ray = sample / samples_per_ray;
        let here = ((ray + 1) * samples_per_ray - sample).min(rest.len() / width);
        let (now, later) = rest.split_at_mut(here * width);
        add_bias(now, &ray_bias[ray * width..(ray + 1) * width], true);
        (sample, rest) = (sample + here, later);
    }
}

/// ReLU's backward pass in place (`g = g * (h > 0)`), adding the column sums of the result to
/// `bias_grad`: one pass, branch-free so that it vectorises ([`wide`]).
fn relu_backward_bias(g: &mut [f32], h: &[f32], bias_grad: &mut [f32]) {
    let w = bias_grad.len();
    wide(
        #[inline(always)]
        || {
            for (grow, hrow) in g.chunks_exact_mut(w).zip(h.chunks_exact(w)) {
                for ((gi, &hi), b) in grow.iter_mut().zip(hrow).zip(bias_grad.iter_mut()) {
                    *gi = if hi > 0.0 { *gi } else { 0.0 };
                    *b += *gi;
                }
            }
        },
    );
}

/// `bias_grad += ` the column sums of `g` (rows of `bias_grad.len()`), row after row ([`wide`]).
fn add_col_sums(bias_grad: &mut [f32], g: &[f32]) {
    wide(
        #[inline(always)]
        || {
            for row in g.chunks_exact(bias_grad.len()) {
                for (b, &x) in bias_grad.iter_mut().zip(row) {
                    *b += x;
                }
            }
        },
    );
}

impl MlpShape {
    /// Forward pass over `n_rays * samples_per_ray` samples.
    ///
    /// `x` is `n x x_dim` (sample encodings, the samples of a ray contiguous), `view` is
    /// `n_rays x view_dim`. Fills `cache.raw_rgb` (`n x 3`) and `cache.raw_density` (`n`) and
    /// keeps what the backward pass needs.
    ///
    /// # Panics
    /// If the slices do not match the shapes.
    pub fn forward(
        &self,
        params: &[f32],
        x: &[f32],
        view: &[f32],
        n_rays: usize,
        samples_per_ray: usize,
        cache: &mut MlpCache,
    ) {
        let c = &self.config;
        let n = n_rays * samples_per_ray;
        assert_eq!(view.len(), n_rays * c.view_dim, "mlp forward: view");
        self.forward_density(params, x, n, cache);
        cache.n_rays = n_rays;
        cache.density_only = false;
        let (w, wc, p) = (c.net_width, c.net_width_condition, self.precision);
        let pack = if cache.pack_in_each_product { Precision::F32 } else { p };
        let MlpCache { trunk, bottleneck, cond, view_proj, raw_rgb, packed, training, .. } = cache;
        let training = *training;
        let x_part = (packed.x.operand(x, Layout::Normal), c.x_dim);
        let top = (packed.trunk[c.net_depth - 1].operand(&trunk[c.net_depth - 1], Layout::Normal), w);
        let top_parts: &[_] = if self.concat_after(c.net_depth - 1) { &[top, x_part] } else { &[top] };
        resize(bottleneck, n * w);
        dense(p, params, self.bottleneck(), top_parts, n, bottleneck);
        let (bias, reads) = (self.bottleneck().bias(params), input_reads(n, w, wc, training));
        packed.bottleneck.pack_after(pack, bottleneck, n, w, reads, |rows, _| add_bias(rows, bias, false));
        // Condition layers. The first takes [bottleneck, view]; its view part, with the bias, is the
        // same for all samples of a ray, so it is computed once per ray and added to each sample.
        cond.resize_with(c.net_depth_condition, Lines::default);
        packed.cond.resize_with(c.net_depth_condition, Packed::default);
        let l0 = self.condition(0);
        resize(view_proj, n_rays * wc);
        let view_rows = Operand::f32(l0.kernel_rows(params, w, c.view_dim), Layout::Normal);
        product(
            p,
            view_proj,
            Operand::f32(view, Layout::Normal),
            view_rows,
            Product::of(n_rays, c.view_dim, wc, false),
        );
        add_bias(view_proj, l0.bias(params), false);
        for j in 0..c.net_depth_condition {
            let (before, rest) = cond.split_at_mut(j);
            let out = &mut rest[0];
            resize(out, n * wc);
            let l = self.condition(j);
            // Read by the next condition layer, or by the 3 colours' head (in f32).
            let next = if j + 1 < c.net_depth_condition { wc } else { self.rgb_head().fan_out };
            let reads = input_reads(n, wc, next, training);
            if j == 0 {
                dense(p, params, l, &[(packed.bottleneck.operand(bottleneck, Layout::Normal), w)], n, out);
                let view_proj = &view_proj[..];
                packed.cond[j].pack_after(pack, out, n, wc, reads, |block, rows| {
                    add_ray_bias_relu(block, rows.start, view_proj, wc, samples_per_ray);
                });
            } else {
                dense(p, params, l, &[(packed.cond[j - 1].operand(&before[j - 1], Layout::Normal), wc)], n, out);
                let bias = l.bias(params);
                packed.cond[j].pack_after(pack, out, n, wc, reads, |rows, _| add_bias(rows, bias, true));
            }
        }
        raw_rgb.resize(n * 3, 0.0);
        let l = self.rgb_head();
        let last = c.net_depth_condition - 1;
        dense(p, params, l, &[(packed.cond[last].operand(&cond[last], Layout::Normal), wc)], n, raw_rgb);
        add_bias(raw_rgb, l.bias(params), false);
    }

    /// The density alone over `n` samples: the trunk and the density head of
    /// [`forward`](Self::forward), the same operations in the same order, so
    /// `cache.raw_density` (`n`) holds the same bits as after a full forward pass over the same
    /// `x`; the colour layers are skipped (17% of the paper's MLP's multiply-adds, 26% of the
    /// fast preset's). What the occupancy grid probes, and what a render of the last level alone
    /// runs at the earlier levels (`Levels::Last`).
    /// No [`backward`](Self::backward) may follow it.
    ///
    /// # Panics
    /// If `x` is not `n x x_dim`.
    pub fn density(&self, params: &[f32], x: &[f32], n: usize, cache: &mut MlpCache) {
        self.forward_density(params, x, n, cache);
        cache.n_rays = n;
        cache.density_only = true;
    }

    /// The trunk and the density head: the part of [`forward`](Self::forward) that
    /// [`density`](Self::density) runs alone.
    fn forward_density(&self, params: &[f32], x: &[f32], n: usize, cache: &mut MlpCache) {
        let c = &self.config;
        assert_eq!(x.len(), n * c.x_dim, "mlp forward: x");
        cache.n = n;
        let (w, p) = (c.net_width, self.precision);
        // The precision the shared packings are made for: none at f32, or if each product packs.
        let pack = if cache.pack_in_each_product { Precision::F32 } else { p };
        let MlpCache { trunk, raw_density, packed, training, .. } = cache;
        let training = *training;
        packed.x.pack(pack, x, n, c.x_dim, input_reads(n, c.x_dim, w, training));
        let x_part = (packed.x.operand(x, Layout::Normal), c.x_dim);
        trunk.resize_with(c.net_depth, Lines::default);
        packed.trunk.resize_with(c.net_depth, Packed::default);
        for i in 0..c.net_depth {
            let (before, rest) = trunk.split_at_mut(i);
            let out = &mut rest[0];
            resize(out, n * w);
            let l = self.trunk(i);
            if i == 0 {
                dense(p, params, l, &[x_part], n, out);
            } else {
                let h = (packed.trunk[i - 1].operand(&before[i - 1], Layout::Normal), w);
                let parts: &[_] = if self.concat_after(i - 1) { &[h, x_part] } else { &[h] };
                dense(p, params, l, parts, n, out);
            }
            // Read by the next trunk layer or the bottleneck, both `net_width` wide (the
            // density head's one output runs in f32).
            let bias = l.bias(params);
            packed.trunk[i]
                .pack_after(pack, out, n, w, input_reads(n, w, w, training), |rows, _| add_bias(rows, bias, true));
        }
        // The density head on [top, x?].
        let top = (packed.trunk[c.net_depth - 1].operand(&trunk[c.net_depth - 1], Layout::Normal), w);
        let top_parts: &[_] = if self.concat_after(c.net_depth - 1) { &[top, x_part] } else { &[top] };
        raw_density.resize(n, 0.0);
        dense(p, params, self.density_head(), top_parts, n, raw_density);
        add_bias(raw_density, self.density_head().bias(params), false);
    }

    /// Backward pass of the last [`forward`](Self::forward) (same `params`, `x`, `view`, `cache`):
    /// given `d_raw_rgb` (`n x 3`) and `d_raw_density` (`n`), **adds** the gradient of every
    /// parameter to `grads` (this MLP's slice, same layout as `params`). Inputs get no gradient.
    ///
    /// # Panics
    /// If the slices do not match the shapes of the forward pass.
    pub fn backward(
        &self,
        params: &[f32],
        inputs: MlpInputs<'_>,
        cache: &mut MlpCache,
        d_raw: OutputGradients<'_>,
        grads: &mut [f32],
    ) {
        let MlpInputs { x, view, samples_per_ray } = inputs;
        let OutputGradients { rgb: d_raw_rgb, density: d_raw_density } = d_raw;
        let c = &self.config;
        let (n, n_rays) = (cache.n, cache.n_rays);
        assert!(!cache.density_only, "mlp backward: the last forward pass was density-only");
        assert_eq!(d_raw_rgb.len(), n * 3, "mlp backward: d_raw_rgb");
        assert_eq!(d_raw_density.len(), n, "mlp backward: d_raw_density");
        assert_eq!(n, n_rays * samples_per_ray, "mlp backward: samples per ray");
        let (w, wc, p) = (c.net_width, c.net_width_condition, self.precision);
        let pack = if cache.pack_in_each_product { Precision::F32 } else { p };
        let MlpCache { trunk, bottleneck, cond, grad_a, grad_b, grad_z, grad_ray, packed, .. } = cache;
        let (normal, transposed) = (Layout::Normal, Layout::Transposed);

        // Accumulate kernel += inᵀ · dz and bias += colsum(dz).
        let weight_grad =
            |grads: &mut [f32], l: &DenseLayer, r0: usize, input: Operand<'_>, in_w: usize, dz: Operand<'_>, rows| {
                let k = &mut grads[l.kernel + r0 * l.fan_out..l.kernel + (r0 + in_w) * l.fan_out];
                product(p, k, input, dz, Product::of(in_w, rows, l.fan_out, true));
            };
        // A layer's kernel (its first `rows` rows), transposed: the input gradient's right operand.
        let kernel_t = |l: &DenseLayer, rows: usize| Operand::f32(l.kernel_rows(params, 0, rows), transposed);

        // rgb head.
        let l = self.rgb_head();
        let last = c.net_depth_condition - 1;
        let d_rgb = Operand::f32(d_raw_rgb, normal);
        weight_grad(grads, l, 0, packed.cond[last].operand(&cond[last], transposed), wc, d_rgb, n);
        add_col_sums(&mut grads[l.bias..l.bias + 3], d_raw_rgb);
        resize(grad_a, n * wc);
        product(p, grad_a, d_rgb, kernel_t(l, wc), Product::of(n, 3, wc, false));
        // Condition layers, top down. grad_a holds d(output of layer j).
        for j in (0..c.net_depth_condition).rev() {
            let l = self.condition(j);
            // The kernel's rows of the previous layer (the bottleneck's at j = 0).
            let fan_in = if j > 0 { wc } else { w };
            let (h, bias_grad) = (&cond[j], &mut grads[l.bias..l.bias + wc]);
            packed.dz.pack_after(pack, grad_a, n, wc, gradient_reads(n, fan_in, wc, fan_in, true), |g, rows| {
                relu_backward_bias(g, &h[rows.start * wc..rows.end * wc], bias_grad);
            });
            if j > 0 {
                let input = packed.cond[j - 1].operand(&cond[j - 1], transposed);
                weight_grad(grads, l, 0, input, wc, packed.dz.right(grad_a), n);
                resize(grad_b, n * wc);
                product(p, grad_b, packed.dz.operand(grad_a, normal), kernel_t(l, wc), Product::of(n, wc, wc, false));
                std::mem::swap(grad_a, grad_b);
            } else {
                let input = packed.bottleneck.operand(bottleneck, transposed);
                weight_grad(grads, l, 0, input, w, packed.dz.right(grad_a), n);
                // View rows: viewᵀ · (per-ray sums of dz).
                resize(grad_ray, n_rays * wc);
                grad_ray.fill(0.0);
                for (r, rows) in grad_a.chunks_exact(samples_per_ray * wc).enumerate() {
                    add_col_sums(&mut grad_ray[r * wc..(r + 1) * wc], rows);
                }
                let (view_t, d_ray) = (Operand::f32(view, transposed), Operand::f32(grad_ray, normal));
                weight_grad(grads, l, w, view_t, c.view_dim, d_ray, n_rays);
                // d bottleneck.
                resize(grad_b, n * w);
                product(p, grad_b, packed.dz.operand(grad_a, normal), kernel_t(l, w), Product::of(n, wc, w, false));
            }
        }
        // grad_b = d bottleneck (no activation). Heads read [top, x?].
        let top_concat = self.concat_after(c.net_depth - 1);
        let top = &trunk[c.net_depth - 1];
        resize(grad_z, n * w);
        for (l, dz, first) in [(self.bottleneck(), &grad_b[..], true), (self.density_head(), d_raw_density, false)] {
            packed.dz.pack(pack, dz, n, l.fan_out, gradient_reads(n, w, l.fan_out, w, true));
            let input = packed.trunk[c.net_depth - 1].operand(top, transposed);
            weight_grad(grads, l, 0, input, w, packed.dz.right(dz), n);
            if top_concat {
                weight_grad(grads, l, w, packed.x.operand(x, transposed), c.x_dim, packed.dz.right(dz), n);
            }
            add_col_sums(&mut grads[l.bias..l.bias + l.fan_out], dz);
            product(p, grad_z, packed.dz.operand(dz, normal), kernel_t(l, w), Product::of(n, l.fan_out, w, !first));
        }
        // Trunk, top down. grad_z holds d(output of layer i).
        for i in (0..c.net_depth).rev() {
            let l = self.trunk(i);
            // The kernel's first rows take the previous layer's output (the input x at layer 0).
            let first_part = if i == 0 { c.x_dim } else { w };
            let (h, bias_grad) = (&trunk[i], &mut grads[l.bias..l.bias + w]);
            packed.dz.pack_after(pack, grad_z, n, w, gradient_reads(n, first_part, w, w, i > 0), |g, rows| {
                relu_backward_bias(g, &h[rows.start * w..rows.end * w], bias_grad);
            });
            if i == 0 {
                weight_grad(grads, l, 0, packed.x.operand(x, transposed), c.x_dim, packed.dz.right(grad_z), n);
            } else {
                let input = packed.trunk[i - 1].operand(&trunk[i - 1], transposed);
                weight_grad(grads, l, 0, input, w, packed.dz.right(grad_z), n);
                if self.concat_after(i - 1) {
                    weight_grad(grads, l, w, packed.x.operand(x, transposed), c.x_dim, packed.dz.right(grad_z), n);
                }
                resize(grad_a, n * w);
                product(p, grad_a, packed.dz.operand(grad_z, normal), kernel_t(l, w), Product::of(n, w, w, false));
                std::mem::swap(grad_a, grad_z);
            }
        }
    }

    /// The gradient of the encoded input `x` (`n x x_dim`, written to `d_x`) of the last
    /// [`backward`](Self::backward) pass: for a field whose encoding is itself trained (the
    /// Tri-Mip planes, [`crate::tri_mip`]). Reads the first trunk layer's gradient, which the
    /// backward pass leaves in `cache`, through that layer's kernel; computed in f32 whatever the
    /// products' precision.
    ///
    /// # Panics
    /// If the MLP concatenates its input again after a trunk layer (`skip_layer`): only the first
    /// layer reads it here; or if `d_x` is not `n x x_dim`.
    pub fn input_gradient(&self, params: &[f32], cache: &MlpCache, d_x: &mut [f32]) {
        let c = &self.config;
        assert!(
            (0..c.net_depth).all(|i| !self.concat_after(i)),
            "mlp input gradient: the input is concatenated after a trunk layer (skip_layer {})",
            c.skip_layer
        );
        let n = cache.n;
        assert_eq!(d_x.len(), n * c.x_dim, "mlp input gradient: d_x");
        let first = self.trunk(0);
        let kernel = first.kernel_rows(params, 0, c.x_dim);
        matmul(
            d_x,
            &cache.grad_z[..n * c.net_width],
            Layout::Normal,
            kernel,
            Layout::Transposed,
            Product::of(n, c.net_width, c.x_dim, false),
        );
    }

    /// The post-ReLU output of trunk layer `i` from the last forward pass (`n x net_width`).
    #[must_use]
    pub fn trunk_output<'a>(&self, cache: &'a MlpCache, i: usize) -> &'a [f32] {
        &cache.trunk[i]
    }
}

#[cfg(test)]
mod tests {
    use super::{MlpCache, MlpConfig, MlpShape};

    /// The products' outputs (AMX's `c`, loaded and stored a tile row at a time) start on cache
    /// lines, whatever the allocator gives ([`crate::lines::Lines`]).
    #[test]
    fn the_products_outputs_start_on_cache_lines() {
        let config =
            MlpConfig { net_depth: 3, net_width: 32, skip_layer: 2, x_dim: 12, view_dim: 5, ..MlpConfig::default() };
        let shape = MlpShape::new(config, 0).unwrap();
        let mut params = vec![0.0; shape.num_params];
        shape.init_glorot(&mut params, 1);
        let mut cache = MlpCache::default();
        cache.set_training(true);
        // Growing sizes, so that the buffers are reallocated on the way.
        for (n_rays, samples) in [(1, 3), (7, 5), (64, 33)] {
            let n = n_rays * samples;
            let x: Vec<f32> = (0..n * config.x_dim).map(|i| (i % 13) as f32 * 0.1 - 0.6).collect();
            let view: Vec<f32> = (0..n_rays * config.view_dim).map(|i| (i % 7) as f32 * 0.2 - 0.5).collect();
            shape.forward(&params, &x, &view, n_rays, samples, &mut cache);
            let (d_rgb, d_density) = (vec![0.1; n * 3], vec![0.2; n]);
            let mut grads = vec![0.0; shape.num_params];
            shape.backward(
                &params,
                super::MlpInputs { x: &x, view: &view, samples_per_ray: samples },
                &mut cache,
                super::OutputGradients { rgb: &d_rgb, density: &d_density },
                &mut grads,
            );
            let MlpCache { trunk, bottleneck, cond, grad_a, grad_b, grad_z, view_proj, grad_ray, .. } = &cache;
            let buffers = trunk.iter().chain(cond).chain([bottleneck, grad_a, grad_b, grad_z, view_proj, grad_ray]);
            for (i, buffer) in buffers.enumerate() {
                assert!(!buffer.is_empty(), "buffer {i}, {n} samples");
                assert_eq!(buffer.as_ptr() as usize % 64, 0, "buffer {i}, {n} samples");
            }
        }
    }
}
