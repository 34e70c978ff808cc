//! Synthetic benchmark generator: phantoms, camera rigs, image formation, noise — the
//! dissertation's chapter 6 (SPEC §4) as a library.
//!
//! # Conventions
//! - **Units**: world lengths in mm; the default box is the 40 mm cube centred at the origin.
//!   Field values are dimensionless (a mixture fraction in `[0, 1]` for the jets); images are
//!   line integrals `∫E ds` (value × mm) until the sensor turns them into counts.
//! - **Axes**: the procedural jets flow along world **+x** from the box's `min.x` face; the CFD
//!   phantoms rise along world **+y** in their simulation domain. Ring rigs go around the flow
//!   axis through the box centre (the y–z plane by default, the x–z plane for the CFD
//!   presets). Cameras use `fluidnerf-core`'s OpenCV conventions.
//! - **Time**: `jet-tr` uses the dimensionless `t* = t U / D` (Eq. 6.1); the CFD phantoms use
//!   solver steps.
//! - **Determinism**: every random choice derives from one `seed`; results are the same bytes
//!   on any number of threads.
//!
//! # Pieces
//! - [`phantom`]: the ground-truth fields: procedural ([`phantom::Jet`],
//!   [`phantom::StartingJet`]), CFD ([`phantom::CfdPhantom`], embedded solver output), analytic
//!   shapes with closed-form line integrals for tests, user volumes.
//! - [`rig`]: lens settings and camera layouts (ring, arc, Fibonacci sphere, explicit,
//!   subsets, jitter, held-out cameras).
//! - [`image`]: the pinhole and thin-lens image models.
//! - [`sensor`]: counts, Gaussian and photon noise, dark offset, quantisation.
//! - [`generate()`]: all of it from one [`SynthSettings`]; [`preset()`] names the standard sets.

mod error;
mod fastmath;
pub mod generate;
pub mod image;
pub mod phantom;
pub mod preset;
pub mod real;
pub mod rig;
pub mod sensor;

pub use error::SynthError;

/// The length unit of every synthetic scene: lengths (the box, the rig, the lens) are in mm.
pub const UNITS: &str = "mm";
pub use generate::{
    available_memory_bytes, generate, no_progress, Progress, SynthFrame, SynthSettings, SynthStats, Synthesis,
};
pub use image::{Emitters, ImageModel, PinholeSettings, ThinLensSettings};
pub use phantom::{
    analytic_image, CfdCase, CfdPhantom, GaussianBlob, Jet, JetParams, LineIntegral, Phantom, PhantomKind,
    PhantomSettings, Shape, ShapeSum, StartingJet, StartingJetParams, UniformBall, MAX_JET_PARAMETER,
    MAX_NOZZLE_DIAMETER_MM, MIN_JET_PARAMETER, MIN_NOZZLE_DIAMETER_MM,
};
pub use preset::{preset, presets, DEFAULT_PRESET};
pub use real::{RealLike, RealRecording};
pub use rig::{
    Jitter, Layout, LensSettings, RigCamera, RigSettings, RingAxis, Subset, MAX_CAMERAS, MAX_JITTER_ROTATION_DEG,
    MAX_START_DEG, MIN_IMAGE_SIDE,
};
pub use sensor::SensorSettings;
