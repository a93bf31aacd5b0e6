//! `mipnerf experiment DIR`: a table of runs described by files, run to completion across
//! interruptions and machines.
//!
//! The folder holds `experiment.toml` (the title, the data it expects, where results go, the
//! rows in order, and the `[protocol]` every row shares: training settings written once) and one
//! `ROW.toml` per row (`label`, and `[settings]` that differ from the protocol). For each row the
//! command trains `OUT/ROW` unless it has finished (resuming one that was interrupted: at most the
//! steps since its last checkpoint are lost), evaluates the test split, writes
//! `RESULTS/ROW.json`, and rebuilds the generated table inside the markdown file `table` from
//! every row's JSON present, so rows run at different times or on different machines meet in one
//! table.

use crate::session::Session;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use mipnerf_core::dataset::Split;
use serde::{Deserialize, Serialize};

use crate::config::TrainSettings;
use crate::lpips::LpipsWeights;
use crate::run;
use crate::run_dir::RunDir;

/// The file describing an experiment.
pub const EXPERIMENT_TOML: &str = "experiment.toml";
/// The file of the paper's rows, beside `experiment.toml` (optional).
pub const PAPER_TOML: &str = "paper.toml";

/// `experiment.toml`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    /// A title for the table.
    pub title: String,
    /// What data the rows expect, in words (shown in the table).
    pub data: String,
    /// The full-resolution width of the data's training images; checked before training.
    pub data_width: u32,
    /// The folder of the rows' JSON files, relative to the experiment folder.
    pub results: PathBuf,
    /// The markdown file whose generated block holds the table, relative to the experiment folder.
    pub table: PathBuf,
    /// The rows, in the table's order; each is `ROW.toml` in the folder.
    pub rows: Vec<String>,
    /// Settings every row shares (the keys of `mipnerf train --config`).
    pub protocol: TrainSettings,
}

/// `ROW.toml`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Row {
    /// The row's name in the table (the paper's).
    pub label: String,
    /// Settings over the protocol.
    #[serde(default)]
    pub settings: TrainSettings,
}

/// `paper.toml`: the paper's rows, for the table beside ours.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Paper {
    source: String,
    row: Vec<PaperRow>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PaperRow {
    id: String,
    psnr: [f64; 4],
    ssim: [f64; 4],
    lpips: [f64; 4],
    avg_error: f64,
    params: String,
}

/// One row's results: `RESULTS/ROW.json`.
#[derive(Debug, Serialize, Deserialize)]
pub struct RowResult {
    /// The row's id (its file name).
    pub row: String,
    /// The row's label.
    pub label: String,
    /// Mean test PSNR per scale, full resolution to 1/8.
    pub psnr: Vec<f64>,
    /// Mean test SSIM per scale.
    pub ssim: Vec<f64>,
    /// Mean test LPIPS per scale, or `null` without the weights.
    pub lpips: Option<Vec<f64>>,
    /// The LPIPS backbone, or `null`.
    pub lpips_net: Option<String>,
    /// The average error over the scales (the paper's when `lpips` is present).
    pub avg_error: f64,
    /// Its terms.
    pub avg_error_terms: Vec<String>,
    /// Wall-clock seconds of training (all segments of an interrupted run added up).
    pub train_seconds: f64,
    /// Wall-clock seconds of this evaluation.
    pub eval_seconds: f64,
    /// Parameters of the model.
    pub params: usize,
    /// Training steps.
    pub steps: u64,
    /// The commit the binary was built from (`-dirty` when the tree had changes).
    pub commit: String,
    /// The CPU's model name.
    pub cpu: String,
    /// Threads used.
    pub threads: usize,
    /// The backend it trained on, and was evaluated on unless `eval_backend` names another.
    pub backend: String,
    /// The backend it was evaluated on when not the training one (`experiment --eval-backend`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eval_backend: Option<String>,
    /// The resolved training settings (without the data path).
    pub settings: TrainSettings,
    /// The SHA-256 of the checkpoint these numbers were measured on: the run they belong to. A
    /// row whose run directory holds another checkpoint is evaluated again.
    #[serde(default)]
    pub checkpoint_sha256: Option<String>,
    /// Evaluations at fixed training times (the run's `snapshots`), earliest first.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub marks: Vec<MarkResult>,
}

/// The test split evaluated on a snapshot of a run taken at a fixed training time.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MarkResult {
    /// The mark (seconds of training time) the snapshot was taken at.
    pub mark_seconds: f64,
    /// The training time the snapshot holds (the first step past the mark).
    pub train_seconds: f64,
    /// Training steps done by then.
    pub steps: u64,
    /// Mean test PSNR per scale, full resolution to 1/8.
    pub psnr: Vec<f64>,
    /// Mean of `psnr` over the scales.
    pub mean_psnr: f64,
    /// Mean test SSIM per scale.
    pub ssim: Vec<f64>,
    /// Mean test LPIPS per scale, or `null` without the weights.
    pub lpips: Option<Vec<f64>>,
    /// The average error over the scales.
    pub avg_error: f64,
    /// Wall-clock seconds of this evaluation (not counted in the training time).
    pub eval_seconds: f64,
    /// The SHA-256 of the snapshot's checkpoint.
    pub checkpoint_sha256: String,
}

/// The flags of `mipnerf experiment`.
pub struct ExperimentArgs {
    /// The experiment folder.
    pub dir: PathBuf,
    /// The dataset.
    pub data: Option<PathBuf>,
    /// Where run directories go.
    pub out: Option<PathBuf>,
    /// Only these rows.
    pub only: Vec<String>,
    /// Only rebuild the table.
    pub table_only: bool,
    /// Evaluate on this backend instead of each row's training backend.
    pub eval_backend: Option<crate::config::Backend>,
    /// LPIPS weights.
    pub lpips: LpipsWeights,
}

fn read_toml<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text = mipnerf_core::io::read_regular_text(path, mipnerf_core::io::cap::SETTINGS)
        .with_context(|| format!("reading {}", path.display()))?;
    toml::from_str(&text).with_context(|| format!("{}: invalid", path.display()))
}

/// Reads `experiment.toml` and every row's file, checking that each listed row has one.
///
/// # Errors
/// A missing or invalid file (unknown keys included), named; a row listed twice or whose name is
/// not a plain file name.
pub fn read(dir: &Path) -> Result<(Experiment, Vec<(String, Row)>)> {
    let exp: Experiment = read_toml(&dir.join(EXPERIMENT_TOML))?;
    if exp.rows.is_empty() {
        bail!("{}: \"rows\" is empty", dir.join(EXPERIMENT_TOML).display());
    }
    let mut rows: Vec<(String, Row)> = Vec::new();
    for id in &exp.rows {
        // A row's name names its TOML, its run folder and its JSON: one plain file name each.
        let plain = !id.is_empty()
            && !id.starts_with('.')
            && id.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
        if !plain {
            bail!(
                "{}: row {id:?}: a row's name is a plain file name (letters, digits, '-', '_' and '.', not first), \
                 as it names ROW.toml, the run folder and the results' ROW.json",
                dir.join(EXPERIMENT_TOML).display()
            );
        }
        if rows.iter().any(|(seen, _)| seen == id) {
            bail!("{}: row {id:?} is listed twice in \"rows\"", dir.join(EXPERIMENT_TOML).display());
        }
        let path = dir.join(format!("{id}.toml"));
        if !path.is_file() {
            bail!(
                "{}: row {id:?} is listed in {} but has no file",
                path.display(),
                dir.join(EXPERIMENT_TOML).display()
            );
        }
        rows.push((id.clone(), read_toml::<Row>(&path)?));
    }
    Ok((exp, rows))
}

/// The commit this binary was built from.
#[must_use]
pub fn commit() -> &'static str {
    env!("MIPNERF_COMMIT")
}

/// The CPU's model name, from `/proc/cpuinfo` where there is one.
#[must_use]
pub fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string())
}

/// The width of the training images at full scale: from a multiscale dataset's metadata, else
/// from the first test image as `settings` load it (LLFF's factor, say).
fn data_width(data: &Path, settings: &TrainSettings) -> Result<u32> {
    let meta = data.join("metadata.json");
    if !meta.is_file() {
        let s = TrainSettings { data: Some(data.to_path_buf()), ..settings.clone() };
        let ds = run::load_split(&s, mipnerf_core::dataset::Split::Test)?;
        return ds
            .views()
            .first()
            .map(|v| v.camera.width)
            .with_context(|| format!("{}: no test images", data.display()));
    }
    let v: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&meta)
            .with_context(|| format!("{}: the experiment needs a multiscale dataset", meta.display()))?,
    )
    .with_context(|| format!("{}: malformed JSON", meta.display()))?;
    v["train"]["width"][0]
        .as_u64()
        .and_then(|w| u32::try_from(w).ok())
        .with_context(|| format!("{}: no train width", meta.display()))
}

/// Settings as they decide what a run computes (data path and backend aside).
fn comparable(s: &TrainSettings) -> TrainSettings {
    TrainSettings { data: None, backend: None, ..s.clone() }
}

/// Runs the experiment.
///
/// # Errors
/// Bad experiment files, data of the wrong size, a run directory made with other settings, and
/// every error of training and evaluation.
pub fn experiment(args: &ExperimentArgs, session: &Session) -> Result<()> {
    let (exp, rows) = read(&args.dir)?;
    for o in &args.only {
        if !exp.rows.contains(o) {
            bail!(
                "--only {o}: no such row in {} (rows: {})",
                args.dir.join(EXPERIMENT_TOML).display(),
                exp.rows.join(", ")
            );
        }
    }
    let results = args.dir.join(&exp.results);
    if !args.table_only {
        let (Some(data), Some(out)) = (&args.data, &args.out) else { bail!("--data and --out are needed to run rows") };
        let data = std::path::absolute(data).with_context(|| data.display().to_string())?;
        let first = rows.first().map(|(_, r)| exp.protocol.overridden_by(&r.settings)).unwrap_or_default();
        let w = data_width(&data, &first)?;
        if w != exp.data_width {
            bail!(
                "{}: the training images are {w} px wide, but {} expects {} ({})",
                data.display(),
                args.dir.join(EXPERIMENT_TOML).display(),
                exp.data_width,
                exp.data
            );
        }
        std::fs::create_dir_all(&results).with_context(|| results.display().to_string())?;
        for (id, row) in rows.iter().filter(|(id, _)| args.only.is_empty() || args.only.contains(id)) {
            let mut settings = TrainSettings { data: Some(data.clone()), ..exp.protocol.overridden_by(&row.settings) };
            // Masks, as the data, are named from the working directory and stored absolute.
            if let Some(m) = &settings.masks {
                settings.masks = Some(std::path::absolute(m).with_context(|| m.display().to_string())?);
            }
            if !run_row(id, row, &settings, &out.join(id), &results, (&args.lpips, args.eval_backend), session)? {
                eprintln!("experiment interrupted in row {id}; run the same command again to continue");
                std::process::exit(crate::signals::EXIT_INTERRUPTED);
            }
            write_table(&args.dir, &exp)?;
        }
    }
    let path = write_table(&args.dir, &exp)?;
    println!("table: {}", path.display());
    Ok(())
}

/// The steps a row's run in `run_dir` has taken, after checking that it is this row's: trained
/// on the same data with the settings the row (`resolved`) and the protocol now give.
///
/// # Errors
/// A run on other data or with other settings (named, with the way out), or an unreadable one.
fn steps_done(id: &str, run_dir: &Path, resolved: &TrainSettings, session: &Session) -> Result<u64> {
    let saved = run::read_config(run_dir)?;
    let mut now = resolved.clone();
    // `auto` precision is whatever the training machine had: the run records which ran.
    if now.precision == Some(crate::config::PrecisionArg::Auto) {
        now.precision = saved.precision;
    }
    // What training resolves from the data where the row leaves it open (the Tri-Mip
    // planes' box, the occupancy grid's bound): the run records what it took.
    if now.tri_mip_bound.is_none() {
        now.tri_mip_bound = saved.tri_mip_bound;
    }
    if now.occupancy_bound.is_none() {
        now.occupancy_bound = saved.occupancy_bound;
    }
    // The row's JSON is bound to this checkpoint (its SHA-256), and the checkpoint to the data
    // it trained on: a run on other data is never reported as this row's.
    if let (Some(theirs), Some(ours)) = (&saved.data, &now.data)
        && !run::same_path(theirs, ours)
    {
        bail!(
            "{}: this run trained on {}, not on --data {}; move it away (or pass another --out) to train the row \
             on this data",
            run_dir.display(),
            theirs.display(),
            ours.display()
        );
    }
    if comparable(&saved) != comparable(&now) {
        bail!(
            "{}: this run was made with other settings than {id}.toml and the protocol now give; \
             move it away to train the row again",
            run_dir.display()
        );
    }
    Ok(run::load_trained(run_dir, &saved, session)?.1.step)
}

/// Trains (or resumes) and evaluates one row; `false` when interrupted.
fn run_row(
    id: &str,
    row: &Row,
    settings: &TrainSettings,
    run_dir: &Path,
    results: &Path,
    (lpips, eval_backend): (&LpipsWeights, Option<crate::config::Backend>),
    session: &Session,
) -> Result<bool> {
    // Defaults that depend on the kind of data (LLFF and COLMAP against the rest) as `train` resolves them.
    let llff = settings
        .data
        .as_deref()
        .and_then(|d| mipnerf_data::detect_format(d).ok())
        .is_some_and(mipnerf_data::Format::is_photos);
    let steps = settings.resolved(llff).steps.unwrap_or(2000);
    let budget = settings.time_budget_seconds()?;
    let ckpt = RunDir::new(run_dir).checkpoint();
    let done_steps = if ckpt.is_file() { steps_done(id, run_dir, &settings.resolved(llff), session)? } else { 0 };
    let spent = if done_steps > 0 { run::train_seconds(run_dir)?.unwrap_or(0.0) } else { 0.0 };
    let trained = done_steps >= steps || budget.is_some_and(|b| spent >= b);
    if !trained {
        match budget {
            Some(b) => println!("== row {id} ({}): training, {spent:.0} of {b:.0} s done", row.label),
            None => println!("== row {id} ({}): training, {} of {steps} steps done", row.label, done_steps),
        }
        let outcome = crate::training::train(
            run_dir,
            Some(settings.clone()),
            TrainSettings::default(),
            done_steps > 0,
            &mipnerf_gpu::DeviceOptions::default(),
            session,
        )?;
        if outcome.interrupted {
            return Ok(false);
        }
    }
    let json_path = results.join(format!("{id}.json"));
    let have_lpips = lpips.open()?.is_ok();
    let sha = mipnerf_core::checkpoint::file_sha256(&ckpt)?;
    let old = std::fs::read_to_string(&json_path).ok().and_then(|t| serde_json::from_str::<RowResult>(&t).ok());
    let marks =
        evaluate_marks(id, run_dir, old.as_ref().map_or(&[][..], |o| &o.marks), (lpips, eval_backend), session)?;
    if let Some(old) = &old
        && old.checkpoint_sha256.as_deref() == Some(sha.as_str())
        && (old.lpips.is_some() || !have_lpips)
        && marks.iter().map(|m| &m.checkpoint_sha256).eq(old.marks.iter().map(|m| &m.checkpoint_sha256))
    {
        println!("== row {id} ({}): done ({}, measured on this run's checkpoint)", row.label, json_path.display());
        return Ok(true);
    }
    if old.is_some() {
        println!(
            "== row {id} ({}): {} holds another run's numbers (or an incomplete row); evaluating this run",
            row.label,
            json_path.display()
        );
    }
    println!("== row {id} ({}): evaluating", row.label);
    let t = Instant::now();
    let saved = run::read_config(run_dir)?;
    let m = evaluate(run_dir, &saved, (lpips, eval_backend), session)?;
    let (model, ck) = run::load_trained(run_dir, &saved, session)?;
    let r = RowResult {
        row: id.to_string(),
        label: row.label.clone(),
        psnr: m.column(|s| s.psnr),
        ssim: m.column(|s| s.ssim),
        lpips: m.lpips_column(),
        lpips_net: m.lpips_net.clone(),
        avg_error: m.avg_error,
        avg_error_terms: m.avg_error_terms.iter().map(|s| (*s).to_string()).collect(),
        train_seconds: run::train_seconds(run_dir)?.unwrap_or(f64::NAN),
        eval_seconds: t.elapsed().as_secs_f64(),
        params: model.num_params(),
        steps: ck.step,
        commit: commit().to_string(),
        cpu: cpu_name(),
        threads: rayon::current_num_threads(),
        backend: format!("{:?}", saved.backend.unwrap_or(crate::config::Backend::Cpu)).to_lowercase(),
        eval_backend: eval_backend.map(|b| format!("{b:?}").to_lowercase()),
        settings: TrainSettings { data: None, ..saved },
        checkpoint_sha256: Some(sha),
        marks,
    };
    crate::outputs::save_keeping_the_old(&json_path, (serde_json::to_string_pretty(&r)? + "\n").as_bytes())?;
    println!(
        "== row {id}: PSNR {} | avg error {:.4} -> {}",
        r.psnr.iter().map(|p| format!("{p:.2}")).collect::<Vec<_>>().join(" / "),
        r.avg_error,
        json_path.display()
    );
    Ok(true)
}

/// Evaluates the test split on each of the run's snapshots (`RUN/snapshots/*/`, see
/// `train --snapshots`), reusing a result of `known` measured on the same checkpoint.
fn evaluate_marks(
    id: &str,
    run_dir: &Path,
    known: &[MarkResult],
    (lpips, eval_backend): (&LpipsWeights, Option<crate::config::Backend>),
    session: &Session,
) -> Result<Vec<MarkResult>> {
    let dir = RunDir::new(run_dir).snapshots();
    let mut snaps: Vec<PathBuf> = match std::fs::read_dir(&dir) {
        Ok(entries) => entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect(),
        Err(_) => return Ok(Vec::new()),
    };
    snaps.sort();
    // A mark measured without LPIPS (on a machine without the weights) is measured again here
    // when they are at hand.
    let have_lpips = lpips.open()?.is_ok();
    let mut out = Vec::new();
    for snap in snaps {
        let mark_seconds: f64 = snap
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.strip_suffix('s'))
            .and_then(|n| n.parse().ok())
            .with_context(|| format!("{}: not a snapshot folder (NNNNNs)", snap.display()))?;
        let sha = mipnerf_core::checkpoint::file_sha256(&RunDir::new(&snap).checkpoint())?;
        if let Some(k) = known.iter().find(|k| k.checkpoint_sha256 == sha && (k.lpips.is_some() || !have_lpips)) {
            out.push(k.clone());
            continue;
        }
        println!("== row {id}: evaluating the snapshot at {mark_seconds:.0} s");
        let t = Instant::now();
        let saved = run::read_config(&snap)?;
        let m = evaluate(&snap, &saved, (lpips, eval_backend), session)?;
        let psnr = m.column(|s| s.psnr);
        out.push(MarkResult {
            mark_seconds,
            train_seconds: run::train_seconds(&snap)?.unwrap_or(f64::NAN),
            steps: m.step,
            mean_psnr: psnr.iter().sum::<f64>() / psnr.len().max(1) as f64,
            psnr,
            ssim: m.column(|s| s.ssim),
            lpips: m.lpips_column(),
            avg_error: m.avg_error,
            eval_seconds: t.elapsed().as_secs_f64(),
            checkpoint_sha256: sha,
        });
        println!(
            "== row {id}: at {mark_seconds:.0} s (step {}): mean PSNR {:.2}",
            m.step,
            out.last().map_or(f64::NAN, |m| m.mean_psnr)
        );
    }
    Ok(out)
}

const BEGIN: &str = "<!-- BEGIN GENERATED TABLE";
const END: &str = "<!-- END GENERATED TABLE -->";

/// Minutes of training as a table shows them: a tenth under ten minutes (a 2.5-minute row is
/// not a 3-minute one), whole minutes above.
fn fmt_minutes(m: f64) -> String {
    if m < 10.0 { format!("{m:.1}") } else { format!("{m:.0}") }
}

fn fmt_list(v: &[f64], digits: usize) -> String {
    v.iter().map(|x| format!(" {x:.digits$} |")).collect()
}

/// The column heads of one metric over `scales` scales: `PSNR full | 1/2 | 1/4 | 1/8` for the
/// multiscale data, `PSNR` for single-scale data.
fn metric_heads(metric: &str, scales: usize) -> String {
    if scales == 1 {
        return format!(" {metric} |");
    }
    (0..scales).map(|j| if j == 0 { format!(" {metric} full |") } else { format!(" 1/{} |", 1u32 << j) }).collect()
}

/// The number of scales the rows' results have (4 when none is there yet: the multiscale data).
fn scales_of(results: &Path, rows: &[String]) -> usize {
    rows.iter()
        .filter_map(|id| std::fs::read_to_string(results.join(format!("{id}.json"))).ok())
        .filter_map(|t| serde_json::from_str::<RowResult>(&t).ok())
        .map(|r| r.psnr.len())
        .next()
        .unwrap_or(4)
}

/// The generated markdown: our rows from their JSON files, then the paper's.
fn table_markdown(dir: &Path, exp: &Experiment) -> Result<String> {
    let results = dir.join(&exp.results);
    let n = scales_of(&results, &exp.rows);
    let head = format!(
        "| row |{}{}{} Avg. error |",
        metric_heads("PSNR", n),
        metric_heads("SSIM", n),
        metric_heads("LPIPS", n)
    );
    let rule = format!("|---|{}---|", "---|".repeat(3 * n));
    let mut s = format!(
        "{BEGIN}: `mipnerf experiment` writes it from {}/*.json; edits inside are overwritten -->\n",
        exp.results.display()
    );
    s += &format!("**Ours** ({}; one seed):\n\n{head} train time | params | commit |\n{rule}---|---|---|\n", exp.data);
    let mut missing = Vec::new();
    let mut two_term = false;
    for id in &exp.rows {
        let path = results.join(format!("{id}.json"));
        let Ok(text) = std::fs::read_to_string(&path) else {
            missing.push(id.as_str());
            continue;
        };
        let r: RowResult = serde_json::from_str(&text).with_context(|| format!("{}: malformed", path.display()))?;
        let lp = r.lpips.as_deref().map_or_else(|| " n/a |".repeat(r.psnr.len()), |l| fmt_list(l, 4));
        two_term |= r.lpips.is_none();
        let star = if r.lpips.is_none() { "*" } else { "" };
        s += &format!(
            "| {} |{}{}{} {:.4}{star} | {} min | {} | {} |\n",
            r.label,
            fmt_list(&r.psnr, 2),
            fmt_list(&r.ssim, 4),
            lp,
            r.avg_error,
            fmt_minutes(r.train_seconds / 60.0),
            r.params,
            &r.commit[..r.commit.len().min(12)]
        );
    }
    if !missing.is_empty() {
        s += &format!("\nNot run yet: {}.\n", missing.join(", "));
    }
    // The chart is linked where the table sits beside it.
    let beside = exp.table.parent() == Some(exp.results.as_path());
    s += &marks_markdown(&results, (&exp.rows, &chart_name(&exp.table)), beside, n)?;
    if two_term {
        s += "\n\\* Without LPIPS: the two-term average error (MSE and sqrt(1 - SSIM)), not the paper's.\n";
    }
    let paper_path = dir.join(PAPER_TOML);
    if paper_path.is_file() {
        let p: Paper = read_toml(&paper_path)?;
        s += &format!("\n**The paper's** ({}):\n\n{head} params |\n{rule}---|\n", p.source);
        for id in &exp.rows {
            let Some(r) = p.row.iter().find(|r| &r.id == id) else { continue };
            let label = read_toml::<Row>(&dir.join(format!("{id}.toml")))?.label;
            s += &format!(
                "| {label} |{}{}{} {:.4} | {} |\n",
                fmt_list(&r.psnr, 3),
                fmt_list(&r.ssim, 4),
                fmt_list(&r.lpips, 4),
                r.avg_error,
                r.params
            );
        }
    }
    s += END;
    Ok(s)
}

/// The chart of a table's rows, named after the table so that experiments sharing a results
/// folder keep theirs: `psnr-vs-time.png` for `TABLE.md`, `psnr-vs-time-whole-scene.png` for
/// `TABLE-whole-scene.md`, `psnr-vs-time-NAME.png` for any other `NAME.md`.
fn chart_name(table: &Path) -> String {
    let stem = table.file_stem().and_then(|s| s.to_str()).unwrap_or("TABLE");
    let suffix = match stem.strip_prefix("TABLE") {
        Some(rest) => rest.to_owned(),
        None => format!("-{stem}"),
    };
    format!("psnr-vs-time{suffix}.png")
}

/// The rows that were evaluated at fixed training times: a table of every mark (and the final
/// checkpoint), and `RESULTS/CHART` ([`chart_name`]) of mean PSNR against minutes. Empty when no
/// row has marks.
fn marks_markdown(results: &Path, (rows, chart): (&[String], &str), link_chart: bool, scales: usize) -> Result<String> {
    let mut curves = Vec::new();
    let mut s = String::new();
    for id in rows {
        let Ok(text) = std::fs::read_to_string(results.join(format!("{id}.json"))) else { continue };
        let r: RowResult = serde_json::from_str(&text)?;
        if r.marks.is_empty() {
            continue;
        }
        if s.is_empty() {
            let which = if scales == 1 { "one scale".to_owned() } else { format!("{scales} scales") };
            s += &format!(
                "\n**At fixed training times** (test split, {which}; evaluation time not counted):\n\n\
                 | row | minutes | steps |{} mean PSNR | mean SSIM | mean LPIPS |\n|---|---|---|{}---|---|---|\n",
                metric_heads("PSNR", scales),
                "---|".repeat(scales)
            );
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let mut pts = Vec::new();
        let finals = (r.train_seconds, r.steps, r.psnr.clone(), r.ssim.clone(), r.lpips.clone());
        let marks = r.marks.iter().map(|m| (m.train_seconds, m.steps, m.psnr.clone(), m.ssim.clone(), m.lpips.clone()));
        for (secs, steps, psnr, ssim, lpips) in marks.chain(std::iter::once(finals)) {
            let lp = lpips.as_deref().map_or_else(|| "n/a".to_string(), |l| format!("{:.4}", mean(l)));
            s += &format!(
                "| {} | {:.1} | {steps} |{} {:.2} | {:.4} | {lp} |\n",
                r.label,
                secs / 60.0,
                fmt_list(&psnr, 2),
                mean(&psnr),
                mean(&ssim)
            );
            pts.push((secs / 60.0, mean(&psnr)));
        }
        curves.push((r.label.clone(), pts));
    }
    if curves.is_empty() {
        return Ok(s);
    }
    let png = results.join(chart);
    crate::plot::quality_vs_time(&png, &curves, scales, None)?;
    if link_chart {
        s += &format!("\n![Mean test PSNR against training time]({chart})\n");
    } else {
        s += &format!("\nChart: {}\n", png.display());
    }
    Ok(s)
}

/// Rebuilds the generated block of `exp.table` (creating the file, or appending the block, when
/// there is none); the rest of the file is kept.
fn write_table(dir: &Path, exp: &Experiment) -> Result<PathBuf> {
    let path = dir.join(&exp.table);
    let block = table_markdown(dir, exp)?;
    let old = std::fs::read_to_string(&path).unwrap_or_else(|_| format!("# {}\n\n", exp.title));
    let new = match (old.find(BEGIN), old.find(END)) {
        (Some(a), Some(b)) if b > a => format!("{}{block}{}", &old[..a], &old[b + END.len()..]),
        _ => format!("{old}\n{block}\n"),
    };
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).with_context(|| parent.display().to_string())?;
    }
    std::fs::write(&path, new).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// The test split's scores of a row's run (or snapshot) on the backend it trained on.
fn evaluate(
    run_dir: &Path,
    saved: &TrainSettings,
    (lpips, eval_backend): (&LpipsWeights, Option<crate::config::Backend>),
    session: &Session,
) -> Result<crate::scores::Metrics> {
    let backend = eval_backend.or(saved.backend).unwrap_or(crate::config::Backend::Cpu);
    let device = mipnerf_gpu::DeviceOptions::default();
    crate::eval::eval(
        run_dir,
        Split::Test,
        crate::run::RunOn { backend, precision: None, device: &device },
        lpips,
        session,
    )
}

#[cfg(test)]
mod tests {
    use super::chart_name;
    use std::path::Path;

    #[test]
    fn each_table_of_a_results_folder_has_its_own_chart() {
        assert_eq!(chart_name(Path::new("../../docs/results/x/TABLE.md")), "psnr-vs-time.png");
        assert_eq!(chart_name(Path::new("../../docs/results/x/TABLE-whole-scene.md")), "psnr-vs-time-whole-scene.png");
        assert_eq!(chart_name(Path::new("RESULTS.md")), "psnr-vs-time-RESULTS.png");
    }
}
