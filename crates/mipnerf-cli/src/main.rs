//! The `mipnerf` command-line tool.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};

/// Anti-aliased neural radiance fields (Mip-NeRF) on any GPU through wgpu, and on the CPU.
#[derive(Parser, Debug)]
#[command(name = "mipnerf", version, about, long_about = None, after_help = "Examples:\n  mipnerf info\n  mipnerf check --backend auto")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Where the heavy passes run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Backend {
    /// The CPU path (always available).
    Cpu,
    /// A GPU through wgpu (a hardware GPU or a software Vulkan adapter such as lavapipe).
    Gpu,
    /// A hardware GPU if one is present, else the CPU.
    Auto,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print the version, every GPU adapter found, and the backend `--backend auto` would choose.
    Info,
    /// Run the GPU kernels on a small synthetic camera and compare them with the CPU reference.
    Check {
        /// Which backend to check; `auto` checks the GPU only if a hardware one is present.
        #[arg(long, value_enum, default_value_t = Backend::Gpu)]
        backend: Backend,
    },
}

fn auto_choice(adapters: &[mipnerf_gpu::AdapterSummary]) -> String {
    match adapters.iter().find(|a| !a.is_software) {
        Some(a) => format!("gpu ({}, {})", a.name, a.backend),
        None => "cpu (no hardware GPU found; software adapters are slower than the CPU path)".to_string(),
    }
}

fn info() {
    println!("mipnerf {}", env!("CARGO_PKG_VERSION"));
    let adapters = mipnerf_gpu::list_adapters();
    if adapters.is_empty() {
        println!("GPU adapters: none found (install a Vulkan driver, e.g. scripts/ensure-vulkan.sh)");
    } else {
        println!("GPU adapters ({}):", adapters.len());
        for a in &adapters {
            println!("  - {} | backend {} | type {} | driver {}", a.name, a.backend, a.device_type, a.driver);
        }
    }
    println!("--backend auto would use: {}", auto_choice(&adapters));
}

fn check(backend: Backend) -> Result<()> {
    use mipnerf_core::mip::{self, Gaussian, RayShape};
    let choice = match backend {
        Backend::Cpu => {
            println!("the CPU backend is the reference; nothing to compare it with");
            return Ok(());
        }
        Backend::Gpu => mipnerf_gpu::AdapterChoice::Any,
        Backend::Auto => mipnerf_gpu::AdapterChoice::HardwareOnly,
    };
    let ctx = match mipnerf_gpu::GpuContext::new(choice) {
        Ok(c) => c,
        Err(e) if backend == Backend::Auto => {
            println!("auto: {e}; the CPU backend would be used");
            return Ok(());
        }
        Err(e) => return Err(e).context("opening the GPU"),
    };
    println!("checking on {} ({}, {})", ctx.adapter.name, ctx.adapter.backend, ctx.adapter.device_type);
    let c2w = [[0.8, 0.0, 0.6, 2.4], [0.36, 0.8, -0.48, -1.92], [-0.48, 0.6, 0.64, 2.56]];
    let cam = mipnerf_core::Camera::from_camera_angle_x(32, 32, 0.69, c2w)?;
    let rays = cam.generate_rays(mipnerf_core::PixelCenters::Centered, 2.0, 6.0, 1.0);
    let n = 32usize;
    let mut t = vec![0.0; rays.len() * (n + 1)];
    for (r, chunk) in t.chunks_mut(n + 1).enumerate() {
        mipnerf_core::sample_along_rays(rays[r].near, rays[r].far, false, None, chunk);
    }
    let kernel = mipnerf_gpu::kernels::cast_ipe::CastIpeKernel::new(&ctx)?;
    let gpu = kernel.run(&ctx, &rays, &t, n as u32, RayShape::Cone, 0, 16)?;
    let len = mip::ipe_len(0, 16);
    let mut gs = vec![Gaussian::default(); n];
    let mut enc = vec![0.0; len];
    let mut max = 0.0f32;
    for (r, ray) in rays.iter().enumerate() {
        mip::cast_ray(
            &t[r * (n + 1)..(r + 1) * (n + 1)],
            ray.origin,
            ray.direction,
            ray.radius,
            RayShape::Cone,
            &mut gs,
        );
        for (s, g) in gs.iter().enumerate() {
            mip::integrated_pos_enc(g, 0, 16, &mut enc);
            let off = (r * n + s) * len;
            for (a, b) in gpu[off..off + len].iter().zip(&enc) {
                let diff = if a.is_nan() { f32::INFINITY } else { (a - b).abs() };
                max = max.max(diff);
            }
        }
    }
    println!("cast_ipe: {} features, max |gpu - cpu| = {max:e}", gpu.len());
    anyhow::ensure!(max <= 1e-4, "the GPU's IPE features differ from the CPU reference by {max:e} (> 1e-4)");
    println!("ok");
    Ok(())
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info => {
            info();
            Ok(())
        }
        Command::Check { backend } => check(backend),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
