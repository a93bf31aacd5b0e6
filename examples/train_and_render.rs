//! Trains a model of the built-in demo scene for a few hundred steps (or a few seconds) and
//! renders a view no training image shows, through the library alone (`mipnerf::Nerf`):
//!
//! ```text
//! cargo run --release --example train_and_render -- [STEPS | SECONDSs] [OUT.png]
//! ```
//!
//! `300` trains 300 steps (the default), `20s` for 20 seconds (`Nerf::train_for`). The test
//! command runs it (`cargo test` runs its `main`) with the default steps, so it stays an example
//! that works whatever the machine's speed. It prints the novel view's PSNR against the demo
//! scene's own render of it and saves the picture (by default `novel-view.png` in the system's
//! temporary folder).

use std::time::Duration;

use mipnerf::{Camera, Device, Nerf, Options, Pixels, View, demo};

/// Steps the example trains where it is not told.
const DEFAULT_STEPS: u64 = 300;

/// The least a novel view may score after [`DEFAULT_STEPS`] (an untrained model's is about 9 dB).
const MIN_NOVEL_VIEW_PSNR: f64 = 15.0;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let budget = args.next().unwrap_or_else(|| DEFAULT_STEPS.to_string());
    let out = args.next().map_or_else(|| std::env::temp_dir().join("novel-view.png"), Into::into);

    // Twelve 32x32 views around the scene, straight RGBA with camera-to-world poses.
    let mut views = Vec::new();
    for (i, pose) in demo::view_poses(12, 0.0).into_iter().enumerate() {
        let camera = Camera::from_camera_angle_x(32, 32, 0.69, pose)?;
        let pixels = Pixels::RgbaF32(demo::render_view(&camera, 1));
        views.push(View::in_memory(&format!("view {i}"), camera, pixels, 2.0, 6.0));
    }
    // The default options: the fast preset, sized for a CPU. On the CPU here, so that the
    // example's time is the same on every machine; `Device::Auto` takes a hardware GPU.
    let mut nerf = Nerf::from_views(views, Options::default().with_device(Device::Cpu))?;
    let started = std::time::Instant::now();
    let report = match budget.strip_suffix('s') {
        Some(seconds) => nerf.train_for(Duration::from_secs_f64(seconds.parse()?))?,
        None => nerf.train(budget.parse()?)?,
    };
    println!(
        "{} steps in {:.1} s on {} ({:?}): training PSNR {:.1} dB",
        nerf.step(),
        started.elapsed().as_secs_f64(),
        nerf.device(),
        nerf.precision(),
        report.stats.psnr()
    );

    // A pose between the training views, higher up: no training image shows it.
    let camera = Camera::from_camera_angle_x(64, 64, 0.69, demo::camera_pose(0.3, 0.5))?;
    let picture = nerf.render(&camera)?.to_rgb_image()?;
    let truth = demo::render_view(&camera, 4);
    // The demo's RGBA composited on white, as the training images were.
    let mse = picture
        .pixels()
        .zip(truth.chunks_exact(4))
        .flat_map(|(p, t)| (0..3).map(move |k| (f32::from(p[k]) / 255.0, t[k] * t[3] + 1.0 - t[3])))
        .map(|(a, b)| f64::from(a - b).powi(2))
        .sum::<f64>()
        / (3.0 * f64::from(picture.width() * picture.height()));
    let psnr = -10.0 * mse.log10();
    println!("novel view: PSNR {psnr:.1} dB against the scene's own render");
    picture.save(&out)?;
    println!("saved {}", out.display());
    if nerf.step() >= DEFAULT_STEPS && psnr < MIN_NOVEL_VIEW_PSNR {
        return Err(format!(
            "the novel view scores {psnr:.1} dB, under {MIN_NOVEL_VIEW_PSNR}: the model learnt too little"
        )
        .into());
    }
    Ok(())
}
