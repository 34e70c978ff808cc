//! A video that needs ffmpeg, read with ffmpeg made unreachable (its own test binary, as it
//! sets environment variables).

use std::path::Path;

use fluidnerf_io::video::{read_video, VideoOptions, FFMPEG_ENV, FFPROBE_ENV};

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video").join(name)
}

/// Without ffmpeg a non-MJPEG video is refused with the file, the reason and how to install
/// it; an MJPEG AVI still reads.
#[test]
fn a_missing_ffmpeg_is_explained() {
    // The variables apply to this test binary only, which holds this one test.
    std::env::set_var(FFPROBE_ENV, "/nonexistent/ffprobe");
    std::env::set_var(FFMPEG_ENV, "/nonexistent/ffmpeg");
    let path = fixture("ramp_h264.mp4");
    let err = read_video(&path, &VideoOptions::default()).expect_err("no ffmpeg").to_string();
    assert!(err.starts_with(&path.display().to_string()), "{err}");
    assert!(err.contains("needs ffmpeg") && err.contains("/nonexistent/ffprobe"), "{err}");
    for hint in ["apt install ffmpeg", "brew install ffmpeg", "conda install -c conda-forge ffmpeg", "MJPEG AVI"] {
        assert!(err.contains(hint), "no `{hint}` in: {err}");
    }
    let v = read_video(&fixture("ramp_mjpeg.avi"), &VideoOptions::default()).expect("reads without ffmpeg");
    assert_eq!(v.frames.len(), 4);
    std::env::remove_var(FFPROBE_ENV);
    std::env::remove_var(FFMPEG_ENV);
}
