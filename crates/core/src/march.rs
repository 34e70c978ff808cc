//! Marching a ray through a volume: the quadrature sums of [`crate::render_image`] over a
//! grid read in place, several samples per instruction where the CPU has AVX2 or AVX-512.
//!
//! Every sample is [`Sampler::sample`] of the point `ray.at(s0 + q·ds)`, computed with the same
//! operations in the same order (no fused multiply–adds, the same clamps and truncations), and
//! the weighted samples are added to the sum one after another in `q`'s order, so the sum is
//! the scalar loop's bit for bit whatever the instruction set (tested).

use crate::geometry::Ray;
use crate::volume::Sampler;
use crate::Isa;

/// Lanes of the widest kernel: the buffer of one block of samples.
const MAX_LANES: usize = 16;

impl Sampler<'_> {
    /// The same sampler with [`Sampler::march`] in scalar code: the reference its vector
    /// kernels are checked and timed against (`cargo bench -p fluidnerf-core --bench march`).
    pub fn scalar(self) -> Self {
        Sampler { isa: Isa::Baseline, ..self }
    }

    /// Adds `wt(q) · self.sample(ray.at(s0 + q·ds))` to `sum` for `q` in `lo..=hi`, in that
    /// order, where `wt(q)` is ½ at `q = 0` and `q = segments` (the trapezoid rule's ends) and
    /// 1 elsewhere. Nothing is added when `lo > hi`.
    pub fn march(&self, ray: &Ray, (s0, ds): (f64, f64), segments: usize, (lo, hi): (usize, usize), sum: &mut f32) {
        if lo > hi {
            return;
        }
        let weight = |q: usize| if q == 0 || q == segments { 0.5f32 } else { 1.0 };
        let lanes = match self.isa {
            _ if !cfg!(target_arch = "x86_64") => 0,
            Isa::Baseline => 0,
            Isa::Avx2 => 8,
            Isa::Avx512 => 16,
        };
        // Vertex indices are 32-bit in the gathers; sample numbers stay exact in f64.
        if lanes == 0 || self.data.len() > i32::MAX as usize || hi >= 1 << 52 {
            for q in lo..=hi {
                *sum += weight(q) * self.sample(ray.at(s0 + q as f64 * ds).as_vec3());
            }
            return;
        }
        let mut values = [0f32; MAX_LANES];
        let mut q = lo;
        while q <= hi {
            // SAFETY: `lanes` is non-zero only for an instruction set `Isa::detected` found
            // on this CPU (the sampler's `isa`), and the data's length fits the
            // gathers' 32-bit indices (checked above).
            unsafe {
                #[cfg(target_arch = "x86_64")]
                match self.isa {
                    Isa::Avx512 => x86::block16(self, ray, s0, ds, q, &mut values),
                    Isa::Avx2 => x86::block8(self, ray, s0, ds, q, &mut values),
                    Isa::Baseline => unreachable!("no lanes"),
                }
            }
            // Samples past `hi` in the last block were computed (at clamped vertices) and are
            // not added.
            let n = lanes.min(hi - q + 1);
            for (k, &v) in values[..n].iter().enumerate() {
                *sum += weight(q + k) * v;
            }
            q += n;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::*;
    use std::arch::x86_64::*;

    /// [`Sampler::sample`] of the sixteen points `ray.at(s0 + (q + l)·ds)`, `l = 0..16`, into
    /// `out`.
    ///
    /// # Safety
    /// AVX-512F must be available, and `s.data.len() ≤ i32::MAX`.
    #[target_feature(enable = "avx512f,avx2")]
    pub(super) unsafe fn block16(s: &Sampler, ray: &Ray, s0: f64, ds: f64, q: usize, out: &mut [f32; MAX_LANES]) {
        let [nx, ny, nz] = s.n.map(|n| n as i32);
        // The sample distances in f64, eight per vector: `s0 + q·ds` as the scalar loop
        // computes it (`q as f64` is exact, and so is adding 0..15 to it below 2⁵²).
        let q0 = _mm512_set1_pd(q as f64);
        let lo = _mm512_add_pd(q0, _mm512_setr_pd(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0));
        let hi = _mm512_add_pd(q0, _mm512_setr_pd(8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0));
        let dist = |qs: __m512d| _mm512_add_pd(_mm512_set1_pd(s0), _mm512_mul_pd(qs, _mm512_set1_pd(ds)));
        let (d_lo, d_hi) = (dist(lo), dist(hi));
        // One coordinate of the points, `origin + s·dir` in f64 and rounded to f32.
        let coord = |o: f64, d: f64| {
            let at =
                |s: __m512d| _mm512_cvtpd_ps(_mm512_add_pd(_mm512_set1_pd(o), _mm512_mul_pd(s, _mm512_set1_pd(d))));
            let (a, b) = (at(d_lo), at(d_hi));
            _mm512_castpd_ps(_mm512_insertf64x4::<1>(_mm512_castps_pd(_mm512_castps256_ps512(a)), _mm256_castps_pd(b)))
        };
        let p = [coord(ray.origin.x, ray.dir.x), coord(ray.origin.y, ray.dir.y), coord(ray.origin.z, ray.dir.z)];
        let (min, max, scale, top) = (s.min.to_array(), s.max.to_array(), s.scale.to_array(), s.top.to_array());
        let zero = _mm512_setzero_ps();
        let mut inside: __mmask16 = 0xFFFF;
        let mut cell = [_mm512_setzero_si512(); 3];
        let mut w = [zero; 3];
        for a in 0..3 {
            let (lo, hi) = (_mm512_set1_ps(min[a]), _mm512_set1_ps(max[a]));
            // Outside the box, or NaN: ordered comparisons are false.
            inside &= _mm512_cmp_ps_mask::<_CMP_GE_OQ>(p[a], lo) & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(p[a], hi);
            let g =
                _mm512_sub_ps(_mm512_mul_ps(_mm512_sub_ps(p[a], lo), _mm512_set1_ps(scale[a])), _mm512_set1_ps(0.5));
            // glam's `max` then `min`: the second operand unless the first is greater (less),
            // as these instructions do, NaN included.
            let g = _mm512_min_ps(_mm512_max_ps(g, zero), _mm512_set1_ps(top[a]));
            cell[a] = _mm512_cvttps_epi32(g);
            w[a] = _mm512_sub_ps(g, _mm512_cvtepi32_ps(cell[a]));
        }
        // The neighbour's offset along each axis, 0 at the last cell.
        let step = |c: __m512i, n: i32, stride: i32| {
            let more = _mm512_cmplt_epi32_mask(c, _mm512_set1_epi32(n - 1));
            _mm512_maskz_mov_epi32(more, _mm512_set1_epi32(stride))
        };
        let (dx, dy, dz) = (step(cell[0], nx, 1), step(cell[1], ny, nx), step(cell[2], nz, nx * ny));
        let at = _mm512_add_epi32(
            _mm512_mullo_epi32(
                _mm512_add_epi32(_mm512_mullo_epi32(cell[2], _mm512_set1_epi32(ny)), cell[1]),
                _mm512_set1_epi32(nx),
            ),
            cell[0],
        );
        let data = s.data.as_ptr();
        // SAFETY: every index is a vertex of the grid (the cells are clamped to it), below
        // `data.len() ≤ i32::MAX`.
        let read = |i: __m512i| unsafe { _mm512_i32gather_ps::<4>(i, data) };
        let lerp = |a: __m512, b: __m512, t: __m512| {
            _mm512_add_ps(_mm512_mul_ps(a, _mm512_sub_ps(_mm512_set1_ps(1.0), t)), _mm512_mul_ps(b, t))
        };
        let (a_y, a_z) = (_mm512_add_epi32(at, dy), _mm512_add_epi32(at, dz));
        let a_zy = _mm512_add_epi32(a_z, dy);
        let c00 = lerp(read(at), read(_mm512_add_epi32(at, dx)), w[0]);
        let c10 = lerp(read(a_y), read(_mm512_add_epi32(a_y, dx)), w[0]);
        let c01 = lerp(read(a_z), read(_mm512_add_epi32(a_z, dx)), w[0]);
        let c11 = lerp(read(a_zy), read(_mm512_add_epi32(a_zy, dx)), w[0]);
        let v = lerp(lerp(c00, c10, w[1]), lerp(c01, c11, w[1]), w[2]);
        // SAFETY: `out` holds sixteen floats.
        unsafe { _mm512_storeu_ps(out.as_mut_ptr(), _mm512_maskz_mov_ps(inside, v)) };
    }

    /// [`block16`] for eight points with AVX2, into `out[..8]`.
    ///
    /// # Safety
    /// AVX2 must be available, and `s.data.len() ≤ i32::MAX`.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn block8(s: &Sampler, ray: &Ray, s0: f64, ds: f64, q: usize, out: &mut [f32; MAX_LANES]) {
        let [nx, ny, nz] = s.n.map(|n| n as i32);
        let q0 = _mm256_set1_pd(q as f64);
        let lo = _mm256_add_pd(q0, _mm256_setr_pd(0.0, 1.0, 2.0, 3.0));
        let hi = _mm256_add_pd(q0, _mm256_setr_pd(4.0, 5.0, 6.0, 7.0));
        let dist = |qs: __m256d| _mm256_add_pd(_mm256_set1_pd(s0), _mm256_mul_pd(qs, _mm256_set1_pd(ds)));
        let (d_lo, d_hi) = (dist(lo), dist(hi));
        let coord = |o: f64, d: f64| {
            let at =
                |s: __m256d| _mm256_cvtpd_ps(_mm256_add_pd(_mm256_set1_pd(o), _mm256_mul_pd(s, _mm256_set1_pd(d))));
            _mm256_set_m128(at(d_hi), at(d_lo))
        };
        let p = [coord(ray.origin.x, ray.dir.x), coord(ray.origin.y, ray.dir.y), coord(ray.origin.z, ray.dir.z)];
        let (min, max, scale, top) = (s.min.to_array(), s.max.to_array(), s.scale.to_array(), s.top.to_array());
        let zero = _mm256_setzero_ps();
        let mut inside = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        let mut cell = [_mm256_setzero_si256(); 3];
        let mut w = [zero; 3];
        for a in 0..3 {
            let (lo, hi) = (_mm256_set1_ps(min[a]), _mm256_set1_ps(max[a]));
            let ok = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(p[a], lo), _mm256_cmp_ps::<_CMP_LE_OQ>(p[a], hi));
            inside = _mm256_and_ps(inside, ok);
            let g =
                _mm256_sub_ps(_mm256_mul_ps(_mm256_sub_ps(p[a], lo), _mm256_set1_ps(scale[a])), _mm256_set1_ps(0.5));
            let g = _mm256_min_ps(_mm256_max_ps(g, zero), _mm256_set1_ps(top[a]));
            cell[a] = _mm256_cvttps_epi32(g);
            w[a] = _mm256_sub_ps(g, _mm256_cvtepi32_ps(cell[a]));
        }
        let step = |c: __m256i, n: i32, stride: i32| {
            let more = _mm256_cmpgt_epi32(_mm256_set1_epi32(n - 1), c);
            _mm256_and_si256(more, _mm256_set1_epi32(stride))
        };
        let (dx, dy, dz) = (step(cell[0], nx, 1), step(cell[1], ny, nx), step(cell[2], nz, nx * ny));
        let at = _mm256_add_epi32(
            _mm256_mullo_epi32(
                _mm256_add_epi32(_mm256_mullo_epi32(cell[2], _mm256_set1_epi32(ny)), cell[1]),
                _mm256_set1_epi32(nx),
            ),
            cell[0],
        );
        let data = s.data.as_ptr();
        // SAFETY: as in `block16`.
        let read = |i: __m256i| unsafe { _mm256_i32gather_ps::<4>(data, i) };
        let lerp = |a: __m256, b: __m256, t: __m256| {
            _mm256_add_ps(_mm256_mul_ps(a, _mm256_sub_ps(_mm256_set1_ps(1.0), t)), _mm256_mul_ps(b, t))
        };
        let (a_y, a_z) = (_mm256_add_epi32(at, dy), _mm256_add_epi32(at, dz));
        let a_zy = _mm256_add_epi32(a_z, dy);
        let c00 = lerp(read(at), read(_mm256_add_epi32(at, dx)), w[0]);
        let c10 = lerp(read(a_y), read(_mm256_add_epi32(a_y, dx)), w[0]);
        let c01 = lerp(read(a_z), read(_mm256_add_epi32(a_z, dx)), w[0]);
        let c11 = lerp(read(a_zy), read(_mm256_add_epi32(a_zy, dx)), w[0]);
        let v = lerp(lerp(c00, c10, w[1]), lerp(c01, c11, w[1]), w[2]);
        // SAFETY: `out` holds at least eight floats.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), _mm256_and_ps(inside, v)) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Aabb, Volume};
    use glam::DVec3;

    /// A pseudo-random number in [0, 1) from a counter (splitmix64).
    fn unit(i: u64) -> f64 {
        let mut z = i.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Every kernel this CPU has gives the scalar loop's sum bit for bit: rays from outside
    /// and inside the box, oblique and along the axes, through grids with sides of one cell
    /// and of odd lengths, spans that start at 0 and end at `segments` (the half weights), and
    /// spans shorter and longer than a block.
    #[test]
    fn every_kernel_sums_as_the_scalar_loop() {
        let aabb = Aabb::new(DVec3::new(-1.0, -0.5, 0.25), DVec3::new(2.0, 1.5, 1.75));
        let kinds = Isa::available();
        let mut checked = 0;
        for (g, dims) in [[13, 7, 5], [1, 9, 4], [16, 16, 16], [5, 1, 1]].into_iter().enumerate() {
            let vol = Volume::from_fn(dims, aabb, |p| ((3.0 * p.x).sin() * (2.0 * p.y).cos() + p.z) as f32);
            for r in 0..60u64 {
                let u = |k: u64| unit(1000 * g as u64 + 10 * r + k);
                let centre = aabb.centre();
                let origin = match r % 3 {
                    // Inside the box.
                    0 => aabb.min + (aabb.max - aabb.min) * DVec3::new(u(0), u(1), u(2)),
                    // Far outside.
                    _ => centre + DVec3::new(u(0) - 0.5, u(1) - 0.5, u(2) - 0.5).normalize() * 6.0,
                };
                let dir = match r % 7 {
                    0 => DVec3::X,
                    1 => -DVec3::Z,
                    _ => (centre - origin + DVec3::new(u(3) - 0.5, u(4) - 0.5, u(5) - 0.5)).normalize(),
                };
                let ray = Ray::new(origin, dir);
                let Some((s0, s1)) = aabb.intersect(&ray) else { continue };
                let segments = 1 + (u(6) * 70.0) as usize;
                let ds = (s1 - s0) / segments as f64;
                // Spans of the chord, some past its ends (read as zero outside the box).
                let spans = [(0, segments), (1, segments - 1), (segments / 3, segments / 3 + 2), (0, 0)];
                for (lo, hi) in spans {
                    let mut expected = 0f32;
                    let scalar = vol.sampler().scalar();
                    for q in lo..=hi {
                        let wt = if q == 0 || q == segments { 0.5f32 } else { 1.0 };
                        expected += wt * scalar.sample(ray.at(s0 + q as f64 * ds).as_vec3());
                    }
                    for &isa in &kinds {
                        let sampler = Sampler { isa, ..vol.sampler() };
                        let mut sum = 0f32;
                        sampler.march(&ray, (s0, ds), segments, (lo, hi), &mut sum);
                        assert_eq!(sum.to_bits(), expected.to_bits(), "{isa:?}, grid {dims:?}, ray {r}, {lo}..={hi}");
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 600, "{checked} sums compared");
    }

    /// A span past the box's faces adds nothing there: a ray along x through a constant grid
    /// sums to the samples inside only.
    #[test]
    fn samples_outside_the_box_are_zero() {
        let aabb = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let vol = Volume::from_fn([4, 4, 4], aabb, |_| 2.0);
        let ray = Ray::new(DVec3::new(-1.0, 0.5, 0.5), DVec3::X);
        // Samples every 0.1 from x = −1: x = 0, 0.1, …, 1 are the 11 inside (20 of 30 outside).
        let mut sum = 0f32;
        vol.sampler().march(&ray, (0.0, 0.1), 1000, (1, 30), &mut sum);
        assert!((sum - 22.0).abs() < 1e-4, "{sum}");
    }
}
