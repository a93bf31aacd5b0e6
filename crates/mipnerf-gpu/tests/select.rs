//! Opening a backend the library's way: `open_backend` for each choice, and a context on a
//! device the app made itself.
#![allow(clippy::unwrap_used, missing_docs)]

use std::sync::Arc;

use mipnerf_core::backend::{ImageSpec, TrainState};
use mipnerf_core::dataset::Dataset;
use mipnerf_core::model::{Levels, Model, Preset};
use mipnerf_core::train::OptimConfig;
use mipnerf_gpu::{BackendChoice, BackendSetup, GpuBackend, GpuContext, open_backend};

fn data() -> Arc<Dataset> {
    mipnerf_gpu::test_support::demo_views(3, 8)
}

fn setup(data: &Arc<Dataset>) -> BackendSetup {
    let model = Model::new(Preset::Tiny.config()).unwrap();
    BackendSetup {
        state: TrainState::fresh(&model, 0),
        model,
        optim: OptimConfig::default(),
        seed: 0,
        data: Some((Arc::clone(data), 16)),
        render_chunk: None,
        device: mipnerf_gpu::DeviceOptions::default(),
    }
}

#[test]
fn every_choice_opens_a_backend_that_trains_and_renders() {
    let d = data();
    let cpu = open_backend(BackendChoice::Cpu, setup(&d)).unwrap();
    assert!(cpu.fallback.is_none() && cpu.backend.describe().starts_with("CPU"));
    let auto = open_backend(BackendChoice::Auto, setup(&d)).unwrap();
    // Auto either runs on a hardware GPU or says why it did not.
    assert_eq!(auto.backend.describe().starts_with("CPU"), auto.fallback.is_some(), "{:?}", auto.fallback);
    // Falling back for want of a hardware GPU, it names every adapter it saw and why it passed
    // each over (so a user learns why their GPU was not used).
    let adapters = mipnerf_gpu::list_adapters();
    if std::env::var_os("WGPU_ADAPTER_NAME").is_none() && adapters.iter().all(|a| a.is_software) {
        let why = auto.fallback.as_deref().unwrap();
        for (i, a) in adapters.iter().enumerate() {
            assert!(why.contains(&format!("[{i}] {}", a.name)) && why.contains("a software adapter"), "{why}");
        }
    }
    let spec = ImageSpec::of_view(&d, 1, 1);
    let mut chosen = vec![cpu.backend, auto.backend];
    if mipnerf_gpu::test_support::context_or_skip("every_choice_opens_a_backend_that_trains_and_renders").is_some() {
        let gpu = open_backend(BackendChoice::Gpu, setup(&d)).unwrap();
        assert!(gpu.fallback.is_none() && gpu.backend.describe().starts_with("GPU"), "{}", gpu.backend.describe());
        chosen.push(gpu.backend);
    }
    for b in &mut chosen {
        b.train_step(true).unwrap().unwrap();
        let r = b.render(&spec, Levels::All).unwrap();
        assert_eq!((r.width, r.height, r.fine.len(), r.coarse.as_ref().map(Vec::len)), (8, 8, 64, Some(64)));
        assert_eq!(r.to_rgb_image().unwrap().dimensions(), (8, 8));
    }
}

#[test]
fn a_context_on_an_apps_own_device_runs_the_backend() {
    let Some(ctx) = mipnerf_gpu::test_support::context_or_skip("a_context_on_an_apps_own_device_runs_the_backend")
    else {
        return;
    };
    drop(ctx);
    // The app makes its own instance, adapter and device...
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
    let instance = wgpu::Instance::new(desc);
    let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default())).unwrap();
    // A device with WebGPU's default limits is refused with what to ask for...
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor::default())).unwrap();
    let err = GpuContext::from_device(&adapter.get_info(), device, queue).unwrap_err();
    assert!(
        matches!(err, mipnerf_gpu::GpuError::UnsupportedLimit { need: 11, have, .. } if have < 11),
        "a typed error naming the limit: {err:?}"
    );
    let msg = err.to_string();
    assert!(msg.contains("max_storage_buffers_per_shader_stage") && msg.contains("need 11"), "{msg}");
    // ...one that asks for the one limit mipnerf needs above them runs everything.
    let limits = wgpu::Limits {
        max_storage_buffers_per_shader_stage: mipnerf_gpu::context::MIN_STORAGE_BUFFERS_PER_STAGE,
        ..wgpu::Limits::default()
    };
    let desc = wgpu::DeviceDescriptor { required_limits: limits, ..Default::default() };
    let (device, queue) = pollster::block_on(adapter.request_device(&desc)).unwrap();
    let ctx = GpuContext::from_device(&adapter.get_info(), device, queue).unwrap();
    let d = data();
    let s = setup(&d);
    let mut b = GpuBackend::new(ctx, s.model, s.optim, s.seed, s.state).unwrap().with_data(&d, 16).unwrap();
    let report = mipnerf_core::backend::Backend::train_step(&mut b, true).unwrap().unwrap();
    assert!(report.stats.loss.is_finite());
}
