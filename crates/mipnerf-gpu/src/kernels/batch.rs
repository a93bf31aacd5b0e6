//! `shaders/batch.wgsl`: ray batches made on the device from images and cameras that live there,
//! and [`RayBatch`], the batch's buffers that every kernel of the model reads.
//!
//! CPU reference: [`mipnerf_core::dataset::push_camera_rays`] (rays) and the CPU backend's batch draw.

use mipnerf_core::Ray;
use mipnerf_core::backend::ImageSpec;
use mipnerf_core::camera::{Camera, PixelCenters};
use mipnerf_core::dataset::{Dataset, Ndc, Pixels};
use mipnerf_core::rng::{RayRng, Stream};

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of these kernels.
pub const SOURCE: super::Shader = super::shader!("batch.wgsl", [BatchParams, GpuView]);

/// Pixel buffers a dataset may span (bindings of `batch.wgsl`).
pub const PIXEL_SLOTS: usize = 4;

/// The uniform block of `batch.wgsl` (`struct Params`), 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct BatchParams {
    /// Rays to make.
    pub n_rays: u32,
    /// 1: pixels `first_pixel..` in raster order (rendering; rays past the last pixel repeat it);
    /// 0: drawn at random (training).
    pub sequential: u32,
    /// First pixel (sequential).
    pub first_pixel: u32,
    /// Views in the table.
    pub n_views: u32,
    /// Pixels over all views.
    pub total_pixels: u32,
    /// The `RayRng` key of the step's batch stream: (seed, step, `RayBatch`, ray 0), computed on
    /// the host.
    pub key: u32,
    /// 0: RGBA8 packed in one `u32` a pixel, 1: four f32 a pixel, 2: no pixels (no targets).
    pub pixel_format: u32,
    /// The background the targets are composited on: `BACKGROUND_BLACK` (alpha dropped), `_WHITE`
    /// or `_RANDOM` (training: each pixel on its own random colour; see
    /// [`render::background_code`](super::render::background_code)).
    pub background: u32,
    /// 1: weight rays by lossmult in the loss's denominator.
    pub area_loss: u32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// NDC: `2 focal / width` (0: world-space rays).
    pub ndc_fx: f32,
    /// NDC: `2 focal / height`.
    pub ndc_fy: f32,
    /// Rays per pixel side (the supersampled NeRF): `k x k` consecutive rays a pixel through a
    /// regular sub-pixel grid, each a cone of `1/k` of the pixel's radius; 1: one ray a pixel.
    pub supersample: u32,
    /// The pixel-centre offset in each view's `dir0` (0.5 or 0).
    pub centre_offset: f32,
    /// Run seed (random backgrounds).
    pub seed: u32,
    /// Step (random backgrounds).
    pub step: u32,
}

/// One view's camera as `batch.wgsl` reads it (`struct View`), 80 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuView {
    /// Direction through pixel (0, 0) (with the centre offset); w: cone radius.
    pub dir0: [f32; 4],
    /// Direction change per pixel along x; w: near.
    pub step_x: [f32; 4],
    /// Direction change per pixel along y; w: far.
    pub step_y: [f32; 4],
    /// Camera centre; w: lossmult.
    pub origin: [f32; 4],
    /// Width, height, pixel buffer slot (0..3), first word of the view's pixels in that slot.
    pub size: [u32; 4],
}

impl GpuView {
    /// The record of a pinhole `camera`: its direction field in `f64`, rounded once; the cone
    /// radius of pixel (0, 0), which a pinhole shares with every pixel.
    #[must_use]
    pub fn new(camera: &Camera, centers: PixelCenters, bounds: (f32, f32), lossmult: f32, pixels: (u32, u32)) -> Self {
        let off = centers.offset();
        let d0 = camera.direction_f64(off, off);
        let col = |c: usize| -> [f64; 3] {
            std::array::from_fn(|r| (0..3).map(|k| camera.cam2world[r][k] * camera.pix2cam[k][c]).sum())
        };
        let (sx, sy) = (col(0), col(1));
        let o = camera.origin();
        let radius = camera.ray_at(0, 0, centers, bounds.0, bounds.1, lossmult).radius;
        let v4 = |a: [f64; 3], w: f32| [a[0] as f32, a[1] as f32, a[2] as f32, w];
        Self {
            dir0: v4(d0, radius),
            step_x: v4(sx, bounds.0),
            step_y: v4(sy, bounds.1),
            origin: v4(o, lossmult),
            size: [camera.width, camera.height, pixels.0, pixels.1],
        }
    }
}

/// How pixels are stored on the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum PixelFormat {
    /// Straight RGBA8, one `u32` per pixel.
    Rgba8 = 0,
    /// Straight RGBA as four `f32` per pixel (images area-downsampled on loading).
    F32 = 1,
    /// No pixels (rendering only).
    None = 2,
}

/// Cameras (and for training, images) resident on the device: what `batch.wgsl` makes rays from.
#[derive(Debug)]
pub struct DeviceImages {
    views: wgpu::Buffer,
    offsets: wgpu::Buffer,
    pixels: [wgpu::Buffer; PIXEL_SLOTS],
    n_views: u32,
    total_pixels: u32,
    format: PixelFormat,
    white_bkgd: bool,
    ndc: Option<Ndc>,
    centre_offset: f32,
    /// Device bytes of the pixel buffers.
    pub pixel_bytes: u64,
}

fn too_large(what: &str) -> GpuError {
    GpuError::InvalidInput(format!("{what}: more than 2^32 - 1 pixels; the GPU backend indexes pixels with 32 bits"))
}

impl DeviceImages {
    /// Uploads every view of `ds` (pixels and cameras), once.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for images that do not fit in the device's buffers (the message
    /// says how much is needed and allowed).
    pub fn upload(ctx: &GpuContext, ds: &Dataset) -> Result<Self, GpuError> {
        Self::upload_with_slot_bytes(ctx, ds, ctx.max_binding_bytes())
    }

    /// [`upload`](Self::upload) with each of the [`PIXEL_SLOTS`] pixel buffers holding at most
    /// `slot_bytes` (the adapter's binding limit at most): views are placed in order, each whole in
    /// one buffer.
    ///
    /// # Errors
    /// As [`upload`](Self::upload).
    pub fn upload_with_slot_bytes(ctx: &GpuContext, ds: &Dataset, slot_bytes: u64) -> Result<Self, GpuError> {
        let total = ds.num_pixels();
        let total_u32 = u32::try_from(total).map_err(|_| too_large(&ds.root.display().to_string()))?;
        let all_u8 = ds.views().iter().all(|v| matches!(v.pixels, Pixels::Rgba8(_)));
        let (format, words_per_pixel) = if all_u8 { (PixelFormat::Rgba8, 1u64) } else { (PixelFormat::F32, 4) };
        let slot_bytes = slot_bytes.min(ctx.max_binding_bytes()) / 4 * 4;
        // Assign views to slots greedily, in order.
        let mut placement = Vec::with_capacity(ds.views().len());
        let mut used = [0u64; PIXEL_SLOTS];
        let mut slot = 0usize;
        for v in ds.views() {
            let bytes = u64::from(v.camera.width) * u64::from(v.camera.height) * words_per_pixel * 4;
            while slot < PIXEL_SLOTS && used[slot] + bytes > slot_bytes {
                slot += 1;
            }
            if slot == PIXEL_SLOTS {
                let need = total * words_per_pixel * 4;
                return Err(GpuError::InvalidInput(format!(
                    "{}: the training images need {:.0} MiB on the device, but this adapter binds at most \
                     {PIXEL_SLOTS} x {:.0} MiB; train at lower resolution (`LoadOptions::half_res`), on fewer views, or on the CPU (`BackendChoice::Cpu`)",
                    ds.root.display(),
                    need as f64 / 1048576.0,
                    slot_bytes as f64 / 1048576.0
                )));
            }
            placement.push((slot as u32, (used[slot] / 4) as u32));
            used[slot] += bytes;
        }
        let pixels: [wgpu::Buffer; PIXEL_SLOTS] = std::array::from_fn(|s| {
            ctx.device().create_buffer(&wgpu::BufferDescriptor {
                label: Some(&format!("training pixels {s}")),
                size: used[s].max(4),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        for (v, &(slot, word)) in ds.views().iter().zip(&placement) {
            let offset = u64::from(word) * 4;
            match (&v.pixels, format) {
                (Pixels::Rgba8(bytes), PixelFormat::Rgba8) => {
                    ctx.queue().write_buffer(&pixels[slot as usize], offset, bytes)
                }
                (Pixels::RgbaF32(f), _) => {
                    ctx.queue().write_buffer(&pixels[slot as usize], offset, bytemuck::cast_slice(f))
                }
                (Pixels::Rgba8(bytes), _) => {
                    let f: Vec<f32> = bytes.iter().map(|&b| f32::from(b) / 255.0).collect();
                    ctx.queue().write_buffer(&pixels[slot as usize], offset, bytemuck::cast_slice(&f));
                }
            }
        }
        let views: Vec<GpuView> = ds
            .views()
            .iter()
            .zip(&placement)
            .map(|(v, &p)| GpuView::new(&v.camera, ds.centers, (v.near, v.far), v.lossmult, p))
            .collect();
        let offsets: Vec<u32> = ds.pixel_offsets().iter().map(|&o| o as u32).collect();
        ctx.check()?;
        Ok(Self {
            views: ctx.storage_buffer("training cameras", &views, false),
            offsets: ctx.storage_buffer("training pixel offsets", &offsets, false),
            pixels,
            n_views: views.len() as u32,
            total_pixels: total_u32,
            format,
            white_bkgd: ds.white_bkgd,
            ndc: ds.ndc,
            centre_offset: ds.centers.offset() as f32,
            pixel_bytes: used.iter().sum(),
        })
    }

    /// The camera of one image to render (no pixels). Its rays are made by [`BatchKernel::encode`],
    /// which refuses supersampled NDC rays.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for an image of 2^32 pixels or more.
    pub fn camera_only(ctx: &GpuContext, image: &ImageSpec) -> Result<Self, GpuError> {
        let total = image.pixels() as u64;
        let total_u32 = u32::try_from(total).map_err(|_| too_large("the image"))?;
        let view = GpuView::new(&image.camera, image.centers, (image.near, image.far), 1.0, (0, 0));
        let empty = || ctx.storage_buffer("no pixels", &[0u32], false);
        Ok(Self {
            views: ctx.storage_buffer("render camera", &[view], false),
            offsets: ctx.storage_buffer("render pixel offsets", &[0u32, total_u32], false),
            pixels: std::array::from_fn(|_| empty()),
            n_views: 1,
            total_pixels: total_u32,
            format: PixelFormat::None,
            white_bkgd: false,
            ndc: image.ndc,
            centre_offset: image.centers.offset() as f32,
            pixel_bytes: 0,
        })
    }

    /// Points a [`camera_only`](Self::camera_only) set at another image, rewriting its buffers in
    /// place (no new buffers, so the dispatches that bind them keep their bind groups).
    ///
    /// # Errors
    /// As [`camera_only`](Self::camera_only); [`GpuError::InvalidInput`] for a set with pixels.
    pub fn set_camera(&mut self, ctx: &GpuContext, image: &ImageSpec) -> Result<(), GpuError> {
        if self.format != PixelFormat::None || self.n_views != 1 {
            return Err(GpuError::InvalidInput("set_camera on training images".into()));
        }
        let total_u32 = u32::try_from(image.pixels() as u64).map_err(|_| too_large("the image"))?;
        let view = GpuView::new(&image.camera, image.centers, (image.near, image.far), 1.0, (0, 0));
        ctx.queue().write_buffer(&self.views, 0, bytemuck::bytes_of(&view));
        ctx.queue().write_buffer(&self.offsets, 0, bytemuck::cast_slice(&[0u32, total_u32]));
        self.total_pixels = total_u32;
        self.ndc = image.ndc;
        self.centre_offset = image.centers.offset() as f32;
        Ok(())
    }

    /// Pixels over all views.
    #[must_use]
    pub fn total_pixels(&self) -> u32 {
        self.total_pixels
    }
}

/// Which pixels a batch holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Draw {
    /// Uniformly drawn with replacement, as `Dataset::sample_batch` draws them (`BatchDraw`:
    /// the same seed, step and `random_bkgd`), targets included.
    Random {
        /// Run seed.
        seed: u32,
        /// Step.
        step: u32,
        /// Composite each target on its pixel's random colour (`ModelConfig::random_bkgd`).
        random_bkgd: bool,
    },
    /// Pixels `first..first + n` in raster order over the views; rays past the last pixel repeat
    /// it (the tail of an image's last chunk).
    Sequential {
        /// First pixel.
        first: u32,
    },
}

/// The two pipelines of `batch.wgsl`.
#[derive(Debug)]
pub struct BatchKernel {
    make_rays: wgpu::ComputePipeline,
    batch_norm: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl BatchKernel {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let mut read_only = vec![true; 6];
        read_only.extend([false; 5]);
        let ([make_rays, batch_norm], layout) =
            kernels::build_entries(ctx, "batch", SOURCE, &read_only, ["make_rays", "batch_norm"])?;
        Ok(Self { make_rays, batch_norm, layout })
    }

    /// Records the making of `out.n_rays` rays from `images` (with targets when the images have
    /// pixels), `supersample²` consecutive rays per pixel, and of the loss's denominator
    /// (lossmult-weighted when `area_loss`).
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a sequential start past the last pixel, or a grid too large.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        images: &DeviceImages,
        draw: Draw,
        area_loss: bool,
        supersample: usize,
        out: &RayBatch,
    ) -> Result<(), GpuError> {
        let n = out.n_rays() as u32;
        let k = supersample.max(1) as u32;
        if !n.is_multiple_of(k * k) || (k > 1 && images.ndc.is_some()) {
            return Err(GpuError::InvalidInput(format!(
                "{n} rays for pixels of {k}x{k} rays{}",
                if images.ndc.is_some() { " in NDC" } else { "" }
            )));
        }
        let fixed = super::render::background_code(images.white_bkgd, false);
        let (sequential, first, key, background, seed, step) = match draw {
            Draw::Random { seed, step, random_bkgd } => {
                let bg = super::render::background_code(images.white_bkgd, random_bkgd);
                (0, 0, RayRng::new(seed, step, Stream::RayBatch, 0).key(), bg, seed, step)
            }
            Draw::Sequential { first } => {
                if first >= images.total_pixels {
                    return Err(GpuError::InvalidInput(format!("pixel {first} of {}", images.total_pixels)));
                }
                (1, first, 0, fixed, 0, 0)
            }
        };
        let (gx, gy) = kernels::dispatch_grid(u64::from(n), kernels::WORKGROUP)?;
        let p = BatchParams {
            n_rays: n,
            sequential,
            first_pixel: first,
            n_views: images.n_views,
            total_pixels: images.total_pixels,
            key,
            pixel_format: images.format as u32,
            background,
            area_loss: u32::from(area_loss),
            groups_x: gx,
            ndc_fx: images.ndc.map_or(0.0, |n| (2.0 * f64::from(n.focal) / f64::from(n.width)) as f32),
            ndc_fy: images.ndc.map_or(0.0, |n| (2.0 * f64::from(n.focal) / f64::from(n.height)) as f32),
            supersample: k,
            centre_offset: images.centre_offset,
            seed,
            step,
        };
        let [p0, p1, p2, p3] = &images.pixels;
        let bufs = [
            &images.views,
            &images.offsets,
            p0,
            p1,
            p2,
            p3,
            &out.rays,
            &out.bounds,
            &out.viewdirs,
            &out.targets,
            &out.norm,
        ];
        rec.dispatch("batch rays", &self.make_rays, &self.layout, &p, &bufs, (gx, gy, 1));
        rec.dispatch("batch norm", &self.batch_norm, &self.layout, &p, &bufs, (1, 1, 1));
        Ok(())
    }
}

super::wgsl_struct!(
    BatchParams,
    "Params",
    [
        n_rays,
        sequential,
        first_pixel,
        n_views,
        total_pixels,
        key,
        pixel_format,
        background,
        area_loss,
        groups_x,
        ndc_fx,
        ndc_fy,
        supersample,
        centre_offset,
        seed,
        step,
    ]
);
super::wgsl_struct!(GpuView, "View", [dir0, step_x, step_y, origin, size]);

/// How many rays of a set of buffers the next passes use: all of them, or the first few (a
/// chunk's tail), never more than the buffers hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ActiveRays {
    n: usize,
    capacity: usize,
}

impl ActiveRays {
    /// All `capacity` rays in use.
    #[must_use]
    pub fn all(capacity: usize) -> Self {
        Self { n: capacity, capacity }
    }

    /// Rays in use.
    #[must_use]
    pub fn n(self) -> usize {
        self.n
    }

    /// Rays the buffers hold.
    #[must_use]
    pub fn capacity(self) -> usize {
        self.capacity
    }

    /// Uses the first `n` rays.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for `n` of 0 or above the capacity.
    pub fn set(&mut self, n: usize) -> Result<(), GpuError> {
        if n == 0 || n > self.capacity {
            return Err(GpuError::InvalidInput(format!("{n} rays in buffers for {}", self.capacity)));
        }
        self.n = n;
        Ok(())
    }
}

/// The rays of a batch on the device, as the model's kernels read them.
#[derive(Debug)]
pub struct RayBatch {
    /// Rays the next pass makes or reads, of those the buffers hold.
    active: ActiveRays,
    /// `u32` per ray: its index in the step's batch, with which its random numbers (jitter,
    /// resampling offsets, density noise, background) are drawn: `0..n` for a whole batch (as
    /// made), the rays' own indices for a chunk of one or the rays an occupancy grid lets
    /// through (written there).
    pub ids: wgpu::Buffer,
    /// Two vec4 per ray: (origin, radius), (direction, lossmult).
    pub rays: wgpu::Buffer,
    /// (near, far) per ray.
    pub bounds: wgpu::Buffer,
    /// Normalised direction per ray (3 floats).
    pub viewdirs: wgpu::Buffer,
    /// Target colour per ray (vec4; w unused).
    pub targets: wgpu::Buffer,
    /// One float: `3 * sum(lossmult)` over the batch (the loss's denominator).
    pub norm: wgpu::Buffer,
}

impl RayBatch {
    /// Buffers for `n_rays` rays, filled with NaN (so that anything not written shows).
    #[must_use]
    pub fn new(ctx: &GpuContext, n_rays: usize) -> Self {
        let nan = |label: &str, len: usize| ctx.storage_buffer(label, &vec![f32::NAN; len.max(1)], true);
        Self {
            active: ActiveRays::all(n_rays),
            ids: ctx.storage_buffer("batch ray indices", &(0..n_rays.max(1) as u32).collect::<Vec<u32>>(), true),
            rays: nan("batch rays", n_rays * 8),
            bounds: nan("batch bounds", n_rays * 2),
            viewdirs: nan("batch view directions", n_rays * 3),
            targets: nan("batch targets", n_rays * 4),
            norm: nan("batch loss denominator", 1),
        }
    }

    /// A batch uploaded from the host: `rays` (`rays_per_pixel` consecutive ones per pixel) with
    /// `targets` (one per pixel), weighted by lossmult in the loss when `area_loss`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for no rays or lengths that disagree.
    pub fn upload(
        ctx: &GpuContext,
        rays: &[Ray],
        targets: &[[f32; 3]],
        rays_per_pixel: usize,
        area_loss: bool,
    ) -> Result<Self, GpuError> {
        let rpp = rays_per_pixel.max(1);
        if rays.len() != targets.len() * rpp || rays.is_empty() {
            return Err(GpuError::InvalidInput(format!(
                "{} rays and {} targets ({rpp} rays per pixel)",
                rays.len(),
                targets.len()
            )));
        }
        let packed = super::packed_rays(rays);
        let bounds: Vec<f32> = rays.iter().flat_map(|r| [r.near, r.far]).collect();
        let viewdirs: Vec<f32> = rays.iter().flat_map(|r| r.viewdir.to_array()).collect();
        let tg: Vec<[f32; 4]> =
            targets.iter().flat_map(|t| std::iter::repeat_n([t[0], t[1], t[2], 0.0], rpp)).collect();
        let lm_sum: f64 = rays.iter().step_by(rpp).map(|r| if area_loss { f64::from(r.lossmult) } else { 1.0 }).sum();
        Ok(Self {
            active: ActiveRays::all(rays.len()),
            ids: ctx.storage_buffer("batch ray indices", &(0..rays.len() as u32).collect::<Vec<u32>>(), true),
            rays: ctx.storage_buffer("batch rays", &packed, true),
            bounds: ctx.storage_buffer("batch bounds", &bounds, true),
            viewdirs: ctx.storage_buffer("batch view directions", &viewdirs, true),
            targets: ctx.storage_buffer("batch targets", &tg, true),
            norm: ctx.storage_buffer("batch loss denominator", &[(3.0 * lm_sum) as f32], true),
        })
    }
}

impl RayBatch {
    /// Rays the buffers hold.
    #[must_use]
    pub fn capacity(&self) -> usize {
        self.active.capacity()
    }

    /// Rays the next pass makes or reads (set by [`set_active`](Self::set_active)).
    #[must_use]
    pub fn n_rays(&self) -> usize {
        self.active.n()
    }

    /// Makes the next passes make or read the first `n` rays (a chunk's tail): [`ActiveRays::set`].
    ///
    /// # Errors
    /// As [`ActiveRays::set`].
    pub fn set_active(&mut self, n: usize) -> Result<(), GpuError> {
        self.active.set(n)
    }
}
