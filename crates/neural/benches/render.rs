//! Rendering a trained field: rays per second of `render_image` on the `fast` hash-grid field
//! (8 levels up to 128, 16 → 64 → 64 → 1) seen by 15 cameras of 128² px on a ring, one ray per
//! pixel, the renderer's default step (the box's smallest side / 256), in one run:
//! - `scalar`: the whole chord sampled, empty cells rejected point by point inside the field,
//!   the encoding's scalar loop (the renderer and encoding before this bench existed);
//! - `exact`: samples only in the occupied cells (3D DDA through the hull), the encoding
//!   vectorised where the CPU allows;
//! - `baked N`: the field sampled once on the vertices of an N³ grid (the time counted), then
//!   that grid rendered, at the field's finest level (128) and twice it (256, what `render
//!   --bake auto` uses), with the image NRMSE against `exact`;
//! - `footprint N`: the field sampled at the centres of an N³ grid filling the box (the time
//!   counted), then projected with the separable-footprint projector (`render --projector
//!   footprint`), which integrates each pixel's area; its NRMSE against `exact` and against
//!   exact rendering with 2 × 2 rays per pixel (a closer model of a pixel's area).
//!
//! Each for a jet-like hull (a cone along x, 18 % of the box) and for a full box. The weights
//! are random (a rougher field than a trained one: the bake errors here are upper bounds; for
//! a trained field see docs/performance.md). Best of 3 runs (1 with `--quick`).
//!
//! Then one view of 480 × 270 px at 2 × 2 rays per pixel with the full hull (518 400 rays; a
//! real camera's frame, and the case where rendering a field was slowest), against the
//! footprint renders of the same view.
//!
//!   cargo bench -p fluidnerf-neural --bench render [-- --quick]
#![allow(clippy::print_stdout)]

use std::time::Instant;

use fluidnerf_classical::projector::{FootprintProjector, Grid, Projector};
use fluidnerf_core::{render_image, Aabb, Baked, Camera, Image, Intrinsics, RenderSettings, ScalarField, Volume};
use fluidnerf_neural::hashgrid::set_vectorised;
use fluidnerf_neural::occupancy::OccupancyGrid;
use fluidnerf_neural::train::FieldMeta;
use fluidnerf_neural::trained::{FieldConfig, NeuralConfig, TrainedField};
use fluidnerf_neural::{HashGridField, TrainableField};
use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};

/// The field without its support: the renderer samples whole chords.
struct Hidden<'a>(&'a dyn ScalarField);

impl ScalarField for Hidden<'_> {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.0.eval(points, time, out);
    }
}

fn cameras(n: usize, width: u32, height: u32) -> Vec<Camera> {
    let f = 1.6 * height as f64;
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let k = Intrinsics { width, height, fx: f, fy: f, cx, cy, skew: 0.0 };
    (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            Camera::look_at(k, DVec3::new(0.3, 4.0 * a.cos(), 4.0 * a.sin()), DVec3::ZERO, DVec3::X)
        })
        .collect()
}

fn field(hull: &str) -> TrainedField<HashGridField> {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let Some(NeuralConfig { field: FieldConfig::HashGrid(cfg), .. }) = NeuralConfig::preset("fast") else {
        unreachable!("the fast preset is a hash grid")
    };
    let mut f = HashGridField::new(&cfg, 3, 7).expect("valid config");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let grid = f.grid_params();
    for p in &mut f.params_mut()[..grid] {
        *p = rng.random_range(-0.5..0.5);
    }
    let cells = (0..64 * 64 * 64)
        .map(|i| {
            let (x, y, z) = (i % 64, (i / 64) % 64, i / 4096);
            let c = |v: usize| (v as f64 + 0.5) / 32.0 - 1.0;
            hull == "full" || c(y).hypot(c(z)) < 0.15 + 0.3 * (c(x) + 1.0)
        })
        .collect();
    let grid = OccupancyGrid::from_cells([64, 64, 64], cells).expect("64³ cells");
    let meta = FieldMeta { aabb, value_scale: 1.0, time_step: 1.0, occupancy: Some(grid.to_record()) };
    TrainedField::new(f, meta).expect("valid meta")
}

/// Best time over `reps` of `work`, and its last result.
fn best<T>(reps: usize, mut work: impl FnMut() -> T) -> (f64, T) {
    let mut t_best = f64::INFINITY;
    let mut out = None;
    for _ in 0..reps {
        let t = Instant::now();
        let r = work();
        t_best = t_best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (t_best, out.expect("reps ≥ 1"))
}

fn views(field: &dyn ScalarField, cams: &[Camera], aabb: &Aabb, supersample: usize) -> Vec<Image> {
    let settings = RenderSettings { supersample, ..RenderSettings::default() };
    cams.iter().map(|c| render_image(field, c, aabb, &settings).expect("renders")).collect()
}

/// What `render --projector footprint --bake N` does: the field sampled at the centres of an
/// N³ grid filling the box, every view projected with the footprint projector.
fn footprint(field: &dyn ScalarField, n: usize, cams: &[Camera], aabb: Aabb) -> Vec<Image> {
    let volume = Volume::from_field([n; 3], aabb, field, 0.0);
    let p = FootprintProjector::new(Grid::new(volume.dims, aabb), cams, 1.0).expect("footprints fit");
    (0..cams.len())
        .map(|v| {
            let mut img = Image::zeros(cams[v].width(), cams[v].height());
            p.forward(v, &volume.data, &mut img.data);
            img
        })
        .collect()
}

fn nrmse(x: &[Image], reference: &[Image]) -> f64 {
    let (mut se, mut ss) = (0.0f64, 0.0f64);
    for (p, q) in x.iter().zip(reference).flat_map(|(p, q)| p.data.iter().zip(&q.data)) {
        se += ((p - q) as f64).powi(2);
        ss += (*q as f64).powi(2);
    }
    (se / ss).sqrt()
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let reps = if quick { 1 } else { 3 };
    let cams = cameras(15, 128, 128);
    let rays = (15 * 128 * 128) as f64;
    println!(
        "render: 15 views of 128² px, one ray per pixel, step = box / 256, {} threads; rays/s (× scalar)",
        rayon::current_num_threads()
    );
    for hull in ["jet", "full"] {
        let f = field(hull);
        let aabb = f.meta.aabb;
        let occupied = f.occupancy.as_ref().map_or(1.0, OccupancyGrid::occupied_fraction);
        set_vectorised(false);
        let (t_scalar, _) = best(reps, || views(&Hidden(&f), &cams, &aabb, 1));
        set_vectorised(true);
        let (t_exact, exact) = best(reps, || views(&f, &cams, &aabb, 1));
        let exact2 = views(&f, &cams, &aabb, 2);
        println!(
            "  {hull:>4} hull ({:4.1} % occupied): scalar {:8.0} | exact {:8.0} (×{:.2})",
            100.0 * occupied,
            rays / t_scalar,
            rays / t_exact,
            t_scalar / t_exact
        );
        for n in [128, 256] {
            let (t, img) = best(reps, || views(&Baked::on_vertices(&f, [n; 3], aabb, 0.0), &cams, &aabb, 1));
            print!("       baked {n}     {:8.0} (×{:5.2}, NRMSE {:.1e})", rays / t, t_scalar / t, nrmse(&img, &exact));
            let (t, img) = best(reps, || footprint(&f, n, &cams, aabb));
            println!(
                " | footprint {n} {:8.0} (×{:5.2}, NRMSE {:.1e}; against 2 × 2 rays {:.1e})",
                rays / t,
                t_scalar / t,
                nrmse(&img, &exact),
                nrmse(&img, &exact2)
            );
        }
    }

    let cam = cameras(1, 480, 270);
    let rays = (480 * 270 * 4) as f64;
    let f = field("full");
    let aabb = f.meta.aabb;
    println!("one view of 480 × 270 px, 2 × 2 rays per pixel, full hull; rays/s (× scalar)");
    set_vectorised(false);
    let (t_scalar, _) = best(reps, || views(&Hidden(&f), &cam, &aabb, 2));
    set_vectorised(true);
    let (t_exact, exact) = best(reps, || views(&f, &cam, &aabb, 2));
    print!("  scalar {:8.0} | exact {:8.0} (×{:.2})", rays / t_scalar, rays / t_exact, t_scalar / t_exact);
    for n in [128, 256] {
        let (t, img) = best(reps, || footprint(&f, n, &cam, aabb));
        print!(" | footprint {n} {:8.0} (×{:5.2}, NRMSE {:.1e})", rays / t, t_scalar / t, nrmse(&img, &exact));
    }
    println!();
}
