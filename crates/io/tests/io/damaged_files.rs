//! Damaged binary and structured files are refused with an error, never a panic, an abort on a
//! huge allocation or an endless loop: each reader gets a valid small file cut short at many
//! lengths, and with its header's fields set to 0, 1, the largest values and negative ones.

use std::path::Path;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Image, Intrinsics, Volume};
use fluidnerf_io::image::{decode_image, Linearisation};

fn fixture(rel: &str) -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(rel)).expect("fixture")
}

/// Lengths to cut `len` bytes at: every length up to `every`, then about 64 more spread over the rest.
fn cuts(len: usize, every: usize) -> impl Iterator<Item = usize> {
    let step = (len.saturating_sub(every) / 64).max(1);
    (0..every.min(len)).chain((every.min(len)..len).step_by(step))
}

/// Copies of `seed` with the 2- and 4-byte little-endian fields at each even byte of its first
/// `head` bytes, and the 8-byte ones at each fourth, set to values that stress sizes, counts and
/// offsets: 0, 1, the largest, and the smallest negative.
fn corrupted(seed: &[u8], head: usize) -> impl Iterator<Item = Vec<u8>> + '_ {
    const FIELDS: [&[u8]; 9] = [
        &[0, 0],
        &[1, 0],
        &[0xff, 0xff],
        &[0, 0x80],
        &[0, 0, 0, 0],
        &[1, 0, 0, 0],
        &[0xff, 0xff, 0xff, 0xff],
        &[0xff, 0xff, 0xff, 0x7f],
        &[0, 0, 0, 0x80],
    ];
    const WIDE: [&[u8]; 2] = [&[0xff; 8], &[0, 0, 0, 0, 0, 0, 0, 0x80]];
    (0..head.min(seed.len())).step_by(2).flat_map(move |at| {
        let wide = if at % 4 == 0 { &WIDE[..] } else { &[] };
        FIELDS.iter().chain(wide).filter(move |f| at + f.len() <= seed.len()).map(move |f| {
            let mut v = seed.to_vec();
            v[at..at + f.len()].copy_from_slice(f);
            v
        })
    })
}

/// Copies of the text `seed` with each of its numbers replaced by 0, -1 and huge values.
fn renumbered(seed: &[u8]) -> Vec<Vec<u8>> {
    let text = String::from_utf8_lossy(seed).into_owned();
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i].is_ascii_digit() {
            let start = i;
            while i < b.len() && (b[i].is_ascii_digit() || b[i] == b'.') {
                i += 1;
            }
            for r in ["0", "-1", "4294967295", "18446744073709551615", "99999999999999999999999", "1e308", "-0"] {
                out.push(format!("{}{r}{}", &text[..start], &text[i..]).into_bytes());
            }
        } else {
            i += 1;
        }
    }
    out
}

/// Writes `bytes` to a new file at `path`: overwriting one in place may make the file system
/// flush it to disk, thousands of times slower.
fn put(path: &Path, bytes: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, bytes).expect("writes");
}

/// Every cut and corruption of `seed`, written to `path` in turn and read by `read`.
fn damage(seed: &[u8], every: usize, head: usize, path: &Path, mut read: impl FnMut(&Path)) {
    for n in cuts(seed.len(), every) {
        put(path, &seed[..n]);
        read(path);
    }
    for v in corrupted(seed, head) {
        put(path, &v);
        read(path);
    }
}

#[test]
fn damaged_cine_files_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("f.cine");
    for name in ["ramp_8bit.cine", "ramp_16bit.cine", "ramp_12bit_packed.cine"] {
        let seed = fixture(&format!("video/{name}"));
        damage(&seed, 160, 200, &p, |p| {
            let _ = fluidnerf_io::video::read_video(p, &Default::default());
        });
    }
}

#[test]
fn damaged_mraw_files_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (mraw, header) in [("ramp_12bit.mraw", "ramp_12bit.cihx"), ("ramp_16bit.mraw", "ramp_16bit.cih")] {
        let p = dir.path().join(mraw);
        let h = dir.path().join(header);
        let (seed, head) = (fixture(&format!("video/{mraw}")), fixture(&format!("video/{header}")));
        std::fs::write(&h, &head).expect("writes");
        damage(&seed, 64, 0, &p, |p| {
            let _ = fluidnerf_io::video::read_video(p, &Default::default());
        });
        std::fs::write(&p, &seed).expect("writes");
        damage(&head, head.len(), 0, &h, |_| {
            let _ = fluidnerf_io::video::read_video(&p, &Default::default());
        });
        for v in renumbered(&head) {
            put(&h, &v);
            let _ = fluidnerf_io::video::read_video(&p, &Default::default());
        }
        std::fs::remove_file(&h).expect("removes");
    }
}

#[test]
fn damaged_davis_images_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("f.im7");
    for name in ["three_cameras_imx.im7", "float.im7", "word.im7", "word_old.imx", "zlib.im7", "fixed12.im7"] {
        let seed = fixture(&format!("davis/{name}"));
        damage(&seed, seed.len(), 256, &p, |p| {
            let _ = fluidnerf_io::davis::read_davis(p);
            let _ = fluidnerf_io::image::read_dimensions(p);
            let _ = fluidnerf_io::image::read_image(p);
        });
    }
}

#[test]
fn damaged_avi_files_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("f.avi");
    for name in ["ramp_mjpeg.avi", "ramp_mjpeg_limited.avi"] {
        let seed = fixture(&format!("video/{name}"));
        damage(&seed, 400, 400, &p, |p| {
            let _ = fluidnerf_io::video::read_video(p, &Default::default());
        });
    }
}

/// A frame whose header claims another size than the first frame's is refused before it is
/// decoded: a damaged one can claim far more pixels than the decoder may allocate.
#[test]
fn an_avi_frame_claiming_another_size_is_refused_before_decoding() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("f.avi");
    let mut v = fixture("video/ramp_mjpeg.avi");
    // The second frame's start of frame (baseline): length, precision, height, width.
    let sof = (0..v.len() - 1).filter(|&k| v[k] == 0xff && v[k + 1] == 0xc0).nth(1).expect("a second frame");
    v[sof + 5..sof + 9].copy_from_slice(&[0xff; 4]);
    put(&p, &v);
    let e = fluidnerf_io::video::read_video(&p, &Default::default()).expect_err("refused").to_string();
    assert!(e.contains("f.avi") && e.contains("frame 1 is 65535×65535 pixels; the first frame kept is 32×24"), "{e}");
}

#[test]
fn damaged_colmap_models_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let k = Intrinsics { width: 16, height: 12, fx: 20.0, fy: 20.0, cx: 7.5, cy: 5.5, skew: 0.0 };
    let named: Vec<(String, Camera)> = (0..2)
        .map(|i| (format!("i{i}.png"), Camera::look_at(k, DVec3::new(50.0, i as f64, 5.0), DVec3::ZERO, DVec3::Z)))
        .collect();
    fluidnerf_io::calib::write_colmap_bin(d, &named).expect("writes");
    for name in ["cameras.bin", "images.bin"] {
        let seed = std::fs::read(d.join(name)).expect("reads");
        damage(&seed, seed.len(), seed.len(), &d.join(name), |_| {
            let _ = fluidnerf_io::calib::read_colmap(d);
        });
        std::fs::write(d.join(name), &seed).expect("writes");
    }
}

fn small_volume() -> Volume {
    Volume::from_fn([3, 2, 2], Aabb::cube(DVec3::ZERO, 1.0), |q| q.x as f32)
}

#[test]
fn damaged_volumes_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let aabb = Aabb::cube(DVec3::ZERO, 1.0);
    let p = d.join("v.npy");
    fluidnerf_io::volume::write_npy(&p, &small_volume()).expect("writes");
    let seed = std::fs::read(&p).expect("reads");
    damage(&seed, seed.len(), 0, &p, |p| {
        let _ = fluidnerf_io::volume::read_npy(p, aabb);
    });
    for v in renumbered(&seed) {
        put(&p, &v);
        let _ = fluidnerf_io::volume::read_npy(&p, aabb);
    }

    let p = d.join("v.vti");
    fluidnerf_io::volume::write_vti(&p, &small_volume()).expect("writes");
    let seed = std::fs::read(&p).expect("reads");
    damage(&seed, seed.len(), 0, &p, |p| {
        let _ = fluidnerf_io::volume::read_vti(p);
    });
    for v in renumbered(&seed) {
        put(&p, &v);
        let _ = fluidnerf_io::volume::read_vti(&p);
    }

    let p = d.join("v.raw");
    fluidnerf_io::volume::write_raw(&p, &small_volume()).expect("writes");
    let seed = std::fs::read(&p).expect("reads");
    damage(&seed, seed.len(), 0, &p, |p| {
        let _ = fluidnerf_io::volume::read_raw(p);
    });
    std::fs::write(&p, &seed).expect("writes");
    let json = fluidnerf_io::volume::raw_sidecar_path(&p);
    let sidecar = std::fs::read(&json).expect("reads");
    for v in renumbered(&sidecar) {
        put(&json, &v);
        let _ = fluidnerf_io::volume::read_raw(&p);
    }

    let p = d.join("v.tif");
    fluidnerf_io::volume::write_tiff_stack(&p, &small_volume(), "mm").expect("writes");
    let seed = std::fs::read(&p).expect("reads");
    damage(&seed, 64, seed.len(), &p, |p| {
        let _ = fluidnerf_io::volume::read_tiff_stack(p, None, None);
        let _ = fluidnerf_io::volume::read_tiff_stack(p, Some(aabb), Some("mm"));
    });
    for v in renumbered(&seed) {
        put(&p, &v);
        let _ = fluidnerf_io::volume::read_tiff_stack(&p, None, None);
    }
}

#[test]
fn damaged_images_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let img = Image::from_vec(6, 4, (0..24).map(|i| (i * 1000) as f32).collect());
    fluidnerf_io::image::write_png16_counts(&d.join("a.png"), &img).expect("png16");
    fluidnerf_io::image::write_tiff_f32(&d.join("a.tif"), &img).expect("tiff");
    let mut tiff16 = std::io::Cursor::new(Vec::new());
    tiff::encoder::TiffEncoder::new(&mut tiff16)
        .expect("enc")
        .write_image::<tiff::encoder::colortype::Gray16>(2, 2, &[0u16, 1, 2, 3])
        .expect("tiff16");
    std::fs::write(d.join("b.tif"), tiff16.into_inner()).expect("writes");
    for name in ["a.png", "a.tif", "b.tif"] {
        let seed = std::fs::read(d.join(name)).expect("reads");
        let p = d.join(format!("x.{}", &name[2..]));
        damage(&seed, seed.len(), seed.len(), &p, |p| {
            let bytes = std::fs::read(p).expect("reads");
            let _ = decode_image(p, &bytes, Linearisation::Linear);
            let _ = fluidnerf_io::image::read_dimensions(p);
        });
    }
}

/// The CRC-32 of PNG chunks (ISO 3309), so that a damaged header is read, not refused for its
/// checksum.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

#[test]
fn a_png_claiming_a_huge_size_is_refused_before_decoding() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("a.png");
    let img = Image::from_vec(6, 4, (0..24).map(|i| (i * 1000) as f32).collect());
    fluidnerf_io::image::write_png16_counts(&p, &img).expect("png16");
    let seed = std::fs::read(&p).expect("reads");
    for (w, h) in [(u32::MAX >> 1, u32::MAX >> 1), (1 << 20, 1 << 20), (65535, 65535), (4, 1 << 28), (0, 4)] {
        let mut v = seed.clone();
        v[16..20].copy_from_slice(&w.to_be_bytes());
        v[20..24].copy_from_slice(&h.to_be_bytes());
        let crc = crc32(&v[12..29]);
        v[29..33].copy_from_slice(&crc.to_be_bytes());
        put(&p, &v);
        let e = fluidnerf_io::image::read_image(&p).expect_err("refused").to_string();
        assert!(e.contains("a.png"), "{e}");
    }
}

#[test]
fn a_tiff_stack_whose_pages_loop_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("v.tif");
    fluidnerf_io::volume::write_tiff_stack(&p, &small_volume(), "mm").expect("writes");
    let seed = std::fs::read(&p).expect("reads");
    let u16_at = |at: usize| usize::from(u16::from_le_bytes([seed[at], seed[at + 1]]));
    let u32_at = |at: usize| u32::from_le_bytes(seed[at..at + 4].try_into().expect("4 bytes")) as usize;
    // Each page's directory and where it names the next.
    let mut pages = vec![];
    let mut ifd = u32_at(4);
    while ifd != 0 {
        let next_at = ifd + 2 + 12 * u16_at(ifd);
        pages.push((ifd, next_at));
        ifd = u32_at(next_at);
    }
    for &(_, next_at) in &pages {
        // Every earlier page, or the page itself: a loop (a later page skips pages, and is read).
        for &(target, _) in pages.iter().filter(|&&(ifd, _)| ifd < next_at) {
            let mut v = seed.clone();
            v[next_at..next_at + 4].copy_from_slice(&(target as u32).to_le_bytes());
            put(&p, &v);
            let e = fluidnerf_io::volume::read_tiff_stack(&p, None, None).expect_err("refused").to_string();
            assert!(e.contains("v.tif"), "{e}");
        }
    }
}
