//! The CPU engine: the whole step fused per chunk of rays, one worker per thread.
//!
//! Each thread takes a fixed share of the chunks (chunk `c` goes to worker `c mod T`, so
//! results do not depend on scheduling) and, per chunk, without materialising per-step
//! tensors:
//! 1. stratified samples on each ray (Eq. 5.1);
//! 2. with `N_f > 0`, the field evaluated at them without gradients ([`TrainableField::eval`]),
//!    and `N_f` feature samples from `|dE/ds|` ([`crate::sampling`]), merged;
//! 3. [`TrainableField::forward`] at all samples (skipping empty cells, see
//!    [`crate::occupancy`]);
//! 4. quadrature (Eq. 5.4), MSE against the measured pixels (Eq. 5.5), and the exact backward
//!    `∂L/∂E_j` ([`crate::render`]);
//! 5. [`TrainableField::backward`] into the worker's own gradient buffer.
//!
//! The per-worker buffers are summed in worker order ([`sum_gradients`]) and kept until
//! [`Engine::apply_gradient`]. The state (field parameters, Adam moments) is the caller's host
//! memory: `load_state` only checks it and sizes the buffers, and `save_state` has nothing to
//! copy.

use rayon::prelude::*;

use crate::batch::RayBatch;
use crate::engine::{BatchLoss, Engine};
use crate::optim::{sum_gradients, Adam};
use crate::prior::{add_point_prior, PriorScratch};
use crate::render::{mse_term, quadrature_weights, render};
use crate::sampling::{feature_samples, merge_sorted, stratified};
use crate::train::{Prepared, PreparedView, TrainConfig};
use crate::{NeuralError, TrainableField};

/// Per-thread scratch, reused across chunks and iterations.
struct Worker<T> {
    tape: T,
    /// This thread's gradient accumulator (empty until [`Engine::load_state`]).
    grads: Vec<f32>,
    inputs: Vec<f32>,
    active: Vec<u32>,
    e_active: Vec<f32>,
    d_active: Vec<f32>,
    s_coarse: Vec<f32>,
    e_coarse: Vec<f32>,
    s_fine: Vec<f32>,
    s_all: Vec<f32>,
    e_all: Vec<f32>,
    w: Vec<f32>,
    loss: f64,
    samples: usize,
}

/// The fused multi-threaded CPU implementation of [`Engine`] (module doc).
pub struct CpuEngine<F: TrainableField> {
    workers: Vec<Worker<F::Tape>>,
    /// The reduced gradient of the last [`Engine::loss_and_gradient`].
    grads: Vec<f32>,
    /// The point-sampled prior's tape and buffers ([`crate::prior`]).
    prior_tape: F::Tape,
    prior_scratch: PriorScratch,
}

impl<F: TrainableField> std::fmt::Debug for CpuEngine<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CpuEngine").field("workers", &self.workers.len()).field("params", &self.grads.len()).finish()
    }
}

impl<F: TrainableField> CpuEngine<F> {
    /// An engine with `workers` workers (at least one) for fields shaped like `field`: enough
    /// to render; [`Engine::load_state`] adds the gradient buffers training needs. Use the
    /// rayon pool's thread count: chunk `c` runs on worker `c mod workers`, and the workers
    /// run on that pool.
    pub fn new(field: &F, workers: usize) -> Self {
        let workers = (0..workers.max(1))
            .map(|_| Worker {
                tape: field.new_tape(),
                grads: Vec::new(),
                inputs: Vec::new(),
                active: Vec::new(),
                e_active: Vec::new(),
                d_active: Vec::new(),
                s_coarse: Vec::new(),
                e_coarse: Vec::new(),
                s_fine: Vec::new(),
                s_all: Vec::new(),
                e_all: Vec::new(),
                w: Vec::new(),
                loss: 0.0,
                samples: 0,
            })
            .collect();
        CpuEngine { workers, grads: Vec::new(), prior_tape: field.new_tape(), prior_scratch: PriorScratch::default() }
    }

    /// The gradient of the last [`Engine::loss_and_gradient`], laid out like `params()`.
    pub fn gradient(&self) -> &[f32] {
        &self.grads
    }

    /// Runs `batch` over the workers (chunk `c` on worker `c mod T`); with `pixels`, writes the
    /// rendered values there instead of back-propagating. Returns (loss, samples).
    fn run(
        &mut self,
        field: &F,
        prep: &Prepared,
        cfg: &TrainConfig,
        batch: &RayBatch,
        pixels: Option<&mut [f32]>,
    ) -> (f64, usize) {
        // Chunks hold whole pixels (`batch.group` rays each).
        let group = batch.group.max(1);
        let rays_per_chunk = (RayBatch::rays_per_chunk(cfg) / group).max(1) * group;
        let chunks: Vec<&[(u32, u32)]> = batch.rays.chunks(rays_per_chunk).collect();
        // Each chunk's pixel offsets, or none.
        let jitter: Vec<&[[f32; 2]]> = if batch.jitter.is_empty() {
            vec![&[][..]; chunks.len()]
        } else {
            batch.jitter.chunks(rays_per_chunk).collect()
        };
        let nw = self.workers.len();
        let n_pix = batch.len() / group;
        let views = prep.views(batch.split);
        let with_grad = pixels.is_none();
        // Each worker's chunks, with the slice of `pixels` each renders into.
        let mut shares: Vec<Vec<(usize, &mut [f32])>> = (0..nw).map(|_| Vec::new()).collect();
        if let Some(pixels) = pixels {
            for (c, out) in pixels.chunks_mut(rays_per_chunk).enumerate() {
                shares[c % nw].push((c, out));
            }
        } else {
            for c in 0..chunks.len() {
                shares[c % nw].push((c, &mut [][..]));
            }
        }
        self.workers.par_iter_mut().zip(shares).for_each(|(wk, share)| {
            wk.loss = 0.0;
            wk.samples = 0;
            for (c, out) in share {
                let mut rng = batch.chunk_rng(c);
                process_chunk(
                    field,
                    prep,
                    views,
                    cfg,
                    ChunkRays { rays: chunks[c], jitter: jitter[c], group },
                    n_pix,
                    &mut rng,
                    wk,
                    with_grad,
                    out,
                );
            }
        });
        (self.workers.iter().map(|w| w.loss).sum(), self.workers.iter().map(|w| w.samples).sum())
    }
}

impl<F: TrainableField> Engine<F> for CpuEngine<F> {
    fn load_state(&mut self, field: &F, adam: &Adam) -> Result<(), NeuralError> {
        let n = field.num_params();
        if adam.m.len() != n || adam.v.len() != n {
            return Err(NeuralError::invalid("optimiser state", "does not match the field's parameter count"));
        }
        let input_dim = field.input_dim();
        if input_dim != 3 && input_dim != 4 {
            return Err(NeuralError::invalid("field", format!("input dimension must be 3 or 4, got {input_dim}")));
        }
        for wk in &mut self.workers {
            wk.grads.clear();
            wk.grads.resize(n, 0.0);
        }
        self.grads.clear();
        self.grads.resize(n, 0.0);
        Ok(())
    }

    fn save_state(&mut self, _field: &mut F, _adam: &mut Adam) {
        // The steps were taken in `field` and `adam` themselves: nothing to copy back.
    }

    fn loss_and_gradient(&mut self, field: &F, prep: &Prepared, cfg: &TrainConfig, batch: &RayBatch) -> BatchLoss {
        assert_eq!(self.grads.len(), field.num_params(), "CpuEngine: load_state must precede training steps");
        let (loss, samples) = self.run(field, prep, cfg, batch, None);
        let mut per_thread: Vec<Vec<f32>> = self.workers.iter_mut().map(|w| std::mem::take(&mut w.grads)).collect();
        sum_gradients(&mut per_thread, &mut self.grads);
        for (w, g) in self.workers.iter_mut().zip(per_thread) {
            w.grads = g;
        }
        let prior = if field.supports_prior() {
            field.add_prior(&cfg.prior, &mut self.grads)
        } else {
            add_point_prior(
                field,
                prep,
                &cfg.prior,
                batch,
                &mut self.prior_tape,
                &mut self.prior_scratch,
                &mut self.grads,
            )
        } as f64;
        BatchLoss { loss: loss + prior, samples }
    }

    fn apply_gradient(&mut self, field: &mut F, adam: &mut Adam, lr: f32) {
        field.restrict_gradient(adam.step, &mut self.grads);
        adam.step(field.params_mut(), &self.grads, lr);
    }

    fn render(
        &mut self,
        field: &F,
        prep: &Prepared,
        cfg: &TrainConfig,
        batch: &RayBatch,
        pixels: &mut Vec<f32>,
    ) -> BatchLoss {
        pixels.clear();
        pixels.resize(batch.len(), 0.0);
        let (loss, samples) = self.run(field, prep, cfg, batch, Some(pixels));
        BatchLoss { loss, samples }
    }
}

/// One chunk's rays as `(view, ray)` pairs, their offsets from their pixels' centres (empty:
/// none) and the rays per pixel.
struct ChunkRays<'a> {
    rays: &'a [(u32, u32)],
    jitter: &'a [[f32; 2]],
    group: usize,
}

/// Renders the rays `batch` (view, ray) of `views` and accumulates the loss over `n_pix`
/// pixels (the mean of each `group` consecutive rays is one pixel) into the worker;
/// `with_grad` adds its parameter gradient into the worker's buffer, otherwise the rendered
/// rays go to `rendered` (one per ray).
#[allow(clippy::too_many_arguments)]
fn process_chunk<F: TrainableField>(
    field: &F,
    prep: &Prepared,
    views: &[PreparedView],
    cfg: &TrainConfig,
    ChunkRays { rays: batch, jitter, group }: ChunkRays,
    n_pix: usize,
    rng: &mut rand_chacha::ChaCha8Rng,
    wk: &mut Worker<F::Tape>,
    with_grad: bool,
    rendered: &mut [f32],
) {
    let (nc, nf) = (cfg.coarse_samples, cfg.fine_samples);
    let nt = nc + nf;
    let dim = field.input_dim();
    let nr = batch.len();
    wk.s_coarse.resize(nr * nc, 0.0);
    wk.s_all.resize(nr * nt, 0.0);
    wk.e_all.resize(nr * nt, 0.0);
    wk.w.resize(nt, 0.0);
    let occ = prep.occupancy();
    // Gathers the active samples of `s` (n per ray) into `inputs`, remembering their index.
    let gather = |s: &[f32], n: usize, inputs: &mut Vec<f32>, active: &mut Vec<u32>| {
        inputs.clear();
        active.clear();
        for (r, &(v, ray)) in batch.iter().enumerate() {
            let pv = &views[v as usize];
            let o = pv.rays.origin_unit;
            let d = pv.rays.dir_jittered(ray as usize, jitter.get(r).copied());
            for q in 0..n {
                let t = s[r * n + q];
                let u = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                if occ.is_some_and(|g| !g.is_occupied(u)) {
                    continue;
                }
                inputs.extend_from_slice(&u);
                if dim == 4 {
                    inputs.push(pv.time);
                }
                active.push((r * n + q) as u32);
            }
        }
    };
    for (r, &(v, ray)) in batch.iter().enumerate() {
        let rays = &views[v as usize].rays;
        let (near, far) = (rays.near[ray as usize], rays.far[ray as usize]);
        stratified(near, far, rng, &mut wk.s_coarse[r * nc..(r + 1) * nc]);
    }
    if nf > 0 {
        gather(&wk.s_coarse, nc, &mut wk.inputs, &mut wk.active);
        wk.e_active.resize(wk.active.len(), 0.0);
        if !wk.active.is_empty() {
            field.eval(&wk.inputs, &mut wk.e_active, &mut wk.tape);
        }
        wk.e_coarse.clear();
        wk.e_coarse.resize(nr * nc, 0.0);
        for (&a, &e) in wk.active.iter().zip(&wk.e_active) {
            wk.e_coarse[a as usize] = e;
        }
        wk.s_fine.resize(nf, 0.0);
        for r in 0..nr {
            let sc = &wk.s_coarse[r * nc..(r + 1) * nc];
            feature_samples(sc, &wk.e_coarse[r * nc..(r + 1) * nc], rng, &mut wk.s_fine);
            merge_sorted(sc, &wk.s_fine, &mut wk.s_all[r * nt..(r + 1) * nt]);
        }
    } else {
        wk.s_all.copy_from_slice(&wk.s_coarse);
    }
    gather(&wk.s_all, nt, &mut wk.inputs, &mut wk.active);
    wk.e_active.resize(wk.active.len(), 0.0);
    if !wk.active.is_empty() {
        if with_grad {
            field.forward(&wk.inputs, &mut wk.e_active, &mut wk.tape);
        } else {
            field.eval(&wk.inputs, &mut wk.e_active, &mut wk.tape);
        }
    }
    wk.samples += wk.active.len();
    wk.e_all.fill(0.0);
    for (&a, &e) in wk.active.iter().zip(&wk.e_active) {
        wk.e_all[a as usize] = e;
    }
    // Render, loss, and ∂L/∂E per sample (stored in e_all's place once a ray is rendered).
    let quad = prep.quadrature();
    let length_scale = prep.length_scale();
    // A pixel is `group` consecutive rays (its sub-pixel rays): its value is their mean.
    let weights = |r: usize, w: &mut [f32]| {
        let (v, ray) = batch[r];
        let rays = &views[v as usize].rays;
        let (s, ray) = (&wk.s_all[r * nt..(r + 1) * nt], ray as usize);
        quadrature_weights(s, rays.near[ray], rays.far[ray], &rays.emission, &quad, length_scale, w);
    };
    for first in (0..nr).step_by(group) {
        let mut sum = 0f32;
        for r in first..first + group {
            weights(r, &mut wk.w);
            let pixel = render(&wk.w, &wk.e_all[r * nt..(r + 1) * nt]);
            sum += pixel;
            if !with_grad {
                rendered[r] = pixel;
            }
        }
        let (v, ray) = batch[first];
        let (l, d_pixel) = mse_term(sum / group as f32, views[v as usize].targets[ray as usize], n_pix);
        wk.loss += l as f64;
        if with_grad {
            let d_ray = d_pixel / group as f32;
            for r in first..first + group {
                if group > 1 {
                    weights(r, &mut wk.w);
                }
                for (ej, &wj) in wk.e_all[r * nt..(r + 1) * nt].iter_mut().zip(&wk.w) {
                    *ej = d_ray * wj;
                }
            }
        }
    }
    if with_grad && !wk.active.is_empty() {
        wk.d_active.clear();
        wk.d_active.extend(wk.active.iter().map(|&a| wk.e_all[a as usize]));
        field.backward(&mut wk.tape, &wk.d_active, &mut wk.grads);
    }
}
