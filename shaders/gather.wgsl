// Compaction of a batch to the rays an occupancy grid lets through (mipnerf-core's guided
// `Model::loss_and_grad` with a grid and `render_guided`, which run the MLP on those rays only), one
// invocation per kept ray: kept ray j is batch ray `kept[j]` (the host's ascending list); its
// ray, bounds, view direction, target and batch index (the key of its random streams) are
// copied. `expand.wgsl` puts the outputs back in batch order.

// The uniform block `Params` is declared from the Rust struct `GatherParams` (kernels/compact.rs).

@group(0) @binding(0) var<uniform> p: Params;
// The batch indices of the kept rays, ascending.
@group(0) @binding(1) var<storage, read> kept: array<u32>;
// The whole batch: two vec4 per ray (origin, radius), (direction, lossmult); (near, far);
// 3 floats of view direction; vec4 target.
@group(0) @binding(2) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> bounds: array<f32>;
@group(0) @binding(4) var<storage, read> viewdirs: array<f32>;
@group(0) @binding(5) var<storage, read> targets: array<vec4<f32>>;
// The kept rays, in the same layouts, and their batch indices.
@group(0) @binding(6) var<storage, read_write> out_rays: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> out_bounds: array<f32>;
@group(0) @binding(8) var<storage, read_write> out_viewdirs: array<f32>;
@group(0) @binding(9) var<storage, read_write> out_targets: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> out_ids: array<u32>;

@compute @workgroup_size(WORKGROUP)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    let j = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (j >= p.n_kept) {
        return;
    }
    let i = kept[j];
    out_rays[2u * j] = rays[2u * i];
    out_rays[2u * j + 1u] = rays[2u * i + 1u];
    out_bounds[2u * j] = bounds[2u * i];
    out_bounds[2u * j + 1u] = bounds[2u * i + 1u];
    for (var c = 0u; c < 3u; c = c + 1u) {
        out_viewdirs[3u * j + c] = viewdirs[3u * i + c];
    }
    out_targets[j] = targets[i];
    out_ids[j] = i;
}
