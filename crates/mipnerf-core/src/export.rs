//! A trained model's geometry for 3D tools: a triangle mesh of its density field (marching cubes,
//! vertex colours from the model) and coloured points at the expected depth of rays, both as PLY.
//!
//! The density is Mip-NeRF's own anti-aliased density: each grid node is encoded by the integrated
//! positional encoding of a Gaussian with the variance of a uniform cube of the grid's cell
//! (`h² / 12` per axis), so the mesh of a coarse grid is the surface of the scene as seen at that
//! scale, without the aliasing of point samples of the high frequencies.
//!
//! Marching cubes here is the face-walking form: on each face of a cell the edge crossings are
//! joined into segments (an ambiguous face, two opposite corners inside, is resolved by the mean
//! of its four corners, which both cells that share the face compute alike, so the surface has no
//! holes), the segments are linked into loops, and each loop becomes a fan of triangles, wound so
//! that their normals point from dense to empty space. Vertices on a grid edge are shared by every
//! cell around it.

use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

use glam::Vec3;
use rayon::prelude::*;

use crate::mip::{self, Gaussian};
use crate::mlp::MlpCache;
use crate::model::Model;
use crate::render::rgb_activation;

/// Grid nodes evaluated per MLP call.
const CHUNK: usize = 4096;

/// A triangle mesh with one colour per vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions (world units).
    pub vertices: Vec<Vec3>,
    /// Unit normals per vertex, pointing from dense to empty space.
    pub normals: Vec<Vec3>,
    /// Colour per vertex, 8 bits per channel.
    pub colors: Vec<[u8; 3]>,
    /// Vertex indices of each triangle, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// A regular grid of `dims` nodes over the box `[lo, hi]` (node `(i, j, k)` at
/// `lo + (hi - lo) (i, j, k) / (dims - 1)`), its values `x`-fastest.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    /// Nodes along x, y and z (each at least 2).
    pub dims: [usize; 3],
    /// The corner of node (0, 0, 0).
    pub lo: Vec3,
    /// The corner of the last node.
    pub hi: Vec3,
    /// `dims[0] dims[1] dims[2]` values, `x` fastest, then `y`, then `z`.
    pub values: Vec<f32>,
}

impl Field {
    /// The field `f` sampled at every node of a `dims` grid over `[lo, hi]`.
    ///
    /// # Panics
    /// If a dimension is below 2.
    #[must_use]
    pub fn from_fn(dims: [usize; 3], lo: Vec3, hi: Vec3, f: impl Fn(Vec3) -> f32 + Sync) -> Self {
        assert!(dims.iter().all(|&d| d >= 2), "Field: {dims:?} nodes");
        let mut field = Self { dims, lo, hi, values: Vec::new() };
        let n = dims[0] * dims[1] * dims[2];
        field.values = (0..n).into_par_iter().map(|i| f(field.node_position(i))).collect();
        field
    }

    /// The spacing of the nodes along each axis.
    #[must_use]
    pub fn spacing(&self) -> Vec3 {
        (self.hi - self.lo) / Vec3::new((self.dims[0] - 1) as f32, (self.dims[1] - 1) as f32, (self.dims[2] - 1) as f32)
    }

    /// The world position of node `i` (its index in `values`).
    #[must_use]
    pub fn node_position(&self, i: usize) -> Vec3 {
        let [nx, ny, _] = self.dims;
        let (x, y, z) = (i % nx, (i / nx) % ny, i / (nx * ny));
        self.lo + self.spacing() * Vec3::new(x as f32, y as f32, z as f32)
    }

    fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        self.values[x + self.dims[0] * (y + self.dims[1] * z)]
    }
}

/// The model's density (after its activation) at every node of a `dims` grid over `[lo, hi]`,
/// from the last level's MLP, each node encoded as a Gaussian with the variance of one cell (see
/// the [module docs](self)).
///
/// # Panics
/// If `params` is not the model's or a dimension is below 2.
#[must_use]
pub fn density_field(model: &Model, params: &[f32], dims: [usize; 3], lo: Vec3, hi: Vec3) -> Field {
    assert_eq!(params.len(), model.num_params(), "density_field: parameter count");
    let mut field = Field::from_fn(dims, lo, hi, |_| 0.0);
    let h = field.spacing();
    let var = h * h / 12.0;
    let points: Vec<Gaussian> =
        (0..field.values.len()).map(|i| Gaussian { mean: field.node_position(i), cov_diag: var }).collect();
    // Density does not depend on the view direction: any direction serves.
    let views = vec![Vec3::Z; points.len()];
    field.values = query(model, params, &points, &views).into_iter().map(|(d, _)| d).collect();
    field
}

/// Density and colour of the last level's MLP at each Gaussian `points[i]` seen along the
/// direction `views[i]` (unit).
fn query(model: &Model, params: &[f32], points: &[Gaussian], views: &[Vec3]) -> Vec<(f32, [f32; 3])> {
    let c = model.config();
    let mlp = &model.mlps()[if c.separate_mlps { c.num_levels - 1 } else { 0 }];
    let (x_dim, v_dim) = (c.x_dim(), c.view_dim());
    let state = model.field_state(params);
    points
        .par_chunks(CHUNK)
        .zip(views.par_chunks(CHUNK))
        .flat_map_iter(|(pts, dirs)| {
            let mut x = vec![0.0f32; pts.len() * x_dim];
            let mut view = vec![0.0f32; pts.len() * v_dim];
            for (k, (g, d)) in pts.iter().zip(dirs).enumerate() {
                model.encode_probe(params, &state, g, false, &mut x[k * x_dim..(k + 1) * x_dim]);
                mip::pos_enc(*d, 0, c.deg_view, true, &mut view[k * v_dim..(k + 1) * v_dim]);
            }
            let mut cache = MlpCache::default();
            mlp.forward(params, &x, &view, pts.len(), 1, &mut cache);
            (0..pts.len())
                .map(|k| {
                    let density = c.density_activation.forward(cache.raw_density[k], c.density_bias);
                    let rgb = std::array::from_fn(|ch| rgb_activation(cache.raw_rgb[3 * k + ch], c.rgb_padding));
                    (density, rgb)
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The 12 edges of a cell as pairs of its corners (corner `c` at offset `(c & 1, c >> 1 & 1,
/// c >> 2 & 1)`).
const EDGES: [[usize; 2]; 12] =
    [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];

/// The 6 faces of a cell as their corners in cyclic order.
const FACES: [[usize; 4]; 6] = [[0, 2, 6, 4], [1, 3, 7, 5], [0, 1, 5, 4], [2, 3, 7, 6], [0, 1, 3, 2], [4, 5, 7, 6]];

/// [`FACES`], each in counter-clockwise order seen from outside the cell.
fn outward_faces() -> [[usize; 4]; 6] {
    let pos = |c: usize| Vec3::new((c & 1) as f32, (c >> 1 & 1) as f32, (c >> 2 & 1) as f32);
    FACES.map(|mut f| {
        let normal = (pos(f[1]) - pos(f[0])).cross(pos(f[2]) - pos(f[1]));
        let centre = f.iter().map(|&c| pos(c)).sum::<Vec3>() / 4.0;
        // The outward direction of a face is from the cell's centre to the face's.
        if normal.dot(centre - Vec3::splat(0.5)) < 0.0 {
            f.reverse();
        }
        f
    })
}

fn edge_of(a: usize, b: usize) -> usize {
    let (a, b) = (a.min(b), a.max(b));
    EDGES.iter().position(|e| *e == [a, b]).unwrap_or_else(|| unreachable!("corners {a} and {b} share no edge"))
}

/// The surface where `field` crosses `iso` (values at or above it are inside), as triangles
/// wound counter-clockwise seen from outside (normals towards lower values), vertices shared
/// between cells, positions in world units; vertex normals are the area-weighted sums of their
/// triangles'. Colours are left empty (see [`extract_mesh`]).
#[must_use]
pub fn marching_cubes(field: &Field, iso: f32) -> Mesh {
    let [nx, ny, nz] = field.dims;
    let h = field.spacing();
    let mut mesh = Mesh::default();
    // Global edge (lower node, axis) -> vertex.
    let mut vertex_of: HashMap<(usize, usize), u32> = HashMap::new();
    let node = |x: usize, y: usize, z: usize| x + nx * (y + ny * z);
    let mut loop_vertices = Vec::new();
    let faces = outward_faces();
    for z in 0..nz - 1 {
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let corner = |c: usize| (x + (c & 1), y + (c >> 1 & 1), z + (c >> 2 & 1));
                let v: [f32; 8] = std::array::from_fn(|c| {
                    let (a, b, d) = corner(c);
                    field.at(a, b, d)
                });
                let inside: [bool; 8] = std::array::from_fn(|c| v[c] >= iso);
                if inside.iter().all(|&i| i) || inside.iter().all(|&i| !i) {
                    continue;
                }
                // Directed segments on each face: walking its boundary counter-clockwise seen
                // from outside the cell, each runs from a crossing out of the inside corners to
                // the next crossing back in, so the inside lies to its left. A crossed edge
                // borders two faces, which walk it in opposite directions: it starts one segment
                // and ends another, and the segments chain into loops that every cell sharing a
                // face orients alike.
                let mut next = [usize::MAX; 12];
                for face in &faces {
                    let crosses = |k: usize| inside[face[k]] != inside[face[(k + 1) % 4]];
                    let edge = |k: usize| edge_of(face[k], face[(k + 1) % 4]);
                    let n_crossed = (0..4).filter(|&k| crosses(k)).count();
                    if n_crossed == 2 {
                        let out = (0..4).find(|&k| crosses(k) && inside[face[k]]);
                        let back = (0..4).find(|&k| crosses(k) && !inside[face[k]]);
                        if let (Some(a), Some(b)) = (out, back) {
                            next[edge(a)] = edge(b);
                        }
                    } else if n_crossed == 4 {
                        // Two opposite corners inside: the face's mean decides whether they
                        // connect through its middle (then each outside corner is cut off) or not
                        // (each inside corner is).
                        let mean = face.iter().map(|&c| v[c]).sum::<f32>() / 4.0;
                        let cut_inside = mean < iso;
                        for k in (0..4).filter(|&k| inside[face[k]] == cut_inside) {
                            // Corner k sits between boundary edges k - 1 and k.
                            let (before, after) = (edge((k + 3) % 4), edge(k));
                            if cut_inside {
                                next[after] = before;
                            } else {
                                next[before] = after;
                            }
                        }
                    }
                }
                // Walk each loop; traced with the inside on the left, its right-hand normal points
                // into the inside, so it is laid out reversed (normals towards lower values).
                let mut used = [false; 12];
                for start in 0..12 {
                    if used[start] || next[start] == usize::MAX {
                        continue;
                    }
                    loop_vertices.clear();
                    let mut cur = start;
                    while !used[cur] && cur != usize::MAX {
                        used[cur] = true;
                        let [a, b] = EDGES[cur];
                        let (pa, pb) = (corner(a), corner(b));
                        let axis = (a ^ b).trailing_zeros() as usize;
                        let key = (node(pa.0, pa.1, pa.2), axis);
                        let id = *vertex_of.entry(key).or_insert_with(|| {
                            let t = ((iso - v[a]) / (v[b] - v[a])).clamp(0.0, 1.0);
                            let p0 = Vec3::new(pa.0 as f32, pa.1 as f32, pa.2 as f32);
                            let p1 = Vec3::new(pb.0 as f32, pb.1 as f32, pb.2 as f32);
                            mesh.vertices.push(field.lo + h * (p0 + (p1 - p0) * t));
                            (mesh.vertices.len() - 1) as u32
                        });
                        loop_vertices.push(id);
                        cur = next[cur];
                    }
                    loop_vertices.reverse();
                    if loop_vertices.len() < 3 {
                        continue;
                    }
                    for k in 1..loop_vertices.len() - 1 {
                        mesh.triangles.push([loop_vertices[0], loop_vertices[k], loop_vertices[k + 1]]);
                    }
                }
            }
        }
    }
    // Vertex normals: the area-weighted sum of the triangles around each.
    mesh.normals = vec![Vec3::ZERO; mesh.vertices.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let n = (b - a).cross(c - a);
        for &i in t {
            mesh.normals[i as usize] += n;
        }
    }
    for n in &mut mesh.normals {
        *n = n.normalize_or_zero();
    }
    mesh
}

/// The surface of the model's density at `threshold` (density units: opacity per world unit)
/// over the box `[lo, hi]` sampled with `resolution` cells along its longest side, each vertex
/// coloured by the model as seen from outside along its normal. Where `sampled` is false space
/// is taken as empty: the model learnt no density there (see [`sampled_space`]).
///
/// # Panics
/// If `params` is not the model's or `resolution` is 0.
#[must_use]
pub fn extract_mesh(
    model: &Model,
    params: &[f32],
    (lo, hi): (Vec3, Vec3),
    resolution: usize,
    threshold: f32,
    sampled: &(dyn Fn(Vec3) -> bool + Sync),
) -> Mesh {
    assert!(resolution > 0, "extract_mesh: resolution 0");
    let size = hi - lo;
    let cell = size.max_element() / resolution as f32;
    let dims = [size.x, size.y, size.z].map(|s| ((s / cell).round() as usize).max(1) + 1);
    let mut field = density_field(model, params, dims, lo, hi);
    let keep: Vec<bool> = (0..field.values.len()).into_par_iter().map(|i| sampled(field.node_position(i))).collect();
    for (v, k) in field.values.iter_mut().zip(keep) {
        if !k {
            *v = 0.0;
        }
    }
    let mut mesh = marching_cubes(&field, threshold);
    let var = field.spacing() * field.spacing() / 12.0;
    let points: Vec<Gaussian> = mesh.vertices.iter().map(|&p| Gaussian { mean: p, cov_diag: var }).collect();
    let views: Vec<Vec3> = mesh.normals.iter().map(|n| if *n == Vec3::ZERO { Vec3::Z } else { -*n }).collect();
    mesh.colors = query(model, params, &points, &views).into_iter().map(|(_, rgb)| rgb.map(to_u8)).collect();
    mesh
}

/// Coloured points where `rays` (world space) reach the model's surface: the expected depth of
/// the last level (`origin + distance direction`) of each ray whose opacity is at least
/// `min_opacity`, coloured by the rendered colour with the background taken back out
/// (`(rgb - (1 - acc) bg) / acc`). Rendered under `grid` when given, as eval renders.
///
/// # Panics
/// If `params` is not the model's, or the model supersamples (its rays are per pixel).
#[must_use]
pub fn ray_points(
    model: &Model,
    params: &[f32],
    rays: &[crate::Ray],
    grid: Option<&crate::occupancy::OccupancyGrid>,
    min_opacity: f32,
) -> (Vec<Vec3>, Vec<[u8; 3]>) {
    assert_eq!(model.rays_per_pixel(), 1, "ray_points: one ray per pixel");
    let bg = crate::render::background(model.config().white_bkgd);
    let out = model.render_levels(params, rays, grid, crate::model::Levels::Last);
    let mut points = Vec::new();
    let mut colors = Vec::new();
    for (ray, &fine) in rays.iter().zip(&out) {
        if fine.acc < min_opacity || fine.acc <= 0.0 {
            continue;
        }
        points.push(ray.origin + ray.direction * fine.distance);
        colors.push(std::array::from_fn(|k| to_u8((fine.rgb[k] - (1.0 - fine.acc) * bg[k]) / fine.acc)));
    }
    (points, colors)
}

/// Where training took samples: the points that some full-resolution view of `ds` sees inside
/// its image between its near and far bounds and, with an occupancy `grid`, that lie in an
/// occupied cell. Elsewhere the density is whatever the network's initialisation left: a mesh
/// of it would be floaters.
pub fn sampled_space<'a>(
    ds: &'a crate::dataset::Dataset,
    grid: Option<&'a crate::occupancy::OccupancyGrid>,
) -> impl Fn(Vec3) -> bool + Sync + 'a {
    let views: Vec<_> = ds
        .views()
        .iter()
        .filter(|v| v.scale == 0)
        .filter_map(|v| {
            let (w, h) = (f64::from(v.camera.width), f64::from(v.camera.height));
            Some((v.camera.projection()?, w, h, f64::from(v.near), f64::from(v.far)))
        })
        .collect();
    move |p: Vec3| {
        grid.is_none_or(|g| g.is_occupied_at(p))
            && views.iter().any(|(proj, w, h, near, far)| {
                proj.project(p.as_dvec3().to_array()).is_some_and(|(x, y, t)| {
                    (0.0..*w).contains(&x) && (0.0..*h).contains(&y) && (*near..=*far).contains(&t)
                })
            })
    }
}

/// A colour channel in `[0, 1]` as 8 bits (rounded, clamped).
#[must_use]
pub fn to_u8(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Writes `mesh` as binary little-endian PLY (float x, y, z, nx, ny, nz; uchar red, green, blue;
/// faces as a uchar count and int indices), written to a temporary name and renamed.
///
/// # Errors
/// Any I/O error.
pub fn write_mesh_ply(path: &Path, mesh: &Mesh) -> std::io::Result<()> {
    let mut out = Vec::with_capacity(mesh.vertices.len() * 27 + mesh.triangles.len() * 13 + 512);
    write!(
        out,
        "{PLY_SIGNATURE} (marching cubes of the density)\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
    for (i, p) in mesh.vertices.iter().enumerate() {
        let n = mesh.normals.get(i).copied().unwrap_or(Vec3::ZERO);
        for x in [p.x, p.y, p.z, n.x, n.y, n.z] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(&mesh.colors.get(i).copied().unwrap_or([200; 3]));
    }
    for t in &mesh.triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    write_atomically(path, &out)
}

/// Writes coloured points as binary little-endian PLY (float x, y, z; uchar red, green, blue),
/// written to a temporary name and renamed.
///
/// # Errors
/// Any I/O error.
pub fn write_points_ply(path: &Path, points: &[Vec3], colors: &[[u8; 3]]) -> std::io::Result<()> {
    let mut out = Vec::with_capacity(points.len() * 15 + 256);
    write!(
        out,
        "{PLY_SIGNATURE} (expected depth of rays)\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    )?;
    for (p, c) in points.iter().zip(colors) {
        for x in [p.x, p.y, p.z] {
            out.extend_from_slice(&x.to_le_bytes());
        }
        out.extend_from_slice(c);
    }
    write_atomically(path, &out)
}

/// How every PLY file [`write_mesh_ply`] and [`write_points_ply`] write begins: what tells a file
/// `mipnerf export --overwrite` may replace ([`written_by_export`]) from any other.
pub const PLY_SIGNATURE: &str = "ply\nformat binary_little_endian 1.0\ncomment made by mipnerf export";

/// Whether `path` is a regular file (not a link, a folder or a device) that begins with
/// [`PLY_SIGNATURE`].
#[must_use]
pub fn written_by_export(path: &Path) -> bool {
    use std::io::Read;
    let regular = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_file());
    let mut head = vec![0u8; PLY_SIGNATURE.len()];
    regular
        && std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut head)).is_ok()
        && head == PLY_SIGNATURE.as_bytes()
}

/// Bytes of memory [`extract_mesh`] holds per node of its grid at its peak, inside
/// [`density_field`]: every node's Gaussian and view direction, the model's output per node, and
/// the field's values (the marching cubes' mesh and the mask of sampled space come after the
/// first three are freed). Against the peak resident memory of real exports:
/// `docs/results/export/memory.txt`.
pub const MESH_BYTES_PER_NODE: u64 = (std::mem::size_of::<Gaussian>()
    + std::mem::size_of::<Vec3>()
    + std::mem::size_of::<(f32, [f32; 3])>()
    + std::mem::size_of::<f32>()) as u64;

/// The nodes of the grid [`extract_mesh`] evaluates for `resolution` cells along the longest side
/// of a box of `size`.
#[must_use]
pub fn mesh_nodes(size: Vec3, resolution: usize) -> u64 {
    let cell = size.max_element() / resolution as f32;
    [size.x, size.y, size.z].iter().map(|s| ((s / cell).round() as u64).max(1) + 1).product()
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    crate::io::write_atomic(path, bytes).map_err(|e| e.error)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every edge of a closed surface is shared by exactly two triangles, once in each direction.
    fn assert_closed(mesh: &Mesh) {
        let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_default() += if a < b { 1 } else { -1 };
            }
        }
        let open: Vec<_> = edges.iter().filter(|&(_, &s)| s != 0).take(5).collect();
        assert!(open.is_empty(), "{} edges are not matched by an opposite one: {open:?}", open.len());
    }

    #[test]
    fn a_sphere_is_meshed_closed_on_its_surface_and_wound_outwards() {
        let (c, r) = (Vec3::new(0.1, -0.05, 0.2), 0.7);
        // Density-like: high inside.
        let field = Field::from_fn([33, 30, 35], Vec3::splat(-1.0), Vec3::splat(1.2), |p| r - (p - c).length());
        let mesh = marching_cubes(&field, 0.0);
        assert!(mesh.triangles.len() > 1000, "{} triangles", mesh.triangles.len());
        let h = field.spacing().max_element();
        let worst = mesh.vertices.iter().map(|p| ((p - c).length() - r).abs()).fold(0.0f32, f32::max);
        // Linear interpolation of a distance field along an edge is off by at most the chord's
        // sagitta, h² / (8 r).
        assert!(worst <= h * h / (8.0 * r) + 1e-5, "a vertex {worst} off the sphere (h {h})");
        assert_closed(&mesh);
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let [a, b, d] = tri.map(|i| mesh.vertices[i as usize]);
            let n = (b - a).cross(d - a);
            let out = (a + b + d) / 3.0 - c;
            assert!(n.dot(out) > 0.0, "triangle {t} faces inwards");
        }
        // The enclosed volume (divergence theorem) is the sphere's within the grid's resolution.
        let volume: f32 = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, d] = t.map(|i| mesh.vertices[i as usize] - c);
                a.dot(b.cross(d)) / 6.0
            })
            .sum();
        let want = 4.0 / 3.0 * std::f32::consts::PI * r * r * r;
        assert!((volume - want).abs() < 0.02 * want, "volume {volume}, sphere {want}");
    }

    #[test]
    fn ambiguous_faces_leave_no_holes() {
        // A field of alternating blobs makes many faces with two opposite corners inside.
        let field = Field::from_fn([18, 18, 18], Vec3::ZERO, Vec3::splat(17.0), |p| {
            (p.x * 2.3).sin() * (p.y * 2.1).sin() * (p.z * 1.9).sin() + 0.05 * (p.x + p.y).cos()
        });
        let mesh = marching_cubes(&field, 0.0);
        assert!(mesh.triangles.len() > 1000);
        // The surface may leave the box (an open boundary there): check closedness inside it by
        // padding the field with outside values.
        let [nx, ny, nz] = field.dims;
        let padded = Field::from_fn([nx + 2, ny + 2, nz + 2], Vec3::splat(-1.0), Vec3::splat(18.0), |p| {
            let q = p.round();
            if q.min_element() < 0.0 || q.max_element() > 17.0 {
                -1.0
            } else {
                field.at(q.x as usize, q.y as usize, q.z as usize)
            }
        });
        assert_closed(&marching_cubes(&padded, 0.0));
    }

    #[test]
    fn ply_files_have_the_header_and_sizes_they_declare() {
        let mesh = Mesh {
            vertices: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            normals: vec![Vec3::Z; 3],
            colors: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255]],
            triangles: vec![[0, 1, 2]],
        };
        let dir = std::env::temp_dir().join(format!("mipnerf-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.ply");
        write_mesh_ply(&path, &mesh).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(bytes.len() - end, 3 * 27 + 13);
        write_points_ply(&path, &mesh.vertices, &mesh.colors).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(bytes.len() - end, 3 * 15);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
