//! COLMAP scenes: a real reconstruction (tests/data/colmap_lego, made by
//! scripts/data/make-colmap-test-data.sh with PyPI's pycolmap) read in both forms, turned into the
//! `poses_bounds.npy` LLFF's imgs2poses gives, aligned with the Blender ground truth, and every
//! kind of damaged model refused with a clear error.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use glam::DVec3;
use mipnerf_core::dataset::{DataError, Split};
use mipnerf_core::test_support::mutate;
use mipnerf_data::{LoadOptions, colmap, llff};

/// Largest difference allowed between the importer's poses_bounds and the reference's: both are
/// float64 from the same model; they differ only in the order of floating-point operations.
const TOL_POSES_BOUNDS: f64 = 1e-9;
/// Camera centres after the best similarity transform onto Blender's, as a fraction of the
/// cameras' distance to the object (4.03 units), for COLMAP's reconstruction from 400 px renders:
/// the median camera (measured: 0.4%) and the worst (measured: 2.3%, a camera with few features).
const TOL_CENTRE_MEDIAN: f64 = 0.01;
const TOL_CENTRE_WORST: f64 = 0.03;

fn scene() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/colmap_lego")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// A scene folder with `images/` and the text model as `sparse/0`.
fn text_scene(dir: &Path) {
    copy_dir(&scene().join("images"), &dir.join("images"));
    copy_dir(&scene().join("text"), &dir.join("sparse/0"));
}

#[test]
fn binary_and_text_models_read_identically() {
    let bin = colmap::read_model(&scene().join("sparse/0")).unwrap();
    let txt = colmap::read_model(&scene().join("text")).unwrap();
    assert_eq!(bin.cameras.len(), 1);
    assert!(
        bin.images.len() >= 20 && bin.points.len() > 500,
        "{} images, {} points",
        bin.images.len(),
        bin.points.len()
    );
    // The text form prints 17 significant digits: the same float64 values.
    assert_eq!(bin, txt);
}

#[test]
fn poses_bounds_match_llffs_imgs2poses_on_the_same_model() {
    let model_dir = scene().join("sparse/0");
    let model = colmap::read_model(&model_dir).unwrap();
    let (rows, names) = colmap::poses_bounds(&model, &model_dir).unwrap();
    let expected = llff::read_poses_bounds(&scene().join("poses_bounds_expected.npy")).unwrap();
    let expected_names: Vec<String> =
        serde_json::from_str(&std::fs::read_to_string(scene().join("poses_bounds_expected_names.json")).unwrap())
            .unwrap();
    assert_eq!(names, expected_names);
    assert_eq!(rows.len(), expected.len());
    let mut worst = 0.0f64;
    for (a, b) in rows.iter().zip(&expected) {
        for (x, y) in a.iter().zip(b) {
            worst = worst.max((x - y).abs() / y.abs().max(1.0));
        }
    }
    assert!(worst <= TOL_POSES_BOUNDS, "largest difference {worst:e}");
    // Near and far bounds are positive and ordered.
    assert!(rows.iter().all(|r| r[15] > 0.0 && r[16] > r[15]));
}

/// Umeyama (1991): the similarity `s R x + t` that maps `src` onto `dst` in least squares.
fn umeyama(src: &[DVec3], dst: &[DVec3]) -> (f64, glam::DMat3, DVec3) {
    let n = src.len() as f64;
    let (ms, md) = (src.iter().sum::<DVec3>() / n, dst.iter().sum::<DVec3>() / n);
    let mut cov = glam::DMat3::ZERO;
    for (a, b) in src.iter().zip(dst) {
        let (a, b) = (*a - ms, *b - md);
        cov += glam::DMat3::from_cols(b * a.x, b * a.y, b * a.z);
    }
    cov *= 1.0 / n;
    let var_s = src.iter().map(|a| (*a - ms).length_squared()).sum::<f64>() / n;
    // SVD of the 3x3 covariance through the polar decomposition: R = cov (cov^T cov)^(-1/2),
    // by Newton iteration on the orthogonal factor (well conditioned for these point sets).
    let mut r = cov * (1.0 / cov.to_cols_array().iter().map(|x| x * x).sum::<f64>().sqrt());
    for _ in 0..100 {
        r = (r + r.inverse().transpose()) * 0.5;
    }
    if r.determinant() < 0.0 {
        panic!("reflection: the cameras are degenerate");
    }
    // Scale: trace(R^T cov) / var_s.
    let rc = r.transpose() * cov;
    let s = (rc.x_axis.x + rc.y_axis.y + rc.z_axis.z) / var_s;
    (s, r, md - s * (r * ms))
}

#[test]
fn camera_centres_match_blender_after_a_similarity_transform() {
    let model = colmap::read_model(&scene().join("sparse/0")).unwrap();
    let truth: std::collections::BTreeMap<String, [f64; 3]> =
        serde_json::from_str(&std::fs::read_to_string(scene().join("blender_centres.json")).unwrap()).unwrap();
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for im in &model.images {
        let [qw, qx, qy, qz] = im.qvec;
        let r = glam::DMat3::from_quat(glam::DQuat::from_xyzw(qx, qy, qz, qw));
        src.push(-(r.transpose() * DVec3::from_array(im.tvec)));
        dst.push(DVec3::from_array(truth[&im.name]));
    }
    assert_eq!(src.len(), truth.len());
    let (s, r, t) = umeyama(&src, &dst);
    let radius = dst.iter().map(|d| d.length()).sum::<f64>() / dst.len() as f64;
    let mut errors: Vec<f64> = src.iter().zip(&dst).map(|(a, b)| (s * (r * *a) + t - *b).length() / radius).collect();
    errors.sort_by(f64::total_cmp);
    let (median, worst) = (errors[errors.len() / 2], errors[errors.len() - 1]);
    assert!(
        median <= TOL_CENTRE_MEDIAN && worst <= TOL_CENTRE_WORST,
        "centre errors (fractions of the camera distance) median {median:.4}, worst {worst:.4}: {errors:?}"
    );
}

#[test]
fn a_colmap_folder_loads_as_a_dataset_with_llff_conventions() {
    let opts = LoadOptions { llff_factor: 2, llff_spherify: true, ..LoadOptions::default() };
    assert_eq!(mipnerf_data::detect_format(&scene()).unwrap(), mipnerf_data::Format::Colmap);
    let train = mipnerf_data::load(&scene(), Split::Train, &opts).unwrap();
    let test = mipnerf_data::load(&scene(), Split::Test, &opts).unwrap();
    let n = colmap::read_model(&scene().join("sparse/0")).unwrap().images.len();
    // Every 8th image (0, 8, 16, ...) is held out, as LLFF does.
    assert_eq!(test.views().len(), n.div_ceil(8));
    assert_eq!(train.views().len() + test.views().len(), n);
    assert_eq!((train.views()[0].camera.width, train.views()[0].camera.height), (100, 100));
    assert!(train.notes.iter().any(|n| n.contains("images_2/ is absent")), "{:?}", train.notes);
    // The text model gives the same dataset.
    let dir = tempfile::tempdir().unwrap();
    text_scene(dir.path());
    let t2 = mipnerf_data::load(dir.path(), Split::Train, &opts).unwrap();
    assert_eq!(t2.views().len(), train.views().len());
    for (a, b) in t2.views().iter().zip(train.views()) {
        assert_eq!(a.camera, b.camera);
        assert_eq!((a.near, a.far), (b.near, b.far));
    }
}

#[test]
fn convert_to_llff_writes_what_the_llff_loader_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let names = colmap::convert_to_llff(&scene(), dir.path(), 2).unwrap();
    let rows = llff::read_poses_bounds(&dir.path().join("poses_bounds.npy")).unwrap();
    let expected = llff::read_poses_bounds(&scene().join("poses_bounds_expected.npy")).unwrap();
    assert_eq!(rows.len(), names.len());
    for (a, b) in rows.iter().zip(&expected) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= TOL_POSES_BOUNDS * y.abs().max(1.0));
        }
    }
    let opts = LoadOptions { llff_factor: 2, ..LoadOptions::default() };
    let from_llff = mipnerf_data::load(dir.path(), Split::Train, &opts).unwrap();
    let from_colmap = mipnerf_data::load(&scene(), Split::Train, &opts).unwrap();
    assert_eq!(from_llff.views().len(), from_colmap.views().len());
    for (a, b) in from_llff.views().iter().zip(from_colmap.views()) {
        assert_eq!(a.camera, b.camera);
        assert_eq!(a.pixels, b.pixels);
    }
}

fn assert_error(err: DataError, file: &str, problem: &str) {
    let msg = err.to_string();
    assert!(msg.contains(file) && msg.contains(problem), "expected {file:?} and {problem:?} in: {msg}");
}

#[test]
fn damaged_models_are_clear_errors() {
    let load =
        |d: &Path| mipnerf_data::load(d, Split::Train, &LoadOptions { llff_factor: 0, ..LoadOptions::default() });
    let case = |edit: &dyn Fn(&Path)| {
        let dir = tempfile::tempdir().unwrap();
        copy_dir(&scene().join("images"), &dir.path().join("images"));
        copy_dir(&scene().join("sparse"), &dir.path().join("sparse"));
        edit(dir.path());
        dir
    };
    let model = |d: &Path, f: &str| d.join("sparse/0").join(f);
    // Truncated binary files, each at a few lengths.
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        for keep in [0usize, 7, 30, 200] {
            let d = case(&|d| {
                let b = std::fs::read(model(d, f)).unwrap();
                std::fs::write(model(d, f), &b[..keep.min(b.len() - 1)]).unwrap();
            });
            assert_error(load(d.path()).unwrap_err(), f, "truncated");
        }
    }
    // An unknown camera model id (the second i32 of the first camera).
    let d = case(&|d| {
        let mut b = std::fs::read(model(d, "cameras.bin")).unwrap();
        b[12..16].copy_from_slice(&42i32.to_le_bytes());
        std::fs::write(model(d, "cameras.bin"), b).unwrap();
    });
    assert_error(load(d.path()).unwrap_err(), "cameras.bin", "unknown camera model id 42");
    // A distorted model (SIMPLE_RADIAL with k != 0) and a fisheye one, in the text form.
    for (line, problem) in [
        ("1 SIMPLE_RADIAL 200 200 273.2 100 100 0.01", "image_undistorter"),
        ("1 OPENCV_FISHEYE 200 200 273.2 273.2 100 100 0 0 0 0", "fisheye"),
        ("1 PINHOLE 200 200 273.2 260.0 100 100", "fx 273.2 and fy 260 differ"),
        ("1 PINHOLE 200 200 273.2 273.2 130 100", "principal point"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        text_scene(dir.path());
        std::fs::write(dir.path().join("sparse/0/cameras.txt"), format!("{line}\n")).unwrap();
        assert_error(load(dir.path()).unwrap_err(), "cameras", problem);
    }
    // A second, different camera.
    let dir = tempfile::tempdir().unwrap();
    text_scene(dir.path());
    let cams = "1 PINHOLE 200 200 273.2 273.2 100 100\n2 PINHOLE 200 200 300 300 100 100\n";
    std::fs::write(dir.path().join("sparse/0/cameras.txt"), cams).unwrap();
    assert_error(load(dir.path()).unwrap_err(), "cameras", "single_camera");
    // An image listed in the model but missing on disk.
    let first = colmap::read_model(&scene().join("sparse/0")).unwrap().images[3].name.clone();
    let d = case(&|d| std::fs::remove_file(d.join("images").join(&first)).unwrap());
    assert_error(load(d.path()).unwrap_err(), &first, "missing on disk");
    // An image that sees no 3D point: no bounds.
    let dir = tempfile::tempdir().unwrap();
    text_scene(dir.path());
    let pts = dir.path().join("sparse/0/points3D.txt");
    let model0 = colmap::read_model(&dir.path().join("sparse/0")).unwrap();
    let victim = model0.images[0].id;
    let text: String = std::fs::read_to_string(&pts)
        .unwrap()
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                return format!("{l}\n");
            }
            let t: Vec<&str> = l.split_whitespace().collect();
            let mut keep: Vec<&str> = t[..8].to_vec();
            for p in t[8..].chunks(2) {
                if p[0] != victim.to_string() {
                    keep.extend(p);
                }
            }
            format!("{}\n", keep.join(" "))
        })
        .collect();
    std::fs::write(&pts, text).unwrap();
    assert_error(load(dir.path()).unwrap_err(), "images", "sees no 3D point");
    // A NaN pose.
    let dir = tempfile::tempdir().unwrap();
    text_scene(dir.path());
    let imgs = dir.path().join("sparse/0/images.txt");
    let mut lines: Vec<String> = std::fs::read_to_string(&imgs).unwrap().lines().map(String::from).collect();
    let i = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    let mut t: Vec<String> = lines[i].split_whitespace().map(String::from).collect();
    t[5] = "nan".into();
    lines[i] = t.join(" ");
    std::fs::write(&imgs, lines.join("\n") + "\n").unwrap();
    assert_error(load(dir.path()).unwrap_err(), "images.txt", "tx is not finite");
    // Several models: the largest is taken, and the dataset says which.
    let d = case(&|d| {
        std::fs::create_dir_all(d.join("sparse/1")).unwrap();
        for f in ["cameras.bin", "points3D.bin"] {
            std::fs::copy(model(d, f), d.join("sparse/1").join(f)).unwrap();
        }
        // A model of no images.
        std::fs::write(d.join("sparse/1/images.bin"), 0u64.to_le_bytes()).unwrap();
    });
    let ds = load(d.path()).unwrap();
    assert!(ds.notes.iter().any(|n| n.contains("took sparse/0, the largest")), "{:?}", ds.notes);
}

proptest::proptest! {
    // The three binary files, with bytes replaced, inserted, deleted or cut: the reader returns a
    // model or an error, never panics (PROPTEST_CASES for a long run).
    #![proptest_config(common::fuzz_config())]
    #[test]
    fn mutated_binary_models_never_panic_the_reader(
        file in 0usize..3,
        ops in proptest::collection::vec((0u8..4, 0.0f64..1.0, proptest::num::u8::ANY), 1..6),
    ) {
        let dir = tempfile::tempdir().unwrap();
        copy_dir(&scene().join("sparse/0"), dir.path());
        let f = dir.path().join(["cameras.bin", "images.bin", "points3D.bin"][file]);
        std::fs::write(&f, mutate(std::fs::read(&f).unwrap(), &ops)).unwrap();
        if let Ok(model) = colmap::read_model(dir.path()) {
            let _ = colmap::poses_bounds(&model, dir.path());
        }
    }
}

/// A capture walked around a ring: 40 photos in name order (`p_00.jpg`...), each 9 degrees on
/// from the last, looking at the centre, 300 points near the centre seen by every photo with a
/// reprojection error of 0.5 px.
fn ring_capture() -> colmap::ColmapModel {
    let mut images = Vec::new();
    for i in 0..40u32 {
        let th = f64::from(i) * 9f64.to_radians();
        let centre = DVec3::new(3.0 * th.cos(), 3.0 * th.sin(), 0.5);
        let forward = (-centre).normalize();
        let right = forward.cross(DVec3::Z).normalize();
        let down = forward.cross(right);
        images.push(image_at(i, centre, right, down, forward));
    }
    let points = (0..300)
        .map(|k| {
            let a = f64::from(k) * 0.7;
            colmap::ColmapPoint {
                xyz: [0.3 * a.cos(), 0.3 * a.sin(), 0.2 * (a * 0.3).sin()],
                image_ids: (1..=40).collect(),
                error: 0.5,
            }
        })
        .collect();
    let camera = colmap::ColmapCamera { id: 1, model_id: 0, width: 64, height: 48, params: vec![50.0, 32.0, 24.0] };
    colmap::ColmapModel { cameras: vec![camera], images, points }
}

/// COLMAP's image record of a camera at `centre` with axes `right`, `down`, `forward` (world).
fn image_at(i: u32, centre: DVec3, right: DVec3, down: DVec3, forward: DVec3) -> colmap::ColmapImage {
    // World-to-camera rotation: rows right, down, forward.
    let r = glam::DMat3::from_cols(right, down, forward).transpose();
    let q = glam::DQuat::from_mat3(&r);
    colmap::ColmapImage {
        id: i + 1,
        qvec: [q.w, q.x, q.y, q.z],
        tvec: (-(r * centre)).to_array(),
        camera_id: 1,
        name: format!("p_{i:02}.jpg"),
    }
}

#[test]
fn the_process_step_names_the_photos_colmap_may_have_got_wrong() {
    use mipnerf_data::process::suspect_photos;
    let clean = ring_capture();
    assert_eq!(suspect_photos(&clean), vec![], "a clean capture");
    let mut model = clean.clone();
    // Three photos in a row turned 120 degrees about the vertical (as COLMAP placed DSC_0071-0073
    // of a real capture): each still agrees with the other two, not with the path.
    for i in 20..23 {
        let th = f64::from(i as u32) * 9f64.to_radians();
        let centre = DVec3::new(3.0 * th.cos(), 3.0 * th.sin(), 0.5);
        let turn = glam::DMat3::from_rotation_z(120f64.to_radians());
        let forward = turn * (-centre).normalize();
        let right = forward.cross(DVec3::Z).normalize();
        model.images[i] = image_at(i as u32, centre, right, forward.cross(right), forward);
    }
    // One photo far off the path; one that sees few points; one with a high reprojection error.
    // (Image ids are one more than the photos' numbers.)
    model.images[5].tvec[0] += 3.0;
    for p in &mut model.points[..285] {
        p.image_ids.retain(|&id| id != 32);
    }
    model.points.push(colmap::ColmapPoint { xyz: [0.0, 0.0, 0.1], image_ids: vec![37], error: 400.0 });
    let suspects = suspect_photos(&model);
    let named: Vec<&str> = suspects.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(named, ["p_05.jpg", "p_20.jpg", "p_21.jpg", "p_22.jpg", "p_31.jpg", "p_36.jpg"], "{suspects:#?}");
    assert!(suspects[0].why.contains("steps away from its neighbours"), "{suspects:#?}");
    assert!(suspects[1..4].iter().all(|s| s.why.contains("degrees away from its neighbours")), "{suspects:#?}");
    assert!(suspects[4].why.contains("sees 15 3D points (the median photo 300)"), "{suspects:#?}");
    assert!(suspects[5].why.contains("reprojection error is 1.83 px (the median photo's 0.50)"), "{suspects:#?}");
}

/// Relative difference allowed between a focal length read from EXIF and the formula's (both
/// f64 from the same numbers).
const TOL_EXIF_FOCAL: f64 = 1e-12;

/// The focal length the photos' EXIF implies (`mipnerf_data::focal`), on tags Pillow wrote
/// (tests/data/exif, scripts/data/make-exif-fixtures.py).
#[test]
fn the_focal_length_a_photos_exif_implies() {
    use mipnerf_data::focal::{FILM_DIAGONAL_MM, FocalSource, exif_focal};
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/exif");
    let near = |a: f64, b: f64| ((a - b) / b).abs() < TOL_EXIF_FOCAL;
    // A square photo is no camera's frame: a crop keeping the frame's short side (24 mm).
    let f = exif_focal(&dir.join("film35_square.jpg"), 20, 20).unwrap();
    assert!(near(f.focal_px, 46.0 * 20.0 / 24.0), "{f:?}");
    assert_eq!(f.source, FocalSource::Film35mm { focal_35mm: 46.0, cropped: true });
    // The same photo read at twice the size: the focal length in pixels doubles.
    assert!(near(exif_focal(&dir.join("film35_square.jpg"), 40, 40).unwrap().focal_px, 46.0 * 40.0 / 24.0));
    // A 3:2 photo is the whole frame: the diagonals correspond.
    let f = exif_focal(&dir.join("film35_whole.jpg"), 30, 20).unwrap();
    assert!(near(f.focal_px, 46.0 * 30f64.hypot(20.0) / FILM_DIAGONAL_MM), "{f:?}");
    assert_eq!(f.source, FocalSource::Film35mm { focal_35mm: 46.0, cropped: false });
    // The sensor's pixel pitch (6000 px over 23.5 mm), from the 6000x4000 the camera recorded to
    // the photo's 30x20.
    let f = exif_focal(&dir.join("focal_plane.jpg"), 30, 20).unwrap();
    assert!(near(f.focal_px, 31.0 * (6000.0 / 23.5) * (30.0 / 6000.0)), "{f:?}");
    assert!(matches!(f.source, FocalSource::FocalPlane { focal_mm: 31.0, .. }), "{f:?}");
    // Recorded 6000x4000 but the photo is square: the pitch is not trusted; the 35 mm route.
    let f = exif_focal(&dir.join("focal_plane_cropped.jpg"), 20, 20).unwrap();
    assert_eq!(f.source, FocalSource::Film35mm { focal_35mm: 46.0, cropped: true });
    // Nothing to read: no check, no error.
    assert_eq!(exif_focal(&dir.join("no_exif.jpg"), 20, 20), None);
    assert_eq!(exif_focal(&dir.join("missing.jpg"), 20, 20), None);
    assert_eq!(exif_focal(&dir.join("film35_square.jpg"), 0, 20), None);
}

/// On the real capture `ethiopian_head` (../shared; skipped with a line when absent): its 1000
/// px photos, cut square from a Nikon D3300's 6000x4000 frame, imply 1917 px from their EXIF
/// (46 mm in 35 mm terms), within 2% of the 1886 px of the capture's own poses, where the 1327 px
/// of a COLMAP run from a prior that took the square for the whole frame is 1.44x off.
#[test]
fn ethiopian_heads_exif_agrees_with_its_poses() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real/ethiopian_head");
    let photo = root.join("images_4/DSC_0047.JPG");
    if !photo.is_file() {
        eprintln!("skipped: {} is absent (../shared is not beside the checkout)", photo.display());
        return;
    }
    let f = mipnerf_data::focal::exif_focal(&photo, 1000, 1000).unwrap();
    let rows = llff::read_poses_bounds(&root.join("poses_bounds.npy")).unwrap();
    let poses = rows[0][14] * 1000.0 / rows[0][4];
    assert!((f.focal_px / poses - 1.0).abs() < 0.02, "EXIF {f:?}, poses {poses}");
    let check = mipnerf_data::focal::FocalCheck {
        colmap_px: 1327.0,
        exif: f,
        photo: "DSC_0047.JPG".into(),
        photos_with_exif: 1,
    };
    assert!(check.disagrees() && (check.ratio() - 1.44).abs() < 0.01, "{}", check.ratio());
}
