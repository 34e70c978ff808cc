//! Small scenes for examples and tests (not part of the stable API).

use std::path::Path;

use fluidnerf_core::Camera;

/// Writes a tiny scene into `dir`: a Gaussian blob seen by 6 pinhole cameras of 32² px on a
/// ring, one of them held out, with its ground truth at 24³.
pub fn small_scene(dir: &Path) -> Result<(), Box<dyn std::error::Error>> {
    use fluidnerf_core::glam::DVec3;
    use fluidnerf_core::{Aabb, Frame, Intrinsics, Scene, TruthRef, Volume};
    let aabb = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
    let blob = |p: DVec3| (-(p - DVec3::new(0.2, -0.1, 0.0)).length_squared() / (2.0 * 0.3 * 0.3)).exp() as f32;
    let truth = Volume::from_fn([24, 24, 24], aabb, blob);
    std::fs::create_dir_all(dir.join("images"))?;
    std::fs::create_dir_all(dir.join("truth"))?;
    fluidnerf_io::volume::write_npy(&dir.join("truth/t0.npy"), &truth)?;
    let k = Intrinsics { width: 32, height: 32, fx: 40.0, fy: 40.0, cx: 15.5, cy: 15.5, skew: 0.0 };
    let mut frames = Vec::new();
    for i in 0..6 {
        let a = i as f64 * std::f64::consts::TAU / 6.0;
        let camera = Camera::look_at(k, DVec3::new(5.0 * a.cos(), 0.3, 5.0 * a.sin()), DVec3::ZERO, DVec3::Y);
        let image = fluidnerf_core::render_image(&truth, &camera, &aabb, &fluidnerf_core::RenderSettings::default())?;
        let file = format!("images/c{i}.tiff");
        fluidnerf_io::image::write_tiff_f32(&dir.join(&file), &image)?;
        frames.push(Frame { file_path: file.into(), camera, time: None, camera_name: None, holdout: i == 3 });
    }
    let scene = Scene {
        root: dir.to_path_buf(),
        aabb,
        units: "mm".into(),
        intensity_scale: 1.0,
        frames,
        truth: vec![TruthRef { time: None, file_path: "truth/t0.npy".into() }],
    };
    fluidnerf_io::scene::save_scene(&scene, dir)?;
    Ok(())
}
