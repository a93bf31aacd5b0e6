//! `render --cameras`: every render writes the cameras it rendered to `cameras.json`, and that
//! file (or one edited from it, or made by another tool) renders the same images.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::{mipnerf, run_err, run_ok};

fn png(path: &std::path::Path) -> image::RgbaImage {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgba8()
}

fn frames(cameras: &std::path::Path) -> Vec<serde_json::Value> {
    let file: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(cameras).unwrap()).unwrap();
    file["frames"].as_array().unwrap().clone()
}

/// A run in `dir/run` of the 16-pixel demo scene, trained `steps` steps of `rays` rays.
fn trained(dir: &std::path::Path, steps: &str, rays: &str) -> std::path::PathBuf {
    let data = common::small_demo_scene(dir, 4);
    let run = dir.join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", steps, "--batch-rays", rays, "--backend", "cpu"]);
    run
}

#[test]
fn a_renders_cameras_render_the_same_images_again() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained(dir.path(), "20", "128");
    let r = run.to_str().unwrap();

    // An orbit, written with its cameras; rendered again from them, the same pixels.
    let orbit = dir.path().join("orbit");
    let o = orbit.to_str().unwrap();
    let size = ["--width", "20", "--height", "12"];
    run_ok(
        &[&["render", "--run", r, "--out", o, "--path", "orbit", "--frames", "3", "--backend", "cpu"][..], &size]
            .concat(),
    );
    let cameras = orbit.join("cameras.json");
    let written = frames(&cameras);
    assert_eq!(written.len(), 3);
    for f in &written {
        assert_eq!((f["w"].as_u64(), f["h"].as_u64()), (Some(20), Some(12)), "{f}");
        assert_eq!(f["transform_matrix"].as_array().unwrap().len(), 4, "{f}");
    }
    let again = dir.path().join("again");
    let a = again.to_str().unwrap();
    let c = cameras.to_str().unwrap();
    let text = run_ok(&["render", "--run", r, "--out", a, "--cameras", c, "--backend", "cpu", "--fps", "6"]);
    // Four files a frame, the preview and the cameras (the frames are too small for a video).
    assert!(text.contains("wrote 14 files"), "{text}");
    for i in 0..3 {
        let name = format!("frame_{i:04}.png");
        assert_eq!(png(&orbit.join(&name)), png(&again.join(&name)), "{name}");
    }
    assert!(again.join("preview.gif").is_file());

    // The three cameras as keyframes of a 5-frame path: frames 0, 2 and 4 are the keys (to
    // rounding: a pose through a quaternion and back), frames 1 and 3 new views between them.
    let smooth = dir.path().join("smooth");
    run_ok(&[
        "render",
        "--run",
        r,
        "--out",
        smooth.to_str().unwrap(),
        "--cameras",
        c,
        "--frames",
        "5",
        "--backend",
        "cpu",
    ]);
    assert_eq!(frames(&smooth.join("cameras.json")).len(), 5);
    for (key, frame) in [(0, 0), (1, 2), (2, 4)] {
        let (want, got) =
            (png(&orbit.join(format!("frame_{key:04}.png"))), png(&smooth.join(format!("frame_{frame:04}.png"))));
        let most =
            want.pixels().zip(got.pixels()).flat_map(|(a, b)| a.0.iter().zip(b.0).map(|(x, y)| x.abs_diff(y))).max();
        assert!(most <= Some(1), "frame {frame} is not keyframe {key}: {most:?} levels apart");
    }
    let between = png(&smooth.join("frame_0001.png"));
    assert!(between != png(&orbit.join("frame_0000.png")) && between != png(&orbit.join("frame_0001.png")));

    // Edited by hand: one frame, at another size and focal length.
    let mut one = written[1].clone();
    one["w"] = 24.into();
    one["h"] = 18.into();
    one["fl_x"] = 30.0.into();
    one["fl_y"] = 30.0.into();
    one["cx"] = 12.0.into();
    one["cy"] = 9.0.into();
    let edited = dir.path().join("edited.json");
    std::fs::write(&edited, serde_json::json!({ "frames": [one] }).to_string()).unwrap();
    let e_out = dir.path().join("edited");
    run_ok(&[
        "render",
        "--run",
        r,
        "--out",
        e_out.to_str().unwrap(),
        "--cameras",
        edited.to_str().unwrap(),
        "--backend",
        "cpu",
    ]);
    assert_eq!(png(&e_out.join("frame_0000.png")).dimensions(), (24, 18));
    let back = &frames(&e_out.join("cameras.json"))[0];
    assert_eq!(back["fl_x"].as_f64(), Some(30.0), "{back}");

    // Frames of two sizes: each rendered at its own, and no preview or video (it would fail at
    // the end, after every frame was rendered), saying why.
    let mixed = dir.path().join("mixed.json");
    std::fs::write(&mixed, serde_json::json!({ "frames": [written[0].clone(), one] }).to_string()).unwrap();
    let m_out = dir.path().join("mixed");
    let text = run_ok(&["render", "--run", r, "--out", m_out.to_str().unwrap(), "--cameras", mixed.to_str().unwrap()]);
    assert!(text.contains("no preview.gif or video.mp4: the frames are of different sizes (20x12, 24x18"), "{text}");
    assert_eq!(png(&m_out.join("frame_0001.png")).dimensions(), (24, 18));
    assert!(!m_out.join("preview.gif").exists() && !m_out.join("video.mp4").exists());

    // A split's render writes its views' cameras too, one frame per view.
    let test = dir.path().join("test");
    run_ok(&["render", "--run", r, "--out", test.to_str().unwrap(), "--backend", "cpu"]);
    let views = frames(&test.join("cameras.json"));
    let pngs = std::fs::read_dir(&test)
        .unwrap()
        .filter(|e| {
            let n = e.as_ref().unwrap().file_name().to_string_lossy().to_string();
            n.ends_with(".png") && !n.contains("_depth") && n != "depth_scale.png"
        })
        .count();
    assert_eq!(views.len(), pngs);
}

#[test]
fn bad_camera_files_and_flags_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained(dir.path(), "2", "64");
    let r = run.to_str().unwrap();
    let out = dir.path().join("out");
    let o = out.to_str().unwrap();

    let bad = dir.path().join("cams.json");
    let b = bad.to_str().unwrap();
    let pose = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";
    for (text, want) in [
        ("{\"frames\": [".to_owned(), "malformed JSON".to_owned()),
        (
            format!("{{\"frames\": [{{\"transform_matrix\": {pose}}}, {{\"transform_matrix\": {pose}, \"h\": 5}}]}}"),
            "frame 1: give both \"w\" and \"h\"".to_owned(),
        ),
        (
            format!("{{\"frames\": [{{\"transform_matrix\": {pose}, \"camera_angle_x\": 0}}]}}"),
            "frame 0: \"camera_angle_x\" is 0".to_owned(),
        ),
        (
            "{\"frames\": [{\"transform_matrix\": [[1,0,0,0],[0,1,0,0],[0,0,1,1e9]]}]}".to_owned(),
            "frame 0: invalid camera".to_owned(),
        ),
    ] {
        std::fs::write(&bad, &text).unwrap();
        let err = run_err(&["render", "--run", r, "--out", o, "--cameras", b, "--backend", "cpu"]);
        assert!(err.contains(b) && err.contains(&want), "{text}: {err}");
        assert!(!out.exists(), "{text}: the refused render made {o}");
    }
    let missing = dir.path().join("missing.json");
    let err = run_err(&["render", "--run", r, "--out", o, "--cameras", missing.to_str().unwrap()]);
    assert!(err.contains("missing.json") && err.contains("No such file"), "{err}");

    // Frames out of range; the flags of a path or a split go with neither.
    std::fs::write(&bad, format!("{{\"frames\": [{{\"transform_matrix\": {pose}}}]}}")).unwrap();
    let err = run_err(&["render", "--run", r, "--out", o, "--cameras", b, "--frames", "0"]);
    assert!(err.contains("--frames must be between 1 and 10000"), "{err}");
    let err = run_err(&["render", "--run", r, "--out", o, "--split", "test", "--frames", "3"]);
    assert!(err.contains("--frames goes with --path"), "{err}");
    for flags in [&["--path", "orbit"][..], &["--split", "test"]] {
        let output = mipnerf(&[&["render", "--run", r, "--out", o, "--cameras", b][..], flags].concat());
        let err = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{flags:?}: {err}");
        assert!(err.contains("cannot be used with"), "{flags:?}: {err}");
    }
    assert!(!out.exists());
}
