//! Output folders that never replace a user's files: `render --out DIR` and `figure --out FILE`
//! write only where mipnerf wrote before, or where nothing is.
//!
//! Every folder mipnerf writes outputs into gets a manifest ([`mipnerf_core::io::MANIFEST`]): the names of the files
//! it wrote there, recorded before they are written (so an interrupted render can be redone).
//! A folder that holds any file not in its manifest, such as a dataset's ground-truth images, is
//! refused unless `--overwrite` is given.

use std::collections::BTreeSet;
use std::path::Path;

use anyhow::{Context, Result, bail};

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

/// Takes the exclusive lock of the folder `dir` that the command `command` (`train`, `colmap`,
/// `convert`) is to write, for the life of the returned file, so that two mipnerf processes
/// never write one folder: a run directory, or a dataset being made. The lock is the operating
/// system's (`flock` on Unix) on [`mipnerf_core::io::LOCK`] in the folder (created here), released
/// when the process ends however it ends, so a killed process leaves no stale lock; the file
/// names its holder.
///
/// # Errors
/// Another process holds the lock (the error names its command and process, and `flag`, the
/// folder's flag, as the way out), or the file cannot be made.
pub fn lock_folder(dir: &Path, command: &str, flag: &str) -> Result<std::fs::File> {
    use std::io::Write;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join(mipnerf_core::io::LOCK);
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    match f.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let holder = std::fs::read_to_string(&path).unwrap_or_default();
            let (process, by) = holder.trim().split_once('\t').unwrap_or((holder.trim(), "train"));
            bail!(
                "{} is in use by another `mipnerf {by}` ({process}); wait for it to finish, or choose another {flag}",
                dir.display(),
            );
        }
        Err(std::fs::TryLockError::Error(e)) => {
            return Err(e).with_context(|| format!("locking {}", path.display()));
        }
    }
    f.set_len(0)?;
    writeln!(f, "process {}\t{command}", std::process::id())?;
    f.flush()?;
    Ok(f)
}

/// Runs `write`, which fills the folder `dir` as the command `command`, holding the folder's lock
/// ([`lock_folder`]): a second `colmap` or `convert` into the same folder is refused while the
/// first runs, so a finished folder is one run's whole output. A folder made here and left with
/// no output by a failed `write` is removed again.
///
/// # Errors
/// The lock's, or `write`'s.
pub fn locked<T>(dir: &Path, command: &str, flag: &str, write: impl FnOnce() -> Result<T>) -> Result<T> {
    let existed = std::fs::symlink_metadata(dir).is_ok();
    let lock = lock_folder(dir, command, flag)?;
    let done = write();
    if done.is_err() && !existed && mipnerf_core::io::names_in(dir).is_ok_and(|names| names.is_empty()) {
        let _ = std::fs::remove_dir_all(dir);
    }
    drop(lock);
    done
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

/// Whether `name`, which the manifest says `by` wrote, is an output of the command `writer`:
/// recorded by it, or (from a version whose manifest did not say) the kind of file it writes:
/// for `render`, images, depth and opacity maps, the preview, the video and `cameras.json`, never
/// a dataset's index.
fn written_by(writer: &str, name: &str, by: Option<&str>) -> bool {
    match by {
        Some(by) => by == writer,
        None if writer == "render" => {
            [".png", ".exr", ".gif", ".mp4"].iter().any(|e| name.ends_with(e)) || name == "cameras.json"
        }
        None => true,
    }
}

/// Checks that `dir` may receive the outputs of the command `writer`: it is a folder or can be
/// made one ([`check_folder_path`]), and it does not exist, or everything in it is that
/// command's earlier output (its manifest lists it as such), or `overwrite` is set.
///
/// # Errors
/// A file in the way, a folder holding files mipnerf did not write or another of its commands
/// did (a dataset `mipnerf colmap` wrote, say; naming some of them and the way out), or an
/// unreadable folder.
pub fn check_dir(dir: &Path, flag: &str, overwrite: bool, writer: &str) -> Result<()> {
    check_folder_path(dir, flag)?;
    if overwrite || !dir.exists() {
        return Ok(());
    }
    let ours = mipnerf_core::io::writers(dir).context("reading the outputs manifest")?;
    let mut foreign = mipnerf_core::io::names_in(dir)?;
    foreign.retain(|name| !ours.get(name).is_some_and(|by| written_by(writer, name, by.as_deref())));
    if !foreign.is_empty() {
        let others: Vec<String> = foreign
            .iter()
            .filter_map(|n| {
                ours.get(n).map(|by| format!("{n} (mipnerf {})", by.as_deref().unwrap_or("an older version")))
            })
            .collect();
        let theirs = if others.is_empty() {
            String::new()
        } else {
            format!(", or that another mipnerf command wrote: {}", list(&others))
        };
        bail!(
            "{flag} {} holds {} file(s) that mipnerf did not write here ({}){theirs}; writing there could replace them. \
             Choose a new or empty folder, or pass --overwrite to write there anyway (files of the same name are \
             replaced; other files are left alone)",
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

/// Removes every file a previous render wrote into `dir` (its manifest lists them as `render`'s),
/// so that a folder never mixes two renders' outputs (fewer frames, another size, an interrupted
/// render), and records
/// `names`, the files this run will write, before any is written. Files mipnerf did not write
/// are left alone.
///
/// # Errors
/// A file that cannot be removed, or an unwritable folder.
pub fn replace_outputs(dir: &Path, names: Vec<String>) -> Result<()> {
    let old: BTreeSet<String> = mipnerf_core::io::writers(dir)
        .context("reading the outputs manifest")?
        .into_iter()
        .filter(|(name, by)| written_by(RENDER, name, by.as_deref()))
        .map(|(name, _)| name)
        .collect();
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
    record(dir, RENDER, new)
}

/// The manifest's name for `render`'s outputs.
pub const RENDER: &str = "render";

/// Adds `names` to the manifest of `dir` (created if needed) as the outputs of the command
/// `writer`, written atomically (`mipnerf_core::io::record`) so that a crash never leaves a
/// half-written manifest.
///
/// # Errors
/// An unwritable folder.
pub fn record(dir: &Path, writer: &str, names: impl IntoIterator<Item = String>) -> Result<()> {
    Ok(mipnerf_core::io::record(dir, writer, names)?)
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
    use mipnerf_core::io::MANIFEST;

    #[test]
    fn a_folder_is_ours_only_when_its_manifest_lists_everything_in_it() {
        let t = tempfile::tempdir().unwrap();
        let dir = t.path().join("out");
        check_dir(&dir, "--out", false, RENDER).unwrap();
        record(&dir, RENDER, ["a.png".to_owned(), "b.exr".to_owned()]).unwrap();
        std::fs::write(dir.join("a.png"), b"x").unwrap();
        check_dir(&dir, "--out", false, RENDER).unwrap();
        check_file(&dir.join("a.png"), "--out", false).unwrap();
        std::fs::write(dir.join("photo.jpg"), b"mine").unwrap();
        let e = check_dir(&dir, "--out", false, RENDER).unwrap_err().to_string();
        assert!(e.contains("photo.jpg") && e.contains("--overwrite"), "{e}");
        check_dir(&dir, "--out", true, RENDER).unwrap();
        let e = check_file(&dir.join("photo.jpg"), "--out", false).unwrap_err().to_string();
        assert!(e.contains("photo.jpg") && e.contains("did not write"), "{e}");
        check_file(&dir.join("photo.jpg"), "--out", true).unwrap();
        // Recording is a union, and the manifest holds no temporary file afterwards.
        record(&dir, RENDER, ["c.png".to_owned()]).unwrap();
        assert_eq!(recorded(&dir).unwrap().len(), 3);
        assert!(!dir.join(format!("{MANIFEST}.tmp")).exists());
    }
}
