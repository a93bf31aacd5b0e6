//! The one context that holds the wgpu device and queue, adapter discovery, and error capture.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use mipnerf_core::backend::WorkCounters;

use crate::GpuError;

/// The most storage buffers one kernel binds (`batch.wgsl`: 11), which a device must allow per
/// shader stage (WebGPU's default is 8).
pub const MIN_STORAGE_BUFFERS_PER_STAGE: u32 = 11;

/// The most invocations one workgroup of the kernels has (`matmul.wgsl`'s `tiled`: 256, WebGPU's
/// default limit), which a device must allow.
pub const MIN_INVOCATIONS_PER_WORKGROUP: u32 = 256;

/// How long a wait on the device may take before it is an error ([`GpuError::Timeout`]), unless
/// [`GpuContext::with_timeout`] sets another.
pub const DEFAULT_DEVICE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(300);

/// Which adapters [`GpuContext::new`] may pick.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum AdapterChoice {
    /// The best adapter found: a discrete GPU, else an integrated one, else a virtual one, else a
    /// software rasteriser (lavapipe).
    #[default]
    Any,
    /// Only a hardware GPU (never a CPU/software adapter); [`GpuError::NoAdapter`] otherwise.
    HardwareOnly,
    /// The first adapter (best first) whose name contains this, ignoring case.
    Named(String),
    /// The adapter at this index of [`list_adapters`] (what `mipnerf info` numbers).
    Index(usize),
}

impl AdapterChoice {
    /// The variable that names an adapter when no `--adapter` is given (as in wgpu's examples).
    pub const ENV: &'static str = "WGPU_ADAPTER_NAME";

    /// Reads `--adapter`: a number is an index into [`list_adapters`], anything else a name
    /// substring.
    #[must_use]
    pub fn parse(s: &str) -> Self {
        let s = s.trim();
        s.parse::<usize>().map_or_else(|_| Self::Named(s.to_string()), Self::Index)
    }

    /// The explicit choice of `flag` (`--adapter`), else of [`ENV`](Self::ENV) when it is set
    /// and not empty; `None` when neither names one.
    #[must_use]
    pub fn explicit(flag: Option<&str>) -> Option<Self> {
        match flag {
            Some(f) if !f.trim().is_empty() => Some(Self::parse(f)),
            _ => std::env::var(Self::ENV).ok().filter(|v| !v.trim().is_empty()).map(|v| Self::parse(&v)),
        }
    }

    /// Whether this choice takes adapter `index` of [`list_adapters`], described by `adapter`
    /// (its limits aside).
    #[must_use]
    pub fn takes(&self, index: usize, adapter: &AdapterSummary) -> bool {
        self.passes_over(index, adapter).is_none()
    }

    /// Why this choice passes over adapter `index` described by `adapter`, or `None` if it takes it.
    fn passes_over(&self, index: usize, adapter: &AdapterSummary) -> Option<String> {
        match self {
            Self::Any => None,
            Self::HardwareOnly => {
                adapter.is_software.then(|| "a software adapter (the CPU path is faster than it)".to_string())
            }
            Self::Named(s) => (!adapter.name.to_lowercase().contains(&s.to_lowercase()))
                .then(|| format!("its name does not contain \"{s}\"")),
            Self::Index(k) => (index != *k).then(|| format!("not adapter {k}")),
        }
    }
}

impl std::fmt::Display for AdapterChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Any => f.write_str("any adapter"),
            Self::HardwareOnly => f.write_str("a hardware GPU"),
            Self::Named(s) => write!(f, "an adapter named like \"{s}\""),
            Self::Index(k) => write!(f, "adapter {k}"),
        }
    }
}

/// Why an adapter with `limits` cannot run the kernels, if it cannot.
fn limits_problem(limits: &wgpu::Limits) -> Option<(&'static str, u64, u64)> {
    let checks = [
        (
            "max_storage_buffers_per_shader_stage",
            limits.max_storage_buffers_per_shader_stage,
            MIN_STORAGE_BUFFERS_PER_STAGE,
        ),
        (
            "max_compute_invocations_per_workgroup",
            limits.max_compute_invocations_per_workgroup,
            MIN_INVOCATIONS_PER_WORKGROUP,
        ),
        ("max_compute_workgroup_size_x", limits.max_compute_workgroup_size_x, MIN_INVOCATIONS_PER_WORKGROUP),
    ];
    checks.into_iter().find(|(_, have, need)| have < need).map(|(l, h, n)| (l, u64::from(h), u64::from(n)))
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

/// Every adapter wgpu can see on this machine, best first (the order `--adapter INDEX` counts in).
#[must_use]
pub fn list_adapters() -> Vec<AdapterSummary> {
    sorted_adapters(&instance()).iter().map(|a| AdapterSummary::from_info(&a.get_info())).collect()
}

fn sorted_adapters(inst: &wgpu::Instance) -> Vec<wgpu::Adapter> {
    let mut adapters = pollster::block_on(inst.enumerate_adapters(wgpu::Backends::all()));
    // Stable: adapters of one rank keep wgpu's order.
    adapters.sort_by_key(|a| rank(&a.get_info()));
    adapters
}

/// Errors that wgpu reported asynchronously (validation, out of memory, device loss).
#[derive(Default)]
struct ErrorSink {
    errors: Vec<wgpu::Error>,
    lost: Option<(wgpu::DeviceLostReason, String)>,
}

/// The sink, even if a callback panicked while holding it (its contents are still valid).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The running totals behind [`GpuContext::counters`].
#[derive(Default)]
struct Counters {
    dispatches: AtomicU64,
    compute_passes: AtomicU64,
    submits: AtomicU64,
    buffers_created: AtomicU64,
    bind_groups_created: AtomicU64,
    bytes_read_back: AtomicU64,
    model_rays: AtomicU64,
}

/// The device and queue every kernel runs on, with the adapter they came from.
///
/// wgpu reports validation errors and device loss through callbacks; the context collects them so
/// that [`GpuContext::check`] turns them into a [`GpuError`] instead of a panic. It also counts
/// the work recorded and the resources made ([`GpuContext::counters`]), and keeps one staging
/// buffer for reading back, grown as needed.
pub struct GpuContext {
    adapter: AdapterSummary,
    device: wgpu::Device,
    queue: wgpu::Queue,
    sink: Arc<Mutex<ErrorSink>>,
    counters: Counters,
    staging: Mutex<Option<wgpu::Buffer>>,
    timeout: std::time::Duration,
    memory_budget: Option<u64>,
    gradient_atomics: GradientAtomics,
}

/// How kernels add into gradients that many invocations share (the Tri-Mip planes' scatter,
/// the fused MLP's weight gradients).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GradientAtomics {
    /// A compare-exchange loop on the f32's bits in an `atomic<u32>`: every adapter.
    CompareExchange,
    /// `atomicAdd` on an `atomic<f32>` (`SHADER_FLOAT32_ATOMIC`): one instruction, where the
    /// device offers it.
    Float,
}

/// Set to any value: kernels add gradients by compare-exchange even where the device offers
/// float atomics (to compare the two).
pub const DISABLE_FLOAT_ATOMICS_ENV: &str = "MIPNERF_DISABLE_FLOAT_ATOMICS";

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.adapter).finish_non_exhaustive()
    }
}

impl GpuContext {
    /// The adapter this context runs on.
    #[must_use]
    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    /// The logical device.
    #[must_use]
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// Its queue.
    #[must_use]
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// Opens the best adapter allowed by `choice` and creates a device with the adapter's own
    /// limits (so large storage buffers are available where the hardware has them). Adapters
    /// whose limits are below what the kernels need are passed over.
    ///
    /// # Errors
    /// [`GpuError::NoAdapter`] when no adapter fits (listing every adapter seen and why each was
    /// passed over, with a hint on how to get one), and [`GpuError::RequestDevice`] when the
    /// device cannot be created.
    pub fn new(choice: AdapterChoice) -> Result<Self, GpuError> {
        let inst = instance();
        let mut passed_over = Vec::new();
        let mut chosen = None;
        for (i, a) in sorted_adapters(&inst).into_iter().enumerate() {
            let info = a.get_info();
            let why = choice.passes_over(i, &AdapterSummary::from_info(&info)).or_else(|| {
                limits_problem(&a.limits()).map(|(l, have, need)| format!("its {l} is {have}, the kernels need {need}"))
            });
            match why {
                Some(w) => {
                    passed_over.push(format!("[{i}] {} ({:?}, {:?}): {w}", info.name, info.backend, info.device_type))
                }
                None => {
                    chosen = Some(a);
                    break;
                }
            }
        }
        let adapter = chosen.ok_or_else(|| GpuError::NoAdapter { wanted: choice.to_string(), passed_over })?;
        let info = adapter.get_info();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("mipnerf device"),
            // Float atomics where offered (the gradients' scatter); nothing else is needed.
            required_features: adapter.features() & wgpu::Features::SHADER_FLOAT32_ATOMIC,
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
    /// kernels need no features (they use `SHADER_FLOAT32_ATOMIC` where the device was made
    /// with it, see [`GradientAtomics`]), and one limit above WebGPU's defaults: at least
    /// [`MIN_STORAGE_BUFFERS_PER_STAGE`] storage buffers per shader stage (request it in
    /// `required_limits`; every Vulkan, Metal and DX12 GPU has it). The other limits the device
    /// was made with bound the batch (a batch too large for them runs in chunks or is refused
    /// with the limit).
    ///
    /// # Errors
    /// [`GpuError::UnsupportedLimit`] when the device allows too few storage buffers per stage or
    /// too few invocations per workgroup.
    pub fn from_device(info: &wgpu::AdapterInfo, device: wgpu::Device, queue: wgpu::Queue) -> Result<Self, GpuError> {
        if let Some((limit, have, need)) = limits_problem(&device.limits()) {
            return Err(GpuError::UnsupportedLimit { adapter: info.name.clone(), limit, have, need });
        }
        let float_atomics = device.features().contains(wgpu::Features::SHADER_FLOAT32_ATOMIC);
        let gradient_atomics = if float_atomics && std::env::var_os(DISABLE_FLOAT_ATOMICS_ENV).is_none() {
            GradientAtomics::Float
        } else {
            GradientAtomics::CompareExchange
        };
        let sink = Arc::new(Mutex::new(ErrorSink::default()));
        let s = Arc::clone(&sink);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            lock(&s).errors.push(e);
        }));
        let s = Arc::clone(&sink);
        device.set_device_lost_callback(move |reason, msg| {
            lock(&s).lost = Some((reason, msg));
        });
        Ok(Self {
            adapter: AdapterSummary::from_info(info),
            device,
            queue,
            sink,
            counters: Counters::default(),
            staging: Mutex::new(None),
            timeout: DEFAULT_DEVICE_TIMEOUT,
            memory_budget: None,
            gradient_atomics,
        })
    }

    /// How the kernels built on this context add shared gradients: float atomics where the
    /// device has them (unless [`DISABLE_FLOAT_ATOMICS_ENV`] is set), else compare-exchange.
    #[must_use]
    pub fn gradient_atomics(&self) -> GradientAtomics {
        self.gradient_atomics
    }

    /// This context with kernels built from now on adding shared gradients by `atomics`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for float atomics on a device made without them.
    pub fn with_gradient_atomics(mut self, atomics: GradientAtomics) -> Result<Self, GpuError> {
        if atomics == GradientAtomics::Float && !self.device.features().contains(wgpu::Features::SHADER_FLOAT32_ATOMIC)
        {
            return Err(GpuError::InvalidInput(format!("{} has no float atomics", self.adapter.name)));
        }
        self.gradient_atomics = atomics;
        Ok(self)
    }

    /// Sets how long a wait on the device may take ([`DEFAULT_DEVICE_TIMEOUT`] otherwise).
    #[must_use]
    pub fn with_timeout(mut self, timeout: std::time::Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// Sets the device memory the backend's batch and render buffers may take, in bytes
    /// (`--gpu-memory`), instead of [`memory_budget`](Self::memory_budget)'s default.
    #[must_use]
    pub fn with_memory_budget(mut self, bytes: Option<u64>) -> Self {
        self.memory_budget = bytes.filter(|&b| b > 0);
        self
    }

    /// Device bytes the training batch's buffers may take (the render buffers get a quarter):
    /// what [`with_memory_budget`](Self::with_memory_budget) set, else, on a hardware GPU, four
    /// of the largest buffers the device binds, between 1 and 16 GiB; on a software adapter,
    /// whose "device memory" is the host's, one of them. wgpu does not report a device's memory;
    /// its binding limit grows with it, and a batch that still does not fit is caught as
    /// out-of-memory with a message naming the flags.
    #[must_use]
    pub fn memory_budget(&self) -> u64 {
        let bindings = if self.adapter.is_software { 1 } else { 4 };
        self.memory_budget.unwrap_or_else(|| (bindings * self.max_binding_bytes()).clamp(1 << 30, 16 << 30))
    }

    /// What has been recorded, submitted, made and read back on this context so far.
    #[must_use]
    pub fn counters(&self) -> WorkCounters {
        let c = &self.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        WorkCounters {
            dispatches: get(&c.dispatches),
            compute_passes: get(&c.compute_passes),
            submits: get(&c.submits),
            buffers_created: get(&c.buffers_created),
            bind_groups_created: get(&c.bind_groups_created),
            bytes_read_back: get(&c.bytes_read_back),
            model_rays: get(&c.model_rays),
        }
    }

    pub(crate) fn count_dispatch(&self, new_pass: bool) {
        self.counters.dispatches.fetch_add(1, Ordering::Relaxed);
        if new_pass {
            self.counters.compute_passes.fetch_add(1, Ordering::Relaxed);
        }
    }

    pub(crate) fn count_model_rays(&self, n: usize) {
        self.counters.model_rays.fetch_add(n as u64, Ordering::Relaxed);
    }

    pub(crate) fn count_bind_group(&self) {
        self.counters.bind_groups_created.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_buffer(&self) {
        self.counters.buffers_created.fetch_add(1, Ordering::Relaxed);
    }

    /// Submits `commands` to the queue (counted).
    pub fn submit(&self, commands: wgpu::CommandBuffer) -> wgpu::SubmissionIndex {
        self.counters.submits.fetch_add(1, Ordering::Relaxed);
        self.queue.submit([commands])
    }

    /// Reads `len` floats from the start of `staging` (a `MAP_READ` buffer that submission
    /// `after` copies into), waiting for that submission only: work submitted after it keeps the
    /// device busy meanwhile.
    ///
    /// # Errors
    /// A timeout, errors wgpu reported, or a failed map.
    pub fn read_staged(
        &self,
        staging: &wgpu::Buffer,
        len: usize,
        after: wgpu::SubmissionIndex,
    ) -> Result<Vec<f32>, GpuError> {
        let size = ((len * 4) as u64).max(4);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..size).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait_for(Some(after))?;
        // The wait above ran every callback: a missing result means the map was dropped unanswered.
        rx.recv().unwrap_or(Err(wgpu::BufferAsyncError)).map_err(GpuError::Readback)?;
        let view = staging.get_mapped_range(..size).map_err(|_| GpuError::Readback(wgpu::BufferAsyncError))?;
        let out = bytemuck::cast_slice::<u8, f32>(&view)[..len].to_vec();
        drop(view);
        staging.unmap();
        self.counters.bytes_read_back.fetch_add((len * 4) as u64, Ordering::Relaxed);
        Ok(out)
    }

    /// A labelled buffer the host maps to read back `bytes` (counted).
    #[must_use]
    pub fn staging_buffer(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.count_buffer();
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Waits for all submitted work, at most the context's timeout, then reports what wgpu
    /// reported meanwhile.
    ///
    /// # Errors
    /// [`GpuError::Timeout`] when the device does not finish in time; [`GpuError::Poll`] when
    /// waiting fails otherwise; errors wgpu reported ([`check`](Self::check)).
    pub fn wait(&self) -> Result<(), GpuError> {
        self.wait_for(None)
    }

    /// Waits for submission `index` (all submitted work when `None`), at most the timeout, then
    /// reports what wgpu reported meanwhile.
    fn wait_for(&self, index: Option<wgpu::SubmissionIndex>) -> Result<(), GpuError> {
        match self.device.poll(wgpu::PollType::Wait { submission_index: index, timeout: Some(self.timeout) }) {
            Ok(_) => {}
            Err(wgpu::PollError::Timeout) => {
                return Err(GpuError::Timeout {
                    adapter: self.adapter.name.clone(),
                    seconds: self.timeout.as_secs_f64(),
                });
            }
            Err(e) => return Err(GpuError::Poll(e)),
        }
        self.check()
    }

    /// Runs `make` (which creates device buffers of `bytes` in all) inside an out-of-memory
    /// error scope, so that a device that cannot hold them is reported as such, naming the
    /// adapter and the size, instead of failing later.
    ///
    /// # Errors
    /// [`GpuError::BatchTooLarge`] when the device runs out of memory; `make`'s own errors.
    pub fn allocating<T>(&self, bytes: u64, make: impl FnOnce() -> Result<T, GpuError>) -> Result<T, GpuError> {
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let made = make();
        let oom = pollster::block_on(scope.pop());
        if let Some(e) = oom {
            return Err(self.batch_too_large(bytes, e));
        }
        made
    }

    /// The error for `bytes` of buffers that did not fit (wgpu's error `source` kept).
    pub(crate) fn batch_too_large(&self, bytes: u64, source: wgpu::Error) -> GpuError {
        GpuError::BatchTooLarge { adapter: self.adapter.name.clone(), mib: bytes as f64 / 1048576.0, source }
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

    /// The most workgroups a dispatch may have along one dimension on this device.
    #[must_use]
    pub fn max_groups_per_dim(&self) -> u32 {
        self.device.limits().max_compute_workgroups_per_dimension
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
        self.count_buffer();
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents, usage })
    }

    /// Creates a labelled uniform buffer holding `value`.
    #[must_use]
    pub fn uniform_buffer<T: bytemuck::Pod>(&self, label: &str, value: &T) -> wgpu::Buffer {
        use wgpu::util::DeviceExt;
        self.count_buffer();
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        })
    }

    /// The staging buffer for reading back at least `size` bytes: the context's own, made (or
    /// grown to the next power of two) only when too small.
    fn staging(&self, size: u64) -> wgpu::Buffer {
        let mut slot = lock(&self.staging);
        if let Some(b) = slot.as_ref().filter(|b| b.size() >= size) {
            return b.clone();
        }
        self.count_buffer();
        let b = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("mipnerf readback staging"),
            size: size.max(256).next_power_of_two(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        *slot = Some(b.clone());
        b
    }

    /// Copies `len` `f32`s from the start of `buffer` (which needs `COPY_SRC`) back to the host,
    /// waiting (at most the timeout) for all submitted work.
    ///
    /// # Errors
    /// Any error wgpu reported while the work ran, a timeout, or a failed map.
    pub fn read_f32(&self, buffer: &wgpu::Buffer, len: usize) -> Result<Vec<f32>, GpuError> {
        self.read_f32_at(buffer, 0, len)
    }

    /// [`read_f32`](Self::read_f32) of `len` floats from element `offset` of `buffer`.
    ///
    /// # Errors
    /// As [`read_f32`](Self::read_f32).
    pub fn read_f32_at(&self, buffer: &wgpu::Buffer, offset: usize, len: usize) -> Result<Vec<f32>, GpuError> {
        let size = (len * 4) as u64;
        let staging = self.staging(size);
        let mut enc =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("mipnerf readback") });
        enc.copy_buffer_to_buffer(buffer, (offset * 4) as u64, &staging, 0, size);
        let index = self.submit(enc.finish());
        self.read_staged(&staging, len, index)
    }
}
