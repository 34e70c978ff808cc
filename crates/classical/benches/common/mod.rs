//! Fixtures shared by the classical benchmarks.

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{Grid, IterState, Projector};
use fluidnerf_core::{Camera, Image, Intrinsics, Volume};
use glam::DVec3;

/// `n` cameras of `px`² px on a ring of radius 360 mm around the x axis, looking at the origin.
pub fn ring(n: usize, px: u32) -> Vec<Camera> {
    // 40 mm field of view at 360 mm plus a margin for the cube's depth.
    let f = px as f64 * 360.0 / 48.0;
    let c = (px as f64 - 1.0) / 2.0;
    let k = Intrinsics { width: px, height: px, fx: f, fy: f, cx: c, cy: c, skew: 0.0 };
    (0..n)
        .map(|i| {
            let a = i as f64 * 2.0 * std::f64::consts::PI / n as f64;
            Camera::look_at(k, DVec3::new(0.0, 360.0 * a.cos(), 360.0 * a.sin()), DVec3::ZERO, DVec3::X)
        })
        .collect()
}

/// A smooth, dense test volume: a Gaussian jet along x, modulated along it.
#[allow(dead_code)] // not every benchmark uses every fixture
pub fn smooth_jet(grid: &Grid) -> Volume {
    Volume::from_fn(grid.dims, grid.aabb, |p| {
        ((-(p.y * p.y + p.z * p.z) / 60.0).exp() * (1.0 + 0.3 * (p.x / 3.0).sin())) as f32
    })
}

/// Mean seconds per iteration of a solver run, from the second iteration on (the first
/// carries the setup): `run` passes the callback it is given as the solver's `on_iter`.
#[allow(dead_code)] // not every benchmark uses every fixture
pub fn per_iteration(run: impl FnOnce(&mut dyn FnMut(&IterState) -> ControlFlow<()>)) -> f64 {
    let mut stamps = Vec::new();
    run(&mut |_| {
        stamps.push(Instant::now());
        ControlFlow::Continue(())
    });
    let d: Vec<f64> = stamps.windows(2).map(|w| (w[1] - w[0]).as_secs_f64()).collect();
    d.iter().sum::<f64>() / d.len().max(1) as f64
}

/// The images of `x` in every view of `p`: the data the solver benchmarks reconstruct from.
#[allow(dead_code)] // not every benchmark uses every fixture
pub fn project_all(p: &dyn Projector, x: &[f32]) -> Vec<Image> {
    p.cameras()
        .iter()
        .enumerate()
        .map(|(v, c)| {
            let mut im = Image::zeros(c.width(), c.height());
            p.forward(v, x, &mut im.data);
            im
        })
        .collect()
}
