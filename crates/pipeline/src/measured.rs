//! The measured images of a run: preprocessed as the scene records it (background subtraction,
//! clipping, flat field, masks: [`fluidnerf_io::scene::load_preprocessed`]), balanced as the run asks
//! ([`GainMode`]), and the least-squares gain fits both method families share.
//!
//! # Gains
//! The imaging model of a real camera `c` is `pixel = g_c × intensity_scale × ∫E ds + b_c`: a
//! sensitivity `g_c` (gain, aperture, filter, vignetting averaged over the image) and, with
//! [`crate::GainConfig::offset`], a residual offset `b_c` left by the background subtraction.
//! Only ratios of gains are observable (a brighter field and dimmer cameras give the same
//! images), so gains are normalised to mean 1 over the training images and the field carries
//! the absolute scale. Given a model image `r` (a rendering or reprojection) and the measured
//! `p`, the gain minimising `Σ (p − g r − b)²` over the used pixels is the ordinary
//! least-squares line through the points `(r, p)` ([`fit_gain`]).

use fluidnerf_classical::{Grid, Projector, SparseRows, Update};
use fluidnerf_core::{Camera, Image, Scene};

use crate::{FrameGain, GainConfig, GainMode, HoldoutScore, PipelineError, Preprocessing};

/// A scene's images ready for a method.
pub(crate) struct Measured {
    /// Per frame: preprocessed, then divided by `gains`.
    pub images: Vec<Image>,
    /// Per frame: `true` for the pixels to use.
    pub masks: Vec<Option<Vec<bool>>>,
    /// Per frame: the balancing gain the image was divided by (1 without balancing).
    pub gains: Vec<f64>,
    /// The gain mode the run takes: the configuration's, with `auto` resolved to `fit` or
    /// `none` ([`load`]).
    pub mode: GainMode,
    /// What was done, for the report; gains are filled in by [`Measured::report`].
    preprocessing: Preprocessing,
    /// Warnings for the run to issue: images with no light while others of their time have
    /// some ([`dark_frames_hint`]), and, without balancing or fitted gains, training images
    /// of one time that differ in total intensity as cameras of different gains do
    /// ([`gain_spread`]).
    pub warnings: Vec<String>,
}

/// Reads and preprocesses the scene's images ([`fluidnerf_io::scene::load_preprocessed`]) and,
/// with `balance` or `fit`, scales every image to the mean total intensity of the training
/// images of its time (masked pixels left out). `auto` is resolved here ([`GainMode::Auto`]):
/// when the images' totals differ as differing gains make them, `fit` for a static run and
/// `balance` for a time-resolved one (`temporal`), which fits no gains; `none` otherwise.
/// [`Measured::mode`] holds the mode taken.
pub(crate) fn load(scene: &Scene, gains: &GainConfig, temporal: bool) -> Result<Measured, PipelineError> {
    let pre = fluidnerf_io::scene::load_preprocessed(scene)?;
    // Training images that are each one value throughout (every pixel saturated, or blank at
    // one level) carry nothing of the field: a run on them made a field as flat as they are
    // and reported it as a result.
    let levels: Vec<Option<f32>> =
        pre.images.iter().zip(&pre.masks).map(|(im, m)| one_value_throughout(&im.data, m.as_deref())).collect();
    if let Some(why) = flat_training_images(scene, &levels) {
        return Err(PipelineError::file(&scene.root.join(fluidnerf_io::scene::SCENE_FILE), why));
    }
    let masked_pixels = pre.masks.iter().flatten().map(|m| m.iter().filter(|&&k| !k).count()).sum();
    let mut images = pre.images;
    let mut factors = vec![1.0; images.len()];
    let totals: Vec<f64> = images.iter().zip(&pre.masks).map(|(im, m)| used_sum(&im.data, m.as_deref())).collect();
    let comparable: Vec<Option<f64>> = totals.iter().zip(&pre.masks).map(|(&t, m)| m.is_none().then_some(t)).collect();
    let dark_warning = dark_frames_hint(scene, &totals);
    let spread =
        matches!(gains.mode, GainMode::None | GainMode::Auto).then(|| gain_spread(scene, &comparable)).flatten();
    let mode = match gains.mode {
        GainMode::Auto if spread.is_some() => {
            if temporal {
                GainMode::Balance
            } else {
                GainMode::Fit
            }
        }
        GainMode::Auto => GainMode::None,
        m => m,
    };
    let gain_hint = spread.and_then(|(i, ratio)| {
        // Read only when a camera stands out: a floor sorts a copy of its image.
        let floors: Vec<Option<Floor>> =
            images.iter().zip(&pre.masks).map(|(im, m)| m.is_none().then(|| Floor::of(&im.data))).collect();
        let offset = offset_note(scene, i, ratio, &floors);
        let text = spread_text(scene, i, ratio, offset.as_deref());
        match (gains.mode, temporal) {
            (GainMode::None, _) => Some(format!(
                "{text}; with --gains none the run takes that for the field. If the cameras' gains, apertures or \
                 filters differ, leave out --gains (auto {} them here) or give --gains {} (docs/real-data.md)",
                if temporal { "balances" } else { "fits" },
                if temporal { "balance" } else { "fit" }
            )),
            // A time-resolved run fits no gains: balancing takes every camera to see the whole
            // flow at every instant, which the run should say.
            (GainMode::Auto, true) => Some(format!(
                "{text}; a time-resolved run fits no gains, so the images are balanced (gains auto: each scaled to \
                 the mean total of its time, as if every camera saw the whole flow); --gains none takes them as they \
                 are (docs/real-data.md)"
            )),
            // A flat excess is an offset, which a gain alone fits badly: worth a warning unless
            // offsets are fitted.
            _ if offset.is_some() && !gains.offset => Some(format!(
                "{text}; a run fits {} here, and no offset unless given --gain-offset (docs/real-data.md)",
                if gains.mode == GainMode::Auto { "a gain per camera (gains auto)" } else { "gains" }
            )),
            // `auto` in a static run: the gains are fitted, as the report says.
            _ => {
                log::info!("fitting a gain per camera (gains auto): {text}");
                None
            }
        }
    });
    // `auto` that fits nothing leaves the fit's settings unused: say so when they were set.
    let gain_hint = gain_hint.or_else(|| {
        let d = GainConfig::default();
        let set: Vec<&str> = [
            ("gains.offset (--gain-offset)", gains.offset != d.offset),
            ("gains.every (--gain-every)", gains.every.is_some()),
            ("gains.rounds (--gain-rounds)", gains.rounds != d.rounds),
        ]
        .into_iter()
        .filter_map(|(name, set)| set.then_some(name))
        .collect();
        let why = match mode {
            GainMode::None => {
                "the training images' totals agree at every time, so gains auto fits none: they are not used; give \
                 --gains fit (gains.mode \"fit\") to fit gains anyway"
            }
            GainMode::Balance => {
                "a time-resolved run fits no gains (gains auto balances its images instead): they are not used"
            }
            _ => return None,
        };
        (gains.mode == GainMode::Auto && !set.is_empty())
            .then(|| format!("{} set how gains are fitted, and {why} (docs/real-data.md)", set.join(", ")))
    });
    let auto_why = spread
        .filter(|_| gains.mode == GainMode::Auto)
        .map(|(i, ratio)| format!("{} holds {ratio:.2}× the median total of its time", frame_label(scene, i)));
    if mode != GainMode::None {
        let time_key = |i: usize| scene.frames[i].time.map(f64::to_bits);
        for i in 0..images.len() {
            // The mean over the training images of the time (all of them when every one is
            // held out), so that training gains average 1 like fitted ones.
            let same: Vec<usize> = (0..images.len()).filter(|&j| time_key(j) == time_key(i)).collect();
            let train: Vec<usize> = same.iter().copied().filter(|&j| !scene.frames[j].holdout).collect();
            let group = if train.is_empty() { same } else { train };
            // Images without light count in no mean: a dark camera would rescale every other.
            let lit: Vec<f64> = group.iter().map(|&j| totals[j]).filter(|&t| t > 0.0).collect();
            let mean = lit.iter().sum::<f64>() / lit.len().max(1) as f64;
            // An image with no light stays as it is (and is warned about above).
            if totals[i] > 0.0 && mean > 0.0 {
                factors[i] = totals[i] / mean;
            }
        }
        for (im, &g) in images.iter_mut().zip(&factors) {
            let inv = (1.0 / g) as f32;
            im.data.iter_mut().for_each(|v| *v *= inv);
        }
        log::info!(
            "balanced every image to the mean total intensity of its time: gains {}",
            factors.iter().map(|g| format!("{g:.3}")).collect::<Vec<_>>().join(", ")
        );
    }
    let preprocessing = Preprocessing {
        scene: pre.recording.describe(),
        clipped_pixels: pre.clipped,
        saturated_pixels: pre.saturated,
        masked_pixels,
        flat_field_range: pre.flat_range.map(|(lo, hi)| [f64::from(lo), f64::from(hi)]),
        gains: GainConfig { mode, ..*gains },
        gains_auto: auto_why,
        frames: Vec::new(),
    };
    let warnings = dark_warning.into_iter().chain(gain_hint).collect();
    Ok(Measured { images, masks: pre.masks, gains: factors, mode, preprocessing, warnings })
}

impl Measured {
    /// A fingerprint of what a voxel run reconstructs from: the scene's box and intensity
    /// scale, and every frame's camera, time, held-out flag, image (as preprocessed and
    /// balanced) and mask, as 16 hex digits of a 64-bit FNV-1a hash over 32-bit words. A voxel
    /// start records it in its report, so that a resume reads the start back only when it was
    /// made from the views the scene holds now. Cameras enter by their `Debug` form (every
    /// value, floats exactly): should that form change between versions, a start only runs
    /// again.
    pub(crate) fn fingerprint(&self, scene: &Scene) -> String {
        let mut h = crate::Fnv::default();
        for v in [scene.aabb.min.to_array(), scene.aabb.max.to_array()].concat() {
            h.float(v);
        }
        h.float(scene.intensity_scale);
        h.word(scene.frames.len() as u32);
        for (i, frame) in scene.frames.iter().enumerate() {
            h.word(u32::from(frame.holdout));
            h.float(frame.time.unwrap_or(f64::NAN));
            format!("{:?}", frame.camera).bytes().for_each(|b| h.word(u32::from(b)));
            let image = &self.images[i];
            h.word(image.width as u32);
            h.word(image.height as u32);
            image.data.iter().for_each(|v| h.word(v.to_bits()));
            match &self.masks[i] {
                Some(mask) => mask.iter().for_each(|&k| h.word(u32::from(k) + 1)),
                None => h.word(0),
            }
        }
        h.hex()
    }

    /// Splits images and masks into training and held-out frames, in frame order.
    pub(crate) fn split(&self, scene: &Scene) -> (Vec<usize>, Vec<usize>) {
        let train = scene.training_frames().map(|(i, _)| i).collect();
        let held = scene.holdout_frames().map(|(i, _)| i).collect();
        (train, held)
    }

    /// The first `count` frames' images as preprocessed, before balancing (times their
    /// `gains`): those of the report's camera figure, which then need not be read again.
    pub(crate) fn preprocessed(&self, count: usize) -> Vec<Image> {
        self.images
            .iter()
            .zip(&self.gains)
            .take(count)
            .map(|(image, &gain)| {
                let mut image = image.clone();
                if gain != 1.0 {
                    image.data.iter_mut().for_each(|v| *v = (f64::from(*v) * gain) as f32);
                }
                image
            })
            .collect()
    }

    /// The report's preprocessing record. `fitted` holds, per training frame (in frame order),
    /// the gain and offset fitted on top of the balancing; `scores` the held-out frames'
    /// scores, in frame order.
    pub(crate) fn report(
        &self,
        scene: &Scene,
        fitted: Option<&[(f64, f64)]>,
        scores: &[(usize, HoldoutScore)],
    ) -> Preprocessing {
        let mut out = self.preprocessing.clone();
        let mut fitted = fitted.map(|f| f.iter());
        for (i, f) in scene.frames.iter().enumerate() {
            let (mut gain, mut offset) = (self.gains[i], 0.0);
            if !f.holdout {
                if let Some((g, b)) = fitted.as_mut().and_then(|it| it.next()) {
                    gain *= g;
                    offset = b * self.gains[i];
                }
            }
            out.frames.push(FrameGain {
                frame: i,
                camera: frame_label(scene, i),
                time: f.time.filter(|_| scene.times().len() > 1),
                holdout: f.holdout,
                gain,
                offset,
                holdout_scores: scores.iter().find(|(j, _)| *j == i).map(|(_, s)| *s),
            });
        }
        out
    }
}

/// How far (as a ratio) a training image's total intensity may lie from the median of its
/// time's before [`gain_hint`] speaks. The line-of-sight integrals of one field seen whole by
/// cameras around it have nearly the same total: the synthetic rings and sphere of
/// `fluidnerf synth` spread by 0.1–4 % (`sphere15`), a recording with camera gains drawn in
/// ±30 % (`real-like`) by −23 % to +29 %.
pub const GAIN_HINT_RATIO: f64 = 1.15;

/// The training image whose total intensity lies farthest off the median of its time's, as
/// `(frame, ratio to the median)`, when it lies more than [`GAIN_HINT_RATIO`] off, at some
/// time with at least three comparable training images: a sign that the cameras' gains differ,
/// which a run without gains takes as differences of the field. A pixel sees `1 / (fx fy)` of
/// the plane at unit depth, so an image of a field at depth `z` totals about `fx fy / z²` times
/// the field's integral: each total is divided by that factor, `z` the depth of the box's
/// centre, so cameras at other distances or with other lenses compare. `totals` holds each
/// frame's total, None for a frame whose total does not compare (one with a mask, which hides
/// part of the light; one not read). None when nothing stands out. Cameras that see the flow
/// only in part differ too, so this never refuses a run.
pub(crate) fn gain_spread(scene: &Scene, totals: &[Option<f64>]) -> Option<(usize, f64)> {
    let mut worst: Option<(usize, f64)> = None;
    let key = |i: usize| scene.frames[i].time.map(f64::to_bits);
    let mut keys: Vec<Option<u64>> = (0..totals.len()).map(key).collect();
    keys.sort_unstable();
    keys.dedup();
    for t in keys {
        let group: Vec<(usize, f64)> = (0..totals.len())
            .filter(|&i| !scene.frames[i].holdout && key(i) == t)
            .filter_map(|i| {
                let camera = &scene.frames[i].camera;
                let z = camera.camera_from_world().transform_point3(scene.aabb.centre()).z;
                let k = &camera.intrinsics;
                let per_integral = k.fx * k.fy / (z * z);
                // An image with no light says nothing of its camera's gain (a dead or covered
                // camera, or one that sees only empty space): it is warned about on its own.
                let total = totals[i].filter(|&total| total > 0.0);
                (z > 0.0 && per_integral.is_finite()).then_some(i).zip(total.map(|total| total / per_integral))
            })
            .collect();
        if group.len() < 3 {
            continue;
        }
        let mut sorted: Vec<f64> = group.iter().map(|&(_, total)| total).collect();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        if median.is_nan() || median <= 0.0 {
            continue;
        }
        for &(i, total) in &group {
            let ratio = total / median;
            let off = if ratio > 0.0 { ratio.max(1.0 / ratio) } else { f64::INFINITY };
            if off > GAIN_HINT_RATIO && worst.is_none_or(|(_, w)| off > w.max(1.0 / w)) {
                worst = Some((i, ratio));
            }
        }
    }
    worst
}

/// A warning naming the frames whose images (as preprocessed, masked pixels left out; their
/// totals in `totals`) hold no light at all while other images of their time hold some, or
/// None. A camera that sees the box and no light is evidence of empty space along all its
/// rays, and a run takes it as such; when the camera was off or covered, or the scene names
/// the wrong file, that evidence is false and darkens the whole reconstruction. Every image
/// dark is refused elsewhere.
fn dark_frames_hint(scene: &Scene, totals: &[f64]) -> Option<String> {
    let key = |i: usize| scene.frames[i].time.map(f64::to_bits);
    let lit = |i: usize| (0..totals.len()).any(|j| j != i && key(j) == key(i) && totals[j] > 0.0);
    let dark: Vec<String> = (0..totals.len())
        .filter(|&i| totals[i] == 0.0 && lit(i))
        .map(|i| {
            let f = &scene.frames[i];
            match &f.camera_name {
                Some(name) => format!("{name} ({})", f.file_path.display()),
                None => f.file_path.display().to_string(),
            }
        })
        .collect();
    let (first, rest) = dark.split_first()?;
    let (what, verb) = if rest.is_empty() {
        (first.clone(), "is")
    } else {
        (format!("{first} and {} other image(s): {}", rest.len(), rest.join(", ")), "are")
    };
    Some(format!(
        "{what} {verb} dark at every pixel used, while other cameras of the same time see light: the run takes \
         that as empty space along every ray of {}; if a camera was off or covered, or the scene names the wrong \
         image, remove that frame from the scene",
        if rest.is_empty() { "that camera" } else { "those cameras" }
    ))
}

/// The level of an image's darkest pixels, against which [`offset_note`] tells a constant
/// offset from a gain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    /// The 5th percentile of the pixels.
    pub level: f64,
    /// The pixels' mean.
    pub mean: f64,
}

/// The value every used pixel of an image holds (`mask`: `true` for the pixels used), or None
/// when they differ (or none is used).
pub fn one_value_throughout(data: &[f32], mask: Option<&[bool]>) -> Option<f32> {
    let mut used = data.iter().enumerate().filter(|(k, _)| mask.is_none_or(|m| m[*k])).map(|(_, v)| *v);
    let first = used.next()?;
    used.all(|v| v == first).then_some(first)
}

/// Why a run cannot use `scene`'s training images when each is one value throughout (every
/// pixel saturated, or blank at one level; `levels` per frame as [`one_value_throughout`] gives
/// them): they carry nothing of the field, and a run on them made a field as flat as they are
/// and reported it as a result. All black is refused later, as such.
pub fn flat_training_images(scene: &Scene, levels: &[Option<f32>]) -> Option<String> {
    let training: Vec<usize> = scene.training_frames().map(|(i, _)| i).collect();
    let at = |i: usize| levels.get(i).copied().flatten();
    let k = training.iter().position(|&i| at(i).is_some_and(|v| v > 0.0))?;
    if !training.iter().all(|&i| at(i).is_some()) {
        return None;
    }
    let i = training[k];
    Some(format!(
        "every training image is one value throughout ({}: {} at every pixel{}, as preprocessed): saturated or \
         blank images carry no information about the field; check the exposure and the images the scene names",
        frame_label(scene, i),
        fluidnerf_core::num(at(i).unwrap_or(0.0)),
        if training.len() > 1 { format!(", and the {} others likewise", training.len() - 1) } else { String::new() }
    ))
}

/// How much of an image's light falls on pixels whose rays miss the reconstruction box
/// ([`light_off_box`]): light no reconstruction can explain, and which a run drops with those
/// rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OffBox {
    /// The share of the lit pixels' light, above the image's floor, on pixels that miss the box.
    pub share: f64,
    /// How many lit pixels miss the box.
    pub pixels: usize,
    /// How many pixels are lit.
    pub lit: usize,
}

/// The light of `image` (taken by `camera`, whose size it must have) on pixels whose rays miss
/// `aabb`. A pixel is lit when it stands above the image's floor (its 5th percentile) by more
/// than four times its noise ([`Image::relative_noise`]) and a twentieth of its range, so that
/// noise and a dim background count for nothing; its light is its value above the floor. None
/// for an image of another size than the camera's, or with no lit pixel. A large share says the
/// camera's calibration (its focal length, its pose) or the box is wrong, or that something
/// bright outside the box is in view.
pub fn light_off_box(camera: &Camera, image: &Image, aabb: &fluidnerf_core::Aabb) -> Option<OffBox> {
    use rayon::prelude::*;
    if (image.width, image.height) != (camera.width(), camera.height()) || image.data.is_empty() {
        return None;
    }
    let floor = Floor::of(&image.data).level;
    let (_, hi) = image.min_max();
    let range = f64::from(hi) - floor;
    if range.is_nan() || range <= 0.0 {
        return None;
    }
    let noise = image.relative_noise().unwrap_or(0.0) * range;
    let threshold = floor + (4.0 * noise).max(0.05 * range);
    let w = image.width;
    let (off, all, pixels, lit) = image
        .data
        .par_chunks(w)
        .enumerate()
        .map(|(v, row)| {
            let mut sums = (0.0, 0.0, 0usize, 0usize);
            for (u, &p) in row.iter().enumerate() {
                let p = f64::from(p);
                if p > threshold {
                    let light = p - floor;
                    sums.1 += light;
                    sums.3 += 1;
                    if !camera.pixel_hits(aabb, u, v) {
                        sums.0 += light;
                        sums.2 += 1;
                    }
                }
            }
            sums
        })
        .reduce(|| (0.0, 0.0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2, a.3 + b.3));
    (lit > 0).then(|| OffBox { share: off / all, pixels, lit })
}

impl Floor {
    /// The floor of an image's pixels (all of them: images with masks are not compared).
    pub fn of(data: &[f32]) -> Floor {
        if data.is_empty() {
            return Floor { level: 0.0, mean: 0.0 };
        }
        let mut sorted = data.to_vec();
        let k = sorted.len() / 20;
        let (_, level, _) = sorted.select_nth_unstable_by(k, f32::total_cmp);
        let mean = data.iter().map(|&v| f64::from(v)).sum::<f64>() / data.len() as f64;
        Floor { level: f64::from(*level), mean }
    }
}

/// For frame `i`, whose total is `ratio` × the median of its time ([`gain_spread`]), a note when
/// its darkest pixels are raised above the other training frames' of its time by at least half
/// of its excess light per pixel: a constant offset (light or a black level not subtracted)
/// raises every pixel alike, where a gain leaves dark pixels dark. A gain fitted to an offset
/// fits neither the dark nor the bright pixels. None for a frame dimmer than the median, or when
/// fewer than two others compare (`floors` None for frames with masks, or not read).
fn offset_note(scene: &Scene, i: usize, ratio: f64, floors: &[Option<Floor>]) -> Option<String> {
    let own = floors.get(i).copied().flatten()?;
    let key = |j: usize| scene.frames[j].time.map(f64::to_bits);
    let mut others: Vec<f64> = (0..floors.len())
        .filter(|&j| j != i && !scene.frames[j].holdout && key(j) == key(i))
        .filter_map(|j| floors[j].map(|f| f.level))
        .collect();
    if ratio <= 1.0 || others.len() < 2 {
        return None;
    }
    others.sort_by(f64::total_cmp);
    let raised = own.level - others[others.len() / 2];
    let excess = own.mean * (1.0 - 1.0 / ratio);
    (raised > 0.0 && raised >= 0.5 * excess).then(|| {
        format!(
            "its darkest pixels lie {} above the other cameras' ({:.0} % of its excess light per pixel), as a \
             constant offset raises them, not a gain: subtract that camera's background (`background`) or fit \
             offsets too (--gains fit --gain-offset)",
            fluidnerf_core::num(raised),
            100.0 * raised / excess
        )
    })
}

/// What [`gain_spread`] found, in words, with [`offset_note`]'s note.
fn spread_text(scene: &Scene, i: usize, ratio: f64, offset: Option<&str>) -> String {
    format!(
        "the training images' total intensities differ between cameras as differing gains make them: {} holds {:.2}× \
         the median of its time, for its distance and lens (more than {:.0} % off){}",
        frame_label(scene, i),
        ratio,
        (GAIN_HINT_RATIO - 1.0) * 100.0,
        offset.map(|o| format!("; {o}")).unwrap_or_default()
    )
}

/// What a scene's images say of the cameras' gains before any run ([`gain_spread`], and
/// [`offset_note`] from the images' `floors`), for `fluidnerf info`: None when their totals
/// agree.
pub fn gain_hint(scene: &Scene, totals: &[Option<f64>], floors: &[Option<Floor>]) -> Option<String> {
    let (i, ratio) = gain_spread(scene, totals)?;
    let offset = offset_note(scene, i, ratio, floors);
    Some(format!(
        "{}; by default (gains auto) a static run fits a gain per camera for that{} and a time-resolved run, which \
         fits none, balances the images; --gains none takes them as they are (docs/real-data.md)",
        spread_text(scene, i, ratio, offset.as_deref()),
        if offset.is_some() { " (no offset unless given --gain-offset)" } else { "" }
    ))
}

/// A frame's camera name, or its image file.
pub(crate) fn frame_label(scene: &Scene, i: usize) -> String {
    let f = &scene.frames[i];
    f.camera_name.clone().unwrap_or_else(|| f.file_path.display().to_string())
}

fn used_sum(data: &[f32], mask: Option<&[bool]>) -> f64 {
    match mask {
        Some(m) => data.iter().zip(m).filter(|(_, &k)| k).map(|(&v, _)| v as f64).sum(),
        None => data.iter().map(|&v| v as f64).sum(),
    }
}

/// The gain (and, with `offset`, the offset) minimising `Σ (p − g r − b)²` over the used
/// pixels; None when the model image is (nearly) dark or the fit is not a positive gain. Nearly
/// dark is below a millionth of the measured image's RMS: a field that renders 10⁻²⁰ everywhere
/// would otherwise "fit" with a gain of 10²⁰.
pub(crate) fn fit_gain(p: &[f32], r: &[f32], mask: Option<&[bool]>, offset: bool) -> Option<(f64, f64)> {
    let (mut n, mut sr, mut sp, mut srr, mut srp, mut spp) = (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (k, (&pv, &rv)) in p.iter().zip(r).enumerate() {
        if mask.is_some_and(|m| !m[k]) {
            continue;
        }
        let (pv, rv) = (pv as f64, rv as f64);
        n += 1.0;
        sr += rv;
        sp += pv;
        srr += rv * rv;
        srp += rv * pv;
        spp += pv * pv;
    }
    if srr.is_nan() || srr <= 1e-12 * spp {
        return None;
    }
    let (g, b) = if offset {
        let det = n * srr - sr * sr;
        if det.is_nan() || det <= 1e-12 * n * srr {
            return None;
        }
        ((n * srp - sr * sp) / det, (srr * sp - sr * srp) / det)
    } else {
        (srp / srr, 0.0)
    };
    (g.is_finite() && g > 0.0 && b.is_finite()).then_some((g, b))
}

/// Scales gains so that those `fitted` average 1 (offsets are in pixel units and stay). A gain
/// that could not be fitted (an image without light) keeps no weight in the mean: it would
/// otherwise rescale every other camera, and with them the whole reconstruction.
pub(crate) fn normalise(gains: &mut [(f64, f64)], fitted: &[bool]) {
    assert_eq!(gains.len(), fitted.len(), "normalise: one flag per gain");
    let used = fitted.iter().filter(|&&f| f).count();
    let mean = gains.iter().zip(fitted).filter(|(_, &f)| f).map(|(g, _)| g.0).sum::<f64>() / used.max(1) as f64;
    if mean > 0.0 && mean.is_finite() {
        gains.iter_mut().for_each(|g| g.0 /= mean);
    }
}

/// How well `r` reproduces `p` over the used pixels, as measured and after the best-fit gain.
pub(crate) fn holdout_score(p: &[f32], r: &[f32], mask: Option<&[bool]>) -> HoldoutScore {
    let g = fit_gain(p, r, mask, false).map_or(1.0, |(g, _)| g);
    let (mut num_raw, mut num_fit, mut den) = (0.0f64, 0.0f64, 0.0f64);
    for (k, (&pv, &rv)) in p.iter().zip(r).enumerate() {
        if mask.is_some_and(|m| !m[k]) {
            continue;
        }
        let (pv, rv) = (pv as f64, rv as f64);
        num_raw += (pv - rv).powi(2);
        num_fit += (pv - g * rv).powi(2);
        den += pv * pv;
    }
    let den = den.max(f64::MIN_POSITIVE);
    HoldoutScore { nrmse_raw: (num_raw / den).sqrt(), nrmse_fitted: (num_fit / den).sqrt(), fitted_gain: g }
}

/// A projector whose masked pixels are rows of zeros: the forward map writes 0 there and the
/// adjoint ignores them, so the voxel methods' residuals, row and column sums leave them out
/// (the system is `M A g = M p` with `M` the diagonal of the masks).
pub(crate) struct MaskedProjector<'a> {
    pub inner: &'a dyn Projector,
    /// Per view (the projector's order).
    pub masks: Vec<Option<Vec<bool>>>,
}

impl Projector for MaskedProjector<'_> {
    fn grid(&self) -> &Grid {
        self.inner.grid()
    }

    fn cameras(&self) -> &[Camera] {
        self.inner.cameras()
    }

    fn forward(&self, view: usize, x: &[f32], out: &mut [f32]) {
        self.inner.forward(view, x, out);
        if let Some(m) = &self.masks[view] {
            out.iter_mut().zip(m).filter(|(_, &k)| !k).for_each(|(o, _)| *o = 0.0);
        }
    }

    fn back_add(&self, view: usize, y: &[f32], out: &mut [f32], col_sums: Option<&mut [f32]>) {
        match &self.masks[view] {
            None => self.inner.back_add(view, y, out, col_sums),
            Some(m) => {
                let masked: Vec<f32> = y.iter().zip(m).map(|(&v, &k)| if k { v } else { 0.0 }).collect();
                self.inner.back_add(view, &masked, out, None);
                if let Some(cs) = col_sums {
                    let ones: Vec<f32> = m.iter().map(|&k| if k { 1.0 } else { 0.0 }).collect();
                    self.inner.back_add(view, &ones, cs, None);
                }
            }
        }
    }

    fn back_update(&self, view: usize, y: &[f32], x: &mut [f32], scratch: (&mut [f32], &mut [f32]), update: &Update) {
        match &self.masks[view] {
            None => self.inner.back_update(view, y, x, scratch, update),
            // Masked column sums come from an image of ones: `back_add`'s, then the update.
            Some(_) => {
                let (b, c) = scratch;
                b.fill(0.0);
                c.fill(0.0);
                self.back_add(view, y, b, Some(c));
                fluidnerf_classical::update_in_stretches(x, b, c, update);
            }
        }
    }

    fn back_add_views(&self, views: &[usize], ys: &[&[f32]], out: &mut [f32], mut col_sums: Option<&mut [f32]>) {
        if col_sums.is_some() {
            // Masked column sums come from images of ones, view by view.
            for (&v, y) in views.iter().zip(ys) {
                self.back_add(v, y, out, col_sums.as_deref_mut());
            }
            return;
        }
        let masked: Vec<Option<Vec<f32>>> = views
            .iter()
            .zip(ys)
            .map(|(&v, y)| {
                self.masks[v].as_ref().map(|m| y.iter().zip(m).map(|(&v, &k)| if k { v } else { 0.0 }).collect())
            })
            .collect();
        let ys: Vec<&[f32]> = masked.iter().zip(ys).map(|(m, y)| m.as_deref().unwrap_or(y)).collect();
        self.inner.back_add_views(views, &ys, out, None);
    }

    fn rows(&self, view: usize) -> SparseRows {
        let rows = self.inner.rows(view);
        let Some(m) = &self.masks[view] else { return rows };
        let mut out = SparseRows { ptr: Vec::with_capacity(rows.ptr.len()), cols: Vec::new(), vals: Vec::new() };
        out.ptr.push(0);
        for i in 0..rows.n_rows() {
            if m[i] {
                let (c, v) = rows.row(i);
                out.cols.extend_from_slice(c);
                out.vals.extend_from_slice(v);
            }
            out.ptr.push(out.cols.len() as u64);
        }
        out
    }

    fn rows_bytes_estimate(&self, view: usize) -> usize {
        self.inner.rows_bytes_estimate(view)
    }

    fn bytes(&self) -> usize {
        self.inner.bytes()
    }

    fn scratch_bytes(&self, view: usize) -> usize {
        self.inner.scratch_bytes(view) + 2 * 4 * self.view_len(view)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::glam::DVec3;
    use fluidnerf_core::{Aabb, Camera, Frame, Intrinsics};

    /// A scene of `n` cameras of 8 × 8 px looking at the centre of a box of side 2, frame `i`
    /// placed by `place(i)` as (its angle about y, its distance, its time, whether it is held
    /// out), named `name(i)`, its image `file(i)`.
    fn ring(
        n: usize,
        place: impl Fn(usize) -> (f64, f64, Option<f64>, bool),
        name: impl Fn(usize) -> Option<String>,
        file: impl Fn(usize) -> String,
    ) -> Scene {
        let k = Intrinsics { width: 8, height: 8, fx: 10.0, fy: 10.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        Scene {
            root: "scene".into(),
            aabb: Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0)),
            units: "mm".into(),
            intensity_scale: 1.0,
            frames: (0..n)
                .map(|i| {
                    let (a, r, time, holdout) = place(i);
                    Frame {
                        file_path: file(i).into(),
                        camera: Camera::look_at(k, r * DVec3::new(a.cos(), 0.0, a.sin()), DVec3::ZERO, DVec3::Y),
                        time,
                        camera_name: name(i),
                        holdout,
                    }
                })
                .collect(),
            truth: Vec::new(),
        }
    }

    /// A masked view's fused back projection and update hands the update the back projection
    /// of the image with its masked pixels zeroed and the column sums of its used pixels; an
    /// unmasked view's is the inner projector's.
    #[test]
    fn masked_views_update_with_their_masked_back_projection_and_column_sums() {
        let scene = ring(2, |i| (1.3 * i as f64, 4.0, None, false), |_| None, |i| format!("{i}.png"));
        let cams: Vec<Camera> = scene.frames.iter().map(|f| f.camera.clone()).collect();
        let grid = Grid::new([6, 5, 7], scene.aabb);
        let inner = fluidnerf_classical::FootprintProjector::new(grid, &cams, 1.0).expect("valid");
        let mask: Vec<bool> = (0..64).map(|k| k % 3 != 0).collect();
        let masked = MaskedProjector { inner: &inner, masks: vec![Some(mask.clone()), None] };
        let y: Vec<f32> = (0..64).map(|k| 1.0 + (k % 7) as f32).collect();
        for view in 0..2 {
            let used = |k: usize| view == 1 || mask[k];
            let y_used: Vec<f32> = (0..64).map(|k| if used(k) { y[k] } else { 0.0 }).collect();
            let ones: Vec<f32> = (0..64).map(|k| if used(k) { 1.0 } else { 0.0 }).collect();
            let (mut b, mut c) = (vec![0f32; grid.len()], vec![0f32; grid.len()]);
            inner.back_add(view, &y_used, &mut b, None);
            inner.back_add(view, &ones, &mut c, None);
            assert!(c.iter().any(|&v| v > 0.0), "view {view} sees the grid");
            let mut x = vec![0f32; grid.len()];
            let (mut sb, mut sc) = (vec![9f32; grid.len()], vec![9f32; grid.len()]);
            masked.back_update(view, &y, &mut x, (&mut sb, &mut sc), &|_, xs, bs, cs| {
                for (g, (&bv, &cv)) in xs.iter_mut().zip(bs.iter().zip(cs)) {
                    *g = bv + 10.0 * cv;
                }
            });
            for j in 0..grid.len() {
                let want = b[j] + 10.0 * c[j];
                assert!(
                    (x[j] - want).abs() <= 1e-5 * want.abs().max(1.0),
                    "view {view}, voxel {j}: {} vs {want}",
                    x[j]
                );
            }
        }
    }

    #[test]
    fn the_gain_hint_names_the_camera_off_its_times_median_and_skips_masked_ones() {
        // Five cameras on a ring of radius 5 around the box, the last held out; `far` puts
        // camera 1 at twice the distance.
        let scene = |far: bool| {
            let place = |i: usize| (i as f64 * 1.2, if far && i == 1 { 10.0 } else { 5.0 }, None, i == 4);
            ring(5, place, |i| Some(format!("cam{i}")), |i| format!("c{i}.tiff"))
        };
        let five = scene(false);
        let hint = |totals: [Option<f64>; 5]| gain_hint(&five, &totals, &[None; 5]);
        // Within 15 % of the median: nothing; the held-out camera does not count.
        assert_eq!(hint([Some(1.0), Some(1.1), Some(0.9), Some(1.0), Some(3.0)]), None);
        let said = hint([Some(1.0), Some(1.0), Some(0.8), Some(1.05), None]).expect("a camera 20 % dim");
        assert!(said.contains("cam2 holds 0.80×") && said.contains("gains auto"), "{said}");
        // A camera with no light says nothing of its gain: not a spread of 0×.
        assert_eq!(hint([Some(1.0), Some(0.0), Some(1.0), Some(1.05), None]), None);
        // A masked image's total does not compare; two comparable images are too few.
        assert_eq!(hint([Some(1.0), Some(1.0), None, Some(1.05), None]).map(|_| ()), None);
        assert_eq!(hint([Some(1.0), None, Some(0.5), None, None]), None);
        // A camera twice as far sees the field a quarter as large: a quarter of the light is
        // its share, and the same light as the others would be four times it.
        let far = scene(true);
        assert_eq!(gain_hint(&far, &[Some(1.0), Some(0.25), Some(1.0), Some(1.0), None], &[None; 5]), None);
        let said =
            gain_hint(&far, &[Some(1.0), Some(1.0), Some(1.0), Some(1.0), None], &[None; 5]).expect("too bright");
        assert!(said.contains("cam1 holds 4.00×"), "{said}");
    }

    /// A camera brighter than the others of its time whose darkest pixels are raised by about
    /// its excess light is said to hold an offset; one whose dark pixels stay dark, a gain.
    #[test]
    fn an_excess_that_raises_the_dark_pixels_is_told_as_an_offset() {
        let data: Vec<f32> = (0..100).map(|v| v as f32).collect();
        assert_eq!(Floor::of(&data), Floor { level: 5.0, mean: 49.5 });
        let scene =
            ring(4, |i| (i as f64 * 1.5, 5.0, None, false), |i| Some(format!("cam{i}")), |i| format!("c{i}.tiff"));
        let dark = Some(Floor { level: 0.0, mean: 1.0 });
        let totals = [Some(1.0), Some(1.0), Some(2.0), Some(1.0)];
        // cam2 holds twice the light: 1 per pixel more. Raised by 1 at its darkest: an offset.
        let said = gain_hint(&scene, &totals, &[dark, dark, Some(Floor { level: 1.0, mean: 2.0 }), dark])
            .expect("twice the light");
        assert!(said.contains("cam2 holds 2.00×") && said.contains("--gain-offset"), "{said}");
        assert!(said.contains("darkest pixels lie 1 above the other cameras' (100 %"), "{said}");
        // Its dark pixels as dark as the others': a gain, without the note.
        let said = gain_hint(&scene, &totals, &[dark, dark, Some(Floor { level: 0.0, mean: 2.0 }), dark])
            .expect("twice the light");
        assert!(!said.contains("offset"), "{said}");
        // Raised by less than half its excess: the gain explains most of it.
        assert_eq!(offset_note(&scene, 2, 2.0, &[dark, dark, Some(Floor { level: 0.4, mean: 2.0 }), dark]), None);
        // A dimmer camera, or too few others to compare with, says nothing of an offset.
        assert_eq!(offset_note(&scene, 2, 0.5, &[dark, dark, Some(Floor { level: 1.0, mean: 0.5 }), dark]), None);
        assert_eq!(offset_note(&scene, 2, 2.0, &[dark, None, Some(Floor { level: 1.0, mean: 2.0 }), None]), None);
    }

    #[test]
    fn dark_frames_are_named_only_beside_lit_ones_of_their_time() {
        // Three cameras at each of two times; the last camera unnamed.
        let scene = ring(
            6,
            |i| ((i % 3) as f64 * 2.0, 5.0, Some((i / 3) as f64), false),
            |i| (i % 3 != 2).then(|| format!("cam{}", i % 3)),
            |i| format!("t{}/c{}.png", i / 3, i % 3),
        );
        assert_eq!(dark_frames_hint(&scene, &[1.0, 2.0, 1.5, 1.0, 1.0, 1.0]), None);
        let said = dark_frames_hint(&scene, &[1.0, 0.0, 1.5, 1.0, 1.0, 1.0]).expect("one dark camera");
        assert!(said.starts_with("cam1 (t0/c1.png) is dark at every pixel used") && said.contains("that camera"));
        // A dark frame is named beside lit frames of its own time only: time 1 is all dark, which
        // is refused elsewhere, and its frames are not named here.
        let said = dark_frames_hint(&scene, &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0]).expect("two dark at time 0");
        assert!(
            said.starts_with("cam0 (t0/c0.png) and 1 other image(s): t0/c2.png are dark")
                && said.contains("those cameras"),
            "{said}"
        );
        assert_eq!(dark_frames_hint(&scene, &[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]), None);
    }

    #[test]
    fn gain_fits_recover_gain_and_offset() {
        let r: Vec<f32> = (0..50).map(|i| (i as f32 * 0.37).sin().abs() * 10.0).collect();
        let p: Vec<f32> = r.iter().map(|&v| 1.3 * v + 2.0).collect();
        let (g, b) = fit_gain(&p, &r, None, true).expect("fit");
        assert!((g - 1.3).abs() < 1e-4 && (b - 2.0).abs() < 1e-3, "{g} {b}");
        let p: Vec<f32> = r.iter().map(|&v| 0.7 * v).collect();
        let (g, b) = fit_gain(&p, &r, None, false).expect("fit");
        assert!((g - 0.7).abs() < 1e-6 && b == 0.0);
        // Masked pixels do not count: corrupt them and the fit is unchanged.
        let mut q = p.clone();
        let mask: Vec<bool> = (0..50).map(|i| i % 3 != 0).collect();
        q.iter_mut().zip(&mask).filter(|(_, &k)| !k).for_each(|(v, _)| *v = 1e6);
        let (gm, _) = fit_gain(&q, &r, Some(&mask), false).expect("fit");
        assert!((gm - 0.7).abs() < 1e-6);
        assert!(fit_gain(&p, &[0.0; 50], None, false).is_none());
        // A rendering far too dark to carry a signal fits no gain, and the held-out score
        // after "fitting" is the raw one.
        let dark: Vec<f32> = r.iter().map(|&v| 1e-20 * v).collect();
        assert!(fit_gain(&p, &dark, None, false).is_none() && fit_gain(&p, &dark, None, true).is_none());
        let s = holdout_score(&p, &dark, None);
        assert!(s.fitted_gain == 1.0 && s.nrmse_fitted == s.nrmse_raw && s.nrmse_raw > 0.99, "{s:?}");
        let s = holdout_score(&p, &r, None);
        assert!(s.nrmse_raw > 0.3 && s.nrmse_fitted < 1e-6 && (s.fitted_gain - 0.7).abs() < 1e-6, "{s:?}");
        let mut gains = vec![(2.0, 0.0), (4.0, 1.0)];
        normalise(&mut gains, &[true, true]);
        assert_eq!(gains, vec![(2.0 / 3.0, 0.0), (4.0 / 3.0, 1.0)]);
        // A gain that was not fitted neither counts in the mean nor is left out of the scaling.
        let mut gains = vec![(2.0, 0.0), (1.0, 0.0), (4.0, 1.0)];
        normalise(&mut gains, &[true, false, true]);
        assert_eq!(gains, vec![(2.0 / 3.0, 0.0), (1.0 / 3.0, 0.0), (4.0 / 3.0, 1.0)]);
    }

    /// The light on pixels whose rays miss the box, against an image lit where the box images
    /// and one lit beside it, with the share known from the pixels chosen.
    #[test]
    fn light_off_box_is_the_share_of_light_on_pixels_that_miss_the_box() {
        // 32 × 32 px, a box of side 2 seen from 10 away: it images about 12 px wide in the middle.
        let k = Intrinsics { width: 32, height: 32, fx: 60.0, fy: 60.0, cx: 15.5, cy: 15.5, skew: 0.0 };
        let camera = Camera::look_at(k, DVec3::new(0.0, 0.0, 10.0), DVec3::ZERO, DVec3::Y);
        let aabb = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        let (hit, miss) = ((16, 16), (1, 1));
        assert!(camera.pixel_hits(&aabb, hit.0, hit.1) && !camera.pixel_hits(&aabb, miss.0, miss.1));
        let lit = |spots: &[((usize, usize), f32)]| {
            let mut im = Image::zeros(32, 32);
            for &((u, v), value) in spots {
                im.data[v * 32 + u] = value;
            }
            im
        };
        let inside = light_off_box(&camera, &lit(&[(hit, 1.0)]), &aabb).expect("lit");
        assert_eq!(inside, OffBox { share: 0.0, pixels: 0, lit: 1 });
        let outside = light_off_box(&camera, &lit(&[(miss, 1.0)]), &aabb).expect("lit");
        assert_eq!(outside, OffBox { share: 1.0, pixels: 1, lit: 1 });
        // Three parts inside, one outside: a quarter of the light above the floor (0).
        let both = light_off_box(&camera, &lit(&[(hit, 3.0), (miss, 1.0)]), &aabb).expect("lit");
        assert_eq!((both.share, both.pixels, both.lit), (0.25, 1, 2));
        // A dim pixel (under a twentieth of the range) is no light.
        let dim = light_off_box(&camera, &lit(&[(hit, 1.0), (miss, 0.04)]), &aabb).expect("lit");
        assert_eq!(dim.pixels, 0);
        // A black image, or one of another size than the camera's, says nothing.
        assert_eq!(light_off_box(&camera, &Image::zeros(32, 32), &aabb), None);
        assert_eq!(light_off_box(&camera, &Image::zeros(16, 32), &aabb), None);
    }
}
