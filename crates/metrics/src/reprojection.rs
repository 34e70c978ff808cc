//! Reprojection metrics: render a reconstruction from a camera held out of the reconstruction
//! and compare the picture with the image that camera measured — the only accuracy measure
//! available on real data (dissertation chapter 9).
//!
//! The rendering is [`fluidnerf_core::render_image`] (line integrals through the scene's box,
//! scaled by the scene's `intensity_scale`, optionally supersampled), at the frame's time. The
//! images are compared with NRMSE (Eq. 6.18), PSNR, the global SSIM (Eq. 6.19) and the windowed
//! 2D SSIM (skimage's form), with the measured image's `max − min` as data range.

use fluidnerf_core::{render_image, Image, RenderSettings, ScalarField, Scene};
use serde::{Deserialize, Serialize};

use crate::{data_range_of, nrmse, psnr, ssim_2d, ssim_global, MetricsError, SsimParams};

/// Settings of the reprojection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReprojectionOptions {
    /// Rays per pixel along each image axis (anti-aliasing). Default 2.
    pub supersample: usize,
    /// Quadrature step in world units. Default (`None`): the box's smallest side / 256.
    pub step: Option<f64>,
    /// Windowed 2D SSIM settings (its `data_range` defaults to the measured image's range).
    pub ssim: SsimParams,
}

impl Default for ReprojectionOptions {
    fn default() -> Self {
        ReprojectionOptions { supersample: 2, step: None, ssim: SsimParams::default() }
    }
}

/// The metrics of one held-out frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReprojectionMetrics {
    /// Index of the frame in the scene.
    pub frame: usize,
    pub camera_name: Option<String>,
    pub time: Option<f64>,
    /// Pixels compared.
    pub pixels: usize,
    /// NaN (`null` in JSON) when undefined: a measured image that is zero throughout.
    #[serde(deserialize_with = "crate::report::null_as_nan")]
    pub nrmse: f64,
    /// Why `nrmse` is undefined, when it is ([`crate::NRMSE_UNDEFINED`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nrmse_undefined: Option<String>,
    #[serde(deserialize_with = "crate::report::null_as_inf")]
    pub psnr_db: f64,
    #[serde(deserialize_with = "crate::report::null_as_nan")]
    pub ssim_global: f64,
    /// Windowed 2D SSIM.
    #[serde(deserialize_with = "crate::report::null_as_nan")]
    pub ssim_windowed: f64,
    pub data_range: f64,
}

impl ReprojectionMetrics {
    /// A short label for tables: the camera name, else `frame N`.
    pub fn label(&self) -> String {
        self.camera_name.clone().unwrap_or_else(|| format!("frame {}", self.frame))
    }
}

/// A reprojection: the metrics and the rendered image (for pictures).
#[derive(Clone, Debug, PartialEq)]
pub struct Reprojection {
    pub metrics: ReprojectionMetrics,
    pub rendered: Image,
}

/// Renders `field` from frame `frame` of `scene` and compares it with `measured`, that frame's
/// image as the reconstruction was fitted to (preprocessed: linear, background subtracted,
/// flat-fielded), over the pixels `mask` uses (`true`; every pixel without one; see
/// [`compare_images`]). Errors if the image size differs from the camera's, the image is
/// smaller than the SSIM window, or rendering fails.
pub fn reproject(
    field: &dyn ScalarField,
    scene: &Scene,
    frame: usize,
    measured: &Image,
    mask: Option<&[bool]>,
    options: &ReprojectionOptions,
) -> Result<Reprojection, MetricsError> {
    assert!(frame < scene.frames.len(), "reproject: frame {frame} out of range ({} frames)", scene.frames.len());
    let f = &scene.frames[frame];
    let (w, h) = (f.camera.width(), f.camera.height());
    if (measured.width, measured.height) != (w, h) {
        return Err(MetricsError::invalid(
            format!("image of frame {frame} ({})", f.file_path.display()),
            format!("is {}x{} but its camera is {w}x{h}", measured.width, measured.height),
        ));
    }
    let settings = RenderSettings {
        step: options.step,
        supersample: options.supersample.max(1),
        time: f.time.unwrap_or(0.0),
        scale: scene.intensity_scale,
    };
    let rendered = render_image(field, &f.camera, &scene.aabb, &settings)
        .map_err(|error| MetricsError::Render { frame, error })?;
    // Scored, such a view gave an NRMSE of inf and an SSIM of NaN.
    if let Some(at) = rendered.data.iter().position(|v| !v.is_finite()) {
        return Err(MetricsError::Overflow { frame, value: rendered.data[at], col: at % w, row: at / w });
    }
    let metrics = compare_images(&rendered, measured, mask, &options.ssim)?;
    Ok(Reprojection {
        metrics: ReprojectionMetrics { frame, camera_name: f.camera_name.clone(), time: f.time, ..metrics },
        rendered,
    })
}

/// Reprojects onto every frame in `measured` (`(frame index, its image)`, typically the
/// scene's held-out frames), in order, over every pixel.
pub fn reproject_all(
    field: &dyn ScalarField,
    scene: &Scene,
    measured: &[(usize, Image)],
    options: &ReprojectionOptions,
) -> Result<Vec<Reprojection>, MetricsError> {
    measured.iter().map(|(i, img)| reproject(field, scene, *i, img, None, options)).collect()
}

/// Compares a rendered image with a measured one (same size): NRMSE, PSNR, global and windowed
/// SSIM, with the measured image's range as data range unless `ssim.data_range` is set. The
/// frame fields of the result are left empty (frame 0, no name, no time).
///
/// With a `mask` (`true` for the pixels to use, as a frame's mask) NRMSE, PSNR, the global
/// SSIM and the data range are taken over the used pixels alone and `pixels` counts them; the
/// windowed SSIM, whose windows need a whole image, over the images with the unused pixels set
/// to 0 in both.
pub fn compare_images(
    rendered: &Image,
    measured: &Image,
    mask: Option<&[bool]>,
    ssim: &SsimParams,
) -> Result<ReprojectionMetrics, MetricsError> {
    assert_eq!(
        (rendered.width, rendered.height),
        (measured.width, measured.height),
        "compare_images: image sizes differ"
    );
    assert!(mask.is_none_or(|m| m.len() == measured.data.len()), "compare_images: the mask's size differs");
    let used = |img: &Image| -> Vec<f32> {
        match mask {
            Some(m) => img.data.iter().zip(m).filter(|(_, &keep)| keep).map(|(&v, _)| v).collect(),
            None => img.data.clone(),
        }
    };
    let zeroed = |img: &Image| -> Vec<f32> {
        match mask {
            Some(m) => img.data.iter().zip(m).map(|(&v, &keep)| if keep { v } else { 0.0 }).collect(),
            None => img.data.clone(),
        }
    };
    let (r, p) = (used(rendered), used(measured));
    let range = ssim.data_range.unwrap_or_else(|| data_range_of(&p));
    let params = SsimParams { data_range: Some(range), ..*ssim };
    let nrmse = nrmse(&r, &p);
    let (rw, pw) = (zeroed(rendered), zeroed(measured));
    Ok(ReprojectionMetrics {
        frame: 0,
        camera_name: None,
        time: None,
        pixels: p.len(),
        nrmse,
        nrmse_undefined: crate::nrmse_undefined(nrmse),
        psnr_db: psnr(&r, &p, range),
        ssim_global: ssim_global(&r, &p, range),
        ssim_windowed: ssim_2d(&rw, &pw, measured.width, measured.height, &params)?,
        data_range: range,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::{Aabb, Camera, Frame, Intrinsics, Volume};
    use glam::DVec3;

    fn scene() -> Scene {
        let k = Intrinsics { width: 32, height: 24, fx: 70.0, fy: 70.0, cx: 15.5, cy: 11.5, skew: 0.0 };
        let frames = [DVec3::new(0.0, -6.0, 0.0), DVec3::new(6.0, 0.0, 0.5)]
            .iter()
            .enumerate()
            .map(|(i, &c)| Frame {
                camera: Camera::look_at(k, c, DVec3::ZERO, DVec3::Z),
                file_path: format!("{i}.png").into(),
                time: None,
                camera_name: Some(format!("cam{i}")),
                holdout: i == 1,
            })
            .collect();
        Scene {
            root: ".".into(),
            aabb: Aabb::cube(DVec3::ZERO, 2.0),
            units: "mm".into(),
            intensity_scale: 3.0,
            frames,
            truth: vec![],
        }
    }

    fn blob(p: DVec3) -> f32 {
        (-(p - DVec3::new(0.2, 0.0, -0.1)).length_squared() * 3.0).exp() as f32
    }

    #[test]
    fn the_truth_reprojects_onto_its_own_image() {
        let s = scene();
        let truth = Volume::from_fn([24, 24, 24], s.aabb, blob);
        let opts = ReprojectionOptions { supersample: 1, ..Default::default() };
        let settings = RenderSettings { scale: 3.0, ..Default::default() };
        let measured = render_image(&truth, &s.frames[1].camera, &s.aabb, &settings).expect("renders");
        let r = reproject(&truth, &s, 1, &measured, None, &opts).expect("reprojects");
        assert_eq!(r.metrics.nrmse, 0.0);
        assert!((r.metrics.ssim_windowed - 1.0).abs() < 1e-12);
        assert_eq!(r.metrics.label(), "cam1");
        assert_eq!(r.rendered, measured);
        // A dimmer reconstruction has exactly the relative intensity error.
        let dim = Volume::from_fn([24, 24, 24], s.aabb, |p| 0.8 * blob(p));
        let r = reproject(&dim, &s, 1, &measured, None, &opts).expect("reprojects");
        assert!((r.metrics.nrmse - 0.2).abs() < 1e-5, "NRMSE {}", r.metrics.nrmse);
        assert!(r.metrics.ssim_windowed < 1.0);
    }

    /// With a mask, pixels it leaves out do not count: a measured image spoilt there scores as
    /// the clean one over the rest, and without the mask it does not.
    #[test]
    fn masked_pixels_are_left_out_of_the_comparison() {
        let s = scene();
        let truth = Volume::from_fn([24, 24, 24], s.aabb, blob);
        let opts = ReprojectionOptions { supersample: 1, ..Default::default() };
        let settings = RenderSettings { scale: 3.0, ..Default::default() };
        let clean = render_image(&truth, &s.frames[1].camera, &s.aabb, &settings).expect("renders");
        let (w, h) = (clean.width, clean.height);
        // The left quarter of the columns hidden, and spoilt in the measured image.
        let mask: Vec<bool> = (0..w * h).map(|k| k % w >= w / 4).collect();
        let mut spoilt = clean.clone();
        for (v, &keep) in spoilt.data.iter_mut().zip(&mask) {
            if !keep {
                *v += 5.0;
            }
        }
        let r = reproject(&truth, &s, 1, &spoilt, Some(&mask), &opts).expect("reprojects");
        assert_eq!(r.metrics.nrmse, 0.0);
        assert_eq!(r.metrics.pixels, mask.iter().filter(|&&k| k).count());
        assert!((r.metrics.ssim_global - 1.0).abs() < 1e-12, "{}", r.metrics.ssim_global);
        assert!((r.metrics.ssim_windowed - 1.0).abs() < 1e-12, "{}", r.metrics.ssim_windowed);
        assert!(r.metrics.psnr_db.is_infinite());
        let unmasked = reproject(&truth, &s, 1, &spoilt, None, &opts).expect("reprojects");
        assert!(unmasked.metrics.nrmse > 0.1, "{}", unmasked.metrics.nrmse);
        assert_eq!(unmasked.metrics.pixels, w * h);
    }

    /// Every frame given is reprojected, in order, and its result names the frame, its camera
    /// and its time.
    #[test]
    fn every_frame_given_is_reprojected_with_its_frame_and_time() {
        let mut s = scene();
        s.frames[0].time = Some(0.5);
        s.frames[1].time = Some(1.5);
        let truth = Volume::from_fn([24, 24, 24], s.aabb, blob);
        let opts = ReprojectionOptions { supersample: 1, ..Default::default() };
        let measured: Vec<(usize, Image)> = [1, 0]
            .iter()
            .map(|&i| {
                let settings = RenderSettings { scale: 3.0, time: 0.0, ..Default::default() };
                (i, render_image(&truth, &s.frames[i].camera, &s.aabb, &settings).expect("renders"))
            })
            .collect();
        let all = reproject_all(&truth, &s, &measured, &opts).expect("reprojects");
        let seen: Vec<(usize, Option<f64>, String)> =
            all.iter().map(|r| (r.metrics.frame, r.metrics.time, r.metrics.label())).collect();
        assert_eq!(seen, vec![(1, Some(1.5), "cam1".to_string()), (0, Some(0.5), "cam0".to_string())]);
        assert!(all.iter().all(|r| r.metrics.nrmse == 0.0));
    }

    /// A data range set in the SSIM settings is the one PSNR and both SSIMs use.
    #[test]
    fn a_given_data_range_is_used_by_every_measure() {
        let data: Vec<f32> = (0..24 * 16).map(|k| ((k * 7) % 11) as f32 * 0.1).collect();
        let measured = Image { width: 24, height: 16, data };
        let mut rendered = measured.clone();
        rendered.data.iter_mut().enumerate().for_each(|(k, v)| *v = *v * 0.9 + (k % 3) as f32 * 0.01);
        let ssim = SsimParams { data_range: Some(4.0), ..Default::default() };
        let m = compare_images(&rendered, &measured, None, &ssim).expect("compares");
        assert_eq!(m.data_range, 4.0);
        assert_eq!(m.psnr_db, psnr(&rendered.data, &measured.data, 4.0));
        assert_eq!(m.ssim_global, ssim_global(&rendered.data, &measured.data, 4.0));
        assert_eq!(m.ssim_windowed, ssim_2d(&rendered.data, &measured.data, 24, 16, &ssim).expect("fits"));
        let own = compare_images(&rendered, &measured, None, &SsimParams::default()).expect("compares");
        assert!((own.data_range - 1.0).abs() < 1e-6, "{}", own.data_range);
        assert!((own.ssim_windowed - m.ssim_windowed).abs() > 1e-4);
        // With a mask, the default range is the used pixels' (0.5 to 1 here), and the windowed
        // SSIM takes it too, not the range of the images with the unused pixels set to 0.
        let mask: Vec<bool> = measured.data.iter().map(|&v| v >= 0.5).collect();
        let masked = compare_images(&rendered, &measured, Some(&mask), &SsimParams::default()).expect("compares");
        assert!((masked.data_range - 0.5).abs() < 1e-6, "{}", masked.data_range);
        let zeroed =
            |img: &Image| -> Vec<f32> { img.data.iter().zip(&mask).map(|(&v, &k)| if k { v } else { 0.0 }).collect() };
        let with_range = SsimParams { data_range: Some(masked.data_range), ..Default::default() };
        let expected = ssim_2d(&zeroed(&rendered), &zeroed(&measured), 24, 16, &with_range).expect("fits");
        assert_eq!(masked.ssim_windowed, expected);
        let with_zeros = ssim_2d(&zeroed(&rendered), &zeroed(&measured), 24, 16, &SsimParams::default()).expect("fits");
        assert!((with_zeros - expected).abs() > 1e-6, "{with_zeros} against {expected}");
    }

    #[test]
    fn image_size_must_match_the_camera() {
        let s = scene();
        let truth = Volume::from_fn([8, 8, 8], s.aabb, blob);
        let err = reproject(&truth, &s, 0, &Image::zeros(10, 10), None, &ReprojectionOptions::default());
        assert!(matches!(err, Err(MetricsError::Invalid { .. })));
    }
}
