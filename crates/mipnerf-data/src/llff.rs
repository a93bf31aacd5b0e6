//! Forward-facing captures in the LLFF format, as the official `LLFF` loader reads them.
//!
//! `poses_bounds.npy` holds one row of 17 numbers per image: a 3x5 matrix (rotation columns in
//! LLFF's `[down, right, back]` order, the camera centre, and `[height, width, focal]`) and the
//! near/far depth bounds. Images are in `images_{factor}` (or `images` for factor 0), sorted by
//! name. Loading reorders the rotation to `[right, up, back]` (`[y, -x, z]`), scales the scene by
//! `1 / (0.75 · min bound)`, recentres the poses on their average, holds out every 8th image as a
//! test image, and maps rays to normalised device coordinates (near plane 1, `t` in `[0, 1]`)
//! with the cylinder ray shape. The render path is the official 120-frame, 2-rotation spiral;
//! `spherify` instead recentres the poses on a sphere (world-space rays) with a 120-frame circle.

use std::path::Path;

use glam::{DMat3, DVec3};

use crate::{DataError, Dataset, Ndc, Pixels, Split, View, check_pixel_memory, image_pixels, read_png_rgba};
use mipnerf_core::camera::{Camera, Similarity, pinhole_pix2cam};

/// Every `LLFF_HOLD`-th image is a test image.
pub const LLFF_HOLD: usize = 8;
/// Frames of the render path.
pub const RENDER_FRAMES: usize = 120;

type Pose = [[f64; 4]; 3];

fn col(p: &Pose, c: usize) -> DVec3 {
    DVec3::new(p[0][c], p[1][c], p[2][c])
}

fn pose_from_cols(x: DVec3, y: DVec3, z: DVec3, t: DVec3) -> Pose {
    std::array::from_fn(|r| [x[r], y[r], z[r], t[r]])
}

/// The official `viewmatrix`: a camera looking along `-z`... with `z` its back axis, `up` roughly
/// its up axis, at `pos`.
fn view_matrix(z: DVec3, up: DVec3, pos: DVec3) -> Pose {
    let vec2 = z.normalize();
    let vec0 = up.cross(vec2).normalize();
    let vec1 = vec2.cross(vec0).normalize();
    pose_from_cols(vec0, vec1, vec2, pos)
}

/// The official `poses_avg`: mean centre, summed back and up axes.
fn poses_avg(poses: &[Pose]) -> Pose {
    let n = poses.len() as f64;
    let center = poses.iter().map(|p| col(p, 3)).sum::<DVec3>() / n;
    let z = poses.iter().map(|p| col(p, 2)).sum::<DVec3>().normalize();
    let up = poses.iter().map(|p| col(p, 1)).sum::<DVec3>();
    view_matrix(z, up, center)
}

/// `inv(a) · b` for rigid 3x4 poses.
fn relative(a: &Pose, b: &Pose) -> Pose {
    let ra = DMat3::from_cols(col(a, 0), col(a, 1), col(a, 2));
    let inv = ra.inverse();
    let t = inv * (col(b, 3) - col(a, 3));
    let rb = inv * DMat3::from_cols(col(b, 0), col(b, 1), col(b, 2));
    pose_from_cols(rb.x_axis, rb.y_axis, rb.z_axis, t)
}

/// The official 120-frame spiral (2 rotations) around the average pose, focused at a depth
/// between the closest and farthest bounds.
fn spiral_path(poses: &[Pose], min_bound: f64, max_bound: f64) -> Vec<Pose> {
    let c2w = poses_avg(poses);
    let up = poses.iter().map(|p| col(p, 1)).sum::<DVec3>().normalize();
    let (close, inf) = (min_bound * 0.9, max_bound * 5.0);
    let dt = 0.75;
    let focal = 1.0 / ((1.0 - dt) / close + dt / inf);
    // 90th percentile of |camera centre| per axis.
    let rads: [f64; 3] = std::array::from_fn(|k| {
        let mut v: Vec<f64> = poses.iter().map(|p| p[k][3].abs()).collect();
        v.sort_by(f64::total_cmp);
        percentile(&v, 90.0)
    });
    let apply = |v: [f64; 4]| DVec3::from_array(std::array::from_fn(|r| (0..4).map(|c| c2w[r][c] * v[c]).sum()));
    (0..RENDER_FRAMES)
        .map(|i| {
            let theta = 2.0 * std::f64::consts::PI * 2.0 * i as f64 / RENDER_FRAMES as f64;
            let c = apply([theta.cos() * rads[0], -theta.sin() * rads[1], -(theta * 0.5).sin() * rads[2], 1.0]);
            let z = (c - apply([0.0, 0.0, -focal, 1.0])).normalize();
            view_matrix(z, up, c)
        })
        .collect()
}

/// numpy's default (linear) percentile of sorted values.
pub(crate) fn percentile(sorted: &[f64], q: f64) -> f64 {
    let pos = q / 100.0 * (sorted.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

/// The cameras' root-mean-square distance from the centre in the official spherical poses
/// ([`Spherify::Official`]): a unit sphere.
pub const OFFICIAL_SPHERIFY_RADIUS: f64 = 1.0;

/// The cameras' distance from the centre that spherified scenes train at by default: the Blender
/// scenes' 4. Volume density is per unit of length and the positional encoding's lowest
/// frequency is one radian per unit, both sized for objects of about a unit across; on the unit
/// sphere a captured object is a few tenths across, so it starts nearly transparent and its
/// lowest frequencies barely vary over it (trained at radius 1, a masked real capture drew its
/// object in exact greys in 3 of 6 seeds; at 4, in colour in 6 of 6, with 22.46 dB mean
/// held-out PSNR after 300 steps against 19.51, `docs/results/masks`).
pub const SPHERIFY_RADIUS: f64 = 4.0;

/// How spherical poses are made for a capture all around its scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spherify {
    /// The official `generate_spherical_poses`: the up axis the mean of the cameras' offsets from
    /// the centre, the cameras on the unit sphere, the official 120-frame circle.
    Official,
    /// The up axis that of the ring the cameras stand on ([`ring_axis`]), the cameras at `radius`
    /// (root-mean-square distance from the centre), and the render path that ring's own circle.
    /// The mean offset tilts with the capture (27 degrees off the ring's axis on a real 360
    /// capture, the ethiopian head), and every orbit and spiral with it.
    Ring {
        /// The cameras' root-mean-square distance from the centre.
        radius: f64,
    },
    /// As [`Ring`](Self::Ring), scaled so that the farthest camera lies on the unit sphere: an
    /// unbounded scene's poses (mip-NeRF 360's normalisation, [`mipnerf_core::contract`]), the same for
    /// every split, as it is taken over every photo.
    UnitBall,
}

/// The axis of the ring the camera centres stand on: the normal of the plane that fits them
/// best (the direction along which they spread least, from their covariance's eigenvectors),
/// pointing the way the cameras' up axes (`ups`) do on average. `None` for fewer than three
/// centres or centres along a line (no plane).
#[must_use]
pub fn ring_axis(centres: &[DVec3], ups: &[DVec3]) -> Option<DVec3> {
    if centres.len() < 3 {
        return None;
    }
    let n = centres.len() as f64;
    let mean = centres.iter().sum::<DVec3>() / n;
    let mut cov = DMat3::ZERO;
    for c in centres {
        let d = *c - mean;
        cov += DMat3::from_cols(d * d.x, d * d.y, d * d.z);
    }
    let (values, vectors) = symmetric_eigen(cov * (1.0 / n));
    // values ascending: [0] the least spread (the axis), [1] must be clearly above 0.
    if !(values[1] > 1e-12 * values[2].max(f64::MIN_POSITIVE) && values[2] > 0.0) {
        return None;
    }
    let axis = vectors[0];
    let up = ups.iter().sum::<DVec3>();
    Some(if axis.dot(up) < 0.0 { -axis } else { axis })
}

/// Eigenvalues (ascending) and unit eigenvectors of a symmetric 3x3 matrix, by cyclic Jacobi
/// rotations (`A <- Jᵀ A J`, `V <- V J`, Numerical Recipes' convention), `a[row][col]`.
fn symmetric_eigen(m: DMat3) -> ([f64; 3], [DVec3; 3]) {
    let mut a: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| m.col(c)[r]));
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..50 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        let diag = a[0][0].powi(2) + a[1][1].powi(2) + a[2][2].powi(2);
        if off <= 1e-30 * diag.max(f64::MIN_POSITIVE) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in &mut a {
                let (kp, kq) = (row[p], row[q]);
                row[p] = c * kp - s * kq;
                row[q] = s * kp + c * kq;
            }
            for k in 0..3 {
                let (pk, qk) = (a[p][k], a[q][k]);
                a[p][k] = c * pk - s * qk;
                a[q][k] = s * pk + c * qk;
            }
            for row in &mut v {
                let (kp, kq) = (row[p], row[q]);
                row[p] = c * kp - s * kq;
                row[q] = s * kp + c * kq;
            }
        }
    }
    // Eigenvector k is column k of V.
    let mut pairs: Vec<(f64, DVec3)> =
        (0..3).map(|k| (a[k][k], DVec3::new(v[0][k], v[1][k], v[2][k]).normalize())).collect();
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
    ([pairs[0].0, pairs[1].0, pairs[2].0], [pairs[0].1, pairs[1].1, pairs[2].1])
}

/// Spherical poses (see [`Spherify`]): recentre on the point closest to all optical axes, turn
/// the up axis to `z`, scale the cameras to the radius, and the path. Returns the new poses, the
/// scale applied, and the path.
fn spherify(poses: &[Pose], how: Spherify) -> Option<(Vec<Pose>, f64, Vec<Pose>)> {
    // Point of least squared distance to every camera's optical axis.
    let mut a_sum = DMat3::ZERO;
    let mut b_sum = DVec3::ZERO;
    for p in poses {
        let d = col(p, 2);
        let o = col(p, 3);
        let a = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        let b = -(a * o);
        a_sum += a.transpose() * a;
        b_sum += b;
    }
    let n = poses.len() as f64;
    let a_mean = a_sum * (1.0 / n);
    if a_mean.determinant().abs() < 1e-9 {
        return None; // parallel optical axes: no point closest to all of them
    }
    let center = -(a_mean.inverse() * (b_sum / n));
    let radius = match how {
        Spherify::Official | Spherify::UnitBall => OFFICIAL_SPHERIFY_RADIUS,
        Spherify::Ring { radius } => radius,
    };
    let up = match how {
        Spherify::Official => poses.iter().map(|p| col(p, 3) - center).sum::<DVec3>() / n,
        Spherify::Ring { .. } | Spherify::UnitBall => {
            let centres: Vec<DVec3> = poses.iter().map(|p| col(p, 3)).collect();
            let ups: Vec<DVec3> = poses.iter().map(|p| col(p, 1)).collect();
            ring_axis(&centres, &ups)?
        }
    };
    let vec0 = up.normalize();
    let vec1 = DVec3::new(0.1, 0.2, 0.3).cross(vec0).normalize();
    let vec2 = vec0.cross(vec1).normalize();
    let c2w = pose_from_cols(vec1, vec2, vec0, center);
    let mut reset: Vec<Pose> = poses.iter().map(|p| relative(&c2w, p)).collect();
    let sc = if how == Spherify::UnitBall {
        1.0 / reset.iter().map(|p| col(p, 3).length()).fold(0.0, f64::max)
    } else {
        radius / (reset.iter().map(|p| col(p, 3).length_squared()).sum::<f64>() / n).sqrt()
    };
    if !(sc.is_finite() && sc > 0.0) {
        return None;
    }
    for p in &mut reset {
        for row in p.iter_mut() {
            row[3] *= sc;
        }
    }
    if let Spherify::Ring { .. } | Spherify::UnitBall = how {
        let path = ring_path(&reset);
        return Some((reset, sc, path));
    }
    // The path's circle on the unit sphere, scaled to the cameras' radius.
    let zh = reset.iter().map(|p| p[2][3]).sum::<f64>() / n / radius;
    let radcircle = (1.0 - zh * zh).max(0.0).sqrt();
    let path = (0..RENDER_FRAMES)
        .map(|i| {
            let th = 2.0 * std::f64::consts::PI * i as f64 / (RENDER_FRAMES - 1) as f64;
            let origin = DVec3::new(radcircle * th.cos(), radcircle * th.sin(), zh);
            let up = DVec3::new(0.0, 0.0, -1.0);
            let v2 = origin.normalize();
            let v0 = v2.cross(up).normalize();
            let v1 = v2.cross(v0).normalize();
            pose_from_cols(v0, v1, v2, origin * radius)
        })
        .collect();
    Some((reset, sc, path))
}

/// The cameras' own circle for poses whose `z` is their ring's axis: the circle that fits their
/// centres best in `x` and `y` (least squares, Kåsa's fit; their mean distance from its centre),
/// at their mean height, every frame looking at the origin (the point closest to all optical
/// axes) with `z` up. [`RENDER_FRAMES`] frames, one turn.
fn ring_path(poses: &[Pose]) -> Vec<Pose> {
    let n = poses.len() as f64;
    let height = poses.iter().map(|p| p[2][3]).sum::<f64>() / n;
    let (centre, rho) = fit_circle(&poses.iter().map(|p| (p[0][3], p[1][3])).collect::<Vec<_>>());
    (0..RENDER_FRAMES)
        .map(|i| {
            let th = std::f64::consts::TAU * i as f64 / RENDER_FRAMES as f64;
            let pos = DVec3::new(centre.0 + rho * th.cos(), centre.1 + rho * th.sin(), height);
            view_matrix(pos, DVec3::Z, pos)
        })
        .collect()
}

/// The circle through 2D points in the least-squares sense of Kåsa (`x² + y² + a x + b y + c`
/// minimal): its centre, and the points' mean distance from it. For points that fit no circle (a
/// singular system), their centroid and mean distance from it.
fn fit_circle(points: &[(f64, f64)]) -> ((f64, f64), f64) {
    let n = points.len() as f64;
    let (mut m, mut r) = (DMat3::ZERO, DVec3::ZERO);
    for &(x, y) in points {
        let row = DVec3::new(x, y, 1.0);
        m += DMat3::from_cols(row * x, row * y, row);
        r += row * -(x * x + y * y);
    }
    let centroid = (points.iter().map(|p| p.0).sum::<f64>() / n, points.iter().map(|p| p.1).sum::<f64>() / n);
    let centre =
        if m.determinant().abs() > 1e-12 * m.to_cols_array().iter().map(|v| v.abs()).fold(0.0, f64::max).powi(3) {
            let abc = m.inverse() * r;
            (-abc.x / 2.0, -abc.y / 2.0)
        } else {
            centroid
        };
    let rho = points.iter().map(|p| (p.0 - centre.0).hypot(p.1 - centre.1)).sum::<f64>() / n;
    (centre, rho)
}

/// Reads `poses_bounds.npy`: `N x 17` float64 (or float32), C order.
///
/// # Errors
/// [`DataError`] naming the file for an unreadable file, another dtype or shape, or non-finite
/// values.
pub fn read_poses_bounds(path: &Path) -> Result<Vec<[f64; 17]>, DataError> {
    let bytes =
        mipnerf_core::io::read_regular(path, mipnerf_core::io::cap::POSES).map_err(|e| DataError::io(path, e))?;
    let npy = npyz::NpyFile::new(&bytes[..]).map_err(|e| DataError::invalid(path, format!("not a .npy file: {e}")))?;
    let shape = npy.shape().to_vec();
    if shape.len() != 2 || shape[1] != 17 || shape[0] == 0 {
        return Err(DataError::invalid(path, format!("expected an N x 17 array (N > 0), found shape {shape:?}")));
    }
    if npy.header().order() != npyz::Order::C {
        return Err(DataError::invalid(path, "Fortran-ordered arrays are not supported"));
    }
    let dtype = npy.dtype();
    let descr = dtype.descr();
    let values: Vec<f64> = match descr.trim_matches('\'') {
        "<f8" => npy.into_vec::<f64>(),
        "<f4" => npy.into_vec::<f32>().map(|v| v.into_iter().map(f64::from).collect()),
        other => {
            return Err(DataError::invalid(path, format!("expected float64 or float32 values, found dtype {other}")));
        }
    }
    .map_err(|e| DataError::invalid(path, format!("truncated or unreadable data: {e}")))?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(DataError::invalid(path, format!("row {} has a non-finite value", i / 17)));
    }
    Ok(values.chunks_exact(17).map(|c| std::array::from_fn(|i| c[i])).collect())
}

/// Writes `poses_bounds.npy` (float64, `N x 17`) atomically ([`mipnerf_core::io::write_atomic`]).
///
/// # Errors
/// [`DataError`] for an unwritable file.
pub fn write_poses_bounds(path: &Path, rows: &[[f64; 17]]) -> Result<(), DataError> {
    use npyz::WriterBuilder;
    let mut bytes = Vec::with_capacity(128 + rows.len() * 17 * 8);
    {
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[rows.len() as u64, 17])
            .writer(std::io::Cursor::new(&mut bytes))
            .begin_nd()
            .map_err(|e| DataError::io(path, e))?;
        w.extend(rows.iter().flatten().copied()).map_err(|e| DataError::io(path, e))?;
        w.finish().map_err(|e| DataError::io(path, e))?;
    }
    Ok(mipnerf_core::io::write_atomic(path, &bytes)?)
}

/// The error for a scene without the image folder `factor` picks: names the folders it has and
/// the `--llff-factor` that reads each (`images`: 0, `images_N`: N).
fn missing_image_folder(dir: &Path, imgdir: &Path, factor: u32) -> DataError {
    let mut present: Vec<(u32, String)> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(Result::ok)
        .filter(|e| e.path().is_dir())
        .filter_map(|e| {
            let name = e.file_name().to_str()?.to_owned();
            let n = if name == "images" { 0 } else { name.strip_prefix("images_")?.parse().ok()? };
            Some((n, name))
        })
        .collect();
    present.sort();
    let wanted = if factor > 0 {
        format!("--llff-factor {factor} reads images_{factor}")
    } else {
        "--llff-factor 0 reads images".to_owned()
    };
    let found = if present.is_empty() {
        "and the scene has no images or images_N folder".to_owned()
    } else {
        let list: Vec<String> = present.iter().map(|(n, name)| format!("{name} (--llff-factor {n})")).collect();
        format!("the scene has {}", list.join(", "))
    };
    DataError::invalid(imgdir, format!("no such image folder: {wanted}, {found}"))
}

fn image_files(dir: &Path) -> Result<Vec<std::path::PathBuf>, DataError> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .map_err(|e| DataError::io(dir, e))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| {
            p.extension().and_then(|e| e.to_str()).is_some_and(|e| matches!(e, "png" | "PNG" | "jpg" | "JPG" | "jpeg"))
        })
        .collect();
    files.sort();
    Ok(files)
}

/// Loads `split` of an LLFF scene (see the module docs). `factor` picks `images_{factor}`
/// (0: `images`); `spherify`, how to make spherical poses (`None`: forward-facing, NDC). The
/// test split also gets the render path.
///
/// # Errors
/// [`DataError`] naming the file: unreadable or malformed `poses_bounds.npy`, a missing image
/// folder, a count of images that differs from the poses, images of different sizes or
/// undecodable, non-positive bounds, singular poses.
pub fn load(dir: &Path, split: Split, factor: u32, spherify: Option<Spherify>) -> Result<Dataset, DataError> {
    let npy = dir.join("poses_bounds.npy");
    let rows = read_poses_bounds(&npy)?;
    let imgdir = if factor > 0 { dir.join(format!("images_{factor}")) } else { dir.join("images") };
    if !imgdir.is_dir() {
        return Err(missing_image_folder(dir, &imgdir, factor));
    }
    let files = image_files(&imgdir)?;
    if files.len() != rows.len() {
        return Err(DataError::invalid(
            &imgdir,
            format!("{} images but poses_bounds.npy has {} poses", files.len(), rows.len()),
        ));
    }
    let mut pixels = 0u64;
    for f in &files {
        pixels += image_pixels(f)?;
    }
    check_pixel_memory(&imgdir, pixels, files.len())?;
    let mut images: Vec<LlffImage> = Vec::with_capacity(files.len());
    for f in files {
        let (w, h, rgba, _) = read_png_rgba(&f)?;
        images.push(LlffImage { file: f, width: w, height: h, rgba });
    }
    from_rows(dir, &npy, &rows, images, factor, split, spherify)
}

/// One image of an LLFF scene: its file, size and straight RGBA8 pixels.
#[derive(Clone, Debug)]
pub struct LlffImage {
    /// Where it was read from (named in errors and outputs).
    pub file: std::path::PathBuf,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Straight RGBA8, row-major.
    pub rgba: Vec<u8>,
}

/// The LLFF loader's work after reading: `rows` (as in `poses_bounds.npy`, whose path `npy`
/// errors name) with one image each, in order, downsampled by `factor` from the resolution the
/// rows' focal length is given at (0 and 1: not downsampled).
///
/// # Errors
/// Images of different sizes, non-positive bounds, singular poses.
pub fn from_rows(
    dir: &Path,
    npy: &Path,
    rows: &[[f64; 17]],
    images: Vec<LlffImage>,
    factor: u32,
    split: Split,
    spherify: Option<Spherify>,
) -> Result<Dataset, DataError> {
    let npy = npy.to_path_buf();
    if images.len() != rows.len() || images.is_empty() {
        return Err(DataError::invalid(&npy, format!("{} images for {} poses", images.len(), rows.len())));
    }
    let (w, h) = (images[0].width, images[0].height);
    if let Some(im) = images.iter().find(|im| (im.width, im.height) != (w, h)) {
        return Err(DataError::invalid(
            &im.file,
            format!("image is {}x{}, the first image is {w}x{h}", im.width, im.height),
        ));
    }
    let files: Vec<std::path::PathBuf> = images.iter().map(|im| im.file.clone()).collect();
    let images: Vec<(u32, u32, Vec<u8>)> = images.into_iter().map(|im| (im.width, im.height, im.rgba)).collect();
    // The official loader reads every photo's focal length from the first row.
    if !rows[0][14].is_finite() || rows[0][14] <= 0.0 {
        return Err(DataError::invalid(
            &npy,
            format!(
                "row 0's focal length (its column 14, read for every photo) must be a positive number, found {}",
                rows[0][14]
            ),
        ));
    }
    let focal = rows[0][14] / f64::from(factor.max(1));
    let ScaledPoses { data_poses, poses, scale, bounds: (min_b, max_b) } = scaled_poses(&npy, rows)?;
    let avg = poses_avg(&poses);
    let mut poses: Vec<Pose> = poses.iter().map(|p| relative(&avg, p)).collect();
    let (near, far, path, ndc, sphere_scale) = if let Some(how) = spherify {
        let (reset, sc, path) = self::spherify(&poses, how).ok_or_else(|| {
            DataError::invalid(
                &npy,
                "spherical poses need cameras whose optical axes converge (and, for the ring's axis, centres that \
                 spread in a plane); these do not",
            )
        })?;
        poses = reset;
        ((min_b * sc * 0.9) as f32, (max_b * sc) as f32, path, None, sc)
    } else {
        let ndc = Ndc { focal: focal as f32, width: w as f32, height: h as f32 };
        (0.0, 1.0, spiral_path(&poses, min_b, max_b), Some(ndc), 1.0)
    };
    // Scaled, recentred on the mean pose and spherified: one similarity, read off the first pose.
    let data_to_scene = Similarity::between(&data_poses[0], &poses[0], scale * sphere_scale);
    let pix2cam = pinhole_pix2cam(w, h, focal);
    let mut views = Vec::new();
    for (i, ((pose, (iw, ih, rgba)), file)) in poses.iter().zip(images).zip(&files).enumerate() {
        let is_test = i % LLFF_HOLD == 0;
        if is_test != (split != Split::Train) {
            continue;
        }
        let camera = Camera::from_pix2cam(iw, ih, pix2cam, *pose)
            .map_err(|e| DataError::invalid(&npy, format!("pose {i}: {e}")))?;
        views.push(View {
            file: file.clone(),
            camera,
            pixels: Pixels::Rgba8(rgba),
            near,
            far,
            lossmult: 1.0,
            scale: 0,
        });
    }
    let mut ds = Dataset::new(dir, split, views, false)?;
    ds.ndc = ndc;
    ds.data_to_scene = data_to_scene;
    if split != Split::Train {
        ds.render_path = path
            .into_iter()
            .map(|p| Camera::from_pix2cam(w, h, pix2cam, p))
            .collect::<Result<_, _>>()
            .map_err(|e| DataError::invalid(&npy, format!("render path: {e}")))?;
    }
    Ok(ds)
}

/// The poses of LLFF rows in the loader's axes, in the data's own frame and scaled so that the
/// nearest depth bound is at 4/3 (the official `1 / (0.75 near)`), with that scale and the
/// scaled bounds.
struct ScaledPoses {
    data_poses: Vec<Pose>,
    poses: Vec<Pose>,
    scale: f64,
    bounds: (f64, f64),
}

/// [`ScaledPoses`] of `rows` (of the file `npy`, which errors name).
///
/// # Errors
/// Bounds that are not positive with far > near; a camera farther from the others than
/// [`mipnerf_core::camera::MAX_SCENE_COORDINATE`] in units of the nearest bound.
fn scaled_poses(npy: &Path, rows: &[[f64; 17]]) -> Result<ScaledPoses, DataError> {
    // Rotation columns [down, right, back] -> [right, up, back]: [y, -x, z] of the stored columns.
    let mut poses: Vec<Pose> = rows
        .iter()
        .map(|r| {
            let m = |i: usize, j: usize| r[i * 5 + j];
            std::array::from_fn(|i| [m(i, 1), -m(i, 0), m(i, 2), m(i, 3)])
        })
        .collect();
    let bounds: Vec<[f64; 2]> = rows.iter().map(|r| [r[15], r[16]]).collect();
    let min_b = bounds.iter().map(|b| b[0]).fold(f64::INFINITY, f64::min);
    let max_b = bounds.iter().map(|b| b[1]).fold(f64::NEG_INFINITY, f64::max);
    if !(min_b > 0.0 && max_b > min_b) {
        return Err(DataError::invalid(
            npy,
            format!("depth bounds must be positive with far > near, found {min_b}..{max_b}"),
        ));
    }
    // The poses in the data's own frame, for the similarity the loader applies to it.
    let data_poses = poses.clone();
    let scale = 1.0 / (min_b * 0.75);
    for (i, p) in poses.iter_mut().enumerate() {
        for row in p.iter_mut() {
            row[3] *= scale;
        }
        // Named by its row here: after recentring on the mean camera, one camera far away
        // moves every camera far away.
        if let Some(t) = p.iter().map(|row| row[3]).find(|t| t.abs() > mipnerf_core::camera::MAX_SCENE_COORDINATE) {
            return Err(DataError::invalid(
                npy,
                format!(
                    "row {i}: a coordinate of the camera's position is {:.3e} times the nearest depth bound (column 15's smallest \
                     value) away; at most {:e} is taken (a wrong row, or bounds in other units than the poses)",
                    t.abs() * 0.75,
                    mipnerf_core::camera::MAX_SCENE_COORDINATE * 0.75
                ),
            ));
        }
    }
    Ok(ScaledPoses { data_poses, poses, scale, bounds: (min_b * scale, max_b * scale) })
}
