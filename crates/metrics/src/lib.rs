//! Reconstruction metrics: NRMSE (dissertation Eq. 6.18), PSNR, SSIM (Eq. 6.19, global and
//! windowed, 2D and 3D), per-region metrics along the jet axis, and reprojection metrics of
//! held-out camera images.
//!
//! # Conventions
//! - Every metric compares an **estimate** `E` (the reconstruction) with a **truth** `Ê`
//!   (ground truth, or a measured image), in that argument order.
//! - Arrays are f32 in the core crate's layouts: volumes x fastest
//!   (`data[(k * ny + j) * nx + i]`), images row-major. Sums accumulate in f64.
//! - The **data range** `R` of PSNR and SSIM defaults to the truth's `max − min`
//!   ([`data_range_of`]); a report states the value it used.
//! - Non-finite results are meaningful: NRMSE is NaN for an all-zero truth, PSNR is +∞ for a
//!   perfect estimate. In JSON both become `null`.

pub mod curve;
mod error;
pub mod pointwise;
pub mod region;
pub mod report;
pub mod reprojection;
pub mod ssim;

pub use curve::{NrmsePoint, TruthSample};
pub use error::MetricsError;
pub use pointwise::{
    data_range_of, data_range_problem, mse, nrmse, nrmse_undefined, psnr, MAX_DATA_RANGE, NRMSE_UNDEFINED,
};
pub use region::{default_regions, estimate_flow_axis, regions_flow_axis, FlowAxisFrom, Region};
pub use report::{
    evaluate_field, evaluate_volume, MetricsReport, RegionMetrics, StepMetrics, VolumeMetricOptions, VolumeMetrics,
    WHOLE_VOLUME,
};
pub use reprojection::{
    compare_images, reproject, reproject_all, Reprojection, ReprojectionMetrics, ReprojectionOptions,
};
pub use ssim::{ssim_2d, ssim_3d, ssim_global, SsimParams, SsimWindow};
