//! Flushing subnormal floats to zero for the span of a training step: x86's MXCSR bits FTZ
//! (a result below f32's smallest normal becomes zero) and DAZ (a subnormal operand is read as
//! zero), set on the calling thread and on every thread of its rayon pool, and restored after.
//!
//! Why: as a model learns, the gradients that reach samples in empty space shrink below
//! `1.2e-38`, and every f32 operation on such a value costs a microcode assist (tens to hundreds
//! of cycles). The faithful path slowed from 0.38 to 0.60 s a step over a run for it
//! (`docs/RESULTS.md`, "Why the faithful row slows"). Flushing changes results only where a
//! value is subnormal, which the paper's f32 leaves to the hardware; the presets whose results
//! are committed bit for bit (paper, small) never flush (see `docs/results/subnormals/`).
//!
//! Off x86-64 this does nothing (AArch64's FPCR.FZ is not set here).
#![allow(unsafe_code)]

use std::cell::Cell;

/// MXCSR's flush-to-zero (bit 15) and denormals-are-zero (bit 6) bits.
const FTZ_DAZ: u32 = (1 << 15) | (1 << 6);
/// MXCSR's sticky exception flags (bits 0 to 5: invalid, denormal, divide by zero, overflow,
/// underflow, precision), which arithmetic sets and a restore clears: not control bits.
const EXCEPTION_FLAGS: u32 = 0x3f;

thread_local! {
    /// How many [`Flushed`] scopes are open on this thread, and its MXCSR before the first.
    static SCOPES: Cell<(u32, u32)> = const { Cell::new((0, 0)) };
}

/// While alive, subnormals are flushed to zero on the thread that made it and on every thread
/// of the rayon pool it was made in; dropping it restores each thread's previous mode. Made on
/// one thread and dropped on it (not `Send`).
#[derive(Debug)]
#[must_use = "subnormals are flushed only while the scope is alive"]
pub struct Flushed {
    _not_send: std::marker::PhantomData<*const ()>,
}

impl Flushed {
    /// Starts flushing subnormals (see [`Flushed`]). Scopes nest: the mode is restored when the
    /// outermost one ends.
    pub fn begin() -> Self {
        on_every_thread(enter);
        Self { _not_send: std::marker::PhantomData }
    }

    /// Whether subnormals are flushed on this thread now (both bits set).
    #[must_use]
    pub fn active_here() -> bool {
        mxcsr().is_some_and(|v| v & FTZ_DAZ == FTZ_DAZ)
    }
}

impl Drop for Flushed {
    fn drop(&mut self) {
        on_every_thread(leave);
    }
}

/// Runs `f` on this thread and on every thread of the current rayon pool (this thread's pool,
/// or the global one).
fn on_every_thread(f: fn()) {
    f();
    if rayon::current_thread_index().is_none() {
        rayon::broadcast(|_| f());
    } else {
        // Inside the pool, broadcast reaches this thread too: `f` must not run twice here.
        let here = std::thread::current().id();
        rayon::broadcast(move |_| {
            if std::thread::current().id() != here {
                f();
            }
        });
    }
}

fn enter() {
    let Some(now) = mxcsr() else { return };
    SCOPES.with(|scopes| {
        let (open, before) = scopes.get();
        if open == 0 {
            set_mxcsr(now | FTZ_DAZ);
            scopes.set((1, now));
        } else {
            scopes.set((open + 1, before));
        }
    });
}

fn leave() {
    SCOPES.with(|scopes| match scopes.get() {
        (0, _) => {}
        (1, before) => {
            set_mxcsr(before);
            scopes.set((0, 0));
        }
        (open, before) => scopes.set((open - 1, before)),
    });
}

/// This thread's MXCSR, where there is one.
#[cfg(target_arch = "x86_64")]
fn mxcsr() -> Option<u32> {
    let mut value = 0u32;
    // SAFETY: `stmxcsr` stores the 32-bit control and status register to the given address,
    // a live local of that size; it touches nothing else.
    unsafe {
        std::arch::asm!("stmxcsr [{}]", in(reg) &raw mut value, options(nostack, preserves_flags));
    }
    Some(value)
}

#[cfg(not(target_arch = "x86_64"))]
fn mxcsr() -> Option<u32> {
    None
}

/// Loads `value` into this thread's MXCSR.
#[cfg(target_arch = "x86_64")]
fn set_mxcsr(value: u32) {
    // Of the control bits, only FTZ and DAZ ever differ from the value read back: the rounding
    // mode and the exception masks stay as they were, so no operation traps or rounds otherwise.
    debug_assert_eq!(mxcsr().map(|now| (now ^ value) & !(FTZ_DAZ | EXCEPTION_FLAGS) & 0xffff), Some(0));
    // SAFETY: `ldmxcsr` reads 32 bits from a live local; the value is a valid MXCSR (the one
    // read back, with FTZ and DAZ set or restored: reserved bits unchanged). LLVM assumes the
    // default floating-point environment: with FTZ/DAZ, an operation on a subnormal value may
    // give zero at run time where constant folding would not. That changes numbers, never
    // memory safety: no code relies on a subnormal result for an index or a bound (indices
    // from floats are clamped and bounds-checked).
    unsafe {
        std::arch::asm!("ldmxcsr [{}]", in(reg) &raw const value, options(nostack, readonly, preserves_flags));
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn set_mxcsr(_value: u32) {}

#[cfg(test)]
mod tests {
    use super::*;

    /// The smallest positive normal f32 halved: subnormal.
    fn subnormal_product(x: f32) -> f32 {
        std::hint::black_box(x) * std::hint::black_box(0.5)
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn a_scope_flushes_on_every_pool_thread_and_restores_them() {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        pool.install(|| {
            let tiny = f32::MIN_POSITIVE;
            assert!(subnormal_product(tiny) > 0.0, "subnormals are kept by default");
            let everywhere = |want: bool| rayon::broadcast(|_| Flushed::active_here() == want).iter().all(|&b| b);
            assert!(everywhere(false));
            {
                let _flushed = Flushed::begin();
                assert!(Flushed::active_here());
                assert!(everywhere(true), "every thread of the pool flushes");
                assert_eq!(subnormal_product(tiny), 0.0, "FTZ: a subnormal result is zero");
                // DAZ: a subnormal operand reads as zero (the sum would be 1.25 MIN_POSITIVE).
                let sub = f32::from_bits(f32::MIN_POSITIVE.to_bits() / 4);
                assert_eq!(std::hint::black_box(sub) + std::hint::black_box(tiny), tiny);
                // A nested scope's end restores nothing: the outer one is still open.
                drop(Flushed::begin());
                assert!(everywhere(true));
            }
            assert!(everywhere(false), "every thread restored");
            assert!(subnormal_product(tiny) > 0.0);
        });
    }
}
