//! Checkpoints: the bytes are a function of the state, damage is detected, non-finite state is
//! never written, and a failing write or rename (injected through the `FileOps` seam) leaves the
//! previous checkpoint as it was.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::Path;

use mipnerf_core::checkpoint::{self, Checkpoint, CheckpointError, FileOps, Integrity, RealFs};
use mipnerf_core::model::{Model, Preset};
use mipnerf_core::train::AdamState;

fn tiny() -> Model {
    Model::new(Preset::Tiny.config()).unwrap()
}

/// A state whose every value differs, at `step`.
fn state(model: &Model, step: u64) -> Checkpoint {
    let n = model.num_params();
    let f = |k: f32| (0..n).map(|i| (i as f32 * 0.37 + k + step as f32).sin()).collect::<Vec<f32>>();
    let v = f(2.0).into_iter().map(f32::abs).collect();
    Checkpoint { step, params: f(0.0), adam: AdamState { m: f(1.0), v, t: step }, occupancy: None }
}

#[test]
fn equal_states_give_equal_bytes_and_load_back_exactly() {
    let model = tiny();
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.safetensors"), dir.path().join("b.safetensors"));
    let ck = state(&model, 7);
    checkpoint::save(&a, &model, &ck).unwrap();
    checkpoint::save(&b, &model, &ck).unwrap();
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap(), "the header must not depend on hash order");
    let (back, integrity) = checkpoint::load_checked(&a, &model).unwrap();
    assert_eq!(back, ck);
    assert_eq!(integrity, Integrity::Verified);
    // Any safetensors reader opens it, and finds the checksum in the metadata.
    let bytes = std::fs::read(&a).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let meta = header.metadata().clone().unwrap();
    assert_eq!(meta[checkpoint::CHECKSUM_KEY].len(), 64);
    assert_eq!(meta["step"], "7");
    // No temporary file is left beside it.
    let names: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into()).collect();
    assert_eq!(names.len(), 2, "{names:?}");
}

#[test]
fn flipped_tensor_bytes_are_detected_and_name_the_file() {
    let model = tiny();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint.safetensors");
    checkpoint::save(&path, &model, &state(&model, 3)).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let header = usize::try_from(u64::from_le_bytes(bytes[..8].try_into().unwrap())).unwrap();
    // 16 bytes in the middle of the tensor data, changed to other finite values.
    let mid = 8 + header + (bytes.len() - 8 - header) / 2;
    for b in &mut bytes[mid..mid + 16] {
        *b ^= 0x01;
    }
    std::fs::write(&path, &bytes).unwrap();
    let err = checkpoint::load(&path, &model).unwrap_err().to_string();
    assert!(err.contains("checkpoint.safetensors") && err.contains("damaged") && err.contains("SHA-256"), "{err}");
}

#[test]
fn files_from_before_checksums_still_load_unchecked() {
    use safetensors::tensor::{Dtype, TensorView};
    let model = tiny();
    let dir = tempfile::tempdir().unwrap();
    let (new, old) = (dir.path().join("new.safetensors"), dir.path().join("old.safetensors"));
    let ck = state(&model, 5);
    checkpoint::save(&new, &model, &ck).unwrap();
    // Rewrite it as version 1 wrote it: the same tensors, metadata without the checksum.
    let bytes = std::fs::read(&new).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    meta.remove(checkpoint::CHECKSUM_KEY);
    let views: Vec<(String, TensorView<'_>)> = st
        .tensors()
        .into_iter()
        .map(|(name, t)| (name, TensorView::new(Dtype::F32, t.shape().to_vec(), t.data()).unwrap()))
        .collect();
    safetensors::serialize_to_file(views, Some(meta), &old).unwrap();
    let (back, integrity) = checkpoint::load_checked(&old, &model).unwrap();
    assert_eq!((back, integrity), (ck, Integrity::Unchecked));
}

#[test]
fn non_finite_state_is_never_written_and_the_previous_file_stays() {
    let model = tiny();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint.safetensors");
    checkpoint::save(&path, &model, &state(&model, 10)).unwrap();
    let before = std::fs::read(&path).unwrap();
    for (k, bad) in [(0, f32::NAN), (1, f32::INFINITY), (2, f32::NEG_INFINITY)] {
        let mut ck = state(&model, 15);
        match k {
            0 => ck.params[123] = bad,
            1 => ck.adam.m[0] = bad,
            _ => ck.adam.v[model.num_params() - 1] = bad,
        }
        let err = checkpoint::save(&path, &model, &ck).unwrap_err();
        assert!(matches!(err, CheckpointError::NonFinite { step: 15, .. }), "{err}");
        let text = err.to_string();
        assert!(text.contains("step 15") && text.contains("not written"), "{text}");
        assert_eq!(std::fs::read(&path).unwrap(), before, "case {k}: the previous checkpoint changed");
    }
}

/// File operations that fail at one point and otherwise act as the real file system.
struct Failing {
    /// Which operation fails: "write", "write-partial", "rename" or "sync-dir".
    at: &'static str,
}

impl FileOps for Failing {
    fn write_synced(&mut self, path: &Path, bytes: &[u8]) -> std::io::Result<()> {
        match self.at {
            "write" => Err(std::io::Error::other("injected: no space left on device")),
            "write-partial" => {
                // Half the file reaches the disk, then the write fails.
                std::fs::write(path, &bytes[..bytes.len() / 2])?;
                Err(std::io::Error::other("injected: write failed half way"))
            }
            _ => RealFs.write_synced(path, bytes),
        }
    }

    fn rename(&mut self, from: &Path, to: &Path) -> std::io::Result<()> {
        if self.at == "rename" {
            Err(std::io::Error::other("injected: rename failed"))
        } else {
            RealFs.rename(from, to)
        }
    }

    fn sync_dir(&mut self, dir: &Path) -> std::io::Result<()> {
        if self.at == "sync-dir" { Err(std::io::Error::other("injected: fsync failed")) } else { RealFs.sync_dir(dir) }
    }
}

#[test]
fn a_failing_write_or_rename_keeps_the_previous_checkpoint() {
    let model = tiny();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint.safetensors");
    let old = state(&model, 100);
    checkpoint::save(&path, &model, &old).unwrap();
    let before = std::fs::read(&path).unwrap();
    for at in ["write", "write-partial", "rename"] {
        let err = checkpoint::save_with(&path, &model, &state(&model, 200), &mut Failing { at }).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("injected") && text.contains("checkpoint.safetensors"), "{at}: {text}");
        assert_eq!(std::fs::read(&path).unwrap(), before, "{at}: the previous checkpoint changed");
        assert_eq!(checkpoint::load(&path, &model).unwrap(), old, "{at}");
        assert!(!dir.path().join("checkpoint.safetensors.tmp").exists(), "{at}: temporary file left behind");
    }
    // A failure after the rename (syncing the directory) is reported; the new file is whole.
    let new = state(&model, 300);
    let err = checkpoint::save_with(&path, &model, &new, &mut Failing { at: "sync-dir" }).unwrap_err();
    assert!(err.to_string().contains("fsync"), "{err}");
    assert_eq!(checkpoint::load(&path, &model).unwrap(), new);
}
