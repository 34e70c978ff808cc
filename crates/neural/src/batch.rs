//! Ray batches: which rays a training step or a render covers, and the random streams their
//! samples come from. This is method, not engine: every [`crate::engine::Engine`] receives the
//! same batches.
//!
//! # What a batch is
//! A [`RayBatch`] names rays of a [`Prepared`] problem as `(view, ray)` pairs: ray `r` of
//! `prep.views(split)[v]` ([`PreparedView`]), whose geometry (box-normalised origin and
//! direction, `near`/`far` in world units along the ray), normalised target pixel and frame
//! time `t'` are fixed when the problem is prepared ([`RayBatch::ray`] gathers them). The loss
//! of a batch is the mean over its rays (Eq. 5.5, `N_pix = len()`), each ray counted as often
//! as it was drawn.
//!
//! # Draws (§5.1.5)
//! - Training, iteration `i` ([`training_batch`]): `N_pix/img` rays with replacement from every
//!   training view that sees the box (with [`Batching::OneTimeStep`], only the views of frame
//!   time `i mod N_t`), in view order, uniformly among each view's kept rays, from the ChaCha8
//!   stream `stream_seed(seed, i, usize::MAX)`. With [`TrainConfig::pixel_supersample`]
//!   `S > 1` each drawn pixel becomes `S²` consecutive rays through its sub-pixel centres
//!   ([`RayBatch::group`]; the pixels drawn are the same whatever `S`).
//! - Held out ([`holdout_batch`]): `⌈validate_pixels / N_views⌉` rays per held-out view, the
//!   same every time (stream `stream_seed(seed ^ 0x5EED, usize::MAX, 0)`).
//! - One whole view ([`view_batch`]): all its kept rays in order.
//!
//! # Random streams of the samples
//! A batch is cut into chunks of [`RayBatch::rays_per_chunk`] consecutive rays; chunk `c`
//! draws everything random about its rays (stratified offsets, then feature-sample quantiles)
//! from ChaCha8 seeded with [`stream_seed`]`(batch.seed, batch.stream, c)`. The chunk is the
//! unit of work the CPU engine hands to a thread, and keying the streams by it makes a step
//! independent of which thread ran which chunk.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::render::EmissionModel;
use crate::train::{Batching, Prepared, PreparedView, Split, TrainConfig};

/// Stream key of the held-out batch and its samples.
pub const HOLDOUT_STREAM: usize = usize::MAX;
/// Stream key of [`view_batch`].
pub const VIEW_STREAM: usize = usize::MAX - 1;
/// Stream key of the renders that refit per-view gains ([`crate::train::train_fitting_gains`]).
pub const GAIN_STREAM: usize = usize::MAX - 2;
/// Mixed into the seed of the held-out batch, so that it differs from training draws.
pub const HOLDOUT_SEED: u64 = 0x5EED;

/// Rays named as `(view, ray)` pairs of one split, with the keys of their random streams.
#[derive(Clone, Debug, PartialEq)]
pub struct RayBatch {
    /// Which views of the [`Prepared`] problem the pairs index.
    pub split: Split,
    /// `(v, r)`: ray `r` of view `v` ([`Prepared::views`]), in the order the loss sums them.
    pub rays: Vec<(u32, u32)>,
    /// First key of the sample streams (the run's seed, or a value derived from it).
    pub seed: u64,
    /// Second key of the sample streams: the iteration, or [`HOLDOUT_STREAM`] /
    /// [`VIEW_STREAM`].
    pub stream: usize,
    /// Per ray, its offset `(a, b)` from the pixel centre in pixels, `|a|, |b| ≤ ½`
    /// ([`TrainConfig::pixel_supersample`]); empty: every ray through its pixel's centre.
    pub jitter: Vec<[f32; 2]>,
    /// Consecutive rays that make one pixel (their mean is scored): `S²`, or 1.
    pub group: usize,
}

/// One ray of a batch with everything an engine needs to sample, render and score it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchRay {
    /// Camera centre in box-normalised coordinates, `(o − min) / size`.
    pub origin_unit: [f32; 3],
    /// Direction `d / size` (component-wise; `d` a unit vector in world units), so that the
    /// sample at distance `s` is `origin_unit + s · dir_unit`.
    pub dir_unit: [f32; 3],
    /// Entry and exit distances along the ray, world units (clipped to occupied cells when the
    /// problem skips empty space).
    pub near: f32,
    pub far: f32,
    /// The measured pixel divided by [`Prepared::image_scale`].
    pub target: f32,
    /// Frame time `t' = t / Δt`, the fourth input of space–time fields.
    pub time: f32,
    /// How Ω·A varies along the ray (1 for pinholes).
    pub emission: EmissionModel,
}

impl RayBatch {
    /// An empty batch of `split` with stream keys `(seed, stream)`.
    pub fn new(split: Split, seed: u64, stream: usize) -> Self {
        RayBatch { split, rays: Vec::new(), seed, stream, jitter: Vec::new(), group: 1 }
    }

    pub fn len(&self) -> usize {
        self.rays.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rays.is_empty()
    }

    /// Rays per chunk, the unit of a random stream: `⌊chunk_samples / (N_c + N_f)⌋`, at least 1.
    pub fn rays_per_chunk(cfg: &TrainConfig) -> usize {
        (cfg.chunk_samples / (cfg.coarse_samples + cfg.fine_samples)).max(1)
    }

    /// The generator of chunk `chunk` (rays `[chunk · R, (chunk + 1) · R)`).
    pub fn chunk_rng(&self, chunk: usize) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(stream_seed(self.seed, self.stream, chunk))
    }

    /// The `i`-th ray of the batch with its geometry, target and time.
    pub fn ray(&self, prep: &Prepared, i: usize) -> BatchRay {
        let (v, r) = self.rays[i];
        let view = &prep.views(self.split)[v as usize];
        let (rays, r) = (view.rays(), r as usize);
        let dir_unit = rays.dir_jittered(r, self.jitter.get(i).copied());
        BatchRay {
            origin_unit: rays.origin_unit,
            dir_unit,
            near: rays.near[r],
            far: rays.far[r],
            target: view.targets()[r],
            time: view.time(),
            emission: rays.emission,
        }
    }
}

/// The seed of the ChaCha8 stream keyed by `(seed, iteration, chunk)`: a SplitMix64 finaliser
/// over the three keys.
pub fn stream_seed(seed: u64, iteration: usize, chunk: usize) -> u64 {
    let mut z = seed
        ^ (iteration as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (chunk as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Fills `batch` (keeping its allocation) with the training rays of `iteration` (module doc);
/// `time_steps` are [`Prepared::time_steps`], used with [`Batching::OneTimeStep`].
pub fn training_batch(
    prep: &Prepared,
    cfg: &TrainConfig,
    seed: u64,
    iteration: usize,
    time_steps: &[f32],
    batch: &mut RayBatch,
) {
    let mut rng = ChaCha8Rng::seed_from_u64(stream_seed(seed, iteration, usize::MAX));
    let (n, pixels) = cfg.pixel_rays(prep.noise());
    let step = (cfg.batching == Batching::OneTimeStep && !time_steps.is_empty())
        .then(|| time_steps[iteration % time_steps.len()]);
    batch.split = Split::Train;
    batch.seed = seed;
    batch.stream = iteration;
    batch.rays.clear();
    for (v, pv) in prep.views(Split::Train).iter().enumerate() {
        if pv.rays().is_empty() || step.is_some_and(|t| pv.time() != t) {
            continue;
        }
        for _ in 0..pixels {
            batch.rays.push((v as u32, rng.random_range(0..pv.rays().len()) as u32));
        }
    }
    batch.jitter.clear();
    batch.group = 1;
    if n > 1 {
        let pixels = std::mem::take(&mut batch.rays);
        let at = |k: usize| (k as f32 + 0.5) / n as f32 - 0.5;
        for p in pixels {
            for b in 0..n {
                for a in 0..n {
                    batch.rays.push(p);
                    batch.jitter.push([at(a), at(b)]);
                }
            }
        }
        batch.group = n * n;
    }
}

/// The learning rate of training iteration `iteration`: `cfg.schedule` at the iteration, or,
/// with [`TrainConfig::schedule_per_frame`] and [`Batching::OneTimeStep`] over `n_steps` frame
/// times, at the number of updates the iteration's frame has had before it (the frame of
/// iteration `i` is `i mod n_steps`, so that is `⌊i / n_steps⌋`).
pub fn learning_rate(cfg: &TrainConfig, iteration: usize, n_steps: usize) -> f32 {
    let per_frame = cfg.schedule_per_frame && cfg.batching == Batching::OneTimeStep && n_steps > 1;
    let n = if per_frame { iteration / n_steps } else { iteration };
    cfg.schedule.lr(n as u64)
}

/// The fixed subset of held-out rays evaluated during training (module doc), or None without
/// held-out rays or with `validate_pixels = 0`.
pub fn holdout_batch(prep: &Prepared, cfg: &TrainConfig, seed: u64) -> Option<RayBatch> {
    let views: &[PreparedView] = prep.views(Split::Holdout);
    let total: usize = views.iter().map(|v| v.rays().len()).sum();
    if total == 0 || cfg.validate_pixels == 0 {
        return None;
    }
    let mut batch = RayBatch::new(Split::Holdout, seed ^ HOLDOUT_SEED, HOLDOUT_STREAM);
    let mut rng = batch.chunk_rng(0);
    let per_view = cfg.validate_pixels.div_ceil(views.len());
    for (v, pv) in views.iter().enumerate() {
        for _ in 0..per_view.min(pv.rays().len()) {
            batch.rays.push((v as u32, rng.random_range(0..pv.rays().len()) as u32));
        }
    }
    Some(batch)
}

/// Every kept ray of view `index` of `split`, in order, with sample streams keyed by
/// `(seed, VIEW_STREAM)`.
pub fn view_batch(prep: &Prepared, split: Split, index: usize, seed: u64) -> RayBatch {
    let n = prep.views(split)[index].rays().len() as u32;
    RayBatch {
        split,
        rays: (0..n).map(|r| (index as u32, r)).collect(),
        seed,
        stream: VIEW_STREAM,
        jitter: Vec::new(),
        group: 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stream_seeds_are_pinned() {
        // Checkpoints resume with these streams: a change here changes every run.
        assert_eq!(stream_seed(0, 0, 0), 0);
        assert_eq!(stream_seed(1, 0, 0), 0x5692_161d_100b_05e5);
        assert_eq!(stream_seed(5, 3, 2), 0xa05b_155f_1d82_5eee);
        assert_ne!(stream_seed(3, 7, 0), stream_seed(3, 8, 0));
        assert_ne!(stream_seed(3, 7, 0), stream_seed(3, 7, 1));
    }

    #[test]
    fn a_per_frame_schedule_gives_each_frame_the_rate_of_its_own_updates() {
        let mut cfg = TrainConfig { batching: Batching::OneTimeStep, ..Default::default() };
        // The dissertation's schedule counts iterations.
        assert_eq!(learning_rate(&cfg, 7, 3), cfg.schedule.lr(7));
        cfg.schedule_per_frame = true;
        // Iterations 6, 7, 8 are the third update (n = 2) of frames 0, 1, 2.
        for it in 6..9 {
            assert_eq!(learning_rate(&cfg, it, 3), cfg.schedule.lr(2));
        }
        assert_eq!(learning_rate(&cfg, 9, 3), cfg.schedule.lr(3));
        // One frame, or every view in each iteration: iterations are the frame's updates.
        assert_eq!(learning_rate(&cfg, 7, 1), cfg.schedule.lr(7));
        cfg.batching = Batching::AllViews;
        assert_eq!(learning_rate(&cfg, 7, 3), cfg.schedule.lr(7));
    }

    #[test]
    fn chunks_hold_whole_rays() {
        let cfg = |c, f, s| TrainConfig { coarse_samples: c, fine_samples: f, chunk_samples: s, ..Default::default() };
        assert_eq!(RayBatch::rays_per_chunk(&cfg(128, 128, 256)), 1);
        assert_eq!(RayBatch::rays_per_chunk(&cfg(64, 64, 256)), 2);
        assert_eq!(RayBatch::rays_per_chunk(&cfg(48, 0, 8192)), 170);
        assert_eq!(RayBatch::rays_per_chunk(&cfg(128, 128, 100)), 1);
    }
}
