//! PSNR and SSIM against the official `math.py` (`metrics.json`).
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;
use mipnerf_core::metrics::{SsimConfig, mse_to_psnr, psnr_to_mse, ssim, ssim_map};
use mipnerf_core::test_support::{Mismatches, TOL_ELEMENTWISE, f, flat, golden};

/// SSIM is computed in f64 here and in f32 by XLA (its eager and jitted results differ by 2 ulp).
const TOL_SSIM: Tol = Tol { rel: 1e-5, abs: 2e-6 };

#[test]
fn ssim_matches_official() {
    let g = golden("metrics.json");
    let mut mm = Mismatches::default();
    for pair in ["independent", "noisy_copy", "identical"] {
        let p = &g["compute_ssim"]["pairs"][pair];
        let (a, b) = (flat(&p["img0"]), flat(&p["img1"]));
        let cfg = SsimConfig::default();
        let map: Vec<f32> = ssim_map(&a, &b, 16, 16, 3, &cfg).iter().map(|&x| x as f32).collect();
        mm.check(&format!("{pair} map"), &map, &flat(&p["ssim_map_eager"]), TOL_SSIM);
        mm.check(&format!("{pair} ssim"), &[ssim(&a, &b, 16, 16, 3, &cfg) as f32], &[f(&p["ssim_eager"])], TOL_SSIM);
        let mse = a.iter().zip(&b).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>() / a.len() as f64;
        mm.check(&format!("{pair} mse"), &[mse as f32], &[f(&p["mse_mean"])], TOL_ACCUMULATED);
        mm.check(&format!("{pair} psnr"), &[mse_to_psnr(mse as f32)], &[f(&p["psnr_of_that_mse"])], TOL_ACCUMULATED);
    }
    mm.finish("ssim_matches_official");
}

#[test]
fn psnr_conversions_match_official() {
    let g = golden("metrics.json");
    let mut mm = Mismatches::default();
    let m = &g["mse_to_psnr"];
    let got: Vec<f32> = flat(&m["mse"]).iter().map(|&x| mse_to_psnr(x)).collect();
    mm.check("mse_to_psnr", &got, &flat(&m["psnr"]), TOL_ELEMENTWISE);
    let p = &g["psnr_to_mse"];
    let got: Vec<f32> = flat(&p["psnr"]).iter().map(|&x| psnr_to_mse(x)).collect();
    mm.check("psnr_to_mse", &got, &flat(&p["mse"]), TOL_ELEMENTWISE);
    mm.finish("psnr_conversions_match_official");
}
