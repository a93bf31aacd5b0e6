// One level's per-ray outputs put back in batch order after `gather.wgsl`'s compaction, one
// invocation per batch ray (mipnerf-core's guided rendering and loss): a kept ray's outputs are
// its compacted ray's; a ray that meets no occupied cell renders the background without running
// the MLP: its colour, distance near, opacity 0, and its loss terms against its target.

// The uniform block `Params` is declared from the Rust struct `ExpandParams` (kernels/compact.rs).

@group(0) @binding(0) var<uniform> p: Params;
// Per batch ray: the index of its kept ray, or 0xffffffff when it meets no occupied cell.
@group(0) @binding(1) var<storage, read> slot: array<u32>;
// The whole batch: two vec4 per ray (origin, radius), (direction, lossmult); (near, far); vec4
// target.
@group(0) @binding(2) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> bounds: array<f32>;
@group(0) @binding(4) var<storage, read> targets: array<vec4<f32>>;
// The kept rays' outputs and the batch's, two vec4 per ray: (rgb, distance),
// (acc, lossmult * squared error, squared error, 0), as `render.wgsl` writes them.
@group(0) @binding(5) var<storage, read> kept_out: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out: array<vec4<f32>>;

@compute @workgroup_size(WORKGROUP)
fn expand(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (i >= p.n_rays) {
        return;
    }
    let j = slot[i];
    if (j != 0xffffffffu) {
        out[2u * i] = kept_out[2u * j];
        out[2u * i + 1u] = kept_out[2u * j + 1u];
        return;
    }
    var bg = vec3<f32>(select(0.0, 1.0, p.background == BACKGROUND_WHITE));
    if (p.background == BACKGROUND_RANDOM) {
        bg = random_background(p.seed, p.step, i);
    }
    let lossmult = select(1.0, rays[2u * i + 1u].w, p.area_loss != 0u);
    let err = bg - targets[i].xyz;
    let se = dot(err, err);
    out[2u * i] = vec4<f32>(bg, bounds[2u * i]);
    out[2u * i + 1u] = vec4<f32>(0.0, lossmult * se, se, 0.0);
}
