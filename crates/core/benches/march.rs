//! Marching rays through a volume as `render`, the report's camera figure and the reprojection
//! metrics do (`Sampler::march`, the quadrature of `render_image` over a grid read in place):
//! 256² parallel oblique rays through a 128³ volume at half a voxel per step, with this CPU's
//! vector kernel and in scalar code, in one run. Run: `cargo bench -p fluidnerf-core --bench march`.

use std::time::Instant;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::volume::Sampler;
use fluidnerf_core::{Aabb, Ray, Volume};

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
    let n = 128;
    let aabb = Aabb::cube(DVec3::ZERO, 1.0);
    let vol = Volume::from_fn([n; 3], aabb, |p| ((p.x * 9.0).sin() * (p.y * 7.0).cos() + p.z).max(0.0) as f32);
    let step = 0.5 / n as f64;
    // Rays from a plane beyond the box, tilted off every axis.
    let dir = DVec3::new(1.0, 0.31, 0.17).normalize();
    let (u, v) = (dir.cross(DVec3::Z).normalize(), dir.cross(dir.cross(DVec3::Z)).normalize());
    let side = 256;
    let rays: Vec<Ray> = (0..side * side)
        .map(|r| {
            let (a, b) = ((r % side) as f64 / side as f64 - 0.5, (r / side) as f64 / side as f64 - 0.5);
            Ray::new(aabb.centre() - 2.0 * dir + 1.6 * (a * u + b * v), dir)
        })
        .collect();
    let march = |sampler: Sampler| {
        let mut total = 0f64;
        let mut samples = 0usize;
        for ray in &rays {
            let Some((s0, s1)) = aabb.intersect(ray) else { continue };
            let segments = ((s1 - s0) / step).ceil().max(1.0) as usize;
            let ds = (s1 - s0) / segments as f64;
            let mut sum = 0f32;
            sampler.march(ray, (s0, ds), segments, (0, segments), &mut sum);
            total += f64::from(sum * ds as f32);
            samples += segments + 1;
        }
        (total, samples)
    };
    let (_, samples) = march(vol.sampler());
    let (vector, a) = time(5, || march(vol.sampler()).0);
    let (scalar, b) = time(5, || march(vol.sampler().scalar()).0);
    let isa = format!("{:?}", fluidnerf_core::Isa::detected());
    println!(
        "{} rays through {n}^3 voxels, {samples} samples, one thread (best of 5); vector kernel: {isa}",
        rays.len()
    );
    println!("march, vector kernel: {vector:8.4} s  ({:.0} M samples/s)", samples as f64 / vector / 1e6);
    println!("march, scalar:        {scalar:8.4} s  ({:.0} M samples/s)", samples as f64 / scalar / 1e6);
    println!("ratio x{:.2}; sums equal: {}", scalar / vector, a == b);
}
