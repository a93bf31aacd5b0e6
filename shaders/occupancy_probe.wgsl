// An occupancy grid's update through the Tri-Mip field in one dispatch (mipnerf-core's
// `OccupancyGrid::update` with `Model::encode_probe`, operation by operation), where the field's
// MLP runs fused: one invocation per cell of the chunk reads the cell's density probe
// (`occupancy_cells.wgsl`) from the planes at its footprint (`plane_taps.wgsl`), runs the MLP's
// trunk and density head on it (`mlp_trunk.wgsl`), and keeps the density as the cell's opacity:
// what `occupancy_update.wgsl`'s two entry points do around `tri_mip.wgsl`'s probe encoding and
// `fused_mlp.wgsl`'s forward pass, the same operations without the buffers between them.

// The uniform block `Params` is declared from the Rust struct `OccupancyUpdateParams` (kernels/occupancy_update.rs).

@group(0) @binding(0) var<uniform> params: Params;
// Per cell of the grid: its remembered opacity, or -1 (carved).
@group(0) @binding(1) var<storage, read_write> opacity: array<f32>;
// The planes: level 0 (the model's first parameters), then levels 1.. (`tri_mip.wgsl`'s).
@group(0) @binding(2) var<storage, read> model_params: array<f32>;
@group(0) @binding(3) var<storage, read> pyramid: array<f32>;
// The MLP's layers' offsets in `trunk_weights` (`fused_mlp.wgsl`'s table).
@group(0) @binding(4) var<storage, read> table: array<u32>;
@group(0) @binding(5) var<uniform> trunk_weights: array<vec4<f32>, MLP_UNIFORM_VEC4S>;

@compute @workgroup_size(WORKGROUP)
fn probe_opacity(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = gid.y * (params.groups_x * WORKGROUP) + gid.x;
    if (idx >= params.n_cells) {
        return;
    }
    let i = params.first_cell + idx;
    if (opacity[i] == CARVED) {
        return;
    }
    let g = cell_probe(i);
    let planes = Planes(params.plane_resolution, params.plane_features, params.plane_levels);
    let radius = probe_footprint(g.w, params.half_side);
    let at = plane_point(planes, params.half_side, params.pre_filtered != 0u, g.xyz, radius);
    // The encoding: each plane's features in turn (`encode_planes`' layout).
    var a: Activations;
    var taps: array<Tap, TAPS_PER_PLANE>;
    for (var plane = 0u; plane < 3u; plane = plane + 1u) {
        for (var k = 0u; k < TAPS_PER_PLANE; k = k + 1u) {
            taps[k] = plane_tap(planes, plane, at.xyz, at.w, k);
        }
        for (var f = 0u; f < planes.features; f = f + 1u) {
            a[plane * planes.features + f] = plane_feature(&taps, f);
        }
    }
    var fan_in = params.x_dim;
    for (var layer = 0u; layer < params.net_depth; layer = layer + 1u) {
        a = trunk_layer(layer, fan_in, params.net_width, &a);
        fan_in = params.net_width;
    }
    keep_opacity(i, density_head(params.net_depth, params.net_width, &a));
}
