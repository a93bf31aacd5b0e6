// The positional encoding of view directions (mipnerf-core's `pos_enc` with the identity), one
// invocation per ray: out = [d (3) | sin(2^l d) (3 deg) | sin(2^l d + pi/2) (3 deg)].

// The uniform block `Params` is declared from the Rust struct `ViewEncParams` (kernels/view_enc.rs).

@group(0) @binding(0) var<uniform> p: Params;
// Three floats per ray.
@group(0) @binding(1) var<storage, read> viewdirs: array<f32>;
@group(0) @binding(2) var<storage, read_write> encoded: array<f32>;

const HALF_PI: f32 = 1.5707964;
// 2 pi = TWO_PI_1 + TWO_PI_2 + TWO_PI_3 (to 48 bits), the first two with 12 significant bits, so
// that the reduction to [-pi, pi] (where WGSL bounds `sin`'s error) needs no fused multiply-add.
const TWO_PI_1: f32 = 6.28125;
const TWO_PI_2: f32 = 0.0019350051879882812;
const TWO_PI_3: f32 = 3.0199160e-7;

fn sin_reduced(x: f32) -> f32 {
    let k = round(x * (1.0 / 6.2831855));
    return sin(((x - k * TWO_PI_1) - k * TWO_PI_2) - k * TWO_PI_3);
}

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (r >= p.n_rays) {
        return;
    }
    let len = 3u + 6u * p.deg_view;
    let half = 3u * p.deg_view;
    let out = r * len;
    for (var k = 0u; k < 3u; k = k + 1u) {
        encoded[out + k] = viewdirs[3u * r + k];
    }
    for (var l = 0u; l < p.deg_view; l = l + 1u) {
        let scale = f32(1u << l);
        for (var k = 0u; k < 3u; k = k + 1u) {
            let y = viewdirs[3u * r + k] * scale;
            encoded[out + 3u + l * 3u + k] = sin_reduced(y);
            encoded[out + 3u + half + l * 3u + k] = sin_reduced(y + HALF_PI);
        }
    }
}
