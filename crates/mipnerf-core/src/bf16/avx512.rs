use std::arch::x86_64::{
    __m512, __m512bh, __m512i, _mm512_dpbf16_ps, _mm512_fmadd_ps, _mm512_loadu_si512, _mm512_mask_storeu_ps,
    _mm512_maskz_loadu_ps, _mm512_set1_epi32, _mm512_set1_ps, _mm512_setzero_ps,
};
use std::hint::black_box;
use std::time::{Duration, Instant};

use super::packed::PackedLeft;
use super::{K_STEP, PackedShape, a_index, b_index};

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

/// Instructions per timed run of [`dot_flop_rate_against_fma`]: 16 independent chains of
/// 65,536 each, about a millisecond on the slowest CPU measured.
const RATE_ROUNDS: usize = 1 << 16;

/// Timed runs of each instruction in [`dot_flop_rate_against_fma`], alternated; the fastest
/// of each counts (the first may run before the core reaches its AVX-512 clock).
const RATE_RUNS: usize = 5;

/// The flop rate of `vdpbf16ps` (16 lanes, each two multiplies and two adds) over that of the
/// f32 FMA `vfmadd231ps` (16 lanes, one of each) on 512-bit registers, on this core, measured
/// now: each instruction on 16 independent accumulators, so that throughput and not latency
/// bounds both. About 2 on AMD Zen 4 (each does twice the FMA's flops at the same rate), 0.5 on
/// an Intel Xeon (Emerald Rapids) with AMX switched off (`docs/results/precision/intel-avx512/`).
/// Takes a few milliseconds.
///
/// # Panics
/// Without AVX-512 F and BF16 ([`detect`] says what is missing).
pub(super) fn dot_flop_rate_against_fma() -> f64 {
    assert!(detect().is_ok(), "dot_flop_rate_against_fma without AVX-512 BF16: {:?}", detect());
    let (mut dots, mut fmas) = (Duration::MAX, Duration::MAX);
    for _ in 0..RATE_RUNS {
        // SAFETY: the CPU has AVX-512 F and BF16 (asserted above).
        unsafe {
            dots = dots.min(time_dots(RATE_ROUNDS));
            fmas = fmas.min(time_fmas(RATE_ROUNDS));
        }
    }
    // Per instruction, a dot does twice the flops of an FMA.
    2.0 * fmas.as_secs_f64() / dots.as_secs_f64().max(f64::MIN_POSITIVE)
}

/// The time of `16 rounds` `vdpbf16ps` in 16 independent chains.
///
/// # Safety
/// The CPU has AVX-512 F and BF16.
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn time_dots(rounds: usize) -> Duration {
    // Pairs of 1.0 times pairs of 2^-100: each step adds 2^-99 to accumulators at 1.0, which it
    // leaves unchanged (nothing overflows or goes subnormal to slow a CPU down).
    // SAFETY: __m512i and __m512bh are both 512 plain bits.
    let to_pairs = |v: __m512i| -> __m512bh { unsafe { std::mem::transmute::<__m512i, __m512bh>(v) } };
    let a = to_pairs(black_box(_mm512_set1_epi32(0x3f80_3f80)));
    let b = to_pairs(black_box(_mm512_set1_epi32(0x0d80_0d80)));
    time_chains(rounds, |acc| _mm512_dpbf16_ps(acc, a, b))
}

/// The time of `16 rounds` `vfmadd231ps` in 16 independent chains.
///
/// # Safety
/// The CPU has AVX-512 F.
#[target_feature(enable = "avx512f")]
unsafe fn time_fmas(rounds: usize) -> Duration {
    // 1.0 times 2^-100 added to accumulators at 1.0, as for the dots.
    let (a, b) = (black_box(_mm512_set1_ps(1.0)), black_box(_mm512_set1_ps(f32::powi(2.0, -100))));
    time_chains(rounds, |acc| _mm512_fmadd_ps(a, b, acc))
}

/// The time of `16 rounds` `step`s in 16 independent chains of accumulators held in registers.
/// Inlined into its callers, so that `step` is compiled with their target features.
#[inline(always)]
fn time_chains(rounds: usize, step: impl Fn(__m512) -> __m512) -> Duration {
    // SAFETY: _mm512_set1_ps only sets a register's value (the callers have AVX-512 F).
    let mut acc: [__m512; 16] = black_box([unsafe { _mm512_set1_ps(1.0) }; 16]);
    let start = Instant::now();
    for _ in 0..rounds {
        for a in &mut acc {
            *a = step(*a);
        }
    }
    let elapsed = start.elapsed();
    black_box(acc);
    elapsed
}

/// `c (m x n, row-major) = [c +] A · B` from the packed operands ([`PackedLeft`], [`b_index`]):
/// k in passes of [`KC`], each pass sweeping the output in 8 x 32 blocks held in sixteen
/// registers. Rows and columns past `m` and `n` are computed on the zero padding and
/// neither read nor written in `c`.
pub(super) fn product(c: &mut [f32], a: PackedLeft<'_>, b: &[u32], shape: PackedShape) {
    let a_values = match a {
        PackedLeft::Tiles(a) => a.len(),
        PackedLeft::Pairs(a) => a.len().saturating_mul(2),
    };
    super::assert_packed(super::Bf16Kernel::Avx512, c, a_values, b, shape);
    // SAFETY: the CPU has AVX-512 F and BF16 and the sizes are asserted (above).
    unsafe { sweep(c, a, b, shape) };
}

/// Where one block of [`block`] lies: its first row and column, and the range of k it sums.
#[derive(Clone, Copy, Debug)]
struct BlockAt {
    i0: usize,
    j0: usize,
    k0: usize,
    k1: usize,
}

/// [`product`]'s passes and blocks, compiled with the kernel's features so that [`block`] is
/// inlined into its loop.
///
/// # Safety
/// As [`product`]'s asserts: the CPU has AVX-512 F and BF16, and the buffers are as large as
/// the padded sizes need.
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn sweep(c: &mut [f32], a: PackedLeft<'_>, b: &[u32], shape: PackedShape) {
    let PackedShape { m, n, kp, accumulate, .. } = shape;
    let a_bytes: (*const u8, usize) = match a {
        PackedLeft::Tiles(a) => (a.as_ptr().cast(), size_of_val(a)),
        PackedLeft::Pairs(a) => (a.as_ptr().cast(), size_of_val(a)),
    };
    let column_blocks = n.div_ceil(COLS);
    for k0 in (0..kp).step_by(KC) {
        let k1 = (k0 + KC).min(kp);
        for i0 in (0..m).step_by(ROWS) {
            for (jb, j0) in (0..n).step_by(COLS).enumerate() {
                prefetch_next_rows(a_bytes, i0, jb, column_blocks, kp, k0..k1);
                prefetch_next_output(c, i0 + ROWS, j0, n);
                let block_shape = PackedShape { accumulate: accumulate || k0 > 0, ..shape };
                let at = BlockAt { i0, j0, k0, k1 };
                // SAFETY: the CPU has AVX-512 F and BF16 (asserted in `product`); the block's rows
                // lie below mp and its columns below np (m <= mp, n <= np, both multiples of
                // the block), k0..k1 below kp, and the sizes of the buffers are asserted.
                unsafe {
                    match a {
                        PackedLeft::Tiles(a) => block::<false>(c, a.as_ptr().cast(), b, block_shape, at),
                        PackedLeft::Pairs(a) => block::<true>(c, a.as_ptr(), b, block_shape, at),
                    }
                }
            }
        }
    }
}

/// Prefetches into L1 the share of the next 16-row group of the packed `a`, over the pass's
/// values of k, that block `jb` of the `column_blocks` blocks of row block `i0` is due: those
/// lines are spread over the two row blocks of the present group, so that the next group is in
/// L1 before the first block reads it. Both layouts keep a group contiguous (16 rows of `kp`
/// bf16 values) and k within it in 32-byte steps per value pair of the 16 rows: k tile by k
/// tile in [`PackedLeft::Tiles`], pair row by pair row in [`PackedLeft::Pairs`]. `a` is the
/// packed operand's first byte and its length in bytes.
#[inline(always)]
fn prefetch_next_rows(
    a: (*const u8, usize),
    i0: usize,
    jb: usize,
    column_blocks: usize,
    kp: usize,
    k: std::ops::Range<usize>,
) {
    use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
    let start = (i0 / 16 + 1) * 32 * kp + 32 * k.start;
    let lines = 32 * k.len() / 64;
    let share = lines.div_ceil(2 * column_blocks);
    let first = ((i0 / ROWS) % 2 * column_blocks + jb) * share;
    for line in first..(first + share).min(lines) {
        let at = start + 64 * line;
        if at < a.1 {
            // SAFETY: a prefetch changes nothing the program sees; the address is inside `a`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(a.0.wrapping_add(at).cast()) };
        }
    }
}

/// Prefetches, for writing, the block of `c` at `(i0, j0)`: 8 rows of 32 values.
#[inline(always)]
fn prefetch_next_output(c: &[f32], i0: usize, j0: usize, n: usize) {
    use std::arch::x86_64::{_MM_HINT_ET0, _mm_prefetch};
    for r in i0..i0 + ROWS {
        for v in [j0, j0 + 16] {
            if v < n
                && let Some(p) = c.get(r * n + v)
            {
                // SAFETY: a prefetch changes nothing the program sees; the address is inside `c`.
                unsafe { _mm_prefetch::<_MM_HINT_ET0>(std::ptr::from_ref(p).cast()) };
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
#[inline]
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn block<const A_PAIRS: bool>(c: &mut [f32], a: *const u32, b: &[u32], shape: PackedShape, at: BlockAt) {
    let PackedShape { m, n, kp, accumulate, .. } = shape;
    let BlockAt { i0, j0, k0, k1 } = at;
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
