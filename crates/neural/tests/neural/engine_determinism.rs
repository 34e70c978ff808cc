//! A multi-threaded training step is bit-reproducible from the seed, and poison inputs (NaN,
//! ±∞, points outside the box) never panic or index out of bounds.

use fluidnerf_neural::optim::{sum_gradients, Adam, AdamConfig};
use fluidnerf_neural::{Activation, HashGridConfig, HashGridField, MlpConfig, MlpField, TrainableField};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

/// Three steps of forward + MSE + backward + reduction + Adam, the batch split into two
/// fixed shares run on the rayon pool in chunks of 37 rows; returns the final parameters.
fn train<F: TrainableField>(mut field: F, seed: u64) -> Vec<f32> {
    let d = field.input_dim();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = 300;
    let x: Vec<f32> = (0..n * d).map(|_| rng.random()).collect();
    let y: Vec<f32> = (0..n).map(|_| rng.random()).collect();
    let mut adam = Adam::new(field.num_params(), AdamConfig::default());
    let mut per_thread = vec![vec![0.0f32; field.num_params()]; 2];
    let mut total = vec![0.0f32; field.num_params()];
    for _ in 0..3 {
        let f = &field;
        per_thread.par_iter_mut().enumerate().for_each(|(t, grads)| {
            let mut tape = f.new_tape();
            let rows = if t == 0 { 0..150 } else { 150..n };
            let mut i = rows.start;
            while i < rows.end {
                let m = 37.min(rows.end - i);
                let mut out = vec![0.0; m];
                f.forward(&x[i * d..(i + m) * d], &mut out, &mut tape);
                let g: Vec<f32> = out.iter().zip(&y[i..i + m]).map(|(o, y)| 2.0 * (o - y) / n as f32).collect();
                f.backward(&mut tape, &g, grads);
                i += m;
            }
        });
        sum_gradients(&mut per_thread, &mut total);
        adam.step(field.params_mut(), &total, 1e-2);
    }
    field.params().to_vec()
}

#[test]
fn training_steps_are_bit_reproducible() {
    let cfg = MlpConfig { depth: 4, width: 32, activation: Activation::Swish, ..MlpConfig::default() };
    let a = train(MlpField::new(&cfg, 3, 1).unwrap(), 2);
    let b = train(MlpField::new(&cfg, 3, 1).unwrap(), 2);
    assert_eq!(a, b);
    let start = MlpField::new(&cfg, 3, 1).unwrap();
    assert_ne!(a, start.params(), "the steps changed the parameters");

    let gcfg = HashGridConfig { levels: 4, log2_table_size: 10, max_resolution: 32, ..HashGridConfig::default() };
    let a = train(HashGridField::new(&gcfg, 4, 3).unwrap(), 4);
    let b = train(HashGridField::new(&gcfg, 4, 3).unwrap(), 4);
    assert_eq!(a, b);
}

#[test]
fn poison_inputs_do_not_panic_and_outside_points_are_clamped() {
    let poison = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -5.0, 7.0, 1e30, -0.0, 1.0];
    let rows: Vec<f32> = poison.iter().flat_map(|&p| [p, 0.5, 0.5, p]).collect();
    let grid = HashGridField::new(&HashGridConfig::default(), 4, 0).unwrap();
    let mlp = MlpField::new(&MlpConfig::default(), 4, 0).unwrap();
    let mut out = vec![0.0; poison.len()];
    let mut tape = grid.new_tape();
    grid.forward(&rows, &mut out, &mut tape);
    let mut grads = vec![0.0; grid.num_params()];
    grid.backward(&mut tape, &vec![1.0; poison.len()], &mut grads);
    // Outside the box the grid sees the nearest boundary point.
    let edge: Vec<f32> = [0.0f32, 1.0].iter().flat_map(|&p| [p, 0.5, 0.5, p]).collect();
    let mut at_edge = vec![0.0; 2];
    grid.eval(&edge, &mut at_edge, &mut grid.new_tape());
    assert_eq!(out[3], at_edge[0], "x = −5 clamps to the box");
    assert_eq!(out[4], at_edge[1], "x = 7 clamps to the box");
    assert!(out[1..].iter().all(|v| v.is_finite() && *v >= 0.0));
    let mut tape = mlp.new_tape();
    mlp.forward(&rows, &mut out, &mut tape);
    let mut grads = vec![0.0; mlp.num_params()];
    mlp.backward(&mut tape, &vec![1.0; poison.len()], &mut grads);
    // Empty chunks are fine too.
    mlp.forward(&[], &mut [], &mut tape);
    mlp.backward(&mut tape, &[], &mut grads);
}
