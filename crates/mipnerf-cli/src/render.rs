//! `mipnerf render`: a split's views or a camera path, as colour PNGs, depth and opacity EXRs,
//! colour-mapped depth PNGs, and an animated preview for paths.

use crate::session::Session;
use std::path::Path;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use mipnerf_core::Camera;
use mipnerf_core::backend::ImageSpec;
use mipnerf_core::dataset::{Dataset, Split};
use mipnerf_core::model::Levels;
use mipnerf_data::camera_path::{MAX_FRAMES, MAX_SIDE};

use crate::config::TrainSettings;
use crate::images::{depth_to_png, rgb_to_png, write_exr, write_png};
use crate::run::{RunOn, load_split, open_trained, read_config};

/// Camera paths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum PathKind {
    /// A circle around the scene at the training cameras' mean distance and elevation.
    Orbit,
    /// LLFF's official spiral; for other scenes an orbit whose elevation swings up and down.
    Spiral,
}

/// What to render.
#[derive(Clone, Debug)]
pub enum Target {
    /// Every view of a split at its own resolution.
    Split(Split),
    /// `frames` cameras along a path, and the video's frames per second.
    Path(PathKind, usize, u32),
    /// The cameras of a camera file ([`mipnerf_data::camera_path`]), or that many frames
    /// along a smooth path through them as keyframes, the video's frames per second, and the
    /// frame the file's poses are in (or nerfstudio's `dataparser_transforms.json`, whose model's
    /// frame they are in).
    Cameras(std::path::PathBuf, Option<usize>, u32, CameraFrame, Option<std::path::PathBuf>),
}

/// The world frame of a camera file's poses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum CameraFrame {
    /// The trained scene's own: what every render's cameras.json holds.
    #[default]
    Scene,
    /// The dataset's own world, before the loader recentred, rescaled or spherified it: COLMAP's
    /// (or a nerfstudio capture's transforms.json's) for data from `mipnerf colmap`, LLFF's
    /// poses_bounds.npy's; for Blender data the same as the scene's.
    Data,
}

impl Target {
    /// The video's frames per second, for a sequence of frames (a path or a camera file).
    const fn fps(&self) -> Option<u32> {
        match self {
            Self::Split(_) => None,
            Self::Path(_, _, fps) | Self::Cameras(_, _, fps, _, _) => Some(*fps),
        }
    }
}

/// The cameras a render rendered, in the camera-file form `--cameras` reads.
pub const CAMERAS: &str = "cameras.json";

/// The video of a path render (H.264 in MP4, see [`crate::images::Video`]).
pub const VIDEO: &str = "video.mp4";

/// Frames of a camera path by default.
pub const DEFAULT_FRAMES: usize = 60;

/// Frames per second of a path's video by default.
pub const DEFAULT_FPS: u32 = 24;

fn look_at(pos: glam::DVec3) -> [[f64; 4]; 3] {
    let back = pos.normalize();
    let right = glam::DVec3::Z.cross(back).normalize();
    let up = back.cross(right);
    std::array::from_fn(|r| [right[r], up[r], back[r], pos[r]])
}

/// Cameras along `kind` for a scene whose training views are `train`.
fn path_cameras(train: &Dataset, test: Option<&Dataset>, kind: PathKind, frames: usize) -> Result<Vec<Camera>> {
    if let (PathKind::Spiral, Some(t)) = (kind, test)
        && !t.render_path.is_empty()
    {
        let n = t.render_path.len();
        return Ok((0..frames).map(|i| t.render_path[i * n / frames].clone()).collect());
    }
    let full: Vec<&Camera> = train.views().iter().filter(|v| v.scale == 0).map(|v| &v.camera).collect();
    let n = full.len() as f64;
    let origins: Vec<glam::DVec3> = full.iter().map(|c| glam::DVec3::from_array(c.origin())).collect();
    let radius = origins.iter().map(|o| o.length()).sum::<f64>() / n;
    let elev = origins.iter().map(|o| (o.z / o.length()).asin()).sum::<f64>() / n;
    let base = full[0];
    (0..frames)
        .map(|i| {
            let az = i as f64 / frames as f64 * std::f64::consts::TAU;
            let el = match kind {
                PathKind::Orbit => elev,
                PathKind::Spiral => elev + 0.25 * (2.0 * az).sin(),
            };
            let pos = glam::DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * radius;
            Ok(Camera::from_pix2cam(base.width, base.height, base.pix2cam, look_at(pos))?)
        })
        .collect()
}

/// How far (degrees) a path's camera may be from the nearest training photo's before the render
/// says it starts outside the region the photos saw: around a scene, as seen from the scene's
/// centre; in a forward-facing (NDC) scene, between the directions they look in.
pub const OUTSIDE_DEGREES: f64 = 20.0;

/// A sentence naming the frames of a path whose cameras are more than [`OUTSIDE_DEGREES`] from
/// every training photo's: for a scene photographed from around it (in world space, around the
/// origin), where the camera stands as seen from the origin; for a forward-facing capture (NDC),
/// which holds only what lies in front of the photos, the direction the camera looks in. There
/// the model shows what it guesses, not what was photographed. `None` when every frame is within
/// reach.
#[must_use]
pub fn outside_the_photos(train: &Dataset, path: &[Camera]) -> Option<String> {
    let forward_facing = train.ndc.is_some();
    let direction = |c: &Camera| {
        let d = if forward_facing {
            // The viewing axis: the camera looks down its -z.
            -glam::DVec3::new(c.cam2world[0][2], c.cam2world[1][2], c.cam2world[2][2])
        } else {
            glam::DVec3::from_array(c.origin())
        };
        d.normalize_or_zero()
    };
    let dirs: Vec<glam::DVec3> = train.views().iter().filter(|v| v.scale == 0).map(|v| direction(&v.camera)).collect();
    let off: Vec<(usize, f64)> = path
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let d = direction(c);
            let nearest = dirs.iter().map(|p| p.dot(d).clamp(-1.0, 1.0).acos()).fold(f64::INFINITY, f64::min);
            (i, nearest.to_degrees())
        })
        .filter(|(_, deg)| *deg > OUTSIDE_DEGREES)
        .collect();
    let worst = off.iter().map(|(_, d)| *d).fold(0.0, f64::max);
    let (first, last) = (off.first()?.0, off.last()?.0);
    let how = if forward_facing {
        format!(
            "look away from the scene the photos saw, up to {worst:.0} degrees from the nearest photo's viewing \
             direction (a forward-facing capture holds only what lies in front of its photos)"
        )
    } else {
        format!(
            "start outside the region the photos saw, up to {worst:.0} degrees from the nearest photo as seen from the scene's centre"
        )
    };
    Some(format!(
        "{} of the {} frames (from frame {first} to {last}) {how}: there the render shows what the model guesses",
        off.len(),
        path.len()
    ))
}

/// `camera` at `w x h` pixels (the focal length scaled with the width).
fn resized(camera: &Camera, w: u32, h: u32) -> Result<Camera> {
    let s = f64::from(camera.width) / f64::from(w);
    let f = 1.0 / (camera.pix2cam[0][0] * s);
    Ok(Camera::from_pix2cam(w, h, mipnerf_core::camera::pinhole_pix2cam(w, h, f), camera.cam2world)?)
}

/// Rays per pixel side of the run's model (the NeRF baseline's supersampling).
pub(crate) fn read_supersample(s: &TrainSettings) -> Result<usize> {
    Ok(s.model_config()?.supersample)
}

/// The colour bar of the depth PNGs, in the render folder.
const DEPTH_SCALE: &str = "depth_scale.png";

/// Renders `target` of the run into `out`; returns the files written.
///
/// # Errors
/// Missing run files, bad sizes, unwritable outputs.
pub fn render(
    run: &Path,
    out: &Path,
    target: Target,
    size: Option<(u32, u32)>,
    on: RunOn<'_>,
    overwrite: bool,
    session: &Session,
) -> Result<Vec<std::path::PathBuf>> {
    let s = read_config(run)?;
    if let Some((w, h)) = size
        && (w == 0 || h == 0 || w > MAX_SIDE || h > MAX_SIDE)
    {
        bail!("--width and --height must be between 1 and {MAX_SIDE}, got {w}x{h}");
    }
    let k = read_supersample(&s)?;
    if let Some(fps) = target.fps()
        && (fps == 0 || fps > 240)
    {
        bail!("--fps must be between 1 and 240, got {fps}");
    }
    let jobs = render_jobs(&s, &target, size, k)?;
    let cameras_file: Vec<mipnerf_core::Camera> = jobs.iter().map(|(_, image)| image.camera.clone()).collect();
    let cameras_file = mipnerf_data::camera_path::to_text(&cameras_file);
    // Never into a folder of files mipnerf did not write (a dataset's images, say).
    crate::outputs::check_dir(out, "--out", overwrite, crate::outputs::RENDER)?;
    // Load the data first: a bad split fails before the device is opened.
    let (mut be, _, _) = open_trained(run, &s, on, session)?;
    // Only now, with every argument checked and the model open, is anything created. The
    // outputs of an earlier render into this folder go first (a folder never mixes two renders),
    // and the manifest names every file before any is written, so an interrupted render can be
    // redone.
    let mut names: Vec<String> = jobs.iter().flat_map(|(n, _)| frame_files(n)).collect();
    if target.fps().is_some() {
        names.extend(["preview.gif".to_owned(), VIDEO.to_owned()]);
    }
    names.extend([DEPTH_SCALE.to_owned(), CAMERAS.to_owned()]);
    crate::outputs::replace_outputs(out, names)?;
    // From here a signal stops the render between files (inside an image, at once), saying how
    // many images it wrote (none while the colour bar is drawn); every file on disk is whole.
    let cooperation = crate::signals::Cooperation::start();
    let mut written = write_depth_scale_and_cameras(out, &jobs, cameras_file)?;
    let (mut preview, mut video) = preview_and_video(target.fps(), &jobs, out)?;
    let mut pb = session.progress("render", 0, jobs.len() as u64);
    for (i, (name, image)) in jobs.iter().enumerate() {
        let left = format!(
            "{i} of {} images rendered into {} (each whole); run the same command again to render them all",
            jobs.len(),
            out.display()
        );
        // An image may take minutes (hours at the largest sizes): a signal while it renders stops
        // at once, and one while files are written waits for them.
        let Some(suspension) = cooperation.suspend(left.clone()) else {
            crate::signals::acted_on();
            pb.finish();
            return Err(crate::signals::Interrupted(left).into());
        };
        let (w, h) = (&image.camera.width, &image.camera.height);
        let fail = |e: anyhow::Error| incomplete_render(out, &jobs, i, e);
        let outs = be.render(image, Levels::Last).with_context(|| format!("rendering {name}")).map_err(fail)?.fine;
        drop(suspension);
        let rgb: Vec<[f32; 3]> = outs.iter().map(|o| o.rgb).collect();
        let depth: Vec<f32> = outs.iter().map(|o| o.distance).collect();
        let acc: Vec<f32> = outs.iter().map(|o| o.acc).collect();
        let (near, far) = (image.near, image.far);
        let png = rgb_to_png(&rgb);
        for (file, result) in [
            (format!("{name}.png"), write_png(&out.join(format!("{name}.png")), *w, *h, &png)),
            (
                format!("{name}_depth.exr"),
                write_exr(&out.join(format!("{name}_depth.exr")), *w as usize, *h as usize, "Z", &depth),
            ),
            (
                format!("{name}_acc.exr"),
                write_exr(&out.join(format!("{name}_acc.exr")), *w as usize, *h as usize, "A", &acc),
            ),
            (
                format!("{name}_depth.png"),
                write_png(&out.join(format!("{name}_depth.png")), *w, *h, &depth_to_png(&depth, &acc, near, far)),
            ),
        ] {
            result.map_err(fail)?;
            written.push(out.join(file));
        }
        if let Some(preview) = preview.as_mut() {
            preview.push(i, &png).map_err(fail)?;
        }
        if let Some(video) = video.as_mut() {
            video.push(&png).map_err(fail)?;
        }
        pb.inc();
    }
    pb.finish();
    let all = jobs.len();
    if let Some(preview) = preview {
        let gif = out.join("preview.gif");
        preview.write(&gif).map_err(|e| incomplete_render(out, &jobs, all, e))?;
        written.push(gif);
    }
    if let Some(video) = video {
        video.finish().map_err(|e| incomplete_render(out, &jobs, all, e))?;
        written.push(out.join(VIDEO));
    }
    Ok(written)
}

/// The files of a render's folder besides its frames: the depth PNGs' colour bar (explained once
/// for the folder) and the cameras (first: a render stopped midway names the frames it was to
/// render; none for cameras that are not a plain pinhole's). Returns the files written.
fn write_depth_scale_and_cameras(
    out: &Path,
    jobs: &[(String, ImageSpec)],
    cameras_file: Option<String>,
) -> Result<Vec<std::path::PathBuf>> {
    // The depth PNGs' colours, explained once for the folder.
    if let Some((_, first)) = jobs.first() {
        let title = "depth (transparent: white)";
        crate::plot::colour_bar(
            &out.join(DEPTH_SCALE),
            title,
            f64::from(first.near),
            f64::from(first.far),
            crate::images::turbo,
        )?;
    }
    let mut written = Vec::new();
    // The cameras, first: a render stopped midway names the frames it was to render.
    match cameras_file {
        Some(text) => {
            let path = out.join(CAMERAS);
            mipnerf_core::io::write_atomic(&path, text.as_bytes())?;
            written.push(path);
        }
        None => eprintln!("note: no {CAMERAS}: the cameras' intrinsics are not a plain pinhole's (fl_x, fl_y, cx, cy)"),
    }
    Ok(written)
}

/// The images a render makes, each with its name: the split's views, or a path's or a camera
/// file's frames (each the first training photo's image but for its camera, named in order).
fn render_jobs(
    s: &TrainSettings,
    target: &Target,
    size: Option<(u32, u32)>,
    k: usize,
) -> Result<Vec<(String, ImageSpec)>> {
    // (name, image) per image.
    let mut jobs: Vec<(String, ImageSpec)> = Vec::new();
    // A sequence of frames: the training split, its cameras, and whether to check them against
    // the photos' region.
    let mut sequence: Option<(Dataset, Vec<Camera>, bool)> = None;
    match target {
        Target::Split(split) => {
            let ds = load_split(s, *split)?;
            for v in 0..ds.views().len() {
                let view = &ds.views()[v];
                let stem = view.file.file_stem().map_or_else(|| format!("{v:04}"), |x| x.to_string_lossy().to_string());
                let mut image = ImageSpec::of_view(&ds, v, k);
                if let Some((w, h)) = size {
                    image.camera = resized(&view.camera, w, h)?;
                }
                jobs.push((stem, image));
            }
        }
        Target::Path(kind, frames, _) => {
            let frames = *frames;
            if frames == 0 || frames > MAX_FRAMES {
                bail!("--frames must be between 1 and {MAX_FRAMES}, got {frames}");
            }
            let train = load_split(s, Split::Train)?;
            let test = load_split(s, Split::Test).ok();
            let kind = *kind;
            if train.ndc.is_some()
                && (kind == PathKind::Orbit || test.as_ref().is_none_or(|t| t.render_path.is_empty()))
            {
                bail!("forward-facing (NDC) scenes only have the spiral path: pass --path spiral");
            }
            let cameras = path_cameras(&train, test.as_ref(), kind, frames)?
                .into_iter()
                .map(|cam| match size {
                    None => Ok(cam),
                    Some((w, h)) => resized(&cam, w, h),
                })
                .collect::<Result<Vec<_>>>()?;
            // LLFF's spiral stays in front of the photos by construction: only orbits are checked.
            let check = train.ndc.is_none();
            sequence = Some((train, cameras, check));
        }
        Target::Cameras(file, frames, _, frame, dataparser) => {
            use mipnerf_data::{camera_path, nerfstudio};
            // Asked of the file before the training split loads, so that such a path fails at once.
            if dataparser.is_none() && camera_path::is_nerfstudio_path(file) {
                bail!(
                    "{}: a camera path of nerfstudio's viewer, whose poses are in the frame of the model nerfstudio \
                     trained: give --dataparser-transforms with that model's dataparser_transforms.json (beside its \
                     config.yml); the mipnerf run must be trained on data from the same capture or COLMAP model",
                    file.display()
                );
            }
            let train = load_split(s, Split::Train)?;
            // What the file leaves out is the first full-scale training photo's.
            let mut cameras = camera_path::read(file, &train.views()[0].camera, size)?;
            // Into the data's frame (from nerfstudio's model's), then into the scene's.
            let to_data = dataparser.as_deref().map(nerfstudio::dataparser_to_data).transpose()?;
            let to_scene = (to_data.is_some() || *frame == CameraFrame::Data).then_some(train.data_to_scene);
            if let Some(to_scene) = to_scene {
                let to_data = to_data.unwrap_or(mipnerf_core::camera::Similarity::IDENTITY);
                cameras = cameras
                    .into_iter()
                    .enumerate()
                    .map(|(i, c)| {
                        Camera::from_pix2cam(c.width, c.height, c.pix2cam, to_scene.pose(&to_data.pose(&c.cam2world)))
                            .map_err(|e| anyhow::anyhow!("{}: camera {i}, moved into the scene: {e}", file.display()))
                    })
                    .collect::<Result<_>>()?;
            }
            if let Some(frames) = *frames {
                if frames == 0 || frames > MAX_FRAMES {
                    bail!("--frames must be between 1 and {MAX_FRAMES}, got {frames}");
                }
                cameras = mipnerf_data::camera_path::interpolate(&cameras, frames)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
            }
            sequence = Some((train, cameras, true));
        }
    }
    // A path's or a camera file's frames: each the first training photo's image but for its
    // camera, named in order.
    if let Some((train, cameras, check)) = sequence {
        if check && let Some(note) = outside_the_photos(&train, &cameras) {
            eprintln!("note: {note}");
        }
        let template = ImageSpec::of_view(&train, 0, k);
        for (i, camera) in cameras.into_iter().enumerate() {
            jobs.push((format!("frame_{i:04}"), ImageSpec { camera, ..template.clone() }));
        }
    }
    Ok(jobs)
}

/// A path's preview and video, made frame by frame as the frames come (so a long path at a
/// large size holds no more than a frame of video and a small preview); none for frames of
/// different sizes (a camera file may give each its own), nor without `fps` (not a path).
fn preview_and_video(
    fps: Option<u32>,
    jobs: &[(String, ImageSpec)],
    out: &Path,
) -> Result<(Option<crate::images::Preview>, Option<crate::images::Video>)> {
    // A path's preview and video, made frame by frame as the frames come (so a long path at a
    // large size holds no more than a frame of video and a small preview); none for frames of
    // different sizes (a camera file may give each its own).
    let (mut preview, mut video) = (None, None);
    if let (Some(fps), Some((_, first))) = (fps, jobs.first()) {
        let (w, h) = (first.camera.width, first.camera.height);
        if let Some((_, other)) = jobs.iter().find(|(_, j)| (j.camera.width, j.camera.height) != (w, h)) {
            eprintln!(
                "note: no preview.gif or {VIDEO}: the frames are of different sizes ({w}x{h}, {}x{}, ...); pass \
                 --width and --height for one size",
                other.camera.width, other.camera.height
            );
        } else {
            preview = Some(crate::images::Preview::new(jobs.len(), w, h));
            if w.min(h) >= crate::images::MIN_VIDEO_SIDE {
                video = Some(crate::images::Video::new(&out.join(VIDEO), w, h, fps)?);
            } else {
                eprintln!(
                    "note: no {VIDEO}: {w}x{h} frames are smaller than H.264 takes ({} px a side); pass --width and \
                     --height",
                    crate::images::MIN_VIDEO_SIDE
                );
            }
        }
    }
    Ok((preview, video))
}

/// The four files of the frame `name`: its image, depth and opacity EXRs, and depth picture.
fn frame_files(name: &str) -> [String; 4] {
    [".png", "_depth.exr", "_acc.exr", "_depth.png"].map(|suffix| format!("{name}{suffix}"))
}

/// The error of a render that failed (a full disk, a device lost) after its first `complete`
/// frames of `jobs` were written whole: what it wrote for the later frames, its preview and its
/// video are removed and dropped from the folder's manifest, so that the manifest lists only
/// whole files; its `cameras.json` is rewritten to hold the complete frames alone (removed when
/// there are none or it cannot be), and the error says which frames are complete.
fn incomplete_render(out: &Path, jobs: &[(String, ImageSpec)], complete: usize, error: anyhow::Error) -> anyhow::Error {
    let mut dropped: std::collections::BTreeSet<String> = jobs[complete..]
        .iter()
        .flat_map(|(n, _)| frame_files(n))
        .chain(["preview.gif".to_owned(), VIDEO.to_owned()])
        .collect();
    let cameras: Vec<mipnerf_core::Camera> = jobs[..complete].iter().map(|(_, image)| image.camera.clone()).collect();
    let kept_cameras = complete > 0
        && out.join(CAMERAS).is_file()
        && mipnerf_data::camera_path::to_text(&cameras)
            .is_some_and(|text| mipnerf_core::io::write_atomic(&out.join(CAMERAS), text.as_bytes()).is_ok());
    if !kept_cameras {
        dropped.insert(CAMERAS.to_owned());
    }
    for name in &dropped {
        let path = out.join(name);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file()) {
            let _ = std::fs::remove_file(&path);
        }
    }
    let listed = mipnerf_core::io::forget(out, &dropped).is_ok();
    let whole = match complete {
        0 => "no frame is complete".to_owned(),
        1 => format!("1 of {} frames is complete ({}, its files whole)", jobs.len(), jobs[0].0),
        n => {
            format!("{n} of {} frames are complete ({} to {}, their files whole)", jobs.len(), jobs[0].0, jobs[n - 1].0)
        }
    };
    error.context(format!(
        "the render into {} stopped: {whole}; {}{}",
        out.display(),
        if complete == jobs.len() {
            "the preview and the video were not written"
        } else {
            "the later frames, the preview and the video were not written"
        },
        if listed { "" } else { " (and its outputs manifest could not be updated)" }
    ))
}

#[cfg(test)]
mod tests {
    use super::{PathKind, outside_the_photos, path_cameras};
    use mipnerf_core::Camera;

    /// An orbit through the photos' own region says nothing; frames from below the floor, where
    /// no photo was taken, are named.
    #[test]
    fn frames_outside_the_photos_region_are_named() {
        let train = mipnerf_core::demo::dataset(16, 8).unwrap();
        let orbit = path_cameras(&train, None, PathKind::Orbit, 12).unwrap();
        assert_eq!(outside_the_photos(&train, &orbit), None);
        let base = &train.views()[0].camera;
        let below = |az: f64| {
            let pose = mipnerf_core::demo::camera_pose(az, -60f64.to_radians());
            Camera::from_pix2cam(base.width, base.height, base.pix2cam, pose).unwrap()
        };
        let mut path = orbit[..4].to_vec();
        path.extend([below(0.0), below(1.0)]);
        let note = outside_the_photos(&train, &path).unwrap();
        assert!(
            note.starts_with("2 of the 6 frames (from frame 4 to 5) start outside the region the photos saw"),
            "{note}"
        );
    }

    /// In a forward-facing scene what counts is where a camera looks: the photos' own cameras,
    /// moved sideways, say nothing; one turned round (or aside) is named.
    #[test]
    fn forward_facing_frames_that_look_away_are_named() {
        let mut train = mipnerf_core::demo::dataset(16, 8).unwrap();
        train.ndc = Some(mipnerf_core::dataset::Ndc { focal: 20.0, width: 16.0, height: 16.0 });
        let photo = train.views()[0].camera.clone();
        let mut moved = photo.clone();
        moved.cam2world[0][3] += 0.5;
        assert_eq!(outside_the_photos(&train, &[photo.clone(), moved]), None);
        let mut turned = photo.clone();
        for row in &mut turned.cam2world {
            (row[0], row[2]) = (-row[0], -row[2]);
        }
        let note = outside_the_photos(&train, &[photo, turned]).unwrap();
        assert!(
            note.starts_with("1 of the 2 frames (from frame 1 to 1) look away from the scene the photos saw"),
            "{note}"
        );
    }
}
