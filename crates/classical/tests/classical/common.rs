//! Shared fixtures: small ring rigs, analytic phantoms and their rendered images.

use fluidnerf_classical::Grid;
use fluidnerf_core::{render_image, Aabb, Camera, Distortion, Image, Intrinsics, RenderSettings, Volume};
use glam::{DVec3, Vec3};

/// The reconstruction box: a 2-unit cube at the origin.
pub fn aabb() -> Aabb {
    Aabb::cube(DVec3::ZERO, 2.0)
}

/// `n` pinhole cameras evenly spaced over 180° in the y–z plane (perpendicular to the x axis,
/// like the dissertation's planar ring), 6 units from the centre, `px × px` pixels, focal length
/// such that the box fills about 70 % of the image.
pub fn ring(n: usize, px: u32) -> Vec<Camera> {
    let f = 0.7 * px as f64 * 6.0 / (2.0 * 3f64.sqrt());
    let k = Intrinsics {
        width: px,
        height: px,
        fx: f,
        fy: f,
        cx: (px as f64 - 1.0) / 2.0,
        cy: (px as f64 - 1.0) / 2.0,
        skew: 0.0,
    };
    (0..n)
        .map(|i| {
            let a = i as f64 * std::f64::consts::PI / n as f64 + 0.1;
            Camera::look_at(k, DVec3::new(0.0, 6.0 * a.cos(), 6.0 * a.sin()), DVec3::ZERO, DVec3::X)
        })
        .collect()
}

/// Like [`ring`] with noticeable lens distortion, skew and a tilted pose on every camera.
pub fn distorted_ring(n: usize, px: u32) -> Vec<Camera> {
    ring(n, px)
        .into_iter()
        .enumerate()
        .map(|(i, mut c)| {
            c.intrinsics.skew = 0.4;
            c.intrinsics.fy *= 1.03;
            c.distortion = Distortion {
                k1: -0.15 + 0.02 * i as f64,
                k2: 0.04,
                p1: 8e-4,
                p2: -6e-4,
                k3: -0.01,
                ..Default::default()
            };
            let tilt = glam::DMat3::from_axis_angle(DVec3::new(0.3, 1.0, 0.2).normalize(), 0.05 * (i as f64 + 1.0));
            c.world_from_camera.matrix3 = tilt * c.world_from_camera.matrix3;
            c
        })
        .collect()
}

/// A phantom: value at a world point.
pub type Phantom = fn(DVec3) -> f64;

/// Uniform ball of radius 0.55 and value 1, centred a little off the origin.
pub fn ball(p: DVec3) -> f64 {
    if (p - DVec3::new(0.1, -0.05, 0.08)).length() <= 0.55 {
        1.0
    } else {
        0.0
    }
}

/// Two Gaussian blobs of different size and height.
pub fn blobs(p: DVec3) -> f64 {
    let a = (-(p - DVec3::new(-0.35, 0.2, -0.1)).length_squared() / (2.0 * 0.18f64.powi(2))).exp();
    let b = 0.6 * (-(p - DVec3::new(0.4, -0.25, 0.3)).length_squared() / (2.0 * 0.25f64.powi(2))).exp();
    a + b
}

/// The phantom at the voxel centres of `grid` (the ground truth a reconstruction is judged by).
pub fn truth(grid: &Grid, phantom: Phantom) -> Volume {
    Volume::from_fn(grid.dims, grid.aabb, move |p| phantom(p) as f32)
}

/// Pinhole images of the analytic phantom (anti-aliased line integrals, 3 × 3 rays per pixel).
pub fn render(phantom: Phantom, cameras: &[Camera], scale: f64) -> Vec<Image> {
    let field = move |p: Vec3, _t: f64| phantom(p.as_dvec3()) as f32;
    let s = RenderSettings { supersample: 3, scale, step: Some(0.01), ..Default::default() };
    cameras.iter().map(|c| render_image(&field, c, &aabb(), &s).expect("renders")).collect()
}

/// NRMSE = sqrt(Σ (E − Ê)² / Σ Ê²) (dissertation Eq. 6.18).
pub fn nrmse(estimate: &[f32], truth: &[f32]) -> f64 {
    let (mut num, mut den) = (0f64, 0f64);
    for (&e, &t) in estimate.iter().zip(truth) {
        num += ((e - t) as f64).powi(2);
        den += (t as f64).powi(2);
    }
    (num / den).sqrt()
}

/// A deterministic pseudo-random sequence in [0, 1) (SplitMix64).
pub fn uniform(seed: u64, n: usize) -> Vec<f32> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}
