// The density's activation (composed in front of every kernel, after frustum.wgsl):
// mipnerf-core's `DensityActivation::forward` of `raw + bias`, softplus in its stable form or
// ReLU, for the kernels that turn the MLP's raw density into a density (rendering, the
// occupancy grid's update).
fn activated_density(raw: f32, bias: f32, activation: u32) -> f32 {
    let x = raw + bias;
    if (activation == DENSITY_SOFTPLUS) {
        return max(x, 0.0) + log(1.0 + exp(-abs(x)));
    }
    return max(x, 0.0);
}
