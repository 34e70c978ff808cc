//! Projection and ASART speed: the separable-footprint projector against the sub-voxel splat
//! (what `SplatProjector::new` chooses on its own, the projector in use before the footprint),
//! measured in one run so that the ratios hold on a busy machine.
//!
//! Geometries (40 mm cube; cameras on a ring of radius 360 mm around the x axis, a 48 mm field of
//! view at the centre, as the dissertation's planar ring scaled down):
//! - `15 x 256^2`: 15 cameras of 256 × 256 px (voxels image at 3.3 px at 64³, 1.7 px at 128³);
//! - `90 x 128^2`: a 90-view ring (every 4°) of 128 × 128 px (1.7 px at 64³, 0.8 px at 128³),
//!   the geometry of `scripts/bench/mbirjax_compare.py`.
//!
//! For each geometry and 64³, 128³: M voxel-views per second forward and back (`back_add`
//! without column sums) for both projectors and the ratio new/old, best of three; the splat
//! is timed on a subset of the views when all of them would take long (the rate is per voxel and
//! view either way). Then seconds per ASART iteration at 64³ with 15 views of 256² px for both.
//!
//! Run: `cargo bench -p fluidnerf-classical --bench projection` (about two minutes). With
//! `--json` only one JSON line is printed, the figures of the footprint projector on the 90-view
//! ring, for the comparison script.

#![allow(clippy::print_stdout)]

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{asart, AsartParams, FootprintProjector, Grid, Problem, Projector, SplatProjector, Stopping};
use fluidnerf_core::{Aabb, Camera, Image};
use glam::DVec3;

mod common;
use common::ring;

/// A dense, smooth test volume (every voxel non-zero, so no work is skipped).
fn phantom(grid: &Grid) -> Vec<f32> {
    let v = fluidnerf_core::Volume::from_fn(grid.dims, grid.aabb, |p| {
        (0.2 + (-(p.y * p.y + p.z * p.z) / 60.0).exp() * (1.0 + 0.3 * (p.x / 3.0).sin())) as f32
    });
    v.data
}

fn time<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = Instant::now();
    let r = f();
    (r, t.elapsed().as_secs_f64())
}

/// Best of `reps` runs: the machine may be shared, the minimum is the least disturbed run.
fn best(reps: usize, f: &mut dyn FnMut()) -> f64 {
    (0..reps).map(|_| time(&mut *f).1).fold(f64::INFINITY, f64::min)
}

/// Forward and back rates (voxel-views per second) of `p` over its first `views` views.
fn rates(p: &dyn Projector, x: &[f32], views: usize, reps: usize) -> (f64, f64) {
    let mut imgs: Vec<Vec<f32>> = (0..views).map(|v| vec![0f32; p.view_len(v)]).collect();
    let t_fwd = best(reps, &mut || {
        for (v, img) in imgs.iter_mut().enumerate() {
            p.forward(v, x, img);
        }
    });
    let mut back = vec![0f32; x.len()];
    let t_back = best(reps, &mut || {
        for (v, img) in imgs.iter().enumerate() {
            p.back_add(v, img, &mut back, None);
        }
    });
    let work = x.len() as f64 * views as f64;
    (work / t_fwd, work / t_back)
}

/// Mean seconds per ASART iteration (iterations 2..=3; the first carries the start, Eq. 2.29).
fn asart_iteration(p: &dyn Projector, x: &[f32]) -> f64 {
    let images: Vec<Image> = p
        .cameras()
        .iter()
        .enumerate()
        .map(|(v, c)| {
            let mut im = Image::zeros(c.width(), c.height());
            p.forward(v, x, &mut im.data);
            im
        })
        .collect();
    let problem = Problem::new(p, &images).expect("consistent");
    let params = AsartParams { stopping: Stopping { max_iterations: 3, plateau: None }, ..Default::default() };
    let mut stamps = vec![];
    asart(&problem, None, &params, |_| {
        stamps.push(Instant::now());
        ControlFlow::Continue(())
    })
    .expect("runs");
    let d: Vec<f64> = stamps.windows(2).map(|w| (w[1] - w[0]).as_secs_f64()).collect();
    d.iter().sum::<f64>() / d.len().max(1) as f64
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if !args.iter().any(|a| a == "--bench") {
        return;
    }
    let aabb = Aabb::cube(DVec3::ZERO, 40.0);
    let ring90 = ring(90, 128);
    if args.iter().any(|a| a == "--json") {
        let mut fields = vec![format!("\"threads\": {}", rayon::current_num_threads())];
        for res in [64usize, 128] {
            let grid = Grid::with_resolution(aabb, res);
            let x = phantom(&grid);
            let p = FootprintProjector::new(grid, &ring90, 1.0).expect("valid");
            let mut img = vec![0f32; p.view_len(0)];
            let mut back = vec![0f32; grid.len()];
            let t_fwd = best(3, &mut || {
                for v in 0..p.n_views() {
                    p.forward(v, &x, &mut img);
                }
            });
            let t_back = best(3, &mut || {
                for v in 0..p.n_views() {
                    p.back_add(v, &img, &mut back, None);
                }
            });
            fields.push(format!("\"forward_s_{res}\": {t_fwd:.6}, \"back_s_{res}\": {t_back:.6}"));
        }
        println!("{{\"views\": 90, \"pixels\": 128, {}}}", fields.join(", "));
        return;
    }
    let threads = rayon::current_num_threads();
    println!("40 mm cube, {threads} rayon threads; M voxel-views/s, best of 3; old = sub-voxel splat, new = footprint");
    let ring15 = ring(15, 256);
    let setups: [(&str, &[Camera]); 2] = [("15 x 256^2", &ring15), ("90 x 128^2", &ring90)];
    println!(
        "{:<11} {:>5} {:>4} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "views", "grid", "sub", "old fwd", "new fwd", "new/old", "old back", "new back", "new/old"
    );
    for (name, cams) in setups {
        for res in [64usize, 128] {
            let grid = Grid::with_resolution(aabb, res);
            let x = phantom(&grid);
            let old = SplatProjector::new(grid, cams, 1.0).expect("valid");
            let new = FootprintProjector::new(grid, cams, 1.0).expect("valid");
            // About 0.1–0.4 s per pass for the splat.
            let sub_views =
                (4e8 / (grid.len() as f64 * old.subdivisions().pow(3) as f64)).clamp(1.0, cams.len() as f64);
            let (of, ob) = rates(&old, &x, sub_views as usize, 2);
            let (nf, nb) = rates(&new, &x, cams.len(), 3);
            println!(
                "{name:<11} {:>4}^3 {:>4} {:>9.1} {:>9.1} {:>8.1}x {:>9.1} {:>9.1} {:>8.1}x",
                res,
                old.subdivisions(),
                of / 1e6,
                nf / 1e6,
                nf / of,
                ob / 1e6,
                nb / 1e6,
                nb / ob
            );
        }
    }
    let grid = Grid::with_resolution(aabb, 64);
    let x = phantom(&grid);
    let old = SplatProjector::new(grid, &ring15, 1.0).expect("valid");
    let new = FootprintProjector::new(grid, &ring15, 1.0).expect("valid");
    let t_new = asart_iteration(&new, &x);
    let t_old = asart_iteration(&old, &x);
    println!(
        "ASART, 64^3, 15 x 256^2: old {t_old:.3} s per iteration, new {t_new:.3} s per iteration, old/new {:.1}x",
        t_old / t_new
    );
}
