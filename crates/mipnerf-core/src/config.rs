//! The model's configuration, its presets, and the mode a pass runs in: plain types that every
//! stage reads and that import no stage. [`crate::model`] re-exports them.

use crate::cone::RayShape;
use crate::hash_grid::HashGridConfig;
use crate::mip;
use crate::mlp::MlpConfig;
use crate::render::DensityActivation;
use crate::sampling::{self, Spacing};
use crate::tri_mip::TriMipConfig;

/// How a sample's Gaussian is encoded for the MLP.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u32)]
pub enum PointEncoding {
    /// Integrated positional encoding of the Gaussian (Mip-NeRF).
    #[default]
    Integrated = 0,
    /// The same features with the covariance set to zero: plain PE of the frustum's mean, no
    /// identity (the paper's "w/o IPE" ablation; same width as IPE).
    Mean = 1,
    /// NeRF's encoding: the mean itself followed by its PE (`3 + 6 (max_deg - min_deg)` features).
    Nerf = 2,
}

impl PointEncoding {
    /// Features per point for degrees `min_deg..max_deg`: `6 (max - min)` for IPE and its
    /// zero-covariance ablation, `3 + 6 (max - min)` for NeRF's encoding (with the identity).
    #[must_use]
    pub fn width(self, min_deg: u32, max_deg: u32) -> usize {
        match self {
            Self::Integrated | Self::Mean => mip::ipe_len(min_deg, max_deg),
            Self::Nerf => mip::pos_enc_len(min_deg, max_deg, true),
        }
    }
}

/// Everything that defines the model. Defaults are the official Mip-NeRF (Blender) settings.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Trunk depth.
    pub net_depth: usize,
    /// Trunk width.
    pub net_width: usize,
    /// Concatenate the encoded input after every trunk layer `i > 0` with `i % skip_layer == 0`.
    pub skip_layer: usize,
    /// Depth of the view-conditioned colour branch.
    pub net_depth_condition: usize,
    /// Width of the colour branch.
    pub net_width_condition: usize,
    /// Samples (intervals) per ray and level.
    pub num_samples: usize,
    /// Levels: 1 (coarse only) or more (coarse then fine, ...).
    pub num_levels: usize,
    /// One MLP for all levels (Mip-NeRF) or one per level (NeRF).
    pub separate_mlps: bool,
    /// First positional-encoding degree of sample positions.
    pub min_deg_point: u32,
    /// One past the last degree.
    pub max_deg_point: u32,
    /// View directions are encoded with degrees `0..deg_view` plus the identity.
    pub deg_view: u32,
    /// How samples are encoded.
    pub point_encoding: PointEncoding,
    /// Cone (Mip-NeRF) or cylinder (NDC scenes).
    pub ray_shape: RayShape,
    /// Sample linearly in disparity instead of depth.
    pub lindisp: bool,
    /// An unbounded scene (mip-NeRF 360): every Gaussian is carried through the scene
    /// contraction, and edges are spaced linearly near and in disparity far, out to infinity
    /// ([`crate::contract`]). The rays' far bound is then
    /// [`UNBOUNDED_FAR`](crate::contract::UNBOUNDED_FAR) and the cameras lie in the unit ball.
    pub unbounded: bool,
    /// Constant added to the blurred weights before resampling.
    pub resample_padding: f32,
    /// Density activation.
    pub density_activation: DensityActivation,
    /// Added to the raw density before the activation.
    pub density_bias: f32,
    /// Colour padding: `rgb = sigmoid(raw) (1 + 2p) - p`.
    pub rgb_padding: f32,
    /// Standard deviation of Gaussian noise added to raw density in training.
    pub density_noise: f32,
    /// The training steps over which [`density_noise`](Self::density_noise) falls linearly to 0
    /// ([`Self::density_noise_at`]); 0: held at its value throughout (the official code's). A
    /// grid field's Adam (epsilon 1e-15) turns the noise's gradients, which change sign from
    /// step to step, into full steps, and the hash grid's loss climbed on fern with the noise
    /// held (`docs/results/hash-grid/climb-noise/`). Not written when 0.
    #[serde(skip_serializing_if = "is_zero_steps")]
    pub density_noise_steps: u64,
    /// Composite on a white background (else black): in evaluation and rendering always, and in
    /// training unless `random_bkgd`.
    pub white_bkgd: bool,
    /// Training only: composite each pixel on its own random colour
    /// ([`rng::random_background`](crate::rng::random_background) of its place in the batch), on
    /// which its target is composited too (`Dataset::sample_batch`), so that the model must learn
    /// where the object is transparent instead of painting the backdrop's colour into the scene.
    /// Needs images with alpha.
    pub random_bkgd: bool,
    /// Weight of every level but the last in the loss.
    pub coarse_loss_mult: f32,
    /// Weight each ray by its `lossmult` (its pixel's area; the paper's "area loss").
    pub area_loss: bool,
    /// Rays per pixel along each axis for supersampling (1 = one ray per pixel); the rendered
    /// colours of a pixel's `k x k` rays are averaged.
    pub supersample: usize,
    /// Weight of mip-NeRF 360's distortion loss ([`crate::stages::distortion_loss`]) on the last
    /// level's weights, averaged over the batch's rays (0: off, Mip-NeRF; the successor's 0.01).
    /// CPU backend.
    pub distortion_loss_mult: f32,
    /// Weight of the total variation of the Tri-Mip planes' level 0 in the loss
    /// ([`crate::tri_mip::total_variation`]: the mean squared difference of neighbouring texels,
    /// as TensoRF regularises its planes), which spreads what the training rays teach the planes
    /// to the texels between them (0: off; the Tri-Mip field only). Not written when 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub planes_tv_mult: f32,
    /// Weight of Zip-NeRF's normalised weight decay of the hash grid's tables in the loss
    /// ([`crate::hash_grid::HashGridConfig::weight_decay`]: the sum over levels of the mean
    /// squared feature; Zip-NeRF's 0.1), which keeps the features that few training rays reach
    /// near zero (0: off; the hash-grid field only). Not written when 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub grid_decay_mult: f32,
    /// The training steps over which a grid field learns coarse to fine: every training sample's
    /// footprint is widened by a floor ([`Self::footprint_floor_at`]) that halves
    /// [`COARSE_TO_FINE_OCTAVES`] times over these steps and is 0 after them, so that the fine
    /// levels (the hash grid's finer grids, the planes' finer mip levels) are read, and learn,
    /// only as the floor passes them (the grids of Plenoxels and TensoRF grow over training for
    /// the same end; BARF and Neuralangelo bring in fine frequencies and levels so). 0: off, the
    /// field read at the sample's own footprint throughout. A grid field only; CPU backend.
    /// Not written when 0.
    #[serde(skip_serializing_if = "is_zero_steps")]
    pub coarse_to_fine_steps: u64,
    /// The field the samples are read from (the Mip-NeRF MLP on the IPE, the default; or the
    /// Tri-Mip planes before a small MLP). Not written when it is the default, so that the
    /// Mip-NeRF model's checkpoints are the bytes they were.
    #[serde(skip_serializing_if = "Field::is_mip_nerf")]
    pub field: Field,
}

/// The field a sample's conical frustum is read from: what the MLP's input is.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind", deny_unknown_fields)]
pub enum Field {
    /// The integrated positional encoding of the frustum's Gaussian (the paper's), before the
    /// MLP of the model's shape.
    #[default]
    MipNerf,
    /// The Tri-Mip planes ([`crate::tri_mip`]) over the cube `[-half_side, half_side]^3` (of
    /// the scene's world space; of NDC space for forward-facing data; of the contracted space
    /// in an unbounded scene),
    /// read at the frustum's footprint (`pre_filtered`, Tri-MipRF) or at level 0 whatever the
    /// cone (point sampling: the aliasing baseline), before an MLP of the model's shape without
    /// skip connection.
    TriMip {
        /// The planes' shape.
        planes: TriMipConfig,
        /// Half the side of the cube the planes cover, in scene units.
        half_side: f32,
        /// Read at the level of the frustum's footprint (true) or at level 0 (false).
        pre_filtered: bool,
    },
    /// Zip-NeRF's hash grid ([`crate::hash_grid`]) over the same cube, each level down-weighted
    /// by how much of it the frustum's footprint averages away, before an MLP of the model's
    /// shape without skip connection.
    HashGrid {
        /// The grid's shape.
        grid: HashGridConfig,
        /// Half the side of the cube the grid covers, in scene units.
        half_side: f32,
    },
}

/// The footprint floor's radius at the first step of a coarse-to-fine run
/// ([`ModelConfig::footprint_floor_at`]), in the grid box's units: a sixteenth of the box, which
/// the recipes' coarsest levels resolve (the hash grid's 16 cells a side; the planes' level 4).
pub const COARSE_TO_FINE_RADIUS: f32 = 1.0 / 16.0;

/// How many times the footprint floor halves over a coarse-to-fine run: from a sixteenth of the
/// box to a thousandth (1/1024), under the finest level's cells (the hash grid's 512 a side).
pub const COARSE_TO_FINE_OCTAVES: f64 = 6.0;

/// Whether `v` is 0 (a weight that is off, not written).
#[allow(clippy::trivially_copy_pass_by_ref)]
fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

/// Whether `v` is 0 (a schedule that is off, not written).
#[allow(clippy::trivially_copy_pass_by_ref)]
fn is_zero_steps(v: &u64) -> bool {
    *v == 0
}

impl Field {
    /// Whether this is the default, the Mip-NeRF field.
    #[must_use]
    pub fn is_mip_nerf(&self) -> bool {
        *self == Self::MipNerf
    }

    /// Half the side of the cube a grid field covers (none for Mip-NeRF's, which has no box).
    #[must_use]
    pub fn half_side(&self) -> Option<f32> {
        match *self {
            Self::MipNerf => None,
            Self::TriMip { half_side, .. } | Self::HashGrid { half_side, .. } => Some(half_side),
        }
    }
}

impl Default for ModelConfig {
    fn default() -> Self {
        // The paper's MLP, as `MlpConfig` states it.
        let mlp = MlpConfig::default();
        Self {
            net_depth: mlp.net_depth,
            net_width: mlp.net_width,
            skip_layer: mlp.skip_layer,
            net_depth_condition: mlp.net_depth_condition,
            net_width_condition: mlp.net_width_condition,
            num_samples: 128,
            num_levels: 2,
            separate_mlps: false,
            min_deg_point: 0,
            max_deg_point: 16,
            deg_view: 4,
            point_encoding: PointEncoding::Integrated,
            ray_shape: RayShape::Cone,
            lindisp: false,
            unbounded: false,
            resample_padding: sampling::RESAMPLE_PADDING,
            density_activation: DensityActivation::Softplus,
            density_bias: -1.0,
            rgb_padding: 0.001,
            density_noise: 0.0,
            density_noise_steps: 0,
            white_bkgd: true,
            random_bkgd: false,
            coarse_loss_mult: 0.1,
            area_loss: true,
            supersample: 1,
            distortion_loss_mult: 0.0,
            planes_tv_mult: 0.0,
            grid_decay_mult: 0.0,
            coarse_to_fine_steps: 0,
            field: Field::MipNerf,
        }
    }
}

/// What a dataset implies for the model where nobody chose otherwise: the one rule the CLI's
/// settings and the library's `Nerf` both follow (`Dataset::model_fit` makes it from a loaded
/// dataset; the CLI from the format and its flags before loading).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataFit {
    /// Forward-facing photos, trained in NDC space (LLFF's protocol).
    pub forward_facing: bool,
    /// Images composited on white (Blender's objects, masked photos) rather than alpha dropped.
    pub white_bkgd: bool,
    /// Photos with foreground masks: an object alone.
    pub masked: bool,
}

impl DataFit {
    /// Whether images are composited on white where nobody chose: Blender's objects and masked
    /// photos (an object alone) are; photos without masks keep no alpha.
    #[must_use]
    pub fn white_by_default(photos: bool, masked: bool) -> bool {
        !photos || masked
    }

    /// Cylinders for NDC rays (the official LLFF setting), else cones.
    #[must_use]
    pub fn ray_shape(self) -> RayShape {
        if self.forward_facing { RayShape::Cylinder } else { RayShape::Cone }
    }

    /// The official LLFF setting on forward-facing data (+0.30 dB at 3 minutes of the fast preset
    /// on fern's held-out training photos, `docs/results/fern/tune`), else none.
    #[must_use]
    pub fn density_noise(self) -> f32 {
        if self.forward_facing { 1.0 } else { 0.0 }
    }

    /// Masked photos train on random backgrounds, so that the model learns where the object ends
    /// rather than a backdrop's colour (they are evaluated and rendered on white).
    #[must_use]
    pub fn random_bkgd(self) -> bool {
        self.masked
    }

    /// `model` fitted to what the data is: composited as the data is, rays of the data's shape
    /// (a trained model loaded for other data: its training settings stay its own).
    pub fn apply_to_rays(self, model: &mut ModelConfig) {
        model.white_bkgd = self.white_bkgd;
        model.ray_shape = self.ray_shape();
    }

    /// `model` fitted to the data for training: [`apply_to_rays`](Self::apply_to_rays), and the
    /// data's density noise and random backgrounds where `model` has the presets' (none).
    pub fn apply(self, model: &mut ModelConfig) {
        self.apply_to_rays(model);
        if model.density_noise == 0.0 {
            model.density_noise = self.density_noise();
        }
        model.random_bkgd |= self.random_bkgd();
    }
}

/// Samples per level of [`Preset::Fast`]: 16 trained to a higher PSNR than 32 and 48 at a
/// 2-minute budget (`experiments/fast-preset-sweep`): in occupied space, more steps beat more
/// samples per ray.
pub const FAST_SAMPLES: usize = 16;

/// How the fast preset trains, beside its model ([`Preset::Fast`]): the one recipe the CLI's
/// `--preset fast` and the library's `Options::preset(Preset::Fast)` both take, chosen by
/// measurement (`experiments/fast-preset-sweep`, `docs/RESULTS.md`, "Time to quality").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FastRecipe {
    /// Rays per batch (drawn pixels; those an occupancy grid finds empty cost no MLP work). 512
    /// scored 0.08 dB more at a 2-minute budget, within one seed's noise; 1024 is kept for the
    /// longer budgets.
    pub batch_rays: usize,
    /// Initial and final learning rates: at a 2-minute budget 5e-3 beat 2e-3 and 1e-3, and a
    /// decay to a tenth beat the decay to a hundredth.
    pub lr: (f32, f32),
    /// Learning-rate warm-up steps (with the official warm-up multiplier, 0.01).
    pub lr_delay_steps: u64,
    /// The occupancy grid's cells a side (occupancy-guided sampling is on).
    pub occupancy_resolution: usize,
    /// The MLP's products in bf16 where the CPU has a kernel for them that outruns f32 (AMX, or
    /// AVX-512 BF16 where `vdpbf16ps` does, [`crate::bf16::Bf16Support::auto`]): 2.3 times the
    /// training rate and +1.8 dB at 2 minutes on AMX.
    pub bf16_where_available: bool,
}

impl FastRecipe {
    /// The recipe.
    pub const RECIPE: Self = Self {
        batch_rays: 1024,
        lr: (5e-3, 5e-4),
        lr_delay_steps: 100,
        occupancy_resolution: 64,
        bf16_where_available: true,
    };

    /// Its learning-rate schedule over `max_steps`.
    #[must_use]
    pub fn schedule(&self, max_steps: u64) -> crate::schedule::LrSchedule {
        crate::schedule::LrSchedule {
            lr_init: self.lr.0,
            lr_final: self.lr.1,
            max_steps,
            lr_delay_steps: self.lr_delay_steps,
            lr_delay_mult: 0.01,
            decay_steps: None,
        }
    }
}

/// How the Tri-Mip field trains ([`Field::TriMip`]) where a run does not say otherwise: its
/// planes, the small MLP after them and the planes' own Adam settings. The CLI's `--field
/// tri-mip` and `tri-plane` take it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriMipRecipe {
    /// Texels along a side of the planes' level 0 (16 features a texel).
    pub resolution: usize,
    /// The MLP after the planes: trunk depth and width, colour branch depth and width.
    pub mlp: [usize; 4],
    /// The planes' learning rate over the MLP's, and their Adam epsilon.
    pub adam: crate::optim::FieldAdam,
    /// Weight of the planes' total variation in the loss ([`ModelConfig::planes_tv_mult`]) on
    /// a scene seen from all round (lego: not measured with it yet, so off).
    pub planes_tv: f32,
    /// The same on forward-facing photos in NDC space: on fern's held-out training photos, 0.1
    /// took 4 minutes of training from 21.40 dB (off) to 23.25, and 1.0 to 22.94
    /// (`docs/results/tri-mip/fern-tune/`): a few photos all from one side leave the planes'
    /// texels between their rays free to overfit, and the total variation ties them together.
    pub planes_tv_forward_facing: f32,
    /// The same on an unbounded scene (its planes over the contracted space), with
    /// [`resolution_unbounded`](Self::resolution_unbounded): on the ethiopian head's held-out
    /// training photos, 4 minutes of training gave 19.58 dB without it (flat from the first
    /// minute), 20.39 with 0.1, 21.26 with 1 and 21.41 with 3 on 256² planes, and 21.67 with 1
    /// on 128² planes (`docs/results/tri-mip/head-tv-more/`): a room seen from one orbit leaves
    /// most texels to overfit, and smoother, coarser planes generalise.
    pub planes_tv_unbounded: f32,
    /// Texels along a side of the planes of an unbounded scene (the contracted space): 128, the
    /// best of the same sweep with [`planes_tv_unbounded`](Self::planes_tv_unbounded).
    pub resolution_unbounded: usize,
}

/// How the hash-grid field trains ([`Field::HashGrid`]) where a run does not say otherwise: its
/// grid, the small MLP after it (the Tri-Mip recipe's) and the grid's own Adam settings. The
/// CLI's `--field hash-grid` takes it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HashGridRecipe {
    /// The grid: 16 levels of 2 features from 16 to 512 cells a side, tables of `2^17` entries
    /// (Instant-NGP's shape with a table a quarter of its `2^19`: 4.2 M parameters, which a
    /// dense Adam step on 2 cores moves in a few milliseconds).
    pub grid: HashGridConfig,
    /// The MLP after the grid: trunk depth and width, colour branch depth and width.
    pub mlp: [usize; 4],
    /// The grid's learning rate over the MLP's, and its Adam epsilon (Instant-NGP's 1e-15): 2,
    /// which starts the grid at Instant-NGP's 1e-2. On lego's held-out training views 3 minutes
    /// gave a four-scale mean of 29.95 dB with 2 and 29.99 with 10 (the planes' factor;
    /// `docs/results/hash-grid/tune/`); on fern's held-out training photos 9 minutes gave 23.23
    /// with 2 and 22.58 with 10, which fell after 3 minutes (`docs/results/hash-grid/fern-tune/`).
    pub adam: crate::optim::FieldAdam,
    /// The weight of the grid's normalised weight decay ([`ModelConfig::grid_decay_mult`]) on
    /// bounded scenes: 0, as lego's results were measured.
    pub decay: f32,
    /// The same for forward-facing photos: 0.01, a tenth of Zip-NeRF's. On fern's held-out
    /// training photos Zip-NeRF's 0.1 cost 1 dB in 9 minutes and 0.01 nothing measurable, with
    /// the features 5 times smaller and a third fewer occupied cells
    /// (`docs/results/hash-grid/decay-fern-tune/`).
    pub decay_forward_facing: f32,
    /// For forward-facing photos, the steps the learning rate takes to decay to its final value,
    /// where it stays however long a time budget runs
    /// ([`crate::schedule::LrSchedule::decay_steps`]): 10,000, about the steps of the 9-minute
    /// runs on fern's held-out photos that chose this recipe. With the rate held high for longer
    /// the loss climbs after about 9,000 steps (`docs/results/hash-grid/stability/`); with it
    /// the climb comes after about 18,000 steps instead (`docs/results/hash-grid/fern-capped/`:
    /// 24.62 dB at 10 minutes, 19.11 at 30).
    pub lr_decay_steps_forward_facing: u64,
    /// For forward-facing photos, the steps over which the density noise (the official code's
    /// 1 on LLFF data) falls to 0 ([`ModelConfig::density_noise_steps`]): 10,000, where the
    /// rate's decay ends. Held, the noise made the loss climb on fern after 9,000 to 18,000
    /// steps (`docs/results/hash-grid/climb-noise/`); on fern's held-out training photos,
    /// 14,000 steps gave 23.49 dB with it held, 23.54 fading over 5,000 steps and 23.65 over
    /// 10,000 (`docs/results/hash-grid/noise-fern-tune/`).
    pub density_noise_steps_forward_facing: u64,
}

impl HashGridRecipe {
    /// The recipe.
    pub const RECIPE: Self = Self {
        grid: HashGridConfig { levels: 16, features: 2, log2_table: 17, coarsest: 16, finest: 512 },
        mlp: TriMipRecipe::RECIPE.mlp,
        adam: crate::optim::FieldAdam { lr_mult: 2.0, eps: 1e-15, skip_untouched: false },
        decay: 0.0,
        decay_forward_facing: 0.01,
        lr_decay_steps_forward_facing: 10_000,
        density_noise_steps_forward_facing: 10_000,
    };
}

impl TriMipRecipe {
    /// The recipe.
    pub const RECIPE: Self = Self {
        resolution: 256,
        mlp: [2, 64, 1, 64],
        adam: crate::optim::FieldAdam { lr_mult: 10.0, eps: 1e-15, skip_untouched: false },
        planes_tv: 0.0,
        planes_tv_forward_facing: 0.1,
        planes_tv_unbounded: 1.0,
        resolution_unbounded: 128,
    };

    /// Features a texel (Tri-MipRF's 16: one 64-byte cache line).
    pub const FEATURES: usize = 16;

    /// The planes of `resolution` texels a side: 16 features, and levels down to 4 texels a
    /// side (Tri-MipRF's 8 levels for 512).
    #[must_use]
    pub fn planes(resolution: usize) -> TriMipConfig {
        let levels = (resolution.max(8).ilog2() as usize).saturating_sub(1);
        TriMipConfig { resolution, features: Self::FEATURES, levels }
    }

    /// `config` with the MLP after the planes `mlp` (trunk depth and width, colour branch depth
    /// and width) and no skip connection (the planes' features are read once).
    #[must_use]
    pub fn with_mlp(config: ModelConfig, mlp: [usize; 4]) -> ModelConfig {
        let [net_depth, net_width, net_depth_condition, net_width_condition] = mlp;
        ModelConfig { net_depth, net_width, net_depth_condition, net_width_condition, skip_layer: 0, ..config }
    }
}

/// A grid field's recipe for the data it trains on, where a run does not say otherwise: the
/// planes' resolution and total variation ([`TriMipRecipe`]), the hash grid's weight decay and
/// the steps its learning rate decays over ([`HashGridRecipe`]). The one rule the CLI's settings
/// and the library's `Options::tri_mip` and `Options::hash_grid` both follow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridFit {
    /// Texels along a side of the Tri-Mip planes.
    pub planes_resolution: usize,
    /// The weight of the planes' total variation ([`ModelConfig::planes_tv_mult`]).
    pub planes_tv: f32,
    /// The weight of the hash grid's weight decay ([`ModelConfig::grid_decay_mult`]).
    pub hash_grid_decay: f32,
    /// The hash grid's: the steps the learning rate decays over, where it then stays
    /// ([`crate::schedule::LrSchedule::decay_steps`]; none: the run's own).
    pub hash_grid_lr_decay_steps: Option<u64>,
    /// The hash grid's: the steps the density noise fades over, where the data has the noise
    /// ([`ModelConfig::density_noise_steps`]; none: held).
    pub hash_grid_density_noise_steps: Option<u64>,
}

impl GridFit {
    /// The recipes' values for data that `fit` describes, in an unbounded scene or not.
    #[must_use]
    pub fn of(fit: DataFit, unbounded: bool) -> Self {
        let (planes, grid) = (TriMipRecipe::RECIPE, HashGridRecipe::RECIPE);
        let planes_tv = if fit.forward_facing {
            planes.planes_tv_forward_facing
        } else if unbounded {
            planes.planes_tv_unbounded
        } else {
            planes.planes_tv
        };
        Self {
            planes_resolution: if unbounded { planes.resolution_unbounded } else { planes.resolution },
            planes_tv,
            hash_grid_decay: if fit.forward_facing { grid.decay_forward_facing } else { grid.decay },
            hash_grid_lr_decay_steps: fit.forward_facing.then_some(grid.lr_decay_steps_forward_facing),
            hash_grid_density_noise_steps: fit.forward_facing.then_some(grid.density_noise_steps_forward_facing),
        }
    }
}

/// Named model sizes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// The official shape: 8 x 256 trunk, 128 + 128 samples (612,740 parameters).
    Paper,
    /// 4 x 128 trunk, skip after layer 2, 64-wide colour branch, 64 + 64 samples (101,060
    /// parameters).
    Small,
    /// 3 x 64 trunk, skip after layer 2, 32-wide colour branch, 32 + 32 samples, IPE degrees
    /// 0..10 (23,392 parameters): trains in minutes on 2 cores.
    Tiny,
    /// The shape of the `fast` training preset (chosen by measurement on lego, see
    /// `docs/RESULTS.md`, "Time to quality"): the small trunk with fewer samples per level, meant
    /// to run with occupancy-guided sampling, which puts them where the scene is.
    Fast,
}

impl Preset {
    /// Whether training at this size flushes subnormal floats to zero on the CPU unless told
    /// otherwise ([`crate::subnormals`]): tiny and fast, whose results are not committed bit for
    /// bit and which train faster for it at the same PSNR (`docs/results/subnormals/`). The
    /// paper and small presets keep IEEE arithmetic and reproduce their committed tables.
    #[must_use]
    pub fn flushes_subnormals(self) -> bool {
        matches!(self, Self::Tiny | Self::Fast)
    }

    /// The Mip-NeRF configuration of this size.
    #[must_use]
    pub fn config(self) -> ModelConfig {
        let base = ModelConfig::default();
        match self {
            Self::Paper => base,
            Self::Small => ModelConfig {
                net_depth: 4,
                net_width: 128,
                skip_layer: 2,
                net_width_condition: 64,
                num_samples: 64,
                ..base
            },
            Self::Tiny => ModelConfig {
                net_depth: 3,
                net_width: 64,
                skip_layer: 2,
                net_width_condition: 32,
                num_samples: 32,
                max_deg_point: 10,
                ..base
            },
            Self::Fast => ModelConfig { num_samples: FAST_SAMPLES, ..Self::Small.config() },
        }
    }
}

impl ModelConfig {
    /// The NeRF baseline of the paper's table, at this configuration's size: NeRF's positional
    /// encoding (degrees 0..10 with the identity), one MLP per level, coarse weight 1, no area
    /// loss, rays through pixel corners (set on the dataset), ReLU density without bias, no colour
    /// padding.
    #[must_use]
    pub fn nerf(mut self) -> Self {
        self.point_encoding = PointEncoding::Nerf;
        self.max_deg_point = self.max_deg_point.min(10);
        self.separate_mlps = true;
        self.coarse_loss_mult = 1.0;
        self.area_loss = false;
        self.without_misc()
    }

    /// The "w/o misc" ablation: ReLU density, density bias 0, colour padding 0.
    #[must_use]
    pub fn without_misc(mut self) -> Self {
        self.density_activation = DensityActivation::Relu;
        self.density_bias = 0.0;
        self.rgb_padding = 0.0;
        self
    }

    /// How the coarse level spaces its edges: unbounded scenes in the contraction's normalised
    /// distance, else in disparity with `lindisp`, else in depth.
    #[must_use]
    pub fn spacing(&self) -> Spacing {
        match (self.unbounded, self.lindisp) {
            (true, _) => Spacing::Unbounded,
            (false, true) => Spacing::Disparity,
            (false, false) => Spacing::Depth,
        }
    }

    /// The density noise's standard deviation in a pass of `mode`: in training,
    /// [`density_noise`](Self::density_noise) times `1 - step / density_noise_steps` (0 from that
    /// step on; held where `density_noise_steps` is 0); none in evaluation.
    #[must_use]
    pub fn density_noise_at(&self, mode: Mode) -> f32 {
        match mode {
            Mode::Eval => 0.0,
            Mode::Train { .. } if self.density_noise_steps == 0 => self.density_noise,
            Mode::Train { step, .. } => {
                let left = 1.0 - f64::from(step) / self.density_noise_steps as f64;
                self.density_noise * left.max(0.0) as f32
            }
        }
    }

    /// The floor under a training sample's footprint in a pass of `mode`, as a radius in the grid
    /// box's units (a side is 1): [`COARSE_TO_FINE_RADIUS`] at step 0, halving
    /// [`COARSE_TO_FINE_OCTAVES`] times by [`coarse_to_fine_steps`](Self::coarse_to_fine_steps)
    /// (a fine level's turn as long as a coarse one's), 0 from then on, where that is 0, and in
    /// evaluation. The footprint's radius `r` is read as `sqrt(r² + floor²)`: the scene seen
    /// through an isotropic blur of that radius. Not differentiated (a constant of the step).
    #[must_use]
    pub fn footprint_floor_at(&self, mode: Mode) -> f32 {
        match mode {
            Mode::Train { step, .. } if u64::from(step) < self.coarse_to_fine_steps => {
                let done = f64::from(step) / self.coarse_to_fine_steps as f64;
                (f64::from(COARSE_TO_FINE_RADIUS) * (-done * COARSE_TO_FINE_OCTAVES).exp2()) as f32
            }
            _ => 0.0,
        }
    }

    /// Width of the sample encoding.
    #[must_use]
    pub fn x_dim(&self) -> usize {
        match self.field {
            Field::MipNerf => self.point_encoding.width(self.min_deg_point, self.max_deg_point),
            Field::TriMip { planes, .. } => planes.encoding_dim(),
            Field::HashGrid { grid, .. } => grid.encoding_dim(),
        }
    }

    /// Width of the view-direction encoding.
    #[must_use]
    pub fn view_dim(&self) -> usize {
        mip::pos_enc_len(0, self.deg_view, true)
    }

    /// The MLP's shape.
    #[must_use]
    pub fn mlp_config(&self) -> MlpConfig {
        MlpConfig {
            net_depth: self.net_depth,
            net_width: self.net_width,
            // The planes' features are read once: no skip connection after them.
            skip_layer: if self.field.is_mip_nerf() { self.skip_layer } else { self.net_depth + 1 },
            net_depth_condition: self.net_depth_condition,
            net_width_condition: self.net_width_condition,
            x_dim: self.x_dim(),
            view_dim: self.view_dim(),
        }
    }
}

/// Whether a pass is training (randomised, with the seed and step that pick its random numbers)
/// or evaluation (deterministic).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Stratified jitter, random inverse-CDF offsets, density noise.
    Train {
        /// Run seed.
        seed: u32,
        /// Step number.
        step: u32,
    },
    /// Deterministic sampling.
    Eval,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_footprint_floor_halves_six_times_over_its_steps_then_is_zero_and_never_in_evaluation() {
        let train = |step| Mode::Train { seed: 0, step };
        let off = ModelConfig::default();
        assert_eq!(off.footprint_floor_at(train(0)), 0.0);
        let c2f = ModelConfig { coarse_to_fine_steps: 600, ..off };
        assert_eq!(c2f.footprint_floor_at(train(0)), COARSE_TO_FINE_RADIUS);
        // An octave each 100 steps.
        for k in 0..6u32 {
            let want = COARSE_TO_FINE_RADIUS / (1u32 << k) as f32;
            assert!((c2f.footprint_floor_at(train(100 * k)) - want).abs() <= 1e-6 * want, "step {}", 100 * k);
        }
        assert!(c2f.footprint_floor_at(train(599)) > COARSE_TO_FINE_RADIUS / 64.0);
        assert_eq!(c2f.footprint_floor_at(train(600)), 0.0);
        assert_eq!(c2f.footprint_floor_at(train(u32::MAX)), 0.0);
        assert_eq!(c2f.footprint_floor_at(Mode::Eval), 0.0);
        let text = serde_json::to_string(&off).unwrap();
        assert!(!text.contains("coarse_to_fine_steps"), "{text}");
        let back: ModelConfig = serde_json::from_str(&serde_json::to_string(&c2f).unwrap()).unwrap();
        assert_eq!(back.coarse_to_fine_steps, 600);
    }

    #[test]
    fn density_noise_falls_linearly_to_zero_over_its_steps_or_is_held() {
        let held = ModelConfig { density_noise: 2.0, ..ModelConfig::default() };
        let train = |step| Mode::Train { seed: 0, step };
        assert_eq!(held.density_noise_at(train(0)), 2.0);
        assert_eq!(held.density_noise_at(train(u32::MAX)), 2.0);
        assert_eq!(held.density_noise_at(Mode::Eval), 0.0);
        let fading = ModelConfig { density_noise_steps: 1000, ..held };
        assert_eq!(fading.density_noise_at(train(0)), 2.0);
        assert_eq!(fading.density_noise_at(train(250)), 1.5);
        assert_eq!(fading.density_noise_at(train(1000)), 0.0);
        assert_eq!(fading.density_noise_at(train(5000)), 0.0);
        assert_eq!(fading.density_noise_at(Mode::Eval), 0.0);
        // Not written when held, so that other runs' checkpoints are the bytes they were.
        let text = serde_json::to_string(&held).unwrap();
        assert!(!text.contains("density_noise_steps"), "{text}");
        let back: ModelConfig = serde_json::from_str(&serde_json::to_string(&fading).unwrap()).unwrap();
        assert_eq!(back.density_noise_steps, 1000);
    }

    #[test]
    fn data_fit_sets_what_the_data_is_and_keeps_chosen_training_settings() {
        let llff = DataFit { forward_facing: true, white_bkgd: false, masked: false };
        let mut m = ModelConfig::default();
        llff.apply(&mut m);
        assert_eq!(
            (m.ray_shape, m.white_bkgd, m.density_noise, m.random_bkgd),
            (RayShape::Cylinder, false, 1.0, false)
        );
        // A density noise chosen by the user stays; a loaded model's training settings stay too.
        let mut chosen = ModelConfig { density_noise: 0.5, ..ModelConfig::default() };
        llff.apply(&mut chosen);
        assert_eq!(chosen.density_noise, 0.5);
        let mut loaded = ModelConfig::default();
        llff.apply_to_rays(&mut loaded);
        assert_eq!((loaded.ray_shape, loaded.density_noise), (RayShape::Cylinder, 0.0));
        let masked = DataFit { forward_facing: false, white_bkgd: true, masked: true };
        let mut m = ModelConfig::default();
        masked.apply(&mut m);
        assert_eq!((m.ray_shape, m.white_bkgd, m.density_noise, m.random_bkgd), (RayShape::Cone, true, 0.0, true));
    }
}
