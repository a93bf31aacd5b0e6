use std::arch::x86_64::{
    __m256i, __m512i, _mm256_storeu_si256, _mm512_castsi512_si256, _mm512_cvtepu16_epi32, _mm512_cvtne2ps_pbh,
    _mm512_cvtneps_pbh, _mm512_extracti64x4_epi64, _mm512_loadu_ps, _mm512_or_si512, _mm512_permutexvar_epi16,
    _mm512_set_epi16, _mm512_setzero_ps, _mm512_shuffle_i32x4, _mm512_slli_epi32, _mm512_storeu_si512,
    _mm512_unpackhi_epi32, _mm512_unpackhi_epi64, _mm512_unpacklo_epi32, _mm512_unpacklo_epi64,
};

use super::{Layout, a_index, b_index, f32_to_bf16_bits, grow};

const FEATURES_CHECKED: &str = "bf16 packing needs AVX-512 BF16 (checked by Bf16Kernel::check)";

/// [`super::pack_rows`], vectorised.
pub(super) fn pack_rows(out: &mut Vec<u16>, a: &[f32], la: Layout, m: usize, k: usize, mp: usize, kp: usize) {
    match la {
        Layout::Normal => pack_rows_and_pairs(Some((out, mp, kp)), None, a, m, k),
        Layout::Transposed => pack_transposed_rows(out, None, a, m, k, mp, kp),
    }
}

/// [`super::pack_pairs`], vectorised where `b` is stored `k x n` (the large operands: weight
/// gradients' `dz`); the transposed case (a layer's kernel, small) is the scalar reference.
pub(super) fn pack_pairs(out: &mut Vec<u32>, b: &[f32], lb: Layout, k: usize, n: usize, kp: usize, np: usize) {
    match lb {
        Layout::Normal => pack_rows_and_pairs(None, Some((out, kp, np)), b, k, n),
        Layout::Transposed => {
            assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
            super::pack_pairs(out, b, lb, k, n, kp, np);
        }
    }
}

/// `x` stored `rows x cols`, each value rounded once and written to either packing or both:
/// - `tiles` (buffer, `mp`, `kp`): `x` as [`pack_rows`] packs it with [`Layout::Normal`] (`x` the
///   left operand, `m = rows`, `k = cols`);
/// - `pairs` (buffer, `kp`, `np`): as [`pack_pairs`] packs it with [`Layout::Normal`] (`x` the
///   right operand, `k = rows`, `n = cols`).
///
/// One pass reads each pair of rows once, rounds it with one instruction and stores it in both
/// orders. The buffers only grow (a shrink and regrowth would zero them whole); every element
/// below `(rows, cols)` is written, and only the padding is zeroed.
pub(super) fn pack_rows_and_pairs(
    tiles: Option<(&mut Vec<u16>, usize, usize)>,
    pairs: Option<(&mut Vec<u32>, usize, usize)>,
    x: &[f32],
    rows: usize,
    cols: usize,
) {
    assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
    let size = crate::linalg::checked_len;
    assert!(x.len() >= size(rows, cols), "packing: x has {} < {rows}x{cols}", x.len());
    let tiles = tiles.map(|(out, mp, kp)| {
        assert!(mp >= rows && kp >= cols && kp.is_multiple_of(32) && mp.is_multiple_of(16));
        grow(out, size(mp, kp));
        for i in 0..mp {
            let from = if i < rows { cols } else { 0 };
            for p in from..kp {
                out[a_index(i, p, kp)] = 0;
            }
        }
        (&mut out[..], kp)
    });
    let pairs = pairs.map(|(out, kp, np)| {
        assert!(kp >= rows && np >= cols && kp.is_multiple_of(2));
        grow(out, size(kp / 2, np));
        // Every pair row below `rows` (the last one's high half zero when `rows` is odd) and
        // column below `cols` is written; only the padding is zeroed.
        for q in 0..kp / 2 {
            let from = if q < rows.div_ceil(2) { cols } else { 0 };
            for j in from..np {
                out[b_index(q, j, kp)] = 0;
            }
        }
        (&mut out[..], kp)
    });
    // SAFETY: the CPU has AVX-512 F/BW/VL/BF16 (asserted above: the check requires them).
    unsafe { rows_and_pairs(tiles, pairs, x, rows, cols) }
}

/// `a` stored `k x m` and packed as the left operand `aᵀ` ([`pack_rows`] with
/// [`Layout::Transposed`]) into `out` (`mp x kp`); with `tiles` (buffer, `tiles_mp`,
/// `tiles_kp`), also `a` itself as a left operand (`k x m`, [`Layout::Normal`]) from the same
/// rounding. Only the padding is zeroed.
pub(super) fn pack_transposed_rows(
    out: &mut Vec<u16>,
    tiles: Option<(&mut Vec<u16>, usize, usize)>,
    a: &[f32],
    m: usize,
    k: usize,
    mp: usize,
    kp: usize,
) {
    assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
    let size = crate::linalg::checked_len;
    assert!(a.len() >= size(m, k) && mp >= m && kp >= k && kp.is_multiple_of(32) && mp.is_multiple_of(16));
    let zero_padding = |out: &mut Vec<u16>, rows: usize, cols: usize, mp: usize, kp: usize| {
        grow(out, size(mp, kp));
        for i in 0..mp {
            let from = if i < rows { cols } else { 0 };
            for p in from..kp {
                out[a_index(i, p, kp)] = 0;
            }
        }
    };
    zero_padding(out, m, k, mp, kp);
    let tiles = tiles.map(|(t, tmp, tkp)| {
        assert!(tmp >= k && tkp >= m && tkp.is_multiple_of(32) && tmp.is_multiple_of(16));
        zero_padding(t, k, m, tmp, tkp);
        (&mut t[..], tkp)
    });
    // SAFETY: as in `pack_rows_and_pairs`.
    unsafe { rows_transposed(out, tiles, a, m, k, kp) }
}

/// 16 f32 from `src[..16]` rounded to bf16: as 16 contiguous values, and in the low halves of
/// 32-bit lanes.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn bf16_lanes(src: &[f32]) -> (__m256i, __m512i) {
    assert!(src.len() >= 16);
    // SAFETY: 16 f32 are in bounds (asserted); unaligned load.
    let v = unsafe { _mm512_loadu_ps(src.as_ptr()) };
    // SAFETY: __m256bh and __m256i are both 256 plain bits.
    let h: __m256i = unsafe { std::mem::transmute(_mm512_cvtneps_pbh(v)) };
    (h, _mm512_cvtepu16_epi32(h))
}

/// `x` stored `rows x cols`: `tiles[a_index(i, p)] = x[i][p]` and
/// `pairs[b_index(q, j)] = x[2q][j] | x[2q + 1][j] << 16`, each with its `kp`.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_and_pairs(
    mut tiles: Option<(&mut [u16], usize)>,
    mut pairs: Option<(&mut [u32], usize)>,
    x: &[f32],
    rows: usize,
    cols: usize,
) {
    let full = cols / 16 * 16;
    // 16-bit lane 2j takes value j (the first row's), lane 2j + 1 value 16 + j (the second's).
    let interleave = _mm512_set_epi16(
        31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1,
        16, 0,
    );
    for q in 0..rows.div_ceil(2) {
        let first = &x[2 * q * cols..(2 * q + 1) * cols];
        // The last row of an odd count pairs with zeros.
        let second = if 2 * q + 1 < rows { Some(&x[(2 * q + 1) * cols..(2 * q + 2) * cols]) } else { None };
        for j in (0..full).step_by(16) {
            // SAFETY: 16 f32 of each row in bounds (j + 16 <= cols); unaligned loads.
            let (lo, hi) = unsafe {
                (
                    _mm512_loadu_ps(first[j..j + 16].as_ptr()),
                    second.map_or(_mm512_setzero_ps(), |r| _mm512_loadu_ps(r[j..j + 16].as_ptr())),
                )
            };
            // Both rows rounded in one instruction (`lo`'s values in the low 256 bits).
            // SAFETY: __m512bh and __m512i are both 512 plain bits.
            let both: __m512i = unsafe { std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo)) };
            if let Some((out, kp)) = tiles.as_mut() {
                // Values j..j + 16 of a row are contiguous in the tiles (j % 32 is 0 or 16).
                let at = a_index(2 * q, j, *kp);
                // SAFETY: out[at..at + 16] is in bounds (the slice is checked); unaligned store.
                unsafe { _mm256_storeu_si256(out[at..at + 16].as_mut_ptr().cast(), _mm512_castsi512_si256(both)) };
                if second.is_some() {
                    let at = a_index(2 * q + 1, j, *kp);
                    let h = _mm512_extracti64x4_epi64::<1>(both);
                    // SAFETY: as above.
                    unsafe { _mm256_storeu_si256(out[at..at + 16].as_mut_ptr().cast(), h) };
                }
            }
            if let Some((out, kp)) = pairs.as_mut() {
                let pair = _mm512_permutexvar_epi16(interleave, both);
                let at = b_index(q, j, *kp);
                // SAFETY: out[at..at + 16] is in bounds (the slice is checked).
                unsafe { _mm512_storeu_si512(out[at..at + 16].as_mut_ptr().cast(), pair) };
            }
        }
        for j in full..cols {
            let lo = f32_to_bf16_bits(first[j]);
            let hi = second.map_or(0, |r| f32_to_bf16_bits(r[j]));
            if let Some((out, kp)) = tiles.as_mut() {
                out[a_index(2 * q, j, *kp)] = lo;
                if second.is_some() {
                    out[a_index(2 * q + 1, j, *kp)] = hi;
                }
            }
            if let Some((out, kp)) = pairs.as_mut() {
                out[b_index(q, j, *kp)] = u32::from(lo) | u32::from(hi) << 16;
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

/// `a` stored `k x m`; `out[i][p] = a[p][i]` (and `tiles[a_index(p, i)] = a[p][i]`, each with
/// its `kp`). Blocks of 32 rows x 16 columns: pairs of rows become 16 32-bit pairs (lane i
/// holds rows 2q and 2q + 1 of column i); transposed, vector i holds the 32 values of column
/// i, the 64 bytes of one row of a packed tile.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_transposed(out: &mut [u16], mut tiles: Option<(&mut [u16], usize)>, a: &[f32], m: usize, k: usize, kp: usize) {
    let (m_full, k_full) = (m / 16 * 16, k / 32 * 32);
    // Rows outer: `a` is read in storage order (32 whole rows at a time), each block's
    // output is one contiguous 1 KiB tile.
    for p0 in (0..k_full).step_by(32) {
        for i0 in (0..m_full).step_by(16) {
            let pairs: [__m512i; 16] = std::array::from_fn(|q| {
                let (lo_values, lo) = bf16_lanes(&a[(p0 + 2 * q) * m + i0..]);
                let (hi_values, hi) = bf16_lanes(&a[(p0 + 2 * q + 1) * m + i0..]);
                if let Some((t, tkp)) = tiles.as_mut() {
                    // Values i0..i0 + 16 of a row of `a` are contiguous in its tiles.
                    for (p, values) in [(p0 + 2 * q, lo_values), (p0 + 2 * q + 1, hi_values)] {
                        let at = a_index(p, i0, *tkp);
                        // SAFETY: t[at..at + 16] is in bounds (the slice is checked).
                        unsafe { _mm256_storeu_si256(t[at..at + 16].as_mut_ptr().cast(), values) };
                    }
                }
                _mm512_or_si512(lo, _mm512_slli_epi32::<16>(hi))
            });
            for (i, row) in transpose_16x16(pairs).into_iter().enumerate() {
                let at = a_index(i0 + i, p0, kp);
                // SAFETY: out[at..at + 32] is in bounds (the slice is checked).
                unsafe { _mm512_storeu_si512(out[at..at + 32].as_mut_ptr().cast(), row) };
            }
        }
    }
    // The ragged edges: columns past m_full (every row), rows past k_full (every column).
    for p in 0..k {
        let cols = if p < k_full { m_full..m } else { 0..m };
        for i in cols {
            let v = f32_to_bf16_bits(a[p * m + i]);
            out[a_index(i, p, kp)] = v;
            if let Some((t, tkp)) = tiles.as_mut() {
                t[a_index(p, i, *tkp)] = v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Bf16Kernel, Layout};

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
                let (mut want, mut got) = (Vec::new(), vec![0x7777u16; mp * kp + 5]);
                super::super::pack_rows(&mut want, &a, la, m, k, mp, kp);
                super::pack_rows(&mut got, &a, la, m, k, mp, kp);
                // The buffer is not shortened: what lies past the packing is not read.
                assert_eq!(got[..want.len()], want, "pack_rows {la:?} {m}x{k}");
            }
            let (kp, np) = (m.next_multiple_of(32), k.next_multiple_of(32));
            for lb in [Layout::Normal, Layout::Transposed] {
                let (mut want, mut got) = (Vec::new(), vec![0x7777_7777u32; kp / 2 * np + 7]);
                super::super::pack_pairs(&mut want, &a, lb, m, k, kp, np);
                super::pack_pairs(&mut got, &a, lb, m, k, kp, np);
                assert_eq!(got[..want.len()], want, "pack_pairs {lb:?} {m}x{k}");
            }
            // One pass into two packings gives each packing's bits.
            let (tmp, tkp) = (m.next_multiple_of(32), k.next_multiple_of(32));
            let (pkp, pnp) = (m.next_multiple_of(32), k.next_multiple_of(32));
            let (mut rows_want, mut pairs_want) = (Vec::new(), Vec::new());
            super::super::pack_rows(&mut rows_want, &a, Layout::Normal, m, k, tmp, tkp);
            super::super::pack_pairs(&mut pairs_want, &a, Layout::Normal, m, k, pkp, pnp);
            let (mut rows_got, mut pairs_got) = (vec![0x5555u16; tmp * tkp + 3], vec![0x5555_5555u32; 9]);
            super::pack_rows_and_pairs(Some((&mut rows_got, tmp, tkp)), Some((&mut pairs_got, pkp, pnp)), &a, m, k);
            assert_eq!(rows_got[..rows_want.len()], rows_want, "rows of both {m}x{k}");
            assert_eq!(pairs_got[..pairs_want.len()], pairs_want, "pairs of both {m}x{k}");
            // `a` (m x k) packed transposed (k x m as the left operand) and as itself.
            let (mut t_want, mut t_got) = (Vec::new(), vec![0x3333u16; 4]);
            let (t_mp, t_kp) = (k.next_multiple_of(32), m.next_multiple_of(32));
            super::super::pack_rows(&mut t_want, &a, Layout::Transposed, k, m, t_mp, t_kp);
            rows_got.fill(0x4444);
            super::pack_transposed_rows(&mut t_got, Some((&mut rows_got, tmp, tkp)), &a, k, m, t_mp, t_kp);
            assert_eq!(t_got[..t_want.len()], t_want, "transposed rows of both {m}x{k}");
            assert_eq!(rows_got[..rows_want.len()], rows_want, "rows beside the transposed rows {m}x{k}");
        }
    }
}
