//! [`RunEvent`]: what a run reports while it works, delivered to the caller's callback, which
//! can stop the run by returning `ControlFlow::Break(())` (the run then writes what it has and
//! reports [`crate::RunStatus::Interrupted`]).

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

/// One event of a run.
#[derive(Debug)]
pub enum RunEvent<'a> {
    /// Set-up is done and iterations start: at most `max_iterations` per window, `windows`
    /// windows (1 for static runs), from `start_iteration` (a resumed run's first).
    Started { method: Method, max_iterations: usize, windows: usize, start_iteration: usize },
    /// An iteration finished. `loss` is the training loss (neural: normalised pixels², Eq. 5.5)
    /// or the relative residual (voxel methods); `smoothed` the neural running mean.
    Iteration { window: Option<WindowPos>, iteration: usize, loss: f64, smoothed: Option<f64>, train_time_s: f64 },
    /// An evaluation: NRMSE against the ground truth over the truth sample, and/or the loss on
    /// the held-out views.
    Evaluation { window: Option<WindowPos>, iteration: usize, nrmse: Option<f64>, holdout: Option<f64> },
    /// A checkpoint was written.
    Checkpoint { path: &'a Path },
    /// A window of a time-resolved run finished.
    WindowFinished(WindowPos),
    /// Something the user should know; the run goes on.
    Warning(&'a str),
    /// Training is over; volumes, metrics and reports are being written.
    Writing,
}
