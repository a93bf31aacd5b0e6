//! Cone casting, conical frustums to Gaussians, and the integrated positional encoding. Kernel:
//! `cast_ipe.wgsl`.

use glam::Vec3;

use crate::bf16::Precision;
use crate::cone::{Ray, RayShape, cast_ray, cast_ray_contracted};
use crate::config::PointEncoding;
use crate::mip::{self, Gaussian};
use crate::wide::wide;

/// One Gaussian's features under a point encoding, into `dst`: the integrated positional
/// encoding (Mip-NeRF), the same with zero covariance (the "w/o IPE" ablation), or NeRF's
/// encoding of the mean with the identity. `precision` is that of the products the features
/// feed: at [`Precision::Bf16`] the IPE is [`mip::integrated_pos_enc_for_bf16`].
#[inline(always)]
pub fn encode_gaussian(
    g: &Gaussian,
    (encoding, precision): (PointEncoding, Precision),
    min_deg: u32,
    max_deg: u32,
    dst: &mut [f32],
) {
    // A closure here was not inlined at `opt-level = 2` (the test build), so its body ran outside
    // `wide`'s AVX-512 context, with `mul_add` and `floor` as library calls.
    #[inline(always)]
    fn ipe(g: &Gaussian, precision: Precision, (min_deg, max_deg): (u32, u32), dst: &mut [f32]) {
        match precision {
            Precision::F32 => mip::integrated_pos_enc(g, min_deg, max_deg, dst),
            Precision::Bf16 => mip::integrated_pos_enc_for_bf16(g, min_deg, max_deg, dst),
        }
    }
    match encoding {
        PointEncoding::Integrated => ipe(g, precision, (min_deg, max_deg), dst),
        PointEncoding::Mean => {
            ipe(&Gaussian { mean: g.mean, cov_diag: Vec3::ZERO }, precision, (min_deg, max_deg), dst)
        }
        PointEncoding::Nerf => mip::pos_enc(g.mean, min_deg, max_deg, true, dst),
    }
}

/// What the cast-and-encode stage makes of a batch's intervals, the same for
/// [`cast_and_encode`] and the device's kernel (`CastIpeKernel::run`, `cast_ipe.wgsl`): the
/// intervals a ray, the footprint's shape, whether the scene is unbounded (the Gaussians
/// contracted), and the point encoding with its degrees.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CastIpe {
    /// Intervals a ray (`n_samples + 1` edges).
    pub n_samples: usize,
    /// Cones or cylinders.
    pub shape: RayShape,
    /// An unbounded scene: the Gaussians carried through the scene contraction.
    pub unbounded: bool,
    /// IPE, PE of the means, or NeRF's PE.
    pub encoding: PointEncoding,
    /// The first degree of the encoding.
    pub min_deg: u32,
    /// One past the last degree.
    pub max_deg: u32,
}

/// Casts each ray's intervals (`t`: `n_samples + 1` edges per ray) as conical frustums (or
/// cylinders), each a Gaussian ([`cast_ray`]; in an unbounded scene carried through the scene
/// contraction, [`cast_ray_contracted`]), and encodes them ([`encode_gaussian`]) into `x`:
/// `rays.len() * n_samples` rows of the encoding's width, sample after sample. Kernel:
/// `cast_ipe.wgsl`.
///
/// `precision` is that of the products the features feed: at [`Precision::Bf16`], which rounds
/// them to bf16 first, the IPE is evaluated in `f32` arithmetic
/// ([`mip::integrated_pos_enc_for_bf16`], within [`mip::IPE_FOR_BF16_MAX_ERROR`]); at
/// [`Precision::F32`] it is the reference, bit for bit. The encoding loop runs through
/// [`wide`]: 512-bit vectors on CPUs with AVX-512, the same bits.
///
/// # Panics
/// If `t` or `x` has the wrong length for `rays.len()` rays.
pub fn cast_and_encode(rays: &[Ray], t: &[f32], stage: CastIpe, precision: Precision, x: &mut [f32]) {
    let CastIpe { n_samples, shape, unbounded, encoding, min_deg, max_deg } = stage;
    assert_eq!(t.len(), rays.len() * (n_samples + 1), "cast_and_encode: t values");
    let width = encoding.width(min_deg, max_deg);
    assert_eq!(x.len(), rays.len() * n_samples * width, "cast_and_encode: features");
    let mut gauss = vec![Gaussian::default(); n_samples];
    let cast = if unbounded { cast_ray_contracted } else { cast_ray };
    let encoding = GaussianEncoding { encoding, precision, degrees: (min_deg, max_deg) };
    for (r, ray) in rays.iter().enumerate() {
        cast(
            &t[r * (n_samples + 1)..(r + 1) * (n_samples + 1)],
            ray.origin,
            ray.direction,
            ray.radius,
            shape,
            &mut gauss,
        );
        encoding.encode(&gauss, &mut x[r * n_samples * width..(r + 1) * n_samples * width]);
    }
}

/// How [`cast_and_encode`] encodes a ray's Gaussians: the point encoding, its degrees, and the
/// precision of the products the features feed.
#[derive(Clone, Copy)]
struct GaussianEncoding {
    encoding: PointEncoding,
    precision: Precision,
    degrees: (u32, u32),
}

impl GaussianEncoding {
    /// Encodes `gauss` into `x` ([`encode_gaussian`], one row each), through [`wide`]'s 512-bit
    /// vectors where the CPU has them.
    fn encode(self, gauss: &[Gaussian], x: &mut [f32]) {
        let (min_deg, max_deg) = self.degrees;
        let width = x.len() / gauss.len().max(1);
        wide(
            #[inline(always)]
            || {
                for (g, row) in gauss.iter().zip(x.chunks_exact_mut(width.max(1))) {
                    encode_gaussian(g, (self.encoding, self.precision), min_deg, max_deg, row);
                }
            },
        );
    }
}
