//! Classical algebraic tomography on a voxel grid: matrix-free projectors (forward and exact
//! adjoint) and the ART family of solvers, MLEM, and total-variation and Tikhonov regularised
//! SART.
//!
//! # Conventions
//! - Grid: [`Grid`] = dims `[nx, ny, nz]` + box, cell-centred voxels, x fastest (index
//!   `(k * ny + j) * nx + i`), the layout of [`fluidnerf_core::Volume`]; all voxel buffers are
//!   contiguous `f32` of [`Grid::len`] elements.
//! - Views: [`fluidnerf_core::Camera`]s (OpenCV axes, pixel centres at integers, distortion),
//!   images row-major `f32`, one per view, in the projector's view order.
//! - Imaging law: `pixel = intensity_scale × ∫ E ds` (the scene's `intensity_scale`, world
//!   units), the model of [`fluidnerf_core::render_image`], so reconstructions are in the units
//!   of the emission field itself.
//!
//! # Layout
//! - [`projector`]: the system matrix `A` of Eq. 2.20 applied per view ([`Projector`]):
//!   [`FootprintProjector`] (voxel-driven separable footprint, the default where it fits),
//!   [`SplatProjector`] (voxel-driven bilinear splat, the dissertation's) and [`RayProjector`]
//!   (ray-driven trilinear); the automatic choice is documented in [`projector`].
//! - [`solve`]: [`asart`], [`art`], [`sart`], [`mart`], [`smart`], [`mlem`], [`sart_tv`],
//!   [`sart_tikhonov`], all `fn(problem, init, &params, on_iter) -> Result<Report, SolveError>`.
//! - [`ClassicalMethod`]: the registry of methods (validate, memory, solve) and
//!   [`ProjectorConfig`], the projector settings every method shares.
//! - [`visual_hull`]: a support mask from dark pixels; [`estimate_memory`]: peak memory before
//!   a run.
//!
//! Equations are numbered as in the dissertation ("On the development of a Neural Radiance
//! Field technique for tomographic reconstruction applied to flow diagnostics", chapter 2.3).

mod axes;
mod error;
mod hull;
mod memory;
mod method;
pub mod projector;
pub mod solve;

pub use axes::{rows_shared_along, AxisShift};
pub use error::{ClassicalError, SolveError};
pub use hull::{dark_level, visual_hull, DEFAULT_HULL_NOISE_SIGMAS, DEFAULT_HULL_THRESHOLD};
pub use memory::{estimate_memory, Algorithm, MemoryEstimate};
pub use method::{
    voxel_footprint_px, ClassicalMethod, ProjectorConfig, MAX_PLATEAU_TOLERANCE, MAX_TIKHONOV_WEIGHT, MAX_TV_STEPS,
    MAX_TV_WEIGHT,
};
pub use projector::{
    update_in_stretches, FootprintProjector, Grid, Isa, Projector, ProjectorKind, RayProjector, SparseRows,
    SplatProjector, Update, AUTO_FOOTPRINT_MAX_PX,
};
pub use solve::{
    art, asart, laplacian, laplacian_norm2, mart, mlem, multilevel_order, sart, sart_tikhonov, sart_tv, smart,
    total_variation, ArtParams, AsartParams, IterState, MartParams, MlemParams, Plateau, Problem, Report, SartParams,
    SmartParams, StopReason, Stopping, TikhonovParams, TvParams, TvStepRule, ROW_CACHE_MIB,
};
