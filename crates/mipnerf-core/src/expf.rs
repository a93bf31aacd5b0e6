//! `exp` of an `f32`, bit for bit as glibc's `expf` computes it on x86-64 with FMA, in a form
//! that vectorises.
//!
//! The IPE's damping, `exp(-4^l var / 2)`, is 48 calls of `f32::exp` per sample at the paper's
//! degrees, and a call to libm is a call per value: on the f32 training path it was about 4% of a
//! step (`docs/results/expf/`). [`expf`] is the same algorithm as glibc's (ARM's
//! optimized-routines `expf`: `exp(x) = 2^(k/32) · 2^(r/32)` with `k` the nearest integer to
//! `32 x / ln 2`, the first factor from a 32-entry table, the second a cubic in `r`, in `f64`),
//! with the same table, the same constants and the same four fused multiply-adds the FMA build of
//! glibc 2.36 (`__expf_fma`, the one its dispatcher picks on every CPU with FMA) executes, and its
//! special cases as selects rather than branches, so a loop of it compiles to vectors.
//!
//! Its results are the bits of `f32::exp` on glibc with FMA for every `f32` (compared for all
//! 2^32 in `docs/results/expf/`, for a sample and the edges in the test suite), so the committed tables, produced there, keep their bits. Elsewhere (another
//! libm, or no FMA) `f32::exp` may differ in the last bit; [`expf`] does not, which makes the IPE
//! the same on every platform. One difference under flushed subnormals (FTZ/DAZ, the tiny and fast
//! presets): where glibc returns its smallest subnormal (`x` in `[-103.97, -103.28)`) and FTZ
//! flushes it, [`expf`] returns `2^-149`; DAZ reads either as zero in the product that uses it.

/// `2^(i/32)` as `f64` bits, less `i << 47` (so that adding `k << 47` gives `2^(k/32)`): glibc's
/// `__exp2f_data.tab`, read from its `libm.so.6` (2.36).
const TABLE: [u64; 32] = [
    0x3ff0_0000_0000_0000,
    0x3fef_d9b0_d315_8574,
    0x3fef_b558_6cf9_890f,
    0x3fef_9301_d012_5b51,
    0x3fef_72b8_3c7d_517b,
    0x3fef_5487_3168_b9aa,
    0x3fef_387a_6e75_6238,
    0x3fef_1e9d_f51f_dee1,
    0x3fef_06fe_0a31_b715,
    0x3fee_f1a7_373a_a9cb,
    0x3fee_dea6_4c12_3422,
    0x3fee_ce08_6061_892d,
    0x3fee_bfda_d536_2a27,
    0x3fee_b42b_569d_4f82,
    0x3fee_ab07_dd48_5429,
    0x3fee_a47e_b03a_5585,
    0x3fee_a09e_667f_3bcd,
    0x3fee_9f75_e8ec_5f74,
    0x3fee_a114_73eb_0187,
    0x3fee_a589_994c_ce13,
    0x3fee_ace5_422a_a0db,
    0x3fee_b737_b0cd_c5e5,
    0x3fee_c491_82a3_f090,
    0x3fee_d503_b23e_255d,
    0x3fee_e89f_995a_d3ad,
    0x3fee_ff76_f2fb_5e47,
    0x3fef_199b_dd85_529c,
    0x3fef_3720_dcef_9069,
    0x3fef_5818_dcfb_a487,
    0x3fef_7c97_337b_9b5f,
    0x3fef_a4af_a2a4_90da,
    0x3fef_d076_5b6e_4540,
];

/// `32 / ln 2` (`invln2_scaled`).
const INV_LN2_N: f64 = f64::from_bits(0x4047_1547_652b_82fe);
/// `1.5 · 2^52`: added to a value of magnitude below `2^51`, rounds it to an integer held in the
/// sum's low mantissa bits (`shift`).
const SHIFT: f64 = f64::from_bits(0x4338_0000_0000_0000);
/// The cubic's coefficients for `r` in units of `ln 2 / 32` (`poly_scaled`): `C0 r³ + C1 r² + C2 r + 1`.
const C0: f64 = f64::from_bits(0x3ebc_6af8_4b91_2394);
const C1: f64 = f64::from_bits(0x3f2e_bfce_50fa_c4f3);
const C2: f64 = f64::from_bits(0x3f96_2e42_ff0c_52d6);

/// Above this (`log(2^128)`), `exp` overflows to infinity.
const OVERFLOW: f32 = f32::from_bits(0x42b1_7217);
/// Below this (`log(2^-150)`), `exp` is zero.
const UNDERFLOW: f32 = f32::from_bits(0xc2cf_f1b4);
/// Below this (`log(2^-149)`), glibc returns its smallest subnormal (`may_uflow`).
const MAY_UNDERFLOW: f32 = f32::from_bits(0xc2ce_8ecf);

/// `exp(x)`, bit for bit as glibc's `expf` on x86-64 with FMA (see the module's docs), branch-free.
#[must_use]
#[inline(always)]
pub fn expf(x: f32) -> f32 {
    let xd = f64::from(x);
    // k = round(32 x / ln 2), in the low bits of `z`; r = 32 x / ln 2 - k, fused as glibc's is.
    let z = INV_LN2_N.mul_add(xd, SHIFT);
    let ki = z.to_bits();
    let kd = z - SHIFT;
    let r = INV_LN2_N.mul_add(xd, -kd);
    // s = 2^(k/32): the table's 2^((k mod 32)/32) with k/32 added to its exponent.
    let s = f64::from_bits(TABLE[(ki & 31) as usize].wrapping_add(ki << 47));
    let y = C0.mul_add(r, C1).mul_add(r * r, C2.mul_add(r, 1.0));
    // glibc's special cases (all at |x| >= 88, or NaN), where they differ from the main path.
    if x.is_nan() {
        x + x
    } else if x > OVERFLOW {
        f32::INFINITY
    } else if x < UNDERFLOW {
        0.0
    } else if x < MAY_UNDERFLOW {
        f32::from_bits(1)
    } else {
        (y * s) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    /// The reference is the platform's `f32::exp`; the claim is for glibc on x86-64 with FMA.
    fn reference_is_glibc_with_fma() -> bool {
        #[cfg(all(target_arch = "x86_64", target_os = "linux", target_env = "gnu"))]
        {
            std::arch::is_x86_feature_detected!("fma")
        }
        #[cfg(not(all(target_arch = "x86_64", target_os = "linux", target_env = "gnu")))]
        {
            false
        }
    }

    /// Every `stride`-th `f32` bit pattern (the test suite: every 11th, 390 million values, all
    /// exponents and signs; `MIPNERF_EXPF_STRIDE=1` for all 2^32, the run behind
    /// `docs/results/expf/`), and every value of the special cases' neighbourhoods
    /// (`87 <= |x| <= 105`), gives glibc's bits (NaNs: a NaN). Where the reference is another
    /// libm, the values must still agree to one ulp.
    #[test]
    fn every_f32_gives_the_bits_of_glibcs_expf() {
        let exact = reference_is_glibc_with_fma();
        if !exact {
            println!("expf: f32::exp here is not glibc's with FMA; checking agreement to one ulp instead of bits");
        }
        let stride: u64 = std::env::var("MIPNERF_EXPF_STRIDE").ok().and_then(|s| s.parse().ok()).unwrap_or(11).max(1);
        let differs = |bits: u32| {
            let x = f32::from_bits(bits);
            let (got, want) = (expf(x), x.exp());
            let same = if want.is_nan() {
                got.is_nan()
            } else if exact {
                got.to_bits() == want.to_bits()
            } else {
                got.to_bits().abs_diff(want.to_bits()) <= 1
            };
            !same
        };
        let edges = |sign: u32| (87.0f32.to_bits()..=105.0f32.to_bits()).map(move |b| b | sign);
        let count = (u64::from(u32::MAX) + 1).div_ceil(stride);
        let sampled = (0..count).into_par_iter().map(|i| (i * stride) as u32);
        let mut mismatches: Vec<u32> = sampled.filter(|&b| differs(b)).collect();
        mismatches.extend(edges(0).chain(edges(1 << 31)).filter(|&b| differs(b)));
        println!("expf: {count} values at stride {stride} and the edges, {} differ", mismatches.len());
        assert!(
            mismatches.is_empty(),
            "{} values differ, the first: {:?}",
            mismatches.len(),
            mismatches.iter().take(5).map(|&b| (f32::from_bits(b), expf(f32::from_bits(b)))).collect::<Vec<_>>()
        );
    }

    /// The special cases by name, so a failure says which.
    #[test]
    fn the_edges_are_glibcs() {
        assert_eq!(expf(f32::NEG_INFINITY), 0.0);
        assert_eq!(expf(f32::INFINITY), f32::INFINITY);
        assert!(expf(f32::NAN).is_nan());
        assert_eq!(expf(0.0), 1.0);
        assert_eq!(expf(-0.0), 1.0);
        assert_eq!(expf(89.0), f32::INFINITY);
        assert_eq!(expf(-104.0), 0.0);
        assert_eq!(expf(-103.5), f32::from_bits(1));
        assert!(expf(-88.0) > 0.0 && expf(-88.0) < f32::MIN_POSITIVE);
    }
}
