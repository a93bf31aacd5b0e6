// The positional encoding of a view direction (mipnerf-core's `pos_enc` with the identity):
// [d (3) | sin(2^l d) (3 deg) | sin(2^l d + pi/2) (3 deg)], one value at a time. Composed in
// front of the kernels that read it (`view_enc.wgsl`, which writes it a ray at a time, and
// `fused_mlp.wgsl`, which reads it from the ray's direction where its first colour layer needs it).

const VIEW_HALF_PI: f32 = 1.5707964;
// 2 pi = VIEW_TWO_PI_1 + VIEW_TWO_PI_2 + VIEW_TWO_PI_3 (to 48 bits), the first two with 12
// significant bits, so that the reduction to [-pi, pi] (where WGSL bounds `sin`'s error) needs no
// fused multiply-add.
const VIEW_TWO_PI_1: f32 = 6.28125;
const VIEW_TWO_PI_2: f32 = 0.0019350051879882812;
const VIEW_TWO_PI_3: f32 = 3.0199160e-7;

fn view_sin_reduced(x: f32) -> f32 {
    let k = round(x * (1.0 / 6.2831855));
    return sin(((x - k * VIEW_TWO_PI_1) - k * VIEW_TWO_PI_2) - k * VIEW_TWO_PI_3);
}

// Value `k` (0 .. 3 + 6 deg_view) of the encoding of `d` with degrees 0..deg_view.
fn view_encoding(d: vec3<f32>, deg_view: u32, k: u32) -> f32 {
    if (k < 3u) {
        return d[k];
    }
    let half = 3u * deg_view;
    let j = (k - 3u) % half;
    let y = d[j % 3u] * f32(1u << (j / 3u));
    if (k < 3u + half) {
        return view_sin_reduced(y);
    }
    return view_sin_reduced(y + VIEW_HALF_PI);
}
