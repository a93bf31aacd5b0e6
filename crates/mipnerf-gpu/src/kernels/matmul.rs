//! `shaders/matmul.wgsl`: matrix products with an optional bias and ReLU epilogue, tiled through
//! workgroup memory (hardware GPUs) or register-blocked (software adapters).

use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: &str = include_str!("../../../../shaders/matmul.wgsl");

/// The uniform block of `matmul.wgsl` (`struct Params`), 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MatmulParams {
    /// Rows of C.
    pub m: u32,
    /// Inner dimension.
    pub k: u32,
    /// Columns of C.
    pub n: u32,
    /// Bit 0: A transposed; 1: B transposed; 2: accumulate; 3: add bias; 4: ReLU.
    pub flags: u32,
    /// Element offset of A in its buffer.
    pub a_off: u32,
    /// Element offset of B in its buffer.
    pub b_off: u32,
    /// Element offset of C in its buffer.
    pub c_off: u32,
    /// Element offset of the bias in B's buffer.
    pub bias_off: u32,
}

/// One operand: a buffer, the element offset of the matrix in it, and whether it is stored
/// transposed.
#[derive(Clone, Copy, Debug)]
pub struct Operand<'a> {
    /// The buffer.
    pub buffer: &'a wgpu::Buffer,
    /// Element offset.
    pub offset: u32,
    /// Stored transposed.
    pub transposed: bool,
}

impl<'a> Operand<'a> {
    /// The matrix at `offset` of `buffer`, stored as used.
    #[must_use]
    pub fn new(buffer: &'a wgpu::Buffer, offset: usize) -> Self {
        Self { buffer, offset: offset as u32, transposed: false }
    }
    /// The matrix at `offset` of `buffer`, stored transposed.
    #[must_use]
    pub fn t(buffer: &'a wgpu::Buffer, offset: usize) -> Self {
        Self { buffer, offset: offset as u32, transposed: true }
    }
}

/// What happens after the product.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Epilogue {
    /// Add to C instead of overwriting it.
    pub accumulate: bool,
    /// Add the bias at this element offset of B's buffer, per column.
    pub bias: Option<usize>,
    /// Then ReLU.
    pub relu: bool,
}

/// Which entry point of `matmul.wgsl` runs. Both give the same sums in the same order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MatmulVariant {
    /// 16 x 16 tiles through workgroup memory (`main`): for hardware GPUs.
    Tiled,
    /// 4 x 4 outputs per invocation from storage (`blocked`): for software adapters, where
    /// workgroup memory and barriers are emulated per lane (measured 5-10x faster on lavapipe).
    Blocked,
}

impl MatmulVariant {
    /// The variant for `ctx`'s adapter: blocked on a software adapter, tiled on hardware.
    #[must_use]
    pub fn for_adapter(ctx: &GpuContext) -> Self {
        if ctx.adapter.is_software { Self::Blocked } else { Self::Tiled }
    }
}

/// The compiled matmul pipeline of one variant.
#[derive(Debug)]
pub struct MatmulKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    variant: MatmulVariant,
}

impl MatmulKernel {
    /// Compiles the variant suited to the adapter ([`MatmulVariant::for_adapter`]).
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Self::with_variant(ctx, MatmulVariant::for_adapter(ctx))
    }

    /// Compiles `variant`.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn with_variant(ctx: &GpuContext, variant: MatmulVariant) -> Result<Self, GpuError> {
        let entry = match variant {
            MatmulVariant::Tiled => "main",
            MatmulVariant::Blocked => "blocked",
        };
        let ([pipeline], layout) = kernels::build_entries(ctx, "matmul", SOURCE, &[true, true, false], [entry])?;
        Ok(Self { pipeline, layout, variant })
    }

    /// The variant this kernel runs.
    #[must_use]
    pub fn variant(&self) -> MatmulVariant {
        self.variant
    }

    /// Records `c (m x n) (+)= a (m x k) · b (k x n)` with `epi` into `enc`. `c` must be another
    /// buffer than `a` and `b`.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        (m, k, n): (usize, usize, usize),
        a: Operand<'_>,
        b: Operand<'_>,
        c: Operand<'_>,
        epi: Epilogue,
    ) {
        let flags = u32::from(a.transposed)
            | (u32::from(b.transposed) << 1)
            | (u32::from(epi.accumulate) << 2)
            | (u32::from(epi.bias.is_some()) << 3)
            | (u32::from(epi.relu) << 4);
        let params = MatmulParams {
            m: m as u32,
            k: k as u32,
            n: n as u32,
            flags,
            a_off: a.offset,
            b_off: b.offset,
            c_off: c.offset,
            bias_off: epi.bias.unwrap_or(0) as u32,
        };
        let outputs_per_group = match self.variant {
            MatmulVariant::Tiled => 16,
            MatmulVariant::Blocked => 32,
        };
        let groups = ((n as u32).div_ceil(outputs_per_group), (m as u32).div_ceil(outputs_per_group), 1);
        kernels::dispatch(
            ctx,
            enc,
            "matmul",
            &self.pipeline,
            &self.layout,
            &params,
            &[a.buffer, b.buffer, c.buffer],
            groups,
        );
    }
}

super::wgsl_struct!(MatmulParams, "Params", [m, k, n, flags, a_off, b_off, c_off, bias_off]);
