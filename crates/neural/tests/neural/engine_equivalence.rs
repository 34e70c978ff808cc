//! The training path gives bit for bit the results it gave before the method was separated
//! from the CPU engine: fingerprints of the parameters, optimiser moments, loss histories and
//! held-out renders after a few iterations, recorded with the fused trainer of revision
//! 20f572e on two threads, and recorded again when the output softplus became branch-free
//! arithmetic (libm's `expf`/`log1pf` replaced; within 4e-7 of them) and nothing else
//! changed. A change to sampling, quadrature, reduction order or the random streams shows up
//! here first.

use std::ops::ControlFlow;

use fluidnerf_core::{render_image, Aabb, RenderSettings};
use fluidnerf_neural::dense::DenseGridField;
use fluidnerf_neural::mlp::{MlpConfig, MlpField};
use fluidnerf_neural::occupancy::OccupancyConfig;
use fluidnerf_neural::train::{render_view, train, Learner, Prepared, Problem, Split, StopRule, TrainConfig, View};
use fluidnerf_neural::TrainableField;
use glam::{DVec3, Vec3};

use crate::common;
use common::ring;

fn problem() -> Problem {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let blob = |p: Vec3, _t: f64| (-(p.as_dvec3() - DVec3::new(0.2, -0.1, 0.0)).length_squared() * 4.0).exp() as f32;
    let settings = RenderSettings { scale: 2.0, ..Default::default() };
    let mut views: Vec<View> = ring(5, 20)
        .into_iter()
        .map(|camera| {
            let image = render_image(&blob, &camera, &aabb, &settings).expect("renders");
            View { camera, image, time: 0.0 }
        })
        .collect();
    let holdout = views.split_off(4);
    Problem { aabb, intensity_scale: 2.0, views, holdout, time_step: 1.0 }
}

/// FNV-1a over the bit patterns.
fn fingerprint(values: &[f32]) -> u64 {
    values
        .iter()
        .flat_map(|v| v.to_bits().to_le_bytes())
        .fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

/// (parameters, m, v, losses, held-out losses, render of the held-out view) fingerprints.
fn run<F: TrainableField>(field: F, cfg: &TrainConfig) -> [u64; 6] {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().expect("pool");
    pool.install(|| {
        let prep = Prepared::new(&problem(), cfg).expect("prepares");
        let mut learner = Learner::fresh(field, &prep, cfg);
        train(&prep, &mut learner, cfg, 9, |_| ControlFlow::Continue(())).expect("trains");
        let holdout: Vec<f32> = learner.holdout_losses.iter().map(|h| h.1).collect();
        let pixels: Vec<f32> =
            render_view(&learner.field, &prep, cfg, Split::Holdout, 0, 4).iter().map(|p| p.1).collect();
        [
            fingerprint(learner.field.params()),
            fingerprint(&learner.adam.m),
            fingerprint(&learner.adam.v),
            fingerprint(&learner.losses),
            fingerprint(&holdout),
            fingerprint(&pixels),
        ]
    })
}

fn settings() -> TrainConfig {
    TrainConfig {
        coarse_samples: 12,
        fine_samples: 12,
        rays_per_image: 40,
        chunk_samples: 100,
        max_iterations: 6,
        validate_every: 2,
        validate_pixels: 50,
        stop: StopRule { window: 0, ..StopRule::default() },
        ..TrainConfig::default()
    }
}

#[test]
fn mlp_with_hierarchical_sampling_trains_as_before() {
    let mlp = MlpConfig { depth: 3, width: 16, space_freqs: 3, ..MlpConfig::table_5_1() };
    let got = run(MlpField::new(&mlp, 3, 2).expect("field"), &settings());
    assert_eq!(
        got,
        [
            0x6d4e_4d6a_88a6_1625,
            0xbd15_698c_8777_5271,
            0xf997_4395_912c_3a4b,
            0xc2c9_b480_ea6a_1631,
            0xe8fa_5463_01a5_bbd8,
            0x8c76_a4ec_7128_e18d,
        ],
        "{got:#x?}"
    );
}

#[test]
fn dense_grid_with_skipping_trains_as_before() {
    let cfg = TrainConfig { fine_samples: 0, occupancy: Some(OccupancyConfig::default()), ..settings() };
    let got = run(DenseGridField::new([8, 8, 8], 0.05), &cfg);
    assert_eq!(
        got,
        [
            0xe3af_8656_409e_8b75,
            0xce9b_1d83_1d58_622f,
            0x7de6_cfc2_4c72_2059,
            0x86bf_92bd_a6f5_84be,
            0x243e_67f6_9119_4f8a,
            0x1e95_72f6_1623_c45f,
        ],
        "{got:#x?}"
    );
}
