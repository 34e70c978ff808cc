//! "Real-like" recordings: what a multi-camera rig in a laboratory records, for testing the
//! preprocessing and gain calibration on data with a known answer.
//!
//! For camera `c` with the noiseless line-integral image `I_c` (field units × mm) the recorded
//! linear image, on the 0..=255 scale of an 8-bit sensor, is
//!
//! ```text
//! L_c = S_c · g_c · k · I_c + B_c + n,    n ~ N(0, σ²) per pixel,
//! ```
//!
//! - `S_c`: the camera's sensitivity per pixel, 1 everywhere unless `vignetting` is set: then a
//!   smooth radial fall-off `1 − vignetting · ρ²` about a centre drawn within ±10 % of the
//!   image's size of its middle, `ρ` the distance from it over the distance to the farthest
//!   corner, scaled to mean 1 over the image (so that the images keep their overall scale and the
//!   gains their meaning) ([`sensitivity_pattern`]);
//! - `g_c`: the camera's gain, drawn uniformly in `[1 − gain_spread, 1 + gain_spread]` and then
//!   scaled so that the training cameras' gains average 1 (only ratios of gains can be
//!   recovered from the images; this fixes the scale a calibrated reconstruction should find);
//! - `k`: the scene's `intensity_scale`, putting the brightest `g_c · k · I_c` of the data set at
//!   `full_scale_fraction` (the sensor setting) of 255;
//! - `B_c`: a smooth background, on average `background` × that brightest value, tilted by
//!   ±20 % across the image and varying by ±20 % between cameras (stray light, dark current);
//! - `σ = dark_noise` × the brightest value.
//!
//! Each camera also records `background_frames` frames of the background alone (same `B_c`,
//! fresh noise) and, with `vignetting`, `flat_frames` flat-field frames of a uniformly lit
//! target, `S_c · FLAT_LEVEL · 255 + B_c + n` (fresh noise). The images are written as 8-bit
//! sRGB JPEGs (the transfer curve applied to `L_c / 255`), which adds quantisation and
//! compression error. A reconstruction recovers `k · ∫E ds` by subtracting the background
//! frames, dividing by the flat field and dividing out the gains.

use fluidnerf_core::num;
use fluidnerf_core::Image;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

use crate::image::thin_lens::mix_seed;
use crate::SynthError;

/// Settings of a real-like recording (module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RealLike {
    /// Half-width of the gains' uniform distribution around 1. Default 0.3.
    pub gain_spread: f64,
    /// Mean background level as a fraction of the brightest signal pixel. Default 0.05.
    pub background: f64,
    /// σ of the per-pixel Gaussian dark noise as a fraction of the brightest signal pixel.
    /// Default 0.005 (about one count of 8 bits).
    pub dark_noise: f64,
    /// Background frames recorded per camera. Default 1.
    pub background_frames: usize,
    /// JPEG quality, 1..=100. Default 95.
    pub jpeg_quality: u8,
    /// How far the sensitivity falls from the vignetting's centre to the farthest image
    /// corner, as a fraction, before the map is scaled to mean 1 (module docs), in [0, 0.9].
    /// Default 0: uniform sensitivity and no flat-field frames.
    pub vignetting: f64,
    /// Flat-field frames recorded per camera when `vignetting` is set, 1..=100. Default 1.
    pub flat_frames: usize,
}

impl Default for RealLike {
    fn default() -> Self {
        RealLike {
            gain_spread: 0.3,
            background: 0.05,
            dark_noise: 0.005,
            background_frames: 1,
            jpeg_quality: 95,
            vignetting: 0.0,
            flat_frames: 1,
        }
    }
}

impl RealLike {
    pub fn validate(&self) -> Result<(), SynthError> {
        if !(0.0..1.0).contains(&self.gain_spread) {
            return Err(SynthError::invalid(
                "real.gain_spread",
                format!("must be in [0, 1), got {}", num(self.gain_spread)),
            ));
        }
        if !(0.0..0.5).contains(&self.background) {
            return Err(SynthError::invalid(
                "real.background",
                format!("must be in [0, 0.5), got {}", num(self.background)),
            ));
        }
        if !(0.0..0.5).contains(&self.dark_noise) {
            return Err(SynthError::invalid(
                "real.dark_noise",
                format!("must be in [0, 0.5), got {}", num(self.dark_noise)),
            ));
        }
        if self.background_frames == 0 || self.background_frames > 100 {
            return Err(SynthError::invalid(
                "real.background_frames",
                format!("must be in 1..=100, got {}", self.background_frames),
            ));
        }
        if !(0.0..=0.9).contains(&self.vignetting) {
            return Err(SynthError::invalid(
                "real.vignetting",
                format!(
                    "must be in [0, 0.9] (the fraction the sensitivity falls to a corner), got {}",
                    num(self.vignetting)
                ),
            ));
        }
        if self.flat_frames == 0 || self.flat_frames > 100 {
            return Err(SynthError::invalid(
                "real.flat_frames",
                format!("must be in 1..=100, got {}", self.flat_frames),
            ));
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            return Err(SynthError::invalid(
                "real.jpeg_quality",
                format!("must be in 1..=100, got {}", self.jpeg_quality),
            ));
        }
        Ok(())
    }
}

/// What a real-like recording adds to a synthetic data set.
#[derive(Clone, Debug)]
pub struct RealRecording {
    /// Per camera: the gain `g_c` (training cameras average 1).
    pub gains: Vec<f64>,
    /// Per camera: its background frames (linear, 0..=255 scale).
    pub backgrounds: Vec<Vec<Image>>,
    /// Per camera: its flat-field frames (linear, 0..=255 scale); none without vignetting.
    pub flats: Vec<Vec<Image>>,
    pub jpeg_quality: u8,
}

/// Draws the gains of `holdout.len()` cameras (module docs).
pub fn draw_gains(settings: &RealLike, holdout: &[bool], seed: u64) -> Vec<f64> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_seed(seed, 0x6761_696e));
    let s = settings.gain_spread;
    let mut gains: Vec<f64> =
        holdout.iter().map(|_| if s > 0.0 { rng.random_range(1.0 - s..=1.0 + s) } else { 1.0 }).collect();
    let train: Vec<f64> = gains.iter().zip(holdout).filter(|(_, &h)| !h).map(|(g, _)| *g).collect();
    let mean = if train.is_empty() { 1.0 } else { train.iter().sum::<f64>() / train.len() as f64 };
    gains.iter_mut().for_each(|g| *g /= mean);
    gains
}

/// The background of camera `camera` (module docs), `level` its mean value.
pub fn background_pattern(width: usize, height: usize, level: f64, camera: usize, seed: u64) -> Image {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_seed(seed, 0x6267 ^ camera as u64));
    let scale = rng.random_range(0.8..=1.2);
    let (tx, ty): (f64, f64) = (rng.random_range(-0.2..=0.2), rng.random_range(-0.2..=0.2));
    let mut img = Image::zeros(width, height);
    for row in 0..height {
        for col in 0..width {
            let u = col as f64 / width.max(2) as f64 - 0.5;
            let v = row as f64 / height.max(2) as f64 - 0.5;
            img.set(col, row, (level * scale * (1.0 + 2.0 * (tx * u + ty * v))) as f32);
        }
    }
    img
}

/// The level of a flat-field frame's uniformly lit target, as a fraction of 255: bright, for
/// little noise, yet below full scale where the sensitivity peaks over a background.
pub const FLAT_LEVEL: f64 = 0.6;

/// The sensitivity of camera `camera` (module docs): `1 − vignetting · ρ²` about an off-centre
/// point, scaled to mean 1 over the image. All ones for `vignetting` 0.
pub fn sensitivity_pattern(width: usize, height: usize, vignetting: f64, camera: usize, seed: u64) -> Image {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_seed(seed, 0x7669_676e ^ camera as u64));
    let (w, h) = (width as f64, height as f64);
    let centre = (0.5 * w * (1.0 + rng.random_range(-0.2..=0.2)), 0.5 * h * (1.0 + rng.random_range(-0.2..=0.2)));
    // Distance from the centre to the farthest corner.
    let reach = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
        .iter()
        .map(|&(x, y): &(f64, f64)| (x - centre.0).hypot(y - centre.1))
        .fold(0.0, f64::max)
        .max(1e-9);
    let mut img = Image::zeros(width, height);
    for row in 0..height {
        for col in 0..width {
            let rho = (col as f64 + 0.5 - centre.0).hypot(row as f64 + 0.5 - centre.1) / reach;
            img.set(col, row, (1.0 - vignetting * rho * rho) as f32);
        }
    }
    let mean = img.data.iter().map(|&v| f64::from(v)).sum::<f64>() / img.data.len().max(1) as f64;
    img.data.iter_mut().for_each(|v| *v = (f64::from(*v) / mean) as f32);
    img
}

/// `base + N(0, σ²)` per pixel, from the stream `(seed, stream)`, clamped to `[0, 255]`.
pub fn add_noise(base: &Image, sigma: f64, seed: u64, stream: u64) -> Result<Image, SynthError> {
    let normal = Normal::new(0.0, sigma).map_err(|e| SynthError::invalid("real.dark_noise", e.to_string()))?;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_seed(seed, stream));
    let mut out = base.clone();
    for v in &mut out.data {
        let n = if sigma > 0.0 { normal.sample(&mut rng) } else { 0.0 };
        *v = (*v as f64 + n).clamp(0.0, 255.0) as f32;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gains_average_one_over_training_cameras_and_stay_near_the_spread() {
        let held = [false, false, true, false, false, false];
        let g = draw_gains(&RealLike::default(), &held, 7);
        let train: Vec<f64> = g.iter().zip(&held).filter(|(_, &h)| !h).map(|(g, _)| *g).collect();
        assert!((train.iter().sum::<f64>() / train.len() as f64 - 1.0).abs() < 1e-12);
        assert!(g.iter().all(|&x| x > 0.5 && x < 1.6), "{g:?}");
        assert!(g.iter().any(|&x| (x - 1.0).abs() > 0.05), "gains should differ: {g:?}");
        assert_eq!(g, draw_gains(&RealLike::default(), &held, 7));
        let bg = background_pattern(10, 8, 10.0, 2, 1);
        let mean = bg.data.iter().map(|&v| v as f64).sum::<f64>() / 80.0;
        assert!(mean > 7.5 && mean < 12.5, "{mean}");
        assert!(RealLike { jpeg_quality: 0, ..Default::default() }.validate().is_err());
        assert!(RealLike { vignetting: 0.95, ..Default::default() }.validate().is_err());
        assert!(RealLike { flat_frames: 0, ..Default::default() }.validate().is_err());
    }

    /// The sensitivity averages 1, falls from its centre by the vignetting to the farthest
    /// corner, and is uniform without vignetting.
    #[test]
    fn the_sensitivity_averages_one_and_falls_towards_the_corners() {
        assert!(sensitivity_pattern(12, 10, 0.0, 1, 3).data.iter().all(|&v| v == 1.0));
        let s = sensitivity_pattern(40, 30, 0.5, 1, 3);
        let mean = s.data.iter().map(|&v| f64::from(v)).sum::<f64>() / s.data.len() as f64;
        assert!((mean - 1.0).abs() < 1e-6, "{mean}");
        let (lo, hi) = s.min_max();
        // The peak over the farthest corner: 1 / (1 − 0.5) at most, nearly that on a fine grid.
        assert!(hi / lo > 1.7 && hi / lo <= 2.0, "{lo} .. {hi}");
        assert!(s.get(20, 15) > s.get(0, 0) && s.get(20, 15) > s.get(39, 29), "the middle is the brightest");
        assert_ne!(s, sensitivity_pattern(40, 30, 0.5, 2, 3), "every camera's differs");
    }
}
