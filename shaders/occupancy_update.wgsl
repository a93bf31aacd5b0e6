// An occupancy grid's update on the device (mipnerf-core's `OccupancyGrid::update`, operation by
// operation), in chunks of cells that the model's own kernels run through the field between the
// two entry points:
// - `place_probes`: one invocation per cell of the chunk: the cell's density probe, a random point
//   of the cell (the cell's `Stream::OccupancyUpdate` stream, uniforms 0, 1 and 2) with the cell's
//   variance `h^2 / 12` on each axis, as a vec4 (mean, variance) in the grid's space. The model's
//   encoders read it in their probe mode (`cast_ipe.wgsl`, `tri_mip.wgsl`), the MLP gives its
//   raw density.
// - `update_opacity`: one invocation per cell of the chunk: the density (the model's activation),
//   the opacity of one cell length `1 - exp(-sigma h stretch)` (a non-finite one counts as 1), kept
//   as `max(decay old, new)`; a carved cell (opacity -1) is left as it is. Which cells are occupied
//   follows on the host from the opacities read back (`OccupancyGrid::update_with_opacity`).

// The uniform block `Params` is declared from the Rust struct `OccupancyUpdateParams` (kernels/occupancy_update.rs).

@group(0) @binding(0) var<uniform> params: Params;
// One vec4 per cell of the chunk: (mean.xyz, variance).
@group(0) @binding(1) var<storage, read_write> probes: array<vec4<f32>>;
// The MLP's raw density of each probe, `raw_stride` floats apart.
@group(0) @binding(2) var<storage, read> raw_density: array<f32>;
// Per cell of the grid: its remembered opacity, or -1 (carved).
@group(0) @binding(3) var<storage, read_write> opacity: array<f32>;

const CARVED: f32 = -1.0;
const CONTRACTED_BOUND: f32 = 2.0;

fn chunk_index(gid: vec3<u32>) -> u32 {
    return gid.y * (params.groups_x * WORKGROUP) + gid.x;
}

// `OccupancyGrid::cell_center`.
fn cell_center(i: u32) -> vec3<f32> {
    let r = params.resolution;
    let cell = vec3<f32>(f32(i % r), f32((i / r) % r), f32(i / (r * r)));
    let h = params.cell_size;
    let b = params.bound;
    return vec3<f32>(-b) + (cell + vec3<f32>(0.5)) * h;
}

@compute @workgroup_size(WORKGROUP)
fn place_probes(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = chunk_index(gid);
    if (idx >= params.n_cells) {
        return;
    }
    let i = params.first_cell + idx;
    let key = stream_key(params.seed, params.step, STREAM_OCCUPANCY_UPDATE, i);
    let jitter = vec3<f32>(uniform01(key, 0u), uniform01(key, 1u), uniform01(key, 2u)) - vec3<f32>(0.5);
    let h = params.cell_size;
    probes[idx] = vec4<f32>(cell_center(i) + jitter * h, h * h / 12.0);
}

// `OccupancyGrid::world_stretch`: the contraction's radial stretch at a contracted cell's centre
// outside the unit ball, else 1.
fn world_stretch(i: u32) -> f32 {
    let c = cell_center(i);
    let rho = sqrt(c.x * c.x + c.y * c.y + c.z * c.z);
    if (params.contracted == 0u || rho <= 1.0) {
        return 1.0;
    }
    let r = 1.0 / max(CONTRACTED_BOUND - rho, 1e-6);
    return r * r;
}

@compute @workgroup_size(WORKGROUP)
fn update_opacity(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = chunk_index(gid);
    if (idx >= params.n_cells) {
        return;
    }
    let i = params.first_cell + idx;
    let old = opacity[i];
    if (old == CARVED) {
        return;
    }
    let sigma = activated_density(raw_density[idx * params.raw_stride], params.density_bias, params.density_activation);
    var alpha = 1.0 - exp(-max(sigma, 0.0) * params.cell_size * world_stretch(i));
    // Not finite (NaN, or an infinite density's): counts as opaque. Tested on the bits, which no
    // compiler may assume away.
    if ((bitcast<u32>(alpha) & 0x7f800000u) == 0x7f800000u) {
        alpha = 1.0;
    }
    opacity[i] = max(old * params.decay, alpha);
}
