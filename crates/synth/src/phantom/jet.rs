//! `jet`: a procedural, statistically steady turbulent round jet of a passive scalar.
//!
//! # Conventions
//! World units (mm). The jet issues along **+x** from a round nozzle of diameter `D` centred on
//! the `x = aabb.min.x` face of the box (by default), so `ξ = x − x_nozzle` is the distance
//! downstream and `r`, `ϑ` are the radius and azimuth around the axis. Values are a
//! nozzle-fluid mixture fraction in `[0, 1]` (1 = pure jet fluid), zero outside a finite
//! envelope, so "non-zero voxels" is meaningful for the thin-lens renderer.
//!
//! # Model (what it mimics and why)
//! The dissertation's ground truth was a DNS of a Re = 5000 round jet (§6.1: `D = 2.36` mm, a
//! laminar top-hat near field, a transition with large asymmetric structures, a multi-scale
//! turbulent far field). This phantom builds the same three regions from textbook jet physics
//! (Pope, *Turbulent Flows*, ch. 5; Mi, Nobes & Nathan 2001 for the scalar field):
//!
//! 1. **Mean field.** A top-hat of radius `R = D/2` with a thin tanh edge of thickness
//!    `δ(ξ) = D (edge_thickness_d + 0.02 ξ/D)` (laminar shear layer) blends, between
//!    `0.7 L_c` and the end of the transition `L_t`, into the self-similar Gaussian profile
//!    `exp(−ln2 r²/b²)` with half-width `b = S ξ` (linear spreading, rate `S ≈ 0.11` for the
//!    scalar). The centreline value is `C_c = (1 + (ξ/L_c)⁶)^{−1/6}`: 1 in the potential core
//!    and `L_c/ξ` downstream (the `1/x` decay with decay constant `K = L_c/D`, 5.5 by default,
//!    measured values 4.5–5.5). The profile is tapered to exactly zero at
//!    `r_cut = max(R + 6δ, 2.6 b)`.
//! 2. **Kelvin–Helmholtz roll-up.** Shear-layer vortices are modelled by their effect on the
//!    scalar: a point-vortex-like *twist map* in the meridional `(ξ, r)` plane rotates points
//!    about each vortex centre by `φ = Φ (1 − ρ²/ρ_s²)³` for `ρ < ρ_s = λ/2` (area-preserving,
//!    like advection by a vortex). Vortices are spaced by a wavelength `λ(ξ) = λ₀ + g (ξ − ξ_r)`
//!    that grows downstream (pairing), appear at `ξ_r = rollup_start_d D` and sit at radius
//!    `max(R, b)`. Two trains are superposed: the axisymmetric mode (`m = 0`, twist
//!    `rollup_twist`, its rings tilted and dented by `m = 1, 2, 3` azimuthal distortions of
//!    relative size `asymmetry`) and the helical mode (`m = 1`, twist `helical_twist`). Their
//!    strength fades to zero over `L_t ± L_c/4` as the coherent structures break down into
//!    turbulence.
//! 3. **Turbulence.** From `L_c` to `L_t` a kinematic-simulation field (see `turbulence`) with a
//!    −5/3 spectrum over `inertial_octaves` octaves, evaluated in self-similar coordinates
//!    `(ln(ξ/D)/S, y/b, z/b)` so that eddies grow in proportion to the local width (the largest
//!    ≈ 2.5 b), displaces the sampling point by `wrinkle · b` rms (wrinkled, intermittent
//!    edges, engulfed ambient fluid) and modulates the scalar by a factor
//!    `1 + scalar_fluctuation · m` (centreline rms fluctuation ≈ 20–25 % of the mean in real
//!    jets). The result is clamped to `[0, 1]`.
//!
//! With the defaults and the 40 mm box, `D = 40/(3 · 5.5) = 2.42` mm (close to the DNS's
//! 2.36 mm), so the laminar core, the transition and the turbulent region each fill about a
//! third of the box. Everything random derives from the seed.

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::num;
use fluidnerf_core::{Aabb, ScalarField};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::turbulence::KinematicModes;
use crate::SynthError;

/// Most random Fourier modes of the jet's turbulence ([`JetParams::turbulence_modes`]).
pub const MAX_TURBULENCE_MODES: usize = 4096;

/// Widest −5/3 range of the jet's turbulence, octaves ([`JetParams::inertial_octaves`]).
pub const MAX_INERTIAL_OCTAVES: f64 = 20.0;

/// Largest value of a jet parameter given in nozzle diameters, in speeds of `U`, in radians or
/// as a rate (here and in the starting jet's): far beyond any jet's (the defaults lie between
/// 0.03 and 11), and small enough that the phantom, evaluated in f32, stays finite: 10³⁰⁰ made
/// every image NaN.
pub const MAX_JET_PARAMETER: f64 = 1000.0;

/// Largest nozzle diameter, mm (a kilometre): beyond it the phantom's f32 coordinates overflow.
pub const MAX_NOZZLE_DIAMETER_MM: f64 = 1e6;

/// Smallest value of a jet parameter that must be positive (a length in nozzle diameters, a
/// speed, a rate or a time, here and in the starting jet's): far below any jet's (the defaults
/// lie between 0.03 and 11), and far above 32-bit floats' smallest normal number (about 1e-38):
/// lengths of 1e-40 rounded to zero or lost their precision in the phantom's f32 arithmetic, and
/// the images held NaN.
pub const MIN_JET_PARAMETER: f64 = 1e-3;

/// Smallest nozzle diameter, mm (a micrometre, finer than any jet's scalar field is imaged): the
/// phantom divides by it in f32, and 1e-45 mm rounded to zero and made every image NaN.
pub const MIN_NOZZLE_DIAMETER_MM: f64 = 1e-3;

/// Parameters of the [`Jet`] phantom; lengths with suffix `_d` are in nozzle diameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct JetParams {
    /// Nozzle diameter `D` in mm. Default: the box's x length / (3 · `core_length_d`), so each
    /// region fills a third of the box.
    pub nozzle_diameter_mm: Option<f64>,
    /// Length of the potential core `L_c` (and the centreline decay constant). Default 5.5.
    pub core_length_d: f64,
    /// End of the transition region `L_t`. Default 11 (twice the core).
    pub transition_end_d: f64,
    /// Spreading rate `S = db/dξ` of the scalar half-width. Default 0.11.
    pub spreading_rate: f64,
    /// Edge (shear-layer) thickness at the nozzle. Default 0.03.
    pub edge_thickness_d: f64,
    /// Where the first Kelvin–Helmholtz vortices have rolled up. Default 2.5.
    pub rollup_start_d: f64,
    /// Initial roll-up wavelength λ₀. Default 1.2.
    pub rollup_wavelength_d: f64,
    /// Growth of the wavelength per unit distance (vortex pairing), `g`. Default 0.15.
    pub pairing_growth: f64,
    /// Peak twist of the axisymmetric roll-up, radians. Default 2.5.
    pub rollup_twist: f64,
    /// Peak twist of the helical roll-up, radians. Default 1.2.
    pub helical_twist: f64,
    /// Azimuthal distortion of the rings, in wavelengths. Default 0.12.
    pub asymmetry: f64,
    /// Number of random Fourier modes of the turbulence, at most [`MAX_TURBULENCE_MODES`].
    /// Default 64.
    pub turbulence_modes: usize,
    /// Width of the −5/3 range, in octaves below the largest eddy (2.5 b), at most
    /// [`MAX_INERTIAL_OCTAVES`]. Default 5.
    pub inertial_octaves: f64,
    /// rms displacement of the turbulence, in local half-widths b. Default 0.3.
    pub wrinkle: f64,
    /// rms relative scalar fluctuation of the turbulence. Default 0.25.
    pub scalar_fluctuation: f64,
}

impl Default for JetParams {
    fn default() -> Self {
        JetParams {
            nozzle_diameter_mm: None,
            core_length_d: 5.5,
            transition_end_d: 11.0,
            spreading_rate: 0.11,
            edge_thickness_d: 0.03,
            rollup_start_d: 2.5,
            rollup_wavelength_d: 1.2,
            pairing_growth: 0.15,
            rollup_twist: 2.5,
            helical_twist: 1.2,
            asymmetry: 0.12,
            turbulence_modes: 64,
            inertial_octaves: 5.0,
            wrinkle: 0.3,
            scalar_fluctuation: 0.25,
        }
    }
}

impl JetParams {
    /// Checks ranges, naming the key (`phantom.jet.…`) in messages: every parameter at most
    /// [`MAX_JET_PARAMETER`] (the nozzle diameter [`MAX_NOZZLE_DIAMETER_MM`]), and those that
    /// must be positive at least [`MIN_JET_PARAMETER`] (the nozzle diameter
    /// [`MIN_NOZZLE_DIAMETER_MM`]).
    pub fn validate(&self) -> Result<(), SynthError> {
        let positive = [
            ("core_length_d", self.core_length_d),
            ("spreading_rate", self.spreading_rate),
            ("edge_thickness_d", self.edge_thickness_d),
            ("rollup_wavelength_d", self.rollup_wavelength_d),
        ];
        for (name, v) in positive {
            if !(MIN_JET_PARAMETER..=MAX_JET_PARAMETER).contains(&v) {
                return Err(SynthError::invalid(
                    format!("phantom.jet.{name}"),
                    format!("must be between {MIN_JET_PARAMETER} and {MAX_JET_PARAMETER}, got {}", num(v)),
                ));
            }
        }
        let non_negative = [
            ("rollup_start_d", self.rollup_start_d),
            ("pairing_growth", self.pairing_growth),
            ("rollup_twist", self.rollup_twist),
            ("helical_twist", self.helical_twist),
            ("asymmetry", self.asymmetry),
            ("wrinkle", self.wrinkle),
            ("scalar_fluctuation", self.scalar_fluctuation),
        ];
        for (name, v) in non_negative {
            if !(0.0..=MAX_JET_PARAMETER).contains(&v) {
                return Err(SynthError::invalid(
                    format!("phantom.jet.{name}"),
                    format!("must be zero or positive and at most {MAX_JET_PARAMETER}, got {}", num(v)),
                ));
            }
        }
        // Each mode is summed at every sample of every ray: a count far beyond the default's 64
        // would run for days, or fail to allocate and abort.
        if self.turbulence_modes > MAX_TURBULENCE_MODES {
            return Err(SynthError::invalid(
                "phantom.jet.turbulence_modes",
                format!("must be at most {MAX_TURBULENCE_MODES}, got {}", self.turbulence_modes),
            ));
        }
        // Eddies 2^-20 of the largest are far finer than a voxel of the finest truth grid
        // (4096 along the box); much farther, their wavenumbers overflow 32-bit floats and the
        // images hold NaN.
        if !(0.0..=MAX_INERTIAL_OCTAVES).contains(&self.inertial_octaves) {
            return Err(SynthError::invalid(
                "phantom.jet.inertial_octaves",
                format!(
                    "must be zero or positive and at most {MAX_INERTIAL_OCTAVES}, got {}",
                    num(self.inertial_octaves)
                ),
            ));
        }
        if !(self.transition_end_d > self.core_length_d && self.transition_end_d <= MAX_JET_PARAMETER) {
            return Err(SynthError::invalid(
                "phantom.jet.transition_end_d",
                format!(
                    "must exceed core_length_d ({}) and be at most {MAX_JET_PARAMETER}, got {}",
                    num(self.core_length_d),
                    num(self.transition_end_d)
                ),
            ));
        }
        if let Some(d) = self.nozzle_diameter_mm {
            if !(MIN_NOZZLE_DIAMETER_MM..=MAX_NOZZLE_DIAMETER_MM).contains(&d) {
                return Err(SynthError::invalid(
                    "phantom.jet.nozzle_diameter_mm",
                    format!(
                        "must be between {MIN_NOZZLE_DIAMETER_MM} mm and {MAX_NOZZLE_DIAMETER_MM} mm, got {}",
                        num(d)
                    ),
                ));
            }
        }
        Ok(())
    }
}

pub(crate) fn smoothstep(a: f32, b: f32, x: f32) -> f32 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// One train of shear-layer vortices (see the module docs, item 2).
#[derive(Clone, Copy, Debug)]
pub(crate) struct RollupTrain {
    /// Azimuthal mode number (0 rings, 1 helix).
    pub m: f32,
    pub twist: f32,
    pub start: f32,
    pub lambda0: f32,
    pub growth: f32,
    pub phase0: f32,
    /// Azimuthal distortion amplitudes (in wavelengths) and phases of modes 1, 2, 3.
    pub distortion: [(f32, f32); 3],
    /// Smooth strength and radius modulation along the train.
    pub modulation: [f32; 2],
    /// Fade-out of the strength between these two distances (to zero), if any.
    pub fade: Option<(f32, f32)>,
}

impl RollupTrain {
    pub fn wavelength(&self, xi: f32) -> f32 {
        self.lambda0 + self.growth * (xi - self.start).max(0.0)
    }

    /// Number of wavelengths from `start` to `xi` (negative upstream): `ln(1 + g n) / g` for
    /// `n = (xi − start) / λ₀` wavelengths of the initial size, computed as `n ln(1 + x) / x`
    /// with `x = g n`, whose limit for a vanishing growth is `n`. The direct form rounded
    /// `1 + g n` to 1 for a tiny growth (1e-10), so the phase stayed 0 all along the train and
    /// one vortex twisted the whole jet, far from the field of zero growth.
    fn phase(&self, xi: f32) -> f32 {
        let n = (xi - self.start) / self.lambda0;
        let x = self.growth * n;
        if n <= 0.0 || x <= 0.0 {
            n
        } else {
            n * (x.ln_1p() / x)
        }
    }

    /// The twist map: `(ξ, r)` at azimuth `theta` → the pre-image point, given the radius of the
    /// vortex centres `centre_radius(ξ_c)` and an extra strength factor.
    pub fn apply(
        &self,
        xi: f32,
        r: f32,
        theta: f32,
        advect: f32,
        centre_radius: impl Fn(f32) -> f32,
        strength: impl Fn(f32) -> f32,
    ) -> (f32, f32) {
        if self.twist == 0.0 || xi < self.start - 2.0 * self.lambda0 {
            return (xi, r);
        }
        let mut psi = self.phase(xi - advect) - self.m * theta / std::f32::consts::TAU - self.phase0;
        for (k, (amp, ph)) in self.distortion.iter().enumerate() {
            psi -= amp * ((k as f32 + 1.0) * theta + ph).cos();
        }
        let frac = psi - psi.round();
        let lambda = self.wavelength(xi - advect);
        let xc = xi - frac * lambda;
        let rho_s = 0.5 * lambda;
        let mut rc = centre_radius(xc);
        rc *= 1.0 + 0.08 * (2.3 * xc / self.lambda0 + self.modulation[1]).sin();
        let (dx, dr) = (xi - xc, r - rc);
        let rho2 = dx * dx + dr * dr;
        if rho2 >= rho_s * rho_s {
            return (xi, r);
        }
        // Roll-up sets in at a fixed place downstream of the nozzle, even when the vortices
        // themselves are carried along (`advect`).
        let fade = self.fade.map_or(1.0, |(a, b)| 1.0 - smoothstep(a, b, xc));
        let ramp = smoothstep(self.start - self.lambda0, self.start + 2.0 * self.lambda0, xc) * fade;
        let wobble = 1.0 + 0.25 * (1.7 * xc / self.lambda0 + self.modulation[0]).sin();
        let w = 1.0 - rho2 / (rho_s * rho_s);
        let phi = self.twist * ramp * wobble * strength(xc) * w * w * w;
        let (s, c) = phi.sin_cos();
        (xc + c * dx - s * dr, (rc + s * dx + c * dr).abs())
    }
}

/// The static turbulent jet phantom (see the module docs).
#[derive(Clone, Debug)]
pub struct Jet {
    params: JetParams,
    nozzle: Vec3,
    d: f32,
    lc: f32,
    lt: f32,
    s: f32,
    trains: [RollupTrain; 2],
    modes: KinematicModes,
}

impl Jet {
    /// The jet in `aabb`, nozzle on the `min.x` face centre, deterministic from `seed`.
    pub fn new(params: &JetParams, aabb: &Aabb, seed: u64) -> Result<Self, SynthError> {
        params.validate()?;
        let len = aabb.size().x;
        let d = params.nozzle_diameter_mm.unwrap_or(len / (3.0 * params.core_length_d)) as f32;
        let centre = aabb.centre();
        let nozzle = Vec3::new(aabb.min.x as f32, centre.y as f32, centre.z as f32);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x6a65_7421);
        let tau = std::f32::consts::TAU;
        let lc = params.core_length_d as f32 * d;
        let lt = params.transition_end_d as f32 * d;
        let mut train = |m: f32, twist: f64, distort: f64| RollupTrain {
            m,
            twist: twist as f32,
            start: params.rollup_start_d as f32 * d,
            lambda0: params.rollup_wavelength_d as f32 * d,
            growth: params.pairing_growth as f32,
            phase0: rng.random::<f32>(),
            distortion: [
                (distort as f32 * 0.5, rng.random::<f32>() * tau),
                (distort as f32, rng.random::<f32>() * tau),
                (distort as f32 * 0.5, rng.random::<f32>() * tau),
            ],
            modulation: [rng.random::<f32>() * tau, rng.random::<f32>() * tau],
            fade: Some((lt - 0.25 * lc, lt + 0.25 * lc)),
        };
        let trains = [
            train(0.0, params.rollup_twist, params.asymmetry),
            train(1.0, params.helical_twist, 0.3 * params.asymmetry),
        ];
        let kappa_min = std::f64::consts::TAU / 2.5;
        let modes = KinematicModes::new(params.turbulence_modes, kappa_min, params.inertial_octaves, rng.random());
        Ok(Jet { params: params.clone(), nozzle, d, lc, lt, s: params.spreading_rate as f32, trains, modes })
    }

    pub fn params(&self) -> &JetParams {
        &self.params
    }

    /// Nozzle diameter D in world units.
    pub fn nozzle_diameter(&self) -> f64 {
        self.d as f64
    }

    /// Distances from the nozzle (world units) where the laminar region ends and the turbulent
    /// region begins (`L_c`, `L_t`).
    pub fn region_bounds(&self) -> (f64, f64) {
        (self.lc as f64, self.lt as f64)
    }

    fn edge(&self, xi: f32) -> f32 {
        self.d * (self.params.edge_thickness_d as f32 + 0.02 * xi / self.d)
    }

    fn r_cut(&self, xi: f32) -> f32 {
        (0.5 * self.d + 6.0 * self.edge(xi)).max(2.6 * self.s * xi)
    }

    /// The mean (unperturbed) field at distance `xi` and radius `r`.
    fn mean(&self, xi: f32, r: f32) -> f32 {
        if xi <= 0.0 {
            return 0.0;
        }
        let rcut = self.r_cut(xi);
        if r >= rcut {
            return 0.0;
        }
        let top_hat = 0.5 * (1.0 - ((r - 0.5 * self.d) / self.edge(xi)).tanh());
        let b = (self.s * xi).max(1e-6);
        let gauss = (-std::f32::consts::LN_2 * (r * r) / (b * b)).exp();
        let beta = smoothstep(0.7 * self.lc, self.lt, xi);
        let centreline = (1.0 + (xi / self.lc).powi(6)).powf(-1.0 / 6.0);
        let taper = 1.0 - smoothstep(0.75 * rcut, rcut, r);
        centreline * ((1.0 - beta) * top_hat + beta * gauss) * taper
    }

    /// A radius beyond which the field is zero at distance `xi`.
    fn envelope(&self, xi: f32) -> f32 {
        let turb = (self.params.wrinkle as f32) * self.modes.disp_bound * self.s * xi.max(0.0);
        let shift = turb + self.trains[0].wavelength(xi + turb) + 0.01 * self.d;
        shift + self.r_cut(xi + 2.0 * shift)
    }

    /// E at one world point.
    #[inline(always)]
    pub fn value(&self, p: Vec3) -> f32 {
        let mut xi = p.x - self.nozzle.x;
        let (mut dy, mut dz) = (p.y - self.nozzle.y, p.z - self.nozzle.z);
        if xi <= 0.0 {
            return 0.0;
        }
        if dy * dy + dz * dz > self.envelope(xi).powi(2) {
            return 0.0;
        }
        let wt = smoothstep(self.lc, self.lt, xi);
        let mut modulation = 0.0;
        if wt > 0.0 && self.params.turbulence_modes > 0 {
            let b = self.s * xi;
            let q = Vec3::new((xi / self.d).ln() / self.s, dy / b, dz / b);
            let (disp, m) = self.modes.eval(q);
            let k = wt * self.params.wrinkle as f32 * b;
            xi += k * disp.x;
            dy += k * disp.y;
            dz += k * disp.z;
            modulation = wt * self.params.scalar_fluctuation as f32 * m;
        }
        if xi <= 0.0 {
            return 0.0;
        }
        let mut r = (dy * dy + dz * dz).sqrt();
        let theta = dz.atan2(dy);
        let half = 0.5 * self.d;
        for train in &self.trains {
            (xi, r) = train.apply(xi, r, theta, 0.0, |xc| half.max(self.s * xc), |_| 1.0);
        }
        (self.mean(xi, r) * (1.0 + modulation)).clamp(0.0, 1.0)
    }
}

impl ScalarField for Jet {
    fn eval(&self, points: &[Vec3], _time: f64, out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "Jet::eval: points and out differ in length");
        super::eval_points(self, points, (), out);
    }
}

impl super::PointValue for Jet {
    type Arg = ();
    #[inline(always)]
    fn point_value(&self, p: Vec3, _: ()) -> f32 {
        self.value(p)
    }
}
