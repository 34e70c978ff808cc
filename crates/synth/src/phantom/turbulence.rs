//! Kinematic simulation of turbulence (Fung, Hunt, Malik & Perkins 1992, J. Fluid Mech. 236):
//! a seeded sum of random Fourier modes with a prescribed spectrum, used by the jet phantoms for
//! broadband, multi-scale content.
//!
//! Mode `n` has wavenumber `κ_n k̂_n` (isotropic random direction), phase `φ_n`, a displacement
//! amplitude vector `a_n ⊥ k̂_n` (so the displacement field is divergence-free, like the
//! velocity field it stands for) and a scalar amplitude `c_n`:
//!
//! ```text
//! d(q) = Σ a_n sin(κ_n k̂_n·q + φ_n)      (displacement, rms |d| = 1)
//! m(q) = Σ c_n cos(κ_n k̂_n·q + φ_n)      (scalar fluctuation, rms m = 1)
//! ```
//!
//! The `κ_n` are log-uniformly stratified over `[κ_min, κ_min 2^octaves]`. For a −5/3
//! (Kolmogorov / Obukhov–Corrsin) spectrum `E(κ) ∝ κ^{−5/3}`, a mode standing for the band
//! `Δκ ∝ κ` carries variance `∝ κ^{−2/3}`: so `c_n ∝ κ_n^{−1/3}`, and the displacement, a
//! velocity `u_κ ∝ κ^{−1/3}` acting for an eddy turnover time `τ_κ ∝ κ^{−2/3}`, has
//! `|a_n| ∝ κ_n^{−1}`.

use fluidnerf_core::glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, UnitSphere};

/// A frozen random-mode turbulence field (structure of arrays for the hot loop).
#[derive(Clone, Debug)]
pub(crate) struct KinematicModes {
    kx: Vec<f32>,
    ky: Vec<f32>,
    kz: Vec<f32>,
    phase: Vec<f32>,
    ax: Vec<f32>,
    ay: Vec<f32>,
    az: Vec<f32>,
    c: Vec<f32>,
    /// An upper bound of |d(q)| over all q (Σ |a_n|).
    pub disp_bound: f32,
}

impl KinematicModes {
    pub fn new(count: usize, kappa_min: f64, octaves: f64, seed: u64) -> Self {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut m = KinematicModes {
            kx: Vec::with_capacity(count),
            ky: Vec::with_capacity(count),
            kz: Vec::with_capacity(count),
            phase: Vec::with_capacity(count),
            ax: Vec::with_capacity(count),
            ay: Vec::with_capacity(count),
            az: Vec::with_capacity(count),
            c: Vec::with_capacity(count),
            disp_bound: 0.0,
        };
        let (mut sum_a2, mut sum_c2) = (0.0f64, 0.0f64);
        let mut amps = Vec::with_capacity(count);
        for n in 0..count {
            let frac = (n as f64 + rng.random::<f64>()) / count.max(1) as f64;
            let kappa = kappa_min * (octaves * frac).exp2();
            let dir: [f64; 3] = UnitSphere.sample(&mut rng);
            let k = fluidnerf_core::glam::DVec3::from(dir);
            // A random unit vector perpendicular to k.
            let r: [f64; 3] = UnitSphere.sample(&mut rng);
            let mut a = fluidnerf_core::glam::DVec3::from(r).cross(k);
            if a.length_squared() < 1e-12 {
                a = k.any_orthonormal_vector();
            }
            let a = a.normalize() / kappa;
            let c = kappa.powf(-1.0 / 3.0);
            sum_a2 += a.length_squared();
            sum_c2 += c * c;
            let kk = k * kappa;
            m.kx.push(kk.x as f32);
            m.ky.push(kk.y as f32);
            m.kz.push(kk.z as f32);
            m.phase.push(rng.random_range(0.0..std::f64::consts::TAU) as f32);
            amps.push((a, c));
        }
        // rms of Σ x_n sin(·) with independent phases is sqrt(Σ x_n² / 2).
        let na = if sum_a2 > 0.0 { (sum_a2 / 2.0).sqrt() } else { 1.0 };
        let nc = if sum_c2 > 0.0 { (sum_c2 / 2.0).sqrt() } else { 1.0 };
        for (a, c) in amps {
            let a = a / na;
            m.ax.push(a.x as f32);
            m.ay.push(a.y as f32);
            m.az.push(a.z as f32);
            m.c.push((c / nc) as f32);
            m.disp_bound += a.length() as f32;
        }
        while !m.kx.len().is_multiple_of(LANES) {
            for v in [&mut m.kx, &mut m.ky, &mut m.kz, &mut m.phase, &mut m.ax, &mut m.ay, &mut m.az, &mut m.c] {
                v.push(0.0);
            }
        }
        m
    }

    /// Displacement `d(q)` and scalar fluctuation `m(q)` (see the module docs).
    #[inline(always)]
    pub fn eval(&self, q: Vec3) -> (Vec3, f32) {
        // Lane-wise accumulation over blocks of LANES modes, so the compiler can vectorise the
        // loop (a single running sum would serialise it); the tail is padded with zero modes.
        let mut dx = [0.0f32; LANES];
        let mut dy = [0.0f32; LANES];
        let mut dz = [0.0f32; LANES];
        let mut sc = [0.0f32; LANES];
        let blocks = self.kx.len() / LANES;
        for b in 0..blocks {
            let r = b * LANES..(b + 1) * LANES;
            let (kx, ky, kz, ph) =
                (&self.kx[r.clone()], &self.ky[r.clone()], &self.kz[r.clone()], &self.phase[r.clone()]);
            let (ax, ay, az, c) = (&self.ax[r.clone()], &self.ay[r.clone()], &self.az[r.clone()], &self.c[r]);
            for l in 0..LANES {
                let arg = kx[l] * q.x + ky[l] * q.y + kz[l] * q.z + ph[l];
                let (sn, cs) = crate::fastmath::sin_cos(arg);
                dx[l] += ax[l] * sn;
                dy[l] += ay[l] * sn;
                dz[l] += az[l] * sn;
                sc[l] += c[l] * cs;
            }
        }
        let sum = |a: [f32; LANES]| a.iter().sum::<f32>();
        (Vec3::new(sum(dx), sum(dy), sum(dz)), sum(sc))
    }
}

/// Modes per vectorised block.
const LANES: usize = 8;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn structure_function_follows_two_thirds_law() {
        // κ from 2π/2.5 to 2⁵ times that: wavelengths 2.5 … 0.078. In the middle of that range
        // S₂(ℓ) = <(m(q + ℓ e) − m(q))²> ∝ ℓ^{2/3} (the −5/3 spectrum).
        let m = KinematicModes::new(64, std::f64::consts::TAU / 2.5, 5.0, 11);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(4);
        let starts: Vec<Vec3> = (0..4000)
            .map(|_| Vec3::new(rng.random_range(0.0..50.0), rng.random_range(0.0..50.0), rng.random_range(0.0..50.0)))
            .collect();
        let lags = [0.12f32, 0.17, 0.24, 0.34, 0.48];
        let pts: Vec<(f64, f64)> = lags
            .iter()
            .map(|&l| {
                let s2 = starts
                    .iter()
                    .map(|&q| ((m.eval(q + Vec3::new(l, 0.0, 0.0)).1 - m.eval(q).1) as f64).powi(2))
                    .sum::<f64>()
                    / starts.len() as f64;
                ((l as f64).ln(), s2.ln())
            })
            .collect();
        let n = pts.len() as f64;
        let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
        let slope = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
            / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();
        assert!((slope - 2.0 / 3.0).abs() < 0.15, "S₂ slope {slope}, expected 2/3");
    }

    #[test]
    fn normalised_and_divergence_free() {
        let m = KinematicModes::new(64, 2.0, 5.0, 3);
        let (mut d2, mut s2, mut n) = (0.0f64, 0.0f64, 0usize);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(9);
        for _ in 0..20_000 {
            let q = Vec3::new(rng.random_range(0.0..40.0), rng.random_range(0.0..40.0), rng.random_range(0.0..40.0));
            let (d, s) = m.eval(q);
            d2 += d.length_squared() as f64;
            s2 += (s * s) as f64;
            n += 1;
        }
        let (rd, rs) = ((d2 / n as f64).sqrt(), (s2 / n as f64).sqrt());
        assert!((rd - 1.0).abs() < 0.1, "rms displacement {rd}");
        assert!((rs - 1.0).abs() < 0.1, "rms scalar {rs}");
        // Central-difference divergence is small compared with the gradient magnitude.
        let h = 1e-3f32;
        let q = Vec3::new(1.3, 2.1, -0.7);
        let div = (m.eval(q + Vec3::X * h).0.x - m.eval(q - Vec3::X * h).0.x + m.eval(q + Vec3::Y * h).0.y
            - m.eval(q - Vec3::Y * h).0.y
            + m.eval(q + Vec3::Z * h).0.z
            - m.eval(q - Vec3::Z * h).0.z)
            / (2.0 * h);
        let grad = (m.eval(q + Vec3::X * h).0.y - m.eval(q - Vec3::X * h).0.y) / (2.0 * h);
        assert!(div.abs() < 0.05 * grad.abs().max(0.1), "divergence {div} vs gradient {grad}");
    }
}
