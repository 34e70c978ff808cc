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
//! without column sums) for both projectors and the ratio new/old (of CPU time, which the
//! machine's other work disturbs least), best of three; the splat
//! is timed on a subset of the views when all of them would take long (the rate is per voxel and
//! view either way). Then seconds per ASART iteration at 64³ with 15 views of 256² px for both.
//!
//! Run: `cargo bench -p fluidnerf-classical --bench projection` (about two minutes). With
//! `--json` only one JSON line is printed, the figures of the footprint projector on the 90-view
//! ring, for the comparison script.

#![allow(clippy::print_stdout)]

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_classical::{
    asart, AsartParams, FootprintProjector, Grid, Isa, Problem, Projector, SplatProjector, Stopping,
};
use fluidnerf_core::{Aabb, Camera};
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

/// The dense volume kept inside an upright cylinder over the lower three quarters of the box
/// (about 15 % of the voxels), zero elsewhere: a flow's volume, where a projection may skip
/// the empty voxels.
fn sparse_phantom(grid: &Grid) -> Vec<f32> {
    let inside = fluidnerf_core::Volume::from_fn(grid.dims, grid.aabb, |p| {
        f32::from(u8::from(p.x * p.x + p.y * p.y < 100.0 && p.z < 10.0))
    });
    phantom(grid).iter().zip(&inside.data).map(|(v, m)| v * m).collect()
}

/// CPU seconds (user + system, all threads) of this process so far (Linux; 10 ms ticks).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit_once(')').map_or("", |p| p.1);
    // Fields after the command name: state, ppid, …; utime and stime are the 12th and 13th.
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

/// Wall and CPU seconds of one run.
#[derive(Clone, Copy)]
struct Cost {
    wall: f64,
    cpu: f64,
}

/// Best of `reps` runs (wall and CPU time each at their minimum): the machine may be shared,
/// the minimum is the least disturbed run. CPU time is what other processes disturb least, so
/// the ratios are taken from it.
fn best(reps: usize, f: &mut dyn FnMut()) -> Cost {
    let mut c = Cost { wall: f64::INFINITY, cpu: f64::INFINITY };
    for _ in 0..reps {
        let (t, cpu0) = (Instant::now(), cpu_seconds());
        f();
        c.wall = c.wall.min(t.elapsed().as_secs_f64());
        c.cpu = c.cpu.min((cpu_seconds() - cpu0).max(0.01));
    }
    c
}

/// Forward and back of a reference and a new projector (costs per voxel-view, from
/// [`rates`]): M voxel-views per wall-clock second of each and the ratio of their CPU times,
/// forward then back.
fn against((rf, rb): (Cost, Cost), (f, b): (Cost, Cost)) -> [f64; 6] {
    [1e-6 / rf.wall, 1e-6 / f.wall, rf.cpu / f.cpu, 1e-6 / rb.wall, 1e-6 / b.wall, rb.cpu / b.cpu]
}

/// Forward and back costs of `p` over its first `views` views, per voxel-view.
fn rates(p: &dyn Projector, x: &[f32], views: usize, reps: usize) -> (Cost, Cost) {
    let mut imgs: Vec<Vec<f32>> = (0..views).map(|v| vec![0f32; p.view_len(v)]).collect();
    let fwd = best(reps, &mut || {
        for (v, img) in imgs.iter_mut().enumerate() {
            p.forward(v, x, img);
        }
    });
    let mut back = vec![0f32; x.len()];
    let bwd = best(reps, &mut || {
        for (v, img) in imgs.iter().enumerate() {
            p.back_add(v, img, &mut back, None);
        }
    });
    let work = x.len() as f64 * views as f64;
    let per = |c: Cost| Cost { wall: c.wall / work, cpu: c.cpu / work };
    (per(fwd), per(bwd))
}

/// Mean wall and CPU seconds per ASART iteration (iterations 2..=3; the first carries the
/// start, Eq. 2.29).
fn asart_iteration(p: &dyn Projector, x: &[f32]) -> Cost {
    let images = common::project_all(p, x);
    let problem = Problem::new(p, &images).expect("consistent");
    let params = AsartParams { stopping: Stopping { max_iterations: 3, plateau: None }, ..Default::default() };
    let mut stamps = vec![];
    asart(&problem, None, &params, |_| {
        stamps.push((Instant::now(), cpu_seconds()));
        ControlFlow::Continue(())
    })
    .expect("runs");
    let (first, last) = (stamps[0], stamps[stamps.len() - 1]);
    let n = (stamps.len() - 1).max(1) as f64;
    Cost { wall: (last.0 - first.0).as_secs_f64() / n, cpu: (last.1 - first.1) / n }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if !args.iter().any(|a| a == "--bench") {
        return;
    }
    let aabb = Aabb::cube(DVec3::ZERO, 40.0);
    let ring90 = ring(90, 128);
    // `--isa baseline|avx2|avx512` caps the footprint kernels' instruction set.
    let isa = match args.iter().position(|a| a == "--isa").and_then(|i| args.get(i + 1)).map(String::as_str) {
        Some("baseline") => Isa::Baseline,
        Some("avx2") => Isa::Avx2,
        _ => Isa::Avx512,
    };
    if args.iter().any(|a| a == "--json") {
        // `--ring15`: the 15 views of 256² px instead of the 90-view ring.
        let (cams, views, pixels) =
            if args.iter().any(|a| a == "--ring15") { (ring(15, 256), 15, 256) } else { (ring90.clone(), 90, 128) };
        let mut fields = vec![format!("\"threads\": {}", rayon::current_num_threads())];
        for res in [64usize, 128] {
            let grid = Grid::with_resolution(aabb, res);
            let x = phantom(&grid);
            let p = FootprintProjector::new(grid, &cams, 1.0)
                .expect("valid")
                .with_isa(isa)
                .with_shared_rows(!args.iter().any(|a| a == "--no-shared-rows"));
            if res == 64 {
                fields.push(format!("\"shared_row_views\": {}", p.shared_row_views()));
                fields.push(format!("\"isa\": \"{:?}\"", p.isa()));
            }
            let mut img = vec![0f32; p.view_len(0)];
            let mut back = vec![0f32; grid.len()];
            let t_fwd = best(3, &mut || {
                for v in 0..p.n_views() {
                    p.forward(v, &x, &mut img);
                }
            })
            .wall;
            let t_back = best(3, &mut || {
                for v in 0..p.n_views() {
                    p.back_add(v, &img, &mut back, None);
                }
            })
            .wall;
            // Every view in one call, as MLEM back-projects (and as mbirjax does).
            let views: Vec<usize> = (0..p.n_views()).collect();
            let imgs: Vec<&[f32]> = views.iter().map(|_| img.as_slice()).collect();
            let t_back_all = best(3, &mut || p.back_add_views(&views, &imgs, &mut back, None)).wall;
            fields.push(format!("\"back_all_s_{res}\": {t_back_all:.6}"));
            // With the moving axis's footprints kept between back projections: the first pass
            // computes and stores them, the later ones read them.
            let kept = p.clone().with_kept_footprints(u64::MAX);
            let t_first = best(1, &mut || {
                for v in 0..kept.n_views() {
                    kept.back_add(v, &img, &mut back, None);
                }
            })
            .wall;
            let t_kept = best(3, &mut || {
                for v in 0..kept.n_views() {
                    kept.back_add(v, &img, &mut back, None);
                }
            })
            .wall;
            let mib = kept.kept_footprint_bytes() as f64 / (1u64 << 20) as f64;
            fields.push(format!(
                "\"back_kept_s_{res}\": {t_kept:.6}, \"back_kept_first_s_{res}\": {t_first:.6}, \"kept_mib_{res}\": {mib:.0}"
            ));
            drop(kept);
            let xs = sparse_phantom(&grid);
            let t_sparse = best(3, &mut || {
                for v in 0..p.n_views() {
                    p.forward(v, &xs, &mut img);
                }
            })
            .wall;
            // Every view in one call, as a render and the iterative methods project: each view
            // on one thread, the non-empty chunks found once.
            let mut outs: Vec<Vec<f32>> = views.iter().map(|&v| vec![0f32; p.view_len(v)]).collect();
            let t_sparse_all = best(3, &mut || {
                let mut refs: Vec<&mut [f32]> = outs.iter_mut().map(Vec::as_mut_slice).collect();
                p.forward_views(&views, &xs, &mut refs);
            })
            .wall;
            fields.push(format!(
                "\"forward_sparse_s_{res}\": {t_sparse:.6}, \"forward_all_sparse_s_{res}\": {t_sparse_all:.6}"
            ));
            // With column sums, as SART and ASART call it.
            let mut cols = vec![0f32; grid.len()];
            let t_cols = best(3, &mut || {
                for v in 0..p.n_views() {
                    p.back_add(v, &img, &mut back, Some(&mut cols));
                }
            })
            .wall;
            fields.push(format!(
                "\"forward_s_{res}\": {t_fwd:.6}, \"back_s_{res}\": {t_back:.6}, \"back_colsums_s_{res}\": {t_cols:.6}"
            ));
        }
        println!("{{\"views\": {views}, \"pixels\": {pixels}, {}}}", fields.join(", "));
        return;
    }
    let threads = rayon::current_num_threads();
    println!(
        "40 mm cube, {threads} rayon threads; old = sub-voxel splat, new = footprint; M voxel-views per wall-clock \
         second (best of 3); new/old from CPU time (robust on a shared machine)"
    );
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
            let [a, b, c, d, e, f] = against(rates(&old, &x, sub_views as usize, 2), rates(&new, &x, cams.len(), 3));
            println!(
                "{name:<11} {res:>4}^3 {:>4} {a:>9.1} {b:>9.1} {c:>8.1}x {d:>9.1} {e:>9.1} {f:>8.1}x",
                old.subdivisions()
            );
        }
    }
    // One line of `reference -> new` figures.
    let versus = |label: String, reference: (Cost, Cost), new: (Cost, Cost)| {
        let [a, b, c, d, e, f] = against(reference, new);
        println!("  {label:<9} forward {a:>6.1} -> {b:>6.1} ({c:>4.2}x)  back {d:>6.1} -> {e:>6.1} ({f:>4.2}x)")
    };
    println!("footprint kernels per instruction set against the baseline, 90 x 128^2, 128^3 (M voxel-views/s, best of 3; ratio of CPU time)");
    let grid = Grid::with_resolution(aabb, 128);
    let x = phantom(&grid);
    let mut base = None;
    for isa in Isa::available() {
        let p = FootprintProjector::new(grid, &ring90, 1.0).expect("valid").with_isa(isa);
        let r = rates(&p, &x, ring90.len(), 3);
        versus(format!("{isa:?}"), *base.get_or_insert(r), r);
    }
    println!("footprint, voxel by voxel -> shared rows (the ring is around the grid's x axis), 90 x 128^2 (M voxel-views/s, best of 3; ratio of CPU time)");
    for res in [64usize, 128] {
        let grid = Grid::with_resolution(aabb, res);
        let x = phantom(&grid);
        let general = FootprintProjector::new(grid, &ring90, 1.0).expect("valid").with_shared_rows(false);
        let shared = FootprintProjector::new(grid, &ring90, 1.0).expect("valid");
        versus(format!("{res}^3"), rates(&general, &x, ring90.len(), 3), rates(&shared, &x, ring90.len(), 3));
    }
    let grid = Grid::with_resolution(aabb, 128);
    let (x, xs) = (phantom(&grid), sparse_phantom(&grid));
    let p = FootprintProjector::new(grid, &ring90, 1.0).expect("valid");
    let (dense, _) = rates(&p, &x, ring90.len(), 3);
    let (sparse, _) = rates(&p, &xs, ring90.len(), 3);
    println!(
        "footprint forward, 90 x 128^2, 128^3: dense volume {:.3} s, flow-like volume ({:.0} % non-zero) {:.3} s; \
         dense/flow-like {:.1}x (CPU time)",
        dense.wall * (x.len() * ring90.len()) as f64,
        100.0 * xs.iter().filter(|&&v| v != 0.0).count() as f64 / xs.len() as f64,
        sparse.wall * (x.len() * ring90.len()) as f64,
        dense.cpu / sparse.cpu
    );
    // All views in one call, as `render` draws a field's views: the volume's empty chunks are
    // found once instead of once per view.
    let views: Vec<usize> = (0..p.n_views()).collect();
    let mut imgs: Vec<Vec<f32>> = views.iter().map(|&v| vec![0f32; p.view_len(v)]).collect();
    let one_by_one = best(3, &mut || {
        for (v, img) in imgs.iter_mut().enumerate() {
            p.forward(v, &xs, img);
        }
    });
    let together = best(3, &mut || {
        let mut outs: Vec<&mut [f32]> = imgs.iter_mut().map(Vec::as_mut_slice).collect();
        p.forward_views(&views, &xs, &mut outs);
    });
    println!(
        "footprint forward of the flow-like volume, 90 x 128^2, 128^3: view by view {:.3} s, all views in one call \
         {:.3} s; {:.2}x (CPU time)",
        one_by_one.wall,
        together.wall,
        one_by_one.cpu / together.cpu
    );
    let grid = Grid::with_resolution(aabb, 64);
    let x = phantom(&grid);
    let old = SplatProjector::new(grid, &ring15, 1.0).expect("valid");
    let new = FootprintProjector::new(grid, &ring15, 1.0).expect("valid");
    let t_new = asart_iteration(&new, &x);
    let t_old = asart_iteration(&old, &x);
    println!(
        "ASART, 64^3, 15 x 256^2: old {:.3} s per iteration, new {:.3} s per iteration; old/new {:.1}x (CPU time)",
        t_old.wall,
        t_new.wall,
        t_old.cpu / t_new.cpu
    );
    let kept = new.clone().with_kept_footprints(u64::MAX);
    let t_kept = asart_iteration(&kept, &x);
    println!(
        "ASART, 64^3, 15 x 256^2, footprints kept ({:.0} MiB): {:.3} s per iteration; new/kept {:.2}x (CPU time)",
        kept.kept_footprint_bytes() as f64 / (1u64 << 20) as f64,
        t_kept.wall,
        t_new.cpu / t_kept.cpu
    );
}
