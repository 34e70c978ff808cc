//! Single-channel linear f32 images.

/// Images whose [`Image::relative_noise`] is above this fraction of their range count as noisy:
/// runs that adapt to the noise ([`Image::relative_noise`]'s users) treat them so. Chosen on
/// the jet phantom, between 1 % noise and 2.5 % (docs/claims.md).
pub const NOISY_ABOVE: f64 = 0.015;

/// Whether images whose (median) [`Image::relative_noise`] is `noise` count as clean: an
/// estimate of at most [`NOISY_ABOVE`]. No estimate counts as noisy, the cautious reading.
/// The one rule the automatic settings share.
pub fn reads_clean(noise: Option<f64>) -> bool {
    noise.is_some_and(|n| n <= NOISY_ABOVE)
}

/// The refusal of every method whose training images hold no light where they are used (no
/// pixel above 0 outside the masks): they can only give an empty volume.
pub const ALL_BLACK: &str = "all training images are black (no pixel above 0 outside the masks)";

/// A single-channel image of linear intensities, row-major: pixel `(col, row)` is
/// `data[row * width + col]` and has its centre at image coordinates `(col, row)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Image {
    /// A black image.
    pub fn zeros(width: usize, height: usize) -> Self {
        Image { width, height, data: vec![0.0; width * height] }
    }

    /// Wraps `data`; panics if its length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height, "Image::from_vec: {width}x{height} needs {} values", width * height);
        Image { width, height, data }
    }

    pub fn get(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }

    pub fn set(&mut self, col: usize, row: usize, value: f32) {
        self.data[row * self.width + col] = value;
    }

    /// Smallest and largest values, ignoring nothing: a NaN anywhere makes both NaN.
    pub fn min_max(&self) -> (f32, f32) {
        self.data.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            if v.is_nan() || lo.is_nan() {
                (f32::NAN, f32::NAN)
            } else {
                (lo.min(v), hi.max(v))
            }
        })
    }

    /// The position `(col, row)` of the first non-finite pixel, if any.
    pub fn first_non_finite(&self) -> Option<(usize, usize)> {
        self.data.iter().position(|v| !v.is_finite()).map(|i| (i % self.width, i / self.width))
    }

    /// Sum of all pixel values, accumulated in f64.
    pub fn sum(&self) -> f64 {
        self.data.iter().map(|&v| v as f64).sum()
    }

    /// The image's noise as a fraction of its range: a robust estimate of the standard
    /// deviation of additive pixel noise, divided by `max − min`. `None` when the image is
    /// constant, smaller than 3 × 3, or holds a non-finite value.
    ///
    /// The estimate is Immerkær's ("Fast noise variance estimation", CVIU 1996): the image is
    /// filtered with the difference of two Laplacians, `[1 −2 1; −2 4 −2; 1 −2 1]`, which
    /// cancels planes and most of a smooth image's curvature and scales white noise of
    /// deviation σ to deviation 6σ. Its median absolute value, times 1.4826, is then σ robustly
    /// (edges are a minority of the pixels). It is taken two ways, and the smaller counts:
    /// - over the pixels whose 3 × 3 neighbourhood lies above the image's minimum, so that a
    ///   background clipped to the sensor's floor (noise cut off at zero) does not read as a
    ///   noiseless image (needs 16 such pixels);
    /// - over every pixel, divided by [`CLIPPED_NOISE_RESPONSE`], the same median for noise
    ///   clipped at zero, so that an image whose background lies exactly on the floor — a
    ///   noiseless image of a small object, whose own sharp structure would dominate the
    ///   first median — reads as clean.
    pub fn relative_noise(&self) -> Option<f64> {
        let (lo, hi) = self.min_max();
        let (w, h) = (self.width, self.height);
        if !(lo.is_finite() && hi.is_finite() && hi > lo) || w < 3 || h < 3 {
            return None;
        }
        let above = |c: usize, r: usize| self.data[r * w + c] > lo;
        let (mut lifted, mut all) = (Vec::new(), Vec::with_capacity((w - 2) * (h - 2)));
        for r in 1..h - 1 {
            for c in 1..w - 1 {
                let p = |dc: usize, dr: usize| self.data[(r + dr - 1) * w + c + dc - 1] as f64;
                let corners = p(0, 0) + p(2, 0) + p(0, 2) + p(2, 2);
                let edges = p(1, 0) + p(0, 1) + p(2, 1) + p(1, 2);
                let response = (corners - 2.0 * edges + 4.0 * p(1, 1)).abs();
                all.push(response);
                if (r - 1..=r + 1).all(|rr| (c - 1..=c + 1).all(|cc| above(cc, rr))) {
                    lifted.push(response);
                }
            }
        }
        let sigma = |v: &mut Vec<f64>| {
            let mid = v.len() / 2;
            1.4826 * *v.select_nth_unstable_by(mid, f64::total_cmp).1 / 6.0
        };
        let floor = sigma(&mut all) / CLIPPED_NOISE_RESPONSE;
        let sigma = if lifted.len() >= 16 { sigma(&mut lifted).min(floor) } else { floor };
        Some(sigma / (hi - lo) as f64)
    }
}

/// The dark level of an image with noise: its background and the standard deviation of its
/// noise, in pixel units, from which a pixel can be judged bright or dark.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Background {
    /// The image's background level: its median, or its 10th percentile plus 1.28 deviations
    /// (where the 10th percentile of Gaussian noise lies; the floor itself when a tenth of the
    /// pixels lie on it, as noise clipped there does) when that is lower, so that an object
    /// covering most of the image is not taken for background.
    pub level: f64,
    /// [`Image::relative_noise`] times the image's range: 0 for a noiseless image.
    pub sigma: f64,
}

impl Image {
    /// The image's [`Background`]; `None` when [`Image::relative_noise`] gives no estimate.
    pub fn background(&self) -> Option<Background> {
        let noise = self.relative_noise()?;
        let (lo, hi) = self.min_max();
        let sigma = noise * (hi - lo) as f64;
        let mut values = self.data.clone();
        let n = values.len();
        let median = *values.select_nth_unstable_by(n / 2, f32::total_cmp).1 as f64;
        let p10 = *values.select_nth_unstable_by(n / 10, f32::total_cmp).1 as f64;
        let low = if p10 <= lo as f64 { p10 } else { p10 + 1.28 * sigma };
        Some(Background { level: median.min(low), sigma })
    }
}

/// The median of several images' noise readings ([`Image::relative_noise`]); `None` for none.
pub fn median_noise(levels: impl IntoIterator<Item = f64>) -> Option<f64> {
    let mut levels: Vec<f64> = levels.into_iter().collect();
    if levels.is_empty() {
        return None;
    }
    levels.sort_by(f64::total_cmp);
    let n = levels.len();
    Some(if n % 2 == 1 { levels[n / 2] } else { 0.5 * (levels[n / 2 - 1] + levels[n / 2]) })
}

/// The robust deviation [`Image::relative_noise`] reads from white noise of deviation 1
/// clipped at zero, `max(0, N(0, 1))`, over every pixel: 0.533 (a 2048² simulation; 0.5331 ±
/// 0.001 between seeds). It turns that reading back into σ.
pub const CLIPPED_NOISE_RESPONSE: f64 = 0.533;

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth bright blob on a black background, scaled to a peak of 1000.
    fn blob(size: usize) -> Image {
        let mut img = Image::zeros(size, size);
        let c = size as f64 / 2.0;
        for r in 0..size {
            for col in 0..size {
                let d2 = ((col as f64 - c).powi(2) + (r as f64 - c).powi(2)) / (size as f64 / 5.0).powi(2);
                img.set(col, r, (1000.0 * (-d2).exp()) as f32);
            }
        }
        img
    }

    /// Deterministic normal deviates (Box–Muller on a 64-bit LCG): the core crate draws no
    /// random numbers elsewhere.
    fn normals(n: usize) -> Vec<f64> {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let (u, v) = (uniform(), uniform());
                (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
            })
            .collect()
    }

    #[test]
    fn relative_noise_recovers_the_added_deviation() {
        let clean = blob(128);
        let clean_level = clean.relative_noise().expect("a blob has usable pixels");
        assert!(clean_level < 0.002, "noiseless blob read as {clean_level}");
        for fraction in [0.01, 0.05] {
            // Noise of σ = fraction × peak, clipped at zero as a sensor clips it, so that most of
            // the background sits exactly on the floor.
            let mut noisy = clean.clone();
            for (p, z) in noisy.data.iter_mut().zip(normals(128 * 128)) {
                *p = (*p as f64 + fraction * 1000.0 * z).max(0.0) as f32;
            }
            let (lo, hi) = noisy.min_max();
            let truth = fraction * 1000.0 / (hi - lo) as f64;
            let level = noisy.relative_noise().expect("usable pixels");
            assert!((level / truth - 1.0).abs() < 0.1, "σ {fraction}: estimated {level}, added {truth}");
        }
    }

    /// A small, sharp object on a background exactly at zero is clean, although its own
    /// structure is all the first estimate sees. Pure noise clipped at zero reads as noisy:
    /// there the pixels above the floor are the positive half of the noise, whose spread is
    /// about 0.6 σ, so it reads low, but within a factor of two.
    #[test]
    fn relative_noise_reads_small_objects_and_clipped_backgrounds() {
        let mut small = Image::zeros(64, 64);
        for r in 0..64 {
            for c in 0..64 {
                let d2 = ((c as f64 - 30.3).powi(2) + (r as f64 - 33.7).powi(2)) / 2.0;
                let v = 1000.0 * (-d2).exp();
                small.set(c, r, if v > 1.0 { v as f32 } else { 0.0 });
            }
        }
        let level = small.relative_noise().expect("readable");
        assert!(level < 1e-3, "a noiseless small object read as {level}");
        let mut noise = Image::zeros(256, 256);
        for (p, z) in noise.data.iter_mut().zip(normals(256 * 256)) {
            *p = (100.0 * z).max(0.0) as f32;
        }
        let (lo, hi) = noise.min_max();
        let truth = 100.0 / (hi - lo) as f64;
        let level = noise.relative_noise().expect("readable");
        assert!(level > 0.5 * truth && level < 1.1 * truth, "clipped noise: estimated {level}, added {truth}");
        assert!(level > NOISY_ABOVE);
    }

    #[test]
    fn relative_noise_refuses_images_it_cannot_read() {
        assert_eq!(Image::zeros(32, 32).relative_noise(), None);
        let mut nan = blob(32);
        nan.set(3, 4, f32::NAN);
        assert_eq!(nan.relative_noise(), None);
        assert_eq!(Image::from_vec(2, 2, vec![0.0, 1.0, 2.0, 3.0]).relative_noise(), None);
        assert_eq!(Image::from_vec(3, 1, vec![0.0, 1.0, 2.0]).relative_noise(), None);
    }
}
