//! Operands rounded to bf16 once and read by several products.
//!
//! In the MLP each activation is the left operand of the next layer's forward product and,
//! transposed, of its weight gradient; each gradient `dz` is the left operand of the input
//! gradient and the right operand of the weight gradient. [`matmul_bf16`](super::matmul_bf16)
//! packs both operands of every product, so each of these matrices would be read in f32,
//! rounded and packed twice. A [`Bf16Matrix`] is packed once, in one pass, in every layout
//! its products read ([`Reads`]), and [`matmul_bf16_with`](super::matmul_bf16_with) reads it.
//! The values are the same bits either way: packing is rounding, the same rounding.

use super::{BLOCK, Bf16Kernel, Bf16Support, K_STEP, Layout};

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
    tiles: Vec<u16>,
    /// `x` in pairs along its rows (`rows / 2` padded x `cols` padded): the right operand, and
    /// the AVX-512 kernel's transposed left operand.
    pairs: Vec<u32>,
    /// `xᵀ` as the AMX kernel's left operand (tiles of the transpose).
    tiles_transposed: Vec<u16>,
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
    /// [`matmul_bf16_with_on`](super::matmul_bf16_with_on).
    ///
    /// # Panics
    /// If `x` is shorter than `rows x cols`, or if the CPU cannot run `kernel`.
    pub fn pack_for(&mut self, kernel: Bf16Kernel, x: &[f32], rows: usize, cols: usize, reads: Reads) {
        if let Err(why) = kernel.check() {
            panic!("Bf16Matrix::pack_for on {}: {why}", kernel.name());
        }
        *self = Self { rows, cols, reads, kernel: Some(kernel), ..std::mem::take(self) };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("no bf16 kernel passes its check off x86_64");
        #[cfg(target_arch = "x86_64")]
        {
            let (rows_p, cols_p) = (rows.next_multiple_of(BLOCK), cols.next_multiple_of(K_STEP));
            let pairs_for_left_transposed = reads.left_transposed && kernel == Bf16Kernel::Avx512;
            let tiles = reads.left.then_some((&mut self.tiles, rows_p, cols_p));
            if reads.left_transposed && kernel == Bf16Kernel::Amx {
                // The transpose (m = cols, k = rows) in AMX's tiles, with `x`'s own tiles from
                // the same rounding; the pairs, if read, in a second pass.
                let (mp, kp) = (cols.next_multiple_of(BLOCK), rows.next_multiple_of(K_STEP));
                super::simd::pack_transposed_rows(&mut self.tiles_transposed, tiles, x, cols, rows, mp, kp);
                if reads.right {
                    let np = cols.next_multiple_of(BLOCK);
                    super::simd::pack_rows_and_pairs(None, Some((&mut self.pairs, kp, np)), x, rows, cols);
                }
            } else {
                let (kp, np) = (rows.next_multiple_of(K_STEP), cols.next_multiple_of(BLOCK));
                let pairs = (reads.right || pairs_for_left_transposed).then_some((&mut self.pairs, kp, np));
                super::simd::pack_rows_and_pairs(tiles, pairs, x, rows, cols);
            }
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

/// One operand of [`matmul_bf16_with`](super::matmul_bf16_with): its f32 values and layout as
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
