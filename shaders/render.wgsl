// Output activations, volume rendering, the loss and its backward pass, one invocation per ray:
// mipnerf-core's `rgb_activation`/`DensityActivation`, `volumetric_rendering` and
// `volumetric_rendering_backward`, and the model's per-level loss gradient, fused in one pass.
//
// Per ray r with samples i (n = n_rays * n_samples):
//   rgb_i = sigmoid(raw_rgb_i) (1 + 2 pad) - pad;  density_i = act(raw_density_i + bias)
//   w_i = (1 - exp(-density_i delta_i)) exp(-sum_{j<i} density_j delta_j)
//   colour = sum w_i rgb_i + (1 - acc) background (white, black, or in training with random
//   backgrounds the ray's pixel's `random_background`)
// With `train` set, the loss level_weight * lossmult |colour - target|^2 / batch_norm[0] is differentiated
// (its gradient is mipnerf_core::model::pixel_loss_gradient, the formula's one statement):
// d_raw_rgb and d_raw_density are written for the MLP's backward pass.

// The uniform block `Params` is declared from the Rust struct `RenderParams` (kernels/render.rs).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> raw_rgb: array<f32>;
@group(0) @binding(2) var<storage, read> raw_density: array<f32>;
@group(0) @binding(3) var<storage, read> t_vals: array<f32>;
// Two vec4 per ray: (origin.xyz, radius), (direction.xyz, lossmult).
@group(0) @binding(4) var<storage, read> rays: array<vec4<f32>>;
// vec4 per ray: (r, g, b, unused).
@group(0) @binding(5) var<storage, read> targets: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> weights: array<f32>;
@group(0) @binding(7) var<storage, read_write> d_raw_rgb: array<f32>;
@group(0) @binding(8) var<storage, read_write> d_raw_density: array<f32>;
// Two vec4 per ray: (r, g, b, distance), (acc, lossmult * squared error, squared error, 0).
@group(0) @binding(9) var<storage, read_write> ray_out: array<vec4<f32>>;
// [0]: 3 * sum of lossmult over the batch (written on the device by batch.wgsl, or by the host).
@group(0) @binding(10) var<storage, read> batch_norm: array<f32>;
// The index of each ray in the step's batch (its random streams are drawn with it): 0.. for a
// whole batch, the chunk's or the compacted rays' own indices otherwise.
@group(0) @binding(11) var<storage, read> ray_ids: array<u32>;

fn sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}

fn density_of(raw: f32) -> f32 {
    return activated_density(raw, p.density_bias, p.density_activation);
}

fn density_derivative(raw: f32) -> f32 {
    let x = raw + p.density_bias;
    if (p.density_activation == DENSITY_SOFTPLUS) {
        return sigmoid(x);
    }
    return select(0.0, 1.0, x > 0.0);
}

// The key of ray r's density noise (`Stream::DensityNoise`, the ray's stream at this level).
fn density_noise_key(r: u32) -> u32 {
    return stream_key(p.seed, p.step, STREAM_DENSITY_NOISE, ray_level_index(ray_ids[r], p.level));
}

// Raw density of sample k (sample i of its ray), with the training noise when there is any.
fn raw_den(k: u32, key: u32, i: u32) -> f32 {
    if (p.density_noise > 0.0) {
        return raw_density[k * p.density_stride] + p.density_noise * normal(key, i);
    }
    return raw_density[k * p.density_stride];
}

// Sample k's colour before padding: the sigmoid of its raw colour.
fn sample_sigmoid(k: u32) -> vec3<f32> {
    return vec3<f32>(sigmoid(raw_rgb[3u * k]), sigmoid(raw_rgb[3u * k + 1u]), sigmoid(raw_rgb[3u * k + 2u]));
}

fn padded(sg: vec3<f32>) -> vec3<f32> {
    return sg * (1.0 + 2.0 * p.rgb_padding) - p.rgb_padding;
}

// The background colour behind ray r: mipnerf-core's `Model::ray_background`.
fn background(r: u32) -> vec3<f32> {
    if (p.background == BACKGROUND_RANDOM) {
        return random_background(p.seed, p.step, ray_ids[r] / (p.supersample * p.supersample));
    }
    return vec3<f32>(select(0.0, 1.0, p.background == BACKGROUND_WHITE));
}

// Sums over some of a ray's samples of w_i rgb_i, w_i and w_i t_mid_i.
struct RayPartial {
    colour: vec3<f32>,
    acc: f32,
    dist_num: f32,
}

// sum over samples i0..i1 of ray r of density_i delta_i.
fn density_delta_sum(r: u32, i0: u32, i1: u32) -> f32 {
    let tb = r * (p.n_samples + 1u);
    let dir_norm = length(rays[2u * r + 1u].xyz);
    let noise_key = density_noise_key(r);
    var sum = 0.0;
    for (var i = i0; i < i1; i = i + 1u) {
        let delta = (t_vals[tb + i + 1u] - t_vals[tb + i]) * dir_norm;
        sum = sum + density_of(raw_den(r * p.n_samples + i, noise_key, i)) * delta;
    }
    return sum;
}

// Volume rendering of samples i0..i1 of ray r, `cum` the sum of density x delta before i0:
// writes each sample's weight, keeps T_{i+1} in its density-gradient slot for the backward pass,
// and returns the samples' sums.
fn forward_samples(r: u32, i0: u32, i1: u32, cum0: f32) -> RayPartial {
    let base = r * p.n_samples;
    let tb = r * (p.n_samples + 1u);
    let dir_norm = length(rays[2u * r + 1u].xyz);
    let noise_key = density_noise_key(r);
    var cum = cum0;
    var out = RayPartial(vec3<f32>(0.0), 0.0, 0.0);
    for (var i = i0; i < i1; i = i + 1u) {
        let k = base + i;
        let t0 = t_vals[tb + i];
        let t1 = t_vals[tb + i + 1u];
        let delta = (t1 - t0) * dir_norm;
        let dd = density_of(raw_den(k, noise_key, i)) * delta;
        let alpha = 1.0 - exp(-dd);
        let trans = exp(-cum);
        cum = cum + dd;
        let w = alpha * trans;
        weights[k] = w;
        out.colour = out.colour + w * padded(sample_sigmoid(k));
        out.acc = out.acc + w;
        out.dist_num = out.dist_num + w * 0.5 * (t0 + t1);
        d_raw_density[k * p.density_stride] = exp(-cum);
    }
    return out;
}

// Ray r's outputs from the sums over all its samples: colour, distance, opacity and its loss
// terms into ray_out. Returns d loss / d colour (zero when supersampling, where `pixel_backward`
// takes the loss on the pixel).
fn finish_ray(r: u32, sums: RayPartial) -> vec3<f32> {
    let tb = r * (p.n_samples + 1u);
    let acc = min(sums.acc, 1.0);
    // A ray that hit nothing (acc = 0, so dist_num = 0) has the CPU's NaN distance, which it
    // then maps to 0 and clamps to near. WGSL promises no NaN semantics: guard the division.
    var dist = 0.0;
    if (acc > 0.0) {
        dist = sums.dist_num / acc;
    }
    dist = clamp(dist, t_vals[tb], t_vals[tb + p.n_samples]);
    let colour = sums.colour + background(r) * (1.0 - acc);
    ray_out[2u * r] = vec4<f32>(colour, dist);
    if (p.supersample > 1u) {
        ray_out[2u * r + 1u] = vec4<f32>(acc, 0.0, 0.0, 0.0);
        return vec3<f32>(0.0);
    }
    let lossmult = select(1.0, rays[2u * r + 1u].w, p.area_loss != 0u);
    let err = colour - targets[r].xyz;
    let se = dot(err, err);
    ray_out[2u * r + 1u] = vec4<f32>(acc, lossmult * se, se, 0.0);
    return p.level_weight * 2.0 * lossmult * err / batch_norm[0];
}

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (r >= p.n_rays) {
        return;
    }
    let d_col = finish_ray(r, forward_samples(r, 0u, p.n_samples, 0.0));
    if (p.supersample > 1u || p.train == 0u) {
        return;
    }
    backward_ray(r, d_col);
}

// d loss / d colour of ray r is `d_col`: back through rendering and the activations.
fn backward_ray(r: u32, d_col: vec3<f32>) {
    backward_samples(r, 0u, p.n_samples, d_col, 0.0);
}

// sum over samples i0..i1 of ray r of g_i w_i, g_i = d_col . (rgb_i - background).
fn colour_grad_sum(r: u32, i0: u32, i1: u32, d_col: vec3<f32>) -> f32 {
    let bg = background(r);
    var sum = 0.0;
    for (var i = i0; i < i1; i = i + 1u) {
        let k = r * p.n_samples + i;
        sum = sum + dot(d_col, padded(sample_sigmoid(k)) - bg) * weights[k];
    }
    return sum;
}

// The backward pass of samples i1 - 1 down to i0 of ray r, `suffix0` the sum of g_j w_j over
// the samples after i1.
fn backward_samples(r: u32, i0: u32, i1: u32, d_col: vec3<f32>, suffix0: f32) {
    let base = r * p.n_samples;
    let tb = r * (p.n_samples + 1u);
    let dir_norm = length(rays[2u * r + 1u].xyz);
    let noise_key = density_noise_key(r);
    let bg = background(r);
    var suffix = suffix0;
    for (var j = i0; j < i1; j = j + 1u) {
        let i = i1 - 1u - (j - i0);
        let k = base + i;
        let sg = sample_sigmoid(k);
        let w = weights[k];
        let g = dot(d_col, padded(sg) - bg);
        let ds = g * d_raw_density[k * p.density_stride] - suffix;
        suffix = suffix + g * w;
        let delta = (t_vals[tb + i + 1u] - t_vals[tb + i]) * dir_norm;
        d_raw_density[k * p.density_stride] = ds * delta * density_derivative(raw_den(k, noise_key, i));
        let d_rgb = w * d_col * sg * (1.0 - sg) * (1.0 + 2.0 * p.rgb_padding);
        d_raw_rgb[3u * k] = d_rgb.x;
        d_raw_rgb[3u * k + 1u] = d_rgb.y;
        d_raw_rgb[3u * k + 2u] = d_rgb.z;
    }
}

// Supersampling, after `main`: each ray's pixel colour is the mean of its pixel's k x k rays'
// colours (in ray order, as the CPU sums them); the first ray of a pixel records the pixel's loss
// terms; in training every ray gets 1 / k^2 of the pixel's colour gradient.
@compute @workgroup_size(WORKGROUP)
fn pixel_backward(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (r >= p.n_rays) {
        return;
    }
    let kk = p.supersample * p.supersample;
    let inv = 1.0 / f32(kk);
    let first = (r / kk) * kk;
    var mean = vec3<f32>(0.0);
    for (var j = 0u; j < kk; j = j + 1u) {
        mean = mean + ray_out[2u * (first + j)].xyz * inv;
    }
    let lossmult = select(1.0, rays[2u * first + 1u].w, p.area_loss != 0u);
    let err = mean - targets[first].xyz;
    let se = dot(err, err);
    if (r == first) {
        ray_out[2u * r + 1u] = vec4<f32>(ray_out[2u * r + 1u].x, lossmult * se, se, 0.0);
    }
    if (p.train == 0u) {
        return;
    }
    backward_ray(r, p.level_weight * 2.0 * lossmult * err / batch_norm[0] * inv);
}

// `main` with RAY_LANES invocations per ray (one workgroup per ray, for hardware GPUs, where one
// invocation per ray leaves most of the device idle at a few thousand rays): lane l takes a
// contiguous block of the ray's samples. The prefix sums of density x delta (forward) and the
// suffix sums of the colour gradient (backward) are sums within each block plus, in lane order,
// the blocks before (after) it; lane 0 adds the lanes' partial colours in lane order. The same
// maths as `main`, with the sums grouped by block.
const RAY_LANES: u32 = 32u;
var<workgroup> lane_sum: array<f32, 32>;
var<workgroup> lane_rgb: array<vec3<f32>, 32>;
var<workgroup> lane_acc: array<f32, 32>;
var<workgroup> lane_dist: array<f32, 32>;
var<workgroup> ray_d_col: vec3<f32>;

// Replaces lane_sum with its exclusive prefix sums (from the first lane, or from the last when
// `from_end`), summed in lane order by lane 0.
fn scan_lanes(lane: u32, from_end: bool) {
    workgroupBarrier();
    if (lane == 0u) {
        var run = 0.0;
        for (var j = 0u; j < RAY_LANES; j = j + 1u) {
            var l = j;
            if (from_end) {
                l = RAY_LANES - 1u - j;
            }
            let v = lane_sum[l];
            lane_sum[l] = run;
            run = run + v;
        }
    }
    workgroupBarrier();
}

@compute @workgroup_size(32)
fn main_wide(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let r = wg.y * p.groups_x + wg.x;
    if (r >= p.n_rays) {
        return;
    }
    let per = (p.n_samples + RAY_LANES - 1u) / RAY_LANES;
    let i0 = min(lane * per, p.n_samples);
    let i1 = min(i0 + per, p.n_samples);
    lane_sum[lane] = density_delta_sum(r, i0, i1);
    scan_lanes(lane, false);
    let part = forward_samples(r, i0, i1, lane_sum[lane]);
    lane_rgb[lane] = part.colour;
    lane_acc[lane] = part.acc;
    lane_dist[lane] = part.dist_num;
    workgroupBarrier();
    if (lane == 0u) {
        var sums = RayPartial(vec3<f32>(0.0), 0.0, 0.0);
        for (var j = 0u; j < RAY_LANES; j = j + 1u) {
            sums.colour = sums.colour + lane_rgb[j];
            sums.acc = sums.acc + lane_acc[j];
            sums.dist_num = sums.dist_num + lane_dist[j];
        }
        ray_d_col = finish_ray(r, sums);
    }
    if (p.supersample > 1u || p.train == 0u) {
        return;
    }
    // Backward: suffix_i = sum over j > i of g_j w_j, across blocks in lane order.
    workgroupBarrier();
    let d_col = ray_d_col;
    lane_sum[lane] = colour_grad_sum(r, i0, i1, d_col);
    scan_lanes(lane, true);
    backward_samples(r, i0, i1, d_col, lane_sum[lane]);
}
