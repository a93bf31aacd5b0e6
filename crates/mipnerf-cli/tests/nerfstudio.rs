//! `mipnerf colmap` on a capture in nerfstudio's `transforms.json` form: nerfstudio's own output
//! (tests/data/nerfstudio_capture, written by its `colmap_to_json` from the OPENCV workspace of
//! tests/data/colmap_workspaces) gives the dataset the workspace itself gives, and what such a
//! capture gets wrong is refused by name.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use common::{copy_dir, run_err, run_ok};

/// How far the two routes' poses may differ (entries of the rotation and the centre): the
/// capture's are COLMAP's turned by `applied_transform` and printed with 17 digits, then turned
/// back.
const POSE_TOLERANCE: f64 = 1e-9;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The capture as `ns-process-data` leaves it: transforms.json and sparse_pc.ply beside images/.
fn capture(dir: &Path) -> PathBuf {
    let capture = dir.join("capture");
    copy_dir(&fixtures().join("nerfstudio_capture"), &capture);
    copy_dir(&fixtures().join("colmap_workspaces/opencv/images"), &capture.join("images"));
    capture
}

fn transforms(capture: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(capture.join("transforms.json")).unwrap()).unwrap()
}

fn write_transforms(capture: &Path, json: &serde_json::Value) {
    std::fs::write(capture.join("transforms.json"), serde_json::to_string_pretty(json).unwrap()).unwrap();
}

/// The command `mipnerf colmap` prints for the test capture, shortened to three steps.
fn train_briefly(data: &Path, run: &Path) -> String {
    let flags = "--llff-factor 1 --spherify --background white --preset fast --steps 3 --quiet";
    let args: Vec<&str> = ["train", "--data", s(data), "--out", s(run)].into_iter().chain(flags.split(' ')).collect();
    run_ok(&args)
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

#[test]
fn a_nerfstudio_capture_gives_the_dataset_of_its_colmap_workspace() {
    let dir = tempfile::tempdir().unwrap();
    let capture = capture(dir.path());
    let (ours, theirs) = (dir.path().join("from-capture"), dir.path().join("from-workspace"));
    let text = run_ok(&["colmap", "--input", s(&capture), "--output", s(&ours), "--max-size", "0"]);
    let workspace = fixtures().join("colmap_workspaces/opencv");
    let reference = run_ok(&["colmap", "--input", s(&workspace), "--output", s(&theirs), "--max-size", "0"]);
    assert!(text.contains("transforms.json: a capture in nerfstudio's or Instant-NGP's form"), "{text}");
    assert!(text.contains("transforms.json: 30 of 40 photos registered"), "{text}");
    assert!(text.contains("camera: OPENCV 320x320 (fx 415.72, fy 418.56"), "{text}");
    assert!(
        text.contains("held out for testing (4 of 30, every 8th by name): images/r_1.jpg, images/r_3.jpg"),
        "{text}"
    );
    assert!(text.contains("the capture's units; depths of the points in front of each photo"), "{text}");
    // The same lens undistorted the same way: the same pixels, byte for byte.
    let (a, b) = (files(&ours.join("images_1")), files(&theirs.join("images_1")));
    assert_eq!(a.len(), 30);
    assert_eq!(
        a.iter().map(|p| p.file_name()).collect::<Vec<_>>(),
        b.iter().map(|p| p.file_name()).collect::<Vec<_>>()
    );
    for (x, y) in a.iter().zip(&b) {
        assert!(std::fs::read(x).unwrap() == std::fs::read(y).unwrap(), "{}", x.display());
    }
    // The same poses: nerfstudio's applied_transform undone, the capture's frame is COLMAP's.
    let read = |d: &Path| mipnerf_data::llff::read_poses_bounds(&d.join("poses_bounds.npy")).unwrap();
    let (rows, reference_rows) = (read(&ours), read(&theirs));
    assert_eq!(rows.len(), reference_rows.len());
    for (r, q) in rows.iter().zip(&reference_rows) {
        for k in 0..15 {
            assert!((r[k] - q[k]).abs() < POSE_TOLERANCE, "entry {k}: {r:?} {q:?}");
        }
    }
    // Bounds from the points each photo could see (no tracks): the scene's nearest the same,
    // its farthest farther (points behind the object count), by 21% here.
    let near = |rows: &[[f64; 17]]| rows.iter().map(|r| r[15]).fold(f64::INFINITY, f64::min);
    let far = |rows: &[[f64; 17]]| rows.iter().map(|r| r[16]).fold(0.0, f64::max);
    let (near_ratio, far_ratio) = (near(&rows) / near(&reference_rows), far(&rows) / far(&reference_rows));
    assert!((near_ratio - 1.0).abs() < 0.01, "near: {near_ratio}");
    assert!((1.0..1.3).contains(&far_ratio), "far: {far_ratio}");
    // The train command is the workspace's, and it trains (shortened to a few steps).
    let command = |t: &str| t.lines().find(|l| l.trim_start().starts_with("mipnerf train")).unwrap().to_owned();
    let (line, reference_line) = (command(&text), command(&reference));
    assert_eq!(
        line.replace(s(&ours), "DATA"),
        reference_line.replace(s(&theirs), "DATA").replace("from-workspace", "from-capture")
    );
    let run = dir.path().join("run");
    let trained = train_briefly(&ours, &run);
    assert!(trained.contains("(Llff, 26 views"), "{trained}");
    // Leaving a photo out by its frame's name.
    let again = run_ok(&[
        "colmap",
        "--input",
        s(&capture),
        "--output",
        s(&ours),
        "--max-size",
        "0",
        "--overwrite",
        "--exclude",
        "images/r_69.jpg",
    ]);
    assert!(again.contains("1 left out (--exclude): images/r_69.jpg; 29 kept"), "{again}");
}

#[test]
fn what_a_capture_gets_wrong_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let capture = capture(dir.path());
    let good = transforms(&capture);
    let out = dir.path().join("out");
    let fails = |json: &serde_json::Value| {
        write_transforms(&capture, json);
        let err = run_err(&["colmap", "--input", s(&capture), "--output", s(&out)]);
        assert!(!out.exists(), "nothing is written: {err}");
        err
    };
    let with = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut j = good.clone();
        edit(&mut j);
        j
    };
    let cases: Vec<(serde_json::Value, &str)> = vec![
        (with(&|j| drop(j.as_object_mut().unwrap().remove("ply_file_path"))), "no point cloud (\"ply_file_path\")"),
        (with(&|j| j["frames"][3]["file_path"] = "images/gone.jpg".into()), "frame 3: its photo"),
        (with(&|j| j["frames"][0]["file_path"] = "../x.jpg".into()), "frame 0: \"../x.jpg\" leads out of the capture"),
        (
            with(&|j| j["camera_model"] = "OPENCV_FISHEYE".into()),
            "camera_model OPENCV_FISHEYE: mipnerf cannot undistort",
        ),
        (with(&|j| j["k3"] = 0.1.into()), "\"k3\" is 0.1"),
        (with(&|j| j["fl_x"] = (-5.0).into()), "frame 0: its lens: focal lengths -5"),
        (
            with(&|j| j["frames"][2]["transform_matrix"][0][0] = 3.0.into()),
            "frame 2: transform_matrix's 3x3 part is not a rotation",
        ),
        (
            with(&|j| j["frames"][1]["transform_matrix"] = "identity".into()),
            "frame 1: transform_matrix: expected a 4x4 matrix",
        ),
        (with(&|j| j["frames"] = serde_json::json!([])), "no \"frames\" list"),
    ];
    for (json, want) in &cases {
        let err = fails(json);
        assert!(err.contains(want) && err.contains("transforms.json"), "{want}:\n{err}");
    }
    // A point cloud that is not one names its own file.
    write_transforms(&capture, &good);
    std::fs::write(capture.join("sparse_pc.ply"), "ply\nformat ascii 1.0\nend_header\n").unwrap();
    let err = run_err(&["colmap", "--input", s(&capture), "--output", s(&out)]);
    assert!(err.contains("sparse_pc.ply: no \"vertex\" element"), "{err}");
    // The trainer points a capture at the process step rather than failing to find a format.
    let err = run_err(&["train", "--data", s(&capture), "--out", s(&dir.path().join("run")), "--steps", "1"]);
    assert!(
        err.contains("a capture in nerfstudio's or Instant-NGP's form: process it first with `mipnerf colmap"),
        "{err}"
    );
}

/// The held-out photos' cameras, given in the data's own frame three ways, render as the test
/// split does: as poses_bounds.npy holds them (`--cameras-in data`), as the capture's own
/// transforms.json holds them (turned by its applied_transform), and as a camera path of
/// nerfstudio's viewer in the frame of a model nerfstudio trained (`--dataparser-transforms`,
/// its transform and scale made up here as nerfstudio makes them: `scale · (T p)`).
#[test]
fn cameras_in_the_datas_frame_and_nerfstudios_render_as_the_split() {
    let dir = tempfile::tempdir().unwrap();
    let capture = capture(dir.path());
    let data = dir.path().join("data");
    run_ok(&["colmap", "--input", s(&capture), "--output", s(&data), "--max-size", "0"]);
    let run = dir.path().join("run");
    train_briefly(&data, &run);
    let split = dir.path().join("split");
    let size = ["--width", "64", "--height", "63"];
    run_ok(&[&["render", "--run", s(&run), "--out", s(&split)][..], &size].concat());
    let png = |p: &Path| image::open(p).unwrap().to_rgba8().into_raw();
    let expected: Vec<Vec<u8>> = files(&split)
        .iter()
        .filter(|p| p.extension().is_some_and(|e| e == "png") && !s(p).contains("depth"))
        .map(|p| png(p))
        .collect();
    assert_eq!(expected.len(), 4);
    let render = |name: &str, args: &[&str]| -> u8 {
        let out = dir.path().join(name);
        run_ok(&[&["render", "--run", s(&run), "--out", s(&out)][..], args, &size].concat());
        (0..4)
            .map(|i| {
                let got = png(&out.join(format!("frame_{i:04}.png")));
                got.iter().zip(&expected[i]).map(|(a, b)| a.abs_diff(*b)).max().unwrap()
            })
            .max()
            .unwrap()
    };
    // The held-out rows (every 8th), as OpenGL camera-to-world poses: [down, right, back,
    // centre, hwf] per row turned to [right, up, back, centre].
    let rows = mipnerf_data::llff::read_poses_bounds(&data.join("poses_bounds.npy")).unwrap();
    let held_out: Vec<&[f64; 17]> = rows.iter().step_by(8).collect();
    let pose = |r: &[f64; 17]| -> [[f64; 4]; 3] {
        std::array::from_fn(|i| [r[i * 5 + 1], -r[i * 5], r[i * 5 + 2], r[i * 5 + 3]])
    };
    let (w, h, focal) = (held_out[0][9], held_out[0][4], held_out[0][14]);
    let frames: Vec<serde_json::Value> = held_out
        .iter()
        .map(|r| {
            let m = pose(r);
            serde_json::json!({"transform_matrix": [m[0], m[1], m[2], [0.0, 0.0, 0.0, 1.0]], "w": w, "h": h, "fl_x": focal})
        })
        .collect();
    let file = dir.path().join("held-out.json");
    std::fs::write(&file, serde_json::json!({ "frames": frames }).to_string()).unwrap();
    let off = render("in-data", &["--cameras", s(&file), "--cameras-in", "data"]);
    assert!(off <= 1, "--cameras-in data: off by {off} levels");
    let off = render("in-scene", &["--cameras", s(&file)]);
    assert!(off > 16, "read in the scene's frame, the data's poses show something else: off by only {off} levels");

    // The capture's own transforms.json: its held-out frames' poses (turned by applied_transform)
    // come out as the split's cameras.
    let out = dir.path().join("capture-frames");
    run_ok(
        &[
            &["render", "--run", s(&run), "--out", s(&out), "--cameras"][..],
            &[s(&capture.join("transforms.json")), "--cameras-in", "data"],
            &size,
        ]
        .concat(),
    );
    let cameras = |d: &Path| -> Vec<serde_json::Value> {
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("cameras.json")).unwrap()).unwrap();
        j["frames"].as_array().unwrap().clone()
    };
    let ours = cameras(&out);
    let names: Vec<String> = transforms(&capture)["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["file_path"].as_str().unwrap().to_owned())
        .collect();
    for (k, want) in cameras(&split).iter().enumerate() {
        let name = ["images/r_1.jpg", "images/r_3.jpg", "images/r_58.jpg", "images/r_78.jpg"][k];
        let got = &ours[names.iter().position(|n| n == name).unwrap()]["transform_matrix"];
        for i in 0..3 {
            for j in 0..4 {
                let (a, b) = (got[i][j].as_f64().unwrap(), want["transform_matrix"][i][j].as_f64().unwrap());
                assert!((a - b).abs() < POSE_TOLERANCE, "{name} [{i}][{j}]: {a} against {b}");
            }
        }
    }

    // A camera path of nerfstudio's viewer: its model's frame is the data's turned, moved and
    // scaled by dataparser_transforms.json.
    let turn = glam::DMat3::from_quat(glam::DQuat::from_euler(glam::EulerRot::ZYX, 0.4, -1.1, 2.0));
    let (shift, scale) = (glam::DVec3::new(0.3, -2.0, 1.5), 0.37);
    let t: Vec<Vec<f64>> = (0..3).map(|i| vec![turn.row(i).x, turn.row(i).y, turn.row(i).z, shift[i]]).collect();
    std::fs::write(
        dir.path().join("dataparser_transforms.json"),
        serde_json::json!({"transform": t, "scale": scale}).to_string(),
    )
    .unwrap();
    let path: Vec<serde_json::Value> = held_out
        .iter()
        .map(|r| {
            let m = pose(r);
            let rot = turn * glam::DMat3::from_cols_array_2d(&[0, 1, 2].map(|j| [m[0][j], m[1][j], m[2][j]]));
            let centre = scale * (turn * glam::DVec3::new(m[0][3], m[1][3], m[2][3]) + shift);
            let c2w: Vec<f64> = (0..3)
                .flat_map(|i| [rot.col(0)[i], rot.col(1)[i], rot.col(2)[i], centre[i]])
                .chain([0.0, 0.0, 0.0, 1.0])
                .collect();
            serde_json::json!({"camera_to_world": c2w, "fov": 2.0 * (0.5 * h / focal).atan().to_degrees(), "aspect": w / h})
        })
        .collect();
    let camera_path = dir.path().join("camera_path.json");
    let json = serde_json::json!({"camera_type": "perspective", "render_width": w, "render_height": h, "camera_path": path, "fps": 24});
    std::fs::write(&camera_path, json.to_string()).unwrap();
    let dataparser = dir.path().join("dataparser_transforms.json");
    let off = render("nerfstudio", &["--cameras", s(&camera_path), "--dataparser-transforms", s(&dataparser)]);
    assert!(off <= 1, "nerfstudio's camera path: off by {off} levels");
    // Without its dataparser transform a nerfstudio path is refused, naming what to give.
    let err = run_err(&["render", "--run", s(&run), "--out", s(&dir.path().join("x")), "--cameras", s(&camera_path)]);
    assert!(
        err.contains("camera_path.json: a camera path of nerfstudio's viewer")
            && err.contains("--dataparser-transforms"),
        "{err}"
    );
}

/// The COLMAP model beside a capture (Instant-NGP's `colmap_sparse/N` here) gives its points and
/// tracks, moved by the similarity that takes its cameras to the capture's: with the capture's
/// frame made up as Instant-NGP's is (COLMAP's turned, moved and scaled without saying so) and no
/// point cloud, the dataset comes out as the workspace's own, its bounds scaled. A model of other
/// photos is refused, or passed over for the point cloud when there is one.
#[test]
fn a_colmap_model_beside_a_capture_gives_its_points_and_tracks() {
    let dir = tempfile::tempdir().unwrap();
    let capture = capture(dir.path());
    let reference = dir.path().join("workspace");
    let workspace = fixtures().join("colmap_workspaces/opencv");
    run_ok(&["colmap", "--input", s(&workspace), "--output", s(&reference), "--max-size", "0"]);
    // Instant-NGP's kind of frame: every pose turned, moved and scaled; no applied_transform.
    let turn = glam::DMat3::from_quat(glam::DQuat::from_euler(glam::EulerRot::XYZ, 1.3, 0.2, -0.7));
    let (shift, scale) = (glam::DVec3::new(-1.0, 4.0, 0.25), 2.5);
    let mut json = transforms(&capture);
    let transforms_with_ply = json.clone();
    let applied: Vec<Vec<f64>> = serde_json::from_value(json["applied_transform"].clone()).unwrap();
    let a = glam::DMat3::from_cols_array_2d(&[0, 1, 2].map(|j| [applied[0][j], applied[1][j], applied[2][j]]));
    let top = json.as_object_mut().unwrap();
    top.remove("ply_file_path");
    top.remove("applied_transform");
    for frame in top["frames"].as_array_mut().unwrap() {
        let m: Vec<Vec<f64>> = serde_json::from_value(frame["transform_matrix"].clone()).unwrap();
        let r = glam::DMat3::from_cols_array_2d(&[0, 1, 2].map(|j| [m[0][j], m[1][j], m[2][j]]));
        // Back to COLMAP's frame (undo nerfstudio's turn), then Instant-NGP's kind of frame.
        let (r, c) = (
            turn * a.transpose() * r,
            scale * (turn * a.transpose() * glam::DVec3::new(m[0][3], m[1][3], m[2][3])) + shift,
        );
        frame["transform_matrix"] = serde_json::json!(
            (0..3)
                .map(|i| vec![r.col(0)[i], r.col(1)[i], r.col(2)[i], c[i]])
                .chain([vec![0.0, 0.0, 0.0, 1.0]])
                .collect::<Vec<_>>()
        );
    }
    write_transforms(&capture, &json);
    std::fs::remove_file(capture.join("sparse_pc.ply")).unwrap();
    // Without the model beside it, the capture is refused, naming where the model would be.
    let out = dir.path().join("from-model");
    let err = run_err(&["colmap", "--input", s(&capture), "--output", s(&out), "--max-size", "0"]);
    assert!(
        err.contains("no point cloud (\"ply_file_path\") and no COLMAP model beside it (colmap/sparse, colmap_sparse"),
        "{err}"
    );
    copy_dir(&fixtures().join("colmap_workspaces/opencv/sparse/2"), &capture.join("colmap_sparse/0"));
    let text = run_ok(&["colmap", "--input", s(&capture), "--output", s(&out), "--max-size", "0"]);
    assert!(
        text.contains("the 3D points of the COLMAP model in") && text.contains("30 photos matched by name"),
        "{text}"
    );
    // The same photos, and the workspace's bounds but for the scale.
    let (a, b) = (files(&out.join("images_1")), files(&reference.join("images_1")));
    assert_eq!(a.len(), 30);
    for (x, y) in a.iter().zip(&b) {
        assert!(std::fs::read(x).unwrap() == std::fs::read(y).unwrap(), "{}", x.display());
    }
    let read = |d: &Path| mipnerf_data::llff::read_poses_bounds(&d.join("poses_bounds.npy")).unwrap();
    for (r, q) in read(&out).iter().zip(&read(&reference)) {
        for k in [15, 16] {
            assert!((r[k] / q[k] - scale).abs() < 1e-9 * scale, "bound {k}: {} against {} x {scale}", r[k], q[k]);
        }
    }
    // A model of other photos is refused, naming it.
    std::fs::remove_dir_all(capture.join("colmap_sparse/0")).unwrap();
    copy_dir(&fixtures().join("colmap_workspaces/simple_radial/sparse/1"), &capture.join("colmap_sparse/0"));
    let err = run_err(&["colmap", "--input", s(&capture), "--output", s(&out), "--max-size", "0", "--overwrite"]);
    assert!(err.contains("colmap_sparse/0 is not this capture's"), "{err}");
    // With its point cloud back, the capture takes its bounds from that, and says why.
    write_transforms(&capture, &transforms_with_ply);
    std::fs::copy(fixtures().join("nerfstudio_capture/sparse_pc.ply"), capture.join("sparse_pc.ply")).unwrap();
    let text = run_ok(&["colmap", "--input", s(&capture), "--output", s(&out), "--max-size", "0", "--overwrite"]);
    assert!(text.contains("is not this capture's") && text.contains("its point cloud gives the bounds"), "{text}");
}
