// A small MLP (the Tri-Mip field's) with each pass in one dispatch: mipnerf-core's
// `MlpShape::forward` and `backward` for a shape with no skip connection whose layers are at
// most MLP_MAX_WIDTH wide (the product kernels of `matmul.wgsl` run every other shape).
//
// Entry points:
// - `forward`: one invocation per sample runs every layer in order, the activations in two
//   private arrays, and keeps what the backward pass reads in its row of `acts`.
// - `backward_samples`: one invocation per sample runs the layers backwards from the raw
//   colours' and raw density's gradients (written by rendering), keeps every layer's
//   pre-activation gradient in its row of `d_acts` and writes the encodings' gradient to `d_x`.
// - `weight_gradients`: one workgroup per MLP_TILE x MLP_TILE tile of one layer's kernel (its
//   bias as one more row, of inputs 1), summing input x output gradient over the samples in
//   order, MLP_TILE samples at a time through workgroup memory, and adding the tile to `grads`.
//   Which layer part a workgroup takes comes from the job list in `table`.
//
// A row of `acts` (and of `d_acts`, the same places): the raw density, the bottleneck
// (`net_width`), the trunk's layers (`net_depth x net_width`, after their ReLU), the colour
// branch's (`depth_condition x width_condition`, after their ReLU). The raw colours go to
// `raw_rgb` (n x 3) and their gradient comes from `d_rgb`. The view direction's encoding enters
// the first colour layer per sample (the CPU multiplies it once per ray: equal to rounding).

struct Params {
    // Samples.
    n: u32,
    samples_per_ray: u32,
    x_dim: u32,
    view_dim: u32,
    net_depth: u32,
    net_width: u32,
    depth_condition: u32,
    width_condition: u32,
    // Floats per sample of `acts` and `d_acts`.
    row: u32,
    // Workgroups along x of the 2-D dispatch grid.
    groups_x: u32,
    // Where the shape's parameters start in `model_params` and `grads`.
    base: u32,
    // `weight_gradients`: jobs in `table` (after the layers' offsets).
    jobs: u32,
    // `backward_samples`: 1 to write `d_x`.
    input_gradient: u32,
    // To 16 bytes.
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
// Per layer (the shape's order: trunk, density, bottleneck, colour layers, colour output): its
// kernel's and its bias's offsets from `p.base`; then the weight-gradient jobs, MLP_JOB_WORDS each.
@group(0) @binding(1) var<storage, read> table: array<u32>;
@group(0) @binding(2) var<storage, read> model_params: array<f32>;
// The encodings, n x x_dim.
@group(0) @binding(3) var<storage, read> x: array<f32>;
// The view directions' encodings, one row of view_dim per ray.
@group(0) @binding(4) var<storage, read> view: array<f32>;
@group(0) @binding(5) var<storage, read_write> acts: array<f32>;
@group(0) @binding(6) var<storage, read_write> raw_rgb: array<f32>;
@group(0) @binding(7) var<storage, read> d_rgb: array<f32>;
@group(0) @binding(8) var<storage, read_write> d_acts: array<f32>;
@group(0) @binding(9) var<storage, read_write> d_x: array<f32>;
@group(0) @binding(10) var<storage, read_write> grads: array<f32>;

alias Activations = array<f32, MLP_MAX_WIDTH>;

// A job of `weight_gradients` (MLP_JOB_WORDS words): the input's source and offset, the output
// gradient's source and offset, input rows (bias not counted), columns, the kernel rows' and the
// bias's offsets in `grads` from `p.base` (MLP_NO_BIAS: none), the job's first workgroup. Input
// sources: MLP_SOURCE_X (the encodings), MLP_SOURCE_ACTS (a part of `acts`), MLP_SOURCE_VIEW
// (the view encoding of the sample's ray); output-gradient sources: MLP_SOURCE_D_ACTS (a part
// of `d_acts`), MLP_SOURCE_D_RGB (the raw colours' gradient).

fn flat_index(gid: vec3<u32>) -> u32 {
    return gid.y * (p.groups_x * WORKGROUP) + gid.x;
}

fn layer_count() -> u32 {
    return p.net_depth + 3u + p.depth_condition;
}

// Kernel entry (k, o) of layer `layer`, `fan_out` wide.
fn weight(layer: u32, k: u32, fan_out: u32, o: u32) -> f32 {
    return model_params[p.base + table[2u * layer] + k * fan_out + o];
}

fn bias(layer: u32, o: u32) -> f32 {
    return model_params[p.base + table[2u * layer + 1u] + o];
}

// Where trunk layer i's outputs start in a row.
fn trunk_at(i: u32) -> u32 {
    return 1u + p.net_width * (1u + i);
}

// Where colour layer j's outputs start in a row.
fn colour_at(j: u32) -> u32 {
    return 1u + p.net_width * (1u + p.net_depth) + j * p.width_condition;
}

@compute @workgroup_size(WORKGROUP)
fn forward(@builtin(global_invocation_id) gid: vec3<u32>) {
    let s = flat_index(gid);
    if (s >= p.n) {
        return;
    }
    let w = p.net_width;
    let wc = p.width_condition;
    let d = p.net_depth;
    let r = s * p.row;
    var a: Activations;
    var b: Activations;
    for (var k = 0u; k < p.x_dim; k = k + 1u) {
        a[k] = x[s * p.x_dim + k];
    }
    var fan_in = p.x_dim;
    for (var i = 0u; i < d; i = i + 1u) {
        for (var o = 0u; o < w; o = o + 1u) {
            var z = bias(i, o);
            for (var k = 0u; k < fan_in; k = k + 1u) {
                z = z + a[k] * weight(i, k, w, o);
            }
            b[o] = max(z, 0.0);
            acts[r + trunk_at(i) + o] = b[o];
        }
        a = b;
        fan_in = w;
    }
    // The heads: the raw density and the bottleneck (no activation), into b.
    var density = bias(d, 0u);
    for (var k = 0u; k < w; k = k + 1u) {
        density = density + a[k] * weight(d, k, 1u, 0u);
    }
    acts[r] = density;
    for (var o = 0u; o < w; o = o + 1u) {
        var z = bias(d + 1u, o);
        for (var k = 0u; k < w; k = k + 1u) {
            z = z + a[k] * weight(d + 1u, k, w, o);
        }
        b[o] = z;
        acts[r + 1u + o] = z;
    }
    // The first colour layer: [bottleneck | view encoding of the ray] in, into a.
    let view_row = (s / p.samples_per_ray) * p.view_dim;
    for (var o = 0u; o < wc; o = o + 1u) {
        var z = bias(d + 2u, o);
        for (var k = 0u; k < w; k = k + 1u) {
            z = z + b[k] * weight(d + 2u, k, wc, o);
        }
        for (var k = 0u; k < p.view_dim; k = k + 1u) {
            z = z + view[view_row + k] * weight(d + 2u, w + k, wc, o);
        }
        a[o] = max(z, 0.0);
        acts[r + colour_at(0u) + o] = a[o];
    }
    for (var j = 1u; j < p.depth_condition; j = j + 1u) {
        for (var o = 0u; o < wc; o = o + 1u) {
            var z = bias(d + 2u + j, o);
            for (var k = 0u; k < wc; k = k + 1u) {
                z = z + a[k] * weight(d + 2u + j, k, wc, o);
            }
            b[o] = max(z, 0.0);
            acts[r + colour_at(j) + o] = b[o];
        }
        a = b;
    }
    let last = layer_count() - 1u;
    for (var m = 0u; m < 3u; m = m + 1u) {
        var z = bias(last, m);
        for (var k = 0u; k < wc; k = k + 1u) {
            z = z + a[k] * weight(last, k, 3u, m);
        }
        raw_rgb[3u * s + m] = z;
    }
}

// The ReLU's backward pass: the gradient where the layer's output was positive.
fn relu_backward(g: f32, output: f32) -> f32 {
    return select(0.0, g, output > 0.0);
}

@compute @workgroup_size(WORKGROUP)
fn backward_samples(@builtin(global_invocation_id) gid: vec3<u32>) {
    let s = flat_index(gid);
    if (s >= p.n) {
        return;
    }
    let w = p.net_width;
    let wc = p.width_condition;
    let d = p.net_depth;
    let dc = p.depth_condition;
    let r = s * p.row;
    var g: Activations;
    var h: Activations;
    // The colour output layer (linear): the last colour layer's pre-activation gradient.
    let last = layer_count() - 1u;
    let at_last = r + colour_at(dc - 1u);
    for (var o = 0u; o < wc; o = o + 1u) {
        var t = 0.0;
        for (var m = 0u; m < 3u; m = m + 1u) {
            t = t + weight(last, o, 3u, m) * d_rgb[3u * s + m];
        }
        g[o] = relu_backward(t, acts[at_last + o]);
        d_acts[at_last + o] = g[o];
    }
    for (var j = dc - 1u; j > 0u; j = j - 1u) {
        let at = r + colour_at(j - 1u);
        for (var o = 0u; o < wc; o = o + 1u) {
            var t = 0.0;
            for (var m = 0u; m < wc; m = m + 1u) {
                t = t + weight(d + 2u + j, o, wc, m) * g[m];
            }
            h[o] = relu_backward(t, acts[at + o]);
            d_acts[at + o] = h[o];
        }
        g = h;
    }
    // The first colour layer's bottleneck rows: the bottleneck's gradient (no activation).
    for (var o = 0u; o < w; o = o + 1u) {
        var t = 0.0;
        for (var m = 0u; m < wc; m = m + 1u) {
            t = t + weight(d + 2u, o, wc, m) * g[m];
        }
        h[o] = t;
        d_acts[r + 1u + o] = t;
    }
    // Both heads: the top trunk layer's pre-activation gradient.
    let d_density = d_acts[r];
    let top = r + trunk_at(d - 1u);
    for (var o = 0u; o < w; o = o + 1u) {
        var t = weight(d, o, 1u, 0u) * d_density;
        for (var m = 0u; m < w; m = m + 1u) {
            t = t + weight(d + 1u, o, w, m) * h[m];
        }
        g[o] = relu_backward(t, acts[top + o]);
        d_acts[top + o] = g[o];
    }
    for (var i = d - 1u; i > 0u; i = i - 1u) {
        let at = r + trunk_at(i - 1u);
        for (var o = 0u; o < w; o = o + 1u) {
            var t = 0.0;
            for (var m = 0u; m < w; m = m + 1u) {
                t = t + weight(i, o, w, m) * g[m];
            }
            h[o] = relu_backward(t, acts[at + o]);
            d_acts[at + o] = h[o];
        }
        g = h;
    }
    if (p.input_gradient != 0u) {
        for (var k = 0u; k < p.x_dim; k = k + 1u) {
            var t = 0.0;
            for (var m = 0u; m < w; m = m + 1u) {
                t = t + weight(0u, k, w, m) * g[m];
            }
            d_x[s * p.x_dim + k] = t;
        }
    }
}

var<workgroup> tile_in: array<f32, MLP_TILE_AREA>;
var<workgroup> tile_dz: array<f32, MLP_TILE_AREA>;

// Input `row` (bias row: 1) of sample `s` for a job; 0 outside.
fn job_input(job: u32, s: u32, k: u32) -> f32 {
    let rows = table[job + 4u];
    if (s >= p.n) {
        return 0.0;
    }
    if (k == rows) {
        return select(0.0, 1.0, table[job + 7u] != MLP_NO_BIAS);
    }
    if (k > rows) {
        return 0.0;
    }
    let off = table[job + 1u];
    switch table[job] {
        case MLP_SOURCE_X: {
            return x[s * p.x_dim + off + k];
        }
        case MLP_SOURCE_VIEW: {
            return view[(s / p.samples_per_ray) * p.view_dim + off + k];
        }
        default: {
            return acts[s * p.row + off + k];
        }
    }
}

// Output gradient `c` of sample `s` for a job; 0 outside.
fn job_output_gradient(job: u32, s: u32, c: u32) -> f32 {
    if (s >= p.n || c >= table[job + 5u]) {
        return 0.0;
    }
    let off = table[job + 3u];
    if (table[job + 2u] == MLP_SOURCE_D_RGB) {
        return d_rgb[3u * s + off + c];
    }
    return d_acts[s * p.row + off + c];
}

@compute @workgroup_size(MLP_TILE, MLP_TILE)
fn weight_gradients(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let group = wid.x;
    // The job whose workgroups hold this one (uniform across the workgroup).
    let jobs_at = 2u * layer_count();
    var j = 0u;
    while (j + 1u < p.jobs && table[jobs_at + (j + 1u) * MLP_JOB_WORDS + 8u] <= group) {
        j = j + 1u;
    }
    let job = jobs_at + j * MLP_JOB_WORDS;
    let cols = table[job + 5u];
    let tiles_across = (cols + MLP_TILE - 1u) / MLP_TILE;
    let tile = group - table[job + 8u];
    let row0 = (tile / tiles_across) * MLP_TILE;
    let col0 = (tile % tiles_across) * MLP_TILE;
    var acc = 0.0;
    for (var s0 = 0u; s0 < p.n; s0 = s0 + MLP_TILE) {
        // Thread (x, y) loads sample s0 + y's input row0 + x and output gradient col0 + x.
        tile_in[lid.y * MLP_TILE + lid.x] = job_input(job, s0 + lid.y, row0 + lid.x);
        tile_dz[lid.y * MLP_TILE + lid.x] = job_output_gradient(job, s0 + lid.y, col0 + lid.x);
        workgroupBarrier();
        for (var q = 0u; q < MLP_TILE; q = q + 1u) {
            acc = acc + tile_in[q * MLP_TILE + lid.y] * tile_dz[q * MLP_TILE + lid.x];
        }
        workgroupBarrier();
    }
    let k = row0 + lid.y;
    let c = col0 + lid.x;
    let rows = table[job + 4u];
    if (c >= cols) {
        return;
    }
    if (k < rows) {
        let at = p.base + table[job + 6u] + k * cols + c;
        grads[at] = grads[at] + acc;
    } else if (k == rows && table[job + 7u] != MLP_NO_BIAS) {
        let at = p.base + table[job + 7u] + c;
        grads[at] = grads[at] + acc;
    }
}
