use std::arch::x86_64::{
    __m256i, __m512i, _mm256_storeu_si256, _mm512_cvtepu16_epi32, _mm512_cvtne2ps_pbh, _mm512_cvtneps_pbh,
    _mm512_loadu_ps, _mm512_or_si512, _mm512_permutexvar_epi16, _mm512_set_epi16, _mm512_shuffle_i32x4,
    _mm512_slli_epi32, _mm512_storeu_si512, _mm512_unpackhi_epi32, _mm512_unpackhi_epi64, _mm512_unpacklo_epi32,
    _mm512_unpacklo_epi64,
};

use super::{Layout, a_index, b_index, f32_to_bf16_bits, grow};

const FEATURES_CHECKED: &str = "bf16 packing needs AVX-512 BF16 (checked by Bf16Kernel::check)";

/// [`super::pack_rows`], vectorised.
pub(super) fn pack_rows(out: &mut Vec<u16>, a: &[f32], la: Layout, m: usize, k: usize, mp: usize, kp: usize) {
    assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
    let size = crate::linalg::checked_len;
    assert!(a.len() >= size(m, k) && mp >= m && kp >= k && kp.is_multiple_of(32) && mp.is_multiple_of(16));
    // Every element below (m, k) is written; only the padding is zeroed. The buffer only
    // grows (a shrink and regrowth would zero it whole).
    grow(out, size(mp, kp));
    for i in 0..mp {
        let from = if i < m { k } else { 0 };
        for p in from..kp {
            out[a_index(i, p, kp)] = 0;
        }
    }
    // SAFETY: the CPU has AVX-512 F/BW/VL/BF16 (asserted above: the check requires them).
    unsafe {
        match la {
            Layout::Normal => rows_normal(out, a, m, k, kp),
            Layout::Transposed => rows_transposed(out, a, m, k, kp),
        }
    }
}

/// [`super::pack_pairs`], vectorised where `b` is stored `k x n` (the large operands: weight
/// gradients' `dz`); the transposed case (a layer's kernel, small) is the scalar reference.
pub(super) fn pack_pairs(out: &mut Vec<u32>, b: &[f32], lb: Layout, k: usize, n: usize, kp: usize, np: usize) {
    assert!(super::Bf16Kernel::Avx512.check().is_ok(), "{FEATURES_CHECKED}");
    let size = crate::linalg::checked_len;
    assert!(b.len() >= size(k, n) && kp >= k && np >= n && kp.is_multiple_of(2));
    match lb {
        Layout::Normal => {
            // Every pair row below k (the last one's high half zero when k is odd) and column
            // below n is written; only the padding is zeroed.
            grow(out, size(kp / 2, np));
            for q in 0..kp / 2 {
                let from = if q < k.div_ceil(2) { n } else { 0 };
                for j in from..np {
                    out[b_index(q, j, kp)] = 0;
                }
            }
            // SAFETY: as in `pack_rows`.
            unsafe { pairs_normal(out, b, k, n, kp) }
        }
        Layout::Transposed => super::pack_pairs(out, b, lb, k, n, kp, np),
    }
}

/// 16 f32 from `src[..16]` as 16 bf16 in the low halves of 32-bit lanes.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn bf16_lanes(src: &[f32]) -> __m512i {
    assert!(src.len() >= 16);
    // SAFETY: 16 f32 are in bounds (asserted); unaligned load.
    let v = unsafe { _mm512_loadu_ps(src.as_ptr()) };
    // SAFETY: __m256bh and __m256i are both 256 plain bits.
    let h: __m256i = unsafe { std::mem::transmute(_mm512_cvtneps_pbh(v)) };
    _mm512_cvtepu16_epi32(h)
}

#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_normal(out: &mut [u16], a: &[f32], m: usize, k: usize, kp: usize) {
    let full = k / 16 * 16;
    for (i, src) in a.chunks_exact(k).take(m).enumerate() {
        for c in (0..full).step_by(16) {
            // SAFETY: 16 f32 in bounds (c + 16 <= k); unaligned load.
            let v = unsafe { _mm512_loadu_ps(src[c..c + 16].as_ptr()) };
            // SAFETY: __m256bh and __m256i are both 256 plain bits.
            let h: __m256i = unsafe { std::mem::transmute(_mm512_cvtneps_pbh(v)) };
            // Values c..c + 16 of row i are contiguous in the packing (c % 32 is 0 or 16).
            let at = a_index(i, c, kp);
            // SAFETY: out[at..at + 16] is in bounds (the slice is checked); unaligned store.
            unsafe { _mm256_storeu_si256(out[at..at + 16].as_mut_ptr().cast(), h) };
        }
        for c in full..k {
            out[a_index(i, c, kp)] = f32_to_bf16_bits(src[c]);
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

/// `a` stored `k x m`; `out[i][p] = a[p][i]`. Blocks of 32 rows x 16 columns: pairs of rows
/// become 16 32-bit pairs (lane i holds rows 2q and 2q + 1 of column i); transposed, vector
/// i holds the 32 values of column i, the 64 bytes of one row of a packed tile.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn rows_transposed(out: &mut [u16], a: &[f32], m: usize, k: usize, kp: usize) {
    let (m_full, k_full) = (m / 16 * 16, k / 32 * 32);
    // Rows outer: `a` is read in storage order (32 whole rows at a time), each block's
    // output is one contiguous 1 KiB tile.
    for p0 in (0..k_full).step_by(32) {
        for i0 in (0..m_full).step_by(16) {
            let pairs: [__m512i; 16] = std::array::from_fn(|q| {
                let lo = bf16_lanes(&a[(p0 + 2 * q) * m + i0..]);
                let hi = bf16_lanes(&a[(p0 + 2 * q + 1) * m + i0..]);
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
            out[a_index(i, p, kp)] = f32_to_bf16_bits(a[p * m + i]);
        }
    }
}

/// `b` stored `k x n`: `out[q][j] = b[2q][j] | b[2q + 1][j] << 16`.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bf16")]
fn pairs_normal(out: &mut [u32], b: &[f32], k: usize, n: usize, kp: usize) {
    let n_full = n / 16 * 16;
    // 16-bit lane 2j takes value j (the first row's), lane 2j + 1 value 16 + j (the second's).
    let interleave = _mm512_set_epi16(
        31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17, 1,
        16, 0,
    );
    for q in 0..k / 2 {
        let (r0, r1) = (&b[2 * q * n..(2 * q + 1) * n], &b[(2 * q + 1) * n..(2 * q + 2) * n]);
        for j in (0..n_full).step_by(16) {
            // SAFETY: 16 f32 of each row in bounds (j + 16 <= n); unaligned loads.
            let (lo, hi) =
                unsafe { (_mm512_loadu_ps(r0[j..j + 16].as_ptr()), _mm512_loadu_ps(r1[j..j + 16].as_ptr())) };
            // Both rows rounded in one instruction (`lo`'s values first), then interleaved.
            // SAFETY: __m512bh and __m512i are both 512 plain bits.
            let both: __m512i = unsafe { std::mem::transmute(_mm512_cvtne2ps_pbh(hi, lo)) };
            let pair = _mm512_permutexvar_epi16(interleave, both);
            let at = b_index(q, j, kp);
            // SAFETY: out[at..at + 16] is in bounds (the slice is checked).
            unsafe { _mm512_storeu_si512(out[at..at + 16].as_mut_ptr().cast(), pair) };
        }
        for j in n_full..n {
            out[b_index(q, j, kp)] = u32::from(f32_to_bf16_bits(r0[j])) | u32::from(f32_to_bf16_bits(r1[j])) << 16;
        }
    }
    if k % 2 == 1 {
        let last = &b[(k - 1) * n..k * n];
        for (j, &x) in last.iter().enumerate() {
            out[b_index(k / 2, j, kp)] = u32::from(f32_to_bf16_bits(x));
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
        }
    }
}
