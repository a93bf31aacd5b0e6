// A small MLP (the Tri-Mip field's) with each pass in one dispatch: mipnerf-core's
// `MlpShape::forward` and `backward` for a shape with no skip connection whose layers are at
// most MLP_MAX_WIDTH wide (the product kernels of `matmul.wgsl` run every other shape).
//
// Entry points:
// - `forward`: one invocation per sample runs every layer in order, the activations in two
//   private arrays, and keeps what the backward pass reads in its row of `acts`. The weights
//   are read from two uniform blocks (the trunk and heads, the colour branch), copied there
//   from the parameters before the pass: every invocation reads the same weight at once, which
//   a GPU serves from its constant cache in one broadcast.
// - `backward_samples`: one invocation per sample runs the layers backwards from the raw
//   colours' and raw density's gradients (written by rendering), keeps every layer's
//   pre-activation gradient in its row of `d_acts` and writes the encodings' gradient to `d_x`.
// - `weight_gradients`: one invocation per 4 x 4 block of one layer's kernel (its bias as one
//   more row, of inputs 1) and run of MLP_SPLIT_SAMPLES samples, summing input x output
//   gradient over its samples in order and adding the block to `grads` atomically (as the
//   planes' scatter does; the runs' order of addition is the device's). Which layer part a
//   block belongs to comes from the job list in `table`.
//
// A row of `acts` (and of `d_acts`, the same places): the raw density, the bottleneck
// (`net_width`), the trunk's layers (`net_depth x net_width`, after their ReLU), the colour
// branch's (`depth_condition x width_condition`, after their ReLU). The raw colours go to
// `raw_rgb` (n x 3) and their gradient comes from `d_rgb`. The view direction's encoding enters
// the first colour layer per sample (the CPU multiplies it once per ray: equal to rounding),
// computed from the direction where it is read (the values `view_enc.wgsl` writes).

// The uniform block `Params` is declared from the Rust struct `FusedMlpParams` (kernels/fused_mlp.rs).

@group(0) @binding(0) var<uniform> p: Params;
// Per layer (the shape's order: trunk, density, bottleneck, colour layers, colour output): its
// kernel's and its bias's offsets in its uniform block (`trunk_weights` for the trunk and
// heads, `colour_weights` for the colour branch); then the weight-gradient jobs.
@group(0) @binding(1) var<storage, read> table: array<u32>;
@group(0) @binding(2) var<uniform> trunk_weights: array<vec4<f32>, MLP_UNIFORM_VEC4S>;
@group(0) @binding(3) var<uniform> colour_weights: array<vec4<f32>, MLP_UNIFORM_VEC4S>;
// The encodings, n x x_dim.
@group(0) @binding(4) var<storage, read> x: array<f32>;
// The view directions, three floats per ray: their encoding (`view_encoding.wgsl`, view_dim
// values, of degrees 0..(view_dim - 3) / 6) is computed where it is read.
@group(0) @binding(5) var<storage, read> view_dirs: array<f32>;
@group(0) @binding(6) var<storage, read_write> acts: array<f32>;
@group(0) @binding(7) var<storage, read_write> raw_rgb: array<f32>;
@group(0) @binding(8) var<storage, read> d_rgb: array<f32>;
@group(0) @binding(9) var<storage, read_write> d_acts: array<f32>;
@group(0) @binding(10) var<storage, read_write> d_x: array<f32>;
// The parameters' gradient (`add_to_grads` is generated: kernels::gradient_atomics).
@group(0) @binding(11) var<storage, read_write> grads: array<GradientAtomic>;

// A job of `weight_gradients` (MLP_JOB_WORDS words): the input's source and offset, the output
// gradient's source and offset, input rows (bias not counted), columns, the kernel rows' and the
// bias's offsets in `grads` from `p.base` (MLP_NO_BIAS: none), the job's first 4 x 4 block.
// Input sources: MLP_SOURCE_X (the encodings), MLP_SOURCE_ACTS (a part of `acts`),
// MLP_SOURCE_VIEW (the view encoding of the sample's ray); output-gradient sources:
// MLP_SOURCE_D_ACTS (a part of `d_acts`), MLP_SOURCE_D_RGB (the raw colours' gradient).

fn flat_index(gid: vec3<u32>) -> u32 {
    return gid.y * (p.groups_x * WORKGROUP) + gid.x;
}

// The direction of sample `s`'s ray.
fn view_dir(s: u32) -> vec3<f32> {
    let r = 3u * (s / p.samples_per_ray);
    return vec3<f32>(view_dirs[r], view_dirs[r + 1u], view_dirs[r + 2u]);
}

// The view encoding's degrees (its width is 3 + 6 of them).
fn view_degrees() -> u32 {
    return (max(p.view_dim, 3u) - 3u) / 6u;
}

fn layer_count() -> u32 {
    return p.net_depth + 3u + p.depth_condition;
}

fn colour_weight(i: u32) -> f32 {
    return colour_weights[i >> 2u][i & 3u];
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
        b = trunk_layer(i, fan_in, w, &a);
        for (var o = 0u; o < w; o = o + 1u) {
            acts[r + trunk_at(i) + o] = b[o];
        }
        a = b;
        fan_in = w;
    }
    // The heads: the raw density and the bottleneck (no activation), into b.
    acts[r] = density_head(d, w, &a);
    let kernel_b = table[2u * d + 2u];
    let bias_b = table[2u * d + 3u];
    for (var o = 0u; o < w; o = o + 1u) {
        var z = trunk_weight(bias_b + o);
        for (var k = 0u; k < w; k = k + 1u) {
            z = z + a[k] * trunk_weight(kernel_b + k * w + o);
        }
        b[o] = z;
        acts[r + 1u + o] = z;
    }
    // The first colour layer: [bottleneck | view encoding of the ray] in, into a.
    var view: Activations;
    let dir = view_dir(s);
    for (var k = 0u; k < p.view_dim; k = k + 1u) {
        view[k] = view_encoding(dir, view_degrees(), k);
    }
    let kernel_c = table[2u * d + 4u];
    let bias_c = table[2u * d + 5u];
    for (var o = 0u; o < wc; o = o + 1u) {
        var z = colour_weight(bias_c + o);
        for (var k = 0u; k < w; k = k + 1u) {
            z = z + b[k] * colour_weight(kernel_c + k * wc + o);
        }
        for (var k = 0u; k < p.view_dim; k = k + 1u) {
            z = z + view[k] * colour_weight(kernel_c + (w + k) * wc + o);
        }
        a[o] = max(z, 0.0);
        acts[r + colour_at(0u) + o] = a[o];
    }
    for (var j = 1u; j < p.depth_condition; j = j + 1u) {
        let kernel = table[2u * (d + 2u + j)];
        let bias = table[2u * (d + 2u + j) + 1u];
        for (var o = 0u; o < wc; o = o + 1u) {
            var z = colour_weight(bias + o);
            for (var k = 0u; k < wc; k = k + 1u) {
                z = z + a[k] * colour_weight(kernel + k * wc + o);
            }
            b[o] = max(z, 0.0);
            acts[r + colour_at(j) + o] = b[o];
        }
        a = b;
    }
    let last = layer_count() - 1u;
    let kernel_o = table[2u * last];
    let bias_o = table[2u * last + 1u];
    for (var m = 0u; m < 3u; m = m + 1u) {
        var z = colour_weight(bias_o + m);
        for (var k = 0u; k < wc; k = k + 1u) {
            z = z + a[k] * colour_weight(kernel_o + k * 3u + m);
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
    let kernel_o = table[2u * (layer_count() - 1u)];
    let at_last = r + colour_at(dc - 1u);
    let d_out = vec3<f32>(d_rgb[3u * s], d_rgb[3u * s + 1u], d_rgb[3u * s + 2u]);
    for (var o = 0u; o < wc; o = o + 1u) {
        let k = kernel_o + 3u * o;
        let t = colour_weight(k) * d_out.x + colour_weight(k + 1u) * d_out.y + colour_weight(k + 2u) * d_out.z;
        g[o] = relu_backward(t, acts[at_last + o]);
        d_acts[at_last + o] = g[o];
    }
    for (var j = dc - 1u; j > 0u; j = j - 1u) {
        let kernel = table[2u * (d + 2u + j)];
        let at = r + colour_at(j - 1u);
        for (var o = 0u; o < wc; o = o + 1u) {
            var t = 0.0;
            for (var m = 0u; m < wc; m = m + 1u) {
                t = t + colour_weight(kernel + o * wc + m) * g[m];
            }
            h[o] = relu_backward(t, acts[at + o]);
            d_acts[at + o] = h[o];
        }
        g = h;
    }
    // The first colour layer's bottleneck rows: the bottleneck's gradient (no activation).
    let kernel_c = table[2u * d + 4u];
    for (var o = 0u; o < w; o = o + 1u) {
        var t = 0.0;
        for (var m = 0u; m < wc; m = m + 1u) {
            t = t + colour_weight(kernel_c + o * wc + m) * g[m];
        }
        h[o] = t;
        d_acts[r + 1u + o] = t;
    }
    // Both heads: the top trunk layer's pre-activation gradient.
    let d_density = d_acts[r];
    let kernel_d = table[2u * d];
    let kernel_b = table[2u * d + 2u];
    let top = r + trunk_at(d - 1u);
    for (var o = 0u; o < w; o = o + 1u) {
        var t = trunk_weight(kernel_d + o) * d_density;
        for (var m = 0u; m < w; m = m + 1u) {
            t = t + trunk_weight(kernel_b + o * w + m) * h[m];
        }
        g[o] = relu_backward(t, acts[top + o]);
        d_acts[top + o] = g[o];
    }
    for (var i = d - 1u; i > 0u; i = i - 1u) {
        let kernel = table[2u * i];
        let at = r + trunk_at(i - 1u);
        for (var o = 0u; o < w; o = o + 1u) {
            var t = 0.0;
            for (var m = 0u; m < w; m = m + 1u) {
                t = t + trunk_weight(kernel + o * w + m) * g[m];
            }
            h[o] = relu_backward(t, acts[at + o]);
            d_acts[at + o] = h[o];
        }
        g = h;
    }
    if (p.input_gradient != 0u) {
        let kernel = table[0];
        for (var k = 0u; k < p.x_dim; k = k + 1u) {
            var t = 0.0;
            for (var m = 0u; m < w; m = m + 1u) {
                t = t + trunk_weight(kernel + k * w + m) * g[m];
            }
            d_x[s * p.x_dim + k] = t;
        }
    }
}

// Input row `k` of sample `s` from `source` at `offset` (within `rows`; the bias row `rows`
// reads 1 where `bias` is set; beyond, 0).
fn job_input(source: u32, offset: u32, s: u32, k: u32, rows: u32, bias: bool) -> f32 {
    if (k >= rows) {
        return select(0.0, 1.0, bias && k == rows);
    }
    if (source == MLP_SOURCE_X) {
        return x[s * p.x_dim + offset + k];
    }
    if (source == MLP_SOURCE_VIEW) {
        return view_encoding(view_dir(s), view_degrees(), offset + k);
    }
    return acts[s * p.row + offset + k];
}

// Output gradient `c` of sample `s` from `source` at `offset` (0 beyond `cols`).
fn job_output_gradient(source: u32, offset: u32, s: u32, c: u32, cols: u32) -> f32 {
    if (c >= cols) {
        return 0.0;
    }
    if (source == MLP_SOURCE_D_RGB) {
        return d_rgb[3u * s + offset + c];
    }
    return d_acts[s * p.row + offset + c];
}

@compute @workgroup_size(WORKGROUP)
fn weight_gradients(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_index(gid);
    if (i >= p.blocks * p.runs) {
        return;
    }
    let block = i % p.blocks;
    let run = i / p.blocks;
    let jobs_at = 2u * layer_count();
    var j = 0u;
    while (j + 1u < p.jobs && table[jobs_at + (j + 1u) * MLP_JOB_WORDS + 8u] <= block) {
        j = j + 1u;
    }
    let job = jobs_at + j * MLP_JOB_WORDS;
    let in_source = table[job];
    let in_offset = table[job + 1u];
    let dz_source = table[job + 2u];
    let dz_offset = table[job + 3u];
    let rows = table[job + 4u];
    let cols = table[job + 5u];
    let kernel = table[job + 6u];
    let bias_at = table[job + 7u];
    let bias = bias_at != MLP_NO_BIAS;
    let across = (cols + 3u) / 4u;
    let local = block - table[job + 8u];
    let r0 = (local / across) * 4u;
    let c0 = (local % across) * 4u;
    var acc: array<vec4<f32>, 4>;
    let first = run * MLP_SPLIT_SAMPLES;
    let end = min(first + MLP_SPLIT_SAMPLES, p.n);
    for (var s = first; s < end; s = s + 1u) {
        let dz = vec4<f32>(
            job_output_gradient(dz_source, dz_offset, s, c0, cols),
            job_output_gradient(dz_source, dz_offset, s, c0 + 1u, cols),
            job_output_gradient(dz_source, dz_offset, s, c0 + 2u, cols),
            job_output_gradient(dz_source, dz_offset, s, c0 + 3u, cols),
        );
        for (var rr = 0u; rr < 4u; rr = rr + 1u) {
            acc[rr] = acc[rr] + job_input(in_source, in_offset, s, r0 + rr, rows, bias) * dz;
        }
    }
    for (var rr = 0u; rr < 4u; rr = rr + 1u) {
        let k = r0 + rr;
        for (var cc = 0u; cc < 4u; cc = cc + 1u) {
            let c = c0 + cc;
            if (c >= cols) {
                continue;
            }
            if (k < rows) {
                add_to_grads(p.base + kernel + k * cols + c, acc[rr][cc]);
            } else if (k == rows && bias) {
                add_to_grads(p.base + bias_at + c, acc[rr][cc]);
            }
        }
    }
}
