//! Starting a field from another reconstruction: before training on rays, the field is fitted
//! to a given field (a classical method's volume, say) by least squares on random points, as
//! in prior-embedded neural tomography (NeRP, Shen et al. 2022). Ray training then continues
//! from that field with a fresh optimiser.
//!
//! Each fitting step draws [`StartFit::points`] points uniformly in the occupied part of the
//! box (all of it without empty-space skipping; for space–time fields at a training frame's
//! time), evaluates the target there and takes one Adam step on the mean squared difference,
//! at the constant rate [`StartFit::learning_rate`]. The points come from their own random
//! stream (`stream_seed(seed ^ START_KEY, step, 0)`), so a start is reproducible.
//!
//! A step's points are split into one contiguous share per thread of the pool, and the
//! shares' gradients are summed in share order: a fit is bit-for-bit the same from run to run
//! on the same thread count, and, like training, may differ in the last digits on another.

use std::ops::ControlFlow;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::batch::stream_seed;
use crate::optim::{sum_gradients, Adam, AdamConfig};
use crate::train::Prepared;
use glam::Vec3;

use crate::{NeuralError, TrainableField};

/// Key that separates the start's random stream from the samplers' and the prior's.
const START_KEY: u64 = 0x7374_6172_7400_0001;

/// The most points of one fitting step ([`StartFit::points`]): they are evaluated in one
/// pass, held with the field's activations.
pub const MAX_START_POINTS: usize = 1 << 20;

/// How a field is fitted to a starting field.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StartFit {
    /// Adam steps, 1 to [`fluidnerf_core::MAX_ITERATIONS`]. Default 300.
    pub iterations: usize,
    /// Points per step. Default 16384.
    pub points: usize,
    /// Constant Adam learning rate. Default 1e-2.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub learning_rate: f32,
}

impl Default for StartFit {
    fn default() -> Self {
        StartFit { iterations: 300, points: 16384, learning_rate: 1e-2 }
    }
}

impl StartFit {
    /// Rejects settings no fit can use.
    pub fn validate(&self) -> Result<(), NeuralError> {
        // A fit of more steps than any run's cap would never end unless a time budget ended it.
        let cap = fluidnerf_core::MAX_ITERATIONS;
        if !(1..=cap).contains(&self.iterations) {
            return Err(NeuralError::invalid(
                "start.iterations",
                format!("must be 1 to {cap} steps, got {}", self.iterations),
            ));
        }
        if !(1..=MAX_START_POINTS).contains(&self.points) {
            return Err(NeuralError::invalid(
                "start.points",
                format!("must be 1 to {MAX_START_POINTS} points per step, got {}", self.points),
            ));
        }
        let max = crate::optim::MAX_LEARNING_RATE;
        if !(self.learning_rate > 0.0 && self.learning_rate <= max) {
            return Err(NeuralError::invalid(
                "start.learning_rate",
                format!(
                    "must be positive and at most {}, got {}",
                    fluidnerf_core::num(max),
                    fluidnerf_core::num(self.learning_rate)
                ),
            ));
        }
        Ok(())
    }
}

/// What a fit reached: the mean squared difference (field units²) of its last step and the
/// mean square of the target there, so `(mse / mean_square).sqrt()` is a relative error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StartReport {
    pub mse: f64,
    pub mean_square: f64,
    pub seconds: f64,
    /// Steps taken: [`StartFit::iterations`], or fewer when the time limit came first or the
    /// caller stopped the fit ([`StartReport::stopped`]).
    pub steps: usize,
    /// The caller's `on_step` stopped the fit.
    pub stopped: bool,
    /// The factor the target was multiplied by, when it lay outside [`START_LEVELS`].
    pub rescaled: Option<f64>,
}

impl StartReport {
    /// The last step's RMS difference relative to the target's RMS.
    pub fn relative_difference(&self) -> f64 {
        (self.mse / self.mean_square.max(f64::MIN_POSITIVE)).sqrt()
    }
}

/// `target(frame_time, points, out)`: a reconstruction's values (world units) at world points
/// at one frame time.
pub type FrameTarget<'a> = dyn Fn(f64, &[Vec3], &mut [f32]) + Sync + 'a;

/// [`fit_to_target`] for a target in world coordinates and units, given per frame: `frames`
/// pairs each training frame's `t'` with its time in the recording. A field of space alone
/// takes exactly one frame (a static field: `[(0.0, 0.0)]`).
pub fn fit_to_frames<F: TrainableField>(
    field: &mut F,
    prep: &Prepared,
    frames: &[(f32, f64)],
    target: &FrameTarget,
    fit: &StartFit,
    seed: u64,
    time_limit_s: Option<f64>,
    on_step: &mut dyn FnMut(usize) -> ControlFlow<()>,
) -> Result<StartReport, NeuralError> {
    let (min, size) = (prep.meta.aabb.min.as_vec3(), prep.meta.aabb.size().as_vec3());
    let inv_scale = (1.0 / prep.meta.value_scale) as f32;
    let dim = field.input_dim();
    if dim == 3 && frames.len() != 1 {
        return Err(NeuralError::invalid(
            "start",
            format!(
                "a field of space alone cannot start from {} instants; it needs a field of space and time",
                frames.len()
            ),
        ));
    }
    let in_units = |inputs: &[f32], out: &mut [f32]| {
        out.fill(0.0);
        let rows: Vec<&[f32]> = inputs.chunks_exact(dim).collect();
        for &(tp, t) in frames {
            let tol = 1e-4 * (1.0 + tp.abs());
            let at: Vec<usize> = (0..rows.len()).filter(|&i| dim == 3 || (rows[i][3] - tp).abs() <= tol).collect();
            if at.is_empty() {
                continue;
            }
            let points: Vec<Vec3> =
                at.iter().map(|&i| min + Vec3::new(rows[i][0], rows[i][1], rows[i][2]) * size).collect();
            let mut values = vec![0f32; at.len()];
            target(t, &points, &mut values);
            for (&i, v) in at.iter().zip(values) {
                out[i] = v * inv_scale;
            }
        }
    };
    fit_to_target(field, prep, &in_units, fit, seed, time_limit_s, on_step)
}

/// The range of the target's RMS over the occupied points, as a multiple of the level the
/// training images ask for ([`Prepared::mean_level`]), within which a start is taken as it is.
/// Starts of the same scene measured 2.1–2.5; one 100 times too dim (a run of a scene whose
/// `intensity_scale` differs, say) left a field the decoder could not bring back to life.
pub const START_LEVELS: (f64, f64) = (0.1, 100.0);

/// The ratio a start outside [`START_LEVELS`] is scaled to: that of a start of the same scene.
const TYPICAL_LEVEL: f64 = 2.0;

/// One thread's share of a fitting step: the field's tape, the values and loss derivatives
/// of its points, and its sums of squared residuals and targets.
struct FitWorker<T> {
    tape: T,
    values: Vec<f32>,
    d_out: Vec<f32>,
    se: f64,
    sq: f64,
}

/// Fits `field` to `target` (module doc). `target(points, out)` writes the target in field
/// units at box-normalised points (rows of `field.input_dim()` values: `x, y, z[, t']`).
/// With `time_limit_s` the fit stops after the step that reaches it (at least one step): a
/// start is part of a run's work, and counts against its time budget. `on_step(steps done)` is
/// called after every step; breaking stops the fit there (a run the user stops while its field
/// is fitted to its start: the fit takes seconds whatever the run's size).
pub fn fit_to_target<F: TrainableField>(
    field: &mut F,
    prep: &Prepared,
    target: &(dyn Fn(&[f32], &mut [f32]) + Sync),
    fit: &StartFit,
    seed: u64,
    time_limit_s: Option<f64>,
    on_step: &mut dyn FnMut(usize) -> ControlFlow<()>,
) -> Result<StartReport, NeuralError> {
    fit.validate()?;
    let t0 = std::time::Instant::now();
    let dim = field.input_dim();
    let times = prep.time_steps();
    let occupancy = prep.occupancy();
    let mut adam = Adam::new(field.num_params(), AdamConfig::default());
    let mut grads = vec![0f32; field.num_params()];
    // One worker per thread of the pool, each with its tape and gradient buffer; worker `w`
    // takes the `w`-th contiguous share of a step's points, and the buffers are summed in
    // worker order, so a fit depends on the thread count, as training does, and not on the
    // scheduling.
    let threads = rayon::current_num_threads().max(1);
    let mut workers: Vec<FitWorker<F::Tape>> = (0..threads)
        .map(|_| FitWorker { tape: field.new_tape(), values: Vec::new(), d_out: Vec::new(), se: 0.0, sq: 0.0 })
        .collect();
    let mut worker_grads = vec![vec![0f32; field.num_params()]; threads];
    let (mut inputs, mut wanted) = (Vec::new(), Vec::new());
    let mut last = StartReport { mse: 0.0, mean_square: 0.0, seconds: 0.0, steps: 0, stopped: false, rescaled: None };
    let mut scale = 1.0f32;
    for step in 0..fit.iterations {
        let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(seed ^ START_KEY, step, 0));
        inputs.clear();
        let mut n = 0;
        // A bounded number of draws: with a sparse hull most draws may land in empty cells.
        for _ in 0..fit.points * 8 {
            if n == fit.points {
                break;
            }
            let x: [f32; 3] = std::array::from_fn(|_| rng.random::<f32>());
            if occupancy.is_some_and(|g| !g.is_occupied(x)) {
                continue;
            }
            inputs.extend_from_slice(&x);
            if dim == 4 {
                inputs.push(if times.is_empty() { 0.0 } else { times[rng.random_range(0..times.len())] });
            }
            n += 1;
        }
        if n == 0 {
            return Err(NeuralError::invalid("start", "no point of the box is occupied; nothing to fit"));
        }
        wanted.resize(n, 0.0);
        let share = n.div_ceil(workers.len());
        inputs.par_chunks(share * dim).zip(wanted.par_chunks_mut(share)).for_each(|(x, y)| target(x, y));
        if let Some(bad) = wanted.iter().position(|v| !v.is_finite()) {
            let p = &inputs[bad * dim..bad * dim + 3];
            return Err(NeuralError::invalid(
                "start",
                format!("the starting field is not finite at {p:?} (box units)"),
            ));
        }
        if step == 0 {
            // A field emits no negative light: a start with no positive value fits a zero field.
            if wanted.iter().all(|&y| y <= 0.0) {
                return Err(NeuralError::invalid(
                    "start",
                    "the starting field is zero at every occupied point, or negative (no emission is): there is \
                     nothing to start from",
                ));
            }
            let rms = (wanted.iter().map(|&y| f64::from(y).powi(2)).sum::<f64>() / n as f64).sqrt();
            let level = f64::from(prep.mean_level());
            let ratio = rms / level;
            if level > 0.0 && !(START_LEVELS.0..=START_LEVELS.1).contains(&ratio) {
                scale = (TYPICAL_LEVEL / ratio) as f32;
                last.rescaled = Some(f64::from(scale));
                log::warn!(
                    "the starting field is {:.3e} times the level the training images ask for (a start of the \
                     same scene is about 1): its values look like those of other units (another \
                     intensity_scale, 8- against 16-bit images); it is multiplied by {scale:.3e} before the fit",
                    ratio / TYPICAL_LEVEL
                );
            }
        }
        if scale != 1.0 {
            wanted.iter_mut().for_each(|v| *v *= scale);
        }
        let field_ref: &F = field;
        // A worker left without points (a step of fewer points than workers) adds nothing.
        workers.iter_mut().for_each(|wk| (wk.se, wk.sq) = (0.0, 0.0));
        let shares = inputs.par_chunks(share * dim).zip(wanted.par_chunks(share));
        workers.par_iter_mut().zip(worker_grads.par_iter_mut()).zip(shares).for_each(|((wk, wk_grads), (x, y))| {
            wk.values.resize(y.len(), 0.0);
            field_ref.forward(x, &mut wk.values, &mut wk.tape);
            wk.d_out.clear();
            for (&e, &y) in wk.values.iter().zip(y) {
                let r = e - y;
                wk.se += (r * r) as f64;
                wk.sq += (y * y) as f64;
                wk.d_out.push(2.0 * r / n as f32);
            }
            field_ref.backward(&mut wk.tape, &wk.d_out, wk_grads);
        });
        let (se, sq) = workers.iter().fold((0.0, 0.0), |(se, sq), wk| (se + wk.se, sq + wk.sq));
        // Sums the workers' buffers into `grads` and zeroes them for the next step.
        sum_gradients(&mut worker_grads, &mut grads);
        adam.step(field.params_mut(), &grads, fit.learning_rate);
        last = StartReport { mse: se / n as f64, mean_square: sq / n as f64, steps: step + 1, ..last };
        if on_step(step + 1).is_break() {
            last.stopped = true;
            break;
        }
        if time_limit_s.is_some_and(|limit| t0.elapsed().as_secs_f64() >= limit) {
            break;
        }
    }
    last.seconds = t0.elapsed().as_secs_f64();
    Ok(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The largest settings of each range pass; one past them, and no steps, points or rate,
    /// are refused under their own key.
    #[test]
    fn fit_settings_are_refused_outside_their_ranges_by_key() {
        let ok = StartFit::default();
        let edge = StartFit {
            iterations: fluidnerf_core::MAX_ITERATIONS,
            points: MAX_START_POINTS,
            learning_rate: crate::optim::MAX_LEARNING_RATE,
        };
        assert!(edge.validate().is_ok());
        assert!(StartFit { iterations: 1, points: 1, ..ok }.validate().is_ok());
        let bad = [
            ("start.iterations", StartFit { iterations: 0, ..ok }),
            ("start.iterations", StartFit { iterations: fluidnerf_core::MAX_ITERATIONS + 1, ..ok }),
            ("start.points", StartFit { points: 0, ..ok }),
            ("start.points", StartFit { points: MAX_START_POINTS + 1, ..ok }),
            ("start.learning_rate", StartFit { learning_rate: 0.0, ..ok }),
            ("start.learning_rate", StartFit { learning_rate: 1.5, ..ok }),
            ("start.learning_rate", StartFit { learning_rate: f32::INFINITY, ..ok }),
        ];
        for (key, fit) in bad {
            let e = fit.validate().expect_err("refused").to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
    }

    #[test]
    fn the_relative_difference_is_the_rms_ratio() {
        let report =
            StartReport { mse: 4.0, mean_square: 16.0, seconds: 0.0, steps: 1, stopped: false, rescaled: None };
        assert_eq!(report.relative_difference(), 0.5);
        // A target of zero does not divide by zero.
        let zero = StartReport { mse: 1.0, mean_square: 0.0, ..report };
        assert!(zero.relative_difference().is_finite() && zero.relative_difference() > 1e100);
    }
}
