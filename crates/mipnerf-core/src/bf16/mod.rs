//! Mixed-precision matrix products: operands rounded to bf16, products accumulated in f32.
//!
//! bf16 keeps f32's 8-bit exponent and 7 of its 23 mantissa bits (8 significant bits with the
//! implicit one), so rounding an operand to it changes it by at most `2^-8` relatively
//! ([`BF16_UNIT_ROUNDOFF`]). Two kernels run the products ([`Bf16Kernel`]), on operands rounded
//! to bf16 by the same packing code and so with the same rounding:
//! - Intel's AMX tiles (`tdpbf16ps`: a 16 x 16 f32 block += a 16 x 32 bf16 block times a 32 x 16
//!   bf16 block, accumulated in f32). On one core of an Intel Xeon (Emerald Rapids) the MLP's
//!   products ran 1.5x to 3.4x gemm's f32 GFLOP/s with them, the packing included
//!   (`cargo bench -p mipnerf-core --bench products`, `docs/results/precision/intel-avx512/`);
//! - AVX-512 BF16 alone (`vdpbf16ps`: sixteen f32 lanes each += the dot product of a bf16 pair),
//!   on CPUs without AMX such as AMD Zen 4 and Zen 5. Each instruction does twice the flops of an
//!   f32 FMA; on an AMD EPYC (Zen 4) at about the FMA's rate, so up to twice its flops
//!   (`docs/results/precision/`). On an Intel Xeon (Emerald Rapids) it runs at a quarter of the
//!   FMA's rate, half its flops (`docs/results/precision/intel-avx512/`): AMX is preferred
//!   wherever both are present, and `--precision auto` takes this kernel only where it outruns
//!   f32 ([`Bf16Support::auto`]).
//!
//! [`Bf16Support::detect`] chooses the kernel and says why; without either, [`Precision::Bf16`]
//! is refused naming what is missing. [`Bf16Support::auto`] says what `--precision auto` runs.
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

use crate::linalg::{Layout, Product, matmul};
use crate::lines::Lines;

use packed::PackedLeft;
pub use packed::{Bf16Matrix, Operand, PACK_BLOCK_ROWS, Reads};

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

    /// What `--precision auto` runs here, decided once per process: bf16 on AMX; bf16 on
    /// AVX-512 BF16 where `vdpbf16ps` does at least [`AVX512_BF16_MIN_FLOP_RATE`] times the f32
    /// FMA's flops per second (measured the first time this is called, a few milliseconds);
    /// otherwise f32, saying why. `--precision bf16` runs the kernel whatever its rate.
    #[must_use]
    pub fn auto() -> &'static AutoPrecision {
        static AUTO: OnceLock<AutoPrecision> = OnceLock::new();
        AUTO.get_or_init(|| {
            Self::detect().auto_with(|| avx512_dot_flop_rate_against_fma().expect("AVX-512 BF16 was detected"))
        })
    }

    /// [`Bf16Support::auto`]'s choice for this support, with `dot_flop_rate` measuring the rate of
    /// `vdpbf16ps` against the FMA (called only for the AVX-512 BF16 kernel).
    #[must_use]
    pub fn auto_with(&self, dot_flop_rate: impl FnOnce() -> f64) -> AutoPrecision {
        match self {
            Self::Unavailable(why) => AutoPrecision::F32(why.clone()),
            Self::Available(Bf16Kernel::Amx) => AutoPrecision::Bf16(Bf16Kernel::Amx),
            Self::Available(Bf16Kernel::Avx512) => {
                let rate = dot_flop_rate();
                if rate >= AVX512_BF16_MIN_FLOP_RATE {
                    AutoPrecision::Bf16(Bf16Kernel::Avx512)
                } else {
                    AutoPrecision::F32(format!(
                        "AVX-512 BF16 would train slower than f32 here: vdpbf16ps does {rate:.2}x the flops per \
                         second of the f32 FMA on this CPU, measured now, under the {AVX512_BF16_MIN_FLOP_RATE:.1}x \
                         it needs; --precision bf16 runs it anyway"
                    ))
                }
            }
        }
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

/// `--precision auto` takes the AVX-512 BF16 kernel only where `vdpbf16ps` does at least this
/// many times the flops per second of the f32 FMA on this CPU
/// ([`avx512_dot_flop_rate_against_fma`]). Below it the bf16 products alone are slower than
/// f32's, before their operands are packed: on an Intel Xeon (Emerald Rapids) with AMX switched
/// off the rate is about 0.5, and bf16 trains every preset slower (fast 0.90x, small 0.85x,
/// paper 0.66x, `docs/results/precision/intel-avx512/`); on AMD Zen 4 it is about 2 and bf16
/// trains faster (1.4x to 1.7x).
pub const AVX512_BF16_MIN_FLOP_RATE: f64 = 1.0;

/// The flop rate of AVX-512 BF16's `vdpbf16ps` over the f32 FMA's on this core, measured the
/// first time it is asked for in a process (a few milliseconds; see
/// [`AVX512_BF16_MIN_FLOP_RATE`]), or why this CPU cannot run it.
///
/// # Errors
/// The CPU lacks AVX-512 BF16 (the features missing, named as [`Bf16Kernel::check`] does).
pub fn avx512_dot_flop_rate_against_fma() -> Result<f64, &'static str> {
    Bf16Kernel::Avx512.check()?;
    static RATE: OnceLock<f64> = OnceLock::new();
    #[cfg(target_arch = "x86_64")]
    return Ok(*RATE.get_or_init(avx512::dot_flop_rate_against_fma));
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!("AVX-512 BF16 passed its check on a CPU that is not x86_64 ({RATE:?})")
}

/// What `--precision auto` (and the fast preset) runs on this CPU ([`Bf16Support::auto`]).
#[derive(Clone, Debug, PartialEq)]
pub enum AutoPrecision {
    /// bf16 products on this kernel: AMX, or AVX-512 BF16 where it outruns f32.
    Bf16(Bf16Kernel),
    /// f32, and why not bf16: no kernel, or one slower than f32 here.
    F32(String),
}

impl AutoPrecision {
    /// The precision chosen.
    #[must_use]
    pub fn precision(&self) -> Precision {
        match self {
            Self::Bf16(_) => Precision::Bf16,
            Self::F32(_) => Precision::F32,
        }
    }

    /// One line for logs: `precision auto: bf16 (AVX-512 BF16)` or `precision auto: f32 (why)`.
    #[must_use]
    pub fn describe(&self) -> String {
        format!("precision auto: {}", self.choice())
    }

    /// The choice and its reason: `bf16 (AVX-512 BF16)` or `f32 (why)`.
    #[must_use]
    pub fn choice(&self) -> String {
        match self {
            Self::Bf16(kernel) => format!("bf16 ({})", kernel.name()),
            Self::F32(why) => format!("f32 ({why})"),
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
/// the products accumulated in f32, on `kernel` or, for `None`, the one
/// [`Bf16Support::detect`] chose. An operand packed before ([`Operand::packed`], [`Bf16Matrix`])
/// is read as packed (it must have been packed for the kernel: [`Bf16Matrix::pack_for`]), the
/// others are packed here: the same bits either way. Shapes below [`MIN_BF16_DIM`] run
/// [`matmul`] in f32.
///
/// # Panics
/// If a slice is shorter than its shape needs, if a size product overflows, if the CPU cannot
/// run `kernel` ([`Bf16Kernel::check`]) or, for `None`, has no bf16 kernel (callers choose
/// [`Precision::Bf16`] only after checking [`Bf16Support::detect`]), or if a packed operand's
/// shape or layouts do not match its role.
pub fn matmul_bf16(c: &mut [f32], a: Operand<'_>, b: Operand<'_>, p: Product, kernel: Option<Bf16Kernel>) {
    let kernel = kernel.or_else(|| Bf16Support::detect().kernel());
    let kernel = kernel.unwrap_or_else(|| panic!("matmul_bf16 without a bf16 kernel: {:?}", Bf16Support::detect()));
    let Product { m, k, n, accumulate } = p;
    let (la, lb) = (a.layout, b.layout);
    if !uses_bf16(m, k, n) {
        matmul(c, a.values, la, b.values, lb, p);
        return;
    }
    let size = crate::linalg::checked_len;
    assert!(c.len() >= size(m, n), "matmul_bf16: c has {} < {m}x{n}", c.len());
    assert!(a.values.len() >= size(m, k), "matmul_bf16: a has {} < {m}x{k}", a.values.len());
    assert!(b.values.len() >= size(k, n), "matmul_bf16: b has {} < {k}x{n}", b.values.len());
    if let Err(why) = kernel.check() {
        panic!("matmul_bf16 on {}: {why}", kernel.name());
    }
    #[cfg(not(target_arch = "x86_64"))]
    unreachable!("no bf16 kernel passes its check off x86_64");
    #[cfg(target_arch = "x86_64")]
    PACKED.with(|p| {
        let p = &mut *p.borrow_mut();
        let (mp, kp, np) = (m.next_multiple_of(BLOCK), k.next_multiple_of(K_STEP), n.next_multiple_of(BLOCK));
        let b_pairs: &[u32] = match b.packed {
            Some(packed) if lb == Layout::Normal => packed.right(kernel, k, n),
            _ => {
                simd::pack_pairs(&mut p.b, b.values, lb, k, n, kp, np);
                &p.b
            }
        };
        let a_packed = match (a.packed, kernel, la) {
            (Some(packed), _, _) => packed.left(kernel, la, m, k),
            // `a` stored `k x m` (a weight gradient's activations): for the AVX-512 kernel its
            // pairs along k are packed as `b`'s are, with no transpose, and read in that order.
            (None, Bf16Kernel::Avx512, Layout::Transposed) => {
                simd::pack_pairs(&mut p.a_pairs, a.values, Layout::Normal, k, m, kp, mp);
                PackedLeft::Pairs(&p.a_pairs)
            }
            (None, _, _) => {
                simd::pack_rows(&mut p.a, a.values, la, m, k, mp, kp);
                PackedLeft::Tiles(&p.a)
            }
        };
        let shape = PackedShape { m, n, mp, kp, np, accumulate };
        match (kernel, a_packed) {
            (Bf16Kernel::Amx, PackedLeft::Tiles(a)) => amx::product(c, a, b_pairs, shape),
            (Bf16Kernel::Amx, PackedLeft::Pairs(_)) => unreachable!("the AMX kernel's operands are packed in tiles"),
            (Bf16Kernel::Avx512, a) => avx512::product(c, a, b_pairs, shape),
        }
    });
}

/// The packed operands' row and column padding: 2 x 2 tiles of 16 x 16 (AMX's block per step;
/// the AVX-512 kernel's 8 x 32 steps divide it).
const BLOCK: usize = 32;
/// The packed operands' padding of k: the bf16 values of k per tile multiply-add.
const K_STEP: usize = 32;

/// The shape of a product on packed operands: `c`'s `m x n`, the padded `mp x kp x np` the
/// operands were packed to, and whether the product adds to `c` (`accumulate`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PackedShape {
    m: usize,
    n: usize,
    mp: usize,
    kp: usize,
    np: usize,
    accumulate: bool,
}

/// What every kernel's `product` rests its `unsafe` code on: the CPU runs `kernel`, the padded
/// sizes are whole blocks at least the real ones, and the packed `a` (`a_values`, at least
/// `mp x kp` bf16 values), the packed `b` (`kp / 2 x np` pairs) and `c` (`m x n`) are that large
/// (sizes checked against overflow).
#[cfg(target_arch = "x86_64")]
fn assert_packed(kernel: Bf16Kernel, c: &[f32], a_values: usize, b: &[u32], s: PackedShape) {
    let PackedShape { m, n, mp, kp, np, .. } = s;
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
pub fn matmul_bf16_emulated(c: &mut [f32], a: &[f32], la: Layout, b: &[f32], lb: Layout, p: Product) {
    let Product { m, k, n, .. } = p;
    if !uses_bf16(m, k, n) {
        matmul(c, a, la, b, lb, p);
        return;
    }
    let a: Vec<f32> = a[..crate::linalg::checked_len(m, k)].iter().map(|&x| round_to_bf16(x)).collect();
    let b: Vec<f32> = b[..crate::linalg::checked_len(k, n)].iter().map(|&x| round_to_bf16(x)).collect();
    matmul(c, &a, la, &b, lb, p);
}

/// Per-thread packing buffers, kept between products.
#[derive(Default)]
struct Packed {
    /// `a` as bf16, `mp x kp` row-major, zero-padded.
    a: Lines<u16>,
    /// `b` as pairs of bf16 along k (AMX's "VNNI" layout): `kp / 2` rows of `np` 32-bit pairs.
    b: Lines<u32>,
    /// `a` stored transposed, for the AVX-512 kernel: laid out as `b` is ([`b_index`], `a`'s
    /// rows as the columns), `kp / 2` rows of `mp` pairs.
    a_pairs: Lines<u32>,
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
fn pack_rows(out: &mut Lines<u16>, a: &[f32], la: Layout, m: usize, k: usize, mp: usize, kp: usize) {
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
/// it was). The scalar reference of [`simd::pack_pairs`].
#[cfg_attr(not(test), allow(dead_code))]
fn pack_pairs(out: &mut Lines<u32>, b: &[f32], lb: Layout, k: usize, n: usize, kp: usize, np: usize) {
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
fn grow<T: Copy + Default>(out: &mut Lines<T>, len: usize) {
    if out.len() < len {
        out.resize(len, T::default());
    }
}

/// The packing with AVX-512 (`vcvtneps2bf16`), which both kernels need (every AMX-BF16 processor
/// has it; [`Bf16Kernel::check`] checks it): the same bits as the scalar [`pack_rows`] and
/// [`pack_pairs`] (a test compares them).
#[cfg(target_arch = "x86_64")]
mod simd;

/// Operands packed once for several products.
mod packed;

/// The AMX kernel. Every `unsafe` block is here and justified where it is.
#[cfg(target_arch = "x86_64")]
mod amx;

/// The AVX-512 BF16 kernel (`vdpbf16ps`), on the packed operands the AMX kernel reads, except
/// a transposed `a`, which it reads in pairs ([`PackedLeft::Pairs`]) rather than transposed into
/// AMX's tiles. Every `unsafe` block is here and justified where it is.
#[cfg(target_arch = "x86_64")]
mod avx512;

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

    #[test]
    fn auto_takes_amx_always_and_avx512_bf16_only_where_it_outruns_the_f32_fma() {
        let never = || -> f64 { panic!("the rate is measured for the AVX-512 BF16 kernel only") };
        let amx = Bf16Support::Available(Bf16Kernel::Amx);
        assert_eq!(amx.auto_with(never), AutoPrecision::Bf16(Bf16Kernel::Amx));
        let none = Bf16Support::Unavailable("this CPU lacks avx512_bf16".into());
        assert_eq!(none.auto_with(never), AutoPrecision::F32("this CPU lacks avx512_bf16".into()));
        let avx512 = Bf16Support::Available(Bf16Kernel::Avx512);
        // Zen 4's rate, the threshold itself, and an Intel Xeon's with AMX switched off.
        assert_eq!(avx512.auto_with(|| 2.0), AutoPrecision::Bf16(Bf16Kernel::Avx512));
        assert_eq!(avx512.auto_with(|| AVX512_BF16_MIN_FLOP_RATE), AutoPrecision::Bf16(Bf16Kernel::Avx512));
        let slow = avx512.auto_with(|| 0.49);
        assert_eq!(slow.precision(), Precision::F32);
        let line = slow.describe();
        assert!(line.starts_with("precision auto: f32 (AVX-512 BF16 would train slower"), "{line}");
        assert!(line.contains("0.49x") && line.contains("--precision bf16"), "{line}");
        assert_eq!(avx512.auto_with(|| 2.0).describe(), "precision auto: bf16 (AVX-512 BF16)");
    }

    #[test]
    fn the_dot_flop_rate_is_measured_where_avx512_bf16_runs_and_refused_where_it_does_not() {
        match (Bf16Kernel::Avx512.check(), avx512_dot_flop_rate_against_fma()) {
            (Ok(()), Ok(rate)) => {
                // Each instruction's rate is bounded by its latency (at most ~20 cycles over 16
                // chains) and by the issue width (at most 2 per cycle): whatever the CPU, the
                // ratio of flops lies well inside (1/16, 16).
                assert!(rate.is_finite() && (1.0 / 16.0..16.0).contains(&rate), "{rate}");
            }
            (Err(why), Err(refused)) => {
                assert_eq!(why, refused);
                crate::test_support::skipped_for_cpu_feature("dot_flop_rate (measured)", "avx512_bf16", why);
            }
            (check, rate) => panic!("the check ({check:?}) and the rate ({rate:?}) disagree"),
        }
    }
}
