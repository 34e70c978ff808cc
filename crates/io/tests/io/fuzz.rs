//! Mutated and random inputs never panic the readers: `transforms.json`, OpenCV
//! `cv::FileStorage` (YAML, XML and JSON), MJPEG AVI video, COLMAP (text and binary), images
//! (PNG 8/16-bit, JPEG, TIFF 16-bit and float, DaVis `.im7`/`.imx`) and `.npy` volumes. Each reader gets valid files
//! written in code, then seeded byte mutations of them (flips, insertions of structural
//! characters, deletions, truncations, duplicated runs) and plain random bytes; it may refuse
//! them, but must return.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Distortion, Frame, Image, Intrinsics, Scene, Volume};
use fluidnerf_io::image::{decode_image, Linearisation};

/// xorshift64*: a tiny seeded generator, so every run tries the same inputs.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Bytes that change the structure of text formats, and values that stress binary ones.
const INTERESTING: &[&[u8]] = &[
    b"{",
    b"}",
    b"[",
    b"]",
    b"\"",
    b",",
    b":",
    b"-",
    b"0",
    b"1e308",
    b"-1",
    b"NaN",
    b"\n",
    b" ",
    b"\0",
    b"!!opencv-matrix",
    b"\xff\xff\xff\xff",
    b"\x00\x00\x00\x80",
    b"\xff\xff\xff\xff\xff\xff\xff\x7f",
];

fn mutate(rng: &mut Rng, seed: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = rng.below(v.len() + 1);
        match rng.below(6) {
            0 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] ^= 1 << rng.below(8);
            }
            1 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] = rng.next() as u8;
            }
            2 => {
                let piece = INTERESTING[rng.below(INTERESTING.len())];
                v.splice(at..at, piece.iter().copied());
            }
            3 if at < v.len() => {
                let end = (at + 1 + rng.below(16)).min(v.len());
                v.drain(at..end);
            }
            4 => v.truncate(at),
            _ if at < v.len() => {
                let end = (at + 1 + rng.below(32)).min(v.len());
                let run: Vec<u8> = v[at..end].to_vec();
                v.splice(at..at, run);
            }
            _ => {}
        }
    }
    v
}

/// Runs `read` on every seed, `rounds` mutations of the seeds, and random byte strings.
fn fuzz(name: &str, seeds: &[Vec<u8>], rounds: usize, mut read: impl FnMut(&[u8])) {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ name.len() as u64);
    for s in seeds {
        read(s);
    }
    for _ in 0..rounds {
        let seed = &seeds[rng.below(seeds.len())];
        read(&mutate(&mut rng, seed));
    }
    for _ in 0..rounds / 10 {
        let n = rng.below(256);
        let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
        read(&bytes);
    }
}

fn ring(n: usize) -> Vec<Camera> {
    let k = Intrinsics { width: 16, height: 12, fx: 20.0, fy: 20.0, cx: 7.5, cy: 5.5, skew: 0.0 };
    (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let mut c = Camera::look_at(k, DVec3::new(50.0 * a.cos(), 50.0 * a.sin(), 5.0), DVec3::ZERO, DVec3::Z);
            c.distortion = Distortion { k1: -0.01 * i as f64, ..Default::default() };
            c
        })
        .collect()
}

fn write_and(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).expect("writes");
}

#[test]
fn transforms_json_never_panics() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let frames = ring(3)
        .into_iter()
        .enumerate()
        .map(|(i, camera)| Frame {
            camera,
            file_path: PathBuf::from(format!("c{i}.png")),
            time: Some(i as f64),
            camera_name: Some(format!("cam{i}")),
            holdout: i == 2,
        })
        .collect();
    let scene = Scene {
        root: d.to_path_buf(),
        aabb: Aabb::cube(DVec3::ZERO, 10.0),
        units: "mm".into(),
        intensity_scale: 1.0,
        frames,
        truth: vec![],
    };
    fluidnerf_io::scene::save_scene(&scene, d).expect("saves");
    let file = d.join("transforms.json");
    let valid = std::fs::read(&file).expect("reads");
    let nerf = br#"{"camera_angle_x": 0.69, "w": 16.0, "h": 12.0, "aabb_scale": 4,
        "frames": [{"file_path": "./train/r_0", "rotation": 0.1,
        "transform_matrix": [[1,0,0,0],[0,0,-1,-50],[0,1,0,0],[0,0,0,1]]}]}"#
        .to_vec();
    fuzz("transforms", &[valid, nerf], 300, |bytes| {
        write_and(&file, bytes);
        let _ = fluidnerf_io::scene::load_scene(d);
    });
}

#[test]
fn opencv_files_never_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cams: Vec<(String, Camera)> = ring(2).into_iter().enumerate().map(|(i, c)| (format!("c{i}"), c)).collect();
    let mut seeds = Vec::new();
    for ext in ["yml", "json", "xml"] {
        let p = dir.path().join(format!("rig.{ext}"));
        fluidnerf_io::calib::write_opencv(&p, &cams).expect("writes");
        seeds.push(std::fs::read(&p).expect("reads"));
    }
    seeds.push(
        b"%YAML:1.0\nCamera_Matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 1., 0., 1., 1., 0., 0., 1. ]\nimage_Width: 4\nimage_Height: 4\nleft: {R: [1,0,0,0,1,0,0,0,1], T: [0,0,1]}\n"
            .to_vec(),
    );
    seeds.push(
        b"<?xml version=\"1.0\"?>\n<opencv_storage>\n<M1 type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt>\
          <data>1. 0. 1. 0. 1. 1. 0. 0. 1.</data></M1>\n<M2>1 0 1 0 1 1 0 0 1</M2><D2><_>0.1</_><_>0</_><_>0</_><_>0</_></D2>\
          <R>1 0 0 0 1 0 0 0 1</R><T>1 0 0</T><imageSize>4 4</imageSize>\n<cam><camera_matrix>1 0 1 0 1 1 0 0 1\
          </camera_matrix><rvec>0 0 0</rvec><tvec>0 0 1</tvec><image_width>4</image_width></cam></opencv_storage>\n"
            .to_vec(),
    );
    seeds.push(
        b"%YAML:1.0\ncameras:\n  - name: a\n    image_width: 4\n    image_height: 4\n    camera_matrix: [1, 0, 1, 0, 1, 1, 0, 0, 1]\n    rvec: [0, 0.1, 0]\n    tvec: [0, 0, 1]\n  - {image_width: 4, image_height: 4, camera_matrix: [1, 0, 1, 0, 1, 1, 0, 0, 1], R: [1, 0, 0, 0, 1, 0, 0, 0, 1], T: [0, 0, 1]}\n"
            .to_vec(),
    );
    seeds.push(
        b"%YAML:1.0\nM1: [1, 0, 1, 0, 1, 1, 0, 0, 1]\nM2: [1, 0, 1, 0, 1, 1, 0, 0, 1]\nD1: [0.1, 0, 0, 0, 0]\nR: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nT: [1, 0, 0]\nimageSize1: [4, 4]\nimage_width2: 4\nimage_height2: 4\nrvec1: [0, 0, 0.2]\ntvec1: [0, 0, 5]\n"
            .to_vec(),
    );
    // Deeply nested XML must not exhaust the stack.
    let deep = format!(
        "<?xml version=\"1.0\"?><opencv_storage>{}{}</opencv_storage>",
        "<a>".repeat(100_000),
        "</a>".repeat(100_000)
    );
    let p = dir.path().join("deep.xml");
    write_and(&p, deep.as_bytes());
    assert!(fluidnerf_io::calib::read_opencv(&p).is_err());
    let p = dir.path().join("deep.yml");
    write_and(&p, format!("%YAML:1.0\na: {}{}\n", "[".repeat(100_000), "]".repeat(100_000)).as_bytes());
    assert!(fluidnerf_io::calib::read_opencv(&p).is_err());
    for ext in ["yml", "json", "xml"] {
        let p = dir.path().join(format!("f.{ext}"));
        fuzz(ext, &seeds, 300, |bytes| {
            write_and(&p, bytes);
            let _ = fluidnerf_io::calib::read_opencv(&p);
        });
    }
}

#[test]
fn avi_files_never_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seed = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video/ramp_mjpeg.avi"))
        .expect("fixture");
    // Deeply nested lists must not exhaust the stack.
    let levels = 100_000u32;
    let mut nested = b"RIFF".to_vec();
    nested.extend_from_slice(&(4 + 12 * levels).to_le_bytes());
    nested.extend_from_slice(b"AVI ");
    for i in 0..levels {
        nested.extend_from_slice(b"LIST");
        nested.extend_from_slice(&(4 + 12 * (levels - 1 - i)).to_le_bytes());
        nested.extend_from_slice(b"movi");
    }
    let p = dir.path().join("f.avi");
    write_and(&p, &nested);
    assert!(fluidnerf_io::video::read_video(&p, &Default::default()).is_err());
    fuzz("avi", std::slice::from_ref(&seed), 300, |bytes| {
        write_and(&p, bytes);
        // An MJPEG AVI is read without ffmpeg; a mutated one may fall through to ffmpeg, which
        // is kept out of reach here.
        if bytes.starts_with(b"RIFF") && bytes.get(8..12) == Some(b"AVI ") {
            let _ = fluidnerf_io::video::read_video(&p, &Default::default());
        }
    });
}

#[test]
fn cine_files_never_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let seed = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video/ramp_8bit.cine"))
        .expect("fixture");
    // The headers and the offset table: where a mutation changes what is read, and where.
    let mut head = seed[..84].to_vec();
    head.extend_from_slice(&seed[84 + 12432..84 + 12432 + 32]);
    let p = dir.path().join("f.cine");
    fuzz("cine", std::slice::from_ref(&seed), 300, |bytes| {
        write_and(&p, bytes);
        let _ = fluidnerf_io::video::read_video(&p, &Default::default());
    });
    fuzz("cine-header", &[head], 300, |bytes| {
        // The mutated headers over the file's own, the mutated table over its table.
        let mut file = seed.clone();
        let table = 84 + 12432;
        for (k, &b) in bytes.iter().enumerate().take(84 + 32) {
            file[if k < 84 { k } else { table + k - 84 }] = b;
        }
        write_and(&p, &file);
        let _ = fluidnerf_io::video::read_video(&p, &Default::default());
    });
}

#[test]
fn mraw_headers_never_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video");
    let mraw = dir.path().join("f.mraw");
    std::fs::copy(fixtures.join("ramp_12bit.mraw"), &mraw).expect("copies");
    for header in ["ramp_12bit.cihx", "ramp_16bit.cih"] {
        let seed = std::fs::read(fixtures.join(header)).expect("fixture");
        let p = mraw.with_extension(Path::new(header).extension().expect("an extension"));
        fuzz(header, std::slice::from_ref(&seed), 300, |bytes| {
            write_and(&p, bytes);
            let _ = fluidnerf_io::video::read_video(&mraw, &Default::default());
        });
        std::fs::remove_file(&p).expect("removes");
    }
}

#[test]
fn colmap_models_never_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let named: Vec<(String, Camera)> = ring(2).into_iter().enumerate().map(|(i, c)| (format!("i{i}.png"), c)).collect();
    fluidnerf_io::calib::write_colmap_bin(d, &named).expect("writes");
    let cams_bin = std::fs::read(d.join("cameras.bin")).expect("reads");
    let imgs_bin = std::fs::read(d.join("images.bin")).expect("reads");
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/colmap");
    let cams_txt = std::fs::read(fixtures.join("cameras.txt")).expect("reads");
    let imgs_txt = std::fs::read(fixtures.join("images.txt")).expect("reads");

    fuzz("cameras.bin", std::slice::from_ref(&cams_bin), 250, |bytes| {
        write_and(&d.join("cameras.bin"), bytes);
        let _ = fluidnerf_io::calib::read_colmap(d);
    });
    write_and(&d.join("cameras.bin"), &cams_bin);
    fuzz("images.bin", std::slice::from_ref(&imgs_bin), 250, |bytes| {
        write_and(&d.join("images.bin"), bytes);
        let _ = fluidnerf_io::calib::read_colmap(d);
    });
    let t = tempfile::tempdir().expect("tempdir");
    write_and(&t.path().join("images.txt"), &imgs_txt);
    fuzz("cameras.txt", std::slice::from_ref(&cams_txt), 250, |bytes| {
        write_and(&t.path().join("cameras.txt"), bytes);
        let _ = fluidnerf_io::calib::read_colmap(t.path());
    });
    write_and(&t.path().join("cameras.txt"), &cams_txt);
    fuzz("images.txt", std::slice::from_ref(&imgs_txt), 250, |bytes| {
        write_and(&t.path().join("images.txt"), bytes);
        let _ = fluidnerf_io::calib::read_colmap(t.path());
    });
}

#[test]
fn images_never_panic() {
    use image::ImageEncoder;
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let img = Image::from_vec(6, 4, (0..24).map(|i| (i * 1000) as f32).collect());
    fluidnerf_io::image::write_png16_counts(&d.join("a.png"), &img).expect("png16");
    fluidnerf_io::image::write_tiff_f32(&d.join("a.tif"), &img).expect("tiff");
    image::GrayImage::from_raw(6, 4, (0..24).collect()).expect("buf").save(d.join("b.png")).expect("png8");
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
        .write_image(&[7u8; 3 * 8 * 8], 8, 8, image::ExtendedColorType::Rgb8)
        .expect("jpeg");
    let mut tiff16 = std::io::Cursor::new(Vec::new());
    tiff::encoder::TiffEncoder::new(&mut tiff16)
        .expect("enc")
        .write_image::<tiff::encoder::colortype::Gray16>(2, 2, &[0u16, 1, 2, 3])
        .expect("tiff16");
    let seeds = vec![
        std::fs::read(d.join("a.png")).expect("read"),
        std::fs::read(d.join("a.tif")).expect("read"),
        std::fs::read(d.join("b.png")).expect("read"),
        jpeg,
        tiff16.into_inner(),
    ];
    let p = d.join("x.img");
    fuzz("images", &seeds, 1000, |bytes| {
        let _ = decode_image(&p, bytes, Linearisation::Srgb);
    });
    fuzz("image headers", &seeds, 300, |bytes| {
        write_and(&p, bytes);
        let _ = fluidnerf_io::image::read_dimensions(&p);
    });
}

#[test]
fn davis_images_never_panic() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/davis");
    let seeds: Vec<Vec<u8>> = ["three_cameras_imx.im7", "float.im7", "word_old.imx", "zlib.im7", "fixed12.im7"]
        .iter()
        .map(|name| std::fs::read(fixtures.join(name)).expect("fixture"))
        .collect();
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("x.im7");
    fuzz("davis", &seeds, 1000, |bytes| {
        let _ = decode_image(&p, bytes, Linearisation::Linear);
    });
    fuzz("davis headers", &seeds, 300, |bytes| {
        write_and(&p, bytes);
        let _ = fluidnerf_io::image::read_dimensions(&p);
    });
}

#[test]
fn npy_never_panics() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("v.npy");
    let aabb = Aabb::cube(DVec3::ZERO, 1.0);
    fluidnerf_io::volume::write_npy(&p, &Volume::from_fn([3, 2, 2], aabb, |q| q.x as f32)).expect("writes");
    let seed = std::fs::read(&p).expect("reads");
    fuzz("npy", &[seed], 500, |bytes| {
        write_and(&p, bytes);
        let _ = fluidnerf_io::volume::read_npy(&p, aabb);
    });
}
