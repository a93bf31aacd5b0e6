//! Every file a user names is opened as a file, within a size a file of its kind can have: a FIFO
//! or a device (a link to `/dev/zero`) is refused at once and by name, never waited on or read
//! without end, and each refusal's peak memory is measured and bounded. Two `colmap` runs never
//! write one folder; an overwrite leaves no earlier output beside the new; a render that meets a
//! full disk leaves only whole frames, listed, and says which.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{copy_dir, run_err, run_ok, trained_demo_run};

/// The most resident memory a refused input may cost the process, in MiB: the binary itself
/// and its libraries take some 20-40 MiB, and nothing of a refused file is held (before these
/// checks a `/dev/zero` point cloud grew to 10 GB, a 70 MB capture to 1.15 GB).
const REFUSAL_PEAK_MIB: f64 = 200.0;

/// How long a refusal may take before the input is taken to have blocked it (a FIFO waited on).
const REFUSAL_DEADLINE: Duration = Duration::from_secs(120);

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data")
}

/// What the binary did with `args`, run under GNU time for its peak resident memory, killed
/// (and the test failed) when it outlives [`REFUSAL_DEADLINE`].
struct Ran {
    code: Option<i32>,
    text: String,
    peak_mib: f64,
}

fn run_measured(args: &[&str]) -> Ran {
    let time = Path::new("/usr/bin/time");
    assert!(time.exists(), "GNU time measures the refusals' memory (Debian: apt-get install time)");
    let peak = tempfile::NamedTempFile::new().unwrap();
    let mut child = Command::new(time)
        .args(["-f", "%M", "-o", s(peak.path()), env!("CARGO_BIN_EXE_mipnerf")])
        .args(args)
        .env("XDG_RUNTIME_DIR", "/tmp")
        .env_remove("MIPNERF_LPIPS_WEIGHTS")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > REFUSAL_DEADLINE {
            child.kill().unwrap();
            panic!("mipnerf {args:?} still running after {REFUSAL_DEADLINE:?}: blocked on its input");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    let kib: f64 = std::fs::read_to_string(peak.path()).unwrap().trim().lines().last().unwrap().parse().unwrap();
    Ran { code: out.status.code(), text, peak_mib: kib / 1024.0 }
}

/// Runs `args`, which must be refused (exit 1, no panic) with a message holding every one of
/// `says`, within [`REFUSAL_PEAK_MIB`]; prints the peak for the record.
fn refused(what: &str, args: &[&str], says: &[&str]) -> String {
    let r = run_measured(args);
    assert_eq!(r.code, Some(1), "{what}: mipnerf {args:?} should be refused:\n{}", r.text);
    assert!(!r.text.contains("panicked"), "{what}: {}", r.text);
    for phrase in says {
        assert!(r.text.contains(phrase), "{what}: expected {phrase:?} in:\n{}", r.text);
    }
    assert!(r.peak_mib < REFUSAL_PEAK_MIB, "{what}: peak {:.1} MiB (bound {REFUSAL_PEAK_MIB})", r.peak_mib);
    eprintln!("{what}: refused, peak resident memory {:.1} MiB", r.peak_mib);
    r.text
}

fn mkfifo(path: &Path) {
    let _ = std::fs::remove_file(path);
    assert!(Command::new("mkfifo").arg(path).status().unwrap().success());
}

fn link_to_dev_zero(path: &Path) {
    let _ = std::fs::remove_file(path);
    std::os::unix::fs::symlink("/dev/zero", path).unwrap();
}

/// The nerfstudio capture of the test workspace: transforms.json and sparse_pc.ply beside images/.
fn capture(dir: &Path) -> PathBuf {
    let capture = dir.join("capture");
    copy_dir(&fixtures().join("nerfstudio_capture"), &capture);
    copy_dir(&fixtures().join("colmap_workspaces/opencv/images"), &capture.join("images"));
    capture
}

#[test]
fn a_capture_whose_files_are_fifos_devices_or_huge_is_refused_at_once_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let capture = capture(dir.path());
    let out = dir.path().join("out");
    let colmap = ["colmap", "--input", s(&capture), "--output", s(&out)];
    let ply = capture.join("sparse_pc.ply");
    let kept_ply = dir.path().join("sparse_pc.ply");
    std::fs::rename(&ply, &kept_ply).unwrap();

    link_to_dev_zero(&ply);
    refused("point cloud on /dev/zero", &colmap, &["sparse_pc.ply", "is a device (such as /dev/zero)"]);
    mkfifo(&ply);
    refused("point cloud as a FIFO", &colmap, &["sparse_pc.ply", "is a FIFO (a named pipe)"]);
    assert!(!out.exists(), "a refused run leaves no output folder");
    std::fs::remove_file(&ply).unwrap();
    std::fs::rename(&kept_ply, &ply).unwrap();

    // A photo that is a FIFO is named as one, not as missing.
    let photo = capture.join("images/r_10.jpg");
    let kept_photo = dir.path().join("r_10.jpg");
    std::fs::rename(&photo, &kept_photo).unwrap();
    mkfifo(&photo);
    let text = refused("photo as a FIFO", &colmap, &["r_10.jpg", "is a FIFO (a named pipe)"]);
    assert!(!text.contains("is not there"), "{text}");
    std::fs::remove_file(&photo).unwrap();
    std::fs::rename(&kept_photo, &photo).unwrap();

    // transforms.json itself: named, not taken for a COLMAP workspace without its sparse/.
    let transforms = capture.join("transforms.json");
    let kept = std::fs::read_to_string(&transforms).unwrap();
    for (what, make, says) in [
        ("transforms.json as a FIFO", mkfifo as fn(&Path), "is a FIFO (a named pipe)"),
        ("transforms.json on /dev/zero", link_to_dev_zero, "is a device (such as /dev/zero)"),
    ] {
        make(&transforms);
        let text = refused(what, &colmap, &["transforms.json", says]);
        assert!(!text.contains("sparse: No such file"), "{text}");
    }
    // 70 MB of a capture (its frames padded as a tool that pretty-prints with wide indents might):
    // refused by its size before a byte of it is held.
    std::fs::remove_file(&transforms).unwrap();
    let padded = kept.replacen('{', &format!("{{{}", " ".repeat(70 << 20)), 1);
    std::fs::write(&transforms, padded).unwrap();
    refused("a 70 MB transforms.json", &colmap, &["transforms.json", "is 70 MiB, more than the 64 MiB"]);
    std::fs::write(&transforms, &kept).unwrap();
    assert!(!out.exists(), "a refused run leaves no output folder");
}

#[test]
fn a_point_cloud_of_too_few_points_or_of_points_no_photo_sees_names_the_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let capture = capture(dir.path());
    let ply = capture.join("sparse_pc.ply");
    let write_cloud = |points: &[[f64; 3]]| {
        let mut text = format!(
            "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
            points.len()
        );
        for p in points {
            text.push_str(&format!("{:e} {:e} {:e}\n", p[0], p[1], p[2]));
        }
        std::fs::write(&ply, text).unwrap();
    };
    let out = dir.path().join("out");
    let colmap = ["colmap", "--input", s(&capture), "--output", s(&out)];
    write_cloud(&[[0.1, 0.2, 0.3]]);
    let text = run_err(&colmap);
    assert!(text.contains("sparse_pc.ply: holds 1 point(s); the depth bounds need at least 100"), "{text}");
    write_cloud(&vec![[1e300, 1e300, 1e300]; 200]);
    let text = run_err(&colmap);
    assert!(text.contains("sparse_pc.ply: none of its 200 points lies in front of a photo"), "{text}");
    assert!(!text.contains("sees no 3D point"), "{text}");
}

#[test]
fn a_runs_camera_files_and_settings_that_are_fifos_devices_or_binary_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained_demo_run(dir.path());
    let out = dir.path().join("frames");
    let cameras = dir.path().join("cameras.json");
    let render = |extra: &[&str]| -> Vec<String> {
        ["render", "--run", s(&run), "--out", s(&out), "--backend", "cpu"]
            .iter()
            .chain(extra)
            .map(|a| (*a).to_string())
            .collect()
    };
    let strs = |v: &[String]| v.iter().map(String::as_str).collect::<Vec<_>>().join("\u{0}");
    let check = |what: &str, args: Vec<String>, says: &[&str]| {
        let joined = strs(&args);
        let args: Vec<&str> = joined.split('\u{0}').collect();
        refused(what, &args, says);
    };
    mkfifo(&cameras);
    check("--cameras as a FIFO", render(&["--cameras", s(&cameras)]), &["cameras.json", "is a FIFO"]);
    link_to_dev_zero(&cameras);
    check("--cameras on /dev/zero", render(&["--cameras", s(&cameras)]), &["cameras.json", "is a device"]);
    // LLFF's poses file given as a camera file: said to be NumPy, not "invalid UTF-8".
    let npy = dir.path().join("poses_bounds.npy");
    mipnerf_data::llff::write_poses_bounds(&npy, &[[0.0; 17]]).unwrap();
    let text = run_err(&strs(&render(&["--cameras", s(&npy)])).split('\u{0}').collect::<Vec<_>>());
    assert!(text.contains("poses_bounds.npy: is a NumPy array file"), "{text}");
    assert!(!text.contains("UTF-8"), "{text}");

    // nerfstudio's dataparser transforms beside a (valid) nerfstudio camera path.
    let path = dir.path().join("camera_path.json");
    let c2w = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4.0, 0.0, 0.0, 0.0, 1.0];
    let json = serde_json::json!({"camera_type": "perspective", "render_width": 16, "render_height": 16,
        "camera_path": [{"camera_to_world": c2w, "fov": 40.0}]});
    std::fs::write(&path, json.to_string()).unwrap();
    let transforms = dir.path().join("dataparser_transforms.json");
    for (what, make, says) in [
        ("--dataparser-transforms as a FIFO", mkfifo as fn(&Path), "is a FIFO"),
        ("--dataparser-transforms on /dev/zero", link_to_dev_zero, "is a device"),
    ] {
        make(&transforms);
        check(
            what,
            render(&["--cameras", s(&path), "--dataparser-transforms", s(&transforms)]),
            &["dataparser_transforms.json", says],
        );
    }
    // train --config.
    let config = dir.path().join("config.toml");
    let data = dir.path().join("data");
    for (what, make, says) in [
        ("--config as a FIFO", mkfifo as fn(&Path), "is a FIFO"),
        ("--config on /dev/zero", link_to_dev_zero, "is a device"),
    ] {
        make(&config);
        let new_run = dir.path().join("run2");
        refused(
            what,
            &["train", "--config", s(&config), "--data", s(&data), "--out", s(&new_run)],
            &["config.toml", says],
        );
    }
    assert!(!out.exists(), "nothing was rendered");
}

/// The number of rows of a `poses_bounds.npy` and of images in the dataset folder `data`'s one
/// image folder.
fn poses_and_images(data: &Path) -> (usize, usize, Vec<String>) {
    let rows = mipnerf_data::llff::read_poses_bounds(&data.join("poses_bounds.npy")).unwrap().len();
    let folders: Vec<String> = std::fs::read_dir(data)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| n.starts_with("images_") || n.starts_with(".mipnerf-partial"))
        .collect();
    assert_eq!(folders.len(), 1, "one image folder, nothing partial: {folders:?}");
    let images = std::fs::read_dir(data.join(&folders[0])).unwrap().count();
    (rows, images, folders)
}

#[test]
fn two_colmap_runs_never_write_one_folder_and_an_overwrite_replaces_every_earlier_output() {
    let dir = tempfile::tempdir().unwrap();
    let workspace = dir.path().join("workspace");
    copy_dir(&fixtures().join("colmap_workspaces/opencv"), &workspace);
    let out = dir.path().join("out");

    // While another process holds the folder's lock, colmap is refused, naming it.
    std::fs::create_dir_all(&out).unwrap();
    let lock_path = out.join(mipnerf_core::io::LOCK);
    let lock = std::fs::File::create(&lock_path).unwrap();
    lock.try_lock().unwrap();
    std::fs::write(&lock_path, "process 4242\tcolmap\n").unwrap();
    let text = run_err(&["colmap", "--input", s(&workspace), "--output", s(&out), "--max-size", "160"]);
    assert!(text.contains("is in use by another `mipnerf colmap` (process 4242)"), "{text}");
    // convert takes the same lock on its --output.
    let blender = fixtures().join("lego_tiny");
    let text = run_err(&["convert", "--input", s(&blender), "--output", s(&out)]);
    assert!(text.contains("is in use by another `mipnerf colmap` (process 4242)"), "{text}");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 1, "nothing written beside the lock");
    drop(lock);

    // Two at once into one new folder (the second leaving a photo out): each either wrote the
    // folder whole or was refused; the folder is one run's whole dataset.
    std::fs::remove_dir_all(&out).unwrap();
    let spawn = |extra: &[&str]| {
        common::command()
            .args(["colmap", "--input", s(&workspace), "--output", s(&out), "--max-size", "160"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let first = spawn(&[]);
    std::thread::sleep(Duration::from_millis(200));
    let second = spawn(&["--exclude", "r_1.jpg"]);
    let mut succeeded = 0;
    for child in [first, second] {
        let o = child.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
        if o.status.success() {
            succeeded += 1;
        } else {
            assert!(
                text.contains("is in use by another `mipnerf colmap`") || text.contains("is not empty"),
                "the other run is refused for the lock or the finished folder: {text}"
            );
        }
    }
    assert!(succeeded >= 1, "one of the two wrote the folder");
    let (rows, images, _) = poses_and_images(&out);
    assert_eq!(rows, images, "the poses and the images are one run's");
    run_ok(&["colmap", "--input", s(&workspace), "--output", s(&out), "--max-size", "160", "--overwrite"]);
    let (registered, _, _) = poses_and_images(&out);

    // An overwrite at another size with a photo left out: the earlier images_N/ goes.
    run_ok(&[
        "colmap",
        "--input",
        s(&workspace),
        "--output",
        s(&out),
        "--max-size",
        "0",
        "--overwrite",
        "--exclude",
        "r_10.jpg",
    ]);
    let (rows, images, folders) = poses_and_images(&out);
    assert_eq!((rows, images), (registered - 1, registered - 1), "{folders:?}");
    assert_eq!(folders, ["images_1"]);
    let manifest = std::fs::read_to_string(out.join(mipnerf_core::io::MANIFEST)).unwrap();
    assert!(!manifest.contains("images_2"), "the earlier folder is forgotten: {manifest}");
}

/// A small tmpfs mounted on a folder for the life of the value (unmounted when dropped).
struct SmallDisk(PathBuf);

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

#[test]
fn a_render_that_meets_a_full_disk_leaves_only_whole_frames_lists_only_them_and_says_which() {
    if std::fs::metadata("/proc/self").map(|m| std::os::unix::fs::MetadataExt::uid(&m)).unwrap_or(1) != 0 {
        eprintln!("SKIPPED the full-disk render: mounting a small tmpfs needs root");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let run = trained_demo_run(dir.path());
    let disk = dir.path().join("disk");
    std::fs::create_dir_all(&disk).unwrap();
    let mounted = Command::new("mount").args(["-t", "tmpfs", "-o", "size=160k", "tmpfs", s(&disk)]).status().unwrap();
    assert!(mounted.success(), "root mounts a tmpfs");
    let _disk = SmallDisk(disk.clone());
    let out = disk.join("frames");
    let text = run_err(&[
        "render",
        "--run",
        s(&run),
        "--out",
        s(&out),
        "--backend",
        "cpu",
        "--path",
        "orbit",
        "--frames",
        "30",
        "--width",
        "96",
        "--height",
        "96",
    ]);
    assert_eq!(text.matches("No space left on device").count(), 1, "the system's words once: {text}");
    assert!(text.contains("the render into") && text.contains("stopped"), "{text}");
    let complete = if text.contains("no frame is complete") {
        0
    } else {
        let at = text.find(" of 30 frames").expect("says how many frames are complete");
        text[..at].rsplit(|c: char| !c.is_ascii_digit()).next().unwrap().parse::<usize>().unwrap()
    };
    assert!(complete < 30, "{text}");
    // Every file under its final name is whole, and the manifest lists exactly what is there.
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .filter(|n| !n.starts_with('.'))
        .collect();
    names.sort();
    for n in names.iter().filter(|n| n.ends_with(".png")) {
        image::open(out.join(n)).unwrap_or_else(|e| panic!("{n} is not whole: {e}"));
    }
    for i in 0..30 {
        let has = names.iter().any(|n| n.starts_with(&format!("frame_{i:04}")));
        assert_eq!(has, i < complete, "frame {i} (complete: {complete}): {names:?}");
    }
    let listed = mipnerf_core::io::recorded(&out).unwrap();
    for n in &names {
        assert!(listed.contains(n), "{n} is listed");
    }
    for n in &listed {
        assert!(names.contains(n), "the manifest lists only what is there: {n}");
    }
    // cameras.json lists the complete frames, or (when the full disk left no room to rewrite it)
    // is gone and unlisted: never the 30 frames the render was to make.
    if let Ok(text) = std::fs::read_to_string(out.join("cameras.json")) {
        let cameras: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(cameras["frames"].as_array().unwrap().len(), complete, "cameras.json lists the complete frames");
    } else {
        assert!(!listed.contains("cameras.json"));
    }
    eprintln!("full disk: {complete} of 30 frames complete; the error said:\n{text}");
}
