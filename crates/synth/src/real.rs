//! "Real-like" recordings: what a multi-camera rig in a laboratory records, for testing the
//! preprocessing and gain calibration on data with a known answer.
//!
//! For camera `c` with the noiseless line-integral image `I_c` (field units × mm) the recorded
//! linear image, on the 0..=255 scale of an 8-bit sensor, is
//!
//! ```text
//! L_c = g_c · k · I_c + B_c + n,    n ~ N(0, σ²) per pixel,
//! ```
//!
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
//! fresh noise). The images are written as 8-bit sRGB JPEGs (the transfer curve applied to
//! `L_c / 255`), which adds quantisation and compression error. A reconstruction recovers `k ·
//! ∫E ds` by subtracting the background frames and dividing out the gains.

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
}

impl Default for RealLike {
    fn default() -> Self {
        RealLike { gain_spread: 0.3, background: 0.05, dark_noise: 0.005, background_frames: 1, jpeg_quality: 95 }
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
    }
}
