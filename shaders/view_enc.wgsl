// The positional encoding of view directions (mipnerf-core's `pos_enc` with the identity), one
// invocation per ray: out = [d (3) | sin(2^l d) (3 deg) | sin(2^l d + pi/2) (3 deg)].

struct Params {
    n_rays: u32,
    // Degrees 0..deg_view.
    deg_view: u32,
    groups_x: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
// Three floats per ray.
@group(0) @binding(1) var<storage, read> viewdirs: array<f32>;
@group(0) @binding(2) var<storage, read_write> encoded: array<f32>;

const HALF_PI: f32 = 1.5707964;
const TWO_PI_HI: f32 = 6.2831855;
const TWO_PI_LO: f32 = -1.7484555e-7;

fn sin_reduced(x: f32) -> f32 {
    let k = round(x * (1.0 / 6.2831855));
    return sin(fma(-k, TWO_PI_LO, fma(-k, TWO_PI_HI, x)));
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
