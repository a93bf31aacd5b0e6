//! `mipnerf train`: train a model on a dataset into a run directory.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

use crate::backend::DeviceArgs;
use clap::ValueEnum;
use mipnerf_core::RayShape;

use crate::config::{Backend, ModelKind, PrecisionArg, PresetArg, TrainSettings};
use crate::session::Session;
use crate::{signals, view};

/// The flags of `mipnerf train`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Run directory (created): config.toml, checkpoint.safetensors, metrics.csv, plots.
    #[arg(long, value_name = "RUN_DIR")]
    pub out: PathBuf,
    /// A TOML file of settings (keys as the flags, with underscores); flags override it.
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<PathBuf>,
    /// Continue the run in --out from its last checkpoint, with its saved configuration. Flags
    /// that may change on resume: --steps, --time-budget, --batch-rays, --backend,
    /// --precision, --lr-init, --lr-final, --lr-delay-steps, --lr-delay-mult,
    /// --grad-max-norm, --grad-max-val, --checkpoint-every, --log-every, --snapshots; any
    /// other flag (model, preset, sampler, seed, data) that differs from the saved run is
    /// refused.
    #[arg(long)]
    pub resume: bool,
    /// Serve the live viewer (as `mipnerf view`) beside training, on 127.0.0.1 at
    /// --view-port; it shows the latest checkpoint, rendered on the CPU.
    #[arg(long)]
    pub view: bool,
    /// The viewer's port (0: any free one).
    #[arg(long, default_value_t = 8080, requires = "view")]
    pub view_port: u16,
    #[command(flatten)]
    pub flags: Box<TrainFlags>,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Trains (beside the live viewer with `--view`); exits with [`signals::EXIT_INTERRUPTED`] when
/// interrupted, the checkpoint saved.
///
/// # Errors
/// Bad settings or data, or a failure while training, naming the file.
pub fn run(a: Args, session: &Session) -> Result<()> {
    let viewer = if a.view { view::beside_training(&a.out, a.view_port, session) } else { Ok(()) };
    viewer.and_then(|()| train(&a.out, a.config, a.resume, &a.flags, &a.device.options(), session)).map(|o| {
        if o.interrupted {
            std::process::exit(signals::EXIT_INTERRUPTED);
        }
    })
}

/// Trains the run in `out` from a settings file and flags, and prints where it ended.
///
/// # Errors
/// As [`crate::training::train`]; `--config` with `--resume`.
pub fn train(
    out: &Path,
    config: Option<PathBuf>,
    resume: bool,
    flags: &TrainFlags,
    device: &mipnerf_gpu::DeviceOptions,
    session: &Session,
) -> Result<crate::training::TrainOutcome> {
    if resume && let Some(p) = &config {
        bail!(
            "--config {} with --resume: a resumed run keeps its own config.toml; pass the settings to change \
             (e.g. --steps) as flags",
            p.display()
        );
    }
    let file = config.map(|p| TrainSettings::from_file(&p)).transpose()?;
    let outcome = crate::training::train(out, file, flags.settings(), resume, device, session)?;
    if let Some((loss, psnr)) = outcome.last {
        println!(
            "trained to step {}: loss {loss:.5}, training PSNR {psnr:.2} dB; run in {}",
            outcome.step,
            out.display()
        );
    }
    Ok(outcome)
}

/// The flags of `mipnerf train`. Every flag can also be given in `--config FILE.toml` under the
/// same name with underscores (flags win).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct TrainFlags {
    /// Dataset directory: Blender (transforms_*.json), multiscale Blender (metadata.json) or LLFF
    /// (poses_bounds.npy); the format is detected.
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// Model size: tiny (minutes on 2 cores), small, or paper (the official 612K network)
    /// [default: tiny].
    #[arg(long, value_enum)]
    pub preset: Option<PresetArg>,
    /// The paper's system: mipnerf, or the nerf baseline (PE, two MLPs, coarse weight 1, no area
    /// loss, corner pixels, ReLU density) [default: mipnerf]. The single switches below override it.
    #[arg(long, value_enum)]
    pub model: Option<ModelKind>,
    /// Total training steps [default: 2000].
    #[arg(long)]
    pub steps: Option<u64>,
    /// Rays per batch [default: 1024].
    #[arg(long)]
    pub batch_rays: Option<usize>,
    /// Where to run: cpu, gpu, or auto (a hardware GPU if present, else the CPU) [default: auto].
    #[arg(long, value_enum)]
    pub backend: Option<Backend>,
    /// Seed of every random number in the run [default: 0].
    #[arg(long)]
    pub seed: Option<u32>,
    /// Steps between checkpoints [default: 500].
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Steps between rows of metrics.csv [default: 10].
    #[arg(long)]
    pub log_every: Option<u64>,
    /// Initial learning rate [default: 5e-4; 5e-3 for the fast preset, and for the tiny preset on
    /// LLFF and COLMAP data].
    #[arg(long)]
    pub lr_init: Option<f32>,
    /// Final learning rate [default: 5e-6; 5e-4 where the initial one is 5e-3].
    #[arg(long)]
    pub lr_final: Option<f32>,
    /// Learning-rate warm-up steps [default: min(2500, steps/10); 100 for the fast preset or a
    /// time budget].
    #[arg(long)]
    pub lr_delay_steps: Option<u64>,
    /// Learning-rate factor at the start of the warm-up [default: 0.01].
    #[arg(long)]
    pub lr_delay_mult: Option<f32>,
    /// Clip the gradient's norm to this (0 = off) [default: 0].
    #[arg(long)]
    pub grad_max_norm: Option<f32>,
    /// Clip each gradient entry to this magnitude (0 = off) [default: 0].
    #[arg(long)]
    pub grad_max_val: Option<f32>,
    /// Samples per ray and level (overrides the preset).
    #[arg(long)]
    pub num_samples: Option<usize>,
    /// Sampling levels per ray: 2 for the paper's coarse and fine levels, 1 to sample once
    /// (overrides the preset).
    #[arg(long)]
    pub num_levels: Option<usize>,
    /// Without integrated positional encoding: plain PE of the frustum means ("w/o IPE").
    #[arg(long)]
    pub no_ipe: bool,
    /// Without the area loss: every ray weighs the same ("w/o area loss").
    #[arg(long)]
    pub no_area_loss: bool,
    /// Two MLPs (one per level) with coarse loss weight 1, as NeRF.
    #[arg(long)]
    pub two_mlps: bool,
    /// Without Mip-NeRF's "misc" changes: ReLU density, no density bias, no colour padding.
    #[arg(long)]
    pub no_misc: bool,
    /// Rays through pixel centres (Mip-NeRF's default).
    #[arg(long, conflicts_with = "corner_pixels")]
    pub centered_pixels: bool,
    /// Rays through pixel corners (NeRF's default).
    #[arg(long)]
    pub corner_pixels: bool,
    /// Supersample: K x K rays per pixel, averaged (the paper's supersampled NeRF) [default: 1].
    #[arg(long, value_name = "K")]
    pub supersample: Option<usize>,
    /// Shape cast through each pixel [default: cone; cylinder for LLFF].
    #[arg(long, value_enum)]
    pub ray_shape: Option<RayShapeArg>,
    /// Standard deviation of the noise added to the raw density in training (the official code
    /// uses 1 on LLFF scenes) [default: 1 for forward-facing photos (NDC), else 0].
    #[arg(long, value_name = "STD")]
    pub density_noise: Option<f32>,
    /// Photos (LLFF, COLMAP): foreground masks, one image per photo named as the photo (PNG or
    /// JPEG, white = the object or a cut-out's alpha, the photo's size or larger), taken as the
    /// photos' alpha: the object trains alone, on random backgrounds unless --background says
    /// otherwise, and evaluates and renders on white.
    #[arg(long, value_name = "DIR")]
    pub masks: Option<PathBuf>,
    /// Blender: load images at half resolution.
    #[arg(long)]
    pub half_res: bool,
    /// LLFF: read images_N [default: 4].
    #[arg(long, value_name = "N")]
    pub llff_factor: Option<u32>,
    /// LLFF: spherical poses and world-space rays instead of NDC.
    #[arg(long)]
    pub spherify: bool,
    /// With --spherify: the cameras' distance from the scene's centre, in world units [default:
    /// 4, the Blender scenes' camera distance, at which a captured object is about a unit across
    /// as Mip-NeRF's density and encoding expect; the official code's is 1]. The up axis is
    /// that of the ring the cameras stand on.
    #[arg(long, value_name = "R")]
    pub spherify_radius: Option<f32>,
    /// Photos taken all around a scene with its surroundings (a room, a landscape): the space
    /// beyond the cameras is contracted into a shell (mip-NeRF 360), so the background is learnt
    /// out to infinity instead of being cut off at a box. Implies --spherify (the farthest
    /// camera on the unit sphere); the occupancy grid (the fast preset's) then covers the
    /// contracted space.
    #[arg(long)]
    pub unbounded: bool,
    /// The field the samples are read from: mip-nerf, the paper's MLP on the frustum's integrated
    /// positional encoding; tri-mip, Tri-MipRF's feature planes read at the frustum's footprint
    /// into a small MLP (CPU backend, bounded scenes); tri-plane, the same planes read at their
    /// finest level (the aliasing baseline); hash-grid, Zip-NeRF's multiresolution hash grid,
    /// each level down-weighted at the frustum's footprint, into the same small MLP (CPU backend
    /// only) [default: mip-nerf].
    #[arg(long, value_enum)]
    pub field: Option<crate::config::FieldArg>,
    /// Weight of mip-NeRF 360's distortion loss, which gathers each ray's weight into one short
    /// stretch against floaters (the successor's: 0.01; CPU backend) [default: 0, off].
    #[arg(long, value_name = "W")]
    pub distortion_loss: Option<f32>,
    /// What the renders are composited on where the rays meet nothing [default: white for
    /// Blender and multiscale data, black (no compositing) for LLFF and COLMAP]. White or black
    /// suits an object photographed on a plain backdrop of that colour (the backdrop then need
    /// not be learnt); Blender images' alpha is composited on the same colour. Random trains each
    /// pixel on its own random colour (images with alpha only) and evaluates and renders on
    /// white.
    #[arg(long, value_enum)]
    pub background: Option<BackgroundArg>,
    /// Occupancy-guided sampling: skip empty space, learnt from the model's densities (on by
    /// default with --preset fast; CPU backend).
    #[arg(long, conflicts_with = "no_occupancy")]
    pub occupancy: bool,
    /// The paper's sampler, even with --preset fast.
    #[arg(long)]
    pub no_occupancy: bool,
    /// Cells along each axis of the occupancy grid [default: 64].
    #[arg(long, value_name = "N")]
    pub occupancy_resolution: Option<usize>,
    /// Half the side of the occupancy grid's cube around the origin [default: from the cameras].
    #[arg(long, value_name = "B")]
    pub occupancy_bound: Option<f32>,
    /// Do not seed the occupancy grid with the visual hull of the training masks.
    #[arg(long)]
    pub no_occupancy_masks: bool,
    /// Train for this long instead of a step count (`90s`, `30m`, `1h30m`), the learning-rate
    /// schedule stretched to the steps that fit; then checkpoint and stop.
    #[arg(long, value_name = "DURATION")]
    pub time_budget: Option<String>,
    /// Every N steps (and at the end) render a few test images and log their PSNR per scale in
    /// metrics.csv (`val_psnr`) and the PSNR plot; the time it takes is not training time.
    #[arg(long, value_name = "N")]
    pub val_every: Option<u64>,
    /// Test images the validation renders, each at every scale [default: 2].
    #[arg(long, value_name = "K")]
    pub val_images: Option<usize>,
    /// Copy the run to snapshots/NNNNNs/ as the training time passes each mark (`2m,5m,10m`).
    #[arg(long, value_name = "DURATION,...", value_delimiter = ',')]
    pub snapshots: Option<Vec<String>>,
    /// Precision of the MLP's matrix products [default: f32; auto for the fast preset with the
    /// Mip-NeRF field; a resumed run keeps its own]:
    /// bf16 (operands rounded to bf16, f32 sums; AMX or AVX-512 BF16, CPU backend) or auto (bf16 where
    /// it outruns f32 on this CPU). May change on --resume.
    #[arg(long, value_enum)]
    pub precision: Option<PrecisionArg>,
    /// Flush subnormal floats to zero in training steps on the CPU (x86 FTZ/DAZ): faster where
    /// gradients in empty space go subnormal, not bit-identical to a run that keeps them
    /// [default: on for the tiny and fast presets]. May change on --resume.
    #[arg(long, conflicts_with = "keep_subnormals")]
    pub flush_subnormals: bool,
    /// Keep subnormal floats (IEEE arithmetic throughout; the default for the small and paper
    /// presets, whose committed results it reproduces bit for bit).
    #[arg(long)]
    pub keep_subnormals: bool,
}

/// `--background` values: what the renders are composited on where the rays meet nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BackgroundArg {
    /// White (the Blender scenes' backdrop; the default for Blender and multiscale data).
    White,
    /// Black (no compositing: the official code's LLFF setting, and the default for LLFF and
    /// COLMAP data).
    Black,
    /// In training, each pixel on its own random colour (its target composited on the same), so
    /// that the model learns where the object is transparent rather than the backdrop's colour;
    /// evaluation and renders on white. Needs images with alpha (Blender, multiscale, photos
    /// with --masks).
    Random,
}

/// `--ray-shape` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum RayShapeArg {
    /// Cones (Mip-NeRF).
    Cone,
    /// Cylinders (NDC scenes).
    Cylinder,
}

impl TrainFlags {
    /// The settings these flags set (unset flags stay `None`).
    #[must_use]
    pub fn settings(&self) -> TrainSettings {
        let yes = |b: bool| b.then_some(true);
        let no = |b: bool| b.then_some(false);
        TrainSettings {
            data: self.data.clone(),
            preset: self.preset,
            model: self.model,
            steps: self.steps,
            batch_rays: self.batch_rays,
            seed: self.seed,
            backend: self.backend,
            checkpoint_every: self.checkpoint_every,
            log_every: self.log_every,
            lr_init: self.lr_init,
            lr_final: self.lr_final,
            lr_delay_steps: self.lr_delay_steps,
            lr_delay_mult: self.lr_delay_mult,
            grad_max_norm: self.grad_max_norm,
            grad_max_val: self.grad_max_val,
            num_samples: self.num_samples,
            num_levels: self.num_levels,
            ipe: no(self.no_ipe),
            area_loss: no(self.no_area_loss),
            two_mlps: yes(self.two_mlps),
            misc: no(self.no_misc),
            centered_pixels: yes(self.centered_pixels).or(no(self.corner_pixels)),
            supersample: self.supersample,
            ray_shape: self.ray_shape.map(|r| match r {
                RayShapeArg::Cone => RayShape::Cone,
                RayShapeArg::Cylinder => RayShape::Cylinder,
            }),
            density_noise: self.density_noise,
            density_noise_steps: None,
            white_bkgd: self.background.map(|b| b != BackgroundArg::Black),
            random_bkgd: self.background.map(|b| b == BackgroundArg::Random),
            masks: self.masks.clone(),
            half_res: yes(self.half_res),
            llff_factor: self.llff_factor,
            spherify: yes(self.spherify),
            spherify_radius: self.spherify_radius,
            unbounded: yes(self.unbounded),
            distortion_loss: self.distortion_loss,
            field: self.field,
            // From the data, when training starts.
            tri_mip_bound: None,
            tri_mip_resolution: None,
            tri_mip_mlp: None,
            tri_mip_lr_mult: None,
            grid_adam_eps: None,
            grid_adam_skip_untouched: None,
            tri_mip_tv: None,
            hash_grid_decay: None,
            adam_beta2: None,
            mlp_l2: None,
            coarse_to_fine_steps: None,
            lr_decay_steps: None,
            occupancy: yes(self.occupancy).or(no(self.no_occupancy)),
            occupancy_resolution: self.occupancy_resolution,
            occupancy_bound: self.occupancy_bound,
            occupancy_masks: no(self.no_occupancy_masks),
            time_budget: self.time_budget.clone(),
            snapshots: self.snapshots.clone(),
            precision: self.precision,
            flush_subnormals: yes(self.flush_subnormals).or(no(self.keep_subnormals)),
            val_every: self.val_every,
            val_images: self.val_images,
        }
    }
}
