//! Colour maps: perceptually uniform sequential maps for fields, a diverging map for differences.
//! The tables are those of matplotlib (viridis, magma, inferno, cividis) and ColorBrewer (RdBu),
//! as shipped by the `colorous` crate.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// A colour map from a normalised value `t ∈ [0, 1]` to an sRGB colour.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Colormap {
    /// Dark blue → green → yellow; the default for fields.
    #[default]
    Viridis,
    /// Black → purple → orange → pale yellow; good for glowing media on dark backgrounds.
    Magma,
    /// Black → purple → orange → bright yellow.
    Inferno,
    /// Blue → yellow, readable with colour-vision deficiency.
    Cividis,
    /// Black → white.
    Gray,
    /// Blue (negative) → white (zero) → red (positive), matplotlib's `RdBu_r`: for differences.
    /// Automatic ranges are symmetric about zero.
    Diverging,
}

impl Colormap {
    /// All maps, in the order `--help` lists them.
    pub const ALL: [Colormap; 6] =
        [Colormap::Viridis, Colormap::Magma, Colormap::Inferno, Colormap::Cividis, Colormap::Gray, Colormap::Diverging];

    /// The colour at `t`, clamped to `[0, 1]`; NaN maps to mid grey.
    pub fn rgb(self, t: f64) -> [u8; 3] {
        if t.is_nan() {
            return [128, 128, 128];
        }
        let t = t.clamp(0.0, 1.0);
        let c = match self {
            Colormap::Viridis => colorous::VIRIDIS.eval_continuous(t),
            Colormap::Magma => colorous::MAGMA.eval_continuous(t),
            Colormap::Inferno => colorous::INFERNO.eval_continuous(t),
            Colormap::Cividis => colorous::CIVIDIS.eval_continuous(t),
            Colormap::Gray => colorous::GREYS.eval_continuous(1.0 - t),
            // colorous's RED_BLUE runs red → blue; reversed so that positive is red.
            Colormap::Diverging => colorous::RED_BLUE.eval_continuous(1.0 - t),
        };
        [c.r, c.g, c.b]
    }

    /// The colour of `v` on a bar from `lo` to `hi`, the position computed in f64: in f32,
    /// `hi − lo` of a range such as ±3·10³⁸ overflows, and every value would be NaN's grey.
    pub fn rgb_in(self, v: f32, lo: f32, hi: f32) -> [u8; 3] {
        let span = f64::from(hi) - f64::from(lo);
        let span = if span > 0.0 { span } else { 1.0 };
        self.rgb((f64::from(v) - f64::from(lo)) / span)
    }

    /// Whether automatic value ranges should be symmetric about zero.
    pub fn is_diverging(self) -> bool {
        self == Colormap::Diverging
    }

    /// The name used on the command line and in settings files.
    pub fn name(self) -> &'static str {
        match self {
            Colormap::Viridis => "viridis",
            Colormap::Magma => "magma",
            Colormap::Inferno => "inferno",
            Colormap::Cividis => "cividis",
            Colormap::Gray => "gray",
            Colormap::Diverging => "diverging",
        }
    }
}

impl fmt::Display for Colormap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Colormap {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Colormap::ALL.into_iter().find(|c| c.name().eq_ignore_ascii_case(s)).ok_or_else(|| {
            let names: Vec<_> = Colormap::ALL.iter().map(|c| c.name()).collect();
            format!("unknown colour map {s:?}; expected one of {}", names.join(", "))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ends of a range as wide as f32 allows take the bar's end colours, not NaN's grey.
    #[test]
    fn a_range_wider_than_f32_holds_colours_its_ends() {
        let (lo, hi) = (-3e38f32, 3e38f32);
        for map in Colormap::ALL {
            assert_eq!(map.rgb_in(hi, lo, hi), map.rgb(1.0), "{map:?}");
            assert_eq!(map.rgb_in(lo, lo, hi), map.rgb(0.0), "{map:?}");
            assert_eq!(map.rgb_in(0.0, lo, hi), map.rgb(0.5), "{map:?}");
            assert_eq!(map.rgb_in(f32::NAN, lo, hi), [128; 3], "{map:?}");
        }
        assert_eq!(Colormap::Gray.rgb_in(2.5, 2.0, 3.0), Colormap::Gray.rgb(0.5));
    }

    fn luminance(c: [u8; 3]) -> f64 {
        0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
    }

    #[test]
    fn sequential_maps_brighten_monotonically() {
        for map in [Colormap::Viridis, Colormap::Magma, Colormap::Inferno, Colormap::Cividis, Colormap::Gray] {
            let l: Vec<f64> = (0..=20).map(|i| luminance(map.rgb(i as f64 / 20.0))).collect();
            assert!(l.windows(2).all(|w| w[1] >= w[0] - 1.0), "{map}: {l:?}");
        }
    }

    #[test]
    fn diverging_is_blue_white_red() {
        let lo = Colormap::Diverging.rgb(0.0);
        let mid = Colormap::Diverging.rgb(0.5);
        let hi = Colormap::Diverging.rgb(1.0);
        assert!(lo[2] > lo[0], "negative end is blue: {lo:?}");
        assert!(hi[0] > hi[2], "positive end is red: {hi:?}");
        assert!(mid.iter().all(|&c| c > 230), "zero is near white: {mid:?}");
    }

    #[test]
    fn names_round_trip() {
        for map in Colormap::ALL {
            assert_eq!(map.name().parse::<Colormap>(), Ok(map));
        }
        assert!("jet".parse::<Colormap>().is_err());
    }
}
