//! Camera files: the cameras of a render in the NeRF `transforms.json` convention, read and
//! written, so that any camera path (one made in Blender, edited by hand, or written by an
//! earlier `mipnerf render`) can be rendered.
//!
//! The file is a JSON object with a list `frames`, each with a 4x4 (or 3x4) camera-to-world
//! `transform_matrix` in OpenGL axes (the camera looks down `-z`, `y` up), as Blender's
//! `transforms_*.json` have. The intrinsics are read from each frame, else from the top level:
//! - `w`, `h`: the image size in pixels;
//! - `fl_x` (focal length in pixels), with optional `fl_y`, `cx`, `cy` (Instant-NGP's and
//!   nerfstudio's keys), or else `camera_angle_x` (the horizontal field of view in radians,
//!   Blender's); `fl_x` wins when both are given, as those tools write both.
//!
//! What a file leaves out comes from a default camera (a training photo's). Other keys (a
//! frame's `file_path`, say) are ignored, so a Blender scene's `transforms_test.json` is a camera
//! file too.
//!
//! Poses are in the world of the trained model: a Blender scene's own frame; for LLFF and COLMAP
//! data the recentred (and with `--spherify` the spherified) frame the loader puts the cameras
//! in. [`to_json`] writes cameras in that frame, so the file an earlier render wrote is the place
//! to start a path of one's own.

use std::path::Path;

use glam::{DQuat, DVec3};
use serde_json::{Map, Value, json};

use crate::{DataError, json_number, pose_from_json, read_json};
use mipnerf_core::camera::{Camera, det3, focal_from_camera_angle_x};

/// The most frames a camera file may hold (as `mipnerf render --frames`).
pub const MAX_FRAMES: usize = 10_000;

/// The largest image side a camera file may ask for, in pixels (as `mipnerf render --width`).
pub const MAX_SIDE: u32 = 16_384;

/// Reads the cameras of the camera file at `path`; what a frame leaves out comes from `default`
/// (its size, and its focal length scaled to the frame's width). With `size`, every camera is
/// rendered at that size instead, with the same horizontal field of view and square pixels kept
/// square.
///
/// # Errors
/// [`DataError`] naming the file (and the frame) for a missing or malformed file, no frames or
/// more than [`MAX_FRAMES`], a size outside 1 to [`MAX_SIDE`], intrinsics that are not positive
/// finite numbers, or a pose [`Camera::from_pix2cam`] refuses.
pub fn read(path: &Path, default: &Camera, size: Option<(u32, u32)>) -> Result<Vec<Camera>, DataError> {
    let file = read_json(path)?;
    let top = file.as_object().ok_or_else(|| DataError::invalid(path, "expected a JSON object with \"frames\""))?;
    if top.contains_key("camera_path") {
        return nerfstudio_path(path, top, size);
    }
    let to_data = crate::nerfstudio::saved_to_data(top, path)?;
    let frames = top
        .get("frames")
        .ok_or_else(|| DataError::invalid(path, "missing key \"frames\" (a list of {\"transform_matrix\": 4x4})"))?
        .as_array()
        .ok_or_else(|| DataError::invalid(path, "\"frames\" must be a list"))?;
    if frames.is_empty() {
        return Err(DataError::invalid(path, "\"frames\" is empty: no camera to render"));
    }
    if frames.len() > MAX_FRAMES {
        return Err(DataError::invalid(path, format!("{} frames; at most {MAX_FRAMES} are rendered", frames.len())));
    }
    frames
        .iter()
        .enumerate()
        .map(|(i, frame)| {
            let frame =
                frame.as_object().ok_or_else(|| DataError::invalid(path, format!("frame {i} is not an object")))?;
            camera(frame, top, default, size)
                .and_then(|c| {
                    Camera::from_pix2cam(c.width, c.height, c.pix2cam, to_data.pose(&c.cam2world))
                        .map_err(|e| e.to_string())
                })
                .map_err(|problem| DataError::invalid(path, format!("frame {i}: {problem}")))
        })
        .collect()
}

/// Whether the camera file at `path` is a camera path of nerfstudio's viewer (`camera_path`
/// rather than `frames`), whose poses are in the frame of the model nerfstudio trained; `false`
/// for a file that cannot be read (which [`read`] then names).
#[must_use]
pub fn is_nerfstudio_path(path: &Path) -> bool {
    read_json(path).is_ok_and(|j| j.get("camera_path").is_some())
}

/// The cameras of a camera path of nerfstudio's viewer (its `camera_path.json`): `render_width`
/// and `render_height`, and for each camera a row-major 4x4 `camera_to_world` (OpenGL's axes, in
/// the frame of the model nerfstudio trained: [`crate::nerfstudio::dataparser_to_data`]) and its
/// vertical field of view `fov` in degrees (three.js's), the principal point at the centre;
/// at another `size`, the same vertical field of view.
fn nerfstudio_path(path: &Path, top: &Map<String, Value>, size: Option<(u32, u32)>) -> Result<Vec<Camera>, DataError> {
    let bad = |problem: String| DataError::invalid(path, problem);
    match top.get("camera_type").and_then(Value::as_str) {
        None | Some("perspective") => {}
        Some(other) => return Err(bad(format!("camera_type {other:?}: only perspective cameras render here"))),
    }
    let empty = Map::new();
    let (w, h) = match (side("render_width", &empty, top), side("render_height", &empty, top)) {
        (Ok(Some(w)), Ok(Some(h))) => (w, h),
        (Err(e), _) | (_, Err(e)) => return Err(bad(e)),
        _ => return Err(bad("a nerfstudio camera path needs \"render_width\" and \"render_height\"".into())),
    };
    let list =
        top.get("camera_path").and_then(Value::as_array).ok_or_else(|| bad("\"camera_path\" must be a list".into()))?;
    if list.is_empty() || list.len() > MAX_FRAMES {
        return Err(bad(format!("{} cameras in \"camera_path\"; 1 to {MAX_FRAMES} are rendered", list.len())));
    }
    list.iter()
        .enumerate()
        .map(|(i, cam)| {
            let at = |problem: String| bad(format!("camera_path[{i}]: {problem}"));
            let m: Vec<f64> = cam
                .get("camera_to_world")
                .and_then(Value::as_array)
                .filter(|m| m.len() == 16)
                .and_then(|m| m.iter().map(Value::as_f64).collect())
                .ok_or_else(|| at("\"camera_to_world\" must be 16 numbers (a row-major 4x4)".into()))?;
            let cam2world: [[f64; 4]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| m[r * 4 + c]));
            let fov = cam.get("fov").and_then(Value::as_f64).filter(|f| *f > 0.0 && *f < 180.0);
            let fov =
                fov.ok_or_else(|| at("\"fov\" must be a vertical field of view in degrees, in (0, 180)".into()))?;
            let (w, h) = size.unwrap_or((w, h));
            let focal = 0.5 * f64::from(h) / (0.5 * fov.to_radians()).tan();
            let pix2cam = mipnerf_core::camera::pinhole_pix2cam(w, h, focal);
            Camera::from_pix2cam(w, h, pix2cam, cam2world).map_err(|e| at(e.to_string()))
        })
        .collect()
}

/// An image side under `key` (`w` or `h`), from the frame or else the top level.
fn side(key: &str, frame: &Map<String, Value>, top: &Map<String, Value>) -> Result<Option<u32>, String> {
    let Some(x) = json_number(key, frame, top)? else { return Ok(None) };
    if x.fract() != 0.0 || !(1.0..=f64::from(MAX_SIDE)).contains(&x) {
        return Err(format!("\"{key}\" is {x}; a side is a whole number of pixels from 1 to {MAX_SIDE}"));
    }
    // A whole number from 1 to MAX_SIDE (checked above).
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    Ok(Some(x as u32))
}

/// One frame's camera.
fn camera(
    frame: &Map<String, Value>,
    top: &Map<String, Value>,
    default: &Camera,
    size: Option<(u32, u32)>,
) -> Result<Camera, String> {
    let pose = frame.get("transform_matrix").ok_or("missing key \"transform_matrix\"")?;
    let cam2world = pose_from_json(pose, Path::new(""), "transform_matrix").map_err(|e| match e {
        DataError::Invalid { problem, .. } => problem,
        other => other.to_string(),
    })?;
    let (w, h) = match (side("w", frame, top)?, side("h", frame, top)?) {
        (Some(w), Some(h)) => (w, h),
        (None, None) => (default.width, default.height),
        _ => return Err("give both \"w\" and \"h\", or neither (the training photos' size)".into()),
    };
    let focal_x = match (json_number("fl_x", frame, top)?, json_number("camera_angle_x", frame, top)?) {
        (Some(f), _) => f,
        (None, Some(angle)) => {
            if !(angle > 0.0 && angle < std::f64::consts::PI) {
                return Err(format!("\"camera_angle_x\" is {angle}; a field of view in radians is in (0, pi)"));
            }
            focal_from_camera_angle_x(w, angle)
        }
        // The default camera's focal length, in pixels of this width.
        (None, None) => f64::from(w) / f64::from(default.width) / default.pix2cam[0][0],
    };
    let focal_y = json_number("fl_y", frame, top)?.unwrap_or(focal_x);
    let cx = json_number("cx", frame, top)?.unwrap_or(0.5 * f64::from(w));
    let cy = json_number("cy", frame, top)?.unwrap_or(0.5 * f64::from(h));
    for (key, f) in [("fl_x", focal_x), ("fl_y", focal_y)] {
        if f <= 0.0 {
            return Err(format!("the focal length \"{key}\" is {f}; it must be positive"));
        }
    }
    // Another size keeps the horizontal field of view and the pixels' shape (as `render
    // --width` does for a split's views), the principal point where it was in the image.
    let ((w, h), (focal_x, focal_y, cx, cy)) = match size {
        None => ((w, h), (focal_x, focal_y, cx, cy)),
        Some((nw, nh)) => {
            let (sx, sy) = (f64::from(nw) / f64::from(w), f64::from(nh) / f64::from(h));
            ((nw, nh), (focal_x * sx, focal_y * sx, cx * sx, cy * sy))
        }
    };
    let pix2cam = [[1.0 / focal_x, 0.0, -cx / focal_x], [0.0, -1.0 / focal_y, cy / focal_y], [0.0, 0.0, -1.0]];
    Camera::from_pix2cam(w, h, pix2cam, cam2world).map_err(|e| e.to_string())
}

/// The intrinsics `(fl_x, fl_y, cx, cy)` of a camera whose `pix2cam` is a pinhole's without skew
/// in OpenGL axes (`[[1/fx, 0, -cx/fx], [0, -1/fy, cy/fy], [0, 0, -1]]`, as every dataset this
/// tool reads makes); `None` for any other.
#[must_use]
pub fn intrinsics(camera: &Camera) -> Option<(f64, f64, f64, f64)> {
    let p = camera.pix2cam;
    let pinhole = p[0][1] == 0.0 && p[1][0] == 0.0 && p[2] == [0.0, 0.0, -1.0] && p[0][0] > 0.0 && p[1][1] < 0.0;
    pinhole.then(|| {
        let (fx, fy) = (1.0 / p[0][0], -1.0 / p[1][1]);
        (fx, fy, -p[0][2] * fx, p[1][2] * fy)
    })
}

/// The camera file of `cameras`: each frame with its `transform_matrix` (4x4), `w`, `h`, `fl_x`,
/// `fl_y`, `cx`, `cy` and `camera_angle_x`; `None` when a camera's intrinsics are not a plain
/// pinhole's ([`intrinsics`]).
#[must_use]
pub fn to_json(cameras: &[Camera]) -> Option<Value> {
    let frames = cameras
        .iter()
        .map(|c| {
            let (fx, fy, cx, cy) = intrinsics(c)?;
            let m = c.cam2world;
            let transform: Vec<Vec<f64>> = m.iter().map(|r| r.to_vec()).chain([vec![0.0, 0.0, 0.0, 1.0]]).collect();
            Some(json!({
                "transform_matrix": transform,
                "w": c.width,
                "h": c.height,
                "fl_x": fx,
                "fl_y": fy,
                "cx": cx,
                "cy": cy,
                "camera_angle_x": 2.0 * (0.5 * f64::from(c.width) / fx).atan(),
            }))
        })
        .collect::<Option<Vec<Value>>>()?;
    Some(json!({ "frames": frames }))
}

/// [`to_json`] as the text of a camera file: one frame a line, its pose first, so that a path
/// reads (and diffs) frame by frame. Every number is written in the fewest digits that parse back
/// to it; `serde_json` (which [`read`] uses) parses some of them to a neighbouring `f64`, a
/// relative change of about 1e-16.
#[must_use]
pub fn to_text(cameras: &[Camera]) -> Option<String> {
    let file = to_json(cameras)?;
    let frames = file["frames"].as_array()?;
    let keys = ["transform_matrix", "w", "h", "fl_x", "fl_y", "cx", "cy", "camera_angle_x"];
    let lines: Vec<String> = frames
        .iter()
        .map(|f| {
            let fields: Vec<String> = keys.iter().map(|k| format!("\"{k}\": {}", f[*k])).collect();
            format!("    {{{}}}", fields.join(", "))
        })
        .collect();
    Some(format!("{{\n  \"frames\": [\n{}\n  ]\n}}\n", lines.join(",\n")))
}

/// `frames` cameras along a smooth path through the keyframes `keys`, from the first to the
/// last: positions on a Catmull-Rom spline through the keys' positions (uniform; at the ends the
/// missing neighbour is the end key itself), orientations by Shoemake's squad (slerps bent by
/// control points so that the camera turns at a rate without jumps at the keys), the intrinsics'
/// `pix2cam` linear between keys (so the tangent of the field of view). Key `k` is frame
/// `k (frames - 1) / (keys - 1)`.
///
/// A loop (more than two keys, the last one the first again) is a video that plays round: the
/// spline's neighbours wrap across the join, so nothing jolts there, and the last key is not a
/// frame of its own (the first frame follows the last), so key `k` is frame
/// `k frames / (keys - 1)`. One key gives `frames` copies of it.
///
/// # Errors
/// A problem naming the keyframe: keys of different image sizes, or an interpolated camera
/// [`Camera::from_pix2cam`] refuses; no keys or no frames.
pub fn interpolate(keys: &[Camera], frames: usize) -> Result<Vec<Camera>, String> {
    let Some(first) = keys.first() else { return Err("no keyframes".into()) };
    if frames == 0 {
        return Err("no frames to make".into());
    }
    if let Some((k, c)) = keys.iter().enumerate().find(|(_, c)| (c.width, c.height) != (first.width, first.height)) {
        return Err(format!(
            "keyframe {k} is {}x{} and keyframe 0 {}x{}: keyframes to interpolate share one image size",
            c.width, c.height, first.width, first.height
        ));
    }
    if let Some(k) = keys.iter().position(|c| det3(|r, col| c.cam2world[r][col]) < 0.0) {
        return Err(format!("keyframe {k}'s axes are left-handed (a mirror image), not a camera's rotation"));
    }
    let position = |c: &Camera| DVec3::from_array(c.origin());
    let last = keys.len() - 1;
    // A loop: more than two keys, the last one the first again (to rounding).
    let closed =
        last >= 2 && position(first).distance(position(&keys[last])) <= 1e-9 * position(first).length().max(1.0);
    // Key `j` of the spline's neighbours: past an end, the end key, or across a loop's join.
    let neighbour = |j: isize| -> usize {
        let last = last as isize;
        let j = match (closed, j) {
            (true, j) if j < 0 => j + last,
            (true, j) if j > last => j - last,
            (_, j) => j.clamp(0, last),
        };
        j as usize
    };
    // The keys' orientations, each on the hemisphere of the one before (q and -q are one
    // rotation), and Shoemake's squad control points, which make the turning rate continuous
    // through the keys as the spline makes the velocity.
    let mut rotations: Vec<DQuat> = keys.iter().map(rotation).collect();
    for k in 1..rotations.len() {
        if rotations[k - 1].dot(rotations[k]) < 0.0 {
            rotations[k] = -rotations[k];
        }
    }
    let controls: Vec<DQuat> = (0..=last)
        .map(|k| {
            let q = rotations[k];
            let towards = |j: isize| {
                let n = rotations[neighbour(k as isize + j)];
                // The turn from `q` to the neighbour, as an axis times its angle (twice its log).
                (q.inverse() * if q.dot(n) < 0.0 { -n } else { n }).to_scaled_axis()
            };
            q * DQuat::from_scaled_axis(-(towards(-1) + towards(1)) / 4.0)
        })
        .collect();
    (0..frames)
        .map(|i| {
            // The path's parameter: key k at t = k.
            #[allow(clippy::cast_precision_loss)]
            let t = match (closed, frames) {
                (true, _) => i as f64 * last as f64 / frames as f64,
                (false, 1) => 0.0,
                (false, _) => i as f64 * last as f64 / (frames - 1) as f64,
            };
            // Truncation of a non-negative t no larger than `last`.
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let k = (t.floor() as usize).min(last.saturating_sub(1));
            let u = t - k as f64;
            let at = |j: isize| position(&keys[neighbour(k as isize + j)]);
            let (p0, p1, p2, p3) = (at(-1), at(0), at(1), at(2));
            let p = 0.5
                * (2.0 * p1
                    + (p2 - p0) * u
                    + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * u * u
                    + (3.0 * p1 - p0 - 3.0 * p2 + p3) * u * u * u);
            let next = (k + 1).min(last);
            let on_chord = rotations[k].slerp(rotations[next], u);
            let r = glam::DMat3::from_quat(on_chord.slerp(controls[k].slerp(controls[next], u), 2.0 * u * (1.0 - u)));
            let (a, b) = (&keys[k].pix2cam, &keys[next].pix2cam);
            let pix2cam =
                std::array::from_fn(|row| std::array::from_fn(|col| a[row][col] + (b[row][col] - a[row][col]) * u));
            let cam2world = std::array::from_fn(|row| {
                let axes = r.row(row);
                [axes.x, axes.y, axes.z, p[row]]
            });
            Camera::from_pix2cam(first.width, first.height, pix2cam, cam2world)
                .map_err(|e| format!("frame {i} (between keyframes {k} and {next}): {e}"))
        })
        .collect()
}

/// The rotation of `camera`'s pose, its axes made orthonormal first (exports may be sloppy by up
/// to [`mipnerf_core::camera::AXIS_LENGTH_RANGE`]).
fn rotation(camera: &Camera) -> DQuat {
    let m = camera.cam2world;
    let axis = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
    let x = axis(0).normalize();
    let y = (axis(1) - x * x.dot(axis(1))).normalize();
    // The third axis from the first two keeps a right-handed frame, as a camera's is.
    DQuat::from_mat3(&glam::DMat3::from_cols(x, y, x.cross(y)))
}

#[cfg(test)]
mod tests {
    use super::{interpolate, read, to_json, to_text};
    use mipnerf_core::camera::{Camera, pinhole_pix2cam};

    fn pose(x: f64) -> [[f64; 4]; 3] {
        [[1.0, 0.0, 0.0, x], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0]]
    }

    fn default_camera() -> Camera {
        Camera::from_pix2cam(40, 30, pinhole_pix2cam(40, 30, 50.0), pose(0.0)).unwrap()
    }

    fn read_text(text: &str, size: Option<(u32, u32)>) -> Result<Vec<Camera>, String> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cameras.json");
        std::fs::write(&path, text).unwrap();
        read(&path, &default_camera(), size).map_err(|e| e.to_string())
    }

    /// Written cameras read back as the same cameras, to rounding (`1 / (1 / f)`, and `serde_json`'s
    /// parsing of floats).
    #[test]
    fn written_cameras_read_back() {
        let a = Camera::from_pix2cam(64, 48, pinhole_pix2cam(64, 48, 71.3), pose(0.5)).unwrap();
        let mut p = pinhole_pix2cam(20, 10, 9.0);
        p[0][2] = -11.0 / 9.0; // cx = 11, off-centre
        p[1][1] = -1.0 / 8.0; // fl_y = 8
        let b = Camera::from_pix2cam(20, 10, p, pose(-2.0)).unwrap();
        let text = to_text(&[a.clone(), b.clone()]).unwrap();
        assert_eq!(
            serde_json::from_str::<serde_json::Value>(&text).unwrap(),
            to_json(&[a.clone(), b.clone()]).unwrap()
        );
        assert_eq!(text.lines().count(), 6, "{text}");
        let back = read_text(&text, None).unwrap();
        for (want, got) in [a, b].iter().zip(&back) {
            assert_eq!((want.width, want.height), (got.width, got.height));
            let values = |c: &Camera| {
                c.pix2cam.iter().flatten().chain(c.cam2world.iter().flatten()).copied().collect::<Vec<_>>()
            };
            for (w, g) in values(want).iter().zip(&values(got)) {
                assert!((w - g).abs() <= 1e-15 * w.abs().max(1.0), "{:?} against {:?}", want.pix2cam, got.pix2cam);
            }
        }
    }

    /// Blender's keys: `camera_angle_x` at the top level; the size and anything else from the
    /// default camera; `--width`/`--height` scale the intrinsics.
    #[test]
    fn blender_transforms_are_a_camera_file() {
        let text = r#"{"camera_angle_x": 1.0, "frames": [
            {"file_path": "./test/r_0", "transform_matrix": [[1,0,0,1],[0,1,0,2],[0,0,1,3],[0,0,0,1]]},
            {"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5]], "fl_x": 20}]}"#;
        let cams = read_text(text, None).unwrap();
        assert_eq!((cams[0].width, cams[0].height), (40, 30));
        assert_eq!(cams[0].origin(), [1.0, 2.0, 3.0]);
        let want = pinhole_pix2cam(40, 30, 20.0 / (0.5f64).tan());
        assert_eq!(cams[0].pix2cam, want);
        assert_eq!(cams[1].pix2cam, pinhole_pix2cam(40, 30, 20.0));
        // No intrinsics at all: the default camera's focal length.
        let plain = read_text(r#"{"frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5]]}]}"#, None).unwrap();
        assert_eq!(plain[0].pix2cam, default_camera().pix2cam);
        // Twice the size: twice the focal length, the principal point still centred.
        let big = read_text(text, Some((80, 60))).unwrap();
        assert_eq!(big[1].pix2cam, pinhole_pix2cam(80, 60, 40.0));
        // Another aspect ratio: the horizontal field of view and square pixels kept.
        let wide = read_text(text, Some((80, 30))).unwrap();
        assert_eq!(wide[1].pix2cam, pinhole_pix2cam(80, 30, 40.0));
    }

    /// A camera at `position` looking at the origin (z up), with focal length `focal`.
    fn looking_at_origin(position: [f64; 3], focal: f64) -> Camera {
        let back = glam::DVec3::from_array(position).normalize();
        let right = glam::DVec3::Z.cross(back).normalize();
        let up = back.cross(right);
        let pose = std::array::from_fn(|r| [right[r], up[r], back[r], position[r]]);
        Camera::from_pix2cam(40, 30, pinhole_pix2cam(40, 30, focal), pose).unwrap()
    }

    fn max_difference(a: &Camera, b: &Camera) -> f64 {
        let values =
            |c: &Camera| c.pix2cam.iter().flatten().chain(c.cam2world.iter().flatten()).copied().collect::<Vec<_>>();
        values(a).iter().zip(&values(b)).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    /// The interpolated path passes through every keyframe (pose and intrinsics), its rotations
    /// stay rotations, halfway between two keys of equal focal length the focal length is theirs,
    /// and the path has no kink at a key: the steps into and out of it agree to first order.
    #[test]
    fn interpolation_passes_through_the_keys_smoothly() {
        let keys = [
            looking_at_origin([4.0, 0.0, 1.0], 50.0),
            looking_at_origin([0.0, 4.0, 1.5], 50.0),
            looking_at_origin([-4.0, 0.0, 1.0], 80.0),
            looking_at_origin([0.0, -3.0, 2.0], 80.0),
        ];
        let frames = 3 * 40 + 1;
        let path = interpolate(&keys, frames).unwrap();
        assert_eq!(path.len(), frames);
        for (k, key) in keys.iter().enumerate() {
            let d = max_difference(key, &path[40 * k]);
            assert!(d < 1e-12, "keyframe {k} is off the path by {d:e}");
        }
        for c in &path {
            let m = c.cam2world;
            let r = glam::DMat3::from_cols_array_2d(&std::array::from_fn(|col| std::array::from_fn(|row| m[row][col])));
            let off =
                (r.transpose() * r - glam::DMat3::IDENTITY).to_cols_array().iter().fold(0.0f64, |a, x| a.max(x.abs()));
            assert!(off < 1e-12 && (r.determinant() - 1.0).abs() < 1e-12, "not a rotation: {r:?}");
        }
        assert!((path[20].pix2cam[0][0] - 1.0 / 50.0).abs() < 1e-15);
        let halfway = 1.0 / path[60].pix2cam[0][0];
        assert!((1.0 / halfway - 0.5 * (1.0 / 50.0 + 1.0 / 80.0)).abs() < 1e-15, "{halfway}");
        for k in [40, 80] {
            let p = |i: usize| glam::DVec3::from_array(path[i].origin());
            let (before, after) = (p(k) - p(k - 1), p(k + 1) - p(k));
            // The change of step over the step: the path's curvature times the step (about 0.1
            // here); joining the keys by straight lines would turn it by 1.4 (90 degrees).
            let kink = (after - before).length() / before.length();
            assert!(kink < 0.25, "the path turns by {kink} at keyframe {}", k / 40);
        }
        // One key: copies of it. Two frames of four keys: the first and the last.
        assert!(interpolate(&keys[..1], 3).unwrap().iter().all(|c| max_difference(c, &keys[0]) < 1e-12));
        let ends = interpolate(&keys, 2).unwrap();
        assert!(max_difference(&ends[0], &keys[0]) < 1e-12 && max_difference(&ends[1], &keys[3]) < 1e-12);
    }

    /// A loop (the last key the first again) plays round without a jolt: the step from the last
    /// frame to the first changes as little as the step through any other key, and the last key
    /// is not rendered twice.
    #[test]
    fn a_looped_path_joins_smoothly() {
        let ring = |deg: f64| {
            let a = deg.to_radians();
            looking_at_origin([4.0 * a.cos(), 4.0 * a.sin(), 1.0 + 0.3 * (2.0 * a).sin()], 50.0)
        };
        let keys: Vec<Camera> = [0.0, 90.0, 180.0, 270.0, 360.0].into_iter().map(ring).collect();
        let path = interpolate(&keys, 4 * 20).unwrap();
        for (k, key) in keys[..4].iter().enumerate() {
            assert!(max_difference(key, &path[20 * k]) < 1e-12, "keyframe {k} is not frame {}", 20 * k);
        }
        let p = |i: usize| glam::DVec3::from_array(path[i].origin());
        let (round_the_join, out_of_first) = (p(0) - p(79), p(1) - p(0));
        assert!(round_the_join.length() > 0.5 * out_of_first.length(), "the first frame is not twice over");
        let jolt = (out_of_first - round_the_join).length() / round_the_join.length();
        let (into_key, out_of_key) = (p(40) - p(39), p(41) - p(40));
        let through_key = (out_of_key - into_key).length() / into_key.length();
        assert!(jolt < 2.0 * through_key, "the join jolts by {jolt}, a key by {through_key}");
        // Without the loop (the last key moved off the first) the ends are the keys' own.
        let open: Vec<Camera> = [0.0, 90.0, 180.0, 270.0, 350.0].into_iter().map(ring).collect();
        let path = interpolate(&open, 81).unwrap();
        let p = |i: usize| glam::DVec3::from_array(path[i].origin());
        let jolt = ((p(1) - p(0)) - (p(80) - p(79))).length() / (p(80) - p(79)).length();
        assert!(jolt > 0.5, "an open path's ends are not joined: {jolt}");
    }

    /// The camera turns smoothly through a key: the turn from one frame to the next changes
    /// there by little more than between any two frames (joining the keys' orientations by
    /// separate slerps changes it by a step).
    #[test]
    fn orientations_turn_smoothly_through_the_keys() {
        let keys = [
            looking_at_origin([4.0, 0.0, 0.0], 50.0),
            looking_at_origin([3.0, 3.0, 2.5], 50.0),
            looking_at_origin([0.0, 4.0, -1.0], 50.0),
            looking_at_origin([-3.0, 2.0, 2.0], 50.0),
        ];
        let path = interpolate(&keys, 3 * 40 + 1).unwrap();
        let q = |i: usize| super::rotation(&path[i]);
        // The turn from frame i to i + 1, in the camera's own axes.
        let turn = |i: usize| (q(i).inverse() * q(i + 1)).to_scaled_axis();
        let change = |i: usize| (turn(i) - turn(i - 1)).length() / turn(i - 1).length();
        let between = (30..35).map(change).fold(0.0, f64::max);
        for k in [40, 80] {
            assert!(
                change(k) < 3.0 * between.max(0.01),
                "the turn changes by {} at frame {k}, {between} between keys",
                change(k)
            );
        }
    }

    /// Keys of different sizes, a mirrored pose and nothing to make are refused, naming the key.
    #[test]
    fn interpolation_refuses_what_it_cannot_join() {
        let a = looking_at_origin([4.0, 0.0, 1.0], 50.0);
        let mut b = Camera::from_pix2cam(20, 30, pinhole_pix2cam(20, 30, 50.0), a.cam2world).unwrap();
        assert!(interpolate(&[a.clone(), b.clone()], 5).unwrap_err().contains("keyframe 1 is 20x30"));
        b = a.clone();
        for row in &mut b.cam2world {
            row[0] = -row[0];
        }
        assert!(interpolate(&[a.clone(), b], 5).unwrap_err().contains("keyframe 1's axes are left-handed"));
        assert!(interpolate(&[], 5).is_err() && interpolate(&[a], 0).is_err());
    }

    /// Each bad file is refused naming the frame and the problem.
    #[test]
    fn bad_camera_files_are_named() {
        let m = r#""transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5]]"#;
        for (text, want) in [
            ("[1, 2]".to_owned(), "expected a JSON object".to_owned()),
            ("{}".to_owned(), "missing key \"frames\"".to_owned()),
            (r#"{"frames": []}"#.to_owned(), "\"frames\" is empty".to_owned()),
            (r#"{"frames": [3]}"#.to_owned(), "frame 0 is not an object".to_owned()),
            (format!(r#"{{"frames": [{{{m}}}, {{}}]}}"#), "frame 1: missing key \"transform_matrix\"".to_owned()),
            (format!(r#"{{"w": 10, "frames": [{{{m}}}]}}"#), "give both \"w\" and \"h\"".to_owned()),
            (format!(r#"{{"w": 0, "h": 5, "frames": [{{{m}}}]}}"#), "\"w\" is 0".to_owned()),
            (format!(r#"{{"w": 10.5, "h": 5, "frames": [{{{m}}}]}}"#), "\"w\" is 10.5".to_owned()),
            (format!(r#"{{"frames": [{{{m}, "fl_x": -3}}]}}"#), "frame 0: the focal length \"fl_x\" is -3".to_owned()),
            (format!(r#"{{"frames": [{{{m}, "fl_x": "wide"}}]}}"#), "\"fl_x\" is not a finite number".to_owned()),
            (format!(r#"{{"camera_angle_x": 4, "frames": [{{{m}}}]}}"#), "\"camera_angle_x\" is 4".to_owned()),
            (
                r#"{"frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,0,5]]}]}"#.to_owned(),
                "frame 0: invalid camera: cam2world rotation is singular".to_owned(),
            ),
            (r#"{"frames": [{"transform_matrix": [[1,0,0,0]]}]}"#.to_owned(), "expected a 4x4 matrix".to_owned()),
        ] {
            let err = read_text(&text, None).unwrap_err();
            assert!(err.contains("cameras.json") && err.contains(&want), "{text}: {err}");
        }
    }
}
