//! `shaders/matmul.wgsl`: matrix products with a bias, ReLU or ReLU-backward epilogue, optionally
//! split over k into partial products added in a fixed order; register-blocked through workgroup
//! memory (hardware GPUs) or straight from storage (software adapters).
//!
//! CPU reference: [`mipnerf_core::mlp::MlpShape::forward`] and [`mipnerf_core::mlp::MlpShape::backward`].

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("matmul.wgsl", [MatmulParams]);

/// The uniform block of `matmul.wgsl` (`struct Params`), 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MatmulParams {
    /// Rows of C.
    pub m: u32,
    /// Inner dimension.
    pub k: u32,
    /// Columns of C.
    pub n: u32,
    /// Bit 0: A transposed; 1: B transposed; 2: accumulate into C; 3: add the bias; 4: ReLU after
    /// the bias; 5: multiply by `(mask > 0)` after accumulating (ReLU backward); 6: write the raw
    /// partial product of split z at `c_off + z m n` (no epilogue); 7: add row
    /// `row / rows_per_group` of the per-group matrix in `mask` (before the bias).
    pub flags: u32,
    /// Element offset of A in its buffer.
    pub a_off: u32,
    /// Element offset of B in its buffer.
    pub b_off: u32,
    /// Element offset of C in its buffer.
    pub c_off: u32,
    /// Element offset of the bias in B's buffer.
    pub bias_off: u32,
    /// Entries of k per split (k when unsplit).
    pub k_chunk: u32,
    /// Partial products `reduce_splits` adds.
    pub n_splits: u32,
    /// Workgroups along x of `reduce_splits`'s grid.
    pub groups_x: u32,
    /// Element offset of the mask (or per-group matrix) in its buffer.
    pub mask_off: u32,
    /// Rows of C per row of the per-group matrix.
    pub rows_per_group: u32,
    /// Elements between stored rows of A (k when stored as used, m when transposed), for packed
    /// matrices; more for a column range of a wider matrix (the fused heads' columns).
    pub a_ld: u32,
    /// Elements between rows of C (n; more for a column range, as `a_ld`).
    pub c_ld: u32,
    /// Padding to 16 bytes.
    pub _pad: u32,
}

/// One product for [`MatmulKernel::encode`]: `c (m x n) (+)= a (m x k) · b (k x n)` for
/// `shape` `(m, k, n)`, finished by `epi`.
#[derive(Clone, Copy, Debug)]
pub struct Product<'a> {
    /// `(m, k, n)`.
    pub shape: (usize, usize, usize),
    /// The left operand.
    pub a: Operand<'a>,
    /// The right operand.
    pub b: Operand<'a>,
    /// The output.
    pub c: Operand<'a>,
    /// What is done with each output.
    pub epi: Epilogue<'a>,
}

/// One operand: a buffer, the element offset of the matrix in it, whether it is stored
/// transposed, and its row stride.
#[derive(Clone, Copy, Debug)]
pub struct Operand<'a> {
    /// The buffer.
    pub buffer: &'a wgpu::Buffer,
    /// Element offset.
    pub offset: u32,
    /// Stored transposed.
    pub transposed: bool,
    /// Elements between consecutive stored rows; 0: packed (the stored row length). Honoured for
    /// A and C.
    pub stride: u32,
}

impl<'a> Operand<'a> {
    /// The matrix at `offset` of `buffer`, stored as used.
    #[must_use]
    pub fn new(buffer: &'a wgpu::Buffer, offset: usize) -> Self {
        Self { buffer, offset: offset as u32, transposed: false, stride: 0 }
    }
    /// The matrix at `offset` of `buffer`, stored transposed.
    #[must_use]
    pub fn t(buffer: &'a wgpu::Buffer, offset: usize) -> Self {
        Self { buffer, offset: offset as u32, transposed: true, stride: 0 }
    }
    /// The columns from `offset` of a wider row-major matrix whose rows are `stride` elements
    /// apart.
    #[must_use]
    pub fn strided(buffer: &'a wgpu::Buffer, offset: usize, stride: usize) -> Self {
        Self { buffer, offset: offset as u32, transposed: false, stride: stride as u32 }
    }
    /// [`strided`](Self::strided), used transposed.
    #[must_use]
    pub fn strided_t(buffer: &'a wgpu::Buffer, offset: usize, stride: usize) -> Self {
        Self { buffer, offset: offset as u32, transposed: true, stride: stride as u32 }
    }
}

/// The stored row stride of an operand whose packed stored rows would be `len` long.
fn ld(op: &Operand<'_>, len: usize) -> u32 {
    if op.stride == 0 { len as u32 } else { op.stride }
}

/// What happens after the product, in this order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Epilogue<'a> {
    /// Add to C instead of overwriting it.
    pub accumulate: bool,
    /// Add the bias at this element offset of B's buffer, per column.
    pub bias: Option<usize>,
    /// Then ReLU.
    pub relu: bool,
    /// Then zero every output whose entry of this m x n matrix (buffer, element offset) is not
    /// positive: the ReLU backward pass, with the layer's output as the mask.
    pub mask: Option<(&'a wgpu::Buffer, usize)>,
    /// Before the bias, add row `row / rows_per_group` of this matrix (buffer, element offset,
    /// rows_per_group): a per-ray term added to each of the ray's samples. Not with `mask`.
    pub per_group: Option<(&'a wgpu::Buffer, usize, usize)>,
}

impl<'a> Epilogue<'a> {
    /// The buffer, offset and rows per group bound at binding 4 (the mask or the per-group
    /// matrix; `fallback` when neither).
    fn extra(&self, fallback: &'a wgpu::Buffer) -> (&'a wgpu::Buffer, u32, u32) {
        debug_assert!(self.mask.is_none() || self.per_group.is_none(), "one of mask and per_group");
        match (self.mask, self.per_group) {
            (Some((b, off)), _) => (b, off as u32, 1),
            (None, Some((b, off, rows))) => (b, off as u32, rows.max(1) as u32),
            (None, None) => (fallback, 0, 1),
        }
    }
}

/// Which product entry point of `matmul.wgsl` runs. Both give the same sums in the same order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MatmulVariant {
    /// `tiled`: 64 x 64 output tiles per workgroup of 256 invocations, a 4 x 4 block of outputs
    /// in registers per invocation, k staged through workgroup memory: for hardware GPUs.
    Tiled,
    /// `blocked`: 4 x 4 outputs per invocation from storage: for software adapters, where
    /// workgroup memory and barriers are emulated per lane (measured 5-10x faster on lavapipe).
    Blocked,
}

impl MatmulVariant {
    /// The variant for `ctx`'s adapter: blocked on a software adapter, tiled on hardware.
    #[must_use]
    #[cfg(feature = "test-support")]
    pub fn for_adapter(ctx: &GpuContext) -> Self {
        if ctx.adapter().is_software { Self::Blocked } else { Self::Tiled }
    }

    /// Output rows (and columns) one workgroup covers.
    #[must_use]
    pub fn tile(self) -> usize {
        match self {
            Self::Tiled => 64,
            Self::Blocked => 32,
        }
    }
}

/// How a product is split over k: `splits` partial products of `k_chunk` entries each (the last
/// one shorter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SplitPlan {
    /// Entries of k per split, a multiple of 16.
    pub k_chunk: usize,
    /// Partial products.
    pub splits: usize,
}

/// Most partial products of one split product.
pub const MAX_SPLITS: usize = 64;
/// Fewest entries of k one split sums (shorter splits cost more in the second pass than they
/// gain).
pub const MIN_K_PER_SPLIT: usize = 256;

/// The compiled matmul pipelines of one variant.
#[derive(Debug)]
pub struct MatmulKernel {
    pipeline: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    variant: MatmulVariant,
    max_groups: u32,
    target_groups: usize,
}

impl MatmulKernel {
    /// Compiles the variant suited to the adapter ([`MatmulVariant::for_adapter`]).
    ///
    /// # Errors
    /// If the device rejects it.
    #[cfg(feature = "test-support")]
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Self::with_variant(ctx, MatmulVariant::for_adapter(ctx))
    }

    /// Compiles `variant`.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn with_variant(ctx: &GpuContext, variant: MatmulVariant) -> Result<Self, GpuError> {
        let entry = match variant {
            MatmulVariant::Tiled => "tiled",
            MatmulVariant::Blocked => "blocked",
        };
        // `tiled` writes all of its workgroup memory before reading it: no zero initialisation.
        let ([pipeline, reduce], layout) = kernels::build_entries_with(
            ctx,
            "matmul",
            SOURCE,
            &[true, true, false, true],
            [entry, "reduce_splits"],
            false,
        )?;
        // Enough workgroups in flight to fill a large GPU several times over; a software adapter
        // has a few cores, which the products' own tiles already fill.
        let target_groups = match variant {
            MatmulVariant::Tiled => 2048,
            MatmulVariant::Blocked => 256,
        };
        let max_groups = ctx.max_groups_per_dim().min(kernels::MAX_GROUPS_PER_DIM);
        Ok(Self { pipeline, reduce, layout, variant, max_groups, target_groups })
    }

    /// Caps the workgroups per dispatch dimension below the device's limit (tests use it to
    /// reach the grid-stride loops at small sizes).
    #[must_use]
    #[cfg(feature = "test-support")]
    pub fn with_max_groups_per_dim(mut self, groups: u32) -> Self {
        self.max_groups = groups.clamp(1, self.max_groups);
        self
    }

    /// How [`encode_split`](Self::encode_split) splits an `m x k x n` product with room for
    /// `scratch_len` floats of partials: enough splits to keep the device's workgroups busy,
    /// each at least [`MIN_K_PER_SPLIT`] long, at most [`MAX_SPLITS`]; one split (no split)
    /// when the output tiles alone are enough.
    #[must_use]
    pub fn split_plan(&self, (m, k, n): (usize, usize, usize), scratch_len: usize) -> SplitPlan {
        let t = self.variant.tile();
        let tiles = m.div_ceil(t) * n.div_ceil(t);
        let splits = (self.target_groups / tiles.max(1))
            .min(k / MIN_K_PER_SPLIT)
            .min(MAX_SPLITS)
            .min(scratch_len / (m * n).max(1))
            .max(1);
        if splits == 1 {
            return SplitPlan { k_chunk: k, splits: 1 };
        }
        let k_chunk = k.div_ceil(splits).next_multiple_of(16);
        SplitPlan { k_chunk, splits: k.div_ceil(k_chunk) }
    }

    fn flags(a: Operand<'_>, b: Operand<'_>, epi: &Epilogue<'_>) -> u32 {
        u32::from(a.transposed)
            | (u32::from(b.transposed) << 1)
            | (u32::from(epi.accumulate) << 2)
            | (u32::from(epi.bias.is_some()) << 3)
            | (u32::from(epi.relu) << 4)
            | (u32::from(epi.mask.is_some()) << 5)
            | (u32::from(epi.per_group.is_some()) << 7)
    }

    fn product_groups(&self, m: usize, n: usize, splits: usize) -> (u32, u32, u32) {
        let t = self.variant.tile();
        let cap = |tiles: usize| (tiles.max(1) as u32).min(self.max_groups);
        (cap(n.div_ceil(t)), cap(m.div_ceil(t)), splits as u32)
    }

    /// The uniform block of the unsplit product `c (+)= a · b` with `epi`, and the buffer bound
    /// at binding 4 (the epilogue's mask or per-group matrix, else `fallback`).
    fn params<'x>(
        (m, k, n): (usize, usize, usize),
        a: Operand<'x>,
        b: Operand<'_>,
        c: Operand<'_>,
        epi: &Epilogue<'x>,
        fallback: &'x wgpu::Buffer,
    ) -> (MatmulParams, &'x wgpu::Buffer) {
        let (extra, mask_off, rows_per_group) = epi.extra(fallback);
        let params = MatmulParams {
            m: m as u32,
            k: k as u32,
            n: n as u32,
            flags: Self::flags(a, b, epi),
            a_off: a.offset,
            b_off: b.offset,
            c_off: c.offset,
            bias_off: epi.bias.unwrap_or(0) as u32,
            k_chunk: k as u32,
            n_splits: 1,
            groups_x: 0,
            mask_off,
            rows_per_group,
            a_ld: ld(&a, if a.transposed { m } else { k }),
            c_ld: ld(&c, n),
            _pad: 0,
        };
        (params, extra)
    }

    /// Records `c (m x n) (+)= a (m x k) · b (k x n)` with `epi` (`job`'s). `c` must be another
    /// buffer than `a`, `b` and the mask.
    pub fn encode(&self, rec: &mut Recorder<'_>, job: Product<'_>) {
        let Product { shape: (m, k, n), a, b, c, epi } = job;
        let (params, extra) = Self::params((m, k, n), a, b, c, &epi, a.buffer);
        let groups = self.product_groups(m, n, 1);
        rec.dispatch("matmul", &self.pipeline, &self.layout, &params, &[a.buffer, b.buffer, c.buffer, extra], groups);
    }

    /// [`encode`](Self::encode), split over k as [`split_plan`](Self::split_plan) says: the
    /// partial products go to `scratch` (`scratch_len` floats, another buffer than the
    /// operands), then a second pass adds them in order into `c` with the epilogue. For products
    /// with few outputs and a long k: the weight gradients.
    pub fn encode_split(&self, rec: &mut Recorder<'_>, job: Product<'_>, scratch: &wgpu::Buffer, scratch_len: usize) {
        let Product { shape: (m, k, n), a, b, c, epi } = job;
        let plan = self.split_plan((m, k, n), scratch_len);
        if plan.splits == 1 {
            self.encode(rec, job);
            return;
        }
        let (whole, extra) = Self::params((m, k, n), a, b, c, &epi, scratch);
        let (k_chunk, n_splits) = (plan.k_chunk as u32, plan.splits as u32);
        // First pass: split z's raw sums into scratch (only the operands' layout flags).
        let partial = MatmulParams {
            flags: (whole.flags & 3) | 64,
            c_off: 0,
            bias_off: 0,
            k_chunk,
            n_splits,
            mask_off: 0,
            rows_per_group: 1,
            c_ld: n as u32,
            ..whole
        };
        let groups = self.product_groups(m, n, plan.splits);
        let bufs = [a.buffer, b.buffer, scratch, a.buffer];
        rec.dispatch("matmul split", &self.pipeline, &self.layout, &partial, &bufs, groups);
        // Second pass: the partials (packed m x n matrices in scratch) added in order, then the
        // epilogue.
        // m * n is a layer's weight count: far inside one dispatch.
        let (gx, gy) = kernels::dispatch_grid((m * n) as u64, kernels::WORKGROUP).unwrap_or((1, 1));
        let reduce = MatmulParams {
            flags: whole.flags & !3,
            a_off: 0,
            k_chunk,
            n_splits,
            groups_x: gx,
            a_ld: k as u32,
            ..whole
        };
        let bufs = [scratch, b.buffer, c.buffer, extra];
        rec.dispatch("matmul reduce", &self.reduce, &self.layout, &reduce, &bufs, (gx, gy, 1));
    }
}

super::wgsl_struct!(
    MatmulParams,
    "Params",
    [
        m,
        k,
        n,
        flags,
        a_off,
        b_off,
        c_off,
        bias_off,
        k_chunk,
        n_splits,
        groups_x,
        mask_off,
        rows_per_group,
        a_ld,
        c_ld,
        _pad
    ]
);
