//! SART with second-order Tikhonov regularisation on noisy images: the default and a tuned
//! weight beat plain SART, the penalty is what falls, and weight 0 is plain SART.

use crate::common;

use std::ops::ControlFlow;

use common::*;
use fluidnerf_classical::*;
use fluidnerf_core::Image;

const SCALE: f64 = 2.5;

/// Images of `phantom` with additive Gaussian noise of standard deviation `fraction` × the
/// image's maximum (Box–Muller on a seeded sequence).
fn noisy(phantom: Phantom, cams: &[fluidnerf_core::Camera], fraction: f32, seed: u64) -> Vec<Image> {
    let mut images = render(phantom, cams, SCALE);
    for (v, img) in images.iter_mut().enumerate() {
        let sigma = fraction * img.min_max().1;
        let u = uniform(seed + v as u64, 2 * img.data.len());
        for (p, pair) in img.data.iter_mut().zip(u.chunks(2)) {
            let r = (-2.0 * (1.0 - pair[0]).ln()).sqrt();
            *p += sigma * r * (std::f32::consts::TAU * pair[1]).cos();
        }
    }
    images
}

/// Runs a solver and returns its report with the NRMSE of every iteration.
fn with_curve(
    truth: &[f32],
    solve: impl FnOnce(&mut dyn FnMut(&IterState) -> ControlFlow<()>) -> Report,
) -> (Report, Vec<f64>) {
    let mut curve = Vec::new();
    let report = solve(&mut |s| {
        curve.push(nrmse(s.volume, truth));
        ControlFlow::Continue(())
    });
    (report, curve)
}

/// 24³ voxels, 8 views of 48² px, images with 5 % Gaussian noise, default stopping rules.
/// Measured NRMSE (blobs / ball): SART 0.575 / 0.473 at the end (0.301 / 0.357 at its best
/// iteration, which only the truth can find); SART-Tikhonov with the default λ = 0.003:
/// 0.437 / 0.386, with ‖∇²g‖² 0.38 / 0.41 times SART's. λ = 0.1 suits the smooth blobs: 0.185,
/// better than SART's best iteration.
#[test]
fn tikhonov_beats_sart_on_noisy_images() {
    let grid = Grid::new([24, 24, 24], aabb());
    let cams = ring(8, 48);
    let projector = SplatProjector::new(grid, &cams, SCALE).expect("valid");
    for (name, phantom) in [("blobs", blobs as Phantom), ("ball", ball as Phantom)] {
        let t = truth(&grid, phantom).data;
        let images = noisy(phantom, &cams, 0.05, 7);
        let problem = Problem::new(&projector, &images).expect("consistent");
        let (plain, plain_curve) = with_curve(&t, |f| sart(&problem, None, &SartParams::default(), f).expect("runs"));
        let mut min = f32::INFINITY;
        let (reg, _) = with_curve(&t, |f| {
            sart_tikhonov(&problem, None, &TikhonovParams::default(), |s| {
                min = min.min(s.volume.iter().cloned().fold(f32::INFINITY, f32::min));
                f(s)
            })
            .expect("runs")
        });
        let (e_plain, e_reg) = (nrmse(&plain.volume, &t), nrmse(&reg.volume, &t));
        assert!(min >= 0.0, "{name}: negative voxel {min}");
        assert!(e_reg < 0.9 * e_plain, "{name}: Tikhonov {e_reg:.4} vs SART {e_plain:.4}");
        let (p_plain, p_reg) = (laplacian_norm2(&grid, &plain.volume), laplacian_norm2(&grid, &reg.volume));
        assert!(p_reg < 0.5 * p_plain, "{name}: penalty ‖∇²g‖² {p_reg:.3e} vs SART's {p_plain:.3e}");
        if name == "blobs" {
            let tuned = TikhonovParams { weight: 0.1, ..Default::default() };
            let r = sart_tikhonov(&problem, None, &tuned, |_| ControlFlow::Continue(())).expect("runs");
            let e = nrmse(&r.volume, &t);
            let best_plain = plain_curve.iter().cloned().fold(f64::INFINITY, f64::min);
            assert!(e < 0.21, "blobs, λ = 0.1: NRMSE {e:.4}");
            assert!(e < best_plain, "blobs, λ = 0.1: {e:.4} vs SART's best iteration {best_plain:.4}");
        }
    }
}

/// λ = 0 is SART, bit for bit; a support mask holds the regularised volume at zero outside.
#[test]
fn zero_weight_is_sart_and_support_is_kept() {
    let grid = Grid::new([16, 16, 16], aabb());
    let cams = ring(6, 32);
    let projector = SplatProjector::new(grid, &cams, SCALE).expect("valid");
    let images = noisy(blobs, &cams, 0.02, 3);
    let problem = Problem::new(&projector, &images).expect("consistent");
    let stopping = Stopping { max_iterations: 6, plateau: None };
    let a = sart(&problem, None, &SartParams { stopping, ..Default::default() }, |_| ControlFlow::Continue(()))
        .expect("runs");
    let b = sart_tikhonov(&problem, None, &TikhonovParams { weight: 0.0, stopping, ..Default::default() }, |_| {
        ControlFlow::Continue(())
    })
    .expect("runs");
    assert_eq!(a.volume, b.volume);
    assert_eq!(a.residual_history, b.residual_history);

    let hull = visual_hull(&grid, &cams, &images, 0.1, 0.0, 0);
    let masked = problem.with_support(&hull);
    // A large weight takes many sub-steps; it must stay stable and inside the support.
    let params = TikhonovParams { weight: 3.0, stopping, ..Default::default() };
    let r = sart_tikhonov(&masked, None, &params, |_| ControlFlow::Continue(())).expect("runs");
    assert!(r.volume.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(r.volume.iter().zip(&hull).all(|(&v, &h)| h || v == 0.0), "value outside the support");
    assert!(r.volume.iter().any(|&v| v > 0.0), "everything was smoothed away");

    let bad = TikhonovParams { weight: -1.0, ..Default::default() };
    let err = sart_tikhonov(&problem, None, &bad, |_| ControlFlow::Continue(())).expect_err("negative weight");
    assert!(err.to_string().contains("Tikhonov weight"), "{err}");
}

/// With 5 % noise (clipped at the floor) the threshold alone (2 % of each image's maximum)
/// carves at random: the brightest of four background pixels lies above it at most voxels and
/// below it at some. Counting four deviations of the images' noise as dark, and dilating by one
/// voxel, carves most of the empty box and keeps every voxel of the ball; ASART inside that hull
/// does better than without one, and better than inside the threshold's.
#[test]
fn a_noisy_scenes_hull_is_carved_above_its_noise() {
    let grid = Grid::new([24, 24, 24], aabb());
    let cams = ring(8, 48);
    let mut images = noisy(ball, &cams, 0.05, 11);
    // Clipped at the floor, as a sensor with its dark level subtracted gives them.
    images.iter_mut().for_each(|img| img.data.iter_mut().for_each(|p| *p = p.max(0.0)));
    let truth = truth(&grid, ball).data;
    let object = truth.iter().filter(|&&t| t > 0.0).count();
    let kept = |hull: &[bool]| hull.iter().filter(|&&h| h).count();

    let threshold_alone = visual_hull(&grid, &cams, &images, DEFAULT_HULL_THRESHOLD, 0.0, 0);
    let hull = visual_hull(&grid, &cams, &images, DEFAULT_HULL_THRESHOLD, DEFAULT_HULL_NOISE_SIGMAS, 1);
    assert!(truth.iter().zip(&hull).all(|(&t, &h)| t <= 0.0 || h), "the hull cut into the ball");
    assert!(kept(&hull) < 3 * object, "hull keeps {} voxels for a {object}-voxel ball", kept(&hull));
    assert!(kept(&threshold_alone) > 3 * object, "the threshold keeps {}", kept(&threshold_alone));

    let projector = SplatProjector::new(grid, &cams, SCALE).expect("valid");
    let problem = Problem::new(&projector, &images).expect("consistent");
    let params = AsartParams { stopping: Stopping { max_iterations: 10, plateau: None }, ..Default::default() };
    let run =
        |p: &Problem| nrmse(&asart(p, None, &params, |_| ControlFlow::Continue(())).expect("runs").volume, &truth);
    // Measured: no hull 0.355, the threshold's 0.378, the noise-aware one 0.324.
    let (free, by_threshold, by_noise) =
        (run(&problem), run(&problem.with_support(&threshold_alone)), run(&problem.with_support(&hull)));
    assert!(by_noise < free && by_noise < by_threshold, "{by_noise:.4} vs {free:.4} and {by_threshold:.4}");
}
