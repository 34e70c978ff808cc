//! Rays and sample placement along them (dissertation §5.1.1).
//!
//! # Conventions
//! - Distances `s` along a ray are in world units from the camera centre (the ray origin);
//!   directions are unit vectors, so `s` is the distance the quadrature integrates over.
//! - Positions handed to a field are box-normalised (`Aabb::to_unit`): for a ray cached in
//!   [`ImageRays`], `u(s) = origin_unit + s · dir_unit` with `origin_unit = (o − min) / size`
//!   and `dir_unit = d / size` (component-wise), so no world-space point is ever formed in the
//!   hot loop.
//! - Rays are cached once per image as a structure of arrays of f32 (`dir_unit` per axis,
//!   `near`, `far`, pixel index); only rays that cross the box (and, with empty-space skipping,
//!   an occupied cell) are kept: the others render to exactly zero whatever the field is.
//!
//! # Sampling
//! - **Stratified** (Eq. 5.1): `N_c` equal bins between `s_near` and `s_far`, one uniform
//!   random sample per bin, so the samples come out sorted.
//! - **Hierarchical feature sampling** (§5.1.1): from the coarse values `E_j` (evaluated
//!   without gradients), `|dE/ds|_j ≈ |E_{j+1} − E_j| / (s_{j+1} − s_j)` is taken as a
//!   piecewise-constant PDF over the coarse intervals, so interval `j` receives probability
//!   `∝ |dE/ds|_j (s_{j+1} − s_j) = |E_{j+1} − E_j|`. A uniform floor of
//!   [`PDF_UNIFORM_FLOOR`] of the total mass keeps the PDF proper when the coarse pass is flat
//!   (at initialisation, or in empty space). `N_f` samples are drawn by inverting the CDF at
//!   stratified quantiles `(i + U_i) / N_f` (lower variance than independent uniforms, and
//!   the result is already sorted); they are merged with the coarse samples, and the pixel is
//!   rendered from all `N_c + N_f` sorted samples.

use fluidnerf_core::{Aabb, Camera, CoreError, Image};
use rand::Rng;

use crate::occupancy::OccupancyGrid;

/// Fraction of the fine-sample mass spread uniformly over the coarse span.
pub const PDF_UNIFORM_FLOOR: f32 = 0.01;

/// The cached rays of one image that can see something, as a structure of arrays.
#[derive(Clone, Debug)]
pub struct ImageRays {
    /// Box-normalised camera centre, `(o − min) / size`.
    pub origin_unit: [f32; 3],
    /// Per ray, box-normalised direction components `d / size`.
    pub dir_unit: [Vec<f32>; 3],
    /// Per ray, the change of `dir_unit` across the pixel along its columns and along its rows
    /// (the rays through the middles of its left and right edges, and of its top and bottom
    /// edges): a ray through `(col + a, row + b)`, `|a|, |b| ≤ ½`, has the direction
    /// `dir_unit + a · dir_du + b · dir_dv` to first order (exactly for an undistorted pinhole
    /// before normalisation; the length changes by less than one part in 10⁵ for pixels under
    /// a hundredth of the focal length).
    pub dir_du: [Vec<f32>; 3],
    pub dir_dv: [Vec<f32>; 3],
    /// Per ray, entry distance into the box (or into its first occupied cell), world units.
    pub near: Vec<f32>,
    /// Per ray, exit distance, world units.
    pub far: Vec<f32>,
    /// Per ray, the pixel it belongs to (`row · width + col`).
    pub pixel: Vec<u32>,
    /// Per ray, `ΩA(s) / ΩA(l_o)` is needed only for thin-lens cameras: see
    /// [`crate::render::EmissionModel`].
    pub emission: crate::render::EmissionModel,
    /// Pixels of the image whose ray crosses the box, whether or not they were kept.
    pub pixels_on_box: usize,
}

impl ImageRays {
    /// Casts the ray of every pixel centre of `camera`, clips it to `aabb` and, when given, to
    /// the occupied span of `occupancy` (rays seeing only empty cells are dropped).
    pub fn new(camera: &Camera, aabb: &Aabb, occupancy: Option<&OccupancyGrid>) -> Result<Self, CoreError> {
        let size = aabb.size();
        let o = aabb.to_unit(camera.centre());
        let origin_unit = [o.x as f32, o.y as f32, o.z as f32];
        let (w, h) = (camera.width(), camera.height());
        let mut rays = ImageRays {
            origin_unit,
            dir_unit: [Vec::new(), Vec::new(), Vec::new()],
            dir_du: [Vec::new(), Vec::new(), Vec::new()],
            dir_dv: [Vec::new(), Vec::new(), Vec::new()],
            near: Vec::new(),
            far: Vec::new(),
            pixel: Vec::new(),
            emission: crate::render::EmissionModel::from_camera(camera),
            pixels_on_box: 0,
        };
        for row in 0..h {
            for col in 0..w {
                let ray = camera.pixel_ray(col as f64, row as f64)?;
                let Some((near, far)) = aabb.intersect(&ray) else { continue };
                rays.pixels_on_box += 1;
                let d = ray.dir / size;
                let dir_unit = [d.x as f32, d.y as f32, d.z as f32];
                let (near, far) = match occupancy {
                    Some(grid) => match grid.occupied_span(origin_unit, dir_unit, near as f32, far as f32) {
                        Some(span) => span,
                        None => continue,
                    },
                    None => (near as f32, far as f32),
                };
                let unit =
                    |u: f64, v: f64| -> Result<glam::DVec3, CoreError> { Ok(camera.pixel_ray(u, v)?.dir / size) };
                let (c, r) = (col as f64, row as f64);
                let du = unit(c + 0.5, r)? - unit(c - 0.5, r)?;
                let dv = unit(c, r + 0.5)? - unit(c, r - 0.5)?;
                for a in 0..3 {
                    rays.dir_unit[a].push(dir_unit[a]);
                    rays.dir_du[a].push(du[a] as f32);
                    rays.dir_dv[a].push(dv[a] as f32);
                }
                rays.near.push(near);
                rays.far.push(far);
                rays.pixel.push((row * w + col) as u32);
            }
        }
        Ok(rays)
    }

    pub fn len(&self) -> usize {
        self.near.len()
    }

    pub fn is_empty(&self) -> bool {
        self.near.is_empty()
    }

    /// Box-normalised direction of ray `r` moved by `jitter = (a, b)` pixels from its pixel's
    /// centre (see [`Self::dir_du`]); the ray's own direction without it.
    #[inline]
    pub fn dir_jittered(&self, r: usize, jitter: Option<[f32; 2]>) -> [f32; 3] {
        let d = [self.dir_unit[0][r], self.dir_unit[1][r], self.dir_unit[2][r]];
        match jitter {
            None => d,
            Some([a, b]) => std::array::from_fn(|k| d[k] + a * self.dir_du[k][r] + b * self.dir_dv[k][r]),
        }
    }

    /// Box-normalised position of ray `r` at distance `s`.
    #[inline]
    pub fn point_unit(&self, r: usize, s: f32) -> [f32; 3] {
        [
            self.origin_unit[0] + s * self.dir_unit[0][r],
            self.origin_unit[1] + s * self.dir_unit[1][r],
            self.origin_unit[2] + s * self.dir_unit[2][r],
        ]
    }

    /// The measured values of the kept rays' pixels in `image`, divided by `scale`.
    pub fn targets(&self, image: &Image, scale: f32) -> Vec<f32> {
        self.pixel.iter().map(|&p| image.data[p as usize] / scale).collect()
    }
}

/// Stratified samples (Eq. 5.1): `out.len()` equal bins on `[near, far]`, one uniform sample
/// in each; sorted.
pub fn stratified(near: f32, far: f32, rng: &mut impl Rng, out: &mut [f32]) {
    let n = out.len();
    let step = (far - near) / n as f32;
    for (i, s) in out.iter_mut().enumerate() {
        let u: f32 = rng.random();
        *s = (near + (i as f32 + u) * step).min(far);
    }
}

/// Hierarchical feature sampling: draws `out.len()` sorted samples from the piecewise-constant
/// PDF `∝ |dE/ds|` over the intervals between the sorted coarse samples `s` with values `e`
/// (see the module docs). With fewer than two coarse samples nothing can be inferred and the
/// samples are spread over `[s₀, s₀]`.
pub fn feature_samples(s: &[f32], e: &[f32], rng: &mut impl Rng, out: &mut [f32]) {
    assert_eq!(s.len(), e.len(), "feature_samples: s and e differ in length");
    let n = out.len();
    if n == 0 {
        return;
    }
    if s.len() < 2 {
        out.fill(s.first().copied().unwrap_or(0.0));
        return;
    }
    let span = s[s.len() - 1] - s[0];
    let total: f32 = e.windows(2).map(|w| (w[1] - w[0]).abs()).sum();
    // Mass of interval j: |ΔE_j| + floor density × Δs_j.
    let floor_density =
        if total > 0.0 && span > 0.0 { PDF_UNIFORM_FLOOR / (1.0 - PDF_UNIFORM_FLOOR) * total / span } else { 1.0 };
    let mass = |j: usize| (e[j + 1] - e[j]).abs() + floor_density * (s[j + 1] - s[j]);
    let norm: f32 = (0..s.len() - 1).map(mass).sum();
    if !(norm > 0.0 && norm.is_finite()) {
        // Zero-length span (or a non-finite coarse pass): nowhere better to put them.
        out.fill(s[0]);
        return;
    }
    let mut j = 0usize;
    let mut cdf_lo = 0.0f32;
    let mut m = mass(0) / norm;
    for (i, o) in out.iter_mut().enumerate() {
        let u = ((i as f32 + rng.random::<f32>()) / n as f32).min(1.0);
        while cdf_lo + m < u && j + 2 < s.len() {
            cdf_lo += m;
            j += 1;
            m = mass(j) / norm;
        }
        let t = if m > 0.0 { ((u - cdf_lo) / m).clamp(0.0, 1.0) } else { 0.5 };
        *o = s[j] + t * (s[j + 1] - s[j]);
    }
}

/// Merges two sorted slices into `out` (length `a.len() + b.len()`), sorted.
pub fn merge_sorted(a: &[f32], b: &[f32], out: &mut [f32]) {
    assert_eq!(out.len(), a.len() + b.len(), "merge_sorted: out has the wrong length");
    let (mut i, mut j) = (0, 0);
    for o in out.iter_mut() {
        if j >= b.len() || (i < a.len() && a[i] <= b[j]) {
            *o = a[i];
            i += 1;
        } else {
            *o = b[j];
            j += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::Intrinsics;
    use glam::DVec3;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn stratified_puts_one_sample_per_bin() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut s = [0.0f32; 16];
        stratified(2.0, 6.0, &mut rng, &mut s);
        for (i, &v) in s.iter().enumerate() {
            let lo = 2.0 + i as f32 * 0.25;
            assert!(v >= lo && v <= lo + 0.25, "sample {i} = {v} outside its bin");
        }
    }

    #[test]
    fn feature_samples_follow_the_gradient() {
        // E is a step at s = 3: all the |dE/ds| mass sits in the interval containing it.
        let s: Vec<f32> = (0..11).map(|i| i as f32 * 0.5).collect();
        let e: Vec<f32> = s.iter().map(|&v| if v > 3.1 { 1.0 } else { 0.0 }).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut out = [0.0f32; 200];
        feature_samples(&s, &e, &mut rng, &mut out);
        assert!(out.windows(2).all(|w| w[0] <= w[1]), "fine samples must be sorted");
        let inside = out.iter().filter(|&&v| (3.0..=3.5).contains(&v)).count();
        assert!(inside >= 195, "{inside} of 200 in the step's interval");
        // A flat coarse pass gives uniform samples over the coarse span.
        let flat = vec![0.3f32; 11];
        feature_samples(&s, &flat, &mut rng, &mut out);
        let first_half = out.iter().filter(|&&v| v < 2.5).count();
        assert_eq!(first_half, 100);
    }

    #[test]
    fn merge_keeps_order() {
        let mut out = [0.0; 7];
        merge_sorted(&[0.0, 2.0, 4.0, 9.0], &[1.0, 2.5, 3.0], &mut out);
        assert_eq!(out, [0.0, 1.0, 2.0, 2.5, 3.0, 4.0, 9.0]);
    }

    /// A generator whose every uniform f32 is the same value: `0x8000_0000` gives ½,
    /// `u32::MAX` the largest value below 1.
    struct Constant(u32);

    impl rand::RngCore for Constant {
        fn next_u32(&mut self) -> u32 {
            self.0
        }
        fn next_u64(&mut self) -> u64 {
            (u64::from(self.0) << 32) | u64::from(self.0)
        }
        fn fill_bytes(&mut self, dst: &mut [u8]) {
            dst.fill(self.0 as u8);
        }
    }

    const HALF: u32 = 0x8000_0000;

    #[test]
    fn stratified_samples_at_half_are_the_bin_centres() {
        let mut s = [0.0f32; 4];
        stratified(2.0, 6.0, &mut Constant(HALF), &mut s);
        assert_eq!(s, [2.5, 3.5, 4.5, 5.5]);
        stratified(2.0, 6.0, &mut Constant(u32::MAX), &mut s);
        assert!(s.iter().all(|&v| v <= 6.0) && s[3] > 5.99, "{s:?}");
    }

    /// A step of 2 in the last of two unit intervals: the uniform floor puts 1 % of the mass
    /// over the span, ½ % on the flat interval, and the quantiles `(i + ½) / n` invert the
    /// piecewise-linear CDF by hand.
    #[test]
    fn feature_samples_invert_the_cdf_with_its_uniform_floor() {
        let (s, e) = ([0.0f32, 1.0, 2.0], [0.0f32, 0.0, 2.0]);
        let mut out = [0.0f32; 200];
        feature_samples(&s, &e, &mut Constant(HALF), &mut out);
        // Quantile 0.0025 lies in the first interval's 0.005; the others in the second.
        assert!((out[0] - 0.5).abs() < 1e-5, "{}", out[0]);
        assert!((out[1] - (1.0 + 0.0025 / 0.995)).abs() < 1e-5, "{}", out[1]);
        assert!((out[199] - (1.0 + 0.9925 / 0.995)).abs() < 1e-5, "{}", out[199]);
        assert_eq!(out.iter().filter(|&&v| v < 1.0).count(), 1);
        let mut two = [0.0f32; 2];
        feature_samples(&s, &e, &mut Constant(HALF), &mut two);
        assert!((two[0] - (1.0 + 0.245 / 0.995)).abs() < 1e-5, "{two:?}");
        assert!((two[1] - (1.0 + 0.745 / 0.995)).abs() < 1e-5, "{two:?}");
    }

    /// Draws at the top of the unit interval still land inside the coarse span, in order, the
    /// last at its end.
    #[test]
    fn feature_samples_stay_inside_the_coarse_span() {
        let s: Vec<f32> = (0..9).map(|i| 1.0 + 0.3 * i as f32).collect();
        let e: Vec<f32> = s.iter().map(|&v| (3.0 * v).sin()).collect();
        for draw in [0, HALF, u32::MAX] {
            let mut out = [0.0f32; 200];
            feature_samples(&s, &e, &mut Constant(draw), &mut out);
            assert!(out.iter().all(|&v| (s[0]..=s[8]).contains(&v)), "{out:?}");
            assert!(out.windows(2).all(|w| w[0] <= w[1]), "{out:?}");
        }
        let mut out = [0.0f32; 200];
        feature_samples(&s, &e, &mut Constant(u32::MAX), &mut out);
        assert!(out[199] > s[8] - 0.01, "{}", out[199]);
    }

    /// With fewer than two coarse samples, all fine samples sit on the one there is (0 with
    /// none); two samples of equal value spread them uniformly over their interval; a coarse
    /// pass with a non-finite value puts them at the first coarse sample.
    #[test]
    fn feature_samples_of_degenerate_coarse_passes() {
        let mut out = [9.0f32; 4];
        feature_samples(&[], &[], &mut Constant(HALF), &mut out);
        assert_eq!(out, [0.0; 4]);
        feature_samples(&[3.0], &[1.0], &mut Constant(HALF), &mut out);
        assert_eq!(out, [3.0; 4]);
        feature_samples(&[1.0, 3.0], &[0.5, 0.5], &mut Constant(HALF), &mut out);
        assert_eq!(out, [1.25, 1.75, 2.25, 2.75]);
        for bad in [f32::NAN, f32::INFINITY] {
            feature_samples(&[1.0, 2.0, 3.0], &[0.0, bad, 1.0], &mut Constant(HALF), &mut out);
            assert_eq!(out, [1.0; 4], "{bad}");
        }
        let mut none: [f32; 0] = [];
        feature_samples(&[1.0, 2.0], &[0.0, 1.0], &mut Constant(HALF), &mut none);
    }

    #[test]
    fn merge_takes_the_rest_of_either_slice() {
        let mut out = [0.0; 4];
        merge_sorted(&[1.0], &[0.0, 2.0, 3.0], &mut out);
        assert_eq!(out, [0.0, 1.0, 2.0, 3.0]);
        merge_sorted(&[0.0, 2.0, 3.0], &[1.0], &mut out);
        assert_eq!(out, [0.0, 1.0, 2.0, 3.0]);
        merge_sorted(&[], &[0.0, 1.0, 2.0, 3.0], &mut out);
        assert_eq!(out, [0.0, 1.0, 2.0, 3.0]);
    }

    fn narrow_camera() -> Camera {
        // A pixel of 1/200 of the focal length: the first-order jitter is exact to ~1e-5.
        let k = Intrinsics { width: 9, height: 7, fx: 200.0, fy: 200.0, cx: 4.0, cy: 3.0, skew: 0.0 };
        Camera::look_at(k, DVec3::new(0.5, -5.0, 0.3), DVec3::ZERO, DVec3::Z)
    }

    /// A ray moved by a fraction of a pixel along its columns or rows is the ray through that
    /// point of the pixel.
    #[test]
    fn jittered_directions_are_the_rays_through_the_moved_points() {
        let cam = narrow_camera();
        let aabb = Aabb::new(DVec3::new(-1.0, -1.5, -1.0), DVec3::new(1.0, 1.5, 2.0));
        let rays = ImageRays::new(&cam, &aabb, None).expect("rays");
        assert_eq!(rays.len(), 63);
        for r in [0, 31, 62] {
            let p = rays.pixel[r] as usize;
            let (col, row) = ((p % 9) as f64, (p / 9) as f64);
            assert_eq!(rays.dir_jittered(r, None), std::array::from_fn(|a| rays.dir_unit[a][r]));
            for (a, b) in [(0.5f32, 0.0f32), (0.0, -0.5), (-0.3, 0.4)] {
                let d = cam.pixel_ray(col + a as f64, row + b as f64).expect("ray").dir / aabb.size();
                let got = rays.dir_jittered(r, Some([a, b]));
                for k in 0..3 {
                    assert!((got[k] as f64 - d[k]).abs() < 2e-5, "ray {r} ({a}, {b}): {got:?} vs {d}");
                }
            }
        }
    }

    /// Targets are the kept rays' pixels divided by the scale; a camera looking away from the
    /// box keeps no ray.
    #[test]
    fn targets_follow_the_kept_pixels_and_a_camera_looking_away_keeps_none() {
        let cam = narrow_camera();
        let aabb = Aabb::cube(DVec3::ZERO, 0.1);
        let rays = ImageRays::new(&cam, &aabb, None).expect("rays");
        assert!(!rays.is_empty() && rays.len() < 63, "{} rays", rays.len());
        let mut image = Image::zeros(9, 7);
        image.data.iter_mut().enumerate().for_each(|(i, v)| *v = i as f32);
        let targets = rays.targets(&image, 4.0);
        assert_eq!(targets.len(), rays.len());
        for (t, &p) in targets.iter().zip(&rays.pixel) {
            assert_eq!(*t, p as f32 / 4.0);
        }
        let k = Intrinsics { width: 9, height: 7, fx: 200.0, fy: 200.0, cx: 4.0, cy: 3.0, skew: 0.0 };
        let away = Camera::look_at(k, DVec3::new(0.0, -5.0, 0.0), DVec3::new(0.0, -10.0, 0.0), DVec3::Z);
        let none = ImageRays::new(&away, &aabb, None).expect("rays");
        assert!(none.is_empty() && none.pixel.is_empty() && none.pixels_on_box == 0);
    }

    /// With an occupancy grid, rays that see only empty cells are dropped though they cross the
    /// box, and the kept ones are clipped to a part of their stretch through the box.
    #[test]
    fn occupancy_drops_rays_of_empty_cells_and_clips_the_others() {
        let k = Intrinsics { width: 9, height: 7, fx: 20.0, fy: 20.0, cx: 4.0, cy: 3.0, skew: 0.0 };
        let cam = Camera::look_at(k, DVec3::new(0.5, -5.0, 0.3), DVec3::ZERO, DVec3::Z);
        let aabb = Aabb::new(DVec3::new(-1.0, -1.5, -1.0), DVec3::new(1.0, 1.5, 2.0));
        let all = ImageRays::new(&cam, &aabb, None).expect("rays");
        let mut cells = vec![false; 8 * 8 * 8];
        // The cell holding the point the camera looks at.
        cells[(2 * 8 + 4) * 8 + 4] = true;
        let grid = OccupancyGrid::from_cells([8, 8, 8], cells).expect("grid");
        let some = ImageRays::new(&cam, &aabb, Some(&grid)).expect("rays");
        assert_eq!(some.pixels_on_box, all.pixels_on_box);
        assert!(!some.is_empty() && some.len() < all.len(), "{} of {}", some.len(), all.len());
        for r in 0..some.len() {
            let q = all.pixel.iter().position(|&p| p == some.pixel[r]).expect("a ray of the box");
            assert!(some.near[r] >= all.near[q] && some.far[r] <= all.far[q] && some.near[r] < some.far[r]);
            assert!(some.far[r] - some.near[r] < 0.5 * (all.far[q] - all.near[q]), "ray {r} not clipped");
            let mid = some.point_unit(r, 0.5 * (some.near[r] + some.far[r]));
            assert!(grid.is_occupied(mid), "ray {r} passes the middle of its span at {mid:?}");
        }
    }

    #[test]
    fn cached_rays_match_world_rays() {
        let k = Intrinsics { width: 9, height: 7, fx: 20.0, fy: 20.0, cx: 4.0, cy: 3.0, skew: 0.0 };
        let cam = Camera::look_at(k, DVec3::new(0.5, -5.0, 0.3), DVec3::ZERO, DVec3::Z);
        let aabb = Aabb::new(DVec3::new(-1.0, -1.5, -1.0), DVec3::new(1.0, 1.5, 2.0));
        let rays = ImageRays::new(&cam, &aabb, None).expect("rays");
        assert_eq!(rays.len(), rays.pixels_on_box);
        assert!(rays.len() > 20);
        for r in 0..rays.len() {
            let p = rays.pixel[r] as usize;
            let ray = cam.pixel_ray((p % 9) as f64, (p / 9) as f64).expect("ray");
            let s = 0.5 * (rays.near[r] + rays.far[r]);
            let expect = aabb.to_unit(ray.at(s as f64));
            let got = rays.point_unit(r, s);
            for a in 0..3 {
                assert!((got[a] as f64 - expect[a]).abs() < 1e-5);
            }
        }
    }
}
