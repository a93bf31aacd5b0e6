//! Lens undistortion against COLMAP itself: the real pycolmap reconstructions of
//! tests/data/colmap_workspaces (one per camera model, made by scripts/data/make-colmap-workspaces.sh
//! from 40 lego photos passed through a known lens distortion) with pycolmap's own
//! `img_from_cam` / `cam_from_img` on a grid and COLMAP's undistortion of three photos.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::cast_possible_truncation, missing_docs)]
use std::path::{Path, PathBuf};

use mipnerf_data::colmap::{self, ColmapCamera};
use mipnerf_data::undistort::{self, Distortion, LensCamera};
use proptest::prelude::*;

/// pycolmap computes in f64 with the same formulas; the iterative inverse stops at steps below
/// 1e-10 (normalised units), so both agree far below a thousandth of a pixel.
const PIXEL_TOLERANCE: f64 = 1e-6;
/// Normalised coordinates: the inverse's stopping step, with margin.
const NORMALISED_TOLERANCE: f64 = 1e-8;
/// COLMAP's warp samples bilinearly in f32 and casts to 8 bits; this one in f64 and rounds, so the
/// two may differ by a level where a value lies near .5 (compared on the photo as COLMAP decoded
/// it, `reference/*.decoded.png`: JPEG decoders differ by a level or two at some pixels).
const MAX_LEVEL_DIFFERENCE: i32 = 1;
/// ... and the share of channel values that differ at all (seen: at most 1 in 10^5).
const SHARE_DIFFERENT: f64 = 0.001;

fn workspaces() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/colmap_workspaces");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&root)
        .expect("tests/data/colmap_workspaces")
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    v.sort();
    v
}

struct Golden {
    model: String,
    camera: ColmapCamera,
    normalised: Vec<[f64; 2]>,
    img_from_cam: Vec<[f64; 2]>,
    pixels: Vec<[f64; 2]>,
    cam_from_img: Vec<[f64; 2]>,
    undistorted: LensCamera,
    images: Vec<String>,
}

fn pairs(v: &serde_json::Value) -> Vec<[f64; 2]> {
    v.as_array().unwrap().iter().map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()]).collect()
}

fn golden(ws: &Path) -> Golden {
    let text = std::fs::read_to_string(ws.join("camera_golden.json")).unwrap();
    let j: serde_json::Value = serde_json::from_str(&text).unwrap();
    let model = j["model"].as_str().unwrap().to_owned();
    let id =
        ["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"].iter().position(|m| *m == model).unwrap();
    let params: Vec<f64> = j["params"].as_array().unwrap().iter().map(|p| p.as_f64().unwrap()).collect();
    let camera = ColmapCamera {
        id: 1,
        model_id: id as i32,
        width: j["width"].as_u64().unwrap(),
        height: j["height"].as_u64().unwrap(),
        params,
    };
    let u = &j["undistorted_camera"];
    assert_eq!(u["model"], "PINHOLE");
    let p: Vec<f64> = u["params"].as_array().unwrap().iter().map(|p| p.as_f64().unwrap()).collect();
    Golden {
        model,
        camera,
        normalised: pairs(&j["normalised"]),
        img_from_cam: pairs(&j["img_from_cam"]),
        pixels: pairs(&j["pixels"]),
        cam_from_img: pairs(&j["cam_from_img"]),
        undistorted: LensCamera {
            fx: p[0],
            fy: p[1],
            cx: p[2],
            cy: p[3],
            width: u["width"].as_u64().unwrap() as u32,
            height: u["height"].as_u64().unwrap() as u32,
            distortion: Distortion::None,
        },
        images: j["undistorted_images"].as_array().unwrap().iter().map(|n| n.as_str().unwrap().to_owned()).collect(),
    }
}

fn read_rgb(path: &Path) -> (u32, u32, Vec<u8>) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb8();
    (img.width(), img.height(), img.into_raw())
}

#[test]
fn every_camera_model_has_a_real_reconstruction() {
    let models: Vec<String> = workspaces().iter().map(|w| golden(w).model).collect();
    assert_eq!(models, ["OPENCV", "RADIAL", "SIMPLE_RADIAL"], "one fixture per camera model that needs undistortion");
    for ws in workspaces() {
        // Real mapper output: the model the camera came from is in the workspace.
        let models = colmap::list_models(&ws).unwrap();
        assert!(models.iter().any(|(_, _, c)| *c >= 25), "{}: {models:?}", ws.display());
    }
}

#[test]
fn projection_and_its_inverse_match_pycolmap_for_every_camera_model() {
    let mut bad = Vec::new();
    for ws in workspaces() {
        let g = golden(&ws);
        let lens = LensCamera::from_colmap(&g.camera).unwrap();
        assert_ne!(lens.distortion, Distortion::None, "{}: the fixture's lens is distorted", g.model);
        for (n, want) in g.normalised.iter().zip(&g.img_from_cam) {
            let got = lens.img_from_cam(n[0], n[1]);
            if (got.0 - want[0]).abs() > PIXEL_TOLERANCE || (got.1 - want[1]).abs() > PIXEL_TOLERANCE {
                bad.push(format!("{} img_from_cam{n:?}: {got:?}, pycolmap {want:?}", g.model));
            }
        }
        for (p, want) in g.pixels.iter().zip(&g.cam_from_img) {
            let got = lens.cam_from_img(p[0], p[1]);
            if (got.0 - want[0]).abs() > NORMALISED_TOLERANCE || (got.1 - want[1]).abs() > NORMALISED_TOLERANCE {
                bad.push(format!("{} cam_from_img{p:?}: {got:?}, pycolmap {want:?}", g.model));
            }
        }
    }
    assert!(bad.is_empty(), "{} mismatches:\n{}", bad.len(), bad.join("\n"));
}

#[test]
fn warping_into_colmaps_undistorted_camera_reproduces_colmaps_images() {
    let mut report = Vec::new();
    let mut bad = Vec::new();
    for ws in workspaces() {
        let g = golden(&ws);
        let lens = LensCamera::from_colmap(&g.camera).unwrap();
        for name in &g.images {
            let stem = Path::new(name).file_stem().unwrap().to_str().unwrap();
            let (w, h, photo) = read_rgb(&ws.join("reference").join(format!("{stem}.decoded.png")));
            assert_eq!((w, h), (lens.width, lens.height));
            let (rw, rh, reference) = read_rgb(&ws.join("reference").join(format!("{stem}.png")));
            assert_eq!((rw, rh), (g.undistorted.width, g.undistorted.height));
            let ours = undistort::warp(&photo, 3, &lens, &g.undistorted);
            let diffs: Vec<i32> =
                ours.iter().zip(&reference).map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs()).collect();
            let max = *diffs.iter().max().unwrap();
            let share = diffs.iter().filter(|&&d| d > 0).count() as f64 / diffs.len() as f64;
            report.push(format!("{} {name}: max {max}, share different {share:.5}", g.model));
            if max > MAX_LEVEL_DIFFERENCE || share > SHARE_DIFFERENT {
                bad.push(format!(
                    "{} {name}: max {max} (at most {MAX_LEVEL_DIFFERENCE}), share different {share:.5} (at most \
                     {SHARE_DIFFERENT})",
                    g.model
                ));
            }
        }
    }
    println!("{}", report.join("\n"));
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

/// The chosen pinhole sees only inside the photo, and is the largest centred one that does:
/// two pixels more along either axis would see outside.
fn check_no_blank_and_largest(lens: &LensCamera) -> Result<(), String> {
    let p = undistort::undistorted_pinhole(lens);
    let inside = |t: &LensCamera| -> bool {
        (0..t.height).all(|y| {
            (0..t.width).all(|x| {
                let (u, v) = t.cam_from_img(f64::from(x) + 0.5, f64::from(y) + 0.5);
                let (px, py) = lens.img_from_cam(u, v);
                px >= 0.5 - 1e-9
                    && py >= 0.5 - 1e-9
                    && px <= f64::from(lens.width) - 0.5 + 1e-9
                    && py <= f64::from(lens.height) - 0.5 + 1e-9
            })
        })
    };
    let t = LensCamera::from(p);
    if !inside(&t) {
        return Err(format!("{lens:?}: {p:?} sees outside the photo"));
    }
    let scale_limited = |n: u32, orig: u32| n == orig * 2 || n == (f64::from(orig) * 0.2).ceil() as u32;
    let wider = LensCamera::from(undistort::Pinhole { width: p.width + 2, ..p });
    let taller = LensCamera::from(undistort::Pinhole { height: p.height + 2, ..p });
    if inside(&wider) && !scale_limited(p.width, lens.width) {
        return Err(format!("{lens:?}: {p:?} is not the widest"));
    }
    if inside(&taller) && !scale_limited(p.height, lens.height) {
        return Err(format!("{lens:?}: {p:?} is not the tallest"));
    }
    Ok(())
}

#[test]
fn the_undistorted_pinhole_is_the_largest_without_blank_pixels() {
    let mut lenses: Vec<LensCamera> =
        workspaces().iter().map(|w| LensCamera::from_colmap(&golden(w).camera).unwrap()).collect();
    let base =
        LensCamera { fx: 300.0, fy: 300.0, cx: 100.0, cy: 75.0, width: 200, height: 150, distortion: Distortion::None };
    lenses.push(base);
    lenses.push(LensCamera { cx: 104.0, ..base });
    lenses.push(LensCamera { distortion: Distortion::SimpleRadial { k: -0.3 }, ..base });
    lenses.push(LensCamera { distortion: Distortion::SimpleRadial { k: 0.25 }, ..base });
    lenses.push(LensCamera { distortion: Distortion::Radial { k1: -0.2, k2: 0.1 }, ..base });
    lenses.push(LensCamera {
        fy: 310.0,
        cx: 97.0,
        cy: 78.0,
        distortion: Distortion::Opencv { k1: -0.15, k2: 0.03, p1: 0.004, p2: -0.003 },
        ..base
    });
    let bad: Vec<String> = lenses.iter().filter_map(|l| check_no_blank_and_largest(l).err()).collect();
    assert!(bad.is_empty(), "{}", bad.join("\n"));
    // A pinhole photo whose principal point is central passes through at its own size.
    assert_eq!(undistort::undistorted_pinhole(&base), undistort::Pinhole { focal: 300.0, width: 200, height: 150 });
}

#[test]
fn unsupported_models_are_named() {
    let c = ColmapCamera { id: 3, model_id: 5, width: 10, height: 10, params: vec![1.0; 8] };
    let e = LensCamera::from_colmap(&c).unwrap_err();
    assert!(e.contains("camera 3 is OPENCV_FISHEYE") && e.contains("SIMPLE_RADIAL, RADIAL, OPENCV"), "{e}");
    let c = ColmapCamera { id: 1, model_id: 2, width: 10, height: 10, params: vec![1.0; 3] };
    let e = LensCamera::from_colmap(&c).unwrap_err();
    assert!(e.contains("3 parameters, the model has 4"), "{e}");
    let c = ColmapCamera { id: 1, model_id: 1, width: 10, height: 10, params: vec![-1.0, 1.0, 5.0, 5.0] };
    assert!(LensCamera::from_colmap(&c).unwrap_err().contains("must be positive"));
}

proptest! {
    /// The inverse undoes the distortion inside the field of view of real lenses.
    #[test]
    fn undistort_inverts_distort(
        u in -0.6f64..0.6, v in -0.6f64..0.6,
        k1 in -0.3f64..0.3, k2 in -0.05f64..0.05, p1 in -0.005f64..0.005, p2 in -0.005f64..0.005,
    ) {
        for d in [
            Distortion::SimpleRadial { k: k1 },
            Distortion::Radial { k1, k2 },
            Distortion::Opencv { k1, k2, p1, p2 },
        ] {
            let (x, y) = d.distort(u, v);
            let (bu, bv) = d.undistort(x, y);
            prop_assert!((bu - u).abs() < NORMALISED_TOLERANCE && (bv - v).abs() < NORMALISED_TOLERANCE,
                "{d:?}: ({u}, {v}) -> ({x}, {y}) -> ({bu}, {bv})");
        }
    }
}
