//! A fast, branch-free `sin`/`cos` for the phantoms' Fourier modes and the thin lens's random
//! directions, where 1e-5 absolute accuracy is plenty and the standard library's correctly
//! rounded versions dominated the run time.

use std::f32::consts::TAU;

/// `sin(2π t')` for `t'` in `[−¼, ¼]` (odd Taylor polynomial to degree 11 in `y = 2πt'`,
/// `|y| ≤ π/2`; truncation error below 6e-8).
#[inline(always)]
fn sin_quarter(t: f32) -> f32 {
    let y = TAU * t;
    let y2 = y * y;
    y * (1.0
        + y2 * (-1.0 / 6.0
            + y2 * (1.0 / 120.0 + y2 * (-1.0 / 5040.0 + y2 * (1.0 / 362_880.0 + y2 * (-1.0 / 39_916_800.0))))))
}

/// `sin(2π t)` for a phase `t` in turns, `|t| < 2²²`.
#[inline(always)]
fn sin_turns(t: f32) -> f32 {
    // Round to nearest by the 1.5·2²³ trick: exact for |t| < 2²², and unlike `f32::round` it
    // needs no library call on baseline x86-64, so loops over it vectorise.
    const MAGIC: f32 = 12_582_912.0;
    let t = t - ((t + MAGIC) - MAGIC);
    // Fold [¼, ½] onto [0, ¼] (and the negative side alike): sin(π − y) = sin(y).
    let folded = if t > 0.25 {
        0.5 - t
    } else if t < -0.25 {
        -0.5 - t
    } else {
        t
    };
    sin_quarter(folded)
}

/// `(sin x, cos x)` with absolute error below `1e-6 + 2e-7 |x|` (the f32 range reduction), for
/// `|x| < 2.6e7`.
#[inline(always)]
pub(crate) fn sin_cos(x: f32) -> (f32, f32) {
    let t = x * (1.0 / TAU);
    (sin_turns(t), sin_turns(t + 0.25))
}

#[cfg(test)]
mod tests {
    #[test]
    fn matches_std() {
        for i in -200_000..200_000 {
            let x = i as f32 * 1e-3 + 0.000_37;
            let (s, c) = super::sin_cos(x);
            let err = (s - x.sin()).abs().max((c - x.cos()).abs());
            assert!(err < 1e-6 + 2e-7 * x.abs(), "error {err} at {x}");
        }
    }
}
