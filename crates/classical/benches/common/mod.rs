//! Fixtures shared by the classical benchmarks.

use fluidnerf_core::{Camera, Intrinsics};
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
