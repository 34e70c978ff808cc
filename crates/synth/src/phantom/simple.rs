//! Phantoms with closed-form line integrals, to test renderers and projectors against exact
//! answers.
//!
//! All shapes are static (time is ignored), live in world units and evaluate to zero outside
//! their support. [`LineIntegral::line_integral`] gives `∫_{s0}^{s1} E(o + s d) ds` along a
//! [`Ray`] with unit direction; [`analytic_image`] turns that into the exact image a pinhole
//! renderer should produce, with the same sub-pixel lattice as
//! [`fluidnerf_core::render_image`].

use fluidnerf_core::glam::{DVec3, Vec3};
use fluidnerf_core::{Aabb, Camera, CoreError, Image, Ray, ScalarField};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Exact line integrals of a field along ray segments.
pub trait LineIntegral {
    /// `∫_{s0}^{s1} E(ray.origin + s ray.dir) ds` (world units × field units); `ray.dir` has unit
    /// length. Zero when `s1 <= s0`.
    fn line_integral(&self, ray: &Ray, s0: f64, s1: f64) -> f64;
}

/// A ball of constant value: `E = value` for `|p − centre| ≤ radius`, else 0. Its line integral
/// is `value ×` the chord length inside `[s0, s1]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UniformBall {
    pub centre: DVec3,
    pub radius: f64,
    pub value: f64,
}

impl UniformBall {
    fn value_at(&self, p: Vec3) -> f32 {
        let d = p.as_dvec3() - self.centre;
        if d.length_squared() <= self.radius * self.radius {
            self.value as f32
        } else {
            0.0
        }
    }
}

impl LineIntegral for UniformBall {
    fn line_integral(&self, ray: &Ray, s0: f64, s1: f64) -> f64 {
        // |o + s d − c|² = r²  →  s = s_c ± sqrt(r² − d⊥²)
        let oc = ray.origin - self.centre;
        let sc = -oc.dot(ray.dir);
        let perp2 = (oc + sc * ray.dir).length_squared();
        let h2 = self.radius * self.radius - perp2;
        if h2 <= 0.0 {
            return 0.0;
        }
        let h = h2.sqrt();
        let (a, b) = ((sc - h).max(s0), (sc + h).min(s1));
        if b > a {
            self.value * (b - a)
        } else {
            0.0
        }
    }
}

/// An isotropic Gaussian blob `E = amplitude · exp(−|p − centre|² / (2σ²))`. Along a ray,
/// `∫ E ds = amplitude · exp(−d⊥² / 2σ²) · σ √(π/2) · [erf((s1 − s_c)/(σ√2)) − erf((s0 − s_c)/(σ√2))]`
/// with `s_c` the ray parameter closest to the centre and `d⊥` the ray's distance from it.
/// Evaluation cuts the tail at 8σ (relative value below 1e-13).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GaussianBlob {
    pub centre: DVec3,
    pub sigma: f64,
    pub amplitude: f64,
}

impl GaussianBlob {
    fn value_at(&self, p: Vec3) -> f32 {
        let d2 = (p.as_dvec3() - self.centre).length_squared() / (self.sigma * self.sigma);
        if d2 > 64.0 {
            0.0
        } else {
            (self.amplitude * (-0.5 * d2).exp()) as f32
        }
    }
}

impl LineIntegral for GaussianBlob {
    fn line_integral(&self, ray: &Ray, s0: f64, s1: f64) -> f64 {
        if s1 <= s0 {
            return 0.0;
        }
        let oc = ray.origin - self.centre;
        let sc = -oc.dot(ray.dir);
        let perp2 = (oc + sc * ray.dir).length_squared();
        let k = self.sigma * std::f64::consts::SQRT_2;
        let e = libm::erf((s1 - sc) / k) - libm::erf((s0 - sc) / k);
        self.amplitude
            * (-perp2 / (2.0 * self.sigma * self.sigma)).exp()
            * self.sigma
            * (std::f64::consts::PI / 2.0).sqrt()
            * e
    }
}

/// One analytic shape.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "shape", rename_all = "kebab-case")]
pub enum Shape {
    Ball(UniformBall),
    Blob(GaussianBlob),
}

/// A sum of analytic shapes: values and line integrals add.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ShapeSum {
    pub shapes: Vec<Shape>,
}

impl ShapeSum {
    /// A ball of value 1 and radius 30 % of the box's smallest side, at the box centre.
    pub fn ball(aabb: &Aabb) -> Self {
        let radius = 0.3 * aabb.size().min_element();
        ShapeSum { shapes: vec![Shape::Ball(UniformBall { centre: aabb.centre(), radius, value: 1.0 })] }
    }

    /// `count` Gaussian blobs of amplitude in [0.5, 1] and σ in [5 %, 12 %] of the box's
    /// smallest side, centred at random inside the middle 60 % of the box (seeded).
    pub fn blobs(aabb: &Aabb, count: usize, seed: u64) -> Self {
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x626c_6f62);
        let side = aabb.size().min_element();
        let shapes = (0..count)
            .map(|_| {
                let f = DVec3::new(rng.random_range(0.2..0.8), rng.random_range(0.2..0.8), rng.random_range(0.2..0.8));
                Shape::Blob(GaussianBlob {
                    centre: aabb.min + f * aabb.size(),
                    sigma: side * rng.random_range(0.05..0.12),
                    amplitude: rng.random_range(0.5..1.0),
                })
            })
            .collect();
        ShapeSum { shapes }
    }

    /// The ball of [`ShapeSum::ball`] at half value plus the blobs of [`ShapeSum::blobs`].
    pub fn ball_and_blobs(aabb: &Aabb, count: usize, seed: u64) -> Self {
        let mut s = ShapeSum::ball(aabb);
        if let Some(Shape::Ball(b)) = s.shapes.first_mut() {
            b.value = 0.5;
        }
        s.shapes.extend(ShapeSum::blobs(aabb, count, seed).shapes);
        s
    }

    fn value_at(&self, p: Vec3) -> f32 {
        self.shapes
            .iter()
            .map(|s| match s {
                Shape::Ball(b) => b.value_at(p),
                Shape::Blob(b) => b.value_at(p),
            })
            .sum()
    }
}

impl LineIntegral for ShapeSum {
    fn line_integral(&self, ray: &Ray, s0: f64, s1: f64) -> f64 {
        self.shapes
            .iter()
            .map(|s| match s {
                Shape::Ball(b) => b.line_integral(ray, s0, s1),
                Shape::Blob(b) => b.line_integral(ray, s0, s1),
            })
            .sum()
    }
}

macro_rules! scalar_field_from_value_at {
    ($($t:ty),*) => {$(
        impl ScalarField for $t {
            fn eval(&self, points: &[Vec3], _time: f64, out: &mut [f32]) {
                assert_eq!(points.len(), out.len(), "eval: points and out differ in length");
                for (o, &p) in out.iter_mut().zip(points) {
                    *o = self.value_at(p);
                }
            }
        }
    )*};
}
scalar_field_from_value_at!(UniformBall, GaussianBlob, ShapeSum);

/// The exact pinhole image of `shape` inside `aabb`: each pixel is `scale` times the mean, over
/// an `n × n` sub-pixel lattice (`n = supersample`, the lattice of
/// [`fluidnerf_core::render_image`]), of the closed-form line integral over the ray's segment in
/// the box.
pub fn analytic_image(
    shape: &(dyn LineIntegral + Sync),
    camera: &Camera,
    aabb: &Aabb,
    supersample: usize,
    scale: f64,
) -> Result<Image, CoreError> {
    let n = supersample.max(1);
    let (w, h) = (camera.width(), camera.height());
    let mut img = Image::zeros(w, h);
    img.data.par_chunks_mut(w).enumerate().try_for_each(|(row, out)| -> Result<(), CoreError> {
        for (col, o) in out.iter_mut().enumerate() {
            let mut acc = 0.0;
            for sj in 0..n {
                for si in 0..n {
                    let u = col as f64 + (si as f64 + 0.5) / n as f64 - 0.5;
                    let v = row as f64 + (sj as f64 + 0.5) / n as f64 - 0.5;
                    let ray = camera.pixel_ray(u, v)?;
                    if let Some((s0, s1)) = aabb.intersect(&ray) {
                        acc += shape.line_integral(&ray, s0, s1);
                    }
                }
            }
            *o = (acc * scale / (n * n) as f64) as f32;
        }
        Ok(())
    })?;
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn numeric(field: &dyn ScalarField, ray: &Ray, s0: f64, s1: f64) -> f64 {
        let n = 200_000;
        let ds = (s1 - s0) / n as f64;
        let pts: Vec<Vec3> = (0..n).map(|i| ray.at(s0 + (i as f64 + 0.5) * ds).as_vec3()).collect();
        let mut out = vec![0.0; n];
        field.eval(&pts, 0.0, &mut out);
        out.iter().map(|&v| v as f64).sum::<f64>() * ds
    }

    #[test]
    fn closed_forms_match_fine_quadrature() {
        let ball = UniformBall { centre: DVec3::new(0.3, -0.2, 0.1), radius: 1.1, value: 2.0 };
        let blob = GaussianBlob { centre: DVec3::new(-0.2, 0.4, 0.0), sigma: 0.35, amplitude: 1.5 };
        let sum = ShapeSum { shapes: vec![Shape::Ball(ball), Shape::Blob(blob)] };
        for (o, d, s0, s1) in [
            (DVec3::new(-5.0, 0.1, 0.2), DVec3::new(1.0, 0.05, -0.02), 0.0, 10.0),
            (DVec3::new(-5.0, 0.1, 0.2), DVec3::new(1.0, 0.05, -0.02), 4.9, 5.2),
            (DVec3::new(0.0, -4.0, 0.5), DVec3::new(0.1, 1.0, -0.1), 1.0, 8.0),
        ] {
            let ray = Ray::new(o, d);
            assert_relative_eq!(ball.line_integral(&ray, s0, s1), numeric(&ball, &ray, s0, s1), max_relative = 1e-4);
            assert_relative_eq!(blob.line_integral(&ray, s0, s1), numeric(&blob, &ray, s0, s1), max_relative = 1e-6);
            assert_relative_eq!(sum.line_integral(&ray, s0, s1), numeric(&sum, &ray, s0, s1), max_relative = 1e-4);
        }
        // A ray through the centre of the ball sees the diameter.
        let ray = Ray::new(ball.centre - 5.0 * DVec3::X, DVec3::X);
        assert_relative_eq!(ball.line_integral(&ray, 0.0, 20.0), 2.0 * 2.2, epsilon = 1e-12);
        // The Gaussian's full line integral through its centre is A σ √(2π).
        let ray = Ray::new(blob.centre - 10.0 * DVec3::Y, DVec3::Y);
        let full = 1.5 * 0.35 * (2.0 * std::f64::consts::PI).sqrt();
        assert_relative_eq!(blob.line_integral(&ray, 0.0, 20.0), full, max_relative = 1e-12);
    }

    #[test]
    fn blobs_are_seeded() {
        let aabb = Aabb::cube(DVec3::ZERO, 40.0);
        assert_eq!(ShapeSum::blobs(&aabb, 4, 7), ShapeSum::blobs(&aabb, 4, 7));
        assert_ne!(ShapeSum::blobs(&aabb, 4, 7), ShapeSum::blobs(&aabb, 4, 8));
    }
}
