//! `mipnerf bench`: training and rendering speed of the backends here, or the live viewer's.

use std::path::PathBuf;

use anyhow::Result;

use crate::backend::DeviceArgs;
use crate::bench::{self, BenchBackends};
use crate::config::{Backend, FieldArg, PrecisionArg, PresetArg};
use crate::session::Session;
use crate::view_bench;

/// The flags of `mipnerf bench`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Which backends.
    #[arg(long, value_enum, default_value_t = BenchBackends::Both)]
    pub backend: BenchBackends,
    #[command(flatten)]
    pub device: DeviceArgs,
    /// Model sizes, one table section each (`small,paper`).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "tiny")]
    pub preset: Vec<PresetArg>,
    /// Fields, one row each (`mip-nerf,tri-mip`): the Tri-Mip ones with their recipe's planes and
    /// MLP (the CPU backend only, so far).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "mip-nerf")]
    pub field: Vec<FieldArg>,
    /// Rays (pixels) per training batch.
    #[arg(long, default_value_t = 1024)]
    pub batch_rays: usize,
    /// Timed training steps (after two untimed ones).
    #[arg(long, default_value_t = 10)]
    pub steps: usize,
    /// Side of the rendered square image, in pixels.
    #[arg(long, default_value_t = 64)]
    pub render_side: u32,
    /// Precisions to measure on the CPU backend, one row each (`f32,bf16`); a device backend
    /// runs f32 only.
    #[arg(long, value_enum, value_delimiter = ',', default_value = "f32")]
    pub precision: Vec<PrecisionArg>,
    /// Instead of the throughput table, measure the live viewer of this trained run: its
    /// frame latency (each level of the coarse-to-fine stream, over HTTP on loopback) and
    /// how much a viewer that streams without pause slows training (`train --view`).
    #[arg(long, value_name = "RUN_DIR")]
    pub viewer: Option<PathBuf>,
    /// With --viewer: the full frame's side in pixels (the page's default).
    #[arg(long, default_value_t = 512, requires = "viewer")]
    pub viewer_size: u32,
    /// With --viewer: camera poses timed.
    #[arg(long, default_value_t = 10, requires = "viewer")]
    pub viewer_frames: usize,
    /// With --viewer: training steps of each stall run, alone and beside the viewer (0:
    /// latency only).
    #[arg(long, default_value_t = 300, requires = "viewer")]
    pub viewer_stall_steps: u64,
}

/// Runs the throughput bench, or the viewer's with `--viewer`, and prints its table.
///
/// # Errors
/// No device, or a failure while measuring.
pub fn run(a: Args, session: &Session) -> Result<()> {
    if let Some(run) = a.viewer {
        let backend = match a.backend {
            BenchBackends::Gpu => Backend::Gpu,
            BenchBackends::Auto => Backend::Auto,
            BenchBackends::Cpu | BenchBackends::Both => Backend::Cpu,
        };
        let args = view_bench::ViewerBenchArgs {
            run,
            device: a.device.options(),
            backend,
            size: a.viewer_size,
            frames: a.viewer_frames,
            stall_steps: a.viewer_stall_steps,
        };
        return view_bench::bench(&args, session);
    }
    let args = bench::BenchArgs {
        device: a.device.options(),
        backends: a.backend,
        presets: a.preset,
        fields: a.field,
        batch: a.batch_rays,
        steps: a.steps,
        render_side: a.render_side,
        precisions: a.precision,
    };
    bench::bench(&args, session)
}
