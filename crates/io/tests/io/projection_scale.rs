//! Projection matrices are cameras at any scale: one written at an extreme scale gives back the
//! camera it was scaled from.

use fluidnerf_core::glam::{DAffine3, DMat3, DVec3};
use fluidnerf_core::{Camera, Distortion, Intrinsics};
use fluidnerf_io::calib::{camera_from_projection, projection_of};

/// A matrix scaled by 1e300 overflowed the decomposition and was refused as "invalid intrinsics:
/// values must be finite"; one scaled by 1e-120 underflowed its determinant and was refused as
/// singular ("determinant 0 against 0"). Both give back the camera; a zero matrix says so.
#[test]
fn a_projection_matrix_at_an_extreme_scale_gives_back_its_camera() {
    let rotation = DMat3::from_axis_angle(DVec3::new(0.3, -1.0, 0.2).normalize(), 2.1);
    let camera = Camera {
        intrinsics: Intrinsics { width: 64, height: 48, fx: 81.25, fy: 79.5, cx: 33.25, cy: 23.5, skew: 0.0 },
        distortion: Distortion::default(),
        world_from_camera: DAffine3::from_mat3_translation(rotation, DVec3::new(0.5, -0.25, 700.0)).inverse(),
        lens: None,
    };
    let p = projection_of(&camera);
    for s in [1e300, -1e300, 1e-120, -1e-300] {
        let scaled = p.map(|r| r.map(|v| v * s));
        let got = camera_from_projection(scaled, 64, 48).unwrap_or_else(|e| panic!("scale {s:e}: {e}"));
        let (a, b) = (&got.intrinsics, &camera.intrinsics);
        for (x, y) in [(a.fx, b.fx), (a.fy, b.fy), (a.cx, b.cx), (a.cy, b.cy), (a.skew, b.skew)] {
            assert!((x - y).abs() < 1e-9 * (1.0 + y.abs()), "scale {s:e}: {x} against {y}");
        }
        let (ma, mb) = (got.world_from_camera.to_cols_array(), camera.world_from_camera.to_cols_array());
        for (x, y) in ma.iter().zip(mb) {
            assert!((x - y).abs() < 1e-9 * (1.0 + y.abs()), "scale {s:e}: {ma:?} against {mb:?}");
        }
    }
    let e = camera_from_projection([[0.0; 4]; 3], 64, 48).expect_err("a zero matrix is no camera");
    assert!(e.contains("zero throughout"), "{e}");
}
