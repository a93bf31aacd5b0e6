//! `train`'s work: settings resolved and checked against a resumed run, the run directory locked,
//! the data, the occupancy grid and the start state loaded, and the training loop with its
//! checkpoints, snapshots, validation renders, metrics rows and estimates.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use mipnerf_core::backend::TrainState;
use mipnerf_core::checkpoint::{self};
use mipnerf_core::dataset::{Dataset, Split};
use mipnerf_core::model::Levels;
use mipnerf_core::model::{Field, Model};
use mipnerf_core::occupancy::{GridPlan, OccupancyGrid};
use mipnerf_data::Format;

use crate::backend;
use crate::config::{Backend, PrecisionArg, TrainSettings};
use crate::progress::Progress;
use crate::session::Session;

use crate::metrics_csv::open_csv;
use crate::run::{load_checkpoint, load_split, precision_arg, precision_for, read_config, same_path, train_seconds};
use crate::run_dir::{CHECKPOINT, CONFIG, LOCK, RunDir, TRAIN_SECONDS};

/// What a training run ended with.
#[derive(Debug)]
pub struct TrainOutcome {
    /// Steps completed.
    pub step: u64,
    /// Whether Ctrl-C stopped it early.
    pub interrupted: bool,
    /// Last logged loss and PSNR.
    pub last: Option<(f32, f32)>,
}

/// Trains (or resumes) the run in `run_dir` with `flags_settings` over the file and defaults:
/// settings resolved and checked, the directory locked, the data and the start state loaded, the
/// backend opened, then the loop of [`TrainLoop`].
///
/// # Errors
/// Bad settings, data, checkpoints or files.
pub fn train(
    run_dir: &Path,
    file_settings: Option<TrainSettings>,
    flag_settings: TrainSettings,
    resume: bool,
    device: &mipnerf_gpu::DeviceOptions,
    session: &Session,
) -> Result<TrainOutcome> {
    let resolved = resolve_settings(run_dir, file_settings, &flag_settings, resume)?;
    crate::outputs::check_folder_path(run_dir, "--out")?;
    let created = std::fs::symlink_metadata(run_dir).is_err();
    std::fs::create_dir_all(run_dir).with_context(|| format!("creating {}", run_dir.display()))?;
    let outcome = train_locked(run_dir, resolved, &flag_settings, resume, device, session);
    // A run refused before it wrote anything (its data, its options) leaves no folder behind
    // that it made: only its released lock would be in it.
    if outcome.is_err() && created {
        let names: Vec<_> = std::fs::read_dir(run_dir)
            .map(|d| d.filter_map(Result::ok).map(|e| e.file_name()).collect())
            .unwrap_or_default();
        if names.iter().all(|n| n == LOCK) {
            let _ = std::fs::remove_dir_all(run_dir);
        }
    }
    outcome
}

/// [`train`] once its settings are resolved and its folder exists: the folder locked, then
/// everything else.
fn train_locked(
    run_dir: &Path,
    resolved: ResolvedRun,
    flag_settings: &TrainSettings,
    resume: bool,
    device: &mipnerf_gpu::DeviceOptions,
    session: &Session,
) -> Result<TrainOutcome> {
    let ResolvedRun { settings: s, format, model } = resolved;
    let _lock = RunDir::new(run_dir).lock()?;
    // Temporary files that a kill during a save left behind (no other writer exists: we hold the
    // lock); the files they were to replace are intact.
    for name in [CHECKPOINT, CONFIG] {
        let _ = std::fs::remove_file(run_dir.join(format!("{name}.tmp")));
    }
    let ckpt_path = RunDir::new(run_dir).checkpoint();
    if !resume && ckpt_path.exists() {
        bail!(
            "{} already holds a run (checkpoint.safetensors); pass --resume to continue it, or choose another --out",
            run_dir.display()
        );
    }
    let ds = Arc::new(load_training_data(&s, format, &model)?);
    let (s, model) = tri_mip_cube_from_data(s, model, &ds)?;
    let seed = s.seed.unwrap_or(0);
    let mut state = if resume {
        let ck = load_checkpoint(&ckpt_path, &model, session)?;
        let steps = s.steps.unwrap_or(0);
        let budget = s.time_budget_seconds()?;
        let spent = train_seconds(run_dir)?.unwrap_or(0.0);
        let done = match budget {
            Some(b) => (spent >= b).then(|| {
                format!(
                    "it has trained for {spent:.0} s of its {b:.0} s budget; pass a longer --time-budget to train on"
                )
            }),
            None => (ck.step >= steps).then(|| {
                format!(
                    "it is at step {} of --steps {steps}; pass a higher --steps (e.g. --steps {}) to train on",
                    ck.step,
                    (ck.step * 2).max(1)
                )
            }),
        };
        if let Some(why) = done {
            eprintln!("nothing to do: {} is finished: {why}", run_dir.display());
            return Ok(TrainOutcome { step: ck.step, interrupted: false, last: None });
        }
        eprintln!("resuming from step {} ({})", ck.step, ckpt_path.display());
        TrainState::from_checkpoint(ck)
    } else {
        TrainState::fresh(&model, seed)
    };
    if s.occupancy == Some(true) && state.occupancy.is_none() {
        state.occupancy = Some(new_occupancy_grid(&s, &ds)?);
    }
    let batch = s.batch_rays.unwrap_or(1024);
    let setup = mipnerf_gpu::BackendSetup {
        model,
        optim: s.optim_config()?,
        seed,
        state,
        data: Some((ds, batch)),
        render_chunk: None,
        device: device.clone(),
    };
    // A resumed run keeps its precision where it can: bf16 becomes auto, so that a run trained
    // on an AMX CPU continues on a GPU (or another CPU) in f32, said in the header.
    let precision = if resume {
        precision_for(s.precision, flag_settings.precision)
    } else {
        s.precision.unwrap_or(PrecisionArg::F32)
    };
    let (mut be, precision) = backend::open(s.backend.unwrap_or(Backend::Auto), setup, precision, session)?;
    be.set_flush_subnormals(s.flush_subnormals.unwrap_or(false));
    // Before the first step allocates it: does a step's memory fit?
    let need = be.host_training_bytes(batch);
    if let Err(e) = mipnerf_core::memory::check(need, &format!("a training step of --batch-rays {batch}")) {
        let per_ray = need / batch.max(1) as u64;
        let fits = mipnerf_core::memory::available().map_or(0, |a| a.bytes / per_ray.max(1));
        bail!("{e}; lower --batch-rays (about {per_ray} bytes a ray here: at most about {fits} rays fit)");
    }
    // The saved configuration records the precision that ran.
    let s = TrainSettings { precision: Some(precision_arg(precision)), ..s };
    // The loop first (it reads the test split for --val-every): a run refused there writes nothing.
    let train_loop = TrainLoop::new(run_dir, &s, be, resume, session.quiet)?;
    s.save(&RunDir::new(run_dir).config())?;
    train_loop.run()
}

/// A run of the Tri-Mip field: its planes' cube from the cameras (as the occupancy grid's,
/// `occupancy::auto_bound`) where the settings do not give it, recorded in the settings (so that
/// `eval` and `render` rebuild the same model), and the model rebuilt over it; forward-facing
/// data in NDC space takes the occupancy grid's NDC cube (every training ray's samples, which
/// reach past `[-1, 1]` for the photos away from the reference pose), and an unbounded scene the
/// contracted space's.
fn tri_mip_cube_from_data(mut s: TrainSettings, model: Model, ds: &Dataset) -> Result<(TrainSettings, Model)> {
    if model.config().field.is_mip_nerf() {
        return Ok((s, model));
    }
    let flag = s.field.map_or("tri-mip", crate::config::FieldArg::name);
    if s.unbounded == Some(true) {
        // All of an unbounded scene's space, contracted into the ball of radius 2.
        s.tri_mip_bound = Some(s.tri_mip_bound.unwrap_or(mipnerf_core::occupancy::CONTRACTED_BOUND));
    }
    if s.tri_mip_bound.is_none() {
        let bound = mipnerf_core::occupancy::auto_bound(ds).ok_or_else(|| {
            anyhow::anyhow!("--field {flag}: the cameras give no cube for the planes (set tri_mip_bound in a --config)")
        })?;
        s.tri_mip_bound = Some(bound);
    }
    let model = Model::new(s.model_config()?)?;
    let shape = match model.config().field {
        Field::TriMip { planes: p, .. } => {
            format!("planes 3 x {}^2 x {} features in {} levels", p.resolution, p.features, p.levels)
        }
        Field::HashGrid { grid: g, .. } => format!(
            "{} levels of {} features from {} to {} cells a side (tables of 2^{})",
            g.levels, g.features, g.coarsest, g.finest, g.log2_table
        ),
        Field::MipNerf => unreachable!("a grid field"),
    };
    eprintln!(
        "field: {flag}, {shape} over the cube [-{b:.3}, {b:.3}]^3 ({} of the model's {} parameters)",
        model.field_params(),
        model.num_params(),
        b = s.tri_mip_bound.unwrap_or_default(),
    );
    Ok((s, model))
}

/// How far `--occupancy-bound` may stray from the cube the cameras give, either way: a factor of
/// 100 (a hundredth of the scene's size holds none of it; a hundred times spends the grid's
/// cells on empty space).
pub const OCCUPANCY_BOUND_RANGE: f32 = 100.0;

/// A run's occupancy grid before training: its cube from the settings or the cameras, seeded
/// with the visual hull of the training masks where the data has transparency (and the settings
/// allow it), said in one line.
fn new_occupancy_grid(s: &TrainSettings, ds: &Dataset) -> Result<OccupancyGrid> {
    let resolution = s.occupancy_resolution.unwrap_or(64);
    if s.unbounded == Some(true) {
        // All of an unbounded scene's space, contracted into the ball of radius 2.
        let plan = GridPlan { resolution, bound: None, unbounded: true, carve_masks: false };
        let (grid, _) = OccupancyGrid::for_data(ds, plan)?;
        let bound = grid.config.bound;
        eprintln!(
            "occupancy: {resolution}^3 cells over the contracted space [-{bound}, {bound}]^3 (an unbounded scene: the \
             cells beyond the contracted ball never sampled; {:.1}% of cells left)",
            100.0 * grid.occupied_fraction(),
        );
        return Ok(grid);
    }
    let auto = mipnerf_core::occupancy::auto_bound(ds);
    if let (Some(b), Some(auto)) = (s.occupancy_bound, auto)
        && !(auto / OCCUPANCY_BOUND_RANGE..=auto * OCCUPANCY_BOUND_RANGE).contains(&b)
    {
        bail!(
            "--occupancy-bound {b} is far from this scene's size: its cameras give a cube of half side {auto:.3}, \
             and a bound under {:.3} holds none of the scene (nothing would be trained) while one over {:.1} spends the \
             grid on empty space; leave it out to take {auto:.3}",
            auto / OCCUPANCY_BOUND_RANGE,
            auto * OCCUPANCY_BOUND_RANGE
        );
    }
    let bound = match s.occupancy_bound {
        Some(b) => b,
        None => auto.context(
            "the occupancy grid's cube cannot be taken from the cameras (a camera's near bound reaches the \
             origin): pass --occupancy-bound B (half the side of a cube around the origin that holds the scene)",
        )?,
    };
    let t = Instant::now();
    let plan =
        GridPlan { resolution, bound: Some(bound), unbounded: false, carve_masks: s.occupancy_masks.unwrap_or(true) };
    let (grid, carved) = OccupancyGrid::for_data(ds, plan)?;
    eprintln!(
        "occupancy: {resolution}^3 cells over [-{bound:.3}, {bound:.3}]^3{}; {} ({:.1}% of cells left, {:.1}s)",
        if ds.ndc.is_some() { " in NDC space" } else { "" },
        if ds.ndc.is_some() {
            format!("{} that no training ray reaches carved", carved.unreached)
        } else if carved.by_masks > 0 {
            format!("{} carved by the training masks", carved.by_masks)
        } else {
            "no masks carved".to_string()
        },
        100.0 * grid.occupied_fraction(),
        t.elapsed().as_secs_f64(),
    );
    Ok(grid)
}

/// The settings of a run: the saved ones on `--resume`, else the file's, overridden by the
/// flags, resolved for the data's format (the dataset made absolute), and checked; with the
/// model they describe.
fn resolve_settings(
    run_dir: &Path,
    file_settings: Option<TrainSettings>,
    flag_settings: &TrainSettings,
    resume: bool,
) -> Result<ResolvedRun> {
    let base = if resume { read_config(run_dir)? } else { file_settings.unwrap_or_default() };
    if resume {
        check_resume_flags(run_dir, &base, flag_settings)?;
    }
    let mut merged = base.overridden_by(flag_settings);
    // A step-limited run resumed with a time budget (and no --steps) trains until the budget is
    // spent: its saved step count, usually the default nobody typed, would end it at once.
    if resume && base.time_budget.is_none() && flag_settings.time_budget.is_some() && flag_settings.steps.is_none() {
        eprintln!(
            "--time-budget on a run saved with --steps {}: it now trains until the budget is spent (pass --steps too \
             to stop at whichever comes first)",
            base.steps.unwrap_or(0)
        );
        merged.steps = Some(crate::config::MAX_STEPS);
    }
    // A saved configuration without density noise ran without it (it is recorded when not 0;
    // runs before the setting had none), whatever the default for its data is now.
    if resume && merged.density_noise.is_none() {
        merged.density_noise = Some(0.0);
    }
    // Likewise its noise was held unless a fade is recorded (runs before the hash grid's recipe
    // faded it on forward-facing photos held it).
    if resume && merged.density_noise_steps.is_none() {
        merged.density_noise_steps = Some(0);
    }
    let data_dir = merged.data.clone().context("no dataset: pass --data DIR (or data = \"DIR\" in --config)")?;
    if resume && !data_dir.exists() {
        return Err(crate::run::moved_dataset(&data_dir));
    }
    let format = mipnerf_data::detect_format(&data_dir)?;
    // The dataset is stored as an absolute path, so that eval, render and --resume work from any
    // working directory.
    let data_dir = std::path::absolute(&data_dir).with_context(|| format!("resolving {}", data_dir.display()))?;
    // A saved spherified run without a radius used the official spherical poses (the unit
    // sphere, the mean offset up), and keeps them.
    let official_spherify = resume && merged.spherify == Some(true) && merged.spherify_radius.is_none();
    if !resume {
        merged.check_occupancy_settings()?;
        merged.check_format_settings(format).with_context(|| data_dir.display().to_string())?;
    }
    let mut s = merged.resolved(format.is_photos());
    if official_spherify {
        s.spherify_radius = None;
    }
    s.data = Some(data_dir);
    if let Some(m) = &s.masks {
        s.masks = Some(std::path::absolute(m).with_context(|| format!("resolving {}", m.display()))?);
    }
    s.optim_config()?;
    let model = Model::new(s.model_config()?)?;
    s.validate(mipnerf_gpu::GpuBackend::bytes_per_ray(&model))?;
    Ok(ResolvedRun { settings: s, format, model })
}

/// A run's settings resolved (the saved ones on `--resume`, else the file's and the flags'),
/// the data's format, and the model they describe.
struct ResolvedRun {
    settings: TrainSettings,
    format: Format,
    model: Model,
}

/// Refuses `--resume` flags that change what the saved run is (its model, sampler, seed or
/// dataset), naming the flag and how to start a new run instead.
fn check_resume_flags(run_dir: &Path, saved: &TrainSettings, flags: &TrainSettings) -> Result<()> {
    let flag = |key: &str| format!("--{}", key.replace('_', "-"));
    let may_change: Vec<String> = crate::config::RESUMABLE.iter().map(|k| flag(k)).collect();
    let new_run = |what: String| {
        anyhow::anyhow!(
            "{what}; --resume continues a run as it was saved ({}). To train with it, start a new run: \
             mipnerf train --out NEW_DIR with the flags you want. Flags that may change on --resume: {}",
            RunDir::new(run_dir).config().display(),
            may_change.join(", ")
        )
    };
    if let (Some(given), Some(ours)) = (&flags.data, &saved.data)
        && !same_path(given, ours)
    {
        return Err(new_run(format!("--data {} is not this run's dataset ({})", given.display(), ours.display())));
    }
    if let Some(given) = &flags.masks
        && !saved.masks.as_ref().is_some_and(|ours| same_path(given, ours))
    {
        let ours = saved.masks.as_ref().map_or_else(|| "none".to_owned(), |m| m.display().to_string());
        return Err(new_run(format!("--masks {} is not this run's masks ({ours})", given.display())));
    }
    if let Some((key, before, after)) = saved.resume_conflict(flags)? {
        return Err(new_run(format!("{} {after} would change this run, which has {key} = {before}", flag(&key))));
    }
    Ok(())
}

/// The training split, said in one line (and the loader's notes), checked against the model.
fn load_training_data(s: &TrainSettings, format: Format, model: &Model) -> Result<Dataset> {
    let t_load = Instant::now();
    let ds = load_split(s, Split::Train)?;
    let data_dir = s.data.clone().unwrap_or_default();
    eprintln!(
        "data: {} ({format:?}, {} views, {} pixels, scales {:?}, {:.1} MiB of pixels, loaded in {:.1}s)",
        data_dir.display(),
        ds.views().len(),
        ds.num_pixels(),
        ds.scales(),
        ds.pixel_bytes() as f64 / (1 << 20) as f64,
        t_load.elapsed().as_secs_f64()
    );
    for note in &ds.notes {
        eprintln!("note: {note}");
    }
    mipnerf_core::backend::check_ndc_supersample(ds.ndc, model.config().supersample)
        .with_context(|| data_dir.display().to_string())?;
    if model.config().random_bkgd && !ds.has_transparency() {
        bail!(
            "--background random needs images with transparent pixels (alpha below 1), as Blender scenes have, \
             but none of the {} training images in {} has any{}; use --background white or black",
            ds.views().len(),
            data_dir.display(),
            match (&s.masks, format.is_photos()) {
                (Some(masks), _) => format!(
                    " (the masks in {} are white everywhere: a mask is white on the object and black on what is to \
                     be left out, and these leave nothing out)",
                    masks.display()
                ),
                (None, true) =>
                    " (photos from COLMAP or LLFF have no alpha: give their masks with --masks DIR)".to_owned(),
                (None, false) => String::new(),
            }
        );
    }
    eprintln!(
        "model: {} parameters ({:?} preset, {:?})",
        model.num_params(),
        s.preset.unwrap_or(crate::config::PresetArg::Tiny),
        s.model.unwrap_or(crate::config::ModelKind::Mipnerf)
    );
    Ok(ds)
}

/// The training loop of one run directory: steps, a metrics row every `log_every`, a checkpoint
/// every `checkpoint_every` and at the end (or on a signal), never a non-finite one.
struct TrainLoop<'a> {
    run_dir: &'a Path,
    be: Box<dyn mipnerf_core::backend::Backend>,
    ckpt_path: PathBuf,
    csv_path: PathBuf,
    csv: std::fs::File,
    steps: u64,
    batch: usize,
    log_every: u64,
    ckpt_every: u64,
    /// Training time of the earlier segments of a resumed run, and this segment's start.
    seconds_before: f64,
    t0: Instant,
    /// The step of the checkpoint on disk written by this run (or found on resume).
    last_saved: Option<u64>,
    /// `--time-budget` in seconds of training time, and the schedule it stretches.
    budget: Option<(f64, mipnerf_core::schedule::LrSchedule)>,
    /// `--snapshots` marks (seconds of training time) not yet passed.
    snapshots: Vec<f64>,
    /// The steps and seconds this segment has run, for the budget's step estimate.
    segment_steps: u64,
    /// Whether the estimate of the run's wall time has been printed.
    estimated: bool,
    /// `--val-every`: the test images it renders, and the step it last rendered them at.
    val: Option<Validation>,
    /// `--quiet`: no progress.
    quiet: bool,
}

/// Validation during training (`--val-every`): a fixed few test images at every scale.
struct Validation {
    ds: Dataset,
    /// Per scale (ascending), the views rendered.
    views: Vec<Vec<usize>>,
    every: u64,
    last: Option<u64>,
}

impl Validation {
    /// The first `images` test views of every scale of the run's test split (`images` checked
    /// with the other settings, [`TrainSettings::validate`]).
    fn new(s: &TrainSettings, every: u64, images: usize) -> Result<Self> {
        let ds = load_split(s, Split::Test).context("--val-every renders test images")?;
        let views: Vec<Vec<usize>> = ds
            .scales()
            .into_iter()
            .map(|scale| (0..ds.views().len()).filter(|&v| ds.views()[v].scale == scale).take(images).collect())
            .collect();
        Ok(Self { ds, views, every, last: None })
    }

    /// Whether the model after step index `step` is due: every `every` steps, and the last.
    fn due(&self, step: u64, steps: u64) -> bool {
        (step + 1).is_multiple_of(self.every) || step + 1 == steps
    }

    /// The mean test PSNR per scale of the model `be` holds, as `eval` scores it. The first
    /// image of each scale is written beside its target to `RUN/val/scale{j}.png` (the latest
    /// validation renders, which the viewer shows).
    fn psnr(&self, be: &mut dyn mipnerf_core::backend::Backend, run_dir: &Path) -> Result<Vec<f64>> {
        let k = be.model().config().supersample;
        let dir = RunDir::new(run_dir).val();
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        self.views
            .iter()
            .enumerate()
            .map(|(j, views)| {
                let mut sum = 0.0;
                for (i, &v) in views.iter().enumerate() {
                    let image = mipnerf_core::backend::ImageSpec::of_view(&self.ds, v, k);
                    let out = be
                        .render(&image, Levels::Last)
                        .with_context(|| self.ds.views()[v].file.display().to_string())?;
                    let rendered: Vec<[f32; 3]> = out.fine.iter().map(|o| o.rgb).collect();
                    let target = self.ds.view_targets(v);
                    sum += crate::scores::render_psnr(&rendered, &target);
                    if i == 0 {
                        let (w, h) = (image.camera.width, image.camera.height);
                        let pair = side_by_side(&rendered, &target, w as usize);
                        crate::images::write_png(&dir.join(format!("scale{j}.png")), 2 * w, h, &pair)?;
                    }
                }
                Ok(sum / views.len() as f64)
            })
            .collect()
    }
}

/// Two images of width `w` as one 8-bit RGB image of width `2w`: `left` then `right` on each row.
fn side_by_side(left: &[[f32; 3]], right: &[[f32; 3]], w: usize) -> Vec<u8> {
    let (l, r) = (crate::images::rgb_to_png(left), crate::images::rgb_to_png(right));
    l.chunks(3 * w).zip(r.chunks(3 * w)).flat_map(|(a, b)| a.iter().chain(b).copied()).collect()
}

/// Seconds of training after which `train` prints its estimate of the run's wall time (and at
/// least [`ESTIMATE_AFTER_STEPS`] steps), so that the first steps' set-up does not skew it much.
pub const ESTIMATE_AFTER_SECONDS: f64 = 10.0;
/// Steps of training before the estimate.
pub const ESTIMATE_AFTER_STEPS: u64 = 20;

/// What `train` says of the run's length at `rate` steps a second, at step `step` of `steps`;
/// with a time budget (`(budget, elapsed)` seconds of training), how many steps fit instead.
#[must_use]
pub fn estimate_line(rate: f64, step: u64, steps: u64, budget: Option<(f64, f64)>) -> String {
    let words = |s: f64| crate::progress::hms(std::time::Duration::from_secs_f64(s.max(0.0)));
    match budget {
        Some((b, elapsed)) => {
            let left = (b - elapsed).max(0.0);
            format!(
                "estimate: about {} steps in the {} budget ({left:.0} s left at {rate:.2} steps/s so far)",
                step + (left * rate) as u64,
                words(b)
            )
        }
        None => {
            let left_steps = steps.saturating_sub(step);
            format!(
                "estimate: about {} more for the {steps} steps asked ({left_steps} left at {rate:.2} steps/s so far); \
                 --time-budget trains for a set time instead",
                words(left_steps as f64 / rate)
            )
        }
    }
}

impl<'a> TrainLoop<'a> {
    fn new(
        run_dir: &'a Path,
        s: &TrainSettings,
        be: Box<dyn mipnerf_core::backend::Backend>,
        resume: bool,
        quiet: bool,
    ) -> Result<Self> {
        let val = match s.val_every.unwrap_or(0) {
            0 => None,
            every => Some(Validation::new(s, every, s.val_images.unwrap_or(2))?),
        };
        let csv_path = RunDir::new(run_dir).metrics_csv();
        let csv = open_csv(&csv_path, be.step())?;
        let seconds_before = if resume { train_seconds(run_dir)?.unwrap_or(0.0) } else { 0.0 };
        let budget = match s.time_budget_seconds()? {
            Some(b) => Some((b, s.optim_config()?.lr)),
            None => None,
        };
        if let (Some(_), Some(steps)) = (budget, s.steps)
            && steps != crate::config::MAX_STEPS
        {
            eprintln!(
                "--steps {steps} and --time-budget {} both given: the run stops at whichever comes first",
                s.time_budget.as_deref().unwrap_or_default()
            );
        }
        let snapshots = s.snapshot_seconds()?.into_iter().filter(|&m| m > seconds_before).collect();
        Ok(Self {
            run_dir,
            ckpt_path: RunDir::new(run_dir).checkpoint(),
            csv_path,
            csv,
            steps: s.steps.unwrap_or(0),
            batch: s.batch_rays.unwrap_or(1024),
            log_every: s.log_every.unwrap_or(10),
            ckpt_every: s.checkpoint_every.unwrap_or(500),
            seconds_before,
            t0: Instant::now(),
            last_saved: resume.then(|| be.step()),
            budget,
            snapshots,
            segment_steps: 0,
            estimated: false,
            val,
            be,
            quiet,
        })
    }

    /// What stays on disk when the run stops with an error.
    fn kept(&self) -> String {
        match self.last_saved {
            Some(k) => format!("the checkpoint of step {k} in {} is kept", self.ckpt_path.display()),
            None => "no checkpoint was written".to_string(),
        }
    }

    /// Writes the checkpoint and the training time it took; never a non-finite state (the last
    /// good checkpoint stays, and the error names the step at which the state broke).
    fn save(&mut self) -> Result<()> {
        let ck = self.be.checkpoint()?;
        match checkpoint::save(&self.ckpt_path, self.be.model(), &ck) {
            Err(checkpoint::CheckpointError::NonFinite { step, what, .. }) => bail!(
                "the training state became non-finite by step {step} ({what}); not saved: {} \
                 (try a lower --lr-init or --grad-max-norm)",
                self.kept()
            ),
            r => r?,
        }
        // The time it took to reach the saved state: a kill loses at most the time since.
        let total = self.seconds_before + self.t0.elapsed().as_secs_f64();
        let path = RunDir::new(self.run_dir).train_seconds();
        mipnerf_core::io::write_atomic(&path, format!("{total:.3}\n").as_bytes())?;
        self.last_saved = Some(self.be.step());
        Ok(())
    }

    /// Training time so far, over every segment of the run.
    fn elapsed(&self) -> f64 {
        self.seconds_before + self.t0.elapsed().as_secs_f64()
    }

    /// `--time-budget`: the schedule's decay stretched over the steps that the budget allows at
    /// this segment's speed so far (the warm-up keeps its step count).
    fn stretch_schedule(&mut self, budget: f64, lr: mipnerf_core::schedule::LrSchedule) {
        let secs = self.t0.elapsed().as_secs_f64();
        let per_step = (self.segment_steps > 0).then(|| secs / self.segment_steps as f64);
        self.be.set_lr_schedule(lr.stretched_to_budget(self.be.step(), budget - self.elapsed(), per_step));
    }

    /// Saves the run and copies it (checkpoint, configuration, training time) to
    /// `snapshots/NNNNNs/` for the mark `mark` (seconds), a run directory `eval` reads.
    fn snapshot(&mut self, mark: f64) -> Result<()> {
        self.save()?;
        let dir = RunDir::new(self.run_dir).snapshot(mark.round() as u64);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        for name in [CHECKPOINT, CONFIG, TRAIN_SECONDS] {
            std::fs::copy(self.run_dir.join(name), dir.join(name))
                .with_context(|| format!("copying {name} to {}", dir.display()))?;
        }
        eprintln!("snapshot at {:.0} s of training (step {}): {}", self.elapsed(), self.be.step(), dir.display());
        Ok(())
    }

    /// Validation of the model after step index `step`: the test PSNR per scale, its time taken
    /// out of the training time (and of the rays/s window `window`).
    fn validate(&mut self, step: u64, window: &mut (Instant, u64)) -> Result<Option<Vec<f64>>> {
        let Some(val) = &mut self.val else { return Ok(None) };
        let t = Instant::now();
        let psnr = val.psnr(self.be.as_mut(), self.run_dir)?;
        val.last = Some(step);
        let took = t.elapsed();
        self.t0 += took;
        window.0 += took;
        Ok(Some(psnr))
    }

    /// One row of metrics.csv for a step's report; returns the progress message.
    fn log_row(
        &mut self,
        rep: &mipnerf_core::train::StepReport,
        rays_per_s: f64,
        val: Option<&[f64]>,
    ) -> Result<String> {
        if !rep.stats.loss.is_finite() {
            bail!(
                "the loss became {} at step {}; {} (try a lower --lr-init or --grad-max-norm)",
                rep.stats.loss,
                rep.step,
                self.kept()
            );
        }
        let psnr = rep.stats.psnr();
        let losses: Vec<String> = rep.stats.losses.iter().map(|l| format!("{l:.6}")).collect();
        let val_cell = val.map_or(String::new(), |v| v.iter().map(|p| format!("{p:.3}")).collect::<Vec<_>>().join(";"));
        writeln!(
            self.csv,
            "{},{:.6},{},{:.3},{:.3e},{:.0},{:.1},{val_cell}",
            rep.step,
            rep.stats.loss,
            losses.join(";"),
            psnr,
            rep.lr,
            rays_per_s,
            self.seconds_before + self.t0.elapsed().as_secs_f64()
        )?;
        self.csv.flush()?;
        let val_msg = val.and_then(|v| v.first()).map_or(String::new(), |p| format!(" test {p:.2}"));
        Ok(format!("loss {:.5} psnr {psnr:.2}{val_msg} lr {:.2e} {rays_per_s:.0} rays/s", rep.stats.loss, rep.lr))
    }

    /// Once, after [`ESTIMATE_AFTER_SECONDS`] and [`ESTIMATE_AFTER_STEPS`]: how long the run
    /// will take at this segment's rate so far (or, with a time budget, how many steps fit).
    fn estimate(&mut self) -> Option<String> {
        let secs = self.t0.elapsed().as_secs_f64();
        if self.estimated || secs < ESTIMATE_AFTER_SECONDS || self.segment_steps < ESTIMATE_AFTER_STEPS {
            return None;
        }
        self.estimated = true;
        let rate = self.segment_steps as f64 / secs;
        Some(estimate_line(rate, self.be.step(), self.steps, self.budget.map(|(b, _)| (b, self.elapsed()))))
    }

    /// Steps until `steps` or a signal, then the last checkpoint and the plots.
    fn run(mut self) -> Result<TrainOutcome> {
        // A signal now lets the step finish and the checkpoint be written.
        let _cooperation = crate::signals::Cooperation::start();
        // With a time budget the bar counts seconds of training, and the message the steps.
        let mut pb = match self.budget {
            Some((b, _)) => Progress::new(self.quiet, "train (s)", self.elapsed() as u64, b.ceil() as u64),
            None => Progress::new(self.quiet, "train", self.be.step(), self.steps),
        };
        let mut window = (Instant::now(), 0u64);
        let mut last = None;
        let mut interrupted = false;
        while self.be.step() < self.steps {
            if crate::signals::stop_requested() {
                crate::signals::acted_on();
                interrupted = true;
                break;
            }
            let step = self.be.step();
            if let Some((budget, lr)) = self.budget {
                let done = self.elapsed();
                if done >= budget {
                    break;
                }
                self.stretch_schedule(budget, lr);
            }
            // The losses are read (from the device, for a GPU) only on logged steps, and on the
            // steps after which the test images are rendered.
            let val_due = self.val.as_ref().is_some_and(|v| v.due(step, self.steps));
            let report = step.is_multiple_of(self.log_every) || step + 1 == self.steps || val_due;
            let rep = self.be.train_step(report)?;
            window.1 += 1;
            let val = if val_due { self.validate(step, &mut window)? } else { None };
            if let Some(rep) = rep.filter(|_| report) {
                let dt = window.0.elapsed().as_secs_f64().max(1e-9);
                let rays_per_s = (window.1 as f64 * self.batch as f64) / dt;
                window = (Instant::now(), 0);
                let msg = self.log_row(&rep, rays_per_s, val.as_deref())?;
                pb.set_message(if self.budget.is_some() { format!("step {} {msg}", rep.step) } else { msg });
                last = Some((rep.stats.loss, rep.stats.psnr()));
            }
            self.segment_steps += 1;
            if let Some(line) = self.estimate() {
                pb.println(&line);
            }
            pb.set_position(if self.budget.is_some() { self.elapsed() as u64 } else { self.be.step() });
            if self.be.step().is_multiple_of(self.ckpt_every) {
                self.save()?;
            }
            while self.snapshots.first().is_some_and(|&m| self.elapsed() >= m) {
                let mark = self.snapshots.remove(0);
                self.snapshot(mark)?;
            }
        }
        // A run stopped by its budget or a signal is validated where it stopped, on a row of its
        // own (no training step reported on it).
        let done = self.be.step();
        if done > 0 && self.val.as_ref().is_some_and(|v| v.last != Some(done - 1)) {
            let mut window = (Instant::now(), 0);
            if let Some(v) = self.validate(done - 1, &mut window)? {
                let cells = v.iter().map(|p| format!("{p:.3}")).collect::<Vec<_>>().join(";");
                writeln!(self.csv, "{},,,,,,{:.1},{cells}", done - 1, self.elapsed())?;
                self.csv.flush()?;
            }
        }
        self.save()?;
        pb.finish();
        if interrupted {
            eprintln!(
                "interrupted at step {}: checkpoint written to {}; continue with --resume",
                self.be.step(),
                self.ckpt_path.display()
            );
        }
        crate::plot::training_curves(&self.csv_path, self.run_dir)?;
        Ok(TrainOutcome { step: self.be.step(), interrupted, last })
    }
}

#[cfg(test)]
mod tests {
    use super::estimate_line;

    #[test]
    fn the_estimate_says_how_long_the_steps_take_or_how_many_fit_the_budget() {
        // 2,000 steps asked, 200 done at 4 steps/s: 1,800 left, 7m30s.
        let line = estimate_line(4.0, 200, 2000, None);
        assert!(line.contains("about 7m30s more for the 2000 steps asked (1800 left at 4.00 steps/s"), "{line}");
        assert!(line.contains("--time-budget"), "{line}");
        // A 15-minute budget, 10 s spent at step 180 at 18 steps/s: 890 s left, 16,020 more steps.
        let line = estimate_line(18.0, 180, u64::from(u32::MAX), Some((900.0, 10.0)));
        assert!(line.contains("about 16200 steps in the 15m00s budget (890 s left at 18.00 steps/s"), "{line}");
    }
}
