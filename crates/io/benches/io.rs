//! Throughput of the IO paths the pipeline waits on: loading a scene (parsing + camera
//! validation + box visibility), loading its images in parallel, and volume files.
//!
//! `cargo bench --no-run -p fluidnerf-io`, then run `target/release/deps/io-<hash> --bench`.

// A benchmark reports on stdout.
#![allow(clippy::print_stdout)]

use std::time::Instant;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Distortion, Frame, Image, Intrinsics, Scene, Volume};
use fluidnerf_io::image::{write_png16_counts, write_tiff_f32};
use fluidnerf_io::scene::{load_images, load_scene, save_scene};
use fluidnerf_io::volume::{read_npy, write_npy, write_vti};

fn time<T>(what: &str, bytes: Option<usize>, repeats: usize, mut f: impl FnMut() -> T) -> T {
    let mut out = f();
    let t0 = Instant::now();
    for _ in 0..repeats {
        out = f();
    }
    let s = t0.elapsed().as_secs_f64() / repeats as f64;
    match bytes {
        Some(b) => println!("{what:<52} {:>9.2} ms  {:>8.1} MB/s", 1e3 * s, b as f64 / s / 1e6),
        None => println!("{what:<52} {:>9.2} ms", 1e3 * s),
    }
    out
}

/// `frames` frames; `cameras` distinct cameras (frame i uses camera i % cameras).
fn scene(root: &std::path::Path, frames: usize, cameras: usize, size: u32, ext: &str) -> Scene {
    let aabb = Aabb::cube(DVec3::ZERO, 40.0);
    let k = Intrinsics {
        width: size,
        height: size,
        fx: 1.2 * size as f64,
        fy: 1.2 * size as f64,
        cx: size as f64 / 2.0,
        cy: size as f64 / 2.0,
        skew: 0.0,
    };
    let frames = (0..frames)
        .map(|i| {
            let a = (i % cameras) as f64 * 0.7;
            let mut camera =
                Camera::look_at(k, DVec3::new(150.0 * a.cos(), 150.0 * a.sin(), 30.0), DVec3::ZERO, DVec3::Z);
            camera.distortion = Distortion { k1: -0.1, k2: 0.02, p1: 1e-4, ..Default::default() };
            Frame {
                camera,
                file_path: format!("images/{i:04}.{ext}").into(),
                time: Some((i / 8) as f64),
                camera_name: Some(format!("cam{}", i % 8)),
                holdout: false,
            }
        })
        .collect();
    Scene { root: root.to_path_buf(), aabb, units: "mm".into(), intensity_scale: 1.0, frames, truth: vec![] }
}

fn main() {
    let dir = tempfile::tempdir().expect("tempdir");
    println!("fluidnerf-io on {} threads", rayon::current_num_threads());

    let s = scene(dir.path(), 256, 256, 512, "png");
    save_scene(&s, dir.path()).expect("save");
    time("load_scene: 256 frames, 256 distorted cameras", None, 3, || load_scene(dir.path()).expect("load"));
    let d = dir.path().join("shared");
    save_scene(&scene(&d, 256, 8, 512, "png"), &d).expect("save");
    time("load_scene: 256 frames, 8 distorted cameras x 32 times", None, 3, || load_scene(&d).expect("load"));

    let n = 32;
    let size = 512usize;
    for ext in ["png", "tif"] {
        let d = dir.path().join(ext);
        let s = scene(&d, n, n, size as u32, ext);
        for f in &s.frames {
            let img = Image::from_vec(size, size, (0..size * size).map(|i| ((i * 7919) % 4096) as f32).collect());
            let p = s.resolve(&f.file_path);
            if ext == "png" {
                write_png16_counts(&p, &img).expect("png")
            } else {
                write_tiff_f32(&p, &img).expect("tiff")
            }
        }
        let bytes = n * size * size * 4;
        time(
            &format!("load_images: {n} x {size}² {}", if ext == "png" { "16-bit PNG" } else { "f32 TIFF" }),
            Some(bytes),
            3,
            || load_images(&s).expect("images"),
        );
    }

    let v = Volume::from_fn([128, 128, 128], Aabb::cube(DVec3::ZERO, 1.0), |p| p.length() as f32);
    let bytes = v.len() * 4;
    let p = dir.path().join("v.npy");
    time("write_npy 128³", Some(bytes), 3, || write_npy(&p, &v).expect("npy"));
    time("read_npy 128³", Some(bytes), 3, || read_npy(&p, v.aabb).expect("npy"));
    let p = dir.path().join("v.vti");
    time("write_vti 128³", Some(bytes), 3, || write_vti(&p, &v).expect("vti"));
    time("read_vti 128³", Some(bytes), 3, || fluidnerf_io::volume::read_vti(&p).expect("vti"));
}
