//! Iterative solvers of `A g = p` (Eq. 2.20) for a non-negative emission field, all with one
//! shape:
//!
//! ```text
//! fn method(problem: &Problem, init: Option<&[f32]>, params: &MethodParams,
//!           on_iter: impl FnMut(&IterState) -> ControlFlow<()>) -> Result<Report, SolveError>
//! ```
//!
//! - `init`: a starting volume ([`crate::Grid::len`] values); `None` uses the method's own start.
//! - `on_iter` is called after every full iteration (every view visited once) with the
//!   residual and the current volume; returning `ControlFlow::Break(())` stops the solver,
//!   which returns the volume of that finished iteration.
//! - The residual of iteration k is the relative data misfit `‖p − A g‖₂ / ‖p‖₂` over all
//!   views, each view's (or row's) part measured just before that view (row) is used for an
//!   update during the sweep (for the simultaneous methods: of the volume entering the
//!   iteration). It is free to compute this way and is what the stopping rule watches.
//! - Stopping ([`Stopping`]): an iteration cap, and optionally the dissertation's plateau rule
//!   (§6.4.1): stop when the residual, smoothed by a sliding mean over 4 iterations, varies by
//!   less than 2 % over the last 20 iterations.
//! - Every method keeps the volume non-negative and, with a support mask
//!   ([`Problem::with_support`], e.g. a [`crate::visual_hull`]), zero outside it.
//!
//! Methods (dissertation chapter 2.3): [`asart`] (Eq. 2.29–2.30), [`art`] (2.21), [`sart`]
//! (2.27), [`mart`] (2.25), [`smart`] (2.28), [`mlem`] (2.33), [`sart_tv`] (SART with
//! total-variation steps, ASD-POCS style) and [`sart_tikhonov`] (SART with second-order
//! Tikhonov regularisation, Eq. 2.35).

mod art;
mod asart;
mod mlem;
mod sart;
mod tikhonov;
mod tv;

use std::ops::ControlFlow;

use fluidnerf_core::{Camera, Image};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use art::{art, mart, ArtParams, MartParams, ROW_CACHE_MIB};
pub use asart::{asart, AsartParams};
pub use mlem::{mlem, smart, MlemParams, SmartParams};
pub use sart::{sart, SartParams};
pub use tikhonov::{laplacian, laplacian_norm2, sart_tikhonov, TikhonovParams};
pub use tv::{sart_tv, total_variation, TvParams, TvStepRule};

use crate::{ClassicalError, Projector, SolveError};

/// The reconstruction problem: a projector (grid + cameras), one measured image per view, and
/// an optional support mask.
#[derive(Clone, Copy)]
pub struct Problem<'a> {
    pub projector: &'a dyn Projector,
    /// `images[v]` is view `v`'s data, `width × height` of its camera.
    pub images: &'a [Image],
    /// Voxels allowed to be non-zero ([`crate::Grid::len`] entries), if restricted.
    pub support: Option<&'a [bool]>,
}

impl std::fmt::Debug for Problem<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Problem")
            .field("grid", self.projector.grid())
            .field("views", &self.images.len())
            .field("support", &self.support.map(|s| s.iter().filter(|&&b| b).count()))
            .finish()
    }
}

impl<'a> Problem<'a> {
    /// Checks that there is one finite, non-negative image per view with the camera's size.
    pub fn new(projector: &'a dyn Projector, images: &'a [Image]) -> Result<Self, ClassicalError> {
        if images.len() != projector.n_views() {
            return Err(ClassicalError::invalid(
                "images",
                format!("{} images for {} views", images.len(), projector.n_views()),
            ));
        }
        for (v, (img, cam)) in images.iter().zip(projector.cameras()).enumerate() {
            if img.width != cam.width() || img.height != cam.height() {
                return Err(ClassicalError::invalid(
                    format!("image of view {v}"),
                    format!("is {}x{} but its camera is {}x{}", img.width, img.height, cam.width(), cam.height()),
                ));
            }
            if let Some((col, row)) = img.first_non_finite() {
                return Err(ClassicalError::NonFiniteImage { view: v, col, row });
            }
        }
        Ok(Problem { projector, images, support: None })
    }

    /// Restricts the volume to `support` (true = may be non-zero). Panics on a length mismatch.
    pub fn with_support(mut self, support: &'a [bool]) -> Self {
        assert_eq!(support.len(), self.projector.grid().len(), "support mask has the wrong length");
        self.support = Some(support);
        self
    }

    /// Zeroes voxels outside the support and clamps negatives.
    pub(crate) fn project_feasible(&self, x: &mut [f32]) {
        match self.support {
            Some(s) => {
                x.par_iter_mut().zip(s.par_iter()).for_each(|(v, &keep)| *v = if keep { v.max(0.0) } else { 0.0 })
            }
            None => x.par_iter_mut().for_each(|v| *v = v.max(0.0)),
        }
    }

    /// [`Problem::project_feasible`] of the voxels `x[at..at + xs.len()]`, given as `xs`.
    pub(crate) fn project_feasible_at(&self, at: usize, xs: &mut [f32]) {
        match self.support {
            Some(s) => {
                let n = xs.len();
                for (v, &keep) in xs.iter_mut().zip(&s[at..at + n]) {
                    *v = if keep { v.max(0.0) } else { 0.0 };
                }
            }
            None => xs.iter_mut().for_each(|v| *v = v.max(0.0)),
        }
    }

    fn data_norm2(&self) -> f64 {
        self.images.iter().flat_map(|im| &im.data).map(|&p| (p as f64) * (p as f64)).sum()
    }

    /// Largest pixel over all views.
    pub(crate) fn data_max(&self) -> f32 {
        self.images.iter().map(|im| im.min_max().1).fold(0f32, f32::max)
    }

    pub(crate) fn max_view_len(&self) -> usize {
        (0..self.projector.n_views()).map(|v| self.projector.view_len(v)).max().unwrap_or(0)
    }

    fn start(&self, init: Option<&[f32]>, default: impl FnOnce() -> Vec<f32>) -> Vec<f32> {
        let mut x = match init {
            Some(x0) => {
                assert_eq!(x0.len(), self.projector.grid().len(), "initial volume has the wrong length");
                x0.to_vec()
            }
            None => default(),
        };
        self.project_feasible(&mut x);
        x
    }
}

/// The state passed to `on_iter` after each iteration.
#[derive(Debug)]
pub struct IterState<'a> {
    /// Iterations finished so far (1 after the first).
    pub iteration: usize,
    /// Relative residual of this iteration (see the module docs).
    pub residual: f64,
    /// The current volume ([`crate::Grid::len`] values, x fastest).
    pub volume: &'a [f32],
}

/// Why a solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StopReason {
    /// The plateau rule was met.
    Converged,
    /// The iteration cap was reached.
    MaxIterations,
    /// `on_iter` asked to stop.
    Interrupted,
}

/// What a solver returns.
#[derive(Clone, Debug)]
pub struct Report {
    /// The reconstructed volume ([`crate::Grid::len`] values, x fastest).
    pub volume: Vec<f32>,
    /// Iterations finished.
    pub iterations: usize,
    /// The residual of each iteration, in order.
    pub residual_history: Vec<f64>,
    pub stop_reason: StopReason,
}

/// The dissertation's plateau stopping rule (§6.4.1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Plateau {
    /// Iterations over which the smoothed residual must vary less than `tolerance`, at most
    /// [`fluidnerf_core::MAX_ITERATION_SPAN`]. Default 20.
    pub window: usize,
    /// Width of the sliding mean that smooths the residual, at most
    /// [`fluidnerf_core::MAX_ITERATION_SPAN`]. Default 4.
    pub smoothing: usize,
    /// Largest relative variation, `(max − min) / mean` of the smoothed residual over the
    /// window, still counted as a plateau, at most [`crate::MAX_PLATEAU_TOLERANCE`]. Default 0.02.
    pub tolerance: f64,
}

impl Default for Plateau {
    fn default() -> Self {
        Plateau { window: 20, smoothing: 4, tolerance: 0.02 }
    }
}

impl Plateau {
    /// Whether `history` has reached the plateau.
    pub fn reached(&self, history: &[f64]) -> bool {
        let (w, s) = (self.window.max(1), self.smoothing.max(1));
        if history.len() < w + s - 1 {
            return false;
        }
        let smoothed: Vec<f64> = history.windows(s).map(|win| win.iter().sum::<f64>() / s as f64).collect();
        let last = &smoothed[smoothed.len() - w..];
        let (lo, hi) = last.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        let mean = last.iter().sum::<f64>() / w as f64;
        mean <= 0.0 || (hi - lo) / mean < self.tolerance
    }
}

/// When to stop.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Stopping {
    /// Iteration cap.
    pub max_iterations: usize,
    /// The plateau rule, if used.
    pub plateau: Option<Plateau>,
}

impl Default for Stopping {
    fn default() -> Self {
        Stopping { max_iterations: 50, plateau: Some(Plateau::default()) }
    }
}

impl Stopping {
    pub(crate) fn with_cap(max_iterations: usize) -> Self {
        Stopping { max_iterations, ..Default::default() }
    }
}

/// Runs iterations of `sweep` (which updates `x` and returns the iteration's sum of squared
/// residuals) until `stopping` or `on_iter` says stop.
pub(crate) fn drive(
    method: &'static str,
    problem: &Problem,
    stopping: &Stopping,
    mut x: Vec<f32>,
    mut sweep: impl FnMut(&mut Vec<f32>, usize) -> f64,
    mut on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
) -> Result<Report, SolveError> {
    let norm2 = problem.data_norm2();
    let norm2 = if norm2 > 0.0 { norm2 } else { 1.0 };
    let mut history = Vec::new();
    let mut stop_reason = StopReason::MaxIterations;
    for it in 0..stopping.max_iterations {
        let ss = sweep(&mut x, it);
        let residual = (ss / norm2).sqrt();
        if !residual.is_finite() {
            return Err(ClassicalError::Diverged { method, iteration: it + 1, residual });
        }
        history.push(residual);
        let state = IterState { iteration: it + 1, residual, volume: &x };
        if on_iter(&state).is_break() {
            stop_reason = StopReason::Interrupted;
            break;
        }
        if stopping.plateau.is_some_and(|p| p.reached(&history)) {
            stop_reason = StopReason::Converged;
            break;
        }
    }
    log::debug!("{method}: {} iterations, stopped: {stop_reason:?}", history.len());
    Ok(Report { volume: x, iterations: history.len(), residual_history: history, stop_reason })
}

/// Orders views so that each next view is as different as possible from those already used:
/// the multilevel access scheme (Guan & Gordon 1994) that ASART adopts, generalised to any
/// pose. Views are lines of sight (a view and its opposite carry nearly the same information),
/// so the distance between views is the angle between their lines to the box centre, in
/// [0°, 90°]; each step picks the view farthest from all chosen ones (lowest index on ties).
/// For an evenly spaced ring this gives the classic 0°, 90°, 45°, 135°, … sequence.
pub fn multilevel_order(cameras: &[Camera], centre: DVec3) -> Vec<usize> {
    let dirs: Vec<DVec3> =
        cameras.iter().map(|c| (centre - c.centre()).try_normalize().unwrap_or_else(|| c.forward())).collect();
    let n = dirs.len();
    let mut order = Vec::with_capacity(n);
    let mut used = vec![false; n];
    // Smallest |cos| to any chosen view (larger = farther); starts at "infinitely far".
    let mut closeness = vec![0f64; n];
    for step in 0..n {
        let next = if step == 0 {
            0
        } else {
            let mut best = usize::MAX;
            for v in 0..n {
                if !used[v] && (best == usize::MAX || closeness[v] < closeness[best] - 1e-12) {
                    best = v;
                }
            }
            best
        };
        used[next] = true;
        order.push(next);
        for v in 0..n {
            closeness[v] = closeness[v].max(dirs[v].dot(dirs[next]).abs());
        }
    }
    order
}

/// Sum over all views of the column sums `Σ_i w_ij` ([`Projector::back_add`] of ones).
pub(crate) fn total_column_sums(problem: &Problem) -> Vec<f32> {
    let p = problem.projector;
    let mut cs = vec![0f32; p.grid().len()];
    let views: Vec<usize> = (0..p.n_views()).collect();
    let ones: Vec<Vec<f32>> = views.iter().map(|&v| vec![1f32; p.view_len(v)]).collect();
    let ys: Vec<&[f32]> = ones.iter().map(Vec::as_slice).collect();
    p.back_add_views(&views, &ys, &mut cs, None);
    cs
}

/// A small positive floor for ratios `p / q`, relative to the data.
pub(crate) fn ratio_floor(problem: &Problem) -> f32 {
    (problem.data_max() * 1e-6).max(f32::MIN_POSITIVE)
}

/// A projector given by small dense matrices, one per view, for answers worked out by hand.
#[cfg(test)]
pub(crate) mod dense {
    use fluidnerf_core::{Aabb, Camera, Image, Intrinsics};
    use glam::DVec3;

    use crate::{Grid, Projector, SparseRows};

    /// View `v` is `matrices[v]` (one row per pixel of a one-row image) on a row of voxels.
    pub(crate) struct Dense {
        grid: Grid,
        cameras: Vec<Camera>,
        matrices: Vec<Vec<Vec<f32>>>,
    }

    impl Dense {
        /// Views on a ring around `x` (so the multilevel order of two views is 0, 1).
        pub(crate) fn new(voxels: usize, matrices: Vec<Vec<Vec<f32>>>) -> Self {
            let grid = Grid::new([voxels, 1, 1], Aabb::cube(DVec3::ZERO, 2.0));
            let n = matrices.len();
            let cameras = matrices
                .iter()
                .enumerate()
                .map(|(v, a)| {
                    assert!(a.iter().all(|row| row.len() == voxels), "view {v}: rows of {voxels} weights");
                    let k = Intrinsics {
                        width: a.len() as u32,
                        height: 1,
                        fx: 10.0,
                        fy: 10.0,
                        cx: 0.0,
                        cy: 0.0,
                        skew: 0.0,
                    };
                    let t = v as f64 * std::f64::consts::PI / n as f64;
                    Camera::look_at(k, DVec3::new(0.0, 6.0 * t.cos(), 6.0 * t.sin()), DVec3::ZERO, DVec3::X)
                })
                .collect();
            Dense { grid, cameras, matrices }
        }

        /// One image per view from its pixel values.
        pub(crate) fn images(&self, data: &[&[f32]]) -> Vec<Image> {
            data.iter().map(|d| Image { width: d.len(), height: 1, data: d.to_vec() }).collect()
        }
    }

    impl Projector for Dense {
        fn grid(&self) -> &Grid {
            &self.grid
        }

        fn cameras(&self) -> &[Camera] {
            &self.cameras
        }

        fn forward(&self, view: usize, x: &[f32], out: &mut [f32]) {
            for (o, row) in out.iter_mut().zip(&self.matrices[view]) {
                *o = row.iter().zip(x).map(|(w, g)| w * g).sum();
            }
        }

        fn back_add(&self, view: usize, y: &[f32], out: &mut [f32], mut col_sums: Option<&mut [f32]>) {
            for (row, &yi) in self.matrices[view].iter().zip(y) {
                for (j, &w) in row.iter().enumerate() {
                    out[j] += w * yi;
                    if let Some(c) = col_sums.as_deref_mut() {
                        c[j] += w;
                    }
                }
            }
        }

        fn rows(&self, view: usize) -> SparseRows {
            let mut rows = SparseRows { ptr: vec![0], cols: Vec::new(), vals: Vec::new() };
            for row in &self.matrices[view] {
                for (j, &w) in row.iter().enumerate() {
                    if w != 0.0 {
                        rows.cols.push(j as u32);
                        rows.vals.push(w);
                    }
                }
                rows.ptr.push(rows.cols.len() as u64);
            }
            rows
        }

        fn rows_bytes_estimate(&self, _view: usize) -> usize {
            0
        }

        fn bytes(&self) -> usize {
            0
        }

        fn scratch_bytes(&self, _view: usize) -> usize {
            0
        }
    }

    /// `a` and `b` agree to `tol` entry by entry.
    pub(crate) fn assert_close(a: &[f32], b: &[f32], tol: f32) {
        assert_eq!(a.len(), b.len(), "{a:?} vs {b:?}");
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= tol, "{a:?} vs {b:?}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::dense::Dense;
    use super::*;
    use fluidnerf_core::Intrinsics;

    #[test]
    fn multilevel_order_of_a_ring() {
        let k = Intrinsics { width: 8, height: 8, fx: 10.0, fy: 10.0, cx: 3.5, cy: 3.5, skew: 0.0 };
        // 8 cameras over 180°: lines of sight 0°, 22.5°, …, 157.5°.
        let cams: Vec<Camera> = (0..8)
            .map(|i| {
                let a = i as f64 * std::f64::consts::PI / 8.0;
                Camera::look_at(k, DVec3::new(0.0, 10.0 * a.cos(), 10.0 * a.sin()), DVec3::ZERO, DVec3::X)
            })
            .collect();
        let order = multilevel_order(&cams, DVec3::ZERO);
        assert_eq!(&order[..4], &[0, 4, 2, 6]);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..8).collect::<Vec<_>>());
    }

    #[test]
    fn plateau_rule() {
        let p = Plateau::default();
        let falling: Vec<f64> = (0..40).map(|i| 1.0 / (1.0 + i as f64)).collect();
        assert!(!p.reached(&falling));
        let mut flat = falling.clone();
        flat.extend(std::iter::repeat_n(0.02, 24));
        assert!(p.reached(&flat));
        assert!(!p.reached(&[0.1; 10]));
    }

    /// The plateau rule judges as soon as the history holds a window of smoothed values
    /// (`window + smoothing − 1` iterations), and a residual of zero is a plateau.
    #[test]
    fn the_plateau_is_judged_from_the_first_full_window() {
        let p = Plateau { window: 3, smoothing: 2, tolerance: 0.1 };
        assert!(p.reached(&[0.5, 0.5, 0.5, 0.5]));
        assert!(!p.reached(&[0.5, 0.5, 0.5]));
        assert!(p.reached(&[0.0; 4]));
        // Smoothed 1.0, 0.95, 0.95: a variation of 0.05 / 0.9667 ≈ 5 % < 10 %.
        assert!(p.reached(&[1.0, 1.0, 0.9, 1.0]));
        // Smoothed 1.0, 0.75, 0.75: 0.25 / 0.8333 = 30 %.
        assert!(!p.reached(&[1.0, 1.0, 0.5, 1.0]));
        // The window is the last `window` smoothed values: an early drop is forgotten.
        assert!(p.reached(&[5.0, 1.0, 1.0, 1.0, 1.0, 1.0]));
    }

    /// The driver reports the residual ‖p − A g‖ / ‖p‖ from the sweep's sum of squares, stops
    /// at the cap, when asked, or on the plateau, and refuses a residual that is not finite.
    #[test]
    fn the_driver_reports_residuals_and_why_it_stopped() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 2.0]]]);
        let images = dense.images(&[&[4.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let capped = Stopping { max_iterations: 3, plateau: None };
        let r =
            drive("test", &problem, &capped, vec![0.0; 2], |_, it| [16.0, 4.0, 1.0][it], |_| ControlFlow::Continue(()))
                .expect("finite");
        assert_eq!(r.residual_history, vec![1.0, 0.5, 0.25]);
        assert_eq!((r.iterations, r.stop_reason), (3, StopReason::MaxIterations));
        let mut seen = Vec::new();
        let r = drive(
            "test",
            &problem,
            &capped,
            vec![0.0; 2],
            |x, _| {
                x[0] += 1.0;
                16.0
            },
            |s| {
                seen.push((s.iteration, s.volume[0]));
                if s.iteration == 2 {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            },
        )
        .expect("finite");
        assert_eq!(seen, vec![(1, 1.0), (2, 2.0)]);
        assert_eq!((r.iterations, r.stop_reason, r.volume[0]), (2, StopReason::Interrupted, 2.0));
        let flat = Stopping { max_iterations: 100, plateau: Some(Plateau { window: 3, smoothing: 2, tolerance: 0.1 }) };
        let r =
            drive("test", &problem, &flat, vec![0.0; 2], |_, _| 4.0, |_| ControlFlow::Continue(())).expect("finite");
        assert_eq!((r.iterations, r.stop_reason), (4, StopReason::Converged));
        let err = drive(
            "test",
            &problem,
            &capped,
            vec![0.0; 2],
            |_, it| if it == 1 { f64::NAN } else { 1.0 },
            |_| ControlFlow::Continue(()),
        )
        .expect_err("diverges");
        assert!(matches!(err, ClassicalError::Diverged { method: "test", iteration: 2, .. }), "{err}");
    }

    /// Images that are all zero are a valid problem: the residual is then the absolute misfit.
    #[test]
    fn dark_images_give_a_finite_residual() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 2.0]]]);
        let images = dense.images(&[&[0.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let capped = Stopping { max_iterations: 1, plateau: None };
        let r =
            drive("test", &problem, &capped, vec![0.0; 2], |_, _| 9.0, |_| ControlFlow::Continue(())).expect("finite");
        assert_eq!(r.residual_history, vec![3.0]);
        assert_eq!(ratio_floor(&problem), f32::MIN_POSITIVE);
    }

    /// The feasible set: non-negative everywhere, zero outside the support.
    #[test]
    fn feasibility_clamps_negatives_and_clears_what_the_support_excludes() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 1.0, 1.0]]]);
        let images = dense.images(&[&[-2.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        let mut x = vec![-1.0, 2.0, 3.0];
        problem.project_feasible(&mut x);
        assert_eq!(x, [0.0, 2.0, 3.0]);
        let support = [true, false, true];
        let mut x = vec![-1.0, 2.0, 3.0];
        problem.with_support(&support).project_feasible(&mut x);
        assert_eq!(x, [0.0, 0.0, 3.0]);
        assert_eq!(problem.data_max(), 0.0, "the largest pixel is floored at zero");
        let debug = format!("{:?}", problem.with_support(&support));
        assert!(debug.contains("views: 1") && debug.contains("support: Some(2)"), "{debug}");
    }

    #[test]
    #[should_panic(expected = "support mask has the wrong length")]
    fn a_support_of_the_wrong_length_is_refused() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 1.0, 1.0]]]);
        let images = dense.images(&[&[1.0]]);
        let _ = Problem::new(&dense, &images).expect("consistent").with_support(&[true; 2]);
    }

    /// Images are checked against the views: count, size and finite values.
    #[test]
    fn images_that_do_not_fit_the_views_are_refused() {
        let dense = Dense::new(2, vec![vec![vec![1.0, 0.0], vec![0.0, 1.0]], vec![vec![1.0, 1.0]]]);
        assert!(Problem::new(&dense, &dense.images(&[&[1.0, 1.0], &[2.0]])).is_ok());
        assert!(Problem::new(&dense, &dense.images(&[&[1.0, 1.0]])).is_err());
        assert!(Problem::new(&dense, &dense.images(&[&[1.0], &[2.0]])).is_err());
        let err = Problem::new(&dense, &dense.images(&[&[1.0, 1.0], &[f32::NAN]])).unwrap_err();
        assert!(matches!(err, ClassicalError::NonFiniteImage { view: 1, col: 0, row: 0 }), "{err}");
    }

    /// The column sums add every view's weights.
    #[test]
    fn column_sums_add_every_views_weights() {
        let dense = Dense::new(3, vec![vec![vec![1.0, 0.5, 0.0], vec![0.0, 2.0, 0.0]], vec![vec![3.0, 0.0, 0.0]]]);
        let images = dense.images(&[&[0.0, 0.0], &[0.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        assert_eq!(total_column_sums(&problem), vec![4.0, 2.5, 0.0]);
        assert_eq!(problem.max_view_len(), 2);
        let images = dense.images(&[&[1.0, 4.0], &[2.0]]);
        let problem = Problem::new(&dense, &images).expect("consistent");
        assert_eq!(ratio_floor(&problem), 4e-6);
    }
}
