//! `jet-tr`: a starting jet whose leading vortex ring travels through the box, continuous in
//! time.
//!
//! # Conventions
//! As for [`super::jet`]: world units (mm), flow along **+x** from a nozzle of diameter `D` on
//! the `min.x` face, values in `[0, 1]`. Time is the dimensionless `t* = t U / D`
//! (dissertation Eq. 6.1, `U` the exit velocity): the field at `t* ≤ 0` is empty, and any real
//! `t*` can be evaluated (the dissertation used t* = 14, 15, 16).
//!
//! # Model
//! An impulsively started jet (Gharib, Rambod & Shariff 1998; Witze 1980) consists of a leading
//! vortex ring that carries a head of nozzle fluid and a trailing jet column behind it:
//!
//! 1. **Base shape.** A top-hat column of radius `D/2` (tanh edge of thickness
//!    `edge_thickness_d · D`) from the nozzle to the ring, plus an ellipsoidal head bulb around
//!    the ring (axial semi-axis `head_length_d · D`, radial semi-axis the ring radius).
//! 2. **Leading ring.** Its centre travels at `front_speed · U` (0.55, the measured 0.5–0.6 U of
//!    starting-jet rings), so `ξ_ring = front_speed · t* · D`. Its core (radius
//!    `a = core_radius_d · D`, ring radius `ring_radius_d · D`) rolls the head up: points are
//!    rotated about the core by the Lamb–Oseen angle `φ(ρ) = Φ(t) (a²/ρ²)(1 − e^{−ρ²/a²})`,
//!    the angle a vortex turns fluid through in a fixed time (∝ 1/ρ² outside the core, finite
//!    inside). The winding grows and saturates as viscosity thickens the core,
//!    `Φ(t) = winding · t*/(t* + winding_time)`; within the core the wound-up scalar is
//!    homogenised towards 0.5 (molecular mixing) with weight `mixing · e^{−ρ²/a²}`.
//! 3. **Azimuthal (Widnall) instability** of the ring: the core is displaced by
//!    `ε(t) cos(m ϑ + φ_w)` radially and half of that axially, with `m = widnall_waves` and
//!    `ε = widnall_amplitude_d · D · exp(widnall_growth (t* − 15))`, capped at `0.3 D`.
//! 4. **Trailing-jet roll-up.** Kelvin–Helmholtz vortices on the column (the twist map of
//!    [`super::jet`], axisymmetric plus a weak helix) convect at `convection_speed · U`, from
//!    `trailing_start_d` downstream to one diameter behind the ring.
//! 5. **Head turbulence.** A weak −5/3 kinematic-simulation displacement (rms `wrinkle_d · D`)
//!    carried with the ring and confined to the head.

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::num;
use fluidnerf_core::{Aabb, ScalarField};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::jet::{
    smoothstep, RollupTrain, MAX_JET_PARAMETER, MAX_NOZZLE_DIAMETER_MM, MIN_JET_PARAMETER, MIN_NOZZLE_DIAMETER_MM,
};
use super::turbulence::KinematicModes;
use crate::SynthError;

/// Parameters of the [`StartingJet`]; lengths with suffix `_d` are in nozzle diameters, times
/// in `t* = t U / D`, speeds in `U`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StartingJetParams {
    /// Nozzle diameter D in mm. Default: the box's x length / 17 (2.35 mm for the 40 mm box,
    /// like the DNS's 2.36 mm), which puts the ring mid-box at t* ≈ 15.
    pub nozzle_diameter_mm: Option<f64>,
    /// Speed of the leading ring. Default 0.55.
    pub front_speed: f64,
    /// Radius of the leading ring (measured rings of starting jets: 0.7–1 D). Default 0.9.
    pub ring_radius_d: f64,
    /// Core radius of the leading ring. Default 0.25.
    pub core_radius_d: f64,
    /// Axial semi-axis of the head bulb. Default 0.9.
    pub head_length_d: f64,
    /// Saturated winding of the ring core, radians. Default 10.
    pub winding: f64,
    /// Time scale of the winding's saturation. Default 5.
    pub winding_time: f64,
    /// Homogenisation of the ring core, in [0, 1]. Default 0.7.
    pub mixing: f64,
    /// Azimuthal wave number of the ring instability. Default 7.
    pub widnall_waves: u32,
    /// Amplitude of the ring instability at t* = 15. Default 0.04.
    pub widnall_amplitude_d: f64,
    /// Growth rate of the ring instability per unit t*. Default 0.25.
    pub widnall_growth: f64,
    /// Where trailing-jet roll-up begins. Default 2.
    pub trailing_start_d: f64,
    /// Wavelength of the trailing roll-up. Default 1.4.
    pub trailing_wavelength_d: f64,
    /// Peak twist of the trailing roll-up, radians. Default 1.8.
    pub trailing_twist: f64,
    /// Convection speed of the trailing vortices. Default 0.6.
    pub convection_speed: f64,
    /// Edge thickness of the column. Default 0.04.
    pub edge_thickness_d: f64,
    /// rms turbulent displacement in the head. Default 0.05.
    pub wrinkle_d: f64,
}

impl Default for StartingJetParams {
    fn default() -> Self {
        StartingJetParams {
            nozzle_diameter_mm: None,
            front_speed: 0.55,
            ring_radius_d: 0.9,
            core_radius_d: 0.25,
            head_length_d: 0.9,
            winding: 10.0,
            winding_time: 5.0,
            mixing: 0.7,
            widnall_waves: 7,
            widnall_amplitude_d: 0.04,
            widnall_growth: 0.25,
            trailing_start_d: 2.0,
            trailing_wavelength_d: 1.4,
            trailing_twist: 1.8,
            convection_speed: 0.6,
            edge_thickness_d: 0.04,
            wrinkle_d: 0.05,
        }
    }
}

impl StartingJetParams {
    /// Checks ranges, naming the key (`phantom.jet_tr.…`) in messages: every parameter at most
    /// [`MAX_JET_PARAMETER`] (the nozzle diameter [`MAX_NOZZLE_DIAMETER_MM`]), and those that
    /// must be positive at least [`MIN_JET_PARAMETER`] (the nozzle diameter
    /// [`MIN_NOZZLE_DIAMETER_MM`]).
    pub fn validate(&self) -> Result<(), SynthError> {
        let positive = [
            ("front_speed", self.front_speed),
            ("ring_radius_d", self.ring_radius_d),
            ("core_radius_d", self.core_radius_d),
            ("head_length_d", self.head_length_d),
            ("winding_time", self.winding_time),
            ("trailing_wavelength_d", self.trailing_wavelength_d),
            ("edge_thickness_d", self.edge_thickness_d),
        ];
        for (name, v) in positive {
            if !(MIN_JET_PARAMETER..=MAX_JET_PARAMETER).contains(&v) {
                return Err(SynthError::invalid(
                    format!("phantom.jet_tr.{name}"),
                    format!("must be between {MIN_JET_PARAMETER} and {MAX_JET_PARAMETER}, got {}", num(v)),
                ));
            }
        }
        let non_negative = [
            ("winding", self.winding),
            ("widnall_amplitude_d", self.widnall_amplitude_d),
            ("trailing_start_d", self.trailing_start_d),
            ("trailing_twist", self.trailing_twist),
            ("convection_speed", self.convection_speed),
            ("wrinkle_d", self.wrinkle_d),
        ];
        for (name, v) in non_negative {
            if !(0.0..=MAX_JET_PARAMETER).contains(&v) {
                return Err(SynthError::invalid(
                    format!("phantom.jet_tr.{name}"),
                    format!("must be zero or positive and at most {MAX_JET_PARAMETER}, got {}", num(v)),
                ));
            }
        }
        if !(0.0..=1.0).contains(&self.mixing) {
            return Err(SynthError::invalid(
                "phantom.jet_tr.mixing",
                format!("must be in [0, 1], got {}", num(self.mixing)),
            ));
        }
        if !(-MAX_JET_PARAMETER..=MAX_JET_PARAMETER).contains(&self.widnall_growth) {
            return Err(SynthError::invalid(
                "phantom.jet_tr.widnall_growth",
                format!("must be at most {MAX_JET_PARAMETER} either way, got {}", num(self.widnall_growth)),
            ));
        }
        if let Some(d) = self.nozzle_diameter_mm {
            if !(MIN_NOZZLE_DIAMETER_MM..=MAX_NOZZLE_DIAMETER_MM).contains(&d) {
                return Err(SynthError::invalid(
                    "phantom.jet_tr.nozzle_diameter_mm",
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

/// The starting-jet phantom (see the module docs). `eval`'s `time` is t*.
#[derive(Clone, Debug)]
pub struct StartingJet {
    params: StartingJetParams,
    nozzle: Vec3,
    d: f32,
    widnall_phase: f32,
    trains: [RollupTrain; 2],
    modes: KinematicModes,
}

impl StartingJet {
    pub fn new(params: &StartingJetParams, aabb: &Aabb, seed: u64) -> Result<Self, SynthError> {
        params.validate()?;
        let d = params.nozzle_diameter_mm.unwrap_or(aabb.size().x / 17.0) as f32;
        let centre = aabb.centre();
        let nozzle = Vec3::new(aabb.min.x as f32, centre.y as f32, centre.z as f32);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x7374_6172);
        let tau = std::f32::consts::TAU;
        let mut train = |m: f32, twist: f64| RollupTrain {
            m,
            twist: twist as f32,
            start: params.trailing_start_d as f32 * d,
            lambda0: params.trailing_wavelength_d as f32 * d,
            growth: 0.0,
            phase0: rng.random::<f32>(),
            distortion: [(0.04, rng.random::<f32>() * tau), (0.06, rng.random::<f32>() * tau), (0.0, 0.0)],
            modulation: [rng.random::<f32>() * tau, rng.random::<f32>() * tau],
            fade: None,
        };
        let trains = [train(0.0, params.trailing_twist), train(1.0, 0.3 * params.trailing_twist)];
        let widnall_phase = rng.random::<f32>() * tau;
        let modes = KinematicModes::new(48, std::f64::consts::TAU / 1.5, 4.0, rng.random());
        Ok(StartingJet { params: params.clone(), nozzle, d, widnall_phase, trains, modes })
    }

    pub fn params(&self) -> &StartingJetParams {
        &self.params
    }

    /// Nozzle diameter D in world units.
    pub fn nozzle_diameter(&self) -> f64 {
        self.d as f64
    }

    /// Distance of the leading ring from the nozzle at time `t_star` (world units).
    pub fn ring_position(&self, t_star: f64) -> f64 {
        self.params.front_speed * t_star.max(0.0) * self.d as f64
    }

    /// E at one world point and time t*.
    #[inline(always)]
    pub fn value(&self, p: Vec3, t: f32) -> f32 {
        if t <= 0.0 {
            return 0.0;
        }
        let prm = &self.params;
        let d = self.d;
        let mut xi = p.x - self.nozzle.x;
        let (mut dy, mut dz) = (p.y - self.nozzle.y, p.z - self.nozzle.z);
        let xr = prm.front_speed as f32 * t * d;
        let ring_r = prm.ring_radius_d as f32 * d;
        let reach = 3.0 * d;
        if xi <= 0.0 || xi > xr + reach || dy * dy + dz * dz > (ring_r + reach).powi(2) {
            return 0.0;
        }
        // Head turbulence, carried with the ring.
        let head = (-((xi - xr) / (1.5 * d)).powi(2)).exp();
        if prm.wrinkle_d > 0.0 && head > 1e-3 {
            let q = Vec3::new((xi - xr) / d, dy / d, dz / d);
            let (disp, _) = self.modes.eval(q);
            let k = prm.wrinkle_d as f32 * d * head;
            xi += k * disp.x;
            dy += k * disp.y;
            dz += k * disp.z;
        }
        let mut r = (dy * dy + dz * dz).sqrt();
        let theta = dz.atan2(dy);
        // Leading ring with its azimuthal instability.
        let eps = (prm.widnall_amplitude_d as f32 * d * (prm.widnall_growth as f32 * (t - 15.0)).exp()).min(0.3 * d);
        let wave = prm.widnall_waves as f32 * theta + self.widnall_phase;
        let (rc, xc) = (ring_r + eps * wave.cos(), xr + 0.5 * eps * wave.sin());
        let a = prm.core_radius_d as f32 * d;
        let (dx, dr) = (xi - xc, r - rc);
        let rho2 = dx * dx + dr * dr;
        let core = (-rho2 / (a * a)).exp();
        let winding = prm.winding as f32 * t / (t + prm.winding_time as f32);
        let phi = if rho2 < 1e-12 { winding } else { winding * a * a / rho2 * (1.0 - core) };
        let (s, c) = phi.sin_cos();
        xi = xc + c * dx - s * dr;
        r = (rc + s * dx + c * dr).abs();
        // Trailing-jet roll-up, convecting, switched off near the head.
        let advect = prm.convection_speed as f32 * t * d;
        let behind = 1.0 - smoothstep(xr - 2.0 * d, xr - 0.8 * d, xi);
        for train in &self.trains {
            (xi, r) = train.apply(xi, r, theta, advect, |_| 0.5 * d, |_| behind);
        }
        // Base shape: column plus head bulb.
        let edge = prm.edge_thickness_d as f32 * d;
        let column = 0.5 * (1.0 - ((r - 0.5 * d) / edge).tanh()) * (1.0 - smoothstep(xr - 0.3 * d, xr + 0.3 * d, xi));
        let ex = (xi - xr) / (prm.head_length_d as f32 * d);
        let er = r / ring_r;
        let bulb = 0.5 * (1.0 - (((ex * ex + er * er).sqrt() - 1.0) * ring_r / edge).tanh());
        let base = if xi > 0.0 { column.max(bulb) } else { 0.0 };
        let mix = prm.mixing as f32 * core;
        (base * (1.0 - mix) + 0.5 * mix).clamp(0.0, 1.0)
    }
}

impl ScalarField for StartingJet {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "StartingJet::eval: points and out differ in length");
        super::eval_points(self, points, time as f32, out);
    }
}

impl super::PointValue for StartingJet {
    type Arg = f32;
    #[inline(always)]
    fn point_value(&self, p: Vec3, t: f32) -> f32 {
        self.value(p, t)
    }
}
