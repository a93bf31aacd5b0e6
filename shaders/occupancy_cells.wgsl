// An occupancy grid's cells as its update sees them (mipnerf-core's `OccupancyGrid::update`,
// operation by operation): a cell's density probe and how a probe's density is kept as the
// cell's opacity. Included by `occupancy_update.wgsl` and `occupancy_probe.wgsl`, which both
// declare `params` of the block `OccupancyUpdateParams` and bind `opacity` (per cell of the grid,
// its remembered opacity, or -1: carved).

const CARVED: f32 = -1.0;
const CONTRACTED_BOUND: f32 = 2.0;

// `OccupancyGrid::cell_center`.
fn cell_center(i: u32) -> vec3<f32> {
    let r = params.resolution;
    let cell = vec3<f32>(f32(i % r), f32((i / r) % r), f32(i / (r * r)));
    let h = params.cell_size;
    let b = params.bound;
    return vec3<f32>(-b) + (cell + vec3<f32>(0.5)) * h;
}

// Cell `i`'s density probe: a random point of the cell (its `Stream::OccupancyUpdate` stream,
// uniforms 0, 1 and 2) with the cell's variance `h^2 / 12` on each axis, (mean, variance) in the
// grid's space.
fn cell_probe(i: u32) -> vec4<f32> {
    let key = stream_key(params.seed, params.step, STREAM_OCCUPANCY_UPDATE, i);
    let jitter = vec3<f32>(uniform01(key, 0u), uniform01(key, 1u), uniform01(key, 2u)) - vec3<f32>(0.5);
    let h = params.cell_size;
    return vec4<f32>(cell_center(i) + jitter * h, h * h / 12.0);
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

// Cell `i`'s opacity kept from its probe's raw density: the density (the model's activation),
// the opacity of one cell length `1 - exp(-sigma h stretch)` (a non-finite one counts as 1), kept
// as `max(decay old, new)`; a carved cell is left as it is.
fn keep_opacity(i: u32, raw: f32) {
    let old = opacity[i];
    if (old == CARVED) {
        return;
    }
    let sigma = activated_density(raw, params.density_bias, params.density_activation);
    var alpha = 1.0 - exp(-max(sigma, 0.0) * params.cell_size * world_stretch(i));
    // Not finite (NaN, or an infinite density's): counts as opaque. Tested on the bits, which no
    // compiler may assume away.
    if ((bitcast<u32>(alpha) & 0x7f800000u) == 0x7f800000u) {
        alpha = 1.0;
    }
    opacity[i] = max(old * params.decay, alpha);
}
