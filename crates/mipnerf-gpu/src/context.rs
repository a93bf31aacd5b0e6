//! The one context that holds the wgpu device and queue, adapter discovery, and error capture.

use std::sync::{Arc, Mutex};

use crate::GpuError;

/// The most storage buffers one kernel binds (`batch.wgsl`: 11), which a device must allow per
/// shader stage (WebGPU's default is 8).
pub const MIN_STORAGE_BUFFERS_PER_STAGE: u32 = 11;

/// Which adapters [`GpuContext::new`] may pick.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AdapterChoice {
    /// The best adapter found: a discrete GPU, else an integrated one, else a virtual one, else a
    /// software rasteriser (lavapipe).
    #[default]
    Any,
    /// Only a hardware GPU (never a CPU/software adapter); [`GpuError::NoAdapter`] otherwise.
    HardwareOnly,
}

/// What is known about one adapter, for `mipnerf info` and logs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AdapterSummary {
    /// The adapter's name, e.g. "NVIDIA H100" or "llvmpipe (LLVM 19.1.7, 256 bits)".
    pub name: String,
    /// The API wgpu drives it through (Vulkan, Metal, Dx12, ...).
    pub backend: String,
    /// Discrete, integrated, virtual, CPU (software) or other.
    pub device_type: String,
    /// The driver's name and version, as the driver reports them.
    pub driver: String,
    /// Whether this is a software (CPU) adapter.
    pub is_software: bool,
}

impl AdapterSummary {
    fn from_info(info: &wgpu::AdapterInfo) -> Self {
        Self {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
            is_software: info.device_type == wgpu::DeviceType::Cpu,
        }
    }
}

fn instance() -> wgpu::Instance {
    // Vulkan, Metal and DX12 only: the backends with the compute features we need.
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
    wgpu::Instance::new(desc)
}

fn rank(info: &wgpu::AdapterInfo) -> u8 {
    match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

/// Every adapter wgpu can see on this machine, best first.
#[must_use]
pub fn list_adapters() -> Vec<AdapterSummary> {
    let mut infos: Vec<wgpu::AdapterInfo> = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::all()))
        .iter()
        .map(wgpu::Adapter::get_info)
        .collect();
    infos.sort_by_key(rank);
    infos.iter().map(AdapterSummary::from_info).collect()
}

/// Errors that wgpu reported asynchronously (validation, out of memory, device loss).
#[derive(Default)]
struct ErrorSink {
    errors: Vec<wgpu::Error>,
    lost: Option<(wgpu::DeviceLostReason, String)>,
}

/// The sink, even if a callback panicked while holding it (its contents are still valid).
fn lock(sink: &Mutex<ErrorSink>) -> std::sync::MutexGuard<'_, ErrorSink> {
    sink.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The device and queue every kernel runs on, with the adapter they came from.
///
/// wgpu reports validation errors and device loss through callbacks; the context collects them so
/// that [`GpuContext::check`] turns them into a [`GpuError`] instead of a panic.
pub struct GpuContext {
    /// The adapter this context runs on.
    pub adapter: AdapterSummary,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    sink: Arc<Mutex<ErrorSink>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.adapter).finish_non_exhaustive()
    }
}

impl GpuContext {
    /// Opens the best adapter allowed by `choice` and creates a device with the adapter's own
    /// limits (so large storage buffers are available where the hardware has them).
    ///
    /// # Errors
    /// [`GpuError::NoAdapter`] when no adapter fits (with a hint on how to get one), and
    /// [`GpuError::RequestDevice`] when the device cannot be created.
    pub fn new(choice: AdapterChoice) -> Result<Self, GpuError> {
        let inst = instance();
        let mut adapters = pollster::block_on(inst.enumerate_adapters(wgpu::Backends::all()));
        adapters.sort_by_key(|a| rank(&a.get_info()));
        let adapter = adapters
            .into_iter()
            .find(|a| choice == AdapterChoice::Any || a.get_info().device_type != wgpu::DeviceType::Cpu)
            .ok_or(GpuError::NoAdapter { hardware_only: choice == AdapterChoice::HardwareOnly })?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("mipnerf device"),
            required_features: wgpu::Features::empty(),
            required_limits: adapter.limits(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|source| GpuError::RequestDevice { adapter: info.name.clone(), source })?;
        Self::from_device(&info, device, queue)
    }

    /// A context on a device and queue an app already owns (made from the adapter `info`
    /// describes). The context installs its error and device-lost callbacks on the device. The
    /// kernels need no features, and one limit above WebGPU's defaults: at least
    /// [`MIN_STORAGE_BUFFERS_PER_STAGE`] storage buffers per shader stage (request it in
    /// `required_limits`; every Vulkan, Metal and DX12 GPU has it). The other limits the device
    /// was made with bound the batch (a batch too large for them runs in chunks or is refused
    /// with the limit).
    ///
    /// # Errors
    /// [`GpuError::UnsupportedLimit`] when the device allows too few storage buffers per stage.
    pub fn from_device(info: &wgpu::AdapterInfo, device: wgpu::Device, queue: wgpu::Queue) -> Result<Self, GpuError> {
        let have = device.limits().max_storage_buffers_per_shader_stage;
        if have < MIN_STORAGE_BUFFERS_PER_STAGE {
            return Err(GpuError::UnsupportedLimit {
                adapter: info.name.clone(),
                limit: "max_storage_buffers_per_shader_stage",
                have: u64::from(have),
                need: u64::from(MIN_STORAGE_BUFFERS_PER_STAGE),
            });
        }
        let sink = Arc::new(Mutex::new(ErrorSink::default()));
        let s = Arc::clone(&sink);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            lock(&s).errors.push(e);
        }));
        let s = Arc::clone(&sink);
        device.set_device_lost_callback(move |reason, msg| {
            lock(&s).lost = Some((reason, msg));
        });
        Ok(Self { adapter: AdapterSummary::from_info(info), device, queue, sink })
    }

    /// Returns the first error wgpu reported since the last check, if any, and clears the list.
    /// A lost device is reported before anything else, then the first out-of-memory error, then
    /// the first other error.
    ///
    /// # Errors
    /// [`GpuError::DeviceLost`], [`GpuError::OutOfMemory`] or [`GpuError::Wgpu`].
    pub fn check(&self) -> Result<(), GpuError> {
        let mut g = lock(&self.sink);
        if let Some((reason, message)) = &g.lost {
            return Err(GpuError::DeviceLost { reason: *reason, message: message.clone() });
        }
        let mut errors = std::mem::take(&mut g.errors);
        if errors.is_empty() {
            return Ok(());
        }
        if let Some(i) = errors.iter().position(|e| matches!(e, wgpu::Error::OutOfMemory { .. })) {
            return Err(GpuError::OutOfMemory(errors.swap_remove(i)));
        }
        let more = errors.len() - 1;
        Err(GpuError::Wgpu { first: errors.swap_remove(0), more })
    }

    /// The most bytes one storage buffer binding may hold on this device (the smaller of the
    /// binding and buffer size limits).
    #[must_use]
    pub fn max_binding_bytes(&self) -> u64 {
        let limits = self.device.limits();
        limits.max_storage_buffer_binding_size.min(limits.max_buffer_size)
    }

    /// Creates a labelled storage buffer initialised with `data`.
    #[must_use]
    pub fn storage_buffer<T: bytemuck::Pod>(&self, label: &str, data: &[T], copy_src: bool) -> wgpu::Buffer {
        use wgpu::util::DeviceExt;
        let mut usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        if copy_src {
            usage |= wgpu::BufferUsages::COPY_SRC;
        }
        // wgpu rejects zero-sized bindings; keep at least 4 bytes.
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let padded;
        let contents = if bytes.is_empty() {
            padded = [0u8; 4];
            &padded[..]
        } else {
            bytes
        };
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
    }

    /// Creates a labelled uniform buffer holding `value`.
    #[must_use]
    pub fn uniform_buffer<T: bytemuck::Pod>(&self, label: &str, value: &T) -> wgpu::Buffer {
        use wgpu::util::DeviceExt;
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
    }

    /// Copies `len` `f32`s from the start of `buffer` (which needs `COPY_SRC`) back to the host,
    /// waiting for all submitted work.
    ///
    /// # Errors
    /// Any error wgpu reported while the work ran, or a failed map.
    pub fn read_f32(&self, buffer: &wgpu::Buffer, len: usize) -> Result<Vec<f32>, GpuError> {
        let size = (len * 4) as u64;
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("mipnerf readback staging"),
            size: size.max(4),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("mipnerf readback") });
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(GpuError::Poll)?;
        self.check()?;
        // The wait above ran every callback: a missing result means the map was dropped unanswered.
        rx.recv().unwrap_or(Err(wgpu::BufferAsyncError)).map_err(GpuError::Readback)?;
        let view = staging.get_mapped_range(..).map_err(|_| GpuError::Readback(wgpu::BufferAsyncError))?;
        let out = bytemuck::cast_slice::<u8, f32>(&view)[..len].to_vec();
        drop(view);
        staging.unmap();
        Ok(out)
    }
}
