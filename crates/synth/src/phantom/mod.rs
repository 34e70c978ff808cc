//! Ground-truth fields: the turbulent [`Jet`], the starting jet [`StartingJet`] (`jet-tr`),
//! analytic shapes with closed-form projections ([`UniformBall`], [`GaussianBlob`],
//! [`ShapeSum`]) and any user volume.
//!
//! Every phantom implements [`fluidnerf_core::ScalarField`] in world coordinates (mm), so it
//! feeds the reference renderer, voxelisation ([`fluidnerf_core::Volume::from_field`]) and tests
//! alike. Phantoms are deterministic functions of their parameters and seed.

mod jet;
mod simple;
mod starting_jet;
mod turbulence;

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::{Aabb, ScalarField, Volume};
use serde::{Deserialize, Serialize};

pub use jet::{Jet, JetParams};
pub use simple::{analytic_image, GaussianBlob, LineIntegral, Shape, ShapeSum, UniformBall};
pub use starting_jet::{StartingJet, StartingJetParams};

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
    /// A user volume (`.npy`/`.vti`), loaded by the caller.
    Volume,
}

impl PhantomKind {
    /// Whether the phantom changes with time (frames at several times).
    pub fn is_time_resolved(self) -> bool {
        matches!(self, PhantomKind::JetTr)
    }
}

/// Phantom settings; only the block of the chosen kind is used.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhantomSettings {
    /// Default `jet`.
    pub kind: PhantomKind,
    pub jet: JetParams,
    pub jet_tr: StartingJetParams,
    /// Number of blobs of `blobs` and `ball-and-blobs`. Default 5.
    pub blob_count: usize,
    /// The user volume for `volume` (recorded for reruns; the caller loads it).
    pub volume_path: Option<std::path::PathBuf>,
}

impl Default for PhantomSettings {
    fn default() -> Self {
        PhantomSettings {
            kind: PhantomKind::Jet,
            jet: JetParams::default(),
            jet_tr: StartingJetParams::default(),
            blob_count: 5,
            volume_path: None,
        }
    }
}

impl PhantomSettings {
    pub fn validate(&self) -> Result<(), SynthError> {
        match self.kind {
            PhantomKind::Jet => self.jet.validate(),
            PhantomKind::JetTr => self.jet_tr.validate(),
            PhantomKind::Blobs | PhantomKind::BallAndBlobs if self.blob_count == 0 => {
                Err(SynthError::invalid("phantom.blob_count", "must be at least 1"))
            }
            _ => Ok(()),
        }
    }
}

/// A built phantom.
#[derive(Clone, Debug)]
pub enum Phantom {
    Jet(Jet),
    StartingJet(StartingJet),
    Shapes(ShapeSum),
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
            PhantomKind::Volume => Phantom::Volume(
                volume.ok_or_else(|| SynthError::invalid("phantom.kind", "`volume` needs a ground-truth volume"))?,
            ),
        })
    }

    pub fn is_time_resolved(&self) -> bool {
        matches!(self, Phantom::StartingJet(_))
    }

    /// The closed-form projector, for analytic shapes.
    pub fn line_integrals(&self) -> Option<&ShapeSum> {
        match self {
            Phantom::Shapes(s) => Some(s),
            _ => None,
        }
    }
}

impl ScalarField for Phantom {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        match self {
            Phantom::Jet(f) => f.eval(points, time, out),
            Phantom::StartingJet(f) => f.eval(points, time, out),
            Phantom::Shapes(f) => f.eval(points, time, out),
            Phantom::Volume(f) => f.eval(points, time, out),
        }
    }
}
