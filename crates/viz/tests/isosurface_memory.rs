//! Marching cubes within a memory bound.

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Volume};
use fluidnerf_viz::{marching_cubes, marching_cubes_within};

/// A surface through noise crosses nearly every cell, and its mesh grew without bound until an
/// allocation failed and the program aborted. Within a bound the mesh is given up as soon as it
/// would pass it; within a bound it fits, it is the mesh unbounded marching cubes gives.
#[test]
fn a_mesh_beyond_its_memory_bound_is_given_up() {
    let noise = |p: DVec3| ((p.x * 12.9898 + p.y * 78.233 + p.z * 37.719).sin() * 43758.5453).fract().abs() as f32;
    let volume = Volume::from_fn([16, 16, 16], Aabb::cube(DVec3::ZERO, 1.0), noise);
    let full = marching_cubes(&volume, 0.5);
    assert!(full.triangles.len() > 3000, "the noise crosses most cells: {}", full.triangles.len());
    assert!(marching_cubes_within(&volume, 0.5, 64 << 10).is_none(), "64 KiB do not hold the mesh");
    let bounded = marching_cubes_within(&volume, 0.5, 64 << 20).expect("64 MiB hold it");
    assert_eq!(bounded.vertices, full.vertices);
    assert_eq!(bounded.triangles, full.triangles);
}
