use std::arch::x86_64::{
    __m512i, _mm256_storeu_si256, _mm512_castsi512_si256, _mm512_cvtne2ps_pbh, _mm512_extracti64x4_epi64,
    _mm512_loadu_ps, _mm512_permutexvar_epi16, _mm512_set_epi16, _mm512_setzero_ps, _mm512_setzero_si512,
    _mm512_shuffle_i32x4, _mm512_storeu_si512, _mm512_unpackhi_epi32, _mm512_unpackhi_epi64, _mm512_unpacklo_epi32,
    _mm512_unpacklo_epi64,
};

use super::{Layout, Lines, a_index, b_index, f32_to_bf16_bits, grow};

const FEATURES_CHECKED: &str = "bf16 packing needs AVX-512 BF16 (checked by Bf16Kernel::check)";

/// [`super::pack_rows`], vectorised.
pub(super) fn pack_rows(out: &mut Lines<u16>, a: &[f32], la: Layout, m: usize, k: usize, mp: usize, kp: usize) {
    match la {
        Layout::Normal => pack(Targets { tiles: Some((out, mp, kp)), ..Targets::default() }, a, m, k),
        // `a` is stored `k x m`: the transpose of what is stored.
        Layout::Transposed => pack(Targets { transposed: Some((out, mp, kp)), ..Targets::default() }, a, k, m),
    }
}

/// [`super::pack_pairs`], vectorised.
pub(super) fn pack_pairs(out: &mut Lines<u32>, b: &[f32], lb: Layout, k: usize, n: usize, kp: usize, np: usize) {
    match lb {
        Layout::Normal => pack(Targets { pairs: Some((out, kp, np)), ..Targets::default() }, b, k, n),
        // `b` stored `n x k` (a layer's kernel in the input gradient `dz · Wᵀ`).
        Layout::Transposed => {
            assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
            let size = crate::linalg::checked_len;
            assert!(b.len() >= size(k, n) && kp >= k && np >= n && kp.is_multiple_of(32) && np.is_multiple_of(16));
            grow(out, size(kp / 2, np));
            // Every pair (its high half zero past k) below column n and pair row k / 2 rounded
            // up is written; only the padding is zeroed.
            for q in 0..kp / 2 {
                let from = if q < k.div_ceil(2) { n } else { 0 };
                for j in from..np {
                    out[b_index(q, j, kp)] = 0;
                }
            }
            // SAFETY: the CPU has AVX-512 F/BW/VL/BF16 (asserted above: the check requires them).
            unsafe { pairs_transposed(out, b, k, n, kp) }
        }
    }
}

/// The packings one pass over a matrix `x` (`rows x cols`, row-major) writes, each buffer with
/// its padded sizes; each value is read and rounded once for all of them.
#[derive(Default)]
pub(super) struct Targets<'a> {
    /// `x` as the left operand (`m = rows`, `k = cols`): [`super::a_index`]'s tiles, `mp x kp`
    /// (as [`pack_rows`] with [`Layout::Normal`]).
    pub tiles: Option<(&'a mut Lines<u16>, usize, usize)>,
    /// `x` as the right operand (`k = rows`, `n = cols`): [`super::b_index`]'s pairs,
    /// `kp / 2 x np` (as [`pack_pairs`] with [`Layout::Normal`]).
    pub pairs: Option<(&'a mut Lines<u32>, usize, usize)>,
    /// `xᵀ` as the left operand (`m = cols`, `k = rows`): tiles, `mp x kp` (as [`pack_rows`]
    /// with [`Layout::Transposed`]).
    pub transposed: Option<(&'a mut Lines<u16>, usize, usize)>,
}

/// [`prepare`], then [`convert`] of every row.
pub(super) fn pack(mut targets: Targets<'_>, x: &[f32], rows: usize, cols: usize) {
    prepare(&mut targets, rows, cols);
    convert(&mut targets, x, rows, cols, 0..rows);
}

/// Sizes the targets for `x` (`rows x cols`) and zeroes their padding, which no row writes.
/// The buffers only grow (a shrink and regrowth would zero them whole).
pub(super) fn prepare(targets: &mut Targets<'_>, rows: usize, cols: usize) {
    let size = crate::linalg::checked_len;
    let zero_tiles = |out: &mut Lines<u16>, m: usize, k: usize, mp: usize, kp: usize| {
        assert!(mp >= m && kp >= k && kp.is_multiple_of(32) && mp.is_multiple_of(16), "tiles {m}x{k} in {mp}x{kp}");
        grow(out, size(mp, kp));
        for i in 0..mp {
            let from = if i < m { k } else { 0 };
            for p in from..kp {
                out[a_index(i, p, kp)] = 0;
            }
        }
    };
    if let Some((out, mp, kp)) = targets.tiles.as_mut() {
        zero_tiles(out, rows, cols, *mp, *kp);
    }
    if let Some((out, mp, kp)) = targets.transposed.as_mut() {
        zero_tiles(out, cols, rows, *mp, *kp);
    }
    if let Some((out, kp, np)) = targets.pairs.as_mut() {
        let (kp, np) = (*kp, *np);
        assert!(kp >= rows && np >= cols && kp.is_multiple_of(2), "pairs {rows}x{cols} in {kp}x{np}");
        grow(out, size(kp / 2, np));
        // Every pair row below `rows` (the last one's high half zero when `rows` is odd) and
        // column below `cols` is written; only the padding is zeroed.
        for q in 0..kp / 2 {
            let from = if q < rows.div_ceil(2) { cols } else { 0 };
            for j in from..np {
                out[b_index(q, j, kp)] = 0;
            }
        }
    }
}

/// Rounds rows `range` of `x` (`rows x cols`) into the targets ([`prepare`]d for this shape).
/// A range starts at a multiple of 32 (whole pair rows and blocks of the transpose) and ends at
/// one or at `rows`, so that ranges in turn convert every row once.
///
/// # Panics
/// If the range or `x` do not fit the shape, or a target is smaller than [`prepare`] makes it.
pub(super) fn convert(targets: &mut Targets<'_>, x: &[f32], rows: usize, cols: usize, range: std::ops::Range<usize>) {
    assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
    let size = crate::linalg::checked_len;
    assert!(x.len() >= size(rows, cols), "packing: x has {} < {rows}x{cols}", x.len());
    assert!(range.start.is_multiple_of(32) && range.start <= range.end, "packing rows {range:?}");
    assert!(range.end == rows || range.end.is_multiple_of(32) && range.end < rows, "packing rows {range:?} of {rows}");
    let tiles = targets.tiles.as_mut().map(|(out, _, kp)| (&mut out[..], *kp));
    let pairs = targets.pairs.as_mut().map(|(out, kp, _)| (&mut out[..], *kp));
    // SAFETY: the CPU has AVX-512 F/BW/VL/BF16 (asserted above: the check requires them).
    unsafe {
        match targets.transposed.as_mut() {
            Some((out, _, kp)) => {
                rows_transposed(out, tiles, x, cols, rows, *kp, range.clone());
                if pairs.is_some() {
                    rows_and_pairs(None, pairs, x, rows, cols, range);
                }
            }
            None => rows_and_pairs(tiles, pairs, x, rows, cols, range),
        }
    }
}

/// `x` stored `rows x cols`, its rows in `range` (starting at an even row):
/// `tiles[a_index(i, p)] = x[i][p]` and `pairs[b_index(q, j)] = x[2q][j] | x[2q + 1][j] << 16`,
/// each with its `kp`.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_and_pairs(
    tiles: Option<(&mut [u16], usize)>,
    pairs: Option<(&mut [u32], usize)>,
    x: &[f32],
    rows: usize,
    cols: usize,
    range: std::ops::Range<usize>,
) {
    // One loop per combination of targets, so that the inner loop tests neither.
    match (tiles, pairs) {
        (Some(t), Some(p)) => rows_and_pairs_into::<true, true>(t, p, x, rows, cols, range),
        (Some(t), None) => rows_and_pairs_into::<true, false>(t, (&mut [], 0), x, rows, cols, range),
        (None, Some(p)) => rows_and_pairs_into::<false, true>((&mut [], 0), p, x, rows, cols, range),
        (None, None) => {}
    }
}

/// [`rows_and_pairs`] into the targets `TILES` and `PAIRS` say (the other is empty and unread).
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_and_pairs_into<const TILES: bool, const PAIRS: bool>(
    (tiles, tkp): (&mut [u16], usize),
    (pairs, pkp): (&mut [u32], usize),
    x: &[f32],
    rows: usize,
    cols: usize,
    range: std::ops::Range<usize>,
) {
    let full = cols / 16 * 16;
    // 16-bit lane 2j takes value j (the first row's), lane 2j + 1 value 16 + j (the second's).
    let interleave = _mm512_set_epi16(
        31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1,
        16, 0,
    );
    for q in range.start / 2..range.end.div_ceil(2) {
        let first = &x[2 * q * cols..(2 * q + 1) * cols];
        // The last row of an odd count pairs with zeros.
        let second = if 2 * q + 1 < rows { Some(&x[(2 * q + 1) * cols..(2 * q + 2) * cols]) } else { None };
        if full > 0 {
            // Where the row pair's first 16 values go; each next 16 values of a row lie 16 bf16
            // further in its tile row, or 512 on (the next k tile) after the tile's second half,
            // and each next 16 columns of pairs `8 kp` on (the next block of 16 columns). The
            // last 16 of them lie inside the targets (checked here), so every store below does.
            let (t0, t1) = (a_index(2 * q, 0, tkp), a_index(2 * q + 1, 0, tkp));
            let p0 = b_index(q, 0, pkp);
            let last_j = full - 16;
            assert!(!TILES || a_index(2 * q + 1, last_j, tkp) + 16 <= tiles.len(), "tiles out of bounds");
            assert!(!PAIRS || b_index(q, last_j, pkp) + 16 <= pairs.len(), "pairs out of bounds");
            let (tp, pp) = (tiles.as_mut_ptr(), pairs.as_mut_ptr());
            let zero = _mm512_setzero_ps();
            for j in (0..full).step_by(16) {
                // SAFETY: 16 f32 of each row in bounds (j + 16 <= full <= cols); unaligned loads.
                let both: __m512i = unsafe {
                    let lo = _mm512_loadu_ps(first.as_ptr().add(j));
                    let hi = second.map_or(zero, |r| _mm512_loadu_ps(r.as_ptr().add(j)));
                    // Both rows rounded in one instruction (`lo`'s values in the low 256 bits).
                    // __m512bh and __m512i are both 512 plain bits.
                    std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo))
                };
                // a_index(r, j) - a_index(r, 0) and b_index(q, j) - b_index(q, 0), j a multiple of 16.
                let (dt, dp) = (j / 32 * 512 + j % 32, j / 16 * 8 * pkp);
                if TILES {
                    // SAFETY: at most the last j's offsets, checked in bounds above; unaligned stores.
                    unsafe {
                        _mm256_storeu_si256(tp.add(t0 + dt).cast(), _mm512_castsi512_si256(both));
                        if second.is_some() {
                            _mm256_storeu_si256(tp.add(t1 + dt).cast(), _mm512_extracti64x4_epi64::<1>(both));
                        }
                    }
                }
                if PAIRS {
                    // SAFETY: as above.
                    unsafe { _mm512_storeu_si512(pp.add(p0 + dp).cast(), _mm512_permutexvar_epi16(interleave, both)) };
                }
            }
        }
        for j in full..cols {
            let lo = f32_to_bf16_bits(first[j]);
            let hi = second.map_or(0, |r| f32_to_bf16_bits(r[j]));
            if TILES {
                tiles[a_index(2 * q, j, tkp)] = lo;
                if second.is_some() {
                    tiles[a_index(2 * q + 1, j, tkp)] = hi;
                }
            }
            if PAIRS {
                pairs[b_index(q, j, pkp)] = u32::from(lo) | u32::from(hi) << 16;
            }
        }
    }
}

/// The transpose of 16 rows of 16 32-bit values, in registers: interleave 32-bit, then
/// 64-bit values within 128-bit lanes, then move the lanes.
#[target_feature(enable = "avx512f")]
fn transpose_16x16(r: [__m512i; 16]) -> [__m512i; 16] {
    let mut t = r;
    for g in 0..8 {
        t[2 * g] = _mm512_unpacklo_epi32(r[2 * g], r[2 * g + 1]);
        t[2 * g + 1] = _mm512_unpackhi_epi32(r[2 * g], r[2 * g + 1]);
    }
    // u[4g + c], lane L: column 4L + c of rows 4g..4g + 4.
    let mut u = t;
    for g in 0..4 {
        let (a0, a1, b0, b1) = (t[4 * g], t[4 * g + 1], t[4 * g + 2], t[4 * g + 3]);
        u[4 * g] = _mm512_unpacklo_epi64(a0, b0);
        u[4 * g + 1] = _mm512_unpackhi_epi64(a0, b0);
        u[4 * g + 2] = _mm512_unpacklo_epi64(a1, b1);
        u[4 * g + 3] = _mm512_unpackhi_epi64(a1, b1);
    }
    let mut out = u;
    for c in 0..4 {
        let x = _mm512_shuffle_i32x4::<0x44>(u[c], u[4 + c]);
        let y = _mm512_shuffle_i32x4::<0x44>(u[8 + c], u[12 + c]);
        let x2 = _mm512_shuffle_i32x4::<0xEE>(u[c], u[4 + c]);
        let y2 = _mm512_shuffle_i32x4::<0xEE>(u[8 + c], u[12 + c]);
        out[c] = _mm512_shuffle_i32x4::<0x88>(x, y);
        out[4 + c] = _mm512_shuffle_i32x4::<0xDD>(x, y);
        out[8 + c] = _mm512_shuffle_i32x4::<0x88>(x2, y2);
        out[12 + c] = _mm512_shuffle_i32x4::<0xDD>(x2, y2);
    }
    out
}

/// `b` stored `n x k` (`b[p][j]` at `j * k + p`): `out[b_index(q, j)] = b[2q][j] | b[2q + 1][j] << 16`.
/// Blocks of 16 columns x 32 values of k: each stored row's 32 values rounded in one instruction
/// are its 16 pairs in order; transposed, vector q holds pair row q of the 16 columns, 64
/// contiguous bytes of the packing.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn pairs_transposed(out: &mut [u32], b: &[f32], k: usize, n: usize, kp: usize) {
    let (n_full, k_full) = (n / 16 * 16, k / 32 * 32);
    for j0 in (0..n_full).step_by(16) {
        for p0 in (0..k_full).step_by(32) {
            let rows: [__m512i; 16] = std::array::from_fn(|j| {
                let row = &b[(j0 + j) * k + p0..(j0 + j) * k + p0 + 32];
                // SAFETY: 32 f32 in bounds (the slice is checked); unaligned loads.
                let (lo, hi) = unsafe { (_mm512_loadu_ps(row.as_ptr()), _mm512_loadu_ps(row[16..].as_ptr())) };
                // SAFETY: __m512bh and __m512i are both 512 plain bits.
                unsafe { std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo)) }
            });
            for (q, pairs) in transpose_16x16(rows).into_iter().enumerate() {
                let at = b_index(p0 / 2 + q, j0, kp);
                // SAFETY: out[at..at + 16] is in bounds (the slice is checked).
                unsafe { _mm512_storeu_si512(out[at..at + 16].as_mut_ptr().cast(), pairs) };
            }
        }
    }
    // The ragged edges: pairs past k_full (every column), columns past n_full (every pair);
    // the high half of a last pair past k is zero.
    for j in 0..n {
        let row = &b[j * k..(j + 1) * k];
        let pairs = if j < n_full { k_full / 2..k.div_ceil(2) } else { 0..k.div_ceil(2) };
        for q in pairs {
            let hi = row.get(2 * q + 1).map_or(0, |&x| u32::from(f32_to_bf16_bits(x)));
            out[b_index(q, j, kp)] = u32::from(f32_to_bf16_bits(row[2 * q])) | hi << 16;
        }
    }
}

/// `a` stored `k x m`, its rows `p` in `range`: `out[i][p] = a[p][i]` (and
/// `tiles[a_index(p, i)] = a[p][i]`, each with its `kp`). Blocks of 32 rows x 16 columns: pairs
/// of rows rounded in one instruction become 16 32-bit pairs (lane i holds rows 2q and 2q + 1 of
/// column i); transposed, vector i holds the 32 values of column i, the 64 bytes of one row of a
/// packed tile, and the block's 16 vectors are one whole tile.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_transposed(
    out: &mut [u16],
    tiles: Option<(&mut [u16], usize)>,
    a: &[f32],
    m: usize,
    k: usize,
    kp: usize,
    range: std::ops::Range<usize>,
) {
    match tiles {
        Some(t) => rows_transposed_into::<true>(out, t, a, m, k, kp, range),
        None => rows_transposed_into::<false>(out, (&mut [], 0), a, m, k, kp, range),
    }
}

/// [`rows_transposed`], with the tiles of `a` itself when `TILES` (else `tiles` is empty and unread).
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_transposed_into<const TILES: bool>(
    out: &mut [u16],
    (tiles, tkp): (&mut [u16], usize),
    a: &[f32],
    m: usize,
    k: usize,
    kp: usize,
    range: std::ops::Range<usize>,
) {
    let (m_full, k_full) = (m / 16 * 16, k / 32 * 32);
    // 16-bit lane 2i takes value i (row 2q's), lane 2i + 1 value 16 + i (row 2q + 1's).
    let interleave = _mm512_set_epi16(
        31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1,
        16, 0,
    );
    // Rows outer: `a` is read in storage order (32 whole rows at a time), each block's
    // output is one contiguous 1 KiB tile. Rows of `a` in `range` only (it starts at a
    // multiple of 32).
    for p0 in (range.start..range.end.min(k_full)).step_by(32) {
        for i0 in (0..m_full).step_by(16) {
            // The block reads a[p0..p0 + 32][i0..i0 + 16], writes the tile of out at
            // (i0, p0) (512 contiguous values) and, for TILES, 16 values of each of the rows
            // p0..p0 + 32 of the tiles at column i0: checked here, so that the loads and stores
            // below are in bounds.
            let (src, dst) = ((p0 + 31) * m + i0 + 16, a_index(i0, p0, kp) + 512);
            assert!(src <= a.len() && dst <= out.len(), "a block of the transposed packing out of bounds");
            // a_index(p, i0, tkp) for rows p of the first and second 16-row group of the block.
            let (g0, g1) = (a_index(p0, i0, tkp), a_index(p0 + 16, i0, tkp));
            if TILES {
                assert!(g1 + 15 * 32 + 16 <= tiles.len(), "a block of the tiles out of bounds");
            }
            let (a_block, out_tile) = (a[p0 * m + i0..].as_ptr(), out[dst - 512..].as_mut_ptr());
            let mut pairs = [_mm512_setzero_si512(); 16];
            for (q, pair) in pairs.iter_mut().enumerate() {
                // SAFETY: rows p0 + 2q and p0 + 2q + 1, 16 values from column i0, lie inside `a`
                // (checked above); unaligned loads.
                let both: __m512i = unsafe {
                    let lo = _mm512_loadu_ps(a_block.add(2 * q * m));
                    let hi = _mm512_loadu_ps(a_block.add((2 * q + 1) * m));
                    // __m512bh and __m512i are both 512 plain bits.
                    std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo))
                };
                if TILES {
                    // Rows p0 + 2q and p0 + 2q + 1 sit in the same 16-row group, 32 apart.
                    let at = if q < 8 { g0 + 2 * q * 32 } else { g1 + (2 * q - 16) * 32 };
                    // SAFETY: at + 32 + 16 <= tiles.len() (checked above); unaligned stores.
                    unsafe {
                        let t = tiles.as_mut_ptr().add(at);
                        _mm256_storeu_si256(t.cast(), _mm512_castsi512_si256(both));
                        _mm256_storeu_si256(t.add(32).cast(), _mm512_extracti64x4_epi64::<1>(both));
                    }
                }
                *pair = _mm512_permutexvar_epi16(interleave, both);
            }
            for (i, row) in transpose_16x16(pairs).into_iter().enumerate() {
                // SAFETY: the tile's 512 values lie inside `out` (checked above).
                unsafe { _mm512_storeu_si512(out_tile.add(32 * i).cast(), row) };
            }
        }
    }
    // The ragged edges: columns past m_full (every row), rows past k_full (every column).
    for p in range {
        let cols = if p < k_full { m_full..m } else { 0..m };
        for i in cols {
            let v = f32_to_bf16_bits(a[p * m + i]);
            out[a_index(i, p, kp)] = v;
            if TILES {
                tiles[a_index(p, i, tkp)] = v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Bf16Kernel, Layout, Lines};

    #[test]
    fn vectorised_packing_gives_the_scalar_bits() {
        if let Err(why) = Bf16Kernel::Avx512.check() {
            crate::test_support::skipped_for_cpu_feature(
                "vectorised_packing_gives_the_scalar_bits",
                "avx512_bf16",
                why,
            );
            return;
        }
        let vals = |len: usize| -> Vec<f32> {
            (0..len)
                .map(|i| match i % 11 {
                    0 => 0.0,
                    1 => -1e-40,
                    2 => f32::NAN,
                    3 => 1.0 + 1.0 / 256.0,
                    _ => ((i * 7919 % 1000) as f32 - 500.0) * 0.0137,
                })
                .collect()
        };
        for (m, k) in [(16, 32), (48, 64), (37, 45), (129, 96), (5, 7)] {
            let a = vals(m * k);
            let (mp, kp) = (m.next_multiple_of(32), k.next_multiple_of(32));
            for la in [Layout::Normal, Layout::Transposed] {
                // A reused buffer holds garbage: the padding must be zeroed.
                let (mut want, mut got) = (Lines::default(), Lines::filled(mp * kp + 5, 0x7777u16));
                super::super::pack_rows(&mut want, &a, la, m, k, mp, kp);
                super::pack_rows(&mut got, &a, la, m, k, mp, kp);
                // The buffer is not shortened: what lies past the packing is not read.
                assert_eq!(got[..want.len()], want[..], "pack_rows {la:?} {m}x{k}");
            }
            let (kp, np) = (m.next_multiple_of(32), k.next_multiple_of(32));
            for lb in [Layout::Normal, Layout::Transposed] {
                let (mut want, mut got) = (Lines::default(), Lines::filled(kp / 2 * np + 7, 0x7777_7777u32));
                super::super::pack_pairs(&mut want, &a, lb, m, k, kp, np);
                super::pack_pairs(&mut got, &a, lb, m, k, kp, np);
                assert_eq!(got[..want.len()], want[..], "pack_pairs {lb:?} {m}x{k}");
            }
            // One pass into several packings gives each packing's bits.
            let (tmp, tkp) = (m.next_multiple_of(32), k.next_multiple_of(32));
            let (pkp, pnp) = (m.next_multiple_of(32), k.next_multiple_of(32));
            let (mut rows_want, mut pairs_want) = (Lines::default(), Lines::default());
            super::super::pack_rows(&mut rows_want, &a, Layout::Normal, m, k, tmp, tkp);
            super::super::pack_pairs(&mut pairs_want, &a, Layout::Normal, m, k, pkp, pnp);
            let (t_mp, t_kp) = (k.next_multiple_of(32), m.next_multiple_of(32));
            let mut t_want = Lines::default();
            super::super::pack_rows(&mut t_want, &a, Layout::Transposed, k, m, t_mp, t_kp);
            // Every combination of targets, in one pass and in ranges of 32 rows.
            for bits in 1..8 {
                for in_ranges in [false, true] {
                    let (mut rows_got, mut pairs_got, mut t_got) = (
                        Lines::filled(tmp * tkp + 3, 0x5555u16),
                        Lines::filled(9, 0x5555_5555u32),
                        Lines::filled(4, 0x3333u16),
                    );
                    let mut targets = super::Targets {
                        tiles: (bits & 1 != 0).then_some((&mut rows_got, tmp, tkp)),
                        pairs: (bits & 2 != 0).then_some((&mut pairs_got, pkp, pnp)),
                        transposed: (bits & 4 != 0).then_some((&mut t_got, t_mp, t_kp)),
                    };
                    super::prepare(&mut targets, m, k);
                    let step = if in_ranges { 32 } else { m.next_multiple_of(32) };
                    for range in (0..m).step_by(step).map(|r| r..(r + step).min(m)) {
                        super::convert(&mut targets, &a, m, k, range);
                    }
                    let what = format!("targets {bits:03b}, ranges {in_ranges}, {m}x{k}");
                    if bits & 1 != 0 {
                        assert_eq!(rows_got[..rows_want.len()], rows_want[..], "rows: {what}");
                    }
                    if bits & 2 != 0 {
                        assert_eq!(pairs_got[..pairs_want.len()], pairs_want[..], "pairs: {what}");
                    }
                    if bits & 4 != 0 {
                        assert_eq!(t_got[..t_want.len()], t_want[..], "transposed: {what}");
                    }
                }
            }
        }
    }
}
