//! Empty-space skipping: an occupancy grid carved from the training images (a visual hull).
//!
//! The imaging model is emission only, with non-negative E: a pixel is the integral of E
//! along its ray. A pixel that measured nothing (below a noise-aware threshold) therefore says
//! that E vanishes on its whole ray, and a region of space every part of which one camera sees
//! only through such dark pixels is empty — whatever the other cameras see. Carving those
//! regions out gives the visual hull of the glowing field.
//!
//! # What is skipped and why it is safe
//! - The grid has `dims` cells over the reconstruction box (box-normalised coordinates, x
//!   fastest, `(k·ny + j)·nx + i`). A cell is declared empty when, for at least one camera, its
//!   projection (the bounding box of its 8 projected corners, widened by
//!   [`OccupancyConfig::margin_px`]) lies wholly inside the image and contains no bright pixel.
//!   Cells partly outside a camera's image, or behind it, are never carved by that camera.
//! - The occupied set is then dilated by [`OccupancyConfig::dilate`] cells, so a thin glowing
//!   structure is never clipped by the coarse grid.
//! - The model becomes `E(x) = occupied(x) · field(x)`: samples in empty cells are not
//!   evaluated (E = 0 there), ray segments before the first and after the last occupied cell
//!   are not sampled at all ([`OccupancyGrid::occupied_span`]), and rays that see no occupied
//!   cell are dropped from training because they render to exactly 0 whatever the field is —
//!   their (dark) targets are matched by construction, so they carry no gradient and only add
//!   a constant to the loss. The trained field is exported through the same mask
//!   (`crate::trained`), so what was skipped in training is zero in the result.
//! - What can be lost: emission so faint that every pixel seeing it stays below the threshold
//!   (`background + noise_sigmas · σ̂`, at least `floor` of the image's range). At that level the
//!   images carry no usable signal about it anyway.
//!
//! Valid for views of one instant (a static scene, or the frames of one time step).

use fluidnerf_core::num;
use fluidnerf_core::{Aabb, Camera, Image};
use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of the visual-hull carving.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OccupancyConfig {
    /// Cells along the longest box side (cubic cells). Default 64.
    pub resolution: usize,
    /// A pixel is bright above `background + noise_sigmas · σ̂`, with the background and σ̂ as
    /// [`OccupancyConfig::noise_estimate`] says. Default 4.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub noise_sigmas: f32,
    /// How the background and σ̂ are read. Default `median`: `laplacian` carves the plume's
    /// noisy images, which `median` leaves whole, but made the hybrid 1–7 % worse on the noisy
    /// jet, where defaults are chosen (`docs/claims.md`).
    pub noise_estimate: NoiseEstimate,
    /// The threshold is at least `background + floor · (max − background)`, which decides for
    /// noiseless images. Default 0.01.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub floor: f32,
    /// Widening of each cell's projected footprint, pixels (absorbs lens distortion and
    /// rounding). Default 1.
    pub margin_px: f64,
    /// Cells of dilation of the occupied set after carving. Default 1.
    pub dilate: usize,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        OccupancyConfig {
            resolution: 64,
            noise_sigmas: 4.0,
            noise_estimate: NoiseEstimate::Median,
            floor: 0.01,
            margin_px: 1.0,
            dilate: 1,
        }
    }
}

/// The finest occupancy grid a run may ask for, in cells along the box's longest side.
pub const MAX_OCCUPANCY_RESOLUTION: usize = 512;

impl OccupancyConfig {
    /// Rejects settings no carving can use.
    pub fn validate(&self) -> Result<(), crate::NeuralError> {
        let bad = |what: &str, why: String| Err(crate::NeuralError::invalid(format!("occupancy.{what}"), why));
        if !(1..=MAX_OCCUPANCY_RESOLUTION).contains(&self.resolution) {
            return bad(
                "resolution",
                format!("must be 1 to {MAX_OCCUPANCY_RESOLUTION} cells, got {}", self.resolution),
            );
        }
        if !(self.noise_sigmas >= 0.0 && self.noise_sigmas <= 100.0) {
            return bad("noise_sigmas", format!("must be in [0, 100], got {}", num(self.noise_sigmas)));
        }
        if !(self.floor >= 0.0 && self.floor < 1.0) {
            return bad("floor", format!("must be a fraction in [0, 1), got {}", num(self.floor)));
        }
        if !(self.margin_px >= 0.0 && self.margin_px <= 100.0) {
            return bad("margin_px", format!("must be in [0, 100] pixels, got {}", num(self.margin_px)));
        }
        if self.dilate > 16 {
            return bad("dilate", format!("must be at most 16 cells, got {}", self.dilate));
        }
        Ok(())
    }
}

/// How [`dark_threshold`] reads an image's background and noise.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NoiseEstimate {
    /// [`Image::background`]: σ̂ from the difference of Laplacians, as the noise reading of
    /// the automatic settings ([`Image::relative_noise`]), which reads noise clipped at the
    /// sensor's floor too; the background the median or a low percentile, whichever is lower.
    Laplacian,
    /// The background the image median, σ̂ `1.4826 · median(background − p)` over the pixels
    /// below it. With noise clipped at the floor, most of those pixels are 0, so σ̂ reads a
    /// fraction of the noise and the threshold lies inside it: on the plume's noisy images
    /// (5 % noise) nothing is carved.
    #[default]
    Median,
}

/// A boolean grid over the reconstruction box in box-normalised coordinates.
#[derive(Clone, Debug, PartialEq)]
pub struct OccupancyGrid {
    dims: [usize; 3],
    occupied: Vec<bool>,
}

/// The on-disk form: dimensions and run lengths of alternating empty / occupied cells
/// (starting with empty), x fastest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OccupancyRecord {
    pub dims: [usize; 3],
    pub runs: Vec<u32>,
}

/// The brightness threshold of one image (see [`OccupancyConfig::noise_sigmas`]).
pub fn dark_threshold(image: &Image, cfg: &OccupancyConfig) -> f32 {
    if cfg.noise_estimate == NoiseEstimate::Laplacian {
        if let Some(b) = image.background() {
            let max = image.min_max().1 as f64;
            let floor = b.level + cfg.floor as f64 * (max - b.level);
            return (b.level + cfg.noise_sigmas as f64 * b.sigma).max(floor) as f32;
        }
    }
    let mut v: Vec<f32> = image.data.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f32::INFINITY;
    }
    v.sort_by(f32::total_cmp);
    let background = v[v.len() / 2];
    let max = v[v.len() - 1];
    let mut dev: Vec<f32> = v[..=v.len() / 2].iter().map(|&p| background - p).collect();
    dev.sort_by(f32::total_cmp);
    let sigma = 1.4826 * dev[dev.len() / 2];
    (background + cfg.noise_sigmas * sigma).max(background + cfg.floor * (max - background))
}

impl OccupancyGrid {
    /// Every cell occupied.
    pub fn full(dims: [usize; 3]) -> Self {
        assert!(dims.iter().all(|&n| n > 0), "OccupancyGrid::full: dims {dims:?} must be positive");
        OccupancyGrid { dims, occupied: vec![true; dims[0] * dims[1] * dims[2]] }
    }

    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// A grid of the given cells (x fastest); `None` if their number is not `dims`' product.
    pub fn from_cells(dims: [usize; 3], cells: Vec<bool>) -> Option<Self> {
        (dims.iter().all(|&n| n > 0) && cells.len() == dims.iter().product::<usize>())
            .then_some(OccupancyGrid { dims, occupied: cells })
    }

    /// The cells, x fastest.
    pub fn cells(&self) -> &[bool] {
        &self.occupied
    }

    /// The grid as a field's [`fluidnerf_core::Support`] over `aabb`.
    pub fn support(&self, aabb: Aabb) -> fluidnerf_core::Support<'_> {
        fluidnerf_core::Support { aabb, dims: self.dims, cells: &self.occupied }
    }

    /// Carves the visual hull of `views` (camera and image of one instant) in `aabb`: a cell is
    /// empty when some view sees only dark pixels over its whole footprint. Views of different
    /// instants must not be mixed (a cell dark at one instant may be bright at another); carve
    /// each instant and combine with [`OccupancyGrid::union_with`].
    pub fn from_views(aabb: &Aabb, views: &[(&Camera, &Image)], cfg: &OccupancyConfig) -> Self {
        let views: Vec<(&Camera, &Image, Option<&[bool]>)> = views.iter().map(|&(c, i)| (c, i, None)).collect();
        Self::from_masked_views(aabb, &views, cfg)
    }

    /// [`OccupancyGrid::from_views`] for views with masks (`true` = pixel used): a masked
    /// pixel says nothing about the cells behind it, so it carves none, and it counts as black
    /// (no light known) where the image's dark level is read. Masked pixels set to the image's
    /// brightest value instead made that value the median of an image masked over more than
    /// half, every pixel then read as dark, and the hull came out empty.
    pub fn from_masked_views(aabb: &Aabb, views: &[(&Camera, &Image, Option<&[bool]>)], cfg: &OccupancyConfig) -> Self {
        let dims = fluidnerf_core::Volume::dims_for(aabb, cfg.resolution.max(1));
        let [nx, ny, nz] = dims;
        let mut empty = vec![false; nx * ny * nz];
        for &(camera, image, mask) in views {
            assert_eq!(
                (camera.width(), camera.height()),
                (image.width, image.height),
                "OccupancyGrid::from_views: image size differs from its camera"
            );
            let used = |k: usize| mask.is_none_or(|m| m[k]);
            let threshold = match mask {
                None => dark_threshold(image, cfg),
                Some(_) => {
                    let mut dark = image.clone();
                    dark.data.iter_mut().enumerate().filter(|(k, _)| !used(*k)).for_each(|(_, p)| *p = 0.0);
                    dark_threshold(&dark, cfg)
                }
            };
            let (w, h) = (image.width, image.height);
            // Summed-area table of bright pixels, (w + 1) × (h + 1).
            let mut sat = vec![0u32; (w + 1) * (h + 1)];
            for row in 0..h {
                let mut acc = 0u32;
                for col in 0..w {
                    let k = row * w + col;
                    acc += u32::from(!used(k) || image.data[k] > threshold);
                    sat[(row + 1) * (w + 1) + col + 1] = sat[row * (w + 1) + col + 1] + acc;
                }
            }
            let bright_in = |c0: usize, r0: usize, c1: usize, r1: usize| {
                sat[(r1 + 1) * (w + 1) + c1 + 1] + sat[r0 * (w + 1) + c0]
                    - sat[r0 * (w + 1) + c1 + 1]
                    - sat[(r1 + 1) * (w + 1) + c0]
            };
            // Project the lattice of cell corners once.
            let (lx, ly) = (nx + 1, ny + 1);
            let size = aabb.size();
            let corners: Vec<Option<[f64; 2]>> = (0..lx * ly * (nz + 1))
                .into_par_iter()
                .map(|q| {
                    let (i, j, k) = (q % lx, (q / lx) % ly, q / (lx * ly));
                    let f = DVec3::new(i as f64 / nx as f64, j as f64 / ny as f64, k as f64 / nz as f64);
                    camera.project(aabb.min + f * size).map(|p| [p.x, p.y])
                })
                .collect();
            empty.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
                for j in 0..ny {
                    for i in 0..nx {
                        let cell = &mut slab[j * nx + i];
                        if *cell {
                            continue;
                        }
                        let (mut u0, mut v0, mut u1, mut v1) =
                            (f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
                        let mut visible = true;
                        for c in 0..8 {
                            let q = ((k + (c >> 2 & 1)) * ly + j + (c >> 1 & 1)) * lx + i + (c & 1);
                            match corners[q] {
                                Some([u, v]) => {
                                    u0 = u0.min(u);
                                    v0 = v0.min(v);
                                    u1 = u1.max(u);
                                    v1 = v1.max(v);
                                }
                                None => visible = false,
                            }
                        }
                        if !visible {
                            continue;
                        }
                        let m = cfg.margin_px;
                        let (c0, r0) = ((u0 - m + 0.5).floor(), (v0 - m + 0.5).floor());
                        let (c1, r1) = ((u1 + m + 0.5).floor(), (v1 + m + 0.5).floor());
                        if c0 < 0.0 || r0 < 0.0 || c1 > (w - 1) as f64 || r1 > (h - 1) as f64 {
                            continue;
                        }
                        if bright_in(c0 as usize, r0 as usize, c1 as usize, r1 as usize) == 0 {
                            *cell = true;
                        }
                    }
                }
            });
        }
        let mut grid = OccupancyGrid { dims, occupied: empty.iter().map(|&e| !e).collect() };
        grid.dilate(cfg.dilate);
        grid
    }

    /// Marks occupied every cell occupied in `other` (the union of two hulls, for example of
    /// two instants). Both grids must have the same dimensions.
    pub fn union_with(&mut self, other: &OccupancyGrid) {
        assert_eq!(self.dims, other.dims, "OccupancyGrid::union_with: grids differ in size");
        for (a, &b) in self.occupied.iter_mut().zip(&other.occupied) {
            *a |= b;
        }
    }

    /// Grows the occupied set by `cells` (26-neighbourhood, repeated).
    pub fn dilate(&mut self, cells: usize) {
        fluidnerf_core::volume::dilate_mask(&mut self.occupied, self.dims, cells);
    }

    /// Fraction of occupied cells.
    pub fn occupied_fraction(&self) -> f64 {
        self.occupied.iter().filter(|&&o| o).count() as f64 / self.occupied.len() as f64
    }

    /// Whether the cell holding the box-normalised point `u` is occupied (false outside the box).
    #[inline]
    pub fn is_occupied(&self, u: [f32; 3]) -> bool {
        let mut idx = [0usize; 3];
        for a in 0..3 {
            if !(0.0..=1.0).contains(&u[a]) {
                return false;
            }
            idx[a] = ((u[a] * self.dims[a] as f32) as usize).min(self.dims[a] - 1);
        }
        self.occupied[(idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0]]
    }

    /// The part `[s0, s1] ⊆ [near, far]` of the ray `u(s) = origin + s · dir` (box-normalised,
    /// see `crate::sampling`) from its first to its last occupied cell, or `None` if it sees
    /// none. Marches at half a cell and widens the span by one step on each side.
    pub fn occupied_span(&self, origin: [f32; 3], dir: [f32; 3], near: f32, far: f32) -> Option<(f32, f32)> {
        let rate = (0..3).map(|a| dir[a].abs() * self.dims[a] as f32).fold(0.0f32, f32::max);
        if rate.is_nan() || rate <= 0.0 || far.is_nan() || far <= near {
            return None;
        }
        let step = 0.5 / rate;
        let n = ((far - near) / step).ceil() as usize + 1;
        let mut first = None;
        let mut last = near;
        for q in 0..n {
            let s = (near + q as f32 * step).min(far);
            let u = [origin[0] + s * dir[0], origin[1] + s * dir[1], origin[2] + s * dir[2]];
            let u = u.map(|c| c.clamp(0.0, 1.0));
            if self.is_occupied(u) {
                first.get_or_insert(s);
                last = s;
            }
        }
        first.map(|f| ((f - step).max(near), (last + step).min(far)))
    }

    /// Run-length form for saving next to a trained field.
    pub fn to_record(&self) -> OccupancyRecord {
        let mut runs = Vec::new();
        let mut current = false;
        let mut len = 0u32;
        for &o in &self.occupied {
            if o == current {
                len += 1;
            } else {
                runs.push(len);
                current = o;
                len = 1;
            }
        }
        runs.push(len);
        OccupancyRecord { dims: self.dims, runs }
    }

    /// Inverse of [`OccupancyGrid::to_record`]; the problem if the dimensions are not those of
    /// a grid a run makes (1 to [`MAX_OCCUPANCY_RESOLUTION`] cells along each axis) or the runs
    /// do not fill the grid.
    pub fn from_record(record: &OccupancyRecord) -> Result<Self, String> {
        // Checked before anything is allocated: a record of a few bytes must not ask for more
        // memory than the machine has.
        if let Some(d) = record.dims.iter().find(|d| !(1..=MAX_OCCUPANCY_RESOLUTION).contains(d)) {
            return Err(format!(
                "dims must be 1 to {MAX_OCCUPANCY_RESOLUTION} cells along each axis, got {d} in {:?}",
                record.dims
            ));
        }
        let n = record.dims.iter().product::<usize>();
        let filled = record.runs.iter().map(|&r| r as u64).sum::<u64>();
        if filled != n as u64 {
            return Err(format!(
                "run lengths do not fill the grid: they count {filled} cells, the grid {:?} has {n}",
                record.dims
            ));
        }
        let mut occupied = Vec::with_capacity(n);
        let mut current = false;
        for &r in &record.runs {
            occupied.extend(std::iter::repeat_n(current, r as usize));
            current = !current;
        }
        Ok(OccupancyGrid { dims: record.dims, occupied })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::{render_image, Intrinsics, RenderSettings};
    use glam::Vec3;

    fn ring(n: usize, px: u32) -> Vec<Camera> {
        let k = Intrinsics {
            width: px,
            height: px,
            fx: px as f64 * 1.6,
            fy: px as f64 * 1.6,
            cx: (px as f64 - 1.0) / 2.0,
            cy: (px as f64 - 1.0) / 2.0,
            skew: 0.0,
        };
        (0..n)
            .map(|c| {
                let a = std::f64::consts::PI * c as f64 / n as f64;
                Camera::look_at(k, DVec3::new(0.0, 5.0 * a.cos(), 5.0 * a.sin()), DVec3::ZERO, DVec3::X)
            })
            .collect()
    }

    #[test]
    fn hull_keeps_the_ball_and_carves_the_corners() {
        let aabb = Aabb::cube(DVec3::ZERO, 2.0);
        let ball = |p: Vec3, _t: f64| if (p - Vec3::new(0.2, 0.0, 0.1)).length() < 0.45 { 1.0f32 } else { 0.0 };
        let cams = ring(6, 32);
        let settings = RenderSettings { supersample: 2, ..Default::default() };
        let imgs: Vec<Image> = cams.iter().map(|c| render_image(&ball, c, &aabb, &settings).expect("render")).collect();
        let views: Vec<(&Camera, &Image)> = cams.iter().zip(&imgs).collect();
        let cfg = OccupancyConfig { resolution: 16, ..Default::default() };
        let grid = OccupancyGrid::from_views(&aabb, &views, &cfg);
        // Every point of the ball is kept.
        for q in 0..2000 {
            let f = |m: usize| ((q * m) % 1000) as f32 / 1000.0 * 2.0 - 1.0;
            let p = Vec3::new(f(7), f(13), f(31)) * 0.45;
            if p.length() < 0.45 {
                let x = p + Vec3::new(0.2, 0.0, 0.1);
                let u = aabb.to_unit(x.as_dvec3()).as_vec3();
                assert!(grid.is_occupied([u.x, u.y, u.z]), "ball point {x} carved away");
            }
        }
        let frac = grid.occupied_fraction();
        assert!(frac < 0.35, "the hull should be much smaller than the box, got {frac}");
        // A corner of the box far from the ball is empty.
        assert!(!grid.is_occupied([0.02, 0.02, 0.98]));
        // Round trip through the record.
        assert_eq!(OccupancyGrid::from_record(&grid.to_record()).as_ref(), Ok(&grid));
    }

    /// A record edited to dimensions no run makes, or whose runs count other cells than the
    /// grid has, is refused before any memory is taken: dimensions of 10⁹ cells each panicked
    /// on a capacity overflow, and runs of 4·10⁹ cells each would have asked for terabytes.
    #[test]
    fn records_of_impossible_grids_are_refused_before_allocating() {
        let e = OccupancyGrid::from_record(&OccupancyRecord { dims: [1_000_000_000; 3], runs: vec![0, 1] });
        assert!(e.expect_err("huge dims").contains("dims must be 1 to 512 cells along each axis"));
        let e = OccupancyGrid::from_record(&OccupancyRecord { dims: [0, 4, 4], runs: vec![] });
        assert!(e.expect_err("empty dims").contains("got 0"));
        let runs = vec![u32::MAX; 300];
        let e = OccupancyGrid::from_record(&OccupancyRecord { dims: [4, 4, 4], runs }).expect_err("too many cells");
        assert!(e.contains("run lengths do not fill the grid") && e.contains("has 64"), "{e}");
        let e = OccupancyGrid::from_record(&OccupancyRecord { dims: [4, 4, 4], runs: vec![10, 20] });
        assert!(e.expect_err("too few cells").contains("they count 30 cells"));
        assert!(OccupancyGrid::from_record(&OccupancyRecord { dims: [4, 4, 4], runs: vec![10, 20, 34] }).is_ok());
    }

    #[test]
    fn noise_threshold_tracks_noise() {
        let mut img = Image::zeros(40, 40);
        // Deterministic ±0.05 "noise" around 0 and a bright square.
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 7919 % 101) as f32 / 100.0 - 0.5) * 0.1;
        }
        for r in 10..20 {
            for c in 10..20 {
                img.set(c, r, 2.0);
            }
        }
        let t = dark_threshold(&img, &OccupancyConfig::default());
        assert!(t > 0.05 && t < 0.5, "threshold {t}");
    }

    /// Noise of deviation 0.05 clipped at 0 around a background at 0, and a bright square on a
    /// tenth of the image: the median rule reads a fraction of the noise and puts the threshold
    /// inside it, where a cell's footprint of a few pixels nearly always holds a brighter one;
    /// the Laplacian rule puts it at about four deviations.
    #[test]
    fn clipped_noise_is_read_by_the_laplacian_rule() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let sigma = 0.05f32;
        let mut img = Image::zeros(60, 60);
        for r in 0..60 {
            for c in 0..60 {
                let object = (20..39).contains(&r) && (20..39).contains(&c);
                let (u, v): (f32, f32) = (rng.random(), rng.random());
                let g = (-2.0 * (1.0 - u).ln()).sqrt() * (std::f32::consts::TAU * v).cos();
                img.set(c, r, (if object { 1.0 } else { 0.0 } + sigma * g).max(0.0));
            }
        }
        let laplacian =
            dark_threshold(&img, &OccupancyConfig { noise_estimate: NoiseEstimate::Laplacian, ..Default::default() });
        let median = dark_threshold(&img, &OccupancyConfig::default());
        assert!((laplacian - 4.0 * sigma).abs() < 0.6 * sigma, "laplacian rule {laplacian}");
        assert!(median < 2.0 * sigma, "median rule {median}: it reads the clipped noise as it did");
    }

    #[test]
    fn a_saved_configuration_without_the_noise_estimate_keeps_the_median_rule() {
        let saved: OccupancyConfig = serde_json::from_str(r#"{"resolution": 64, "noise_sigmas": 4}"#).expect("parses");
        assert_eq!(saved.noise_estimate, NoiseEstimate::Median);
        let cfg = OccupancyConfig { noise_estimate: NoiseEstimate::Laplacian, ..Default::default() };
        let written = serde_json::to_string(&cfg).expect("serialises");
        assert!(written.contains(r#""noise_estimate":"laplacian""#), "{written}");
        let again: OccupancyConfig = serde_json::from_str(&written).expect("parses");
        assert_eq!(again, cfg);
    }

    #[test]
    fn settings_outside_their_ranges_are_refused_by_key() {
        let ok = OccupancyConfig::default();
        let edges = [
            OccupancyConfig { resolution: 1, noise_sigmas: 0.0, floor: 0.0, margin_px: 0.0, dilate: 0, ..ok.clone() },
            OccupancyConfig {
                resolution: MAX_OCCUPANCY_RESOLUTION,
                noise_sigmas: 100.0,
                floor: 0.999,
                margin_px: 100.0,
                dilate: 16,
                ..ok.clone()
            },
        ];
        for good in edges {
            assert!(good.validate().is_ok(), "{good:?}");
        }
        let bad = [
            ("resolution", OccupancyConfig { resolution: 0, ..ok.clone() }),
            ("resolution", OccupancyConfig { resolution: MAX_OCCUPANCY_RESOLUTION + 1, ..ok.clone() }),
            ("noise_sigmas", OccupancyConfig { noise_sigmas: -0.1, ..ok.clone() }),
            ("noise_sigmas", OccupancyConfig { noise_sigmas: 100.5, ..ok.clone() }),
            ("noise_sigmas", OccupancyConfig { noise_sigmas: f32::NAN, ..ok.clone() }),
            ("floor", OccupancyConfig { floor: -0.01, ..ok.clone() }),
            ("floor", OccupancyConfig { floor: 1.0, ..ok.clone() }),
            ("margin_px", OccupancyConfig { margin_px: -1.0, ..ok.clone() }),
            ("margin_px", OccupancyConfig { margin_px: 100.5, ..ok.clone() }),
            ("dilate", OccupancyConfig { dilate: 17, ..ok.clone() }),
        ];
        for (key, cfg) in bad {
            let e = cfg.validate().expect_err("refused").to_string();
            assert!(e.contains(&format!("occupancy.{key}")), "{key}: {e}");
        }
    }

    /// A point is in the cell `⌊u · n⌋` along each axis (x fastest), the far faces of the box
    /// in the last cell; points outside the box are in none.
    #[test]
    fn a_point_is_occupied_when_its_cell_is() {
        let dims = [2, 3, 4];
        let mut cells = vec![false; 24];
        cells[(2 * 3 + 1) * 2 + 1] = true; // cell (1, 1, 2)
        cells[23] = true; // cell (1, 2, 3), the far corner
        let grid = OccupancyGrid::from_cells(dims, cells).expect("grid");
        assert!(grid.is_occupied([0.75, 0.5, 0.625]));
        assert!(grid.is_occupied([0.51, 0.34, 0.51]));
        assert!(!grid.is_occupied([0.25, 0.5, 0.625]));
        assert!(!grid.is_occupied([0.75, 0.2, 0.625]));
        assert!(!grid.is_occupied([0.75, 0.5, 0.375]));
        assert!(!grid.is_occupied([0.75, 0.5, 0.8]));
        assert!(grid.is_occupied([1.0, 1.0, 1.0]));
        for outside in [[1.01, 1.0, 1.0], [1.0, 1.01, 1.0], [1.0, 1.0, 1.01], [-0.01, 0.5, 0.625], [f32::NAN, 0.5, 0.6]]
        {
            assert!(!grid.is_occupied(outside), "{outside:?}");
        }
        assert_eq!(grid.dims(), dims);
        assert_eq!(grid.cells().iter().filter(|&&c| c).count(), 2);
        assert!((grid.occupied_fraction() - 2.0 / 24.0).abs() < 1e-12);
    }

    #[test]
    fn grids_are_made_only_of_as_many_cells_as_their_dims_hold() {
        assert!(OccupancyGrid::from_cells([2, 2, 2], vec![true; 7]).is_none());
        assert!(OccupancyGrid::from_cells([0, 2, 2], vec![]).is_none());
        let full = OccupancyGrid::full([2, 3, 1]);
        assert_eq!(full.cells(), &[true; 6]);
        assert_eq!(full.occupied_fraction(), 1.0);
        let mut a = OccupancyGrid::from_cells([2, 1, 1], vec![true, false]).expect("grid");
        a.union_with(&OccupancyGrid::from_cells([2, 1, 1], vec![false, false]).expect("grid"));
        assert_eq!(a.cells(), &[true, false]);
        a.union_with(&OccupancyGrid::from_cells([2, 1, 1], vec![false, true]).expect("grid"));
        assert_eq!(a.cells(), &[true, true]);
    }

    /// The record's runs alternate empty and occupied, starting with empty (0 when the first
    /// cell is occupied), and read back to the same grid.
    #[test]
    fn records_hold_runs_starting_with_empty_and_round_trip() {
        let cases = [
            (vec![true, true, false, true], vec![0, 2, 1, 1]),
            (vec![false, false, true, true], vec![2, 2]),
            (vec![false; 4], vec![4]),
            (vec![true; 4], vec![0, 4]),
        ];
        for (cells, runs) in cases {
            let grid = OccupancyGrid::from_cells([4, 1, 1], cells.clone()).expect("grid");
            let record = grid.to_record();
            assert_eq!(record, OccupancyRecord { dims: [4, 1, 1], runs }, "{cells:?}");
            assert_eq!(OccupancyGrid::from_record(&record), Ok(grid));
        }
    }

    /// A ray without a direction, an empty stretch or a NaN end sees nothing.
    #[test]
    fn degenerate_rays_see_no_span() {
        let grid = OccupancyGrid::full([4, 4, 4]);
        assert!(grid.occupied_span([0.5; 3], [0.0; 3], 0.0, 1.0).is_none());
        assert!(grid.occupied_span([0.5; 3], [1.0, 0.0, 0.0], 1.0, 1.0).is_none());
        assert!(grid.occupied_span([0.5; 3], [1.0, 0.0, 0.0], 1.0, 0.5).is_none());
        assert!(grid.occupied_span([0.5; 3], [1.0, 0.0, 0.0], 0.0, f32::NAN).is_none());
        assert!(grid.occupied_span([0.5; 3], [f32::NAN, 0.0, 0.0], 0.0, 1.0).is_none());
        // In a full grid the span is the whole stretch.
        assert_eq!(grid.occupied_span([0.0, 0.5, 0.5], [1.0, 0.0, 0.0], 0.0, 1.0), Some((0.0, 1.0)));
    }

    /// The median rule by hand: pixels 0, 1, 2, 3, 10 have the median 2, deviations below it
    /// 2, 1, 0 with median 1, so σ̂ = 1.4826; the floor rule takes over when it is higher.
    /// Non-finite pixels are left out, and an image of none has no dark level.
    #[test]
    fn the_median_threshold_by_hand() {
        let mut img = Image::zeros(6, 1);
        img.data.copy_from_slice(&[3.0, 0.0, 10.0, f32::NAN, 2.0, 1.0]);
        let t = dark_threshold(&img, &OccupancyConfig::default());
        assert!((t - (2.0 + 4.0 * 1.4826)).abs() < 1e-5, "{t}");
        let t = dark_threshold(&img, &OccupancyConfig { noise_sigmas: 0.0, floor: 0.5, ..Default::default() });
        assert!((t - 6.0).abs() < 1e-6, "{t}");
        let t = dark_threshold(&img, &OccupancyConfig { noise_sigmas: 1.0, floor: 0.0, ..Default::default() });
        assert!((t - 3.4826).abs() < 1e-5, "{t}");
        img.data.fill(f32::NAN);
        assert_eq!(dark_threshold(&img, &OccupancyConfig::default()), f32::INFINITY);
    }

    /// A camera that sees only black carves every cell it sees whole, and none whose footprint
    /// leaves its image; masked pixels carve nothing.
    #[test]
    fn dark_views_carve_the_cells_they_see_whole_and_masks_carve_none() {
        let aabb = Aabb::cube(DVec3::ZERO, 2.0);
        let cfg = OccupancyConfig { resolution: 8, dilate: 0, ..Default::default() };
        let wide = ring(1, 32).remove(0);
        let dark = Image::zeros(32, 32);
        let grid = OccupancyGrid::from_views(&aabb, &[(&wide, &dark)], &cfg);
        assert_eq!(grid.occupied_fraction(), 0.0, "the whole box is in view");
        let unused = vec![false; 32 * 32];
        // Footprints widened past the image's edges leave every cell partly outside it.
        let wide_margin = OccupancyConfig { margin_px: 20.0, ..cfg.clone() };
        assert_eq!(OccupancyGrid::from_views(&aabb, &[(&wide, &dark)], &wide_margin).occupied_fraction(), 1.0);
        let grid = OccupancyGrid::from_masked_views(&aabb, &[(&wide, &dark, Some(&unused))], &cfg);
        assert_eq!(grid.occupied_fraction(), 1.0, "masked pixels carve nothing");
        let used = vec![true; 32 * 32];
        let grid = OccupancyGrid::from_masked_views(&aabb, &[(&wide, &dark, Some(&used))], &cfg);
        assert_eq!(grid.occupied_fraction(), 0.0);
        // A lone bright pixel at the image's centre keeps the cells along its ray.
        let mut spot = dark.clone();
        spot.set(16, 16, 1.0);
        let grid = OccupancyGrid::from_views(&aabb, &[(&wide, &spot)], &cfg);
        let f = grid.occupied_fraction();
        assert!(f > 0.0 && f < 0.25, "{f}");
        // A long lens sees the middle of the box whole, its corners outside the image.
        let k = Intrinsics { width: 32, height: 32, fx: 128.0, fy: 128.0, cx: 15.5, cy: 15.5, skew: 0.0 };
        let narrow = Camera::look_at(k, DVec3::new(0.0, 5.0, 0.0), DVec3::ZERO, DVec3::X);
        let grid = OccupancyGrid::from_views(&aabb, &[(&narrow, &dark)], &cfg);
        assert!(!grid.is_occupied([0.55, 0.55, 0.55]), "the middle is carved");
        assert!(grid.is_occupied([0.01, 0.01, 0.01]) && grid.is_occupied([0.99, 0.01, 0.99]), "corners are kept");
        let dilated = OccupancyGrid::from_views(&aabb, &[(&narrow, &dark)], &OccupancyConfig { dilate: 1, ..cfg });
        assert!(dilated.occupied_fraction() > grid.occupied_fraction());
    }

    #[test]
    fn span_covers_occupied_cells_only() {
        let mut grid = OccupancyGrid { dims: [10, 10, 10], occupied: vec![false; 1000] };
        grid.occupied[(5 * 10 + 5) * 10 + 5] = true;
        // A ray along x through the centre of cell (5, 5, 5).
        let span = grid.occupied_span([-1.0, 0.55, 0.55], [1.0, 0.0, 0.0], 1.0, 2.0).expect("hit");
        assert!(span.0 <= 1.5 && span.0 >= 1.4, "{span:?}");
        assert!(span.1 >= 1.599 && span.1 <= 1.7, "{span:?}");
        assert!(grid.occupied_span([-1.0, 0.15, 0.55], [1.0, 0.0, 0.0], 1.0, 2.0).is_none());
    }
}
