//! Datasets: the official multiscale conversion, the Blender, multiscale and LLFF loaders, the demo
//! scene, ray batches, and a clear error for every kind of bad input.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use mipnerf_core::Camera;
use mipnerf_core::dataset::{BatchDraw, DataError, Dataset, Pixels, Split, View};
use mipnerf_core::demo;
use mipnerf_core::test_support::{Mismatches, TOL_ELEMENTWISE, f, flat, golden, mutate};
use mipnerf_data::{LoadOptions, llff, multiscale};

fn lego_tiny() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny")
}

#[test]
fn multiscale_conversion_matches_the_official_converter() {
    let g = golden("multiscale.json");
    let c = &g["convert_blender_data"];
    let inp = &c["inputs"];
    let bytes: Vec<u8> = flat(&inp["image_rgba_uint8_8x8"]).iter().map(|&x| x as u8).collect();
    let tm = inp["transform_matrix"].as_array().unwrap();
    let cam2world: [[f64; 4]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| tm[i][j].as_f64().unwrap()));
    let img = multiscale::SourceImage {
        width: 8,
        height: 8,
        rgba: bytes.iter().map(|&b| f32::from(b) / 255.0).collect(),
        cam2world,
    };
    let focal = mipnerf_core::camera::focal_from_camera_angle_x(8, inp["camera_angle_x"].as_f64().unwrap());
    let dir = tempfile::tempdir().unwrap();
    let n_down = inp["n_down"].as_u64().unwrap() as u32;
    let meta = multiscale::write_split(
        dir.path(),
        Split::Test,
        std::slice::from_ref(&img),
        multiscale::Scales { focal, n_scales: n_down, near: 2.0, far: 6.0 },
    )
    .unwrap();
    let mut mm = Mismatches::default();
    let (mut w, mut px) = (8usize, img.rgba.clone());
    for (j, level) in c["outputs"]["levels"].as_array().unwrap().iter().enumerate() {
        mm.check(
            &format!("level {j} float image"),
            &px,
            &flat(&level["image_float32_before_quantisation"]),
            TOL_ELEMENTWISE,
        );
        let (_, _, written) = {
            let p = dir.path().join(level["file_path"].as_str().unwrap());
            let im = image::open(&p).unwrap().to_rgba8();
            (im.width(), im.height(), im.into_raw())
        };
        let want: Vec<u8> = flat(&level["png_uint8_written"]).iter().map(|&x| x as u8).collect();
        assert_eq!(written, want, "level {j}: PNG bytes differ from the official converter's");
        for key in ["focal", "lossmult", "label", "near", "far", "width", "height"] {
            mm.check(
                &format!("level {j} {key}"),
                &[meta[key][j].as_f64().unwrap() as f32],
                &[f(&level[key])],
                TOL_ELEMENTWISE,
            );
        }
        mm.check(&format!("level {j} pix2cam"), &flat(&meta["pix2cam"][j]), &flat(&level["pix2cam"]), TOL_ELEMENTWISE);
        mm.check(
            &format!("level {j} cam2world"),
            &flat(&meta["cam2world"][j]),
            &flat(&level["cam2world"]),
            TOL_ELEMENTWISE,
        );
        assert_eq!(meta["file_path"][j], level["file_path"]);
        px = mipnerf_data::down2(&px, w, w);
        w /= 2;
    }
    mm.finish("multiscale_conversion_matches_the_official_converter");
}

#[test]
fn blender_scene_loads_with_cameras_and_composited_pixels() {
    let ds = mipnerf_data::load(&lego_tiny(), Split::Train, &LoadOptions::default()).unwrap();
    assert_eq!(ds.views().len(), 4);
    assert_eq!((ds.views()[0].camera.width, ds.views()[0].camera.height), (100, 100));
    assert_eq!(ds.num_pixels(), 4 * 100 * 100);
    // Corners are background: transparent, composited on white.
    assert_eq!(ds.target(0, 0, 0), [1.0, 1.0, 1.0]);
    let rays = ds.view_rays(0);
    assert_eq!(rays.len(), 10_000);
    assert!(
        rays.iter().all(|r| r.near == 2.0 && r.far == 6.0 && r.radius > 0.0 && (r.viewdir.length() - 1.0).abs() < 1e-5)
    );
    // Half resolution: 2x2 area filter.
    let half =
        mipnerf_data::load(&lego_tiny(), Split::Train, &LoadOptions { half_res: true, ..LoadOptions::default() })
            .unwrap();
    assert_eq!(half.views()[0].camera.width, 50);
    let (full, hv) = (&ds, &half);
    let avg: [f32; 3] =
        std::array::from_fn(|c| (0..4).map(|k| full.target(0, 60 + k % 2, 40 + k / 2)[c]).sum::<f32>() / 4.0);
    let got = hv.target(0, 30, 20);
    for c in 0..3 {
        assert!((avg[c] - got[c]).abs() < 2e-3, "half-res pixel {got:?} vs average {avg:?}");
    }
}

#[test]
fn the_real_lego_scene_loads() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/nerf_synthetic/lego");
    if !dir.join("transforms_train.json").is_file() {
        eprintln!("SKIPPED the_real_lego_scene_loads: {} is absent (it lives in ../shared)", dir.display());
        return;
    }
    let test = mipnerf_data::load(&dir, Split::Test, &LoadOptions::default()).unwrap();
    assert_eq!(test.views().len(), 13);
    assert_eq!((test.views()[0].camera.width, test.views()[0].camera.height), (800, 800));
    assert!(test.num_pixels() == 13 * 640_000);
    // A missing split is an error only when it is asked for.
    let err = mipnerf_data::load(&dir, Split::Val, &LoadOptions::default()).unwrap_err().to_string();
    assert!(err.contains("transforms_val.json"), "{err}");
}

#[test]
fn demo_scene_generates_every_scale_and_loads() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = mipnerf_data::demo::DemoConfig { size: 32, train_views: 6, test_views: 2, supersample: 3 };
    let t = std::time::Instant::now();
    mipnerf_data::demo::write_demo_scene(dir.path(), &cfg).unwrap();
    eprintln!("demo scene generated in {:?}", t.elapsed());
    assert_eq!(mipnerf_data::detect_format(dir.path()).unwrap(), mipnerf_data::Format::Multiscale);
    let train = mipnerf_data::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap();
    assert_eq!(train.views().len(), 6 * 4);
    assert_eq!(train.scales(), vec![0, 1, 2, 3]);
    for v in train.views() {
        assert_eq!(v.camera.width, 32 >> v.scale);
        assert_eq!(v.lossmult, 4f32.powi(v.scale as i32));
    }
    // Scale 1 is the 2x2 box filter of scale 0's straight RGBA (up to 8-bit quantisation).
    let (v0, v1) = (0, 1);
    assert_eq!(train.views()[v1].scale, 1);
    let px = |v: usize, x: usize, y: usize| train.views()[v].pixels.rgba(y * (32 >> train.views()[v].scale) + x);
    for y in 0..16 {
        for x in 0..16 {
            let fine: [f32; 4] =
                std::array::from_fn(|c| (0..4).map(|k| px(v0, 2 * x + k % 2, 2 * y + k / 2)[c]).sum::<f32>() / 4.0);
            let coarse = px(v1, x, y);
            for c in 0..4 {
                assert!((fine[c] - coarse[c]).abs() <= 2.0 / 255.0, "({x},{y}) {fine:?} vs {coarse:?}");
            }
        }
    }
    // The scene has fine detail: many distinct colours at full resolution.
    let mut colours: Vec<[u8; 3]> = train.view_targets(0).iter().map(|c| c.map(|x| (x * 255.0) as u8)).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(colours.len() > 100, "only {} distinct colours", colours.len());
    // The same rays every time.
    let ray = train.ray(3, 5, 7);
    assert_eq!(ray, train.ray(3, 5, 7));
}

/// The demo scene written at 16 px (3 training views, 4 scales each) and its training split
/// loaded; the folder lives as long as the first value.
fn small_demo_training_split() -> (tempfile::TempDir, Dataset) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = mipnerf_data::demo::DemoConfig { size: 16, train_views: 3, test_views: 1, supersample: 1 };
    mipnerf_data::demo::write_demo_scene(dir.path(), &cfg).unwrap();
    let ds = mipnerf_data::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap();
    (dir, ds)
}

#[test]
fn batches_come_from_every_scale_with_their_lossmult() {
    let (_dir, ds) = small_demo_training_split();
    let (mut rays, mut targets) = (Vec::new(), Vec::new());
    ds.sample_batch(BatchDraw::new(4000, 1, 0), &mut rays, &mut targets);
    assert_eq!((rays.len(), targets.len()), (4000, 4000));
    let mut seen = std::collections::BTreeMap::new();
    for r in &rays {
        *seen.entry(r.lossmult as u32).or_insert(0) += 1;
    }
    // Pixels per scale: 256, 64, 16, 4 per view; uniform over pixels.
    assert_eq!(seen.keys().copied().collect::<Vec<_>>(), vec![1, 4, 16, 64], "{seen:?}");
    let frac0 = f64::from(seen[&1]) / 4000.0;
    assert!((frac0 - 256.0 / 340.0).abs() < 0.03, "{frac0}");
    let (mut r2, mut t2) = (Vec::new(), Vec::new());
    ds.sample_batch(BatchDraw::new(4000, 1, 0), &mut r2, &mut t2);
    assert_eq!(rays, r2, "batches are a function of (seed, step)");
    ds.sample_batch(BatchDraw::new(4000, 1, 1), &mut r2, &mut t2);
    assert_ne!(rays, r2);
    ds.sample_batch(BatchDraw { supersample: 3, ..BatchDraw::new(10, 1, 0) }, &mut r2, &mut t2);
    assert_eq!((r2.len(), t2.len()), (90, 10), "3x3 rays per pixel");
    assert!((r2[0].radius * 3.0 - rays[0].radius).abs() < 1e-6 && r2[0].origin == rays[0].origin);
    assert_ne!(rays, r2);
}

#[test]
fn random_background_batches_composite_each_target_on_its_pixels_colour() {
    // The demo scene's object is opaque over a transparent backdrop: pixels of every alpha.
    let (_dir, ds) = small_demo_training_split();
    assert!(ds.has_transparency());
    let (mut rays, mut targets, mut r2, mut white) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (seed, step) = (3, 11);
    ds.sample_batch(BatchDraw { random_bkgd: true, ..BatchDraw::new(2000, seed, step) }, &mut rays, &mut targets);
    ds.sample_batch(BatchDraw::new(2000, seed, step), &mut r2, &mut white);
    assert_eq!(rays, r2, "the background changes the targets, not the pixels drawn");
    let (mut opaque, mut clear) = (0, 0);
    for (i, ((ray, t), w)) in rays.iter().zip(&targets).zip(&white).enumerate() {
        let bg = mipnerf_core::rng::random_background(seed, step, i as u32);
        // Find the pixel again to read its alpha.
        let (v, x, y) = (0..ds.views().len())
            .flat_map(|v| {
                let c = &ds.views()[v].camera;
                (0..c.height).flat_map(move |y| (0..c.width).map(move |x| (v, x, y)))
            })
            .find(|&(v, x, y)| ds.ray(v, x, y) == *ray)
            .unwrap();
        let view = &ds.views()[v];
        let [r, g, b, a] = view.pixels.rgba((y * view.camera.width + x) as usize);
        let want = [r * a + bg[0] * (1.0 - a), g * a + bg[1] * (1.0 - a), b * a + bg[2] * (1.0 - a)];
        assert_eq!(*t, want, "pixel {i}");
        if a == 1.0 {
            opaque += 1;
            assert_eq!(t, w, "an opaque pixel {i} keeps its colour");
        } else if a == 0.0 {
            clear += 1;
            assert_eq!(*t, bg, "a transparent pixel {i} is its background");
        }
    }
    assert!(opaque > 100 && clear > 100, "{opaque} opaque and {clear} clear pixels drawn");
    // The colours cover the cube: no channel is stuck.
    let mean: [f64; 3] = std::array::from_fn(|k| {
        (0..2000).map(|i| f64::from(mipnerf_core::rng::random_background(seed, step, i)[k])).sum::<f64>() / 2000.0
    });
    assert!(mean.iter().all(|m| (m - 0.5).abs() < 0.03), "mean background {mean:?}");
}

#[test]
fn photos_without_alpha_have_no_transparency() {
    let pixel = |a: u8| Pixels::Rgba8(vec![10, 20, 30, a, 40, 50, 60, 255]);
    let view = |pixels| View {
        file: PathBuf::from("p.png"),
        camera: Camera::from_camera_angle_x(
            2,
            1,
            0.8,
            [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0]],
        )
        .unwrap(),
        pixels,
        near: 1.0,
        far: 5.0,
        lossmult: 1.0,
        scale: 0,
    };
    let opaque = Dataset::from_views(Split::Train, vec![view(pixel(255))], false).unwrap();
    assert!(!opaque.has_transparency());
    let one = Dataset::from_views(Split::Train, vec![view(pixel(255)), view(pixel(254))], false).unwrap();
    assert!(one.has_transparency());
    let f = Dataset::from_views(Split::Train, vec![view(Pixels::RgbaF32(vec![0.5, 0.5, 0.5, 0.999]))], false);
    assert!(f.unwrap().has_transparency());
}

/// A small forward-facing LLFF scene made from the demo scene: 9 cameras on a 3x3 grid looking
/// along -y at the scene, images in images_4.
fn make_llff(dir: &Path) {
    std::fs::create_dir_all(dir.join("images_4")).unwrap();
    let (w, h, factor) = (32u32, 24u32, 4.0);
    let focal = 30.0;
    let mut rows = Vec::new();
    for i in 0..9 {
        let (gx, gz) = ((i % 3) as f64 - 1.0, (i / 3) as f64 - 1.0);
        let pos = [0.3 * gx, -4.0, 0.2 + 0.2 * gz];
        // OpenGL camera looking (roughly along +y) at a point behind the scene, so that the
        // optical axes converge as a real capture's do.
        let back = (glam::DVec3::from_array(pos) - glam::DVec3::new(0.0, 3.0, 0.2)).normalize();
        let right = glam::DVec3::Z.cross(back).normalize();
        let up = back.cross(right);
        let (right, up, back) = (right.to_array(), up.to_array(), back.to_array());
        let c2w: [[f64; 4]; 3] = std::array::from_fn(|r| [right[r], up[r], back[r], pos[r]]);
        let cam =
            mipnerf_core::Camera::from_pix2cam(w, h, mipnerf_core::camera::pinhole_pix2cam(w, h, focal), c2w).unwrap();
        let rgba = demo::render_view(&cam, 1);
        let bytes: Vec<u8> = rgba
            .chunks(4)
            .flat_map(|p| [p[0], p[1], p[2]].map(|c| (c * 255.0) as u8).into_iter().chain([255]))
            .collect();
        image::save_buffer(dir.join(format!("images_4/img_{i:02}.png")), &bytes, w, h, image::ExtendedColorType::Rgba8)
            .unwrap();
        // LLFF stores [down, right, back] columns: down = -up.
        let llff_cols = [[-up[0], right[0], back[0]], [-up[1], right[1], back[1]], [-up[2], right[2], back[2]]];
        let mut row = [0.0; 17];
        for r in 0..3 {
            row[r * 5] = llff_cols[r][0];
            row[r * 5 + 1] = llff_cols[r][1];
            row[r * 5 + 2] = llff_cols[r][2];
            row[r * 5 + 3] = pos[r];
        }
        row[4] = f64::from(h) * factor;
        row[9] = f64::from(w) * factor;
        row[14] = focal * factor;
        row[15] = 2.5;
        row[16] = 5.5;
        rows.push(row);
    }
    llff::write_poses_bounds(&dir.join("poses_bounds.npy"), &rows).unwrap();
}

#[test]
fn llff_scene_loads_with_ndc_rays_holdout_and_spiral() {
    let dir = tempfile::tempdir().unwrap();
    make_llff(dir.path());
    assert_eq!(mipnerf_data::detect_format(dir.path()).unwrap(), mipnerf_data::Format::Llff);
    let opts = LoadOptions { white_bkgd: Some(false), ..LoadOptions::default() };
    let train = mipnerf_data::load(dir.path(), Split::Train, &opts).unwrap();
    let test = mipnerf_data::load(dir.path(), Split::Test, &opts).unwrap();
    assert_eq!((train.views().len(), test.views().len()), (7, 2), "every 8th image (0 and 8) is held out");
    assert!(!train.white_bkgd && train.ndc.is_some());
    assert_eq!(test.render_path.len(), llff::RENDER_FRAMES);
    // Recentred: the average camera centre is the origin, the average camera looks down -z.
    let mut centre = glam::DVec3::ZERO;
    for v in train.views().iter().chain(test.views()) {
        centre += glam::DVec3::from_array(v.camera.origin());
    }
    assert!((centre / 9.0).length() < 1e-9, "average centre {centre:?}");
    for v in 0..7 {
        for ray in train.view_rays(v) {
            assert!(ray.origin.is_finite() && ray.direction.is_finite() && ray.radius > 0.0);
            // NDC origins lie on the near plane z = -1, and t in [0, 1] spans the frustum.
            assert!((ray.origin.z + 1.0).abs() < 1e-5, "ndc origin {:?}", ray.origin);
            assert_eq!((ray.near, ray.far), (0.0, 1.0));
            let end = ray.origin + ray.direction;
            assert!(end.z > 0.0 && end.z <= 1.0 + 1e-5, "far point {end:?}");
        }
    }
    // The spherical variant loads too, with world-space rays.
    let sph = mipnerf_data::load(dir.path(), Split::Test, &LoadOptions { llff_spherify: true, ..opts }).unwrap();
    assert!(sph.ndc.is_none() && sph.render_path.len() == llff::RENDER_FRAMES);
    let r = sph.ray(0, 3, 3);
    assert!(r.near > 0.0 && r.far > r.near && r.origin.is_finite());
}

/// Foreground masks (`LoadOptions::masks`) become the photos' alpha, matched by file name:
/// a mask of the photo's size as it is, a larger one of the same aspect area-resampled, a JPEG's
/// near-black and near-white levels snapped to 0 and 1, a cut-out's alpha taken over its colours;
/// composited on white, the targets keep the
/// object and leave out the rest (an LLFF photo's alpha once never reached its targets).
#[test]
fn llff_photos_take_their_masks_as_alpha_and_composite_on_white() {
    let dir = tempfile::tempdir().unwrap();
    make_llff(dir.path());
    let masks = dir.path().join("masks");
    std::fs::create_dir_all(&masks).unwrap();
    let (w, h) = (32u32, 24u32);
    // The left half is the object; img_03's mask is twice the size, img_05's a JPEG with noise.
    let half = |scale: u32, lo: u8, hi: u8| {
        image::GrayImage::from_fn(w * scale, h * scale, |x, _| image::Luma([if x < w * scale / 2 { hi } else { lo }]))
    };
    for i in 0..9 {
        let path = masks.join(format!("img_{i:02}.png"));
        match i {
            3 => half(2, 0, 255).save(&path).unwrap(),
            5 => half(1, 5, 250).save(masks.join("img_05.jpg")).unwrap(),
            // Cut-outs, as background-removal tools write them: the mask is the alpha, whatever
            // the colour (white everywhere here, black and grey with alpha).
            7 => image::RgbaImage::from_fn(w, h, |x, _| image::Rgba([255, 255, 255, if x < w / 2 { 255 } else { 0 }]))
                .save(&path)
                .unwrap(),
            1 => image::GrayAlphaImage::from_fn(w, h, |x, _| {
                image::LumaA([if x < w / 2 { 0 } else { 255 }, if x < w / 2 { 255 } else { 0 }])
            })
            .save(&path)
            .unwrap(),
            _ => half(1, 0, 255).save(&path).unwrap(),
        }
    }
    let opts = LoadOptions { white_bkgd: Some(true), masks: Some(masks.clone()), ..LoadOptions::default() };
    let train = mipnerf_data::load(dir.path(), Split::Train, &opts).unwrap();
    assert!(train.white_bkgd && train.has_transparency());
    assert!(train.notes.iter().any(|n| n.contains("7 photos masked by")), "{:?}", train.notes);
    let plain = mipnerf_data::load(dir.path(), Split::Train, &LoadOptions::default()).unwrap();
    assert!(!plain.white_bkgd && !plain.has_transparency(), "photos are not composited by default");
    for (v, view) in train.views().iter().enumerate() {
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let alpha = view.pixels.rgba(i)[3];
                let object = x < w / 2;
                assert_eq!(alpha, if object { 1.0 } else { 0.0 }, "{} ({x}, {y})", view.file.display());
                let photo = plain.views()[v].pixels.rgba(i);
                let target = train.target(v, x, y);
                let want = if object { [photo[0], photo[1], photo[2]] } else { [1.0; 3] };
                assert_eq!(target, want, "{} ({x}, {y})", view.file.display());
            }
        }
    }
    // The photos' own folder given as their masks is refused, naming it.
    let photos = train.views()[0].file.parent().unwrap().to_path_buf();
    let err = mipnerf_data::load(dir.path(), Split::Train, &LoadOptions { masks: Some(photos.clone()), ..opts })
        .unwrap_err()
        .to_string();
    assert!(err.contains("the photos' own folder") && err.contains(&photos.display().to_string()), "{err}");
}

/// `spherify_radius` puts the spherified cameras at that root-mean-square distance from the
/// centre, scaling the bounds and the render path with them (the official code's is 1).
#[test]
fn spherified_cameras_sit_at_the_radius_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    make_llff(dir.path());
    let load = |radius: f64, split: Split| {
        let opts = LoadOptions { llff_spherify: true, spherify_radius: Some(radius), ..LoadOptions::default() };
        mipnerf_data::load(dir.path(), split, &opts).unwrap()
    };
    let rms = |ds: &Dataset| {
        let d2: f64 = ds.views().iter().map(|v| glam::DVec3::from_array(v.camera.origin()).length_squared()).sum();
        (d2 / ds.views().len() as f64).sqrt()
    };
    let (unit, four) = (load(1.0, Split::Train), load(4.0, Split::Train));
    let (unit_test, four_test) = (load(1.0, Split::Test), load(4.0, Split::Test));
    // Over all 9 cameras (train and test) the mean square distance is the radius squared.
    let all = |a: &Dataset, b: &Dataset| {
        let n = (a.views().len() + b.views().len()) as f64;
        ((rms(a).powi(2) * a.views().len() as f64 + rms(b).powi(2) * b.views().len() as f64) / n).sqrt()
    };
    assert!((all(&unit, &unit_test) - 1.0).abs() < 1e-9, "{}", all(&unit, &unit_test));
    assert!((all(&four, &four_test) - 4.0).abs() < 1e-9, "{}", all(&four, &four_test));
    for (a, b) in unit.views().iter().zip(four.views()) {
        let (oa, ob) = (glam::DVec3::from_array(a.camera.origin()), glam::DVec3::from_array(b.camera.origin()));
        assert!((ob - 4.0 * oa).length() < 1e-9);
        assert!((b.near - 4.0 * a.near).abs() < 1e-5 && (b.far - 4.0 * a.far).abs() < 1e-5);
    }
    for (a, b) in unit_test.render_path.iter().zip(&four_test.render_path) {
        let (oa, ob) = (glam::DVec3::from_array(a.origin()), glam::DVec3::from_array(b.origin()));
        assert!((ob - 4.0 * oa).length() < 1e-9);
    }
}

/// A 360-degree capture: 16 cameras on a ring of radius 3 tilted 30 degrees from the world's
/// `z`, 1 unit above the point they all look at and centred 0.8 to the side of it (so the mean
/// offset from that point leans 39 degrees off the ring's axis), images 8x6 (blank: only the
/// poses matter here).
fn make_tilted_ring(dir: &Path) -> glam::DVec3 {
    std::fs::create_dir_all(dir.join("images_1")).unwrap();
    let tilt = 30f64.to_radians();
    let axis = glam::DVec3::new(0.0, -tilt.sin(), tilt.cos());
    let u = glam::DVec3::X;
    let v = axis.cross(u);
    let target = glam::DVec3::new(0.5, -0.2, 0.3);
    let mut rows = Vec::new();
    for i in 0..16 {
        let th = std::f64::consts::TAU * i as f64 / 16.0;
        let pos = target + 3.0 * (th.cos() * u + th.sin() * v) + axis + 0.8 * u;
        let back = (pos - target).normalize();
        let right = axis.cross(back).normalize();
        let up = back.cross(right);
        image::RgbImage::new(8, 6).save(dir.join(format!("images_1/img_{i:02}.png"))).unwrap();
        let mut row = [0.0; 17];
        for r in 0..3 {
            let m = [-up[r], right[r], back[r], pos[r], [6.0, 8.0, 10.0][r]];
            row[r * 5..r * 5 + 5].copy_from_slice(&m);
        }
        row[15] = 2.0;
        row[16] = 4.5;
        rows.push(row);
    }
    llff::write_poses_bounds(&dir.join("poses_bounds.npy"), &rows).unwrap();
    axis
}

/// With the ring's axis (`spherify_radius` given), the spherified frame's `z` is the axis of the
/// ring the cameras stand on: every camera at one height, the render path the cameras' own
/// circle at that height looking at the centre with `z` up. The official up axis (the mean
/// offset from the centre) tilts with the capture.
#[test]
fn spherified_poses_take_the_axis_of_the_cameras_ring() {
    let dir = tempfile::tempdir().unwrap();
    let axis = make_tilted_ring(dir.path());
    let load = |radius: Option<f64>, split: Split| {
        let opts =
            LoadOptions { llff_factor: 1, llff_spherify: true, spherify_radius: radius, ..LoadOptions::default() };
        mipnerf_data::load(dir.path(), split, &opts).unwrap()
    };
    let heights = |ds: &Dataset| -> Vec<f64> { ds.views().iter().map(|v| v.camera.origin()[2]).collect() };
    let spread = |h: &[f64]| {
        h.iter().copied().fold(f64::NEG_INFINITY, f64::max) - h.iter().copied().fold(f64::INFINITY, f64::min)
    };
    let (ring, ring_test) = (load(Some(4.0), Split::Train), load(Some(4.0), Split::Test));
    let h = heights(&ring);
    assert!(spread(&h) < 1e-9, "cameras on the ring at one height: {h:?}");
    for v in ring.views() {
        // The camera's up axis is the ring's: its x axis stays level.
        assert!(v.camera.cam2world[2][0].abs() < 1e-9, "a rolled camera: {:?}", v.camera.cam2world);
    }
    // The path is the cameras' own circle: every camera (train and test) lies on it, at its
    // height, and every frame is upright and looks at the centre.
    assert_eq!(ring_test.render_path.len(), llff::RENDER_FRAMES);
    let path: Vec<glam::DVec3> = ring_test.render_path.iter().map(|c| glam::DVec3::from_array(c.origin())).collect();
    let centre = path.iter().sum::<glam::DVec3>() / path.len() as f64;
    let rho = (path[0] - centre).length();
    for (p, cam) in path.iter().zip(&ring_test.render_path) {
        assert!(((*p - centre).length() - rho).abs() < 1e-9 && (p.z - h[0]).abs() < 1e-9, "{p:?}");
        assert!(cam.cam2world[2][0].abs() < 1e-9 && cam.cam2world[2][1] > 0.0, "upright: {:?}", cam.cam2world);
        let back = glam::DVec3::new(cam.cam2world[0][2], cam.cam2world[1][2], cam.cam2world[2][2]);
        assert!((back - p.normalize()).length() < 1e-9, "looks at the centre");
    }
    for v in ring.views().iter().chain(ring_test.views()) {
        let o = glam::DVec3::from_array(v.camera.origin());
        assert!(((o - centre).length() - rho).abs() < 1e-9, "camera {o:?} off the path's circle");
    }
    // The official frame is tilted against the ring: its cameras' heights differ.
    let official = load(None, Split::Train);
    assert!(spread(&heights(&official)) > 0.1, "{:?}", heights(&official));
    // The ring's axis itself, recovered from the world-space poses and oriented by their ups.
    let centres: Vec<glam::DVec3> = (0..16)
        .map(|i| {
            let th = std::f64::consts::TAU * i as f64 / 16.0;
            3.0 * (th.cos() * glam::DVec3::X + th.sin() * axis.cross(glam::DVec3::X)) + axis
        })
        .collect();
    let found = llff::ring_axis(&centres, &vec![axis; 16]).unwrap();
    assert!((found - axis).length() < 1e-9, "{found:?}");
    assert!((llff::ring_axis(&centres, &vec![-axis; 16]).unwrap() + axis).length() < 1e-9);
    let line: Vec<glam::DVec3> = (0..5).map(|i| glam::DVec3::X * f64::from(i)).collect();
    assert_eq!(llff::ring_axis(&line, &[glam::DVec3::Z; 5]), None, "centres along a line have no plane");
}

/// Asserts that the error names `file` and contains `problem`.
fn assert_error(err: DataError, file: &str, problem: &str) {
    let msg = err.to_string();
    assert!(msg.contains(file), "error does not name {file}: {msg}");
    assert!(msg.to_lowercase().contains(&problem.to_lowercase()), "error does not say {problem:?}: {msg}");
}

fn copy_lego(dir: &Path) {
    for sub in ["train", "test"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        for e in std::fs::read_dir(lego_tiny().join(sub)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.join(sub).join(e.file_name())).unwrap();
        }
    }
    for f in ["transforms_train.json", "transforms_test.json"] {
        std::fs::copy(lego_tiny().join(f), dir.join(f)).unwrap();
    }
}

fn edit_json(path: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(path, serde_json::to_string(&v).unwrap()).unwrap();
}

#[test]
fn bad_inputs_get_clear_errors_naming_the_file() {
    let load = |d: &Path| mipnerf_data::load(d, Split::Train, &LoadOptions::default());
    let case = |setup: &dyn Fn(&Path)| {
        let dir = tempfile::tempdir().unwrap();
        copy_lego(dir.path());
        setup(dir.path());
        (dir, ())
    };
    // Malformed and truncated JSON.
    let (d, _) = case(&|d| std::fs::write(d.join("transforms_train.json"), "{ \"camera_angle_x\": 0.69, ").unwrap());
    assert_error(load(d.path()).unwrap_err(), "transforms_train.json", "malformed JSON");
    let (d, _) = case(&|d| std::fs::write(d.join("transforms_train.json"), "not json").unwrap());
    assert_error(load(d.path()).unwrap_err(), "transforms_train.json", "malformed JSON");
    // Missing keys.
    let (d, _) = case(&|d| {
        edit_json(&d.join("transforms_train.json"), |v| drop(v.as_object_mut().unwrap().remove("camera_angle_x")))
    });
    assert_error(load(d.path()).unwrap_err(), "transforms_train.json", "missing key \"camera_angle_x\"");
    let (d, _) = case(&|d| {
        edit_json(&d.join("transforms_train.json"), |v| {
            drop(v["frames"][1].as_object_mut().unwrap().remove("transform_matrix"))
        })
    });
    assert_error(load(d.path()).unwrap_err(), "transforms_train.json", "frame 1: missing key \"transform_matrix\"");
    // Empty split.
    let (d, _) = case(&|d| edit_json(&d.join("transforms_train.json"), |v| v["frames"] = serde_json::json!([])));
    assert_error(load(d.path()).unwrap_err(), "transforms_train.json", "no frames");
    // Non-finite and singular poses.
    let (d, _) = case(&|d| {
        edit_json(&d.join("transforms_train.json"), |v| {
            v["frames"][0]["transform_matrix"][0][0] = serde_json::json!("NaN")
        })
    });
    assert_error(
        load(d.path()).unwrap_err(),
        "transforms_train.json",
        "frame 0 transform_matrix: entry [0][0] is not a number",
    );
    let (d, _) = case(&|d| {
        edit_json(&d.join("transforms_train.json"), |v| {
            v["frames"][2]["transform_matrix"] =
                serde_json::json!([[1, 0, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]])
        })
    });
    assert_error(
        load(d.path()).unwrap_err(),
        "transforms_train.json",
        "frame 2: invalid camera: cam2world rotation is singular",
    );
    // Missing and unreadable images.
    let (d, _) = case(&|d| std::fs::remove_file(d.join("train/r_23.png")).unwrap());
    assert_error(load(d.path()).unwrap_err(), "r_23.png", "No such file");
    let (d, _) = case(&|d| std::fs::write(d.join("train/r_23.png"), b"\x89PNG\r\n\x1a\ngarbage").unwrap());
    assert_error(load(d.path()).unwrap_err(), "r_23.png", "cannot decode");
    // Wrong size and wrong channel count.
    let (d, _) = case(&|d| {
        image::save_buffer(d.join("train/r_46.png"), &[0u8; 64 * 4], 8, 8, image::ExtendedColorType::Rgba8).unwrap()
    });
    assert_error(load(d.path()).unwrap_err(), "r_46.png", "image is 8x8 but the split's first image is 100x100");
    let (d, _) = case(&|d| {
        image::save_buffer(d.join("train/r_1.png"), &[0u8; 100 * 100], 100, 100, image::ExtendedColorType::L8).unwrap()
    });
    assert_error(load(d.path()).unwrap_err(), "r_1.png", "found 1 channel");
    // Not a dataset at all, and not a directory.
    let empty = tempfile::tempdir().unwrap();
    assert_error(load(empty.path()).unwrap_err(), &empty.path().display().to_string(), "not a known dataset");
    assert_error(load(&empty.path().join("nope")).unwrap_err(), "nope", "No such file");
    // Multiscale metadata with lists of different lengths, and an LLFF file of the wrong shape.
    let ms = tempfile::tempdir().unwrap();
    mipnerf_data::demo::write_demo_scene(
        ms.path(),
        &mipnerf_data::demo::DemoConfig { size: 16, train_views: 2, test_views: 1, supersample: 1 },
    )
    .unwrap();
    edit_json(&ms.path().join("metadata.json"), |v| drop(v["train"]["near"].as_array_mut().unwrap().pop()));
    assert_error(load(ms.path()).unwrap_err(), "metadata.json", "\"near\" has 7 entries, \"file_path\" has 8");
    let ll = tempfile::tempdir().unwrap();
    make_llff(ll.path());
    llff::write_poses_bounds(&ll.path().join("poses_bounds.npy"), &[[1.0; 17]; 3]).unwrap();
    assert_error(load(ll.path()).unwrap_err(), "images_4", "9 images but poses_bounds.npy has 3 poses");
    // Every photo's focal length is read from row 0; a zero there is named as such, not as the
    // first training pose's singular camera.
    make_llff(ll.path());
    let mut rows = llff::read_poses_bounds(&ll.path().join("poses_bounds.npy")).unwrap();
    rows[0][14] = 0.0;
    llff::write_poses_bounds(&ll.path().join("poses_bounds.npy"), &rows).unwrap();
    assert_error(load(ll.path()).unwrap_err(), "poses_bounds.npy", "row 0's focal length (its column 14");
    // One camera absurdly far away is named by its row, not as whichever recentred pose fails.
    make_llff(ll.path());
    let mut rows = llff::read_poses_bounds(&ll.path().join("poses_bounds.npy")).unwrap();
    rows[5][8] = 1e30;
    llff::write_poses_bounds(&ll.path().join("poses_bounds.npy"), &rows).unwrap();
    assert_error(load(ll.path()).unwrap_err(), "poses_bounds.npy", "row 5: a coordinate of the camera's position");
    let mut rows = [[1.0; 17]; 9];
    rows[4][7] = f64::NAN;
    llff::write_poses_bounds(&ll.path().join("poses_bounds.npy"), &rows).unwrap();
    assert_error(load(ll.path()).unwrap_err(), "poses_bounds.npy", "row 4 has a non-finite value");
    std::fs::write(ll.path().join("poses_bounds.npy"), b"\x93NUMPY truncated").unwrap();
    assert_error(load(ll.path()).unwrap_err(), "poses_bounds.npy", "not a .npy file");
    // An image folder the factor does not name: the error lists the folders there are, each with
    // the factor that reads it.
    let moved = tempfile::tempdir().unwrap();
    make_llff(moved.path());
    std::fs::rename(moved.path().join("images_4"), moved.path().join("images_8")).unwrap();
    std::fs::create_dir(moved.path().join("images")).unwrap();
    let err = llff::load(moved.path(), Split::Train, 4, None).unwrap_err();
    assert_error(
        err,
        "images_4",
        "--llff-factor 4 reads images_4, the scene has images (--llff-factor 0), images_8 (--llff-factor 8)",
    );
    let bare = tempfile::tempdir().unwrap();
    make_llff(bare.path());
    std::fs::remove_dir_all(bare.path().join("images_4")).unwrap();
    let err = llff::load(bare.path(), Split::Train, 2, None).unwrap_err();
    assert_error(err, "images_2", "the scene has no images or images_N folder");
}

#[test]
fn box_resize_averages_areas_at_any_ratio() {
    // A factor of 2 is the official 2x2 box filter.
    let (w, h) = (6, 4);
    let img: Vec<f32> = (0..w * h * 4).map(|i| ((i * 37) % 101) as f32 / 100.0).collect();
    let a = mipnerf_data::box_resize(&img, w, h, 3, 2);
    let b = mipnerf_data::down2(&img, w, h);
    assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6), "{a:?} vs {b:?}");
    // 3 -> 2 pixels in a row: each output covers 1.5 source pixels.
    let row: Vec<f32> = [0.0, 0.3, 0.9].iter().flat_map(|&v| [v, 1.0 - v, v, 1.0]).collect();
    let r = mipnerf_data::box_resize(&row, 3, 1, 2, 1);
    let want0 = (0.0 + 0.5 * 0.3) / 1.5;
    let want1 = (0.5 * 0.3 + 0.9) / 1.5;
    assert!((r[0] - want0).abs() < 1e-6 && (r[4] - want1).abs() < 1e-6, "{r:?}");
    // Straight alpha is averaged like the other channels, and the mean of the image is kept.
    assert!((r[3] - 1.0).abs() < 1e-6);
    let big: Vec<f32> = (0..10 * 10 * 4).map(|i| (i % 7) as f32 / 7.0).collect();
    let small = mipnerf_data::box_resize(&big, 10, 10, 4, 4);
    for c in 0..4 {
        let m = |v: &[f32], n: usize| v.iter().skip(c).step_by(4).sum::<f32>() / n as f32;
        assert!((m(&big, 100) - m(&small, 16)).abs() < 1e-5, "channel {c}");
    }
}

#[test]
fn convert_with_a_size_box_filters_first_and_checks_the_size() {
    let out = tempfile::tempdir().unwrap();
    let splits = multiscale::convert_resized(&lego_tiny(), out.path(), Some(48)).unwrap();
    assert_eq!(splits, vec![Split::Train, Split::Test]);
    let ds = mipnerf_data::load(out.path(), Split::Train, &LoadOptions::default()).unwrap();
    let widths: Vec<u32> = ds.views().iter().take(4).map(|v| v.camera.width).collect();
    assert_eq!(widths, vec![48, 24, 12, 6]);
    // The field of view is kept: the focal length scales with the width.
    let full = mipnerf_data::load(&lego_tiny(), Split::Train, &LoadOptions::default()).unwrap();
    let ratio = full.views()[0].camera.pix2cam[0][0] / ds.views()[0].camera.pix2cam[0][0];
    assert!((ratio - 48.0 / 100.0).abs() < 1e-6, "focal ratio {ratio}");
    // The full scale is the area average of the source image, quantised as the converter does.
    let (w, h, src, _) = {
        let img = image::open(lego_tiny().join("train/r_1.png")).unwrap().to_rgba8();
        (img.width(), img.height(), img.clone().into_raw(), ())
    };
    let f: Vec<f32> = src.iter().map(|&b| f32::from(b) / 255.0).collect();
    let want = multiscale::quantise(&mipnerf_data::box_resize(&f, w as usize, h as usize, 48, 48));
    let got = image::open(out.path().join("images_train/000_d0.png")).unwrap().to_rgba8().into_raw();
    assert_eq!(got, want);
    // Sizes that cannot be made into 4 whole scales, or that upsample, are refused.
    for (n, problem) in [(8, "at least 16"), (20, "divisible by 8"), (200, "larger than the image")] {
        let o = tempfile::tempdir().unwrap();
        let err = multiscale::convert_resized(&lego_tiny(), o.path(), Some(n)).unwrap_err();
        assert!(err.to_string().contains(problem), "--size {n}: {err}");
    }
}

#[test]
fn multiscale_numbers_are_checked_and_each_error_names_the_key_and_the_index() {
    use serde_json::json;
    let base = tempfile::tempdir().unwrap();
    mipnerf_data::demo::write_demo_scene(
        base.path(),
        &mipnerf_data::demo::DemoConfig { size: 16, train_views: 2, test_views: 1, supersample: 1 },
    )
    .unwrap();
    let meta = base.path().join("metadata.json");
    let original = std::fs::read_to_string(&meta).unwrap();
    let load = || mipnerf_data::load(base.path(), Split::Train, &LoadOptions::default());
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(Edit, &str)> = vec![
        (
            Box::new(|v| v["train"]["near"][3] = json!(7.0)),
            "train entry 3: \"near\" 7 and \"far\" 6: need 0 < near < far",
        ),
        (Box::new(|v| v["train"]["near"][2] = json!(6.0)), "train entry 2: \"near\" 6 and \"far\" 6"),
        (Box::new(|v| v["train"]["near"][1] = json!(0.0)), "train entry 1: \"near\" 0"),
        (Box::new(|v| v["train"]["near"][1] = json!(-1.0)), "train entry 1: \"near\" -1"),
        (
            Box::new(|v| drop(v["train"]["label"].as_array_mut().unwrap().pop())),
            "\"label\" has 7 entries, \"file_path\" has 8",
        ),
        (
            Box::new(|v| {
                v["train"].as_object_mut().unwrap().remove("pix2cam");
                v["train"]["focal"].as_array_mut().unwrap().truncate(5);
            }),
            "\"focal\" has 5 entries, \"file_path\" has 8",
        ),
        (
            Box::new(|v| {
                v["train"].as_object_mut().unwrap().remove("pix2cam");
                v["train"]["focal"][4] = json!(-20.0);
            }),
            "train entry 4 \"focal\" is -20 pixels",
        ),
        (Box::new(|v| v["train"]["lossmult"][6] = json!(-4.0)), "train entry 6 \"lossmult\" must be positive"),
        (Box::new(|v| v["train"]["lossmult"][0] = json!(0.0)), "train entry 0 \"lossmult\" must be positive"),
        (
            Box::new(|v| v["train"]["width"][0] = json!(16.5)),
            "train entry 0 \"width\" must be a whole number from 1 to 65536, got 16.5",
        ),
        (
            Box::new(|v| v["train"]["height"][5] = json!(-8)),
            "train entry 5 \"height\" must be a whole number from 1 to 65536, got -8",
        ),
        (Box::new(|v| v["train"]["label"][2] = json!(7)), "train entry 2 \"label\" must be a whole number from 0 to 3"),
        (Box::new(|v| v["train"]["label"][2] = json!(1.5)), "train entry 2 \"label\" must be a whole number"),
        (Box::new(|v| v["train"]["far"][1] = json!("far")), "train entry 1 \"far\" must be a finite number"),
    ];
    for (edit, problem) in cases {
        std::fs::write(&meta, &original).unwrap();
        edit_json(&meta, edit);
        assert_error(load().unwrap_err(), "metadata.json", problem);
    }
}

proptest::proptest! {
    // Every parser a user feeds, given mutated bytes of a valid file, returns Ok or an error and
    // never panics. Cases here: 48 per parser (PROPTEST_CASES=100000 for the long run; see README).
    #![proptest_config(common::fuzz_config())]
    #[test]
    fn mutated_files_never_panic_a_parser(
        ops in proptest::collection::vec((0u8..4, 0.0f64..1.0, proptest::num::u8::ANY), 1..6),
    ) {
        use mipnerf_core::checkpoint;
        use mipnerf_core::model::{Model, Preset};
        // metadata.json of a multiscale scene.
        let ms = tempfile::tempdir().unwrap();
        mipnerf_data::demo::write_demo_scene(ms.path(), &mipnerf_data::demo::DemoConfig { size: 16, train_views: 1, test_views: 1, supersample: 1 })
            .unwrap();
        let meta = ms.path().join("metadata.json");
        std::fs::write(&meta, mutate(std::fs::read(&meta).unwrap(), &ops)).unwrap();
        let _ = mipnerf_data::load(ms.path(), Split::Train, &LoadOptions::default());
        // transforms_train.json of a Blender scene.
        let bl = tempfile::tempdir().unwrap();
        copy_lego(bl.path());
        let tf = bl.path().join("transforms_train.json");
        std::fs::write(&tf, mutate(std::fs::read(&tf).unwrap(), &ops)).unwrap();
        let _ = mipnerf_data::load(bl.path(), Split::Train, &LoadOptions::default());
        // A checkpoint.
        let model = Model::new(Preset::Tiny.config()).unwrap();
        let ck = tempfile::tempdir().unwrap();
        let path = ck.path().join("checkpoint.safetensors");
        let state = mipnerf_core::backend::TrainState::fresh(&model, 0);
        let c = checkpoint::Checkpoint { step: 1, params: state.params.clone(), adam: state.adam.clone(), occupancy: None };
        checkpoint::save(&path, &model, &c).unwrap();
        let mutated = mutate(std::fs::read(&path).unwrap(), &ops);
        let changed = mutated != std::fs::read(&path).unwrap();
        std::fs::write(&path, mutated).unwrap();
        let loaded = checkpoint::load(&path, &model);
        // A changed checkpoint never loads as it was silently... unless the change only touched
        // header whitespace padding, which carries no information.
        if changed && let Ok(back) = loaded {
            proptest::prop_assert_eq!(back, c);
        }
    }
}

/// A value at an extreme of `f64`: 0, a subnormal, `f64::MAX`, or `±10^e` for `e` in -320..=308.
fn extreme() -> impl proptest::strategy::Strategy<Value = f64> {
    use proptest::prelude::*;
    prop_oneof![
        Just(0.0),
        Just(f64::MAX),
        Just(f64::MIN_POSITIVE / 4.0),
        (any::<bool>(), -320i32..=308).prop_map(|(neg, e)| if neg { -(10f64.powi(e)) } else { 10f64.powi(e) }),
    ]
}

proptest::proptest! {
    #![proptest_config(common::fuzz_config())]
    // Property (a hand-edited file must fail clearly or run): a numeric field of metadata.json set to an extreme finite value either
    // fails to load with an error naming metadata.json, or the scene trains a step and renders a
    // view without panicking.
    #[test]
    fn extreme_numbers_in_metadata_are_refused_or_train_and_render_without_panic(
        field in 0usize..6,
        entry in 0usize..4,
        slot in 0usize..12,
        value in extreme(),
    ) {
        use std::sync::Arc;
        use mipnerf_core::backend::{Backend, CpuBackend, ImageSpec, TrainState};
        use mipnerf_core::model::{Model, Preset};
        let dir = tempfile::tempdir().unwrap();
        mipnerf_data::demo::write_demo_scene(dir.path(), &mipnerf_data::demo::DemoConfig { size: 16, train_views: 1, test_views: 1, supersample: 1 })
            .unwrap();
        let path = dir.path().join("metadata.json");
        let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let e = &mut m["train"];
        let key = ["near", "far", "focal", "lossmult", "cam2world", "pix2cam"][field];
        match key {
            "cam2world" => e[key][entry][slot / 4][slot % 4] = serde_json::json!(value),
            "pix2cam" => e[key][entry][slot % 3][slot / 4 % 3] = serde_json::json!(value),
            _ => e[key][entry] = serde_json::json!(value),
        }
        std::fs::write(&path, m.to_string()).unwrap();
        let ds = match mipnerf_data::load(dir.path(), Split::Train, &LoadOptions::default()) {
            Ok(ds) => ds,
            Err(err) => {
                let msg = err.to_string();
                proptest::prop_assert!(msg.contains("metadata.json"), "{key} = {value}: {msg}");
                return Ok(());
            }
        };
        let model = Model::new(Preset::Tiny.config()).unwrap();
        let state = TrainState::fresh(&model, 0);
        let image = ImageSpec::of_view(&ds, entry.min(ds.views().len() - 1), 1);
        let mut be = CpuBackend::new(model, mipnerf_core::train::OptimConfig::default(), 0, state)
            .unwrap()
            .with_data(Arc::new(ds), 16);
        let _ = be.train_step(true);
        let _ = be.render(&image, mipnerf_core::model::Levels::Last);
    }
}

/// Found by the property test above: a pix2cam entry of f64::MAX in the row that makes the
/// direction's z overflows to infinity at a corner, which the off-axis angle alone (x / inf = 0)
/// let through, and the ray's cone radius became NaN. The direction's length is now checked.
#[test]
fn a_pix2cam_whose_corner_direction_overflows_is_refused() {
    let pose = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0]];
    let mut pix2cam = [[1.0 / 40.0, 0.0, -0.5], [0.0, -1.0 / 40.0, 0.5], [0.0, 0.0, -1.0]];
    pix2cam[2][0] = f64::MAX;
    let e = mipnerf_core::camera::Camera::from_pix2cam(32, 32, pix2cam, pose).unwrap_err().to_string();
    assert!(e.contains("along a direction of length") && e.contains("accepted: 1e-6 to 1e6"), "{e}");
    // Scaled by 1e-9 the directions vanish in f32: refused too; a camera's own passes.
    let tiny = pix2cam.map(|r| r.map(|v| v * 1e-9));
    let mut fine = pix2cam;
    fine[2][0] = 0.0;
    let tiny = [[tiny[0][0], 0.0, tiny[0][2]], [0.0, tiny[1][1], tiny[1][2]], [0.0, 0.0, tiny[2][2]]];
    assert!(mipnerf_core::camera::Camera::from_pix2cam(32, 32, tiny, pose).is_err());
    assert!(mipnerf_core::camera::Camera::from_pix2cam(32, 32, fine, pose).is_ok());
}

/// An unbounded scene's photos (`unbounded`): spherified with the ring's axis as at any radius,
/// scaled so that the farthest camera of the whole capture (train and test alike) lies on the
/// unit sphere and the others inside it, and every ray reaching
/// [`UNBOUNDED_FAR`](mipnerf_core::contract::UNBOUNDED_FAR).
#[test]
fn unbounded_photos_put_the_farthest_camera_on_the_unit_sphere() {
    use mipnerf_core::contract::UNBOUNDED_FAR;
    let dir = tempfile::tempdir().unwrap();
    make_tilted_ring(dir.path());
    let load = |unbounded: bool, split: Split| {
        let opts = LoadOptions {
            llff_factor: 1,
            llff_spherify: true,
            spherify_radius: (!unbounded).then_some(4.0),
            unbounded,
            ..LoadOptions::default()
        };
        mipnerf_data::load(dir.path(), split, &opts).unwrap()
    };
    let origins = |ds: &Dataset| -> Vec<glam::DVec3> {
        ds.views().iter().map(|v| glam::DVec3::from_array(v.camera.origin())).collect()
    };
    let (train, test) = (load(true, Split::Train), load(true, Split::Test));
    let all: Vec<f64> = origins(&train).iter().chain(&origins(&test)).map(|o| o.length()).collect();
    let farthest = all.iter().copied().fold(0.0, f64::max);
    let nearest = all.iter().copied().fold(f64::INFINITY, f64::min);
    assert!((farthest - 1.0).abs() < 1e-9, "the farthest camera at {farthest}");
    // The ring is off-centre, so the other cameras lie strictly inside.
    assert!(nearest < 0.9, "cameras at {all:?}");
    for ds in [&train, &test] {
        assert!(ds.notes.iter().any(|n| n.contains("unbounded")), "{:?}", ds.notes);
        // Cameras on a ring look all around: no forward-facing note.
        assert!(!ds.notes.iter().any(|n| n.contains("all look one way")), "{:?}", ds.notes);
        for v in ds.views() {
            assert_eq!(v.far, UNBOUNDED_FAR, "{}", v.file.display());
            assert!(v.near > 0.0 && v.near < 1.0, "{}: near {}", v.file.display(), v.near);
        }
    }
    // The same frame as the ring's at radius 4, scaled by one factor.
    let ring = origins(&load(false, Split::Train));
    let k = ring[0].length() / origins(&train)[0].length();
    for (a, b) in origins(&train).iter().zip(&ring) {
        assert!((*a * k - *b).length() < 1e-9, "{a:?} x {k} vs {b:?}");
    }
}

/// Forward-facing photos spherified and unbounded train in the contracted space (meaningful:
/// it holds what lies beyond their depth range), with a note that the LLFF protocol trains them
/// in NDC.
#[test]
fn forward_facing_photos_unbounded_are_said_to_differ_from_the_llff_protocol() {
    let fern = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/llff_fern_tiny");
    let opts = LoadOptions { llff_factor: 64, llff_spherify: true, unbounded: true, ..LoadOptions::default() };
    let ds = mipnerf_data::load(&fern, Split::Train, &opts).unwrap();
    assert!(ds.notes.iter().any(|n| n.contains("all look one way") && n.contains("NDC")), "{:?}", ds.notes);
}

/// `unbounded` is for world-space photos: forward-facing photos in NDC space and Blender scenes
/// are refused, naming the folder and what to do.
#[test]
fn unbounded_scenes_need_spherified_photos() {
    let dir = tempfile::tempdir().unwrap();
    make_tilted_ring(dir.path());
    let opts = LoadOptions { llff_factor: 1, unbounded: true, ..LoadOptions::default() };
    let err = mipnerf_data::load(dir.path(), Split::Train, &opts).unwrap_err().to_string();
    assert!(
        err.contains("NDC") && err.contains("--spherify") && err.contains(&dir.path().display().to_string()),
        "{err}"
    );
    let err =
        mipnerf_data::load(&lego_tiny(), Split::Train, &LoadOptions { unbounded: true, ..LoadOptions::default() })
            .unwrap_err()
            .to_string();
    assert!(err.contains("Blender") && err.contains("lego_tiny"), "{err}");
}

/// `Dataset::data_to_scene` takes every photo's pose in the data's own frame
/// (`poses_bounds.npy`'s, its columns turned to OpenGL's) to its camera in the scene, whichever
/// way the loader recentres, rescales and spherifies (the fern capture's own poses).
#[test]
fn the_data_to_scene_similarity_takes_each_photo_to_its_camera() {
    let fern = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/llff_fern_tiny");
    let rows = llff::read_poses_bounds(&fern.join("poses_bounds.npy")).unwrap();
    // [down, right, back] columns -> [right, up, back], as the loader turns them.
    let data_pose = |r: &[f64; 17]| -> [[f64; 4]; 3] {
        std::array::from_fn(|i| [r[i * 5 + 1], -r[i * 5], r[i * 5 + 2], r[i * 5 + 3]])
    };
    let base = LoadOptions { llff_factor: 64, ..LoadOptions::default() };
    let modes = [
        ("ndc", base.clone()),
        ("spherify", LoadOptions { llff_spherify: true, ..base.clone() }),
        ("ring", LoadOptions { llff_spherify: true, spherify_radius: Some(4.0), ..base.clone() }),
        ("unbounded", LoadOptions { llff_spherify: true, unbounded: true, ..base.clone() }),
    ];
    for (mode, opts) in modes {
        let ds = mipnerf_data::load(&fern, Split::Train, &opts).unwrap();
        let s = ds.data_to_scene;
        assert!(s.scale > 0.0 && s.scale.is_finite(), "{mode}");
        // The train split: every photo but every 8th.
        let train_rows = rows.iter().enumerate().filter(|(i, _)| i % llff::LLFF_HOLD != 0).map(|(_, r)| r);
        for (v, r) in ds.views().iter().zip(train_rows) {
            let want = v.camera.cam2world;
            let got = s.pose(&data_pose(r));
            for i in 0..3 {
                for j in 0..4 {
                    assert!(
                        (got[i][j] - want[i][j]).abs() < 1e-9,
                        "{mode}: {} [{i}][{j}] {got:?} {want:?}",
                        v.file.display()
                    );
                }
            }
        }
    }
    // Blender's frame is the scene's.
    let lego = mipnerf_data::load(&lego_tiny(), Split::Train, &LoadOptions::default()).unwrap();
    assert_eq!(lego.data_to_scene, mipnerf_core::camera::Similarity::IDENTITY);
}
