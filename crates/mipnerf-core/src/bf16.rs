//! Mixed-precision matrix products: operands rounded to bf16, products accumulated in f32.
//!
//! bf16 keeps f32's 8-bit exponent and 7 of its 23 mantissa bits (8 significant bits with the
//! implicit one), so rounding an operand to it changes it by at most `2^-8` relatively
//! ([`BF16_UNIT_ROUNDOFF`]). Two kernels run the products ([`Bf16Kernel`]), on operands rounded
//! to bf16 by the same packing code and so with the same rounding:
//! - Intel's AMX tiles (`tdpbf16ps`: a 16 x 16 f32 block += a 16 x 32 bf16 block times a 32 x 16
//!   bf16 block, accumulated in f32), which on the Xeons these runs use do 33 times the f32 FMA
//!   rate of one core (3.7 TFLOP/s against 112 GFLOP/s, measured by `mipnerf bench --peak`);
//! - AVX-512 BF16 alone (`vdpbf16ps`: sixteen f32 lanes each += the dot product of a bf16 pair),
//!   on CPUs without AMX such as AMD Zen 4 and Zen 5. Each instruction does twice the flops of an
//!   f32 FMA; measured on an AMD EPYC (Zen 4) in `docs/results/precision/`. On the Sapphire
//!   Rapids Xeons it ran at the f32 rate, so AMX is preferred wherever both are present.
//!
//! [`Bf16Support::detect`] chooses the kernel and says why; without either, [`Precision::Bf16`]
//! is refused naming what is missing.
//!
//! What stays f32 (the parameters, Adam's state, the checkpoints, every non-matrix operation,
//! and the products too small to gain: fewer than [`MIN_BF16_DIM`] rows or columns, such as the
//! density and colour heads) is listed in [`matmul_bf16`]'s docs.
//!
//! [`matmul_bf16_emulated`] computes the same rounding on any CPU (operands rounded to bf16 as
//! f32 values, then the f32 product); it is the reference both kernels are tested against.
#![allow(unsafe_code)]

use std::cell::RefCell;
use std::sync::OnceLock;

use crate::linalg::{Layout, matmul};

/// Relative rounding error of one f32 -> bf16 conversion (round to nearest even): `2^-8`.
pub const BF16_UNIT_ROUNDOFF: f64 = 1.0 / 256.0;

/// Relative rounding error of one f32 operation: `2^-24`.
pub const F32_UNIT_ROUNDOFF: f64 = 1.0 / 16_777_216.0;

/// Products with fewer rows or output columns than this, or a shorter inner dimension, run in f32:
/// one 16 x 16 tile is the smallest unit of AMX work, and for these the packing costs more than
/// the product.
pub const MIN_BF16_DIM: usize = 16;

/// Set to `1`, this environment variable makes [`Bf16Support::detect`] report AMX as absent, so
/// that an AMX machine runs (and tests, and times) the AVX-512 BF16 kernel.
pub const DISABLE_AMX_ENV: &str = "MIPNERF_DISABLE_AMX";

/// Set to `1`, this environment variable makes [`Bf16Support::detect`] report AVX-512 BF16 as
/// absent (with [`DISABLE_AMX_ENV`], a CPU without any bf16 kernel, as the refusals are tested).
pub const DISABLE_AVX512_BF16_ENV: &str = "MIPNERF_DISABLE_AVX512_BF16";

/// The precision of the MLP's matrix products on the CPU.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// f32 throughout: the paper's precision and the reference.
    #[default]
    F32,
    /// bf16 operands and f32 accumulation for the MLP's matrix products (forward, input gradient
    /// and weight gradient); f32 everywhere else. The IPE features, rounded to bf16 before their
    /// only use, are evaluated in f32 arithmetic ([`crate::mip::integrated_pos_enc_for_bf16`])
    /// rather than through f64 as the reference does.
    Bf16,
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::F32 => "f32",
            Self::Bf16 => "bf16",
        })
    }
}

/// A kernel that runs the bf16 products.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Bf16Kernel {
    /// Intel AMX tiles (`tdpbf16ps`), with AVX-512 BF16 for the packing.
    Amx,
    /// AVX-512 BF16 (`vdpbf16ps`) alone: AMD Zen 4 and Zen 5, Intel Cooper Lake.
    Avx512,
}

impl Bf16Kernel {
    /// Both kernels, AMX first (the one [`Bf16Support::detect`] prefers).
    pub const ALL: [Self; 2] = [Self::Amx, Self::Avx512];

    /// The CPU feature the kernel is named by in logs: `AMX-BF16` or `AVX-512 BF16`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Amx => "AMX-BF16",
            Self::Avx512 => "AVX-512 BF16",
        }
    }

    /// Whether this CPU (and operating system) can run the kernel, whatever the environment
    /// variables say; the error names the missing feature as `/proc/cpuinfo` spells it
    /// (`amx_tile`, `amx_bf16`, `avx512_bf16`, ...). Cached.
    ///
    /// # Errors
    /// The reason the kernel cannot run here.
    pub fn check(self) -> Result<(), &'static str> {
        static AMX: OnceLock<Result<(), String>> = OnceLock::new();
        static AVX512: OnceLock<Result<(), String>> = OnceLock::new();
        let (cell, probe): (_, fn() -> Result<(), String>) = match self {
            Self::Amx => (&AMX, probe_amx),
            Self::Avx512 => (&AVX512, probe_avx512),
        };
        cell.get_or_init(probe).as_ref().map(|_| ()).map_err(String::as_str)
    }
}

fn probe_avx512() -> Result<(), String> {
    #[cfg(target_arch = "x86_64")]
    return avx512::detect();
    #[cfg(not(target_arch = "x86_64"))]
    Err("this CPU lacks avx512_bf16 (bf16 products need an x86_64 CPU with AVX-512 BF16 or AMX)".into())
}

fn probe_amx() -> Result<(), String> {
    #[cfg(target_arch = "x86_64")]
    return amx::detect();
    #[cfg(not(target_arch = "x86_64"))]
    Err("this CPU lacks amx_bf16 (Intel AMX needs an x86_64 CPU)".into())
}

/// Whether this CPU runs [`Precision::Bf16`] products, on which kernel, and if not, why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Bf16Support {
    /// The products run on this kernel.
    Available(Bf16Kernel),
    /// Not available; the reason names the missing CPU features or the refusal.
    Unavailable(String),
}

impl Bf16Support {
    /// Chooses the kernel once per process: AMX where the CPU has AMX-BF16 (CPUID leaf 7:
    /// `amx-tile`, `amx-bf16`; AVX-512 BF16 for the conversions) and Linux grants the tile state
    /// (`arch_prctl(ARCH_REQ_XCOMP_PERM, XTILEDATA)`), else AVX-512 BF16 where the CPU has
    /// `avx512f`, `avx512bw`, `avx512vl` and `avx512_bf16`, else unavailable, naming what each
    /// lacks. [`DISABLE_AMX_ENV`] and [`DISABLE_AVX512_BF16_ENV`] set to `1` report a kernel as
    /// absent (to compare the two, or to avoid a hypervisor's faulty AMX). Cached.
    #[must_use]
    pub fn detect() -> &'static Self {
        static SUPPORT: OnceLock<Bf16Support> = OnceLock::new();
        SUPPORT.get_or_init(|| {
            let switched_off = |env: &str| std::env::var(env).is_ok_and(|v| v == "1");
            let why_not = |kernel: Bf16Kernel, env: &str| -> Option<String> {
                if switched_off(env) {
                    return Some(format!("{} is switched off by {env}=1", kernel.name()));
                }
                kernel.check().err().map(str::to_string)
            };
            let Some(amx) = why_not(Bf16Kernel::Amx, DISABLE_AMX_ENV) else {
                return Self::Available(Bf16Kernel::Amx);
            };
            let Some(avx512) = why_not(Bf16Kernel::Avx512, DISABLE_AVX512_BF16_ENV) else {
                return Self::Available(Bf16Kernel::Avx512);
            };
            Self::Unavailable(format!("{amx}; {avx512}"))
        })
    }

    /// One line for logs: `bf16: AVX-512 BF16` or `bf16: unavailable (why)`.
    #[must_use]
    pub fn describe(&self) -> String {
        match self {
            Self::Available(kernel) => format!("bf16: {}", kernel.name()),
            Self::Unavailable(why) => format!("bf16: unavailable ({why})"),
        }
    }

    /// True where a kernel runs the products.
    #[must_use]
    pub fn available(&self) -> bool {
        matches!(self, Self::Available(_))
    }

    /// The kernel that runs the products, if any.
    #[must_use]
    pub fn kernel(&self) -> Option<Bf16Kernel> {
        match self {
            Self::Available(kernel) => Some(*kernel),
            Self::Unavailable(_) => None,
        }
    }
}

/// `x` rounded to bf16 (round to nearest, ties to even), as its 16 bits. Subnormal inputs become a
/// signed zero, as in `vcvtneps2bf16` and the AMX instructions; NaN stays NaN.
#[must_use]
#[inline]
pub fn f32_to_bf16_bits(x: f32) -> u16 {
    let bits = x.to_bits();
    if x.is_nan() {
        return ((bits >> 16) | 0x0040) as u16;
    }
    if bits & 0x7f80_0000 == 0 {
        // Zero exponent: zero or subnormal, read as a signed zero (as `vcvtneps2bf16` does).
        return ((bits >> 16) & 0x8000) as u16;
    }
    // A normal input rounds to a normal value or to infinity.
    (bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16) as u16
}

/// The f32 value of a bf16 bit pattern (exact).
#[must_use]
#[inline]
pub fn bf16_bits_to_f32(b: u16) -> f32 {
    f32::from_bits(u32::from(b) << 16)
}

/// `x` rounded to bf16 and back: the value a bf16 product sees.
#[must_use]
#[inline]
pub fn round_to_bf16(x: f32) -> f32 {
    bf16_bits_to_f32(f32_to_bf16_bits(x))
}

/// The error bound of one output element of a bf16 product with inner dimension `k`, relative to
/// `sum_p |a_ip| |b_pj|` (the exact sum of absolute products, computed in f64 by a test):
/// each operand is rounded once (`(1 + u)^2 - 1` for the product, `u` = [`BF16_UNIT_ROUNDOFF`]),
/// and the `k` products are summed in f32 in some order with one rounding per addition
/// (`gamma_k = k u32 / (1 - k u32)`, `u32` = [`F32_UNIT_ROUNDOFF`]). Valid for any summation
/// order, as long as no value is subnormal.
#[must_use]
pub fn bf16_product_relative_bound(k: usize) -> f64 {
    let u = BF16_UNIT_ROUNDOFF;
    let operands = (1.0 + u) * (1.0 + u) - 1.0;
    let ku = k as f64 * F32_UNIT_ROUNDOFF;
    let gamma = ku / (1.0 - ku);
    operands + gamma * (1.0 + operands)
}

/// Whether a product of this shape runs in bf16 (see [`MIN_BF16_DIM`]).
#[must_use]
pub fn uses_bf16(m: usize, k: usize, n: usize) -> bool {
    m >= MIN_BF16_DIM && n >= MIN_BF16_DIM && k >= MIN_BF16_DIM
}

/// `c (m x n) = [c +] a (m x k) · b (k x n)` as [`matmul`], with `a` and `b` rounded to bf16 and
/// the products accumulated in f32, on the kernel [`Bf16Support::detect`] chose. Shapes below
/// [`MIN_BF16_DIM`] run [`matmul`] in f32.
///
/// # Panics
/// If a slice is shorter than its shape needs, or if the CPU has no bf16 kernel
/// ([`Bf16Support::detect`]): callers choose [`Precision::Bf16`] only after checking it.
pub fn matmul_bf16(
    c: &mut [f32],
    a: &[f32],
    la: Layout,
    b: &[f32],
    lb: Layout,
    m: usize,
    k: usize,
    n: usize,
    accumulate: bool,
) {
    let kernel = Bf16Support::detect().kernel();
    let kernel = kernel.unwrap_or_else(|| panic!("matmul_bf16 without a bf16 kernel: {:?}", Bf16Support::detect()));
    matmul_bf16_on(kernel, c, a, la, b, lb, m, k, n, accumulate);
}

/// [`matmul_bf16`] on the given kernel, whichever [`Bf16Support::detect`] prefers: to test and
/// time each kernel on a CPU that has both.
///
/// # Panics
/// If a slice is shorter than its shape needs, if a size product overflows, or if the CPU cannot
/// run `kernel` ([`Bf16Kernel::check`]).
pub fn matmul_bf16_on(
    kernel: Bf16Kernel,
    c: &mut [f32],
    a: &[f32],
    la: Layout,
    b: &[f32],
    lb: Layout,
    m: usize,
    k: usize,
    n: usize,
    accumulate: bool,
) {
    if !uses_bf16(m, k, n) {
        matmul(c, a, la, b, lb, m, k, n, accumulate);
        return;
    }
    let size = crate::linalg::checked_len;
    assert!(c.len() >= size(m, n), "matmul_bf16: c has {} < {m}x{n}", c.len());
    assert!(a.len() >= size(m, k), "matmul_bf16: a has {} < {m}x{k}", a.len());
    assert!(b.len() >= size(k, n), "matmul_bf16: b has {} < {k}x{n}", b.len());
    if let Err(why) = kernel.check() {
        panic!("matmul_bf16 on {}: {why}", kernel.name());
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!("no bf16 kernel passes its check off x86_64");
    #[cfg(target_arch = "x86_64")]
    PACKED.with(|p| {
        let p = &mut *p.borrow_mut();
        let (mp, kp, np) = (m.next_multiple_of(BLOCK), k.next_multiple_of(K_STEP), n.next_multiple_of(BLOCK));
        simd::pack_pairs(&mut p.b, b, lb, k, n, kp, np);
        match (kernel, la) {
            (Bf16Kernel::Amx, _) => {
                simd::pack_rows(&mut p.a, a, la, m, k, mp, kp);
                amx::product(c, &p.a, &p.b, m, n, mp, kp, np, accumulate);
            }
            (Bf16Kernel::Avx512, Layout::Normal) => {
                simd::pack_rows(&mut p.a, a, la, m, k, mp, kp);
                avx512::product(c, avx512::PackedA::Tiles(&p.a), &p.b, m, n, mp, kp, np, accumulate);
            }
            // `a` stored `k x m` (a weight gradient's activations): its pairs along k are packed
            // as `b`'s are, with no transpose, and the kernel reads them in that order.
            (Bf16Kernel::Avx512, Layout::Transposed) => {
                simd::pack_pairs(&mut p.a_pairs, a, Layout::Normal, k, m, kp, mp);
                avx512::product(c, avx512::PackedA::Pairs(&p.a_pairs), &p.b, m, n, mp, kp, np, accumulate);
            }
        }
    });
}

/// The packed operands' row and column padding: 2 x 2 tiles of 16 x 16 (AMX's block per step;
/// the AVX-512 kernel's 8 x 32 steps divide it).
const BLOCK: usize = 32;
/// The packed operands' padding of k: the bf16 values of k per tile multiply-add.
const K_STEP: usize = 32;

/// What every kernel's `product` rests its `unsafe` code on: the CPU runs `kernel`, the padded
/// sizes are whole blocks at least the real ones, and the packed `a` (`a_values`, at least
/// `mp x kp` bf16 values), the packed `b` (`kp / 2 x np` pairs) and `c` (`m x n`) are that large
/// (sizes checked against overflow).
#[cfg(target_arch = "x86_64")]
fn assert_packed(
    kernel: Bf16Kernel,
    c: &[f32],
    a_values: usize,
    b: &[u32],
    m: usize,
    n: usize,
    mp: usize,
    kp: usize,
    np: usize,
) {
    if let Err(why) = kernel.check() {
        panic!("the {} kernel on a CPU without it: {why}", kernel.name());
    }
    assert!(mp.is_multiple_of(BLOCK) && np.is_multiple_of(BLOCK) && kp.is_multiple_of(K_STEP));
    assert!(mp >= m && np >= n);
    let size = crate::linalg::checked_len;
    assert!(a_values >= size(mp, kp) && b.len() >= size(kp / 2, np) && c.len() >= size(m, n));
}

/// The same rounding as [`matmul_bf16`] on any CPU: `a` and `b` rounded to bf16 (as f32 values),
/// then the f32 product. Differs from the AMX kernel only in the order of the f32 additions.
pub fn matmul_bf16_emulated(
    c: &mut [f32],
    a: &[f32],
    la: Layout,
    b: &[f32],
    lb: Layout,
    m: usize,
    k: usize,
    n: usize,
    accumulate: bool,
) {
    if !uses_bf16(m, k, n) {
        matmul(c, a, la, b, lb, m, k, n, accumulate);
        return;
    }
    let a: Vec<f32> = a[..crate::linalg::checked_len(m, k)].iter().map(|&x| round_to_bf16(x)).collect();
    let b: Vec<f32> = b[..crate::linalg::checked_len(k, n)].iter().map(|&x| round_to_bf16(x)).collect();
    matmul(c, &a, la, &b, lb, m, k, n, accumulate);
}

/// Per-thread packing buffers, kept between products.
#[derive(Default)]
struct Packed {
    /// `a` as bf16, `mp x kp` row-major, zero-padded.
    a: Vec<u16>,
    /// `b` as pairs of bf16 along k (AMX's "VNNI" layout): `kp / 2` rows of `np` 32-bit pairs.
    b: Vec<u32>,
    /// `a` stored transposed, for the AVX-512 kernel: laid out as `b` is ([`b_index`], `a`'s
    /// rows as the columns), `kp / 2` rows of `mp` pairs.
    a_pairs: Vec<u32>,
}

thread_local! {
    static PACKED: RefCell<Packed> = RefCell::new(Packed::default());
}

/// Where element `(i, p)` of `a` goes in the packed `a` (`mp x kp`, bf16): tile after tile, each
/// tile 16 rows x 32 values of k, 64 contiguous bytes per row, the k tiles of a 16-row block
/// in order. One tile is 1 KiB read at a stride of 64 bytes, which keeps the tiles of a product
/// in distinct cache sets.
#[inline]
fn a_index(i: usize, p: usize, kp: usize) -> usize {
    ((i / 16) * (kp / 32) + p / 32) * 512 + (i % 16) * 32 + p % 32
}

/// Where pair row `q` (k = 2q, 2q + 1), column `j` of `b` goes in the packed `b` (`kp/2 x np`
/// 32-bit pairs): blocks of 16 columns, each `kp / 2` rows of 64 bytes, so that one tile (16
/// pair rows x 16 columns) is 1 KiB contiguous.
#[inline]
fn b_index(q: usize, j: usize, kp: usize) -> usize {
    ((j / 16) * (kp / 2) + q) * 16 + j % 16
}

/// Packs `a (m x k)` into `out` as bf16 at [`a_index`], zero-padded to `mp x kp`. The scalar
/// reference of [`simd::pack_rows`].
#[cfg_attr(not(test), allow(dead_code))]
fn pack_rows(out: &mut Vec<u16>, a: &[f32], la: Layout, m: usize, k: usize, mp: usize, kp: usize) {
    out.clear();
    out.resize(mp * kp, 0);
    for i in 0..m {
        for p in 0..k {
            let x = if la == Layout::Normal { a[i * k + p] } else { a[p * m + i] };
            out[a_index(i, p, kp)] = f32_to_bf16_bits(x);
        }
    }
}

/// Packs `b (k x n)` into `out`: pairs `(b[2q][j], b[2q + 1][j])`, the first in the low 16 bits,
/// at [`b_index`], zero-padded to `kp/2 x np` (`out` only grows: what lies past that is left as
/// it was). The scalar reference of [`simd::pack_pairs`], which uses it for the transposed case
/// (a layer's kernel: small).
fn pack_pairs(out: &mut Vec<u32>, b: &[f32], lb: Layout, k: usize, n: usize, kp: usize, np: usize) {
    let len = kp / 2 * np;
    grow(out, len);
    out[..len].fill(0);
    for p in 0..k {
        for j in 0..n {
            let x = if lb == Layout::Normal { b[p * n + j] } else { b[j * k + p] };
            out[b_index(p / 2, j, kp)] |= u32::from(f32_to_bf16_bits(x)) << (16 * (p % 2));
        }
    }
}

/// Lengthens `out` to `len` if it is shorter; never shortens it. The packing buffers hold large
/// operands and small ones in turn: kept long, they are not zeroed again each time.
fn grow<T: Copy + Default>(out: &mut Vec<T>, len: usize) {
    if out.len() < len {
        out.resize(len, T::default());
    }
}

/// The packing with AVX-512 (`vcvtneps2bf16`), which both kernels need (every AMX-BF16 processor
/// has it; [`Bf16Kernel::check`] checks it): the same bits as the scalar [`pack_rows`] and
/// [`pack_pairs`] (a test compares them).
#[cfg(target_arch = "x86_64")]
mod simd {
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
            31, 15, 30, 14, 29, 13, 28, 12, 27, 11, 26, 10, 25, 9, 24, 8, 23, 7, 22, 6, 21, 5, 20, 4, 19, 3, 18, 2, 17,
            1, 16, 0,
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
}

/// The AMX kernel. Every `unsafe` block is here and justified where it is.
#[cfg(target_arch = "x86_64")]
mod amx {
    use std::arch::asm;

    use super::{BLOCK, K_STEP};

    /// Whether this CPU and operating system run the AMX kernel, and if not, why.
    pub(super) fn detect() -> Result<(), String> {
        {
            // CPUID leaf 7 exists when leaf 0 reports a maximum leaf of at least 7.
            let edx =
                if std::arch::x86_64::__cpuid(0).eax >= 7 { std::arch::x86_64::__cpuid_count(7, 0).edx } else { 0 };
            let (tile, bf16) = (edx & (1 << 24) != 0, edx & (1 << 22) != 0);
            if !tile || !bf16 {
                return Err(format!("this CPU lacks {} (Intel AMX)", if tile { "amx_bf16" } else { "amx_tile" }));
            }
            // The packing converts to bf16 with AVX-512, which the AVX-512 kernel's check covers.
            if let Err(why) = super::Bf16Kernel::Avx512.check() {
                return Err(format!("this CPU has AMX, but for the conversions to bf16 {why}"));
            }
            if !cfg!(target_os = "linux") {
                return Err("AMX tiles are only enabled on Linux in this build".into());
            }
            let ret = request_tile_permission();
            if ret != 0 {
                return Err(format!(
                    "the operating system refused the AMX tile state (arch_prctl returned {ret}; Linux 5.16 or later \
                     is needed)"
                ));
            }
            Ok(())
        }
    }

    /// `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`: Linux grants the process the AMX
    /// tile data state (required before the first tile instruction, or the process is killed).
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    fn request_tile_permission() -> i64 {
        const SYS_ARCH_PRCTL: i64 = 158;
        const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
        const XFEATURE_XTILEDATA: i64 = 18;
        let ret: i64;
        // SAFETY: a raw Linux system call that takes two integers and touches no memory of ours;
        // rcx and r11 are clobbered by `syscall` and declared so.
        unsafe {
            asm!(
                "syscall",
                inlateout("rax") SYS_ARCH_PRCTL => ret,
                in("rdi") ARCH_REQ_XCOMP_PERM,
                in("rsi") XFEATURE_XTILEDATA,
                lateout("rcx") _,
                lateout("r11") _,
                options(nostack),
            );
        }
        ret
    }
    #[cfg(all(target_arch = "x86_64", not(target_os = "linux")))]
    fn request_tile_permission() -> i64 {
        -1
    }

    /// Tile configuration (palette 1): 8 tiles of 16 rows x 64 bytes.
    #[repr(C, align(64))]
    struct TileConfig([u8; 64]);

    impl TileConfig {
        fn all_16x64() -> Self {
            let mut c = [0u8; 64];
            c[0] = 1;
            for t in 0..8 {
                c[16 + 2 * t] = 64;
                c[48 + t] = 16;
            }
            Self(c)
        }
    }

    /// `c (m x n, row-major) = [c +] A · B` from the packed operands ([`super::a_index`],
    /// [`super::b_index`]). Tiles: tmm0..3 accumulate a 32 x 32 block of `c`, tmm4/5 hold two
    /// 16-row tiles of `a`, tmm6/7 two 16-column tiles of `b`. A block inside `c` is loaded
    /// (when accumulating) and stored in place; a block on the ragged edge goes through a
    /// scratch block.
    pub(super) fn product(
        c: &mut [f32],
        a: &[u16],
        b: &[u32],
        m: usize,
        n: usize,
        mp: usize,
        kp: usize,
        np: usize,
        accumulate: bool,
    ) {
        super::assert_packed(super::Bf16Kernel::Amx, c, a.len(), b, m, n, mp, kp, np);
        let cfg = TileConfig::all_16x64();
        let k_tiles = kp / K_STEP;
        let mut scratch = [0f32; BLOCK * BLOCK];
        // SAFETY: the process holds the tile permission (the check above), and the
        // configuration is a valid palette-1 layout; no other code in this program uses tiles.
        unsafe { asm!("ldtilecfg [{}]", in(reg) cfg.0.as_ptr(), options(nostack, readonly)) };
        for i0 in (0..mp).step_by(BLOCK) {
            for j0 in (0..np).step_by(BLOCK) {
                let inside = i0 + BLOCK <= m && j0 + BLOCK <= n;
                // The block's top-left f32 and row stride in bytes: in `c`, or in the scratch.
                let (base, stride) = if inside {
                    (c[i0 * n + j0..].as_mut_ptr(), n * 4)
                } else {
                    if accumulate {
                        for r in 0..BLOCK.min(m - i0.min(m)) {
                            let cols = BLOCK.min(n - j0.min(n));
                            scratch[r * BLOCK..r * BLOCK + cols].copy_from_slice(&c[(i0 + r) * n + j0..][..cols]);
                        }
                    }
                    (scratch.as_mut_ptr(), BLOCK * 4)
                };
                // SAFETY: 32 rows x 32 f32 at `stride` from `base` lie inside `c` (the block is
                // inside: i0 + 32 <= m, j0 + 32 <= n) or inside the 32 x 32 scratch.
                unsafe {
                    if accumulate {
                        asm!(
                            "tileloadd tmm0, [{p0} + {s}]",
                            "tileloadd tmm1, [{p1} + {s}]",
                            "tileloadd tmm2, [{p2} + {s}]",
                            "tileloadd tmm3, [{p3} + {s}]",
                            p0 = in(reg) base,
                            p1 = in(reg) base.add(16),
                            p2 = in(reg) base.add(16 * stride / 4),
                            p3 = in(reg) base.add(16 * stride / 4 + 16),
                            s = in(reg) stride,
                            options(nostack, readonly),
                        );
                    } else {
                        asm!(
                            "tilezero tmm0",
                            "tilezero tmm1",
                            "tilezero tmm2",
                            "tilezero tmm3",
                            options(nostack, nomem)
                        );
                    }
                }
                for kt in 0..k_tiles {
                    let pa = a[super::a_index(i0, kt * K_STEP, kp)..].as_ptr();
                    let pa1 = a[super::a_index(i0 + 16, kt * K_STEP, kp)..].as_ptr();
                    let pb = b[super::b_index(kt * K_STEP / 2, j0, kp)..].as_ptr();
                    let pb1 = b[super::b_index(kt * K_STEP / 2, j0 + 16, kp)..].as_ptr();
                    // SAFETY: each load reads one packed tile, 16 rows of 64 contiguous bytes
                    // (1 KiB) from its first element: a tiles (rows i0.. and i0 + 16.., k tile
                    // kt) and b tiles (pair rows 16 kt.., columns j0.. and j0 + 16..) lie inside
                    // the packed buffers, whose sizes are asserted above.
                    unsafe {
                        asm!(
                            "tileloadd tmm4, [{pa} + {s}]",
                            "tileloadd tmm6, [{pb} + {s}]",
                            "tdpbf16ps tmm0, tmm4, tmm6",
                            "tileloadd tmm7, [{pb1} + {s}]",
                            "tdpbf16ps tmm1, tmm4, tmm7",
                            "tileloadd tmm5, [{pa1} + {s}]",
                            "tdpbf16ps tmm2, tmm5, tmm6",
                            "tdpbf16ps tmm3, tmm5, tmm7",
                            pa = in(reg) pa,
                            pa1 = in(reg) pa1,
                            pb = in(reg) pb,
                            pb1 = in(reg) pb1,
                            s = in(reg) 64usize,
                            options(nostack, readonly),
                        );
                    }
                }
                // SAFETY: as for the loads of the block above.
                unsafe {
                    asm!(
                        "tilestored [{p0} + {s}], tmm0",
                        "tilestored [{p1} + {s}], tmm1",
                        "tilestored [{p2} + {s}], tmm2",
                        "tilestored [{p3} + {s}], tmm3",
                        p0 = in(reg) base,
                        p1 = in(reg) base.add(16),
                        p2 = in(reg) base.add(16 * stride / 4),
                        p3 = in(reg) base.add(16 * stride / 4 + 16),
                        s = in(reg) stride,
                        options(nostack),
                    );
                }
                if !inside {
                    let cols = BLOCK.min(n.saturating_sub(j0));
                    for r in 0..BLOCK.min(m.saturating_sub(i0)) {
                        c[(i0 + r) * n + j0..][..cols].copy_from_slice(&scratch[r * BLOCK..r * BLOCK + cols]);
                    }
                }
            }
        }
        // SAFETY: returns the tile state to its initial configuration.
        unsafe { asm!("tilerelease", options(nostack, nomem)) };
    }
}

/// The AVX-512 BF16 kernel (`vdpbf16ps`), on the packed operands the AMX kernel reads, except
/// a transposed `a`, which it reads in pairs ([`PackedA::Pairs`]) rather than transposed into
/// AMX's tiles. Every `unsafe` block is here and justified where it is.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::{
        __m512bh, __m512i, _mm512_dpbf16_ps, _mm512_loadu_si512, _mm512_mask_storeu_ps, _mm512_maskz_loadu_ps,
        _mm512_set1_epi32, _mm512_setzero_ps,
    };

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

    /// The packed `a`, in one of two orders; the kernel reads the pair of k values `(2q, 2q + 1)`
    /// of a row from either.
    pub(super) enum PackedA<'a> {
        /// [`a_index`]'s tiles (the AMX kernel's), from `a` stored `m x k`: a row's pairs are
        /// contiguous.
        Tiles(&'a [u16]),
        /// [`b_index`]'s order with `a`'s rows as the columns, from `a` stored `k x m` (packed
        /// without a transpose): the pairs of 16 rows at one `q` are contiguous.
        Pairs(&'a [u32]),
    }

    /// `c (m x n, row-major) = [c +] A · B` from the packed operands ([`PackedA`], [`b_index`]):
    /// k in passes of [`KC`], each pass sweeping the output in 8 x 32 blocks held in sixteen
    /// registers. Rows and columns past `m` and `n` are computed on the zero padding and
    /// neither read nor written in `c`.
    pub(super) fn product(
        c: &mut [f32],
        a: PackedA<'_>,
        b: &[u32],
        m: usize,
        n: usize,
        mp: usize,
        kp: usize,
        np: usize,
        accumulate: bool,
    ) {
        let a_values = match a {
            PackedA::Tiles(a) => a.len(),
            PackedA::Pairs(a) => a.len().saturating_mul(2),
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
                            PackedA::Tiles(a) => {
                                block::<false>(c, a.as_ptr().cast(), b, m, n, kp, i0, j0, k0, k1, accumulate);
                            }
                            PackedA::Pairs(a) => block::<true>(c, a.as_ptr(), b, m, n, kp, i0, j0, k0, k1, accumulate),
                        }
                    }
                }
            }
        }
    }

    /// One 8 x 32 block of `c` at `(i0, j0)` over k in `k0..k1` (whole k tiles): sixteen
    /// accumulators; per pair of k values, two vectors of `b` and eight broadcast pairs of `a`,
    /// read from `a` in [`PackedA::Pairs`]' order if `A_PAIRS`, else [`PackedA::Tiles`]'.
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
                    if A_PAIRS {
                        a.add(b_index(kt * K_STEP / 2, i0, kp))
                    } else {
                        a.add(a_index(i0, kt * K_STEP, kp) / 2)
                    },
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_is_to_nearest_even_with_subnormals_flushed() {
        assert_eq!(round_to_bf16(1.0), 1.0);
        // 1 + 2^-8 is halfway between 1 and 1 + 2^-7: ties to the even (1).
        assert_eq!(round_to_bf16(1.0 + 1.0 / 256.0), 1.0);
        // 1 + 3 * 2^-8 is halfway between 1 + 2^-7 and 1 + 2^-6: ties to even (1 + 2^-6).
        assert_eq!(round_to_bf16(1.0 + 3.0 / 256.0), 1.0 + 1.0 / 64.0);
        assert_eq!(round_to_bf16(1.0 + 1.0 / 256.0 + 1e-6), 1.0 + 1.0 / 128.0);
        assert_eq!(round_to_bf16(-2.5), -2.5);
        assert_eq!(round_to_bf16(1e-39).to_bits(), 0);
        assert_eq!(round_to_bf16(-1e-39).to_bits(), (-0.0f32).to_bits());
        assert!(round_to_bf16(f32::NAN).is_nan());
        assert_eq!(round_to_bf16(f32::INFINITY), f32::INFINITY);
        assert_eq!(round_to_bf16(f32::MAX), f32::INFINITY);
        for x in [0.1f32, 3.7, -1234.5, 6.02e23, 1.5e-30] {
            let r = round_to_bf16(x);
            assert!((f64::from(r) - f64::from(x)).abs() <= BF16_UNIT_ROUNDOFF * f64::from(x).abs(), "{x} -> {r}");
        }
    }
}
