//! How numbers are shown in messages.
//!
//! Rust's `{}` writes a floating-point number in full, so a value of 1e300 given where a
//! setting wants 0.5 would come back in a refusal as 301 digits, and 1e-300 as 302. Messages that
//! echo a number write it through [`num`]: as `{}` while that is short, in scientific notation
//! (`{:e}`) beyond.

use std::fmt;

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

/// A point or vector as `[x, y, z]`, each coordinate as [`num`] writes it.
impl fmt::Display for Num<[f64; 3]> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.0;
        write!(f, "[{}, {}, {}]", Num(x), Num(y), Num(z))
    }
}

#[cfg(test)]
mod tests {
    use super::num;

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
