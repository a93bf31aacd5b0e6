//! # mipnerf-gpu
//!
//! Mip-NeRF's passes as WGSL compute shaders run through wgpu (Vulkan, Metal, DX12, or software
//! Vulkan: lavapipe). Every kernel computes what `mipnerf-core` computes on the CPU and is tested
//! against it.
//!
//! - [`GpuContext`]: the one device and queue, with adapter discovery and error capture.
//! - `kernels` (internal): one type per kernel, owning its pipeline and bind-group layout; the WGSL
//!   sources live in the workspace's `shaders/` folder and are compiled in with `include_str!`.
//! - `mlp` and `model` (internal): the MLP and the whole two-level model of a batch, forward and
//!   backward, from those kernels.
//! - [`GpuBackend`]: training and chunked rendering entirely on the device, behind
//!   `mipnerf_core::backend::Backend` (the CPU implements the same trait);
//!   [`GpuBackend::bytes_per_ray`] sizes its batches.
//! - [`check`]: the device against the CPU reference (`mipnerf check`).

pub mod check;
pub mod context;
// The kernels, the MLP and model passes built from them, and the test helpers are public only
// with the `test-support` feature, which this workspace's tests and benchmarks turn on to check
// each kernel against the CPU; the API an app builds on is `open_backend`, `GpuBackend`,
// `GpuContext` and `check`. What only the tests call (a kernel run on host data, a variant
// chosen by hand) is compiled with the feature alone, so that code nothing calls is a warning.
#[cfg(feature = "test-support")]
#[doc(hidden)]
pub mod kernels;
#[cfg(not(feature = "test-support"))]
mod kernels;
#[cfg(feature = "test-support")]
#[doc(hidden)]
pub mod mlp;
#[cfg(not(feature = "test-support"))]
mod mlp;
#[cfg(feature = "test-support")]
#[doc(hidden)]
pub mod model;
#[cfg(not(feature = "test-support"))]
mod model;
pub mod select;
pub mod trainer;

pub use context::{
    AdapterChoice, AdapterSummary, DISABLE_FLOAT_ATOMICS_ENV, GpuContext, GradientAtomics, list_adapters,
};
pub use select::{BackendChoice, BackendSetup, DeviceOptions, OpenError, OpenedBackend, open_backend};
pub use trainer::GpuBackend;

/// Errors of the GPU backend. None of them is a panic: a missing or lost device is an error value.
/// Each variant keeps wgpu's own error as its [`source`](std::error::Error::source) where wgpu gave
/// one, so `{:#}` (or anyhow's chain) prints what the driver said.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No adapter fits the request.
    #[error(
        "no GPU adapter found for {wanted}{}. Install a Vulkan driver (for a software one on Debian/Ubuntu: \
         'apt-get install mesa-vulkan-drivers libvulkan1', or run scripts/ensure-vulkan.sh), pick another \
         adapter (`DeviceOptions::adapter`), or use the CPU backend (`BackendChoice::Cpu`)",
        if passed_over.is_empty() { "; wgpu saw no adapter".to_string() } else { format!("; passed over: {}", passed_over.join("; ")) }
    )]
    NoAdapter {
        /// What was asked for ("a hardware GPU", "adapter 2", ...).
        wanted: String,
        /// Every adapter seen, numbered as `mipnerf info` numbers them, with why it was passed over.
        passed_over: Vec<String>,
    },
    /// The adapter refused to create a device.
    #[error("could not open the GPU device on {adapter}")]
    RequestDevice {
        /// The adapter's name.
        adapter: String,
        /// What wgpu said.
        #[source]
        source: wgpu::RequestDeviceError,
    },
    /// The device's limits are below what the kernels need: an unsupported configuration.
    #[error(
        "{adapter}: the device's {limit} is {have}; mipnerf's kernels need {need} (when you create the \
         device yourself, request it in required_limits)"
    )]
    UnsupportedLimit {
        /// The adapter's name.
        adapter: String,
        /// The limit, as `wgpu::Limits` names it (e.g. `max_storage_buffers_per_shader_stage`).
        limit: &'static str,
        /// What the device allows.
        have: u64,
        /// What the kernels need.
        need: u64,
    },
    /// The device was lost (driver reset, GPU removed, device destroyed).
    #[error("the GPU device was lost ({reason:?}): {message}")]
    DeviceLost {
        /// wgpu's reason.
        reason: wgpu::DeviceLostReason,
        /// The driver's message.
        message: String,
    },
    /// The device ran out of memory while making a buffer or running work.
    #[error("the GPU ran out of memory")]
    OutOfMemory(#[source] wgpu::Error),
    /// wgpu rejected a shader, pipeline, buffer or command (validation), or failed internally.
    /// `more` counts further errors reported with it.
    #[error("wgpu reported an error{}", if *more > 0 { format!(" ({more} more after it)") } else { String::new() })]
    Wgpu {
        /// The first error wgpu reported.
        #[source]
        first: wgpu::Error,
        /// How many more it reported since the last check.
        more: usize,
    },
    /// The device did not finish the submitted work within the timeout.
    #[error(
        "{adapter} did not finish its work within {seconds:.0} s: the device may hang, or a batch is too \
         large for it (lower the rays per batch, `BackendSetup::data`)"
    )]
    Timeout {
        /// The adapter's name.
        adapter: String,
        /// The timeout.
        seconds: f64,
    },
    /// Making a batch's buffers ran the device out of memory.
    #[error(
        "the batch does not fit on {adapter} ({mib:.0} MiB needed): lower the rays per batch \
         (`BackendSetup::data`) or the memory budget (`DeviceOptions::memory_budget`)"
    )]
    BatchTooLarge {
        /// The adapter's name.
        adapter: String,
        /// The buffers' size, in MiB.
        mib: f64,
        /// What wgpu said.
        #[source]
        source: wgpu::Error,
    },
    /// Waiting for the device failed.
    #[error("waiting for the GPU failed")]
    Poll(#[source] wgpu::PollError),
    /// Reading a buffer back to the host failed.
    #[error("reading a GPU buffer back failed")]
    Readback(#[source] wgpu::BufferAsyncError),
    /// The caller's inputs are inconsistent.
    #[error("invalid input to a GPU kernel: {0}")]
    InvalidInput(String),
    /// A setting this backend does not run (the CPU backend does).
    #[error(transparent)]
    Unsupported(#[from] mipnerf_core::backend::Unsupported),
}

/// Support for tests that need a GPU, shared by this crate's and the workspace's tests (the
/// `test-support` feature, which only the tests' dev-dependencies turn on).
#[cfg(feature = "test-support")]
#[doc(hidden)]
pub mod test_support {
    use std::sync::Arc;

    use mipnerf_core::dataset::Dataset;
    use mipnerf_core::demo;

    use crate::{AdapterChoice, GpuContext};

    /// `n` views of the demo scene held in memory, `side` x `side` pixels each
    /// ([`demo::dataset`]).
    ///
    /// # Panics
    /// If `n` or `side` is 0.
    #[must_use]
    pub fn demo_views(n: usize, side: u32) -> Arc<Dataset> {
        Arc::new(demo::dataset(n, side).expect("at least one view of at least one pixel"))
    }

    /// Relative size of the input changes that stand for a hardware GPU's rounding: 2^-20, 8 ulps
    /// of an f32. Vulkan allows division 2.5 ulp off and `sqrt` and `exp` a few, the driver's
    /// compiler fuses multiply-adds where it likes, and reductions run in another order, so a
    /// position or weight a kernel computes lands a few ulps from the CPU's. Measured on an
    /// NVIDIA H100 (`docs/results/gpu-h100/`): IPE features 1e-5 from the CPU's where lavapipe
    /// gives 2.4e-7, the inputs of the high-degree sines moved by an ulp or two.
    pub const HARDWARE_ROUNDING_REL: f32 = 1.0 / 1_048_576.0;

    /// On a hardware adapter, `n` perturbed copies of a kernel's inputs for
    /// [`check_kernel_conditioned`](mipnerf_core::compare::check_kernel_conditioned), the `i`th
    /// made by `perturb` with a [`Nudge`] of its own seeded by `i`, each value moved by up to
    /// `rel` of itself. On a software adapter none: lavapipe's arithmetic is the CPU's operation
    /// for operation, so there the checks stay as strict as their tolerances.
    pub fn hardware_perturbations<T>(
        ctx: &GpuContext,
        n: usize,
        rel: f32,
        mut perturb: impl FnMut(&mut Nudge) -> T,
    ) -> Vec<T> {
        // MIPNERF_TEST_PERTURB=1 perturbs on a software adapter too (to see the spreads there).
        if ctx.adapter().is_software && std::env::var_os("MIPNERF_TEST_PERTURB").is_none_or(|v| v != "1") {
            return Vec::new();
        }
        (0..n).map(|i| perturb(&mut Nudge { state: 0x9e37_79b9_7f4a_7c15 ^ i as u64, rel })).collect()
    }

    /// Random relative nudges of values: `x (1 + rel u)`, `u` uniform in [-1, 1] (splitmix64).
    #[derive(Clone, Debug)]
    pub struct Nudge {
        state: u64,
        /// The largest relative change.
        pub rel: f32,
    }

    impl Nudge {
        /// `x` moved by up to `rel` of itself.
        pub fn value(&mut self, x: f32) -> f32 {
            self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^= z >> 31;
            let u = (z >> 40) as f32 / (1u64 << 23) as f32 - 1.0;
            x * (1.0 + self.rel * u)
        }

        /// `ray` with each coordinate of its origin and direction, its radius, its near bound and
        /// a finite far bound (not an unbounded scene's stand-in for infinity) moved.
        pub fn ray(&mut self, ray: &mipnerf_core::Ray) -> mipnerf_core::Ray {
            let far = if ray.far < mipnerf_core::contract::UNBOUNDED_FAR { self.value(ray.far) } else { ray.far };
            mipnerf_core::Ray {
                origin: ray.origin.map(|c| self.value(c)),
                direction: ray.direction.map(|c| self.value(c)),
                radius: self.value(ray.radius),
                near: self.value(ray.near),
                far,
                ..*ray
            }
        }
    }

    /// The context GPU tests run on, or `None` (after printing one line saying how to get an
    /// adapter) when this machine has none and the tests do not run in CI.
    ///
    /// # Panics
    /// In CI (`CI` set to anything but `false`/`0`), when no adapter is found or it cannot be
    /// opened: CI must prove the WGSL on a real (software) adapter, never skip silently.
    #[must_use]
    pub fn context_or_skip(test: &str) -> Option<GpuContext> {
        match GpuContext::new(AdapterChoice::Any) {
            Ok(ctx) => Some(ctx),
            Err(e) => {
                let in_ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "false" && v != "0");
                assert!(!in_ci, "{test}: CI needs a GPU adapter (lavapipe at least), but: {e}");
                eprintln!(
                    "SKIPPED {test}: no GPU adapter ({e}); run scripts/ensure-vulkan.sh as root to install lavapipe"
                );
                None
            }
        }
    }

    /// Contexts for a test to build kernels on, one for each way of adding shared gradients
    /// ([`GradientAtomics`](crate::GradientAtomics)): compare-exchange always, float atomics
    /// where the adapter has them (lavapipe does; a line says when it does not). Empty where
    /// [`context_or_skip`] skips.
    #[must_use]
    pub fn contexts_of_each_atomics(test: &str) -> Vec<(crate::GradientAtomics, GpuContext)> {
        use crate::GradientAtomics;
        let mut out = Vec::new();
        for atomics in [GradientAtomics::CompareExchange, GradientAtomics::Float] {
            let Some(ctx) = context_or_skip(test) else { return out };
            match ctx.with_gradient_atomics(atomics) {
                Ok(ctx) => out.push((atomics, ctx)),
                Err(e) => eprintln!("{test}: {atomics:?} not run: {e}"),
            }
        }
        out
    }
}
