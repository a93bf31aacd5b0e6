//! Operands rounded to bf16 once and read by several products.
//!
//! In the MLP each activation is the left operand of the next layer's forward product and,
//! transposed, of its weight gradient; each gradient `dz` is the left operand of the input
//! gradient and the right operand of the weight gradient. [`matmul_bf16`](super::matmul_bf16)
//! packs both operands of every product, so each of these matrices would be read in f32,
//! rounded and packed twice. A [`Bf16Matrix`] is packed once, in one pass, in every layout
//! its products read ([`Reads`]), and [`matmul_bf16`](super::matmul_bf16) reads it.
//! The values are the same bits either way: packing is rounding, the same rounding.

use std::ops::Range;

use super::{BLOCK, Bf16Kernel, Bf16Support, K_STEP, Layout, Lines};

/// Rows per block of [`Bf16Matrix::pack_after`]: whole pair rows and whole 32-row blocks of the
/// packings, and few enough that a block (32 KiB of a 256-wide f32 matrix) is still in the
/// cache when it is packed.
pub const PACK_BLOCK_ROWS: usize = 32;
const _: () = assert!(PACK_BLOCK_ROWS.is_multiple_of(32) && BLOCK == K_STEP, "blocks of whole pair rows and tiles");

/// The roles in which products read a [`Bf16Matrix`] `x` (`rows x cols`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Reads {
    /// `x` as the left operand `a` (`m = rows`, `k = cols`): an activation in the next layer's
    /// forward product, a gradient in the input gradient.
    pub left: bool,
    /// `xᵀ` as the left operand (`x` given with [`Layout::Transposed`], `m = cols`,
    /// `k = rows`): an activation in a weight gradient.
    pub left_transposed: bool,
    /// `x` as the right operand `b` (`k = rows`, `n = cols`): a gradient in a weight gradient.
    pub right: bool,
}

/// A row-major f32 matrix rounded to bf16 and packed in the layouts of the products that read
/// it ([`Reads`]), for one [`Bf16Kernel`]. Its buffers are kept and reused by the next
/// [`pack`](Self::pack).
#[derive(Clone, Debug, Default)]
pub struct Bf16Matrix {
    rows: usize,
    cols: usize,
    reads: Reads,
    kernel: Option<Bf16Kernel>,
    /// `x` as the left operand: the kernels' tiles (`rows` padded to 32 x `cols` padded to 32).
    tiles: Lines<u16>,
    /// `x` in pairs along its rows (`rows / 2` padded x `cols` padded): the right operand, and
    /// the AVX-512 kernel's transposed left operand.
    pairs: Lines<u32>,
    /// `xᵀ` as the AMX kernel's left operand (tiles of the transpose).
    tiles_transposed: Lines<u16>,
}

impl Bf16Matrix {
    /// Packs `x` (`rows x cols`, row-major) for the kernel [`Bf16Support::detect`] chose, in
    /// the layouts `reads` needs, reading and rounding each value once.
    ///
    /// # Panics
    /// If `x` is shorter than `rows x cols`, or if the CPU has no bf16 kernel.
    pub fn pack(&mut self, x: &[f32], rows: usize, cols: usize, reads: Reads) {
        let kernel = Bf16Support::detect().kernel();
        let kernel = kernel.unwrap_or_else(|| panic!("Bf16Matrix::pack without a bf16 kernel"));
        self.pack_for(kernel, x, rows, cols, reads);
    }

    /// [`pack`](Self::pack) for the given kernel, for products on
    /// [`matmul_bf16`](super::matmul_bf16).
    ///
    /// # Panics
    /// If `x` is shorter than `rows x cols`, or if the CPU cannot run `kernel`.
    pub fn pack_for(&mut self, kernel: Bf16Kernel, x: &[f32], rows: usize, cols: usize, reads: Reads) {
        self.begin(kernel, rows, cols, reads);
        self.convert(x, 0..rows);
    }

    /// Lets `prepare` finish `x` (`rows x cols`, row-major) block after block of
    /// [`PACK_BLOCK_ROWS`] rows (called with the block's values and its rows), and packs each
    /// block as [`pack`](Self::pack) does right after, while it is still in the cache: one
    /// pass over `x` where a pass that writes it (a bias and activation, say) and the packing
    /// would be two.
    ///
    /// # Panics
    /// If `x` is shorter than `rows x cols`, or if the CPU has no bf16 kernel.
    pub fn pack_after(
        &mut self,
        x: &mut [f32],
        rows: usize,
        cols: usize,
        reads: Reads,
        mut prepare: impl FnMut(&mut [f32], Range<usize>),
    ) {
        let kernel = Bf16Support::detect().kernel();
        let kernel = kernel.unwrap_or_else(|| panic!("Bf16Matrix::pack_after without a bf16 kernel"));
        assert!(x.len() >= crate::linalg::checked_len(rows, cols), "Bf16Matrix::pack_after: x is short");
        self.begin(kernel, rows, cols, reads);
        for r0 in (0..rows).step_by(PACK_BLOCK_ROWS) {
            let r1 = (r0 + PACK_BLOCK_ROWS).min(rows);
            prepare(&mut x[r0 * cols..r1 * cols], r0..r1);
            self.convert(x, r0..r1);
        }
    }

    /// Sets the shape, roles and kernel, and sizes the buffers, their padding zeroed.
    fn begin(&mut self, kernel: Bf16Kernel, rows: usize, cols: usize, reads: Reads) {
        if let Err(why) = kernel.check() {
            panic!("Bf16Matrix on {}: {why}", kernel.name());
        }
        (self.rows, self.cols, self.reads, self.kernel) = (rows, cols, reads, Some(kernel));
        #[cfg(target_arch = "x86_64")]
        super::simd::prepare(&mut self.targets(), rows, cols);
    }

    /// Rounds and packs rows `range` of `x` ([`super::simd::convert`]'s ranges).
    fn convert(&mut self, x: &[f32], range: Range<usize>) {
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("no bf16 kernel passes its check off x86_64: {x:?} {range:?}");
        #[cfg(target_arch = "x86_64")]
        {
            let (rows, cols) = (self.rows, self.cols);
            super::simd::convert(&mut self.targets(), x, rows, cols, range);
        }
    }

    /// The buffers this matrix's roles need on its kernel, with their padded sizes (rows and
    /// columns padded to whole blocks, as the products pad their operands): tiles for `left`,
    /// pairs for `right` and for the AVX-512 kernel's `left_transposed`, AMX's tiles of the
    /// transpose for its `left_transposed`.
    #[cfg(target_arch = "x86_64")]
    fn targets(&mut self) -> super::simd::Targets<'_> {
        let (rows_p, cols_p) = (self.rows.next_multiple_of(BLOCK), self.cols.next_multiple_of(BLOCK));
        let amx = self.kernel == Some(Bf16Kernel::Amx);
        let r = self.reads;
        super::simd::Targets {
            tiles: r.left.then_some((&mut self.tiles, rows_p, cols_p)),
            pairs: (r.right || r.left_transposed && !amx).then_some((&mut self.pairs, rows_p, cols_p)),
            transposed: (r.left_transposed && amx).then_some((&mut self.tiles_transposed, cols_p, rows_p)),
        }
    }

    /// Rows of the packed matrix.
    #[must_use]
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Columns of the packed matrix.
    #[must_use]
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// The packing of `x` as the left operand `a (m x k)` of a product on `kernel` with this
    /// layout: tiles for [`Layout::Normal`]; for [`Layout::Transposed`], AMX's tiles of the
    /// transpose or the AVX-512 kernel's pairs.
    ///
    /// # Panics
    /// If the shape, the kernel or the layouts packed do not match: a caller's error.
    pub(super) fn left(&self, kernel: Bf16Kernel, layout: Layout, m: usize, k: usize) -> PackedLeft<'_> {
        self.assert_packed_for(kernel, "left");
        match layout {
            Layout::Normal => {
                assert!(self.reads.left && (self.rows, self.cols) == (m, k), "{self:?} read as a {m}x{k} left operand");
                PackedLeft::Tiles(&self.tiles)
            }
            Layout::Transposed => {
                assert!(
                    self.reads.left_transposed && (self.rows, self.cols) == (k, m),
                    "{self:?} read transposed as a {m}x{k} left operand"
                );
                match kernel {
                    Bf16Kernel::Amx => PackedLeft::Tiles(&self.tiles_transposed),
                    Bf16Kernel::Avx512 => PackedLeft::Pairs(&self.pairs),
                }
            }
        }
    }

    /// The packing of `x` as the right operand `b (k x n)`, stored `k x n`.
    ///
    /// # Panics
    /// If the shape, the kernel or the layouts packed do not match: a caller's error.
    pub(super) fn right(&self, kernel: Bf16Kernel, k: usize, n: usize) -> &[u32] {
        self.assert_packed_for(kernel, "right");
        assert!(self.reads.right && (self.rows, self.cols) == (k, n), "{self:?} read as a {k}x{n} right operand");
        &self.pairs
    }

    fn assert_packed_for(&self, kernel: Bf16Kernel, role: &str) {
        assert_eq!(
            self.kernel,
            Some(kernel),
            "a matrix packed for {:?} read as a {role} operand on {kernel:?}",
            self.kernel
        );
    }
}

/// A packed left operand `a (m x k)`, in one of two orders; the AVX-512 kernel reads the pair
/// of k values `(2q, 2q + 1)` of a row from either, the AMX kernel only tiles.
pub(super) enum PackedLeft<'a> {
    /// [`super::a_index`]'s tiles (the AMX kernel's), from `a` stored `m x k`, or, for AMX,
    /// from `a` stored `k x m` through a transpose: a row's pairs are contiguous.
    Tiles(&'a [u16]),
    /// [`super::b_index`]'s order with `a`'s rows as the columns, from `a` stored `k x m`
    /// (packed without a transpose): the pairs of 16 rows at one `q` are contiguous.
    Pairs(&'a [u32]),
}

/// One operand of [`matmul_bf16`](super::matmul_bf16): its f32 values and layout as
/// [`matmul_bf16`](super::matmul_bf16) takes them, and, if it was packed before, its packing,
/// which the product then reads instead of packing the values. The values are still read where
/// the product runs in f32 (shapes below [`super::MIN_BF16_DIM`]).
#[derive(Clone, Copy, Debug)]
pub struct Operand<'a> {
    /// The values, as [`matmul`](crate::linalg::matmul) reads them.
    pub values: &'a [f32],
    /// How `values` are stored.
    pub layout: Layout,
    /// The same values packed ([`Bf16Matrix::pack`]), for the role this operand plays.
    pub packed: Option<&'a Bf16Matrix>,
}

impl<'a> Operand<'a> {
    /// An operand the product packs itself.
    #[must_use]
    pub fn f32(values: &'a [f32], layout: Layout) -> Self {
        Self { values, layout, packed: None }
    }
}
