//! Finite-difference checks of every hand-written backward pass of the training engine, and
//! the fused MLP forward against a naive f64 reference built from the named tensors.
//!
//! Tolerance argument: the fields compute in f32, so a central difference of the loss
//! `L = Σ_i c_i E(x_i)` (|L| ≲ 10) with step h = 10⁻² carries a rounding error of about
//! `ε_f32 |L| / h ≈ 10⁻⁵ … 10⁻⁴` and a truncation error `h² |L'''| / 6 ≈ 10⁻⁵` for the smooth
//! parts. We therefore accept `|fd − an| ≤ 3·10⁻⁴ + 2·10⁻² max(|fd|, |an|)`. ReLU is not
//! differentiable at 0: a parameter whose perturbation moves some pre-activation across 0
//! within ±h gets an O(1) finite-difference error. ReLU networks are therefore checked with
//! h = 10⁻³ (rounding error ≈ 10⁻⁴, still inside the tolerance; fewer kinks crossed) and may
//! have at most 2 % of such outliers; smooth networks (Swish, softplus) must pass for every
//! parameter.

use fluidnerf_neural::{
    Activation, HashGridConfig, HashGridField, MlpConfig, MlpField, MlpPrecision, OutputActivation, TrainableField,
};
use rand::{Rng, SeedableRng};

fn random_inputs(n: usize, d: usize, seed: u64) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n * d).map(|i| if i % d == 3 { rng.random_range(0.0..3.0) } else { rng.random::<f32>() }).collect()
}

fn loss<F: TrainableField>(field: &F, x: &[f32], c: &[f32]) -> f64 {
    let mut tape = field.new_tape();
    let mut out = vec![0.0; c.len()];
    field.forward(x, &mut out, &mut tape);
    out.iter().zip(c).map(|(&o, &c)| o as f64 * c as f64).sum()
}

/// Returns the fraction of parameters (among `indices`) failing the tolerance.
fn fd_check<F: TrainableField>(field: &mut F, x: &[f32], indices: &[usize], seed: u64) -> FdReport {
    fd_check_h(field, x, indices, seed, 1e-2)
}

fn fd_check_h<F: TrainableField>(field: &mut F, x: &[f32], indices: &[usize], seed: u64, h: f32) -> FdReport {
    let n = x.len() / field.input_dim();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let c: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut tape = field.new_tape();
    let mut out = vec![0.0; n];
    field.forward(x, &mut out, &mut tape);
    let mut grads = vec![0.0; field.num_params()];
    field.backward(&mut tape, &c, &mut grads);
    // backward must accumulate: a second call doubles the gradient.
    let mut twice = grads.clone();
    field.forward(x, &mut out, &mut tape);
    field.backward(&mut tape, &c, &mut twice);
    for (a, b) in grads.iter().zip(&twice) {
        assert!((2.0 * a - b).abs() <= 1e-5 * (1.0 + a.abs()), "backward does not accumulate");
    }
    let mut bad = 0;
    let mut worst = (0.0f64, 0usize, 0.0f64, 0.0f64);
    for &i in indices {
        let p0 = field.params()[i];
        field.params_mut()[i] = p0 + h;
        let lp = loss(field, x, &c);
        field.params_mut()[i] = p0 - h;
        let lm = loss(field, x, &c);
        field.params_mut()[i] = p0;
        let fd = (lp - lm) / (2.0 * h as f64);
        let an = grads[i] as f64;
        let err = (fd - an).abs();
        let tol = 3e-4 + 2e-2 * fd.abs().max(an.abs());
        if err > tol {
            bad += 1;
        }
        if err / tol > worst.0 {
            worst = (err / tol, i, fd, an);
        }
    }
    FdReport { bad: bad as f64 / indices.len() as f64, worst }
}

/// Fraction of parameters failing, and the worst (err/tol, index, fd, analytic).
#[derive(Debug)]
struct FdReport {
    bad: f64,
    #[allow(dead_code)] // shown in assertion messages
    worst: (f64, usize, f64, f64),
}

fn all(field: &impl TrainableField) -> Vec<usize> {
    (0..field.num_params()).collect()
}

fn small(activation: Activation, output: OutputActivation) -> MlpConfig {
    MlpConfig { depth: 4, width: 8, space_freqs: 2, time_freqs: 1, activation, output_activation: output, skip: true }
}

#[test]
fn mlp_swish_softplus_with_skip_3d() {
    let mut f = MlpField::new(&small(Activation::Swish, OutputActivation::Softplus), 3, 1).unwrap();
    let x = random_inputs(24, 3, 2);
    let idx = all(&f);
    let r = fd_check(&mut f, &x, &idx, 3);
    assert_eq!(r.bad, 0.0, "{r:?}");
}

#[test]
fn mlp_swish_4d_with_time_encoding() {
    let mut f = MlpField::new(&small(Activation::Swish, OutputActivation::Softplus), 4, 4).unwrap();
    let x = random_inputs(24, 4, 5);
    let idx = all(&f);
    let r = fd_check(&mut f, &x, &idx, 6);
    assert_eq!(r.bad, 0.0, "{r:?}");
}

#[test]
fn mlp_relu_softplus_with_skip() {
    let mut f = MlpField::new(&small(Activation::Relu, OutputActivation::Softplus), 3, 7).unwrap();
    let x = random_inputs(24, 3, 8);
    let idx = all(&f);
    let r = fd_check_h(&mut f, &x, &idx, 9, 1e-3);
    assert!(r.bad <= 0.02, "{r:?}");
}

#[test]
fn mlp_relu_output_passes_no_gradient_where_dead() {
    let cfg = small(Activation::Swish, OutputActivation::Relu);
    let mut f = MlpField::new(&cfg, 3, 10).unwrap();
    let x = random_inputs(24, 3, 11);
    // Shift the output bias so some rows are clearly alive and some clearly dead.
    let (_, _, bias) = f.tensors().into_iter().find(|(n, _, _)| n == "output.bias").unwrap();
    let mut tape = f.new_tape();
    let mut out = vec![0.0; 24];
    f.forward(&x, &mut out, &mut tape);
    let mut sorted = out.clone();
    sorted.sort_by(f32::total_cmp);
    f.params_mut()[bias.start] -= 0.5 * (sorted[11] + sorted[12]) - f.params()[bias.start] * 0.0;
    f.forward(&x, &mut out, &mut tape);
    let alive = out.iter().filter(|&&o| o > 0.0).count();
    assert!((6..=18).contains(&alive), "{alive} alive rows");
    let idx = all(&f);
    let r = fd_check_h(&mut f, &x, &idx, 12, 1e-3);
    assert!(r.bad <= 0.02, "{r:?}");
    // Dead rows alone: zero gradient.
    let d: Vec<f32> = out.iter().map(|&o| if o > 0.0 { 0.0 } else { 1.0 }).collect();
    let mut g = vec![0.0; f.num_params()];
    f.forward(&x, &mut out, &mut tape);
    f.backward(&mut tape, &d, &mut g);
    assert!(g.iter().all(|&v| v == 0.0), "a dead ReLU output must pass no gradient");
}

#[test]
fn mlp_without_skip_and_deep_narrow() {
    let cfg = MlpConfig { depth: 6, width: 5, skip: false, ..small(Activation::Swish, OutputActivation::Softplus) };
    let mut f = MlpField::new(&cfg, 3, 13).unwrap();
    let x = random_inputs(16, 3, 14);
    let idx = all(&f);
    let r = fd_check(&mut f, &x, &idx, 15);
    assert_eq!(r.bad, 0.0, "{r:?}");
}

fn small_grid(d: usize, seed: u64) -> HashGridField {
    let cfg = HashGridConfig {
        levels: 4,
        features_per_level: 2,
        log2_table_size: 7,
        base_resolution: 2,
        max_resolution: 12,
        time_resolution: 3,
        time_base_resolution: 0,
        time_span: 3.0,
        // A 4D grid with levels without a time axis too, so their gradients are checked.
        static_levels: if d == 4 { 2 } else { 0 },
        mlp_depth: 2,
        mlp_width: 8,
        activation: Activation::Swish,
        output_activation: OutputActivation::Softplus,
        // Large enough that the MLP sees features of order one.
        init_scale: 0.5,
        coarse_to_fine: 0,
        // Finite differences need the f32 products.
        mlp_precision: MlpPrecision::F32,
    };
    HashGridField::new(&cfg, d, seed).unwrap()
}

#[test]
fn hash_grid_3d_dense_and_hashed_levels() {
    let mut f = small_grid(3, 16);
    let s = f.level_summary();
    assert!(s.iter().any(|l| l.2) && s.iter().any(|l| !l.2), "want dense and hashed levels: {s:?}");
    let x = random_inputs(40, 3, 17);
    let idx = all(&f);
    let r = fd_check(&mut f, &x, &idx, 18);
    assert_eq!(r.bad, 0.0, "{r:?}");
}

#[test]
fn hash_grid_4d() {
    let mut f = small_grid(4, 19);
    let x = random_inputs(40, 4, 20);
    let idx = all(&f);
    let r = fd_check(&mut f, &x, &idx, 21);
    assert_eq!(r.bad, 0.0, "{r:?}");
}

/// Naive f64 forward of the dissertation network from the named tensors: checks the fused
/// forward, the parameter layout and the architecture (encoding, skip, output activation).
#[test]
fn fused_forward_matches_naive_f64_reference() {
    for (act, d) in [(Activation::Relu, 3), (Activation::Swish, 4)] {
        let cfg =
            MlpConfig { depth: 4, width: 16, space_freqs: 3, time_freqs: 2, activation: act, ..Default::default() };
        let f = MlpField::new(&cfg, d, 22).unwrap();
        let x = random_inputs(300, d, 23);
        let mut out = vec![0.0; 300];
        let mut tape = f.new_tape();
        f.eval(&x, &mut out, &mut tape);
        let t = f.tensors();
        let p = f.params();
        let get = |name: &str| {
            let (_, shape, r) = t.iter().find(|(n, _, _)| n == name).unwrap();
            (shape.clone(), p[r.clone()].iter().map(|&v| v as f64).collect::<Vec<f64>>())
        };
        for (row, &o) in x.chunks(d).zip(&out) {
            let mut enc = Vec::new();
            for (c, &u) in row.iter().enumerate() {
                let (tau, l) = if c < 3 { (2.0 * u as f64 - 1.0, 3) } else { (u as f64, 2) };
                enc.push(tau);
                for k in 0..l {
                    let ph = 2f64.powi(k) * std::f64::consts::PI * tau;
                    enc.push(ph.sin());
                    enc.push(ph.cos());
                }
            }
            let mut h = enc.clone();
            for l in 0..4 {
                if l == 2 {
                    h.extend_from_slice(&enc);
                }
                let (ws, w) = get(&format!("layers.{l}.weight"));
                let (_, b) = get(&format!("layers.{l}.bias"));
                assert_eq!(ws, vec![h.len(), 16]);
                let z: Vec<f64> =
                    (0..16).map(|j| b[j] + (0..h.len()).map(|i| h[i] * w[i * 16 + j]).sum::<f64>()).collect();
                h = z
                    .iter()
                    .map(|&z| match act {
                        Activation::Relu => z.max(0.0),
                        Activation::Swish => z / (1.0 + (-z).exp()),
                    })
                    .collect();
            }
            let (_, w) = get("output.weight");
            let (_, b) = get("output.bias");
            let z = b[0] + h.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            let want = z.exp().ln_1p();
            assert!((o as f64 - want).abs() < 2e-5 * (1.0 + want), "{act:?}: fused {o} vs reference {want}");
        }
    }
}

#[test]
fn tensors_partition_the_parameters() {
    let mlp = MlpField::new(&MlpConfig::table_5_2(), 4, 0).unwrap();
    let grid = small_grid(3, 0);
    for t in [mlp.tensors(), grid.tensors()] {
        let mut end = 0;
        for (name, shape, r) in &t {
            assert_eq!(r.start, end, "{name} does not follow its predecessor");
            assert_eq!(shape.iter().product::<usize>(), r.len(), "{name} shape vs range");
            end = r.end;
        }
        let n = if t[0].0.starts_with("grid") { grid.num_params() } else { mlp.num_params() };
        assert_eq!(end, n);
    }
}

#[test]
fn initialisation_is_deterministic_from_the_seed() {
    let a = MlpField::new(&MlpConfig::default(), 3, 42).unwrap();
    let b = MlpField::new(&MlpConfig::default(), 3, 42).unwrap();
    let c = MlpField::new(&MlpConfig::default(), 3, 43).unwrap();
    assert_eq!(a.params(), b.params());
    assert_ne!(a.params(), c.params());
    let g1 = HashGridField::new(&HashGridConfig::default(), 3, 5).unwrap();
    let g2 = HashGridField::new(&HashGridConfig::default(), 3, 5).unwrap();
    assert_eq!(g1.params(), g2.params());
    // He-uniform bound of the first layer: √(6 / 51).
    let (_, _, r) = a.tensors().into_iter().next().unwrap();
    let bound = (6.0f32 / 51.0).sqrt();
    let w = &a.params()[r];
    assert!(w.iter().all(|v| v.abs() <= bound));
    assert!(w.iter().map(|v| v.abs()).fold(0.0, f32::max) > 0.9 * bound);
}

#[test]
fn chunked_evaluation_matches_one_call_and_tape_reuse() {
    let f = MlpField::new(&small(Activation::Swish, OutputActivation::Softplus), 3, 30).unwrap();
    let x = random_inputs(100, 3, 31);
    let mut tape = f.new_tape();
    let mut whole = vec![0.0; 100];
    f.eval(&x, &mut whole, &mut tape);
    let mut parts = vec![0.0; 100];
    for (xc, oc) in x.chunks(17 * 3).zip(parts.chunks_mut(17)) {
        f.eval(xc, oc, &mut tape);
    }
    assert_eq!(whole, parts);
}

/// `eval` (ping-pong inference) agrees with `forward`, and an `eval` between a `forward` and
/// its `backward` on the same tape leaves the recorded pass intact.
fn eval_matches_forward_and_keeps_the_tape<F: TrainableField>(f: &F, seed: u64) {
    let d = f.input_dim();
    let (xa, xb) = (random_inputs(50, d, seed), random_inputs(30, d, seed + 1));
    let c = vec![0.5f32; 50];
    let mut tape = f.new_tape();
    let (mut fa, mut ea, mut eb) = (vec![0.0; 50], vec![0.0; 50], vec![0.0; 30]);
    f.forward(&xa, &mut fa, &mut tape);
    let mut g_plain = vec![0.0; f.num_params()];
    f.backward(&mut tape, &c, &mut g_plain);
    f.forward(&xa, &mut fa, &mut tape);
    f.eval(&xb, &mut eb, &mut tape);
    f.eval(&xa, &mut ea, &mut tape);
    let mut g_interleaved = vec![0.0; f.num_params()];
    f.backward(&mut tape, &c, &mut g_interleaved);
    assert_eq!(g_plain, g_interleaved, "eval disturbed the recorded forward pass");
    for (a, b) in fa.iter().zip(&ea) {
        assert!((a - b).abs() <= 1e-6 * (1.0 + a.abs()), "eval {b} vs forward {a}");
    }
}

#[test]
fn eval_matches_forward_for_every_field() {
    for act in [Activation::Relu, Activation::Swish] {
        let cfg = MlpConfig { depth: 5, width: 24, activation: act, ..MlpConfig::default() };
        eval_matches_forward_and_keeps_the_tape(&MlpField::new(&cfg, 3, 40).unwrap(), 41);
        eval_matches_forward_and_keeps_the_tape(&MlpField::new(&cfg, 4, 42).unwrap(), 43);
    }
    eval_matches_forward_and_keeps_the_tape(&small_grid(3, 44), 45);
    eval_matches_forward_and_keeps_the_tape(&small_grid(4, 46), 47);
}
