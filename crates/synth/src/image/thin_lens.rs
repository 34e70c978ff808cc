//! The dissertation's thin-lens image model (§6.3, Eq. 6.2–6.17): rays are cast from every
//! non-zero voxel through a finite circular aperture onto the sensor, giving defocus blur and
//! shot-like noise from the finite ray count.
//!
//! # Model
//! In camera coordinates (OpenCV axes, lens in the plane `z = 0`, object at depth `Z > 0`), a
//! voxel of value `E` and side `h` is a sphere of diameter `h` (Eq. 6.4's voxel-as-sphere);
//! each ray starts at a uniformly random point `P` on that sphere's surface and passes through
//! a point `A` of the aperture of diameter `d_a = f / f#`. The thin lens changes the ray's slope
//! by `−A/f` (Eq. 6.14–6.15), and the ray reaches the sensor at distance `l_i` (Eq. 6.16–6.17);
//! with `1/l_o + 1/l_i = 1/f` (Eq. 6.2) the sensor point, read out upright in pixels, is
//!
//! ```text
//! u = c_x + f_x (P_x/Z − A_x (1/Z − 1/l_o)),   v = c_y + f_y (P_y/Z − A_y (1/Z − 1/l_o))
//! ```
//!
//! with `f_x = l_i / pitch`: a pinhole projection plus a defocus term that vanishes on the
//! focal plane. The slopes are the tangents of the dissertation's angles θ, ϕ, so no
//! trigonometry is needed per ray. Each ray is binned into the pixel it lands in.
//!
//! **Ray count** (Eq. 6.5–6.7): `N_vox = N_rays ((θ_u − θ_d)/θ_col)²` with
//! `θ_{u,d} = atan((±d_a/2 − x)/Z)` and `θ_col` the same at the focal plane on the axis;
//! fractional counts are rounded stochastically so the expectation is exact.
//!
//! **Weights.** Every ray carries `E · V_vox / (N_rays · a_px)` (voxel volume over `N_rays`
//! times the pixel footprint area on the focal plane, `a_px = (l_o/f_x)(l_o/f_y)`), so the
//! expected image is the same line integral `∫E ds` (mm) as the pinhole model's, blurred by
//! the lens: the ray count ∝ 1/Z² and the footprint ∝ Z² cancel (the Ω·A identity of Eq. 5.3).
//!
//! **Differences from the dissertation**, both deliberate: aperture points are drawn uniformly
//! over the disc (the dissertation draws θ uniformly and then ϕ within the chord of Eq.
//! 6.8–6.11, which over-weights the aperture's x edges); and pixels accumulate in 64-bit fixed
//! point (values quantised to 2⁻²⁴ of the largest voxel value), so that sums over threads are
//! exact and the image is the same bytes for the same seed on any number of threads.

use fluidnerf_core::glam::Vec3;
use fluidnerf_core::num;
use fluidnerf_core::{Camera, Image, Isa, Volume};
use rand::{Rng, RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::SynthError;

/// The most rays [`ThinLensSettings::rays_per_voxel`] may ask for: 2²⁰, about 2000 times the
/// dissertation's 500. Beyond it the shot noise is far below any sensor's while the cost grows
/// without bound: 10³⁰⁰ would count rays past `u64::MAX` and never finish.
pub const MAX_RAYS_PER_VOXEL: f64 = (1u64 << 20) as f64;

/// Settings of the thin-lens image model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ThinLensSettings {
    /// Rays cast from a voxel on the focal plane, `N_rays` of Eq. 6.7. The dissertation used
    /// 500 with 0.05 mm voxels; fewer rays give more shot noise. More than 0 and at most
    /// [`MAX_RAYS_PER_VOXEL`]. Default 128.
    pub rays_per_voxel: f64,
    /// Voxels with values at or below this are not cast. Default 0 (every non-zero voxel).
    pub threshold: f32,
}

impl Default for ThinLensSettings {
    fn default() -> Self {
        ThinLensSettings { rays_per_voxel: 128.0, threshold: 0.0 }
    }
}

impl ThinLensSettings {
    pub fn validate(&self) -> Result<(), SynthError> {
        if !(self.rays_per_voxel > 0.0 && self.rays_per_voxel <= MAX_RAYS_PER_VOXEL) {
            return Err(SynthError::invalid(
                "image.rays_per_voxel",
                format!(
                    "must be more than 0 and at most {MAX_RAYS_PER_VOXEL} rays per voxel, got {}",
                    num(self.rays_per_voxel)
                ),
            ));
        }
        if !self.threshold.is_finite() || self.threshold < 0.0 {
            return Err(SynthError::invalid(
                "image.threshold",
                format!("must be zero or positive, got {}", num(self.threshold)),
            ));
        }
        Ok(())
    }
}

/// The non-zero voxels of a volume, as light sources (structure of arrays, world units).
#[derive(Clone, Debug)]
pub struct Emitters {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    /// Values in fixed point: `value = q · unit`.
    q: Vec<u32>,
    unit: f64,
    /// Voxel volume and the diameter of its sphere (the cube root of the volume).
    voxel_volume: f64,
    sphere_radius: f32,
}

/// Emitters are processed in chunks of this many; each chunk has its own random stream, so the
/// result does not depend on how rayon schedules them.
const CHUNK: usize = 2048;
/// Fixed-point resolution of voxel values relative to the largest.
const FIXED_ONE: f64 = (1u64 << 24) as f64;
/// Rays traced together (see the ray loop).
const RAY_LANES: usize = 8;
/// 2⁻²⁴: 24 random bits to a uniform f32 in [0, 1).
const BITS24: f32 = 1.0 / (1u32 << 24) as f32;

impl Emitters {
    /// The voxels of `volume` above `threshold`. Negative values are not light sources and are
    /// skipped.
    pub fn from_volume(volume: &Volume, threshold: f32) -> Self {
        let (_, max) = volume.min_max();
        let max = if max.is_finite() && max > 0.0 { max as f64 } else { 1.0 };
        let unit = max / FIXED_ONE;
        let [nx, ny, _] = volume.dims;
        let sp = volume.spacing();
        let mut e = Emitters {
            x: Vec::new(),
            y: Vec::new(),
            z: Vec::new(),
            q: Vec::new(),
            unit,
            voxel_volume: sp.x * sp.y * sp.z,
            sphere_radius: (0.5 * (sp.x * sp.y * sp.z).cbrt()) as f32,
        };
        for (idx, &v) in volume.data.iter().enumerate() {
            if v <= threshold || v.is_nan() || !v.is_finite() {
                continue;
            }
            let q = (v as f64 / unit).round();
            if q < 1.0 {
                continue;
            }
            let (i, j, k) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
            let c = volume.voxel_centre(i, j, k);
            e.x.push(c.x as f32);
            e.y.push(c.y as f32);
            e.z.push(c.z as f32);
            e.q.push(q as u32);
        }
        e
    }

    pub fn len(&self) -> usize {
        self.q.len()
    }

    pub fn is_empty(&self) -> bool {
        self.q.is_empty()
    }
}

/// Splits a seed into independent streams (SplitMix64 finaliser).
pub(crate) fn mix_seed(a: u64, b: u64) -> u64 {
    let mut z = a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(0x6A09_E667_F3BC_C909);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The thin-lens image of `emitters` seen by `camera` (which must carry a [`fluidnerf_core::ThinLens`]
/// and no lens distortion), `scale × ∫E ds` per pixel in expectation. `seed` selects the random
/// stream (use a different one per image). Returns the image and the number of rays cast.
pub fn render(
    emitters: &Emitters,
    camera: &Camera,
    settings: &ThinLensSettings,
    scale: f64,
    seed: u64,
) -> Result<(Image, u64), SynthError> {
    render_with(emitters, camera, settings, scale, seed, Isa::detected())
}

/// [`render`] with its ray loop compiled for the x86-64 baseline alone (SSE2): the same image
/// and ray count bit for bit, the reference the run-time choice of AVX2 or AVX-512 is checked
/// and timed against (`cargo bench -p fluidnerf-synth --bench image_formation`).
pub fn render_baseline(
    emitters: &Emitters,
    camera: &Camera,
    settings: &ThinLensSettings,
    scale: f64,
    seed: u64,
) -> Result<(Image, u64), SynthError> {
    render_with(emitters, camera, settings, scale, seed, Isa::Baseline)
}

/// [`render`] with the ray loop compiled for `isa`, which this CPU must have.
fn render_with(
    emitters: &Emitters,
    camera: &Camera,
    settings: &ThinLensSettings,
    scale: f64,
    seed: u64,
    isa: Isa,
) -> Result<(Image, u64), SynthError> {
    settings.validate()?;
    let lens = camera
        .lens
        .ok_or_else(|| SynthError::invalid("camera.lens", "the thin-lens model needs a camera with a lens"))?;
    lens.validate()?;
    if !camera.distortion.is_identity() {
        return Err(SynthError::invalid("camera.distortion", "the thin-lens model does not model lens distortion"));
    }
    let k = camera.intrinsics;
    let (w, h) = (camera.width(), camera.height());
    let pose = camera.camera_from_world();
    let rot: [f32; 9] = pose.matrix3.transpose().to_cols_array().map(|v| v as f32);
    let t = pose.translation.as_vec3();
    let lo = lens.object_distance();
    let da = lens.aperture_diameter;
    let ra = (0.5 * da) as f32;
    let inv_lo = (1.0 / lo) as f32;
    let (fx, fy, cx, cy) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32);
    let theta_col = 2.0 * (0.5 * da / lo).atan();
    let n_rays = settings.rays_per_voxel;
    let radius = emitters.sphere_radius;
    let footprint = (lo / k.fx) * (lo / k.fy);
    let weight = emitters.voxel_volume / (n_rays * footprint) * emitters.unit * scale;
    let npx = w * h;
    let cast = Cast { emitters, rot, t, radius, da, lo, theta_col, n_rays, ra, inv_lo, fx, fy, cx, cy, w, h, seed };
    let (acc, rays) = emitters
        .q
        .par_chunks(CHUNK)
        .enumerate()
        .fold(
            || (vec![0u64; npx], 0u64),
            |(mut acc, rays), (ci, qs)| {
                let more = cast.run(isa, ci, qs, &mut acc);
                (acc, rays + more)
            },
        )
        .reduce(
            || (vec![0u64; npx], 0u64),
            |(mut a, ra), (b, rb)| {
                for (x, y) in a.iter_mut().zip(&b) {
                    *x += y;
                }
                (a, ra + rb)
            },
        );
    let data = acc.iter().map(|&v| (v as f64 * weight) as f32).collect();
    Ok((Image::from_vec(w, h, data), rays))
}

/// What [`render`] casts rays with: the camera, the lens and the emitters.
struct Cast<'a> {
    emitters: &'a Emitters,
    rot: [f32; 9],
    t: Vec3,
    radius: f32,
    da: f64,
    lo: f64,
    theta_col: f64,
    n_rays: f64,
    ra: f32,
    inv_lo: f32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    w: usize,
    h: usize,
    seed: u64,
}

impl Cast<'_> {
    /// Casts the rays of chunk `ci` of the emitters (`qs`, their values) into `acc`; returns
    /// how many were cast. The loop is compiled again for AVX2 and AVX-512: the rays and their
    /// pixels are the same on each (the same random streams, and no fused multiply–adds are
    /// formed); wider vectors only run more of its lanes at once. `isa` must be one this CPU
    /// has ([`Isa::available`]).
    fn run(&self, isa: Isa, ci: usize, qs: &[u32], acc: &mut [u64]) -> u64 {
        match isa {
            // SAFETY: the caller passes an instruction set this CPU has.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => unsafe { self.chunk_avx2(ci, qs, acc) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => unsafe { self.chunk_avx512(ci, qs, acc) },
            _ => self.chunk(ci, qs, acc),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn chunk_avx2(&self, ci: usize, qs: &[u32], acc: &mut [u64]) -> u64 {
        self.chunk(ci, qs, acc)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    unsafe fn chunk_avx512(&self, ci: usize, qs: &[u32], acc: &mut [u64]) -> u64 {
        self.chunk(ci, qs, acc)
    }

    #[inline(always)]
    fn chunk(&self, ci: usize, qs: &[u32], acc: &mut [u64]) -> u64 {
        let Cast { rot, t, radius, da, lo, theta_col, n_rays, ra, inv_lo, fx, fy, cx, cy, w, h, seed, .. } = *self;
        let mut rays = 0u64;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_seed(seed, ci as u64));
        let base = ci * CHUNK;
        for (o, &q) in qs.iter().enumerate() {
            let wp = Vec3::new(self.emitters.x[base + o], self.emitters.y[base + o], self.emitters.z[base + o]);
            // camera_from_world, row-major rows of the rotation.
            let c = Vec3::new(
                rot[0] * wp.x + rot[1] * wp.y + rot[2] * wp.z + t.x,
                rot[3] * wp.x + rot[4] * wp.y + rot[5] * wp.z + t.y,
                rot[6] * wp.x + rot[7] * wp.y + rot[8] * wp.z + t.z,
            );
            if c.z <= radius {
                continue;
            }
            let (x, z) = (c.x as f64, c.z as f64);
            // Eq. 6.5–6.7, with the small-aperture limit when d_a → 0.
            let ratio = if da > 1e-9 * lo {
                (((0.5 * da - x) / z).atan() - ((-0.5 * da - x) / z).atan()) / theta_col
            } else {
                lo * z / (z * z + x * x)
            };
            let expected = n_rays * ratio * ratio;
            let mut count = expected.floor() as u64;
            if rng.random::<f64>() < expected - count as f64 {
                count += 1;
            }
            rays += count;
            // Rays in blocks of RAY_LANES: the random bits are drawn first, then the
            // arithmetic runs lane-wise (vectorisable), then the hits are binned.
            let mut left = count as usize;
            while left > 0 {
                let n = left.min(RAY_LANES);
                left -= n;
                let mut bits = [0u64; 2 * RAY_LANES];
                for b in bits.iter_mut().take(2 * n) {
                    *b = rng.next_u64();
                }
                let mut fu = [0.0f32; RAY_LANES];
                let mut fv = [0.0f32; RAY_LANES];
                for l in 0..RAY_LANES {
                    // A uniform point on the unit sphere (z uniform, Archimedes) and one
                    // on the unit disc (r = √u), each from 48 random bits.
                    let (b0, b1) = (bits[2 * l], bits[2 * l + 1]);
                    let (u1, u2) = ((b0 >> 40) as f32 * BITS24, ((b0 >> 16) & 0xff_ffff) as f32 * BITS24);
                    let sz = 2.0 * u1 - 1.0;
                    let sr = (1.0 - sz * sz).max(0.0).sqrt();
                    let (ss, sc) = crate::fastmath::sin_cos(std::f32::consts::TAU * u2);
                    let (u3, u4) = ((b1 >> 40) as f32 * BITS24, ((b1 >> 16) & 0xff_ffff) as f32 * BITS24);
                    let ar = u3.sqrt();
                    let (as_, ac) = crate::fastmath::sin_cos(std::f32::consts::TAU * u4);
                    let (px, py, pz) = (c.x + radius * sr * sc, c.y + radius * sr * ss, c.z + radius * sz);
                    let inv_z = 1.0 / pz;
                    let defocus = inv_z - inv_lo;
                    // Pixel (col, row) covers [col − ½, col + ½).
                    fu[l] = cx + fx * (px * inv_z - ra * ar * ac * defocus) + 0.5;
                    fv[l] = cy + fy * (py * inv_z - ra * ar * as_ * defocus) + 0.5;
                }
                for l in 0..n {
                    // Truncation is the floor for the non-negative values kept (NaN
                    // fails the test too).
                    if fu[l] >= 0.0 && fv[l] >= 0.0 {
                        let (col, row) = (fu[l] as usize, fv[l] as usize);
                        if col < w && row < h {
                            acc[row * w + col] += q as u64;
                        }
                    }
                }
            }
        }
        rays
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::pinhole::{render_volume, PinholeSettings};
    use crate::phantom::{GaussianBlob, Shape, ShapeSum};
    use crate::rig::{Layout, LensSettings, RigSettings, RingAxis};
    use fluidnerf_core::glam::DVec3;
    use fluidnerf_core::{Aabb, ThinLens};

    fn camera(px: u32, f_number: f64) -> Camera {
        let rig = RigSettings {
            layout: Layout::Ring { count: 3, arc_deg: 360.0, start_deg: 20.0, axis: RingAxis::X },
            ..Default::default()
        };
        let lens = LensSettings { resolution: [px, px], f_number, ..Default::default() };
        rig.build(&lens, &Aabb::cube(DVec3::ZERO, 40.0), 0).expect("rig").swap_remove(1).camera
    }

    fn blob_volume(n: usize) -> Volume {
        let aabb = Aabb::cube(DVec3::ZERO, 40.0);
        let blob = ShapeSum {
            shapes: vec![Shape::Blob(GaussianBlob { centre: DVec3::new(2.0, -1.0, 1.5), sigma: 5.0, amplitude: 1.0 })],
        };
        Volume::from_field([n, n, n], aabb, &blob, 0.0)
    }

    /// Ray counts are bounded: 1e300 counted rays past `u64::MAX` and never finished.
    #[test]
    fn rays_per_voxel_are_bounded() {
        let with = |n: f64| ThinLensSettings { rays_per_voxel: n, threshold: 0.0 }.validate();
        with(0.5).expect("a fraction of a ray on average");
        with(MAX_RAYS_PER_VOXEL).expect("the bound");
        for n in [0.0, -1.0, MAX_RAYS_PER_VOXEL * 2.0, 1e300, f64::INFINITY, f64::NAN] {
            let err = with(n).expect_err("out of range").to_string();
            assert!(err.contains("image.rays_per_voxel") && err.contains("at most 1048576"), "{n}: {err}");
        }
    }

    #[test]
    fn small_aperture_converges_to_pinhole() {
        let vol = blob_volume(48);
        let em = Emitters::from_volume(&vol, 0.0);
        let pin_cam = camera(32, 3.5);
        let pinhole = render_volume(&vol, &pin_cam, &PinholeSettings::default(), 1.0).expect("pinhole");
        let peak = pinhole.min_max().1;
        let mut errors = Vec::new();
        for f_number in [3.5, 1000.0] {
            let cam = camera(32, f_number);
            let (img, rays) = render(&em, &cam, &ThinLensSettings { rays_per_voxel: 64.0, threshold: 0.0 }, 1.0, 5)
                .expect("thin lens");
            assert!(rays > 1_000_000);
            let err = img.data.iter().zip(&pinhole.data).map(|(a, b)| ((a - b) / peak).powi(2) as f64).sum::<f64>()
                / img.data.len() as f64;
            errors.push(err.sqrt());
            // Total signal is preserved: the lens only redistributes it.
            let ratio = img.sum() / pinhole.sum();
            assert!((ratio - 1.0).abs() < 0.02, "flux ratio {ratio}");
        }
        // At f/1000 the blur vanishes and only shot noise and voxel-sphere spread remain.
        assert!(errors[1] < 0.02, "rms difference to pinhole at f/1000: {}", errors[1]);
        assert!(errors[0] < 0.05, "rms difference to pinhole at f/3.5: {}", errors[0]);
    }

    #[test]
    fn defocused_point_blurs_to_predicted_circle() {
        // One bright voxel 30 mm behind the focal plane, on the optical axis. The box is long
        // along the viewing direction and thin across it, so voxels are small (0.1 mm, 0.5 px
        // on the sensor) without a huge grid.
        let aabb = Aabb::new(DVec3::new(-1.0, -40.0, -1.0), DVec3::new(1.0, 40.0, 1.0));
        let mut vol = Volume::zeros([21, 801, 21], aabb);
        let cam = {
            let rig = RigSettings {
                layout: Layout::Ring { count: 1, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X },
                ..Default::default()
            };
            let lens =
                LensSettings { resolution: [96, 96], pixel_pitch_mm: Some(0.02), f_number: 2.0, ..Default::default() };
            rig.build(&lens, &aabb, 0).expect("rig").swap_remove(0).camera
        };
        // The ring camera 0 sits on +y looking along −y; a voxel at y = −30 is 30 mm farther.
        let idx = vol.index(10, 100, 10);
        vol.data[idx] = 1.0;
        let src = vol.voxel_centre(10, 100, 10);
        let em = Emitters::from_volume(&vol, 0.0);
        let (img, _) =
            render(&em, &cam, &ThinLensSettings { rays_per_voxel: 200_000.0, threshold: 0.0 }, 1.0, 1).expect("render");
        let lens: ThinLens = cam.lens.expect("lens");
        let depth = (cam.centre() - src).length();
        let diameter_px = lens.blur_circle_diameter(depth) / lens.pixel_pitch;
        // Measure the blur disc: the radius holding 99 % of the light, and the flat-top radius.
        let centre = cam.project(src).expect("in front");
        let total = img.sum();
        let mut by_radius: Vec<(f64, f64)> = (0..img.height)
            .flat_map(|r| (0..img.width).map(move |c| (c, r)))
            .map(|(c, r)| {
                (((c as f64 - centre.x).powi(2) + (r as f64 - centre.y).powi(2)).sqrt(), img.get(c, r) as f64)
            })
            .collect();
        by_radius.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut cum = 0.0;
        let r99 = by_radius.iter().find(|(_, v)| {
            cum += v;
            cum >= 0.99 * total
        });
        let r99 = r99.expect("light").0;
        // Uniform disc of radius R: 99 % within 0.995 R; pixelation and the voxel sphere
        // (radius 0.5 px here) widen it slightly.
        let predicted = 0.5 * diameter_px;
        assert!(predicted > 8.0, "test needs a visible blur, got {predicted} px");
        assert!((r99 - predicted).abs() < 0.08 * predicted + 1.0, "blur radius {r99} px vs thin-lens {predicted} px");
    }

    #[test]
    fn every_instruction_set_casts_the_same_rays() {
        let vol = blob_volume(24);
        let em = Emitters::from_volume(&vol, 0.0);
        let cam = camera(32, 2.8);
        let s = ThinLensSettings { rays_per_voxel: 37.0, threshold: 0.0 };
        let (a, rays) = render_with(&em, &cam, &s, 1.0, 5, Isa::Baseline).expect("render");
        assert!(rays > 10_000 && a.data.iter().filter(|&&v| v > 0.0).count() > 200, "{rays} rays");
        for isa in Isa::available() {
            let (b, n) = render_with(&em, &cam, &s, 1.0, 5, isa).expect("render");
            assert_eq!(n, rays, "{isa:?}");
            assert!(a.data.iter().zip(&b.data).all(|(x, y)| x.to_bits() == y.to_bits()), "{isa:?}");
        }
    }

    #[test]
    fn same_seed_same_image_any_thread_count() {
        let vol = blob_volume(24);
        let em = Emitters::from_volume(&vol, 0.0);
        let cam = camera(24, 3.5);
        let s = ThinLensSettings::default();
        let (a, _) = render(&em, &cam, &s, 1.0, 9).expect("render");
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
        let (b, _) = pool.install(|| render(&em, &cam, &s, 1.0, 9)).expect("render");
        let (c, _) = render(&em, &cam, &s, 1.0, 10).expect("render");
        assert_eq!(a, b);
        assert_ne!(a, c);
    }
}
