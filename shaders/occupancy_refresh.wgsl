// Which cells of an occupancy grid are occupied, from its opacities, on the device
// (mipnerf-core's `OccupancyGrid::refresh`, operation by operation), into the bit layers the
// sampler walks (`occupancy.wgsl`; `OccupancyGrid::packed_layers`: layer 0 the occupied cells,
// layer k those within k cells of one, cell i of layer k at bit k * n_cells + i). The layers are
// cleared before `occupied` runs.
// - `candidate_mean`: one workgroup: the mean opacity of the candidate (not carved) cells, each
//   invocation summing a stride of cells, then a tree over the workgroup (a fixed order).
// - `occupied`: one invocation per cell: occupied when not carved and, after the warm-up, above
//   min(threshold, mean); layer 0's bit set.
// - `dilate`: one invocation per cell: layer `layer`'s bit set when a cell of the 3x3x3 block
//   around it (within the grid) is set in layer `layer - 1`.

struct Params {
    // Cells along each axis.
    resolution: u32,
    // resolution^3.
    n_cells: u32,
    // The layer `dilate` writes (1 to MAX_DILATION).
    layer: u32,
    // 1: the warm-up is over (cells are occupied by their opacity, not all).
    warmed_up: u32,
    // The grid's threshold (before its min with the mean).
    threshold: f32,
    // Workgroups along x of the 2-D dispatch grid.
    groups_x: u32,
    pad0: u32,
    pad1: u32,
}

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

@compute @workgroup_size(WORKGROUP)
fn dilate(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = cell_index(gid);
    if (i >= params.n_cells) {
        return;
    }
    let r = i32(params.resolution);
    let c = vec3<i32>(i32(i % params.resolution), i32((i / params.resolution) % params.resolution), i32(i / (params.resolution * params.resolution)));
    for (var dz = -1; dz <= 1; dz = dz + 1) {
        for (var dy = -1; dy <= 1; dy = dy + 1) {
            for (var dx = -1; dx <= 1; dx = dx + 1) {
                let n = c + vec3<i32>(dx, dy, dz);
                if (all(n >= vec3<i32>(0)) && all(n < vec3<i32>(r))) {
                    if (bit(params.layer - 1u, u32(n.x + r * (n.y + r * n.z)))) {
                        set_bit(params.layer, i);
                        return;
                    }
                }
            }
        }
    }
}
