// The moments of a sample's conical frustum (or cylinder), shared by the kernels that cast
// samples (composed in front of every kernel, after rng.wgsl): mipnerf-core's
// `mip::conical_frustum_moments` in the official code's stable form, operation by operation,
// and `mip::cylinder_moments`. Returns (t_mean, t_var, r_var).
fn frustum_moments(t0: f32, t1: f32, radius: f32, ray_shape: u32) -> vec3<f32> {
    if (ray_shape == RAY_SHAPE_CONE) {
        let mu = (t0 + t1) / 2.0;
        let hw = (t1 - t0) / 2.0;
        let mu2 = mu * mu;
        let hw2 = hw * hw;
        let hw4 = hw2 * hw2;
        let denom = 3.0 * mu2 + hw2;
        let t_mean = mu + (2.0 * mu * hw2) / denom;
        let t_var = hw2 / 3.0 - (4.0 / 15.0) * ((hw4 * (12.0 * mu2 - hw2)) / (denom * denom));
        let r_var = radius * radius * (mu2 / 4.0 + (5.0 / 12.0) * hw2 - 4.0 / 15.0 * hw4 / denom);
        return vec3<f32>(t_mean, t_var, r_var);
    }
    let dt = t1 - t0;
    return vec3<f32>((t0 + t1) / 2.0, dt * dt / 12.0, radius * radius / 4.0);
}
