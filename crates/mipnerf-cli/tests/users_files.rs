//! A user's files are never lost nor mixed into: export over a device, a folder, a link or a
//! foreign file, and both exports on one path;
//! convert and colmap replacing or mixing into a user's dataset, or killing the old one when they
//! fail part-way; render folders mixing two renders.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use common::{copy_dir, run_err, run_ok, small_demo_scene, trained_demo_run};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data")
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().to_string()).collect();
    v.sort();
    v
}

#[test]
fn export_replaces_only_a_ply_file_it_wrote_and_never_both_outputs_on_one_path() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained_demo_run(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let export = |flag: &str, path: &Path, extra: &[&str]| {
        let mut args = vec!["export", "--run", s(&run), flag, s(path), "--min-opacity", "0.01"];
        args.extend_from_slice(extra);
        args.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let fails = |args: Vec<String>| run_err(&args.iter().map(String::as_str).collect::<Vec<_>>());

    // A folder, a link and a device-like file (a FIFO) are never replaced, --overwrite or not,
    // and nothing is left beside them.
    let folder = out.join("folder.ply");
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::write(folder.join("inside.txt"), "mine").unwrap();
    let e = fails(export("--points", &folder, &["--overwrite"]));
    assert!(e.contains("--points") && e.contains("is a folder"), "{e}");
    assert_eq!(std::fs::read_to_string(folder.join("inside.txt")).unwrap(), "mine");
    let target = out.join("target.txt");
    std::fs::write(&target, "the link's target").unwrap();
    let link = out.join("link.ply");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let e = fails(export("--mesh", &link, &["--overwrite"]));
    assert!(e.contains("is a symbolic link"), "{e}");
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "the link's target");
    let fifo = out.join("fifo.ply");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let e = fails(export("--points", &fifo, &["--overwrite"]));
    assert!(e.contains("not a regular file"), "{e}");
    assert!(std::os::unix::fs::FileTypeExt::is_fifo(&std::fs::symlink_metadata(&fifo).unwrap().file_type()));
    // A user's file, even a PLY one, is left as it is.
    let mine = out.join("mine.ply");
    std::fs::write(&mine, "ply\nformat ascii 1.0\nend_header\n").unwrap();
    let e = fails(export("--points", &mine, &["--overwrite"]));
    assert!(e.contains("is not a PLY file mipnerf export wrote"), "{e}");
    assert_eq!(std::fs::read_to_string(&mine).unwrap(), "ply\nformat ascii 1.0\nend_header\n");
    assert_eq!(names(&out), ["fifo.ply", "folder.ply", "link.ply", "mine.ply", "target.txt"], "nothing left beside");

    // --mesh and --points on one file (also through another spelling of the path): refused.
    let same = out.join("same.ply");
    let other_spelling = out.join("folder.ply/../same.ply");
    let mut args = export("--mesh", &same, &[]);
    args.extend(["--points".to_string(), s(&other_spelling).to_string()]);
    let e = fails(args);
    assert!(e.contains("--mesh and --points name the same file"), "{e}");
    assert!(!same.exists());

    // Its own file: refused without --overwrite, replaced with it.
    let ours = out.join("points.ply");
    run_ok(&export("--points", &ours, &[]).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(mipnerf_core::export::written_by_export(&ours));
    let e = fails(export("--points", &ours, &[]));
    assert!(e.contains("exists; pass --overwrite"), "{e}");
    run_ok(&export("--points", &ours, &["--overwrite"]).iter().map(String::as_str).collect::<Vec<_>>());

    // A grid that cannot fit in memory is refused before it is allocated, naming the flag.
    let need =
        mipnerf_core::export::mesh_nodes(glam::Vec3::splat(2.0), 1024) * mipnerf_core::export::MESH_BYTES_PER_NODE;
    let room = mipnerf_core::memory::available().map_or(u64::MAX, |a| a.bytes);
    assert!(need > room, "this test needs a machine with less than {need} bytes free (it has {room})");
    let e = fails(export("--mesh", &out.join("big.ply"), &["--resolution", "1024"]));
    assert!(e.contains("--resolution 1024") && e.contains("GiB") && e.contains("lower --resolution"), "{e}");
    assert!(!out.join("big.ply").exists());
}

#[test]
fn convert_refuses_a_users_files_and_never_mixes_its_images_into_theirs() {
    let dir = tempfile::tempdir().unwrap();
    let blender = fixtures().join("lego_tiny");
    // A user's metadata.json: refused without --overwrite, and kept when the conversion fails.
    let out = dir.path().join("multiscale");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("metadata.json"), "mine").unwrap();
    let e = run_err(&["convert", "--input", s(&blender), "--output", s(&out)]);
    assert!(e.contains("metadata.json") && e.contains("--overwrite"), "{e}");
    let e = run_err(&["convert", "--input", s(&dir.path().join("nothing")), "--output", s(&out), "--overwrite"]);
    assert!(e.contains("transforms_"), "{e}");
    assert_eq!(std::fs::read_to_string(out.join("metadata.json")).unwrap(), "mine");
    // Beside the user's file: the manifest, and the lock the conversion held (hidden, kept: a
    // lock file removed on exit would let two later runs each lock a different file).
    assert_eq!(names(&out), [".mipnerf-lock", ".mipnerf-outputs", "metadata.json"]);
    // With --overwrite the user's other files stay; the conversion is whole.
    std::fs::write(out.join("notes.txt"), "keep").unwrap();
    run_ok(&["convert", "--input", s(&blender), "--output", s(&out), "--size", "16", "--overwrite"]);
    assert_eq!(std::fs::read_to_string(out.join("notes.txt")).unwrap(), "keep");
    assert!(std::fs::read_to_string(out.join("metadata.json")).unwrap().contains("images_train"));
    // A conversion into a folder of only its own output needs no --overwrite; a failed one
    // leaves nothing behind in a folder it created.
    std::fs::remove_file(out.join("notes.txt")).unwrap();
    run_ok(&["convert", "--input", s(&blender), "--output", s(&out), "--size", "16"]);
    let fresh = dir.path().join("fresh");
    run_err(&["convert", "--input", s(&dir.path().join("nothing")), "--output", s(&fresh)]);
    assert!(!fresh.exists());

    // LLFF: a user's poses_bounds.npy and images_2/ are refused, and --overwrite does not mix
    // the conversion's images into the user's folder.
    let colmap = fixtures().join("colmap_lego");
    let llff = dir.path().join("llff");
    std::fs::create_dir_all(llff.join("images_2")).unwrap();
    std::fs::write(llff.join("poses_bounds.npy"), "my poses").unwrap();
    std::fs::write(llff.join("images_2/my_photo.png"), "my photo").unwrap();
    let args = ["convert", "--to", "llff", "--factor", "2", "--input", s(&colmap), "--output", s(&llff)];
    let e = run_err(&args);
    assert!(e.contains("--overwrite"), "{e}");
    let e = run_err(&[&args[..], &["--overwrite"]].concat());
    assert!(e.contains("images_2/ is a folder mipnerf did not write"), "{e}");
    assert_eq!(std::fs::read_to_string(llff.join("poses_bounds.npy")).unwrap(), "my poses");
    assert_eq!(names(&llff.join("images_2")), ["my_photo.png"]);
    // Into a new folder, twice: the images are replaced whole, as many as the poses.
    let fresh = dir.path().join("llff2");
    let args = ["convert", "--to", "llff", "--factor", "2", "--input", s(&colmap), "--output", s(&fresh)];
    run_ok(&args);
    let first = names(&fresh.join("images_2"));
    std::fs::write(fresh.join("images_2/stray.png"), "left by hand").unwrap();
    run_ok(&args);
    assert_eq!(names(&fresh.join("images_2")), first, "the folder is replaced whole, never mixed");
    let rows = mipnerf_data::llff::read_poses_bounds(&fresh.join("poses_bounds.npy")).unwrap();
    assert_eq!(rows.len(), first.len());
}

#[test]
fn colmap_overwrite_replaces_only_its_own_dataset_and_a_failed_run_keeps_the_old_one() {
    let dir = tempfile::tempdir().unwrap();
    let ws = fixtures().join("colmap_workspaces/simple_radial");
    let scene = dir.path().join("scene");
    let args = ["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "200"];
    run_ok(&args);
    let npy = std::fs::read(scene.join("poses_bounds.npy")).unwrap();
    let images = names(&scene.join("images_2"));
    std::fs::write(scene.join("notes.txt"), "keep").unwrap();

    // A run that fails part-way (a registered photo missing) leaves the old dataset whole.
    let broken = dir.path().join("broken");
    copy_dir(&ws, &broken);
    std::fs::remove_file(broken.join("images/r_30.jpg")).unwrap();
    let e = run_err(&["colmap", "--input", s(&broken), "--output", s(&scene), "--max-size", "200", "--overwrite"]);
    assert!(e.contains("r_30.jpg"), "{e}");
    assert_eq!(std::fs::read(scene.join("poses_bounds.npy")).unwrap(), npy, "the old index is kept");
    assert_eq!(names(&scene.join("images_2")), images, "the old images are kept");
    // The next run is not refused because of the partial folder the failed one left.
    run_ok(&[&args[..], &["--overwrite"]].concat());
    assert_eq!(std::fs::read_to_string(scene.join("notes.txt")).unwrap(), "keep");
    assert!(!names(&scene).iter().any(|n| n.starts_with(".mipnerf-partial")), "{:?}", names(&scene));

    // An index or image folder it did not write is left alone, --overwrite or not.
    let theirs = dir.path().join("theirs");
    std::fs::create_dir_all(&theirs).unwrap();
    std::fs::write(theirs.join("poses_bounds.npy"), "my poses").unwrap();
    let e = run_err(&["colmap", "--input", s(&ws), "--output", s(&theirs), "--max-size", "200", "--overwrite"]);
    assert!(e.contains("poses_bounds.npy that this step did not write"), "{e}");
    assert_eq!(std::fs::read_to_string(theirs.join("poses_bounds.npy")).unwrap(), "my poses");
    assert!(!theirs.join("images_2").exists());
}

#[test]
fn a_render_folder_never_mixes_two_renders() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained_demo_run(dir.path());
    let out = dir.path().join("renders");
    let render = |extra: &[&str]| {
        let mut args = vec!["render", "--run", s(&run), "--out", s(&out), "--backend", "cpu", "--quiet"];
        args.extend_from_slice(extra);
        run_ok(&args);
    };
    render(&["--path", "orbit", "--frames", "3", "--width", "16", "--height", "16"]);
    assert!(out.join("frame_0002.png").exists() && out.join("preview.gif").exists());
    // Fewer frames: the third frame of the earlier render is gone.
    render(&["--path", "orbit", "--frames", "2", "--width", "16", "--height", "16"]);
    assert!(!out.join("frame_0002.png").exists() && !out.join("frame_0002_depth.exr").exists());
    assert!(out.join("frame_0001.png").exists());
    // A split into the same folder: no frame or video of the path is left beside its images.
    std::fs::write(out.join("mine.txt"), "keep").unwrap();
    render(&["--split", "test", "--overwrite"]);
    let left = names(&out);
    assert!(!left.iter().any(|n| n.starts_with("frame_") || n == "preview.gif" || n == "video.mp4"), "{left:?}");
    assert_eq!(std::fs::read_to_string(out.join("mine.txt")).unwrap(), "keep");
}

/// A render into a dataset `mipnerf colmap` wrote (whose manifest lists its index) once removed
/// that index as an earlier render's output; now only a render's own outputs are replaced, and
/// the folder is refused without --overwrite, for a manifest that names its writers and for one
/// an older version wrote (names alone).
#[test]
fn a_render_never_removes_what_another_command_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained_demo_run(dir.path());
    let scene = dir.path().join("scene");
    let ws = fixtures().join("colmap_workspaces/simple_radial");
    run_ok(&["colmap", "--input", s(&ws), "--output", s(&scene), "--max-size", "64"]);
    let npy = std::fs::read(scene.join("poses_bounds.npy")).unwrap();
    let folder = names(&scene).into_iter().find(|n| n.starts_with("images_")).unwrap();
    let factor = folder.trim_start_matches("images_").to_owned();
    let manifest = scene.join(".mipnerf-outputs");
    let tagged = std::fs::read_to_string(&manifest).unwrap();
    assert!(tagged.contains("poses_bounds.npy\tcolmap"), "{tagged}");
    let untagged: String = tagged.lines().map(|l| format!("{}\n", l.split('\t').next().unwrap())).collect();
    for text in [tagged, untagged] {
        std::fs::write(&manifest, &text).unwrap();
        let args = ["render", "--run", s(&run), "--out", s(&scene), "--split", "test", "--backend", "cpu", "--quiet"];
        let e = run_err(&args);
        assert!(e.contains("poses_bounds.npy") && e.contains("--overwrite"), "{e}");
        run_ok(&[&args[..], &["--overwrite"]].concat());
        assert_eq!(std::fs::read(scene.join("poses_bounds.npy")).unwrap(), npy, "the dataset's index is kept");
        assert_eq!(names(&scene.join(&folder)).len(), 37, "its images are kept");
        // A second render replaces the first one's outputs, and only those.
        run_ok(&[&args[..], &["--overwrite", "--width", "8", "--height", "8"]].concat());
        assert!(scene.join("poses_bounds.npy").exists() && scene.join("cameras.json").exists());
        // And the dataset still trains.
        let again = dir.path().join(format!("again-{}", text.len()));
        run_ok(&[
            "train",
            "--data",
            s(&scene),
            "--llff-factor",
            &factor,
            "--spherify",
            "--steps",
            "1",
            "--out",
            s(&again),
            "--quiet",
        ]);
    }
}

#[test]
fn flags_that_would_do_nothing_sensible_are_refused_or_said_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 4);
    let train = |name: &str, extra: &[&str]| {
        let run = dir.path().join(name);
        let mut args = vec!["train", "--data", s(&data), "--out", s(&run), "--backend", "cpu", "--quiet"];
        args.extend_from_slice(extra);
        args.into_iter().map(str::to_string).collect::<Vec<_>>()
    };
    let fails = |args: Vec<String>| run_err(&args.iter().map(String::as_str).collect::<Vec<_>>());
    for bound in ["1e-30", "1e30"] {
        let e = fails(train("bound", &["--occupancy", "--occupancy-bound", bound, "--steps", "2"]));
        assert!(e.contains("--occupancy-bound") && e.contains("far from this scene's size"), "{bound}: {e}");
    }
    // The grid's settings without the grid (the tiny preset has none) would do nothing.
    let e = fails(train("no grid", &["--occupancy-resolution", "32", "--steps", "2"]));
    assert!(e.contains("--occupancy-resolution set(s) the occupancy grid") && e.contains("add --occupancy"), "{e}");
    let e = fails(train("no grid", &["--occupancy-bound", "2", "--no-occupancy-masks", "--steps", "2"]));
    assert!(e.contains("--occupancy-bound and --no-occupancy-masks") && e.contains("drop them"), "{e}");
    let e = fails(train("no grid", &["--preset", "fast", "--no-occupancy", "--occupancy-resolution", "32"]));
    assert!(e.contains("--occupancy-resolution"), "{e}");
    assert!(!dir.path().join("no grid").exists(), "a refused run made its folder");
    let e = fails(train("budget", &["--time-budget", "99999999999h"]));
    assert!(e.contains("--time-budget") && e.contains("longer than a year"), "{e}");
    let e = fails(train("late", &["--time-budget", "10m", "--snapshots", "1m,1h"]));
    assert!(e.contains("--snapshots 3600 s is at or past the end of --time-budget"), "{e}");
    let e = fails(train("twice", &["--time-budget", "10m", "--snapshots", "1s,1s"]));
    assert!(e.contains("--snapshots names 1 s twice"), "{e}");
    assert!(!dir.path().join("twice").join("checkpoint.safetensors").exists());
    // Both a step count and a budget: accepted, and the run says which ends it.
    let args = train("both", &["--steps", "2", "--time-budget", "1h", "--batch-rays", "16"]);
    let said = run_ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(
        said.contains("--steps 2 and --time-budget 1h both given: the run stops at whichever comes first"),
        "{said}"
    );
    let ws = fixtures().join("colmap_workspaces/simple_radial");
    let e = run_err(&["colmap", "--input", s(&ws), "--output", s(&dir.path().join("tiny")), "--max-size", "1"]);
    assert!(e.contains("--max-size 1") && e.contains("at least 32 px"), "{e}");
    assert!(!dir.path().join("tiny").exists());
}

/// A COLMAP workspace of the committed capture (30 photos) with its model as text, for editing.
fn text_workspace(dir: &Path, name: &str) -> PathBuf {
    let src = fixtures().join("colmap_lego");
    let ws = dir.join(name);
    copy_dir(&src.join("images"), &ws.join("images"));
    std::fs::create_dir_all(ws.join("sparse/0")).unwrap();
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        std::fs::copy(src.join("text").join(f), ws.join("sparse/0").join(f)).unwrap();
    }
    ws
}

/// Rewrites the data lines (not the comments) of a model's text file.
fn edit_model(ws: &Path, file: &str, edit: impl FnOnce(&mut Vec<String>)) {
    let path = ws.join("sparse/0").join(file);
    let text = std::fs::read_to_string(&path).unwrap();
    let (comments, mut data): (Vec<String>, Vec<String>) =
        text.lines().map(str::to_string).partition(|l| l.starts_with('#'));
    edit(&mut data);
    std::fs::write(&path, comments.into_iter().chain(data).collect::<Vec<_>>().join("\n") + "\n").unwrap();
}

/// A case: its name, an edit of a model file's data lines, and what the refusal must say.
type ModelEdit<'a> = (&'a str, &'a dyn Fn(&mut Vec<String>), &'a str);

/// Sets field `k` of data line `line` (fields split by spaces).
fn set_field(lines: &mut [String], line: usize, k: usize, value: &str) {
    let mut fields: Vec<String> = lines[line].split(' ').map(str::to_string).collect();
    fields[k] = value.to_string();
    lines[line] = fields.join(" ");
}

#[test]
fn colmap_models_that_make_no_sense_are_refused_at_once_naming_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let process = |ws: &Path| {
        let out = ws.with_extension("out");
        let e = run_err(&["colmap", "--input", s(ws), "--output", s(&out)]);
        assert!(!out.exists(), "nothing is written for a model that makes no sense: {e}");
        e
    };
    // The unedited model processes (the edits below are what fails).
    let ws = text_workspace(dir.path(), "good");
    run_ok(&["colmap", "--input", s(&ws), "--output", s(&dir.path().join("good-out"))]);

    // Cameras: 2^32 - 1 pixels wide (compared with the photo first: no hang), absurd focal
    // lengths, a principal point outside the picture, a distortion no lens has.
    // cameras.txt: ID MODEL WIDTH HEIGHT fx fy cx cy
    let cases: [ModelEdit; 5] = [
        // A distorted camera: before, undistortion walked its 2^32 border pixels (a hang).
        (
            "wide",
            &|l| l[0] = "1 SIMPLE_RADIAL 4294967295 200 273.18 100 100 0.01".into(),
            "camera 1 is 4294967295x200, but its photo",
        ),
        ("focal", &|l| (set_field(l, 0, 4, "1e-3"), set_field(l, 0, 5, "1e-3")).1, "field of view"),
        ("tiny-focal", &|l| (set_field(l, 0, 4, "1e-300"), set_field(l, 0, 5, "1e-300")).1, "field of view"),
        ("centre", &|l| set_field(l, 0, 6, "1e9"), "the principal point (1e9, 100) lies outside"),
        (
            "distortion",
            &|l| l[0] = "1 SIMPLE_RADIAL 200 200 273.18 100 100 1e6".into(),
            "distortion coefficient of 1000000",
        ),
    ];
    for (name, edit, want) in cases {
        let ws = text_workspace(dir.path(), name);
        edit_model(&ws, "cameras.txt", edit);
        let e = process(&ws);
        assert!(e.contains(want), "{name}: {e}");
    }

    // Images: duplicate ids and names, a camera that does not exist, names out of images/.
    // images.txt data lines come in pairs: ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then points.
    let cases: [ModelEdit; 5] = [
        ("dup-id", &|l| set_field(l, 2, 0, "1"), "image id 1 is given twice"),
        ("dup-name", &|l| set_field(l, 2, 9, "r_10.png"), "the name \"r_10.png\" is given twice"),
        ("no-camera", &|l| set_field(l, 0, 8, "7"), "uses camera 7, which the model's cameras do not have"),
        ("parent", &|l| set_field(l, 0, 9, "../secret.png"), "leads out of images/"),
        ("absolute", &|l| set_field(l, 0, 9, "/etc/passwd"), "leads out of images/"),
    ];
    for (name, edit, want) in cases {
        let ws = text_workspace(dir.path(), name);
        edit_model(&ws, "images.txt", edit);
        let e = process(&ws);
        assert!(e.contains(want), "{name}: {e}");
    }

    // Points: one at 1e300 (a far bound of 300 digits, then NaN), and every point behind the
    // cameras (each mirrored through its camera: negative near bounds).
    let ws = text_workspace(dir.path(), "far");
    edit_model(&ws, "points3D.txt", |l| {
        for line in 0..l.len() {
            set_field(l, line, 1, "1e300");
        }
    });
    let e = process(&ws);
    assert!(e.contains("more than 1e6 times as far as near") || e.contains("lie behind it"), "{e}");
    let ws = text_workspace(dir.path(), "behind");
    edit_model(&ws, "points3D.txt", |l| {
        for line in 0..l.len() {
            for k in 1..4 {
                let v: f64 = l[line].split(' ').nth(k).unwrap().parse().unwrap();
                set_field(l, line, k, &format!("{}", -1000.0 * v));
            }
        }
    });
    let e = process(&ws);
    assert!(e.contains("its 3D points lie behind it") || e.contains("times as far as near"), "{e}");

    // A JPEG cut to a third is refused, not read as grey.
    let ws = text_workspace(dir.path(), "cut");
    let photo = image::open(ws.join("images/r_10.png")).unwrap().to_rgb8();
    let jpeg = ws.join("images/r_10.jpg");
    photo.save(&jpeg).unwrap();
    let bytes = std::fs::read(&jpeg).unwrap();
    std::fs::write(&jpeg, &bytes[..bytes.len() / 3]).unwrap();
    std::fs::remove_file(ws.join("images/r_10.png")).unwrap();
    edit_model(&ws, "images.txt", |l| set_field(l, 0, 9, "r_10.jpg"));
    let out = ws.with_extension("out");
    let e = run_err(&["colmap", "--input", s(&ws), "--output", s(&out)]);
    assert!(e.contains("r_10.jpg") && e.contains("cut short"), "{e}");
}

/// A `train` refused before it writes anything (here an occupancy grid far larger than the scene;
/// occupancy on forward-facing data was refused here once, and is now accepted) leaves no folder
/// behind that it made; a folder that was there stays.
#[test]
fn a_refused_train_leaves_no_folder_it_made() {
    let dir = tempfile::tempdir().unwrap();
    let colmap = fixtures().join("colmap_lego");
    let run = dir.path().join("run");
    let args = [
        "train",
        "--data",
        s(&colmap),
        "--out",
        s(&run),
        "--occupancy",
        "--occupancy-bound",
        "100000",
        "--steps",
        "2",
        "--backend",
        "cpu",
    ];
    let e = run_err(&args);
    assert!(e.contains("is far from this scene's size"), "{e}");
    assert!(!run.exists(), "the refused run left {:?}", names(&run));
    std::fs::create_dir_all(&run).unwrap();
    run_err(&args);
    assert!(run.is_dir(), "a folder that was there is kept");
}
