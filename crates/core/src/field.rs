//! The scalar-field abstraction shared by phantoms, voxel grids and neural fields.

use glam::{DVec3, Vec3};

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
    pub fn on_vertices(field: &dyn ScalarField, dims: [usize; 3], aabb: Aabb, time: f64) -> Self {
        let n = glam::DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let half = 0.5 * aabb.size() / n;
        let grid = Aabb::new(aabb.min - half, aabb.max + half);
        let volume = Volume::from_field(dims.map(|d| d + 1), grid, field, time);
        let support = field.support().map(|s| (s.aabb, s.dims, s.cells.to_vec()));
        Baked { volume, support }
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

impl Support<'_> {
    /// Appends to `out` the parameter intervals `[a, b] ⊆ [s0, s1]` of `ray` that cross
    /// occupied cells, sorted and merged (a 3D DDA through the grid). Intervals are exact up to
    /// rounding; callers that must not miss a sample near a cell face widen them.
    pub fn occupied_intervals(&self, ray: &Ray, s0: f64, s1: f64, out: &mut Vec<(f64, f64)>) {
        let Some((b0, b1)) = self.aabb.intersect(ray) else { return };
        let (t_start, t_end) = (s0.max(b0), s1.min(b1));
        if t_start >= t_end || self.cells.len() != self.dims.iter().product::<usize>() {
            return;
        }
        let size = self.aabb.size();
        let dims = DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64);
        let h = size / dims;
        // The cell holding the middle of the first step, and per axis the parameter of the next
        // face crossing and the parameter between crossings.
        let p = (ray.at(t_start) - self.aabb.min) / h;
        let mut cell = [0i64; 3];
        let mut next = [f64::INFINITY; 3];
        let mut delta = [f64::INFINITY; 3];
        let mut step = [0i64; 3];
        for a in 0..3 {
            cell[a] = (p[a].floor() as i64).clamp(0, self.dims[a] as i64 - 1);
            let d = ray.dir[a];
            if d > 0.0 {
                step[a] = 1;
                delta[a] = h[a] / d;
                next[a] = t_start + ((cell[a] + 1) as f64 - p[a]) * h[a] / d;
            } else if d < 0.0 {
                step[a] = -1;
                delta[a] = -h[a] / d;
                next[a] = t_start + (cell[a] as f64 - p[a]) * h[a] / d;
            }
        }
        let mut t = t_start;
        let mut open: Option<f64> = None;
        let [nx, ny, _] = self.dims;
        loop {
            let a = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            let t_exit = next[a].min(t_end);
            let idx = (cell[2] as usize * ny + cell[1] as usize) * nx + cell[0] as usize;
            if self.cells[idx] {
                open.get_or_insert(t);
            } else if let Some(a0) = open.take() {
                out.push((a0, t));
            }
            if t_exit >= t_end {
                break;
            }
            t = t_exit;
            cell[a] += step[a];
            if cell[a] < 0 || cell[a] >= self.dims[a] as i64 {
                break;
            }
            next[a] += delta[a];
        }
        if let Some(a0) = open {
            out.push((a0, t_end));
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
