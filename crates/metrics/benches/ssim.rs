//! Speed of the metrics on a 200³ volume (uniform and Gaussian windowed SSIM, global SSIM,
//! NRMSE). Run: `cargo bench -p fluidnerf-metrics --bench ssim`.

use std::time::Instant;

use fluidnerf_metrics::{nrmse, ssim_3d, ssim_global, SsimParams};

fn volume(n: usize, phase: f32) -> Vec<f32> {
    (0..n * n * n)
        .map(|idx| {
            let (i, j, k) = (idx % n, (idx / n) % n, idx / (n * n));
            let (x, y, z) = (i as f32 / n as f32, j as f32 / n as f32, k as f32 / n as f32);
            (0.5 + 0.5 * (9.0 * x + phase).sin() * (7.0 * y).cos() * (5.0 * z + phase).sin()).max(0.0)
        })
        .collect()
}

/// Best of `reps` wall times in seconds, and the last result.
fn time(reps: usize, mut f: impl FnMut() -> f64) -> (f64, f64) {
    let mut best = f64::INFINITY;
    let mut value = 0.0;
    for _ in 0..reps {
        let t = Instant::now();
        value = f();
        best = best.min(t.elapsed().as_secs_f64());
    }
    (best, value)
}

#[allow(clippy::print_stdout)]
fn main() {
    let n = 200;
    let (a, b) = (volume(n, 0.0), volume(n, 0.2));
    let dims = [n; 3];
    println!("metrics on {n}^3 voxels, {} rayon threads (best of 3)", rayon::current_num_threads());
    let (t, v) = time(3, || ssim_3d(&a, &b, dims, &SsimParams::default()).unwrap_or(f64::NAN));
    println!("ssim_3d uniform 7:      {:8.3} s  (SSIM {v:.6})", t);
    let (t, v) = time(3, || ssim_3d(&a, &b, dims, &SsimParams::gaussian()).unwrap_or(f64::NAN));
    println!("ssim_3d gaussian 1.5:   {:8.3} s  (SSIM {v:.6})", t);
    let (t, v) = time(3, || ssim_global(&a, &b, 1.0));
    println!("ssim_global:            {:8.3} s  (SSIM {v:.6})", t);
    let (t, v) = time(3, || nrmse(&a, &b));
    println!("nrmse:                  {:8.3} s  (NRMSE {v:.6})", t);
}
