//! Fixtures shared by the method's integration tests.

use fluidnerf_core::{Camera, Intrinsics};
use glam::DVec3;

/// `n` cameras on a half ring around the x axis (like the jet rigs), `px²` pixels, 5 units from
/// the origin, looking at it; a box of side 2 at the origin fills most of each image.
pub fn ring(n: usize, px: u32) -> Vec<Camera> {
    let k = Intrinsics {
        width: px,
        height: px,
        fx: px as f64 * 1.9,
        fy: px as f64 * 1.9,
        cx: (px as f64 - 1.0) / 2.0,
        cy: (px as f64 - 1.0) / 2.0,
        skew: 0.0,
    };
    (0..n)
        .map(|c| {
            let a = std::f64::consts::PI * c as f64 / n as f64;
            Camera::look_at(k, DVec3::new(0.0, 5.0 * a.cos(), 5.0 * a.sin()), DVec3::ZERO, DVec3::X)
        })
        .collect()
}
