//! Visual-hull masking: a voxel whose centre projects onto a dark pixel in any view cannot
//! emit (the pixel integrates along a ray through it), so it is held at zero.
//!
//! "Dark" means the largest of the four pixels around the projected centre is at most the
//! image's dark level ([`dark_level`]): `threshold × the image's maximum`, or the image's floor
//! plus `noise_sigmas` deviations of its noise if that is higher, so that noisy images carve
//! their background too. The four-pixel test keeps the hull conservative at the object's
//! silhouette. Voxels that project outside a view's image are not judged by that view.

use fluidnerf_core::volume::dilate_mask;
use fluidnerf_core::{Camera, Image};
use glam::DVec3;
use rayon::prelude::*;

use crate::Grid;

/// Default dark threshold, as a fraction of each image's maximum.
pub const DEFAULT_HULL_THRESHOLD: f64 = 0.02;

/// Default noise deviations above the image's floor that still count as dark.
pub const DEFAULT_HULL_NOISE_SIGMAS: f64 = 4.0;

/// The level at or below which a pixel of `image` counts as dark: `threshold ×` its maximum,
/// or, if higher, its background plus `noise_sigmas` standard deviations of its noise
/// ([`Image::background`], whose deviation reads noise clipped at the sensor's floor too and
/// reads 0 on noiseless images). With 5 % noise of the peak a 2 % threshold alone carves at
/// random: the brightest of four background pixels lies above it at most voxels and below it
/// at some. `noise_sigmas = 0` is the threshold alone.
pub fn dark_level(image: &Image, threshold: f64, noise_sigmas: f64) -> f32 {
    let by_max = image.min_max().1.max(0.0) as f64 * threshold;
    match image.background() {
        Some(b) if noise_sigmas > 0.0 && b.sigma > 0.0 => by_max.max(b.level + noise_sigmas * b.sigma) as f32,
        _ => by_max as f32,
    }
}

/// The support mask of `grid` (true = may be non-zero), carved by every view: `images[v]` is
/// seen by `cameras[v]`, and a pixel is dark at or below [`dark_level`]`(image, threshold,
/// noise_sigmas)`. The kept voxels are then dilated by `dilation` voxels (each step adds the 26
/// neighbours), so that a hull carved at a noise-aware level keeps the object's faint rim and
/// multiplicative methods do not pile the noise of the rays that only graze it onto its surface.
/// Shapes: the mask has [`Grid::len`] entries, x fastest.
pub fn visual_hull(
    grid: &Grid,
    cameras: &[Camera],
    images: &[Image],
    threshold: f64,
    noise_sigmas: f64,
    dilation: usize,
) -> Vec<bool> {
    assert_eq!(cameras.len(), images.len(), "visual_hull: one image per camera");
    let [nx, ny, _] = grid.dims;
    let sp = grid.spacing();
    let limits: Vec<f32> = images.iter().map(|im| dark_level(im, threshold, noise_sigmas)).collect();
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
    dilate_mask(&mut mask, grid.dims, dilation);
    mask
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A 64² image of `background` with a bright square of 1 + `background` on `covered` of
    /// its rows, Gaussian noise of deviation `sigma` added (Box–Muller), clipped at 0 if asked.
    fn image(background: f32, covered: f64, sigma: f32, clip: bool) -> Image {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut img = Image::zeros(64, 64);
        for r in 0..64 {
            for c in 0..64 {
                let object = (r as f64) < covered * 64.0 && (8..56).contains(&c);
                let (u, v): (f32, f32) = (rng.random(), rng.random());
                let g = (-2.0 * (1.0 - u).ln()).sqrt() * (std::f32::consts::TAU * v).cos();
                let p = background + if object { 1.0 } else { 0.0 } + sigma * g;
                img.set(c, r, if clip { p.max(0.0) } else { p });
            }
        }
        img
    }

    /// A row of nine voxels (centres x = −4 … 4) seen by one camera 10 units away whose
    /// pixels are one unit there: centre x lands at column x + 3.25 of a 6 × 1 image. A voxel
    /// is carved when the brighter of its two pixel columns is at most the dark level (a pixel
    /// exactly at it counts as dark); voxels outside the image are not judged by it.
    #[test]
    fn a_voxel_is_carved_where_its_pixels_are_dark_and_kept_outside_the_image() {
        use fluidnerf_core::{Aabb, Intrinsics};
        let grid = Grid::new([9, 1, 1], Aabb::new(DVec3::new(-4.5, -0.5, -0.5), DVec3::new(4.5, 0.5, 0.5)));
        let k = Intrinsics { width: 6, height: 1, fx: 10.0, fy: 10.0, cx: 3.25, cy: 0.0, skew: 0.0 };
        let camera = Camera::look_at(k, DVec3::new(0.0, 0.0, 10.0), DVec3::ZERO, DVec3::Y);
        assert!((camera.project(DVec3::new(1.0, 0.0, 0.0)).unwrap().x - 4.25).abs() < 1e-9);
        let mut img = Image::zeros(6, 1);
        img.data.copy_from_slice(&[0.0, 0.0, 0.02, 0.0, 1.0, 0.0]);
        // Columns −0.75 (outside), 0.25, 1.25, 2.25, 3.25, 4.25, 5.25, 6.25 and 7.25 (outside).
        let want = [true, false, false, false, true, true, false, true, true];
        let hull = visual_hull(&grid, std::slice::from_ref(&camera), std::slice::from_ref(&img), 0.02, 0.0, 0);
        assert_eq!(hull, want);
        let dilated = visual_hull(&grid, std::slice::from_ref(&camera), std::slice::from_ref(&img), 0.02, 0.0, 1);
        assert_eq!(dilated, [true, true, false, true, true, true, true, true, true]);
        // A lower threshold keeps the voxels whose brightest pixel is 0.02.
        let hull = visual_hull(&grid, std::slice::from_ref(&camera), std::slice::from_ref(&img), 0.01, 0.0, 0);
        assert_eq!(hull, [true, false, true, true, true, true, false, true, true]);
        // A second view that sees nothing dark carves nothing more; one voxel dark in any view
        // is carved.
        let bright = Image { width: 6, height: 1, data: vec![1.0; 6] };
        let both = visual_hull(&grid, &[camera.clone(), camera], &[bright, img], 0.02, 0.0, 0);
        assert_eq!(both, want);
    }

    /// An image whose every pixel is negative has a dark level of zero, not a negative one.
    #[test]
    fn a_negative_image_is_dark_at_zero() {
        let img = Image { width: 2, height: 1, data: vec![-1.0, -0.5] };
        assert_eq!(dark_level(&img, 0.02, 0.0), 0.0);
    }

    #[test]
    fn dilation_adds_the_26_neighbours_per_step() {
        let dims = [5, 5, 5];
        let mut mask = vec![false; 125];
        mask[(2 * 5 + 2) * 5 + 2] = true;
        dilate_mask(&mut mask, dims, 1);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 27);
        assert!(mask[(5 + 1) * 5 + 1] && mask[(3 * 5 + 3) * 5 + 3] && !mask[0]);
        dilate_mask(&mut mask, dims, 1);
        assert!(mask.iter().all(|&m| m));
        let mut corner = vec![false; 125];
        corner[0] = true;
        dilate_mask(&mut corner, dims, 1);
        assert_eq!(corner.iter().filter(|&&m| m).count(), 8, "clipped at the grid's faces");
    }

    #[test]
    fn a_saved_configuration_without_the_noise_keys_keeps_the_threshold_alone() {
        let saved: crate::ProjectorConfig =
            serde_json::from_str(r#"{"kind": "auto", "visual_hull": true, "hull_threshold": 0.02}"#).expect("parses");
        assert_eq!((saved.hull_noise_sigmas, saved.hull_dilation), (0.0, 0));
        let new = crate::ProjectorConfig::default();
        assert_eq!((new.hull_noise_sigmas, new.hull_dilation), (DEFAULT_HULL_NOISE_SIGMAS, 1));
        let again: crate::ProjectorConfig = serde_json::from_str(&serde_json::to_string(&new).unwrap()).unwrap();
        assert_eq!(again, new);
    }

    #[test]
    fn noiseless_images_keep_the_threshold_alone() {
        let img = image(0.0, 0.2, 0.0, false);
        assert_eq!(dark_level(&img, 0.02, 4.0), 0.02);
        assert_eq!(dark_level(&img, 0.02, 0.0), 0.02);
    }

    /// Noise of 5 % of the object's brightness: the threshold alone (2 % of the maximum) lies
    /// inside the background's noise; with 4 deviations the level is about background + 4σ,
    /// whether the noise is clipped at the floor or not, whatever the offset, and stays below
    /// an object that covers most of the image.
    #[test]
    fn noisy_images_are_dark_up_to_four_deviations_of_their_noise() {
        let sigma = 0.05;
        for (background, covered, clip) in [(0.0, 0.2, true), (0.0, 0.2, false), (10.0, 0.2, false), (0.0, 0.8, true)] {
            let img = image(background, covered, sigma, clip);
            let level = dark_level(&img, 0.02, 4.0) as f64;
            let expected = background as f64 + 4.0 * sigma as f64;
            let case = format!("background {background}, {covered} covered, clipped {clip}: level {level:.4}");
            assert!((level - expected).abs() < 0.8 * sigma as f64, "{case}, expected about {expected:.4}");
            assert!(level < background as f64 + 0.5, "{case}: above the object");
            if background == 0.0 {
                assert!(dark_level(&img, 0.02, 0.0) < 0.03, "{case}: the threshold alone");
            }
        }
    }
}
