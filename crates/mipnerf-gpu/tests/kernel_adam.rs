//! Adam's kernel (`adam.wgsl`), gradient clipping included, against `stages::adam_step`.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

#[test]
fn adam_and_gradient_clipping_match_cpu_reference() {
    use mipnerf_core::stages::AdamStep;
    use mipnerf_core::train::{AdamConfig, AdamState, FieldAdam};
    use mipnerf_gpu::kernels::adam::{AdamBuffers, AdamKernel};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("adam_and_gradient_clipping_match_cpu_reference") else { return };
    let kernel = AdamKernel::new(&ctx).unwrap();
    // More than one workgroup of the norm's first pass (256), not a multiple of it.
    let n = 1000;
    let (cfg, lr) = (AdamConfig::default(), 1e-3);
    let mut bad = Vec::new();
    // (max_val, max_norm): off; by value (some entries clipped); by norm (the norm of 1000 entries
    // of about 0.06 is about 1.8, so it is scaled); both. Then a field's own first 300
    // parameters at 10 times the rate with a tiny epsilon (the Tri-Mip planes' split), with and
    // without clipping by norm.
    let planes = Some((300, FieldAdam { lr_mult: 10.0, eps: 1e-15, skip_untouched: false }));
    // The same with the field's untouched entries skipped, some gradients 0 on both sides of the
    // split.
    let sparse = Some((300, FieldAdam { lr_mult: 10.0, eps: 1e-15, skip_untouched: true }));
    // Last, the MLP's L2 (Instant-NGP's, here large enough to move every update: 0.05 x
    // parameters of about 0.5 against gradients of about 0.05), over all the parameters and
    // after a field's.
    let cases = [
        (0.0, 0.0, None, 0.0),
        (0.05, 0.0, None, 0.0),
        (0.0, 0.5, None, 0.0),
        (0.08, 1.0, None, 0.0),
        (0.0, 0.0, planes, 0.0),
        (0.0, 0.5, planes, 0.0),
        (0.0, 0.0, sparse, 0.0),
        (0.0, 0.5, sparse, 0.0),
        (0.0, 0.0, None, 0.05),
        (0.0, 0.5, planes, 0.05),
    ];
    for (max_val, max_norm, split, l2) in cases {
        let step = AdamStep { cfg: AdamConfig { l2, ..cfg }, lr, max_val, max_norm, split };
        // The starting parameters and three steps' gradients.
        let mut rng = SmallRng::seed_from_u64(3);
        let params: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut steps: Vec<Vec<f32>> = (0..3).map(|_| (0..n).map(|_| rng.random_range(-0.1..0.1)).collect()).collect();
        if split.is_some_and(|(_, f)| f.skip_untouched) {
            // After the first step, a third of the first 400 entries untouched, others each step.
            for (k, grads) in steps.iter_mut().enumerate().skip(1) {
                grads.iter_mut().take(400).skip(k).step_by(3).for_each(|g| *g = 0.0);
            }
        }
        let cpu = |(params, steps): &(Vec<f32>, Vec<Vec<f32>>)| -> Outputs {
            let (mut params, mut state, mut norms) = (params.clone(), AdamState::new(n), Vec::new());
            for grads in steps {
                let norm = stages::adam_step(&step, &mut state, &mut params, &mut grads.clone());
                norms.push(norm);
            }
            let norms = if max_norm > 0.0 { norms } else { Vec::new() };
            vec![("params", params), ("m", state.m), ("v", state.v), ("gradient norm", norms)]
        };
        let on_gpu = |(params, steps): &(Vec<f32>, Vec<Vec<f32>>)| -> Result<Outputs, GpuError> {
            let b = AdamBuffers::new(&ctx, params, &vec![0.0; n], &vec![0.0; n]);
            let mut norms = Vec::new();
            for (t, grads) in (1..).zip(steps) {
                ctx.queue().write_buffer(&b.grads, 0, bytemuck::cast_slice(grads));
                let mut rec = Recorder::new(&ctx, "adam test");
                kernel.encode(&mut rec, &step, t, &b)?;
                let _ = rec.submit();
                if max_norm > 0.0 {
                    norms.push(ctx.read_f32(&b.stats, 1)?[0]);
                }
            }
            Ok(vec![
                ("params", ctx.read_f32(&b.params, n)?),
                ("m", ctx.read_f32(&b.m, n)?),
                ("v", ctx.read_f32(&b.v, n)?),
                ("gradient norm", norms),
            ])
        };
        let tol = |name: &str| match name {
            "params" => Tolerance::new(1e-7, 1e-6),
            "m" => Tolerance::new(1e-9, 1e-6),
            "v" => Tolerance::new(1e-12, 1e-5),
            _ => Tolerance::new(0.0, 1e-5),
        };
        let label = format!("max_val {max_val} max_norm {max_norm} split {split:?}");
        bad.extend(check_kernel(&label, cpu, on_gpu, &(params, steps), tol).into_mismatches());
    }
    assert_none(&bad);
}
