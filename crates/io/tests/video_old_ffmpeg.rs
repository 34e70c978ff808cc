//! An ffmpeg older than 5.1 (no `-fps_mode`) is used through `-vsync` (its own test binary, as
//! it sets environment variables).

use std::path::Path;

use fluidnerf_io::video::{read_video, VideoOptions, FFMPEG_ENV};

/// A wrapper refusing `-fps_mode` as ffmpeg 4 does decodes the same frames. Needs ffmpeg on the
/// PATH and a POSIX shell; reported and skipped without them.
#[test]
#[allow(clippy::print_stdout)] // The skip is reported.
fn an_ffmpeg_without_fps_mode_is_used_through_vsync() {
    let has = |p: &str| std::process::Command::new(p).arg("-version").output().is_ok_and(|o| o.status.success());
    if !cfg!(unix) || !has("ffmpeg") || !has("ffprobe") {
        println!("skipped: ffmpeg/ffprobe are not on the PATH");
        return;
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let log = dir.path().join("calls");
    let wrapper = dir.path().join("ffmpeg4");
    let script = format!(
        "#!/bin/sh\necho \"$*\" >> '{}'\nfor a in \"$@\"; do\n  if [ \"$a\" = -fps_mode ]; then\n    echo \
         \"Unrecognized option 'fps_mode'.\" >&2\n    exit 8\n  fi\ndone\nexec ffmpeg \"$@\"\n",
        log.display()
    );
    std::fs::write(&wrapper, script).expect("writes the wrapper");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&wrapper, std::fs::Permissions::from_mode(0o755)).expect("chmod");
    }
    std::env::set_var(FFMPEG_ENV, &wrapper);
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video/ramp_h264.mp4");
    let v = read_video(&path, &VideoOptions::default()).expect("reads through -vsync");
    std::env::remove_var(FFMPEG_ENV);
    assert_eq!(v.frames.len(), 4);
    let calls = std::fs::read_to_string(&log).expect("the wrapper ran");
    let calls: Vec<&str> = calls.lines().collect();
    assert_eq!(calls.len(), 2, "{calls:?}");
    assert!(calls[0].contains("-fps_mode passthrough") && calls[1].contains("-vsync passthrough"), "{calls:?}");
}
