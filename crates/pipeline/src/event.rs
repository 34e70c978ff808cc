//! [`RunEvent`]: what a run reports while it works, delivered to the caller's callback, which
//! can stop the run by returning `ControlFlow::Break(())` (the run then writes what it has and
//! reports [`crate::RunStatus::Interrupted`]).
//!
//! Stopping a run after its third iteration, then reading back what it wrote:
//!
//! ```
//! use std::ops::ControlFlow;
//! use fluidnerf_pipeline::load::LoadedRun;
//! use fluidnerf_pipeline::{reconstruct, Method, Overwrite, RunConfig, RunDir, RunEvent, RunStatus};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! # let tmp = tempfile::tempdir()?;
//! # let scene_dir = tmp.path().join("scene");
//! # fluidnerf_pipeline::testing::small_scene(&scene_dir)?;
//! let scene = fluidnerf_io::scene::load_scene(&scene_dir)?;
//! let mut config = RunConfig::new(&scene_dir, Method::Sart);
//! config.resolution = 8;
//! let dir = RunDir::create(tmp.path().join("run"), Overwrite::Refuse, Some(&scene.root))?;
//! let report = reconstruct(&scene, &config, &dir, |event| match event {
//!     RunEvent::Iteration { iteration: 3.., .. } => ControlFlow::Break(()),
//!     RunEvent::Warning(text) => {
//!         eprintln!("warning: {text}");
//!         ControlFlow::Continue(())
//!     }
//!     _ => ControlFlow::Continue(()),
//! })?;
//! assert_eq!(report.status, RunStatus::Interrupted);
//! assert_eq!(report.iterations, 3);
//! let run = LoadedRun::open(dir.root(), None)?;
//! assert_eq!(run.first_volume()?.dims, [8, 8, 8]);
//! # Ok(())
//! # }
//! ```

use std::path::Path;

use crate::Method;

/// Where in a time-resolved run an event happens.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WindowPos {
    /// 0-based window index.
    pub index: usize,
    pub count: usize,
    /// First and one-past-last frame of the window.
    pub frames: [usize; 2],
}

/// Steps of the fit to a start between two [`RunEvent::StartFit`].
pub const START_FIT_EVENT_EVERY: usize = 10;

/// One event of a run.
#[derive(Debug)]
pub enum RunEvent<'a> {
    /// Set-up is done and iterations start: at most `max_iterations` per window, `windows`
    /// windows (1 for static runs), from `start_iteration` (a resumed run's first). A run that
    /// starts from voxel reconstructions it runs itself (the hybrid, `--start-method`) first
    /// delivers each of those runs' events, from its own `Started` (naming the voxel method) to
    /// its `Writing`; stopping there stops the whole run.
    Started { method: Method, max_iterations: usize, windows: usize, start_iteration: usize },
    /// The field is being fitted to its start (a voxel reconstruction: the hybrid, `--start-from`,
    /// `--start-method`) before it trains on the images: `step` of `steps` Adam steps are done.
    /// Delivered every [`START_FIT_EVENT_EVERY`] steps and at the last one, in static runs.
    /// Stopping here ends the fit and the run after its first iteration, as a stop during the
    /// voxel start does.
    StartFit { step: usize, steps: usize },
    /// An iteration finished. `loss` is the training loss (neural: normalised pixels², Eq. 5.5)
    /// or the relative residual (voxel methods); `smoothed` the neural running mean.
    Iteration { window: Option<WindowPos>, iteration: usize, loss: f64, smoothed: Option<f64>, train_time_s: f64 },
    /// An evaluation: NRMSE against the ground truth over the truth sample, and/or the loss on
    /// the held-out views.
    Evaluation { window: Option<WindowPos>, iteration: usize, nrmse: Option<f64>, holdout: Option<f64> },
    /// How long the run will take, measured on its first iterations (emitted once, after at
    /// least three iterations and a second of training, or after ten seconds): the seconds per
    /// iteration so far, the iterations left under the iteration cap (every window counted),
    /// and the time they take, shortened to the time budget when one is set. The stopping rule
    /// may end the run sooner, so this is an upper bound.
    Estimate { seconds_per_iteration: f64, iterations_left: usize, seconds_left: f64, budget_limited: bool },
    /// A checkpoint was written.
    Checkpoint { path: &'a Path },
    /// A window of a time-resolved run finished.
    WindowFinished(WindowPos),
    /// Something the user should know; the run goes on.
    Warning(&'a str),
    /// Training is over; volumes, metrics and reports are being written.
    Writing,
}

impl RunEvent<'_> {
    /// A one-line account of an [`RunEvent::Estimate`] for people ("about 0.05 s per iteration,
    /// at most 1950 more iterations: at most 1 min 38 s"), `None` for other events.
    pub fn describe_estimate(&self) -> Option<String> {
        let RunEvent::Estimate { seconds_per_iteration, iterations_left, seconds_left, budget_limited } = self else {
            return None;
        };
        let per = duration(*seconds_per_iteration);
        if !*budget_limited {
            return Some(format!(
                "about {per} per iteration, at most {iterations_left} more iterations: at most {}",
                duration(*seconds_left)
            ));
        }
        // The budget, not the iteration cap, bounds the run: the iterations it leaves room for.
        // "at most 24999 more iterations: at most 0.000 s" said the cap's count beside a budget
        // already spent.
        let fit = (seconds_left / seconds_per_iteration).floor();
        if fit.is_nan() || fit < 1.0 {
            return Some(format!(
                "about {per} per iteration, more than is left of the time budget: the run stops after the iteration \
                 under way (an iteration is not cut short)"
            ));
        }
        let more = (fit as usize).min(*iterations_left);
        Some(format!(
            "about {per} per iteration, about {more} more iterations: at most {} (the time budget)",
            duration(*seconds_left)
        ))
    }
}

/// A duration for people: "0.052 s", "4.2 s", "38 s", "4 min 12 s", "3 h 05 min".
pub fn duration(seconds: f64) -> String {
    match seconds {
        s if !s.is_finite() => "unknown".into(),
        s if s < 1.0 => format!("{s:.3} s"),
        s if s < 10.0 => format!("{s:.1} s"),
        s if s < 60.0 => format!("{s:.0} s"),
        s if s < 3600.0 => format!("{} min {:02} s", (s / 60.0) as u64, (s % 60.0) as u64),
        s => format!("{} h {:02} min", (s / 3600.0) as u64, ((s % 3600.0) / 60.0) as u64),
    }
}
