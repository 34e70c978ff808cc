//! Isosurfaces by marching cubes (Lorensen & Cline 1987) on the grid of cell centres.
//!
//! The 256-case triangle table is not typed in but built once from a rule, which makes the
//! result watertight: on each cube face, the contour segments join the edge crossings so that
//! *inside corners are kept apart* on ambiguous faces (two diagonal corners inside, two
//! outside). The decision depends only on the face's four corners, so two cubes sharing a face
//! cut it identically and the surface has no cracks (the failure of the original table that
//! the asymptotic decider of Nielson & Hamann 1991 also repairs). The segments of the six faces
//! chain into closed loops, each fanned into triangles.
//!
//! Conventions: a grid point is *inside* when its value is `> iso`; vertices lie on grid edges
//! at the linearly interpolated crossing, in world coordinates of the volume's box; triangles
//! wind counter-clockwise seen from outside (normals point towards lower values), so a blob
//! brighter than `iso` gives a positive [`TriMesh::enclosed_volume`]. The surface is open where
//! it leaves the hull of the cell centres (half a cell inside the box).

use std::collections::HashMap;
use std::sync::OnceLock;

use fluidnerf_core::Volume;

/// An indexed triangle mesh in world coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub vertices: Vec<[f32; 3]>,
    /// Vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// The signed volume enclosed by a closed mesh (divergence theorem:
    /// `V = Σ (a · (b × c)) / 6` over triangles `abc`), accumulated in f64; 0 (not −0, the
    /// empty sum of floats) for an empty mesh.
    pub fn enclosed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| glam::DVec3::from(self.vertices[i as usize].map(f64::from)));
                a.dot(b.cross(c)) / 6.0
            })
            .fold(0.0, |sum, v| sum + v)
    }

    /// Total triangle area; 0 (not −0) for an empty mesh.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| glam::DVec3::from(self.vertices[i as usize].map(f64::from)));
                0.5 * (b - a).cross(c - a).length()
            })
            .fold(0.0, |sum, v| sum + v)
    }

    /// Edges (vertex index pairs, smaller first) not shared by exactly two triangles, or shared
    /// twice in the same direction (inconsistent winding). Empty for a closed, consistently
    /// oriented (watertight) mesh.
    pub fn defective_edges(&self) -> Vec<(u32, u32)> {
        // Per undirected edge: (uses, sum of directions as +1 for a<b, -1 otherwise).
        let mut edges: HashMap<(u32, u32), (u32, i32)> = HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                let e = edges.entry(key).or_default();
                e.0 += 1;
                e.1 += if a < b { 1 } else { -1 };
            }
        }
        let mut bad: Vec<_> = edges.into_iter().filter(|(_, (n, dir))| *n != 2 || *dir != 0).map(|(k, _)| k).collect();
        bad.sort_unstable();
        bad
    }

    /// Whether every edge is shared by exactly two triangles with opposite directions.
    pub fn is_watertight(&self) -> bool {
        self.defective_edges().is_empty()
    }
}

/// Corner `c` of a cube is offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)` from its base point.
const fn corner_offset(c: usize) -> [usize; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The twelve cube edges as corner pairs (lower corner first).
const EDGES: [(usize, usize); 12] =
    [(0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7)];

/// The six faces, corners counter-clockwise seen from outside the cube.
const FACES: [[usize; 4]; 6] = [
    [0, 2, 3, 1], // z = 0, normal −z
    [4, 5, 7, 6], // z = 1, normal +z
    [0, 1, 5, 4], // y = 0, normal −y
    [2, 6, 7, 3], // y = 1, normal +y
    [0, 4, 6, 2], // x = 0, normal −x
    [1, 3, 7, 5], // x = 1, normal +x
];

fn edge_id(a: usize, b: usize) -> usize {
    let key = (a.min(b), a.max(b));
    EDGES.iter().position(|&e| e == key).unwrap_or_else(|| unreachable!("corners {a} and {b} share no edge"))
}

/// Whether two cube edges lie on a common face.
fn share_face(a: usize, b: usize) -> bool {
    let on = |face: &[usize; 4], e: usize| {
        let (p, q) = EDGES[e];
        face.contains(&p) && face.contains(&q)
    };
    FACES.iter().any(|f| on(f, a) && on(f, b))
}

/// Triangles (as edge triples) for each of the 256 inside/outside patterns.
fn table() -> &'static [Vec<[u8; 3]>] {
    static TABLE: OnceLock<Vec<Vec<[u8; 3]>>> = OnceLock::new();
    TABLE.get_or_init(|| (0..256).map(triangulate_case).collect())
}

fn triangulate_case(mask: usize) -> Vec<[u8; 3]> {
    let inside = |c: usize| mask >> c & 1 == 1;
    // next[e] = the edge the contour goes to after edge e.
    let mut next = [usize::MAX; 12];
    for face in FACES {
        // Walking the face counter-clockwise from outside, an edge is an entry (outside →
        // inside) or an exit. Pairing each entry with the next exit keeps inside corners apart.
        let mut crossings = Vec::with_capacity(4);
        for k in 0..4 {
            let (a, b) = (face[k], face[(k + 1) % 4]);
            if inside(a) != inside(b) {
                crossings.push((edge_id(a, b), inside(b)));
            }
        }
        for (i, &(e, is_entry)) in crossings.iter().enumerate() {
            if is_entry {
                let (exit, _) = crossings[(i + 1) % crossings.len()];
                // The contour runs from the entry to the exit, so that triangles wind
                // counter-clockwise seen from the outside region.
                next[e] = exit;
            }
        }
    }
    let mut tris = Vec::new();
    let mut used = [false; 12];
    for start in 0..12 {
        if next[start] == usize::MAX || used[start] {
            continue;
        }
        let mut loop_edges = vec![start];
        used[start] = true;
        let mut e = next[start];
        while e != start {
            assert!(e != usize::MAX && !used[e], "marching cubes table: open contour in case {mask:#010b}");
            used[e] = true;
            loop_edges.push(e);
            e = next[e];
        }
        // Fan from a vertex whose diagonals do not run along a cube face: such a diagonal
        // could also be cut by the neighbouring cube and make a non-manifold edge.
        let n = loop_edges.len();
        let start = (0..n)
            .find(|&s| (2..n - 1).all(|k| !share_face(loop_edges[s], loop_edges[(s + k) % n])))
            .unwrap_or_else(|| panic!("marching cubes table: no clean fan in case {mask:#010b}"));
        for k in 1..n - 1 {
            tris.push(
                [loop_edges[start], loop_edges[(start + k) % n], loop_edges[(start + k + 1) % n]].map(|e| e as u8),
            );
        }
    }
    tris
}

/// The isosurface `volume = iso` by marching cubes over the cell centres (see the module docs
/// for conventions). Vertices on shared grid edges are shared, so the mesh is indexed.
pub fn marching_cubes(volume: &Volume, iso: f32) -> TriMesh {
    marching_cubes_within(volume, iso, u64::MAX).unwrap_or_default()
}

/// Bytes a mesh under construction holds per vertex (its position and its entry in the table
/// of shared edges, which grows by doubling) and per triangle.
const VERTEX_BYTES: u64 = 12 + 48;
const TRIANGLE_BYTES: u64 = 12;

/// [`marching_cubes`], given up (None) as soon as the mesh would take more than `max_bytes` of
/// memory: a surface through a noisy field crosses nearly every cell of a fine grid, and its
/// mesh can need many times the volume's memory, which a failed allocation aborts on.
pub fn marching_cubes_within(volume: &Volume, iso: f32, max_bytes: u64) -> Option<TriMesh> {
    let spacing = volume.spacing();
    let origin = volume.aabb.min + 0.5 * spacing;
    march(volume.dims, origin, spacing, |i, j, k| volume.get(i, j, k), iso, max_bytes)
}

/// The volume of the region brighter than `iso` within the hull of the cell centres: where the
/// isosurface leaves that hull it is open, and the divergence theorem over an open mesh gives a
/// number that depends on where the world's origin lies. Here the surface is closed on the
/// hull's faces (the grid surrounded by one layer of values far below `iso`, whose crossings
/// then lie on the outermost cell centres to a ten-millionth of a cell) before its volume is
/// taken. None when the mesh would take more than `max_bytes` (see [`marching_cubes_within`]).
pub fn enclosed_volume_within(volume: &Volume, iso: f32, max_bytes: u64) -> Option<f64> {
    let [nx, ny, nz] = volume.dims;
    let (lo, hi) = volume.min_max();
    let range = f64::from(hi.max(iso)) - f64::from(lo.min(iso));
    let below = (f64::from(iso) - 1e7 * (range + 1.0)).max(f64::from(f32::MIN)) as f32;
    let spacing = volume.spacing();
    let origin = volume.aabb.min - 0.5 * spacing;
    let value = |i: usize, j: usize, k: usize| {
        let inside = (1..=nx).contains(&i) && (1..=ny).contains(&j) && (1..=nz).contains(&k);
        if inside {
            volume.get(i - 1, j - 1, k - 1)
        } else {
            below
        }
    };
    march([nx + 2, ny + 2, nz + 2], origin, spacing, value, iso, max_bytes).map(|mesh| mesh.enclosed_volume())
}

/// Marching cubes over the grid points `origin + (i, j, k) · spacing`, `dims` of them, whose
/// values `value` gives.
fn march(
    dims: [usize; 3],
    origin: glam::DVec3,
    spacing: glam::DVec3,
    value: impl Fn(usize, usize, usize) -> f32,
    iso: f32,
    max_bytes: u64,
) -> Option<TriMesh> {
    let [nx, ny, nz] = dims;
    let mut mesh = TriMesh::default();
    if nx < 2 || ny < 2 || nz < 2 {
        return Some(mesh);
    }
    let table = table();
    // Vertex of each crossed grid edge, keyed by (lower grid point index) * 3 + axis.
    let mut vertex_of: HashMap<usize, u32> = HashMap::new();
    let point_index = |i: usize, j: usize, k: usize| (k * ny + j) * nx + i;
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let mut values = [0f32; 8];
                let mut mask = 0usize;
                for (c, v) in values.iter_mut().enumerate() {
                    let o = corner_offset(c);
                    *v = value(i + o[0], j + o[1], k + o[2]);
                    if *v > iso {
                        mask |= 1 << c;
                    }
                }
                let tris = &table[mask];
                if tris.is_empty() {
                    continue;
                }
                for tri in tris {
                    let mut idx = [0u32; 3];
                    for (slot, &e) in idx.iter_mut().zip(tri) {
                        let (a, b) = EDGES[e as usize];
                        let oa = corner_offset(a);
                        let axis = (0..3).find(|&d| corner_offset(b)[d] != oa[d]).unwrap_or(0);
                        let key = point_index(i + oa[0], j + oa[1], k + oa[2]) * 3 + axis;
                        *slot = *vertex_of.entry(key).or_insert_with(|| {
                            let (va, vb) = (values[a], values[b]);
                            let t = if (vb - va).abs() > 0.0 && (va - vb).is_finite() {
                                ((iso - va) / (vb - va)).clamp(0.0, 1.0)
                            } else {
                                0.5
                            };
                            let mut g = [(i + oa[0]) as f64, (j + oa[1]) as f64, (k + oa[2]) as f64];
                            g[axis] += t as f64;
                            let p = origin + glam::DVec3::from(g) * spacing;
                            mesh.vertices.push(p.as_vec3().to_array());
                            (mesh.vertices.len() - 1) as u32
                        });
                    }
                    mesh.triangles.push(idx);
                }
                // Doubling containers may take twice what they hold while they grow.
                let held = (mesh.vertices.len() as u64 * VERTEX_BYTES)
                    .saturating_add(mesh.triangles.len() as u64 * TRIANGLE_BYTES)
                    .saturating_mul(2);
                if held > max_bytes {
                    return None;
                }
            }
        }
    }
    Some(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::Aabb;
    use glam::DVec3;

    #[test]
    fn every_case_gives_closed_loops() {
        // Building the table asserts that every contour closes; each case has at most five
        // triangles in the classic table, fans may give more on the ambiguous cases.
        for (mask, tris) in table().iter().enumerate() {
            assert_eq!(tris.is_empty(), mask == 0 || mask == 255, "case {mask:#010b}");
            assert!(tris.len() <= 12, "case {mask:#010b}: {} triangles", tris.len());
        }
        // One corner inside: one triangle cutting it off.
        assert_eq!(table()[1].len(), 1);
    }

    #[test]
    fn an_empty_surface_has_zero_area_and_volume_not_negative_zero() {
        let vol = Volume::from_fn([4, 4, 4], Aabb::cube(DVec3::ZERO, 1.0), |_| 0.25);
        let mesh = marching_cubes(&vol, 0.5);
        assert!(mesh.triangles.is_empty());
        for v in [mesh.area(), mesh.enclosed_volume()] {
            assert!(v == 0.0 && v.is_sign_positive(), "{v}");
        }
    }

    #[test]
    fn ball_is_watertight_with_the_right_volume() {
        let r = 0.7;
        let aabb = Aabb::cube(DVec3::new(1.0, -2.0, 0.5), 2.0);
        let c = aabb.centre();
        // A smooth radial profile, 1 at the centre, crossing 0.5 at radius r.
        let vol = Volume::from_fn([32, 32, 32], aabb, |p| (1.0 - 0.5 * ((p - c).length() / r).powi(2)) as f32);
        let mesh = marching_cubes(&vol, 0.5);
        assert!(mesh.triangles.len() > 1000, "{} triangles", mesh.triangles.len());
        let bad = mesh.defective_edges();
        assert!(bad.is_empty(), "{} open or misoriented edges, e.g. {:?}", bad.len(), &bad[..bad.len().min(5)]);
        let exact = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        let v = mesh.enclosed_volume();
        assert!((v - exact).abs() < 0.02 * exact, "volume {v} vs {exact}");
        for p in &mesh.vertices {
            let d = (DVec3::from(p.map(f64::from)) - c).length();
            assert!((d - r).abs() < 0.02, "vertex at radius {d}");
        }
    }

    #[test]
    fn a_surface_leaving_the_box_encloses_the_part_inside_it() {
        // A ball centred on the plane of the outermost cell centres at x: half of it lies within
        // the hull of the centres. The open mesh's own sum depends on where the world's origin
        // is; the volume closed on the hull's faces is the half ball's, wherever the box lies.
        let r = 0.6;
        for shift in [DVec3::ZERO, DVec3::new(100.0, -40.0, 7.0)] {
            let aabb = Aabb::new(DVec3::new(-0.5, -1.0, -1.0) + shift, DVec3::new(1.5, 1.0, 1.0) + shift);
            let dims = [40, 40, 40];
            let first_centre_x = aabb.min.x + 0.5 * aabb.size().x / 40.0;
            let c = DVec3::new(first_centre_x, aabb.centre().y, aabb.centre().z);
            let vol = Volume::from_fn(dims, aabb, |p| (1.0 - 0.5 * ((p - c).length() / r).powi(2)) as f32);
            let open = marching_cubes(&vol, 0.5);
            assert!(!open.is_watertight(), "the surface leaves the hull");
            let half = 2.0 / 3.0 * std::f64::consts::PI * r * r * r;
            let v = enclosed_volume_within(&vol, 0.5, u64::MAX).expect("fits");
            assert!((v - half).abs() < 0.02 * half, "shift {shift}: volume {v} against the half ball's {half}");
            if shift != DVec3::ZERO {
                let sum = open.enclosed_volume();
                assert!((sum - half).abs() > 0.5 * half, "the open mesh's own sum ({sum}) is no volume");
            }
        }
        // Closed inside the hull, it is the mesh's own volume.
        let aabb = Aabb::cube(DVec3::new(3.0, 0.0, 0.0), 2.0);
        let c = aabb.centre();
        let vol = Volume::from_fn([24, 24, 24], aabb, |p| (1.0 - 0.5 * ((p - c).length() / 0.6).powi(2)) as f32);
        let closed = marching_cubes(&vol, 0.5);
        let v = enclosed_volume_within(&vol, 0.5, u64::MAX).expect("fits");
        assert!((v - closed.enclosed_volume()).abs() < 1e-9 * v, "{v} against {}", closed.enclosed_volume());
        // A field above the level everywhere fills the whole hull.
        let full = Volume::from_fn([5, 4, 3], aabb, |_| 1.0);
        let hull = aabb.size() * (DVec3::new(4.0, 3.0, 2.0) / DVec3::new(5.0, 4.0, 3.0));
        let v = enclosed_volume_within(&full, 0.5, u64::MAX).expect("fits");
        assert!((v - hull.x * hull.y * hull.z).abs() < 1e-5 * v, "{v}");
    }

    #[test]
    fn ambiguous_faces_stay_closed() {
        // Random values give every case, ambiguous faces included: the mesh must still have no
        // cracks in the interior. Values are kept above iso on the boundary shell so the
        // surface cannot leave the grid.
        let aabb = Aabb::cube(DVec3::ZERO, 1.0);
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let data = (0..12 * 12 * 12)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        let mut vol = Volume::from_vec([12, 12, 12], aabb, data);
        let [nx, ny, nz] = vol.dims;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if i == 0 || j == 0 || k == 0 || i == nx - 1 || j == ny - 1 || k == nz - 1 {
                        let idx = vol.index(i, j, k);
                        vol.data[idx] = 0.0;
                    }
                }
            }
        }
        let mesh = marching_cubes(&vol, 0.5);
        assert!(!mesh.triangles.is_empty());
        assert!(mesh.is_watertight(), "{} defective edges", mesh.defective_edges().len());
    }
}
