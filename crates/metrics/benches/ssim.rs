//! Speed of the metrics on a 200³ volume (uniform and Gaussian windowed SSIM, global SSIM,
//! NRMSE), and of resampling a 128³ reconstruction onto a 200³ truth's grid as `eval` does,
//! against sampling each centre on its own. Run: `cargo bench -p fluidnerf-metrics --bench ssim`.

use std::time::Instant;

use fluidnerf_core::{Aabb, Volume};
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
    // A reconstruction on its own box, resampled onto a truth's grid whose box reaches past it.
    let rec = Volume::from_fn([128; 3], Aabb::cube(glam::DVec3::ZERO, 1.0), |p| (p.x * 3.0 + p.y * p.z).sin() as f32);
    let truth_box = Aabb::cube(glam::DVec3::splat(0.05), 1.1);
    let (each, _) = time(3, || {
        let r = Volume::from_fn(dims, truth_box, |p| rec.sample(p.as_vec3()));
        f64::from(r.data[r.data.len() / 2])
    });
    let (grid, _) = time(3, || f64::from(rec.resample(dims, truth_box).data[n * n * n / 2]));
    println!(
        "resample 128^3 -> {n}^3: {grid:8.3} s  (each centre sampled on its own: {each:.3} s, x{:.1})",
        each / grid
    );
}
