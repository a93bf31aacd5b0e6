//! `train --masks DIR`: photos of an object in a room, with a foreground mask per photo, train
//! the object alone; bad masks are refused naming the file.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use common::{run_err, run_ok};
use mipnerf_core::camera::Camera;
use mipnerf_core::demo;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// How much darker than the demo scene's own colours the photographed object is: a dark object
/// over a white (or random) background is where a model's colour could die (a masked real
/// capture once rendered grey).
const DARKEN: f32 = 0.3;

/// The colour of the "room" behind the object in pixel `(x, y)`: a bright, colourful pattern
/// that differs between photos, which the masks must leave out.
fn room(x: u32, y: u32, view: usize) -> [u8; 3] {
    let t = (x + 2 * y + 7 * view as u32) % 32;
    [200 + (t as u8), 120 + 3 * (t as u8), 40 + 5 * (t as u8)]
}

/// Writes the demo scene, darkened by [`DARKEN`], as LLFF photos of an object in a room: `n`
/// `size`-pixel RGB photos in `images/` (the room wherever the object is not), their masks in
/// `masks/` (white = the object), and `poses_bounds.npy`.
fn masked_capture(dir: &Path, size: u32, n: usize) -> PathBuf {
    let data = dir.join("capture");
    for sub in ["images", "masks"] {
        std::fs::create_dir_all(data.join(sub)).unwrap();
    }
    let mut rows = Vec::new();
    for (i, pose) in demo::view_poses(n, 0.0).into_iter().enumerate() {
        let cam = Camera::from_camera_angle_x(size, size, demo::CAMERA_ANGLE_X, pose).unwrap();
        let rgba = demo::render_view(&cam, 2);
        let mut photo = image::RgbImage::new(size, size);
        let mut mask = image::GrayImage::new(size, size);
        for (k, p) in rgba.chunks_exact(4).enumerate() {
            let (x, y) = (k as u32 % size, k as u32 / size);
            let a = p[3];
            let bg = room(x, y, i);
            let px: [u8; 3] =
                std::array::from_fn(|c| (p[c] * DARKEN * 255.0 * a + f32::from(bg[c]) * (1.0 - a)).round() as u8);
            photo.put_pixel(x, y, image::Rgb(px));
            mask.put_pixel(x, y, image::Luma([(a * 255.0).round() as u8]));
        }
        photo.save(data.join(format!("images/view{i:03}.png"))).unwrap();
        mask.save(data.join(format!("masks/view{i:03}.png"))).unwrap();
        // LLFF's columns: [down, right, back] (the demo pose's [right, up, back]), the centre, and
        // [height, width, focal]; then near and far.
        let focal = mipnerf_core::camera::focal_from_camera_angle_x(size, demo::CAMERA_ANGLE_X);
        let mut row = [0.0f64; 17];
        for r in 0..3 {
            let m = [-pose[r][1], pose[r][0], pose[r][2], pose[r][3], [f64::from(size), f64::from(size), focal][r]];
            row[r * 5..r * 5 + 5].copy_from_slice(&m);
        }
        row[15] = 2.0;
        row[16] = 6.0;
        rows.push(row);
    }
    mipnerf_data::llff::write_poses_bounds(&data.join("poses_bounds.npy"), &rows).unwrap();
    data
}

/// `mipnerf train` on the capture in `data`, spherified, with the masks in `masks`, for `steps`
/// steps into `out`, then `extra`.
fn train_args(data: &Path, masks: &Path, steps: &str, out: &Path, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> =
        ["train", "--data", s(data), "--llff-factor", "0", "--spherify", "--masks", s(masks), "--steps", steps]
            .map(String::from)
            .to_vec();
    args.extend(["--out", s(out)].map(String::from));
    args.extend(extra.iter().map(|a| (*a).to_string()));
    args
}

fn strs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

/// Mean over pixels of `max(r, g, b) - min(r, g, b)` where `inside` holds: how much colour an
/// image has.
fn chroma(img: &image::RgbImage, inside: impl Fn(u32, u32) -> bool) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (x, y, p) in img.enumerate_pixels() {
        if inside(x, y) {
            let (hi, lo) = (p.0.iter().max().unwrap(), p.0.iter().min().unwrap());
            sum += f64::from(hi - lo) / 255.0;
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// The fraction of the held-out photos' colour (inside their masks) that the renders keep must be
/// at least this: a model whose colour died draws the object in exact greys (0).
const MIN_COLOUR_KEPT: f64 = 0.5;

/// A dark, coloured object photographed in a bright room, with masks: trained with `--masks`
/// (spherified, the fast preset), its held-out renders show the object alone over white, in
/// colour. Before masks were read, nothing took them, and the LLFF loader dropped a photo's alpha from
/// its targets.
#[test]
fn a_dark_coloured_object_with_masks_keeps_its_colours_and_leaves_the_room_out() {
    let dir = tempfile::tempdir().unwrap();
    let data = masked_capture(dir.path(), 32, 24);
    let run = dir.path().join("run");
    let args = train_args(&data, &data.join("masks"), "400", &run, &["--preset", "fast", "--quiet"]);
    let text = run_ok(&strs(&args));
    assert!(text.contains("note: 21 photos masked by"), "{text}");
    assert!(text.contains("carved by the training masks"), "{text}");
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config.contains("random_bkgd = true") && config.contains("white_bkgd = true"), "{config}");
    assert!(config.contains("spherify_radius = 4.0"), "{config}");
    run_ok(&["eval", "--run", s(&run), "--quiet"]);
    // Test photos 0, 8 and 16: their ground truth is the object over white, the room left out.
    let eval = run.join("eval");
    let (mut kept, mut truth) = (0.0, 0.0);
    for i in [0, 8, 16] {
        let gt = image::open(eval.join(format!("view{i:03}_gt.png"))).unwrap().to_rgb8();
        let render = image::open(eval.join(format!("view{i:03}.png"))).unwrap().to_rgb8();
        let mask = image::open(data.join(format!("masks/view{i:03}.png"))).unwrap().to_luma8();
        // Where the mask is empty the ground truth is white: the room is gone from the targets.
        let outside = |x: u32, y: u32| mask.get_pixel(x, y).0[0] == 0;
        assert!(gt.enumerate_pixels().filter(|(x, y, _)| outside(*x, *y)).all(|(_, _, p)| p.0 == [255; 3]));
        let inside = |x: u32, y: u32| mask.get_pixel(x, y).0[0] == 255;
        truth += chroma(&gt, inside);
        kept += chroma(&render, inside);
    }
    assert!(truth > 0.05, "the object is coloured: {truth}");
    assert!(kept >= MIN_COLOUR_KEPT * truth, "renders keep {kept:.4} of the photos' {truth:.4} colour");
}

/// A missing mask, one of another size and an all-black one are refused before anything is
/// written, naming the file.
#[test]
fn bad_masks_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = masked_capture(dir.path(), 16, 9);
    let masks = data.join("masks");
    let train = |out: &str| {
        let run = dir.path().join(out);
        let text = run_err(&strs(&train_args(&data, &masks, "1", &run, &[])));
        assert!(!run.exists(), "a refused run leaves no folder: {text}");
        text
    };
    std::fs::remove_file(masks.join("view003.png")).unwrap();
    let text = train("missing");
    assert!(text.contains("view003.png") && text.contains("no mask for photo"), "{text}");
    image::GrayImage::new(12, 16).save(masks.join("view003.png")).unwrap();
    let text = train("size");
    assert!(text.contains("view003.png") && text.contains("the mask is 12x16 but its photo is 16x16"), "{text}");
    image::GrayImage::new(16, 16).save(masks.join("view003.png")).unwrap();
    let text = train("black");
    assert!(text.contains("view003.png") && text.contains("all black"), "{text}");
    // Two masks for one photo: which is meant is not guessed.
    image::GrayImage::from_pixel(16, 16, image::Luma([255])).save(masks.join("view003.png")).unwrap();
    std::fs::copy(masks.join("view003.png"), masks.join("view003.jpg")).unwrap();
    let text = train("two");
    assert!(text.contains("view003.png has 2 masks (view003.jpg, view003.png): keep one"), "{text}");
    let text = train_missing_folder(&data, dir.path());
    assert!(text.contains("no-such-masks") && text.contains("does not exist"), "{text}");
    // A mask that is there but is a FIFO or a device is named as what it is, never waited on
    // nor called missing.
    std::fs::remove_file(masks.join("view003.jpg")).unwrap();
    std::fs::remove_file(masks.join("view003.png")).unwrap();
    assert!(std::process::Command::new("mkfifo").arg(masks.join("view003.png")).status().unwrap().success());
    let text = train("fifo");
    assert!(text.contains("view003.png") && text.contains("is a FIFO (a named pipe), not a regular file"), "{text}");
    assert!(!text.contains("no mask for photo"), "{text}");
    std::fs::remove_file(masks.join("view003.png")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", masks.join("view003.png")).unwrap();
    let text = train("device");
    assert!(text.contains("view003.png") && text.contains("is a device (such as /dev/zero)"), "{text}");
}

/// Masks given with `--masks` that are white everywhere leave nothing out: `--background random`
/// says that of the masks, not that masks should be given.
#[test]
fn white_masks_with_a_random_background_are_named_as_leaving_nothing_out() {
    let dir = tempfile::tempdir().unwrap();
    let data = masked_capture(dir.path(), 16, 9);
    let masks = data.join("masks");
    for i in 0..9 {
        image::GrayImage::from_pixel(16, 16, image::Luma([255])).save(masks.join(format!("view{i:03}.png"))).unwrap();
    }
    let run = dir.path().join("run");
    let text = run_err(&strs(&train_args(&data, &masks, "1", &run, &["--background", "random"])));
    assert!(text.contains("white everywhere") && text.contains(s(&masks)), "{text}");
    assert!(!text.contains("give their masks with --masks"), "{text}");
}

fn train_missing_folder(data: &Path, dir: &Path) -> String {
    run_err(&strs(&train_args(data, &dir.join("no-such-masks"), "1", &dir.join("nofolder"), &[])))
}
