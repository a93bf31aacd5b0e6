//! Loops compiled for the CPU's widest vectors, chosen when they run.
//!
//! The workspace is built for the baseline x86-64 (SSE2), so a plain loop runs 4 `f32` lanes
//! wide, or 2 `f64`. [`wide`] runs a loop compiled for AVX-512F (16 and 8 lanes) where the CPU
//! has it, else for AVX2 (8 and 4) where it has that, both with FMA. The floating-point results
//! are the same bits either way: Rust neither fuses a multiply with an add nor reorders a sum
//! unless asked (`mul_add`, which is one fused operation on every build: an instruction with FMA,
//! a call to libm's `fma` on the baseline), so a wider build performs the same operations on more
//! values at once.

// Calling a function compiled for features the baseline lacks is `unsafe`: each call here is
// behind the check that the CPU has them.
#![allow(unsafe_code)]

/// Calls `f` compiled for AVX-512F and FMA where the CPU has both, else for AVX2 and FMA where it
/// has those, else as built.
///
/// `f` should be a closure around a loop whose callees are inlined (`#[inline(always)]`): code
/// behind a call that is not inlined runs as built.
#[inline(always)]
pub fn wide<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if has_avx512() {
        // SAFETY: the CPU has AVX-512F and FMA (checked above).
        return unsafe { avx512(f) };
    }
    #[cfg(target_arch = "x86_64")]
    if has_avx2() {
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        return unsafe { avx2(f) };
    }
    f()
}

/// Whether the CPU has AVX2 and FMA, [`wide`]'s second choice.
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether [`wide`] runs 512-bit vectors on this CPU.
#[must_use]
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
unsafe fn avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loop_gives_the_same_bits_wide_and_as_built() {
        let x: Vec<f32> = (0..1000).map(|i| (i as f32 * 0.37).sin() * 1e3).collect();
        let run = |x: &[f32]| -> (Vec<f32>, f32) {
            let y: Vec<f32> = x.iter().map(|&v| (v * 1.7 + 0.3).max(0.0) / (1.0 + v * v)).collect();
            let sum = y.iter().fold(0.0f32, |s, &v| s + v * v);
            (y, sum)
        };
        let (y0, s0) = run(&x);
        let (y1, s1) = wide(|| run(&x));
        assert!(y0.iter().zip(&y1).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(s0.to_bits(), s1.to_bits());
        // The AVX2 build too, where the CPU has it (every CPU with AVX-512 does).
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            let (y2, s2) = unsafe { avx2(|| run(&x)) };
            assert!(y0.iter().zip(&y2).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert_eq!(s0.to_bits(), s2.to_bits());
        }
    }

    /// A loop of fused multiply-adds and glibc's `expf` ([`crate::expf::expf`], a table lookup
    /// and four of them) gives the same bits on every build: FMA instructions at 16 and 8 lanes,
    /// libm's `fma` as built.
    #[test]
    fn fused_multiply_adds_and_expf_give_the_same_bits_on_every_build() {
        let x: Vec<f32> = (0..4000).map(|i| -0.05 * i as f32 + (i as f32 * 0.7).sin()).collect();
        let run = |x: &[f32]| -> Vec<u32> {
            x.iter().map(|&v| (crate::expf::expf(v) + v.mul_add(1.5, 0.25)).to_bits()).collect()
        };
        let built = run(&x);
        assert_eq!(built, wide(|| run(&x)));
        #[cfg(target_arch = "x86_64")]
        if has_avx2() {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            assert_eq!(built, unsafe { avx2(|| run(&x)) });
        }
    }
}
