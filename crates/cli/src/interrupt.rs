//! Ctrl-C handling: the first Ctrl-C asks long runs to stop after the current iteration (they
//! then write a usable result); a second one exits at once. SIGTERM and SIGHUP are taken as
//! Ctrl-C: a batch scheduler's time limit (Slurm sends SIGTERM, then SIGKILL after a grace
//! period) or a closed terminal stopped a run without its results, and one that had not yet
//! reached its first checkpoint could not be resumed.

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Installs the handler. Safe to call more than once.
pub fn install() {
    // An error means a handler is already installed, which is fine.
    let _ = ctrlc::set_handler(|| {
        if REQUESTED.swap(true, Ordering::SeqCst) {
            // Exiting runs no destructor: the files being written would stay half-written
            // beside their targets.
            fluidnerf_io::remove_unfinished_writes();
            #[allow(clippy::print_stderr)]
            {
                eprintln!(
                    "aborted: the current iteration's results were not written; a neural run keeps its last \
                     checkpoint, which `fluidnerf reconstruct -o OUT --resume` continues"
                );
            }
            std::process::exit(130);
        }
        log::warn!("interrupted: finishing the current iteration and writing results (Ctrl-C again to abort)");
    });
}

/// Whether the user asked to stop.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}
