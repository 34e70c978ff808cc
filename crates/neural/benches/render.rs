//! Rendering a trained field: rays per second of `render_image` on the `fast` hash-grid field
//! seen by 15 cameras of 128² px on a ring (one ray per pixel, the renderer's default step of
//! the box's smallest side / 256), in one run:
//! - `all samples`: the whole chord sampled, empty cells rejected point by point inside the
//!   field (the renderer before it used the field's support);
//! - `support`: samples generated only in the occupied cells (3D DDA through the hull);
//! each for a jet-like hull (a cone along x) and for a full box. The field's weights are random:
//! speed does not depend on them. Prints rays/s, samples evaluated and the ratio.
//!
//!   cargo bench -p fluidnerf-neural --bench render [-- --quick]
#![allow(clippy::print_stdout)]

use std::time::Instant;

use fluidnerf_core::{render_image, Aabb, Camera, Image, Intrinsics, RenderSettings, ScalarField};
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

struct Baked<'a>(&'a fluidnerf_core::Volume, Option<fluidnerf_core::Support<'a>>);

impl ScalarField for Baked<'_> {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.0.eval(points, time, out);
    }
    fn support(&self) -> Option<fluidnerf_core::Support<'_>> {
        self.1
    }
}

fn cameras(n: usize, px: usize) -> Vec<Camera> {
    let k = Intrinsics {
        width: px as u32,
        height: px as u32,
        fx: 1.6 * px as f64,
        fy: 1.6 * px as f64,
        cx: (px as f64 - 1.0) / 2.0,
        cy: (px as f64 - 1.0) / 2.0,
        skew: 0.0,
    };
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
    let dims = [64, 64, 64];
    let cells = (0..64 * 64 * 64)
        .map(|i| {
            let (x, y, z) = (i % 64, (i / 64) % 64, i / 4096);
            let c = |v: usize| (v as f64 + 0.5) / 32.0 - 1.0;
            hull == "full" || c(y).hypot(c(z)) < 0.15 + 0.3 * (c(x) + 1.0)
        })
        .collect();
    let grid = OccupancyGrid::from_cells(dims, cells).expect("64³ cells");
    let meta = FieldMeta { aabb, value_scale: 1.0, time_step: 1.0, occupancy: Some(grid.to_record()) };
    TrainedField::new(f, meta).expect("valid meta")
}

fn time_views(field: &dyn ScalarField, cams: &[Camera], aabb: &Aabb, reps: usize) -> (f64, Vec<Image>) {
    let s = RenderSettings::default();
    let mut best = f64::INFINITY;
    let mut images = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        images = cams.iter().map(|c| render_image(field, c, aabb, &s).expect("renders")).collect();
        best = best.min(t.elapsed().as_secs_f64());
    }
    (best, images)
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let reps = if quick { 1 } else { 3 };
    let cams = cameras(15, 128);
    let rays = (15 * 128 * 128) as f64;
    println!(
        "render: 15 views of 128² px, one ray per pixel, step = box / 256, {} threads",
        rayon::current_num_threads()
    );
    for hull in ["jet", "full"] {
        let f = field(hull);
        let aabb = f.meta.aabb;
        let occupied = f.occupancy.as_ref().map_or(1.0, OccupancyGrid::occupied_fraction);
        let (t_all, a) = time_views(&Hidden(&f), &cams, &aabb, reps);
        let (t_sup, b) = time_views(&f, &cams, &aabb, reps);
        let t = Instant::now();
        let vol = fluidnerf_core::Volume::from_field([128, 128, 128], aabb, &f, 0.0);
        let t_bake = t.elapsed().as_secs_f64();
        let baked = Baked(&vol, f.support());
        let (t_vol, c) = time_views(&baked, &cams, &aabb, reps);
        let nr = |x: &[Image], y: &[Image]| {
            let (mut se, mut ss) = (0.0f64, 0.0f64);
            for (p, q) in x.iter().zip(y).flat_map(|(p, q)| p.data.iter().zip(&q.data)) {
                se += ((p - q) as f64).powi(2);
                ss += (*q as f64).powi(2);
            }
            (se / ss).sqrt()
        };
        println!("    baked 128³: bake {t_bake:.3} s, render {:8.0} rays/s, with bake {:8.0} rays/s, image NRMSE vs exact {:.2e}", rays / t_vol, rays / (t_vol + t_bake), nr(&c, &b));
        let peak = a.iter().flat_map(|i| i.data.iter()).fold(0.0f32, |m, &v| m.max(v.abs()));
        let diff = a
            .iter()
            .zip(&b)
            .flat_map(|(x, y)| x.data.iter().zip(&y.data))
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        println!(
            "  {hull:>4} hull ({:4.1} % occupied): all samples {:8.0} rays/s | support {:8.0} rays/s | ×{:.2} | max diff {:.1e} of peak",
            100.0 * occupied,
            rays / t_all,
            rays / t_sup,
            t_all / t_sup,
            diff / peak.max(f32::MIN_POSITIVE)
        );
    }
}
