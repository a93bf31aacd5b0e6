// The positional encoding of view directions (`view_encoding.wgsl`: mipnerf-core's `pos_enc` with
// the identity), one invocation per ray: out = [d (3) | sin(2^l d) (3 deg) | sin(2^l d + pi/2)
// (3 deg)].

// The uniform block `Params` is declared from the Rust struct `ViewEncParams` (kernels/view_enc.rs).

@group(0) @binding(0) var<uniform> p: Params;
// Three floats per ray.
@group(0) @binding(1) var<storage, read> viewdirs: array<f32>;
@group(0) @binding(2) var<storage, read_write> encoded: array<f32>;

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (r >= p.n_rays) {
        return;
    }
    let len = 3u + 6u * p.deg_view;
    let d = vec3<f32>(viewdirs[3u * r], viewdirs[3u * r + 1u], viewdirs[3u * r + 2u]);
    for (var k = 0u; k < len; k = k + 1u) {
        encoded[r * len + k] = view_encoding(d, p.deg_view, k);
    }
}
