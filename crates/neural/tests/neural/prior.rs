//! The point-sampled prior ([`fluidnerf_neural::prior`]): its gradient against central finite
//! differences, its reproducibility from the batch's stream keys, its agreement with the dense
//! grid's prior, and its effect: on noisy images it lowers the error of a hash-grid field
//! (measured: NRMSE 0.606 with TV 2e-3 against 0.787 without).

use fluidnerf_core::{render_image, Aabb, Image, RenderSettings, Volume};
use fluidnerf_neural::batch::RayBatch;
use fluidnerf_neural::dense::DenseGridField;
use fluidnerf_neural::prior::{add_point_prior, PriorScratch};
use fluidnerf_neural::train::{Learner, Prepared, Problem, Split, StopRule, TrainConfig, View};
use fluidnerf_neural::{
    Activation, HashGridConfig, HashGridField, MlpConfig, MlpField, OutputActivation, Prior, TrainableField,
};
use glam::{DVec3, Vec3};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::common;
use common::ring;

fn blob(p: DVec3) -> f32 {
    let a = (-(p - DVec3::new(0.2, 0.0, 0.1)).length_squared() / (2.0 * 0.2 * 0.2)).exp();
    let b = 0.6 * (-(p - DVec3::new(-0.35, 0.15, -0.1)).length_squared() / (2.0 * 0.12 * 0.12)).exp();
    (a + b) as f32
}

fn aabb() -> Aabb {
    Aabb::cube(DVec3::ZERO, 2.0)
}

fn problem(cameras: usize, px: u32, noise: f32, seed: u64) -> Problem {
    let settings = RenderSettings { supersample: 2, scale: 3.0, ..Default::default() };
    let field = |p: Vec3, _: f64| blob(p.as_dvec3());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let views = ring(cameras, px)
        .into_iter()
        .map(|camera| {
            let mut image: Image = render_image(&field, &camera, &aabb(), &settings).expect("renders");
            let peak = image.min_max().1;
            let normal = Normal::new(0.0f32, noise * peak).expect("normal");
            for v in &mut image.data {
                *v += normal.sample(&mut rng);
            }
            View { camera, image, time: 0.0 }
        })
        .collect();
    Problem { aabb: aabb(), intensity_scale: 3.0, views, holdout: Vec::new(), time_step: 1.0 }
}

fn batch(stream: usize) -> RayBatch {
    RayBatch { split: Split::Train, rays: Vec::new(), seed: 11, stream, jitter: Vec::new(), group: 1 }
}

fn prior_value<F: TrainableField>(field: &F, prep: &Prepared, prior: &Prior, stream: usize) -> (f32, Vec<f32>) {
    let mut grads = vec![0.0; field.num_params()];
    let mut tape = field.new_tape();
    let v = add_point_prior(field, prep, prior, &batch(stream), &mut tape, &mut PriorScratch::default(), &mut grads);
    (v, grads)
}

#[test]
fn the_point_prior_gradient_matches_finite_differences() {
    let prep = Prepared::new(&problem(3, 12, 0.0, 1), &TrainConfig::default()).expect("prepares");
    let cfg = MlpConfig {
        depth: 3,
        width: 8,
        space_freqs: 2,
        time_freqs: 0,
        activation: Activation::Swish,
        output_activation: OutputActivation::Softplus,
        skip: false,
    };
    let mut field = MlpField::new(&cfg, 3, 5).expect("field");
    // Large enough steps that the differences are well above f32 rounding.
    let prior = Prior { tv: 0.5, smooth: 0.3, sparsity: 0.2, points: 64, step: 0.2 };
    let (v0, grads) = prior_value(&field, &prep, &prior, 4);
    assert!(v0 > 0.0);
    // The same keys draw the same points; another iteration draws others.
    assert_eq!(prior_value(&field, &prep, &prior, 4).0, v0);
    assert_ne!(prior_value(&field, &prep, &prior, 5).0, v0);
    let h = 1e-2f32;
    let mut worst = 0.0f64;
    for i in 0..field.num_params() {
        let p0 = field.params()[i];
        field.params_mut()[i] = p0 + h;
        let lp = prior_value(&field, &prep, &prior, 4).0 as f64;
        field.params_mut()[i] = p0 - h;
        let lm = prior_value(&field, &prep, &prior, 4).0 as f64;
        field.params_mut()[i] = p0;
        let fd = (lp - lm) / (2.0 * h as f64);
        let an = grads[i] as f64;
        let err = (fd - an).abs() - (3e-4 + 2e-2 * fd.abs().max(an.abs()));
        worst = worst.max(err);
        assert!(err <= 0.0, "parameter {i}: finite difference {fd:.6e}, analytic {an:.6e}");
    }
}

#[test]
fn the_point_prior_estimates_the_dense_grid_prior() {
    // A dense grid of 16³ cells over the box, step = one cell: the point estimate samples the
    // same forward differences as the grid's own prior (mean over cells), so the two agree to
    // Monte Carlo accuracy when no cell is empty.
    let dims = [16usize, 16, 16];
    let raw: Vec<f32> = (0..16 * 16 * 16)
        .map(|c| {
            let (i, j, k) = (c % 16, (c / 16) % 16, c / 256);
            let p = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) / 8.0 - DVec3::ONE;
            // Inverse softplus of the blob, so the grid's E is the blob.
            let e = blob(p).max(1e-4) as f64;
            (e.exp_m1().ln()) as f32
        })
        .collect();
    let field = DenseGridField::from_raw(dims, raw);
    let prep = Prepared::new(&problem(3, 12, 0.0, 1), &TrainConfig::default()).expect("prepares");
    let exact = {
        let mut g = vec![0.0; field.num_params()];
        field.add_prior(&Prior { tv: 1.0, smooth: 2.0, sparsity: 0.1, ..Prior::default() }, &mut g)
    };
    let estimate = {
        // Through the generic path: the dense grid interpolates trilinearly, so points one cell
        // apart see differences of cell values (plus interpolation), a close estimate.
        let prior = Prior { tv: 1.0, smooth: 2.0, sparsity: 0.1, points: 20_000, step: 1.0 / 16.0 };
        (0..4).map(|s| prior_value(&field, &prep, &prior, s).0 as f64).sum::<f64>() / 4.0
    };
    let rel = (estimate - exact as f64).abs() / exact as f64;
    assert!(rel < 0.25, "point estimate {estimate:.4e} vs the grid's prior {exact:.4e} ({:.1} %)", 100.0 * rel);
}

#[test]
fn a_tv_prior_lowers_the_error_of_a_grid_field_on_noisy_images() {
    let p = problem(6, 24, 0.05, 7);
    let grid = HashGridConfig {
        levels: 6,
        features_per_level: 2,
        log2_table_size: 14,
        base_resolution: 4,
        max_resolution: 48,
        mlp_depth: 1,
        mlp_width: 16,
        ..HashGridConfig::default()
    };
    let truth = Volume::from_fn([24, 24, 24], aabb(), blob);
    let error = |tv: f32| {
        let mut cfg = TrainConfig {
            rays_per_image: 256,
            coarse_samples: 32,
            fine_samples: 0,
            max_iterations: 400,
            validate_every: 0,
            stop: StopRule { window: 0, ..Default::default() },
            prior: Prior { tv, points: 1024, step: 1.0 / 48.0, ..Prior::default() },
            ..Default::default()
        };
        cfg.schedule.initial = 2e-2;
        cfg.schedule.at_decay_iters = 2e-3;
        cfg.schedule.decay_iters = 400;
        let prep = Prepared::new(&p, &cfg).expect("prepares");
        let field = HashGridField::new(&grid, 3, 3).expect("field");
        let mut learner = Learner::fresh(field, &prep, &cfg);
        fluidnerf_neural::train::train(&prep, &mut learner, &cfg, 9, |_| std::ops::ControlFlow::Continue(()))
            .expect("trains");
        let world = fluidnerf_neural::trained::WorldField {
            field: &learner.field,
            meta: &prep.meta,
            occupancy: prep.occupancy(),
        };
        let v = Volume::from_field([24, 24, 24], aabb(), &world, 0.0);
        let num: f64 = v.data.iter().zip(&truth.data).map(|(a, b)| ((a - b) as f64).powi(2)).sum();
        let den: f64 = truth.data.iter().map(|b| (*b as f64).powi(2)).sum();
        (num / den).sqrt()
    };
    let (plain, with_tv) = (error(0.0), error(2e-3));
    assert!(with_tv < 0.9 * plain, "TV prior NRMSE {with_tv:.4} vs none {plain:.4}");
}
