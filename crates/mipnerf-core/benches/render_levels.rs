//! Rendering every level against the last level alone (`Levels::Last`, which runs the coarse
//! level's MLP only to its density), alternated in one process so that the machine's drift falls
//! on both alike: `cargo bench -p mipnerf-core --bench render_levels [-- --preset fast|small|paper]`.
//!
//! 4096 rays of [`synthetic_rays`] (a 64x64 camera 4 units out, looking at the origin; no
//! occupancy grid: every ray runs the MLP), the preset's model at f32 with initial parameters, on the rayon pool. Prints the
//! rays per second of each, the medians of 15 rounds, and their ratio.
#![allow(missing_docs)]

use std::time::Instant;

use mipnerf_core::bench::synthetic_rays;
use mipnerf_core::model::{Levels, Model, Preset};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick") || !args.iter().any(|a| a == "--bench");
    let preset = match args.iter().position(|a| a == "--preset").and_then(|i| args.get(i + 1)).map(String::as_str) {
        Some("small") => Preset::Small,
        Some("paper") => Preset::Paper,
        _ => Preset::Fast,
    };
    let (n, rounds) = if quick { (128, 1) } else { (4096, 15) };
    let model = Model::new(preset.config()).expect("a preset's model");
    let params = model.init_params(0);
    let rays = synthetic_rays(n);
    let mut rates = [Vec::new(), Vec::new()];
    for _ in 0..rounds {
        for (k, levels) in [Levels::All, Levels::Last].into_iter().enumerate() {
            let start = Instant::now();
            let out = model.render_levels(&params, &rays, None, levels);
            rates[k].push(n as f64 / start.elapsed().as_secs_f64());
            assert!(out.iter().all(|o| o.rgb.iter().all(|c| c.is_finite())), "a non-finite colour");
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (all, last) = (median(&mut rates[0]), median(&mut rates[1]));
    println!("{preset:?} preset, {n} rays, {} threads, median of {rounds}:", rayon::current_num_threads());
    println!("| levels | rays/s |\n|---|---|\n| all | {all:.0} |\n| last alone | {last:.0} |");
    println!("last alone / all: {:.3}x", last / all);
}
