//! Writing files so that nothing a user has is lost: every file mipnerf writes goes through
//! [`write_atomic`] (or [`replace_with`] for encoders that write to a path), and every folder it
//! fills records what it wrote in a manifest ([`MANIFEST`]), so that a later run replaces only
//! its own files.
//!
//! An atomic write puts the bytes under a temporary name beside the file, flushes them to the
//! disk (`fsync`), renames them over the file and flushes the folder: the file holds either its
//! previous content or all of the new, never a mix, across a crash, a kill or a power loss. A
//! failure removes the temporary file and leaves the file as it was. An encoder's bytes are made
//! in memory first ([`write_encoded`]): an encoder writing to a file through a buffer loses the
//! error of its last flush (a full disk left truncated PNGs under their final names that way).
//!
//! Every file a user names is read through [`read_regular`] (or opened through [`open_regular`]):
//! a FIFO, a device (a link to `/dev/zero`), a socket or a folder is refused at once, naming what
//! it is, and a file larger than the cap its kind is given (`cap`, a size a real file of its kind
//! never reaches) is refused before a byte of it is held.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Read;
use std::path::{Path, PathBuf};

/// An I/O failure and the file or folder it concerns.
#[derive(Debug, thiserror::Error)]
#[error("{}: {error}", path.display())]
pub struct IoError {
    /// The file or folder.
    pub path: PathBuf,
    /// What the system said (in the message itself, not as its source, so that an error chain
    /// printed whole says it once).
    pub error: std::io::Error,
}

impl IoError {
    /// `error` on `path`.
    #[must_use]
    pub fn new(path: &Path, error: std::io::Error) -> Self {
        Self { path: path.to_path_buf(), error }
    }
}

/// What `meta` is when it is not a regular file, in a user's words (`None` for a regular file).
#[must_use]
pub fn not_regular(meta: &std::fs::Metadata) -> Option<&'static str> {
    let t = meta.file_type();
    if t.is_file() {
        return None;
    }
    if t.is_dir() {
        return Some("is a folder, not a file");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return Some("is a FIFO (a named pipe), not a regular file");
        }
        if t.is_char_device() || t.is_block_device() {
            return Some("is a device (such as /dev/zero), not a regular file");
        }
        if t.is_socket() {
            return Some("is a socket, not a regular file");
        }
    }
    Some("is not a regular file")
}

/// Whether `path` (links followed) is a regular file: `Ok(())`; missing, or something else, as
/// the error a user reads (`NotFound` for a missing file, `InvalidInput` naming what it is).
///
/// # Errors
/// As above.
pub fn check_regular(path: &Path) -> std::io::Result<()> {
    match not_regular(&std::fs::metadata(path)?) {
        None => Ok(()),
        Some(what) => Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, what)),
    }
}

/// Opens `path` for reading if it is a regular file ([`check_regular`]), without ever blocking on
/// a FIFO (it is asked what it is before it is opened, and opened non-blocking in case it changed
/// in between), and checks again what was opened.
///
/// # Errors
/// [`check_regular`]'s, or the system's.
pub fn open_regular(path: &Path) -> std::io::Result<std::fs::File> {
    check_regular(path)?;
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path)?;
    if let Some(what) = not_regular(&file.metadata()?) {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, what));
    }
    Ok(file)
}

/// The whole of the regular file `path` ([`open_regular`]), refused when it holds more than
/// `cap` bytes (before anything is read, and again while reading, for a file that grows).
///
/// # Errors
/// [`open_regular`]'s; a file over the cap (`InvalidData`, naming its size and the cap).
pub fn read_regular(path: &Path, cap: u64) -> std::io::Result<Vec<u8>> {
    let file = open_regular(path)?;
    let over = |len: u64| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "is {}, more than the {} a file of its kind may be here (is it the right file?)",
                bytes_in_words(len),
                bytes_in_words(cap)
            ),
        )
    };
    let len = file.metadata()?.len();
    if len > cap {
        return Err(over(len));
    }
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    file.take(cap.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > cap {
        return Err(over(bytes.len() as u64));
    }
    Ok(bytes)
}

/// [`read_regular`] as UTF-8 text.
///
/// # Errors
/// [`read_regular`]'s; bytes that are not UTF-8 text (`InvalidData`, saying it looks like a
/// binary file).
pub fn read_regular_text(path: &Path, cap: u64) -> std::io::Result<String> {
    String::from_utf8(read_regular(path, cap)?).map_err(|_| {
        std::io::Error::new(std::io::ErrorKind::InvalidData, "is not UTF-8 text (a binary file given for a text one?)")
    })
}

/// `bytes` as a user reads a size: `"512 bytes"`, `"64 MiB"`, `"1.5 GiB"`.
#[must_use]
pub fn bytes_in_words(bytes: u64) -> String {
    const UNITS: [&str; 4] = ["KiB", "MiB", "GiB", "TiB"];
    if bytes < 1024 {
        return format!("{bytes} bytes");
    }
    let mut value = bytes as f64 / 1024.0;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    if (value - value.round()).abs() < 0.05 {
        format!("{} {}", value.round(), UNITS[unit])
    } else {
        format!("{value:.1} {}", UNITS[unit])
    }
}

/// Caps of [`read_regular`] for the kinds of file a user names: sizes a real file of the kind
/// never reaches, so that a wrong file is refused before it fills the memory.
pub mod cap {
    /// A JSON file of cameras or a capture (`transforms.json`, a camera path, multiscale
    /// Blender's `metadata.json`): 64 MiB is some 100,000 frames.
    pub const JSON: u64 = 64 << 20;
    /// A small settings file (a run's `config.toml`, nerfstudio's `dataparser_transforms.json`,
    /// an experiment's plan).
    pub const SETTINGS: u64 = 1 << 20;
    /// A point cloud (`sparse_pc.ply`): 512 MiB is some 20 million binary points.
    pub const POINT_CLOUD: u64 = 512 << 20;
    /// A COLMAP model's file (`points3D.bin` of a large reconstruction is some 100s of MiB).
    pub const COLMAP_MODEL: u64 = 2 << 30;
    /// LLFF's `poses_bounds.npy` (136 bytes a photo): 16 MiB is 100,000 photos.
    pub const POSES: u64 = 16 << 20;
    /// A checkpoint or a set of network weights (safetensors).
    pub const WEIGHTS: u64 = 8 << 30;
}

/// Writes the bytes an encoder makes (`encode` writes them into a `Vec`) to `path` whole or not
/// at all ([`replace_with`]): made in memory, they reach the file in one checked write, so the
/// encoder's last write cannot fail unseen.
///
/// # Errors
/// `encode`'s error, or the write's, naming the file.
pub fn write_encoded<E: From<IoError>>(
    path: &Path,
    encode: impl FnOnce(&mut std::io::Cursor<Vec<u8>>) -> Result<(), E>,
) -> Result<(), E> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    encode(&mut bytes)?;
    replace_with(path, |tmp| std::fs::write(tmp, bytes.get_ref()).map_err(|e| E::from(IoError::new(tmp, e))))
}

/// The file operations of an atomic write, a seam so that tests can make any of them fail.
pub trait FileOps {
    /// Creates (or truncates) `path`, writes `bytes` and flushes them to the disk (`fsync`).
    ///
    /// # Errors
    /// What the system said.
    fn write_synced(&mut self, path: &Path, bytes: &[u8]) -> std::io::Result<()>;
    /// Renames `from` to `to`, replacing `to` atomically.
    ///
    /// # Errors
    /// What the system said.
    fn rename(&mut self, from: &Path, to: &Path) -> std::io::Result<()>;
    /// Flushes the directory `dir` itself (the rename) to the disk.
    ///
    /// # Errors
    /// What the system said.
    fn sync_dir(&mut self, dir: &Path) -> std::io::Result<()>;
}

/// The real file system.
#[derive(Clone, Copy, Debug, Default)]
pub struct RealFs;

impl FileOps for RealFs {
    fn write_synced(&mut self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
        use std::io::Write;
        let mut f = std::fs::File::create(path)?;
        f.write_all(bytes)?;
        f.sync_all()
    }

    fn rename(&mut self, from: &Path, to: &Path) -> std::io::Result<()> {
        std::fs::rename(from, to)
    }

    fn sync_dir(&mut self, dir: &Path) -> std::io::Result<()> {
        // Directories can be opened and synced on Unix; elsewhere the rename is what we have.
        #[cfg(unix)]
        {
            std::fs::File::open(dir)?.sync_all()
        }
        #[cfg(not(unix))]
        {
            let _ = dir;
            Ok(())
        }
    }
}

/// The folder a file lies in (`.` for a bare name).
#[must_use]
pub fn parent_dir(path: &Path) -> &Path {
    path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// Writes `bytes` to `path` atomically (see the module docs), the temporary file being `path` +
/// `.tmp`.
///
/// # Errors
/// The failing operation's error, naming the file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_atomic_with(path, bytes, &mut RealFs)
}

/// [`write_atomic`] through `fs` (tests inject failures).
///
/// # Errors
/// The failing operation's error, naming the file.
pub fn write_atomic_with(path: &Path, bytes: &[u8], fs: &mut dyn FileOps) -> Result<(), IoError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    if let Err(e) = fs.write_synced(&tmp, bytes) {
        let _ = std::fs::remove_file(&tmp);
        return Err(IoError::new(&tmp, e));
    }
    if let Err(e) = fs.rename(&tmp, path) {
        let _ = std::fs::remove_file(&tmp);
        return Err(IoError::new(path, e));
    }
    let dir = parent_dir(path);
    fs.sync_dir(dir).map_err(|e| IoError::new(dir, e))
}

/// The prefix of the temporary name [`replace_with`] writes under (the extension is kept, so
/// that an encoder choosing its format by the name still sees it).
pub const PARTIAL_PREFIX: &str = ".mipnerf-partial-";

/// The temporary name beside `path` that [`replace_with`] writes under: a writer that fills it
/// over a long time (a video, frame by frame) then calls [`replace_with`] with a `write` that
/// does nothing, to publish it.
#[must_use]
pub fn partial_file(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    path.with_file_name(format!("{PARTIAL_PREFIX}{name}"))
}

/// Runs `write` on a temporary name beside `path` ([`PARTIAL_PREFIX`]), flushes the result to
/// the disk, renames it over `path` and flushes the folder: for encoders that write to a path
/// (PNG, EXR). A failure removes the temporary file and leaves `path` as it was.
///
/// # Errors
/// `write`'s error, or the failing operation's, naming the file.
pub fn replace_with<E: From<IoError>>(path: &Path, write: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), E> {
    let tmp = partial_file(path);
    let finish = || -> Result<(), IoError> {
        std::fs::File::open(&tmp).and_then(|f| f.sync_all()).map_err(|e| IoError::new(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| IoError::new(path, e))?;
        RealFs.sync_dir(parent_dir(path)).map_err(|e| IoError::new(parent_dir(path), e))
    };
    let done = write(&tmp).and_then(|()| finish().map_err(E::from));
    if done.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    done
}

/// The temporary name beside `dest` that [`swap_in_dir`] moves into place: a folder is filled
/// there and appears under its name only when whole.
#[must_use]
pub fn partial_dir(dest: &Path) -> PathBuf {
    let name = dest.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    dest.with_file_name(format!("{PARTIAL_PREFIX}{name}"))
}

/// A fresh, empty [`partial_dir`] for `dest` (a stale one, left by an interrupted run, removed).
///
/// # Errors
/// An unwritable folder.
pub fn start_partial_dir(dest: &Path) -> Result<PathBuf, IoError> {
    let partial = partial_dir(dest);
    if std::fs::symlink_metadata(&partial).is_ok() {
        std::fs::remove_dir_all(&partial).map_err(|e| IoError::new(&partial, e))?;
    }
    std::fs::create_dir_all(&partial).map_err(|e| IoError::new(&partial, e))?;
    Ok(partial)
}

/// Moves the whole [`partial_dir`] of `dest` into place, replacing `dest` (which the caller has
/// checked is its own to replace), and flushes the parent folder.
///
/// # Errors
/// An unwritable folder.
pub fn swap_in_dir(dest: &Path) -> Result<(), IoError> {
    let partial = partial_dir(dest);
    if std::fs::symlink_metadata(dest).is_ok() {
        std::fs::remove_dir_all(dest).map_err(|e| IoError::new(dest, e))?;
    }
    std::fs::rename(&partial, dest).map_err(|e| IoError::new(dest, e))?;
    RealFs.sync_dir(parent_dir(dest)).map_err(|e| IoError::new(parent_dir(dest), e))
}

/// The manifest's file name, in a folder mipnerf writes outputs into: the names (one a line) of
/// the files and folders it wrote there, recorded before they are written, each with the command
/// that wrote it after a tab (`poses_bounds.npy\tcolmap`); a name alone is from a version that
/// did not say.
pub const MANIFEST: &str = ".mipnerf-outputs";

/// The lock file of a folder a mipnerf command writes (a run directory, a dataset being made):
/// the command that writes the folder holds an operating-system lock on it, and the file names
/// that process and command. Not an output: [`names_in`] passes over it.
pub const LOCK: &str = ".mipnerf-lock";

/// The names the manifest of `dir` lists (none when it has no manifest).
///
/// # Errors
/// A manifest that exists but cannot be read.
pub fn recorded(dir: &Path) -> Result<BTreeSet<String>, IoError> {
    Ok(writers(dir)?.into_keys().collect())
}

/// The names the manifest of `dir` lists, each with the command that wrote it (`None`: written
/// by a version that did not say).
///
/// # Errors
/// A manifest that exists but cannot be read.
pub fn writers(dir: &Path) -> Result<BTreeMap<String, Option<String>>, IoError> {
    let path = dir.join(MANIFEST);
    match std::fs::read_to_string(&path) {
        Ok(text) => Ok(text
            .lines()
            .filter(|l| !l.is_empty())
            .map(|l| match l.split_once('\t') {
                Some((name, writer)) => (name.to_owned(), Some(writer.to_owned())),
                None => (l.to_owned(), None),
            })
            .collect()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(BTreeMap::new()),
        Err(e) => Err(IoError::new(&path, e)),
    }
}

/// The names in the folder `dir` that are outputs, sorted: everything but its manifest, its
/// [`LOCK`] and the
/// temporary files and folders mipnerf fills before renaming them ([`PARTIAL_PREFIX`]: what a
/// kill mid-write leaves is mipnerf's own too).
///
/// # Errors
/// An unreadable folder.
pub fn names_in(dir: &Path) -> Result<Vec<String>, IoError> {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| IoError::new(dir, e))? {
        let name = entry.map_err(|e| IoError::new(dir, e))?.file_name().to_string_lossy().to_string();
        if name != MANIFEST && name != LOCK && !name.starts_with(PARTIAL_PREFIX) {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

fn write_manifest(dir: &Path, entries: &BTreeMap<String, Option<String>>) -> Result<(), IoError> {
    let text: String = entries
        .iter()
        .map(|(name, writer)| match writer {
            Some(w) => format!("{name}\t{w}\n"),
            None => format!("{name}\n"),
        })
        .collect();
    write_atomic(&dir.join(MANIFEST), text.as_bytes())
}

/// Adds `names` to the manifest of `dir` (the folder created if needed) as written by the
/// command `writer` (`render`, `colmap`, ...), written atomically.
///
/// # Errors
/// An unwritable folder.
pub fn record(dir: &Path, writer: &str, names: impl IntoIterator<Item = String>) -> Result<(), IoError> {
    std::fs::create_dir_all(dir).map_err(|e| IoError::new(dir, e))?;
    let mut all = writers(dir)?;
    let before = all.clone();
    all.extend(names.into_iter().map(|n| (n, Some(writer.to_owned()))));
    if all == before && dir.join(MANIFEST).exists() {
        return Ok(());
    }
    write_manifest(dir, &all)
}

/// Removes `names` from the manifest of `dir` (after the files themselves are gone).
///
/// # Errors
/// An unreadable or unwritable manifest.
pub fn forget(dir: &Path, names: &BTreeSet<String>) -> Result<(), IoError> {
    let mut all = writers(dir)?;
    let before = all.len();
    all.retain(|name, _| !names.contains(name));
    if all.len() == before {
        return Ok(());
    }
    write_manifest(dir, &all)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn an_atomic_write_replaces_whole_and_a_failed_one_leaves_the_file() {
        let t = tempfile::tempdir().unwrap();
        let path = t.path().join("a.txt");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        let failed: Result<(), IoError> = replace_with(&path, |tmp: &Path| {
            std::fs::write(tmp, b"half").unwrap();
            Err(IoError::new(tmp, std::io::Error::other("encoder failed")))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        let names: Vec<_> = std::fs::read_dir(t.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.txt")], "no temporary file is left");
        replace_with::<IoError>(&path, |tmp| std::fs::write(tmp, b"three").map_err(|e| IoError::new(tmp, e))).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"three");
    }

    #[test]
    fn the_manifest_records_and_forgets_names() {
        let t = tempfile::tempdir().unwrap();
        let dir = t.path().join("out");
        assert!(recorded(&dir).unwrap().is_empty());
        record(&dir, "render", ["b".to_string(), "a".to_string()]).unwrap();
        record(&dir, "render", ["a".to_string()]).unwrap();
        assert_eq!(std::fs::read_to_string(dir.join(MANIFEST)).unwrap(), "a\trender\nb\trender\n");
        forget(&dir, &BTreeSet::from(["a".to_string()])).unwrap();
        assert_eq!(recorded(&dir).unwrap(), BTreeSet::from(["b".to_string()]));
        // An older manifest's names have no writer; recording keeps them so.
        std::fs::write(dir.join(MANIFEST), "old.png\nb\trender\n").unwrap();
        record(&dir, "colmap", ["poses_bounds.npy".to_string()]).unwrap();
        let w = writers(&dir).unwrap();
        assert_eq!(w["old.png"], None);
        assert_eq!(w["poses_bounds.npy"].as_deref(), Some("colmap"));
        assert_eq!(w["b"].as_deref(), Some("render"));
    }
}
