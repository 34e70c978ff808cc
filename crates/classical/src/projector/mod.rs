//! Matrix-free projectors: the system matrix `A` of Eq. 2.20 (`p = A g`), applied per view and
//! never stored.
//!
//! # Conventions
//! - The unknown `g` is a [`Grid`]: `dims = [nx, ny, nz]` cell-centred voxels filling an
//!   axis-aligned box, x fastest (index `(k * ny + j) * nx + i`), exactly the layout of
//!   [`fluidnerf_core::Volume`]. Values are the emission density E (intensity per unit length).
//! - A view's data `p` is its image, row-major (`row * width + col`), pixel centres at integer
//!   coordinates (OpenCV). Distortion and any pose are handled through [`Camera`].
//! - Scale: both projectors model the scene's imaging law `pixel = intensity_scale × ∫ E ds`
//!   (what [`fluidnerf_core::render_image`] computes), so `A g` of a smooth volume matches a
//!   rendering of that volume to a few percent (tested), and solvers return E in the units of
//!   the ground truth.
//! - Every projector implements the forward map and its exact adjoint with the same f32
//!   weights, so `⟨A x, y⟩ = ⟨x, Aᵀ y⟩` to rounding (tested with distortion).
//!
//! Three projectors:
//! - [`FootprintProjector`], voxel-driven separable footprint (after Long, Fessler & Balter's
//!   SF projector): each voxel is spread over the pixels its cube images onto, with separable
//!   trapezoid weights integrated over each pixel. One evaluation per voxel and view, so its
//!   cost follows voxels × views at any voxel size.
//! - [`SplatProjector`], voxel-driven (the dissertation's, §6.4.1): each voxel's projected
//!   centre is spread bilinearly over a 2 × 2 pixel block; voxels imaging larger than 1.5 px are
//!   split into `s³` sub-voxels, so its cost grows as `s³`.
//! - [`RayProjector`], ray-driven: the trilinear line integral along each pixel's ray; its
//!   basis (trilinear) is the renderer's, so it matches [`fluidnerf_core::render_image`] of a
//!   voxel volume best, at a cost of pixels × samples per ray.
//!
//! # Choosing ([`ProjectorKind::Auto`], the default)
//! The footprint projector whenever it can hold the voxels' footprints: when the widest
//! footprint over all views (measured on a 9³ lattice through the box,
//! [`FootprintProjector::largest_footprint_px`]) is at most [`AUTO_FOOTPRINT_MAX_PX`] pixels,
//! that is for any voxel imaging at up to about 40 px; otherwise the ray projector. Measured
//! (`benches/projection.rs`): where the splat subdivides (voxels over 1.5 px) the footprint is
//! several times faster than it (3.4× on an ASART iteration at 64³ with 15 views of 256² px)
//! and closer to the renderer (1.0–1.2 % against 2.5–3.7 % relative L2 on the test blobs); where
//! the splat does not subdivide (voxels under 1.5 px) the splat is cheaper per voxel and view
//! (about 1.5×) but blurs by a pixel and leaves gaps once voxels grow, so the rule does not
//! pick it. The splat stays available by name (`kind: "splat"`), as the dissertation's scheme.

mod camera32;
mod footprint;
mod ray;
mod splat;

use fluidnerf_core::{Aabb, Camera, Volume};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

pub use fluidnerf_core::Isa;
pub use footprint::{FootprintProjector, AUTO_FOOTPRINT_MAX_PX, MAX_FOOTPRINT_SIDE};
pub use ray::RayProjector;
pub use splat::SplatProjector;

/// The voxel grid of the unknown: dims and box, the layout of [`Volume`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// `[nx, ny, nz]`.
    pub dims: [usize; 3],
    pub aabb: Aabb,
}

impl Grid {
    /// A grid over `aabb`; panics if a dimension is zero.
    pub fn new(dims: [usize; 3], aabb: Aabb) -> Self {
        assert!(dims.iter().all(|&n| n > 0), "Grid::new: dims {dims:?} must be positive");
        Grid { dims, aabb }
    }

    /// `longest` voxels along the box's longest side, cubic cells ([`Volume::dims_for`]).
    pub fn with_resolution(aabb: Aabb, longest: usize) -> Self {
        Grid::new(Volume::dims_for(&aabb, longest), aabb)
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Cell size along each axis.
    pub fn spacing(&self) -> DVec3 {
        self.aabb.size() / DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64)
    }

    /// Volume of one cell.
    pub fn voxel_volume(&self) -> f64 {
        let s = self.spacing();
        s.x * s.y * s.z
    }

    /// Wraps voxel values (length [`Grid::len`]) as a [`Volume`].
    pub fn volume(&self, data: Vec<f32>) -> Volume {
        Volume::from_vec(self.dims, self.aabb, data)
    }
}

/// Which projector to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ProjectorKind {
    /// Chosen from the voxel's image size (the rule in the module docs;
    /// [`crate::ProjectorConfig::resolve`]).
    #[default]
    Auto,
    /// Voxel-driven separable footprint.
    Footprint,
    /// Voxel-driven bilinear splat (the dissertation's), with sub-voxels for coarse grids.
    Splat,
    /// Ray-driven trilinear line integral.
    Ray,
}

/// One view's rows of `A` in compressed sparse row form: row `i` (pixel `row * width + col`)
/// holds `cols[ptr[i]..ptr[i + 1]]` (voxel indices, each at most once) with `vals` the weights.
#[derive(Clone, Debug, Default)]
pub struct SparseRows {
    pub ptr: Vec<u64>,
    pub cols: Vec<u32>,
    pub vals: Vec<f32>,
}

impl SparseRows {
    /// Number of rows (pixels).
    pub fn n_rows(&self) -> usize {
        self.ptr.len().saturating_sub(1)
    }

    /// The entries of row `i`.
    pub fn row(&self, i: usize) -> (&[u32], &[f32]) {
        let (a, b) = (self.ptr[i] as usize, self.ptr[i + 1] as usize);
        (&self.cols[a..b], &self.vals[a..b])
    }

    /// The rows with only the entries of voxels in `keep` (entries in their order).
    pub fn restricted(&self, keep: &[bool]) -> SparseRows {
        let mut out = SparseRows { ptr: Vec::with_capacity(self.ptr.len()), cols: Vec::new(), vals: Vec::new() };
        out.ptr.push(0);
        for i in 0..self.n_rows() {
            let (c, w) = self.row(i);
            for (&j, &wij) in c.iter().zip(w) {
                if keep[j as usize] {
                    out.cols.push(j);
                    out.vals.push(wij);
                }
            }
            out.ptr.push(out.cols.len() as u64);
        }
        out.cols.shrink_to_fit();
        out.vals.shrink_to_fit();
        out
    }

    /// Largest weight of each row (0 for empty rows): `A_{i,max}` of Eq. 2.24–2.28.
    pub fn row_max(&self) -> Vec<f32> {
        (0..self.n_rows()).map(|i| self.row(i).1.iter().fold(0f32, |m, &v| m.max(v))).collect()
    }

    /// Sums repeated voxels within each row (and sorts each row by voxel index).
    pub fn merge_duplicates(&mut self) {
        let mut ptr = Vec::with_capacity(self.ptr.len());
        ptr.push(0u64);
        let mut write = 0usize;
        let mut pairs: Vec<(u32, f32)> = Vec::new();
        for i in 0..self.n_rows() {
            let (a, b) = (self.ptr[i] as usize, self.ptr[i + 1] as usize);
            pairs.clear();
            pairs.extend(self.cols[a..b].iter().copied().zip(self.vals[a..b].iter().copied()));
            pairs.sort_unstable_by_key(|p| p.0);
            let start = write;
            for &(j, w) in &pairs {
                if write > start && self.cols[write - 1] == j {
                    self.vals[write - 1] += w;
                } else {
                    self.cols[write] = j;
                    self.vals[write] = w;
                    write += 1;
                }
            }
            ptr.push(write as u64);
        }
        self.cols.truncate(write);
        self.vals.truncate(write);
        self.ptr = ptr;
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.ptr.len() * 8 + self.cols.len() * 4 + self.vals.len() * 4
    }
}

/// A linear map from a voxel grid to every view's image, applied one view at a time.
///
/// Shapes: `x`, `out` of voxel maps have [`Grid::len`] elements; images of view `v` have
/// `width × height` of `cameras()[v]`.
pub trait Projector: Sync {
    /// The grid of the unknown.
    fn grid(&self) -> &Grid;

    /// The views' cameras, in view order.
    fn cameras(&self) -> &[Camera];

    fn n_views(&self) -> usize {
        self.cameras().len()
    }

    /// Pixels of view `view`.
    fn view_len(&self, view: usize) -> usize {
        let c = &self.cameras()[view];
        c.width() * c.height()
    }

    /// `out = A_v x` (overwrites `out`).
    fn forward(&self, view: usize, x: &[f32], out: &mut [f32]);

    /// `outs[k] = A_{views[k]} x` for one volume and several views, the images of
    /// [`Projector::forward`] for each view in turn, bit for bit. A projector may share work
    /// between the views (the footprint projector finds the volume's empty chunks once); the
    /// default calls `forward` view by view.
    fn forward_views(&self, views: &[usize], x: &[f32], outs: &mut [&mut [f32]]) {
        assert_eq!(views.len(), outs.len(), "one image per view");
        for (&v, out) in views.iter().zip(outs.iter_mut()) {
            self.forward(v, x, out);
        }
    }

    /// `out += A_vᵀ y`, and, if given, `col_sums += A_vᵀ 1` (the column sums `Σ_i w_ij` of
    /// the view) in the same pass.
    fn back_add(&self, view: usize, y: &[f32], out: &mut [f32], col_sums: Option<&mut [f32]>);

    /// `out += Σ_k A_{views[k]}ᵀ ys[k]` (and the column sums with it), the views added to each
    /// voxel in the order given, so the result is [`Projector::back_add`]'s for each view in
    /// turn, bit for bit. A projector may do it in one pass over the grid (the footprint
    /// projector does); the default calls `back_add` view by view.
    fn back_add_views(&self, views: &[usize], ys: &[&[f32]], out: &mut [f32], mut col_sums: Option<&mut [f32]>) {
        assert_eq!(views.len(), ys.len(), "one image per view");
        for (&v, y) in views.iter().zip(ys) {
            self.back_add(v, y, out, col_sums.as_deref_mut());
        }
    }

    /// One view's step of the row- and column-normalised methods (SART, ASART): with `b =
    /// A_vᵀ y` and `c = A_vᵀ 1` (the view's column sums), calls `update(at, xs, bs, cs)` on
    /// stretches of the grid that together cover it once, `xs` being `x[at..at + xs.len()]`
    /// and `bs`, `cs` the same voxels of `b` and `c`; stretches may run in parallel. `scratch`
    /// holds two buffers of the grid's length, which hold `b` and `c` afterwards. The values
    /// are [`Projector::back_add`]'s into zeroed buffers, bit for bit. The default does exactly
    /// that and then updates; a projector may compute each stretch and update it while it is in
    /// cache (the footprint projector does, slab by slab).
    fn back_update(&self, view: usize, y: &[f32], x: &mut [f32], scratch: (&mut [f32], &mut [f32]), update: &Update) {
        let (b, c) = scratch;
        assert!(b.len() == x.len() && c.len() == x.len(), "back_update: scratch of the wrong length");
        b.par_iter_mut().for_each(|v| *v = 0.0);
        c.par_iter_mut().for_each(|v| *v = 0.0);
        self.back_add(view, y, b, Some(c));
        update_in_stretches(x, b, c, update);
    }

    /// The rows of `A_v`, for the row-action methods (ART, MART). Holds the view's part of the
    /// matrix, so it costs memory ([`Projector::rows_bytes_estimate`]) while alive.
    fn rows(&self, view: usize) -> SparseRows;

    /// Rough size of [`Projector::rows`] for one view, in bytes.
    fn rows_bytes_estimate(&self, view: usize) -> usize;

    /// Extra memory the projector itself holds (cached rays and such), in bytes.
    fn bytes(&self) -> usize;

    /// Working memory of one `forward` or `back_add` call, in bytes.
    fn scratch_bytes(&self, view: usize) -> usize;
}

/// The update of [`Projector::back_update`]: `(at, x, b, c)` for a stretch of voxels starting
/// at `at`.
pub type Update<'a> = dyn Fn(usize, &mut [f32], &[f32], &[f32]) + Sync + 'a;

/// Runs `update` of [`Projector::back_update`] over `x`, `b` and `c` (one length) in
/// stretches, in parallel.
pub fn update_in_stretches(x: &mut [f32], b: &[f32], c: &[f32], update: &Update) {
    const STRETCH: usize = 1 << 14;
    x.par_chunks_mut(STRETCH)
        .zip(b.par_chunks(STRETCH).zip(c.par_chunks(STRETCH)))
        .enumerate()
        .for_each(|(k, (xs, (bs, cs)))| update(k * STRETCH, xs, bs, cs));
}

/// Splits `0..n` into at most `parts` contiguous ranges of near-equal length.
pub(crate) fn bands(n: usize, parts: usize) -> Vec<std::ops::Range<usize>> {
    let parts = parts.clamp(1, n.max(1));
    (0..parts).map(|p| (p * n / parts)..((p + 1) * n / parts)).filter(|r| !r.is_empty()).collect()
}

/// Number of independent accumulators used by the scatter passes: a few per thread so that
/// rayon can balance uneven bands.
pub(crate) fn scatter_parts() -> usize {
    rayon::current_num_threads().max(1)
}

/// Checks the shapes of a projection call (programmer contract).
pub(crate) fn check_shapes<P: Projector + ?Sized>(p: &P, view: usize, x_len: usize, img_len: usize) {
    assert!(view < p.n_views(), "view {view} out of range ({} views)", p.n_views());
    assert_eq!(x_len, p.grid().len(), "voxel buffer has the wrong length");
    assert_eq!(img_len, p.view_len(view), "image buffer of view {view} has the wrong length");
}

#[cfg(test)]
mod tests {
    use super::SparseRows;

    /// Restricting rows to a support keeps the supported entries of each row in their order,
    /// and empties rows with none.
    #[test]
    fn restricted_rows_keep_the_supported_entries_in_order() {
        let rows = SparseRows {
            ptr: vec![0, 3, 4, 6],
            cols: vec![4, 0, 2, 1, 3, 2],
            vals: vec![0.5, 1.0, 2.0, 3.0, 4.0, 5.0],
        };
        let keep = [false, false, true, false, true];
        let r = rows.restricted(&keep);
        assert_eq!(r.n_rows(), 3);
        assert_eq!(r.row(0), (&[4u32, 2][..], &[0.5f32, 2.0][..]));
        assert_eq!(r.row(1), (&[][..], &[][..]));
        assert_eq!(r.row(2), (&[2u32][..], &[5.0f32][..]));
        assert_eq!(r.bytes(), 4 * 8 + 3 * 4 + 3 * 4);
    }
}
