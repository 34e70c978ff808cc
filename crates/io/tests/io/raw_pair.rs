//! A raw volume and its sidecar are replaced together or not at all.

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Volume};
use fluidnerf_io::volume::{raw_sidecar_path, read_raw, write_raw};

/// The volume was renamed into place before its sidecar was written: when the sidecar could
/// not be (a full disk; here a folder in its place), the new data stayed beside the earlier
/// sidecar and was read with its grid and box. Now the earlier volume is left as it was.
#[test]
fn a_raw_volume_whose_sidecar_cannot_be_written_leaves_the_earlier_pair() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("volume.raw");
    let earlier = Volume::from_fn([4, 4, 4], Aabb::cube(DVec3::ZERO, 1.0), |p| p.x as f32);
    write_raw(&path, &earlier).expect("the earlier pair");
    let earlier_bytes = std::fs::read(&path).expect("reads the volume");
    let sidecar = raw_sidecar_path(&path);
    std::fs::remove_file(&sidecar).expect("removes");
    std::fs::create_dir_all(sidecar.join("x")).expect("a folder in the sidecar's place");
    let later = Volume::from_fn([4, 4, 4], Aabb::cube(DVec3::splat(5.0), 2.0), |p| p.y as f32 + 1.0);
    let e = write_raw(&path, &later).expect_err("the sidecar cannot be written");
    assert!(e.to_string().contains("volume.raw.json"), "{e}");
    assert_eq!(std::fs::read(&path).expect("reads the volume"), earlier_bytes, "the earlier volume is left");
    let names: Vec<_> = std::fs::read_dir(tmp.path()).expect("lists").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(names.len(), 2, "no temporary left: {names:?}");
    // Where both can be written, both are replaced.
    std::fs::remove_dir_all(&sidecar).expect("removes the folder");
    write_raw(&path, &later).expect("writes");
    assert_eq!(read_raw(&path).expect("reads").data, later.data);
}
