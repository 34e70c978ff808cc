//! Visual-hull masking: a voxel whose centre projects onto a dark pixel in any view cannot
//! emit (the pixel integrates along a ray through it), so it is held at zero.
//!
//! "Dark" means the largest of the four pixels around the projected centre is at most
//! `threshold × the image's maximum`; the four-pixel test keeps the hull conservative at the
//! object's silhouette. Voxels that project outside a view's image are not judged by that view.

use fluidnerf_core::{Camera, Image};
use glam::DVec3;
use rayon::prelude::*;

use crate::Grid;

/// Default dark threshold, as a fraction of each image's maximum.
pub const DEFAULT_HULL_THRESHOLD: f64 = 0.02;

/// The support mask of `grid` (true = may be non-zero), carved by every view: `images[v]` is
/// seen by `cameras[v]`. Shapes: the mask has [`Grid::len`] entries, x fastest.
pub fn visual_hull(grid: &Grid, cameras: &[Camera], images: &[Image], threshold: f64) -> Vec<bool> {
    assert_eq!(cameras.len(), images.len(), "visual_hull: one image per camera");
    let [nx, ny, _] = grid.dims;
    let sp = grid.spacing();
    let limits: Vec<f32> = images.iter().map(|im| (im.min_max().1.max(0.0) as f64 * threshold) as f32).collect();
    let views: Vec<_> = cameras.iter().map(|c| (c, c.camera_from_world())).collect();
    let mut mask = vec![true; grid.len()];
    mask.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
        for j in 0..ny {
            for i in 0..nx {
                let c = grid.aabb.min + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * sp;
                let dark = views.iter().zip(images).zip(&limits).any(|(((cam, cfw), img), &limit)| {
                    let Some(uv) = cam.project_camera_point(cfw.transform_point3(c)) else { return false };
                    let (w, h) = (img.width as f64, img.height as f64);
                    if !(uv.x >= -0.5 && uv.y >= -0.5 && uv.x < w - 0.5 && uv.y < h - 0.5) {
                        return false;
                    }
                    let (c0, r0) = (uv.x.floor() as i64, uv.y.floor() as i64);
                    let mut brightest = f32::NEG_INFINITY;
                    for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (cc, rr) =
                            ((c0 + dc).clamp(0, img.width as i64 - 1), (r0 + dr).clamp(0, img.height as i64 - 1));
                        brightest = brightest.max(img.get(cc as usize, rr as usize));
                    }
                    brightest <= limit
                });
                slab[j * nx + i] = !dark;
            }
        }
    });
    mask
}
