//! The priors of [`Prior`] for fields without a grid of their own (the hash grid, the MLPs):
//! a Monte Carlo estimate of the dense grid's prior ([`crate::dense`]).
//!
//! Every iteration draws `prior.points` points `x` uniformly in the occupied part of the box
//! (all of it without empty-space skipping; for space–time fields, at a training frame's time
//! drawn uniformly) and evaluates the field at `x` and at its three forward neighbours
//! `x + h·e_a`, `h = prior.step` (box-normalised units; default 1/128, the finest cell of the
//! `fast` grid). With `d_a = E(x + h·e_a) − E(x)` and `g² = Σ_a d_a²` the term is
//!
//! ```text
//! tv · mean √(g² + ε²) + smooth · mean g² + sparsity · mean E(x),        ε = 1e-3,
//! ```
//!
//! the same forward differences and weights as the dense grid's prior with cell size `h`, so
//! one weight means the same on every representation. Points outside the occupied cells are
//! skipped (the field is never used there); the estimate is unbiased for the mean over the
//! occupied region. The points come from their own random stream
//! (`stream_seed(seed ^ PRIOR_KEY, iteration, 0)`), so a run stays reproducible.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::batch::{stream_seed, RayBatch};
use crate::train::{Prepared, Split};
use crate::{Prior, TrainableField};

/// Key that separates the prior's random stream from the samplers'.
const PRIOR_KEY: u64 = 0x7072_696f_7200_0001;
const EPS2: f32 = 1e-6;

/// Buffers reused across iterations.
#[derive(Debug, Default)]
pub struct PriorScratch {
    inputs: Vec<f32>,
    values: Vec<f32>,
    d_out: Vec<f32>,
}

/// Adds the gradient of the point-sampled prior to `grads` and returns its value (module doc).
/// Does nothing and returns 0 when the prior is zero.
pub fn add_point_prior<F: TrainableField>(
    field: &F,
    prep: &Prepared,
    prior: &Prior,
    batch: &RayBatch,
    tape: &mut F::Tape,
    scratch: &mut PriorScratch,
    grads: &mut [f32],
) -> f32 {
    if prior.is_zero() || prior.points == 0 {
        return 0.0;
    }
    let dim = field.input_dim();
    let h = prior.step;
    let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(batch.seed ^ PRIOR_KEY, batch.stream, 0));
    let times: Vec<f32> = {
        let mut t: Vec<f32> = prep.views(Split::Train).iter().map(|v| v.time()).collect();
        t.sort_by(f32::total_cmp);
        t.dedup();
        t
    };
    let occupancy = prep.occupancy();
    let inputs = &mut scratch.inputs;
    inputs.clear();
    let mut n = 0usize;
    // A bounded number of draws: with a sparse hull most draws may land in empty cells.
    for _ in 0..prior.points * 8 {
        if n == prior.points {
            break;
        }
        let x: [f32; 3] = std::array::from_fn(|_| rng.random::<f32>() * (1.0 - h));
        if occupancy.is_some_and(|g| !g.is_occupied(x)) {
            continue;
        }
        let t = if dim == 4 { times[rng.random_range(0..times.len())] } else { 0.0 };
        for a in 0..4 {
            let mut p = x;
            if a > 0 {
                p[a - 1] += h;
            }
            inputs.extend_from_slice(&p);
            if dim == 4 {
                inputs.push(t);
            }
        }
        n += 1;
    }
    if n == 0 {
        return 0.0;
    }
    let rows = 4 * n;
    scratch.values.resize(rows, 0.0);
    field.forward(inputs, &mut scratch.values, tape);
    let e = &scratch.values;
    scratch.d_out.clear();
    scratch.d_out.resize(rows, 0.0);
    let inv_n = 1.0 / n as f32;
    let mut value = 0f64;
    for q in 0..n {
        let c = e[4 * q];
        let d = [e[4 * q + 1] - c, e[4 * q + 2] - c, e[4 * q + 3] - c];
        let g2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        let t = (g2 + EPS2).sqrt();
        value += (prior.tv * t + prior.smooth * g2 + prior.sparsity * c) as f64;
        scratch.d_out[4 * q] += prior.sparsity * inv_n;
        let s = (prior.tv / t + 2.0 * prior.smooth) * inv_n;
        for a in 0..3 {
            scratch.d_out[4 * q + 1 + a] += s * d[a];
            scratch.d_out[4 * q] -= s * d[a];
        }
    }
    field.backward(tape, &scratch.d_out, grads);
    (value / n as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::DenseGridField;
    use crate::train::{Problem, TrainConfig, View};
    use fluidnerf_core::{Aabb, Camera, Image, Intrinsics};
    use glam::DVec3;

    fn prepared() -> Prepared {
        let k = Intrinsics { width: 8, height: 8, fx: 15.0, fy: 15.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        let views = (0..3)
            .map(|i| {
                let a = i as f64;
                let camera = Camera::look_at(k, DVec3::new(0.0, 5.0 * a.cos(), 5.0 * a.sin()), DVec3::ZERO, DVec3::X);
                let mut image = Image::zeros(8, 8);
                image.data.fill(1.0);
                View { camera, image, time: 0.0 }
            })
            .collect();
        let problem = Problem {
            aabb: Aabb::cube(DVec3::ZERO, 2.0),
            intensity_scale: 1.0,
            views,
            holdout: vec![],
            time_step: 1.0,
        };
        Prepared::new(&problem, &TrainConfig::default()).expect("prepares")
    }

    fn prior_of(field: &DenseGridField, prep: &Prepared, prior: &Prior) -> (f32, Vec<f32>) {
        let mut grads = vec![0.0; field.num_params()];
        let batch = RayBatch::new(crate::train::Split::Train, 3, 1);
        let mut tape = field.new_tape();
        let v = add_point_prior(field, prep, prior, &batch, &mut tape, &mut PriorScratch::default(), &mut grads);
        (v, grads)
    }

    /// On a constant field every difference is zero: the value is `tv · ε + sparsity · E`, and
    /// the gradient is the sparsity's alone, `sparsity · dE/dv` spread over the grid's
    /// parameters by trilinear weights that sum to 1.
    #[test]
    fn the_prior_of_a_constant_field_is_its_sparsity_and_the_tv_floor() {
        let prep = prepared();
        let field = DenseGridField::new([4, 4, 4], 1.0);
        let prior = Prior { tv: 0.5, smooth: 0.3, sparsity: 0.2, points: 64, step: 1.0 / 64.0 };
        let (value, grads) = prior_of(&field, &prep, &prior);
        assert!((value - (0.5 * 1e-3 + 0.2)).abs() < 1e-5, "{value}");
        // dE/dv = sigmoid(v) = 1 − e⁻¹ where softplus(v) = 1.
        let total: f32 = grads.iter().sum();
        assert!((total - 0.2 * (1.0 - (-1.0f32).exp())).abs() < 1e-5, "{total}");
        // Without weights, or without points, there is nothing to add.
        for none in [Prior { points: 64, ..Prior::default() }, Prior { points: 0, ..prior }] {
            let (value, grads) = prior_of(&field, &prep, &none);
            assert_eq!(value, 0.0);
            assert!(grads.iter().all(|&g| g == 0.0));
        }
    }
}
