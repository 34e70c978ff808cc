//! The method–engine boundary: ray batches carry what they claim, the CPU engine's step equals
//! a step written out from the equations, its gradient matches finite differences of its
//! loss, and a non-finite loss stops training before the optimiser touches the parameters.

use std::ops::{ControlFlow, Range};
use std::sync::atomic::{AtomicBool, Ordering};

use fluidnerf_core::{render_image, Aabb, RenderSettings};
use fluidnerf_neural::batch::{holdout_batch, stream_seed, training_batch, view_batch, RayBatch};
use fluidnerf_neural::dense::DenseGridField;
use fluidnerf_neural::optim::{Adam, AdamConfig};
use fluidnerf_neural::render::{mse_term, quadrature_weights, render};
use fluidnerf_neural::sampling::{feature_samples, merge_sorted, stratified};
use fluidnerf_neural::train::{
    train, train_with_engine, Batching, Learner, Prepared, Problem, Split, StopRule, Supersample, TrainConfig, View,
};
use fluidnerf_neural::{CpuEngine, Engine, NeuralError, TrainableField};
use glam::{DVec3, Vec3};
use rand::SeedableRng;

use crate::common;
use common::ring;

/// 4 training and 1 held-out view (16² px) of a Gaussian blob; views 2 and 3 at time 1.
fn problem() -> Problem {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let blob = |p: Vec3, _t: f64| (-(p.as_dvec3() - DVec3::new(0.2, -0.1, 0.0)).length_squared() * 4.0).exp() as f32;
    let settings = RenderSettings { scale: 2.0, ..Default::default() };
    let mut views: Vec<View> = ring(5, 16)
        .into_iter()
        .enumerate()
        .map(|(i, camera)| {
            let image = render_image(&blob, &camera, &aabb, &settings).expect("renders");
            View { camera, image, time: if i == 2 || i == 3 { 1.0 } else { 0.0 } }
        })
        .collect();
    let holdout = views.split_off(4);
    Problem { aabb, intensity_scale: 2.0, views, holdout, time_step: 1.0 }
}

fn settings() -> TrainConfig {
    TrainConfig {
        coarse_samples: 10,
        fine_samples: 6,
        rays_per_image: 30,
        chunk_samples: 50,
        validate_every: 0,
        validate_pixels: 20,
        stop: StopRule { window: 0, ..StopRule::default() },
        ..TrainConfig::default()
    }
}

/// A grid with values varying across the box, so that feature sampling has something to find.
fn grid(n: usize) -> DenseGridField {
    let params = (0..n * n * n).map(|i| 0.05 + 0.1 * ((i * 7919) % 13) as f32 / 13.0).collect();
    DenseGridField::from_raw([n, n, n], params)
}

fn one_thread<T: Send>(f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool").install(f)
}

#[test]
fn batches_carry_their_rays_geometry_targets_and_times() {
    let problem = problem();
    let cfg = settings();
    let prep = Prepared::new(&problem, &cfg).expect("prepares");
    let mut batch = RayBatch::new(Split::Train, 0, 0);
    training_batch(&prep, &cfg, 5, 3, &prep.time_steps(), &mut batch);
    assert_eq!((batch.split, batch.seed, batch.stream, batch.len()), (Split::Train, 5, 3, 4 * 30));
    for (i, &(v, _)) in batch.rays.iter().enumerate() {
        assert_eq!(v as usize, i / 30, "rays_per_image rays from every view, in view order");
    }
    let scale = prep.image_scale() as f32;
    for i in 0..batch.len() {
        let ray = batch.ray(&prep, i);
        let (v, r) = batch.rays[i];
        let view = &problem.views[v as usize];
        let pixel = prep.views(Split::Train)[v as usize].rays().pixel[r as usize] as usize;
        assert_eq!(ray.target, view.image.data[pixel] / scale);
        assert_eq!(ray.time, view.time as f32);
        // near and far lie on the box (unit coordinates: one of them at 0 or 1).
        for s in [ray.near, ray.far] {
            let u: Vec<f32> = (0..3).map(|a| ray.origin_unit[a] + s * ray.dir_unit[a]).collect();
            assert!(u.iter().all(|&c| (-1e-4..=1.0 + 1e-4).contains(&c)), "{u:?} outside the box");
            assert!(u.iter().any(|&c| c.abs() < 1e-4 || (c - 1.0).abs() < 1e-4), "{u:?} not on a face");
        }
    }
    // The same keys draw the same batch; another iteration draws another.
    let mut again = RayBatch::new(Split::Holdout, 1, 1);
    training_batch(&prep, &cfg, 5, 3, &prep.time_steps(), &mut again);
    assert_eq!(again, batch);
    training_batch(&prep, &cfg, 5, 4, &prep.time_steps(), &mut again);
    assert_ne!(again.rays, batch.rays);

    // One time step per iteration: frame times t' = 0, 1 alternate.
    let one = TrainConfig { batching: Batching::OneTimeStep, ..cfg.clone() };
    assert_eq!(prep.time_steps(), [0.0, 1.0]);
    for it in 0..4 {
        training_batch(&prep, &one, 5, it, &prep.time_steps(), &mut batch);
        assert_eq!(batch.len(), 2 * 30);
        assert!((0..batch.len()).all(|i| batch.ray(&prep, i).time == (it % 2) as f32), "iteration {it}");
    }

    // Held out: ⌈20 / 1⌉ rays of the one held-out view, the same subset every call.
    let h = holdout_batch(&prep, &cfg, 5).expect("held-out rays");
    assert_eq!((h.split, h.len()), (Split::Holdout, 20));
    assert_eq!(Some(&h), holdout_batch(&prep, &cfg, 5).as_ref());
    assert!(holdout_batch(&prep, &TrainConfig { validate_pixels: 0, ..cfg.clone() }, 5).is_none());

    let whole = view_batch(&prep, Split::Train, 1, 0);
    let n = prep.views(Split::Train)[1].rays().len();
    assert_eq!(whole.rays, (0..n as u32).map(|r| (1, r)).collect::<Vec<_>>());
}

/// The loss and gradient of `batch` written out from Eq. 5.1–5.5 with the public sampling and
/// rendering functions, one ray after another, on one gradient buffer.
fn reference_step(field: &DenseGridField, prep: &Prepared, cfg: &TrainConfig, batch: &RayBatch) -> (f64, Vec<f32>) {
    let (nc, nf) = (cfg.coarse_samples, cfg.fine_samples);
    let mut grads = vec![0.0f32; field.num_params()];
    let mut loss = 0.0f64;
    let mut tape = field.new_tape();
    let n_pix = batch.len();
    let per_chunk = RayBatch::rays_per_chunk(cfg);
    for (c, chunk) in (0..batch.len()).collect::<Vec<_>>().chunks(per_chunk).enumerate() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(stream_seed(batch.seed, batch.stream, c));
        let rays: Vec<_> = chunk.iter().map(|&i| batch.ray(prep, i)).collect();
        let point = |ray: &fluidnerf_neural::batch::BatchRay, s: f32| -> [f32; 3] {
            std::array::from_fn(|a| ray.origin_unit[a] + s * ray.dir_unit[a])
        };
        let coarse: Vec<Vec<f32>> = rays
            .iter()
            .map(|ray| {
                let mut s = vec![0.0; nc];
                stratified(ray.near, ray.far, &mut rng, &mut s);
                s
            })
            .collect();
        let mut samples = Vec::new();
        for (ray, sc) in rays.iter().zip(&coarse) {
            let x: Vec<f32> = sc.iter().flat_map(|&s| point(ray, s)).collect();
            let mut e = vec![0.0; nc];
            field.eval(&x, &mut e, &mut tape);
            let mut fine = vec![0.0; nf];
            feature_samples(sc, &e, &mut rng, &mut fine);
            let mut all = vec![0.0; nc + nf];
            merge_sorted(sc, &fine, &mut all);
            samples.push(all);
        }
        for (ray, s) in rays.iter().zip(&samples) {
            let x: Vec<f32> = s.iter().flat_map(|&s| point(ray, s)).collect();
            let mut e = vec![0.0; s.len()];
            field.forward(&x, &mut e, &mut tape);
            let mut w = vec![0.0; s.len()];
            quadrature_weights(s, ray.near, ray.far, &ray.emission, &prep.quadrature(), prep.length_scale(), &mut w);
            let (l, d_pixel) = mse_term(render(&w, &e), ray.target, n_pix);
            loss += l as f64;
            let d_e: Vec<f32> = w.iter().map(|&wj| d_pixel * wj).collect();
            field.backward(&mut tape, &d_e, &mut grads);
        }
    }
    (loss, grads)
}

#[test]
fn the_cpu_step_equals_the_step_written_out_from_the_equations() {
    let prep = Prepared::new(&problem(), &settings()).expect("prepares");
    let cfg = settings();
    let field = grid(6);
    let mut batch = RayBatch::new(Split::Train, 0, 0);
    training_batch(&prep, &cfg, 11, 2, &prep.time_steps(), &mut batch);
    assert!(batch.len() > RayBatch::rays_per_chunk(&cfg), "several chunks");
    let (want_loss, want_grads) = reference_step(&field, &prep, &cfg, &batch);
    assert!(want_loss > 0.0 && want_grads.iter().any(|&g| g != 0.0));
    // One worker runs the chunks in the reference's order: equal to the bit.
    let (loss, grads) = one_thread(|| {
        let mut engine = CpuEngine::new(&field, 1);
        engine.load_state(&field, &Adam::new(field.num_params(), AdamConfig::default())).expect("fits");
        let stats = engine.loss_and_gradient(&field, &prep, &cfg, &batch);
        assert_eq!(stats.samples, batch.len() * (cfg.coarse_samples + cfg.fine_samples));
        (stats.loss, engine.gradient().to_vec())
    });
    assert_eq!(loss, want_loss);
    assert_eq!(grads, want_grads);
    // Three workers sum in another order: equal to rounding.
    let mut engine = CpuEngine::new(&field, 3);
    engine.load_state(&field, &Adam::new(field.num_params(), AdamConfig::default())).expect("fits");
    let stats = engine.loss_and_gradient(&field, &prep, &cfg, &batch);
    assert!((stats.loss - want_loss).abs() <= 1e-6 * want_loss, "{} vs {want_loss}", stats.loss);
    for (g, w) in engine.gradient().iter().zip(&want_grads) {
        assert!((g - w).abs() <= 1e-5 * (1.0 + w.abs()), "{g} vs {w}");
    }
    // Rendering samples as training does: its MSE is the training loss.
    let mut pixels = Vec::new();
    let rendered = engine.render(&field, &prep, &cfg, &batch, &mut pixels);
    assert_eq!(pixels.len(), batch.len());
    assert!((rendered.loss - want_loss).abs() <= 1e-6 * want_loss);
    let direct: f64 = (0..batch.len()).map(|i| ((pixels[i] - batch.ray(&prep, i).target) as f64).powi(2)).sum();
    assert!((direct / batch.len() as f64 - rendered.loss).abs() <= 1e-6 * rendered.loss);
}

#[test]
fn the_cpu_gradient_matches_finite_differences_of_its_loss() {
    // Without feature sampling the samples do not depend on the parameters, and the loss is a
    // smooth function of the grid values (softplus of a trilinear blend, squared).
    let cfg = TrainConfig { fine_samples: 0, ..settings() };
    let prep = Prepared::new(&problem(), &cfg).expect("prepares");
    let mut field = grid(4);
    let mut batch = RayBatch::new(Split::Train, 0, 0);
    training_batch(&prep, &cfg, 1, 0, &prep.time_steps(), &mut batch);
    let mut engine = CpuEngine::new(&field, 2);
    let adam = Adam::new(field.num_params(), AdamConfig::default());
    engine.load_state(&field, &adam).expect("fits");
    engine.loss_and_gradient(&field, &prep, &cfg, &batch);
    let grads = engine.gradient().to_vec();
    let h = 1e-3f32;
    let mut checked = 0;
    for p in 0..field.num_params() {
        let x = field.params()[p];
        field.params_mut()[p] = x + h;
        let plus = engine.loss_and_gradient(&field, &prep, &cfg, &batch).loss;
        field.params_mut()[p] = x - h;
        let minus = engine.loss_and_gradient(&field, &prep, &cfg, &batch).loss;
        field.params_mut()[p] = x;
        let fd = (plus - minus) / (2.0 * h as f64);
        let an = grads[p] as f64;
        assert!((fd - an).abs() <= 2e-5 + 1e-2 * fd.abs().max(an.abs()), "parameter {p}: fd {fd} vs {an}");
        checked += (an != 0.0) as usize;
    }
    assert!(checked > field.num_params() / 2, "only {checked} parameters are seen by the batch");
}

#[test]
fn load_state_rejects_an_optimiser_of_another_size() {
    let field = grid(3);
    let mut engine = CpuEngine::new(&field, 2);
    let err = engine.load_state(&field, &Adam::new(28, AdamConfig::default())).expect_err("27 parameters");
    assert!(err.to_string().contains("optimiser state"), "{err}");
}

/// A grid that can be switched to output NaN, to make a run diverge at a chosen iteration.
#[derive(Clone)]
struct Poisoned<'a> {
    grid: DenseGridField,
    poison: &'a AtomicBool,
}

impl TrainableField for Poisoned<'_> {
    type Tape = <DenseGridField as TrainableField>::Tape;
    fn input_dim(&self) -> usize {
        3
    }
    fn new_tape(&self) -> Self::Tape {
        self.grid.new_tape()
    }
    fn params(&self) -> &[f32] {
        self.grid.params()
    }
    fn params_mut(&mut self) -> &mut [f32] {
        self.grid.params_mut()
    }
    fn start_uniform(&mut self, level: f32) {
        self.grid.start_uniform(level);
    }
    fn eval(&self, inputs: &[f32], out: &mut [f32], tape: &mut Self::Tape) {
        self.grid.eval(inputs, out, tape);
    }
    fn forward(&self, inputs: &[f32], out: &mut [f32], tape: &mut Self::Tape) {
        self.grid.forward(inputs, out, tape);
        if self.poison.load(Ordering::Relaxed) {
            out.fill(f32::NAN);
        }
    }
    fn backward(&self, tape: &mut Self::Tape, d_out: &[f32], grads: &mut [f32]) {
        self.grid.backward(tape, d_out, grads);
    }
    fn tensors(&self) -> Vec<(String, Vec<usize>, Range<usize>)> {
        self.grid.tensors()
    }
}

#[test]
fn a_non_finite_loss_stops_training_before_the_optimiser_step() {
    let cfg = TrainConfig { max_iterations: 10, ..settings() };
    let prep = Prepared::new(&problem(), &cfg).expect("prepares");
    let poison = AtomicBool::new(false);
    let mut learner = Learner::new(Poisoned { grid: grid(5), poison: &poison });
    let mut after_three = None;
    let err = train(&prep, &mut learner, &cfg, 0, |s| {
        if s.iteration == 3 {
            after_three = Some((s.field.params().to_vec(), s.learner.adam.clone()));
            poison.store(true, Ordering::Relaxed);
        }
        ControlFlow::Continue(())
    })
    .expect_err("diverges at iteration 3");
    assert!(matches!(err, NeuralError::Diverged { iteration: 3, loss, .. } if loss.is_nan()), "{err:?}");
    assert!(err.to_string().contains("training diverged: the loss of iteration 3 is NaN"), "{err}");
    assert!(err.to_string().contains("a lower learning rate may help"), "{err}");
    let (params, adam) = after_three.expect("three iterations ran");
    assert!(params.iter().all(|p| p.is_finite()));
    assert_eq!(learner.field.params(), params, "the parameters are those after iteration 3");
    assert_eq!(learner.adam, adam, "and so are the optimiser's moments and step count");
    assert_eq!((learner.iteration, learner.losses.len()), (3, 3));

    // Diverging at the very first iteration (a field too bright for f32 squares) leaves the
    // initial state, through any engine-driven loop.
    let mut learner = Learner::new(DenseGridField::new([4, 4, 4], 1e37));
    let start = learner.field.params().to_vec();
    let mut engine = CpuEngine::new(&learner.field, 2);
    let err = train_with_engine(&prep, &mut learner, &cfg, 0, &mut engine, |_| ControlFlow::Continue(()))
        .expect_err("the squared residual overflows");
    assert!(matches!(err, NeuralError::Diverged { iteration: 0, loss, .. } if loss.is_infinite()), "{err:?}");
    // No step was taken: the message points at the start's settings, not at the learning rate.
    let e = err.to_string();
    assert!(e.contains("image_scale") && e.contains("init_scale") && !e.contains("lower learning rate"), "{e}");
    assert_eq!(learner.field.params(), start);
    assert_eq!((learner.adam.step, learner.iteration), (0, 0));
    assert!(learner.adam.m.iter().chain(&learner.adam.v).all(|&m| m == 0.0));
}

/// A given image_scale that puts the brightest training pixel out of 1e-6..1e6 is refused
/// naming it (1e-30 made the loss of iteration 0 infinite); the bounds themselves prepare.
#[test]
fn an_image_scale_far_from_the_pixels_is_refused_naming_it() {
    use fluidnerf_neural::train::{MAX_TARGET_PEAK, MIN_TARGET_PEAK};
    let problem = problem();
    let largest = problem.views.iter().map(|v| v.image.min_max().1).fold(0.0f32, f32::max) as f64;
    for scale in [1e-30, largest / MAX_TARGET_PEAK / 10.0, largest / MIN_TARGET_PEAK * 10.0, 1e30] {
        let cfg = TrainConfig { image_scale: Some(scale as f32), ..settings() };
        let Err(e) = Prepared::new(&problem, &cfg) else { panic!("{scale}: prepared") };
        let e = e.to_string();
        assert!(e.starts_with("invalid image_scale: ") && e.contains("between 1e-6 and 1e6"), "{scale}: {e}");
    }
    for scale in [largest / MAX_TARGET_PEAK * 1.001, largest, largest / MIN_TARGET_PEAK * 0.999] {
        let cfg = TrainConfig { image_scale: Some(scale as f32), ..settings() };
        Prepared::new(&problem, &cfg).unwrap_or_else(|e| panic!("{scale}: {e}"));
    }
}

/// `pixel_supersample = "auto"` draws 2 × 2 rays over a quarter of the pixels from clean
/// images, the same rays per iteration, and one ray per pixel from noisy ones (5 % of the peak
/// added); the setting reads and writes as `"auto"` or a number.
#[test]
fn automatic_supersampling_follows_the_images_noise() {
    let clean = problem();
    let mut noisy = problem();
    for (k, v) in noisy.views.iter_mut().enumerate() {
        let top = v.image.min_max().1;
        let mut rng = rand::rngs::StdRng::seed_from_u64(k as u64);
        let normal = rand_distr::Normal::new(0.0f32, 0.05 * top).expect("valid");
        for p in &mut v.image.data {
            *p = (*p + rand_distr::Distribution::sample(&normal, &mut rng)).max(0.0);
        }
    }
    let cfg = TrainConfig { pixel_supersample: Supersample::Auto, rays_per_image: 32, ..settings() };
    let counts = |problem: &Problem| {
        let prep = Prepared::new(problem, &cfg).expect("prepares");
        let mut batch = RayBatch::new(Split::Train, 0, 0);
        training_batch(&prep, &cfg, 1, 0, &prep.time_steps(), &mut batch);
        (prep.noise().expect("estimated"), batch.group, batch.len())
    };
    let (clean_noise, clean_group, clean_rays) = counts(&clean);
    let (noisy_noise, noisy_group, noisy_rays) = counts(&noisy);
    assert!(clean_noise < 0.01 && noisy_noise > 0.03, "noise {clean_noise} clean, {noisy_noise} noisy");
    assert_eq!((clean_group, noisy_group), (4, 1));
    assert_eq!((clean_rays, noisy_rays), (4 * 4 * 8, 4 * 32), "4 views: 8 pixels × 4 rays, 32 × 1");
    assert_eq!(cfg.pixel_rays(Some(0.0)), (2, 8));
    assert_eq!(cfg.pixel_rays(None), (1, 32));
    let json = serde_json::to_value(&cfg).expect("serialises");
    assert_eq!(json["pixel_supersample"], "auto");
    let back: TrainConfig = serde_json::from_value(json).expect("reads back");
    assert_eq!(back.pixel_supersample, Supersample::Auto);
    let two: Supersample = serde_json::from_str("2").expect("a number");
    assert_eq!(two, Supersample::Fixed(2));
    let bad = serde_json::from_str::<Supersample>("\"twice\"").expect_err("not a setting");
    assert!(bad.to_string().contains("auto"), "{bad}");
    let bad = TrainConfig { pixel_supersample: Supersample::Fixed(5), ..settings() }.validate().expect_err("too many");
    assert!(bad.to_string().contains("pixel_supersample"), "{bad}");
}

/// With `pixel_supersample = 2` a training pixel is four rays through its sub-pixel centres,
/// and the loss scores their mean: the batch names each drawn pixel four times with the
/// offsets (±¼, ±¼), each ray's direction is the camera's ray through that point, the loss is
/// the MSE of the four rays' mean against the pixel, and its gradient matches finite
/// differences.
#[test]
fn supersampled_pixels_score_the_mean_of_their_sub_pixel_rays() {
    let problem = problem();
    let cfg = TrainConfig { fine_samples: 0, pixel_supersample: Supersample::Fixed(2), ..settings() };
    let prep = Prepared::new(&problem, &cfg).expect("prepares");
    let (mut batch, mut single) = (RayBatch::new(Split::Train, 0, 0), RayBatch::new(Split::Train, 0, 0));
    training_batch(&prep, &cfg, 1, 0, &prep.time_steps(), &mut batch);
    let centres = TrainConfig { pixel_supersample: Supersample::Fixed(1), ..cfg.clone() };
    training_batch(&prep, &centres, 1, 0, &prep.time_steps(), &mut single);
    assert_eq!((batch.group, single.group), (4, 1));
    assert_eq!(batch.len(), 4 * single.len());
    assert!(single.jitter.is_empty());
    for (p, &pixel) in single.rays.iter().enumerate() {
        let mut offsets: Vec<[f32; 2]> = (0..4).map(|k| batch.jitter[4 * p + k]).collect();
        offsets.sort_by(|a, b| a.partial_cmp(b).expect("finite"));
        assert_eq!(offsets, [[-0.25, -0.25], [-0.25, 0.25], [0.25, -0.25], [0.25, 0.25]]);
        for k in 0..4 {
            let i = 4 * p + k;
            assert_eq!(batch.rays[i], pixel);
            // The ray through the sub-pixel centre, from the camera itself, to the first order
            // the batch uses (this test camera's pixels are wide: 1e-4 of the direction).
            let (v, r) = pixel;
            let at = prep.views(Split::Train)[v as usize].rays().pixel[r as usize] as usize;
            let camera = &problem.views[v as usize].camera;
            let [a, b] = batch.jitter[i];
            let (col, row) = ((at % camera.width()) as f64 + a as f64, (at / camera.width()) as f64 + b as f64);
            let want = camera.pixel_ray(col, row).expect("ray").dir / problem.aabb.size();
            let got = batch.ray(&prep, i).dir_unit;
            for c in 0..3 {
                assert!((got[c] as f64 - want[c]).abs() <= 1e-4 * want.length(), "ray {i}: {got:?} vs {want}");
            }
        }
    }
    let mut field = grid(4);
    let mut engine = CpuEngine::new(&field, 2);
    engine.load_state(&field, &Adam::new(field.num_params(), AdamConfig::default())).expect("fits");
    let mut pixels = Vec::new();
    let rendered = engine.render(&field, &prep, &cfg, &batch, &mut pixels);
    let direct: f64 = (0..single.len())
        .map(|p| {
            let mean = (0..4).map(|k| pixels[4 * p + k]).sum::<f32>() / 4.0;
            ((mean - batch.ray(&prep, 4 * p).target) as f64).powi(2)
        })
        .sum::<f64>()
        / single.len() as f64;
    assert!((direct - rendered.loss).abs() <= 1e-6 * direct, "{direct} vs {}", rendered.loss);
    let loss = engine.loss_and_gradient(&field, &prep, &cfg, &batch).loss;
    assert!((loss - direct).abs() <= 1e-6 * direct, "{loss} vs {direct}");
    let grads = engine.gradient().to_vec();
    let h = 1e-3f32;
    let mut checked = 0;
    for p in 0..field.num_params() {
        let x = field.params()[p];
        field.params_mut()[p] = x + h;
        let plus = engine.loss_and_gradient(&field, &prep, &cfg, &batch).loss;
        field.params_mut()[p] = x - h;
        let minus = engine.loss_and_gradient(&field, &prep, &cfg, &batch).loss;
        field.params_mut()[p] = x;
        let fd = (plus - minus) / (2.0 * h as f64);
        let an = grads[p] as f64;
        assert!((fd - an).abs() <= 2e-5 + 1e-2 * fd.abs().max(an.abs()), "parameter {p}: fd {fd} vs {an}");
        checked += (an != 0.0) as usize;
    }
    assert!(checked > field.num_params() / 2, "only {checked} parameters are seen by the batch");
}
