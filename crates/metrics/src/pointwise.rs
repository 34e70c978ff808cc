//! Point-wise error measures: NRMSE (dissertation Eq. 6.18), MSE and PSNR.
//!
//! All functions take two equally long f32 slices, the estimate (the reconstruction, `E`) and
//! the truth (`Ê`), in any layout (they compare element `i` with element `i`), and accumulate
//! in f64.

/// Why an NRMSE is undefined when [`nrmse`] returns NaN: reports give it next to the
/// missing value (`null` in JSON).
pub const NRMSE_UNDEFINED: &str = "the truth is zero throughout, and NRMSE divides by its energy";

/// [`NRMSE_UNDEFINED`] when `nrmse` is NaN (undefined), else `None`.
pub fn nrmse_undefined(nrmse: f64) -> Option<String> {
    nrmse.is_nan().then(|| NRMSE_UNDEFINED.to_string())
}

/// Normalised root-mean-square error, dissertation Eq. 6.18:
///
/// `ε₂(E, Ê) = sqrt( Σⱼ (Eⱼ − Êⱼ)² / Σⱼ Êⱼ² )`
///
/// with `E` the estimate and `Ê` the truth (so the normalisation is by the truth's energy and
/// the measure is not symmetric). 0 is perfect; an all-zero estimate scores 1. Returns NaN when
/// the truth is all zero (the ratio is undefined: [`NRMSE_UNDEFINED`]). Panics if the lengths
/// differ.
pub fn nrmse(estimate: &[f32], truth: &[f32]) -> f64 {
    assert_eq!(estimate.len(), truth.len(), "nrmse: estimate and truth differ in length");
    let (err, energy) = estimate.iter().zip(truth).fold((0f64, 0f64), |(err, energy), (&e, &t)| {
        let d = e as f64 - t as f64;
        (err + d * d, energy + t as f64 * t as f64)
    });
    if energy == 0.0 {
        return f64::NAN;
    }
    (err / energy).sqrt()
}

/// Mean squared error `Σⱼ (Eⱼ − Êⱼ)² / N`. Returns NaN for empty slices; panics if the lengths
/// differ.
pub fn mse(estimate: &[f32], truth: &[f32]) -> f64 {
    assert_eq!(estimate.len(), truth.len(), "mse: estimate and truth differ in length");
    if truth.is_empty() {
        return f64::NAN;
    }
    let sum: f64 = estimate
        .iter()
        .zip(truth)
        .map(|(&e, &t)| {
            let d = e as f64 - t as f64;
            d * d
        })
        .sum();
    sum / truth.len() as f64
}

/// Peak signal-to-noise ratio in decibels, `PSNR = 10 log₁₀(R² / MSE)` with `R` the data range
/// (as `skimage.metrics.peak_signal_noise_ratio`). +∞ for identical inputs. Panics if the
/// lengths differ or `data_range` is not positive.
///
/// Computed as `20 log₁₀ R − 10 log₁₀ MSE`: `R²` underflowed to 0 for `R` below about 1e-154
/// (PSNR −∞) and overflowed for `R` above about 1e154 (+∞), while the PSNR itself is a modest
/// finite number of decibels for every positive finite `R` (the MSE of f32 values lies between
/// about 1e-90 and 1e78), so it is given rather than refused.
pub fn psnr(estimate: &[f32], truth: &[f32], data_range: f64) -> f64 {
    assert!(data_range > 0.0, "psnr: data_range must be positive, got {data_range}");
    let m = mse(estimate, truth);
    20.0 * data_range.log10() - 10.0 * m.log10()
}

/// The truth's value range `max − min` (the default data range of PSNR and SSIM), or 1 when the
/// truth is constant or empty so that the metrics stay defined.
pub fn data_range_of(truth: &[f32]) -> f64 {
    let (lo, hi) = truth
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let r = hi as f64 - lo as f64;
    if r > 0.0 && r.is_finite() {
        r
    } else {
        1.0
    }
}

/// The widest data range: more than any two f32 values differ by (`2 × f32::MAX`, about
/// 6.8e38), no two values compared are that far apart.
pub const MAX_DATA_RANGE: f64 = 2.0 * f32::MAX as f64;

/// What is wrong with the data range `r` of PSNR and SSIM with the SSIM constants `ks` (K₁, K₂;
/// `[0.0, 0.0]` for PSNR alone), if anything, as the end of a sentence that names it:
/// - not positive and finite;
/// - wider than [`MAX_DATA_RANGE`];
/// - so small that SSIM's constants `c₁ = (K₁ R)²` and `c₂ = (K₂ R)²` (those of `K` above 0)
///   multiply to less than the smallest normal f64 (about 2.2e-308; `R` below about 7e-76
///   with the default K's), where SSIM computes `c₁c₂ / c₁c₂` over flat parts of the arrays
///   and got 0/0: NaN, or a meaningless score. SSIM is defined by its constants, so no finite
///   answer stands in for them. (PSNR takes any positive range: [`psnr`].)
///
/// The default range (the truth's `max − min`, [`data_range_of`]) always passes.
pub fn data_range_problem(r: f64, ks: [f64; 2]) -> Option<String> {
    let shown = fluidnerf_core::num(r);
    if !(r > 0.0 && r.is_finite()) {
        return Some(format!("must be positive, got {shown}"));
    }
    if r > MAX_DATA_RANGE {
        return Some(format!(
            "{shown} is more than any two float32 values differ by ({MAX_DATA_RANGE:e}); give the range of the values \
             compared"
        ));
    }
    let constants: Vec<f64> = ks.iter().filter(|&&k| k > 0.0).map(|&k| (k * r).powi(2)).collect();
    let product: f64 = constants.iter().product();
    if !constants.is_empty() && product < f64::MIN_POSITIVE {
        return Some(format!(
            "{shown} is so small that SSIM's constants (K₁ R)² and (K₂ R)² vanish in double precision (their \
             product is below {:e}), and SSIM would divide zero by zero where the arrays are flat; give the range \
             of the values compared",
            f64::MIN_POSITIVE
        ));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn nrmse_by_hand() {
        // Σ(E−Ê)² = 0.25 + 0 + 1 + 0.25 = 1.5; ΣÊ² = 1 + 4 + 9 + 0 = 14.
        let e = [1.5f32, 2.0, 2.0, 0.5];
        let t = [1.0f32, 2.0, 3.0, 0.0];
        assert_relative_eq!(nrmse(&e, &t), (1.5f64 / 14.0).sqrt(), epsilon = 1e-12);
        assert_eq!(nrmse(&t, &t), 0.0);
        assert_relative_eq!(nrmse(&[0.0; 4], &t), 1.0);
        // Normalised by the truth, hence asymmetric.
        assert!((nrmse(&t, &e) - nrmse(&e, &t)).abs() > 1e-3);
        assert!(nrmse(&e, &[0.0; 4]).is_nan());
    }

    #[test]
    fn psnr_by_hand() {
        // MSE = 1.5 / 4 = 0.375; R = 3.
        let e = [1.5f32, 2.0, 2.0, 0.5];
        let t = [1.0f32, 2.0, 3.0, 0.0];
        assert_relative_eq!(mse(&e, &t), 0.375, epsilon = 1e-12);
        assert_relative_eq!(psnr(&e, &t, 3.0), 10.0 * (9.0f64 / 0.375).log10(), epsilon = 1e-12);
        assert_relative_eq!(data_range_of(&t), 3.0);
        assert_eq!(psnr(&t, &t, 1.0), f64::INFINITY);
        // Halving the error gains 20 log10(2) dB.
        let half: Vec<f32> = e.iter().zip(&t).map(|(&a, &b)| b + 0.5 * (a - b)).collect();
        assert_relative_eq!(psnr(&half, &t, 3.0) - psnr(&e, &t, 3.0), 20.0 * 2f64.log10(), epsilon = 1e-9);
    }

    /// `R²` underflowed for a tiny data range (PSNR −∞) and overflowed for a huge one (+∞); the
    /// PSNR of such ranges is finite, and so is the answer.
    #[test]
    fn psnr_of_tiny_and_huge_data_ranges_is_finite() {
        // MSE = 0.375 as above.
        let e = [1.5f32, 2.0, 2.0, 0.5];
        let t = [1.0f32, 2.0, 3.0, 0.0];
        let by_hand = |r: f64| 20.0 * r.log10() - 10.0 * 0.375f64.log10();
        for r in [1e-300, 1e-160, 1e160, 1e300, f64::MIN_POSITIVE, f64::MAX] {
            let p = psnr(&e, &t, r);
            assert!(p.is_finite(), "R {r:e}: {p}");
            assert_relative_eq!(p, by_hand(r), max_relative = 1e-12);
        }
        assert_relative_eq!(psnr(&e, &t, 1e-300), -6000.0 + 4.259687322722811, max_relative = 1e-12);
        // The smallest and largest errors of f32 values stay finite too.
        let tiny = [f32::from_bits(1), 0.0];
        assert!(psnr(&tiny, &[0.0, 0.0], 1e-300).is_finite());
        assert!(psnr(&[f32::MAX, -f32::MAX], &[-f32::MAX, f32::MAX], 1e300).is_finite());
        // NRMSE divides the f64 sums of f32 squares: at the f32 extremes it stays finite and exact.
        assert_relative_eq!(nrmse(&[f32::MAX, 0.0], &[-f32::MAX, 0.0]), 2.0, max_relative = 1e-12);
        assert_relative_eq!(nrmse(&[0.0], &tiny[..1]), 1.0, max_relative = 1e-12);
    }

    /// Every way a data range is refused, and the ranges SSIM can use.
    #[test]
    fn data_ranges_are_refused_with_their_reason() {
        let ks = [0.01, 0.03];
        for r in [0.0, -2.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let why = data_range_problem(r, ks).expect("refused");
            assert!(why.starts_with("must be positive, got"), "{r}: {why}");
        }
        let why = data_range_problem(MAX_DATA_RANGE * 2.0, ks).expect("refused");
        assert!(why.contains("more than any two float32 values differ by"), "{why}");
        let why = data_range_problem(1e-80, ks).expect("refused");
        assert!(why.contains("SSIM's constants"), "{why}");
        // Without constants (K₁ = K₂ = 0) a tiny range divides nothing by zero.
        assert_eq!(data_range_problem(1e-80, [0.0, 0.0]), None);
        for r in [1e-60, 1.0, MAX_DATA_RANGE] {
            assert_eq!(data_range_problem(r, ks), None, "{r}");
        }
    }

    #[test]
    fn constant_truth_has_unit_range() {
        assert_eq!(data_range_of(&[2.0; 5]), 1.0);
        assert_eq!(data_range_of(&[]), 1.0);
    }
}
