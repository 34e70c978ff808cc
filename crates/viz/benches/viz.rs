//! Timings of the viz hot paths: marching cubes on a 128³ grid, a three-panel slice figure
//! and a convergence figure. Run with `cargo bench -p fluidnerf-viz` (prints figures).

use std::hint::black_box;
use std::time::Instant;

use fluidnerf_core::{Aabb, Volume};
use fluidnerf_viz::{
    comparison_groups, convergence_plots, encode_panels_png, encode_plots_png, encode_plots_svg, marching_cubes, slice,
    Axis, PanelStyle, RunHistory, Trace,
};
use glam::DVec3;

/// Best of `reps` runs, in milliseconds.
fn time_ms(reps: usize, mut f: impl FnMut()) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

#[allow(clippy::print_stdout)]
fn main() {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let vol = Volume::from_fn([128, 128, 128], aabb, |p| {
        (1.0 - p.length() + 0.05 * (8.0 * p.x).sin() * (6.0 * p.y).cos()) as f32
    });
    let mut tris = 0;
    let ms = time_ms(3, || tris = black_box(marching_cubes(&vol, 0.4)).triangles.len());
    println!("marching cubes 128³: {ms:.1} ms, {tris} triangles ({:.2} M triangles/s)", tris as f64 / ms / 1e3);

    let t = slice(&vol, Axis::Z, 0.0, "mm").expect("inside");
    let r = slice(&vol, Axis::Z, 0.1, "mm").expect("inside");
    let groups = comparison_groups(&t, &r, &PanelStyle::default());
    let mut bytes = 0;
    let ms = time_ms(3, || bytes = black_box(encode_panels_png(&groups).expect("draws")).len());
    println!("truth | recon | difference figure of 128² slices: {ms:.1} ms, {} kB PNG", bytes / 1000);

    let trace = |rate: f64| Trace {
        iteration: (0..2000).map(f64::from).collect(),
        time_s: (0..2000).map(|i| f64::from(i) * 0.01).collect(),
        value: (0..2000).map(|i| (-rate * f64::from(i)).exp() + 1e-3).collect(),
    };
    let runs: Vec<RunHistory> = (0..3)
        .map(|k| RunHistory {
            label: format!("run {k}"),
            loss_label: "loss".into(),
            loss: trace(0.002 * (k + 1) as f64),
            nrmse: Some(trace(0.001 * (k + 1) as f64)),
            ssim: None,
            kept: None,
        })
        .collect();
    let plots = convergence_plots(&runs);
    let ms = time_ms(3, || bytes = black_box(encode_plots_png(&plots, 2).expect("draws")).len());
    println!("convergence figure (4 plots × 3 runs × 2000 points): PNG {ms:.1} ms, {} kB", bytes / 1000);
    let ms = time_ms(3, || bytes = black_box(encode_plots_svg(&plots, 2).expect("draws")).len());
    println!("convergence figure: SVG {ms:.1} ms, {} kB", bytes / 1000);
}
