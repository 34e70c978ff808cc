//! Positional (frequency) encoding with the identity term, dissertation Eq. 5.2:
//!
//! γ(τ) = [τ, sin(2⁰πτ), cos(2⁰πτ), …, sin(2^{L−1}πτ), cos(2^{L−1}πτ)]
//!
//! applied to each input coordinate separately, `L_x` frequencies for the spatial coordinates
//! and `L_t` for time (Table 5.2: `L_t = 0`, time enters through the identity term only).
//!
//! # Conventions
//! - Spatial inputs are box-normalised `u ∈ [0, 1]` (`Aabb::to_unit`) and are mapped to
//!   `τ = 2u − 1 ∈ [−1, 1]` before encoding, as NeRF does for its normalised scenes: the lowest
//!   frequency then spans one full period across the box (with `[0, 1]` it would span half a
//!   period and `cos(πτ)` alone would carry the coarse position), the encoding is centred on
//!   the box centre, and the highest default frequency (`L = 8`: 2⁷π) resolves 1/256 of the
//!   box, the size of a voxel of the volumes we reconstruct.
//! - The time input is the frame time `t' = t / Δt` (chapter 5.2) and is encoded as is.
//! - Output rows are laid out coordinate by coordinate: for x, `[τ, sin f₀, cos f₀, sin f₁, …]`,
//!   then y, then z, then t. Row width `3 (1 + 2 L_x) [+ 1 + 2 L_t]`.
//! - Phases are reduced exactly in f32 (`2^k τ` is exact; subtracting the nearest even integer
//!   is exact) before `sin`/`cos`, so high frequencies keep full f32 accuracy.

/// The positional encoding of Eq. 5.2 for 3D (`x, y, z`) or 4D (`x, y, z, t'`) inputs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PositionalEncoding {
    input_dim: usize,
    space_freqs: usize,
    time_freqs: usize,
}

impl PositionalEncoding {
    /// `input_dim` is 3 or 4; `space_freqs` is `L_x`, `time_freqs` is `L_t` (ignored for 3D).
    pub fn new(input_dim: usize, space_freqs: usize, time_freqs: usize) -> Self {
        assert!(input_dim == 3 || input_dim == 4, "PositionalEncoding: input_dim must be 3 or 4, got {input_dim}");
        Self { input_dim, space_freqs, time_freqs }
    }

    pub fn input_dim(&self) -> usize {
        self.input_dim
    }

    /// Width of an encoded row.
    pub fn output_dim(&self) -> usize {
        let space = 3 * (1 + 2 * self.space_freqs);
        if self.input_dim == 4 {
            space + 1 + 2 * self.time_freqs
        } else {
            space
        }
    }

    /// Encodes `inputs` (`n × input_dim`) into `out` (`n × output_dim`).
    pub fn encode(&self, inputs: &[f32], out: &mut [f32]) {
        let d = self.input_dim;
        let w = self.output_dim();
        assert_eq!(inputs.len() % d, 0, "PositionalEncoding: inputs not a multiple of {d}");
        let n = inputs.len() / d;
        assert_eq!(out.len(), n * w, "PositionalEncoding: out must hold {n}×{w} values");
        for (row, enc) in inputs.chunks_exact(d).zip(out.chunks_exact_mut(w)) {
            let mut o = 0;
            for (c, &u) in row.iter().enumerate() {
                let (tau, freqs) = if c < 3 { (2.0 * u - 1.0, self.space_freqs) } else { (u, self.time_freqs) };
                enc[o] = tau;
                o += 1;
                let mut p = tau;
                for _ in 0..freqs {
                    let (s, co) = sin_cos_pi(p);
                    enc[o] = s;
                    enc[o + 1] = co;
                    o += 2;
                    p *= 2.0;
                }
            }
        }
    }
}

/// `(sin πp, cos πp)` with the phase reduced exactly to `[−1, 1]` first.
#[inline]
fn sin_cos_pi(p: f32) -> (f32, f32) {
    let r = p - 2.0 * (0.5 * p).round();
    (std::f32::consts::PI * r).sin_cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_eq_5_2_in_f64() {
        let pe = PositionalEncoding::new(4, 6, 2);
        assert_eq!(pe.output_dim(), 3 * 13 + 5);
        let inputs = [0.1f32, 0.77, 0.999, 3.25, 0.0, 0.5, 1.0, 0.0];
        let mut out = vec![0.0; 2 * pe.output_dim()];
        pe.encode(&inputs, &mut out);
        for (row, enc) in inputs.chunks(4).zip(out.chunks(pe.output_dim())) {
            let mut o = 0;
            for (c, &u) in row.iter().enumerate() {
                // τ itself is rounded to f32; the test checks the accuracy of the phases.
                let (tau, l) = if c < 3 { ((2.0 * u - 1.0) as f64, 6) } else { (u as f64, 2) };
                assert!((enc[o] as f64 - tau).abs() < 1e-6);
                o += 1;
                for k in 0..l {
                    let ph = 2f64.powi(k) * std::f64::consts::PI * tau;
                    assert!((enc[o] as f64 - ph.sin()).abs() < 2e-6, "sin k={k} c={c}");
                    assert!((enc[o + 1] as f64 - ph.cos()).abs() < 2e-6, "cos k={k} c={c}");
                    o += 2;
                }
            }
        }
    }
}
