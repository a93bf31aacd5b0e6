// The Tri-Mip field's planes on the device (mipnerf-core's `tri_mip.rs` and
// `Model::encode_samples`, operation by operation): three planes (xy, xz, yz) of
// `resolution^2` texels of `features` values, level 0 the model's first parameters, the levels
// above it 2x2 box filters of the one below, kept in `pyramid` one after the other.
//
// Entry points:
// - `build_levels`: `params.group_levels` levels of the pyramid from `params.level` up, from the
//   level below them: one invocation per value of the group's coarsest level, which reads its
//   block of the finer level and box-filters it level by level (the CPU's operations in its
//   order), writing every level it passes; a pyramid of 7 levels takes two dispatches.
// - `encode_planes`: a sample's encoding, one invocation per (sample, plane): the frustum's
//   moments (`frustum.wgsl`), its mean and footprint radius in the planes' box (through the
//   scene contraction for an unbounded scene), the level `log2(2 radius resolution)`, and the
//   24 taps (bilinear at the two levels around it) summed in the CPU's order. In probe mode
//   (`probes` 1) the samples are given Gaussians (an occupancy grid's density probes,
//   `occupancy_update.wgsl`) read at their isotropic standard deviation, as `Model::encode_probe`.
// - `scatter_planes`: the encoding's adjoint, one invocation per (sample, plane): the same taps
//   recomputed, each texel's gradient added atomically: one `atomicAdd` where the device has
//   float atomics, else a compare-exchange loop on the f32's bits (WGSL's core has no float
//   atomics; every adapter has `atomic<u32>`). The sums' order is the device's, not the CPU's:
//   equal to rounding.
// - `push_down`: the pyramid's gradients carried to level 0 through the box filters' adjoint,
//   one invocation per level-0 value, nested from the coarsest level down as the CPU's
//   `Pyramid::push_down` cascades them (the same operations in the same order); then, where
//   `tv_scale` is not 0, the gradient of TensoRF's total variation of level 0 at that value,
//   added as `tri_mip::total_variation` adds it.
// - `total_variation`: that regulariser's loss, one invocation per row of a plane, as
//   `tri_mip::total_variation` loops (its row's sum into `tv_rows`, summed on the host in f64);
//   for the steps that report their losses.

// The uniform block `Params` is declared from the Rust struct `TriMipParams` (kernels/tri_mip.rs).

@group(0) @binding(0) var<uniform> params: Params;
// Two vec4 per ray: (origin.xyz, radius), (direction.xyz, unused).
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
// n_samples + 1 interval edges per ray.
@group(0) @binding(2) var<storage, read> t_vals: array<f32>;
// The model's parameters: level 0 of the planes first, laid out [plane][v][u][feature].
@group(0) @binding(3) var<storage, read> model_params: array<f32>;
// Levels 1.. of the planes, one after the other, each laid out as level 0.
@group(0) @binding(4) var<storage, read_write> pyramid: array<f32>;
// The samples' encodings (`encode_planes` writes them; `scatter_planes` reads their gradient).
@group(0) @binding(5) var<storage, read_write> encoded: array<f32>;
// The parameters' gradient (level 0 first); `load_grads`, `store_grads` and `add_to_grads`
// are generated (kernels::gradient_atomics), as for `grad_pyramid`.
@group(0) @binding(6) var<storage, read_write> grads: array<GradientAtomic>;
// The gradient of levels 1.., laid out as `pyramid`.
@group(0) @binding(7) var<storage, read_write> grad_pyramid: array<GradientAtomic>;
// Per row of level 0 (3 resolution rows): the row's sum of squared neighbour differences.
@group(0) @binding(8) var<storage, read_write> tv_rows: array<f32>;

// The planes' shape (`plane_taps.wgsl`).
fn planes() -> Planes {
    return Planes(params.resolution, params.features, params.levels);
}

fn side_at(level: u32) -> u32 {
    return plane_side(planes(), level);
}

// Where level `level` >= 1 starts in `pyramid`.
fn level_base(level: u32) -> u32 {
    return plane_level_base(planes(), level);
}

// The point (in the planes' box, [0, 1]^3) and the level a sample reads: Model::encode_samples.
fn sample_point(sample: u32) -> vec4<f32> {
    var x: vec3<f32>;
    var radius: f32;
    if (params.probes != 0u) {
        let g = rays[sample];
        x = g.xyz;
        radius = probe_footprint(g.w, params.half_side);
    } else {
        let xr = frustum_point(sample);
        x = xr.xyz;
        radius = xr.w;
    }
    return plane_point(planes(), params.half_side, params.pre_filtered != 0u, x, radius);
}

// A frustum's mean (through the contraction in an unbounded scene) and its footprint's radius
// over the box's side.
fn frustum_point(sample: u32) -> vec4<f32> {
    let ray = sample / params.n_samples;
    let j = sample % params.n_samples;
    let o_r = rays[2u * ray];
    let d = rays[2u * ray + 1u].xyz;
    let base_t = ray * (params.n_samples + 1u) + j;
    let m = frustum_moments(t_vals[base_t], t_vals[base_t + 1u], o_r.w, params.ray_shape);
    let side = 2.0 * params.half_side;
    var x = o_r.xyz + d * m.x;
    // footprint_radius(m) * |d| / side, |d| as glam's length: sqrt((x x + y y) + z z).
    let d_len = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    var radius = 2.0 * sqrt(max(m.z, 0.0)) * d_len / side;
    if (params.unbounded != 0u) {
        // contract::contraction_across and contract::contract.
        let r2 = x.x * x.x + x.y * x.y + x.z * x.z;
        if (r2 > 1.0) {
            let r = sqrt(r2);
            let across = (2.0 - 1.0 / r) / r;
            radius = radius * across;
            x = x * across;
        }
    }
    return vec4<f32>(x, radius);
}

fn flat_index(gid: vec3<u32>) -> u32 {
    return gid.y * (params.groups_x * WORKGROUP) + gid.x;
}

// A value of level `level - 1` (level 0: the model's parameters): row `row` (over the three
// planes), column `u`, feature `f`.
fn finer_value(level: u32, row: u32, u: u32, f: u32) -> f32 {
    let at = (row * side_at(level - 1u) + u) * params.features + f;
    if (level == 1u) {
        return model_params[at];
    }
    return pyramid[level_base(level - 1u) + at];
}

@compute @workgroup_size(WORKGROUP)
fn build_levels(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid);
    let first = params.level;
    let g = params.group_levels;
    let top = first + g - 1u;
    let s = side_at(top);
    let c = params.features;
    if (i >= 3u * s * s * c) {
        return;
    }
    let f = i % c;
    let texel = i / c;
    let u = texel % s;
    let row = texel / s;
    // The block of level first - 1 under this texel of level `top`, then each level's 2x2 box
    // filters over it in place (a texel is written at or before the first value it reads).
    let b = 1u << g;
    var block: array<f32, PYRAMID_BLOCK_AREA>;
    for (var y = 0u; y < b; y = y + 1u) {
        for (var x = 0u; x < b; x = x + 1u) {
            block[y * b + x] = finer_value(first, row * b + y, u * b + x, f);
        }
    }
    var side = b;
    for (var l = first; l <= top; l = l + 1u) {
        let finer = side;
        side = side / 2u;
        for (var y = 0u; y < side; y = y + 1u) {
            for (var x = 0u; x < side; x = x + 1u) {
                let a = 2u * y * finer + 2u * x;
                let v = 0.25 * (block[a] + block[a + 1u] + block[a + finer] + block[a + finer + 1u]);
                block[y * side + x] = v;
                let at = ((row * side + y) * side_at(l) + u * side + x) * c + f;
                pyramid[level_base(l) + at] = v;
            }
        }
    }
}

@compute @workgroup_size(WORKGROUP)
fn encode_planes(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = flat_index(gid);
    if (idx >= 3u * params.n_rays * params.n_samples) {
        return;
    }
    let sample = idx / 3u;
    let plane = idx % 3u;
    let p = sample_point(sample);
    var taps: array<Tap, TAPS_PER_PLANE>;
    for (var k = 0u; k < TAPS_PER_PLANE; k = k + 1u) {
        taps[k] = plane_tap(planes(), plane, p.xyz, p.w, k);
    }
    let c = params.features;
    let out = (3u * sample + plane) * c;
    for (var f = 0u; f < c; f = f + 1u) {
        encoded[out + f] = plane_feature(&taps, f);
    }
}

@compute @workgroup_size(WORKGROUP)
fn scatter_planes(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = flat_index(gid);
    if (idx >= 3u * params.n_rays * params.n_samples) {
        return;
    }
    let sample = idx / 3u;
    let plane = idx % 3u;
    let p = sample_point(sample);
    let c = params.features;
    let src = (3u * sample + plane) * c;
    for (var k = 0u; k < TAPS_PER_PLANE; k = k + 1u) {
        let t = plane_tap(planes(), plane, p.xyz, p.w, k);
        if (t.weight == 0.0) {
            continue;
        }
        if (t.level == 0u) {
            for (var f = 0u; f < c; f = f + 1u) {
                add_to_grads(t.offset + f, t.weight * encoded[src + f]);
            }
        } else {
            for (var f = 0u; f < c; f = f + 1u) {
                add_to_grad_pyramid(t.offset + f, t.weight * encoded[src + f]);
            }
        }
    }
}

@compute @workgroup_size(WORKGROUP)
fn push_down(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid);
    let r = params.resolution;
    let c = params.features;
    if (i >= 3u * r * r * c) {
        return;
    }
    var g = load_grads(i);
    let f = i % c;
    let texel = i / c;
    let u = texel % r;
    let v = (texel / r) % r;
    let plane = texel / (r * r);
    if (params.levels >= 2u) {
        let top = params.levels - 1u;
        var acc = 0.0;
        for (var l = top; l >= 1u; l = l - 1u) {
            let s = side_at(l);
            let at = level_base(l) + ((plane * s + (v >> l)) * s + (u >> l)) * c + f;
            let own = load_grad_pyramid(at);
            if (l == top) {
                acc = own;
            } else {
                acc = own + 0.25 * acc;
            }
        }
        g = g + 0.25 * acc;
    }
    if (params.tv_scale != 0.0 && r >= 2u) {
        // The value's differences with its neighbours along u, then v (the CPU's order).
        let x = model_params[i];
        let row = r * c;
        var d = 0.0;
        if (u > 0u) {
            d = d + (x - model_params[i - c]);
        }
        if (u + 1u < r) {
            d = d + (x - model_params[i + c]);
        }
        if (v > 0u) {
            d = d + (x - model_params[i - row]);
        }
        if (v + 1u < r) {
            d = d + (x - model_params[i + row]);
        }
        g = g + 2.0 * params.tv_scale * d;
    }
    store_grads(i, g);
}

@compute @workgroup_size(WORKGROUP)
fn total_variation(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = flat_index(gid);
    let size = params.resolution;
    if (r >= 3u * size || size < 2u) {
        return;
    }
    let c = params.features;
    let row = size * c;
    let v = r % size;
    let here = r * row;
    var acc = 0.0;
    for (var i = 0u; i < row; i = i + 1u) {
        let x = model_params[here + i];
        if (i + c < row) {
            let e = x - model_params[here + i + c];
            acc = acc + e * e;
        }
        if (v + 1u < size) {
            let e = x - model_params[here + row + i];
            acc = acc + e * e;
        }
    }
    tv_rows[r] = acc;
}
