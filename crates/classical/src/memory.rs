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
    /// Every algorithm, in the order of the enum.
    pub const ALL: [Algorithm; 8] = [
        Algorithm::Asart,
        Algorithm::Art,
        Algorithm::Sart,
        Algorithm::Mart,
        Algorithm::Smart,
        Algorithm::Mlem,
        Algorithm::Tv,
        Algorithm::Tikhonov,
    ];

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
    /// The sum of the parts, saturating at `u64::MAX` (a request beyond any memory).
    pub fn total(&self) -> u64 {
        self.volumes.saturating_add(self.images).saturating_add(self.projector)
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
    // Saturating throughout: a request too large for any memory is estimated at `u64::MAX`,
    // which every caller refuses, instead of wrapping round to a small estimate.
    let mul = |factors: &[u64]| factors.iter().fold(1u64, |acc, &f| acc.saturating_mul(f));
    let add = |terms: &[u64]| terms.iter().fold(0u64, |acc, &t| acc.saturating_add(t));
    let n = mul(&grid.dims.map(|d| d as u64));
    let view = |&(w, h): &(usize, usize)| mul(&[w as u64, h as u64]);
    let pixels = add(&view_sizes.iter().map(view).collect::<Vec<_>>());
    let max_view = view_sizes.iter().map(view).max().unwrap_or(0);
    let threads = threads.max(1) as u64;
    let volumes = add(&[mul(&[n, 4, algorithm.volume_buffers() as u64]), n]);
    // Data, a per-view cache (SART row sums, SMART row maxima) and two view-sized buffers;
    // MLEM and SMART hold every view's ratio image for one back projection of them all.
    let ratios = if matches!(algorithm, Algorithm::Mlem | Algorithm::Smart) { mul(&[pixels, 4]) } else { 0 };
    let images = add(&[mul(&[pixels, 4, 2]), mul(&[max_view, 4, 2]), ratios]);
    // A padded copy: 5/4 of the image.
    let padded = |bytes: u64| bytes.saturating_add(bytes / 4);
    let scratch = match projector {
        // Two padded images per thread and a padded copy for the back projection; the margins
        // are small next to the image at the voxel sizes the footprint is chosen for.
        // A back projection of all views at once (MLEM, SMART, the column sums of MART's
        // start) holds a padded copy of each.
        ProjectorKind::Auto | ProjectorKind::Footprint => {
            let all_views = matches!(algorithm, Algorithm::Mlem | Algorithm::Smart | Algorithm::Mart);
            add(&[
                padded(mul(&[threads.saturating_mul(2).saturating_add(1), max_view, 4])),
                if all_views { padded(mul(&[pixels, 4])) } else { 0 },
            ])
        }
        ProjectorKind::Splat => mul(&[2, threads, max_view, 4]),
        ProjectorKind::Ray => add(&[mul(&[pixels, 32]), mul(&[2, threads, n, 4])]),
    };
    let view_rows = if algorithm.holds_rows() {
        match projector {
            // About 3 × 3 pixels with a positive weight per voxel (voxels of 1–2 px).
            ProjectorKind::Auto | ProjectorKind::Footprint => add(&[mul(&[n, 8, 9]), mul(&[max_view, 8])]),
            ProjectorKind::Splat => {
                let sub = subdivisions.max(1) as u64;
                add(&[mul(&[n, 4, 8, sub, sub, sub]), mul(&[max_view, 16])])
            }
            ProjectorKind::Ray => {
                // Samples per ray ≈ 2 × the grid's diagonal in voxels, ~4 distinct voxels each
                // (a float past `u64::MAX` converts to it).
                let d = grid.dims.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>().sqrt();
                (max_view as f64 * 2.0 * d * 4.0 * 8.0) as u64
            }
        }
    } else {
        0
    };
    let kept = match algorithm {
        Algorithm::Art | Algorithm::Mart => row_cache_bytes.min(mul(&[view_rows, view_sizes.len() as u64])),
        _ => 0,
    };
    MemoryEstimate { volumes, images, projector: add(&[scratch, view_rows, kept]) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::Aabb;
    use glam::DVec3;

    const PROJECTORS: [ProjectorKind; 4] =
        [ProjectorKind::Auto, ProjectorKind::Footprint, ProjectorKind::Splat, ProjectorKind::Ray];

    /// How the estimate depends on the method: the volume buffers each holds, the ratio
    /// images of MLEM and SMART, one view's rows for ART, MART and SMART, and the rows ART and
    /// MART keep, up to their budget; the total is the sum of the parts.
    #[test]
    fn each_method_is_charged_for_what_it_holds() {
        let grid = Grid::new([16, 16, 16], Aabb::cube(DVec3::ZERO, 1.0));
        let n = grid.len() as u64;
        let views = vec![(32usize, 32usize); 4];
        let pixels = 4 * 32 * 32;
        let e = |a, p, cache| estimate_memory(a, p, &grid, &views, 4, 2, cache);
        for p in PROJECTORS {
            let sart = e(Algorithm::Sart, p, 0);
            // The result, two work buffers and the support mask.
            assert_eq!(sart.volumes, 3 * 4 * n + n, "{p:?}");
            assert_eq!(sart.total(), sart.volumes + sart.images + sart.projector);
            assert_eq!(e(Algorithm::Art, p, 0).volumes, 4 * n + n);
            assert_eq!(e(Algorithm::Tikhonov, p, 0).volumes, 4 * 4 * n + n);
            assert_eq!(e(Algorithm::Tv, p, 0).volumes, 6 * 4 * n + n);
            assert_eq!(e(Algorithm::Asart, p, 0), sart, "{p:?}");
            for a in [Algorithm::Mlem, Algorithm::Smart] {
                assert_eq!(e(a, p, 0).images, sart.images + 4 * pixels, "{a:?} {p:?}");
            }
            for a in [Algorithm::Asart, Algorithm::Art, Algorithm::Mart, Algorithm::Tv, Algorithm::Tikhonov] {
                assert_eq!(e(a, p, 0).images, sart.images, "{a:?} {p:?}");
            }
            // One view's rows, and as many as fit of every view's.
            let one = e(Algorithm::Art, p, 0).projector - sart.projector;
            assert!(one > 0, "{p:?}");
            assert_eq!(e(Algorithm::Art, p, 1000).projector, sart.projector + one + 1000, "{p:?}");
            assert_eq!(e(Algorithm::Art, p, u64::MAX).projector, sart.projector + one + 4 * one, "{p:?}");
            assert_eq!(e(Algorithm::Smart, p, u64::MAX).projector, e(Algorithm::Mlem, p, 0).projector + one, "{p:?}");
            assert_eq!(e(Algorithm::Tv, p, u64::MAX).projector, sart.projector, "{p:?}");
        }
        // Per-thread scratch: more threads, more memory; no threads count as one.
        for p in PROJECTORS {
            let threads = |t| estimate_memory(Algorithm::Sart, p, &grid, &views, t, 2, 0).projector;
            assert!(threads(8) > threads(4), "{p:?}");
            assert_eq!(threads(0), threads(1), "{p:?}");
        }
        // The splat's rows grow with the cube of its sub-voxels.
        let rows = |sub| {
            estimate_memory(Algorithm::Art, ProjectorKind::Splat, &grid, &views, 4, sub, 0).projector
                - estimate_memory(Algorithm::Sart, ProjectorKind::Splat, &grid, &views, 4, sub, 0).projector
        };
        assert_eq!(rows(2) - rows(1), 7 * 4 * 8 * n);
    }

    /// Grids and images too large for any memory saturate the estimate at `u64::MAX`, which
    /// every caller refuses, instead of overflowing (a panic) or wrapping round to a small
    /// estimate that let the run start.
    #[test]
    fn absurd_requests_saturate_instead_of_wrapping() {
        let aabb = Aabb::cube(DVec3::ZERO, 1.0);
        let huge_grid = Grid::new([1 << 21, 1 << 21, 1 << 21], aabb);
        let small_grid = Grid::new([16, 16, 16], aabb);
        let huge_views = vec![(1usize << 31, 1usize << 31); 4];
        let small_views = vec![(32usize, 32usize); 4];
        for algorithm in Algorithm::ALL {
            for projector in PROJECTORS {
                for (grid, views) in [(&huge_grid, &small_views), (&small_grid, &huge_views)] {
                    let e = estimate_memory(algorithm, projector, grid, views, 64, 1 << 10, u64::MAX);
                    assert_eq!(e.total(), u64::MAX, "{algorithm:?} {projector:?} {:?} {:?}", grid.dims, views[0]);
                }
                let e = estimate_memory(algorithm, projector, &small_grid, &small_views, 4, 2, 0);
                assert!(e.total() > 0 && e.total() < 1 << 30, "{algorithm:?} {projector:?}: {e:?}");
            }
        }
    }
}
