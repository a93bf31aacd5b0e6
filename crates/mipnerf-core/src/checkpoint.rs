//! Checkpoints: parameters and Adam's state in one safetensors file, written atomically.
//!
//! Each dense layer is its own tensor, named as the official flax checkpoint names it
//! (`MLP_{i}/Dense_{k}/kernel` with shape `[fan_in, fan_out]`, `.../bias` with `[fan_out]`), so the
//! file opens in any safetensors reader; Adam's moments are the same tensors prefixed with
//! `adam_m/` and `adam_v/`. Metadata holds the format version, the step, Adam's update count and the
//! SHA-256 of the content (the other metadata and every tensor), verified on every load. Writes are atomic and synced, and refuse
//! non-finite state, so the file on disk is always the last good state.

use std::path::Path;

use safetensors::tensor::{Dtype, SafeTensors};

use crate::model::Model;
use crate::occupancy::OccupancyGrid;
use crate::train::AdamState;

/// The tensor holding an occupancy grid's per-cell opacity.
pub const OCCUPANCY_TENSOR: &str = "occupancy/opacity";

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
    /// The occupancy grid of a run that uses one (tensor `occupancy/opacity`, `[R, R, R]` with x
    /// fastest, its settings in the `occupancy` metadata as JSON).
    pub occupancy: Option<OccupancyGrid>,
}

/// A checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The file system failed.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
    /// The state to save holds a non-finite value: nothing was written.
    #[error("{}: not written: {what} is not finite at step {step}; the previous file is kept", path.display())]
    NonFinite {
        /// The file that was not written.
        path: std::path::PathBuf,
        /// The step of the state.
        step: u64,
        /// Which value (tensor kind and flat index) and what it was.
        what: String,
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
    match model.config().field {
        crate::model::Field::MipNerf => {}
        crate::model::Field::TriMip { planes, .. } => {
            let r = planes.resolution;
            out.push(("tri_mip/planes".to_owned(), 0, vec![3, r, r, planes.features]));
        }
        crate::model::Field::HashGrid { grid, .. } => {
            out.push(("hash_grid/tables".to_owned(), 0, vec![grid.num_params() / grid.features, grid.features]));
        }
    }
    for (i, mlp) in model.mlps().iter().enumerate() {
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

/// The metadata key holding the SHA-256 (lower-case hex) of the file's content (metadata and
/// tensors).
pub const CHECKSUM_KEY: &str = "sha256";

pub use crate::io::{FileOps, RealFs};

/// Writes `bytes` to `path` atomically through `fs` ([`crate::io::write_atomic_with`]): `path`
/// holds either its previous content or all of `bytes`, never a mix, even across a crash or a
/// power loss. A failure removes the temporary file and leaves `path` as it was.
///
/// # Errors
/// The failing operation's error, naming the file.
pub fn write_atomic(path: &Path, bytes: &[u8], fs: &mut dyn FileOps) -> Result<(), CheckpointError> {
    crate::io::write_atomic_with(path, bytes, fs).map_err(|e| CheckpointError::Io { path: e.path, error: e.error })
}

/// The SHA-256 (lower-case hex) of a checkpoint's content: every metadata entry but the checksum
/// (sorted by key), then every tensor's name, shape and bytes (sorted by name). It covers all that
/// [`load`] reads, so a change anywhere that matters is detected, whatever the layout of the header.
fn content_digest<'a>(
    meta: impl IntoIterator<Item = (&'a str, &'a str)>,
    tensors: impl IntoIterator<Item = (&'a str, &'a [usize], &'a [u8])>,
) -> String {
    use sha2::Digest;
    let mut h = sha2::Sha256::new();
    let mut meta: Vec<_> = meta.into_iter().filter(|(k, _)| *k != CHECKSUM_KEY).collect();
    meta.sort_unstable();
    for (k, v) in meta {
        for part in [k.as_bytes(), b"\0", v.as_bytes(), b"\0"] {
            h.update(part);
        }
    }
    let mut tensors: Vec<_> = tensors.into_iter().collect();
    tensors.sort_unstable_by_key(|t| t.0);
    for (name, shape, bytes) in tensors {
        h.update(name.as_bytes());
        h.update(b"\0");
        for d in shape {
            h.update((*d as u64).to_le_bytes());
        }
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// The bytes of a safetensors file holding `tensors` (name, little-endian `f32` data, shape) and
/// `meta`, laid out deterministically: header keys sorted (`__metadata__` first, then the tensors
/// by name), data in the same order, the header padded with spaces to 8 bytes. Equal inputs give
/// equal bytes. The metadata gains [`CHECKSUM_KEY`]: the [`content_digest`] of the rest.
fn safetensors_bytes(mut tensors: Vec<(String, Vec<u8>, Vec<usize>)>, meta: &[(&str, String)]) -> Vec<u8> {
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let mut data = Vec::with_capacity(tensors.iter().map(|t| t.1.len()).sum());
    let mut entries = serde_json::Map::new();
    for (name, bytes, shape) in &tensors {
        let begin = data.len();
        data.extend_from_slice(bytes);
        entries.insert(
            name.clone(),
            serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [begin, data.len()]}),
        );
    }
    let mut m: std::collections::BTreeMap<&str, String> = meta.iter().map(|(k, v)| (*k, v.clone())).collect();
    let digest = content_digest(
        meta.iter().map(|(k, v)| (*k, v.as_str())),
        tensors.iter().map(|(n, b, sh)| (n.as_str(), sh.as_slice(), b.as_slice())),
    );
    m.insert(CHECKSUM_KEY, digest);
    // serde_json's map is ordered by key; "__metadata__" sorts before every tensor name, which
    // begins with a letter.
    entries.insert("__metadata__".to_string(), serde_json::json!(m));
    let mut header = serde_json::to_vec(&serde_json::Value::Object(entries)).unwrap_or_default();
    while !header.len().is_multiple_of(8) {
        header.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + header.len() + data.len());
    out.extend_from_slice(&(header.len() as u64).to_le_bytes());
    out.extend_from_slice(&header);
    out.extend_from_slice(&data);
    out
}

/// Writes `ckpt` for `model` to `path` atomically ([`write_atomic`]): an interrupted or failed
/// write never damages the previous checkpoint. The file is a function of `ckpt` alone (byte for
/// byte) and carries the SHA-256 of its content ([`CHECKSUM_KEY`]).
///
/// # Errors
/// [`CheckpointError`] when the file cannot be written, the state does not fit the model, or the
/// state holds a non-finite value (nothing is written then: the previous checkpoint stays).
pub fn save(path: &Path, model: &Model, ckpt: &Checkpoint) -> Result<(), CheckpointError> {
    save_with(path, model, ckpt, &mut RealFs)
}

/// [`save`] through the file operations `fs` (the seam the fault-injection tests use).
///
/// # Errors
/// As [`save`].
pub fn save_with(path: &Path, model: &Model, ckpt: &Checkpoint, fs: &mut dyn FileOps) -> Result<(), CheckpointError> {
    save_inner(path, model, ckpt, None, fs)
}

/// What rendering a saved model needs beside its parameters: the model's configuration (its
/// background, ray shape, encodings) and how pixels become rays (bounds, pixel centres, the NDC
/// mapping of forward-facing data). [`save_for_rendering`] stores it in the metadata (`render`,
/// as JSON) and [`render_settings`] reads it back, so that a model loaded without its data
/// renders as it did.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSettings {
    /// The model's configuration.
    pub model: crate::model::ModelConfig,
    /// Near bound along every ray.
    pub near: f32,
    /// Far bound along every ray.
    pub far: f32,
    /// Rays through pixel centres or corners.
    pub centers: crate::camera::PixelCenters,
    /// The NDC mapping of forward-facing scenes.
    pub ndc: Option<crate::dataset::Ndc>,
}

/// The metadata key of [`RenderSettings`].
pub const RENDER_KEY: &str = "render";

/// [`save`], with the settings a render needs stored beside the state ([`RenderSettings`]).
///
/// # Errors
/// As [`save`].
pub fn save_for_rendering(
    path: &Path,
    model: &Model,
    ckpt: &Checkpoint,
    render: &RenderSettings,
) -> Result<(), CheckpointError> {
    save_inner(path, model, ckpt, Some(render), &mut RealFs)
}

/// The [`RenderSettings`] stored in the checkpoint at `path`, or `None` for a checkpoint saved
/// without them. The checksum covers them; [`load`] verifies it.
///
/// # Errors
/// An unreadable, damaged or foreign file, or settings that cannot be read.
pub fn render_settings(path: &Path) -> Result<Option<RenderSettings>, CheckpointError> {
    let bytes = crate::io::read_regular(path, crate::io::cap::WEIGHTS)
        .map_err(|e| CheckpointError::Io { path: path.to_path_buf(), error: e })?;
    let (_, header) =
        SafeTensors::read_metadata(&bytes).map_err(|e| invalid(path, format!("not a safetensors file: {e}")))?;
    let meta = header.metadata().clone().unwrap_or_default();
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err(invalid(path, format!("not a {FORMAT} file (format {:?})", meta.get("format"))));
    }
    meta.get(RENDER_KEY)
        .map(|text| {
            serde_json::from_str(text).map_err(|e| invalid(path, format!("the render settings are not readable: {e}")))
        })
        .transpose()
}

fn save_inner(
    path: &Path,
    model: &Model,
    ckpt: &Checkpoint,
    render: Option<&RenderSettings>,
    fs: &mut dyn FileOps,
) -> Result<(), CheckpointError> {
    let n = model.num_params();
    if ckpt.params.len() != n || ckpt.adam.m.len() != n || ckpt.adam.v.len() != n {
        return Err(invalid(path, format!("state has {} parameters, the model {n}", ckpt.params.len())));
    }
    for (what, v) in
        [("parameter", &ckpt.params), ("Adam first moment", &ckpt.adam.m), ("Adam second moment", &ckpt.adam.v)]
    {
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(CheckpointError::NonFinite {
                path: path.to_path_buf(),
                step: ckpt.step,
                what: format!("{what} {i} ({})", v[i]),
            });
        }
    }
    let mut buffers: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
    for (prefix, source) in [("", &ckpt.params), ("adam_m/", &ckpt.adam.m), ("adam_v/", &ckpt.adam.v)] {
        for (name, off, shape) in tensors(model) {
            let len: usize = shape.iter().product();
            buffers.push((format!("{prefix}{name}"), le_bytes(&source[off..off + len]), shape));
        }
    }
    let mut meta = vec![
        ("format", FORMAT.to_string()),
        ("step", ckpt.step.to_string()),
        ("adam_t", ckpt.adam.t.to_string()),
        ("num_params", n.to_string()),
    ];
    if let Some(g) = &ckpt.occupancy {
        let r = g.resolution();
        buffers.push((OCCUPANCY_TENSOR.to_string(), le_bytes(&g.opacity), vec![r, r, r]));
        let cfg = serde_json::to_string(&g.config).map_err(|e| invalid(path, e.to_string()))?;
        meta.push(("occupancy", cfg));
        meta.push(("occupancy_warmed_up", g.warmed_up.to_string()));
    }
    if let Some(render) = render {
        if render.model != *model.config() {
            return Err(invalid(path, "the render settings describe another model than the one saved"));
        }
        meta.push((RENDER_KEY, serde_json::to_string(render).map_err(|e| invalid(path, e.to_string()))?));
    }
    write_atomic(path, &safetensors_bytes(buffers, &meta), fs)
}

/// The SHA-256 (lower-case hex) of a file's bytes: what identifies the checkpoint a result came
/// from.
///
/// # Errors
/// An unreadable file.
pub fn file_sha256(path: &Path) -> Result<String, CheckpointError> {
    use sha2::Digest;
    let bytes = crate::io::read_regular(path, crate::io::cap::WEIGHTS)
        .map_err(|e| CheckpointError::Io { path: path.to_path_buf(), error: e })?;
    Ok(sha2::Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

/// Whether a loaded checkpoint's content was checked against its stored SHA-256.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Integrity {
    /// The checksum was present and matched.
    Verified,
    /// The file predates checksums (no [`CHECKSUM_KEY`] metadata): read as it is.
    Unchecked,
}

/// Reads a checkpoint of `model` from `path`.
///
/// # Errors
/// [`CheckpointError`] for an unreadable file, another format, or tensors that do not fit the
/// model (a checkpoint of another configuration).
pub fn load(path: &Path, model: &Model) -> Result<Checkpoint, CheckpointError> {
    load_checked(path, model).map(|(ck, _)| ck)
}

/// [`load`], also saying whether the file's checksum was verified ([`Integrity::Unchecked`] for a
/// file written before checksums existed).
///
/// # Errors
/// As [`load`], and a checksum that does not match the content (a damaged file).
pub fn load_checked(path: &Path, model: &Model) -> Result<(Checkpoint, Integrity), CheckpointError> {
    let bytes = crate::io::read_regular(path, crate::io::cap::WEIGHTS)
        .map_err(|e| CheckpointError::Io { path: path.to_path_buf(), error: e })?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| invalid(path, format!("not a safetensors file: {e}")))?;
    let (_, header) = SafeTensors::read_metadata(&bytes).map_err(|e| invalid(path, e.to_string()))?;
    let meta = header.metadata().clone().unwrap_or_default();
    if meta.get("format").map(String::as_str) != Some(FORMAT) {
        return Err(invalid(path, format!("not a {FORMAT} file (format {:?})", meta.get("format"))));
    }
    let integrity = match meta.get(CHECKSUM_KEY) {
        None => Integrity::Unchecked,
        Some(stored) => {
            let views = st.tensors();
            let actual = content_digest(
                meta.iter().map(|(k, v)| (k.as_str(), v.as_str())),
                views.iter().map(|(n, t)| (n.as_str(), t.shape(), t.data())),
            );
            if *stored != actual {
                return Err(invalid(
                    path,
                    format!(
                        "damaged: the content's SHA-256 is {actual}, the file says {stored} \
                         (restore the file from a copy, or retrain)"
                    ),
                ));
            }
            Integrity::Verified
        }
    };
    let num = |k: &str| -> Result<u64, CheckpointError> {
        meta.get(k)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| invalid(path, format!("metadata \"{k}\" is missing or not a number")))
    };
    let n = model.num_params();
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
    let occupancy = match (meta.get("occupancy"), st.tensor(OCCUPANCY_TENSOR)) {
        (None, Err(_)) => None,
        (Some(cfg), Ok(t)) => {
            let config = serde_json::from_str(cfg)
                .map_err(|e| invalid(path, format!("the occupancy grid's settings are not readable: {e}")))?;
            if t.dtype() != Dtype::F32 {
                return Err(invalid(path, format!("{OCCUPANCY_TENSOR} is {:?}, not F32", t.dtype())));
            }
            let opacity = t.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            let warmed_up = meta.get("occupancy_warmed_up").is_some_and(|v| v == "true");
            Some(OccupancyGrid::from_state(config, opacity, warmed_up).map_err(|e| invalid(path, e.to_string()))?)
        }
        _ => return Err(invalid(path, "holds half an occupancy grid (its tensor or its settings are missing)")),
    };
    let adam = AdamState { m, v, t: num("adam_t")? };
    Ok((Checkpoint { step: num("step")?, params, adam, occupancy }, integrity))
}
