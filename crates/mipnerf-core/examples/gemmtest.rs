#![allow(unsafe_code)]
fn main() {
    let (m, k, n) = (16384usize, 256usize, 256usize);
    let a = vec![0.5f32; m * k];
    let b = vec![0.25f32; k * n];
    let mut c = vec![0.0f32; m * n];
    for par in [gemm::Parallelism::None, gemm::Parallelism::Rayon(2)] {
        for _ in 0..3 {
            let t = std::time::Instant::now();
            unsafe {
                gemm::gemm(
                    m,
                    n,
                    k,
                    c.as_mut_ptr(),
                    1,
                    n as isize,
                    false,
                    a.as_ptr(),
                    1,
                    k as isize,
                    b.as_ptr(),
                    1,
                    n as isize,
                    1.0,
                    1.0,
                    false,
                    false,
                    false,
                    par,
                );
            }
            let s = t.elapsed().as_secs_f64();
            println!("{par:?}: {:.1} GFLOP/s", 2.0 * (m * k * n) as f64 / s / 1e9);
        }
    }
}
