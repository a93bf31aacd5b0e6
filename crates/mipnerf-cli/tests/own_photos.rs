//! `mipnerf colmap`, the process step from a COLMAP workspace to a dataset, on real pycolmap
//! output (tests/data/colmap_workspaces: one workspace per camera model that needs undistorting,
//! two of them with more than one model; tests/data/colmap_lego: a PINHOLE model COLMAP
//! undistorted itself), and the own-photos guide (docs/guide/own-photos.md) followed as written.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use common::{STDERR_FOLLOWS, copy_dir, run_err, run_ok};

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data")
}

fn workspace(model: &str) -> PathBuf {
    fixtures().join("colmap_workspaces").join(model)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn pngs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    v.sort();
    v
}

#[test]
fn the_largest_of_several_models_is_taken_and_the_dataset_trains() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let ws = workspace("simple_radial");
    let text = run_ok(&["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "200"]);
    // pycolmap's mapper made two models here: 2 and 37 registered photos.
    assert!(
        text.contains("2 COLMAP models (sparse/0 registers 2, sparse/1 registers 37): took sparse/1, the largest"),
        "{text}"
    );
    assert!(text.contains("sparse/1: 37 of 40 photos registered"), "{text}");
    assert!(text.contains("camera: SIMPLE_RADIAL 320x320") && text.contains("SimpleRadial { k: -0.12"), "{text}");
    assert!(text.contains("held out for testing (5 of 37, every 8th by name): r_1.jpg,"), "{text}");
    assert!(text.contains("scene bounds: near ") && text.contains("cameras all around the scene"), "{text}");
    assert!(!text.contains("warning"), "{text}");
    // 320 px photos undistort to 325 px; factor 2 brings them under 200.
    assert!(
        text.contains("undistorted to a centred pinhole 325x325") && text.contains("at 162x162 (factor 2)"),
        "{text}"
    );
    let images = pngs(&scene.join("images_2"));
    assert_eq!(images.len(), 37);
    assert_eq!(image::image_dimensions(&images[0]).unwrap(), (162, 162));
    let rows = mipnerf_data::llff::read_poses_bounds(&scene.join("poses_bounds.npy")).unwrap();
    assert_eq!(rows.len(), 37);
    assert_eq!([rows[0][4], rows[0][9], rows[0][14]], [325.0, 325.0, rows[0][14]]);
    assert!(!dir.path().join("scene").join(".mipnerf-partial-images_2").exists());
    // The command it prints trains (shortened to a few steps).
    let line = text.lines().find(|l| l.trim_start().starts_with("mipnerf train")).expect("a train command");
    let run = dir.path().join("run");
    let mut args: Vec<String> = line.split_whitespace().skip(1).map(str::to_owned).collect();
    let out = args.iter().position(|a| a == "--out").unwrap();
    args[out + 1] = s(&run).to_owned();
    let budget = args.iter().position(|a| a == "--time-budget").unwrap();
    args.splice(budget..budget + 2, ["--steps".to_owned(), "3".to_owned()]);
    assert_eq!(
        args[..6],
        ["train", "--data", s(&scene), "--llff-factor", "2", "--spherify"].map(str::to_owned),
        "{line}"
    );
    let argv: Vec<&str> = args.iter().map(String::as_str).collect();
    let trained = run_ok(&argv);
    assert!(trained.contains("(Llff, 32 views"), "{trained}");
}

#[test]
fn every_camera_model_is_undistorted_and_a_pinhole_passes_through() {
    for (model, registered, name) in
        [("simple_radial", 37, "SIMPLE_RADIAL"), ("radial", 35, "RADIAL"), ("opencv", 30, "OPENCV")]
    {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene");
        let text = run_ok(&["colmap", "--input", s(&workspace(model)), "--output", s(&scene), "--max-size", "0"]);
        assert!(text.contains(&format!("{registered} of 40 photos registered")), "{model}: {text}");
        assert!(text.contains(&format!("camera: {name} 320x320")), "{model}: {text}");
        assert!(text.contains("(factor 1)"), "{model}: {text}");
        assert_eq!(pngs(&scene.join("images_1")).len(), registered, "{model}");
    }
    // COLMAP's own undistorted output (PINHOLE, centred): the photos come through unchanged.
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let lego = fixtures().join("colmap_lego");
    let text = run_ok(&["colmap", "--input", s(&lego), "--output", s(&scene), "--max-size", "0"]);
    assert!(text.contains("camera: PINHOLE") && text.contains("distortion None"), "{text}");
    let written = pngs(&scene.join("images_1"));
    let mut originals = pngs(&lego.join("images"));
    originals.sort_by_key(|p| p.file_name().unwrap().to_owned());
    assert_eq!(written.len(), originals.len());
    for w in &written {
        // Written as NNNN_<name>.png, in name order.
        let stem = w.file_name().unwrap().to_str().unwrap()[5..].to_owned();
        let original = lego.join("images").join(&stem);
        let a = image::open(w).unwrap().to_rgba8();
        let b = image::open(&original).unwrap().to_rgba8();
        assert_eq!(a.dimensions(), b.dimensions(), "{stem}");
        assert!(a.as_raw() == b.as_raw(), "{stem}: a centred pinhole photo must pass through unchanged");
    }
}

#[test]
fn the_process_step_refuses_what_it_cannot_use_and_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let ws = workspace("simple_radial");
    let scene = dir.path().join("scene");
    // Too few registered photos for the minimum asked.
    let e = run_err(&["colmap", "--input", s(&ws), "--output", s(&scene), "--min-views", "38"]);
    assert!(
        e.contains("registers 37 of 40 photos, fewer than the minimum of 38 (--min-views)") && e.contains("sparse/1"),
        "{e}"
    );
    assert!(!scene.join("poses_bounds.npy").exists());
    // A non-empty output folder is never written into without --overwrite ...
    std::fs::create_dir_all(&scene).unwrap();
    std::fs::write(scene.join("mine.txt"), "keep").unwrap();
    let e = run_err(&["colmap", "--input", s(&ws), "--output", s(&scene)]);
    assert!(e.contains("is not empty") && e.contains("--overwrite"), "{e}");
    assert_eq!(std::fs::read_to_string(scene.join("mine.txt")).unwrap(), "keep");
    // ... and with it, the dataset is replaced (and the user's file left alone).
    run_ok(&["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "200", "--overwrite"]);
    assert_eq!(pngs(&scene.join("images_2")).len(), 37);
    assert_eq!(std::fs::read_to_string(scene.join("mine.txt")).unwrap(), "keep");

    // A registered photo missing from images/: named, and no dataset left looking complete.
    let broken = dir.path().join("broken");
    copy_dir(&ws, &broken);
    std::fs::remove_file(broken.join("images/r_30.jpg")).unwrap();
    let out = dir.path().join("out1");
    let e = run_err(&["colmap", "--input", s(&broken), "--output", s(&out)]);
    assert!(e.contains("r_30.jpg") && e.contains("missing from images/"), "{e}");
    assert!(!out.join("poses_bounds.npy").exists());
    // A photo of another size than the camera's.
    image::RgbImage::new(100, 80).save(broken.join("images/r_30.jpg")).unwrap();
    let e = run_err(&["colmap", "--input", s(&broken), "--output", s(&dir.path().join("out2"))]);
    assert!(e.contains("r_30.jpg") && e.contains("is 100x80, the COLMAP camera is 320x320"), "{e}");

    // A camera model mipnerf cannot undistort (a fisheye), named with what to do.
    let fisheye = dir.path().join("fisheye");
    std::fs::create_dir_all(fisheye.join("sparse/0")).unwrap();
    let lego = fixtures().join("colmap_lego");
    copy_dir(&lego.join("images"), &fisheye.join("images"));
    for f in ["images.txt", "points3D.txt"] {
        std::fs::copy(lego.join("text").join(f), fisheye.join("sparse/0").join(f)).unwrap();
    }
    let cameras = std::fs::read_to_string(lego.join("text/cameras.txt")).unwrap();
    let line = cameras.lines().find(|l| !l.starts_with('#')).unwrap();
    let f: Vec<&str> = line.split_whitespace().collect();
    let fish = format!("{} OPENCV_FISHEYE {} {} {} {} {} {} 0.01 0 0 0\n", f[0], f[2], f[3], f[4], f[4], f[6], f[7]);
    std::fs::write(fisheye.join("sparse/0/cameras.txt"), fish).unwrap();
    let e = run_err(&["colmap", "--input", s(&fisheye), "--output", s(&dir.path().join("out3"))]);
    assert!(e.contains("OPENCV_FISHEYE, which mipnerf cannot undistort") && e.contains("cameras"), "{e}");

    // No images/ folder, and no sparse/ folder.
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let e = run_err(&["colmap", "--input", s(&empty), "--output", s(&dir.path().join("out4"))]);
    assert!(e.contains("no images/ folder"), "{e}");
    std::fs::create_dir_all(empty.join("images")).unwrap();
    let e = run_err(&["colmap", "--input", s(&empty), "--output", s(&dir.path().join("out4"))]);
    assert!(e.contains("sparse"), "{e}");
}

#[test]
fn few_registered_photos_are_a_warning_above_the_minimum() {
    let dir = tempfile::tempdir().unwrap();
    let ws = workspace("simple_radial");
    // The mapper's small model alone: 2 registered photos.
    let small = dir.path().join("small");
    copy_dir(&ws.join("images"), &small.join("images"));
    copy_dir(&ws.join("sparse/0"), &small.join("sparse/0"));
    let e = run_err(&["colmap", "--input", s(&small), "--output", s(&dir.path().join("a"))]);
    assert!(e.contains("registers 2 of 40 photos, fewer than the minimum of 8"), "{e}");
    let text = run_ok(&["colmap", "--input", s(&small), "--output", s(&dir.path().join("b")), "--min-views", "2"]);
    assert!(text.contains("warning: only 2 photos are registered; 25 or more"), "{text}");
}

/// The shell commands of the own-photos guide's block (`docs/guide/own-photos.md`),
/// continuation lines joined, comments dropped.
fn readme_commands() -> Vec<String> {
    let guide = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/guide/own-photos.md");
    let readme = std::fs::read_to_string(guide).unwrap();
    let start = readme.find("<!-- own-photos:begin -->").expect("the guide marks its own-photos block");
    let end = readme.find("<!-- own-photos:end -->").unwrap();
    let block = &readme[start..end];
    let mut commands = Vec::new();
    let mut current = String::new();
    for line in block.lines().filter(|l| !l.starts_with("```") && !l.starts_with("<!--")) {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(head) = line.strip_suffix('\\') {
            current.push_str(head);
            continue;
        }
        current.push_str(line);
        commands.push(std::mem::take(&mut current));
    }
    commands
}

#[test]
fn the_readmes_own_photos_section_works_as_written() {
    let commands = readme_commands();
    let (colmap, ours): (Vec<&String>, Vec<&String>) = commands.iter().partition(|c| !c.starts_with("mipnerf "));
    // Step 1 is COLMAP's (its result here is the committed workspace, made by pycolmap with the
    // same settings: scripts/data/make-colmap-workspaces.py).
    assert_eq!(colmap.len(), 4, "{colmap:?}");
    assert!(colmap.iter().all(|c| c.starts_with("colmap ") || c.starts_with("mkdir ")), "{colmap:?}");
    for option in ["domain_size_pooling", "estimate_affine_shape", "peak_threshold 0.004", "init_min_num_inliers 50"] {
        assert!(commands.iter().any(|c| c.contains(option)), "the guide's COLMAP step sets {option}");
    }
    let script = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/data/make-colmap-workspaces.py"),
    )
    .unwrap();
    for option in [
        "domain_size_pooling = True",
        "estimate_affine_shape = True",
        "peak_threshold = 0.004",
        "init_min_num_inliers = 50",
        "abs_pose_min_num_inliers = 15",
    ] {
        assert!(script.contains(option), "the workspaces were made with {option}");
    }
    let dir = tempfile::tempdir().unwrap();
    let ws = workspace("simple_radial");
    copy_dir(&ws.join("images"), &dir.path().join("workspace/images"));
    copy_dir(&ws.join("sparse"), &dir.path().join("workspace/sparse"));
    let train_line = ours.iter().find(|c| c.starts_with("mipnerf train")).unwrap().to_string();
    for c in &ours {
        // The only changes: a few steps instead of 15 minutes, two frames instead of 120.
        let shortened = c.replace("--time-budget 15m", "--steps 20").replace("--frames 120", "--frames 2");
        let args: Vec<&str> = shortened.split_whitespace().skip(1).collect();
        let out = common::command().current_dir(dir.path()).args(&args).output().unwrap();
        let text =
            String::from_utf8_lossy(&out.stdout).to_string() + STDERR_FOLLOWS + &String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{c}:\n{text}");
        if c.starts_with("mipnerf colmap") {
            // Step 3's train command is the one step 2 prints, word for word.
            assert!(text.contains(&format!("train with:\n  {train_line}\n")), "README: {train_line}\nprinted:\n{text}");
        }
    }
    assert!(dir.path().join("runs/scene/eval/index.html").is_file());
    assert!(dir.path().join("orbit/preview.gif").is_file());
}

/// Photos all around an object with surroundings that are no plain backdrop (here the real
/// workspace's photos with their white borders painted over in varied colours, as a room's
/// would be): the process step says the scene trains unbounded and prints `--unbounded` in the
/// train command, which trains.
#[test]
fn photos_all_around_in_their_surroundings_train_unbounded() {
    let dir = tempfile::tempdir().unwrap();
    let ws = dir.path().join("workspace");
    copy_dir(&workspace("simple_radial").join("images"), &ws.join("images"));
    copy_dir(&workspace("simple_radial").join("sparse"), &ws.join("sparse"));
    for entry in std::fs::read_dir(ws.join("images")).unwrap() {
        let path = entry.unwrap().path();
        let mut img = image::open(&path).unwrap().to_rgb8();
        let (w, h) = img.dimensions();
        for (x, y, p) in img.enumerate_pixels_mut() {
            if x < w / 8 || x >= w - w / 8 || y < h / 8 || y >= h - h / 8 {
                *p = image::Rgb([(x * 7 % 200) as u8 + 30, (y * 5 % 180) as u8 + 40, ((x + y) * 3 % 150) as u8 + 50]);
            }
        }
        img.save(&path).unwrap();
    }
    let scene = dir.path().join("scene");
    let text = run_ok(&["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "100"]);
    assert!(text.contains("no plain backdrop") && text.contains("training the scene unbounded (--unbounded"), "{text}");
    let line = text.lines().find(|l| l.trim_start().starts_with("mipnerf train")).expect("a train command");
    assert!(line.contains(" --unbounded ") && !line.contains("--spherify"), "{line}");
    let run = dir.path().join("run");
    let shortened = line.replace("--time-budget 15m", "--steps 3").replace("runs/scene", s(&run));
    let args: Vec<&str> = shortened.split_whitespace().skip(1).collect();
    let trained = run_ok(&args);
    assert!(trained.contains("unbounded: the farthest camera on the unit sphere"), "{trained}");
}

/// `--exclude` leaves registered photos out of the dataset (the photos the step names as
/// possibly wrong, or any; a name given twice or an empty one counts once or not at all), says
/// so, and refuses a name the model does not register or leaving out too many, writing nothing.
#[test]
fn photos_named_by_exclude_are_left_out() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let ws = workspace("radial");
    let text = run_ok(&["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "100"]);
    // A photo with few 3D points is named, with the flag that leaves it out.
    assert!(
        text.contains("COLMAP may have got 1 photos wrong") && text.contains("r_17.jpg: sees 9 3D points"),
        "{text}"
    );
    assert!(text.contains("run this step again with --exclude r_17.jpg --overwrite"), "{text}");
    let text = run_ok(&[
        "colmap",
        "--input",
        s(&ws),
        "--output",
        s(&scene),
        "--max-size",
        "100",
        "--exclude",
        "r_17.jpg,r_1.jpg,r_17.jpg,",
        "--overwrite",
    ]);
    assert!(text.contains("35 of 40 photos registered, 2 left out (--exclude): r_17.jpg, r_1.jpg; 33 kept"), "{text}");
    assert!(!text.contains("may have got"), "{text}");
    assert_eq!(pngs(&scene.join("images_4")).len(), 33);
    let fresh = dir.path().join("fresh");
    let err = run_err(&["colmap", "--input", s(&ws), "--output", s(&fresh), "--exclude", "nope.jpg"]);
    assert!(err.contains("--exclude nope.jpg: the model registers no photo of that name"), "{err}");
    assert!(!fresh.exists());
    // Leaving out too many says so (not "take more photos"), and the photos' own folder is no
    // folder of masks.
    let model = mipnerf_data::colmap::read_model(&ws.join("sparse/0")).unwrap();
    let many = model.images.iter().skip(3).map(|im| im.name.as_str()).collect::<Vec<_>>().join(",");
    let err = run_err(&["colmap", "--input", s(&ws), "--output", s(&fresh), "--exclude", &many]);
    assert!(err.contains("leaves") && err.contains("(--exclude)") && err.contains("leave out fewer photos"), "{err}");
    let images = ws.join("images");
    let err = run_err(&["colmap", "--input", s(&ws), "--output", s(&fresh), "--masks", s(&images)]);
    assert!(err.contains("the photos' own folder") && err.contains(s(&images)), "{err}");
    assert!(!fresh.exists());
}

/// The first APP1 (EXIF) segment of a JPEG, its marker included.
fn app1_segment(jpeg: &[u8]) -> &[u8] {
    let mut i = 2;
    while i + 4 <= jpeg.len() && jpeg[i] == 0xFF {
        let len = usize::from(u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]));
        if jpeg[i + 1] == 0xE1 {
            return &jpeg[i..i + 2 + len];
        }
        i += 2 + len;
    }
    panic!("no APP1 segment");
}

/// A copy of the real `simple_radial` workspace whose photos carry the EXIF of the fixture
/// `exif` (tests/data/exif, written by Pillow: scripts/data/make-exif-fixtures.py), spliced in after
/// each JPEG's start marker.
fn workspace_with_exif(dir: &Path, exif: &str) -> PathBuf {
    let ws = dir.join(format!("workspace-{exif}"));
    copy_dir(&workspace("simple_radial").join("sparse"), &ws.join("sparse"));
    std::fs::create_dir_all(ws.join("images")).unwrap();
    let fixture = std::fs::read(fixtures().join("exif").join(exif)).unwrap();
    let segment = app1_segment(&fixture);
    for entry in std::fs::read_dir(workspace("simple_radial").join("images")).unwrap() {
        let path = entry.unwrap().path();
        let photo = std::fs::read(&path).unwrap();
        let spliced = [&photo[..2], segment, &photo[2..]].concat();
        std::fs::write(ws.join("images").join(path.file_name().unwrap()), spliced).unwrap();
    }
    ws
}

/// `mipnerf colmap` checks COLMAP's focal length (here pycolmap's 444 px for 320 px lego photos)
/// against the one the photos' EXIF implies: 33 mm in 35 mm terms on a square crop agrees (440
/// px); 66 mm (880 px) does not, and the step says how to run COLMAP again with it given; photos
/// without EXIF say the focal length was not checked.
#[test]
fn colmaps_focal_length_is_checked_against_the_photos_exif() {
    let dir = tempfile::tempdir().unwrap();
    let ws = workspace_with_exif(dir.path(), "square_33mm.jpg");
    let text = run_ok(&["colmap", "--input", s(&ws), "--output", s(&dir.path().join("a")), "--max-size", "100"]);
    assert!(
        text.contains("focal length: COLMAP's 44")
            && text.contains("agrees with the photos' EXIF, 440 px (33 mm in 35 mm terms"),
        "{text}"
    );
    assert!(text.contains("37 of 37 photos have one") && !text.contains("warning"), "{text}");
    let ws = workspace_with_exif(dir.path(), "square_66mm.jpg");
    let text = run_ok(&["colmap", "--input", s(&ws), "--output", s(&dir.path().join("b")), "--max-size", "100"]);
    let (_, err) = text.split_once(STDERR_FOLLOWS).unwrap();
    assert!(
        err.contains("warning: COLMAP's focal length, 44")
            && err.contains("shorter than the one the photos' EXIF implies, 880 px"),
        "{err}"
    );
    assert!(err.contains("--ImageReader.camera_params \"880.0,160.0,160.0,0\""), "{err}");
    assert!(err.contains("--Mapper.ba_refine_focal_length 0 --Mapper.abs_pose_refine_focal_length 0"), "{err}");
    // Still written: the check warns, the user decides.
    assert_eq!(pngs(&dir.path().join("b").join("images_4")).len(), 37);
    let text = run_ok(&[
        "colmap",
        "--input",
        s(&workspace("simple_radial")),
        "--output",
        s(&dir.path().join("c")),
        "--max-size",
        "100",
    ]);
    assert!(text.contains("focal length: no photo has an EXIF focal length"), "{text}");
}

/// `mipnerf colmap --masks DIR` carries each photo's mask through the undistortion and the
/// downscaling to `masks_N/`, named as `images_N/` is, so the printed command (`--spherify
/// --masks`) trains the object alone; a missing, all-black or wrongly sized mask is refused
/// naming its file, before anything is written.
#[test]
fn masks_go_through_the_process_step_with_their_photos() {
    let dir = tempfile::tempdir().unwrap();
    let ws = workspace("simple_radial");
    // Masks of the lego photos: white where a photo is not its white backdrop.
    let masks = dir.path().join("masks");
    std::fs::create_dir_all(&masks).unwrap();
    for entry in std::fs::read_dir(ws.join("images")).unwrap() {
        let path = entry.unwrap().path();
        let photo = image::open(&path).unwrap().to_rgb8();
        let mask = image::GrayImage::from_fn(photo.width(), photo.height(), |x, y| {
            image::Luma([if photo.get_pixel(x, y).0.iter().any(|&c| c < 230) { 255 } else { 0 }])
        });
        mask.save(masks.join(format!("{}.png", path.file_stem().unwrap().to_str().unwrap()))).unwrap();
    }
    let scene = dir.path().join("scene");
    let text = run_ok(&["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "100", "--masks", s(&masks)]);
    let written = scene.join("masks_4");
    assert!(
        text.contains(&format!("masks: undistorted and downscaled as the photos are, in {}", written.display())),
        "{text}"
    );
    let (images, mask_files) = (pngs(&scene.join("images_4")), pngs(&written));
    assert_eq!(images.len(), 37);
    let names = |v: &[PathBuf]| v.iter().map(|p| p.file_name().unwrap().to_owned()).collect::<Vec<_>>();
    assert_eq!(names(&images), names(&mask_files));
    // Each written mask covers its written photo's object: the pixels where they disagree are
    // the object's edge, a few percent of the photo.
    let mut worst = 0.0f64;
    for (image, mask) in images.iter().zip(&mask_files) {
        let (image, mask) = (image::open(image).unwrap().to_rgb8(), image::open(mask).unwrap().to_luma8());
        assert_eq!(image.dimensions(), mask.dimensions());
        let disagree =
            image.pixels().zip(mask.pixels()).filter(|(p, m)| p.0.iter().any(|&c| c < 230) != (m.0[0] >= 128)).count();
        worst = worst.max(disagree as f64 / f64::from(image.width() * image.height()));
    }
    eprintln!("written masks against their photos' objects: at most {worst:.4} of the pixels disagree");
    assert!(worst < MASK_EDGE_SHARE, "{worst:.4} of a photo's pixels disagree with its mask");
    let line = text.lines().find(|l| l.trim_start().starts_with("mipnerf train")).expect("a train command");
    assert!(
        line.contains(&format!(" --spherify --masks {} ", written.display())) && !line.contains("--unbounded"),
        "{line}"
    );
    let run = dir.path().join("run");
    let shortened = line.replace("--time-budget 15m", "--steps 3").replace("runs/scene", s(&run));
    let args: Vec<&str> = shortened.split_whitespace().skip(1).collect();
    run_ok(&args);
    // Bad masks: nothing is written.
    let fresh = dir.path().join("fresh");
    std::fs::remove_file(masks.join("r_1.png")).unwrap();
    let err = run_err(&["colmap", "--input", s(&ws), "--output", s(&fresh), "--masks", s(&masks)]);
    assert!(err.contains("r_1.png") && err.contains("no mask for photo r_1.jpg"), "{err}");
    image::GrayImage::new(320, 320).save(masks.join("r_1.png")).unwrap();
    let err = run_err(&["colmap", "--input", s(&ws), "--output", s(&fresh), "--masks", s(&masks)]);
    assert!(err.contains("r_1.png") && err.contains("all black"), "{err}");
    image::GrayImage::from_pixel(100, 80, image::Luma([255])).save(masks.join("r_1.png")).unwrap();
    let err = run_err(&["colmap", "--input", s(&ws), "--output", s(&fresh), "--masks", s(&masks)]);
    assert!(err.contains("r_1.png") && err.contains("the mask is 100x80 but its photo is 320x320"), "{err}");
    assert!(!fresh.exists());
}

/// The share of a written photo's pixels where its written mask and its own backdrop test
/// disagree (the object's edge, box-filtered and JPEG-blurred): measured at most 0.014.
const MASK_EDGE_SHARE: f64 = 0.03;
