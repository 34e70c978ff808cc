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

    use crate::train::{Problem, Supersample, View};
    use fluidnerf_core::{Aabb, Camera, Image, Intrinsics};
    use glam::DVec3;

    /// Views of 8×8 pixels from three sides of a box of side 2, at the given times, and held-out
    /// views from two more sides; every pixel measures its own index.
    fn prepared(times: &[f64]) -> Prepared {
        let k = Intrinsics { width: 8, height: 8, fx: 15.0, fy: 15.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        let view = |a: f64, time: f64| {
            let camera = Camera::look_at(k, DVec3::new(0.0, 5.0 * a.cos(), 5.0 * a.sin()), DVec3::ZERO, DVec3::X);
            let mut image = Image::zeros(8, 8);
            image.data.iter_mut().enumerate().for_each(|(i, v)| *v = 1.0 + i as f32);
            View { camera, image, time }
        };
        let problem = Problem {
            aabb: Aabb::cube(DVec3::ZERO, 2.0),
            intensity_scale: 1.0,
            views: times.iter().enumerate().map(|(i, &t)| view(i as f64, t)).collect(),
            holdout: vec![view(0.5, 0.0), view(1.5, 0.0)],
            time_step: 1.0,
        };
        Prepared::new(&problem, &TrainConfig::default()).expect("prepares")
    }

    fn config(rays_per_image: usize, s: usize) -> TrainConfig {
        TrainConfig { rays_per_image, pixel_supersample: Supersample::Fixed(s), ..Default::default() }
    }

    /// Every view gets `rays_per_image` draws of its own kept rays, in view order; the draw is
    /// fixed by the seed and the iteration.
    #[test]
    fn a_training_batch_draws_the_same_number_of_rays_from_every_view() {
        let prep = prepared(&[0.0, 0.0, 0.0]);
        let mut batch = RayBatch::new(Split::Holdout, 0, 0);
        training_batch(&prep, &config(5, 1), 3, 7, &[0.0], &mut batch);
        assert_eq!((batch.split, batch.seed, batch.stream, batch.group), (Split::Train, 3, 7, 1));
        assert!(batch.jitter.is_empty());
        assert_eq!(batch.len(), 15);
        for v in 0..3u32 {
            let n = prep.views(Split::Train)[v as usize].rays().len() as u32;
            let of_view: Vec<u32> = batch.rays.iter().filter(|r| r.0 == v).map(|r| r.1).collect();
            assert_eq!(of_view.len(), 5, "view {v}");
            assert!(of_view.iter().all(|&r| r < n), "view {v}: {of_view:?}");
        }
        assert!(batch.rays.windows(2).all(|w| w[0].0 <= w[1].0));
        let mut again = RayBatch::new(Split::Train, 0, 0);
        training_batch(&prep, &config(5, 1), 3, 7, &[0.0], &mut again);
        assert_eq!(again, batch);
        training_batch(&prep, &config(5, 1), 3, 8, &[0.0], &mut again);
        assert_ne!(again.rays, batch.rays);
    }

    /// With one time step per iteration, iteration `i` draws only from the views of frame
    /// time `i mod N_t`.
    #[test]
    fn one_time_step_batches_draw_from_the_views_of_one_frame() {
        let prep = prepared(&[0.0, 1.0, 1.0]);
        let steps = prep.time_steps();
        assert_eq!(steps, vec![0.0, 1.0]);
        let cfg = TrainConfig { batching: Batching::OneTimeStep, ..config(4, 1) };
        let mut batch = RayBatch::new(Split::Train, 0, 0);
        for (iteration, views) in [(0, vec![0]), (1, vec![1, 2]), (2, vec![0]), (5, vec![1, 2])] {
            training_batch(&prep, &cfg, 1, iteration, &steps, &mut batch);
            let mut seen: Vec<u32> = batch.rays.iter().map(|r| r.0).collect();
            seen.dedup();
            assert_eq!(seen, views, "iteration {iteration}");
            assert_eq!(batch.len(), 4 * views.len());
        }
    }

    /// With `S` rays per pixel axis each drawn pixel becomes `S²` rays at the sub-pixel
    /// centres, the pixels being those drawn with one ray per pixel.
    #[test]
    fn supersampled_batches_cover_each_pixel_at_its_sub_pixel_centres() {
        let prep = prepared(&[0.0, 0.0, 0.0]);
        let mut one = RayBatch::new(Split::Train, 0, 0);
        training_batch(&prep, &config(3, 1), 5, 2, &[0.0], &mut one);
        let mut two = RayBatch::new(Split::Train, 0, 0);
        training_batch(&prep, &config(3, 2), 5, 2, &[0.0], &mut two);
        assert_eq!(two.group, 4);
        assert_eq!(two.len(), 4 * one.len());
        assert_eq!(two.jitter.len(), two.len());
        for (p, rays) in one.rays.iter().zip(two.rays.chunks(4)) {
            assert!(rays.iter().all(|r| r == p));
        }
        let corners = [[-0.25, -0.25], [0.25, -0.25], [-0.25, 0.25], [0.25, 0.25]];
        assert!(two.jitter.chunks(4).all(|j| j == corners), "{:?}", &two.jitter[..4]);
        // Three per axis: nine rays at the thirds of the pixel.
        let mut three = RayBatch::new(Split::Train, 0, 0);
        training_batch(&prep, &config(3, 3), 5, 2, &[0.0], &mut three);
        assert_eq!((three.group, three.len()), (9, 9 * one.len()));
        let third = 1.0 / 3.0;
        assert!(three.jitter[..9].iter().zip([-third, 0.0, third].repeat(3)).all(|(j, a)| (j[0] - a).abs() < 1e-6));
        assert!(three.jitter[..9].iter().enumerate().all(|(k, j)| (j[1] - [-third, 0.0, third][k / 3]).abs() < 1e-6));
        // Back to one ray per pixel, the same batch forgets its jitter.
        training_batch(&prep, &config(3, 1), 5, 2, &[0.0], &mut two);
        assert_eq!(two, one);
    }

    /// A ray of a batch carries its view's geometry, target and time, its direction moved by
    /// its jitter.
    #[test]
    fn a_batch_ray_is_its_views_ray() {
        let prep = prepared(&[0.0, 2.0, 0.0]);
        let view = &prep.views(Split::Train)[1];
        let r = view.rays().len() - 1;
        let mut batch = RayBatch::new(Split::Train, 0, 0);
        batch.rays = vec![(1, r as u32), (1, r as u32)];
        batch.jitter = vec![[0.0, 0.0], [0.5, -0.25]];
        let ray = batch.ray(&prep, 0);
        let rays = view.rays();
        assert_eq!(ray.origin_unit, rays.origin_unit);
        assert_eq!(ray.dir_unit, rays.dir_jittered(r, None));
        assert_eq!((ray.near, ray.far, ray.target, ray.time), (rays.near[r], rays.far[r], view.targets()[r], 2.0));
        assert_eq!(batch.ray(&prep, 1).dir_unit, rays.dir_jittered(r, Some([0.5, -0.25])));
        assert_ne!(batch.ray(&prep, 1).dir_unit, ray.dir_unit);
    }

    /// The held-out batch takes `⌈validate_pixels / N_views⌉` rays of every held-out view, the
    /// same each time, under its own keys; a whole view's batch is its rays in order.
    #[test]
    fn holdout_and_view_batches() {
        let prep = prepared(&[0.0, 0.0, 0.0]);
        let cfg = TrainConfig { validate_pixels: 5, ..Default::default() };
        let held = holdout_batch(&prep, &cfg, 9).expect("held-out rays");
        assert_eq!((held.split, held.seed, held.stream), (Split::Holdout, 9 ^ HOLDOUT_SEED, HOLDOUT_STREAM));
        assert_eq!(held.rays.iter().filter(|r| r.0 == 0).count(), 3);
        assert_eq!(held.rays.iter().filter(|r| r.0 == 1).count(), 3);
        assert_eq!(holdout_batch(&prep, &cfg, 9), Some(held));
        assert!(holdout_batch(&prep, &TrainConfig { validate_pixels: 0, ..cfg.clone() }, 9).is_none());

        let whole = view_batch(&prep, Split::Train, 2, 4);
        let n = prep.views(Split::Train)[2].rays().len();
        assert_eq!(whole.rays, (0..n as u32).map(|r| (2, r)).collect::<Vec<_>>());
        assert_eq!((whole.split, whole.seed, whole.stream, whole.group), (Split::Train, 4, VIEW_STREAM, 1));
        let mut a = whole.chunk_rng(3);
        let mut b = ChaCha8Rng::seed_from_u64(stream_seed(4, VIEW_STREAM, 3));
        assert_eq!(a.random::<u64>(), b.random::<u64>());
        assert!(!whole.is_empty() && RayBatch::new(Split::Train, 0, 0).is_empty());
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
