//! Checkpoints: parameters and Adam's state in one safetensors file, written atomically.
//!
//! Each dense layer is its own tensor, named as the official flax checkpoint names it
//! (`MLP_{i}/Dense_{k}/kernel` with shape `[fan_in, fan_out]`, `.../bias` with `[fan_out]`), so the
//! file opens in any safetensors reader; Adam's moments are the same tensors prefixed with
//! `adam_m/` and `adam_v/`. Metadata holds the format version, the step and Adam's update count.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::model::Model;
use crate::train::AdamState;

/// The `format` metadata value this version writes and reads.
pub const FORMAT: &str = "mipnerf-checkpoint-v1";

/// What a checkpoint holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// The number of training steps taken (the next step's number).
    pub step: u64,
    /// The parameters, in the model's flat layout.
    pub params: Vec<f32>,
    /// Adam's state.
    pub adam: AdamState,
}

/// A checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The file system failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file is not a checkpoint of this model.
    #[error("{}: {problem}", path.display())]
    Invalid {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong.
        problem: String,
    },
}

fn invalid(path: &Path, problem: impl Into<String>) -> CheckpointError {
    CheckpointError::Invalid { path: path.to_path_buf(), problem: problem.into() }
}

/// `(name, offset, shape)` of every tensor of `model`'s parameters.
fn tensors(model: &Model) -> Vec<(String, usize, Vec<usize>)> {
    let mut out = Vec::new();
    for (i, mlp) in model.mlps.iter().enumerate() {
        for l in &mlp.layers {
            out.push((format!("MLP_{i}/{}/kernel", l.name), l.kernel, vec![l.fan_in, l.fan_out]));
            out.push((format!("MLP_{i}/{}/bias", l.name), l.bias, vec![l.fan_out]));
        }
    }
    out
}

fn le_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Writes `ckpt` for `model` to `path` atomically: to a temporary file beside it, then renamed,
/// so an interrupted write never damages the previous checkpoint.
///
/// # Errors
/// [`CheckpointError`] when the file cannot be written or the state does not fit the model.
pub fn save(path: &Path, model: &Model, ckpt: &Checkpoint) -> Result<(), CheckpointError> {
    let n = model.num_params;
    if ckpt.params.len() != n || ckpt.adam.m.len() != n || ckpt.adam.v.len() != n {
        return Err(invalid(path, format!("state has {} parameters, the model {n}", ckpt.params.len())));
    }
    let mut buffers: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
    for (prefix, source) in [("", &ckpt.params), ("adam_m/", &ckpt.adam.m), ("adam_v/", &ckpt.adam.v)] {
        for (name, off, shape) in tensors(model) {
            let len: usize = shape.iter().product();
            buffers.push((format!("{prefix}{name}"), le_bytes(&source[off..off + len]), shape));
        }
    }
    let views: Vec<(String, TensorView<'_>)> = buffers
        .iter()
        .map(|(name, bytes, shape)| {
            TensorView::new(Dtype::F32, shape.clone(), bytes)
                .map(|v| (name.clone(), v))
                .map_err(|e| invalid(path, e.to_string()))
        })
        .collect::<Result<_, _>>()?;
    let meta = HashMap::from([
        ("format".to_string(), FORMAT.to_string()),
        ("step".to_string(), ckpt.step.to_string()),
        ("adam_t".to_string(), ckpt.adam.t.to_string()),
        ("num_params".to_string(), n.to_string()),
    ]);
    let tmp = path.with_extension("safetensors.tmp");
    safetensors::serialize_to_file(views, Some(meta), &tmp).map_err(|e| invalid(&tmp, e.to_string()))?;
    std::fs::rename(&tmp, path).map_err(|e| CheckpointError::Io { path: path.to_path_buf(), source: e })
}

/// Reads a checkpoint of `model` from `path`.
///
/// # Errors
/// [`CheckpointError`] for an unreadable file, another format, or tensors that do not fit the
/// model (a checkpoint of another configuration).
pub fn load(path: &Path, model: &Model) -> Result<Checkpoint, CheckpointError> {
    let bytes = std::fs::read(path).map_err(|e| CheckpointError::Io { path: path.to_path_buf(), source: e })?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| invalid(path, format!("not a safetensors file: {e}")))?;
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| invalid(path, e.to_string()))?;
    let meta = header.metadata().clone().unwrap_or_default();
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err(invalid(path, format!("not a {FORMAT} file (format {:?})", meta.get("format"))));
    }
    let num = |k: &str| -> Result<u64, CheckpointError> {
        meta.get(k)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| invalid(path, format!("metadata \"{k}\" is missing or not a number")))
    };
    let n = model.num_params;
    let mut out = [vec![0.0f32; n], vec![0.0f32; n], vec![0.0f32; n]];
    for (buf, prefix) in out.iter_mut().zip(["", "adam_m/", "adam_v/"]) {
        for (name, off, shape) in tensors(model) {
            let full = format!("{prefix}{name}");
            let t = st.tensor(&full).map_err(|_| {
                invalid(path, format!("no tensor {full}: a checkpoint of another model configuration?"))
            })?;
            if t.dtype() != Dtype::F32 || t.shape() != shape.as_slice() {
                return Err(invalid(
                    path,
                    format!("{full} is {:?} {:?}, the model needs F32 {shape:?}", t.dtype(), t.shape()),
                ));
            }
            for (dst, c) in buf[off..].iter_mut().zip(t.data().chunks_exact(4)) {
                *dst = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            }
        }
    }
    let [params, m, v] = out;
    if params.iter().chain(&m).chain(&v).any(|x| !x.is_finite()) {
        return Err(invalid(path, "holds non-finite values"));
    }
    Ok(Checkpoint { step: num("step")?, params, adam: AdamState { m, v, t: num("adam_t")? } })
}
