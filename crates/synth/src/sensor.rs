//! The sensor: conversion of line-integral images to integer counts, with photon (Poisson)
//! noise, Gaussian noise, a dark offset and quantisation (dissertation §6.3.1: Gaussian noise
//! with σ a fraction of each image's maximum, 1–10 %).
//!
//! For a noiseless image `I` (field units × mm) the sensor records, in this order:
//!
//! 1. `c = k · I`, with the scene's `intensity_scale` `k` chosen so that the brightest
//!    noiseless pixel of the whole data set sits at `full_scale_fraction` of full scale
//!    (`2^bits − 1` counts);
//! 2. photon noise, if `full_well` is set: `c ← Poisson(c · g) / g` with `g = full_well /
//!    (2^bits − 1)` photo-electrons per count;
//! 3. Gaussian noise `N(0, σ²)` with `σ = gaussian_noise · max(k · I)` (per image);
//! 4. the dark offset (counts), then rounding and clipping to `[0, 2^bits − 1]`.
//!
//! So `counts − dark_offset ≈ intensity_scale × ∫E ds`. Counts are stored unscaled (a 12-bit
//! sensor's values stay in 0..=4095, in a 16-bit file).

use fluidnerf_core::num;
use fluidnerf_core::Image;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, Poisson};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::image::thin_lens::mix_seed;
use crate::SynthError;

/// Sensor settings. Defaults: a noiseless 16-bit sensor with the brightest pixel at 80 % of
/// full scale.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorSettings {
    /// 8, 10, 12 or 16. Default 16.
    pub bit_depth: u32,
    /// Brightest noiseless pixel as a fraction of full scale. Default 0.8.
    pub full_scale_fraction: f64,
    /// σ of additive Gaussian noise as a fraction of each image's maximum (0.01, 0.025, 0.05,
    /// 0.1 in the dissertation). Default 0.
    pub gaussian_noise: f64,
    /// Photo-electrons at full scale; enables photon (Poisson) noise. Default none.
    pub full_well: Option<f64>,
    /// Constant added to every pixel, counts; at most `(1 − full_scale_fraction) × full scale`,
    /// so the brightest noiseless pixel stays unclipped. Default 0.
    pub dark_offset: f64,
}

impl Default for SensorSettings {
    fn default() -> Self {
        SensorSettings {
            bit_depth: 16,
            full_scale_fraction: 0.8,
            gaussian_noise: 0.0,
            full_well: None,
            dark_offset: 0.0,
        }
    }
}

impl SensorSettings {
    pub fn validate(&self) -> Result<(), SynthError> {
        if ![8, 10, 12, 16].contains(&self.bit_depth) {
            return Err(SynthError::invalid(
                "sensor.bit_depth",
                format!("must be 8, 10, 12 or 16, got {}", self.bit_depth),
            ));
        }
        if !(self.full_scale_fraction > 0.0 && self.full_scale_fraction <= 1.0) {
            return Err(SynthError::invalid(
                "sensor.full_scale_fraction",
                format!("must be in (0, 1], got {}", num(self.full_scale_fraction)),
            ));
        }
        if !(self.gaussian_noise >= 0.0 && self.gaussian_noise < 1.0) {
            return Err(SynthError::invalid(
                "sensor.gaussian_noise",
                format!(
                    "must be a fraction of the image's maximum in [0, 1) (0.05 for 5 %), got {}",
                    num(self.gaussian_noise)
                ),
            ));
        }
        if let Some(fw) = self.full_well {
            if !(fw > 0.0 && fw.is_finite()) {
                return Err(SynthError::invalid("sensor.full_well", format!("must be positive, got {}", num(fw))));
            }
            // A pixel that holds no whole photo-electron records rare specks at full scale.
            if fw < 1.0 {
                return Err(SynthError::invalid(
                    "sensor.full_well",
                    format!("must be at least 1 photo-electron at full scale, got {}", num(fw)),
                ));
            }
        }
        if !(self.dark_offset >= 0.0 && self.dark_offset < self.full_scale()) {
            return Err(SynthError::invalid(
                "sensor.dark_offset",
                format!("must be in [0, {}), got {}", num(self.full_scale()), num(self.dark_offset)),
            ));
        }
        // The offset lifts the brightest noiseless pixel too: past full scale it is clipped, and
        // the brightest parts of every image hold less than the line-integral model says.
        let brightest = self.full_scale_fraction * self.full_scale();
        // Up to round-off: 0.8 × 65535 leaves 13107 counts, not 13106.99….
        let headroom = self.full_scale() - brightest + 1e-9 * self.full_scale();
        if self.dark_offset > headroom {
            return Err(SynthError::invalid(
                "sensor.dark_offset",
                format!(
                    "{} counts lift the brightest noiseless pixel ({} of full scale, {} counts) to {} counts, past \
                     the full scale of {}: the brightest pixels would be clipped (saturated); give an offset of at \
                     most {}, or a lower full_scale_fraction",
                    num(self.dark_offset),
                    num(self.full_scale_fraction),
                    num(brightest),
                    num(self.dark_offset + brightest),
                    num(self.full_scale()),
                    num(headroom.floor())
                ),
            ));
        }
        Ok(())
    }

    /// Full scale in counts, `2^bits − 1`.
    pub fn full_scale(&self) -> f64 {
        ((1u64 << self.bit_depth) - 1) as f64
    }

    /// The `intensity_scale` putting `max_line_integral` at `full_scale_fraction` of full scale
    /// (1 if the data set is black).
    pub fn intensity_scale(&self, max_line_integral: f64) -> f64 {
        if max_line_integral > 0.0 && max_line_integral.is_finite() {
            self.full_scale_fraction * self.full_scale() / max_line_integral
        } else {
            1.0
        }
    }

    /// Records `clean` (line integrals) as counts (see the module docs). `seed` and `stream`
    /// select the noise; rows draw from independent streams, so the result is the same on any
    /// number of threads.
    pub fn expose(&self, clean: &Image, intensity_scale: f64, seed: u64, stream: u64) -> Result<Image, SynthError> {
        self.validate()?;
        let full = self.full_scale();
        let peak = clean.min_max().1 as f64 * intensity_scale;
        let sigma = self.gaussian_noise * peak.max(0.0);
        let gauss = Normal::new(0.0, sigma).map_err(|e| SynthError::invalid("sensor.gaussian_noise", e.to_string()))?;
        let gain = self.full_well.map(|fw| fw / full);
        let w = clean.width;
        let mut out = Image::zeros(clean.width, clean.height);
        let row_seed = mix_seed(seed, stream);
        out.data.par_chunks_mut(w.max(1)).zip(clean.data.par_chunks(w.max(1))).enumerate().for_each(|(row, (o, c))| {
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_seed(row_seed, row as u64));
            for (o, &c) in o.iter_mut().zip(c) {
                let mut counts = (c as f64 * intensity_scale).max(0.0);
                if let Some(g) = gain {
                    let electrons = counts * g;
                    counts = if electrons > 0.0 {
                        Poisson::new(electrons).map_or(electrons, |p| p.sample(&mut rng)) / g
                    } else {
                        0.0
                    };
                }
                if sigma > 0.0 {
                    counts += gauss.sample(&mut rng);
                }
                *o = (counts + self.dark_offset).round().clamp(0.0, full) as f32;
            }
        });
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mean_var(v: &[f32]) -> (f64, f64) {
        let n = v.len() as f64;
        let m = v.iter().map(|&x| x as f64).sum::<f64>() / n;
        (m, v.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / (n - 1.0))
    }

    #[test]
    fn gaussian_sigma_is_a_fraction_of_the_maximum() {
        // A flat image at 1000 counts with one pixel at 2000 (the maximum).
        let mut clean = Image::from_vec(256, 256, vec![1000.0; 256 * 256]);
        clean.set(0, 0, 2000.0);
        for frac in [0.01, 0.025, 0.05, 0.1] {
            let s = SensorSettings { gaussian_noise: frac, ..Default::default() };
            let img = s.expose(&clean, 1.0, 3, 0).expect("expose");
            let (m, v) = mean_var(&img.data[1..]);
            let expected = frac * 2000.0;
            assert!((v.sqrt() - expected).abs() < 0.02 * expected, "σ {} vs {expected}", v.sqrt());
            assert!((m - 1000.0).abs() < 0.05 * expected);
        }
    }

    #[test]
    fn photon_noise_mean_equals_variance_in_electrons() {
        let clean = Image::from_vec(256, 256, vec![0.5; 256 * 256]);
        let s = SensorSettings { bit_depth: 12, full_well: Some(4095.0 * 4.0), ..Default::default() };
        // intensity scale 2000 → 1000 counts → 4000 electrons.
        let img = s.expose(&clean, 2000.0, 1, 0).expect("expose");
        let (m, v) = mean_var(&img.data);
        let (me, ve) = (m * 4.0, v * 16.0);
        assert!((me - 4000.0).abs() < 4.0, "mean {me} e⁻");
        assert!((ve / me - 1.0).abs() < 0.03, "variance/mean {}", ve / me);
    }

    #[test]
    fn quantisation_offset_clipping_and_seeds() {
        let clean = Image::from_vec(4, 1, vec![0.0, 0.5, 1.0, 10.0]);
        let s = SensorSettings { bit_depth: 8, dark_offset: 10.0, ..Default::default() };
        let scale = s.intensity_scale(1.0);
        assert!((scale - 0.8 * 255.0).abs() < 1e-12);
        let img = s.expose(&clean, scale, 0, 0).expect("expose");
        assert_eq!(
            img.data,
            vec![10.0, (0.4f64 * 255.0 + 10.0).round() as f32, (0.8f64 * 255.0 + 10.0).round() as f32, 255.0]
        );
        let noisy = SensorSettings { gaussian_noise: 0.05, ..Default::default() };
        let flat = Image::from_vec(32, 32, vec![1.0; 1024]);
        let a = noisy.expose(&flat, 1000.0, 5, 2).expect("expose");
        assert_eq!(a, noisy.expose(&flat, 1000.0, 5, 2).expect("expose"));
        assert_ne!(a, noisy.expose(&flat, 1000.0, 6, 2).expect("expose"));
        assert_ne!(a, noisy.expose(&flat, 1000.0, 5, 3).expect("expose"));
    }

    #[test]
    fn bad_settings_are_rejected() {
        assert!(SensorSettings { gaussian_noise: -0.01, ..Default::default() }.validate().is_err());
        assert!(SensorSettings { gaussian_noise: 5.0, ..Default::default() }.validate().is_err());
        assert!(SensorSettings { gaussian_noise: 0.99, ..Default::default() }.validate().is_ok());
        assert!(SensorSettings { bit_depth: 14, ..Default::default() }.validate().is_err());
        assert!(SensorSettings { full_well: Some(0.0), ..Default::default() }.validate().is_err());
        // Less than one photo-electron at full scale: every count is a rare saturated speck.
        let err = SensorSettings { full_well: Some(1e-300), ..Default::default() }.validate().expect_err("tiny");
        assert!(err.to_string().contains("must be at least 1 photo-electron at full scale, got 1e-300"), "{err}");
        assert!(SensorSettings { full_well: Some(1.0), ..Default::default() }.validate().is_ok());
    }

    #[test]
    fn an_offset_that_lifts_the_brightest_pixel_past_full_scale_is_refused() {
        // 60000 + 0.8 × 65535 counts: the brightest pixels were written clipped at 65535.
        let err = SensorSettings { dark_offset: 60000.0, ..Default::default() }.validate().expect_err("clips");
        let text = err.to_string();
        assert!(text.contains("`sensor.dark_offset`") && text.contains("past the full scale of 65535"), "{text}");
        assert!(text.contains("give an offset of at most 13107"), "{text}");
        // Up to the headroom the fraction leaves, the brightest pixel stays below full scale.
        assert!(SensorSettings { dark_offset: 13107.0, ..Default::default() }.validate().is_ok());
        assert!(SensorSettings { dark_offset: 13108.0, ..Default::default() }.validate().is_err());
        let full = SensorSettings { full_scale_fraction: 1.0, dark_offset: 1.0, ..Default::default() };
        assert!(full.validate().is_err(), "no headroom at a fraction of 1");
    }
}
