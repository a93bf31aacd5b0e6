// mipnerf-core's counter-based random numbers (crates/mipnerf-core/src/rng.rs) and the stratified
// draws built on them (crates/mipnerf-core/src/sampling.rs), with the normalised distance of
// unbounded scenes (crates/mipnerf-core/src/contract.rs), the one WGSL copy:
// composed in front of every kernel's own source, after the generated constants (STREAM_*,
// RAY_LEVEL_STRIDE) that come from the Rust definitions.

// One round of the PCG-RXS-M-XS 32-bit permutation: `rng::pcg_hash`.
fn pcg_hash(x: u32) -> u32 {
    let state = x * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// The key of the stream (seed, step, stream, index): `RayRng::new(..).key()`.
fn stream_key(seed: u32, step: u32, stream: u32, index: u32) -> u32 {
    return pcg_hash(seed ^ pcg_hash(step ^ pcg_hash(stream ^ pcg_hash(index))));
}

// The stream index of a ray's draws at one level: `rng::ray_level_index`.
fn ray_level_index(ray: u32, level: u32) -> u32 {
    return ray * RAY_LEVEL_STRIDE + level;
}

// The i-th 32 random bits of a stream: `RayRng::bits`.
fn stream_bits(key: u32, i: u32) -> u32 {
    return pcg_hash(key ^ pcg_hash(i));
}

// A uniform number in [0, 1) from the top 24 bits: `RayRng::uniform`.
fn uniform01(key: u32, i: u32) -> f32 {
    return f32(stream_bits(key, i) >> 8u) * (1.0 / 16777216.0);
}

// The random background colour of batch pixel `pixel`: `rng::random_background`.
fn random_background(seed: u32, step: u32, pixel: u32) -> vec3<f32> {
    let key = stream_key(seed, step, STREAM_BACKGROUND, pixel);
    return vec3<f32>(uniform01(key, 0u), uniform01(key, 1u), uniform01(key, 2u));
}

// `RayRng::normal`: Box-Muller on uniforms 2i and 2i + 1; the cosine's argument is brought into
// [-pi, pi], where GPU `cos` is accurate.
fn normal(key: u32, i: u32) -> f32 {
    let u1 = 1.0 - uniform01(key, 2u * i);
    var a = 6.2831855 * uniform01(key, 2u * i + 1u);
    if (a > 3.1415927) {
        a = a - 6.2831855;
    }
    return sqrt(-2.0 * log(u1)) * cos(a);
}

// Edge i of the n + 1 evenly spaced edges between near and far (or evenly in disparity):
// `sampling::sample_along_rays` before its jitter.
fn linspace_edge(i: u32, n: u32, near: f32, far: f32, lindisp: bool) -> f32 {
    let s = f32(i) / f32(n);
    if (lindisp) {
        return 1.0 / (1.0 / near * (1.0 - s) + 1.0 / far * s);
    }
    return near * (1.0 - s) + far * s;
}

// Edge i of `sampling::sample_along_rays(near, far, lindisp, jitter)`: the even edge, or in
// training (`jitter`) a uniform draw of the ray's stream `key` between the midpoints of the even
// edges on either side (the edge itself at either end).
fn stratified_edge(i: u32, n: u32, near: f32, far: f32, lindisp: bool, jitter: bool, key: u32) -> f32 {
    let cur = linspace_edge(i, n, near, far, lindisp);
    if (!jitter) {
        return cur;
    }
    var lower = cur;
    if (i > 0u) {
        lower = 0.5 * (cur + linspace_edge(i - 1u, n, near, far, lindisp));
    }
    var upper = cur;
    if (i < n) {
        upper = 0.5 * (linspace_edge(i + 1u, n, near, far, lindisp) + cur);
    }
    return lower + (upper - lower) * uniform01(key, i);
}

// mipnerf-core's `contract::ray_distance_to_s` and `s_to_ray_distance`: the normalised distance
// unbounded scenes space their edges in (`sample.wgsl`, `occupancy.wgsl`).
fn ray_distance_to_s(t: f32) -> f32 {
    if (t < 1.0) {
        return 0.5 * t;
    }
    return 1.0 - 0.5 / t;
}

fn s_to_ray_distance(s: f32) -> f32 {
    if (s < 0.5) {
        return 2.0 * s;
    }
    return 1.0 / (2.0 - 2.0 * s);
}
