//! Ground-truth fields in two independent classes, plus test shapes and user volumes:
//! - procedural: the turbulent [`Jet`] and the starting jet [`StartingJet`] (`jet-tr`), flowing
//!   along +x and fitted to the box;
//! - CFD: a buoyant plume and a forced round jet from an incompressible-flow solver
//!   ([`CfdPhantom`], module [`cfd`]), rising along +y in their own simulation domain;
//! - analytic shapes with closed-form projections ([`UniformBall`], [`GaussianBlob`],
//!   [`ShapeSum`]) and any user volume.
//!
//! Every phantom implements [`fluidnerf_core::ScalarField`] in world coordinates (mm), so it
//! feeds the reference renderer, voxelisation ([`fluidnerf_core::Volume::from_field`]) and tests
//! alike. Phantoms are deterministic functions of their parameters and seed.

pub mod cfd;
mod jet;
mod simple;
mod starting_jet;
mod turbulence;

use fluidnerf_core::glam::{DVec3, Vec3};
use fluidnerf_core::{Aabb, ScalarField, Volume};
use serde::{Deserialize, Serialize};

pub use cfd::{CfdCase, CfdPhantom};
pub use jet::{Jet, JetParams, MAX_JET_PARAMETER, MAX_NOZZLE_DIAMETER_MM, MIN_JET_PARAMETER, MIN_NOZZLE_DIAMETER_MM};
pub use simple::{analytic_image, GaussianBlob, LineIntegral, Shape, ShapeSum, UniformBall};
pub use starting_jet::{StartingJet, StartingJetParams};

use crate::rig::RingAxis;
use crate::SynthError;

/// Which phantom to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PhantomKind {
    /// The static turbulent round jet ([`Jet`]).
    Jet,
    /// The starting jet with its travelling vortex ring ([`StartingJet`]); time-resolved.
    JetTr,
    /// A uniform ball ([`ShapeSum::ball`]).
    Ball,
    /// Gaussian blobs ([`ShapeSum::blobs`]).
    Blobs,
    /// A half-value ball plus Gaussian blobs ([`ShapeSum::ball_and_blobs`]).
    BallAndBlobs,
    /// The CFD buoyant plume ([`CfdCase::Plume`]), rising along +y; static, or at the solver
    /// steps given as times.
    Plume,
    /// The CFD forced round jet ([`CfdCase::Jet`]), along +y; static, or at the solver steps
    /// given as times.
    CfdJet,
    /// A user volume (`.npy`/`.vti`), loaded by the caller.
    Volume,
}

impl PhantomKind {
    /// The name a setting gives it (`jet-tr`, `ball-and-blobs`, …).
    pub fn name(self) -> &'static str {
        match self {
            PhantomKind::Jet => "jet",
            PhantomKind::JetTr => "jet-tr",
            PhantomKind::Ball => "ball",
            PhantomKind::Blobs => "blobs",
            PhantomKind::BallAndBlobs => "ball-and-blobs",
            PhantomKind::Plume => "plume",
            PhantomKind::CfdJet => "cfd-jet",
            PhantomKind::Volume => "volume",
        }
    }

    /// Whether the phantom needs frame times (it has no static form).
    pub fn is_time_resolved(self) -> bool {
        matches!(self, PhantomKind::JetTr)
    }

    /// Whether the phantom accepts frame times: the time-resolved ones, and the CFD ones, whose
    /// times are solver steps (without times they are static at `phantom.cfd_step`).
    pub fn takes_times(self) -> bool {
        self.is_time_resolved() || self.cfd_case().is_some()
    }

    /// The CFD flow of a CFD phantom.
    pub fn cfd_case(self) -> Option<CfdCase> {
        match self {
            PhantomKind::Plume => Some(CfdCase::Plume),
            PhantomKind::CfdJet => Some(CfdCase::Jet),
            _ => None,
        }
    }

    /// The world axis the flow runs along, which ring rigs go around: x for the procedural
    /// phantoms, y for the CFD ones.
    pub fn flow_axis(self) -> RingAxis {
        if self.cfd_case().is_some() {
            RingAxis::Y
        } else {
            RingAxis::X
        }
    }

    /// The direction the flow runs in ([`PhantomKind::flow_axis`]), for the phantoms that are
    /// flows (jets and plumes); `None` for balls, blobs and user volumes.
    pub fn flow_direction(self) -> Option<DVec3> {
        match self {
            PhantomKind::Ball | PhantomKind::Blobs | PhantomKind::BallAndBlobs | PhantomKind::Volume => None,
            _ => Some(match self.flow_axis() {
                RingAxis::X => DVec3::X,
                RingAxis::Y => DVec3::Y,
            }),
        }
    }
}

/// Phantom settings; only the block of the chosen kind is used.
/// Most Gaussian blobs of the `blobs` and `ball-and-blobs` phantoms.
pub const MAX_BLOBS: usize = 1000;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhantomSettings {
    /// Default `jet`.
    pub kind: PhantomKind,
    pub jet: JetParams,
    pub jet_tr: StartingJetParams,
    /// Number of blobs of `blobs` and `ball-and-blobs`, at most [`MAX_BLOBS`]. Default 5.
    pub blob_count: usize,
    /// The user volume for `volume` (recorded for reruns; the caller loads it).
    pub volume_path: Option<std::path::PathBuf>,
    /// Solver step of a static `plume` or `cfd-jet` (one of [`cfd::STEPS`]). Default: the last
    /// stored step, [`cfd::DEFAULT_STEP`].
    pub cfd_step: Option<u32>,
}

impl Default for PhantomSettings {
    fn default() -> Self {
        PhantomSettings {
            kind: PhantomKind::Jet,
            jet: JetParams::default(),
            jet_tr: StartingJetParams::default(),
            blob_count: 5,
            volume_path: None,
            cfd_step: None,
        }
    }
}

impl PhantomSettings {
    pub fn validate(&self) -> Result<(), SynthError> {
        self.refuse_unused()?;
        match self.kind {
            PhantomKind::Jet => self.jet.validate(),
            PhantomKind::JetTr => self.jet_tr.validate(),
            // Every blob is summed at every sample of every ray: a count far beyond the default's
            // 5 would run for days, or fail to allocate and abort.
            PhantomKind::Blobs | PhantomKind::BallAndBlobs if !(1..=MAX_BLOBS).contains(&self.blob_count) => {
                Err(SynthError::invalid(
                    "phantom.blob_count",
                    format!("must be in 1..={MAX_BLOBS}, got {}", self.blob_count),
                ))
            }
            PhantomKind::Plume | PhantomKind::CfdJet => match self.cfd_step {
                Some(s) if !cfd::STEPS.contains(&s) => Err(SynthError::invalid(
                    "phantom.cfd_step",
                    format!("no instant at solver step {s}; stored: {:?}", cfd::STEPS),
                )),
                _ => Ok(()),
            },
            _ => Ok(()),
        }
    }
}

impl PhantomSettings {
    /// Refuses a setting of another phantom than `kind` set away from its default (`jet` for
    /// the jet, `jet_tr` for the starting jet, `blob_count` for `blobs` and `ball-and-blobs`,
    /// `volume_path` for `volume`): the phantom would ignore it. Named by its key down to the
    /// first that differs (`phantom.jet_tr.front_speed`). `cfd_step` is checked with the times.
    fn refuse_unused(&self) -> Result<(), SynthError> {
        let d = PhantomSettings::default();
        let uses_blobs = matches!(self.kind, PhantomKind::Blobs | PhantomKind::BallAndBlobs);
        let set = |key: &str, value: serde_json::Value, default: serde_json::Value| -> Option<(String, String)> {
            if value == default {
                return None;
            }
            // The first key inside that differs, where the setting is a group of them.
            let inner = match (&value, &default) {
                (serde_json::Value::Object(v), serde_json::Value::Object(d)) => {
                    v.iter().find(|(k, x)| d.get(*k) != Some(x)).map(|(k, x)| (format!("{key}.{k}"), x.to_string()))
                }
                _ => None,
            };
            Some(inner.unwrap_or_else(|| (key.to_string(), value.to_string())))
        };
        fn json<T: Serialize>(v: &T) -> serde_json::Value {
            serde_json::to_value(v).unwrap_or(serde_json::Value::Null)
        }
        let unused = [
            (self.kind != PhantomKind::Jet).then(|| set("phantom.jet", json(&self.jet), json(&d.jet))),
            (self.kind != PhantomKind::JetTr).then(|| set("phantom.jet_tr", json(&self.jet_tr), json(&d.jet_tr))),
            (!uses_blobs).then(|| set("phantom.blob_count", json(&self.blob_count), json(&d.blob_count))),
            (self.kind != PhantomKind::Volume)
                .then(|| set("phantom.volume_path", json(&self.volume_path), json(&d.volume_path))),
        ];
        match unused.into_iter().flatten().flatten().next() {
            Some((key, value)) => Err(SynthError::invalid(
                key.clone(),
                format!(
                    "{value} is set for another phantom than the {} phantom this configuration makes, which would \
                     ignore it; leave {key} at its default, or choose the phantom that uses it",
                    self.kind.name()
                ),
            )),
            None => Ok(()),
        }
    }

    /// Puts the settings of the phantoms other than `kind` back to their defaults: what a
    /// change of phantom (`synth --phantom` over a `--config` of another) leaves unread, and
    /// so does not record either.
    pub fn reset_unused(&mut self) {
        let d = PhantomSettings::default();
        if self.kind != PhantomKind::Jet {
            self.jet = d.jet;
        }
        if self.kind != PhantomKind::JetTr {
            self.jet_tr = d.jet_tr;
        }
        if !matches!(self.kind, PhantomKind::Blobs | PhantomKind::BallAndBlobs) {
            self.blob_count = d.blob_count;
        }
        if self.kind != PhantomKind::Volume {
            self.volume_path = d.volume_path;
        }
    }
}

/// A built phantom.
#[derive(Clone, Debug)]
pub enum Phantom {
    Jet(Jet),
    StartingJet(StartingJet),
    Shapes(ShapeSum),
    Cfd(CfdPhantom),
    Volume(Volume),
}

impl Phantom {
    /// Builds the phantom of `settings` inside `aabb`. `volume` is required for
    /// [`PhantomKind::Volume`] and ignored otherwise.
    pub fn build(
        settings: &PhantomSettings,
        aabb: &Aabb,
        seed: u64,
        volume: Option<Volume>,
    ) -> Result<Self, SynthError> {
        settings.validate()?;
        Ok(match settings.kind {
            PhantomKind::Jet => Phantom::Jet(Jet::new(&settings.jet, aabb, seed)?),
            PhantomKind::JetTr => Phantom::StartingJet(StartingJet::new(&settings.jet_tr, aabb, seed)?),
            PhantomKind::Ball => Phantom::Shapes(ShapeSum::ball(aabb)),
            PhantomKind::Blobs => Phantom::Shapes(ShapeSum::blobs(aabb, settings.blob_count, seed)),
            PhantomKind::BallAndBlobs => Phantom::Shapes(ShapeSum::ball_and_blobs(aabb, settings.blob_count, seed)),
            PhantomKind::Plume => Phantom::Cfd(CfdPhantom::new(CfdCase::Plume, settings.cfd_step)?),
            PhantomKind::CfdJet => Phantom::Cfd(CfdPhantom::new(CfdCase::Jet, settings.cfd_step)?),
            PhantomKind::Volume => {
                let v = volume
                    .ok_or_else(|| SynthError::invalid("phantom.kind", "`volume` needs a ground-truth volume"))?;
                if let Some(i) = v.data.iter().position(|x| !x.is_finite()) {
                    let [nx, ny, _] = v.dims;
                    return Err(SynthError::invalid(
                        "phantom.volume",
                        format!(
                            "voxel (i {}, j {}, k {}) is {}; the ground truth must be finite",
                            i % nx,
                            (i / nx) % ny,
                            i / (nx * ny),
                            v.data[i]
                        ),
                    ));
                }
                let top = v.data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                if top <= 0.0 {
                    return Err(SynthError::invalid(
                        "phantom.volume",
                        format!(
                            "no voxel is positive (the largest value is {top}): a field of emission with none images \
                             as black in every camera; give a volume whose glowing parts are positive"
                        ),
                    ));
                }
                Phantom::Volume(v)
            }
        })
    }

    /// Whether the phantom changes with time.
    pub fn is_time_resolved(&self) -> bool {
        matches!(self, Phantom::StartingJet(_) | Phantom::Cfd(_))
    }

    /// The closed-form projector, for analytic shapes.
    pub fn line_integrals(&self) -> Option<&ShapeSum> {
        match self {
            Phantom::Shapes(s) => Some(s),
            _ => None,
        }
    }
}

/// A phantom evaluated point by point ([`eval_points`]).
pub(crate) trait PointValue {
    /// What every point's value also depends on (the time, or nothing).
    type Arg: Copy;
    /// The value at `p`; implementations mark it `#[inline(always)]` down to their arithmetic,
    /// so that the copies of [`eval_points`]' loop take it in.
    fn point_value(&self, p: Vec3, arg: Self::Arg) -> f32;
}

/// `out[i] = field.point_value(points[i], arg)`, in a copy of the loop compiled for AVX-512 or
/// AVX2 where the CPU has them: the phantoms' modes run eight lanes wide, which the baseline
/// build runs as SSE. The operations are the same, so the values are the same bit for bit.
#[inline(always)]
pub(crate) fn eval_points<T: PointValue>(field: &T, points: &[Vec3], arg: T::Arg, out: &mut [f32]) {
    #[inline(always)]
    fn each<T: PointValue>(field: &T, points: &[Vec3], arg: T::Arg, out: &mut [f32]) {
        for (o, &p) in out.iter_mut().zip(points) {
            *o = field.point_value(p, arg);
        }
    }
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx512f,avx2")]
        unsafe fn avx512<T: PointValue>(field: &T, points: &[Vec3], arg: T::Arg, out: &mut [f32]) {
            each(field, points, arg, out)
        }
        #[target_feature(enable = "avx2")]
        unsafe fn avx2<T: PointValue>(field: &T, points: &[Vec3], arg: T::Arg, out: &mut [f32]) {
            each(field, points, arg, out)
        }
        match fluidnerf_core::Isa::detected() {
            // SAFETY: the CPU has AVX-512F and AVX2.
            fluidnerf_core::Isa::Avx512 => return unsafe { avx512(field, points, arg, out) },
            // SAFETY: the CPU has AVX2.
            fluidnerf_core::Isa::Avx2 => return unsafe { avx2(field, points, arg, out) },
            fluidnerf_core::Isa::Baseline => {}
        }
    }
    each(field, points, arg, out)
}

impl ScalarField for Phantom {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        match self {
            Phantom::Jet(f) => f.eval(points, time, out),
            Phantom::StartingJet(f) => f.eval(points, time, out),
            Phantom::Shapes(f) => f.eval(points, time, out),
            Phantom::Cfd(f) => f.eval(points, time, out),
            Phantom::Volume(f) => f.eval(points, time, out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Another phantom's setting, away from its default, would be ignored: refused naming its
    /// key and the phantom made; the defaults every written synth.json holds are taken.
    #[test]
    fn another_phantoms_setting_is_refused_naming_the_key_and_the_phantom() {
        let mut jet = PhantomSettings::default();
        jet.jet_tr.front_speed = 2.0;
        let mut ball = PhantomSettings { kind: PhantomKind::Ball, blob_count: 8, ..Default::default() };
        let mut procedural = PhantomSettings { kind: PhantomKind::Blobs, ..Default::default() };
        procedural.volume_path = Some("cfd.tif".into());
        for (p, key, phantom) in [
            (&jet, "phantom.jet_tr.front_speed", "the jet phantom"),
            (&ball, "phantom.blob_count", "the ball phantom"),
            (&procedural, "phantom.volume_path", "the blobs phantom"),
        ] {
            let e = p.validate().expect_err(key).to_string();
            assert!(e.contains(&format!("`{key}`")) && e.contains(phantom) && e.contains("ignore"), "{key}: {e}");
        }
        // Once the phantom's kind resets them, or for the phantom that uses them, they are taken.
        for p in [&mut jet, &mut ball, &mut procedural] {
            p.reset_unused();
            p.validate().unwrap_or_else(|e| panic!("{:?}: {e}", p.kind));
        }
        let blobs = PhantomSettings { kind: PhantomKind::BallAndBlobs, blob_count: 8, ..Default::default() };
        blobs.validate().expect("ball-and-blobs uses blob_count");
        let mut starting = PhantomSettings { kind: PhantomKind::JetTr, ..Default::default() };
        starting.jet_tr.front_speed = 0.7;
        starting.validate().expect("jet-tr uses jet_tr");
        for kind in [PhantomKind::Jet, PhantomKind::JetTr, PhantomKind::Ball, PhantomKind::Plume, PhantomKind::Volume] {
            PhantomSettings { kind, ..Default::default() }.validate().expect("defaults");
        }
    }
}
