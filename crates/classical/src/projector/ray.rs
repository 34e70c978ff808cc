//! The ray-driven projector: each pixel's value is `intensity_scale × ∫ E ds` along the ray
//! through its centre, with E the trilinear interpolant of the grid ([`Volume::sample`]: between
//! cell centres, clamped to the outermost centres inside the box, zero outside), integrated by
//! the midpoint rule with a fixed step (default half the smallest voxel side).
//!
//! Forward is a gather over pixels (parallel over image rows). The adjoint scatters into the
//! grid; each band of image rows scatters into its own copy of the grid and the copies are
//! summed, so it needs one grid of scratch per thread.
//!
//! [`Volume::sample`]: fluidnerf_core::Volume::sample

use fluidnerf_core::num;
use fluidnerf_core::Camera;
use rayon::prelude::*;

use super::{bands, check_shapes, scatter_parts, splat::validate, Grid, Projector, SparseRows};
use crate::ClassicalError;

/// A pixel ray in grid coordinates (`g = (p − min) / spacing − ½`, so voxel centres sit at
/// integers), clipped to the box: samples at `start + (q + ½) · step` for `q < n`.
#[derive(Clone, Copy, Debug, Default)]
struct GridRay {
    start: [f32; 3],
    step: [f32; 3],
    n: u32,
    /// `intensity_scale × ds` in world units.
    weight: f32,
}

/// The ray-driven trilinear projector; see the module docs.
#[derive(Clone, Debug)]
pub struct RayProjector {
    grid: Grid,
    cameras: Vec<Camera>,
    /// Per view, per pixel (row-major).
    rays: Vec<Vec<GridRay>>,
}

impl RayProjector {
    /// A projector from `grid` to the images of `cameras` with the scene's `intensity_scale`,
    /// sampling each ray every `step_fraction` × the smallest voxel side (0.5 is a good
    /// default: finer costs time, coarser aliases). Fails if a pixel cannot be undistorted.
    pub fn new(
        grid: Grid,
        cameras: &[Camera],
        intensity_scale: f64,
        step_fraction: f64,
    ) -> Result<Self, ClassicalError> {
        validate(&grid, cameras, intensity_scale)?;
        if !(step_fraction > 0.0 && step_fraction <= 4.0) {
            return Err(ClassicalError::invalid(
                "ray step",
                format!("fraction must be in (0, 4], got {}", num(step_fraction)),
            ));
        }
        let sp = grid.spacing();
        let step = step_fraction * sp.min_element();
        let rays = cameras
            .iter()
            .enumerate()
            .map(|(c, cam)| {
                let (w, h) = (cam.width(), cam.height());
                (0..w * h)
                    .into_par_iter()
                    .map(|pix| {
                        let ray = cam.pixel_ray((pix % w) as f64, (pix / w) as f64)?;
                        let Some((s0, s1)) = grid.aabb.intersect(&ray) else { return Ok(GridRay::default()) };
                        let n = ((s1 - s0) / step).ceil().max(1.0);
                        let ds = (s1 - s0) / n;
                        let g0 = (ray.at(s0) - grid.aabb.min) / sp - 0.5;
                        let gd = ray.dir * ds / sp;
                        Ok(GridRay {
                            start: [g0.x as f32, g0.y as f32, g0.z as f32],
                            step: [gd.x as f32, gd.y as f32, gd.z as f32],
                            n: n as u32,
                            weight: (intensity_scale * ds) as f32,
                        })
                    })
                    .collect::<Result<Vec<_>, fluidnerf_core::CoreError>>()
                    .map_err(|e| ClassicalError::invalid(format!("camera {c}"), e.to_string()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(RayProjector { grid, cameras: cameras.to_vec(), rays })
    }

    /// Visits the trilinear taps of every sample of `ray`: `visit(voxel index, weight)`.
    #[inline(always)]
    fn for_each_tap(&self, ray: &GridRay, mut visit: impl FnMut(usize, f32)) {
        let [nx, ny, nz] = self.grid.dims;
        let hi = [(nx - 1) as f32, (ny - 1) as f32, (nz - 1) as f32];
        for q in 0..ray.n {
            let t = q as f32 + 0.5;
            let mut i0 = [0usize; 3];
            let mut i1 = [0usize; 3];
            let mut f = [0f32; 3];
            for a in 0..3 {
                let c = (ray.start[a] + t * ray.step[a]).clamp(0.0, hi[a]);
                let fl = c.floor();
                i0[a] = fl as usize;
                i1[a] = if fl < hi[a] { i0[a] + 1 } else { i0[a] };
                f[a] = c - fl;
            }
            let w = ray.weight;
            let (gx, gy, gz) = (f[0], f[1], f[2]);
            let idx = |i: usize, j: usize, k: usize| (k * ny + j) * nx + i;
            let wy0z0 = w * (1.0 - gy) * (1.0 - gz);
            let wy1z0 = w * gy * (1.0 - gz);
            let wy0z1 = w * (1.0 - gy) * gz;
            let wy1z1 = w * gy * gz;
            visit(idx(i0[0], i0[1], i0[2]), wy0z0 * (1.0 - gx));
            visit(idx(i1[0], i0[1], i0[2]), wy0z0 * gx);
            visit(idx(i0[0], i1[1], i0[2]), wy1z0 * (1.0 - gx));
            visit(idx(i1[0], i1[1], i0[2]), wy1z0 * gx);
            visit(idx(i0[0], i0[1], i1[2]), wy0z1 * (1.0 - gx));
            visit(idx(i1[0], i0[1], i1[2]), wy0z1 * gx);
            visit(idx(i0[0], i1[1], i1[2]), wy1z1 * (1.0 - gx));
            visit(idx(i1[0], i1[1], i1[2]), wy1z1 * gx);
        }
    }
}

impl Projector for RayProjector {
    fn grid(&self) -> &Grid {
        &self.grid
    }

    fn cameras(&self) -> &[Camera] {
        &self.cameras
    }

    fn forward(&self, view: usize, x: &[f32], out: &mut [f32]) {
        check_shapes(self, view, x.len(), out.len());
        let w = self.cameras[view].width();
        let rays = &self.rays[view];
        out.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
            for (c, o) in row.iter_mut().enumerate() {
                let mut acc = 0f32;
                self.for_each_tap(&rays[r * w + c], |j, wt| acc += wt * x[j]);
                *o = acc;
            }
        });
    }

    fn back_add(&self, view: usize, y: &[f32], out: &mut [f32], col_sums: Option<&mut [f32]>) {
        check_shapes(self, view, out.len(), y.len());
        let rays = &self.rays[view];
        let n = out.len();
        let with_sums = col_sums.is_some();
        let partials: Vec<(Vec<f32>, Vec<f32>)> = bands(rays.len(), scatter_parts())
            .into_par_iter()
            .map(|pixels| {
                let mut acc = vec![0f32; n];
                let mut sums = if with_sums { vec![0f32; n] } else { Vec::new() };
                for pix in pixels {
                    let yi = y[pix];
                    if with_sums {
                        self.for_each_tap(&rays[pix], |j, wt| {
                            acc[j] += wt * yi;
                            sums[j] += wt;
                        });
                    } else if yi != 0.0 {
                        self.for_each_tap(&rays[pix], |j, wt| acc[j] += wt * yi);
                    }
                }
                (acc, sums)
            })
            .collect();
        const CHUNK: usize = 1 << 14;
        out.par_chunks_mut(CHUNK).enumerate().for_each(|(c, o)| {
            for (acc, _) in &partials {
                for (a, b) in o.iter_mut().zip(&acc[c * CHUNK..]) {
                    *a += b;
                }
            }
        });
        if let Some(cs) = col_sums {
            assert_eq!(cs.len(), n, "column-sum buffer has the wrong length");
            cs.par_chunks_mut(CHUNK).enumerate().for_each(|(c, o)| {
                for (_, sums) in &partials {
                    for (a, b) in o.iter_mut().zip(&sums[c * CHUNK..]) {
                        *a += b;
                    }
                }
            });
        }
    }

    fn rows(&self, view: usize) -> SparseRows {
        let w = self.cameras[view].width();
        let rays = &self.rays[view];
        // Image rows in parallel; taps of one ray merged so each voxel appears once per row.
        let per_row: Vec<(Vec<u64>, Vec<u32>, Vec<f32>)> = (0..rays.len() / w)
            .into_par_iter()
            .map(|r| {
                let mut lens = Vec::with_capacity(w);
                let mut cols = Vec::new();
                let mut vals = Vec::new();
                let mut taps: Vec<(u32, f32)> = Vec::new();
                for c in 0..w {
                    taps.clear();
                    self.for_each_tap(&rays[r * w + c], |j, wt| {
                        if wt > 0.0 {
                            taps.push((j as u32, wt))
                        }
                    });
                    taps.sort_unstable_by_key(|t| t.0);
                    let before = cols.len();
                    for &(j, wt) in &taps {
                        if cols.len() > before && *cols.last().unwrap_or(&u32::MAX) == j {
                            if let Some(v) = vals.last_mut() {
                                *v += wt;
                            }
                        } else {
                            cols.push(j);
                            vals.push(wt);
                        }
                    }
                    lens.push((cols.len() - before) as u64);
                }
                (lens, cols, vals)
            })
            .collect();
        let mut out = SparseRows { ptr: vec![0], cols: Vec::new(), vals: Vec::new() };
        for (lens, cols, vals) in per_row {
            for l in lens {
                let last = *out.ptr.last().unwrap_or(&0);
                out.ptr.push(last + l);
            }
            out.cols.extend(cols);
            out.vals.extend(vals);
        }
        out
    }

    fn rows_bytes_estimate(&self, view: usize) -> usize {
        // About 4 distinct voxels per sample after merging the 8 taps of neighbouring samples.
        let samples: usize = self.rays[view].iter().map(|r| r.n as usize).sum();
        samples * 4 * 8 + (self.view_len(view) + 1) * 8
    }

    fn bytes(&self) -> usize {
        self.rays.iter().map(|r| r.len() * std::mem::size_of::<GridRay>()).sum()
    }

    fn scratch_bytes(&self, _view: usize) -> usize {
        2 * scatter_parts() * self.grid.len() * 4
    }
}
