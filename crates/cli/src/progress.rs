//! Progress bars. Library crates report progress through callbacks; only the CLI draws.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use indicatif::{HumanDuration, ProgressBar, ProgressState, ProgressStyle};

static QUIET: AtomicBool = AtomicBool::new(false);

/// Suppresses all progress bars (`--quiet`).
pub fn set_quiet(quiet: bool) {
    QUIET.store(quiet, Ordering::Relaxed);
}

/// Whether `--quiet` was given.
pub fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// A bar over `len` steps labelled `what`; hidden with `--quiet` or when stderr is not a
/// terminal (indicatif's default draw target).
pub fn bar(len: u64, what: &str) -> ProgressBar {
    bar_until(len, what, &Deadline::default())
}

/// A time by which the work ends whatever its steps' rate says: a run's time budget. Set once
/// it is known; the bar's time left is then the sooner of the two.
#[derive(Clone, Default)]
pub struct Deadline(Arc<Mutex<Option<Instant>>>);

impl Deadline {
    pub fn set(&self, at: Instant) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(at);
    }

    fn left(&self) -> Option<Duration> {
        let at = (*self.0.lock().unwrap_or_else(|e| e.into_inner()))?;
        Some(at.saturating_duration_since(Instant::now()))
    }
}

/// [`bar`] whose time left is at most what `deadline` leaves.
pub fn bar_until(len: u64, what: &str, deadline: &Deadline) -> ProgressBar {
    if QUIET.load(Ordering::Relaxed) {
        return ProgressBar::hidden();
    }
    let deadline = deadline.clone();
    let eta = move |state: &ProgressState, w: &mut dyn std::fmt::Write| {
        let _ = w.write_str(&eta_text(state.per_sec(), state.eta(), deadline.left()));
    };
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{prefix:>12} [{bar:30}] {pos}/{len} {elapsed_precise} (eta {eta}) {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .with_key("eta", eta)
            .progress_chars("=> "),
    );
    pb.set_prefix(what.to_string());
    pb.enable_steady_tick(Duration::from_millis(250));
    pb
}

/// The bar's time left: `?` until a step has been timed (indicatif reads 0 s then, which a run
/// whose first iteration takes minutes showed for all of them), else the steps' estimate,
/// at most what a deadline leaves.
fn eta_text(steps_per_s: f64, by_rate: Duration, deadline_left: Option<Duration>) -> String {
    let by_rate = (steps_per_s > 0.0).then_some(by_rate);
    let left = match (by_rate, deadline_left) {
        (Some(r), Some(d)) => r.min(d),
        (r, d) => match r.or(d) {
            Some(t) => t,
            None => return "?".into(),
        },
    };
    let mut s = String::new();
    let _ = write!(s, "{:#}", HumanDuration(left));
    s
}

/// `field` sampled on a grid (as [`fluidnerf_core::Volume::from_field_averaged`]) under a bar
/// of its z-slices, labelled "sampling": a faithful network's field takes minutes at 256³.
///
/// A value that is infinite or NaN is refused: loading refuses such weights, so it comes from
/// finite weights so large that the field's arithmetic overflows (a damaged or edited weights
/// file), and written out it would pass for a reconstruction.
pub fn sampled(
    dims: [usize; 3],
    aabb: fluidnerf_core::Aabb,
    field: &dyn fluidnerf_core::ScalarField,
    time: f64,
    n: usize,
) -> anyhow::Result<fluidnerf_core::Volume> {
    let bar = bar(dims[2] as u64, "sampling");
    let volume = fluidnerf_core::Volume::from_field_averaged_with(dims, aabb, field, time, n, &|| bar.inc(1));
    bar.finish_and_clear();
    if let Some(first) = volume.data.iter().position(|v| !v.is_finite()) {
        let bad = volume.data[first..].iter().filter(|v| !v.is_finite()).count();
        let [nx, ny, _] = dims;
        let at = volume.voxel_centre(first % nx, (first / nx) % ny, first / (nx * ny));
        anyhow::bail!(
            "the field is {} at {bad} of the {} points it was sampled at on a {}×{}×{} grid (the first at ({:.3}, {:.3}, {:.3})): \
             its weights are finite but so large that its values overflow 32-bit floats; the weights file is damaged \
             or was edited",
            volume.data[first],
            volume.data.len(),
            dims[0],
            dims[1],
            dims[2],
            at.x,
            at.y,
            at.z
        );
    }
    Ok(volume)
}

/// A spinner with the time elapsed, for work whose steps are not counted, labelled `what`
/// with `msg`; hidden as [`bar`] is.
pub fn spinner(what: &str, msg: &str) -> ProgressBar {
    if QUIET.load(Ordering::Relaxed) {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{prefix:>12} {spinner} {elapsed_precise} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    pb.set_prefix(what.to_string());
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(Duration::from_millis(250));
    pb
}

/// A counter of steps whose number is not known in advance (frames decoded from a video),
/// labelled `what`, with the rate; hidden as [`bar`] is.
pub fn counter(what: &str, unit: &str) -> ProgressBar {
    if QUIET.load(Ordering::Relaxed) {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::no_length();
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{{prefix:>12}} {{spinner}} {{pos}} {unit} {{elapsed_precise}} ({{per_sec}}) {{msg}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    pb.set_prefix(what.to_string());
    pb.enable_steady_tick(Duration::from_millis(250));
    pb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_left_is_unknown_until_a_step_is_timed_and_a_deadline_bounds_it() {
        let s = Duration::from_secs;
        assert_eq!(eta_text(0.0, s(0), None), "?");
        assert_eq!(eta_text(2.0, s(90), None), eta_text(2.0, s(90), Some(s(3600))));
        assert_ne!(eta_text(2.0, s(3600), None), eta_text(2.0, s(3600), Some(s(90))));
        // Before a step is timed, a deadline still tells the most the work can take.
        assert_eq!(eta_text(0.0, s(0), Some(s(90))), eta_text(1.0, s(90), None));
    }
}
