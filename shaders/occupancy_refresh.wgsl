// Which cells of an occupancy grid are occupied, from its opacities, on the device
// (mipnerf-core's `OccupancyGrid::refresh`, operation by operation), into the bit layers the
// sampler walks (`occupancy.wgsl`; `OccupancyGrid::packed_layers`: layer 0 the occupied cells,
// layer k those within k cells of one, cell i of layer k at bit k * n_cells + i). The layers are
// cleared before `occupied` runs.
// - `candidate_mean`: one workgroup: the mean opacity of the candidate (not carved) cells, each
//   invocation summing a stride of cells, then a tree over the workgroup (a fixed order).
// - `occupied`: one invocation per cell: occupied when not carved and, after the warm-up, above
//   min(threshold, mean); layer 0's bit set.
// - `dilate`: one invocation per cell: every layer k in 1..=MAX_DILATION at once, each the
//   layer before it dilated by the 3x3x3 block (within the grid), which is the cells within
//   Chebyshev distance k of an occupied one: the invocation finds its distance to the nearest
//   bit of layer 0 within MAX_DILATION cells, reading the rows of the (2 MAX_DILATION + 1)^2
//   block around it a word or two at a time, and sets layers distance..=MAX_DILATION. Layer 0
//   is only read, so one dispatch makes them all.

// The uniform block `Params` is declared from the Rust struct `RefreshParams` (kernels/occupancy_update.rs).

@group(0) @binding(0) var<uniform> params: Params;
// Per cell: its remembered opacity, or -1 (carved).
@group(0) @binding(1) var<storage, read> opacity: array<f32>;
// The bit layers, one bit a cell, layer after layer.
@group(0) @binding(2) var<storage, read_write> layers: array<atomic<u32>>;
// [0]: the candidates' mean opacity (`candidate_mean` writes it, `occupied` reads it).
@group(0) @binding(3) var<storage, read_write> mean: array<f32>;

const CARVED: f32 = -1.0;

var<workgroup> partial_sum: array<f32, REDUCE_WORKGROUP>;
var<workgroup> partial_count: array<u32, REDUCE_WORKGROUP>;

fn cell_index(gid: vec3<u32>) -> u32 {
    return gid.y * (params.groups_x * WORKGROUP) + gid.x;
}

@compute @workgroup_size(REDUCE_WORKGROUP)
fn candidate_mean(@builtin(local_invocation_id) lid: vec3<u32>) {
    var sum = 0.0;
    var count = 0u;
    for (var i = lid.x; i < params.n_cells; i = i + REDUCE_WORKGROUP) {
        let v = opacity[i];
        if (v != CARVED) {
            sum = sum + v;
            count = count + 1u;
        }
    }
    partial_sum[lid.x] = sum;
    partial_count[lid.x] = count;
    workgroupBarrier();
    for (var half = REDUCE_WORKGROUP / 2u; half > 0u; half = half / 2u) {
        if (lid.x < half) {
            partial_sum[lid.x] = partial_sum[lid.x] + partial_sum[lid.x + half];
            partial_count[lid.x] = partial_count[lid.x] + partial_count[lid.x + half];
        }
        workgroupBarrier();
    }
    if (lid.x == 0u) {
        let n = partial_count[0];
        mean[0] = select(0.0, partial_sum[0] / f32(n), n > 0u);
    }
}

fn set_bit(layer: u32, i: u32) {
    let j = layer * params.n_cells + i;
    atomicOr(&layers[j / 32u], 1u << (j % 32u));
}

fn bit(layer: u32, i: u32) -> bool {
    let j = layer * params.n_cells + i;
    return (atomicLoad(&layers[j / 32u]) & (1u << (j % 32u))) != 0u;
}

@compute @workgroup_size(WORKGROUP)
fn occupied(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = cell_index(gid);
    if (i >= params.n_cells) {
        return;
    }
    let v = opacity[i];
    let threshold = min(params.threshold, mean[0]);
    if (v != CARVED && (params.warmed_up == 0u || v > threshold)) {
        set_bit(0u, i);
    }
}

// Bits x - MAX_DILATION ..= x + MAX_DILATION of layer 0's row that starts at cell `row` (the
// cells outside the grid left 0), as bits 0 ..= 2 MAX_DILATION of the result.
fn row_window(row: u32, x: i32) -> u32 {
    let r = i32(params.resolution);
    let d = i32(MAX_DILATION);
    let lo = max(x - d, 0);
    let hi = min(x + d, r - 1);
    let j = row + u32(lo);
    let n = u32(hi - lo + 1);
    let off = j % 32u;
    var bits = atomicLoad(&layers[j / 32u]) >> off;
    if (off + n > 32u) {
        bits = bits | (atomicLoad(&layers[j / 32u + 1u]) << (32u - off));
    }
    bits = bits & ((1u << n) - 1u);
    return bits << u32(lo - (x - d));
}

@compute @workgroup_size(WORKGROUP)
fn dilate(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = cell_index(gid);
    if (i >= params.n_cells) {
        return;
    }
    let r = i32(params.resolution);
    let d = i32(MAX_DILATION);
    let c = vec3<i32>(i32(i % params.resolution), i32((i / params.resolution) % params.resolution), i32(i / (params.resolution * params.resolution)));
    // The Chebyshev distance to the nearest occupied cell, MAX_DILATION + 1 when none is within
    // MAX_DILATION.
    var nearest = d + 1;
    for (var dz = -d; dz <= d; dz = dz + 1) {
        for (var dy = -d; dy <= d; dy = dy + 1) {
            let y = c.y + dy;
            let z = c.z + dz;
            let across = max(abs(dy), abs(dz));
            if (y < 0 || y >= r || z < 0 || z >= r || across >= nearest) {
                continue;
            }
            let window = row_window(u32(r * (y + r * z)), c.x);
            // The nearest set bit along the row: the narrowest window around the centre.
            for (var k = 0; k <= d; k = k + 1) {
                let mask = ((1u << u32(2 * k + 1)) - 1u) << u32(d - k);
                if ((window & mask) != 0u) {
                    nearest = min(nearest, max(across, k));
                    break;
                }
            }
        }
    }
    for (var layer = max(nearest, 1); layer <= d; layer = layer + 1) {
        set_bit(u32(layer), i);
    }
}
