//! How numbers are shown in messages.
//!
//! Rust's `{}` writes a floating-point number in full, so a value of 1e300 given where a
//! setting wants 0.5 would come back in a refusal as 301 digits, and 1e-300 as 302. Messages that
//! echo a number write it through [`num`]: as `{}` while that is short, in scientific notation
//! (`{:e}`) beyond.
//!
//! Settings held in 32-bit floats are read from their files through [`f32_setting`], so that a
//! refusal shows the number written rather than the infinity or zero serde would round it to.

use std::fmt;

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// A number as messages show it (see [`num`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Num<T>(pub T);

/// `x` for a message: `0.5`, `250`, `-3.25` as `{}` writes them; `1e300`, `1.5e-7` when the
/// magnitude is 1e16 or more, or below 1e-4 (not zero); `NaN`, `inf` and `-inf` as they are.
pub fn num<T>(x: T) -> Num<T> {
    Num(x)
}

fn long(x: f64) -> bool {
    x.is_finite() && x != 0.0 && !(1e-4..1e16).contains(&x.abs())
}

impl fmt::Display for Num<f64> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if long(self.0) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

impl fmt::Display for Num<f32> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if long(f64::from(self.0)) {
            write!(f, "{:e}", self.0)
        } else {
            write!(f, "{}", self.0)
        }
    }
}

/// The magnitude from which [`fixed`] writes a number in scientific notation.
const FIXED_UP_TO: f64 = 1e9;

/// `x` with `decimals` decimals, as tables write measured values (`{:.N}`), while that is short:
/// from 10⁹ in magnitude in scientific notation with as many decimals (`1.0e308`), so that a
/// value no run gives (a time of 1e308 s read from a file) keeps its column narrow instead of
/// taking 300 digits. `NaN`, `inf` and `-inf` as they are.
pub fn fixed(x: f64, decimals: usize) -> String {
    if x.is_finite() && x.abs() >= FIXED_UP_TO {
        format!("{x:.decimals$e}")
    } else {
        format!("{x:.decimals$}")
    }
}

/// A point or vector as `[x, y, z]`, each coordinate as [`num`] writes it.
impl fmt::Display for Num<[f64; 3]> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.0;
        write!(f, "[{}, {}, {}]", Num(x), Num(y), Num(z))
    }
}

/// Reads an `f32` setting as the number written, for `#[serde(deserialize_with = ...)]`.
/// serde's own `f32` rounds the decimal to the nearest `f32`, so 1e300 became infinity and 1e-50
/// zero, and whatever check followed refused "inf" or "0", a value nobody wrote (or, worse, let
/// the zero pass). A number no `f32` holds, beyond ±[`f32::MAX`] or so small that it would read
/// as 0, is refused here, with the number as written; the caller's error adds the key.
pub fn f32_setting<'de, D: Deserializer<'de>>(d: D) -> Result<f32, D::Error> {
    to_f32(f64::deserialize(d)?).map_err(D::Error::custom)
}

/// [`f32_setting`] for an optional setting.
pub fn optional_f32_setting<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f32>, D::Error> {
    Option::<f64>::deserialize(d)?.map(to_f32).transpose().map_err(D::Error::custom)
}

fn to_f32(x: f64) -> Result<f32, String> {
    let y = x as f32;
    // serde_json's parser may land an ulp off the decimal written (1e-60 as
    // 1.0000000000000001e-60): to the 15 significant digits every f64 keeps, it reads as written.
    let written = || num(format!("{x:.14e}").parse().unwrap_or(x));
    if x.is_finite() && y.is_infinite() {
        return Err(format!(
            "{} is beyond what this setting's 32-bit float holds (at most {:e} in magnitude)",
            written(),
            f32::MAX
        ));
    }
    if x != 0.0 && y == 0.0 {
        return Err(format!(
            "{} is below the smallest non-zero value this setting's 32-bit float holds ({:e}); it would read as 0",
            written(),
            f32::from_bits(1)
        ));
    }
    Ok(y)
}

#[cfg(test)]
mod tests {
    use super::{fixed, num};

    #[derive(serde::Deserialize, Debug)]
    struct Setting {
        #[serde(deserialize_with = "super::f32_setting")]
        v: f32,
        #[serde(default, deserialize_with = "super::optional_f32_setting")]
        o: Option<f32>,
    }

    fn read(text: &str) -> Result<Setting, String> {
        serde_json::from_str(text).map_err(|e| e.to_string())
    }

    /// A setting reads as the number written; one no f32 holds is refused as written, where
    /// serde's own f32 turned it into infinity or zero.
    #[test]
    fn f32_settings_read_as_written_or_are_refused() {
        let s = read(r#"{"v": 0.3, "o": -2.5e-3}"#).expect("reads");
        assert_eq!((s.v, s.o), (0.3f32, Some(-2.5e-3f32)));
        assert_eq!(read(r#"{"v": 0, "o": null}"#).expect("reads").o, None);
        assert_eq!(read(r#"{"v": 3.4e38}"#).expect("reads").v, 3.4e38f32);
        let e = read(r#"{"v": 1e300}"#).expect_err("refused");
        assert!(e.contains("1e300 is beyond what this setting's 32-bit float holds"), "{e}");
        let e = read(r#"{"v": 1, "o": -1e-60}"#).expect_err("refused");
        assert!(e.contains("-1e-60 is below the smallest non-zero value"), "{e}");
    }

    #[test]
    fn fixed_decimals_stay_short() {
        for (x, decimals, shown) in [
            (0.5, 2, "0.50"),
            (12.345, 1, "12.3"),
            (999_999_999.0, 1, "999999999.0"),
            (1e9, 1, "1.0e9"),
            (1e308, 2, "1.00e308"),
            (-2.5e300, 3, "-2.500e300"),
            (1e-300, 4, "0.0000"),
            (f64::INFINITY, 1, "inf"),
            (f64::NAN, 1, "NaN"),
        ] {
            assert_eq!(fixed(x, decimals), shown);
        }
    }

    #[test]
    fn short_numbers_are_written_as_they_are_and_long_ones_in_scientific_notation() {
        for (x, shown) in [
            (0.5, "0.5"),
            (250.0, "250"),
            (-3.25, "-3.25"),
            (0.0, "0"),
            (1e-4, "0.0001"),
            (1e15, "1000000000000000"),
            (1e16, "1e16"),
            (1e300, "1e300"),
            (-1.7e308, "-1.7e308"),
            (1e-300, "1e-300"),
            (1.5e-7, "1.5e-7"),
            (f64::INFINITY, "inf"),
            (f64::NAN, "NaN"),
        ] {
            assert_eq!(num(x).to_string(), shown);
        }
        assert_eq!(num(0.1f32).to_string(), "0.1");
        assert_eq!(num(3e38f32).to_string(), "3e38");
        assert_eq!(num([1.0, -1e300, 0.25]).to_string(), "[1, -1e300, 0.25]");
    }
}
