//! The projectors: adjoint identity, row access, and agreement with the reference renderer.

use crate::common;

use common::*;
use fluidnerf_classical::{FootprintProjector, Grid, Isa, Projector, RayProjector, SplatProjector};
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

/// The footprint back projector has several paths: small footprints are read eight or sixteen
/// voxels at a time (AVX2 or AVX-512 gathers), larger ones voxel by voxel, with or without
/// column sums; each compiled for the baseline, AVX2 and AVX-512. All must give the baseline's
/// f32 results (back projection and column sums) bit for bit, for every footprint side, with
/// and without lens distortion; the forward projections agree up to the order of summation.
#[test]
fn footprint_back_projection_paths_agree_bit_for_bit() {
    let (mut sides, mut kept_views) = (Vec::new(), 0);
    for (dims, cams) in [
        ([40, 36, 32], ring(3, 24)),
        ([20, 18, 16], ring(3, 24)),
        ([20, 18, 16], distorted_ring(3, 40)),
        ([10, 9, 8], distorted_ring(2, 40)),
        ([6, 6, 5], ring(2, 64)),
        ([20, 18, 16], ring_turned(3, 24)),
        ([40, 36, 32], zoomed(2, 24, 1.8, false)),
        ([40, 36, 32], zoomed(2, 24, 1.8, true)),
        ([16, 32, 32], zoomed(2, 24, 3.3, false)),
        ([16, 32, 32], zoomed(2, 24, 3.3, true)),
        ([16, 32, 32], zoomed(2, 48, 1.65, false)),
        ([16, 32, 32], zoomed(2, 48, 1.65, true)),
    ] {
        let grid = Grid::new(dims, aabb());
        let base = FootprintProjector::new(grid, &cams, 0.9).expect("valid").with_isa(Isa::Baseline);
        assert_eq!(base.isa(), Isa::Baseline);
        let x = uniform(7, grid.len());
        for v in 0..base.n_views() {
            sides.push(base.footprint_side(v));
            let y = uniform(20 + v as u64, base.view_len(v));
            let mut reference = vec![0f32; grid.len()];
            base.back_add(v, &y, &mut reference, None);
            let (mut with_cols, mut ref_cols) = (vec![0f32; grid.len()], vec![0f32; grid.len()]);
            base.back_add(v, &y, &mut with_cols, Some(&mut ref_cols));
            assert!(ref_cols.iter().any(|&c| c > 0.0), "view {v} of {dims:?}: no column sums");
            assert!(reference.iter().any(|&b| b > 0.0), "view {v} of {dims:?} sees nothing");
            let mut fwd_ref = vec![0f32; base.view_len(v)];
            base.forward(v, &x, &mut fwd_ref);
            for isa in Isa::available() {
                let p = base.clone().with_isa(isa);
                let side = p.footprint_side(v);
                let mut lanes = vec![0f32; grid.len()];
                p.back_add(v, &y, &mut lanes, None);
                let mut by_voxel = vec![0f32; grid.len()];
                let mut cols = vec![0f32; grid.len()];
                p.back_add(v, &y, &mut by_voxel, Some(&mut cols));
                for (j, ((a, b), r)) in lanes.iter().zip(&by_voxel).zip(&reference).enumerate() {
                    assert_eq!(a.to_bits(), r.to_bits(), "{isa:?} voxel {j} of {dims:?}, view {v}, side {side}");
                    assert_eq!(b.to_bits(), r.to_bits(), "{isa:?} voxel {j} of {dims:?}, view {v}, side {side}");
                }
                for (j, (c, r)) in cols.iter().zip(&ref_cols).enumerate() {
                    assert_eq!(c.to_bits(), r.to_bits(), "{isa:?} column sum {j} of {dims:?}, view {v}, side {side}");
                }
                // Footprints kept by the first back projection and read by the next: the same
                // bits, with and without column sums.
                let kept = p.clone().with_kept_footprints(u64::MAX);
                kept_views += kept.kept_footprint_views();
                for pass in 0..2 {
                    let (mut b, mut kc, mut bc) =
                        (vec![0f32; grid.len()], vec![0f32; grid.len()], vec![0f32; grid.len()]);
                    kept.back_add(v, &y, &mut b, None);
                    kept.back_add(v, &y, &mut bc, Some(&mut kc));
                    for (j, ((a, c), r)) in b.iter().zip(&bc).zip(&reference).enumerate() {
                        assert_eq!(
                            a.to_bits(),
                            r.to_bits(),
                            "{isa:?} kept, pass {pass}, voxel {j} of {dims:?}, view {v}"
                        );
                        assert_eq!(
                            c.to_bits(),
                            r.to_bits(),
                            "{isa:?} kept, pass {pass}, voxel {j} of {dims:?}, view {v}"
                        );
                    }
                    for (j, (c, r)) in kc.iter().zip(&ref_cols).enumerate() {
                        assert_eq!(c.to_bits(), r.to_bits(), "{isa:?} kept column sum {j} of {dims:?}, view {v}");
                    }
                }
                let mut fwd = vec![0f32; p.view_len(v)];
                p.forward(v, &x, &mut fwd);
                for (i, (a, r)) in fwd.iter().zip(&fwd_ref).enumerate() {
                    assert!((a - r).abs() <= 1e-5 * r.abs().max(1e-3), "{isa:?} pixel {i} of view {v}: {a} vs {r}");
                }
            }
        }
    }
    sides.sort_unstable();
    sides.dedup();
    assert!(sides.contains(&2) && sides.contains(&4) && sides.len() >= 3, "sides covered: {sides:?}");
    assert!(kept_views > 0, "no view kept footprints");
}

/// Kept footprints fill a budget view by view, each view whole or not at all: with room for
/// one view of a ring around the grid's `x` axis exactly that view is kept, its bytes are
/// what the projector reports, and back projections of every view, several passes, match a
/// projector that keeps none bit for bit.
#[test]
fn kept_footprints_fill_their_budget_view_by_view() {
    let grid = Grid::new([40, 36, 32], aabb());
    let cams = ring(3, 24);
    let plain = FootprintProjector::new(grid, &cams, 0.9).expect("valid");
    let all = plain.clone().with_kept_footprints(u64::MAX);
    assert_eq!(all.kept_footprint_views(), 3);
    let per_view = all.kept_footprint_bytes() / 3;
    assert!(per_view > grid.len() as u64 * 4, "{per_view} bytes per view");
    let one = plain.clone().with_kept_footprints(per_view + per_view / 2);
    assert_eq!((one.kept_footprint_views(), one.kept_footprint_bytes()), (1, per_view));
    assert_eq!(plain.clone().with_kept_footprints(per_view - 1).kept_footprint_views(), 0);
    assert_eq!(one.bytes() - plain.bytes(), per_view as usize);
    let ys: Vec<Vec<f32>> = (0..3).map(|v| uniform(40 + v as u64, plain.view_len(v))).collect();
    let back = |p: &FootprintProjector| {
        let mut out = vec![0f32; grid.len()];
        for _ in 0..2 {
            for (v, y) in ys.iter().enumerate() {
                p.back_add(v, y, &mut out, None);
            }
        }
        out
    };
    let reference = back(&plain);
    assert!(reference.iter().any(|&b| b != 0.0));
    for p in [&one, &all] {
        assert!(back(p).iter().zip(&reference).all(|(a, r)| a.to_bits() == r.to_bits()));
    }
}

/// Back-projecting several views in one call (one pass over the grid, each slab taking the
/// views in turn) gives what `back_add` gives view by view, bit for bit, with and without
/// column sums, for views that share rows, views that do not, and distorted ones mixed, in
/// any order; and a projector without its own version (the ray projector) does the same.
#[test]
fn back_projection_of_several_views_equals_view_by_view() {
    let mut cams = ring(2, 24);
    cams.extend(ring_turned(2, 40));
    cams.extend(distorted_ring(2, 40));
    cams.extend(zoomed(1, 24, 3.3, false));
    let grid = Grid::new([20, 18, 16], aabb());
    let footprint = FootprintProjector::new(grid, &cams, 0.8).expect("valid");
    assert!(footprint.shared_row_views() >= 3, "some views share their rows");
    let ray: Box<dyn Projector> = Box::new(RayProjector::new(grid, &cams[..3], 0.8, 0.5).expect("valid"));
    let fp: Box<dyn Projector> = Box::new(footprint);
    for (p, views) in [(&fp, vec![6, 0, 4, 2, 5, 1, 3]), (&fp, vec![3]), (&ray, vec![2, 0, 1])] {
        let ys: Vec<Vec<f32>> = views.iter().map(|&v| uniform(60 + v as u64, p.view_len(v))).collect();
        let refs: Vec<&[f32]> = ys.iter().map(Vec::as_slice).collect();
        for with_cols in [false, true] {
            let start = uniform(5, grid.len());
            let (mut one, mut ones_cols) = (start.clone(), vec![0.5f32; grid.len()]);
            for (&v, y) in views.iter().zip(&refs) {
                p.back_add(v, y, &mut one, with_cols.then_some(&mut ones_cols[..]));
            }
            let (mut all, mut all_cols) = (start.clone(), vec![0.5f32; grid.len()]);
            p.back_add_views(&views, &refs, &mut all, with_cols.then_some(&mut all_cols[..]));
            assert!(one != start, "the views add something");
            for (j, (a, b)) in all.iter().zip(&one).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "views {views:?}, voxel {j}: {a} vs {b}");
            }
            if with_cols {
                assert!(ones_cols.iter().any(|&c| c > 0.5));
                for (j, (a, b)) in all_cols.iter().zip(&ones_cols).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "views {views:?}, column sum {j}");
                }
            }
        }
    }
}

/// A view's fused back projection and update (`back_update`, slab by slab in the footprint
/// projector) hands the update the back projection and column sums `back_add` gives into zeroed
/// buffers, bit for bit, and every voxel exactly once, with its offset: for views that share
/// rows (either way round), views that do not, distorted ones, and a projector that keeps the
/// default (the ray projector); the buffers hold them afterwards.
#[test]
fn fused_back_projection_and_update_equals_back_add_then_update() {
    let mut cams = ring(2, 24);
    cams.extend(ring_turned(1, 40));
    cams.extend(distorted_ring(1, 40));
    cams.extend(zoomed(1, 24, 3.3, false));
    let grid = Grid::new([20, 18, 37], aabb());
    let footprint = FootprintProjector::new(grid, &cams, 0.8).expect("valid");
    assert!(footprint.shared_row_views() >= 2, "some views share their rows");
    let ray: Box<dyn Projector> = Box::new(RayProjector::new(grid, &cams[..2], 0.8, 0.5).expect("valid"));
    let fp: Box<dyn Projector> = Box::new(footprint);
    for (p, views) in [(&fp, 0..5), (&ray, 0..2)] {
        for v in views {
            let y = uniform(70 + v as u64, p.view_len(v));
            let (mut b, mut c) = (vec![0f32; grid.len()], vec![0f32; grid.len()]);
            p.back_add(v, &y, &mut b, Some(&mut c));
            assert!(c.iter().any(|&c| c > 0.0), "view {v} sees the grid");
            // The update records what it was handed: x ← 3 b + c.
            let x0 = uniform(9, grid.len());
            let mut x = x0.clone();
            let (mut sb, mut sc) = (vec![f32::NAN; grid.len()], vec![7.0f32; grid.len()]);
            let seen = std::sync::atomic::AtomicUsize::new(0);
            p.back_update(v, &y, &mut x, (&mut sb, &mut sc), &|at, xs, bs, cs| {
                seen.fetch_add(xs.len(), std::sync::atomic::Ordering::Relaxed);
                for (k, (g, (&bv, &cv))) in xs.iter_mut().zip(bs.iter().zip(cs)).enumerate() {
                    // The voxel's own start value: the offset is right.
                    assert_eq!(g.to_bits(), x0[at + k].to_bits(), "view {v}, voxel {}", at + k);
                    *g = 3.0 * bv + cv;
                }
            });
            assert_eq!(seen.into_inner(), grid.len(), "view {v}: every voxel once");
            for j in 0..grid.len() {
                assert_eq!(x[j].to_bits(), (3.0 * b[j] + c[j]).to_bits(), "view {v}, voxel {j}");
                assert_eq!((sb[j].to_bits(), sc[j].to_bits()), (b[j].to_bits(), c[j].to_bits()), "view {v}, voxel {j}");
            }
        }
    }
}

/// Projecting one volume into several views at once finds its empty chunks once; the images
/// are those of the views projected one by one, bit for bit, with every instruction set, for
/// views that share their rows, general and distorted ones, and a volume with empty slices,
/// empty rows, lone voxels and a filled block. With few views for the threads (seven on two)
/// each view is split over the threads as one view alone is; with many (sixteen on two) each
/// view runs on one thread, and its image is then the one a single thread draws.
#[test]
fn forward_projection_of_several_views_equals_view_by_view() {
    let mut cams = ring(2, 24);
    cams.extend(ring_turned(2, 40));
    cams.extend(distorted_ring(2, 40));
    cams.extend(zoomed(1, 24, 3.3, false));
    let grid = Grid::new([40, 18, 16], aabb());
    let mut x = vec![0f32; grid.len()];
    for (i, j, k) in [(0, 0, 0), (15, 5, 3), (16, 5, 3), (39, 17, 15), (33, 9, 12)] {
        x[(k * 18 + j) * 40 + i] = 1.0 + i as f32 / 40.0;
    }
    let block = uniform(8, grid.len());
    for k in 6..10 {
        for j in 4..14 {
            for i in 10..27 {
                let at = (k * 18 + j) * 40 + i;
                x[at] = block[at];
            }
        }
    }
    let pool = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
    let (two, one_thread) = (pool(2), pool(1));
    let few = [6, 0, 4, 2, 5, 1, 3];
    let many: Vec<usize> = few.iter().chain(&few).chain(&[0, 6]).copied().collect();
    for isa in Isa::available() {
        let p = FootprintProjector::new(grid, &cams, 0.8).expect("valid").with_isa(isa);
        assert!(p.shared_row_views() >= 3, "some views share their rows");
        for (views, alone_on) in [(&few[..], &two), (&many[..], &one_thread)] {
            let mut together: Vec<Vec<f32>> = views.iter().map(|&v| vec![7f32; p.view_len(v)]).collect();
            let mut outs: Vec<&mut [f32]> = together.iter_mut().map(Vec::as_mut_slice).collect();
            two.install(|| p.forward_views(views, &x, &mut outs));
            for (&v, got) in views.iter().zip(&together) {
                let mut one = vec![0f32; p.view_len(v)];
                alone_on.install(|| p.forward(v, &x, &mut one));
                assert!(one.iter().any(|&a| a > 0.0), "{isa:?} view {v} sees nothing");
                for (i, (a, b)) in got.iter().zip(&one).enumerate() {
                    let n = views.len();
                    assert_eq!(a.to_bits(), b.to_bits(), "{isa:?}, {n} views, view {v}, pixel {i}: {a} vs {b}");
                }
            }
        }
    }
}

/// The cameras of [`ring`] turned a quarter about their axis: a grid row is horizontal in
/// their images (as in the synthetic jets' rings), where [`ring`]'s see it vertical.
fn ring_turned(n: usize, px: u32) -> Vec<fluidnerf_core::Camera> {
    zoomed(n, px, 1.0, true)
}

/// [`ring`] (or [`ring_turned`]) with the focal length scaled by `zoom`: above about 1.4 the
/// box overfills the images, so footprints cross their edges.
fn zoomed(n: usize, px: u32, zoom: f64, turned: bool) -> Vec<fluidnerf_core::Camera> {
    ring(n, px)
        .into_iter()
        .map(|c| {
            let eye = c.centre();
            let up = if turned { glam::DVec3::X.cross(eye).normalize() } else { glam::DVec3::X };
            let mut k = c.intrinsics;
            (k.fx, k.fy) = (k.fx * zoom, k.fy * zoom);
            fluidnerf_core::Camera::look_at(k, eye, glam::DVec3::ZERO, up)
        })
        .collect()
}

/// On a ring around the grid's x axis the voxels of a row share their footprint along one
/// image axis, computed once per row: the projections, the column sums and the back
/// projections agree with the voxel-by-voxel evaluation to rounding, with every instruction
/// set, whether rows image vertical or horizontal, also where footprints cross the image's
/// edges (the column sums' masks), and each path is its own exact adjoint.
#[test]
fn footprint_shared_rows_agree_with_the_general_path() {
    let mut cases = Vec::new();
    for turn in [false, true] {
        for (dims, px) in [([40, 18, 16], 24), ([20, 12, 10], 64), ([9, 7, 6], 40)] {
            cases.push((dims, if turn { ring_turned(3, px) } else { ring(3, px) }));
        }
        cases.push(([16, 32, 32], zoomed(3, 24, 3.3, turn)));
    }
    for (dims, cams) in cases {
        let grid = Grid::new(dims, aabb());
        let general = FootprintProjector::new(grid, &cams, 0.7).expect("valid").with_shared_rows(false);
        assert_eq!(general.shared_row_views(), 0);
        let x = uniform(3, grid.len());
        for isa in Isa::available() {
            let shared = FootprintProjector::new(grid, &cams, 0.7).expect("valid").with_isa(isa);
            assert_eq!(shared.shared_row_views(), 3, "a ring around x shares its rows");
            let general = general.clone().with_isa(isa);
            for v in 0..3 {
                let side = shared.footprint_side(v);
                let (mut a, mut b) = (vec![0f32; shared.view_len(v)], vec![0f32; shared.view_len(v)]);
                shared.forward(v, &x, &mut a);
                general.forward(v, &x, &mut b);
                let peak = b.iter().cloned().fold(0f32, f32::max);
                assert!(peak > 0.0);
                for (i, (p, q)) in a.iter().zip(&b).enumerate() {
                    assert!(
                        (p - q).abs() <= 2e-5 * peak,
                        "{isa:?} {dims:?} view {v} side {side} pixel {i}: {p} vs {q}"
                    );
                }
                let y = uniform(40 + v as u64, shared.view_len(v));
                let (mut ba, mut bb) = (vec![0f32; grid.len()], vec![0f32; grid.len()]);
                let (mut ca, mut cb) = (vec![0f32; grid.len()], vec![0f32; grid.len()]);
                shared.back_add(v, &y, &mut ba, Some(&mut ca));
                general.back_add(v, &y, &mut bb, Some(&mut cb));
                let top = bb.iter().chain(&cb).cloned().fold(0f32, f32::max);
                for (j, ((p, q), (c, d))) in ba.iter().zip(&bb).zip(ca.iter().zip(&cb)).enumerate() {
                    assert!((p - q).abs() <= 2e-5 * top, "{isa:?} {dims:?} view {v} voxel {j}: {p} vs {q}");
                    assert!((c - d).abs() <= 2e-5 * top, "{isa:?} {dims:?} view {v} column sum {j}: {c} vs {d}");
                }
                let (lhs, rhs) = (dot(&a, &y), dot(&x, &ba));
                assert!(
                    (lhs - rhs).abs() <= 1e-5 * lhs.abs(),
                    "{isa:?} {dims:?} view {v}: <Ax,y> {lhs} vs <x,A'y> {rhs}"
                );
            }
        }
    }
}

/// The forward projection skips runs of empty voxels: a volume that is empty but for a few
/// voxels (alone in their chunk, at a chunk's edge, in a row's short last chunk) projects as
/// its matrix rows say, with every instruction set, and an empty volume projects to zero.
#[test]
fn footprint_forward_of_a_mostly_empty_volume_matches_its_rows() {
    let grid = Grid::new([40, 12, 10], aabb());
    let cams = distorted_ring(3, 32);
    let mut x = vec![0f32; grid.len()];
    for (i, j, k) in [(0, 0, 0), (15, 5, 3), (16, 5, 3), (37, 11, 9), (39, 6, 4), (20, 2, 8)] {
        x[(k * 12 + j) * 40 + i] = 1.0 + i as f32 / 40.0;
    }
    for isa in Isa::available() {
        let p = FootprintProjector::new(grid, &cams, 1.5).expect("valid").with_isa(isa);
        for v in 0..p.n_views() {
            let mut ax = vec![1f32; p.view_len(v)];
            p.forward(v, &vec![0f32; grid.len()], &mut ax);
            assert!(ax.iter().all(|&a| a == 0.0), "{isa:?} view {v}: an empty volume must project to zero");
            p.forward(v, &x, &mut ax);
            let rows = p.rows(v);
            let peak = ax.iter().cloned().fold(0f32, f32::max);
            assert!(peak > 0.0, "{isa:?} view {v} sees nothing");
            for (i, &got) in ax.iter().enumerate() {
                let (cols, vals) = rows.row(i);
                let want: f32 = cols.iter().zip(vals).map(|(&j, &w)| w * x[j as usize]).sum();
                assert!((got - want).abs() <= 1e-5 * peak, "{isa:?} view {v} pixel {i}: {got} vs {want}");
            }
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

/// The footprint projector's rows are built in parallel, each thread over a range of
/// z-slices: they are the same, entry for entry and in the same order (voxel order within a
/// row), whatever the number of threads and the instruction set, for undistorted views (rows
/// shared along an image axis) and distorted ones.
#[test]
fn footprint_rows_do_not_depend_on_threads_or_instruction_set() {
    let grid = Grid::new([13, 11, 9], aabb());
    for cams in [ring(2, 30), distorted_ring(2, 30)] {
        let reference = FootprintProjector::new(grid, &cams, 1.5).expect("valid").with_isa(Isa::Baseline);
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
        let want: Vec<_> = one.install(|| (0..2).map(|v| reference.rows(v)).collect());
        assert!(want.iter().all(|r| r.vals.len() > grid.len()), "too few entries to test");
        for isa in Isa::available() {
            let p = FootprintProjector::new(grid, &cams, 1.5).expect("valid").with_isa(isa);
            for threads in [1, 2, 3, 5] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                for (v, want) in want.iter().enumerate() {
                    let got = pool.install(|| p.rows(v));
                    assert_eq!(got.ptr, want.ptr, "{isa:?}, {threads} threads, view {v}: row starts");
                    assert_eq!(got.cols, want.cols, "{isa:?}, {threads} threads, view {v}: voxels");
                    let bits =
                        |r: &fluidnerf_classical::SparseRows| r.vals.iter().map(|w| w.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&got), bits(want), "{isa:?}, {threads} threads, view {v}: weights");
                }
            }
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

/// A uniform ball of radius 0.55 voxelised with partial volumes (4³ samples per voxel).
fn ball_volume(grid: &Grid) -> Vec<f32> {
    let sp = grid.spacing();
    let [nx, ny, nz] = grid.dims;
    let mut out = Vec::with_capacity(grid.len());
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let mut inside = 0;
                for s in 0..64 {
                    let o = glam::DVec3::new((s % 4) as f64, ((s / 4) % 4) as f64, (s / 16) as f64) * 0.25 + 0.125;
                    let p = grid.aabb.min + (glam::DVec3::new(i as f64, j as f64, k as f64) + o) * sp;
                    inside += usize::from(ball(p) > 0.0);
                }
                out.push(inside as f32 / 64.0);
            }
        }
    }
    out
}

/// The analytic image of [`ball`]: `scale ×` the chord length along each ray, averaged over
/// 4 × 4 rays per pixel (the pixel-area average the footprint models).
fn ball_image(cam: &fluidnerf_core::Camera, scale: f64) -> Vec<f32> {
    let centre = glam::DVec3::new(0.1, -0.05, 0.08);
    let r2 = 0.55f64 * 0.55;
    let mut img = Vec::with_capacity(cam.width() * cam.height());
    for row in 0..cam.height() {
        for col in 0..cam.width() {
            let mut sum = 0.0;
            for s in 0..16 {
                let (du, dv) = ((s % 4) as f64 * 0.25 - 0.375, (s / 4) as f64 * 0.25 - 0.375);
                let ray = cam.pixel_ray(col as f64 + du, row as f64 + dv).expect("undistorts");
                let oc = centre - ray.origin;
                let t = oc.dot(ray.dir);
                let d2 = oc.length_squared() - t * t;
                sum += 2.0 * (r2 - d2).max(0.0).sqrt();
            }
            img.push((scale * sum / 16.0) as f32);
        }
    }
    img
}

/// The uniform ball's projections against its analytic chord lengths (pixel-area averages),
/// for voxels imaging at about 3 px (16³ on 120² px; the splat splits them into 3³) and about
/// 1 px (32³ on 80² px), with and without distortion. At 16³ the error is mostly the
/// voxelisation of the ball's edge, shared by all projectors. Measured relative L2 errors:
/// footprint 8.9–10.7 % / splat 9.0–10.7 % / ray 8.8–9.1 % at 16³, and 1.9–2.8 % / 2.1–2.8 % /
/// 1.9–2.8 % at 32³. Asserted: the footprint is no worse than the splat (1 % slack), within
/// 25 % of the ray projector's error, and under 12 % and 3.5 %.
#[test]
fn footprint_matches_the_analytic_ball_at_least_as_well_as_the_splat() {
    let scale = 1.8;
    for (n, px, bound) in [(16usize, 120u32, 0.12), (32, 80, 0.035)] {
        let grid = Grid::new([n, n, n], aabb());
        let x = ball_volume(&grid);
        for distorted in [false, true] {
            let cams = if distorted { distorted_ring(3, px) } else { ring(3, px) };
            let ps = projectors(grid, &cams, scale);
            for v in 0..cams.len() {
                let exact = ball_image(&cams[v], scale);
                let err: Vec<(&str, f64)> = ps
                    .iter()
                    .map(|(name, p)| {
                        let mut ax = vec![0f32; p.view_len(v)];
                        p.forward(v, &x, &mut ax);
                        (*name, nrmse(&ax, &exact))
                    })
                    .collect();
                let get = |w: &str| err.iter().find(|e| e.0 == w).expect("projector").1;
                let (fp, splat, ray) = (get("footprint"), get("splat"), get("ray"));
                let ctx = format!(
                    "{n}^3, distorted {distorted}, view {v}: footprint {fp:.4}, splat {splat:.4}, ray {ray:.4}"
                );
                assert!(fp < bound, "{ctx}");
                assert!(fp <= 1.01 * splat, "{ctx}");
                assert!(fp <= 1.25 * ray, "{ctx}");
            }
        }
    }
}

/// The footprint projector against the ray projector on a smooth volume (the two-blob phantom
/// at the voxel centres): within 2.5 % relative L2 at 32³ (voxels of about 1 px, measured
/// 1.0–1.3 %) and 6 % at 12³ (about 3 px, where the two bases — piecewise constant against
/// trilinear — differ most; measured 3–4 %), distortion included.
#[test]
fn footprint_agrees_with_the_ray_projector() {
    for (n, bound) in [(12usize, 0.06), (32, 0.025)] {
        let grid = Grid::new([n, n, n], aabb());
        let x = truth(&grid, blobs).data;
        for distorted in [false, true] {
            let cams = if distorted { distorted_ring(3, 40) } else { ring(3, 40) };
            let fp = FootprintProjector::new(grid, &cams, 2.0).expect("valid");
            let ray = RayProjector::new(grid, &cams, 2.0, 0.25).expect("valid");
            for v in 0..cams.len() {
                let mut a = vec![0f32; fp.view_len(v)];
                let mut b = a.clone();
                fp.forward(v, &x, &mut a);
                ray.forward(v, &x, &mut b);
                let err = nrmse(&a, &b);
                assert!(err < bound, "{n}^3 distorted {distorted} view {v}: {err:.4}");
            }
        }
    }
}

/// Coarse voxels (wide footprints, sides 8–32) and a camera next to the box (footprints
/// narrowed to fit their square) keep the exact adjoint and the voxel's total weight.
#[test]
fn footprint_adjoint_and_totals_with_wide_footprints() {
    let grid = Grid::new([5, 4, 6], aabb());
    let mut cams = distorted_ring(2, 64);
    let mut near = ring(1, 64).remove(0);
    near.world_from_camera.translation *= 0.45;
    cams.push(near);
    let p = FootprintProjector::new(grid, &cams, 1.1).expect("valid");
    assert!(
        (0..3).any(|v| p.footprint_side(v) >= 16),
        "sides {:?}",
        (0..3).map(|v| p.footprint_side(v)).collect::<Vec<_>>()
    );
    let x = uniform(7, grid.len());
    for v in 0..p.n_views() {
        let y = uniform(20 + v as u64, p.view_len(v));
        let mut ax = vec![0f32; p.view_len(v)];
        p.forward(v, &x, &mut ax);
        let mut aty = vec![0f32; grid.len()];
        p.back_add(v, &y, &mut aty, None);
        let (lhs, rhs) = (dot(&ax, &y), dot(&x, &aty));
        let rel = (lhs - rhs).abs() / lhs.abs().max(rhs.abs());
        assert!(lhs > 0.0 && rel < 1e-5, "view {v}: <Ax,y> = {lhs}, <x,A'y> = {rhs}");
    }
    // A constant volume inside the image of a distant camera: the total is the emitted power.
    let cams = ring(1, 64);
    let p = FootprintProjector::new(grid, &cams, 1.0).expect("valid");
    let ones = vec![1f32; grid.len()];
    let mut ax = vec![0f32; p.view_len(0)];
    p.forward(0, &ones, &mut ax);
    let reference = render_image(
        &Volume::from_fn(grid.dims, grid.aabb, |_| 1.0),
        &cams[0],
        &grid.aabb,
        &RenderSettings { step: Some(0.005), ..Default::default() },
    )
    .expect("renders");
    let (a, b) = (ax.iter().map(|&v| v as f64).sum::<f64>(), reference.sum());
    assert!((a / b - 1.0).abs() < 0.01, "total {a} vs {b}");
}

/// A grid whose voxels 32-bit indices cannot reach is refused by every projector before any
/// work, saying what to lower.
#[test]
fn a_grid_beyond_32_bit_voxel_indices_is_refused_naming_the_resolution() {
    let grid = Grid::new([2048, 2048, 1025], aabb());
    let cams = ring(2, 8);
    let errors = [
        FootprintProjector::new(grid, &cams, 1.0).err(),
        SplatProjector::new(grid, &cams, 1.0).err(),
        RayProjector::new(grid, &cams, 1.0, 0.5).err(),
    ];
    for e in errors {
        let e = e.expect("refused").to_string();
        assert!(e.contains("[2048, 2048, 1025]") && e.contains("2^32") && e.contains("--resolution"), "{e}");
    }
}
