//! ART and MART per iteration with every view's rows kept between iterations (the default
//! `row_cache_mib`) against building them again each iteration (`row_cache_mib = 0`),
//! interleaved twice in one run so that the ratios hold on a busy machine. Both give the same
//! volume bit for bit (`tests/solvers.rs`).
//!
//! Geometry: 15 cameras of 128 × 128 px on a planar ring around a 40 mm cube (as
//! `projection.rs`), 64³ voxels, footprint projector, images projected from a smooth phantom.
//!
//! Run: `cargo bench -p fluidnerf-classical --bench row_action` (about a minute).

#![allow(clippy::print_stdout)]

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{
    art, mart, ArtParams, FootprintProjector, Grid, MartParams, Problem, Projector, Stopping, ROW_CACHE_MIB,
};
use fluidnerf_core::{Aabb, Image};
use glam::DVec3;

mod common;
use common::ring;

/// Mean seconds per iteration over iterations 2 to 4 (the first builds the kept rows).
fn per_iteration(run: impl FnOnce(&mut dyn FnMut())) -> f64 {
    let mut stamps = Vec::new();
    run(&mut || stamps.push(Instant::now()));
    let d: Vec<f64> = stamps.windows(2).map(|w| (w[1] - w[0]).as_secs_f64()).collect();
    d.iter().sum::<f64>() / d.len().max(1) as f64
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let grid = Grid::with_resolution(Aabb::cube(DVec3::ZERO, 40.0), 64);
    let cams = ring(15, 128);
    let truth = fluidnerf_core::Volume::from_fn(grid.dims, grid.aabb, |p| {
        ((-(p.y * p.y + p.z * p.z) / 60.0).exp() * (1.0 + 0.3 * (p.x / 3.0).sin())) as f32
    });
    let projector = FootprintProjector::new(grid, &cams, 1.0).expect("valid");
    let images: Vec<Image> = (0..cams.len())
        .map(|v| {
            let mut im = Image::zeros(128, 128);
            projector.forward(v, &truth.data, &mut im.data);
            im
        })
        .collect();
    let problem = Problem::new(&projector, &images).expect("consistent");
    let stopping = Stopping { max_iterations: 4, plateau: None };
    let kept: usize = (0..cams.len()).map(|v| projector.rows(v).bytes()).sum();
    println!(
        "64^3 voxels, 15 views of 128^2 px, footprint projector, {} rayon threads; every view's rows: {:.0} MB",
        rayon::current_num_threads(),
        kept as f64 / 1e6
    );
    let tick_art = |mib: u64| {
        per_iteration(|tick| {
            art(&problem, None, &ArtParams { stopping, row_cache_mib: mib, ..Default::default() }, |_| {
                tick();
                ControlFlow::Continue(())
            })
            .expect("runs");
        })
    };
    let tick_mart = |mib: u64| {
        per_iteration(|tick| {
            mart(&problem, None, &MartParams { stopping, row_cache_mib: mib, ..Default::default() }, |_| {
                tick();
                ControlFlow::Continue(())
            })
            .expect("runs");
        })
    };
    let mut t = [[f64::INFINITY; 2]; 2];
    for _ in 0..2 {
        for (m, run) in [&tick_art as &dyn Fn(u64) -> f64, &tick_mart].iter().enumerate() {
            t[m][0] = t[m][0].min(run(0));
            t[m][1] = t[m][1].min(run(ROW_CACHE_MIB));
        }
    }
    for (m, name) in ["ART", "MART"].iter().enumerate() {
        let [built, kept] = t[m];
        println!(
            "{name:<5} rows built each iteration {built:.3} s, kept {kept:.3} s per iteration ({:.2}x)",
            built / kept
        );
    }
}
