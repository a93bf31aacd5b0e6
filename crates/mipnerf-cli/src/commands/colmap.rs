//! `mipnerf colmap`: a COLMAP workspace of the user's photos (or a capture in nerfstudio's or
//! Instant-NGP's `transforms.json` form) to a dataset the trainer reads, with what COLMAP may have
//! got wrong named, and the command to train.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

/// The flags of `mipnerf colmap`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The COLMAP workspace: images/ (the photos) and sparse/ (the mapper's output); or a
    /// folder with nerfstudio's or Instant-NGP's transforms.json (and its point cloud,
    /// ply_file_path, for the depth bounds).
    #[arg(long, value_name = "DIR")]
    pub input: PathBuf,
    /// The dataset to write (a new or empty folder).
    #[arg(long, value_name = "DIR")]
    pub output: PathBuf,
    /// Downscale by the smallest whole factor that brings the longer side to at most this
    /// many pixels (0: full size).
    #[arg(long, value_name = "PX", default_value_t = mipnerf_data::process::DEFAULT_MAX_SIZE)]
    pub max_size: u32,
    /// Refuse when the largest model registers fewer photos than this.
    #[arg(long, value_name = "N", default_value_t = mipnerf_data::process::MIN_REGISTERED_VIEWS)]
    pub min_views: usize,
    /// Replace the dataset in a non-empty --output.
    #[arg(long)]
    pub overwrite: bool,
    /// Registered photos to leave out, by file name (comma-separated or repeated), such as
    /// those the step names as possibly wrong (a pose that disagrees with its neighbours, few
    /// 3D points, a high reprojection error).
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    pub exclude: Vec<String>,
    /// Foreground masks, one per photo (named as the photo, PNG or JPEG, white = the object, or a
    /// cut-out whose alpha is the mask): undistorted and downscaled as the photos are, to
    /// masks_N/ in --output, for `train --masks` (the object alone, without its surroundings).
    #[arg(long, value_name = "DIR")]
    pub masks: Option<PathBuf>,
}

/// Processes the workspace and prints the report and the train command.
///
/// # Errors
/// A `--max-size` too small, or the processing's errors, naming the file.
pub fn run(a: Args) -> Result<()> {
    colmap(&a.input, &a.output, a.max_size, a.min_views, a.overwrite, a.exclude, a.masks)
}

/// The recommended first run on a processed COLMAP scene (measured: docs/results/own-photos).
const COLMAP_FIRST_RUN: &str = "--preset fast --time-budget 15m";

/// The smallest `--max-size` of `mipnerf colmap` (besides 0, full size): smaller photos hold too
/// little of the scene to train on.
const MIN_COLMAP_SIZE: u32 = 32;

fn colmap(
    input: &Path,
    output: &Path,
    max_size: u32,
    min_views: usize,
    overwrite: bool,
    exclude: Vec<String>,
    masks: Option<PathBuf>,
) -> Result<()> {
    if max_size != 0 && max_size < MIN_COLMAP_SIZE {
        bail!(
            "--max-size {max_size}: the photos' longer side must be at least {MIN_COLMAP_SIZE} px (or 0 for full size)"
        );
    }
    crate::outputs::check_folder_path(output, "--output")?;
    let opts = mipnerf_data::process::ProcessOptions {
        max_size,
        min_views,
        recommended_views: mipnerf_data::process::RECOMMENDED_VIEWS.max(min_views),
        overwrite,
        exclude,
        masks,
    };
    let t = std::time::Instant::now();
    let r = crate::outputs::locked(output, "colmap", "--output", || {
        Ok(mipnerf_data::process::process(input, output, &opts)?)
    })?;
    print_registration(&r, input);
    print_camera(&r, t);
    print_train_command(&r, output);
    Ok(())
}

/// What `colmap` says of the photos: the model taken, the photos registered, left out and
/// suspect, and the warnings.
fn print_registration(r: &mipnerf_data::process::ProcessReport, input: &Path) {
    let taken = r.model_dir.strip_prefix(input).unwrap_or(&r.model_dir).display().to_string();
    let capture = r.source == mipnerf_data::process::SourceKind::Transforms;
    if capture {
        println!("{taken}: a capture in nerfstudio's or Instant-NGP's form (its poses, lens and point cloud)");
    }
    if r.models.len() > 1 {
        let list: Vec<String> = r.models.iter().map(|(k, c)| format!("sparse/{k} registers {c}")).collect();
        println!("{} COLMAP models ({}): took {taken}, the largest", r.models.len(), list.join(", "));
    }
    println!(
        "{taken}: {} of {} photos registered{}",
        r.registered + r.excluded.len(),
        r.photos,
        if r.excluded.is_empty() {
            String::new()
        } else {
            format!(", {} left out (--exclude): {}; {} kept", r.excluded.len(), r.excluded.join(", "), r.registered)
        }
    );
    if !r.suspects.is_empty() {
        println!(
            "{} may have got {} photos wrong (trained on, they blur or ghost the scene):",
            if capture { "the reconstruction behind the capture" } else { "COLMAP" },
            r.suspects.len()
        );
        for s in &r.suspects {
            println!("  {}: {}", s.name, s.why);
        }
        let names: Vec<&str> =
            r.suspects.iter().map(|s| s.name.as_str()).chain(r.excluded.iter().map(String::as_str)).collect();
        println!("to leave them out, run this step again with --exclude {} --overwrite", names.join(","));
    }
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
}

/// What `colmap` says of the camera: the lens and its undistortion, the focal check, the scene's
/// bounds, the photos held out and how the cameras face.
fn print_camera(r: &mipnerf_data::process::ProcessReport, t: std::time::Instant) {
    let capture = r.source == mipnerf_data::process::SourceKind::Transforms;
    // A capture's poses are COLMAP's too (or another tool's): what the step says of them.
    let who = if capture { "the capture's" } else { "COLMAP's" };
    let l = &r.lens;
    println!(
        "camera: {} {}x{} (fx {:.2}, fy {:.2}, principal point {:.2}, {:.2}, distortion {:?})",
        r.camera_model, l.width, l.height, l.fx, l.fy, l.cx, l.cy, l.distortion
    );
    println!(
        "undistorted to a centred pinhole {}x{}, focal {:.2}; written at {}x{} (factor {}) in {:.1}s",
        r.pinhole.width,
        r.pinhole.height,
        r.pinhole.focal,
        r.size.0,
        r.size.1,
        r.factor,
        t.elapsed().as_secs_f64()
    );
    print_focal_check(r, who);
    println!(
        "scene bounds: near {:.4}, far {:.4} ({}, 0.1 and 99.9 percentiles)",
        r.bounds.0,
        r.bounds.1,
        if capture {
            "the capture's units; depths of the points in front of each photo that project into it"
        } else {
            "COLMAP units; depths of the 3D points each photo sees"
        }
    );
    println!(
        "held out for testing ({} of {}, every 8th by name): {}",
        r.held_out.len(),
        r.registered,
        r.held_out.join(", ")
    );
    println!(
        "cameras {}",
        if r.all_around {
            "all around the scene: training with --spherify"
        } else {
            "facing one way (a forward-facing capture): training in NDC space, as LLFF scenes do"
        }
    );
}

/// What `colmap` says of the backdrop and the masks, and the command that trains the scene.
fn print_train_command(r: &mipnerf_data::process::ProcessReport, output: &Path) {
    let (white, black) = r.border_shares;
    let (background, backdrop) = match r.backdrop {
        Some(mipnerf_data::process::Backdrop::White) => {
            (" --background white", "a white backdrop, composited on white (--background white)")
        }
        Some(mipnerf_data::process::Backdrop::Black) => {
            (" --background black", "a black backdrop, composited on black (--background black)")
        }
        None => ("", "no plain backdrop (the surroundings are learnt)"),
    };
    println!("photo borders: {:.0}% near white, {:.0}% near black: {backdrop}", 100.0 * white, 100.0 * black);
    // Photos all around an object in its surroundings (a room): the room reaches past any box
    // around the cameras, so the scene trains unbounded.
    let unbounded = r.all_around && r.backdrop.is_none();
    if unbounded {
        println!(
            "surroundings seen all around: training the scene unbounded (--unbounded: space beyond the cameras \
             contracted into a shell, as mip-NeRF 360 does, so the room is learnt out to infinity)"
        );
    }
    let name = output.file_name().map_or_else(|| "scene".to_owned(), |n| n.to_string_lossy().into_owned());
    let scene = match &r.masks {
        // The object alone: its surroundings are masked out, so nothing reaches past the cameras.
        Some(dir) => {
            println!(
                "masks: undistorted and downscaled as the photos are, in {} (the object alone, composited on a random \
                 colour per pixel while training and on white for renders)",
                dir.display()
            );
            format!("{} --masks {}", if r.all_around { " --spherify" } else { "" }, dir.display())
        }
        None => format!(
            "{}{background}",
            match (r.all_around, unbounded) {
                (true, true) => " --unbounded",
                (true, false) => " --spherify",
                (false, _) => "",
            }
        ),
    };
    println!(
        "train with:\n  mipnerf train --data {} --llff-factor {}{scene} {COLMAP_FIRST_RUN} --out runs/{name}",
        output.display(),
        r.factor,
    );
}

/// Prints the reconstruction's focal length (`who`'s: COLMAP's, or the capture's) against the
/// photos' EXIF, and what to do when they disagree.
fn print_focal_check(r: &mipnerf_data::process::ProcessReport, who: &str) {
    let Some(c) = &r.focal else {
        println!("focal length: no photo has an EXIF focal length, so {who} {:.0} px is not checked", r.lens.fx);
        return;
    };
    let from = format!("{} of {} photos have one; the median, {}", c.photos_with_exif, r.registered, c.photo);
    if !c.disagrees() {
        println!(
            "focal length: {who} {:.0} px agrees with the photos' EXIF, {} ({from}), within {:.0}%",
            c.colmap_px,
            c.exif,
            100.0 * (mipnerf_data::focal::FOCAL_MISMATCH_FACTOR - 1.0)
        );
        return;
    }
    let l = &r.lens;
    eprintln!(
        "warning: {who} focal length, {:.0} px, is {:.2}x {} than the one the photos' EXIF implies, {} ({from}). \
         With the focal length wrong, every pose is wrong with it and the model blurs or ghosts: run COLMAP again \
         with the focal length given and kept (a mapper that refines it can trade it for lens distortion again), \
         from feature extraction on:\n  \
         colmap feature_extractor ... --ImageReader.single_camera 1 --ImageReader.camera_model SIMPLE_RADIAL \
         --ImageReader.camera_params \"{:.1},{:.1},{:.1},0\"\n  \
         colmap mapper ... --Mapper.ba_refine_focal_length 0 --Mapper.abs_pose_refine_focal_length 0\n  \
         (pycolmap: ImageReaderOptions(camera_model=\"SIMPLE_RADIAL\", camera_params=\"...\" as above) for \
         extract_features; IncrementalPipelineOptions' ba_refine_focal_length and mapper.abs_pose_refine_focal_length \
         False for incremental_mapping)",
        c.colmap_px,
        c.ratio(),
        if c.colmap_px < c.exif.focal_px { "shorter" } else { "longer" },
        c.exif,
        c.exif.focal_px,
        f64::from(l.width) / 2.0,
        f64::from(l.height) / 2.0,
    );
}
