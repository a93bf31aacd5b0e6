//! What a hardware GPU can do to a run, shown on a real adapter (lavapipe in CI): waits that time
//! out, batches that do not fit, memory budgets.
#![allow(clippy::unwrap_used, missing_docs)]

use std::time::Duration;

use mipnerf_core::backend::BackendError;
use mipnerf_gpu::GpuError;
use mipnerf_gpu::kernels::Recorder;
use mipnerf_gpu::kernels::matmul::{Epilogue, MatmulKernel, MatmulVariant, Operand};
use mipnerf_gpu::test_support::context_or_skip;

/// A wait that outlasts the context's timeout is a [`GpuError::Timeout`] naming the adapter and
/// what to do, not a hang; the work still finishes, and a longer wait sees it.
#[test]
fn a_wait_past_the_timeout_is_a_clear_error() {
    let Some(ctx) = context_or_skip("a_wait_past_the_timeout_is_a_clear_error") else { return };
    let ctx = ctx.with_timeout(Duration::from_micros(1));
    // About 2 GFLOP: far longer than a microsecond on any device.
    let (m, k, n) = (65_536usize, 128usize, 128usize);
    let a = ctx.storage_buffer("a", &vec![0.5f32; m * k], false);
    let b = ctx.storage_buffer("b", &vec![0.25f32; k * n], false);
    let c = ctx.storage_buffer("c", &vec![f32::NAN; m * n], true);
    let kernel = MatmulKernel::with_variant(&ctx, MatmulVariant::for_adapter(&ctx)).unwrap();
    let mut rec = Recorder::new(&ctx, "long product");
    for _ in 0..4 {
        kernel.encode(
            &mut rec,
            mipnerf_gpu::kernels::matmul::Product {
                shape: (m, k, n),
                a: Operand::new(&a, 0),
                b: Operand::new(&b, 0),
                c: Operand::new(&c, 0),
                epi: Epilogue::default(),
            },
        );
    }
    let _ = rec.submit();
    let err = ctx.wait().unwrap_err();
    assert!(matches!(err, GpuError::Timeout { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(
        msg.contains(&ctx.adapter().name) && msg.contains("did not finish") && msg.contains("rays per batch"),
        "{msg}"
    );
    let ctx = ctx.with_timeout(Duration::from_secs(600));
    let got = ctx.read_f32(&c, 4).unwrap();
    assert_eq!(got, vec![0.5 * 0.25 * k as f32; 4]);
}

/// A batch that the device cannot hold is reported as "the batch does not fit on <adapter> (<MiB>
/// needed): lower the rays per batch" (the setting, which the CLI names by its flag), kept as an out-of-memory error of the backend with wgpu's error
/// as its source. (A real out-of-memory cannot be provoked safely on a shared CI machine: lavapipe
/// allocates host memory; the scope that catches it is [`GpuContext::allocating`], run around
/// every batch and render allocation.)
#[test]
fn a_batch_too_large_for_the_device_names_the_adapter_the_size_and_the_setting() {
    use std::error::Error as _;
    let e = GpuError::BatchTooLarge {
        adapter: "NVIDIA H100 80GB HBM3".into(),
        mib: 81_234.4,
        source: wgpu::Error::OutOfMemory { source: Box::new(std::io::Error::other("vkAllocateMemory")) },
    };
    assert_eq!(
        e.to_string(),
        "the batch does not fit on NVIDIA H100 80GB HBM3 (81234 MiB needed): lower the rays per batch \
         (`BackendSetup::data`) or the memory budget (`DeviceOptions::memory_budget`)"
    );
    let b = BackendError::from(e);
    assert!(matches!(b, BackendError::OutOfMemory(_)), "{b:?}");
    assert!(b.to_string().starts_with("the batch does not fit on NVIDIA H100"), "{b}");
    assert!(b.source().is_some(), "wgpu's error is kept");
    // The scope passes what it wraps through when nothing runs out.
    let Some(ctx) = context_or_skip("a_batch_too_large_for_the_device_names_the_adapter_the_size_and_the_flag") else {
        return;
    };
    let buf = ctx.allocating(1 << 20, || Ok(ctx.storage_buffer("fits", &vec![1.0f32; 1 << 18], true))).unwrap();
    assert_eq!(ctx.read_f32(&buf, 2).unwrap(), vec![1.0, 1.0]);
    let err = ctx.allocating(0, || -> Result<(), GpuError> { Err(GpuError::InvalidInput("mine".into())) });
    assert!(matches!(err, Err(GpuError::InvalidInput(ref m)) if m == "mine"), "{err:?}");
}

/// The memory budget follows the device (four of its largest bindings on hardware, one on a
/// software adapter, 1 to 16 GiB) unless set, and a set budget is what sizes the training chunks.
#[test]
fn the_memory_budget_scales_with_the_device_or_the_flag() {
    use mipnerf_core::backend::{Backend, TrainState};
    use mipnerf_core::model::{Model, Preset};
    use mipnerf_core::train::OptimConfig;
    use mipnerf_gpu::GpuBackend;
    use mipnerf_gpu::model::ModelBuffers;
    let Some(ctx) = context_or_skip("the_memory_budget_scales_with_the_device_or_the_flag") else { return };
    let default = ctx.memory_budget();
    let bindings = if ctx.adapter().is_software { 1 } else { 4 };
    assert_eq!(default, (bindings * ctx.max_binding_bytes()).clamp(1 << 30, 16 << 30));
    let ctx = ctx.with_memory_budget(Some(8 << 20));
    assert_eq!(ctx.memory_budget(), 8 << 20);
    let model = Model::new(Preset::Tiny.config()).unwrap();
    let state = TrainState::fresh(&model, 0);
    let ds = mipnerf_gpu::test_support::demo_views(2, 16);
    let per_ray = ModelBuffers::bytes_per_ray(&model);
    let b = GpuBackend::new(ctx, model, OptimConfig::default(), 0, state).unwrap().with_data(&ds, 512).unwrap();
    let chunk = (8u64 << 20) / per_ray;
    assert!(chunk < 512, "the test needs a budget below one batch ({chunk} rays)");
    let d = b.describe();
    assert!(d.contains(&format!("in chunks of {chunk} rays")), "{d}");
}
