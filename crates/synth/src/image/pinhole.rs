//! Ideal pinhole images: the line integral of the emission field along each pixel's ray through
//! the box (dissertation Eq. 5.3 with the pinhole's constant Ω·A), averaged over an `n × n`
//! sub-pixel lattice for anti-aliasing.
//!
//! [`render_volume`] is a specialised path for voxel grids: it marches each ray in grid
//! coordinates with a fixed step (default half the smallest voxel side) and the composite
//! trapezoid rule (Eq. 5.4) on the trilinear interpolant, with the sub-pixel lattice and the
//! boundary rule of [`fluidnerf_core::render_image`] and [`Volume::sample`]; it is tested
//! against them. [`render_field`] renders any field (analytic phantoms) with the reference
//! renderer itself.

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::{render_image, Aabb, Camera, CoreError, Image, RenderSettings, ScalarField, Volume};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::SynthError;

/// Settings of the pinhole image model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PinholeSettings {
    /// Rays per pixel along each image axis (`n × n` rays per pixel). Default 2.
    pub supersample: usize,
    /// Quadrature step as a fraction of the smallest voxel side, 0.01 to 2. Default 0.5.
    pub step_fraction: f64,
    /// Render the continuous phantom with the reference renderer instead of its voxel grid
    /// (exact but slow for the jets). Default false.
    pub analytic: bool,
}

impl Default for PinholeSettings {
    fn default() -> Self {
        PinholeSettings { supersample: 2, step_fraction: 0.5, analytic: false }
    }
}

impl PinholeSettings {
    pub fn validate(&self) -> Result<(), SynthError> {
        if self.supersample == 0 || self.supersample > 16 {
            return Err(SynthError::invalid(
                "image.supersample",
                format!("must be in 1..=16, got {}", self.supersample),
            ));
        }
        // As the projectors' ray step: a vanishing step takes steps without end.
        if !(0.01..=2.0).contains(&self.step_fraction) {
            return Err(SynthError::invalid(
                "image.step_fraction",
                format!("must be in [0.01, 2], got {}", fluidnerf_core::num(self.step_fraction)),
            ));
        }
        Ok(())
    }
}

/// Trilinear value at continuous grid coordinates `g` (voxel centres at integers), clamped to
/// the outermost centres like [`Volume::sample`].
#[inline(always)]
fn trilinear(data: &[f32], n: [usize; 3], g: Vec3) -> f32 {
    let cx = g.x.clamp(0.0, (n[0] - 1) as f32);
    let cy = g.y.clamp(0.0, (n[1] - 1) as f32);
    let cz = g.z.clamp(0.0, (n[2] - 1) as f32);
    // The coordinates are clamped non-negative, so truncation is the floor (and, unlike
    // `f32::floor`, needs no library call on baseline x86-64).
    let (i, j, k) = (cx as usize, cy as usize, cz as usize);
    let (wx, wy, wz) = (cx - i as f32, cy - j as f32, cz - k as f32);
    let di = usize::from(i + 1 < n[0]);
    let dj = if j + 1 < n[1] { n[0] } else { 0 };
    let dk = if k + 1 < n[2] { n[0] * n[1] } else { 0 };
    let base = (k * n[1] + j) * n[0] + i;
    let at = |o: usize| data[base + o];
    let c00 = at(0) + wx * (at(di) - at(0));
    let c10 = at(dj) + wx * (at(dj + di) - at(dj));
    let c01 = at(dk) + wx * (at(dk + di) - at(dk));
    let c11 = at(dk + dj) + wx * (at(dk + dj + di) - at(dk + dj));
    let c0 = c00 + wy * (c10 - c00);
    let c1 = c01 + wy * (c11 - c01);
    c0 + wz * (c1 - c0)
}

/// The box (inside `volume.aabb`) outside which the trilinear interpolant of `volume` is zero,
/// or `None` if the volume is all zero.
pub fn support_box(volume: &Volume) -> Option<Aabb> {
    let [nx, ny, _] = volume.dims;
    let mut lo = [usize::MAX; 3];
    let mut hi = [0usize; 3];
    for (idx, &v) in volume.data.iter().enumerate() {
        if v != 0.0 {
            let ijk = [idx % nx, (idx / nx) % ny, idx / (nx * ny)];
            for a in 0..3 {
                lo[a] = lo[a].min(ijk[a]);
                hi[a] = hi[a].max(ijk[a]);
            }
        }
    }
    if lo[0] == usize::MAX {
        return None;
    }
    let sp = volume.spacing();
    let (min, max) = (volume.aabb.min, volume.aabb.max);
    let lo_w = fluidnerf_core::glam::DVec3::new(lo[0] as f64 - 0.5, lo[1] as f64 - 0.5, lo[2] as f64 - 0.5) * sp + min;
    let hi_w = fluidnerf_core::glam::DVec3::new(hi[0] as f64 + 1.5, hi[1] as f64 + 1.5, hi[2] as f64 + 1.5) * sp + min;
    Some(Aabb::new(lo_w.max(min), hi_w.min(max)))
}

/// The pinhole image of a voxel grid (see the module docs), `scale × ∫E ds` per pixel.
pub fn render_volume(
    volume: &Volume,
    camera: &Camera,
    settings: &PinholeSettings,
    scale: f64,
) -> Result<Image, SynthError> {
    render_volume_counting(volume, camera, settings, scale).map(|(img, _)| img)
}

/// [`render_volume`], also returning the number of sub-pixel rays traced (those crossing the
/// support of the field).
pub fn render_volume_counting(
    volume: &Volume,
    camera: &Camera,
    settings: &PinholeSettings,
    scale: f64,
) -> Result<(Image, u64), SynthError> {
    settings.validate()?;
    let aabb = volume.aabb;
    aabb.validate()?;
    let spacing = volume.spacing();
    let step = settings.step_fraction * spacing.min_element();
    let n = settings.supersample;
    let (w, h) = (camera.width(), camera.height());
    let dims = volume.dims;
    let data = &volume.data[..];
    let inv_sp = spacing.recip();
    // Rays are clipped to the box around the non-zero voxels (grown by one voxel, the reach of
    // the trilinear interpolant): the integrand is exactly zero elsewhere.
    let Some(support) = support_box(volume) else {
        return Ok((Image::zeros(w, h), 0));
    };
    let mut img = Image::zeros(w, h);
    let norm = scale / (n * n) as f64;
    let rays = img
        .data
        .par_chunks_mut(w)
        .enumerate()
        .map(|(row, out)| -> Result<u64, CoreError> {
            let mut rays = 0u64;
            for (col, o) in out.iter_mut().enumerate() {
                let mut acc = 0.0f64;
                for sj in 0..n {
                    for si in 0..n {
                        let u = col as f64 + (si as f64 + 0.5) / n as f64 - 0.5;
                        let v = row as f64 + (sj as f64 + 0.5) / n as f64 - 0.5;
                        let ray = camera.pixel_ray(u, v)?;
                        let Some((s0, s1)) = support.intersect(&ray) else { continue };
                        rays += 1;
                        let segments = ((s1 - s0) / step).ceil().max(1.0) as usize;
                        let ds = (s1 - s0) / segments as f64;
                        let g0 = ((ray.at(s0) - aabb.min) * inv_sp - 0.5).as_vec3();
                        let dg = (ray.dir * ds * inv_sp).as_vec3();
                        let mut sum =
                            0.5 * (trilinear(data, dims, g0) + trilinear(data, dims, g0 + dg * segments as f32));
                        for q in 1..segments {
                            sum += trilinear(data, dims, g0 + dg * q as f32);
                        }
                        acc += sum as f64 * ds;
                    }
                }
                *o = (acc * norm) as f32;
            }
            Ok(rays)
        })
        .try_reduce(|| 0, |a, b| Ok(a + b))?;
    Ok((img, rays))
}

/// The pinhole image of any field with the reference renderer
/// ([`fluidnerf_core::render_image`]), quadrature step `step` (world units).
pub fn render_field(
    field: &dyn ScalarField,
    camera: &Camera,
    aabb: &Aabb,
    supersample: usize,
    step: f64,
    time: f64,
    scale: f64,
) -> Result<Image, SynthError> {
    let settings = RenderSettings { step: Some(step), supersample, time, scale };
    Ok(render_image(field, camera, aabb, &settings)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::{analytic_image, GaussianBlob, ShapeSum, UniformBall};
    use crate::rig::{Layout, LensSettings, RigSettings, RingAxis};
    use fluidnerf_core::glam::DVec3;

    fn cameras(px: u32) -> Vec<Camera> {
        let rig = RigSettings {
            layout: Layout::Ring { count: 5, arc_deg: 360.0, start_deg: 7.0, axis: RingAxis::X },
            ..Default::default()
        };
        let lens = LensSettings { resolution: [px, px], ..Default::default() };
        rig.build(&lens, &Aabb::cube(DVec3::ZERO, 40.0), 0).expect("rig").into_iter().map(|c| c.camera).collect()
    }

    #[test]
    fn reference_renderer_matches_closed_forms() {
        let aabb = Aabb::cube(DVec3::ZERO, 40.0);
        let ball = ShapeSum {
            shapes: vec![crate::phantom::Shape::Ball(UniformBall {
                centre: DVec3::new(2.0, -1.0, 3.0),
                radius: 11.0,
                value: 1.0,
            })],
        };
        let blob = ShapeSum {
            shapes: vec![crate::phantom::Shape::Blob(GaussianBlob {
                centre: DVec3::new(-3.0, 2.0, 1.0),
                sigma: 4.0,
                amplitude: 1.0,
            })],
        };
        for cam in cameras(48).iter().take(3) {
            // Gaussian: smooth, so the quadrature is accurate to far better than 0.1 %.
            let exact = analytic_image(&blob, cam, &aabb, 2, 1.0).expect("exact");
            let img = render_field(&blob, cam, &aabb, 2, 0.1, 0.0, 1.0).expect("renders");
            let peak = exact.min_max().1;
            for (a, e) in img.data.iter().zip(&exact.data) {
                if *e > 1e-3 * peak {
                    assert!((a - e).abs() <= 1e-3 * e, "blob: {a} vs exact {e}");
                }
            }
            // Ball: within 0.5 % wherever the chord is at least a tenth of the diameter, and
            // within 0.5 % of the peak everywhere (the edge is a discontinuity).
            let exact = analytic_image(&ball, cam, &aabb, 2, 1.0).expect("exact");
            let img = render_field(&ball, cam, &aabb, 2, 0.02, 0.0, 1.0).expect("renders");
            let peak = exact.min_max().1;
            for (a, e) in img.data.iter().zip(&exact.data) {
                assert!((a - e).abs() <= 5e-3 * peak, "ball: {a} vs exact {e}");
                if *e > 2.2 {
                    assert!((a - e).abs() <= 5e-3 * e, "ball: {a} vs exact {e}");
                }
            }
        }
    }

    #[test]
    fn voxel_path_matches_reference_renderer() {
        let aabb = Aabb::cube(DVec3::ZERO, 40.0);
        let field = ShapeSum::ball_and_blobs(&aabb, 4, 3);
        let vol = Volume::from_field([24, 20, 28], aabb, &field, 0.0);
        let settings = PinholeSettings { supersample: 2, step_fraction: 0.5, analytic: false };
        let step = 0.5 * vol.spacing().min_element();
        for cam in cameras(40).iter().take(2) {
            let fast = render_volume(&vol, cam, &settings, 1.0).expect("fast");
            let reference = render_field(&vol, cam, &aabb, 2, step, 0.0, 1.0).expect("reference");
            let peak = reference.min_max().1;
            assert!(peak > 1.0);
            for (a, b) in fast.data.iter().zip(&reference.data) {
                assert!((a - b).abs() <= 2e-4 * peak, "fast {a} vs reference {b}");
            }
        }
    }

    #[test]
    fn voxelised_blob_converges_to_closed_form() {
        let aabb = Aabb::cube(DVec3::ZERO, 40.0);
        let blob = ShapeSum {
            shapes: vec![crate::phantom::Shape::Blob(GaussianBlob {
                centre: DVec3::new(1.0, -2.0, 0.5),
                sigma: 5.0,
                amplitude: 1.0,
            })],
        };
        let vol = Volume::from_field([64, 64, 64], aabb, &blob, 0.0);
        let cam = &cameras(32)[1];
        let img = render_volume(&vol, cam, &PinholeSettings::default(), 1.0).expect("renders");
        let exact = analytic_image(&blob, cam, &aabb, 2, 1.0).expect("exact");
        let peak = exact.min_max().1;
        for (a, e) in img.data.iter().zip(&exact.data) {
            assert!((a - e).abs() <= 5e-3 * peak, "{a} vs exact {e}");
        }
    }
}
