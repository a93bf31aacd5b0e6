// Gradient clipping and one bias-corrected Adam update per parameter (mipnerf-core's
// `clip_gradients` and `AdamState::update`):
//   g = clamp(g, -max_val, max_val)                     (max_val > 0)
//   g = g * min(max_norm / (1e-7 + |g|), 1)            (max_norm > 0; |g| after value clipping)
//   m = b1 m + (1 - b1) g; v = b2 v + (1 - b2) g^2; p -= lr (m / c1) / (sqrt(v / c2) + eps),
// the first `split` parameters (a field's own, the Tri-Mip planes) with `field_lr` and
// `field_eps` (`AdamState::update_split`), and, where `field_skip_untouched` is 1, those of them
// whose gradient is 0 left as they are, moments included (`FieldAdam::skip_untouched`), and the
// others' (the MLP's) gradient plus `mlp_l2` times the parameter where it is not 0
// (`AdamConfig::l2`).
//
// Entry points: `grad_sq_partial` (one sum of squares per workgroup of REDUCE_WORKGROUP (256) gradients),
// `grad_norm_finish` (one workgroup: the norm and the clipping factor into `stats`), `main` (the
// update). The norm passes run only when clipping by norm; the sums are in a fixed order.

// The uniform block `Params` is declared from the Rust struct `AdamParams` (kernels/adam.rs).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> grads: array<f32>;
@group(0) @binding(2) var<storage, read_write> params: array<f32>;
@group(0) @binding(3) var<storage, read_write> m: array<f32>;
@group(0) @binding(4) var<storage, read_write> v: array<f32>;
@group(0) @binding(5) var<storage, read_write> partials: array<f32>;
// [0]: the gradient's norm after value clipping; [1]: the factor norm clipping applies.
@group(0) @binding(6) var<storage, read_write> stats: array<f32>;

fn clipped(i: u32) -> f32 {
    let g = grads[i];
    if (p.max_val > 0.0) {
        return clamp(g, -p.max_val, p.max_val);
    }
    return g;
}

var<workgroup> sums: array<f32, REDUCE_WORKGROUP>;

// Tree sum of `sums` within the workgroup; the result is in sums[0].
fn reduce_workgroup(t: u32) {
    workgroupBarrier();
    for (var half = 128u; half > 0u; half = half / 2u) {
        if (t < half) {
            sums[t] = sums[t] + sums[t + half];
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(REDUCE_WORKGROUP)
fn grad_sq_partial(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let group = wg.y * p.groups_x + wg.x;
    let i = group * REDUCE_WORKGROUP + t;
    var s = 0.0;
    if (i < p.count) {
        let g = clipped(i);
        s = g * g;
    }
    sums[t] = s;
    reduce_workgroup(t);
    if (t == 0u && group < p.n_partials) {
        partials[group] = sums[0];
    }
}

@compute @workgroup_size(REDUCE_WORKGROUP)
fn grad_norm_finish(@builtin(local_invocation_index) t: u32) {
    var s = 0.0;
    for (var k = t; k < p.n_partials; k = k + REDUCE_WORKGROUP) {
        s = s + partials[k];
    }
    sums[t] = s;
    reduce_workgroup(t);
    if (t == 0u) {
        let norm = sqrt(sums[0]);
        stats[0] = norm;
        stats[1] = min(p.max_norm / (1e-7 + norm), 1.0);
    }
}

@compute @workgroup_size(WORKGROUP)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (i >= p.count) {
        return;
    }
    var g = clipped(i);
    if (p.max_norm > 0.0) {
        g = g * stats[1];
    }
    if (i < p.split && p.field_skip_untouched != 0u && g == 0.0) {
        return;
    }
    if (i >= p.split && p.mlp_l2 != 0.0) {
        g = g + p.mlp_l2 * params[i];
    }
    let mi = p.beta1 * m[i] + (1.0 - p.beta1) * g;
    let vi = p.beta2 * v[i] + (1.0 - p.beta2) * g * g;
    m[i] = mi;
    v[i] = vi;
    var lr = p.lr;
    var eps = p.eps;
    if (i < p.split) {
        lr = p.field_lr;
        eps = p.field_eps;
    }
    params[i] = params[i] - lr * (mi / p.c1) / (sqrt(vi / p.c2) + eps);
}
