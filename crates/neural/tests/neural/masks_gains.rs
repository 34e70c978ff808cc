//! Masks and per-view gains in the method layer: masked pixels are never sampled, and gains
//! fitted with the field recover the factors by which views were scaled.

use fluidnerf_core::{render_image, Aabb, RenderSettings};
use fluidnerf_neural::dense::DenseGridField;
use fluidnerf_neural::train::{train_fitting_gains, GainFit, Learner, Prepared, Problem, TrainConfig, View, ViewMasks};
use glam::{DVec3, Vec3};

use crate::common;
use common::ring;

/// A Gaussian blob seen by `n` cameras at 24² px; view `v`'s image scaled by `gains[v]`.
fn blob_problem(gains: &[f32]) -> Problem {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let field = |p: Vec3, _t: f64| (-(p - Vec3::new(0.1, 0.0, -0.1)).length_squared() / 0.18).exp();
    let settings = RenderSettings { scale: 2.0, ..Default::default() };
    let views = ring(gains.len(), 24)
        .into_iter()
        .zip(gains)
        .map(|(camera, &g)| {
            let mut image = render_image(&field, &camera, &aabb, &settings).expect("renders");
            image.data.iter_mut().for_each(|v| *v *= g);
            View { camera, image, time: 0.0 }
        })
        .collect();
    Problem { aabb, intensity_scale: 2.0, views, holdout: Vec::new(), time_step: 1.0 }
}

#[test]
fn masked_pixels_are_never_sampled() {
    let problem = blob_problem(&[1.0; 4]);
    let cfg = TrainConfig { coarse_samples: 16, fine_samples: 0, ..Default::default() };
    let plain = Prepared::new(&problem, &cfg).expect("prepares");
    // Mask out the left half of view 1.
    let mask: Vec<bool> = (0..24 * 24).map(|p| p % 24 >= 12).collect();
    let masks = ViewMasks { train: vec![None, Some(mask.clone()), None, None], holdout: Vec::new() };
    let masked = Prepared::with_masks(&problem, &cfg, &masks).expect("prepares");
    let rays = |p: &Prepared, v: usize| p.views(fluidnerf_neural::train::Split::Train)[v].rays().pixel.clone();
    assert_eq!(rays(&masked, 0), rays(&plain, 0));
    let kept = rays(&masked, 1);
    assert!(kept.iter().all(|&p| mask[p as usize]), "a masked pixel was kept");
    let expected: Vec<u32> = rays(&plain, 1).into_iter().filter(|&p| mask[p as usize]).collect();
    assert_eq!(kept, expected);
    assert!(!kept.is_empty());
    let bad = ViewMasks { train: vec![None], holdout: Vec::new() };
    assert!(Prepared::with_masks(&problem, &cfg, &bad).is_err(), "a mask list of the wrong length is refused");
}

#[test]
fn fitted_gains_recover_the_scaling_of_each_view() {
    let truth = [0.75f32, 1.2, 1.0, 1.05];
    let mean = truth.iter().sum::<f32>() / 4.0;
    let problem = blob_problem(&truth);
    let cfg = TrainConfig {
        coarse_samples: 32,
        fine_samples: 0,
        rays_per_image: 256,
        max_iterations: 300,
        chunk_samples: 4096,
        stop: fluidnerf_neural::train::StopRule { window: 0, ..Default::default() },
        schedule: fluidnerf_neural::optim::LrSchedule { initial: 5e-2, at_decay_iters: 5e-3, decay_iters: 300 },
        ..Default::default()
    };
    let mut prep = Prepared::new(&problem, &cfg).expect("prepares");
    let field = DenseGridField::new([16, 16, 16], 0.0);
    let mut learner = Learner::fresh(field, &prep, &cfg);
    let fit = GainFit { every: 25, rays_per_view: 400, offset: false };
    let (_, gains) =
        train_fitting_gains(&mut prep, &mut learner, &cfg, 3, &fit, |_| std::ops::ControlFlow::Continue(()))
            .expect("trains");
    for (g, t) in gains.iter().zip(truth) {
        assert!((g.0 - t / mean).abs() < 0.03, "fitted {gains:?}, drawn {truth:?}");
    }
}

/// A view with no light (a dead or covered camera) fits no gain, and the gains are normalised
/// over the views that have one: the dark view's unfitted gain used to count in the mean and
/// rescale every other view's.
#[test]
fn a_dark_view_counts_in_no_gain_normalisation() {
    let problem = blob_problem(&[1.0, 1.3, 0.0, 0.8]);
    let cfg = TrainConfig {
        coarse_samples: 16,
        fine_samples: 0,
        rays_per_image: 128,
        max_iterations: 60,
        chunk_samples: 4096,
        stop: fluidnerf_neural::train::StopRule { window: 0, ..Default::default() },
        ..Default::default()
    };
    let mut prep = Prepared::new(&problem, &cfg).expect("prepares");
    let mut learner = Learner::fresh(DenseGridField::new([8, 8, 8], 0.0), &prep, &cfg);
    let fit = GainFit { every: 20, rays_per_view: 200, offset: false };
    let (_, gains) =
        train_fitting_gains(&mut prep, &mut learner, &cfg, 5, &fit, |_| std::ops::ControlFlow::Continue(()))
            .expect("trains");
    let lit = [gains[0].0, gains[1].0, gains[3].0];
    let mean = lit.iter().sum::<f32>() / 3.0;
    assert!((mean - 1.0).abs() < 1e-5, "the lit views' gains average {mean}: {gains:?}");
    assert!(lit[1] > lit[0] && lit[0] > lit[2], "the lit views' order of gains: {gains:?}");
}
