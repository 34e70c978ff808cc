//! The voxel-driven bilinear splat (dissertation §6.4.1).
//!
//! Voxel `j` with centre `c_j` projects to the continuous pixel position `(u, v)` through the
//! camera (pose, pinhole, OpenCV distortion). Its weight on the four pixels around `(u, v)` is
//! `w_ij = γ_j · b_ij` with `b_ij` the bilinear interpolation weights (summing to 1) and
//!
//! ```text
//! γ_j = intensity_scale · V_vox · |∂(u, v)/∂(x_n, y_n)| · s / z³
//! ```
//!
//! where `(x_n, y_n) = (X/Z, Y/Z)` are normalised image coordinates, `z` the voxel's depth and
//! `s` its distance from the camera centre. `z³ / (s |∂(u,v)/∂(x_n,y_n)|)` is the volume swept
//! per unit length along the ray by one pixel's viewing cone at that depth (the pixel footprint,
//! `z² / (f_x f_y)` on the optical axis without distortion), so a voxel adds its emitted power
//! `E_j V_vox` spread over the pixels it covers, and `Σ_j w_ij g_j ≈ intensity_scale ∫ E ds`,
//! the scene's imaging law. Pixels outside the image are dropped; voxels behind the camera
//! contribute nothing.
//!
//! One splat per voxel centre (the dissertation's scheme) leaves gaps in the projection once a
//! voxel images larger than about 1.5 pixels, so such voxels are split into `s³` sub-voxels
//! (cell-centred within the voxel), each splatted the same way with `1/s³` of the weight; `s` is
//! chosen from the geometry ([`SplatProjector::auto_subdivisions`]) or set
//! ([`SplatProjector::with_subdivisions`]). Sub-voxels of one voxel share its unknown, so the
//! map stays a linear function of the voxel values with an exact adjoint.

use fluidnerf_core::num;
use fluidnerf_core::Camera;
use rayon::prelude::*;

use super::camera32::{distort, CameraF32, GridF32};
use super::{bands, check_shapes, scatter_parts, Grid, Projector, SparseRows};
use crate::ClassicalError;

/// One view's camera in f32, ready for the voxel loop.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SplatView {
    cam: CameraF32,
    /// `intensity_scale · V_vox · f_x · f_y`.
    gain: f32,
}

/// Where a voxel lands: the top-left pixel of its 2 × 2 block and the four weights
/// (top-left, top-right, bottom-left, bottom-right).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Footprint {
    pub col: i32,
    pub row: i32,
    pub w: [f32; 4],
}

impl SplatView {
    fn new(camera: &Camera, gain_base: f64) -> Self {
        // `gain_base` already holds 1 / subdivisions³.
        let k = camera.intrinsics;
        SplatView { cam: CameraF32::new(camera), gain: (gain_base * k.fx * k.fy) as f32 }
    }

    /// Projects `len ≤ CHUNK` consecutive voxels of a row (`p = base + (i0 + q) · step`) into
    /// `out`. Branch-free so that it vectorises; voxels whose 2 × 2 block misses the image (or
    /// that lie behind the camera) get `col = MISS`.
    #[inline(always)]
    fn project_chunk<const DISTORTED: bool>(&self, base: [f32; 3], step: [f32; 3], i0: usize, out: &mut Chunk) {
        let (w, h) = (self.cam.width as f32, self.cam.height as f32);
        for q in 0..CHUNK {
            let fi = (i0 + q) as f32;
            let x = base[0] + fi * step[0];
            let y = base[1] + fi * step[1];
            let z = base[2] + fi * step[2];
            let in_front = z > 1e-6;
            let zs = if in_front { z } else { 1.0 };
            let inv_z = 1.0 / zs;
            let (xn, yn) = (x * inv_z, y * inv_z);
            let (xd, yd, det) = if DISTORTED {
                let (xd, yd, j) = distort(&self.cam.dist, xn, yn);
                (xd, yd, j[0] * j[3] - j[1] * j[2])
            } else {
                (xn, yn, 1.0)
            };
            let u = self.cam.fx * xd + self.cam.skew * yd + self.cam.cx;
            let v = self.cam.fy * yd + self.cam.cy;
            // `u > -1` makes `u + 1` positive, so truncation is floor (and vectorises, unlike
            // `floor` on baseline x86-64). The comparisons are false for NaN.
            let hit = in_front & (u > -1.0) & (v > -1.0) & (u < w) & (v < h);
            let s = (x * x + y * y + zs * zs).sqrt();
            // Shifted by one so that every hit is positive and a miss is negative; the integer
            // split happens in the (scalar) visiting loop, float-to-int casts do not vectorise.
            out.u[q] = if hit { u + 1.0 } else { -1.0 };
            out.v[q] = v + 1.0;
            out.gamma[q] = self.gain * det.abs() * s * inv_z * inv_z * inv_z;
        }
    }

    /// The footprint of entry `q` of a projected chunk.
    #[inline(always)]
    fn footprint(c: &Chunk, q: usize) -> Footprint {
        let (us, vs, gamma) = (c.u[q], c.v[q], c.gamma[q]);
        // Both positive, so truncation is floor.
        let (cu, cv) = (us as i32, vs as i32);
        let (fu, fv) = (us - cu as f32, vs - cv as f32);
        let (a, b) = (gamma * (1.0 - fv), gamma * fv);
        Footprint { col: cu - 1, row: cv - 1, w: [a * (1.0 - fu), a * fu, b * (1.0 - fu), b * fu] }
    }

    /// The in-image pixels of a footprint as (pixel index, weight); out-of-image ones are
    /// skipped.
    #[inline(always)]
    fn for_each_pixel(&self, f: &Footprint, mut visit: impl FnMut(usize, f32)) {
        let (w, h) = (self.cam.width as i32, self.cam.height as i32);
        if f.col >= 0 && f.row >= 0 && f.col + 1 < w && f.row + 1 < h {
            let at = f.row as usize * self.cam.width + f.col as usize;
            visit(at, f.w[0]);
            visit(at + 1, f.w[1]);
            visit(at + self.cam.width, f.w[2]);
            visit(at + self.cam.width + 1, f.w[3]);
            return;
        }
        for (q, (dc, dr)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
            let (c, r) = (f.col + dc, f.row + dr);
            if c >= 0 && r >= 0 && c < w && r < h {
                visit(r as usize * self.cam.width + c as usize, f.w[q]);
            }
        }
    }
}

/// Voxels projected per batch.
const CHUNK: usize = 32;

/// A batch of projected voxels, structure of arrays: pixel position plus one (negative for
/// a miss) and the weight factor γ.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Chunk {
    u: [f32; CHUNK],
    v: [f32; CHUNK],
    gamma: [f32; CHUNK],
}

impl Default for Chunk {
    fn default() -> Self {
        Chunk { u: [-1.0; CHUNK], v: [0.0; CHUNK], gamma: [0.0; CHUNK] }
    }
}

/// The voxel-driven bilinear splat projector; see the module docs.
#[derive(Clone, Debug)]
pub struct SplatProjector {
    grid: Grid,
    cameras: Vec<Camera>,
    views: Vec<SplatView>,
    gf: GridF32,
    /// Sub-voxels per axis.
    sub: usize,
    intensity_scale: f64,
}

impl SplatProjector {
    /// A projector from `grid` to the images of `cameras`, with the scene's
    /// `intensity_scale` (pixel = scale × ∫ E ds).
    ///
    /// Voxels that image larger than 1.5 pixels are split into `s³` sub-voxels (`s` =
    /// ⌈largest voxel image / 1.5 px⌉, at most 8), each splatted with `1/s³` of the weight, so the
    /// projection has no gaps at any resolution; [`SplatProjector::auto_subdivisions`] gives
    /// `s`, and [`SplatProjector::with_subdivisions`] sets it (1 is the dissertation's splat).
    pub fn new(grid: Grid, cameras: &[Camera], intensity_scale: f64) -> Result<Self, ClassicalError> {
        validate(&grid, cameras, intensity_scale)?;
        let sub = Self::auto_subdivisions(&grid, cameras);
        let gf = GridF32::new(&grid);
        let mut p = SplatProjector { grid, cameras: cameras.to_vec(), views: Vec::new(), gf, sub, intensity_scale };
        p.set_views();
        Ok(p)
    }

    /// Splits every voxel into `n³` sub-voxels (1 = one splat per voxel centre, the
    /// dissertation's scheme). Panics unless `1 ≤ n ≤ 16`.
    pub fn with_subdivisions(mut self, n: usize) -> Self {
        assert!((1..=16).contains(&n), "SplatProjector: subdivisions must be in 1..=16, got {n}");
        self.sub = n;
        self.set_views();
        self
    }

    /// Sub-voxels per axis in use.
    pub fn subdivisions(&self) -> usize {
        self.sub
    }

    /// The subdivision [`SplatProjector::new`] chooses: ⌈largest voxel image / 1.5 px⌉ (1..=8),
    /// with the voxel's image measured at the box corner nearest to each camera.
    pub fn auto_subdivisions(grid: &Grid, cameras: &[Camera]) -> usize {
        let side = grid.spacing().max_element();
        let px = cameras
            .iter()
            .map(|c| {
                let cfw = c.camera_from_world();
                let near = grid.aabb.corners().iter().map(|&p| cfw.transform_point3(p).z).fold(f64::INFINITY, f64::min);
                let depth = near.max(0.25 * (grid.aabb.centre() - c.centre()).length());
                side * c.intrinsics.fx.max(c.intrinsics.fy) / depth
            })
            .fold(0.0, f64::max);
        ((px / 1.5).ceil() as usize).clamp(1, 8)
    }

    fn set_views(&mut self) {
        let gain_base = self.intensity_scale * self.grid.voxel_volume() / (self.sub as f64).powi(3);
        self.views = self.cameras.iter().map(|c| SplatView::new(c, gain_base)).collect();
    }

    /// Sub-voxel centre offsets, in voxel sides, along each axis.
    fn offsets(&self) -> Vec<f32> {
        let s = self.sub;
        (0..s).map(|a| ((a as f64 + 0.5) / s as f64 - 0.5) as f32).collect()
    }

    /// Visits every voxel of z-slices `ks` that lands on view `view`'s image:
    /// `visit(voxel index, footprint)`.
    #[inline(always)]
    fn for_each_voxel(&self, view: usize, ks: std::ops::Range<usize>, visit: impl FnMut(usize, &Footprint)) {
        if self.views[view].cam.distorted {
            self.for_each_voxel_impl::<true>(view, ks, visit)
        } else {
            self.for_each_voxel_impl::<false>(view, ks, visit)
        }
    }

    #[inline(always)]
    fn for_each_voxel_impl<const DISTORTED: bool>(
        &self,
        view: usize,
        ks: std::ops::Range<usize>,
        mut visit: impl FnMut(usize, &Footprint),
    ) {
        let sv = &self.views[view];
        let [nx, ny, _] = self.grid.dims;
        let mut chunk = Chunk::default();
        let offs = self.offsets();
        for k in ks {
            for &oz in &offs {
                for &oy in &offs {
                    for &ox in &offs {
                        for j in 0..ny {
                            let (base, step) = sv.cam.row_start(&self.gf, j, k, [ox, oy, oz]);
                            let row0 = (k * ny + j) * nx;
                            for i0 in (0..nx).step_by(CHUNK) {
                                sv.project_chunk::<DISTORTED>(base, step, i0, &mut chunk);
                                for q in 0..CHUNK.min(nx - i0) {
                                    if chunk.u[q] >= 0.0 {
                                        visit(row0 + i0 + q, &SplatView::footprint(&chunk, q));
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// `out = A_v x` by a plain single-threaded loop over voxels in f64 through
    /// [`Camera::project`] and [`fluidnerf_core::Distortion::apply_with_jacobian`]: the straightforward
    /// implementation, kept as the reference the fast path is tested and benchmarked against.
    pub fn forward_reference(&self, view: usize, x: &[f32], out: &mut [f32]) {
        check_shapes(self, view, x.len(), out.len());
        out.fill(0.0);
        let cam = &self.cameras[view];
        let (w, h) = (cam.width() as i64, cam.height() as i64);
        let k = cam.intrinsics;
        let cfw = cam.camera_from_world();
        let gain = f64::from(self.views[view].gain) / (k.fx * k.fy);
        let [nx, ny, nz] = self.grid.dims;
        let sp = self.grid.spacing();
        let offs = self.offsets();
        let mut sub_offsets = Vec::new();
        for &c in &offs {
            for &b in &offs {
                for &a in &offs {
                    sub_offsets.push([a, b, c]);
                }
            }
        }
        for o in sub_offsets {
            let o = glam::DVec3::new(f64::from(o[0]), f64::from(o[1]), f64::from(o[2]));
            for kk in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let idx = (kk * ny + j) * nx + i;
                        let c = self.grid.aabb.min
                            + (glam::DVec3::new(i as f64 + 0.5, j as f64 + 0.5, kk as f64 + 0.5) + o) * sp;
                        let p = cfw.transform_point3(c);
                        let Some(uv) = cam.project_camera_point(p) else { continue };
                        let n = glam::DVec2::new(p.x / p.z, p.y / p.z);
                        let (_, jac) = cam.distortion.apply_with_jacobian(n);
                        let det = k.fx * k.fy * (jac.dxx * jac.dyy - jac.dxy * jac.dyx);
                        let gamma = gain * det.abs() * p.length() / (p.z * p.z * p.z);
                        let (u0, v0) = (uv.x.floor(), uv.y.floor());
                        let (fu, fv) = (uv.x - u0, uv.y - v0);
                        for (dc, dr, wt) in [
                            (0, 0, (1.0 - fu) * (1.0 - fv)),
                            (1, 0, fu * (1.0 - fv)),
                            (0, 1, (1.0 - fu) * fv),
                            (1, 1, fu * fv),
                        ] {
                            let (c, r) = (u0 as i64 + dc, v0 as i64 + dr);
                            if c >= 0 && r >= 0 && c < w && r < h {
                                out[(r * w + c) as usize] += (gamma * wt) as f32 * x[idx];
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Shared input checks of the projectors.
pub(crate) fn validate(grid: &Grid, cameras: &[Camera], intensity_scale: f64) -> Result<(), ClassicalError> {
    grid.aabb.validate()?;
    if cameras.is_empty() {
        return Err(ClassicalError::invalid("cameras", "at least one view is needed"));
    }
    for c in cameras {
        c.validate()?;
    }
    if !(intensity_scale > 0.0 && intensity_scale.is_finite()) {
        return Err(ClassicalError::invalid(
            "intensity scale",
            format!("must be positive, got {}", num(intensity_scale)),
        ));
    }
    if u32::try_from(grid.len()).is_err() {
        // Rows and kept footprints index voxels in 32 bits.
        return Err(ClassicalError::invalid(
            "grid",
            format!(
                "{:?} has {} voxels, more than the 2^32 a voxel method indexes; lower the resolution (--resolution)",
                grid.dims,
                grid.len()
            ),
        ));
    }
    Ok(())
}

impl Projector for SplatProjector {
    fn grid(&self) -> &Grid {
        &self.grid
    }

    fn cameras(&self) -> &[Camera] {
        &self.cameras
    }

    fn forward(&self, view: usize, x: &[f32], out: &mut [f32]) {
        check_shapes(self, view, x.len(), out.len());
        let sv = &self.views[view];
        let nz = self.grid.dims[2];
        // Scatter: each band of z-slices accumulates into its own image, then the images are
        // summed; images are small next to the volume.
        // Neighbouring voxels mostly land on the same pixels; alternating between two images
        // by voxel parity breaks the read-modify-write chains through memory.
        let m = out.len();
        let partials: Vec<Vec<f32>> = bands(nz, scatter_parts())
            .into_par_iter()
            .map(|ks| {
                let mut img = vec![0f32; 2 * m];
                self.for_each_voxel(view, ks, |idx, f| {
                    let g = x[idx];
                    if g != 0.0 {
                        let half = &mut img[(idx & 1) * m..][..m];
                        sv.for_each_pixel(f, |pix, w| half[pix] += w * g);
                    }
                });
                img
            })
            .collect();
        out.par_chunks_mut(4096).enumerate().for_each(|(c, chunk)| {
            let off = c * 4096;
            for (q, o) in chunk.iter_mut().enumerate() {
                *o = partials.iter().map(|p| p[off + q] + p[m + off + q]).sum();
            }
        });
    }

    fn back_add(&self, view: usize, y: &[f32], out: &mut [f32], col_sums: Option<&mut [f32]>) {
        check_shapes(self, view, out.len(), y.len());
        let sv = &self.views[view];
        let [nx, ny, _] = self.grid.dims;
        let slab = nx * ny;
        // Gather: every voxel reads its own four pixels, so z-slices are independent.
        match col_sums {
            None => out.par_chunks_mut(slab).enumerate().for_each(|(k, o)| {
                self.for_each_voxel(view, k..k + 1, |idx, f| {
                    let mut acc = 0.0;
                    sv.for_each_pixel(f, |pix, w| acc += w * y[pix]);
                    o[idx - k * slab] += acc;
                });
            }),
            Some(cs) => {
                assert_eq!(cs.len(), out.len(), "column-sum buffer has the wrong length");
                out.par_chunks_mut(slab).zip(cs.par_chunks_mut(slab)).enumerate().for_each(|(k, (o, c))| {
                    self.for_each_voxel(view, k..k + 1, |idx, f| {
                        let (mut acc, mut sum) = (0.0, 0.0);
                        sv.for_each_pixel(f, |pix, w| {
                            acc += w * y[pix];
                            sum += w;
                        });
                        o[idx - k * slab] += acc;
                        c[idx - k * slab] += sum;
                    });
                })
            }
        }
    }

    fn rows(&self, view: usize) -> SparseRows {
        let sv = &self.views[view];
        let n_pix = sv.cam.width * sv.cam.height;
        let nz = self.grid.dims[2];
        let mut ptr = vec![0u64; n_pix + 1];
        self.for_each_voxel(view, 0..nz, |_, f| sv.for_each_pixel(f, |pix, _| ptr[pix + 1] += 1));
        for i in 0..n_pix {
            ptr[i + 1] += ptr[i];
        }
        let nnz = ptr[n_pix] as usize;
        let mut cols = vec![0u32; nnz];
        let mut vals = vec![0f32; nnz];
        let mut fill: Vec<u64> = ptr[..n_pix].to_vec();
        self.for_each_voxel(view, 0..nz, |idx, f| {
            sv.for_each_pixel(f, |pix, w| {
                let at = fill[pix] as usize;
                cols[at] = idx as u32;
                vals[at] = w;
                fill[pix] += 1;
            })
        });
        let mut rows = SparseRows { ptr, cols, vals };
        if self.sub > 1 {
            rows.merge_duplicates();
        }
        rows
    }

    fn rows_bytes_estimate(&self, view: usize) -> usize {
        self.grid.len() * 4 * 8 * self.sub.pow(3) + (self.view_len(view) + 1) * 16
    }

    fn bytes(&self) -> usize {
        std::mem::size_of::<SplatView>() * self.views.len()
    }

    fn scratch_bytes(&self, view: usize) -> usize {
        2 * scatter_parts() * self.view_len(view) * 4
    }
}

// Keep the f32 fast path honest against the f64 reference (the public test suite also checks
// the imaging scale against the renderer).
#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::{Aabb, Distortion, Intrinsics};
    use glam::DVec3;

    #[test]
    fn fast_forward_matches_reference_loop() {
        let grid = Grid::new([12, 10, 9], Aabb::cube(DVec3::ZERO, 2.0));
        let k = Intrinsics { width: 30, height: 26, fx: 90.0, fy: 92.0, cx: 14.5, cy: 12.2, skew: 0.3 };
        let mut cam = Camera::look_at(k, DVec3::new(0.4, -6.0, 1.0), DVec3::ZERO, DVec3::Z);
        cam.distortion = Distortion { k1: -0.2, k2: 0.05, p1: 1e-3, p2: -2e-3, ..Default::default() };
        let p = SplatProjector::new(grid, &[cam], 1.7).expect("valid");
        let x: Vec<f32> = (0..grid.len()).map(|i| ((i * 37) % 11) as f32 * 0.1).collect();
        let mut a = vec![0f32; p.view_len(0)];
        let mut b = a.clone();
        p.forward(0, &x, &mut a);
        p.forward_reference(0, &x, &mut b);
        let peak = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(peak > 0.0);
        for (u, v) in a.iter().zip(&b) {
            assert!((u - v).abs() <= 1e-4 * peak, "{u} vs {v}");
        }
    }
}
