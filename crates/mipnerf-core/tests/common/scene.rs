//! A tiny analytic scene for training tests: a coloured ball on white, seen by cameras on a ring.
#![allow(dead_code, clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::render::{self, volumetric_rendering};
use mipnerf_core::{Camera, PixelCenters, Ray};

pub const BALL_RADIUS: f32 = 0.8;

fn field(p: Vec3) -> (f32, [f32; 3]) {
    let inside = p.length() < BALL_RADIUS;
    let rgb = [0.5 + 0.5 * (p.x / BALL_RADIUS), 0.3, 0.5 - 0.5 * (p.z / BALL_RADIUS)];
    (if inside { 30.0 } else { 0.0 }, rgb.map(|c| c.clamp(0.0, 1.0)))
}

/// Rays and ground-truth colours of `views` cameras of `size x size` pixels.
pub fn ball_scene(views: usize, size: u32) -> (Vec<Ray>, Vec<[f32; 3]>) {
    let mut rays = Vec::new();
    let mut colours = Vec::new();
    for v in 0..views {
        let a = v as f64 / views as f64 * std::f64::consts::TAU;
        let (s, c) = a.sin_cos();
        let pos = [3.0 * c, 3.0 * s, 1.0];
        // Look at the origin: back = normalised position.
        let back = Vec3::new(pos[0] as f32, pos[1] as f32, pos[2] as f32).normalize();
        let right = Vec3::Z.cross(back).normalize();
        let up = back.cross(right);
        let m = |k: usize| [right[k] as f64, up[k] as f64, back[k] as f64, pos[k]];
        let cam = Camera::from_camera_angle_x(size, size, 0.8, [m(0), m(1), m(2)]).unwrap();
        for ray in cam.generate_rays(PixelCenters::Centered, 1.5, 4.5, 1.0) {
            let n = 512;
            let t: Vec<f32> = (0..=n).map(|i| ray.near + (ray.far - ray.near) * i as f32 / n as f32).collect();
            let (density, rgb): (Vec<f32>, Vec<[f32; 3]>) =
                (0..n).map(|i| field(ray.origin + ray.direction * 0.5 * (t[i] + t[i + 1]))).unzip();
            let mut w = vec![0.0; n];
            colours.push(volumetric_rendering(&rgb, &density, &t, ray.direction, render::background(true), &mut w).rgb);
            rays.push(ray);
        }
    }
    (rays, colours)
}
