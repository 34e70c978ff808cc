//! Geometry, cameras, images, volumes and scenes: the vocabulary every other fluidnerf crate
//! speaks, plus the emission imaging model (line integrals of a scalar field along camera rays).
//!
//! # Conventions
//! - **World frame**: right-handed, in the scene's length unit (`Scene::units`, usually mm).
//!   Synthetic jets flow along +x.
//! - **Camera frame** (OpenCV): x right, y down, z forward (viewing direction).
//!   `Camera::world_from_camera` maps camera coordinates to world coordinates.
//! - **Pixels** (OpenCV): pixel `(col, row)` has its centre at the continuous image coordinate
//!   `(u, v) = (col, row)`; the top-left pixel covers `[-0.5, 0.5]²`. Importers of nerfstudio and
//!   COLMAP data (whose pixel centres sit at `+0.5`) convert on the way in.
//! - **Images**: [`Image`] is row-major f32, index `row * width + col`, linear intensity.
//! - **Volumes**: [`Volume`] is a dense, cell-centred f32 grid filling an [`Aabb`], x varying
//!   fastest: index `(k * ny + j) * nx + i` for voxel `(i, j, k)`; on disk as `.npy` of shape
//!   `(nz, ny, nx)`.
//! - **Precision**: camera geometry is f64 (distortion inversion needs it); hot loops over
//!   samples and voxels use f32.
//! - **Angles** are radians.

pub mod camera;
pub mod error;
pub mod field;
pub mod geometry;
pub mod image;
pub mod isa;
mod march;
pub mod number;
pub mod render;
pub mod scene;
pub mod volume;

/// The largest iteration cap a run may take (a run's `stopping.max_iterations`, a method's own
/// cap, a warm-started window's): 10⁹, a thousand times the 10⁶ that runs bounded by a time
/// budget take as their cap (`--max-iterations 1000000 --time-budget 90`), 40 000 times the
/// dissertation's 25 000. A cap of 2⁶⁴ − 1 overflowed the progress total of a run of several
/// windows (iterations per window × windows).
pub const MAX_ITERATIONS: usize = 1_000_000_000;

/// The most iterations a span of a run's schedule may take: a stopping rule's window and
/// smoothing (the neural methods' and the voxel methods' plateau), the hash grid's steps
/// between levels, the held-out interval and a run's intervals of evaluation, checkpoints and
/// gain refits, and its patience in evaluations. Ten million: ten times the 10⁶ iterations
/// that runs bounded by a time budget take as their cap, 400 times the dissertation's 25 000.
/// A longer span could never act within a run's cap, and a stopping window of 2⁶⁴ − 1
/// overflowed the rule's sums.
pub const MAX_ITERATION_SPAN: usize = 10_000_000;

pub use camera::{Camera, Distortion, Intrinsics, ThinLens, Visibility, MAX_INTRINSIC_PX};
pub use error::CoreError;
pub use field::{Baked, ScalarField, Support, SupportWalk};
pub use geometry::{Aabb, Ray};
pub use glam;
pub use image::Image;
pub use isa::Isa;
pub use number::{fixed, num, Num};
pub use render::{render_image, RenderSettings};
pub use scene::{Frame, Scene, TruthRef};
pub use volume::Volume;
