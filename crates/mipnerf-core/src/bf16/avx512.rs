use std::arch::x86_64::{
    __m512bh, __m512i, _mm512_dpbf16_ps, _mm512_loadu_si512, _mm512_mask_storeu_ps, _mm512_maskz_loadu_ps,
    _mm512_set1_epi32, _mm512_setzero_ps,
};

use super::packed::PackedLeft;
use super::{K_STEP, a_index, b_index};

/// Output rows per step of the micro-kernel: half a packed 16-row tile.
const ROWS: usize = 8;
const _: () = assert!(16 % ROWS == 0, "a step's rows lie in one packed tile");
/// Output columns per step: two vectors of 16 f32 (one packed column block each).
const COLS: usize = 32;
/// Values of k per pass over the output: the packed `b` of one pass (`KC / 2` pair rows of
/// every column) stays in L2 while every row block reads it, and one row block's `a`
/// (8 rows of `KC` bf16, 8 KiB) in L1 while it meets every column block.
const KC: usize = 512;

/// Whether this CPU has what the kernel and the packing use (AVX-512 F, BW, VL and BF16).
pub(super) fn detect() -> Result<(), String> {
    let features = [
        ("avx512f", std::arch::is_x86_feature_detected!("avx512f")),
        ("avx512bw", std::arch::is_x86_feature_detected!("avx512bw")),
        ("avx512vl", std::arch::is_x86_feature_detected!("avx512vl")),
        ("avx512_bf16", std::arch::is_x86_feature_detected!("avx512bf16")),
    ];
    let missing: Vec<&str> = features.iter().filter(|(_, present)| !present).map(|(name, _)| *name).collect();
    if missing.is_empty() { Ok(()) } else { Err(format!("this CPU lacks {} (AVX-512 BF16)", missing.join(", "))) }
}

/// `c (m x n, row-major) = [c +] A · B` from the packed operands ([`PackedLeft`], [`b_index`]):
/// k in passes of [`KC`], each pass sweeping the output in 8 x 32 blocks held in sixteen
/// registers. Rows and columns past `m` and `n` are computed on the zero padding and
/// neither read nor written in `c`.
pub(super) fn product(
    c: &mut [f32],
    a: PackedLeft<'_>,
    b: &[u32],
    m: usize,
    n: usize,
    mp: usize,
    kp: usize,
    np: usize,
    accumulate: bool,
) {
    let a_values = match a {
        PackedLeft::Tiles(a) => a.len(),
        PackedLeft::Pairs(a) => a.len().saturating_mul(2),
    };
    super::assert_packed(super::Bf16Kernel::Avx512, c, a_values, b, m, n, mp, kp, np);
    for k0 in (0..kp).step_by(KC) {
        let k1 = (k0 + KC).min(kp);
        for i0 in (0..m).step_by(ROWS) {
            for j0 in (0..n).step_by(COLS) {
                let accumulate = accumulate || k0 > 0;
                // SAFETY: the CPU has AVX-512 F and BF16 (asserted above); the block's rows
                // lie below mp and its columns below np (m <= mp, n <= np, both multiples of
                // the block), k0..k1 below kp, and the sizes of the buffers are asserted.
                unsafe {
                    match a {
                        PackedLeft::Tiles(a) => {
                            block::<false>(c, a.as_ptr().cast(), b, m, n, kp, i0, j0, k0, k1, accumulate);
                        }
                        PackedLeft::Pairs(a) => block::<true>(c, a.as_ptr(), b, m, n, kp, i0, j0, k0, k1, accumulate),
                    }
                }
            }
        }
    }
}

/// One 8 x 32 block of `c` at `(i0, j0)` over k in `k0..k1` (whole k tiles): sixteen
/// accumulators; per pair of k values, two vectors of `b` and eight broadcast pairs of `a`,
/// read from `a` in [`PackedLeft::Pairs`]' order if `A_PAIRS`, else [`PackedLeft::Tiles`]'.
///
/// # Safety
/// The CPU has AVX-512 F and BF16; `i0 + 8 <= mp`, `j0 + 32 <= np`, `k1 <= kp` with `k0` and
/// `k1` multiples of [`K_STEP`]; `a` points to `mp x kp` packed values (read unaligned), `b`
/// holds `kp / 2 x np` pairs, and `c` at least `m x n`.
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn block<const A_PAIRS: bool>(
    c: &mut [f32],
    a: *const u32,
    b: &[u32],
    m: usize,
    n: usize,
    kp: usize,
    i0: usize,
    j0: usize,
    k0: usize,
    k1: usize,
    accumulate: bool,
) {
    // Valid columns of each of the two vectors, as load and store masks.
    let masks: [u16; 2] = std::array::from_fn(|v| {
        let valid = n.saturating_sub(j0 + 16 * v).min(16);
        ((1u32 << valid) - 1) as u16
    });
    let rows = m.saturating_sub(i0).min(ROWS);
    let mut acc = [_mm512_setzero_ps(); 2 * ROWS];
    if accumulate {
        for r in 0..rows {
            for v in 0..2 {
                if masks[v] != 0 {
                    // SAFETY: row i0 + r < m and column j0 + 16 v < n lie inside `c`; the
                    // mask reads only the columns below n (masked lanes are not accessed).
                    acc[2 * r + v] =
                        unsafe { _mm512_maskz_loadu_ps(masks[v], c.as_ptr().add((i0 + r) * n + j0 + 16 * v)) };
                }
            }
        }
    }
    for kt in k0 / K_STEP..k1 / K_STEP {
        // The 16 pairs of k tile kt: for the 8 rows of `a`, 16 contiguous pairs each, the
        // rows 64 bytes apart (i0 is a multiple of 8, so the 8 rows share one packed tile:
        // one base pointer, constant offsets); for each column block of `b`, one 64-byte
        // row of 16 pairs per pair row.
        // In the pairs' order, pair q of the 8 rows at k tile kt is 16 q + r from the tile's
        // first pair (i0 % 16 is 0 or 8: the 8 rows share one 16-column block).
        // SAFETY: row i0 < mp and k tile kt < kp / 32 index inside the packed `a` (the tiles'
        // index is even: i0 % 16 and kt * 32 are); pair row 16 kt < kp / 2 and columns j0,
        // j0 + 16 < np index inside `b`.
        let (pa, pb0, pb1) = unsafe {
            (
                if A_PAIRS { a.add(b_index(kt * K_STEP / 2, i0, kp)) } else { a.add(a_index(i0, kt * K_STEP, kp) / 2) },
                b.as_ptr().add(b_index(kt * K_STEP / 2, j0, kp)),
                b.as_ptr().add(b_index(kt * K_STEP / 2, j0 + 16, kp)),
            )
        };
        for q in 0..K_STEP / 2 {
            // SAFETY: 16 pairs at pair row 16 kt + q of each column block, inside `b`.
            let (b0, b1): (__m512bh, __m512bh) = unsafe {
                (
                    std::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(pb0.add(16 * q).cast())),
                    std::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(pb1.add(16 * q).cast())),
                )
            };
            for r in 0..ROWS {
                // SAFETY: pair q (values 2q, 2q + 1) of row i0 + r's k tile (in the tiles, 16
                // pairs per 64-byte row; in the pairs' order, 16 rows per 64 bytes), inside
                // `a`; a u16 buffer gives no 4-byte alignment, hence the unaligned read.
                let pair = unsafe { pa.add(if A_PAIRS { 16 * q + r } else { 16 * r + q }).read_unaligned() };
                // SAFETY: __m512i and __m512bh are both 512 plain bits.
                let av = unsafe { std::mem::transmute::<__m512i, __m512bh>(_mm512_set1_epi32(pair as i32)) };
                acc[2 * r] = _mm512_dpbf16_ps(acc[2 * r], av, b0);
                acc[2 * r + 1] = _mm512_dpbf16_ps(acc[2 * r + 1], av, b1);
            }
        }
    }
    for r in 0..rows {
        for v in 0..2 {
            if masks[v] != 0 {
                // SAFETY: as for the loads above.
                unsafe {
                    _mm512_mask_storeu_ps(c.as_mut_ptr().add((i0 + r) * n + j0 + 16 * v), masks[v], acc[2 * r + v]);
                }
            }
        }
    }
}
