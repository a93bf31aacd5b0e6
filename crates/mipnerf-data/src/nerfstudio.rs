//! A capture in nerfstudio's (and Instant-NGP's) `transforms.json` form, read as the process step
//! reads a COLMAP model ([`crate::process`]).
//!
//! nerfstudio's `ns-process-data` writes one `transforms.json` beside the photos, from its COLMAP
//! run; Instant-NGP's `colmap2nerf.py` and apps that export for either write the same form:
//! - the intrinsics `w`, `h`, `fl_x`, `fl_y`, `cx`, `cy` (pixels, COLMAP's convention: pixel
//!   centres at `i + 0.5`) and the lens's `k1`, `k2`, `p1`, `p2` (OpenCV's model), at the top
//!   level or per frame (a frame's own win); `camera_angle_x` when `fl_x` is absent; the size of
//!   the photo when `w` and `h` are;
//! - `camera_model`: `OPENCV` (or `PINHOLE`, `SIMPLE_PINHOLE`); fisheye and equirectangular
//!   lenses are refused, as is OpenCV's `k3`/`k4`;
//! - each frame's `file_path` (relative to the file's folder; Blender's files without extension
//!   are PNGs) and `transform_matrix`, camera to world with OpenGL's axes (x right, y up, looking
//!   down -z), in the capture's own world frame: nerfstudio's is COLMAP's turned by the file's
//!   `applied_transform`, which is undone (`saved_to_data`), so the dataset written is in
//!   COLMAP's frame whichever route it took (Instant-NGP's is also recentred and scaled, which the
//!   trainer's own recentring and rescaling take out);
//! - `ply_file_path`: the capture's 3D points (nerfstudio's `sparse_pc.ply`), which give each
//!   photo's depth bounds when no COLMAP model lies beside the file (below). The file holds no tracks, so a point counts as seen by a photo when it
//!   lies in front of it and projects into it. Points hidden behind a surface count too, so the
//!   far bound comes out farther than COLMAP's tracks give: on the test capture (nerfstudio's
//!   own output from a COLMAP model, `tests/data/nerfstudio_capture`) the scene's nearest bound
//!   is COLMAP's within 0.1% and its farthest 21% farther (`crates/mipnerf-cli/tests/nerfstudio.rs`).
//!
//! Where the COLMAP model the capture was made from lies beside the file ([`COLMAP_BESIDE`]:
//! nerfstudio's `colmap/sparse/N`, Instant-NGP's `colmap_sparse/N`), its points and tracks give
//! the bounds instead, as for the workspace itself: moved into the capture's frame by the
//! similarity that takes the model's cameras to the capture's (fitted to the photos matched by
//! name; Instant-NGP's frame is COLMAP's turned, recentred and scaled without saying so). A model
//! that does not fit is passed over for the point cloud, with a note. With neither, the step
//! refuses the capture and says what to do.
//! nerfstudio's own extras (`train_filenames`, per-frame `mask_path`, depth maps) are not read,
//! and [`Capture::notes`] says so.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use serde_json::{Map, Value};

use crate::colmap::{ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use crate::json_number;
use crate::undistort::LensCamera;
use crate::{DataError, pose_from_json, read_json};
use mipnerf_core::camera::{Similarity, focal_from_camera_angle_x};

/// The file a capture folder holds.
pub const TRANSFORMS: &str = "transforms.json";

/// How far a `transform_matrix`'s rotation may be from orthonormal (largest entry of `RᵀR − I`).
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// Whether `dir` holds a capture in this form.
#[must_use]
pub fn is_capture(dir: &Path) -> bool {
    // Whatever it is: one that is not a regular file is then refused by name, not taken for a
    // COLMAP workspace without its sparse/.
    std::fs::symlink_metadata(dir.join(TRANSFORMS)).is_ok()
}

/// A capture read as a COLMAP model.
#[derive(Clone, Debug)]
pub struct Capture {
    /// Its cameras (one per distinct set of intrinsics, numbered from 1 in frame order), images
    /// (named by their `file_path` relative to the capture's folder, numbered from 1 in frame
    /// order) and points (each seen by the photos it projects into; reprojection error 0, as the
    /// file has none).
    pub model: ColmapModel,
    /// The image folders the frames' files are in.
    pub photo_folders: Vec<PathBuf>,
    /// What of the file was not used, for the user.
    pub notes: Vec<String>,
}

/// Reads the capture in `dir` (its [`TRANSFORMS`] and point cloud).
///
/// # Errors
/// [`DataError`] naming the file (and the frame): malformed JSON, no frames, a frame without a
/// `file_path` or `transform_matrix`, a photo that is not there, a path that leaves the folder,
/// intrinsics that are not positive finite numbers, a lens this tool cannot undistort, a
/// rotation that is not one, no point cloud, and [`crate::ply::read_points`]'s errors.
pub fn read(dir: &Path) -> Result<Capture, DataError> {
    let path = dir.join(TRANSFORMS);
    let json = read_json(&path)?;
    let top = json.as_object().ok_or_else(|| DataError::invalid(&path, "expected a JSON object with \"frames\""))?;
    let frames = top.get("frames").and_then(Value::as_array).filter(|f| !f.is_empty()).ok_or_else(|| {
        DataError::invalid(&path, "no \"frames\" list (each with a file_path and a transform_matrix)")
    })?;
    let to_data = saved_to_data(top, &path)?;
    let mut model = ColmapModel::default();
    let mut cameras: HashMap<String, u32> = HashMap::new();
    let mut folders: Vec<PathBuf> = Vec::new();
    for (i, frame) in frames.iter().enumerate() {
        let at = |problem: String| DataError::invalid(&path, format!("frame {i}: {problem}"));
        let frame = frame.as_object().ok_or_else(|| at("is not an object".into()))?;
        let name = photo_name(dir, frame).map_err(at)?;
        let file = dir.join(&name);
        if let Some(parent) = file.parent().map(Path::to_path_buf)
            && !folders.contains(&parent)
        {
            folders.push(parent);
        }
        let camera = camera(frame, top, &file).map_err(at)?;
        let key = format!("{} {} {} {:?}", camera.model_id, camera.width, camera.height, camera.params);
        let next = u32::try_from(cameras.len() + 1).unwrap_or(u32::MAX);
        let camera_id = *cameras.entry(key).or_insert_with(|| {
            model.cameras.push(ColmapCamera { id: next, ..camera });
            next
        });
        let pose = frame.get("transform_matrix").ok_or_else(|| at("missing key \"transform_matrix\"".into()))?;
        let c2w = pose_from_json(pose, &path, &format!("frame {i}: transform_matrix"))?;
        let (qvec, tvec) = world_to_camera(&to_data.pose(&c2w)).map_err(at)?;
        let id = u32::try_from(i + 1).unwrap_or(u32::MAX);
        model.images.push(ColmapImage { id, qvec, tvec, camera_id, name });
    }
    let mut notes = Vec::new();
    for (key, what) in [
        ("train_filenames", "its train/test lists are not used: every 8th photo by name is held out for testing"),
        ("mask_path", "its frames' mask_path files are not read: give masks with --masks"),
        ("depth_file_path", "its depth maps are not used"),
    ] {
        if top.contains_key(key) || frames.iter().any(|f| f.get(key).is_some()) {
            notes.push(format!("{}: {what}", path.display()));
        }
    }
    let ply = top.get("ply_file_path").and_then(Value::as_str);
    // The COLMAP model beside the file, when there is one that fits: its points with their tracks.
    let beside = match model_beside(dir)? {
        None => None,
        Some(folder) => {
            let colmap = crate::colmap::read_model(&folder)?;
            match colmap_to_capture(&colmap, &model) {
                Ok(fit) => Some((folder, colmap, fit)),
                Err(e) if ply.is_some() => {
                    notes.push(format!(
                        "{}: the COLMAP model in {} is not this capture's ({e}); its point cloud gives the bounds",
                        path.display(),
                        folder.display()
                    ));
                    None
                }
                Err(e) => {
                    return Err(DataError::invalid(
                        &path,
                        format!("the COLMAP model in {} is not this capture's: {e}", folder.display()),
                    ));
                }
            }
        }
    };
    if let Some((folder, colmap, (fit, ids, residual))) = beside {
        notes.push(format!(
            "{}: the 3D points of the COLMAP model in {}, with the photos that see them, give the depth bounds, moved \
             into the capture's frame by the similarity that takes its cameras to the capture's ({} photos matched by \
             name, the farthest {residual:.1e} of their spread off)",
            path.display(),
            folder.display(),
            ids.len()
        ));
        model.points = colmap
            .points
            .iter()
            .map(|p| ColmapPoint {
                xyz: fit.point(p.xyz),
                image_ids: p.image_ids.iter().filter_map(|id| ids.get(id).copied()).collect(),
                error: p.error,
            })
            .filter(|p| !p.image_ids.is_empty())
            .collect();
    } else if let Some(ply) = ply {
        let ply = dir.join(relative(ply).map_err(|e| DataError::invalid(&path, format!("\"ply_file_path\": {e}")))?);
        let points: Vec<[f64; 3]> = crate::ply::read_points(&ply)?.into_iter().map(|p| to_data.point(p)).collect();
        if points.len() < MIN_CLOUD_POINTS {
            return Err(DataError::invalid(
                &ply,
                format!(
                    "holds {} point(s); the depth bounds need at least {MIN_CLOUD_POINTS} (a structure-from-motion cloud \
                     has thousands): is it this capture's point cloud?",
                    points.len()
                ),
            ));
        }
        model.points = seen_points(&model, &points).map_err(|e| DataError::invalid(&path, e))?;
        check_some_photo_sees_points(&model, &ply, points.len())?;
    } else {
        return Err(DataError::invalid(
            &path,
            format!(
                "no point cloud (\"ply_file_path\") and no COLMAP model beside it ({}), so the photos' depth bounds \
                 cannot be measured: nerfstudio's ns-process-data writes one (sparse_pc.ply); or run this step on the \
                 COLMAP workspace the poses came from (its images/ and sparse/)",
                COLMAP_BESIDE.join(", ")
            ),
        ));
    }
    Ok(Capture { model, photo_folders: folders, notes })
}

/// The fewest points a capture's point cloud may hold: each photo's bounds are the 0.1 and 99.9
/// percentiles of the depths of the points it sees, which a handful of points do not measure.
pub const MIN_CLOUD_POINTS: usize = 100;

/// Refuses a point cloud (`ply`, of `count` points) of which no photo sees a point, naming the
/// cloud rather than a photo: a cloud whose points are all far away (at 1e300), or of another
/// capture, is the cloud's fault. (A photo alone that sees none is named later, after
/// `--exclude` could leave it out.)
fn check_some_photo_sees_points(model: &ColmapModel, ply: &Path, count: usize) -> Result<(), DataError> {
    if model.points.iter().any(|p| !p.image_ids.is_empty()) {
        return Ok(());
    }
    Err(DataError::invalid(
        ply,
        format!(
            "none of its {count} points lies in front of a photo and inside its frame, so the photos have no depth \
             bounds: is it this capture's point cloud, in the frame of its transforms.json?"
        ),
    ))
}

/// Where nerfstudio (`colmap/sparse/N`) and Instant-NGP's `colmap2nerf.py` (`colmap_sparse/N`,
/// `colmap_text`) leave the COLMAP model a capture was made from, relative to its folder.
pub const COLMAP_BESIDE: [&str; 3] = ["colmap/sparse", "colmap_sparse", "colmap_text"];

/// How far a camera of the COLMAP model beside a capture may lie from the capture's own once
/// moved by the fitted similarity, as a share of the capture's cameras' spread (their RMS
/// distance from their mean); the two are the same reconstruction, so only rounding separates
/// them.
pub const FIT_TOLERANCE: f64 = 1e-4;

/// The COLMAP model beside the capture in `dir` ([`COLMAP_BESIDE`], the first found; of several
/// numbered ones, the largest).
fn model_beside(dir: &Path) -> Result<Option<PathBuf>, DataError> {
    for rel in COLMAP_BESIDE {
        let folder = dir.join(rel);
        if folder.is_dir()
            && let Ok(models) = crate::colmap::models_in(&folder)
        {
            return Ok(Some(crate::colmap::largest(&models).1.clone()));
        }
    }
    Ok(None)
}

/// The similarity that takes the cameras of the COLMAP model `colmap` to those of the same
/// photos (matched by file name) in `capture`, the capture's read as a COLMAP model; with the
/// matched photos' ids (COLMAP's to the capture's) and the farthest camera's residual as a share
/// of their spread.
///
/// # Errors
/// Fewer than 3 photos matched, cameras all in one place, a residual over [`FIT_TOLERANCE`].
fn colmap_to_capture(
    colmap: &ColmapModel,
    capture: &ColmapModel,
) -> Result<(Similarity, HashMap<u32, u32>, f64), String> {
    let file_name = |n: &str| n.rsplit('/').next().unwrap_or(n).to_owned();
    let by_name: HashMap<String, &ColmapImage> = colmap.images.iter().map(|im| (file_name(&im.name), im)).collect();
    // Camera-to-world rotation and centre of a COLMAP image.
    let pose = |im: &ColmapImage| {
        let [w, x, y, z] = im.qvec;
        let rt = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize()).transpose();
        (rt, -(rt * DVec3::from_array(im.tvec)))
    };
    let matched: Vec<(&ColmapImage, &ColmapImage)> =
        capture.images.iter().filter_map(|im| by_name.get(&file_name(&im.name)).map(|c| (*c, im))).collect();
    let pairs: Vec<((DMat3, DVec3), (DMat3, DVec3))> = matched.iter().map(|(c, im)| (pose(c), pose(im))).collect();
    if pairs.len() < 3 {
        return Err(format!("{} of its photos match the capture's by name; at least 3 are needed", pairs.len()));
    }
    // The rotation: the mean of each pair's, as unit quaternions on one side of the sphere.
    let first = DQuat::from_mat3(&(pairs[0].1.0 * pairs[0].0.0.transpose()));
    let sum = pairs.iter().fold(glam::DVec4::ZERO, |acc, ((from, _), (to, _))| {
        let q = DQuat::from_mat3(&(*to * from.transpose()));
        let q = if q.dot(first) < 0.0 { -q } else { q };
        acc + glam::DVec4::from(q)
    });
    let turn = DMat3::from_quat(DQuat::from_vec4(sum).normalize());
    let n = pairs.len() as f64;
    let mean_from = pairs.iter().map(|p| turn * p.0.1).sum::<DVec3>() / n;
    let mean_to = pairs.iter().map(|p| p.1.1).sum::<DVec3>() / n;
    let spread_from = (pairs.iter().map(|p| (turn * p.0.1 - mean_from).length_squared()).sum::<f64>() / n).sqrt();
    let spread_to = (pairs.iter().map(|p| (p.1.1 - mean_to).length_squared()).sum::<f64>() / n).sqrt();
    if !(spread_from > 0.0 && spread_to > 0.0) {
        return Err("the matched cameras stand in one place, so no scale can be fitted".into());
    }
    let scale = spread_to / spread_from;
    let shift = mean_to - scale * mean_from;
    let fit = Similarity { rotation: turn.transpose().to_cols_array_2d(), scale, translation: shift.to_array() };
    let residual = pairs
        .iter()
        .map(|((_, c), (_, d))| (DVec3::from_array(fit.point(c.to_array())) - *d).length() / spread_to)
        .fold(0.0, f64::max);
    if residual > FIT_TOLERANCE {
        return Err(format!(
            "moved onto the capture's cameras, one stands {residual:.1e} of their spread off (at most {FIT_TOLERANCE:e})"
        ));
    }
    Ok((fit, matched.iter().map(|(c, im)| (c.id, im.id)).collect(), residual))
}

/// The similarity from a `transforms.json`'s frame back to the data's own: nerfstudio turns
/// COLMAP's world by `applied_transform` (rigid, 3x4) before it writes the poses and points,
/// so they are turned back; the identity without one (Instant-NGP's files, and nerfstudio's from
/// `--keep-original-world-coordinate`).
///
/// # Errors
/// An `applied_transform` that is not a 3x4 (or 4x4) rigid transform, naming `path`.
pub(crate) fn saved_to_data(top: &Map<String, Value>, path: &Path) -> Result<Similarity, DataError> {
    let Some(applied) = top.get("applied_transform") else { return Ok(Similarity::IDENTITY) };
    let m = pose_from_json(applied, path, "applied_transform")?;
    let rigid = Similarity::rigid(&m, ROTATION_TOLERANCE)
        .ok_or_else(|| DataError::invalid(path, "applied_transform's 3x3 part is not a rotation"))?;
    Ok(rigid.inverse())
}

/// The similarity from the frame of a model nerfstudio trained (its viewer's, its camera paths')
/// back to the data's own, read from the `dataparser_transforms.json` that `ns-train` writes
/// beside its `config.yml`: nerfstudio takes the data's points `p` to `scale · (T p)`, with `T`
/// its `transform` (3x4, rigid, `applied_transform` included) and `scale` its `scale`.
///
/// # Errors
/// [`DataError`] naming the file: malformed JSON, no `transform` or `scale`, a transform that is
/// not rigid, a scale that is not a positive finite number.
pub fn dataparser_to_data(path: &Path) -> Result<Similarity, DataError> {
    let json = read_json(path)?;
    let transform = json.get("transform").ok_or_else(|| {
        DataError::invalid(path, "no \"transform\" (nerfstudio's dataparser_transforms.json has transform and scale)")
    })?;
    let m = pose_from_json(transform, path, "transform")?;
    let rigid = Similarity::rigid(&m, ROTATION_TOLERANCE)
        .ok_or_else(|| DataError::invalid(path, "transform's 3x3 part is not a rotation"))?;
    let scale = json
        .get("scale")
        .and_then(Value::as_f64)
        .filter(|s| s.is_finite() && *s > 0.0)
        .ok_or_else(|| DataError::invalid(path, "\"scale\" must be a positive number"))?;
    Ok(Similarity { scale, translation: rigid.translation.map(|t| scale * t), ..rigid }.inverse())
}

/// `p` as a path inside the capture's folder (`./` dropped); absolute paths and `..` refused.
fn relative(p: &str) -> Result<PathBuf, String> {
    let path = Path::new(p);
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            std::path::Component::Normal(s) => out.push(s),
            std::path::Component::CurDir => {}
            _ => return Err(format!("{p:?} leads out of the capture's folder; give paths inside it")),
        }
    }
    if out.as_os_str().is_empty() {
        return Err(format!("{p:?} names no file"));
    }
    Ok(out)
}

/// A frame's photo, relative to the capture's folder, as a `/`-separated name; Blender's
/// `file_path`s without extension are PNGs.
fn photo_name(dir: &Path, frame: &Map<String, Value>) -> Result<String, String> {
    let p = frame.get("file_path").and_then(Value::as_str).ok_or("missing key \"file_path\" (a string)")?;
    let mut rel = relative(p)?;
    let there = |rel: &Path| std::fs::symlink_metadata(dir.join(rel)).is_ok();
    if !there(&rel) && rel.extension().is_none() && there(&rel.with_extension("png")) {
        rel.set_extension("png");
    }
    match mipnerf_core::io::check_regular(&dir.join(&rel)) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!("its photo {} is not there", dir.join(&rel).display()));
        }
        Err(e) => return Err(format!("its photo {} {e}", dir.join(&rel).display())),
    }
    Ok(rel.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/"))
}

/// The COLMAP camera of a frame: PINHOLE without distortion, else OPENCV (its id set by the
/// caller). `file` gives the size when the frame and the file leave it out.
fn camera(frame: &Map<String, Value>, top: &Map<String, Value>, file: &Path) -> Result<ColmapCamera, String> {
    let lens =
        frame.get("camera_model").or_else(|| top.get("camera_model")).and_then(Value::as_str).unwrap_or("OPENCV");
    match lens {
        "OPENCV" | "PINHOLE" | "SIMPLE_PINHOLE" => {}
        "OPENCV_FISHEYE" | "EQUIRECTANGULAR" => {
            return Err(format!(
                "camera_model {lens}: mipnerf cannot undistort this lens; undistort the photos to pinholes first \
                 (COLMAP's image_undistorter), or run this step on the COLMAP workspace"
            ));
        }
        other => return Err(format!("camera_model {other:?}: expected OPENCV, PINHOLE or SIMPLE_PINHOLE")),
    }
    let (w, h) = match (json_number("w", frame, top)?, json_number("h", frame, top)?) {
        (Some(w), Some(h)) => (w, h),
        (None, None) => {
            let (w, h) = crate::image_size(file).map_err(|e| e.to_string())?;
            (f64::from(w), f64::from(h))
        }
        _ => return Err("give both \"w\" and \"h\", or neither (the photo's size)".into()),
    };
    if !(w >= 1.0 && h >= 1.0 && w.fract() == 0.0 && h.fract() == 0.0 && w.max(h) <= f64::from(u32::MAX)) {
        return Err(format!("the size {w}x{h} is not a whole number of pixels"));
    }
    let fx = match (json_number("fl_x", frame, top)?, json_number("camera_angle_x", frame, top)?) {
        (Some(f), _) => f,
        (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => {
            // `w` is a whole number of pixels from 1 to u32::MAX (checked above).
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            focal_from_camera_angle_x(w as u32, a)
        }
        (None, Some(a)) => return Err(format!("\"camera_angle_x\" is {a}; a field of view in radians is in (0, pi)")),
        (None, None) => return Err("no focal length: give \"fl_x\" (pixels) or \"camera_angle_x\" (radians)".into()),
    };
    let fy = json_number("fl_y", frame, top)?.unwrap_or(fx);
    let cx = json_number("cx", frame, top)?.unwrap_or(0.5 * w);
    let cy = json_number("cy", frame, top)?.unwrap_or(0.5 * h);
    let mut k = [0.0; 4];
    for (slot, key) in k.iter_mut().zip(["k1", "k2", "p1", "p2"]) {
        *slot = json_number(key, frame, top)?.unwrap_or(0.0);
    }
    for key in ["k3", "k4"] {
        if let Some(x) = json_number(key, frame, top)?.filter(|&x| x != 0.0) {
            return Err(format!(
                "\"{key}\" is {x}: mipnerf undistorts OpenCV's k1, k2, p1, p2 only; undistort the photos first \
                 (COLMAP's image_undistorter)"
            ));
        }
    }
    let (model_id, params) =
        if k == [0.0; 4] { (1, vec![fx, fy, cx, cy]) } else { (4, vec![fx, fy, cx, cy, k[0], k[1], k[2], k[3]]) };
    // Whole numbers from 1 to u32::MAX (checked above).
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let camera = ColmapCamera { id: 0, model_id, width: w as u64, height: h as u64, params };
    LensCamera::from_colmap(&camera).map_err(|e| e.replacen("camera 0", "its lens", 1))?;
    Ok(camera)
}

/// COLMAP's world-to-camera rotation (`[w, x, y, z]`) and translation of an OpenGL
/// camera-to-world pose: its y and z axes turned round (OpenCV's camera looks down +z with y
/// down), then inverted.
fn world_to_camera(c2w: &[[f64; 4]; 3]) -> Result<([f64; 4], [f64; 3]), String> {
    let col = |j: usize| DVec3::new(c2w[0][j], c2w[1][j], c2w[2][j]);
    let r = DMat3::from_cols(col(0), -col(1), -col(2));
    let opencv: [[f64; 4]; 3] = std::array::from_fn(|i| [c2w[i][0], -c2w[i][1], -c2w[i][2], c2w[i][3]]);
    if Similarity::rigid(&opencv, ROTATION_TOLERANCE).is_none() {
        return Err(format!(
            "transform_matrix's 3x3 part is not a rotation (its columns are {:.4}, {:.4}, {:.4} long, its determinant \
             {:.4}): a camera-to-world pose has orthonormal axes",
            col(0).length(),
            col(1).length(),
            col(2).length(),
            r.determinant()
        ));
    }
    let rt = r.transpose();
    let q = DQuat::from_mat3(&rt).normalize();
    let t = -(rt * col(3));
    Ok(([q.w, q.x, q.y, q.z], t.to_array()))
}

/// Each point with the images it lies in front of and projects into (through each camera's lens).
fn seen_points(model: &ColmapModel, points: &[[f64; 3]]) -> Result<Vec<ColmapPoint>, String> {
    let lenses: HashMap<u32, LensCamera> =
        model.cameras.iter().map(|c| LensCamera::from_colmap(c).map(|l| (c.id, l))).collect::<Result<_, _>>()?;
    let views: Vec<(u32, DMat3, DVec3, &LensCamera)> = model
        .images
        .iter()
        .map(|im| {
            let [w, x, y, z] = im.qvec;
            (im.id, DMat3::from_quat(DQuat::from_xyzw(x, y, z, w)), DVec3::from_array(im.tvec), &lenses[&im.camera_id])
        })
        .collect();
    Ok(points
        .iter()
        .map(|&xyz| {
            let p = DVec3::from_array(xyz);
            let image_ids = views
                .iter()
                .filter(|(_, r, t, lens)| {
                    let c = *r * p + *t;
                    if c.z <= 0.0 {
                        return false;
                    }
                    let (x, y) = lens.img_from_cam(c.x / c.z, c.y / c.z);
                    (0.0..f64::from(lens.width)).contains(&x) && (0.0..f64::from(lens.height)).contains(&y)
                })
                .map(|v| v.0)
                .collect();
            ColmapPoint { xyz, image_ids, error: 0.0 }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera turned and moved arbitrarily: the COLMAP pose maps its centre to the origin and
    /// a point on its OpenGL viewing axis (-z) to +z in COLMAP's camera frame, y up to -y.
    #[test]
    fn opengl_poses_become_colmaps_world_to_camera() {
        let rot = DMat3::from_quat(DQuat::from_euler(glam::EulerRot::YXZ, 0.7, -0.3, 1.1));
        let centre = DVec3::new(1.0, -2.0, 0.5);
        let mut c2w = [[0.0; 4]; 3];
        for i in 0..3 {
            c2w[i] = [rot.x_axis[i], rot.y_axis[i], rot.z_axis[i], centre[i]];
        }
        let (q, t) = world_to_camera(&c2w).unwrap();
        let r = DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]));
        let t = DVec3::from_array(t);
        assert!((r * centre + t).length() < 1e-12);
        let ahead = r * (centre - 2.0 * rot.z_axis) + t;
        assert!((ahead - DVec3::new(0.0, 0.0, 2.0)).length() < 1e-12, "{ahead}");
        let up = r * (centre + rot.y_axis) + t;
        assert!((up - DVec3::new(0.0, -1.0, 0.0)).length() < 1e-12, "{up}");
        // A scaled rotation and a mirror are refused.
        let mut scaled = c2w;
        scaled[0][0] *= 2.0;
        assert!(world_to_camera(&scaled).unwrap_err().contains("not a rotation"));
        let mut mirrored = c2w;
        for row in &mut mirrored {
            row[0] = -row[0];
        }
        assert!(world_to_camera(&mirrored).unwrap_err().contains("determinant"));
    }

    #[test]
    fn paths_stay_inside_the_capture() {
        assert_eq!(relative("./images/a.png").unwrap(), PathBuf::from("images/a.png"));
        assert!(relative("../a.png").unwrap_err().contains("leads out"));
        assert!(relative("/etc/a.png").unwrap_err().contains("leads out"));
        assert!(relative("./").unwrap_err().contains("names no file"));
    }
}
