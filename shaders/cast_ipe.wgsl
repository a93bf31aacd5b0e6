// Rays to conical-frustum (or cylinder) Gaussians to integrated positional encoding (IPE).
//
// One invocation per (ray, sample). The maths mirrors mipnerf-core's `mip.rs` operation by
// operation: `conical_frustum_moments` (stable form, `frustum.wgsl`), `lift_gaussian` (diagonal), then
// `integrated_pos_enc` with the official 100*pi argument guard. Sine arguments are further
// reduced to [-pi, pi] with a three-part 2*pi (Cody-Waite), because WGSL only bounds `sin`'s error
// there (2^-11 absolute). Neither reduction relies on a fused multiply-add: the leading parts of
// the constants have few enough bits that their products with the quotient are exact.
//
// Unbounded scenes (`unbounded` 1) carry each Gaussian through mip-NeRF 360's contraction, as
// mipnerf-core's `contract::contract_frustum`: unchanged inside the unit ball; outside it the mean
// is contracted and the covariance is the diagonal of J Sigma J^T for the frustum's full
// covariance, t_var u^2 + r_var |J_i x d|^2 / |d|^2 with u = J d, J the contraction's Jacobian at
// the mean (formed as `contract_jacobian` forms it).
//
// In probe mode (`probes` 1) the Gaussians are given, one vec4 a sample in `rays`: an occupancy
// grid's density probes (`occupancy_update.wgsl`), already in the encoding's space.
//
// Output layout, per sample: [sin part | cos part], index (deg - min_deg) * 3 + axis inside a part,
// samples of a ray contiguous: out[(ray * n_samples + sample) * ipe_len + feature]. NeRF's
// encoding (`encoding` 2) puts the mean's 3 coordinates first.

// The uniform block `Params` is declared from the Rust struct `CastIpeParams` (kernels/cast_ipe.rs).

@group(0) @binding(0) var<uniform> params: Params;
// Two vec4 per ray: (origin.xyz, radius), (direction.xyz, unused).
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
// n_samples + 1 interval edges per ray.
@group(0) @binding(2) var<storage, read> t_vals: array<f32>;
@group(0) @binding(3) var<storage, read_write> encoded: array<f32>;

const SAFE_TRIG_LIMIT: f32 = 314.15927;
// SAFE_TRIG_LIMIT = LIMIT_HI + LIMIT_LO exactly, LIMIT_HI with 12 significant bits.
const LIMIT_HI: f32 = 314.125;
const LIMIT_LO: f32 = 0.034271240234375;
const HALF_PI: f32 = 1.5707964;
// 2 pi = TWO_PI_1 + TWO_PI_2 + TWO_PI_3 (to 48 bits), the first two with 12 significant bits.
const TWO_PI_1: f32 = 6.28125;
const TWO_PI_2: f32 = 0.0019350051879882812;
const TWO_PI_3: f32 = 3.0199160e-7;

// The official guard: reduce |x| >= 100 pi modulo 100 pi (Python-style, into [0, 100 pi)).
fn safe_trig_arg(x: f32) -> f32 {
    if (abs(x) < SAFE_TRIG_LIMIT) {
        return x;
    }
    // x - q * LIMIT, exactly for |q| < 2^12 (|x| < 1.2e6): both products are exact, the first
    // difference is exact (Sterbenz), and the true remainder is representable.
    let q = trunc(x / SAFE_TRIG_LIMIT);
    var r = (x - q * LIMIT_HI) - q * LIMIT_LO;
    if (r < 0.0) {
        r = r + SAFE_TRIG_LIMIT;
    }
    if (r >= SAFE_TRIG_LIMIT) {
        r = r - SAFE_TRIG_LIMIT;
    }
    return r;
}

// sin(x) for |x| < 2^12 * 2 pi, with a precise reduction to [-pi, pi] first: k * TWO_PI_1 and
// k * TWO_PI_2 are exact, and so is x - k * TWO_PI_1 (Sterbenz).
fn sin_reduced(x: f32) -> f32 {
    let k = round(x * (1.0 / 6.2831855));
    let r = ((x - k * TWO_PI_1) - k * TWO_PI_2) - k * TWO_PI_3;
    return sin(r);
}

fn safe_sin(x: f32) -> f32 {
    return sin_reduced(safe_trig_arg(x));
}

// The scene contraction's Jacobian at x, |x| > 1 (mipnerf-core's `contract_jacobian`): scale
// a = (2 - 1/r)/r across x, c = 1/r^2 along it; the diagonal as (a (r^2 - x_i^2) + c x_i^2)/r^2.
fn contract_jacobian(x: vec3<f32>) -> mat3x3<f32> {
    let x2 = x * x;
    let r2 = x2.x + x2.y + x2.z;
    let r = sqrt(r2);
    let a = (2.0 - 1.0 / r) / r;
    let c = 1.0 / r2;
    let others = vec3<f32>(x2.y + x2.z, x2.x + x2.z, x2.x + x2.y);
    let diag = (others * a + x2 * c) / r2;
    let off = -2.0 * (r - 1.0) / (r2 * r2);
    let xy = off * x.x * x.y;
    let xz = off * x.x * x.z;
    let yz = off * x.y * x.z;
    return mat3x3<f32>(vec3<f32>(diag.x, xy, xz), vec3<f32>(xy, diag.y, yz), vec3<f32>(xz, yz, diag.z));
}

struct Gaussian {
    mean: vec3<f32>,
    cov: vec3<f32>,
}

// Sample `idx`'s Gaussian: its frustum's, through the contraction in an unbounded scene.
fn frustum_gaussian(idx: u32) -> Gaussian {
    let ray = idx / params.n_samples;
    let s = idx % params.n_samples;
    let o_r = rays[2u * ray];
    let d = rays[2u * ray + 1u].xyz;
    let radius = o_r.w;
    let base_t = ray * (params.n_samples + 1u) + s;
    let t0 = t_vals[base_t];
    let t1 = t_vals[base_t + 1u];

    let moments = frustum_moments(t0, t1, radius, params.ray_shape);
    let t_mean = moments.x;
    let t_var = moments.y;
    let r_var = moments.z;
    let d2 = d * d;
    let d_mag_sq = max(d2.x + d2.y + d2.z, 1e-10);
    var mean = o_r.xyz + d * t_mean;
    var cov = t_var * d2 + r_var * (vec3<f32>(1.0) - d2 / d_mag_sq);
    let r2 = dot(mean, mean);
    if (params.unbounded != 0u && r2 > 1.0) {
        // J is symmetric: its columns are its rows.
        let j = contract_jacobian(mean);
        let u = j * d;
        let inv_d_mag_sq = 1.0 / d_mag_sq;
        let c0 = cross(j[0], d);
        let c1 = cross(j[1], d);
        let c2 = cross(j[2], d);
        let across = vec3<f32>(dot(c0, c0), dot(c1, c1), dot(c2, c2)) * inv_d_mag_sq;
        cov = u * u * t_var + across * r_var;
        let r = sqrt(r2);
        mean = mean * ((2.0 - 1.0 / r) / r);
    }
    return Gaussian(mean, cov);
}

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = gid.y * (params.groups_x * WORKGROUP) + gid.x;
    if (idx >= params.n_rays * params.n_samples) {
        return;
    }
    var g: Gaussian;
    if (params.probes != 0u) {
        let probe = rays[idx];
        g = Gaussian(probe.xyz, vec3<f32>(probe.w));
    } else {
        g = frustum_gaussian(idx);
    }
    let mean = g.mean;
    var cov = g.cov;
    if (params.encoding != ENCODING_INTEGRATED) {
        cov = vec3<f32>(0.0);
    }

    let n_deg = params.max_deg - params.min_deg;
    let half = 3u * n_deg;
    if (params.encoding == ENCODING_NERF) {
        let base = idx * (6u * n_deg + 3u);
        encoded[base] = mean.x;
        encoded[base + 1u] = mean.y;
        encoded[base + 2u] = mean.z;
        for (var i = 0u; i < n_deg; i = i + 1u) {
            let y = mean * f32(1u << (params.min_deg + i));
            for (var k = 0u; k < 3u; k = k + 1u) {
                encoded[base + 3u + i * 3u + k] = sin_reduced(y[k]);
                encoded[base + 3u + half + i * 3u + k] = sin_reduced(y[k] + HALF_PI);
            }
        }
        return;
    }
    let ipe_len = 6u * n_deg;
    let out_base = idx * ipe_len;
    for (var i = 0u; i < n_deg; i = i + 1u) {
        let scale = f32(1u << (params.min_deg + i));
        let y = mean * scale;
        let damp = exp(-0.5 * (cov * (scale * scale)));
        for (var k = 0u; k < 3u; k = k + 1u) {
            encoded[out_base + i * 3u + k] = damp[k] * safe_sin(y[k]);
            encoded[out_base + half + i * 3u + k] = damp[k] * safe_sin(y[k] + HALF_PI);
        }
    }
}
