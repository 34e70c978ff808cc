//! Memory of the `tr-fast` space–time field against the number of frames in one window, and of
//! a recording cut into windows (`cargo run --release -p fluidnerf-neural --example
//! temporal_memory`).
//!
//! Prints, for 3, 30 and 300 frames: the parameters of one field over all frames, its weight
//! bytes, its training bytes (weights + 2 Adam moments + one gradient buffer per thread, 2
//! threads), and, with the `tr-fast` windows (16 frames, overlap 4), the number of windows and
//! the bytes of all their weights on disk (training holds one window at a time).

use fluidnerf_neural::temporal::{fast_field_memory, temporal_preset};
use fluidnerf_neural::window::plan_windows;

#[allow(clippy::print_stdout)]
fn main() -> Result<(), fluidnerf_neural::NeuralError> {
    let cfg = temporal_preset("tr-fast").ok_or_else(|| fluidnerf_neural::NeuralError::invalid("preset", "tr-fast"))?;
    let (w, o) = (cfg.windows.frames, cfg.windows.overlap);
    println!("tr-fast: one space-time hash grid (time axis = one cell per frame interval), 2 threads");
    println!(
        "{:>7} {:>12} {:>12} {:>14} | {:>8} {:>16} {:>16}",
        "frames", "params", "weights MB", "training MB", "windows", "window train MB", "all weights MB"
    );
    for frames in [3usize, 30, 300] {
        let (params, weights, training) = fast_field_memory(frames, 2)?;
        let windows = plan_windows(frames, w, o).len();
        let (_, wb, wt) = fast_field_memory(frames.min(w), 2)?;
        println!(
            "{frames:>7} {params:>12} {:>12.2} {:>14.2} | {windows:>8} {:>16.2} {:>16.2}",
            weights as f64 / 1e6,
            training as f64 / 1e6,
            wt as f64 / 1e6,
            (windows * wb) as f64 / 1e6
        );
    }
    Ok(())
}
