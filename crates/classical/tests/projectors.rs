//! The projectors: adjoint identity, row access, and agreement with the reference renderer.

mod common;

use common::*;
use fluidnerf_classical::{FootprintProjector, Grid, Projector, RayProjector, SplatProjector};
use fluidnerf_core::{render_image, RenderSettings, Volume};

fn dot(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| x as f64 * y as f64).sum()
}

fn projectors(grid: Grid, cams: &[fluidnerf_core::Camera], scale: f64) -> Vec<(&'static str, Box<dyn Projector>)> {
    vec![
        ("splat", Box::new(SplatProjector::new(grid, cams, scale).expect("valid")) as Box<dyn Projector>),
        ("ray", Box::new(RayProjector::new(grid, cams, scale, 0.5).expect("valid"))),
        ("footprint", Box::new(FootprintProjector::new(grid, cams, scale).expect("valid"))),
    ]
}

#[test]
fn adjoint_identity_with_distortion() {
    let grid = Grid::new([17, 14, 12], aabb());
    let cams = distorted_ring(3, 40);
    for (name, p) in projectors(grid, &cams, 1.3) {
        let x = uniform(1, grid.len());
        for v in 0..p.n_views() {
            let y = uniform(10 + v as u64, p.view_len(v));
            let mut ax = vec![0f32; p.view_len(v)];
            p.forward(v, &x, &mut ax);
            let mut aty = vec![0f32; grid.len()];
            p.back_add(v, &y, &mut aty, None);
            let (lhs, rhs) = (dot(&ax, &y), dot(&x, &aty));
            let rel = (lhs - rhs).abs() / lhs.abs().max(rhs.abs());
            assert!(lhs > 0.0, "{name}: view {v} sees nothing");
            assert!(rel < 1e-5, "{name} view {v}: <Ax,y> = {lhs}, <x,A'y> = {rhs}, rel {rel:e}");
        }
    }
}

#[test]
fn back_add_accumulates_and_column_sums_are_adjoint_of_ones() {
    let grid = Grid::new([10, 9, 8], aabb());
    let cams = distorted_ring(2, 24);
    for (name, p) in projectors(grid, &cams, 0.7) {
        let y = uniform(3, p.view_len(1));
        let mut once = vec![0f32; grid.len()];
        p.back_add(1, &y, &mut once, None);
        let mut twice = once.clone();
        let mut cols = vec![0f32; grid.len()];
        p.back_add(1, &y, &mut twice, Some(&mut cols));
        let mut ones_back = vec![0f32; grid.len()];
        p.back_add(1, &vec![1.0; p.view_len(1)], &mut ones_back, None);
        for j in 0..grid.len() {
            assert!((twice[j] - 2.0 * once[j]).abs() <= 1e-5 * once[j].abs().max(1e-6), "{name}: not accumulated");
            assert!((cols[j] - ones_back[j]).abs() <= 1e-5 * ones_back[j].max(1e-6), "{name}: column sums differ");
        }
    }
}

#[test]
fn rows_reproduce_the_forward_projection() {
    let grid = Grid::new([11, 10, 9], aabb());
    let cams = distorted_ring(2, 28);
    for (name, p) in projectors(grid, &cams, 2.0) {
        let x = uniform(5, grid.len());
        let mut ax = vec![0f32; p.view_len(0)];
        p.forward(0, &x, &mut ax);
        let rows = p.rows(0);
        assert_eq!(rows.n_rows(), p.view_len(0));
        let peak = ax.iter().cloned().fold(0f32, f32::max);
        for (i, &expected) in ax.iter().enumerate() {
            let (cols, vals) = rows.row(i);
            let mut seen = cols.to_vec();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), cols.len(), "{name}: row {i} repeats a voxel");
            let got: f32 = cols.iter().zip(vals).map(|(&j, &w)| w * x[j as usize]).sum();
            assert!((got - expected).abs() <= 1e-4 * peak, "{name} row {i}: {got} vs {expected}");
        }
    }
}

/// Forward projection of a smooth volume = the renderer's image of that volume (same imaging
/// law and scale): total intensity within 0.5 %, and pixel by pixel within 5 % relative L2 for
/// the splat (its 2 × 2 bilinear footprint blurs by about a pixel; measured 2.5–3.7 %) and
/// 0.5 % for the ray projector (the same trilinear integrand; measured 0.03 %).
#[test]
fn forward_matches_the_reference_renderer() {
    let grid = Grid::new([32, 32, 32], aabb());
    let vol = truth(&grid, blobs);
    let scale = 3.5;
    for distorted in [false, true] {
        let cams = if distorted { distorted_ring(3, 48) } else { ring(3, 48) };
        let s = RenderSettings { scale, step: Some(0.005), ..Default::default() };
        for (name, p) in projectors(grid, &cams, scale) {
            let bound = match name {
                "splat" => 0.05,
                "footprint" => 0.015,
                _ => 0.005,
            };
            for (v, cam) in cams.iter().enumerate() {
                let reference = render_image(&vol, cam, &grid.aabb, &s).expect("renders");
                let mut ax = vec![0f32; p.view_len(v)];
                p.forward(v, &vol.data, &mut ax);
                let err = nrmse(&ax, &reference.data);
                let total = ax.iter().map(|&v| v as f64).sum::<f64>() / reference.sum();
                assert!(
                    (total - 1.0).abs() < 0.005,
                    "{name} (distorted: {distorted}) view {v}: total ratio {total:.4}"
                );
                assert!(err < bound, "{name} (distorted: {distorted}) view {v}: relative error {err:.4}");
            }
        }
    }
    // A constant volume: the splat conserves the total emitted power.
    let ones = Volume::from_fn(grid.dims, grid.aabb, |_| 1.0);
    let cams = ring(1, 48);
    let p = SplatProjector::new(grid, &cams, 1.0).expect("valid");
    let mut ax = vec![0f32; p.view_len(0)];
    p.forward(0, &ones.data, &mut ax);
    let reference =
        render_image(&ones, &cams[0], &grid.aabb, &RenderSettings { step: Some(0.005), ..Default::default() })
            .expect("renders");
    let (a, b) = (ax.iter().map(|&v| v as f64).sum::<f64>(), reference.sum());
    assert!((a / b - 1.0).abs() < 0.01, "total {a} vs {b}");
}

/// Voxels several pixels wide: one splat per voxel centre leaves gaps between the 2 × 2 blocks;
/// the automatic sub-voxel splat closes them and matches the renderer of the same piecewise-
/// constant voxels (the splat's basis) again.
#[test]
fn coarse_voxels_are_subdivided() {
    let grid = Grid::new([10, 10, 10], aabb());
    let cams = ring(2, 48);
    let vol = truth(&grid, blobs);
    let s = RenderSettings { step: Some(0.005), supersample: 2, ..Default::default() };
    let boxes = |p: glam::Vec3, _t: f64| {
        let g = (p.as_dvec3() - grid.aabb.min) / grid.spacing();
        let [i, j, k] = [g.x, g.y, g.z].map(|c| (c.floor().max(0.0) as usize).min(9));
        vol.data[(k * 10 + j) * 10 + i]
    };
    let auto = SplatProjector::new(grid, &cams, 1.0).expect("valid");
    assert!(auto.subdivisions() >= 2, "voxels of ~3 px need sub-voxels, got {}", auto.subdivisions());
    let single = auto.clone().with_subdivisions(1);
    for v in 0..cams.len() {
        let reference = render_image(&boxes, &cams[v], &grid.aabb, &s).expect("renders");
        let mut a = vec![0f32; auto.view_len(v)];
        auto.forward(v, &vol.data, &mut a);
        let mut b = a.clone();
        single.forward(v, &vol.data, &mut b);
        let (ea, eb) = (nrmse(&a, &reference.data), nrmse(&b, &reference.data));
        assert!(ea < 0.06, "view {v}: subdivided splat error {ea:.4}");
        assert!(eb > 2.0 * ea, "view {v}: single splat {eb:.4} should be clearly worse than {ea:.4}");
    }
}
