//! Memory estimates, so a caller can refuse a run that will not fit before it starts.

use serde::{Deserialize, Serialize};

use crate::{Grid, ProjectorKind};

/// The classical algorithms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Algorithm {
    Asart,
    Art,
    Sart,
    Mart,
    Smart,
    Mlem,
    /// SART with total-variation steps.
    Tv,
    /// SART with second-order Tikhonov steps.
    Tikhonov,
}

impl Algorithm {
    /// Voxel-sized f32 buffers the solver holds, the result included.
    fn volume_buffers(self) -> usize {
        match self {
            Algorithm::Art | Algorithm::Mart => 1,
            Algorithm::Asart | Algorithm::Sart | Algorithm::Mlem | Algorithm::Smart => 3,
            Algorithm::Tikhonov => 4,
            Algorithm::Tv => 6,
        }
    }

    /// Whether the solver holds one view's rows of the matrix at a time.
    fn holds_rows(self) -> bool {
        matches!(self, Algorithm::Art | Algorithm::Mart | Algorithm::Smart)
    }
}

/// Estimated peak memory of a reconstruction, in bytes, by part.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MemoryEstimate {
    /// Solver volumes (result, work buffers, support mask).
    pub volumes: u64,
    /// Images and per-view caches.
    pub images: u64,
    /// Projector state and scratch (ray tables, per-thread accumulators, one view's rows).
    pub projector: u64,
}

impl MemoryEstimate {
    pub fn total(&self) -> u64 {
        self.volumes + self.images + self.projector
    }
}

/// Estimates the peak memory of running `algorithm` with a `projector` on `grid` and views of
/// `view_sizes` (width, height) with `threads` worker threads (`Auto` is estimated as the
/// footprint projector; [`crate::ProjectorConfig::resolve`] first for the exact choice) and,
/// for the splat, `subdivisions`
/// sub-voxels per axis ([`crate::SplatProjector::subdivisions`]), before anything is allocated.
/// The estimate is within tens of percent; the row-holding methods (ART, MART, SMART's setup)
/// are estimated for a ray step of half a voxel. ART and MART keep views' rows between
/// iterations up to `row_cache_bytes` (their `row_cache_mib`; 0 for the other methods), which
/// the estimate counts in full when every view's rows would exceed it.
pub fn estimate_memory(
    algorithm: Algorithm,
    projector: ProjectorKind,
    grid: &Grid,
    view_sizes: &[(usize, usize)],
    threads: usize,
    subdivisions: usize,
    row_cache_bytes: u64,
) -> MemoryEstimate {
    let n = grid.len() as u64;
    let pixels: u64 = view_sizes.iter().map(|&(w, h)| (w * h) as u64).sum();
    let max_view = view_sizes.iter().map(|&(w, h)| (w * h) as u64).max().unwrap_or(0);
    let threads = threads.max(1) as u64;
    let volumes = n * 4 * algorithm.volume_buffers() as u64 + n;
    // Data, a per-view cache (SART row sums, SMART row maxima) and two view-sized buffers;
    // MLEM and SMART hold every view's ratio image for one back projection of them all.
    let ratios = if matches!(algorithm, Algorithm::Mlem | Algorithm::Smart) { pixels * 4 } else { 0 };
    let images = pixels * 4 * 2 + max_view * 4 * 2 + ratios;
    let scratch = match projector {
        // Two padded images per thread and a padded copy for the back projection; the margins
        // are small next to the image at the voxel sizes the footprint is chosen for.
        // A back projection of all views at once (MLEM, SMART, the column sums of MART's
        // start) holds a padded copy of each.
        ProjectorKind::Auto | ProjectorKind::Footprint => {
            let all_views = matches!(algorithm, Algorithm::Mlem | Algorithm::Smart | Algorithm::Mart);
            (2 * threads + 1) * max_view * 4 * 5 / 4 + if all_views { pixels * 4 * 5 / 4 } else { 0 }
        }
        ProjectorKind::Splat => 2 * threads * max_view * 4,
        ProjectorKind::Ray => pixels * 32 + 2 * threads * n * 4,
    };
    let view_rows = if algorithm.holds_rows() {
        match projector {
            // About 3 × 3 pixels with a positive weight per voxel (voxels of 1–2 px).
            ProjectorKind::Auto | ProjectorKind::Footprint => n * 8 * 9 + max_view * 8,
            ProjectorKind::Splat => n * 4 * 8 * (subdivisions.max(1) as u64).pow(3) + max_view * 16,
            ProjectorKind::Ray => {
                // Samples per ray ≈ 2 × the grid's diagonal in voxels, ~4 distinct voxels each.
                let d = grid.dims.iter().map(|&v| (v * v) as f64).sum::<f64>().sqrt();
                (max_view as f64 * 2.0 * d * 4.0 * 8.0) as u64
            }
        }
    } else {
        0
    };
    let kept = match algorithm {
        Algorithm::Art | Algorithm::Mart => row_cache_bytes.min(view_rows * view_sizes.len() as u64),
        _ => 0,
    };
    MemoryEstimate { volumes, images, projector: scratch + view_rows + kept }
}
