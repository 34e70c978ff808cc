//! The scalar-field abstraction shared by phantoms, voxel grids and neural fields.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::{Aabb, Ray, Volume};

/// A scalar field E(x, t) in world coordinates, evaluated in batches so that expensive
/// fields (neural networks) can amortise their cost. Implementations must be thread-safe:
/// renderers call `eval` from several threads at once.
pub trait ScalarField: Sync {
    /// Writes E(`points[i]`, `time`) into `out[i]`. `points` and `out` have the same length.
    /// Points outside the field's support evaluate to zero.
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]);

    /// Where the field may be non-zero, if it knows: renderers then generate no samples in
    /// the empty cells (the field must evaluate to zero there). Default: unknown.
    fn support(&self) -> Option<Support<'_>> {
        None
    }

    /// The field as a voxel grid read trilinearly, if it is one: renderers then read it in
    /// place instead of calling [`ScalarField::eval`] on batches. Default: not a grid.
    fn as_volume(&self) -> Option<&Volume> {
        None
    }

    /// E at `points` as the field's own representation holds it, without the mask of its
    /// [`ScalarField::support`]: outside the occupied cells, where [`ScalarField::eval`] gives
    /// zero, the values continue the field. A grid read trilinearly inside the support
    /// ([`Baked`]) needs them at the vertices on and just past the support's faces, or the
    /// cells inside are pulled towards zero. Default: [`ScalarField::eval`] (a field without a
    /// support, or one whose zeros are its own).
    fn eval_unmasked(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.eval(points, time, out);
    }

    /// Grid dimensions that resolve the field's finest detail (a trained grid's finest level),
    /// if it has one: the grid to bake it on ([`Baked`]). Default: none.
    fn detail_dims(&self) -> Option<[usize; 3]> {
        None
    }
}

/// A field sampled once at the cell centres of a grid and read back trilinearly, keeping the
/// source's support: the fast way to render many views of an expensive field (a trained
/// network), at the cost of the interpolation error between the samples.
#[derive(Clone, Debug)]
pub struct Baked {
    pub volume: Volume,
    support: Option<(Aabb, [usize; 3], Vec<bool>)>,
}

impl Baked {
    /// Samples `field` at `time` on the vertices of a partition of `aabb` into `dims` cells:
    /// the grid read back has `dims + 1` cells per axis, centred on those vertices (its box
    /// reaches half a cell beyond `aabb`), so a field that is trilinear on the partition's
    /// cells — a trained grid's finest level — is read back exactly.
    ///
    /// A field with a support is sampled without its mask ([`ScalarField::eval_unmasked`]) at
    /// every vertex a read inside an occupied cell uses, and nowhere else: a read near a face
    /// of the support then interpolates the field, not a step down to the zeros outside it.
    /// (The renderer reads a baked field only inside the occupied cells.)
    pub fn on_vertices(field: &dyn ScalarField, dims: [usize; 3], aabb: Aabb, time: f64) -> Self {
        let n = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let half = 0.5 * aabb.size() / n;
        let grid = Aabb::new(aabb.min - half, aabb.max + half);
        let vdims = dims.map(|d| d + 1);
        let support = field.support();
        let volume = match support {
            // A support whose cells do not fill its grid says nothing (as for the renderer).
            Some(sup) if sup.cells.len() == sup.dims.iter().product::<usize>() => {
                let mut v = Volume::zeros(vdims, grid);
                let sp = v.spacing();
                // Per axis, the support cells each vertex's two neighbouring grid cells overlap
                // (with positive length): the vertex is read from inside an occupied cell only
                // if one of them is occupied.
                let reach = |a: usize| -> Vec<(usize, usize)> {
                    let hs = sup.aabb.size()[a] / sup.dims[a] as f64;
                    let r = sp[a] / hs;
                    (0..vdims[a])
                        .map(|i| {
                            let c = (aabb.min[a] + i as f64 * sp[a] - sup.aabb.min[a]) / hs;
                            let lo = (c - r + 1e-6).floor().max(0.0);
                            let hi = ((c + r - 1e-6).ceil() - 1.0).min(sup.dims[a] as f64 - 1.0);
                            if lo > hi {
                                (1, 0)
                            } else {
                                (lo as usize, hi as usize)
                            }
                        })
                        .collect()
                };
                let rows = SupportRows::new(sup, [reach(0), reach(1), reach(2)]);
                let [nx, ny, _] = vdims;
                v.data.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
                    let (mut pts, mut at, mut column) = (Vec::new(), Vec::new(), Vec::new());
                    for j in 0..ny {
                        rows.row(j, k, &mut column, |i| {
                            // The cell centre of `Volume::from_field`, as a field without a
                            // support is sampled.
                            let p = grid.min + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * sp;
                            pts.push(p.as_vec3());
                            at.push(j * nx + i);
                        });
                    }
                    let mut vals = vec![0f32; pts.len()];
                    field.eval_unmasked(&pts, time, &mut vals);
                    for (&i, &x) in at.iter().zip(&vals) {
                        slab[i] = x;
                    }
                });
                v
            }
            _ => Volume::from_field(vdims, grid, field, time),
        };
        Baked { volume, support: support.map(|s| (s.aabb, s.dims, s.cells.to_vec())) }
    }
}

impl ScalarField for Baked {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.volume.eval(points, time, out);
    }

    fn support(&self) -> Option<Support<'_>> {
        self.support.as_ref().map(|(aabb, dims, cells)| Support { aabb: *aabb, dims: *dims, cells })
    }

    fn as_volume(&self) -> Option<&Volume> {
        Some(&self.volume)
    }
}

/// A boolean grid of cells over a box outside whose occupied cells a field is zero (a trained
/// field's empty-space hull). Cell `(i, j, k)` covers `[min + i·h, min + (i+1)·h)` per axis,
/// x fastest in `cells`.
#[derive(Clone, Copy, Debug)]
pub struct Support<'a> {
    pub aabb: Aabb,
    pub dims: [usize; 3],
    pub cells: &'a [bool],
}

/// A [`Support`] prepared for walking many rays: the box of its occupied cells found once,
/// each ray clipped to it before the walk through the grid (a ray that misses it crosses no
/// occupied cell), and the grid summarised in blocks of [`WALK_BLOCK`]³ cells, each empty, full
/// or mixed, so that a walk crosses an empty or a full block in one step and walks cell by cell
/// only through the mixed ones (a hull's surface).
#[derive(Clone, Debug)]
pub struct SupportWalk<'a> {
    pub support: Support<'a>,
    occupied: Option<Aabb>,
    /// Per block, x fastest: [`BLOCK_EMPTY`], [`BLOCK_FULL`] or [`BLOCK_MIXED`].
    blocks: Vec<u8>,
    block_dims: [usize; 3],
}

/// Cells per side of the blocks a [`SupportWalk`] steps over.
pub const WALK_BLOCK: usize = 4;
const BLOCK_EMPTY: u8 = 0;
const BLOCK_FULL: u8 = 1;
const BLOCK_MIXED: u8 = 2;

impl<'a> Support<'a> {
    /// This support with its occupied cells' box, widened by a hair so that rounding never
    /// clips a walk through its faces, and its blocks.
    pub fn walk(self) -> SupportWalk<'a> {
        let pad = DVec3::splat(1e-9 * self.aabb.size().max_element());
        let occupied = self.occupied_box().map(|b| Aabb::new(b.min - pad, b.max + pad));
        let [nx, ny, nz] = self.dims;
        let block_dims = self.dims.map(|n| n.div_ceil(WALK_BLOCK));
        let mut blocks = vec![BLOCK_EMPTY; block_dims.iter().product()];
        if self.cells.len() == nx * ny * nz {
            // Counts of occupied cells per block, then each block's state from its count and size.
            let mut counts = vec![0u32; blocks.len()];
            for k in 0..nz {
                for j in 0..ny {
                    let row = &self.cells[(k * ny + j) * nx..][..nx];
                    let base = ((k / WALK_BLOCK) * block_dims[1] + j / WALK_BLOCK) * block_dims[0];
                    for (i, &c) in row.iter().enumerate() {
                        counts[base + i / WALK_BLOCK] += u32::from(c);
                    }
                }
            }
            let side = |b: usize, n: usize| (n - b * WALK_BLOCK).min(WALK_BLOCK);
            for (b, (state, &count)) in blocks.iter_mut().zip(&counts).enumerate() {
                let (bi, bj, bk) =
                    (b % block_dims[0], (b / block_dims[0]) % block_dims[1], b / (block_dims[0] * block_dims[1]));
                let size = side(bi, nx) * side(bj, ny) * side(bk, nz);
                *state = match count as usize {
                    0 => BLOCK_EMPTY,
                    c if c == size => BLOCK_FULL,
                    _ => BLOCK_MIXED,
                };
            }
        }
        SupportWalk { support: self, occupied, blocks, block_dims }
    }
}

/// The parameters of a grid walk (a 3D DDA) along `ray` from `t`, in a grid of cells of size
/// `h` from `origin`, its cell indices clamped to `lo..hi` per axis: the cell holding
/// `ray.at(t)`, per axis the parameter of the next face crossing, the parameter between
/// crossings and the step.
fn dda_start(ray: &Ray, t: f64, origin: DVec3, h: DVec3, lo: [i64; 3], hi: [i64; 3]) -> DdaState {
    let p = (ray.at(t) - origin) / h;
    let mut s = DdaState { cell: [0; 3], next: [f64::INFINITY; 3], delta: [f64::INFINITY; 3], step: [0; 3] };
    for a in 0..3 {
        // `lo ≥ 0`: after the clamp, truncation gives what the floor gives (both put every
        // `p < lo` at `lo`), without the library call `floor` is on the x86-64 baseline.
        s.cell[a] = (p[a] as i64).clamp(lo[a], hi[a] - 1);
        let d = ray.dir[a];
        if d > 0.0 {
            s.step[a] = 1;
            s.delta[a] = h[a] / d;
            s.next[a] = t + ((s.cell[a] + 1) as f64 - p[a]) * h[a] / d;
        } else if d < 0.0 {
            s.step[a] = -1;
            s.delta[a] = -h[a] / d;
            s.next[a] = t + (s.cell[a] as f64 - p[a]) * h[a] / d;
        }
    }
    s
}

/// The state of a grid walk ([`dda_start`]).
struct DdaState {
    cell: [i64; 3],
    next: [f64; 3],
    delta: [f64; 3],
    step: [i64; 3],
}

impl DdaState {
    /// The axis whose face the walk crosses next.
    #[inline]
    fn axis(&self) -> usize {
        if self.next[0] <= self.next[1] && self.next[0] <= self.next[2] {
            0
        } else if self.next[1] <= self.next[2] {
            1
        } else {
            2
        }
    }
}

/// Which points of a grid a [`Support`] may hold non-zero values at: per axis, the support
/// cells each grid index reaches, and a row at a time the indices along x whose reach holds an
/// occupied cell. Sampling a field on a grid then evaluates it only there; a flow's hull is
/// a small part of its box.
pub(crate) struct SupportRows<'a> {
    support: Support<'a>,
    /// Per axis and grid index, the first and last support cell it reaches (`(1, 0)`: none).
    reach: [Vec<(usize, usize)>; 3],
    /// Per support cell along x, the first and last grid index that reaches it (`(1, 0)`:
    /// none). The reaches move along the axis as the index grows, so these are intervals.
    reached_by: Vec<(usize, usize)>,
}

impl<'a> SupportRows<'a> {
    /// From the reach of every grid index along each axis (cells of the support's grid), which
    /// must move along the axis as the index grows (both ends non-decreasing).
    pub(crate) fn new(support: Support<'a>, reach: [Vec<(usize, usize)>; 3]) -> Self {
        let mut reached_by = vec![(1, 0); support.dims[0]];
        for (i, &(lo, hi)) in reach[0].iter().enumerate() {
            if lo <= hi {
                for r in &mut reached_by[lo..=hi] {
                    *r = if r.0 > r.1 { (i, i) } else { (r.0, i) };
                }
            }
        }
        SupportRows { support, reach, reached_by }
    }

    /// For a grid of `dims` cells over `aabb`, each sampled at `n³` points as
    /// [`Volume::from_field_averaged`] places them (`n = 1`: the cell centres): the support
    /// cells those points may fall in, widened by a thousandth of a support cell so that no
    /// point's rounding puts it in a cell left out, and clamped to the support's grid (a point
    /// outside its box evaluates to zero wherever it is counted). `None` when the support's
    /// cells do not fill its grid, which then says nothing.
    pub(crate) fn for_samples(support: Support<'a>, aabb: &Aabb, dims: [usize; 3], n: usize) -> Option<Self> {
        const SLACK: f64 = 1e-3;
        if support.cells.len() != support.dims.iter().product::<usize>() {
            return None;
        }
        let n = n.max(1) as f64;
        let reach = |a: usize| -> Vec<(usize, usize)> {
            let cells = support.dims[a] as f64;
            let hs = support.aabb.size()[a] / cells;
            let h = aabb.size()[a] / dims[a] as f64;
            (0..dims[a])
                .map(|i| {
                    let at = |q: f64| {
                        ((aabb.min[a] + (i as f64 + (q + 0.5) / n) * h - support.aabb.min[a]) / hs).clamp(0.0, cells)
                    };
                    let lo = (at(0.0) - SLACK).floor().max(0.0);
                    let hi = (at(n - 1.0) + SLACK).floor().min(cells - 1.0);
                    (lo as usize, hi as usize)
                })
                .collect()
        };
        Some(SupportRows::new(support, [reach(0), reach(1), reach(2)]))
    }

    /// Calls `hit(i)`, in order, for every grid index `i` along x of row `(j, k)` whose reach
    /// holds an occupied support cell. `column` is scratch space.
    pub(crate) fn row(&self, j: usize, k: usize, column: &mut Vec<bool>, mut hit: impl FnMut(usize)) {
        let sup = &self.support;
        let [sx, sy, _] = sup.dims;
        let ((y0, y1), (z0, z1)) = (self.reach[1][j], self.reach[2][k]);
        // The support's columns along x that the row reaches.
        column.clear();
        column.resize(sx, false);
        for ck in z0..=z1 {
            for cj in y0..=y1 {
                let row = &sup.cells[(ck * sy + cj) * sx..][..sx];
                for (c, &o) in column.iter_mut().zip(row) {
                    *c |= o;
                }
            }
        }
        // Each occupied column's grid indices, in order and once each.
        let mut next = 0;
        for (&o, &(first, last)) in column.iter().zip(&self.reached_by) {
            if o && first <= last {
                for i in first.max(next)..=last {
                    hit(i);
                }
                next = next.max(last + 1);
            }
        }
    }
}

impl SupportWalk<'_> {
    /// [`Support::occupied_intervals`] (the same intervals up to rounding), the walk limited to
    /// the occupied cells' box and made block by block: an empty block closes an open
    /// interval, a full one opens one, and only a mixed one is walked cell by cell.
    pub fn occupied_intervals(&self, ray: &Ray, s0: f64, s1: f64, out: &mut Vec<(f64, f64)>) {
        let Some((h0, h1)) = self.occupied.and_then(|b| b.intersect(ray)) else { return };
        let (a, b) = (h0.max(s0), h1.min(s1));
        if a >= b {
            return;
        }
        let sup = &self.support;
        let Some((b0, b1)) = sup.aabb.intersect(ray) else { return };
        let (t_start, t_end) = (a.max(b0), b.min(b1));
        if t_start >= t_end || sup.cells.len() != sup.dims.iter().product::<usize>() {
            return;
        }
        let dims = sup.dims.map(|n| n as i64);
        let h = sup.aabb.size() / DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let hb = h * WALK_BLOCK as f64;
        let bd = self.block_dims.map(|n| n as i64);
        let mut blk = dda_start(ray, t_start, sup.aabb.min, hb, [0; 3], bd);
        let mut t = t_start;
        let mut open: Option<f64> = None;
        loop {
            let a = blk.axis();
            let t_exit = blk.next[a].min(t_end);
            let b = ((blk.cell[2] * bd[1] + blk.cell[1]) * bd[0] + blk.cell[0]) as usize;
            match self.blocks[b] {
                BLOCK_EMPTY => {
                    if let Some(a0) = open.take() {
                        out.push((a0, t));
                    }
                }
                BLOCK_FULL => {
                    open.get_or_insert(t);
                }
                _ if t < t_exit => {
                    // Cell by cell through this block, from `t` to where the walk leaves it.
                    let lo = blk.cell.map(|c| c * WALK_BLOCK as i64);
                    let hi = [0, 1, 2].map(|k| (lo[k] + WALK_BLOCK as i64).min(dims[k]));
                    sup.walk_cells(ray, t, t_exit, lo, hi, &mut open, out);
                }
                _ => {}
            }
            if t_exit >= t_end {
                break;
            }
            t = t_exit;
            blk.cell[a] += blk.step[a];
            if blk.cell[a] < 0 || blk.cell[a] >= bd[a] {
                break;
            }
            blk.next[a] += blk.delta[a];
        }
        if let Some(a0) = open {
            out.push((a0, t_end));
        }
    }
}

impl Support<'_> {
    /// The box of the occupied cells (`None` when none is occupied, or the cells do not fill
    /// the grid): a ray that misses it crosses no occupied cell.
    pub fn occupied_box(&self) -> Option<Aabb> {
        let [nx, ny, nz] = self.dims;
        if self.cells.len() != nx * ny * nz {
            return None;
        }
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        // Row by row along x: the first and last occupied cell of each (a full row costs two
        // reads, an empty one a scan).
        for (r, row) in self.cells.chunks_exact(nx.max(1)).enumerate() {
            let Some(first) = row.iter().position(|&c| c) else { continue };
            let last = row.iter().rposition(|&c| c).unwrap_or(first);
            let (j, k) = (r % ny, r / ny);
            for (a, (l, h)) in [(first, last), (j, j), (k, k)].into_iter().enumerate() {
                lo[a] = lo[a].min(l);
                hi[a] = hi[a].max(h + 1);
            }
        }
        if lo[0] == usize::MAX {
            return None;
        }
        let h = self.aabb.size() / DVec3::new(nx as f64, ny as f64, nz as f64);
        let at = |i: [usize; 3]| self.aabb.min + DVec3::new(i[0] as f64, i[1] as f64, i[2] as f64) * h;
        Some(Aabb::new(at(lo), at(hi)))
    }

    /// Appends to `out` the parameter intervals `[a, b] ⊆ [s0, s1]` of `ray` that cross
    /// occupied cells, sorted and merged (a 3D DDA through the grid). Intervals are exact up to
    /// rounding; callers that must not miss a sample near a cell face widen them.
    pub fn occupied_intervals(&self, ray: &Ray, s0: f64, s1: f64, out: &mut Vec<(f64, f64)>) {
        let Some((b0, b1)) = self.aabb.intersect(ray) else { return };
        let (t_start, t_end) = (s0.max(b0), s1.min(b1));
        if t_start >= t_end || self.cells.len() != self.dims.iter().product::<usize>() {
            return;
        }
        let mut open: Option<f64> = None;
        self.walk_cells(ray, t_start, t_end, [0; 3], self.dims.map(|n| n as i64), &mut open, out);
        if let Some(a0) = open {
            out.push((a0, t_end));
        }
    }

    /// Walks `ray` cell by cell from `t` to `t_end` (a 3D DDA), within the cells `lo..hi` per
    /// axis: an occupied cell opens an interval at its entry (`open`, kept across calls), an
    /// empty one closes the open one into `out`. The walk ends at `t_end` or where it leaves
    /// those cells; an interval still open is left to the caller.
    #[allow(clippy::too_many_arguments)]
    fn walk_cells(
        &self,
        ray: &Ray,
        t: f64,
        t_end: f64,
        lo: [i64; 3],
        hi: [i64; 3],
        open: &mut Option<f64>,
        out: &mut Vec<(f64, f64)>,
    ) {
        let dims = DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64);
        let h = self.aabb.size() / dims;
        let [nx, ny, _] = self.dims;
        let mut c = dda_start(ray, t, self.aabb.min, h, lo, hi);
        let mut t = t;
        loop {
            let a = c.axis();
            let t_exit = c.next[a].min(t_end);
            let idx = (c.cell[2] as usize * ny + c.cell[1] as usize) * nx + c.cell[0] as usize;
            if self.cells[idx] {
                open.get_or_insert(t);
            } else if let Some(a0) = open.take() {
                out.push((a0, t));
            }
            if t_exit >= t_end {
                break;
            }
            t = t_exit;
            c.cell[a] += c.step[a];
            if c.cell[a] < lo[a] || c.cell[a] >= hi[a] {
                break;
            }
            c.next[a] += c.delta[a];
        }
    }
}

impl<F: Fn(Vec3, f64) -> f32 + Sync> ScalarField for F {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "ScalarField::eval: points and out differ in length");
        for (o, &p) in out.iter_mut().zip(points) {
            *o = self(p, time);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift64*), values in `[0, 1)`.
    struct Draw(u64);
    impl Draw {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// The block-by-block walk gives the cell-by-cell walk's intervals, up to rounding, on grids
    /// whose sides are and are not multiples of the block, with hulls that leave blocks empty,
    /// full and mixed, for rays from outside and inside the box, along the axes and oblique,
    /// clipped to parts of their chord.
    #[test]
    fn the_block_walk_gives_the_cell_walk_intervals() {
        let mut draw = Draw(0x9e37_79b9_7f4a_7c15);
        let aabb = Aabb::new(DVec3::new(-1.0, -2.0, -0.5), DVec3::new(3.0, 1.0, 2.5));
        let mut compared = 0;
        for dims in [[16, 16, 16], [13, 9, 22], [5, 4, 7], [1, 6, 3], [33, 17, 4]] {
            // Two balls and scattered single cells.
            let size = aabb.size();
            let centre = |i: usize, n: usize, lo: f64, s: f64| lo + (i as f64 + 0.5) / n as f64 * s;
            let mut cells = vec![false; dims.iter().product()];
            for k in 0..dims[2] {
                for j in 0..dims[1] {
                    for i in 0..dims[0] {
                        let p = DVec3::new(
                            centre(i, dims[0], aabb.min.x, size.x),
                            centre(j, dims[1], aabb.min.y, size.y),
                            centre(k, dims[2], aabb.min.z, size.z),
                        );
                        let balls = (p - DVec3::new(0.5, -0.5, 1.0)).length() < 1.2
                            || (p - DVec3::new(2.2, 0.4, 0.0)).length() < 0.6;
                        cells[(k * dims[1] + j) * dims[0] + i] = balls || draw.next() < 0.03;
                    }
                }
            }
            let support = Support { aabb, dims, cells: &cells };
            let walk = support.walk();
            for r in 0..400 {
                let inside = r % 4 == 0;
                let origin = if inside {
                    aabb.min + DVec3::new(draw.next(), draw.next(), draw.next()) * size
                } else {
                    aabb.centre()
                        + DVec3::new(draw.next() - 0.5, draw.next() - 0.5, draw.next() - 0.5).normalize() * 9.0
                };
                let mut dir = if inside {
                    DVec3::new(draw.next() - 0.5, draw.next() - 0.5, draw.next() - 0.5)
                } else {
                    aabb.centre() + DVec3::new(draw.next() - 0.5, draw.next() - 0.5, draw.next() - 0.5) * 3.0 - origin
                };
                // Some rays along an axis or in an axis plane.
                match r % 7 {
                    1 => dir = DVec3::new(dir.x, 0.0, 0.0),
                    2 => dir = DVec3::new(0.0, dir.y, dir.z),
                    _ => {}
                }
                if dir.length() == 0.0 {
                    continue;
                }
                let ray = Ray::new(origin, dir);
                let (s0, s1) =
                    if r % 3 == 0 { (0.0, f64::INFINITY) } else { (draw.next() * 8.0, 6.0 + draw.next() * 8.0) };
                let (mut want, mut got) = (Vec::new(), Vec::new());
                // The cell walk, clipped as the block walk clips.
                if let Some((h0, h1)) = walk.occupied.and_then(|b| b.intersect(&ray)) {
                    let (a, b) = (h0.max(s0), h1.min(s1));
                    if a < b {
                        support.occupied_intervals(&ray, a, b, &mut want);
                    }
                }
                walk.occupied_intervals(&ray, s0, s1, &mut got);
                assert_eq!(got.len(), want.len(), "{dims:?} ray {r}: {got:?} vs {want:?}");
                for (g, w) in got.iter().zip(&want) {
                    assert!(
                        (g.0 - w.0).abs() < 1e-9 && (g.1 - w.1).abs() < 1e-9,
                        "{dims:?} ray {r}: {got:?} vs {want:?}"
                    );
                }
                compared += want.len();
            }
        }
        assert!(compared > 500, "the rays crossed {compared} intervals");
    }
}
