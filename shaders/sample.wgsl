// Interval edges along rays, one invocation per ray (mipnerf-core's `sampling.rs`):
// - `stratified`: linspace between near and far (or linear in disparity), jittered in training
//   with the same counter-based random numbers as the CPU (`rng.rs`);
// - `resample`: the fine level's edges from the coarse weights: pad, 2-tap max, 2-tap blur,
//   + resample_padding, then inverse-CDF sampling (deterministic or stratified offsets).
// With `spacing` 2 (unbounded scenes, mipnerf-core's `contract` module) both work in the
// normalised distance s = t/2 (t < 1), 1 - 1/(2t) (beyond): the coarse edges are stratified in s,
// the histogram is resampled over the coarse edges' s, and every new edge is mapped back to t.

// The uniform block `Params` is declared from the Rust struct `SampleParams` (kernels/sample.rs).

@group(0) @binding(0) var<uniform> p: Params;
// stratified: (near, far) per ray. resample: the coarse edges.
@group(0) @binding(1) var<storage, read> src_a: array<f32>;
// resample: the coarse weights (stratified: unused).
@group(0) @binding(2) var<storage, read> src_b: array<f32>;
@group(0) @binding(3) var<storage, read_write> t_out: array<f32>;
// The index of each ray in the step's batch (its random streams are drawn with it): 0.. for a
// whole batch, the chunk's or the compacted rays' own indices otherwise.
@group(0) @binding(4) var<storage, read> ray_ids: array<u32>;

const F32_EPS: f32 = 1.1920929e-7;
const PDF_WEIGHT_EPS: f32 = 1e-5;
const MAX_EDGES: u32 = 1025u;
const SPACING_DISPARITY: u32 = 1u;
const SPACING_UNBOUNDED: u32 = 2u;

// The coarse edge at index `i` of `src_a`, in the coordinate resampling works in.
fn coarse_edge(i: u32) -> f32 {
    let t = src_a[i];
    if (p.spacing == SPACING_UNBOUNDED) {
        return ray_distance_to_s(t);
    }
    return t;
}

// A resampled edge back in t.
fn fine_edge(v: f32) -> f32 {
    if (p.spacing == SPACING_UNBOUNDED) {
        return s_to_ray_distance(v);
    }
    return v;
}

// Output `i` of `n_out` of the ray whose edges start at `tb`, resampled to `v` (in t): in an
// unbounded scene the first and last stay at the coarse level's (the ray's domain).
fn pinned_edge(tb: u32, i: u32, n_out: u32, v: f32) -> f32 {
    if (p.spacing == SPACING_UNBOUNDED && (i == 0u || i + 1u == n_out)) {
        return src_a[tb + i];
    }
    return v;
}

fn ray_key(stream: u32, ray: u32) -> u32 {
    return stream_key(p.seed, p.step, stream, ray);
}

fn ray_index(gid: vec3<u32>) -> u32 {
    return gid.y * (p.groups_x * WORKGROUP) + gid.x;
}

@compute @workgroup_size(WORKGROUP)
fn stratified(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = ray_index(gid);
    if (r >= p.n_rays) {
        return;
    }
    let near = src_a[2u * r];
    let far = src_a[2u * r + 1u];
    let n = p.n_samples;
    let base = r * (n + 1u);
    let key = ray_key(STREAM_SAMPLE_JITTER, ray_ids[r]);
    if (p.spacing == SPACING_UNBOUNDED) {
        let s_near = ray_distance_to_s(near);
        let s_far = ray_distance_to_s(far);
        // The first and last edges stay at near and far: the intervals span the ray's domain.
        t_out[base] = near;
        for (var i = 1u; i < n; i = i + 1u) {
            t_out[base + i] = s_to_ray_distance(stratified_edge(i, n, s_near, s_far, false, p.randomized != 0u, key));
        }
        t_out[base + n] = far;
        return;
    }
    for (var i = 0u; i <= n; i = i + 1u) {
        t_out[base + i] = stratified_edge(i, n, near, far, p.spacing == SPACING_DISPARITY, p.randomized != 0u, key);
    }
}

fn coarse_weight(base: u32, nw: u32, i: i32) -> f32 {
    return src_b[base + u32(clamp(i, 0, i32(nw) - 1))];
}

// Coarse weight i of the ray whose weights start at `base`, blurred (the max of each pair of
// neighbours, averaged) and padded.
fn blurred_weight(base: u32, nw: u32, i: u32) -> f32 {
    let ii = i32(i);
    let m0 = max(coarse_weight(base, nw, ii - 1), coarse_weight(base, nw, ii));
    let m1 = max(coarse_weight(base, nw, ii), coarse_weight(base, nw, ii + 1));
    return 0.5 * (m0 + m1) + p.resample_padding;
}

// Where in [0, 1) output i of `n_out` falls: stratified with the ray's random offsets, or evenly
// spaced.
fn resample_u(i: u32, n_out: u32, key: u32) -> f32 {
    if (p.randomized != 0u) {
        let s = 1.0 / f32(n_out);
        return min(f32(i) * s + uniform01(key, i) * (s - F32_EPS), 1.0 - F32_EPS);
    }
    if (i + 1u == n_out) {
        return 1.0 - F32_EPS;
    }
    return (1.0 - F32_EPS) * (f32(i) / f32(n_out - 1u));
}

// The edge at u in the CDF interval [c0, c1] between the coarse edges b0 and b1.
fn edge_at(u: f32, c0: f32, c1: f32, b0: f32, b1: f32) -> f32 {
    // The CPU's (u - c0) / (c1 - c0) with NaN to 0 and infinities to the largest floats, then
    // clamped. WGSL promises no NaN or infinity semantics, so the zero denominator (which the
    // CDF search rules out, c0 <= u < c1) is decided before dividing.
    let num = u - c0;
    let den = c1 - c0;
    var t = select(0.0, 1.0, num > 0.0);
    if (den > 0.0) {
        t = num / den;
    }
    t = clamp(t, 0.0, 1.0);
    return b0 + t * (b1 - b0);
}

@compute @workgroup_size(WORKGROUP)
fn resample(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = ray_index(gid);
    if (r >= p.n_rays) {
        return;
    }
    let nw = p.n_samples;
    let n_out = nw + 1u;
    let tb = r * (nw + 1u);
    let wb = r * nw;
    // Blurred weights, their sum, and the CDF (nw + 1 entries, 0 first, 1 last).
    var cdf: array<f32, 1025>;
    var weight_sum = 0.0;
    for (var i = 0u; i < nw; i = i + 1u) {
        let blurred = blurred_weight(wb, nw, i);
        cdf[i + 1u] = blurred;
        weight_sum = weight_sum + blurred;
    }
    let padding = max(PDF_WEIGHT_EPS - weight_sum, 0.0);
    let per_weight = padding / f32(nw);
    weight_sum = weight_sum + padding;
    cdf[0] = 0.0;
    var acc = 0.0;
    for (var i = 0u; i + 1u < nw; i = i + 1u) {
        acc = acc + (cdf[i + 1u] + per_weight) / weight_sum;
        cdf[i + 1u] = min(acc, 1.0);
    }
    cdf[nw] = 1.0;
    let key = ray_key(STREAM_RESAMPLE_OFFSETS, ray_level_index(ray_ids[r], p.level));
    var prev = -3.4e38;
    var k = 0u;
    for (var i = 0u; i < n_out; i = i + 1u) {
        let u = resample_u(i, n_out, key);
        // k = number of CDF entries <= u (u increases, so continue from the last k).
        while (k <= nw && cdf[k] <= u) {
            k = k + 1u;
        }
        let i0 = max(k, 1u) - 1u;
        let i1 = min(k, nw);
        var v = edge_at(u, cdf[i0], cdf[i1], coarse_edge(tb + i0), coarse_edge(tb + i1));
        v = max(v, prev);
        prev = v;
        t_out[tb + i] = pinned_edge(tb, i, n_out, fine_edge(v));
    }
}

// `resample` with RESAMPLE_LANES invocations per ray (one workgroup per ray, for hardware GPUs):
// lane l takes a contiguous block of the coarse weights, then of the outputs. The weights' sum
// and the CDF's running sums are sums within each block plus, in lane order, the blocks before
// it; each output's CDF interval is found by binary search (the same count of entries <= u as
// `resample`'s merge), and the running maximum that keeps the edges sorted is the maximum within
// the block and over the blocks before it (exact: the same edges as in one pass).
const RESAMPLE_LANES: u32 = 32u;
var<workgroup> w_cdf: array<f32, 1025>;
var<workgroup> w_lane: array<f32, 32>;
var<workgroup> w_total: f32;

// Replaces w_lane with its exclusive prefix sums, in lane order (by lane 0).
fn scan_resample_lanes(lane: u32) {
    workgroupBarrier();
    if (lane == 0u) {
        var run = 0.0;
        for (var j = 0u; j < RESAMPLE_LANES; j = j + 1u) {
            let v = w_lane[j];
            w_lane[j] = run;
            run = run + v;
        }
        w_total = run;
    }
    workgroupBarrier();
}

@compute @workgroup_size(32)
fn resample_wide(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let r = wg.y * p.groups_x + wg.x;
    if (r >= p.n_rays) {
        return;
    }
    let nw = p.n_samples;
    let n_out = nw + 1u;
    let tb = r * (nw + 1u);
    let wb = r * nw;
    let per = (nw + RESAMPLE_LANES - 1u) / RESAMPLE_LANES;
    let i0 = min(lane * per, nw);
    let i1 = min(i0 + per, nw);
    // Blurred weights into w_cdf[i + 1], and their sum.
    var local = 0.0;
    for (var i = i0; i < i1; i = i + 1u) {
        let blurred = blurred_weight(wb, nw, i);
        w_cdf[i + 1u] = blurred;
        local = local + blurred;
    }
    w_lane[lane] = local;
    scan_resample_lanes(lane);
    var weight_sum = w_total;
    let padding = max(PDF_WEIGHT_EPS - weight_sum, 0.0);
    let per_weight = padding / f32(nw);
    weight_sum = weight_sum + padding;
    // The CDF's running sums over entries 1..nw - 1 (0 first, 1 last).
    let j1 = min(i1, nw - 1u);
    local = 0.0;
    for (var i = i0; i < j1; i = i + 1u) {
        local = local + (w_cdf[i + 1u] + per_weight) / weight_sum;
    }
    // Every lane has read its blurred weights' sum before the scan's first barrier.
    w_lane[lane] = local;
    scan_resample_lanes(lane);
    var acc = w_lane[lane];
    for (var i = i0; i < j1; i = i + 1u) {
        acc = acc + (w_cdf[i + 1u] + per_weight) / weight_sum;
        w_cdf[i + 1u] = min(acc, 1.0);
    }
    if (lane == 0u) {
        w_cdf[0] = 0.0;
        w_cdf[nw] = 1.0;
    }
    workgroupBarrier();
    // The outputs: this lane's block, each from its own CDF interval.
    let key = ray_key(STREAM_RESAMPLE_OFFSETS, ray_level_index(ray_ids[r], p.level));
    let per_out = (n_out + RESAMPLE_LANES - 1u) / RESAMPLE_LANES;
    let o0 = min(lane * per_out, n_out);
    let o1 = min(o0 + per_out, n_out);
    var run_max = -3.4e38;
    for (var i = o0; i < o1; i = i + 1u) {
        let u = resample_u(i, n_out, key);
        // k = number of CDF entries <= u (the CDF is sorted): binary search over 0..=nw.
        var lo = 0u;
        var hi = nw + 1u;
        while (lo < hi) {
            let mid = (lo + hi) / 2u;
            if (w_cdf[mid] <= u) {
                lo = mid + 1u;
            } else {
                hi = mid;
            }
        }
        let k = lo;
        let i_lo = max(k, 1u) - 1u;
        let i_hi = min(k, nw);
        let v = edge_at(u, w_cdf[i_lo], w_cdf[i_hi], coarse_edge(tb + i_lo), coarse_edge(tb + i_hi));
        run_max = max(v, run_max);
        t_out[tb + i] = pinned_edge(tb, i, n_out, fine_edge(run_max));
    }
    // The running maximum over the blocks before this one, then applied to this block.
    workgroupBarrier();
    w_lane[lane] = run_max;
    workgroupBarrier();
    var before = -3.4e38;
    for (var j = 0u; j < lane; j = j + 1u) {
        before = max(before, w_lane[j]);
    }
    // The edges are in t and the maxima in s: the map between them is increasing.
    // (No block before: nothing to raise, and the sentinel is not mapped.)
    var before_t = before;
    if (before > -3.4e38) {
        before_t = fine_edge(before);
    }
    for (var i = o0; i < o1; i = i + 1u) {
        t_out[tb + i] = pinned_edge(tb, i, n_out, max(t_out[tb + i], before_t));
    }
}
