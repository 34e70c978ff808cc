//! Optimiser and learning-rate schedule of section 5.1.5, on flat f32 parameter vectors.
//!
//! - [`Adam`] (Kingma & Ba 2015, Algorithm 1, with bias correction):
//!   `m ← β₁ m + (1 − β₁) g`, `v ← β₂ v + (1 − β₂) g²`,
//!   `θ ← θ − lr · m̂ / (√v̂ + ε)` with `m̂ = m / (1 − β₁ᵗ)`, `v̂ = v / (1 − β₂ᵗ)`.
//!   Defaults are the "default" hyperparameters the dissertation keeps from NeRF:
//!   β₁ = 0.9, β₂ = 0.999, ε = 10⁻⁷ (NeRF and TensorFlow's value; PyTorch uses 10⁻⁸).
//!   With [`AdamConfig::lazy`] an element whose gradient is exactly zero is left as it is
//!   (parameter and both moments), as instant-ngp does for its hash-table entries: a table entry
//!   that no sample of the batch touched is not moved by momentum from earlier batches. Every
//!   element with a non-zero gradient gets the dense update above, bias correction included
//!   (`t` counts the optimiser's steps, not the element's).
//! - [`LrSchedule`]: exponential decay `lr(i) = lr₀ (lr₁ / lr₀)^{i / N}`, 5·10⁻⁴ → 5·10⁻⁵ at
//!   N = 25 000 iterations; like NeRF's schedule it keeps decaying past N.
//! - [`sum_gradients`]: the reduction of per-thread gradient buffers (see
//!   [`crate::TrainableField`]'s threading contract).
//!
//! Large vectors are updated in parallel over fixed 16 384-element blocks; every element's
//! arithmetic is independent of the blocking, so results are bit-identical for any number of
//! threads.

use fluidnerf_core::num;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::NeuralError;
use crate::kernels::multiversion;

/// Elements per parallel block: large enough to amortise rayon, small enough to balance.
const BLOCK: usize = 1 << 14;

/// The largest [`AdamConfig::eps`] ([`AdamConfig::validate`] says why).
pub const MAX_ADAM_EPS: f32 = 1.0;

/// Adam hyperparameters (the learning rate comes from [`LrSchedule`] at each step).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdamConfig {
    /// Decay of the first-moment average β₁. Default 0.9.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub beta1: f32,
    /// Decay of the second-moment average β₂. Default 0.999.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub beta2: f32,
    /// ε added to √v̂, at most [`MAX_ADAM_EPS`]. Default 1e-7.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub eps: f32,
    /// Skip elements whose gradient is exactly zero (see the module docs). Default false.
    pub lazy: bool,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-7, lazy: false }
    }
}

impl AdamConfig {
    pub fn validate(&self) -> Result<(), NeuralError> {
        let ok = |b: f32| (0.0..1.0).contains(&b);
        for (key, b) in [("adam.beta1", self.beta1), ("adam.beta2", self.beta2)] {
            if !ok(b) {
                return Err(NeuralError::invalid(key, format!("Adam's decay rate must lie in [0, 1), got {}", num(b))));
            }
        }
        if !(self.eps > 0.0 && self.eps.is_finite()) {
            return Err(NeuralError::invalid("adam.eps", format!("must be positive, got {}", num(self.eps))));
        }
        // ε guards the division by √v̂, the root mean square of a parameter's gradient, which
        // is well below 1 on images scaled to a peak of about 1. An ε beyond it divides every
        // step by ε instead: at 1e30 training moved nothing and ran to its cap.
        if self.eps > MAX_ADAM_EPS {
            return Err(NeuralError::invalid(
                "adam.eps",
                format!(
                    "must be at most {} (it only keeps the step's division by the gradients' root mean square \
                     finite; a larger one shrinks every step), got {}",
                    num(MAX_ADAM_EPS),
                    num(self.eps)
                ),
            ));
        }
        Ok(())
    }
}

/// Adam state: first and second moments and the step count, laid out like the parameters.
/// Serialisable as a whole (serde) or tensor by tensor (`m`, `v` sliced by
/// [`crate::TrainableField::tensors`], as the safetensors checkpoints do).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adam {
    pub config: AdamConfig,
    /// First-moment estimates m.
    pub m: Vec<f32>,
    /// Second-moment estimates v.
    pub v: Vec<f32>,
    /// Number of steps taken (t in the update; the next step uses t + 1).
    pub step: u64,
}

impl Adam {
    /// Zero moments for `num_params` parameters.
    pub fn new(num_params: usize, config: AdamConfig) -> Self {
        Self { config, m: vec![0.0; num_params], v: vec![0.0; num_params], step: 0 }
    }

    /// One update of `params` with gradient `grads` and learning rate `lr`.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        assert_eq!(params.len(), self.m.len(), "Adam::step: {} params, state for {}", params.len(), self.m.len());
        assert_eq!(grads.len(), params.len(), "Adam::step: gradient length differs from params");
        self.step += 1;
        let t = self.step as f64;
        let c = self.config;
        let coeffs = AdamCoeffs {
            lazy: c.lazy,
            beta1: c.beta1,
            beta2: c.beta2,
            eps: c.eps,
            lr,
            bias1: (1.0 / (1.0 - (c.beta1 as f64).powf(t))) as f32,
            bias2: (1.0 / (1.0 - (c.beta2 as f64).powf(t))) as f32,
        };
        let kernel = |p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]| {
            // A lazy block without any gradient is left as it is.
            if !c.lazy || g.iter().any(|&g| g != 0.0) {
                adam_kernel(p, g, m, v, coeffs);
            }
        };
        if params.len() <= BLOCK {
            kernel(params, grads, &mut self.m, &mut self.v);
        } else {
            params
                .par_chunks_mut(BLOCK)
                .zip(grads.par_chunks(BLOCK))
                .zip(self.m.par_chunks_mut(BLOCK))
                .zip(self.v.par_chunks_mut(BLOCK))
                .for_each(|(((p, g), m), v)| kernel(p, g, m, v));
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub(crate) struct AdamCoeffs {
    lazy: bool,
    beta1: f32,
    beta2: f32,
    eps: f32,
    lr: f32,
    bias1: f32,
    bias2: f32,
}

multiversion! {
    /// One Adam step per element; with `c.lazy`, elements whose gradient is zero keep their
    /// values. Branch-free (selects), so it vectorises either way.
    fn adam_kernel(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], c: AdamCoeffs) {
        for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
            let live = !c.lazy || g != 0.0;
            let m_new = c.beta1 * *m + (1.0 - c.beta1) * g;
            let v_new = c.beta2 * *v + (1.0 - c.beta2) * (g * g);
            let p_new = *p - c.lr * (m_new * c.bias1) / ((v_new * c.bias2).sqrt() + c.eps);
            *m = if live { m_new } else { *m };
            *v = if live { v_new } else { *v };
            *p = if live { p_new } else { *p };
        }
    }
}

/// The largest learning rate a schedule or a start's fit accepts. Adam moves each parameter by
/// about the rate at every step, and the fields' parameters are of order 10⁻⁴ to 1, so a rate
/// above 1 is never a training setting: it diverges or overflows at its first steps. The presets
/// use 5·10⁻⁴ to 2·10⁻².
pub const MAX_LEARNING_RATE: f32 = 1.0;

/// Exponential learning-rate decay of section 5.1.5.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LrSchedule {
    /// Learning rate at iteration 0. Default 5e-4.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub initial: f32,
    /// Learning rate reached at `decay_iters`. Default 5e-5.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub at_decay_iters: f32,
    /// Iterations over which the rate falls from `initial` to `at_decay_iters`. Default 25 000.
    pub decay_iters: u64,
}

impl Default for LrSchedule {
    fn default() -> Self {
        Self { initial: 5e-4, at_decay_iters: 5e-5, decay_iters: 25_000 }
    }
}

impl LrSchedule {
    /// Learning rate of (0-based) iteration `iter`.
    pub fn lr(&self, iter: u64) -> f32 {
        let ratio = self.at_decay_iters as f64 / self.initial as f64;
        (self.initial as f64 * ratio.powf(iter as f64 / self.decay_iters as f64)) as f32
    }

    /// Rejects a schedule no run can train with: rates outside (0, [`MAX_LEARNING_RATE`]] (an
    /// Adam step moves every parameter by about the rate, so a larger one only diverges or
    /// overflows), or no decay length.
    pub fn validate(&self) -> Result<(), NeuralError> {
        for (key, rate) in [("schedule.initial", self.initial), ("schedule.at_decay_iters", self.at_decay_iters)] {
            if !(rate > 0.0 && rate <= MAX_LEARNING_RATE) {
                return Err(NeuralError::invalid(
                    key,
                    format!(
                        "the learning rate must be positive and at most {} (an Adam step moves each parameter by \
                         about the rate), got {}",
                        num(MAX_LEARNING_RATE),
                        num(rate)
                    ),
                ));
            }
        }
        if self.decay_iters == 0 {
            return Err(NeuralError::invalid("schedule.decay_iters", "must be at least 1"));
        }
        Ok(())
    }
}

/// `total = Σ_k per_thread[k]`, then zeroes every `per_thread[k]` for the next step. Parallel
/// over blocks; the sum over threads runs in a fixed order, so it is deterministic. Each
/// block's task clears the ranges it has just read, while they are in its cache, instead of a
/// pass of its own over every buffer afterwards.
pub fn sum_gradients(per_thread: &mut [Vec<f32>], total: &mut [f32]) {
    for g in per_thread.iter() {
        assert_eq!(g.len(), total.len(), "sum_gradients: buffer length differs from total");
    }
    /// A worker's buffer, shared between the block tasks, each of which touches only its own
    /// range of it.
    struct Buffer(*mut f32);
    // SAFETY: the tasks access disjoint ranges of the buffer (below).
    unsafe impl Sync for Buffer {}
    let buffers: Vec<Buffer> = per_thread.iter_mut().map(|g| Buffer(g.as_mut_ptr())).collect();
    total.par_chunks_mut(BLOCK).enumerate().for_each(|(b, out)| {
        let start = b * BLOCK;
        out.fill(0.0);
        for buffer in &buffers {
            // SAFETY: every buffer is `total.len()` long (asserted above) and outlives this
            // call, in which nothing else accesses it; block `b` is the only task that reads or
            // writes `start..start + out.len()` of it.
            let g = unsafe { std::slice::from_raw_parts_mut(buffer.0.add(start), out.len()) };
            crate::kernels::add_assign(out, g);
            g.fill(0.0);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_hits_its_end_points() {
        let s = LrSchedule::default();
        assert!((s.lr(0) - 5e-4).abs() < 1e-9);
        assert!((s.lr(25_000) - 5e-5).abs() < 1e-10);
        assert!((s.lr(12_500) - 5e-4 * 0.1f32.sqrt()).abs() < 1e-9);
    }

    /// Rates that are not positive, absurdly large (finite or not) or NaN are refused under
    /// their own key; the largest accepted rate passes.
    #[test]
    fn schedule_refuses_rates_out_of_range_by_key() {
        let ok = LrSchedule { initial: MAX_LEARNING_RATE, at_decay_iters: 1e-6, ..LrSchedule::default() };
        assert!(ok.validate().is_ok());
        for bad in [0.0, -1e-3, 1.5, 1e30, f32::INFINITY, f32::NAN] {
            for (key, s) in [
                ("schedule.initial", LrSchedule { initial: bad, ..LrSchedule::default() }),
                ("schedule.at_decay_iters", LrSchedule { at_decay_iters: bad, ..LrSchedule::default() }),
            ] {
                let e = s.validate().expect_err("refused").to_string();
                assert!(e.contains(key) && e.contains("at most 1") && e.contains(&num(bad).to_string()), "{e}");
            }
        }
        let e = LrSchedule { decay_iters: 0, ..LrSchedule::default() }.validate().expect_err("refused");
        assert!(e.to_string().contains("schedule.decay_iters"), "{e}");
    }

    /// A rate written beyond what an f32 holds is refused as written, not as the infinity or
    /// zero it would round to (which the range check would then report as "got inf").
    #[test]
    fn a_schedule_read_from_a_file_refuses_rates_no_f32_holds_as_written() {
        let read = |text: &str| serde_json::from_str::<LrSchedule>(text).map_err(|e| e.to_string());
        assert_eq!(read(r#"{"initial": 0.01}"#).map(|s| s.initial), Ok(0.01));
        let e = read(r#"{"initial": 1e300}"#).expect_err("refused");
        assert!(e.starts_with("1e300 is beyond what this setting's 32-bit float holds"), "{e}");
        let e = read(r#"{"at_decay_iters": -1e-50}"#).expect_err("refused");
        assert!(e.starts_with("-1e-50 is below the smallest non-zero value"), "{e}");
    }

    /// Decay rates outside [0, 1) and an ε that is not positive, not finite or above
    /// [`MAX_ADAM_EPS`] are refused under their own key; the edges of the ranges pass.
    #[test]
    fn adam_refuses_decay_rates_and_eps_out_of_range_by_key() {
        let ok = AdamConfig::default();
        for good in [AdamConfig { beta1: 0.0, beta2: 0.0, ..ok }, AdamConfig { eps: MAX_ADAM_EPS, ..ok }] {
            assert!(good.validate().is_ok(), "{good:?}");
        }
        for bad in [-0.1, 1.0, 1.5, f32::NAN] {
            for (key, c) in
                [("adam.beta1", AdamConfig { beta1: bad, ..ok }), ("adam.beta2", AdamConfig { beta2: bad, ..ok })]
            {
                let e = c.validate().expect_err("refused").to_string();
                assert!(e.contains(key) && e.contains("[0, 1)"), "{e}");
            }
        }
        for bad in [0.0, -1e-7, 1.5, 1e30, f32::INFINITY, f32::NAN] {
            let e = AdamConfig { eps: bad, ..ok }.validate().expect_err("refused").to_string();
            assert!(e.contains("adam.eps"), "{e}");
        }
    }

    /// Two steps worked out by hand: the first moves by `lr · g / (|g| + ε)` (m̂ = g, v̂ = g²),
    /// the second by `lr · m̂ / (√v̂ + ε)` with the bias corrections of t = 2.
    #[test]
    fn two_adam_steps_match_the_hand_computed_update() {
        let mut adam = Adam::new(1, AdamConfig::default());
        let mut p = [1.0f32];
        adam.step(&mut p, &[1.0], 0.1);
        assert!((p[0] - (1.0 - 0.1 / (1.0 + 1e-7))).abs() < 1e-7, "{}", p[0]);
        // (1 − β₂ in f32 is 1e-3 to 1.3e-5 relative.)
        assert!((adam.m[0] - 0.1).abs() < 1e-7 && (adam.v[0] - 1e-3).abs() < 1e-7, "{adam:?}");
        adam.step(&mut p, &[0.5], 0.1);
        // m = 0.9 · 0.1 + 0.1 · 0.5 = 0.14, v = 0.999 · 0.001 + 0.001 · 0.25 = 0.001249;
        // m̂ = 0.14 / (1 − 0.81), v̂ = 0.001249 / (1 − 0.998001).
        let (m_hat, v_hat) = (0.14f64 / 0.19, 0.001249f64 / 0.001999);
        let expect = 1.0 - 0.1 / (1.0 + 1e-7) - 0.1 * m_hat / (v_hat.sqrt() + 1e-7);
        assert!((p[0] as f64 - expect).abs() < 2e-6, "{} vs {expect}", p[0]);
        assert!((adam.m[0] - 0.14).abs() < 1e-7 && (adam.v[0] - 0.001249).abs() < 1e-7, "{adam:?}");
        assert_eq!(adam.step, 2);
    }

    /// Dense Adam moves an element without a gradient by its momentum, even in a block of the
    /// parallel update where no element has a gradient.
    #[test]
    fn dense_adam_moves_elements_without_gradient_by_their_momentum() {
        let n = 2 * BLOCK + 3;
        let mut adam = Adam::new(n, AdamConfig::default());
        let mut p = vec![0.0f32; n];
        adam.step(&mut p, &vec![1.0; n], 0.1);
        let after_first = p.clone();
        adam.step(&mut p, &vec![0.0; n], 0.1);
        // m = 0.09, v = 0.000999: m̂ = 0.09 / 0.19, v̂ = 0.000999 / 0.001999.
        let moved = 0.1 * (0.09f64 / 0.19) / ((0.000999f64 / 0.001999).sqrt() + 1e-7);
        for i in [0, BLOCK, n - 1] {
            assert!(((after_first[i] - p[i]) as f64 - moved).abs() < 1e-6, "element {i}: {}", p[i]);
        }
    }

    /// Lazy Adam leaves elements without a gradient exactly as they were, and updates the others
    /// exactly as dense Adam does: over several blocks (one of them without any gradient), from
    /// moments that are not zero, for several steps.
    #[test]
    fn lazy_adam_skips_elements_without_gradient_and_matches_dense_elsewhere() {
        let n = 3 * BLOCK + 5;
        let live = |i: usize| !i.is_multiple_of(3) && !(BLOCK..2 * BLOCK).contains(&i);
        let start: Vec<f32> = (0..n).map(|i| ((i * 37 % 101) as f32 - 50.0) * 1e-3).collect();
        let mut dense = Adam::new(n, AdamConfig::default());
        dense.m.iter_mut().enumerate().for_each(|(i, m)| *m = ((i % 7) as f32 - 3.0) * 1e-4);
        dense.v.iter_mut().enumerate().for_each(|(i, v)| *v = (1 + i % 5) as f32 * 1e-6);
        dense.step = 4;
        let mut lazy = dense.clone();
        lazy.config.lazy = true;
        let (m0, v0) = (dense.m.clone(), dense.v.clone());
        let (mut p_dense, mut p_lazy) = (start.clone(), start.clone());
        for step in 0..4 {
            let g: Vec<f32> =
                (0..n).map(|i| if live(i) { ((i + step) % 11) as f32 * 1e-2 - 0.05 + 1e-3 } else { 0.0 }).collect();
            dense.step(&mut p_dense, &g, 0.01);
            lazy.step(&mut p_lazy, &g, 0.01);
        }
        let mut coasted = 0;
        for i in 0..n {
            if live(i) {
                assert_eq!(p_lazy[i].to_bits(), p_dense[i].to_bits(), "element {i}");
                assert_eq!(lazy.m[i].to_bits(), dense.m[i].to_bits(), "m of element {i}");
                assert_eq!(lazy.v[i].to_bits(), dense.v[i].to_bits(), "v of element {i}");
            } else {
                assert_eq!((p_lazy[i], lazy.m[i], lazy.v[i]), (start[i], m0[i], v0[i]), "element {i}");
                coasted += usize::from(p_dense[i] != start[i]);
            }
        }
        // Dense Adam moves elements without a gradient by their momentum: the two differ.
        assert!(coasted > n / 4, "dense Adam moved {coasted} elements without a gradient");
    }
}
