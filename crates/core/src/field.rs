//! The scalar-field abstraction shared by phantoms, voxel grids and neural fields.

use glam::Vec3;

/// A scalar field E(x, t) in world coordinates, evaluated in batches so that expensive
/// fields (neural networks) can amortise their cost. Implementations must be thread-safe:
/// renderers call `eval` from several threads at once.
pub trait ScalarField: Sync {
    /// Writes E(`points[i]`, `time`) into `out[i]`. `points` and `out` have the same length.
    /// Points outside the field's support evaluate to zero.
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]);
}

impl<F: Fn(Vec3, f64) -> f32 + Sync> ScalarField for F {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "ScalarField::eval: points and out differ in length");
        for (o, &p) in out.iter_mut().zip(points) {
            *o = self(p, time);
        }
    }
}
