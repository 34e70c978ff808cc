//! The emission imaging model: a pixel records the line integral of the field along its ray
//! through the reconstruction box (dissertation Eq. 5.3 with the pinhole's constant Ω·A, see
//! [`crate::ThinLens::emission_weight`]).
//!
//! [`render_image`] is the reference renderer: exact ray–box clipping, composite trapezoid
//! quadrature with a fixed step, and optional supersampling of each pixel for anti-aliasing.
//! It works for any [`ScalarField`] (analytic phantoms, voxel grids, trained fields). A field
//! that states its [`crate::Support`] gets samples only in its occupied cells (found by a 3D
//! DDA through the support grid), with the same positions and weights as the full chord's, so
//! the image is the same up to summation order. A grid with a support (a [`crate::Baked`]
//! field) is read at the samples inside the occupied cells only, where its source is non-zero.

use crate::num;
use glam::Vec3;
use rayon::prelude::*;

use crate::{Aabb, Camera, CoreError, Image, ScalarField};

/// The most quadrature samples [`render_image`] takes along the box's diagonal: 4096 times
/// the default density (the box's smallest side / 256). It walks every step of every ray, so a
/// step of 1e-300 would otherwise never finish.
pub const MAX_SAMPLES_ON_DIAGONAL: f64 = (1u64 << 20) as f64;

/// The most rays per pixel along each image axis [`render_image`] takes (4096 per pixel).
pub const MAX_SUPERSAMPLE: usize = 64;

/// Settings of [`render_image`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Quadrature step along each ray, in world units. Default: the box's smallest side / 256.
    pub step: Option<f64>,
    /// Rays per pixel along each image axis (`n × n` rays on a regular sub-pixel lattice,
    /// averaged): 1 samples the pixel centre only. Default 1.
    pub supersample: usize,
    /// Time at which the field is evaluated. Default 0.
    pub time: f64,
    /// Factor applied to every pixel (`intensity_scale` of the scene). Default 1.
    pub scale: f64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings { step: None, supersample: 1, time: 0.0, scale: 1.0 }
    }
}

/// Points evaluated per batch: large enough to amortise a network call, small enough to stay
/// in cache for cheap fields.
const BATCH: usize = 16_384;

/// Why a ray-marching `step` does not suit `aabb`: too fine, more than
/// [`MAX_SAMPLES_ON_DIAGONAL`] samples along its diagonal, or too coarse, longer than its
/// thinnest side (rays across it would be integrated from at most one sample each, however far
/// they cross), with the step allowed (`units`, the box's length unit, follows the lengths when
/// not empty). `None` when the step suits the box. A step of a grid's cell is always allowed.
pub fn step_out_of_range(aabb: &Aabb, step: f64, units: &str) -> Option<String> {
    let diagonal = aabb.size().length();
    let thinnest = aabb.size().min_element();
    let units = if units.is_empty() { String::new() } else { format!(" {units}") };
    if diagonal / step > MAX_SAMPLES_ON_DIAGONAL {
        return Some(format!(
            "{step:e} would take more than {MAX_SAMPLES_ON_DIAGONAL} samples along the box's diagonal \
             ({diagonal:.4}{units}); give a step of at least {:.3e}",
            diagonal / MAX_SAMPLES_ON_DIAGONAL
        ));
    }
    (step > thinnest).then(|| {
        format!(
            "{step:e} is longer than the box's thinnest side ({thinnest:.4}{units}): rays across it would be \
             integrated from at most one sample each; give a step of at most {thinnest:.3e}"
        )
    })
}

/// Why the images of `volume` times `scale` would not be finite 32-bit floats: no ray crosses
/// more of the volume than its box's diagonal, so its integral is at most its largest magnitude
/// × the diagonal × `scale`, and beyond the largest float the renderers' sums overflow to
/// infinities and NaN. `None` when every image is finite.
pub fn integrals_overflow(volume: &crate::Volume, scale: f64) -> Option<String> {
    let largest = volume.data.iter().fold(0f32, |m, x| m.max(x.abs()));
    let diagonal = volume.aabb.size().length();
    let bound = f64::from(largest) * diagonal * scale;
    (bound > f64::from(f32::MAX)).then(|| {
        format!(
            "values up to {largest:.3e} over paths up to the box's diagonal ({diagonal:.4}) long, times the \
             intensity scale {}, make line integrals of up to {bound:.3e}, beyond the largest 32-bit float \
             ({:.3e}): the images would hold infinities; scale the volume down",
            num(scale),
            f32::MAX
        )
    })
}

/// Renders `camera`'s image of `field` inside `aabb`: each pixel is `scale` times the mean,
/// over its sub-pixel rays, of `∫ E ds` over the ray's segment in the box.
pub fn render_image(
    field: &dyn ScalarField,
    camera: &Camera,
    aabb: &Aabb,
    settings: &RenderSettings,
) -> Result<Image, CoreError> {
    aabb.validate()?;
    let step = settings.step.unwrap_or(aabb.size().min_element() / 256.0);
    if !(step > 0.0 && step.is_finite()) {
        return Err(CoreError::invalid("render step", format!("must be positive, got {}", num(step))));
    }
    if let Some(problem) = step_out_of_range(aabb, step, "") {
        return Err(CoreError::invalid("render step", problem));
    }
    if settings.supersample > MAX_SUPERSAMPLE {
        return Err(CoreError::invalid(
            "render supersampling",
            format!("rays per pixel along each axis must be at most {MAX_SUPERSAMPLE}, got {}", settings.supersample),
        ));
    }
    let n = settings.supersample.max(1);
    let (w, h) = (camera.width(), camera.height());
    let mut img = Image::zeros(w, h);
    let norm = (settings.scale / (n * n) as f64) as f32;
    let support = field.support().map(crate::Support::walk);
    let sampler = field.as_volume().map(crate::Volume::sampler);
    img.data.par_chunks_mut(w).enumerate().try_for_each(|(row, out_row)| -> Result<(), CoreError> {
        let mut pts: Vec<Vec3> = Vec::with_capacity(BATCH + 4096);
        let mut owner: Vec<u32> = Vec::with_capacity(BATCH + 4096);
        let mut wts: Vec<f32> = Vec::with_capacity(BATCH + 4096);
        let mut vals: Vec<f32> = Vec::with_capacity(BATCH + 4096);
        let mut acc = vec![0f64; w];
        let mut cells: Vec<(f64, f64)> = Vec::new();
        let mut spans: Vec<(usize, usize)> = Vec::new();
        let mut flush = |pts: &mut Vec<Vec3>, owner: &mut Vec<u32>, wts: &mut Vec<f32>, acc: &mut [f64]| {
            vals.resize(pts.len(), 0.0);
            field.eval(pts, settings.time, &mut vals);
            for ((&o, &wt), &v) in owner.iter().zip(wts.iter()).zip(vals.iter()) {
                acc[o as usize] += (wt * v) as f64;
            }
            pts.clear();
            owner.clear();
            wts.clear();
        };
        for col in 0..w {
            for sj in 0..n {
                for si in 0..n {
                    let u = col as f64 + (si as f64 + 0.5) / n as f64 - 0.5;
                    let v = row as f64 + (sj as f64 + 0.5) / n as f64 - 0.5;
                    let ray = camera.pixel_ray(u, v)?;
                    let Some((s0, s1)) = aabb.intersect(&ray) else { continue };
                    let segments = ((s1 - s0) / step).ceil().max(1.0) as usize;
                    let ds = (s1 - s0) / segments as f64;
                    // The samples of the whole chord, or only those in the field's occupied
                    // cells, widened by one sample each side so rounding at a cell face never
                    // drops one the field would count (the field is zero at the others).
                    // A grid with a support reads the intervals themselves (below).
                    spans.clear();
                    match &support {
                        Some(sup) => {
                            cells.clear();
                            sup.occupied_intervals(&ray, s0, s1, &mut cells);
                            if sampler.is_none() {
                                for &(a, b) in &cells {
                                    let lo = ceil_usize((a - s0) / ds).saturating_sub(1);
                                    let hi = (((b - s0) / ds) as usize + 1).min(segments);
                                    match spans.last_mut() {
                                        Some(last) if lo <= last.1 + 1 => last.1 = last.1.max(hi),
                                        _ => spans.push((lo, hi)),
                                    }
                                }
                            }
                        }
                        None => spans.push((0, segments)),
                    }
                    if let Some(vol) = &sampler {
                        // A grid is read in place, sample by sample, without batching.
                        let mut sum = 0.0f32;
                        if support.is_some() {
                            // A grid with a support (a baked field, whose vertices continue the
                            // field past the support's faces) is read at the samples inside
                            // the occupied intervals only: the source is zero at the others.
                            // A sample within rounding of an interval's end (the chord's last,
                            // on the box's face) belongs to it.
                            let mut next = 0;
                            for &(a, b) in &cells {
                                let lo = ceil_usize((a - s0) / ds - 1e-9).max(next);
                                let hi = (((b - s0) / ds + 1e-9) as usize).min(segments);
                                vol.march(&ray, (s0, ds), segments, (lo, hi), &mut sum);
                                next = next.max(hi + 1);
                            }
                        } else {
                            for &(lo, hi) in &spans {
                                vol.march(&ray, (s0, ds), segments, (lo, hi), &mut sum);
                            }
                        }
                        acc[col] += (sum * ds as f32) as f64;
                        continue;
                    }
                    for &(lo, hi) in &spans {
                        for q in lo..=hi {
                            let s = s0 + q as f64 * ds;
                            let wt = if q == 0 || q == segments { 0.5 * ds } else { ds };
                            pts.push(ray.at(s).as_vec3());
                            owner.push(col as u32);
                            wts.push(wt as f32);
                        }
                    }
                    if pts.len() >= BATCH {
                        flush(&mut pts, &mut owner, &mut wts, &mut acc);
                    }
                }
            }
        }
        if !pts.is_empty() {
            flush(&mut pts, &mut owner, &mut wts, &mut acc);
        }
        for (o, a) in out_row.iter_mut().zip(&acc) {
            *o = *a as f32 * norm;
        }
        Ok(())
    })?;
    Ok(img)
}

/// `x.ceil().max(0.0) as usize` without the library call `ceil` is on the x86-64 baseline
/// (once per interval of every ray). The float-to-integer cast saturates, so `x as usize` is
/// already `x.floor().max(0.0) as usize`.
#[inline]
fn ceil_usize(x: f64) -> usize {
    if x > 0.0 {
        let t = x as usize;
        t.saturating_add(usize::from((t as f64) < x))
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Intrinsics, Volume};
    use approx::assert_relative_eq;
    use glam::DVec3;

    fn camera() -> Camera {
        let k = Intrinsics { width: 24, height: 20, fx: 60.0, fy: 60.0, cx: 11.5, cy: 9.5, skew: 0.0 };
        Camera::look_at(k, DVec3::new(0.3, -6.0, 0.2), DVec3::ZERO, DVec3::Z)
    }

    /// The rounding helpers give what the library's `ceil` and `floor` give, at and around
    /// whole numbers, for negative values, NaN and infinity.
    #[test]
    fn ceil_and_floor_without_the_library_agree_with_it() {
        let mut xs = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0, 1e300, -1e300, 2f64.powi(53)];
        for k in -50..50 {
            let w = k as f64 * 0.5;
            xs.extend([w, w + 1e-9, w - 1e-9, w + 0.3, f64::from_bits(w.to_bits() + 1)]);
        }
        for x in xs {
            assert_eq!(ceil_usize(x), x.ceil().max(0.0) as usize, "ceil at {x}");
            assert_eq!(x as usize, x.floor().max(0.0) as usize, "floor at {x}");
        }
    }

    #[test]
    fn constant_field_renders_chord_lengths() {
        let aabb = Aabb::cube(DVec3::ZERO, 2.0);
        let field = |p: Vec3, _t: f64| if p.abs().max_element() <= 1.0 { 1.5f32 } else { 0.0 };
        let cam = camera();
        let img = render_image(&field, &cam, &aabb, &RenderSettings::default()).expect("renders");
        let mut hits = 0;
        for row in 0..cam.height() {
            for col in 0..cam.width() {
                let ray = cam.pixel_ray(col as f64, row as f64).expect("ray");
                let chord = aabb.intersect(&ray).map_or(0.0, |(a, b)| b - a);
                hits += usize::from(chord > 0.0);
                assert_relative_eq!(img.get(col, row) as f64, 1.5 * chord, epsilon = 1e-4, max_relative = 1e-4);
            }
        }
        assert!(hits > 50, "the box must fill part of the image");
    }

    /// Steps and supersampling that would never finish are refused before any ray is walked,
    /// naming the setting; the limits themselves render.
    #[test]
    fn steps_and_supersampling_that_would_never_finish_are_refused() {
        let aabb = Aabb::cube(DVec3::ZERO, 2.0);
        let field = |_p: Vec3, _t: f64| 1.0f32;
        let cam = camera();
        let tiny = RenderSettings { step: Some(1e-300), ..Default::default() };
        let e = render_image(&field, &cam, &aabb, &tiny).expect_err("refused").to_string();
        assert!(e.contains("render step") && e.contains("at least"), "{e}");
        let wide = RenderSettings { supersample: MAX_SUPERSAMPLE + 1, ..Default::default() };
        let e = render_image(&field, &cam, &aabb, &wide).expect_err("refused").to_string();
        assert!(e.contains("render supersampling") && e.contains("at most 64"), "{e}");
        let finest = aabb.size().length() / MAX_SAMPLES_ON_DIAGONAL;
        let small = Camera::look_at(
            Intrinsics { width: 2, height: 2, fx: 4.0, fy: 4.0, cx: 0.5, cy: 0.5, skew: 0.0 },
            DVec3::new(0.0, -6.0, 0.0),
            DVec3::ZERO,
            DVec3::Z,
        );
        let at_limit = RenderSettings { step: Some(finest), ..Default::default() };
        assert!(render_image(&field, &small, &aabb, &at_limit).is_ok());
        let widest = RenderSettings { supersample: MAX_SUPERSAMPLE, step: Some(0.5), ..Default::default() };
        assert!(render_image(&field, &small, &aabb, &widest).is_ok());
        for step in [0.0, -0.1, f64::NAN, f64::INFINITY] {
            let bad = RenderSettings { step: Some(step), ..Default::default() };
            let e = render_image(&field, &small, &aabb, &bad).expect_err("refused").to_string();
            assert!(e.contains("render step") && e.contains("must be positive"), "{step}: {e}");
        }
    }

    /// A step as long as the box's thinnest side is allowed, a longer one is refused with the
    /// side; the default step is 1/256 of that side.
    #[test]
    fn a_step_longer_than_the_thinnest_side_is_refused() {
        let aabb = Aabb::new(DVec3::ZERO, DVec3::new(4.0, 1.0, 2.0));
        assert_eq!(step_out_of_range(&aabb, 1.0, "mm"), None);
        let why = step_out_of_range(&aabb, 1.5, "mm").expect("refused");
        assert!(why.contains("longer than the box's thinnest side (1.0000 mm)"), "{why}");
        // ∫₀¹ 3y² dy = 1 across the thinnest side, to the default step's 1/256 sampling (a
        // single sample there gives 0.75).
        let field = |p: Vec3, _t: f64| 3.0 * p.y * p.y;
        let cam = Camera::look_at(
            Intrinsics { width: 1, height: 1, fx: 4.0, fy: 4.0, cx: 0.0, cy: 0.0, skew: 0.0 },
            DVec3::new(2.0, -6.0, 1.0),
            DVec3::new(2.0, 0.0, 1.0),
            DVec3::Z,
        );
        let img = render_image(&field, &cam, &aabb, &RenderSettings::default()).expect("renders");
        assert!((img.data[0] - 1.0).abs() < 1e-4, "{}", img.data[0]);
    }

    /// Line integrals beyond the largest 32-bit float are foreseen from the volume's largest
    /// magnitude, its box's diagonal and the scale, and those within it are not.
    #[test]
    fn integrals_beyond_f32_are_foreseen() {
        let aabb = Aabb::cube(DVec3::ZERO, 1.0);
        let mut v = Volume::zeros([4, 4, 4], aabb);
        v.data[5] = -1e30;
        // Bound: 1e30 × √3 × scale against 3.4e38.
        assert_eq!(integrals_overflow(&v, 1e8), None);
        let why = integrals_overflow(&v, 1e9).expect("overflows");
        assert!(why.contains("values up to 1.000e30") && why.contains("beyond the largest 32-bit float"), "{why}");
        assert_eq!(integrals_overflow(&Volume::zeros([2, 2, 2], aabb), 1e300), None);
    }

    #[test]
    fn volume_and_closure_agree() {
        let aabb = Aabb::cube(DVec3::ZERO, 2.0);
        let f = |p: DVec3| (-(p.length_squared()) * 2.0).exp() as f32;
        let vol = Volume::from_fn([48, 48, 48], aabb, f);
        let cam = camera();
        let s = RenderSettings { supersample: 2, ..Default::default() };
        let a = render_image(&vol, &cam, &aabb, &s).expect("renders");
        let b = render_image(&|p: Vec3, _t: f64| f(p.as_dvec3()), &cam, &aabb, &s).expect("renders");
        let peak = b.min_max().1;
        for (x, y) in a.data.iter().zip(&b.data) {
            assert!((x - y).abs() < 0.01 * peak, "{x} vs {y}");
        }
    }

    /// A grid read in place renders as the same grid evaluated in batches.
    #[test]
    fn a_volume_read_in_place_matches_batched_evaluation() {
        struct Batched<'a>(&'a Volume);
        impl ScalarField for Batched<'_> {
            fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
                self.0.eval(points, time, out);
            }
        }
        let aabb = Aabb::new(DVec3::new(-1.0, -0.9, -1.1), DVec3::new(1.2, 1.0, 0.8));
        let vol = Volume::from_fn([13, 11, 9], aabb, |p| (1.0 + p.x * p.y - 0.5 * p.z).max(0.0) as f32);
        assert!(vol.as_volume().is_some() && Batched(&vol).as_volume().is_none());
        let s = RenderSettings { supersample: 2, ..Default::default() };
        let a = render_image(&vol, &camera(), &aabb, &s).expect("renders");
        let b = render_image(&Batched(&vol), &camera(), &aabb, &s).expect("renders");
        let peak = b.min_max().1;
        assert!(peak > 1.0);
        for (x, y) in a.data.iter().zip(&b.data) {
            assert!((x - y).abs() <= 1e-5 * peak, "{x} vs {y}");
        }
    }

    /// A field that is zero outside the occupied cells of a grid, with or without telling so.
    struct Masked {
        aabb: Aabb,
        dims: [usize; 3],
        cells: Vec<bool>,
        tell: bool,
    }

    impl Masked {
        fn occupied(&self, p: Vec3) -> bool {
            let u = (p.as_dvec3() - self.aabb.min) / self.aabb.size();
            let mut idx = [0usize; 3];
            for a in 0..3 {
                // Points on the box's faces count as inside despite their rounding to f32, as
                // a trained field's do.
                if !(-1e-6..=1.0 + 1e-6).contains(&u[a]) {
                    return false;
                }
                let u = u[a].clamp(0.0, 1.0);
                idx[a] = ((u * self.dims[a] as f64) as usize).min(self.dims[a] - 1);
            }
            self.cells[(idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0]]
        }
    }

    impl ScalarField for Masked {
        fn eval(&self, points: &[Vec3], _time: f64, out: &mut [f32]) {
            for (o, &p) in out.iter_mut().zip(points) {
                *o = if self.occupied(p) { 1.0 + 0.3 * p.x.sin() + 0.2 * p.y * p.z } else { 0.0 };
            }
        }

        fn support(&self) -> Option<crate::Support<'_>> {
            self.tell.then(|| crate::Support { aabb: self.aabb, dims: self.dims, cells: &self.cells })
        }
    }

    /// An affine field under [`Masked`]'s support: zero in the empty cells, and affine without
    /// the mask, so that a trilinear grid of its unmasked values reads it back exactly.
    struct Affine(Masked);

    impl Affine {
        fn value(p: Vec3) -> f32 {
            1.0 + 0.3 * p.x - 0.2 * p.y + 0.25 * p.z
        }
    }

    impl ScalarField for Affine {
        fn eval(&self, points: &[Vec3], _time: f64, out: &mut [f32]) {
            for (o, &p) in out.iter_mut().zip(points) {
                *o = if self.0.occupied(p) { Affine::value(p) } else { 0.0 };
            }
        }

        fn eval_unmasked(&self, points: &[Vec3], _time: f64, out: &mut [f32]) {
            for (o, &p) in out.iter_mut().zip(points) {
                *o = Affine::value(p);
            }
        }

        fn support(&self) -> Option<crate::Support<'_>> {
            self.0.support()
        }
    }

    /// A baked field renders as its source does, up to rounding, when the source is trilinear
    /// on the bake's cells: the vertices on and past the support's faces hold the field's own
    /// values, not the mask's zeros, and only samples inside the occupied cells are read. The
    /// bake grid is twice the support's cells and, the harder case, unaligned with them. With
    /// masked vertices the cells along the faces read up to half the field's value low.
    #[test]
    fn a_baked_field_renders_like_its_source_up_to_the_supports_faces() {
        let cam = camera();
        let field = Affine(masked(true));
        let s = RenderSettings { supersample: 2, step: Some(0.013), ..Default::default() };
        let exact = render_image(&field, &cam, &field.0.aabb, &s).expect("renders");
        let peak = exact.min_max().1;
        assert!(peak > 0.5);
        for dims in [[14, 10, 12], [9, 8, 11]] {
            let baked = crate::Baked::on_vertices(&field, dims, field.0.aabb, 0.0);
            let img = render_image(&baked, &cam, &field.0.aabb, &s).expect("renders");
            // A sample that falls on a face between an occupied and an empty cell counts on
            // the side its rounding puts it (rays along y through the box's faces, with a
            // multiple of 5 steps, sample every y face): at most one sample per sub-pixel ray,
            // a quarter of 0.013 × 1.45 in a pixel.
            let (mut worst, mut se, mut ss) = (0f32, 0f64, 0f64);
            for (a, b) in img.data.iter().zip(&exact.data) {
                worst = worst.max((a - b).abs());
                se += ((a - b) as f64).powi(2);
                ss += (*b as f64).powi(2);
            }
            let nrmse = (se / ss).sqrt();
            assert!(worst <= 0.006 && nrmse < 1e-3, "bake {dims:?}: largest difference {worst}, NRMSE {nrmse}");
        }
    }

    fn masked(tell: bool) -> Masked {
        let dims = [7, 5, 6];
        // A fixed pseudo-random pattern with about a third of the cells occupied.
        let cells = (0..dims.iter().product::<usize>()).map(|i| (i * 7919 + 13) % 97 < 33).collect();
        Masked { aabb: Aabb::new(DVec3::new(-1.0, -0.8, -0.9), DVec3::new(1.1, 0.9, 1.0)), dims, cells, tell }
    }

    /// [`Masked`], counting the points it is asked for.
    struct Counted(Masked, std::sync::atomic::AtomicUsize);

    impl ScalarField for Counted {
        fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
            self.1.fetch_add(points.len(), std::sync::atomic::Ordering::Relaxed);
            self.0.eval(points, time, out);
        }

        fn support(&self) -> Option<crate::Support<'_>> {
            self.0.support()
        }
    }

    /// Sampling a field with a support on a grid evaluates it only where the support may hold
    /// a value, and gives the grid that evaluating every point gives, bit for bit: on grids
    /// finer and coarser than the support's cells, aligned with them (14 × 10 × 12 cells
    /// against 7 × 5 × 6) or not, at the cell centres and averaged over 2³ and 3³ points, and
    /// on a grid reaching past the field's box.
    #[test]
    fn sampling_a_grid_skips_the_empty_cells_and_gives_the_same_values() {
        let aabb = masked(true).aabb;
        let wider = Aabb::new(aabb.min - DVec3::splat(0.3), aabb.max + DVec3::splat(0.2));
        for (dims, b, n) in [
            ([14, 10, 12], aabb, 1),
            ([23, 17, 19], aabb, 1),
            ([5, 4, 3], aabb, 3),
            ([9, 8, 11], aabb, 2),
            ([20, 18, 16], wider, 1),
        ] {
            let every = Volume::from_field_averaged(dims, b, &masked(false), 0.0, n);
            let field = Counted(masked(true), Default::default());
            let skipped = Volume::from_field_averaged(dims, b, &field, 0.0, n);
            assert_eq!(skipped.data, every.data, "grid {dims:?}, {n}³ points per cell");
            assert!(every.data.iter().any(|&v| v > 0.5), "grid {dims:?}: some cells are occupied");
            // A cell counts where any support cell its points may reach is occupied. On the
            // aligned grid twice as fine as the support's, each centre lies well inside one
            // support cell, so exactly the cells that hold a value are evaluated (about a third).
            let asked = field.1.into_inner();
            let all = dims.iter().product::<usize>() * n * n * n;
            assert!(asked <= all, "grid {dims:?}: {asked} of {all} points evaluated");
            let needed = every.data.iter().filter(|&&v| v != 0.0).count() * n * n * n;
            assert!(asked >= needed, "grid {dims:?}: {asked} points evaluated, {needed} hold a value");
            if dims == [14, 10, 12] {
                assert_eq!(asked, needed, "the aligned grid");
                assert!(asked < all / 2, "the aligned grid: {asked} of {all}");
            }
        }
    }

    /// The DDA's intervals hold exactly the points of the ray in occupied cells (checked on a
    /// fine march, away from cell faces).
    #[test]
    fn support_intervals_match_a_fine_march() {
        let field = masked(true);
        let sup = field.support().expect("support");
        let cam = camera();
        let mut checked = 0;
        for row in 0..cam.height() {
            for col in 0..cam.width() {
                let ray = cam.pixel_ray(col as f64 + 0.37, row as f64 - 0.21).expect("ray");
                let Some((s0, s1)) = field.aabb.intersect(&ray) else { continue };
                let mut iv = Vec::new();
                sup.occupied_intervals(&ray, s0, s1, &mut iv);
                assert!(iv.windows(2).all(|w| w[0].1 < w[1].0), "sorted, disjoint: {iv:?}");
                for q in 0..2000 {
                    let s = s0 + (q as f64 + 0.5) / 2000.0 * (s1 - s0);
                    let inside = iv.iter().any(|&(a, b)| (a..=b).contains(&s));
                    let near_face = iv.iter().any(|&(a, b)| (s - a).abs() < 1e-9 || (s - b).abs() < 1e-9);
                    if !near_face {
                        assert_eq!(inside, field.occupied(ray.at(s).as_vec3()), "pixel ({col}, {row}) at s = {s}");
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 100_000);
    }

    /// The occupied cells' box holds every occupied cell's centre and touches the outermost
    /// ones; no occupied cell, no box.
    #[test]
    fn the_occupied_box_bounds_the_occupied_cells() {
        let mut field = masked(true);
        // Clear the outermost layers along x, so the box is smaller than the grid.
        for (n, c) in field.cells.iter_mut().enumerate() {
            if n % 7 == 0 || n % 7 == 6 {
                *c = false;
            }
        }
        let sup = field.support().expect("support");
        let b = sup.occupied_box().expect("some cells are occupied");
        let h = field.aabb.size() / DVec3::new(7.0, 5.0, 6.0);
        assert!(
            (b.min.x - (field.aabb.min.x + h.x)).abs() < 1e-12 && (b.max.x - (field.aabb.max.x - h.x)).abs() < 1e-12
        );
        for (n, &c) in field.cells.iter().enumerate() {
            if c {
                let centre = field.aabb.min
                    + DVec3::new((n % 7) as f64 + 0.5, ((n / 7) % 5) as f64 + 0.5, (n / 35) as f64 + 0.5) * h;
                assert!(centre.cmpge(b.min).all() && centre.cmple(b.max).all());
            }
        }
        field.cells.iter_mut().for_each(|c| *c = false);
        assert!(field.support().expect("support").occupied_box().is_none());
    }

    /// Rendering with the support skips the empty cells and gives the same image.
    #[test]
    fn rendering_with_a_support_matches_the_full_chord() {
        let cam = camera();
        let s = RenderSettings { supersample: 2, step: Some(0.013), ..Default::default() };
        let (with, without) = (masked(true), masked(false));
        let a = render_image(&with, &cam, &with.aabb, &s).expect("renders");
        let b = render_image(&without, &cam, &without.aabb, &s).expect("renders");
        let peak = b.min_max().1;
        assert!(peak > 0.5);
        for (x, y) in a.data.iter().zip(&b.data) {
            assert!((x - y).abs() <= 1e-5 * peak, "{x} vs {y}");
        }
    }
}
