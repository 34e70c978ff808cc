//! Adam against hand-computed steps, the learning-rate schedule, and the deterministic
//! gradient reduction.

use fluidnerf_neural::optim::{sum_gradients, Adam, AdamConfig, LrSchedule};

/// Adam (Kingma & Ba, Algorithm 1) in f64, written out step by step.
fn reference_adam(p: &mut [f64], m: &mut [f64], v: &mut [f64], g: &[f64], t: i32, lr: f64, eps: f64) {
    for i in 0..p.len() {
        m[i] = 0.9 * m[i] + 0.1 * g[i];
        v[i] = 0.999 * v[i] + 0.001 * g[i] * g[i];
        let m_hat = m[i] / (1.0 - 0.9f64.powi(t));
        let v_hat = v[i] / (1.0 - 0.999f64.powi(t));
        p[i] -= lr * m_hat / (v_hat.sqrt() + eps);
    }
}

#[test]
fn first_adam_step_moves_each_parameter_by_the_learning_rate() {
    // After one step m̂ = g and v̂ = g², so every parameter moves by lr·g/(|g| + ε).
    let mut adam = Adam::new(3, AdamConfig::default());
    let mut p = [1.0f32, -2.0, 0.5];
    let g = [0.5f32, -0.1, 0.0];
    adam.step(&mut p, &g, 0.1);
    assert!((p[0] - (1.0 - 0.1 * 0.5 / (0.5 + 1e-7))).abs() < 1e-6);
    assert!((p[1] - (-2.0 + 0.1 * 0.1 / (0.1 + 1e-7))).abs() < 1e-6);
    assert_eq!(p[2], 0.5, "a zero gradient does not move the parameter");
    assert_eq!(adam.step, 1);
}

#[test]
fn adam_matches_the_f64_reference_over_several_steps() {
    let n = 5;
    let mut adam = Adam::new(n, AdamConfig::default());
    let mut p: Vec<f32> = (0..n).map(|i| i as f32 * 0.3 - 0.6).collect();
    let mut pr: Vec<f64> = p.iter().map(|&x| x as f64).collect();
    let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
    for t in 1..=20 {
        let g: Vec<f32> = (0..n).map(|i| ((t * 7 + i * 3) as f32 * 0.37).sin()).collect();
        let gr: Vec<f64> = g.iter().map(|&x| x as f64).collect();
        adam.step(&mut p, &g, 1e-2);
        reference_adam(&mut pr, &mut m, &mut v, &gr, t as i32, 1e-2, 1e-7);
    }
    for (a, b) in p.iter().zip(&pr) {
        assert!((*a as f64 - b).abs() < 1e-5, "{a} vs {b}");
    }
}

#[test]
fn parallel_adam_on_a_large_vector_equals_the_serial_update() {
    let n = 100_003;
    let g: Vec<f32> = (0..n).map(|i| ((i * 13 % 101) as f32 - 50.0) * 1e-3).collect();
    let p0: Vec<f32> = (0..n).map(|i| (i as f32 * 1e-4).cos()).collect();
    let mut big = Adam::new(n, AdamConfig::default());
    let mut p_big = p0.clone();
    big.step(&mut p_big, &g, 3e-3);
    big.step(&mut p_big, &g, 3e-3);
    // The same update element by element through small (serial) optimisers.
    for i in (0..n).step_by(9973) {
        let mut one = Adam::new(1, AdamConfig::default());
        let mut p = [p0[i]];
        one.step(&mut p, &g[i..i + 1], 3e-3);
        one.step(&mut p, &g[i..i + 1], 3e-3);
        assert_eq!(p[0], p_big[i], "element {i}");
    }
}

#[test]
fn schedule_decays_exponentially_from_5e4_to_5e5() {
    let s = LrSchedule::default();
    assert_eq!(s.initial, 5e-4);
    assert!((s.lr(25_000) / 5e-5 - 1.0).abs() < 1e-5);
    // Constant ratio per iteration: exponential.
    let r1 = s.lr(1000) / s.lr(0);
    let r2 = s.lr(21_000) / s.lr(20_000);
    assert!((r1 / r2 - 1.0).abs() < 1e-4);
    assert!((r1 as f64 - 0.1f64.powf(1000.0 / 25_000.0)).abs() < 1e-5);
    // Keeps decaying past 25 000 (as NeRF's schedule).
    assert!((s.lr(50_000) / 5e-6 - 1.0).abs() < 1e-4);
}

#[test]
fn gradient_reduction_sums_and_clears_the_per_thread_buffers() {
    let n = 40_000;
    let mut per_thread: Vec<Vec<f32>> = (0..3).map(|k| (0..n).map(|i| (i + k) as f32).collect()).collect();
    let mut total = vec![7.0; n];
    sum_gradients(&mut per_thread, &mut total);
    for (i, t) in total.iter().enumerate() {
        assert_eq!(*t, (3 * i + 3) as f32);
    }
    assert!(per_thread.iter().all(|g| g.iter().all(|&x| x == 0.0)));
}

#[test]
fn invalid_settings_are_rejected() {
    assert!(AdamConfig { beta1: 1.0, ..Default::default() }.validate().is_err());
    assert!(AdamConfig { eps: 0.0, ..Default::default() }.validate().is_err());
    assert!(LrSchedule { decay_iters: 0, ..Default::default() }.validate().is_err());
    assert!(AdamConfig::default().validate().is_ok());
}
