//! Starting a field from another reconstruction ([`fluidnerf_neural::start`]): a fit recovers a
//! target the field can represent exactly, is reproducible from its seed, and refuses settings
//! and targets it cannot use, naming them.

use fluidnerf_core::{render_image, Aabb, RenderSettings};
use fluidnerf_neural::dense::DenseGridField;
use std::ops::ControlFlow;

use fluidnerf_neural::start::{fit_to_target, StartFit};
use fluidnerf_neural::train::{Prepared, Problem, TrainConfig, View};
use fluidnerf_neural::{NeuralError, TrainableField};
use glam::{DVec3, Vec3};

use crate::common;
use common::ring;

fn problem() -> Problem {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let blob = |p: Vec3, _t: f64| (-(p.as_dvec3()).length_squared() * 2.0).exp() as f32;
    let settings = RenderSettings { scale: 2.0, ..Default::default() };
    let views = ring(3, 12)
        .into_iter()
        .map(|camera| {
            let image = render_image(&blob, &camera, &aabb, &settings).expect("renders");
            View { camera, image, time: 0.0 }
        })
        .collect();
    Problem { aabb, intensity_scale: 2.0, views, holdout: Vec::new(), time_step: 1.0 }
}

/// A 5³ grid field with raw values spread over [-1.5, 1.5]: not uniform, all finite.
fn target_grid() -> DenseGridField {
    let params = (0..125).map(|i| -1.5 + 3.0 * ((i * 37) % 29) as f32 / 28.0).collect();
    DenseGridField::from_raw([5, 5, 5], params)
}

fn eval(field: &DenseGridField, inputs: &[f32]) -> Vec<f32> {
    let mut out = vec![0f32; inputs.len() / 3];
    field.eval(inputs, &mut out, &mut field.new_tape());
    out
}

/// Relative RMS difference of two fields on a fixed lattice of points.
fn relative_difference(a: &DenseGridField, b: &DenseGridField) -> f64 {
    let inputs: Vec<f32> = (0..11 * 11 * 11)
        .flat_map(|i| [(i % 11) as f32 / 10.0, (i / 11 % 11) as f32 / 10.0, (i / 121) as f32 / 10.0])
        .collect();
    let (x, y) = (eval(a, &inputs), eval(b, &inputs));
    let se: f64 = x.iter().zip(&y).map(|(p, q)| ((p - q) as f64).powi(2)).sum();
    let sq: f64 = y.iter().map(|q| (*q as f64).powi(2)).sum();
    (se / sq).sqrt()
}

#[test]
fn a_fit_recovers_a_target_the_field_can_represent() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let target = target_grid();
    let to_target = |inputs: &[f32], out: &mut [f32]| out.copy_from_slice(&eval(&target, inputs));
    let mut field = DenseGridField::new([5, 5, 5], 0.5);
    let before = relative_difference(&field, &target);
    let fit = StartFit { iterations: 400, points: 4096, learning_rate: 5e-2 };
    let report = fit_to_target(&mut field, &prep, &to_target, &fit, 3, None, &mut go_on).expect("fits");
    let after = relative_difference(&field, &target);
    assert!(before > 0.4, "the start is far from the target: {before}");
    assert!(after < 0.02, "fitted: relative difference {after} (from {before})");
    // The report's error is the last step's, on its own points: as small.
    assert!((report.mse / report.mean_square).sqrt() < 0.03, "{report:?}");
    assert!(report.seconds >= 0.0);
}

/// A start far dimmer than the images ask for (values in other units) is scaled to their level
/// before the fit, and said so in the report; one at their level is taken as it is.
#[test]
fn a_start_in_other_units_is_scaled_to_the_images() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let level = prep.mean_level();
    let fit = StartFit { iterations: 150, points: 2048, learning_rate: 5e-2 };
    let mean = |field: &DenseGridField| eval(field, &[0.5f32; 3])[0];
    for (dim, rescaled) in [(1.0f32, false), (1e-3, true), (1e4, true)] {
        let to_target = |_: &[f32], out: &mut [f32]| out.fill(2.0 * level * dim);
        let mut field = DenseGridField::new([5, 5, 5], 0.5);
        let report = fit_to_target(&mut field, &prep, &to_target, &fit, 3, None, &mut go_on).expect("fits");
        assert_eq!(report.rescaled.is_some(), rescaled, "{dim}: {report:?}");
        let reached = mean(&field) / level;
        let wanted = if rescaled { 2.0 } else { 2.0 * dim };
        assert!((reached / wanted - 1.0).abs() < 0.05, "{dim}: the field reached {reached} × the level");
    }
    let zero = |_: &[f32], out: &mut [f32]| out.fill(0.0);
    let mut field = DenseGridField::new([5, 5, 5], 0.5);
    let err = fit_to_target(&mut field, &prep, &zero, &fit, 3, None, &mut go_on).expect_err("a zero start").to_string();
    assert!(err.contains("zero at every occupied point"), "{err}");
    // A negative start (an edited volume) fitted a zero field, which the run then trained on.
    let negative = |_: &[f32], out: &mut [f32]| out.fill(-1.0);
    let err = fit_to_target(&mut field, &prep, &negative, &fit, 3, None, &mut go_on)
        .expect_err("a negative start")
        .to_string();
    assert!(err.contains("or negative"), "{err}");
}

#[test]
fn a_fit_is_reproducible_from_its_seed() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let target = target_grid();
    let to_target = |inputs: &[f32], out: &mut [f32]| out.copy_from_slice(&eval(&target, inputs));
    let fit = StartFit { iterations: 20, points: 256, learning_rate: 5e-2 };
    let run = |seed| {
        let mut field = DenseGridField::new([5, 5, 5], 0.5);
        fit_to_target(&mut field, &prep, &to_target, &fit, seed, None, &mut go_on).expect("fits");
        field.params().to_vec()
    };
    assert_eq!(run(1), run(1));
    assert_ne!(run(1), run(2));
}

#[test]
fn settings_and_targets_a_fit_cannot_use_are_refused_by_name() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let zero = |_: &[f32], out: &mut [f32]| out.fill(0.0);
    let why = |fit: StartFit, target: &(dyn Fn(&[f32], &mut [f32]) + Sync)| {
        let mut field = DenseGridField::new([5, 5, 5], 0.5);
        let before = field.params().to_vec();
        let err = fit_to_target(&mut field, &prep, target, &fit, 0, None, &mut go_on).expect_err("refused");
        assert_eq!(field.params(), before, "a refused fit leaves the field as it was");
        match err {
            NeuralError::Invalid { what, why } => format!("{what}: {why}"),
            e => panic!("{e}"),
        }
    };
    let ok = StartFit::default();
    assert!(why(StartFit { iterations: 0, ..ok }, &zero).starts_with("start.iterations"));
    let endless = why(StartFit { iterations: 1 << 40, ..ok }, &zero);
    assert!(endless.starts_with("start.iterations: must be 1 to 1000000000 steps"), "{endless}");
    assert!(why(StartFit { points: 0, ..ok }, &zero).starts_with("start.points"));
    assert!(why(StartFit { learning_rate: f32::NAN, ..ok }, &zero).starts_with("start.learning_rate"));
    let broken = |_: &[f32], out: &mut [f32]| out.fill(f32::INFINITY);
    let msg = why(ok, &broken);
    assert!(msg.contains("not finite"), "{msg}");
}

/// A time limit already reached stops the fit after its first step, and says so.
#[test]
fn a_time_limit_stops_the_fit_after_one_step() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let target = target_grid();
    let to_target = |inputs: &[f32], out: &mut [f32]| out.copy_from_slice(&eval(&target, inputs));
    let fit = StartFit { iterations: 50, points: 256, learning_rate: 5e-2 };
    let mut field = DenseGridField::new([5, 5, 5], 0.5);
    let report = fit_to_target(&mut field, &prep, &to_target, &fit, 3, Some(0.0), &mut go_on).expect("fits");
    assert_eq!(report.steps, 1);
    let mut field = DenseGridField::new([5, 5, 5], 0.5);
    let report = fit_to_target(&mut field, &prep, &to_target, &fit, 3, Some(1e9), &mut go_on).expect("fits");
    assert_eq!(report.steps, 50);
    assert!(!report.stopped);
}

/// The caller sees every step and can stop the fit after any, as a user stops a run: the fit
/// ends there, says so, and its field is the field of that step (the first steps of an
/// unstopped fit, bit for bit).
#[test]
fn the_caller_stops_the_fit_after_any_step() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let target = target_grid();
    let to_target = |inputs: &[f32], out: &mut [f32]| out.copy_from_slice(&eval(&target, inputs));
    let mut seen = Vec::new();
    let mut stop_at_3 = |step: usize| {
        seen.push(step);
        if step == 3 {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    };
    let fit = StartFit { iterations: 50, points: 256, learning_rate: 5e-2 };
    let mut stopped = DenseGridField::new([5, 5, 5], 0.5);
    let report = fit_to_target(&mut stopped, &prep, &to_target, &fit, 3, None, &mut stop_at_3).expect("fits");
    assert_eq!(seen, [1, 2, 3]);
    assert_eq!((report.steps, report.stopped), (3, true), "{report:?}");
    let mut three = DenseGridField::new([5, 5, 5], 0.5);
    let short = StartFit { iterations: 3, ..fit };
    let report = fit_to_target(&mut three, &prep, &to_target, &short, 3, None, &mut go_on).expect("fits");
    assert_eq!((report.steps, report.stopped), (3, false));
    assert_eq!(stopped.params(), three.params());
}

/// A target in world units and coordinates is fitted in field units (divided by the value
/// scale); a field of space alone refuses the frames of more than one instant.
#[test]
fn a_fit_to_frames_takes_the_target_in_world_units() {
    let problem = problem();
    let prep = Prepared::new(&problem, &TrainConfig::default()).expect("prepares");
    let level = 2.0 * prep.mean_level() as f64 * prep.meta.value_scale;
    let world = |_: f64, points: &[Vec3], out: &mut [f32]| {
        assert!(points.iter().all(|p| p.abs().max_element() <= 1.0 + 1e-5), "points in the box, world units");
        out.fill(level as f32);
    };
    let fit = StartFit { iterations: 150, points: 2048, learning_rate: 5e-2 };
    let mut field = DenseGridField::new([5, 5, 5], 0.5);
    let report =
        fluidnerf_neural::start::fit_to_frames(&mut field, &prep, &[(0.0, 0.0)], &world, &fit, 3, None, &mut go_on)
            .expect("fits");
    assert_eq!(report.rescaled, None);
    let reached = eval(&field, &[0.5f32; 3])[0] as f64 * prep.meta.value_scale;
    assert!((reached / level - 1.0).abs() < 0.05, "reached {reached}, wanted {level}");
    let mut field = DenseGridField::new([5, 5, 5], 0.5);
    let err = fluidnerf_neural::start::fit_to_frames(
        &mut field,
        &prep,
        &[(0.0, 0.0), (1.0, 1.0)],
        &world,
        &fit,
        3,
        None,
        &mut go_on,
    )
    .expect_err("two instants")
    .to_string();
    assert!(err.contains("cannot start from 2 instants"), "{err}");
}

/// An `on_step` that never stops the fit.
fn go_on(_: usize) -> ControlFlow<()> {
    ControlFlow::Continue(())
}
