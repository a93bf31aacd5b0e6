//! Conical frustums as Gaussians and the integrated positional encoding (IPE).
//!
//! This is section 3.1 of the Mip-NeRF paper: every interval `[t0, t1]` along a cone cast through a
//! pixel is approximated by a Gaussian with the same first and second moments, and the positional
//! encoding of every point in that frustum is replaced by its expectation under the Gaussian.
//!
//! All arithmetic is `f32` and follows the official code's operation order, so results agree with
//! it to about one ulp (the only differences come from `sin`/`exp` implementations).

use glam::{Mat3, Vec3};

/// The moments of a frustum along and across its ray, before lifting to world space.
///
/// `t_mean` is the mean distance along the ray (in units of the ray's direction vector),
/// `t_var` the variance along the ray and `r_var` the variance perpendicular to it (per axis).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct FrustumMoments {
    /// Mean of `t` over the frustum's volume.
    pub t_mean: f32,
    /// Variance of `t` over the frustum's volume.
    pub t_var: f32,
    /// Variance of the perpendicular offset, per perpendicular axis.
    pub r_var: f32,
}

/// A Gaussian in world space with a diagonal covariance (the paper's Eq. 8 keeps only the diagonal).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Gaussian {
    /// Mean position (world units).
    pub mean: Vec3,
    /// Diagonal of the covariance matrix (world units squared).
    pub cov_diag: Vec3,
}

/// The moments of the conical frustum between `t0` and `t1` of a cone with radius `base_radius`
/// at `t = 1`, in the numerically stable form of the official code.
///
/// With `t_mu = (t0 + t1) / 2` and `t_delta = (t1 - t0) / 2`:
/// - `t_mean = t_mu + 2 t_mu t_delta² / (3 t_mu² + t_delta²)`
/// - `t_var = t_delta²/3 - (4/15) t_delta⁴ (12 t_mu² - t_delta²) / (3 t_mu² + t_delta²)²`
/// - `r_var = r² (t_mu²/4 + (5/12) t_delta² - (4/15) t_delta⁴ / (3 t_mu² + t_delta²))`
///
/// This form keeps full `f32` precision for thin, distant frustums, where the textbook formula
/// (`tests/precision.rs` keeps it, to show where) subtracts huge nearly equal powers of `t`.
///
/// `t0 = t1 = 0` is the one input that gives NaN (0/0), exactly as the official code does.
#[must_use]
#[inline]
pub fn conical_frustum_moments(t0: f32, t1: f32, base_radius: f32) -> FrustumMoments {
    debug_assert!(t0.is_finite() && t1.is_finite() && base_radius.is_finite(), "frustum [{t0}, {t1}] r {base_radius}");
    let mu = (t0 + t1) / 2.0;
    let hw = (t1 - t0) / 2.0;
    let mu2 = mu * mu;
    let hw2 = hw * hw;
    let hw4 = hw2 * hw2;
    let denom = 3.0 * mu2 + hw2;
    let t_mean = mu + (2.0 * mu * hw2) / denom;
    let t_var = hw2 / 3.0 - (4.0 / 15.0) * ((hw4 * (12.0 * mu2 - hw2)) / (denom * denom));
    let r_var = base_radius * base_radius * (mu2 / 4.0 + (5.0 / 12.0) * hw2 - 4.0 / 15.0 * hw4 / denom);
    FrustumMoments { t_mean, t_var, r_var }
}

/// The moments of the cylinder between `t0` and `t1` with radius `radius`: mean `t_mu`,
/// variance `(t1 - t0)² / 12` along the ray and `radius² / 4` across it.
#[must_use]
#[inline]
pub fn cylinder_moments(t0: f32, t1: f32, radius: f32) -> FrustumMoments {
    debug_assert!(t0.is_finite() && t1.is_finite() && radius.is_finite(), "cylinder [{t0}, {t1}] r {radius}");
    let dt = t1 - t0;
    FrustumMoments { t_mean: (t0 + t1) / 2.0, t_var: dt * dt / 12.0, r_var: radius * radius / 4.0 }
}

/// Lifts frustum moments along direction `d` to a world-space Gaussian with diagonal covariance,
/// centred at `d * t_mean` (add the ray origin to place it in the world):
/// `cov_diag = t_var d² + r_var (1 - d² / max(|d|², 1e-10))`.
#[must_use]
#[inline]
pub fn lift_gaussian(d: Vec3, m: FrustumMoments) -> Gaussian {
    let d2 = d * d;
    let d_mag_sq = (d2.x + d2.y + d2.z).max(1e-10);
    let null_outer = Vec3::ONE - d2 / d_mag_sq;
    Gaussian { mean: d * m.t_mean, cov_diag: m.t_var * d2 + m.r_var * null_outer }
}

/// The full 3x3 covariance that [`lift_gaussian`] keeps the diagonal of:
/// `t_var d dᵀ + r_var (I - d dᵀ / max(|d|², 1e-10))`.
#[must_use]
pub fn lift_gaussian_full_cov(d: Vec3, m: FrustumMoments) -> Mat3 {
    let outer = Mat3::from_cols(d * d.x, d * d.y, d * d.z);
    let d_mag_sq = d.length_squared().max(1e-10);
    let null_outer = Mat3::IDENTITY - outer * (1.0 / d_mag_sq);
    outer * m.t_var + null_outer * m.r_var
}

/// The Gaussian of the conical frustum `[t0, t1]` along direction `d` (not normalised, so `t` is
/// depth along the camera axis), with cone radius `base_radius` at `t = 1`; mean relative to the
/// ray origin. See [`conical_frustum_moments`].
#[must_use]
#[inline]
pub fn conical_frustum_to_gaussian(d: Vec3, t0: f32, t1: f32, base_radius: f32) -> Gaussian {
    lift_gaussian(d, conical_frustum_moments(t0, t1, base_radius))
}

/// The Gaussian of the cylinder `[t0, t1]` along `d` with radius `radius`; mean relative to the
/// ray origin. See [`cylinder_moments`].
#[must_use]
#[inline]
pub fn cylinder_to_gaussian(d: Vec3, t0: f32, t1: f32, radius: f32) -> Gaussian {
    lift_gaussian(d, cylinder_moments(t0, t1, radius))
}

/// `100 π` in `f32`: the official code reduces sine arguments at or above this magnitude.
pub const SAFE_TRIG_LIMIT: f32 = 100.0 * std::f32::consts::PI;

/// `x` reduced modulo [`SAFE_TRIG_LIMIT`] (Python-style, into `[0, 100π)`) when `|x| >= 100π`,
/// else `x` unchanged. This is the official guard that keeps `sin` of the high IPE degrees
/// (arguments up to `2^15 |x|`) accurate and finite; note it is not odd, as in the official code.
///
/// The remainder is exact (as C's `fmod` is): it is computed in `f64`, where `q · 100π` is exact
/// for the quotients that occur (`|x| < 2^28`), branch-free so that loops over it vectorise.
#[must_use]
#[inline(always)]
pub fn safe_trig_arg(x: f32) -> f32 {
    const T: f64 = SAFE_TRIG_LIMIT as f64;
    const INV_T: f64 = 1.0 / (SAFE_TRIG_LIMIT as f64);
    let xd = f64::from(x);
    // Nearest integer quotient by the 1.5 * 2^52 trick (no SSE4.1 rounding needed); the remainder
    // x - q t is then exact in f64 and in (-t, t), and exactly representable in f32.
    let q = (xd * INV_T + ROUND_MAGIC) - ROUND_MAGIC;
    let r = xd - q * T;
    let r = if r < 0.0 { r + T } else { r };
    let r = if r >= T { r - T } else { r };
    // A zero remainder keeps the sign of x, as fmod's does.
    let r = if r == 0.0 { 0.0f64.copysign(xd) } else { r };
    if x.abs() < SAFE_TRIG_LIMIT { x } else { r as f32 }
}

/// `1.5 · 2^52`: adding and subtracting it rounds an `f64` of magnitude below `2^51` to an integer.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

/// `sin` of an `f32` argument of magnitude below about `2^20`, evaluated in `f64` and rounded once,
/// so the result is the correctly rounded `sin` in all but rare half-way cases.
///
/// Range reduction by multiples of `π/2` in `f64` (a two-part `π/2`), then the Taylor series of
/// `sin` or `cos` on `[-π/4, π/4]` (truncation below `1e-11`). Branch-free, so loops vectorise.
#[must_use]
#[inline(always)]
pub fn sin_f32(x: f32) -> f32 {
    const FRAC_2_PI: f64 = std::f64::consts::FRAC_2_PI;
    const PIO2_HI: f64 = std::f64::consts::FRAC_PI_2;
    const PIO2_LO: f64 = 6.123_233_995_736_766e-17;
    let xd = f64::from(x);
    let shifted = xd * FRAC_2_PI + ROUND_MAGIC;
    let kf = shifted - ROUND_MAGIC;
    let r = (xd - kf * PIO2_HI) - kf * PIO2_LO;
    // k mod 4 from the shifted value's mantissa, which holds `2^51 + k`: `kf as i32 & 3` without
    // a saturating float-to-int conversion (see `sin_f32_poly`).
    let quadrant = shifted.to_bits() & 3;
    let z = r * r;
    let s = r + r
        * z
        * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0 + z * (1.0 / 362_880.0 + z * (-1.0 / 39_916_800.0)))));
    let c = 1.0 - 0.5 * z
        + z * z
            * (1.0 / 24.0
                + z * (-1.0 / 720.0 + z * (1.0 / 40_320.0 + z * (-1.0 / 3_628_800.0 + z * (1.0 / 479_001_600.0)))));
    let v = if quadrant & 1 == 0 { s } else { c };
    let v = if quadrant & 2 == 0 { v } else { -v };
    v as f32
}

/// `sin` with the official large-argument guard ([`safe_trig_arg`]).
#[must_use]
#[inline(always)]
pub fn safe_sin(x: f32) -> f32 {
    sin_f32(safe_trig_arg(x))
}

/// `cos` with the official large-argument guard ([`safe_trig_arg`]).
#[must_use]
#[inline]
pub fn safe_cos(x: f32) -> f32 {
    safe_trig_arg(x).cos()
}

/// The mean and variance of `sin(z)` for `z ~ N(x, x_var)`:
/// `E = exp(-x_var/2) sin(x)`, `Var = max(0, (1 - exp(-2 x_var) cos(2x)) / 2 - E²)`.
#[must_use]
#[inline]
pub fn expected_sin(x: f32, x_var: f32) -> (f32, f32) {
    let y = (-0.5 * x_var).exp() * safe_sin(x);
    let y_var = (0.5 * (1.0 - (-2.0 * x_var).exp() * safe_cos(2.0 * x)) - y * y).max(0.0);
    (y, y_var)
}

/// Number of features [`integrated_pos_enc`] writes for degrees `min_deg..max_deg` of a 3-D point.
#[must_use]
pub const fn ipe_len(min_deg: u32, max_deg: u32) -> usize {
    2 * 3 * (max_deg - min_deg) as usize
}

/// `0.5 π` in `f32`: the IPE "cos" half is `sin(y + π/2)` evaluated in `f32`, as in the official code.
pub const HALF_PI: f32 = 0.5 * std::f32::consts::PI;

/// The integrated positional encoding of a Gaussian (the paper's Eq. 14) for degrees
/// `min_deg..max_deg` (the paper uses `0..16`):
/// `exp(-4^l var / 2) * sin(2^l x)` and the same with `cos`, per axis.
///
/// Layout of `out` (length [`ipe_len`]): `[sin part | cos part]`, and within a part the feature of
/// degree `l` and axis `k` is at `(l - min_deg) * 3 + k`. Every feature lies in `[-1, 1]` and shrinks
/// towards zero as the variance grows, which is how IPE anti-aliases.
///
/// # Panics
/// If `out.len() != ipe_len(min_deg, max_deg)`.
#[inline(always)]
pub fn integrated_pos_enc(g: &Gaussian, min_deg: u32, max_deg: u32, out: &mut [f32]) {
    let n = ipe_len(min_deg, max_deg);
    assert_eq!(out.len(), n, "integrated_pos_enc: output length");
    assert!(max_deg <= 24, "integrated_pos_enc: degrees up to 24");
    debug_assert!(g.mean.is_finite(), "integrated_pos_enc: non-finite mean {:?}", g.mean);
    // The damping by glibc's `expf`, bit for bit, in a form that vectorises (`crate::expf`).
    ipe_with(g, (min_deg, max_deg), out, crate::expf::expf, safe_sin);
}

/// The IPE's evaluation for both precisions: the arguments and the damping's exponents
/// ([`ipe_arguments`]), then one vectorisable pass ([`in_blocks`]) of `exp(exponent) * sin(argument)`
/// with the `exp` and `sin` given (inlined, so that they are compiled in the pass's loop).
#[inline(always)]
fn ipe_with(
    g: &Gaussian,
    (min_deg, max_deg): (u32, u32),
    out: &mut [f32],
    exp: impl Fn(f32) -> f32,
    sin: impl Fn(f32) -> f32,
) {
    let mut exponent = [0.0f32; 3 * 24];
    let half = ipe_arguments(g, min_deg, max_deg, out, &mut exponent);
    in_blocks(
        out,
        &exponent[..half],
        #[inline(always)]
        |e, s, c| {
            let d = exp(e);
            (d * sin(s), d * sin(c))
        },
    );
}

/// The IPE's arguments in place in `out` (`ipe_len` long): `2^l x` in its first half and
/// `2^l x + π/2` (rounded in `f32`, as the official code's `cos` part is) in its second; the
/// damping's exponents `-4^l var / 2` in `exponent`. Returns the length of a half.
#[inline(always)]
fn ipe_arguments(g: &Gaussian, min_deg: u32, max_deg: u32, out: &mut [f32], exponent: &mut [f32; 3 * 24]) -> usize {
    let half = out.len() / 2;
    let x = g.mean.to_array();
    let var = g.cov_diag.to_array();
    for (i, deg) in (min_deg..max_deg).enumerate() {
        let scale = (1u32 << deg) as f32;
        for k in 0..3 {
            let y = x[k] * scale;
            out[i * 3 + k] = y;
            out[half + i * 3 + k] = y + HALF_PI;
            exponent[i * 3 + k] = -0.5 * (var[k] * (scale * scale));
        }
    }
    half
}

/// The largest absolute difference between [`integrated_pos_enc_for_bf16`] and
/// [`integrated_pos_enc`] on any feature (2^-20). Each feature lies in `[-1, 1]`, where bf16's rounding moves a
/// value by up to 2^-9 of its magnitude; features of magnitude below 2^-11 differ by more than
/// half a bf16 ulp only where bf16 already loses their leading bits to the products' f32 sums.
pub const IPE_FOR_BF16_MAX_ERROR: f32 = 1.0 / 1_048_576.0;

/// The integrated positional encoding exactly as [`integrated_pos_enc`] lays it out, evaluated in
/// `f32` arithmetic for features that are rounded to bf16 before their only use (the MLP's
/// products at [`crate::bf16::Precision::Bf16`]). Within [`IPE_FOR_BF16_MAX_ERROR`] of
/// [`integrated_pos_enc`], which evaluates `sin` in `f64` and rounds it correctly: bf16 keeps 8
/// bits of each feature, so the reference's last 15 bits are spent on nothing there.
///
/// The same official large-argument guard (the remainder modulo [`SAFE_TRIG_LIMIT`], rounded
/// once through a fused multiply-add), `sin` by a three-part Cody-Waite reduction by `π/2` and
/// Taylor polynomials, `exp` by a reduction by `ln 2` and a degree-7 polynomial (0 below
/// `exp(-87)`). Branch-free, so its loop vectorises: 16 lanes where AVX-512 is enabled
/// (`stages::cast_and_encode` compiles it so on CPUs that have it, which every CPU with a
/// bf16 kernel does).
///
/// # Panics
/// If `out.len() != ipe_len(min_deg, max_deg)`.
#[inline(always)]
pub fn integrated_pos_enc_for_bf16(g: &Gaussian, min_deg: u32, max_deg: u32, out: &mut [f32]) {
    let n = ipe_len(min_deg, max_deg);
    assert_eq!(out.len(), n, "integrated_pos_enc_for_bf16: output length");
    assert!(max_deg <= 24, "integrated_pos_enc_for_bf16: degrees up to 24");
    ipe_with(
        g,
        (min_deg, max_deg),
        out,
        exp_f32_poly,
        #[inline(always)]
        |x| sin_f32_poly(safe_trig_arg_f32(x)),
    );
}

/// Features per block of [`in_blocks`]: one 512-bit vector of `f32`.
const IPE_BLOCK: usize = 16;

/// The IPE's last pass over `out` (`[sin part | cos part]`, each as long as `exponent`, which
/// holds each feature's damping exponent): feature
/// `j` of each part becomes `feature(exponent[j], sin_part[j], cos_part[j])`, in zero-padded
/// blocks of [`IPE_BLOCK`]. A loop over the whole half (48 features at the paper's degrees, a
/// count known only when it runs) compiled to a vector body it never entered and a scalar
/// remainder that did all the work; a block's loop has a trip count the compiler knows and
/// vectorises whole. Inlined, so that `feature` is compiled in the caller's loop.
#[inline(always)]
fn in_blocks(out: &mut [f32], exponent: &[f32], feature: impl Fn(f32, f32, f32) -> (f32, f32)) {
    let half = exponent.len();
    let (sin_part, cos_part) = out.split_at_mut(half);
    for start in (0..half).step_by(IPE_BLOCK) {
        let len = (half - start).min(IPE_BLOCK);
        let (mut s, mut c, mut d) = ([0.0f32; IPE_BLOCK], [0.0f32; IPE_BLOCK], [0.0f32; IPE_BLOCK]);
        s[..len].copy_from_slice(&sin_part[start..start + len]);
        c[..len].copy_from_slice(&cos_part[start..start + len]);
        d[..len].copy_from_slice(&exponent[start..start + len]);
        for j in 0..IPE_BLOCK {
            (s[j], c[j]) = feature(d[j], s[j], c[j]);
        }
        sin_part[start..start + len].copy_from_slice(&s[..len]);
        cos_part[start..start + len].copy_from_slice(&c[..len]);
    }
}

/// `1.5 · 2^23`: adding and subtracting it rounds an `f32` of magnitude below `2^22` to an
/// integer (nearest, ties to even).
const ROUND_MAGIC_F32: f32 = 12_582_912.0;

/// [`safe_trig_arg`] in `f32` arithmetic: the Python-style remainder modulo [`SAFE_TRIG_LIMIT`]
/// for `|x| >= 100π`, rounded once (the quotient corrected until the fused multiply-add's exact
/// `x - q·T` lies in `[0, T)`), for `|x| < 2^22 · 100π`: the same bits as [`safe_trig_arg`].
#[inline(always)]
fn safe_trig_arg_f32(x: f32) -> f32 {
    const T: f32 = SAFE_TRIG_LIMIT;
    let q = (x * (1.0 / T)).floor();
    let r = (-q).mul_add(T, x);
    let q = if r < 0.0 {
        q - 1.0
    } else if r >= T {
        q + 1.0
    } else {
        q
    };
    let r = (-q).mul_add(T, x);
    // A zero remainder keeps the sign of x, as fmod's does.
    let r = if r == 0.0 { 0.0f32.copysign(x) } else { r };
    if x.abs() < T { x } else { r }
}

/// `sin` in `f32` for `|x| < 2^22`: `x - k π/2` by a three-part `π/2` (fused multiply-adds), then
/// the Taylor series of `sin` (to `x^9`) or `cos` (to `x^8`) on `[-π/4, π/4]`. Within 3e-7 of
/// the true sine for the arguments [`integrated_pos_enc_for_bf16`] passes (`|x| < 100π`).
#[inline(always)]
fn sin_f32_poly(x: f32) -> f32 {
    const PIO2_1: f32 = std::f32::consts::FRAC_PI_2;
    const PIO2_2: f32 = (std::f64::consts::FRAC_PI_2 - PIO2_1 as f64) as f32;
    const PIO2_3: f32 = (std::f64::consts::FRAC_PI_2 - PIO2_1 as f64 - PIO2_2 as f64) as f32;
    let shifted = x * std::f32::consts::FRAC_2_PI + ROUND_MAGIC_F32;
    let kf = shifted - ROUND_MAGIC_F32;
    let r = (-kf).mul_add(PIO2_1, x);
    let r = (-kf).mul_add(PIO2_2, r);
    let r = (-kf).mul_add(PIO2_3, r);
    // k's low bits from the shifted value's mantissa (`1.5 · 2^23 + k` holds `2^22 + k` there,
    // and 4 divides 2^22): k mod 4, as `kf as i32 & 3` but without a float-to-int conversion,
    // whose saturation keeps the loop from vectorising.
    let quadrant = shifted.to_bits() & 3;
    let z = r * r;
    let s = r + r * z * (-1.0 / 6.0 + z * (1.0 / 120.0 + z * (-1.0 / 5040.0 + z * (1.0 / 362_880.0))));
    let c = 1.0 - 0.5 * z + z * z * (1.0 / 24.0 + z * (-1.0 / 720.0 + z * (1.0 / 40_320.0 + z * (-1.0 / 3_628_800.0))));
    let v = if quadrant & 1 == 0 { s } else { c };
    if quadrant & 2 == 0 { v } else { -v }
}

/// `exp(a)` in `f32` for `a <= 0` (the IPE's damping): `a = k ln 2 + r` with `|r| <= ln 2 / 2`
/// (a two-part `ln 2`), the degree-7 Taylor polynomial of `exp(r)` times `2^k`; 0 below
/// `exp(-87)` (under `2e-38`). A NaN stays NaN. Within 3e-7 relative of the true value above.
#[inline(always)]
fn exp_f32_poly(a: f32) -> f32 {
    const LN2_HI: f32 = std::f32::consts::LN_2;
    const LN2_LO: f32 = (std::f64::consts::LN_2 - LN2_HI as f64) as f32;
    const FLOOR: f32 = -87.0;
    let underflows = a < FLOOR;
    let a = if underflows { FLOOR } else { a };
    let shifted = a * std::f32::consts::LOG2_E + ROUND_MAGIC_F32;
    let kf = shifted - ROUND_MAGIC_F32;
    let r = (-kf).mul_add(LN2_HI, a);
    let r = (-kf).mul_add(LN2_LO, r);
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    // k in [-126, 0] here, so 2^k is a normal f32 built from its exponent bits; k is the
    // difference of the shifted value's bits and the shift's (both share one exponent), taken
    // without a float-to-int conversion, as for the sine's quadrant.
    let k = shifted.to_bits().wrapping_sub(ROUND_MAGIC_F32.to_bits());
    let two_k = f32::from_bits(k.wrapping_add(127) << 23);
    if underflows { 0.0 } else { p * two_k }
}

/// Number of features [`pos_enc`] writes for a 3-D vector.
#[must_use]
pub const fn pos_enc_len(min_deg: u32, max_deg: u32, append_identity: bool) -> usize {
    2 * 3 * (max_deg - min_deg) as usize + if append_identity { 3 } else { 0 }
}

/// The ordinary positional encoding of NeRF (used for view directions, degrees `0..4` with the
/// identity): `[x (if append_identity) | sin(2^l x) | sin(2^l x + π/2)]`, index `(l - min_deg) * 3 + k`
/// inside each part. Uses plain `sin` (no large-argument guard), as the official code does.
///
/// # Panics
/// If `out.len() != pos_enc_len(min_deg, max_deg, append_identity)`.
pub fn pos_enc(x: Vec3, min_deg: u32, max_deg: u32, append_identity: bool, out: &mut [f32]) {
    assert_eq!(out.len(), pos_enc_len(min_deg, max_deg, append_identity), "pos_enc: output length");
    let (id, rest) = out.split_at_mut(if append_identity { 3 } else { 0 });
    id.copy_from_slice(&x.to_array()[..id.len()]);
    let half = rest.len() / 2;
    let xs = x.to_array();
    for (i, deg) in (min_deg..max_deg).enumerate() {
        let scale = (1u32 << deg) as f32;
        for k in 0..3 {
            let y = xs[k] * scale;
            rest[i * 3 + k] = y.sin();
            rest[half + i * 3 + k] = (y + HALF_PI).sin();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance in units in the last place between two finite f32.
    fn ulps(a: f32, b: f32) -> u32 {
        let key = |x: f32| {
            let i = x.to_bits() as i32;
            if i < 0 { i32::MIN - i } else { i }
        };
        key(a).abs_diff(key(b))
    }

    #[test]
    fn sin_f32_is_within_one_ulp_of_the_true_sine() {
        let mut worst = 0;
        let mut x = -320.0f32;
        while x < 320.0 {
            let want = f64::from(x).sin() as f32;
            worst = worst.max(if want.abs() < 1e-30 { 0 } else { ulps(sin_f32(x), want) });
            x += 0.000_731;
        }
        for &x in &[0.0f32, 1e-20, -1e-8, std::f32::consts::PI, 314.159_27, 1e5, -65_536.5] {
            let want = f64::from(x).sin() as f32;
            assert!(ulps(sin_f32(x), want) <= 1, "sin({x}): {} vs {want}", sin_f32(x));
        }
        assert!(worst <= 1, "worst error {worst} ulp");
    }

    #[test]
    fn safe_trig_arg_is_the_exact_python_remainder() {
        let t = SAFE_TRIG_LIMIT;
        let reference = |x: f32| {
            if x.abs() < t {
                return x;
            }
            let r = x % t; // C fmod: exact
            if r != 0.0 && r < 0.0 { r + t } else { r }
        };
        let mut x = 1.0f32;
        while x < 3.0e7 {
            for v in [x, -x, x + 0.37, -(x * 1.618)] {
                assert_eq!(safe_trig_arg(v).to_bits(), reference(v).to_bits(), "x = {v}");
            }
            x *= 1.013;
        }
        for k in 1..2000 {
            let v = t * k as f32; // multiples of the period, the worst case for a rounded quotient
            assert_eq!(safe_trig_arg(v).to_bits(), reference(v).to_bits(), "x = {v}");
            assert_eq!(safe_trig_arg(-v).to_bits(), reference(-v).to_bits(), "x = -{v}");
        }
    }
    /// A small deterministic generator for the sweeps below (xorshift32, uniform in `[0, 1)`).
    fn uniform(state: &mut u32) -> f32 {
        *state ^= *state << 13;
        *state ^= *state >> 17;
        *state ^= *state << 5;
        (*state >> 8) as f32 / 16_777_216.0
    }

    #[test]
    fn the_f32_remainder_is_the_exact_one() {
        let mut x = 1.0f32;
        while x < 3.0e7 {
            for v in [x, -x, x + 0.37, -(x * 1.618)] {
                assert_eq!(safe_trig_arg_f32(v).to_bits(), safe_trig_arg(v).to_bits(), "x = {v}");
            }
            x *= 1.013;
        }
        for k in 1..2000 {
            let v = SAFE_TRIG_LIMIT * k as f32;
            assert_eq!(safe_trig_arg_f32(v).to_bits(), safe_trig_arg(v).to_bits(), "x = {v}");
            assert_eq!(safe_trig_arg_f32(-v).to_bits(), safe_trig_arg(-v).to_bits(), "x = -{v}");
        }
    }

    #[test]
    fn the_f32_sine_and_exponential_are_within_their_stated_bounds() {
        const SIN_BOUND: f64 = 3e-7;
        const EXP_REL_BOUND: f64 = 3e-7;
        let mut x = -320.0f32;
        while x < 320.0 {
            let err = (f64::from(sin_f32_poly(x)) - f64::from(x).sin()).abs();
            assert!(err <= SIN_BOUND, "sin({x}): off by {err:e}");
            x += 0.000_731;
        }
        let mut a = 0.0f32;
        while a > -87.0 {
            let want = f64::from(a).exp();
            let err = (f64::from(exp_f32_poly(a)) - want).abs() / want;
            assert!(err <= EXP_REL_BOUND, "exp({a}): off by {err:e} relative");
            a -= 0.000_917;
        }
        assert_eq!(exp_f32_poly(-87.5), 0.0);
        assert_eq!(exp_f32_poly(f32::NEG_INFINITY), 0.0);
        assert!(exp_f32_poly(f32::NAN).is_nan() && sin_f32_poly(f32::NAN).is_nan());
    }

    #[test]
    fn the_ipe_for_bf16_is_within_its_bound_of_the_reference() {
        let mut state = 0x9e37_79b9u32;
        let mut worst = 0.0f32;
        for case in 0..20_000 {
            // Means from the unit cube to far outside it (unbounded scenes' raw coordinates), and
            // variances from none to wider than the scene, log-uniformly.
            let reach = [1.5f32, 3.0, 40.0][case % 3];
            let mean = Vec3::from_array(std::array::from_fn(|_| (2.0 * uniform(&mut state) - 1.0) * reach));
            let var = Vec3::from_array(std::array::from_fn(|_| 10f32.powf(-14.0 + 15.0 * uniform(&mut state))));
            let g = Gaussian { mean, cov_diag: if case % 7 == 0 { Vec3::ZERO } else { var } };
            let (min_deg, max_deg) = if case % 5 == 0 { (0, 24) } else { (0, 16) };
            let mut want = vec![0.0f32; ipe_len(min_deg, max_deg)];
            let mut got = want.clone();
            integrated_pos_enc(&g, min_deg, max_deg, &mut want);
            integrated_pos_enc_for_bf16(&g, min_deg, max_deg, &mut got);
            for (j, (&w, &v)) in want.iter().zip(&got).enumerate() {
                let err = (w - v).abs();
                worst = worst.max(err);
                assert!(err <= IPE_FOR_BF16_MAX_ERROR, "{g:?}, feature {j}: {v} against {w}");
            }
        }
        println!("worst difference from the reference: {worst:e}");
        // The bound is not loose by orders of magnitude: the sweep comes within 16x of it.
        assert!(worst > IPE_FOR_BF16_MAX_ERROR / 16.0, "worst error {worst:e}");
    }

    #[test]
    fn the_ipe_for_bf16_in_blocks_gives_the_bits_of_one_feature_at_a_time() {
        let mut state = 0x1234_5678u32;
        // Whole blocks (48 features a half), a ragged last block (72, 15) and less than one (3).
        for (min_deg, max_deg) in [(0, 16), (8, 24), (0, 24), (3, 8), (0, 1)] {
            let n = ipe_len(min_deg, max_deg);
            for case in 0..200 {
                let mean = Vec3::from_array(std::array::from_fn(|_| (2.0 * uniform(&mut state) - 1.0) * 3.0));
                let var = Vec3::from_array(std::array::from_fn(|_| 10f32.powf(-8.0 + 8.0 * uniform(&mut state))));
                let g = Gaussian { mean, cov_diag: if case % 7 == 0 { Vec3::ZERO } else { var } };
                let mut want = vec![0.0f32; n];
                let mut exponent = [0.0f32; 3 * 24];
                let half = ipe_arguments(&g, min_deg, max_deg, &mut want, &mut exponent);
                for j in 0..half {
                    let d = exp_f32_poly(exponent[j]);
                    want[j] = d * sin_f32_poly(safe_trig_arg_f32(want[j]));
                    want[half + j] = d * sin_f32_poly(safe_trig_arg_f32(want[half + j]));
                }
                let mut got = vec![f32::NAN; n];
                integrated_pos_enc_for_bf16(&g, min_deg, max_deg, &mut got);
                for (j, (w, v)) in want.iter().zip(&got).enumerate() {
                    assert_eq!(
                        w.to_bits(),
                        v.to_bits(),
                        "degrees {min_deg}..{max_deg}, {g:?}, feature {j}: {v} against {w}"
                    );
                }
            }
        }
    }
}
