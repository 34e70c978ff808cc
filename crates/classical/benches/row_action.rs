//! ART and MART per iteration with every view's rows kept between iterations (the default
//! `row_cache_mib`) against building them again each iteration (`row_cache_mib = 0`),
//! interleaved twice in one run so that the ratios hold on a busy machine. Both give the same
//! volume bit for bit (`tests/classical/solvers.rs`).
//!
//! Geometry: 15 cameras of 128 × 128 px on a planar ring around a 40 mm cube (as
//! `projection.rs`), 64³ voxels, footprint projector, images projected from a smooth phantom.
//!
//! Run: `cargo bench -p fluidnerf-classical --bench row_action` (about a minute).

#![allow(clippy::print_stdout)]

use fluidnerf_classical::{
    art, mart, ArtParams, FootprintProjector, Grid, MartParams, Problem, Projector, Stopping, ROW_CACHE_MIB,
};
use fluidnerf_core::Aabb;
use glam::DVec3;

mod common;
use common::{per_iteration, ring, smooth_jet};

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let grid = Grid::with_resolution(Aabb::cube(DVec3::ZERO, 40.0), 64);
    let cams = ring(15, 128);
    let truth = smooth_jet(&grid);
    let projector = FootprintProjector::new(grid, &cams, 1.0).expect("valid");
    let images = common::project_all(&projector, &truth.data);
    let problem = Problem::new(&projector, &images).expect("consistent");
    let stopping = Stopping { max_iterations: 4, plateau: None };
    let kept: usize = (0..cams.len()).map(|v| projector.rows(v).bytes()).sum();
    println!(
        "64^3 voxels, 15 views of 128^2 px, footprint projector, {} rayon threads; every view's rows: {:.0} MB",
        rayon::current_num_threads(),
        kept as f64 / 1e6
    );
    // Seconds per iteration over iterations 2 to 4 (the first builds the kept rows).
    let seconds = |is_mart: bool, mib: u64| {
        per_iteration(|on_iter| {
            if is_mart {
                mart(&problem, None, &MartParams { stopping, row_cache_mib: mib, ..Default::default() }, on_iter)
            } else {
                art(&problem, None, &ArtParams { stopping, row_cache_mib: mib, ..Default::default() }, on_iter)
            }
            .expect("runs");
        })
    };
    let mut t = [[f64::INFINITY; 2]; 2];
    for _ in 0..2 {
        for (m, is_mart) in [false, true].into_iter().enumerate() {
            t[m][0] = t[m][0].min(seconds(is_mart, 0));
            t[m][1] = t[m][1].min(seconds(is_mart, ROW_CACHE_MIB));
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
