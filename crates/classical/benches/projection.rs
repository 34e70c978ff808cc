//! Projection and ASART speed on the dissertation's geometry, scaled down: 15 cameras on a
//! planar ring (y–z plane, perpendicular to the jet axis) around a 40 mm cube at 360 mm
//! (magnification −0.2 with f = 60 mm), 256 × 256 pixels each.
//!
//! Prints voxel–view updates per second for the splat's forward and back projection (both
//! cores) and for a straightforward single-threaded loop over voxels and views
//! (`SplatProjector::forward_reference`) in the same run, the speed-up, the ray projector's
//! rates, and seconds per ASART iteration at 128³ and 200³.
//!
//! Run: `cargo bench --no-run -p fluidnerf-classical`, then the printed executable with
//! `--bench`.

#![allow(clippy::print_stdout)]

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{asart, AsartParams, Grid, Problem, Projector, RayProjector, SplatProjector, Stopping};
use fluidnerf_core::{Aabb, Image};
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

/// CPU seconds (user + system) of this process so far (Linux), to show how busy the cores were.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit_once(')').map_or("", |p| p.1);
    // Fields after the command name: state, ppid, …; utime and stime are the 12th and 13th.
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn time<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = Instant::now();
    let r = f();
    (r, t.elapsed().as_secs_f64())
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let threads = rayon::current_num_threads();
    let aabb = Aabb::cube(DVec3::ZERO, 40.0);
    let cams = ring(15, 256);
    println!("15 cameras, 256 x 256 px, 40 mm cube, {threads} rayon threads");
    for res in [128usize, 200] {
        let grid = Grid::with_resolution(aabb, res);
        let n = grid.len() as f64;
        let x = phantom(&grid);
        // One splat per voxel centre, the dissertation's scheme (at 128³ the automatic choice
        // would split each voxel into 2³).
        let splat = SplatProjector::new(grid, &cams, 1.0).expect("valid").with_subdivisions(1);
        let mut imgs: Vec<Vec<f32>> = (0..cams.len()).map(|v| vec![0f32; splat.view_len(v)]).collect();
        let views = cams.len() as f64;
        // Best of three: the machine is shared, the minimum is the least disturbed run.
        let best = |f: &mut dyn FnMut()| (0..3).map(|_| time(&mut *f).1).fold(f64::INFINITY, f64::min);
        let cpu0 = cpu_seconds();
        let wall0 = Instant::now();
        let t_fwd = best(&mut || {
            for (v, img) in imgs.iter_mut().enumerate() {
                splat.forward(v, &x, img);
            }
        });
        let busy = (cpu_seconds() - cpu0) / wall0.elapsed().as_secs_f64();
        let mut back = vec![0f32; grid.len()];
        let t_back = best(&mut || {
            for (v, img) in imgs.iter().enumerate() {
                splat.back_add(v, img, &mut back, None);
            }
        });
        let fwd_rate = n * views / t_fwd;
        let back_rate = n * views / t_back;
        println!(
            "{res}^3 splat forward: {:.3} s for 15 views, {:.1} M voxel-views/s (cores busy: {busy:.2} CPU-s per s)",
            t_fwd,
            fwd_rate / 1e6
        );
        println!("{res}^3 splat back:    {:.3} s for 15 views, {:.1} M voxel-views/s", t_back, back_rate / 1e6);
        if res == 128 {
            let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("thread pool");
            let mut out = vec![0f32; splat.view_len(0)];
            let t_one = one.install(|| {
                best(&mut || {
                    for v in 0..3 {
                        splat.forward(v, &x, &mut out);
                    }
                })
            });
            // The straightforward loop is slow: 3 views.
            let t_ref = best(&mut || {
                for v in 0..3 {
                    splat.forward_reference(v, &x, &mut out);
                }
            });
            let ref_rate = n * 3.0 / t_ref;
            let one_rate = n * 3.0 / t_one;
            println!(
                "{res}^3 splat forward on one thread: {:.1} M voxel-views/s; straightforward single-threaded loop: {:.1} M voxel-views/s",
                one_rate / 1e6,
                ref_rate / 1e6
            );
            println!(
                "{res}^3 forward speed-up over the straightforward loop: {:.1}x ({:.1}x from the inner loop, {:.2}x from {threads} threads)",
                fwd_rate / ref_rate,
                one_rate / ref_rate,
                fwd_rate / one_rate
            );
            let ray = RayProjector::new(grid, &cams, 1.0, 0.5).expect("valid");
            let t_rf = best(&mut || {
                for (v, img) in imgs.iter_mut().enumerate() {
                    ray.forward(v, &x, img);
                }
            });
            back.fill(0.0);
            let t_rb = best(&mut || {
                for (v, img) in imgs.iter().enumerate() {
                    ray.back_add(v, img, &mut back, None);
                }
            });
            println!(
                "{res}^3 ray forward: {:.3} s ({:.1} M voxel-views/s), back: {:.3} s ({:.1} M voxel-views/s)",
                t_rf,
                n * views / t_rf / 1e6,
                t_rb,
                n * views / t_rb / 1e6
            );
        }
        // ASART on the splat's own projections of the phantom.
        let images: Vec<Image> = imgs
            .iter()
            .enumerate()
            .map(|(v, _)| {
                let mut im = Image::zeros(256, 256);
                splat.forward(v, &x, &mut im.data);
                im
            })
            .collect();
        let problem = Problem::new(&splat, &images).expect("consistent");
        let params = AsartParams { stopping: Stopping { max_iterations: 3, plateau: None }, ..Default::default() };
        let mut stamps = vec![Instant::now()];
        let (_, t_all) = time(|| {
            asart(&problem, None, &params, |_| {
                stamps.push(Instant::now());
                ControlFlow::Continue(())
            })
            .expect("runs")
        });
        let per_iter: Vec<f64> = stamps.windows(2).skip(1).map(|w| (w[1] - w[0]).as_secs_f64()).collect();
        let mean = per_iter.iter().sum::<f64>() / per_iter.len().max(1) as f64;
        println!(
            "{res}^3 ASART: {:.2} s per iteration (iterations 2-3: {per_iter:.2?}; setup + first {:.2} s; total {t_all:.2} s)",
            mean,
            (stamps[1] - stamps[0]).as_secs_f64()
        );
    }
}
