//! The cast and IPE of one chunk's samples on one thread, at each precision's IPE:
//! `cargo bench -p mipnerf-core --bench ipe`.
//!
//! 64 rays x 128 samples through `stages::cast_and_encode` (conical frustums, degrees 0..16: the
//! paper's), the f32 reference IPE (sines through `f64`, `exp` from libm) and the bf16 one (`f32`
//! polynomials). Prints nanoseconds per sample, the median of the repetitions: a regression of
//! the loops' vectorisation (see `mip.rs`'s `IPE_BLOCK`) shows here as a several-fold slowdown.
#![allow(missing_docs)]

use std::time::Instant;

use glam::Vec3;
use mipnerf_core::bf16::Precision;
use mipnerf_core::cone::{Ray, RayShape};
use mipnerf_core::config::PointEncoding;
use mipnerf_core::mip::ipe_len;
use mipnerf_core::stages::{CastIpe, cast_and_encode};

fn main() {
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let (rays, samples, reps) = if quick { (4, 16, 1) } else { (64, 128, 31) };
    let (min_deg, max_deg) = (0, 16);
    // Rays from a camera 4 units out, fanning over a 40-degree field, pixel footprints of a 256 px
    // image: samples from near 2 to far 6 through the unit cube, as in the Blender scenes.
    let ray = |i: usize| {
        let a = i as f32 / rays as f32 - 0.5;
        let direction = Vec3::new(0.7 * a, 0.3 * a, -1.0);
        Ray {
            origin: Vec3::new(0.1, -0.2, 4.0),
            direction,
            viewdir: direction.normalize(),
            radius: 0.7 / 256.0 * 2.0 / 12f32.sqrt(),
            lossmult: 1.0,
            near: 2.0,
            far: 6.0,
        }
    };
    let rays: Vec<Ray> = (0..rays).map(ray).collect();
    let t: Vec<f32> = rays
        .iter()
        .flat_map(|r| (0..=samples).map(move |j| r.near + (r.far - r.near) * j as f32 / samples as f32))
        .collect();
    let mut x = vec![0.0f32; rays.len() * samples * ipe_len(min_deg, max_deg)];
    println!(
        "cast and IPE (degrees {min_deg}..{max_deg}) of {} samples on one thread, median of {reps}:",
        rays.len() * samples
    );
    println!("| precision | ns per sample |");
    println!("|---|---|");
    for precision in [Precision::F32, Precision::Bf16] {
        let mut times: Vec<f64> = (0..reps)
            .map(|_| {
                let start = Instant::now();
                let stage = CastIpe {
                    n_samples: samples,
                    shape: RayShape::Cone,
                    unbounded: false,
                    encoding: PointEncoding::Integrated,
                    min_deg,
                    max_deg,
                };
                cast_and_encode(&rays, &t, stage, precision, &mut x);
                std::hint::black_box(&x);
                start.elapsed().as_secs_f64() / (rays.len() * samples) as f64 * 1e9
            })
            .collect();
        times.sort_by(f64::total_cmp);
        assert!(x.iter().all(|v| v.is_finite() && v.abs() <= 1.0), "features outside [-1, 1]");
        println!("| {precision} | {:.1} |", times[times.len() / 2]);
    }
}
