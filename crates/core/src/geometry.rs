//! Axis-aligned boxes and rays.

use crate::num;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A ray `origin + s * dir`, with `dir` of unit length so that `s` is a distance in world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    /// Unit direction.
    pub dir: DVec3,
}

impl Ray {
    /// Builds a ray, normalising `dir`.
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Ray { origin, dir: dir.normalize() }
    }

    /// The point at distance `s` along the ray.
    pub fn at(&self, s: f64) -> DVec3 {
        self.origin + s * self.dir
    }
}

/// An axis-aligned box `[min, max]` in world units (the reconstruction box).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

/// The farthest a box's corner may lie from the origin on any axis. Rays are marched and
/// pixels rendered in 32-bit floats: lengths of 1e16 square to 1e32, within their range (about
/// 3.4e38) with room for sums and factors, while a box of ±1e300 made every pixel infinite.
pub const MAX_COORDINATE: f64 = 1e16;

/// The farthest a scene's box may lie from the origin, in units of its smallest side. The
/// projectors and the networks work in 32-bit floats, whose steps at a distance `d` are about
/// `d / 1.7e7`: at 10⁴ sides a voxel of a 128-cell grid is still resolved to about a tenth of its
/// size, and beyond it results degrade without an error (a 40 mm box 10 km out, 2.5·10⁵ sides,
/// gave ASART an NRMSE of 0.80 instead of 0.23).
pub const MAX_OFFSET_IN_SIDES: f64 = 1e4;

/// The shortest side a box may have, in world units: a micrometre in metres. The projectors and
/// the networks work in 32-bit floats, and quantities derived from the box scale with powers of
/// its side (a voxel's side and volume, ray steps, the field's values in inverse lengths); a
/// 40-unit scene shrunk by 10⁻¹⁰ made ASART return a volume of zeros, while at this bound it
/// reconstructs as the unshrunk scene does.
pub const MIN_SIDE: f64 = 1e-6;

/// The longest side a box may have, in world units: a thousand kilometres in millimetres. A
/// 40-unit scene grown by 10¹² made ASART return a volume of zeros (the field's values, in
/// inverse lengths, fall towards f32's smallest), while at this bound it reconstructs as the
/// original does.
pub const MAX_SIDE: f64 = 1e9;

impl Aabb {
    /// A box from its corners. Panics if any `min` component exceeds `max` (a programmer error;
    /// input from files is validated with [`Aabb::validate`]).
    pub fn new(min: DVec3, max: DVec3) -> Self {
        assert!(min.cmple(max).all(), "Aabb::new: min {min} must not exceed max {max}");
        Aabb { min, max }
    }

    /// A cube of side `side` centred on `centre`.
    pub fn cube(centre: DVec3, side: f64) -> Self {
        let h = DVec3::splat(0.5 * side);
        Aabb::new(centre - h, centre + h)
    }

    /// Checks that the box is finite, within [`MAX_COORDINATE`] of the origin, and has sides
    /// between [`MIN_SIDE`] and [`MAX_SIDE`].
    pub fn validate(&self) -> Result<(), crate::CoreError> {
        if !(self.min.is_finite() && self.max.is_finite()) {
            return Err(crate::CoreError::invalid("aabb", "corners must be finite"));
        }
        let far = self.farthest_coordinate();
        if far > MAX_COORDINATE {
            return Err(crate::CoreError::invalid(
                "aabb",
                format!(
                    "corners must lie within ±{} of the origin (rendering and training run in 32-bit floats, \
                     whose squared lengths overflow beyond), got min {} max {}",
                    num(MAX_COORDINATE),
                    num(self.min.to_array()),
                    num(self.max.to_array())
                ),
            ));
        }
        if !self.min.cmplt(self.max).all() {
            return Err(crate::CoreError::invalid(
                "aabb",
                format!(
                    "min {} must be below max {} on every axis",
                    num(self.min.to_array()),
                    num(self.max.to_array())
                ),
            ));
        }
        let size = self.size();
        if size.min_element() < MIN_SIDE || size.max_element() > MAX_SIDE {
            return Err(crate::CoreError::invalid(
                "aabb",
                format!(
                    "sides must be between {MIN_SIDE:e} and {MAX_SIDE:e} world units (rendering and training run in 32-bit floats, \
                     whose voxel sizes, ray steps and field values leave their range outside), got sides {}; \
                     give the box in other units (e.g. mm instead of m), scaling the camera positions with it",
                    num(size.to_array())
                ),
            ));
        }
        Ok(())
    }

    /// Checks that the box lies within [`MAX_OFFSET_IN_SIDES`] of its smallest side from the
    /// origin, so that 32-bit arithmetic resolves its voxels (a valid box, [`Aabb::validate`]).
    pub fn check_resolvable(&self) -> Result<(), crate::CoreError> {
        let far = self.farthest_coordinate();
        let side = self.size().min_element();
        if far > MAX_OFFSET_IN_SIDES * side {
            return Err(crate::CoreError::invalid(
                "aabb",
                format!(
                    "the box reaches {} from the origin, more than {} times its smallest side ({}): \
                     projection and training run in 32-bit floats, too coarse there to place its voxels; \
                     move the origin near the box (shift the box and every camera position by the same vector)",
                    num(far),
                    num(MAX_OFFSET_IN_SIDES),
                    num(side)
                ),
            ));
        }
        Ok(())
    }

    /// The largest absolute coordinate of the box's corners.
    fn farthest_coordinate(&self) -> f64 {
        self.min.abs().max(self.max.abs()).max_element()
    }

    pub fn size(&self) -> DVec3 {
        self.max - self.min
    }

    pub fn centre(&self) -> DVec3 {
        0.5 * (self.min + self.max)
    }

    /// Whether `p` lies inside the closed box.
    pub fn contains(&self, p: DVec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Whether the two boxes share some volume: boxes that only touch along a face, an edge
    /// or a corner do not.
    pub fn overlaps(&self, other: &Aabb) -> bool {
        (0..3).all(|a| self.min[a] < other.max[a] && other.min[a] < self.max[a])
    }

    /// The eight corners, x varying fastest.
    pub fn corners(&self) -> [DVec3; 8] {
        let (a, b) = (self.min, self.max);
        std::array::from_fn(|i| {
            DVec3::new(
                if i & 1 == 0 { a.x } else { b.x },
                if i & 2 == 0 { a.y } else { b.y },
                if i & 4 == 0 { a.z } else { b.z },
            )
        })
    }

    /// Maps a world point to box-normalised coordinates, `min -> 0`, `max -> 1`.
    pub fn to_unit(&self, p: DVec3) -> DVec3 {
        (p - self.min) / self.size()
    }

    /// Entry and exit distances `(s_near, s_far)` of `ray` through the box, clipped to `s >= 0`
    /// (the part in front of the ray origin), or `None` if the ray misses the box or the
    /// segment has zero length. Slab method; rays parallel to a slab are handled exactly.
    pub fn intersect(&self, ray: &Ray) -> Option<(f64, f64)> {
        let mut near = 0.0f64;
        let mut far = f64::INFINITY;
        for axis in 0..3 {
            let o = ray.origin[axis];
            let d = ray.dir[axis];
            let (lo, hi) = (self.min[axis], self.max[axis]);
            if d == 0.0 {
                if o < lo || o > hi {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d;
            let (mut t0, mut t1) = ((lo - o) * inv, (hi - o) * inv);
            if t0 > t1 {
                std::mem::swap(&mut t0, &mut t1);
            }
            near = near.max(t0);
            far = far.min(t1);
            if near >= far {
                return None;
            }
        }
        Some((near, far))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn ray_through_cube_diagonal() {
        let b = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let r = Ray::new(DVec3::splat(-1.0), DVec3::ONE);
        let (n, f) = b.intersect(&r).expect("hits");
        assert_relative_eq!(n, 3f64.sqrt(), epsilon = 1e-12);
        assert_relative_eq!(f - n, 3f64.sqrt(), epsilon = 1e-12);
    }

    #[test]
    fn axis_parallel_rays() {
        let b = Aabb::new(DVec3::new(-1.0, -2.0, -3.0), DVec3::new(1.0, 2.0, 3.0));
        let r = Ray::new(DVec3::new(0.5, 1.5, -10.0), DVec3::Z);
        let (n, f) = b.intersect(&r).expect("hits");
        assert_relative_eq!(n, 7.0);
        assert_relative_eq!(f, 13.0);
        // Parallel to the z slabs but outside the x slab: a miss.
        assert!(b.intersect(&Ray::new(DVec3::new(1.5, 0.0, -10.0), DVec3::Z)).is_none());
        // Pointing away: a miss.
        assert!(b.intersect(&Ray::new(DVec3::new(0.0, 0.0, -10.0), -DVec3::Z)).is_none());
    }

    #[test]
    fn origin_inside_clips_at_zero() {
        let b = Aabb::cube(DVec3::ZERO, 2.0);
        let (n, f) = b.intersect(&Ray::new(DVec3::ZERO, DVec3::X)).expect("hits");
        assert_eq!(n, 0.0);
        assert_relative_eq!(f, 1.0);
    }

    #[test]
    fn validate_rejects_degenerate() {
        let b = Aabb { min: DVec3::ZERO, max: DVec3::new(1.0, 0.0, 1.0) };
        assert!(b.validate().is_err());
        for (min, max) in [
            (DVec3::ZERO, DVec3::new(1.0, f64::NAN, 1.0)),
            (DVec3::new(f64::NAN, 0.0, 0.0), DVec3::ONE),
            (DVec3::new(0.0, f64::NEG_INFINITY, 0.0), DVec3::ONE),
        ] {
            let e = Aabb { min, max }.validate().expect_err("refused").to_string();
            assert!(e.contains("corners must be finite"), "{min} {max}: {e}");
        }
    }

    /// The box's centre, corners (x fastest), closed containment and unit coordinates.
    #[test]
    fn centre_corners_containment_and_unit_coordinates() {
        let b = Aabb::new(DVec3::new(-1.0, 2.0, 10.0), DVec3::new(3.0, 4.0, 16.0));
        assert_eq!(b.centre(), DVec3::new(1.0, 3.0, 13.0));
        let c = b.corners();
        assert_eq!(c[0], b.min);
        assert_eq!(c[7], b.max);
        assert_eq!(c[1], DVec3::new(3.0, 2.0, 10.0));
        assert_eq!(c[2], DVec3::new(-1.0, 4.0, 10.0));
        assert_eq!(c[4], DVec3::new(-1.0, 2.0, 16.0));
        assert_eq!(c[6], DVec3::new(-1.0, 4.0, 16.0));
        assert!(c.iter().all(|&p| b.contains(p)), "the closed box holds its corners");
        assert!(b.contains(b.centre()));
        // Outside along one axis alone is outside.
        for p in [DVec3::new(3.5, 3.0, 13.0), DVec3::new(1.0, 1.9, 13.0), DVec3::new(1.0, 3.0, 16.1)] {
            assert!(!b.contains(p), "{p}");
        }
        assert_eq!(b.to_unit(b.min), DVec3::ZERO);
        assert_eq!(b.to_unit(b.max), DVec3::ONE);
        assert_eq!(b.to_unit(DVec3::new(0.0, 3.5, 11.5)), DVec3::new(0.25, 0.75, 0.25));
    }

    /// Boxes that share volume overlap; boxes apart along one axis, or touching only along a
    /// face, do not.
    #[test]
    fn boxes_overlap_when_they_share_volume() {
        let b = Aabb::new(DVec3::ZERO, DVec3::new(4.0, 2.0, 2.0));
        assert!(b.overlaps(&Aabb::new(DVec3::splat(1.0), DVec3::splat(3.0))));
        assert!(b.overlaps(&b));
        for other in [
            Aabb::new(DVec3::new(4.0, 0.0, 0.0), DVec3::new(5.0, 2.0, 2.0)),
            Aabb::new(DVec3::new(1.0, 2.5, 0.0), DVec3::new(2.0, 3.0, 2.0)),
            Aabb::new(DVec3::splat(100.0), DVec3::splat(104.0)),
        ] {
            assert!(!b.overlaps(&other) && !other.overlaps(&b), "{other:?}");
        }
    }

    /// A ray in a face's plane, parallel to it, runs on the closed box's surface and hits it; a
    /// ray that only touches an edge crosses no length of the box and misses.
    #[test]
    fn rays_along_a_face_hit_and_rays_touching_an_edge_miss() {
        let b = Aabb::new(DVec3::ZERO, DVec3::ONE);
        for x in [0.0, 1.0] {
            let (n, f) = b.intersect(&Ray::new(DVec3::new(x, 0.5, -2.0), DVec3::Z)).expect("on the face");
            assert_relative_eq!(n, 2.0);
            assert_relative_eq!(f, 3.0);
        }
        assert!(b.intersect(&Ray::new(DVec3::new(-1.0, 1.0, 0.5), DVec3::new(1.0, -1.0, 0.0))).is_none());
    }

    /// A box whose corners are finite but too far out for 32-bit rendering is refused, naming
    /// the limit; one just inside it passes.
    #[test]
    fn validate_rejects_boxes_beyond_the_f32_range() {
        let b = Aabb { min: DVec3::splat(-1e300), max: DVec3::splat(1.0) };
        let e = b.validate().expect_err("refused").to_string();
        assert!(e.contains("aabb") && e.contains("±1e16") && e.contains("-1e300"), "{e}");
        let b = Aabb { min: DVec3::ZERO, max: DVec3::new(1.0, 2e16, 1.0) };
        assert!(b.validate().is_err());
        let b = Aabb { min: DVec3::splat(MAX_COORDINATE - 1e9), max: DVec3::splat(MAX_COORDINATE) };
        assert!(b.validate().is_ok());
    }

    /// A box whose sides leave the range where 32-bit voxel sizes, ray steps and field values
    /// stay meaningful is refused with the range and its sides (a side of 10⁻³⁶ or 10³⁶ passed,
    /// and such scenes reconstructed to volumes of zeros); boxes from a micrometre in metres to
    /// a thousand kilometres in millimetres pass.
    #[test]
    fn validate_rejects_sides_beyond_the_f32_range() {
        for b in [
            Aabb { min: DVec3::ZERO, max: DVec3::splat(1e-36) },
            Aabb { min: DVec3::ZERO, max: DVec3::new(1.0, 1.0, 1e-7) },
            Aabb { min: DVec3::splat(-1e10), max: DVec3::splat(1e10) },
            Aabb { min: DVec3::ZERO, max: DVec3::new(1.0, 2e9, 1.0) },
        ] {
            let e = b.validate().expect_err("refused").to_string();
            assert!(e.contains("aabb") && e.contains("between 1e-6 and 1e9"), "{e}");
        }
        let e = Aabb::cube(DVec3::ZERO, 1e36).validate().expect_err("refused").to_string();
        assert!(e.contains("±1e16"), "{e}");
        for side in [MIN_SIDE, 1e-3, 0.04, 1.0, 40.0, 2000.0, MAX_SIDE] {
            Aabb::cube(DVec3::ZERO, side).validate().unwrap_or_else(|e| panic!("side {side}: {e}"));
        }
    }

    /// A small box far from the origin, where 32-bit floats cannot place its voxels, is refused
    /// with the distance, the limit and its side; at 10⁴ sides it passes, as does a box around
    /// the origin of any size.
    #[test]
    fn boxes_too_far_out_for_their_size_are_refused() {
        let e = Aabb::cube(DVec3::new(0.0, 1e6, 0.0), 40.0).check_resolvable().expect_err("refused").to_string();
        assert!(
            e.contains("reaches 1000020 from the origin") && e.contains("10000 times its smallest side (40)"),
            "{e}"
        );
        assert!(Aabb::cube(DVec3::new(0.0, 0.0, -4e5 + 20.0), 40.0).check_resolvable().is_ok());
        assert!(Aabb::cube(DVec3::new(0.0, 0.0, -4e5 + 19.0), 40.0).check_resolvable().is_err());
        assert!(Aabb::cube(DVec3::ZERO, 1e-6).check_resolvable().is_ok());
        assert!(Aabb { min: DVec3::new(0.0, 0.0, 0.0), max: DVec3::new(1.0, 1e4, 1e4) }.check_resolvable().is_ok());
    }
}
