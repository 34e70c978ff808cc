//! Dense, cell-centred voxel grids.

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::field::SupportRows;
use crate::{Aabb, ScalarField};

/// A dense f32 grid of `nx × ny × nz` cells filling `aabb`, x varying fastest
/// (`data[(k * ny + j) * nx + i]`). Values live at cell centres:
/// voxel `(i, j, k)` is centred at `aabb.min + (i + ½, j + ½, k + ½) * spacing`.
///
/// Sampling ([`Volume::sample`]) is trilinear between cell centres, clamped to the outermost
/// centres inside the box (so a constant grid is constant up to the box faces and line
/// integrals through it equal value × chord length) and zero outside the box.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// `[nx, ny, nz]`.
    pub dims: [usize; 3],
    pub aabb: Aabb,
    pub data: Vec<f32>,
}

impl Volume {
    /// A zero grid. Panics if a dimension is zero.
    pub fn zeros(dims: [usize; 3], aabb: Aabb) -> Self {
        assert!(dims.iter().all(|&n| n > 0), "Volume::zeros: dims {dims:?} must be positive");
        Volume { dims, aabb, data: vec![0.0; dims[0] * dims[1] * dims[2]] }
    }

    /// Wraps `data`; panics if its length does not match `dims`.
    pub fn from_vec(dims: [usize; 3], aabb: Aabb, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "Volume::from_vec: data does not match dims {dims:?}");
        Volume { dims, aabb, data }
    }

    /// Samples `f` at every voxel centre, in parallel over z-slices.
    pub fn from_fn(dims: [usize; 3], aabb: Aabb, f: impl Fn(DVec3) -> f32 + Sync) -> Self {
        let mut v = Volume::zeros(dims, aabb);
        let [nx, ny, _] = dims;
        let sp = v.spacing();
        v.data.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
            for j in 0..ny {
                for i in 0..nx {
                    let p = aabb.min + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * sp;
                    slab[j * nx + i] = f(p);
                }
            }
        });
        v
    }

    /// Samples any [`ScalarField`] at every voxel centre at time `time`, one batch per z-slice.
    /// A field with a [`ScalarField::support`] is evaluated only at the centres that may lie in
    /// its occupied cells; the others hold the zero it has there.
    pub fn from_field(dims: [usize; 3], aabb: Aabb, field: &dyn ScalarField, time: f64) -> Self {
        Volume::from_field_averaged(dims, aabb, field, time, 1)
    }

    /// Samples `field` at `time` as the mean over each cell of `n³` points on a regular
    /// sub-lattice (`(i + (a + ½)/n) · h` per axis): the cell average up to the sub-lattice's
    /// quadrature error, a box filter that keeps detail finer than a cell from aliasing into the
    /// grid. `n = 1` is [`Volume::from_field`]. As there, a field with a support is evaluated
    /// only in the cells whose points may lie in its occupied cells.
    pub fn from_field_averaged(dims: [usize; 3], aabb: Aabb, field: &dyn ScalarField, time: f64, n: usize) -> Self {
        Volume::from_field_averaged_with(dims, aabb, field, time, n, &|| {})
    }

    /// [`Volume::from_field_averaged`], calling `slab_done` (from any thread) as each of the
    /// grid's `dims[2]` z-slices is sampled: a progress bar's tick.
    pub fn from_field_averaged_with(
        dims: [usize; 3],
        aabb: Aabb,
        field: &dyn ScalarField,
        time: f64,
        n: usize,
        slab_done: &(dyn Fn() + Sync),
    ) -> Self {
        let n = n.max(1);
        let mut v = Volume::zeros(dims, aabb);
        let [nx, ny, _] = dims;
        let sp = v.spacing();
        let sub = n * n * n;
        let inv = 1.0 / sub as f32;
        let rows = field.support().and_then(|s| SupportRows::for_samples(s, &aabb, dims, n));
        // The sub-lattice's offsets within a cell, point `c` at `(c % n, (c / n) % n, c / n²)`.
        let offsets: Vec<DVec3> = (0..sub)
            .map(|c| {
                let q = |m: usize| (m as f64 + 0.5) / n as f64;
                DVec3::new(q(c % n), q((c / n) % n), q(c / (n * n)))
            })
            .collect();
        v.data.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
            let (mut pts, mut at, mut column) = (Vec::new(), Vec::new(), Vec::new());
            for j in 0..ny {
                let cell = |i: usize| {
                    for o in &offsets {
                        let index = DVec3::new(i as f64 + o.x, j as f64 + o.y, k as f64 + o.z);
                        pts.push((aabb.min + index * sp).as_vec3());
                    }
                    at.push(j * nx + i);
                };
                match &rows {
                    Some(rows) => rows.row(j, k, &mut column, cell),
                    None => (0..nx).for_each(cell),
                }
            }
            let mut vals = vec![0.0f32; pts.len()];
            field.eval(&pts, time, &mut vals);
            if sub == 1 {
                for (&i, &x) in at.iter().zip(&vals) {
                    slab[i] = x;
                }
            } else {
                for (&i, cell) in at.iter().zip(vals.chunks_exact(sub)) {
                    slab[i] = cell.iter().sum::<f32>() * inv;
                }
            }
            slab_done();
        });
        v
    }

    /// Grid dimensions for `aabb` with `longest` cells along its longest side and (nearly)
    /// cubic cells elsewhere (at least one cell per axis).
    pub fn dims_for(aabb: &Aabb, longest: usize) -> [usize; 3] {
        assert!(longest > 0, "Volume::dims_for: longest must be positive");
        let size = aabb.size();
        let cell = size.max_element() / longest as f64;
        [0, 1, 2].map(|a| ((size[a] / cell).round() as usize).max(1))
    }

    pub fn len(&self) -> usize {
        self.data.len()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Cell size along each axis.
    pub fn spacing(&self) -> DVec3 {
        self.aabb.size() / DVec3::new(self.dims[0] as f64, self.dims[1] as f64, self.dims[2] as f64)
    }

    /// Linear index of voxel `(i, j, k)`.
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.dims[1] + j) * self.dims[0] + i
    }

    pub fn get(&self, i: usize, j: usize, k: usize) -> f32 {
        self.data[self.index(i, j, k)]
    }

    /// World position of the centre of voxel `(i, j, k)`.
    pub fn voxel_centre(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.aabb.min + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * self.spacing()
    }

    /// A reader of many points ([`Sampler::sample`]).
    pub fn sampler(&self) -> Sampler<'_> {
        let min = self.aabb.min.as_vec3();
        let max = self.aabb.max.as_vec3();
        let n = Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32);
        Sampler {
            data: &self.data,
            min,
            max,
            scale: n / (max - min),
            n: self.dims,
            top: n - 1.0,
            isa: crate::Isa::detected(),
        }
    }

    /// Trilinear value at a world point (see the type's docs for the boundary rule).
    pub fn sample(&self, p: Vec3) -> f32 {
        let min = self.aabb.min.as_vec3();
        let max = self.aabb.max.as_vec3();
        if p.cmplt(min).any() || p.cmpgt(max).any() || p.is_nan() {
            return 0.0;
        }
        let size = max - min;
        let cells: [_; 3] = std::array::from_fn(|a| axis_cell(p[a], min[a], size[a], self.dims[a]));
        self.blend(cells[0], cells[1], cells[2])
    }

    /// The trilinear blend of the eight values around a point, from its cells along each axis
    /// ([`axis_cell`]).
    #[inline(always)]
    fn blend(&self, (x0, x1, wx): AxisCell, (y0, y1, wy): AxisCell, (z0, z1, wz): AxisCell) -> f32 {
        let [nx, ny, _] = self.dims;
        let at = |i: usize, j: usize, k: usize| self.data[(k * ny + j) * nx + i];
        let c00 = at(x0, y0, z0) * (1.0 - wx) + at(x1, y0, z0) * wx;
        let c10 = at(x0, y1, z0) * (1.0 - wx) + at(x1, y1, z0) * wx;
        let c01 = at(x0, y0, z1) * (1.0 - wx) + at(x1, y0, z1) * wx;
        let c11 = at(x0, y1, z1) * (1.0 - wx) + at(x1, y1, z1) * wx;
        let c0 = c00 * (1.0 - wy) + c10 * wy;
        let c1 = c01 * (1.0 - wy) + c11 * wy;
        c0 * (1.0 - wz) + c1 * wz
    }

    /// Smallest and largest value (NaN if any value is NaN).
    pub fn min_max(&self) -> (f32, f32) {
        self.data.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            if v.is_nan() || lo.is_nan() {
                (f32::NAN, f32::NAN)
            } else {
                (lo.min(v), hi.max(v))
            }
        })
    }

    /// Resamples onto another grid (trilinear, at the new voxel centres): [`Self::sample`] at
    /// each centre, bit for bit. On a grid the set-up is separable (a centre's coordinate
    /// along an axis depends on its index along that axis only), so each axis's cells and
    /// weights are found once and each voxel only reads and blends its eight neighbours.
    pub fn resample(&self, dims: [usize; 3], aabb: Aabb) -> Volume {
        let mut v = Volume::zeros(dims, aabb);
        let (sp, min, max) = (v.spacing(), self.aabb.min.as_vec3(), self.aabb.max.as_vec3());
        let size = max - min;
        // Per axis and index: the cells, `None` outside this volume's box (or NaN), where
        // `sample` gives 0.
        let axis = |a: usize| -> Vec<Option<AxisCell>> {
            (0..dims[a])
                .map(|i| {
                    let p = (aabb.min[a] + (i as f64 + 0.5) * sp[a]) as f32;
                    let inside = p >= min[a] && p <= max[a];
                    inside.then(|| axis_cell(p, min[a], size[a], self.dims[a]))
                })
                .collect()
        };
        let (xs, ys, zs) = (axis(0), axis(1), axis(2));
        v.data.par_chunks_mut(dims[0] * dims[1]).zip(&zs).for_each(|(slab, &z)| {
            let Some(z) = z else { return };
            for (row, &y) in slab.chunks_mut(dims[0]).zip(&ys) {
                let Some(y) = y else { continue };
                for (o, &x) in row.iter_mut().zip(&xs) {
                    if let Some(x) = x {
                        *o = self.blend(x, y, z);
                    }
                }
            }
        });
        v
    }
}

/// A point's two cells along one axis and the weight of the upper one.
type AxisCell = (usize, usize, f32);

/// The cells along an axis of `n` cells from `min`, `size` long, around coordinate `p` (inside
/// the box): clamped to the end cells' centres at the faces.
#[inline(always)]
fn axis_cell(p: f32, min: f32, size: f32, n: usize) -> AxisCell {
    let c = ((p - min) / size * n as f32 - 0.5).clamp(0.0, (n - 1) as f32);
    // `c ≥ 0`, so truncation is the floor (and, unlike `floor`, no library call on the
    // x86-64 baseline).
    let i0 = c as usize;
    (i0, (i0 + 1).min(n - 1), c - i0 as f32)
}

impl ScalarField for Volume {
    fn eval(&self, points: &[Vec3], _time: f64, out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "Volume::eval: points and out differ in length");
        let sampler = self.sampler();
        for (o, &p) in out.iter_mut().zip(points) {
            *o = sampler.sample(p);
        }
    }

    fn as_volume(&self) -> Option<&Volume> {
        Some(self)
    }
}

/// [`Volume::sample`] with the grid's constants computed once, for reading many points.
#[derive(Clone, Copy, Debug)]
pub struct Sampler<'a> {
    pub(crate) data: &'a [f32],
    pub(crate) min: Vec3,
    pub(crate) max: Vec3,
    /// Cells per world unit along each axis.
    pub(crate) scale: Vec3,
    pub(crate) n: [usize; 3],
    pub(crate) top: Vec3,
    /// The instruction set of [`Sampler::march`].
    pub(crate) isa: crate::Isa,
}

impl Sampler<'_> {
    /// The trilinear value at a world point, as [`Volume::sample`] (up to rounding).
    #[inline]
    pub fn sample(&self, p: Vec3) -> f32 {
        if p.cmplt(self.min).any() || p.cmpgt(self.max).any() || p.is_nan() {
            return 0.0;
        }
        let g = ((p - self.min) * self.scale - 0.5).clamp(Vec3::ZERO, self.top);
        // `g ≥ 0`, so truncation is the floor (and, unlike `floor`, no library call on the
        // x86-64 baseline, where this runs once per sample of a ray).
        let (i, j, k) = (g.x as usize, g.y as usize, g.z as usize);
        let w = g - Vec3::new(i as f32, j as f32, k as f32);
        let [nx, ny, _] = self.n;
        let dx = usize::from(i + 1 < nx);
        let dy = if j + 1 < ny { nx } else { 0 };
        let dz = if k + 1 < self.n[2] { nx * ny } else { 0 };
        let at = (k * ny + j) * nx + i;
        let d = self.data;
        let lerp = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
        let c00 = lerp(d[at], d[at + dx], w.x);
        let c10 = lerp(d[at + dy], d[at + dy + dx], w.x);
        let c01 = lerp(d[at + dz], d[at + dz + dx], w.x);
        let c11 = lerp(d[at + dz + dy], d[at + dz + dy + dx], w.x);
        lerp(lerp(c00, c10, w.y), lerp(c01, c11, w.y), w.z)
    }
}

/// Dilates a cell mask (`dims` x fastest, then y, then z) by `steps` cells: each step adds
/// every cell whose 26 neighbours include a marked one, clipped at the grid's faces. The 3³ box
/// is separable, so a step is three passes of a 3-cell run along x, y and z.
pub fn dilate_mask(mask: &mut [bool], dims: [usize; 3], steps: usize) {
    let [nx, ny, nz] = dims;
    assert_eq!(mask.len(), nx * ny * nz, "dilate_mask: the mask is not {nx}×{ny}×{nz}");
    if mask.is_empty() {
        return;
    }
    let mut line = Vec::new();
    for _ in 0..steps {
        // (stride, count) of each axis; every line along it starts at the cells with a 0 there.
        for (stride, count) in [(1, nx), (nx, ny), (nx * ny, nz)] {
            if count < 2 {
                continue;
            }
            for start in (0..mask.len()).filter(|&c| (c / stride) % count == 0) {
                line.clear();
                line.extend((0..count).map(|i| mask[start + i * stride]));
                for i in 0..count {
                    mask[start + i * stride] = line[i.saturating_sub(1)..(i + 2).min(count)].iter().any(|&m| m);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {

    /// The separable dilation equals the 26-neighbour definition, cell by cell, on a random
    /// mask of an uneven grid, for one and two steps.
    #[test]
    fn dilate_mask_matches_the_26_neighbour_definition() {
        let dims = [7, 5, 4];
        let [nx, ny, nz] = dims;
        let mut state = 12345u64;
        let start: Vec<bool> = (0..nx * ny * nz)
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                state >> 61 == 0
            })
            .collect();
        let brute = |m: &[bool]| -> Vec<bool> {
            let mut out = vec![false; m.len()];
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        out[(k * ny + j) * nx + i] = (k.saturating_sub(1)..(k + 2).min(nz)).any(|kk| {
                            (j.saturating_sub(1)..(j + 2).min(ny))
                                .any(|jj| (i.saturating_sub(1)..(i + 2).min(nx)).any(|ii| m[(kk * ny + jj) * nx + ii]))
                        });
                    }
                }
            }
            out
        };
        assert!(start.iter().any(|&m| m) && !start.iter().all(|&m| m));
        let mut once = start.clone();
        dilate_mask(&mut once, dims, 1);
        assert_eq!(once, brute(&start));
        let mut twice = start.clone();
        dilate_mask(&mut twice, dims, 2);
        assert_eq!(twice, brute(&brute(&start)));
        let mut flat = vec![false; 6];
        flat[2] = true;
        dilate_mask(&mut flat, [6, 1, 1], 1);
        assert_eq!(flat, [false, true, true, true, false, false]);
    }
    use super::*;
    use approx::assert_relative_eq;

    fn unit_box() -> Aabb {
        Aabb::new(DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0))
    }

    #[test]
    fn layout_is_x_fastest_and_cell_centred() {
        let v = Volume::from_fn([4, 3, 2], unit_box(), |p| (p.x * 100.0 + p.y * 10.0 + p.z) as f32);
        assert_eq!(v.index(1, 0, 0), 1);
        assert_eq!(v.index(0, 1, 0), 4);
        assert_eq!(v.index(0, 0, 1), 12);
        let c = v.voxel_centre(0, 0, 0);
        assert_relative_eq!(c.x, 0.25);
        assert_relative_eq!(c.y, 1.0 / 6.0);
        assert_relative_eq!(c.z, 0.25);
        assert_relative_eq!(v.get(3, 2, 1), (1.75 * 100.0 + (5.0 / 6.0) * 10.0 + 0.75) as f32, epsilon = 1e-4);
    }

    #[test]
    fn trilinear_reproduces_linear_fields_and_is_zero_outside() {
        let f = |p: DVec3| (1.0 + 2.0 * p.x - 3.0 * p.y + 0.5 * p.z) as f32;
        let v = Volume::from_fn([8, 7, 6], unit_box(), f);
        // Inside the hull of the voxel centres a linear field is reproduced exactly.
        for p in [DVec3::new(0.4, 0.2, 0.3), DVec3::new(1.7, 0.8, 0.6), DVec3::new(1.0, 0.5, 0.5)] {
            assert_relative_eq!(v.sample(p.as_vec3()), f(p), epsilon = 1e-5);
        }
        assert_eq!(v.sample(Vec3::new(-0.01, 0.5, 0.5)), 0.0);
        assert_eq!(v.sample(Vec3::new(1.0, 0.5, 1.01)), 0.0);
        assert_eq!(v.sample(Vec3::NAN), 0.0);
    }

    #[test]
    fn sampler_reads_like_sample() {
        let v = Volume::from_fn([9, 4, 1], unit_box(), |p| (p.x * 3.0).sin() as f32 + (p.y * p.z) as f32);
        let s = v.sampler();
        for i in 0..2000 {
            let p =
                Vec3::new((i % 23) as f32 * 0.1 - 0.1, (i % 17) as f32 * 0.07 - 0.05, (i % 13) as f32 * 0.09 - 0.03);
            assert!((s.sample(p) - v.sample(p)).abs() < 1e-5, "{p}: {} vs {}", s.sample(p), v.sample(p));
        }
    }

    /// The cell average of a linear field is its value at the centre; of `x²` over a cell
    /// `[a, a + h]` it is `a² + a h + h²/3`, which the midpoint sub-lattice of n points per axis
    /// reproduces up to `h² / (12 n²)`.
    #[test]
    fn averaged_sampling_gives_cell_means() {
        let aabb = unit_box();
        let lin = |p: Vec3, _t: f64| 1.0 + 2.0 * p.x - p.y + 0.5 * p.z;
        let a = Volume::from_field_averaged([4, 3, 2], aabb, &lin, 0.0, 3);
        let b = Volume::from_field([4, 3, 2], aabb, &lin, 0.0);
        for (x, y) in a.data.iter().zip(&b.data) {
            assert!((x - y).abs() < 1e-5);
        }
        let sq = |p: Vec3, _t: f64| p.x * p.x;
        let n = 4;
        let v = Volume::from_field_averaged([4, 1, 1], aabb, &sq, 0.0, n);
        let h = 0.5f64;
        for i in 0..4 {
            let a0 = i as f64 * h;
            let exact = a0 * a0 + a0 * h + h * h / 3.0;
            let midpoint = exact - h * h / (12.0 * (n * n) as f64);
            assert!((v.get(i, 0, 0) as f64 - midpoint).abs() < 1e-5, "cell {i}: {} vs {midpoint}", v.get(i, 0, 0));
        }
    }

    #[test]
    fn dims_for_keeps_cells_cubic() {
        assert_eq!(Volume::dims_for(&unit_box(), 64), [64, 32, 32]);
        assert_eq!(Volume::dims_for(&Aabb::cube(DVec3::ZERO, 3.0), 17), [17, 17, 17]);
    }

    #[test]
    fn constant_grid_is_constant_up_to_faces() {
        let v = Volume::from_fn([5, 5, 5], unit_box(), |_| 2.5);
        assert_eq!(v.sample(Vec3::new(0.0, 0.0, 0.0)), 2.5);
        assert_eq!(v.sample(Vec3::new(2.0, 1.0, 1.0)), 2.5);
    }

    /// The extremes of the values, NaN as soon as one value is NaN, wherever it is.
    #[test]
    fn min_max_reads_the_extremes_and_any_nan() {
        let v = Volume::from_vec([3, 1, 1], unit_box(), vec![3.0, -1.0, 2.0]);
        assert_eq!(v.min_max(), (-1.0, 3.0));
        for at in 0..3 {
            let mut data = vec![3.0, -1.0, 2.0];
            data[at] = f32::NAN;
            let (lo, hi) = Volume::from_vec([3, 1, 1], unit_box(), data).min_max();
            assert!(lo.is_nan() && hi.is_nan(), "NaN at {at}");
        }
        assert_eq!((v.len(), v.is_empty()), (3, false));
    }

    /// A box far thinner than a cell along an axis still gets one cell there.
    #[test]
    fn dims_for_keeps_at_least_one_cell_per_axis() {
        let flat = Aabb::new(DVec3::ZERO, DVec3::new(10.0, 0.01, 1.0));
        assert_eq!(Volume::dims_for(&flat, 4), [4, 1, 1]);
        assert_eq!(Volume::dims_for(&flat, 20), [20, 1, 2]);
    }

    /// The progress callback ticks once per z-slice.
    #[test]
    fn sampling_a_field_ticks_once_per_slice() {
        let ticks = std::sync::atomic::AtomicUsize::new(0);
        let one = |_: Vec3, _t: f64| 1.0f32;
        let tick = || {
            ticks.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        };
        let v = Volume::from_field_averaged_with([3, 2, 5], unit_box(), &one, 0.0, 2, &tick);
        assert_eq!(ticks.load(std::sync::atomic::Ordering::Relaxed), 5);
        assert!(v.data.iter().all(|&x| (x - 1.0).abs() < 1e-6));
    }

    /// Resampling equals sampling each new centre, bit for bit: onto finer and coarser grids,
    /// a box shifted partly outside the volume (zeros there) and a single voxel.
    #[test]
    fn resample_equals_sampling_each_centre() {
        let v = Volume::from_fn([7, 5, 6], unit_box(), |p| (p.x * 3.1 + p.y * p.z * 7.0 + (p.z * 9.0).sin()) as f32);
        let shifted = Aabb::new(DVec3::new(-0.3, 0.1, 0.05), DVec3::new(0.9, 1.4, 1.0));
        for (dims, aabb) in
            [([13, 9, 11], unit_box()), ([4, 3, 2], unit_box()), ([10, 10, 10], shifted), ([1, 1, 1], shifted)]
        {
            let fast = v.resample(dims, aabb);
            let each = Volume::from_fn(dims, aabb, |p| v.sample(p.as_vec3()));
            assert_eq!(fast.dims, dims);
            for (i, (a, b)) in fast.data.iter().zip(&each.data).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{dims:?} voxel {i}: {a} against {b}");
            }
        }
    }

    #[test]
    fn resample_identity_grid_is_exact() {
        let v = Volume::from_fn([6, 5, 4], unit_box(), |p| (p.x * p.y + p.z) as f32);
        let r = v.resample(v.dims, v.aabb);
        for (a, b) in v.data.iter().zip(&r.data) {
            assert_relative_eq!(a, b, epsilon = 1e-6);
        }
    }
}
