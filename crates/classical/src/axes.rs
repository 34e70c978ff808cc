//! Grid rows along the axis the cameras ring.
//!
//! The footprint projector shares one footprint axis between the voxels of a grid row when the
//! row runs along the grid's `x` axis and a camera sees it as a vertical or horizontal line of
//! voxels (rings of cameras around `x`; [`crate::FootprintProjector::shared_row_views`]). That
//! makes its back projection several times faster. A scene whose cameras ring `y` or `z` (a
//! CFD flow rising along `y`, say) gets the same by naming the world's axes cyclically, so
//! that the ringed axis becomes `x`: a rotation that only moves coordinates, exact in floating
//! point, which keeps a camera's exact zeros where they were. [`AxisShift`] does that to the
//! grid, the cameras and volumes, and puts a volume back on the original axes.

use std::borrow::Cow;

use fluidnerf_core::{Aabb, Camera, Volume};
use glam::{DAffine3, DMat3, DVec3};

use crate::Grid;

/// The world's axes named cyclically: shifted coordinate `a` is original coordinate
/// `(a + s) mod 3`, so with `s = 1` the original `y` axis becomes `x` (and `z` becomes `y`,
/// `x` becomes `z`), with `s = 2` the original `z` axis becomes `x`. A proper rotation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisShift {
    s: usize,
}

impl AxisShift {
    /// No renaming.
    pub const IDENTITY: AxisShift = AxisShift { s: 0 };

    /// The shift that makes `axis` (0, 1, 2 for `x`, `y`, `z`) the `x` axis.
    pub fn to_x(axis: usize) -> AxisShift {
        assert!(axis < 3, "AxisShift::to_x: axis {axis} is not 0, 1 or 2");
        AxisShift { s: axis }
    }

    /// The shift under which the most views share their rows' footprints
    /// ([`rows_shared_along`]); the identity unless another axis gives strictly more.
    pub fn for_rows(cameras: &[Camera]) -> AxisShift {
        let count = |a: usize| cameras.iter().filter(|c| rows_shared_along(c, a)).count();
        let best = (1..3).fold(0, |best, a| if count(a) > count(best) { a } else { best });
        AxisShift::to_x(best)
    }

    pub fn is_identity(&self) -> bool {
        self.s == 0
    }

    /// The original axis that shifted axis `a` is.
    fn source(&self, a: usize) -> usize {
        (a + self.s) % 3
    }

    pub fn vec(&self, v: DVec3) -> DVec3 {
        let c = v.to_array();
        DVec3::new(c[self.source(0)], c[self.source(1)], c[self.source(2)])
    }

    pub fn dims(&self, d: [usize; 3]) -> [usize; 3] {
        [d[self.source(0)], d[self.source(1)], d[self.source(2)]]
    }

    pub fn aabb(&self, b: &Aabb) -> Aabb {
        Aabb { min: self.vec(b.min), max: self.vec(b.max) }
    }

    pub fn grid(&self, g: &Grid) -> Grid {
        Grid::new(self.dims(g.dims), self.aabb(&g.aabb))
    }

    /// The camera in the shifted world: its pose's columns and centre shifted, the rest as it
    /// was.
    pub fn camera(&self, c: &Camera) -> Camera {
        let m = c.world_from_camera.matrix3;
        let pose = DAffine3 {
            matrix3: DMat3::from_cols(self.vec(m.x_axis), self.vec(m.y_axis), self.vec(m.z_axis)),
            translation: self.vec(c.world_from_camera.translation),
        };
        Camera { world_from_camera: pose, ..c.clone() }
    }

    /// Every camera of `cameras` in the shifted world ([`Self::camera`]).
    pub fn cameras(&self, cameras: &[Camera]) -> Vec<Camera> {
        cameras.iter().map(|c| self.camera(c)).collect()
    }

    /// `data` (on a grid of `dims`, `x` fastest) on the shifted grid; borrowed, not copied,
    /// when the shift is the identity.
    pub fn data<'a>(&self, dims: [usize; 3], data: &'a [f32]) -> Cow<'a, [f32]> {
        if self.is_identity() {
            return Cow::Borrowed(data);
        }
        let mut out = vec![0f32; data.len()];
        self.walk(dims, |orig, shifted| out[shifted] = data[orig]);
        Cow::Owned(out)
    }

    /// `shifted` (on the shifted grid of a grid of `dims`) back on the original grid; returned
    /// as it is when the shift is the identity.
    pub fn data_back(&self, dims: [usize; 3], shifted: Vec<f32>) -> Vec<f32> {
        if self.is_identity() {
            return shifted;
        }
        let mut out = vec![0f32; shifted.len()];
        self.walk(dims, |orig, s| out[orig] = shifted[s]);
        out
    }

    /// `v` on the shifted axes; borrowed when the shift is the identity.
    pub fn volume<'a>(&self, v: &'a Volume) -> Cow<'a, Volume> {
        if self.is_identity() {
            return Cow::Borrowed(v);
        }
        Cow::Owned(Volume::from_vec(self.dims(v.dims), self.aabb(&v.aabb), self.data(v.dims, &v.data).into_owned()))
    }

    /// Calls `f(original index, shifted index)` for every voxel of a grid of `dims`.
    fn walk(&self, dims: [usize; 3], mut f: impl FnMut(usize, usize)) {
        assert!(dims.iter().product::<usize>() > 0, "AxisShift: empty grid {dims:?}");
        let sd = self.dims(dims);
        // The shifted index's stride along each original axis.
        let mut stride = [0usize; 3];
        let mut s = 1;
        for a in 0..3 {
            stride[self.source(a)] = s;
            s *= sd[a];
        }
        let mut orig = 0;
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                let base = j * stride[1] + k * stride[2];
                for i in 0..dims[0] {
                    f(orig, base + i * stride[0]);
                    orig += 1;
                }
            }
        }
    }
}

/// Whether the voxels of a grid row along world axis `axis` share one footprint axis in
/// `camera`'s image: an undistorted camera whose depth, and its image `x` (without skew) or
/// `y`, do not change along the axis, bit for bit in f32 (the footprint projector's test).
pub fn rows_shared_along(camera: &Camera, axis: usize) -> bool {
    if !camera.distortion.is_identity() {
        return false;
    }
    let m = camera.camera_from_world().matrix3;
    // Row r of the rotation at column `axis`: the axis's r-th camera coordinate.
    let col = [m.x_axis, m.y_axis, m.z_axis][axis];
    let r = |row: usize| col[row] as f32;
    r(2) == 0.0 && ((r(0) == 0.0 && camera.intrinsics.skew as f32 == 0.0) || r(1) == 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::Intrinsics;

    const K: Intrinsics = Intrinsics { width: 64, height: 48, fx: 80.0, fy: 80.0, cx: 32.0, cy: 24.0, skew: 0.0 };

    fn ring_camera(axis: DVec3, angle: f64) -> Camera {
        // A camera 100 units out on a ring around `axis`, looking at the origin.
        let (a, b) = if axis.x != 0.0 {
            (DVec3::Y, DVec3::Z)
        } else if axis.y != 0.0 {
            (DVec3::Z, DVec3::X)
        } else {
            (DVec3::X, DVec3::Y)
        };
        let centre = 100.0 * (angle.cos() * a + angle.sin() * b);
        Camera::look_at(K, centre, DVec3::ZERO, axis)
    }

    /// A camera looking along `z` sees grid rows along `x` and along `y` as lines of pixels
    /// (rows along `y` only without skew), none along `z`, and none at all with distortion;
    /// between `x` and `y` the identity is kept.
    #[test]
    fn a_camera_along_z_shares_rows_along_x_and_y() {
        let cam = Camera::look_at(K, DVec3::new(0.0, 0.0, 100.0), DVec3::ZERO, DVec3::Y);
        assert!(rows_shared_along(&cam, 0) && rows_shared_along(&cam, 1) && !rows_shared_along(&cam, 2));
        assert!(AxisShift::for_rows(std::slice::from_ref(&cam)).is_identity());
        let mut skewed = cam.clone();
        skewed.intrinsics.skew = 0.5;
        assert!(rows_shared_along(&skewed, 0) && !rows_shared_along(&skewed, 1));
        let mut distorted = cam;
        distorted.distortion.k1 = 0.01;
        assert!((0..3).all(|a| !rows_shared_along(&distorted, a)));
    }

    /// A volume, its box and the grid move with the axes: with `s = 1` the original `y`
    /// becomes `x`.
    #[test]
    fn a_volume_moves_with_its_box() {
        let aabb = Aabb { min: DVec3::new(-1.0, -2.0, -3.0), max: DVec3::new(1.0, 2.0, 3.0) };
        let v = Volume::from_vec([4, 3, 2], aabb, (0..24).map(|v| v as f32).collect());
        let shift = AxisShift::to_x(1);
        assert!(!shift.is_identity() && AxisShift::IDENTITY.is_identity());
        let moved = shift.volume(&v);
        assert_eq!(moved.dims, [3, 2, 4]);
        assert_eq!(moved.aabb.min, DVec3::new(-2.0, -3.0, -1.0));
        assert_eq!(moved.aabb.max, DVec3::new(2.0, 3.0, 1.0));
        assert_eq!(moved.data, shift.data(v.dims, &v.data).into_owned());
        let grid = shift.grid(&Grid::new(v.dims, aabb));
        assert_eq!((grid.dims, grid.aabb), (moved.dims, moved.aabb));
        assert_eq!(shift.vec(DVec3::new(1.0, 2.0, 3.0)), DVec3::new(2.0, 3.0, 1.0));
        assert_eq!(AxisShift::to_x(2).dims([4, 3, 2]), [2, 4, 3]);
        let same = AxisShift::IDENTITY.volume(&v);
        assert_eq!((same.dims, &same.data), (v.dims, &v.data));
    }

    #[test]
    fn volumes_go_there_and_back_and_land_where_the_axes_say() {
        let dims = [4, 3, 2];
        let data: Vec<f32> = (0..24).map(|v| v as f32).collect();
        for s in 0..3 {
            let shift = AxisShift::to_x(s);
            let shifted = shift.data(dims, &data);
            assert_eq!(shift.data_back(dims, shifted.to_vec()), data, "shift {s}");
            // Voxel (i, j, k) = (3, 2, 1) of the original grid.
            // i + nx (j + ny k) with k = 1.
            let (orig, idx) = (3 + 4 * (2 + 3), [3usize, 2, 1]);
            let sd = shift.dims(dims);
            let si = [idx[s % 3], idx[(s + 1) % 3], idx[(s + 2) % 3]];
            assert_eq!(shifted[si[0] + sd[0] * (si[1] + sd[1] * si[2])], data[orig], "shift {s}");
        }
    }

    #[test]
    fn a_shifted_camera_sees_shifted_points_where_it_saw_them() {
        let cam =
            Camera::look_at(K, DVec3::new(30.0, -70.0, 55.0), DVec3::new(1.0, 2.0, -3.0), DVec3::new(0.2, 0.1, 1.0));
        for s in 0..3 {
            let shift = AxisShift::to_x(s);
            let moved = shift.camera(&cam);
            for p in [DVec3::new(1.0, 2.0, 3.0), DVec3::new(-5.0, 4.0, 0.5)] {
                let (a, b) = (cam.project(p).unwrap(), moved.project(shift.vec(p)).unwrap());
                assert!((a - b).length() < 1e-9, "shift {s}: {a} against {b}");
            }
            assert!(moved.validate().is_ok(), "shift {s}: the pose stays a right-handed rotation");
        }
    }

    #[test]
    fn rings_pick_the_shift_that_makes_their_axis_x() {
        for (axis, s) in [(DVec3::X, 0), (DVec3::Y, 1), (DVec3::Z, 2)] {
            let cams: Vec<Camera> = (0..6).map(|i| ring_camera(axis, i as f64 * 1.0471975511965976)).collect();
            let shift = AxisShift::for_rows(&cams);
            assert_eq!(shift, AxisShift::to_x(s), "ring around {axis}");
            assert!(cams.iter().all(|c| rows_shared_along(&shift.camera(c), 0)), "ring around {axis}");
        }
        // A camera in general position shares nothing: no shift.
        let free = Camera::look_at(K, DVec3::new(30.0, -70.0, 55.0), DVec3::ZERO, DVec3::new(0.2, 0.1, 1.0));
        assert!(AxisShift::for_rows(&[free]).is_identity());
    }

    /// The footprint projector on the shifted grid and cameras draws the images it drew on the
    /// original ones (to rounding: the shifted one shares its rows, the original does not), and
    /// back-projects them to the shifted volume of what it gave before.
    #[test]
    fn the_footprint_projector_draws_the_same_images_on_the_shifted_axes() {
        use crate::{FootprintProjector, Projector};
        let aabb = Aabb { min: DVec3::new(-6.0, -5.0, -4.0), max: DVec3::new(6.0, 5.0, 4.0) };
        let grid = Grid::new([12, 10, 8], aabb);
        let cams: Vec<Camera> = (0..5).map(|i| ring_camera(DVec3::Y, 0.3 + i as f64 * 1.2566370614359172)).collect();
        let shift = AxisShift::for_rows(&cams);
        assert_eq!(shift, AxisShift::to_x(1));
        let x: Vec<f32> = (0..grid.len()).map(|v| ((v * 37 % 101) as f32) / 101.0).collect();
        let before = FootprintProjector::new(grid, &cams, 1.0).unwrap();
        let shifted_cams = shift.cameras(&cams);
        let after = FootprintProjector::new(shift.grid(&grid), &shifted_cams, 1.0).unwrap();
        assert_eq!((before.shared_row_views(), after.shared_row_views()), (0, cams.len()));
        let xs = shift.data(grid.dims, &x);
        let (mut back_before, mut back_after) = (vec![0f32; grid.len()], vec![0f32; grid.len()]);
        for v in 0..cams.len() {
            let (mut a, mut b) = (vec![0f32; before.view_len(v)], vec![0f32; after.view_len(v)]);
            before.forward(v, &x, &mut a);
            after.forward(v, &xs, &mut b);
            let peak = a.iter().fold(0f32, |m, &p| m.max(p));
            assert!(peak > 0.0, "view {v} sees the volume");
            let worst = a.iter().zip(&b).fold(0f32, |m, (p, q)| m.max((p - q).abs()));
            assert!(worst <= 1e-4 * peak, "view {v}: images differ by {worst} (peak {peak})");
            before.back_add(v, &a, &mut back_before, None);
            after.back_add(v, &a, &mut back_after, None);
        }
        let back_after = shift.data_back(grid.dims, back_after);
        let peak = back_before.iter().fold(0f32, |m, &p| m.max(p));
        let worst = back_before.iter().zip(&back_after).fold(0f32, |m, (p, q)| m.max((p - q).abs()));
        assert!(worst <= 1e-4 * peak, "back projections differ by {worst} (peak {peak})");
    }
}
