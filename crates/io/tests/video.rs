//! Video reading against fixtures written by ffmpeg (see fixtures/video/make_fixtures.py):
//! four grey 32 × 24 frames at 10 frames/s, pixel (x, y) of frame k = 20 + 4x + 3y + 10k.

use std::path::{Path, PathBuf};

use fluidnerf_io::image::Linearisation;
use fluidnerf_io::video::{read_video, VideoOptions, VideoRange};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video").join(name)
}

fn ramp(x: usize, y: usize, k: usize) -> f32 {
    (20 + 4 * x + 3 * y + 10 * k) as f32
}

fn has_ffmpeg() -> bool {
    std::process::Command::new("ffmpeg").arg("-version").output().is_ok_and(|o| o.status.success())
}

/// The largest difference from the ramp over every pixel of the kept frames.
fn worst(video: &fluidnerf_io::video::Video, ks: &[usize], map: impl Fn(f32) -> f32) -> f32 {
    let mut worst = 0.0f32;
    for (img, &k) in video.frames.iter().zip(ks) {
        assert_eq!((img.width, img.height), (32, 24));
        for y in 0..24 {
            for x in 0..32 {
                worst = worst.max((img.get(x, y) - map(ramp(x, y, k))).abs());
            }
        }
    }
    worst
}

#[test]
fn mjpeg_avi_reads_without_ffmpeg() {
    let v = read_video(&fixture("ramp_mjpeg.avi"), &VideoOptions::default()).expect("reads");
    assert_eq!(v.decoder, "mjpeg-avi");
    assert_eq!(v.range, VideoRange::Full);
    assert_eq!(v.times, [0.0, 0.1, 0.2, 0.3]);
    let w = worst(&v, &[0, 1, 2, 3], |c| c);
    assert!(w <= 3.0, "JPEG error {w} counts");

    // A subset, and the same file forced to limited range: 16 → 0, 235 → 255, clipped counted.
    let opts = VideoOptions { start: 1, every: 2, range: VideoRange::Limited, ..VideoOptions::default() };
    let v = read_video(&fixture("ramp_mjpeg.avi"), &opts).expect("reads");
    assert_eq!(v.times, [0.1, 0.3]);
    assert_eq!(v.range, VideoRange::Limited);
    let w = worst(&v, &[1, 3], |c| ((c - 16.0) / 219.0).clamp(0.0, 1.0) * 255.0);
    assert!(w <= 4.0, "limited-range error {w}");
    let above: u64 = [1, 3]
        .iter()
        .map(|&k| {
            (0..24).flat_map(|y| (0..32).map(move |x| (x, y))).filter(|&(x, y)| ramp(x, y, k) > 237.0).count() as u64
        })
        .sum();
    assert!(v.clipped >= above && above > 0, "clipped {} of at least {above}", v.clipped);

    // sRGB linearisation applies to the decoded value.
    let opts = VideoOptions { end: Some(1), linearisation: Linearisation::Srgb, ..VideoOptions::default() };
    let v = read_video(&fixture("ramp_mjpeg.avi"), &opts).expect("reads");
    assert_eq!(v.frames.len(), 1);
    let w = worst(&v, &[0], |c| Linearisation::Srgb.apply_unit(f64::from(c) / 255.0));
    assert!(w <= 3.0, "sRGB error {w}");
}

#[test]
fn broken_avi_files_are_refused_with_their_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = std::fs::read(fixture("ramp_mjpeg.avi")).expect("fixture");
    let cases: [(&str, Vec<u8>, &str); 3] = [
        ("truncated.avi", bytes[..bytes.len() / 2].to_vec(), "truncated"),
        ("noframes.avi", bytes[..400.min(bytes.len())].to_vec(), "AVI"),
        ("notriff.avi", b"this is not a video at all, just text".to_vec(), "notriff.avi"),
    ];
    for (name, data, want) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, data).expect("write");
        let err = read_video(&p, &VideoOptions::default()).expect_err(name).to_string();
        assert!(err.contains(name) && err.contains(want), "{name}: {err}");
    }
}

/// H.264 in MP4 through ffmpeg: limited-range luma (the stream states no range, so the video
/// default applies) mapped back to the ramp, times from the stamps. Needs ffmpeg on the PATH;
/// reported and skipped without it.
#[test]
#[allow(clippy::print_stdout)] // The skip is reported.
fn h264_mp4_reads_through_ffmpeg() {
    if !has_ffmpeg() {
        println!("skipped: ffmpeg is not on the PATH");
        return;
    }
    let v = read_video(&fixture("ramp_h264.mp4"), &VideoOptions::default()).expect("reads");
    assert_eq!(v.decoder, "ffmpeg");
    assert_eq!(v.range, VideoRange::Limited);
    assert_eq!(v.frames.len(), 4);
    for (t, want) in v.times.iter().zip([0.0, 0.1, 0.2, 0.3]) {
        assert!((t - want).abs() < 1e-6, "{:?}", v.times);
    }
    let w = worst(&v, &[0, 1, 2, 3], |c| c);
    assert!(w <= 1.5, "error {w} counts");
}
