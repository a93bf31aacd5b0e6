// An occupancy grid's update on the device (mipnerf-core's `OccupancyGrid::update`, operation by
// operation; the cells' probes and opacities are `occupancy_cells.wgsl`'s), in chunks of cells
// that the model's own kernels run through the field between the two entry points (where the
// field and its MLP have no fused kernel, `occupancy_probe.wgsl`):
// - `place_probes`: one invocation per cell of the chunk: the cell's density probe, as a vec4
//   (mean, variance) in the grid's space. The model's encoders read it in their probe mode
//   (`cast_ipe.wgsl`, `tri_mip.wgsl`), the MLP gives its raw density.
// - `update_opacity`: one invocation per cell of the chunk: its opacity kept from the probe's
//   raw density. Which cells are occupied follows on the device (`occupancy_refresh.wgsl`).

// The uniform block `Params` is declared from the Rust struct `OccupancyUpdateParams` (kernels/occupancy_update.rs).

@group(0) @binding(0) var<uniform> params: Params;
// One vec4 per cell of the chunk: (mean.xyz, variance).
@group(0) @binding(1) var<storage, read_write> probes: array<vec4<f32>>;
// The MLP's raw density of each probe, `raw_stride` floats apart.
@group(0) @binding(2) var<storage, read> raw_density: array<f32>;
// Per cell of the grid: its remembered opacity, or -1 (carved).
@group(0) @binding(3) var<storage, read_write> opacity: array<f32>;

fn chunk_index(gid: vec3<u32>) -> u32 {
    return gid.y * (params.groups_x * WORKGROUP) + gid.x;
}

@compute @workgroup_size(WORKGROUP)
fn place_probes(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = chunk_index(gid);
    if (idx >= params.n_cells) {
        return;
    }
    probes[idx] = cell_probe(params.first_cell + idx);
}

@compute @workgroup_size(WORKGROUP)
fn update_opacity(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = chunk_index(gid);
    if (idx >= params.n_cells) {
        return;
    }
    keep_opacity(params.first_cell + idx, raw_density[idx * params.raw_stride]);
}
