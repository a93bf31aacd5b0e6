//! Output folders that never replace a user's files: `render --out DIR` and `figure --out FILE`
//! write only where mipnerf wrote before, or where nothing is.
//!
//! Every folder mipnerf writes outputs into gets a manifest ([`MANIFEST`]): the names of the files
//! it wrote there, recorded before they are written (so an interrupted render can be redone).
//! A folder that holds any file not in its manifest, such as a dataset's ground-truth images, is
//! refused unless `--overwrite` is given.

use std::collections::BTreeSet;
use std::path::Path;

use anyhow::{Context, Result, bail};

pub use mipnerf_core::io::MANIFEST;

/// How many foreign names an error lists.
const NAMES_SHOWN: usize = 5;

/// The names the manifest of `dir` lists (none when it has no manifest).
fn recorded(dir: &Path) -> Result<BTreeSet<String>> {
    mipnerf_core::io::recorded(dir).context("reading the outputs manifest")
}

fn list(names: &[String]) -> String {
    let mut shown: Vec<&str> = names.iter().take(NAMES_SHOWN).map(String::as_str).collect();
    if names.len() > NAMES_SHOWN {
        shown.push("...");
    }
    shown.join(", ")
}

/// Checks that `dir` (given as `flag`) is a folder or can be made one: neither it nor a folder
/// above it is a file.
///
/// # Errors
/// The file in the way, named.
pub fn check_folder_path(dir: &Path, flag: &str) -> Result<()> {
    match dir.ancestors().find(|a| a.exists()).filter(|a| !a.is_dir()) {
        Some(file) if file == dir => bail!("{flag} {} is a file, not a folder", dir.display()),
        Some(file) => bail!("{flag} {}: {} is a file, not a folder", dir.display(), file.display()),
        None => Ok(()),
    }
}

/// Checks that `dir` may receive outputs: it is a folder or can be made one
/// ([`check_folder_path`]), and it does not exist, or everything in it was written by mipnerf
/// (its manifest lists it), or `overwrite` is set.
///
/// # Errors
/// A file in the way, a folder holding files mipnerf did not write (naming some of them and the
/// way out), or an unreadable folder.
pub fn check_dir(dir: &Path, flag: &str, overwrite: bool) -> Result<()> {
    check_folder_path(dir, flag)?;
    if overwrite || !dir.exists() {
        return Ok(());
    }
    let ours = recorded(dir)?;
    let mut foreign = mipnerf_core::io::names_in(dir)?;
    foreign.retain(|name| !ours.contains(name));
    if !foreign.is_empty() {
        bail!(
            "{flag} {} holds {} file(s) that mipnerf did not write ({}); writing there could replace them. \
             Choose a new or empty folder, or pass --overwrite to write there anyway (files of the same name are replaced)",
            dir.display(),
            foreign.len(),
            list(&foreign)
        );
    }
    Ok(())
}

/// Checks that the file `path` may be written: it does not exist, or mipnerf wrote it (its
/// folder's manifest lists it), or `overwrite` is set.
///
/// # Errors
/// An existing file mipnerf did not write, or an unreadable manifest.
pub fn check_file(path: &Path, flag: &str, overwrite: bool) -> Result<()> {
    if overwrite || !path.exists() {
        return Ok(());
    }
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    if path.is_dir() || !recorded(dir)?.contains(&name) {
        bail!(
            "{flag} {} already exists and mipnerf did not write it; choose another name, or pass --overwrite to replace it",
            path.display()
        );
    }
    Ok(())
}

/// Removes every file a previous run wrote into `dir` (its manifest lists them), so that a folder
/// never mixes two runs' outputs (fewer frames, another size, an interrupted run), and records
/// `names`, the files this run will write, before any is written. Files mipnerf did not write
/// are left alone.
///
/// # Errors
/// A file that cannot be removed, or an unwritable folder.
pub fn replace_outputs(dir: &Path, names: Vec<String>) -> Result<()> {
    let old = recorded(dir)?;
    for name in &old {
        let path = dir.join(name);
        // Only plain files: a name the manifest lists is never a way out of the folder.
        let plain = !name.contains('/') && !name.contains('\\') && name != ".." && name != ".";
        if plain && std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file()) {
            std::fs::remove_file(&path).with_context(|| format!("removing the earlier output {}", path.display()))?;
        }
    }
    let new: BTreeSet<String> = names.into_iter().collect();
    mipnerf_core::io::forget(dir, &old.difference(&new).cloned().collect())?;
    record(dir, new)
}

/// Adds `names` to the manifest of `dir` (created if needed), written atomically
/// (`mipnerf_core::io::record`) so that a crash never leaves a half-written manifest.
///
/// # Errors
/// An unwritable folder.
pub fn record(dir: &Path, names: impl IntoIterator<Item = String>) -> Result<()> {
    Ok(mipnerf_core::io::record(dir, names)?)
}

/// Writes a result file atomically (a temporary file renamed over it): on a full disk or any
/// other failure the previous file stays whole, and the error says so.
///
/// # Errors
/// The failure, naming the file.
pub fn save_keeping_the_old(path: &Path, bytes: &[u8]) -> Result<()> {
    mipnerf_core::io::write_atomic(path, bytes).map_err(|e| {
        let kept = if path.exists() { "the previous one is unchanged" } else { "nothing was written" };
        anyhow::anyhow!("{e} ({kept})")
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_folder_is_ours_only_when_its_manifest_lists_everything_in_it() {
        let t = tempfile::tempdir().unwrap();
        let dir = t.path().join("out");
        check_dir(&dir, "--out", false).unwrap();
        record(&dir, ["a.png".to_owned(), "b.exr".to_owned()]).unwrap();
        std::fs::write(dir.join("a.png"), b"x").unwrap();
        check_dir(&dir, "--out", false).unwrap();
        check_file(&dir.join("a.png"), "--out", false).unwrap();
        std::fs::write(dir.join("photo.jpg"), b"mine").unwrap();
        let e = check_dir(&dir, "--out", false).unwrap_err().to_string();
        assert!(e.contains("photo.jpg") && e.contains("--overwrite"), "{e}");
        check_dir(&dir, "--out", true).unwrap();
        let e = check_file(&dir.join("photo.jpg"), "--out", false).unwrap_err().to_string();
        assert!(e.contains("photo.jpg") && e.contains("did not write"), "{e}");
        check_file(&dir.join("photo.jpg"), "--out", true).unwrap();
        // Recording is a union, and the manifest holds no temporary file afterwards.
        record(&dir, ["c.png".to_owned()]).unwrap();
        assert_eq!(recorded(&dir).unwrap().len(), 3);
        assert!(!dir.join(format!("{MANIFEST}.tmp")).exists());
    }
}
