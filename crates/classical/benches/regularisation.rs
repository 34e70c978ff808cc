//! The cost of regularisation: seconds per iteration of SART, SART-Tikhonov (default λ, one
//! penalty step of two Laplacians) and SART-TV (20 TV steps), interleaved in one run so that the
//! ratios hold on a busy machine, and the Laplacian's throughput.
//!
//! Geometry as `projection.rs`: 15 cameras of 256 × 256 px on a planar ring around a 40 mm cube,
//! splat projector without subdivision, 128³ voxels, images projected from a smooth phantom.
//!
//! Run: `cargo bench --no-run -p fluidnerf-classical`, then the printed `regularisation-…`
//! executable with `--bench`.

#![allow(clippy::print_stdout)]

use std::time::Instant;

use fluidnerf_classical::{
    laplacian, sart, sart_tikhonov, sart_tv, Grid, Problem, SartParams, SplatProjector, Stopping, TikhonovParams,
    TvParams,
};
use fluidnerf_core::Aabb;
use glam::DVec3;

mod common;
use common::{per_iteration, ring, smooth_jet};

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let grid = Grid::with_resolution(Aabb::cube(DVec3::ZERO, 40.0), 128);
    let cams = ring(15, 256);
    let truth = smooth_jet(&grid);
    let splat = SplatProjector::new(grid, &cams, 1.0).expect("valid").with_subdivisions(1);
    let images = common::project_all(&splat, &truth.data);
    let problem = Problem::new(&splat, &images).expect("consistent");
    let stopping = Stopping { max_iterations: 3, plateau: None };
    println!("128^3 voxels, 15 views of 256^2 px, {} rayon threads", rayon::current_num_threads());

    let mut lap = vec![0f32; grid.len()];
    let t = Instant::now();
    for _ in 0..10 {
        laplacian(&grid, &truth.data, &mut lap);
    }
    let t_lap = t.elapsed().as_secs_f64() / 10.0;
    println!("laplacian: {:.4} s per pass, {:.0} M voxels/s", t_lap, grid.len() as f64 / t_lap / 1e6);

    let (mut s, mut k, mut v) = (Vec::new(), Vec::new(), Vec::new());
    // Interleaved, twice: the machine is shared, so each ratio compares neighbours in time.
    for _ in 0..2 {
        s.push(per_iteration(|on_iter| {
            sart(&problem, None, &SartParams { stopping, ..Default::default() }, on_iter).expect("runs");
        }));
        k.push(per_iteration(|on_iter| {
            sart_tikhonov(&problem, None, &TikhonovParams { stopping, ..Default::default() }, on_iter).expect("runs");
        }));
        v.push(per_iteration(|on_iter| {
            sart_tv(&problem, None, &TvParams { stopping, ..Default::default() }, on_iter).expect("runs");
        }));
    }
    let min = |x: &[f64]| x.iter().cloned().fold(f64::INFINITY, f64::min);
    let (s, k, v) = (min(&s), min(&k), min(&v));
    println!("SART:           {s:.3} s per iteration");
    println!("SART-Tikhonov:  {k:.3} s per iteration ({:.2}x SART)", k / s);
    println!("SART-TV:        {v:.3} s per iteration ({:.2}x SART)", v / s);
}
