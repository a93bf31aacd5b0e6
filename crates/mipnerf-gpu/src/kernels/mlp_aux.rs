//! `shaders/mlp_aux.wgsl`: column sums (bias gradients) and per-ray sums of per-sample rows.
//!
//! CPU reference: [`mipnerf_core::mlp::MlpShape::forward`] and [`mipnerf_core::mlp::MlpShape::backward`].

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of these kernels.
pub const SOURCE: super::Shader = super::shader!("mlp_aux.wgsl", [AuxParams]);

/// The uniform block of `mlp_aux.wgsl` (`struct Params`), 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AuxParams {
    /// Rows.
    pub rows: u32,
    /// Columns.
    pub cols: u32,
    /// Rows per group (`group_sums`: samples per ray).
    pub count: u32,
    /// Offset of x.
    pub x_off: u32,
    /// Unused (alignment with other kernels' blocks).
    pub y_off: u32,
    /// Offset of out.
    pub out_off: u32,
    /// `col_sums`: 1 to add to `out`, 0 to overwrite it.
    pub accumulate: u32,
    /// Workgroups along x of the dispatch grid.
    pub groups_x: u32,
}

/// The shape of [`MlpAuxKernels::col_sums`]: `rows x cols` summed down the rows, added to the
/// output (`accumulate`) or written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ColSums {
    /// Rows summed.
    pub rows: usize,
    /// Columns (sums).
    pub cols: usize,
    /// Add to the output rather than overwrite it.
    pub accumulate: bool,
}

/// The three pipelines of `mlp_aux.wgsl`.
#[derive(Debug)]
pub struct MlpAuxKernels {
    col_sums: wgpu::ComputePipeline,
    col_sums_partial: wgpu::ComputePipeline,
    group_sums: wgpu::ComputePipeline,
    pack_heads: wgpu::ComputePipeline,
    unpack_heads_add: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl MlpAuxKernels {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let entries = ["col_sums", "col_sums_partial", "group_sums", "pack_heads", "unpack_heads_add"];
        let ([col_sums, col_sums_partial, group_sums, pack_heads, unpack_heads_add], layout) =
            kernels::build_entries(ctx, "mlp_aux", SOURCE, &[true, false], entries)?;
        Ok(Self { col_sums, col_sums_partial, group_sums, pack_heads, unpack_heads_add, layout })
    }

    fn run(
        &self,
        rec: &mut Recorder<'_>,
        which: &wgpu::ComputePipeline,
        items: usize,
        mut params: AuxParams,
        x: &wgpu::Buffer,
        out: &wgpu::Buffer,
    ) {
        // Sizes are validated by the callers (they come from the model's shape).
        let (gx, gy) = kernels::dispatch_grid(items as u64, kernels::WORKGROUP).unwrap_or((1, 1));
        params.groups_x = gx;
        rec.dispatch("mlp_aux", which, &self.layout, &params, &[x, out], (gx, gy, 1));
    }

    /// Rows summed per block by the first pass of [`col_sums`](Self::col_sums).
    pub const BLOCK_ROWS: usize = 256;

    /// Floats of scratch [`col_sums`](Self::col_sums) needs for `rows x cols`.
    #[must_use]
    pub fn col_sums_scratch_len(rows: usize, cols: usize) -> usize {
        rows.div_ceil(Self::BLOCK_ROWS) * cols
    }

    /// `out[col] (+)= sum over rows of x[row, col]` for `sums`' shape, `x` and `out` at their
    /// element offsets, in a fixed order: for more than [`BLOCK_ROWS`](Self::BLOCK_ROWS) rows,
    /// blocks of rows are summed first (into `scratch`,
    /// [`col_sums_scratch_len`](Self::col_sums_scratch_len) floats), then the blocks.
    pub fn col_sums(
        &self,
        rec: &mut Recorder<'_>,
        x: (&wgpu::Buffer, usize),
        out: (&wgpu::Buffer, usize),
        sums: ColSums,
        scratch: &wgpu::Buffer,
    ) {
        let ColSums { rows, cols, accumulate } = sums;
        let (x, rows) = if rows > Self::BLOCK_ROWS {
            let params = AuxParams {
                rows: rows as u32,
                cols: cols as u32,
                x_off: x.1 as u32,
                out_off: 0,
                ..AuxParams::default()
            };
            let items = Self::col_sums_scratch_len(rows, cols);
            self.run(rec, &self.col_sums_partial, items, params, x.0, scratch);
            ((scratch, 0), rows.div_ceil(Self::BLOCK_ROWS))
        } else {
            (x, rows)
        };
        let params = AuxParams {
            rows: rows as u32,
            cols: cols as u32,
            x_off: x.1 as u32,
            out_off: out.1 as u32,
            accumulate: u32::from(accumulate),
            ..AuxParams::default()
        };
        self.run(rec, &self.col_sums, cols, params, x.0, out.0);
    }

    /// `out[r, :] = sum over i < rep of x[r * rep + i, :]`, in order, for `rows` groups of `rep`
    /// rows of `cols`.
    pub fn group_sums(
        &self,
        rec: &mut Recorder<'_>,
        x: &wgpu::Buffer,
        out: &wgpu::Buffer,
        rows: usize,
        cols: usize,
        rep: usize,
    ) {
        let params = AuxParams { rows: rows as u32, cols: cols as u32, count: rep as u32, ..AuxParams::default() };
        self.run(rec, &self.group_sums, rows * cols, params, x, out);
    }
}

/// The density layer (`rows x 1` at `density` of the parameters, bias last) and the bottleneck
/// layer (`rows x cols` at `bottleneck`), packed side by side as one `rows x (cols + 1)` matrix
/// `[density | bottleneck]` so that both heads run as one product.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Heads {
    /// The density layer's offset in the parameters.
    pub density: usize,
    /// The bottleneck layer's offset in the parameters.
    pub bottleneck: usize,
    /// The layers' inputs plus one (the bias row).
    pub rows: usize,
    /// The bottleneck layer's outputs.
    pub cols: usize,
}

impl Heads {
    /// The uniform block's shape and the bottleneck's offset; the density's offset is set by
    /// the direction of the copy.
    fn params(self) -> AuxParams {
        AuxParams {
            rows: self.rows as u32,
            cols: self.cols as u32,
            y_off: self.bottleneck as u32,
            ..AuxParams::default()
        }
    }
}

impl MlpAuxKernels {
    /// Packs the two `heads` layers of `params` into `out`.
    pub fn pack_heads(&self, rec: &mut Recorder<'_>, params: &wgpu::Buffer, heads: Heads, out: &wgpu::Buffer) {
        let p = AuxParams { x_off: heads.density as u32, ..heads.params() };
        self.run(rec, &self.pack_heads, heads.rows * (heads.cols + 1), p, params, out);
    }

    /// Adds the packed heads' gradient `packed` to the density layer's gradient and the
    /// bottleneck layer's in `grads`.
    pub fn unpack_heads_add(&self, rec: &mut Recorder<'_>, packed: &wgpu::Buffer, grads: &wgpu::Buffer, heads: Heads) {
        let p = AuxParams { out_off: heads.density as u32, ..heads.params() };
        self.run(rec, &self.unpack_heads_add, heads.rows * (heads.cols + 1), p, packed, grads);
    }
}

super::wgsl_struct!(AuxParams, "Params", [rows, cols, count, x_off, y_off, out_off, accumulate, groups_x]);
