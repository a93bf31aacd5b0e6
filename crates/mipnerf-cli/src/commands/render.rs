//! `mipnerf render`: a trained run's views or a camera path.

use std::path::PathBuf;

use anyhow::Result;

use super::SplitArg;
use crate::backend::RenderOnArgs;
use crate::render;
use crate::session::Session;

/// The flags of `mipnerf render`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run directory.
    #[arg(long, value_name = "RUN_DIR")]
    pub run: PathBuf,
    /// Output directory (created).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Render every view of this split [default: test, unless --path or --cameras is given].
    #[arg(long, value_enum, conflicts_with_all = ["path", "cameras"])]
    pub split: Option<SplitArg>,
    /// Render a camera path instead.
    #[arg(long, value_enum, conflicts_with = "cameras")]
    pub path: Option<render::PathKind>,
    /// Render the cameras of a camera file instead: `transforms.json`-style frames, each a 4x4
    /// camera-to-world `transform_matrix`, with optional `w`, `h`, `fl_x`, `fl_y`, `cx`, `cy` or
    /// `camera_angle_x` per frame or for all (what a frame leaves out is the training photos');
    /// or a camera path of nerfstudio's viewer (camera_path.json, with --dataparser-transforms).
    /// Every render writes the cameras it rendered to `cameras.json` in this form.
    #[arg(long, value_name = "FILE")]
    pub cameras: Option<PathBuf>,
    /// The world frame of the --cameras file's poses: scene, the trained scene's own (what every
    /// render's cameras.json holds), or data, the dataset's own (COLMAP's, a nerfstudio capture's
    /// transforms.json's, LLFF's poses_bounds.npy's), before the loader recentred, rescaled or
    /// spherified it.
    #[arg(long, value_enum, default_value_t = render::CameraFrame::Scene, requires = "cameras")]
    pub cameras_in: render::CameraFrame,
    /// The --cameras file's poses are in the frame of a model nerfstudio trained (its viewer's
    /// camera_path.json): that model's dataparser_transforms.json (beside its config.yml) takes
    /// them to the data's frame, then into this run's scene (for a run trained on data from the
    /// same capture or COLMAP model).
    #[arg(long, value_name = "FILE", requires = "cameras")]
    pub dataparser_transforms: Option<PathBuf>,
    /// Frames of the path [default: 60]. With --cameras: that many frames along a smooth path
    /// through the file's cameras as keyframes (without it, the file's cameras as they are).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Frames per second of the path's (or camera file's) video (video.mp4, H.264, beside
    /// preview.gif).
    #[arg(long, default_value_t = render::DEFAULT_FPS)]
    pub fps: u32,
    /// Output width in pixels (with --height) [default: the data's].
    #[arg(long, requires = "height")]
    pub width: Option<u32>,
    /// Output height in pixels (with --width).
    #[arg(long, requires = "width")]
    pub height: Option<u32>,
    #[command(flatten)]
    pub on: RenderOnArgs,
    /// Write into --out even when it holds files mipnerf did not write (files of the same
    /// name are replaced); without it such a folder is refused.
    #[arg(long)]
    pub overwrite: bool,
}

/// Renders and prints how many files were written.
///
/// # Errors
/// As [`render::render`].
pub fn run(a: Args, session: &Session) -> Result<()> {
    if a.frames.is_some() && a.path.is_none() && a.cameras.is_none() {
        anyhow::bail!("--frames goes with --path (the frames of the path) or --cameras (frames through its cameras)");
    }
    let target = match (a.path, a.cameras) {
        (Some(kind), _) => render::Target::Path(kind, a.frames.unwrap_or(render::DEFAULT_FRAMES), a.fps),
        (None, Some(file)) => render::Target::Cameras(file, a.frames, a.fps, a.cameras_in, a.dataparser_transforms),
        (None, None) => render::Target::Split(a.split.unwrap_or(SplitArg::Test).into()),
    };
    let size = a.width.zip(a.height);
    let device = a.on.device.options();
    let on = crate::run::RunOn { backend: a.on.backend, precision: a.on.precision, device: &device };
    render::render(&a.run, &a.out, target, size, on, a.overwrite, session)
        .map(|files| println!("wrote {} files to {}", files.len(), a.out.display()))
}
