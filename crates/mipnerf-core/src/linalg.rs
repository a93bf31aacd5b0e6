//! Dense matrix products through the `gemm` crate's f32 kernels (`gemm-f32`), behind a safe,
//! bounds-checked interface.
//!
//! All matrices are row-major and contiguous. The products run single-threaded: the training step
//! parallelises over independent chunks of rays instead, which keeps every result independent of
//! the thread count (bit-for-bit reproducible runs).
#![allow(unsafe_code)]

/// How an operand is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// As the product uses it: `rows x cols` row-major.
    Normal,
    /// Transposed: stored `cols x rows` row-major, used as its transpose.
    Transposed,
}

/// The element count of a `rows x cols` matrix, checked: every size an `unsafe` block's bounds
/// rest on is computed here, so that sizes whose product overflows are a panic, never a wrapped
/// count that a short slice would pass.
///
/// # Panics
/// If `rows * cols` overflows `usize`.
#[must_use]
pub fn checked_len(rows: usize, cols: usize) -> usize {
    rows.checked_mul(cols).unwrap_or_else(|| panic!("a {rows} x {cols} matrix has more elements than usize holds"))
}

/// The shape of a product `c (m x n) = [c +] a (m x k) · b (k x n)`, and whether it adds to `c`
/// (`accumulate`) or overwrites it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Product {
    /// Rows of `a` and `c`.
    pub m: usize,
    /// Columns of `a`, rows of `b`.
    pub k: usize,
    /// Columns of `b` and `c`.
    pub n: usize,
    /// Add to `c` rather than overwrite it.
    pub accumulate: bool,
}

impl Product {
    /// `m x k · k x n`, added to `c` when `accumulate`.
    #[must_use]
    pub const fn of(m: usize, k: usize, n: usize, accumulate: bool) -> Self {
        Self { m, k, n, accumulate }
    }
}

/// `c (m x n) = [c +] a (m x k) · b (k x n)` for `p`'s shape, with `a` and `b` stored as `la`
/// and `lb` say, and `c` overwritten or added to (`p.accumulate`).
///
/// # Panics
/// If a slice is shorter than its shape needs, or a size product overflows ([`checked_len`]).
pub fn matmul(c: &mut [f32], a: &[f32], la: Layout, b: &[f32], lb: Layout, p: Product) {
    let Product { m, k, n, accumulate } = p;
    assert!(c.len() >= checked_len(m, n), "matmul: c has {} < {m}x{n}", c.len());
    assert!(a.len() >= checked_len(m, k), "matmul: a has {} < {m}x{k}", a.len());
    assert!(b.len() >= checked_len(k, n), "matmul: b has {} < {k}x{n}", b.len());
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            c[..m * n].fill(0.0);
        }
        return;
    }
    // (row stride, column stride) of each operand as the product sees it.
    let (a_rs, a_cs) = match la {
        Layout::Normal => (k as isize, 1),
        Layout::Transposed => (1, m as isize),
    };
    let (b_rs, b_cs) = match lb {
        Layout::Normal => (n as isize, 1),
        Layout::Transposed => (1, k as isize),
    };
    // gemm's f32 kernels prefer a column-major destination, and `c` is row-major: where its rows
    // are longer than one element the product is computed as its transpose, `cᵀ = bᵀ · aᵀ`, the
    // operands swapped and each stride pair read the other way round. This is what the `gemm`
    // crate's dispatcher does before it calls these same kernels (the only ones this product
    // needs), so the sums run in the same order.
    let (c_ptr, a_ptr, b_ptr) = (c.as_mut_ptr(), a.as_ptr(), b.as_ptr());
    #[rustfmt::skip]
    let (rows, cols, c_cs, c_rs, lhs, lhs_cs, lhs_rs, rhs, rhs_cs, rhs_rs) = if n > 1 {
        (n, m, n as isize, 1, b_ptr, b_rs, b_cs, a_ptr, a_rs, a_cs)
    } else {
        (m, n, 1, n as isize, a_ptr, a_cs, a_rs, b_ptr, b_cs, b_rs)
    };
    // SAFETY: the asserts above guarantee that every element addressed through these strides lies
    // inside the slices: a reads rows < m and columns < k of an m*k (or k*m) block, b likewise, and
    // c writes an m*n block (transposing swaps which operand is which, not what is addressed).
    // `c` is exclusively borrowed and does not alias `a` or `b`. Every stride is positive.
    unsafe {
        gemm_f32::gemm::f32::get_gemm_fn()(
            rows,
            cols,
            k,
            c_ptr,
            c_cs,
            c_rs,
            accumulate,
            lhs,
            lhs_cs,
            lhs_rs,
            rhs,
            rhs_cs,
            rhs_rs,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm_common::Parallelism::None,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sizes whose products overflow `usize` would wrap to small counts that empty slices pass,
    /// and `gemm` would then read far out of bounds: they panic before any `unsafe` code.
    #[test]
    fn sizes_whose_product_overflows_panic_before_the_product() {
        for (m, k, n) in [(1usize << 60, 1 << 4, 1), (1, 1 << 60, 1 << 4), (1 << 33, 1, 1 << 33)] {
            let caught = std::panic::catch_unwind(|| {
                let mut c = Vec::new();
                matmul(&mut c, &[], Layout::Normal, &[], Layout::Normal, Product { m, k, n, accumulate: false });
            });
            let message = caught.expect_err("an overflowing shape must panic");
            let text = message.downcast_ref::<String>().cloned().unwrap_or_default();
            assert!(text.contains("matrix") || text.contains("matmul"), "{m}x{k}x{n}: {text}");
        }
    }

    fn naive(a: &[f32], la: Layout, b: &[f32], lb: Layout, m: usize, k: usize, n: usize) -> Vec<f32> {
        let at = |i: usize, p: usize| {
            if la == Layout::Normal { a[i * k + p] } else { a[p * m + i] }
        };
        let bt = |p: usize, j: usize| {
            if lb == Layout::Normal { b[p * n + j] } else { b[j * k + p] }
        };
        (0..m * n).map(|ij| (0..k).map(|p| at(ij / n, p) * bt(p, ij % n)).sum()).collect()
    }

    #[test]
    fn matches_a_naive_product_for_every_layout() {
        // One column (`n == 1`: the density head's product, which gemm runs untransposed), one
        // row, and a general shape (run as its transpose).
        for (m, k, n) in [(37, 19, 23), (37, 19, 1), (1, 19, 23)] {
            let a: Vec<f32> = (0..m * k).map(|i| ((i * 7 % 13) as f32 - 6.0) / 5.0).collect();
            let b: Vec<f32> = (0..k * n).map(|i| ((i * 5 % 11) as f32 - 5.0) / 3.0).collect();
            for la in [Layout::Normal, Layout::Transposed] {
                for lb in [Layout::Normal, Layout::Transposed] {
                    let want = naive(&a, la, &b, lb, m, k, n);
                    let mut c = vec![1.0; m * n];
                    matmul(&mut c, &a, la, &b, lb, Product { m, k, n, accumulate: false });
                    for (g, w) in c.iter().zip(&want) {
                        assert!((g - w).abs() < 1e-4, "{m}x{k}x{n} {la:?} {lb:?}: {g} vs {w}");
                    }
                    matmul(&mut c, &a, la, &b, lb, Product { m, k, n, accumulate: true });
                    for (g, w) in c.iter().zip(&want) {
                        assert!((g - 2.0 * w).abs() < 2e-4, "accumulate {m}x{k}x{n} {la:?} {lb:?}");
                    }
                }
            }
        }
    }
}
