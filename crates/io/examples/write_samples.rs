//! Writes sample files for the external checks in `tests/fixtures/` (the Python `vtk` and
//! OpenCV packages reading what we write):
//!
//! ```text
//! cargo run --release -p fluidnerf-io --example write_samples -- OUT_DIR
//! python3 crates/io/tests/fixtures/check_vti_with_vtk.py OUT_DIR/sample.vti
//! python3 crates/io/tests/fixtures/check_opencv_readback.py OUT_DIR
//! ```
//!
//! `sample.vti`: 5 × 4 × 3 voxels filling the box [−1, 3] × [2, 4.5] × [0.5, 1.7], value at
//! voxel (i, j, k) = i + 10 j + 100 k. `calib.yml`/`calib.json`: the cameras of
//! `opencv_two_cameras.yml` written back by `write_opencv`.

use std::path::PathBuf;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Volume};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).ok_or("usage: write_samples OUT_DIR")?);
    let aabb = Aabb::new(DVec3::new(-1.0, 2.0, 0.5), DVec3::new(3.0, 4.5, 1.7));
    let mut v = Volume::zeros([5, 4, 3], aabb);
    for k in 0..3 {
        for j in 0..4 {
            for i in 0..5 {
                let idx = v.index(i, j, k);
                v.data[idx] = (i + 10 * j + 100 * k) as f32;
            }
        }
    }
    fluidnerf_io::volume::write_vti(&out.join("sample.vti"), &v)?;
    let fixtures = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    let cams = fluidnerf_io::calib::read_opencv(&fixtures.join("opencv_two_cameras.yml"))?;
    fluidnerf_io::calib::write_opencv(&out.join("calib.yml"), &cams)?;
    fluidnerf_io::calib::write_opencv(&out.join("calib.json"), &cams)?;
    Ok(())
}
