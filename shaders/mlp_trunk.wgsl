// The small MLP's trunk and density head as the fused kernels lay it out (mipnerf-core's
// `MlpShape::forward`, its operations in order): included by `fused_mlp.wgsl` and
// `occupancy_probe.wgsl`, which bind `table` (per layer of the shape, its kernel's and bias's
// offsets in its uniform block) and `trunk_weights` (the trunk's and heads' weights, copied from
// the parameters).

alias Activations = array<f32, MLP_MAX_WIDTH>;

fn trunk_weight(i: u32) -> f32 {
    return trunk_weights[i >> 2u][i & 3u];
}

// Trunk layer `i` (`width` outputs) on `a` (`fan_in` values): relu(a W + b).
fn trunk_layer(i: u32, fan_in: u32, width: u32, a: ptr<function, Activations>) -> Activations {
    let kernel = table[2u * i];
    let bias = table[2u * i + 1u];
    var b: Activations;
    for (var o = 0u; o < width; o = o + 1u) {
        var z = trunk_weight(bias + o);
        for (var k = 0u; k < fan_in; k = k + 1u) {
            z = z + (*a)[k] * trunk_weight(kernel + k * width + o);
        }
        b[o] = max(z, 0.0);
    }
    return b;
}

// The raw density (layer `depth`, the density head) on the trunk's last layer `a` (`width`
// values).
fn density_head(depth: u32, width: u32, a: ptr<function, Activations>) -> f32 {
    let kernel = table[2u * depth];
    var density = trunk_weight(table[2u * depth + 1u]);
    for (var k = 0u; k < width; k = k + 1u) {
        density = density + (*a)[k] * trunk_weight(kernel + k);
    }
    return density;
}
