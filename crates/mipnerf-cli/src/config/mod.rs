//! Training settings: command-line flags, a TOML file, or both (flags win over the file, the file
//! over the defaults). The resolved settings are saved as `RUN_DIR/config.toml`, which `--resume`,
//! `eval` and `render` read back.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use mipnerf_core::PixelCenters;
use mipnerf_core::RayShape;
use mipnerf_core::model::{FastRecipe, Field, HashGridRecipe, ModelConfig, PointEncoding, Preset, TriMipRecipe};
use mipnerf_core::schedule::LrSchedule;
use mipnerf_core::train::{AdamConfig, FieldAdam, OptimConfig};
use serde::{Deserialize, Serialize};

mod checks;
mod resolve;

/// Where the heavy passes run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// The CPU path (always available).
    Cpu,
    /// A GPU through wgpu: any adapter, software ones (lavapipe) included.
    Gpu,
    /// A hardware GPU if one is present, else the CPU.
    Auto,
}

/// The precision of the MLP's matrix products (`--precision`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PrecisionArg {
    /// f32 throughout: the paper's precision, the reference and every golden test's.
    F32,
    /// bf16 operands with f32 accumulation (Intel AMX or AVX-512 BF16; CPU backend only).
    /// Parameters, Adam and checkpoints stay f32.
    Bf16,
    /// bf16 where the CPU backend runs on a CPU whose bf16 outruns its f32: AMX-BF16, or AVX-512
    /// BF16 whose `vdpbf16ps` does at least the f32 FMA's flops per second (measured at start:
    /// about 2x on AMD Zen 4, 0.5x on Intel Xeons); else f32, saying why.
    Auto,
}

/// Which of the paper's two systems.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Mip-NeRF: IPE, one MLP, coarse weight 0.1, area loss, centred pixels, softplus density.
    Mipnerf,
    /// The NeRF baseline: PE, two MLPs, coarse weight 1, no area loss, corner pixels, ReLU density.
    Nerf,
}

/// The field the samples are read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FieldArg {
    /// The paper's: the conical frustum's integrated positional encoding into the MLP.
    MipNerf,
    /// Tri-MipRF's: three feature planes with mipmaps, read at the frustum's footprint, into a
    /// small MLP (CPU backend).
    TriMip,
    /// The same planes read at their finest level whatever the cone (point sampling: the
    /// aliasing baseline for tri-mip).
    TriPlane,
    /// Zip-NeRF's: a multiresolution hash grid, each level down-weighted by how much of it the
    /// frustum's footprint averages away, into a small MLP (CPU backend).
    HashGrid,
}

/// The half side of the planes' cube before the data gives it (replaced when training starts).
const TRI_MIP_BOUND_UNTIL_DATA: f32 = 1.5;

/// The model size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PresetArg {
    /// 3 x 64 trunk, 32 + 32 samples: minutes on 2 cores.
    Tiny,
    /// 4 x 128 trunk, 64 + 64 samples.
    Small,
    /// The paper's 8 x 256 trunk, 128 + 128 samples (612K parameters).
    Paper,
    /// Time to quality: the small trunk with 16 + 16 samples, occupancy-guided sampling, bf16
    /// where it outruns f32 on the CPU (`--precision auto`), and the batch and learning rates
    /// measured fastest to a sharp picture (CPU backend).
    Fast,
}

impl PresetArg {
    /// The model size this names.
    #[must_use]
    pub fn preset(self) -> Preset {
        match self {
            Self::Tiny => Preset::Tiny,
            Self::Small => Preset::Small,
            Self::Paper => Preset::Paper,
            Self::Fast => Preset::Fast,
        }
    }
}

/// Rays per batch of the fast preset (core's [`FastRecipe`], shared with the library).
pub const FAST_BATCH_RAYS: usize = FastRecipe::RECIPE.batch_rays;
/// Initial and final learning rates of the fast preset ([`FastRecipe`]).
pub const FAST_LR: (f32, f32) = FastRecipe::RECIPE.lr;
/// Learning-rate warm-up steps of the fast preset (and of any run with a time budget).
pub const FAST_LR_DELAY_STEPS: u64 = FastRecipe::RECIPE.lr_delay_steps;

/// A duration: `90`, `90s`, `30m`, `1h`, `1h30m`, `2.5m` (seconds when no unit is given).
///
/// # Errors
/// Anything else, or a duration that is not positive and finite.
pub fn parse_duration(text: &str) -> Result<f64> {
    let t = text.trim();
    let mut total = 0.0;
    let mut num = String::new();
    for ch in t.chars() {
        if ch.is_ascii_digit() || ch == '.' {
            num.push(ch);
            continue;
        }
        let unit = match ch {
            'h' => 3600.0,
            'm' => 60.0,
            's' => 1.0,
            _ => bail!("not a duration: {t:?} (write e.g. 90s, 30m, 1h30m)"),
        };
        let v: f64 = num.parse().map_err(|_| anyhow::anyhow!("not a duration: {t:?} (write e.g. 90s, 30m, 1h30m)"))?;
        total += v * unit;
        num.clear();
    }
    if !num.is_empty() {
        total += num.parse::<f64>().map_err(|_| anyhow::anyhow!("not a duration: {t:?} (write e.g. 90s, 30m)"))?;
    }
    if !(total.is_finite() && total > 0.0) {
        bail!("not a positive duration: {t:?} (write e.g. 90s, 30m, 1h30m)");
    }
    if total > MAX_DURATION_SECONDS {
        bail!("{t:?} is longer than a year (366 days); no run of this tool takes that long");
    }
    Ok(total)
}

/// The longest duration a flag takes (`--time-budget`, `--snapshots`): a year.
pub const MAX_DURATION_SECONDS: f64 = 366.0 * 24.0 * 3600.0;

/// The most training steps a run can take: the step number seeds the random numbers as a `u32`.
pub const MAX_STEPS: u64 = u32::MAX as u64;

/// The most rays per batch (the library's bound, `mipnerf_core::backend::MAX_BATCH_RAYS`).
pub const MAX_BATCH_RAYS: usize = mipnerf_core::backend::MAX_BATCH_RAYS;

/// The most sampling levels a run takes: the paper's two (coarse and fine), the levels both
/// backends are tested with.
pub const MAX_LEVELS: usize = 2;

/// Every training setting. In a `--config` TOML file the keys are these field names
/// (e.g. `steps = 5000`, `ipe = false`); every key is optional.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainSettings {
    /// Dataset directory.
    pub data: Option<PathBuf>,
    /// Model size [default: tiny].
    pub preset: Option<PresetArg>,
    /// Mip-NeRF or the NeRF baseline [default: mipnerf].
    pub model: Option<ModelKind>,
    /// The field the samples are read from [default: mip-nerf; recorded only when another].
    pub field: Option<FieldArg>,
    /// Half the side of the Tri-Mip planes' cube, centred on the origin [default: the cameras'
    /// cube, as the occupancy grid's (in NDC space for forward-facing photos); the contracted space's
    /// 2 in an unbounded scene; recorded when training starts].
    pub tri_mip_bound: Option<f32>,
    /// Texels along a side of the Tri-Mip planes (a power of two, 16 to 2048), each of 16
    /// features, in levels down to 4 texels a side [default: the field's recipe,
    /// `TriMipRecipe::RECIPE`: 256, 128 in an unbounded scene; recorded with the field].
    pub tri_mip_resolution: Option<usize>,
    /// The MLP after the Tri-Mip planes: `[trunk depth, trunk width, colour depth, colour
    /// width]` [default: the field's recipe; recorded with the field].
    pub tri_mip_mlp: Option<[usize; 4]>,
    /// The Tri-Mip planes' learning rate over the MLP's (Tri-MipRF's 10) [default: the field's
    /// recipe; recorded with the field].
    pub tri_mip_lr_mult: Option<f32>,
    /// Adam's epsilon for a grid field's own parameters (the Tri-Mip planes or the hash grid)
    /// [default: the field's recipe: Instant-NGP's 1e-15; recorded when set].
    pub grid_adam_eps: Option<f32>,
    /// Whether Adam leaves a grid field's entries whose gradient is 0 as they are, moments
    /// included (Instant-NGP's rule) [default: the field's recipe: no; recorded when set].
    pub grid_adam_skip_untouched: Option<bool>,
    /// Weight of the Tri-Mip planes' total variation in the loss (TensoRF's regulariser, the
    /// mean squared difference of neighbouring texels) [default: the field's recipe: 0.1 for
    /// forward-facing photos, 1 for unbounded scenes, else 0; recorded when not 0, or when 0
    /// against the recipe].
    pub tri_mip_tv: Option<f32>,
    /// Weight of Zip-NeRF's normalised weight decay of the hash grid's tables in the loss (the
    /// sum over levels of the mean squared feature) [default: the field's recipe,
    /// `HashGridRecipe::RECIPE`: 0.01 for forward-facing photos, else 0; recorded when not 0, or
    /// when 0 against the recipe].
    pub hash_grid_decay: Option<f32>,
    /// Adam's `beta2`, the decay of its running mean of squared gradients, for every parameter
    /// [default: flax's 0.999; recorded when another]. Instant-NGP's 0.99 makes the hash grid's
    /// loss climb on fern (docs/results/hash-grid/stability).
    pub adam_beta2: Option<f32>,
    /// Instant-NGP's L2 regularisation of the MLP: this times each of the MLP's parameters
    /// added to its gradient before Adam (Instant-NGP: 1e-6) [default: 0, off, the official
    /// code's; recorded when set].
    pub mlp_l2: Option<f32>,
    /// A grid field learns coarse to fine over this many steps: each training sample's footprint
    /// widened by a floor that halves from a sixteenth of the grid's box six times over them
    /// (`ModelConfig::coarse_to_fine_steps`) [default: 0, off; recorded when set].
    pub coarse_to_fine_steps: Option<u64>,
    /// Training steps in total [default: 2000].
    pub steps: Option<u64>,
    /// Rays (pixels) per batch [default: 1024].
    pub batch_rays: Option<usize>,
    /// Seed of every random number of the run [default: 0].
    pub seed: Option<u32>,
    /// Backend [default: auto].
    pub backend: Option<Backend>,
    /// Steps between checkpoints [default: 500].
    pub checkpoint_every: Option<u64>,
    /// Steps between log lines in metrics.csv [default: 10].
    pub log_every: Option<u64>,
    /// Initial learning rate [default: 5e-4; 5e-3 for the fast preset, and for the tiny preset on
    /// LLFF and COLMAP data].
    pub lr_init: Option<f32>,
    /// Final learning rate [default: 5e-6; 5e-4 where the initial one is 5e-3].
    pub lr_final: Option<f32>,
    /// Warm-up steps of the learning rate [default: 2500, or steps/10 if shorter; 100 for the fast
    /// preset or a time budget].
    pub lr_delay_steps: Option<u64>,
    /// Learning-rate factor at step 0 of the warm-up [default: 0.01].
    pub lr_delay_mult: Option<f32>,
    /// The rate reaches `lr_final` by this step and stays there, however long the run or its
    /// time budget [default: the run's last step; the hash-grid field's recipe,
    /// `HashGridRecipe::RECIPE`, for forward-facing photos: 10000; recorded when set].
    pub lr_decay_steps: Option<u64>,
    /// Clip the gradient to this norm (0 = off) [default: 0].
    pub grad_max_norm: Option<f32>,
    /// Clip gradient entries to this magnitude (0 = off) [default: 0].
    pub grad_max_val: Option<f32>,
    /// Samples per ray and level (overrides the preset).
    pub num_samples: Option<usize>,
    /// Sampling levels per ray: 2 for the paper's coarse and fine levels (the fine level's
    /// samples drawn from the coarse level's weights), 1 to sample once (overrides the preset).
    pub num_levels: Option<usize>,
    /// Integrated positional encoding (false: plain PE of the frustum means) [default: true].
    pub ipe: Option<bool>,
    /// Weight rays by their pixel's area [default: true for mipnerf].
    pub area_loss: Option<bool>,
    /// One MLP per level with coarse weight 1 [default: false for mipnerf].
    pub two_mlps: Option<bool>,
    /// Mip-NeRF's softplus density, bias -1 and colour padding [default: true for mipnerf].
    pub misc: Option<bool>,
    /// Rays through pixel centres (false: corners) [default: true for mipnerf].
    pub centered_pixels: Option<bool>,
    /// Rays per pixel along each axis (supersampled NeRF) [default: 1].
    pub supersample: Option<usize>,
    /// Cone or cylinder [default: cone; cylinder for LLFF].
    pub ray_shape: Option<RayShape>,
    /// Standard deviation of the Gaussian noise added to the raw density in training (the
    /// official code's `density_noise`: 0 for Blender, 1 for LLFF) [default: 1 for forward-facing
    /// photos, else 0].
    pub density_noise: Option<f32>,
    /// The training steps over which the density noise falls linearly to 0; 0 holds it
    /// [default: held throughout, the official code's; the hash-grid field's recipe,
    /// `HashGridRecipe::RECIPE`, for forward-facing photos: 10000; recorded when not 0, or when 0
    /// against the recipe]. A grid field's Adam turns the held noise into floaters on fern
    /// (docs/results/hash-grid/climb-noise).
    pub density_noise_steps: Option<u64>,
    /// Composite on white (`--background white`) or not (`black`) [default: true, false for LLFF
    /// and COLMAP].
    pub white_bkgd: Option<bool>,
    /// Training only: composite each pixel on a random colour, its target too
    /// (`--background random`; evaluation and renders use `white_bkgd`). Needs images with alpha
    /// [default: false].
    pub random_bkgd: Option<bool>,
    /// Photos (LLFF, COLMAP): a folder of foreground masks, one per photo (named as the photo,
    /// PNG or JPEG, white = the object), taken as the photos' alpha: the object trains alone
    /// [default: none].
    pub masks: Option<PathBuf>,
    /// Blender: load at half resolution [default: false].
    pub half_res: Option<bool>,
    /// LLFF: image folder factor, images_N [default: 4].
    pub llff_factor: Option<u32>,
    /// LLFF: spherical poses instead of NDC [default: false].
    pub spherify: Option<bool>,
    /// With `spherify`: the cameras' distance from the scene's centre, in world units, with the
    /// up axis that of the ring they stand on [default: 4 for new runs; a saved run without it
    /// used the official spherical poses: the unit sphere, the mean offset up].
    pub spherify_radius: Option<f32>,
    /// An unbounded scene (mip-NeRF 360's contraction of space, samples out to infinity): photos
    /// taken all around with their surroundings, spherified with the farthest camera on the unit
    /// sphere [default: false; recorded only when set].
    pub unbounded: Option<bool>,
    /// Weight of mip-NeRF 360's distortion loss on the last level's weights (CPU backend)
    /// [default: 0, off; recorded only when set].
    pub distortion_loss: Option<f32>,
    /// Occupancy-guided sampling [default: true for the fast preset, else false].
    pub occupancy: Option<bool>,
    /// Cells along each axis of the occupancy grid [default: 64].
    pub occupancy_resolution: Option<usize>,
    /// Half the side of the occupancy grid's cube, centred on the origin [default: from the
    /// cameras: the nearest camera's distance to the origin less its near bound].
    pub occupancy_bound: Option<f32>,
    /// Seed the occupancy grid with the visual hull of the training images' alpha masks, where
    /// they have transparency [default: true].
    pub occupancy_masks: Option<bool>,
    /// Train for this long (`90s`, `30m`, `1h30m`; training time over every resumed segment)
    /// instead of a step count, with the learning-rate schedule stretched to the steps that fit.
    pub time_budget: Option<String>,
    /// Copy the run (checkpoint, config, training time) to `snapshots/NNNNNs/` when the training
    /// time passes each of these marks (`2m`, `5m`, ...), for evaluation at fixed times.
    pub snapshots: Option<Vec<String>>,
    /// Precision of the MLP's matrix products: f32, bf16 or auto [default: f32; auto for the
    /// fast preset with the Mip-NeRF field]. A saved run records the precision that ran (f32 or bf16).
    pub precision: Option<PrecisionArg>,
    /// Flush subnormal floats to zero in the CPU backend's training steps (x86's FTZ and DAZ,
    /// `mipnerf_core::subnormals`) [default: the preset's, `Preset::flushes_subnormals`: on for
    /// tiny and fast].
    pub flush_subnormals: Option<bool>,
    /// Every this many steps (and at the end), render a few test images and log their PSNR per
    /// scale in metrics.csv's `val_psnr` [default: 0, off]. Not counted as training time.
    pub val_every: Option<u64>,
    /// Test images validation renders, at every scale [default: 2].
    pub val_images: Option<usize>,
}

/// The settings that may change when a run is resumed: how long and how fast it trains, where,
/// and how often it logs. Every other setting is part of what the run is (its model, sampler,
/// data and seed) and is refused on `--resume` when it differs from the saved one.
pub const RESUMABLE: &[&str] = &[
    "steps",
    "time_budget",
    "batch_rays",
    "backend",
    "precision",
    "flush_subnormals",
    "lr_init",
    "lr_final",
    "lr_delay_steps",
    "lr_delay_mult",
    "grad_max_norm",
    "grad_max_val",
    "checkpoint_every",
    "log_every",
    "snapshots",
    "val_every",
    "val_images",
];

macro_rules! merge_fields {
    ($base:expr, $over:expr, $($f:ident),*) => { TrainSettings { $($f: $over.$f.clone().or($base.$f.clone()),)* } };
}

impl FieldArg {
    /// The flag's value, as `--field` takes it.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::MipNerf => "mip-nerf",
            Self::TriMip => "tri-mip",
            Self::TriPlane => "tri-plane",
            Self::HashGrid => "hash-grid",
        }
    }
}

impl TrainSettings {
    /// `self` with every field that `over` sets replaced.
    #[must_use]
    pub fn overridden_by(&self, over: &Self) -> Self {
        merge_fields!(
            self,
            over,
            data,
            preset,
            model,
            field,
            tri_mip_bound,
            tri_mip_resolution,
            tri_mip_mlp,
            tri_mip_lr_mult,
            grid_adam_eps,
            grid_adam_skip_untouched,
            tri_mip_tv,
            hash_grid_decay,
            adam_beta2,
            mlp_l2,
            coarse_to_fine_steps,
            steps,
            batch_rays,
            seed,
            backend,
            checkpoint_every,
            log_every,
            lr_init,
            lr_final,
            lr_delay_steps,
            lr_delay_mult,
            lr_decay_steps,
            grad_max_norm,
            grad_max_val,
            num_samples,
            num_levels,
            ipe,
            area_loss,
            two_mlps,
            misc,
            centered_pixels,
            supersample,
            ray_shape,
            density_noise,
            density_noise_steps,
            white_bkgd,
            random_bkgd,
            masks,
            half_res,
            llff_factor,
            spherify,
            spherify_radius,
            unbounded,
            distortion_loss,
            occupancy,
            occupancy_resolution,
            occupancy_bound,
            occupancy_masks,
            time_budget,
            snapshots,
            precision,
            flush_subnormals,
            val_every,
            val_images
        )
    }

    /// Reads settings from a TOML file.
    ///
    /// # Errors
    /// An unreadable file, malformed TOML or an unknown key, naming the file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = mipnerf_core::io::read_regular_text(path, mipnerf_core::io::cap::SETTINGS)
            .with_context(|| format!("reading {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("{}: invalid configuration", path.display()))
    }

    /// The first setting `flags` gives on `--resume` that would change what this saved run is:
    /// `(key, saved value, given value)`. Settings in [`RESUMABLE`] may change; the dataset is
    /// compared by the caller (paths need resolving).
    ///
    /// # Errors
    /// Settings that do not serialise (never for valid settings).
    pub fn resume_conflict(&self, flags: &Self) -> Result<Option<(String, String, String)>> {
        let saved = toml::Value::try_from(self)?;
        let given = toml::Value::try_from(flags)?;
        let Some(given) = given.as_table() else { return Ok(None) };
        for (key, value) in given {
            if key == "data" || key == "masks" || RESUMABLE.contains(&key.as_str()) {
                continue;
            }
            let before = saved.get(key);
            if before != Some(value) {
                let show = |v: &toml::Value| v.as_str().map_or_else(|| v.to_string(), str::to_owned);
                let shown = before.map_or_else(|| "unset (its default)".to_owned(), show);
                return Ok(Some((key.clone(), shown, show(value))));
            }
        }
        Ok(None)
    }

    /// Writes these settings as TOML, atomically.
    ///
    /// # Errors
    /// An unwritable file.
    pub fn save(&self, path: &Path) -> Result<()> {
        let text = format!(
            "# mipnerf run configuration (resolved; read back by --resume, eval and render)\n{}",
            toml::to_string(self)?
        );
        Ok(mipnerf_core::io::write_atomic(path, text.as_bytes())?)
    }

    /// The time budget in seconds, if one is set.
    ///
    /// # Errors
    /// A malformed duration, named.
    pub fn time_budget_seconds(&self) -> Result<Option<f64>> {
        self.time_budget
            .as_deref()
            .map(|t| parse_duration(t).with_context(|| format!("--time-budget {t:?}")))
            .transpose()
    }

    /// The snapshot marks in seconds, sorted.
    ///
    /// # Errors
    /// A malformed duration, a mark given twice, or one at or past the time budget (no snapshot
    /// would be taken there), named.
    pub fn snapshot_seconds(&self) -> Result<Vec<f64>> {
        let mut v = self
            .snapshots
            .iter()
            .flatten()
            .map(|t| parse_duration(t).with_context(|| format!("--snapshots {t:?}")))
            .collect::<Result<Vec<_>>>()?;
        v.sort_by(f64::total_cmp);
        if let Some(w) = v.windows(2).find(|w| w[0] == w[1]) {
            bail!("--snapshots names {} s twice; give each time once", w[0]);
        }
        if let (Some(budget), Some(&last)) = (self.time_budget_seconds()?, v.last())
            && last >= budget
        {
            bail!(
                "--snapshots {last} s is at or past the end of --time-budget ({budget} s), where no snapshot is \
                 taken (the run's checkpoint is the model at its end)"
            );
        }
        Ok(v)
    }

    /// The model configuration of resolved settings.
    ///
    /// # Errors
    /// Out-of-range values.
    pub fn model_config(&self) -> Result<ModelConfig> {
        let preset = self.preset.unwrap_or(PresetArg::Tiny).preset();
        let mut m = preset.config();
        if self.model == Some(ModelKind::Nerf) {
            m = m.nerf();
        }
        if self.ipe == Some(false) && m.point_encoding == PointEncoding::Integrated {
            m.point_encoding = PointEncoding::Mean;
        }
        if self.ipe == Some(true) && m.point_encoding != PointEncoding::Integrated {
            m.point_encoding = PointEncoding::Integrated;
            m.max_deg_point = preset.config().max_deg_point;
        }
        m.area_loss = self.area_loss.unwrap_or(m.area_loss);
        if let Some(two) = self.two_mlps {
            m.separate_mlps = two;
            m.coarse_loss_mult = if two { 1.0 } else { 0.1 };
        }
        if self.misc == Some(false) {
            m = m.without_misc();
        } else if self.misc == Some(true) {
            let d = ModelConfig::default();
            (m.density_activation, m.density_bias, m.rgb_padding) =
                (d.density_activation, d.density_bias, d.rgb_padding);
        }
        if let Some(n) = self.num_samples {
            m.num_samples = n;
        }
        if let Some(n) = self.num_levels {
            m.num_levels = n;
        }
        m.supersample = self.supersample.unwrap_or(1);
        m.ray_shape = self.ray_shape.unwrap_or(RayShape::Cone);
        m.density_noise = self.density_noise.unwrap_or(0.0);
        if !(m.density_noise.is_finite() && (0.0..=100.0).contains(&m.density_noise)) {
            bail!("--density-noise must be between 0 and 100, got {}", m.density_noise);
        }
        m.density_noise_steps = self.density_noise_steps.unwrap_or(0);
        m.coarse_to_fine_steps = self.coarse_to_fine_steps.unwrap_or(0);
        m.unbounded = self.unbounded.unwrap_or(false);
        m.distortion_loss_mult = self.distortion_loss.unwrap_or(0.0);
        if !(m.distortion_loss_mult.is_finite() && (0.0..=1.0).contains(&m.distortion_loss_mult)) {
            bail!("--distortion-loss must be between 0 and 1 (the successor's: 0.01), got {}", m.distortion_loss_mult);
        }
        m.white_bkgd = self.white_bkgd.unwrap_or(true);
        m.random_bkgd = self.random_bkgd.unwrap_or(false);
        self.check_tri_mip()?;
        if let Some(field) = self.field.filter(|_| self.uses_grid_field()) {
            let what = if field == FieldArg::HashGrid { "grid" } else { "planes" };
            if self.model == Some(ModelKind::Nerf) {
                bail!("--field {} reads the {what} into Mip-NeRF's model; leave out --model nerf", field.name());
            }
            let half_side = self.tri_mip_bound.unwrap_or(TRI_MIP_BOUND_UNTIL_DATA);
            if !(half_side.is_finite() && half_side > 0.0) {
                bail!("tri_mip_bound must be a positive number, got {half_side}");
            }
            let recipe = TriMipRecipe::RECIPE;
            m = TriMipRecipe::with_mlp(m, self.tri_mip_mlp.unwrap_or(recipe.mlp));
            m.field = if field == FieldArg::HashGrid {
                Field::HashGrid { grid: HashGridRecipe::RECIPE.grid, half_side }
            } else {
                let planes = TriMipRecipe::planes(self.tri_mip_resolution.unwrap_or(recipe.resolution));
                Field::TriMip { planes, half_side, pre_filtered: field == FieldArg::TriMip }
            };
            // Resolved settings carry the recipe's weight for the data (none when it is 0).
            m.planes_tv_mult = self.tri_mip_tv.unwrap_or(0.0);
            m.grid_decay_mult = self.hash_grid_decay.unwrap_or(0.0);
        }
        if m.supersample == 0 || m.supersample > 16 {
            bail!("--supersample must be between 1 and 16, got {}", m.supersample);
        }
        if m.num_samples == 0 || m.num_samples > 1024 {
            bail!("--num-samples must be between 1 and 1024, got {}", m.num_samples);
        }
        if !(1..=MAX_LEVELS).contains(&m.num_levels) {
            bail!("--num-levels must be between 1 and {MAX_LEVELS}, got {}", m.num_levels);
        }
        Ok(m)
    }

    /// The optimiser configuration of resolved settings.
    ///
    /// # Errors
    /// Non-positive or non-finite learning rates.
    pub fn optim_config(&self) -> Result<OptimConfig> {
        let lr = LrSchedule {
            lr_init: self.lr_init.unwrap_or(5e-4),
            lr_final: self.lr_final.unwrap_or(5e-6),
            max_steps: self.steps.unwrap_or(2000),
            lr_delay_steps: self.lr_delay_steps.unwrap_or(0),
            lr_delay_mult: self.lr_delay_mult.unwrap_or(0.01),
            decay_steps: self.lr_decay_steps,
        };
        for (name, v) in [("--lr-init", lr.lr_init), ("--lr-final", lr.lr_final), ("--lr-delay-mult", lr.lr_delay_mult)]
        {
            if !(v.is_finite() && v > 0.0) {
                bail!("{name} must be a positive number, got {v}");
            }
        }
        Ok(OptimConfig {
            lr,
            grad_max_norm: self.grad_max_norm.unwrap_or(0.0),
            grad_max_val: self.grad_max_val.unwrap_or(0.0),
            adam: AdamConfig {
                beta2: self.adam_beta2.unwrap_or(AdamConfig::default().beta2),
                l2: self.mlp_l2.unwrap_or(0.0),
                ..AdamConfig::default()
            },
            field: self.uses_grid_field().then(|| FieldAdam {
                lr_mult: self.tri_mip_lr_mult.unwrap_or(self.grid_adam().lr_mult),
                eps: self.grid_adam_eps.unwrap_or(self.grid_adam().eps),
                skip_untouched: self.grid_adam_skip_untouched.unwrap_or(self.grid_adam().skip_untouched),
            }),
        })
    }

    /// Whether the run reads its samples from the Tri-Mip planes (`--field tri-mip` or
    /// `tri-plane`).
    #[must_use]
    pub fn uses_tri_mip(&self) -> bool {
        matches!(self.field, Some(FieldArg::TriMip | FieldArg::TriPlane))
    }

    /// Whether a grid (planes or hash grid) feeds a small MLP: `tri_mip_bound`, `_mlp`, `_lr_mult`.
    #[must_use]
    pub fn uses_grid_field(&self) -> bool {
        self.uses_tri_mip() || self.field == Some(FieldArg::HashGrid)
    }

    /// The grid's own Adam settings in the field's recipe (the planes' or the hash grid's).
    fn grid_adam(&self) -> FieldAdam {
        if self.field == Some(FieldArg::HashGrid) { HashGridRecipe::RECIPE.adam } else { TriMipRecipe::RECIPE.adam }
    }

    /// Whether the run samples with the occupancy grid: as set, else with the fast preset.
    #[must_use]
    pub fn uses_occupancy(&self) -> bool {
        self.occupancy.unwrap_or(self.preset == Some(PresetArg::Fast))
    }

    /// Pixel centres or corners.
    #[must_use]
    pub fn centers(&self) -> PixelCenters {
        if self.centered_pixels.unwrap_or(true) { PixelCenters::Centered } else { PixelCenters::Corner }
    }
}

#[cfg(test)]
mod tests;
