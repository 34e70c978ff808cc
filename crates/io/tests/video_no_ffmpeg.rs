//! A video that needs ffmpeg, read with ffmpeg made unreachable (its own test binary, as it
//! sets environment variables).

use std::path::Path;

use fluidnerf_io::video::{read_video, VideoOptions, FFMPEG_ENV, FFPROBE_ENV};

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video").join(name)
}

/// Without ffmpeg a non-MJPEG video is refused with the file, the reason and how to install it.
#[test]
fn a_missing_ffmpeg_is_explained() {
    // The variables apply to this test binary only, which holds this one test.
    std::env::set_var(FFPROBE_ENV, "/nonexistent/ffprobe");
    std::env::set_var(FFMPEG_ENV, "/nonexistent/ffmpeg");
    let err = read_video(&fixture("ramp_h264.mp4"), &VideoOptions::default()).expect_err("no ffmpeg").to_string();
    std::env::remove_var(FFPROBE_ENV);
    std::env::remove_var(FFMPEG_ENV);
    assert!(err.contains("ramp_h264.mp4") && err.contains("needs ffmpeg"), "{err}");
    assert!(err.contains("apt install ffmpeg") && err.contains("MJPEG AVI"), "{err}");
    // An MJPEG AVI needs no ffmpeg.
    std::env::set_var(FFPROBE_ENV, "/nonexistent/ffprobe");
    std::env::set_var(FFMPEG_ENV, "/nonexistent/ffmpeg");
    let v = read_video(&fixture("ramp_mjpeg.avi"), &VideoOptions::default()).expect("reads without ffmpeg");
    assert_eq!(v.frames.len(), 4);
}
