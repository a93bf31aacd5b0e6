//! `mipnerf convert`: a Blender scene to the multiscale format, or a COLMAP scene to LLFF's.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::ValueEnum;

use crate::outputs;

/// The flags of `mipnerf convert`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scene: Blender (transforms_*.json) for --to multiscale, COLMAP (sparse/ and
    /// images/) for --to llff.
    #[arg(long, value_name = "DIR")]
    pub input: PathBuf,
    /// Output directory (created). A folder holding files mipnerf did not write is refused
    /// unless --overwrite; the image folders are replaced whole, never mixed.
    #[arg(long, value_name = "DIR")]
    pub output: PathBuf,
    /// Write into a folder that holds files mipnerf did not write (a metadata.json or
    /// poses_bounds.npy of the same name is replaced; an image folder mipnerf did not
    /// write is still refused, and other files are left alone).
    #[arg(long)]
    pub overwrite: bool,
    /// What to write: the multiscale Blender format (from a Blender scene), or LLFF's
    /// poses_bounds.npy and images (from a COLMAP scene, as LLFF's imgs2poses does).
    #[arg(long, value_enum, default_value_t = ConvertTo::Multiscale)]
    pub to: ConvertTo,
    /// --to multiscale: first box-filter every image to N pixels wide (straight RGBA, area
    /// average, any ratio; the height in proportion), then make the 4 scales. N: at least 16,
    /// divisible by 8.
    #[arg(long, value_name = "N")]
    pub size: Option<u32>,
    /// --to llff: write the images box-filtered by N into images_N (0 or 1: full size, into
    /// images/; train on it with the same --llff-factor) [default: 4].
    #[arg(long, value_name = "N")]
    pub factor: Option<u32>,
}

/// `convert --to` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ConvertTo {
    /// The multiscale Blender format (metadata.json), from a Blender scene.
    Multiscale,
    /// LLFF's poses_bounds.npy and images, from a COLMAP scene.
    Llff,
}

/// Converts into `--output` under the outputs manifest's rule.
///
/// # Errors
/// A folder mipnerf did not write, or the conversion's errors.
pub fn run(a: Args) -> Result<()> {
    let Args { input, output, overwrite, to, size, factor } = a;
    match to {
        ConvertTo::Multiscale => {
            if factor.is_some() {
                bail!("--factor applies to --to llff; for --to multiscale, make smaller images with --size N");
            }
            let names = ["metadata.json", "images_train", "images_val", "images_test"];
            into_output_folder(&output, &names, overwrite, || {
                let done = mipnerf_data::multiscale::convert_resized(&input, &output, size)
                    .map(|splits| println!("converted {splits:?} into {}", output.display()));
                match size {
                    Some(n) => done.map_err(anyhow::Error::from).with_context(|| format!("--size {n}")),
                    None => done.map_err(Into::into),
                }
            })
        }
        ConvertTo::Llff => {
            let factor = factor.unwrap_or(4);
            let folder = if factor > 1 { format!("images_{factor}") } else { "images".to_string() };
            into_output_folder(&output, &["poses_bounds.npy", &folder], overwrite, || {
                convert_llff(&input, &output, size, factor)
            })
        }
    }
}

/// Runs `write`, which writes `names` (files and folders) into `output`, under the outputs
/// manifest's rule (`outputs::check_dir`): a folder holding files mipnerf did not write is
/// refused unless `overwrite`; a folder among `names` that mipnerf did not write is refused
/// even then (it would be replaced whole); the names are recorded before they are written. A
/// folder that did not exist and is left with nothing written is removed again.
fn into_output_folder(
    output: &Path,
    names: &[&str],
    overwrite: bool,
    write: impl FnOnce() -> Result<()>,
) -> Result<()> {
    outputs::check_dir(output, "--output", overwrite, "convert")?;
    let ours = mipnerf_core::io::recorded(output).context("reading the outputs manifest")?;
    for name in names {
        let path = output.join(name);
        if path.is_dir() && !ours.contains(*name) {
            bail!(
                "--output {}: {name}/ is a folder mipnerf did not write; it would be replaced whole, so it is left \
                 alone, --overwrite or not (choose another --output, or move it away)",
                output.display()
            );
        }
    }
    outputs::locked(output, "convert", "--output", || {
        outputs::record(output, "convert", names.iter().map(|n| (*n).to_string()))?;
        write()
    })
}

fn convert_llff(input: &Path, output: &Path, size: Option<u32>, factor: u32) -> Result<()> {
    if size.is_some() {
        bail!("--size applies to --to multiscale; for --to llff, downsample with --factor N");
    }
    if factor > 64 {
        bail!("--factor must be between 0 and 64, got {factor}");
    }
    let names = mipnerf_data::colmap::convert_to_llff(input, output, factor)?;
    let folder = if factor > 1 { format!("images_{factor}") } else { "images".to_string() };
    println!(
        "wrote {} and {} images to {}/{folder}; train with --data {} --llff-factor {} (add --spherify for a \
         capture all around the object)",
        output.join("poses_bounds.npy").display(),
        names.len(),
        output.display(),
        output.display(),
        if factor > 1 { factor } else { 0 }
    );
    Ok(())
}
