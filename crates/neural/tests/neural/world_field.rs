//! A trained field in world coordinates: its occupancy mask zeroes the empty cells in `eval`,
//! and `eval_unmasked` gives the network's own values there (what a bake reads at the vertices
//! on the hull's faces), the same values in the occupied cells, and zero outside the box. A
//! time-resolved run's stitched field states its windows' hull when they share one.

use fluidnerf_core::{Aabb, ScalarField};
use fluidnerf_neural::occupancy::OccupancyGrid;
use fluidnerf_neural::temporal::{StitchedField, TimeAxis};
use fluidnerf_neural::train::FieldMeta;
use fluidnerf_neural::trained::{TrainedField, WorldField};
use fluidnerf_neural::{HashGridConfig, HashGridField, TrainableField};
use glam::{DVec3, Vec3};

fn field(seed: u64) -> HashGridField {
    let cfg = HashGridConfig {
        levels: 4,
        log2_table_size: 12,
        base_resolution: 4,
        max_resolution: 16,
        init_scale: 0.0,
        ..HashGridConfig::default()
    };
    let mut field = HashGridField::new(&cfg, 3, seed).expect("valid config");
    let grid = field.grid_params();
    for (i, p) in field.params_mut()[..grid].iter_mut().enumerate() {
        *p = 0.4 * ((i as f32 * 0.37 + seed as f32).sin() + (i as f32 * 0.011).cos());
    }
    field
}

/// Every cell of a 4³ hull occupied but those with i < 2 and j < 2 (and, with `more`, the
/// cell at the far corner).
fn hull(more: bool) -> OccupancyGrid {
    let empty = |c: usize| (c % 4 < 2 && (c / 4) % 4 < 2) || (more && c == 63);
    let cells: Vec<bool> = (0..64).map(|c| !empty(c)).collect();
    OccupancyGrid::from_cells([4, 4, 4], cells).expect("4³ cells")
}

fn aabb() -> Aabb {
    Aabb::new(DVec3::new(-1.0, -2.0, 0.0), DVec3::new(3.0, 2.0, 2.0))
}

#[test]
fn the_mask_zeroes_the_empty_cells_and_nothing_else() {
    let (field, hull) = (field(1), hull(false));
    let meta = FieldMeta { aabb: aabb(), value_scale: 2.5, time_step: 1.0, occupancy: None };
    let world = WorldField { field: &field, meta: &meta, occupancy: Some(&hull) };

    // A lattice over the box and a little beyond it.
    let points: Vec<Vec3> = (0..13 * 13 * 13)
        .map(|n| {
            let f = |m: usize| (m as f32 + 0.5) / 12.0 * 1.1 - 0.05;
            let (u, v, w) = (f(n % 13), f((n / 13) % 13), f(n / 169));
            Vec3::new(-1.0 + 4.0 * u, -2.0 + 4.0 * v, 2.0 * w)
        })
        .collect();
    let (mut masked, mut unmasked) = (vec![0f32; points.len()], vec![0f32; points.len()]);
    world.eval(&points, 0.0, &mut masked);
    world.eval_unmasked(&points, 0.0, &mut unmasked);
    let (mut empty_nonzero, mut occupied) = (0, 0);
    for ((p, &m), &u) in points.iter().zip(&masked).zip(&unmasked) {
        let rel = (*p - Vec3::new(-1.0, -2.0, 0.0)) / Vec3::new(4.0, 4.0, 2.0);
        if rel.cmplt(Vec3::ZERO).any() || rel.cmpgt(Vec3::ONE).any() {
            assert_eq!((m, u), (0.0, 0.0), "outside the box at {p}");
        } else if rel.x < 0.5 && rel.y < 0.5 {
            assert_eq!(m, 0.0, "an empty cell at {p}");
            empty_nonzero += usize::from(u != 0.0);
        } else {
            // The same network on other batches: equal up to the kernels' rounding.
            assert!((m - u).abs() <= 1e-5 * u.abs().max(1.0), "an occupied cell at {p}: {m} vs {u}");
            occupied += usize::from(m != 0.0);
        }
    }
    assert!(empty_nonzero > 100, "the network holds values in the empty cells: {empty_nonzero}");
    assert!(occupied > 500, "{occupied}");
}

/// Two windows with one hull: the stitched field states it, zeroes the empty cells in `eval`
/// and gives the blend of the windows' own values there in `eval_unmasked`. Windows whose
/// hulls differ state their union, and `eval_unmasked` keeps their masks: a bake read inside
/// the union would otherwise show one window's values where only the other's hull holds the
/// flow.
#[test]
fn a_stitched_field_states_the_union_of_its_windows_hulls() {
    let window = |seed: u64, more: bool| -> Box<dyn ScalarField + Send + Sync> {
        let occupancy = Some(hull(more).to_record());
        let meta = FieldMeta { aabb: aabb(), value_scale: 1.0, time_step: 1.0, occupancy };
        Box::new(TrainedField::new(field(seed), meta).expect("valid hull"))
    };
    let stitched = |more: bool| {
        StitchedField::new(
            vec![0.0, 1.0, 2.0, 3.0],
            vec![0..3, 1..4],
            vec![0.0, 1.0],
            vec![TimeAxis::Time; 2],
            vec![window(1, more), window(2, false)],
        )
    };
    // In an empty cell of both hulls (i, j < 2), in the far corner cell that only the second
    // window's hull holds with `more`, and in a cell both hold; at a time both windows blend.
    let points = [Vec3::new(-0.5, -1.5, 0.7), Vec3::new(2.5, 1.5, 1.7), Vec3::new(2.5, 1.5, 0.7)];
    let eval = |f: &StitchedField| {
        let (mut masked, mut unmasked) = ([0f32; 3], [0f32; 3]);
        f.eval(&points, 1.5, &mut masked);
        f.eval_unmasked(&points, 1.5, &mut unmasked);
        (masked, unmasked)
    };

    let shared = stitched(false);
    let sup = shared.support().expect("the windows share their hull");
    assert_eq!((sup.dims, sup.cells), ([4, 4, 4], hull(false).cells()));
    let (masked, unmasked) = eval(&shared);
    assert_eq!(masked[0], 0.0);
    assert!(unmasked[0] != 0.0, "the windows' own values in the empty cell");
    for c in 1..3 {
        assert!(masked[c] != 0.0 && (masked[c] - unmasked[c]).abs() <= 1e-5 * masked[c].abs());
    }

    let differ = stitched(true);
    let sup = differ.support().expect("the union of the hulls");
    assert_eq!(sup.cells, hull(false).cells(), "the second window's hull holds the first's");
    let (masked, unmasked) = eval(&differ);
    assert_eq!(masked, unmasked, "the masks stay");
    assert_eq!(masked[0], 0.0);
    assert!(masked[1] != 0.0, "the second window holds the corner");
    // The first window's own mask, at a time only it covers, drops the corner.
    let mut first = [0f32; 3];
    differ.eval(&points, 0.0, &mut first);
    assert_eq!(first[1], 0.0);
    assert!(first[2] != 0.0);
}
