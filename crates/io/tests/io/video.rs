//! Video reading against fixtures written by ffmpeg (see fixtures/video/make_fixtures.py):
//! four grey 32 × 24 frames at 10 frames/s, pixel (x, y) of frame k = 20 + 4x + 3y + 10k, as
//! full-range MJPEG AVI, limited-range MJPEG AVI and limited-range H.264 MP4.

use std::path::{Path, PathBuf};

use fluidnerf_io::image::Linearisation;
use fluidnerf_io::video::{read_video, Decoder, RangeSource, Video, VideoOptions, VideoRange};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/video").join(name)
}

fn ramp(x: usize, y: usize, k: usize) -> f32 {
    (20 + 4 * x + 3 * y + 10 * k) as f32
}

/// Per frame: `((x, y), value)` at four pixels, and the frame's sum.
type Recorded = Vec<(Vec<((usize, usize), f32)>, f64)>;

/// What a reference reader recorded in the fixture file `record` for the recording `file`:
/// after a line that begins with `file`, lines `frame K X,Y=V … sum=S`.
fn recorded(record: &str, file: &str) -> Recorded {
    let text = std::fs::read_to_string(fixture(record)).expect("reads the record");
    let mut frames = Vec::new();
    let mut inside = false;
    for line in text.lines() {
        if !line.starts_with("frame ") {
            inside = line.starts_with(file);
            continue;
        }
        if inside {
            let mut pixels = Vec::new();
            let mut sum = 0.0;
            for item in line.split_whitespace().skip(2) {
                let (key, value) = item.split_once('=').expect("key=value");
                let value: f64 = value.parse().expect("a count");
                match key.split_once(',') {
                    Some((x, y)) => pixels.push(((x.parse().expect("x"), y.parse().expect("y")), value as f32)),
                    None => sum = value,
                }
            }
            frames.push((pixels, sum));
        }
    }
    assert_eq!(frames.len(), 4, "{record}: four frames of {file}");
    frames
}

/// The ramp as limited-range code values.
fn limited(c: f32) -> f32 {
    16.0 + 219.0 * c / 255.0
}

fn has_ffmpeg() -> bool {
    let works = |p: &str| std::process::Command::new(p).arg("-version").output().is_ok_and(|o| o.status.success());
    works("ffmpeg") && works("ffprobe")
}

/// The largest difference from the ramp over every pixel of the kept frames.
fn worst(video: &Video, ks: &[usize], map: impl Fn(f32) -> f32) -> f32 {
    assert_eq!(video.frames.len(), ks.len());
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

fn assert_times(got: &[f64], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{got:?}");
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-9, "times {got:?}, expected {want:?}");
    }
}

#[test]
fn mjpeg_avi_reads_without_ffmpeg() {
    let v = read_video(&fixture("ramp_mjpeg.avi"), &VideoOptions::default()).expect("reads");
    assert_eq!(v.info.decoder, Decoder::MjpegAvi);
    assert_eq!((v.info.range, v.info.range_source), (VideoRange::Full, RangeSource::JpegDefault));
    assert_eq!((v.info.width, v.info.height, v.info.frame_rate), (32, 24, Some(10.0)));
    assert_eq!((v.info.frames_in_file, v.info.frames_kept, v.info.clipped_pixels), (4, 4, 0));
    assert_eq!(v.times, [0.0, 0.1, 0.2, 0.3]);
    let w = worst(&v, &[0, 1, 2, 3], |c| c);
    assert!(w <= 3.0, "JPEG error {w} counts");

    // A subset, and the same file forced to limited range: 16 → 0, 235 → 255, clipped counted.
    let opts = VideoOptions { start: 1, every: 2, range: VideoRange::Limited, ..VideoOptions::default() };
    let v = read_video(&fixture("ramp_mjpeg.avi"), &opts).expect("reads");
    assert_eq!(v.times, [0.1, 0.3]);
    assert_eq!((v.info.range, v.info.range_source), (VideoRange::Limited, RangeSource::Option));
    let w = worst(&v, &[1, 3], |c| ((c - 16.0) / 219.0).clamp(0.0, 1.0) * 255.0);
    assert!(w <= 4.0, "limited-range error {w}");
    let above: u64 = [1, 3]
        .iter()
        .map(|&k| {
            (0..24).flat_map(|y| (0..32).map(move |x| (x, y))).filter(|&(x, y)| ramp(x, y, k) > 237.0).count() as u64
        })
        .sum();
    assert!(v.info.clipped_pixels >= above && above > 0, "clipped {} of at least {above}", v.info.clipped_pixels);
    // Codes at or above 235, white in limited range, are saturated; in full range none reaches 255.
    assert!(v.info.saturated_pixels >= above, "saturated {} of at least {above}", v.info.saturated_pixels);
    let full = read_video(&fixture("ramp_mjpeg.avi"), &VideoOptions::default()).expect("reads");
    assert_eq!(full.info.saturated_pixels, 0, "the ramp ends at 243 of 255");

    // sRGB linearisation applies to the decoded value.
    let opts = VideoOptions { end: Some(1), linearisation: Linearisation::Srgb, ..VideoOptions::default() };
    let v = read_video(&fixture("ramp_mjpeg.avi"), &opts).expect("reads");
    let w = worst(&v, &[0], |c| Linearisation::Srgb.apply_unit(f64::from(c) / 255.0));
    assert!(w <= 3.0, "sRGB error {w}");
}

/// The limited-range MJPEG says so in its JPEG comments: `auto` maps 16–235 back to 0–255;
/// `full` keeps the stored codes.
#[test]
fn limited_range_mjpeg_is_detected_and_mapped_back() {
    let path = fixture("ramp_mjpeg_limited.avi");
    let v = read_video(&path, &VideoOptions::default()).expect("reads");
    assert_eq!(v.info.decoder, Decoder::MjpegAvi);
    assert_eq!((v.info.range, v.info.range_source), (VideoRange::Limited, RangeSource::File));
    assert_eq!(v.times, [0.0, 0.1, 0.2, 0.3]);
    // JPEG error of up to 3 codes grows by 255/219 in the mapping.
    let w = worst(&v, &[0, 1, 2, 3], |c| c);
    assert!(w <= 4.0, "error {w} counts after the range mapping");
    assert_eq!(v.info.clipped_pixels, 0, "the ramp lies inside 16–235");

    let v = read_video(&path, &VideoOptions { range: VideoRange::Full, ..VideoOptions::default() }).expect("reads");
    assert_eq!((v.info.range, v.info.range_source), (VideoRange::Full, RangeSource::Option));
    let w = worst(&v, &[0, 1, 2, 3], limited);
    assert!(w <= 3.0, "stored codes differ by {w} from 16 + 219 v / 255");
}

#[test]
fn selection_and_time_offset() {
    let opts = VideoOptions { start: 1, end: Some(3), every: 1, time_offset_s: 2.5, ..VideoOptions::default() };
    let v = read_video(&fixture("ramp_mjpeg.avi"), &opts).expect("reads");
    assert_times(&v.times, &[2.6, 2.7]);
    assert!(worst(&v, &[1, 2], |c| c) <= 3.0);
    assert_eq!((v.info.frames_in_file, v.info.frames_kept), (4, 2));

    let past = VideoOptions { start: 4, ..VideoOptions::default() };
    let err = read_video(&fixture("ramp_mjpeg.avi"), &past).expect_err("nothing kept").to_string();
    assert!(err.contains("ramp_mjpeg.avi") && err.contains("no frame kept"), "{err}");
    // Frames past the end are not silently dropped from the selection.
    let long = VideoOptions { start: 1, end: Some(10), ..VideoOptions::default() };
    let err = read_video(&fixture("ramp_mjpeg.avi"), &long).expect_err("past the end").to_string();
    assert!(
        err.contains("ramp_mjpeg.avi") && err.contains("runs to frame 9 but the video has only 4 frame(s), 0 to 3"),
        "{err}"
    );
    let to_end = VideoOptions { start: 1, end: Some(4), ..VideoOptions::default() };
    assert_eq!(read_video(&fixture("ramp_mjpeg.avi"), &to_end).expect("frames 1 to 3").times.len(), 3);
    let nan = VideoOptions { time_offset_s: f64::NAN, ..VideoOptions::default() };
    let err = read_video(&fixture("ramp_mjpeg.avi"), &nan).expect_err("NaN offset").to_string();
    assert!(err.contains("not finite"), "{err}");
    // An offset that rounds the 0.1 s frame interval away would put frames at one time.
    let huge = VideoOptions { time_offset_s: 1e17, ..VideoOptions::default() };
    let err = read_video(&fixture("ramp_mjpeg.avi"), &huge).expect_err("frames at one time").to_string();
    assert!(err.contains("ramp_mjpeg.avi") && err.contains("not after frame 0") && err.contains("offset"), "{err}");
    // The times and the offset in short: an offset of 1.7e308 s was written out in 309 digits,
    // three times over.
    let huge = VideoOptions { time_offset_s: 1.7e308, ..VideoOptions::default() };
    let err = read_video(&fixture("ramp_mjpeg.avi"), &huge).expect_err("frames at one time").to_string();
    assert!(
        err.contains(
            "frame 1 is at 1.7e308 s, not after frame 0 at 1.7e308 s (with the time offset of 1.7e308 s added"
        ),
        "{err}"
    );
}

/// The offset of the `n`-th occurrence of `tag` in `bytes`.
fn find(bytes: &[u8], tag: &[u8], n: usize) -> usize {
    bytes.windows(tag.len()).enumerate().filter(|(_, w)| *w == tag).nth(n).map(|(i, _)| i).expect("tag in fixture")
}

fn put_u32(bytes: &mut [u8], at: usize, v: u32) {
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// Every broken file is refused with its name and what is wrong, without ffmpeg.
#[test]
fn broken_video_files_are_refused_with_their_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let good = std::fs::read(fixture("ramp_mjpeg.avi")).expect("fixture");

    let mut zero_rate = good.clone();
    let strh = find(&good, b"strh", 0) + 8;
    put_u32(&mut zero_rate, strh + 20, 0); // dwScale
    put_u32(&mut zero_rate, strh + 24, 0); // dwRate
    put_u32(&mut zero_rate, find(&good, b"avih", 0) + 8, 0); // dwMicroSecPerFrame

    let mut no_video = good.clone();
    no_video[strh..strh + 4].copy_from_slice(b"auds");

    // Frame 2's JPEG data overwritten with zeros (its chunk size kept); the index in the
    // headers names `00dc` too, so the frames are counted from the `movi` list.
    let mut bad_jpeg = good.clone();
    let movi = find(&good, b"movi", 0);
    let chunk = movi + find(&good[movi..], b"00dc", 2);
    let size = u32::from_le_bytes(good[chunk + 4..chunk + 8].try_into().expect("4 bytes")) as usize;
    bad_jpeg[chunk + 8..chunk + 8 + size].fill(0);

    // Frame 2's JPEG cut short inside its scan: its last 22 bytes, the end-of-image marker
    // among them, zeroed (a camera that stopped writing mid-frame).
    let mut cut_jpeg = good.clone();
    cut_jpeg[chunk + 8 + size - 22..chunk + 8 + size].fill(0);

    let cases: [(&str, Vec<u8>, &str); 8] = [
        ("truncated.avi", good[..good.len() / 2].to_vec(), "truncated"),
        ("headers_only.avi", good[..400].to_vec(), "malformed AVI"),
        ("notriff.avi", b"this is not a video at all, just some text".to_vec(), "not a video file"),
        ("empty.mp4", Vec::new(), "the video file is empty (0 bytes)"),
        ("zero_rate.avi", zero_rate, "zero frame rate"),
        ("no_video.avi", no_video, "no video stream"),
        ("bad_jpeg.avi", bad_jpeg, "frame 2: not a decodable JPEG"),
        ("cut_jpeg.avi", cut_jpeg, "frame 2: truncated JPEG"),
    ];
    for (name, data, want) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, data).expect("write");
        let err = read_video(&p, &VideoOptions::default()).expect_err(name).to_string();
        assert!(err.contains(&p.display().to_string()) && err.contains(want), "{name}: {err}");
    }
    // Frames before the broken one read when the selection stops short of it.
    let p = dir.path().join("bad_jpeg.avi");
    let v = read_video(&p, &VideoOptions { end: Some(2), ..VideoOptions::default() }).expect("frames 0 and 1");
    assert_eq!(v.times, [0.0, 0.1]);

    let missing = dir.path().join("missing.avi");
    let err = read_video(&missing, &VideoOptions::default()).expect_err("missing").to_string();
    assert!(err.contains("not found") && err.contains("missing.avi"), "{err}");
}

/// A frame the camera dropped (an empty `00dc` chunk) gives no image but keeps its time slot.
#[test]
fn a_dropped_frame_keeps_its_time_slot() {
    let mut bytes = std::fs::read(fixture("ramp_mjpeg.avi")).expect("fixture");
    // Frame 1's chunk becomes an empty `00dc` and a `JUNK` chunk of the same total size, so
    // no list around it changes size.
    let movi = find(&bytes, b"movi", 0);
    let chunk = movi + find(&bytes[movi..], b"00dc", 1);
    let size = u32::from_le_bytes(bytes[chunk + 4..chunk + 8].try_into().expect("4 bytes"));
    put_u32(&mut bytes, chunk + 4, 0);
    bytes[chunk + 8..chunk + 12].copy_from_slice(b"JUNK");
    put_u32(&mut bytes, chunk + 12, size - 8);
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("dropped.avi");
    std::fs::write(&p, bytes).expect("write");
    let v = read_video(&p, &VideoOptions::default()).expect("reads");
    assert_eq!(v.times, [0.0, 0.2, 0.3]);
    assert_eq!((v.info.frames_in_file, v.info.frames_kept), (4, 3));
    assert!(worst(&v, &[0, 2, 3], |c| c) <= 3.0);
}

/// H.264 in MP4 through ffmpeg: limited-range luma (the MP4 states no range, so the video
/// default applies) mapped back to the ramp, times from the stamps. Needs ffmpeg on the PATH; reported and skipped without it.
#[test]
#[allow(clippy::print_stdout)] // The skip is reported.
fn h264_mp4_reads_through_ffmpeg() {
    if !has_ffmpeg() {
        println!("skipped: ffmpeg/ffprobe are not on the PATH");
        return;
    }
    let v = read_video(&fixture("ramp_h264.mp4"), &VideoOptions::default()).expect("reads");
    assert_eq!(v.info.decoder, Decoder::Ffmpeg);
    assert_eq!((v.info.range, v.info.range_source), (VideoRange::Limited, RangeSource::VideoDefault));
    assert_eq!((v.info.width, v.info.height, v.info.frame_rate), (32, 24, Some(10.0)));
    assert_eq!((v.info.frames_in_file, v.info.frames_kept), (4, 4));
    assert_times(&v.times, &[0.0, 0.1, 0.2, 0.3]);
    let w = worst(&v, &[0, 1, 2, 3], |c| c);
    assert!(w <= 1.5, "error {w} counts");

    // Forced full range keeps the stored codes; a selection stops ffmpeg early.
    let opts = VideoOptions {
        range: VideoRange::Full,
        start: 1,
        end: Some(3),
        time_offset_s: -0.1,
        ..VideoOptions::default()
    };
    let v = read_video(&fixture("ramp_h264.mp4"), &opts).expect("reads");
    assert_times(&v.times, &[0.0, 0.1]);
    let w = worst(&v, &[1, 2], limited);
    assert!(w <= 1.0, "stored codes differ by {w} from 16 + 219 v / 255");

    // The MJPEG AVI read by ffmpeg agrees with the native reader.
    let native = read_video(&fixture("ramp_mjpeg_limited.avi"), &VideoOptions::default()).expect("native");
    let mp4 = read_video(&fixture("ramp_h264.mp4"), &VideoOptions::default()).expect("ffmpeg");
    assert_eq!(native.times.len(), mp4.times.len());
    for (a, b) in native.frames.iter().zip(&mp4.frames) {
        let d = a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(d <= 5.0, "native MJPEG and ffmpeg H.264 frames differ by {d}");
    }
}

/// A video whose file asks players to turn its frames (a camera held on its side; made from
/// ramp_h264.mp4 with `ffmpeg -display_rotation 90 -c copy`, see make_fixtures.py) is read as
/// stored: the same size and pixels as the unturned file, the rotation recorded. ffmpeg
/// turns such frames unless told not to, and the turned 24 × 32 frames were read as 32 × 24
/// rows, scrambling every pixel. Needs ffmpeg on the PATH; reported and skipped without it.
#[test]
#[allow(clippy::print_stdout)] // The skip is reported.
fn a_video_asking_to_be_shown_turned_is_read_as_stored() {
    if !has_ffmpeg() {
        println!("skipped: ffmpeg/ffprobe are not on the PATH");
        return;
    }
    let turned = read_video(&fixture("ramp_h264_rot90.mp4"), &VideoOptions::default()).expect("reads");
    let stored = read_video(&fixture("ramp_h264.mp4"), &VideoOptions::default()).expect("reads");
    assert_eq!(turned.info.display_rotation_deg.map(f64::abs), Some(90.0));
    assert_eq!(stored.info.display_rotation_deg, None);
    assert_eq!((turned.info.width, turned.info.height), (32, 24));
    assert_eq!(turned.frames.len(), stored.frames.len());
    for (a, b) in turned.frames.iter().zip(&stored.frames) {
        assert_eq!((a.width, a.height), (32, 24));
        assert_eq!(a.data, b.data, "the frames differ from the stored ones");
    }
}

/// Phantom cine reading against fixtures laid out with pycine's header structures and read
/// back by pycine (fixtures/video/make_cine.py, check_cine_with_pycine.py and its output
/// check_cine_with_pycine.txt): four grey 32 × 24 frames at 1000 frames/s, pixel (x, y) of
/// frame k = 20 + 4x + 3y + 10k, stored bottom-up; 16-bit with black level 64 and stored value
/// 64 + 10 v, and 8-bit with the value itself.
mod cine {
    use std::path::{Path, PathBuf};

    use fluidnerf_io::video::{read_video, Decoder, RangeSource, VideoOptions};

    use super::{fixture, ramp, recorded};

    #[test]
    fn sixteen_bit_frames_are_counts_above_the_black_level() {
        let video = read_video(&fixture("ramp_16bit.cine"), &VideoOptions::default()).expect("reads");
        assert_eq!(video.info.decoder, Decoder::Cine);
        assert_eq!(video.info.range_source, RangeSource::Raw);
        assert_eq!((video.info.width, video.info.height, video.info.frame_rate), (32, 24, Some(1000.0)));
        assert_eq!((video.info.frames_in_file, video.info.frames_kept, video.info.clipped_pixels), (4, 4, 0));
        assert_eq!(video.times, [0.0, 0.001, 0.002, 0.003]);
        for (k, img) in video.frames.iter().enumerate() {
            assert_eq!((img.width, img.height), (32, 24));
            for y in 0..24 {
                for x in 0..32 {
                    assert_eq!(img.get(x, y), 10.0 * ramp(x, y, k), "frame {k} pixel ({x}, {y})");
                }
            }
        }
        as_pycine_reads(&video.frames, "check_cine_with_pycine.txt", "ramp_16bit.cine");
    }

    /// `frames`, counts above the black level 64, against pycine's reading of `file` recorded in
    /// `record`: pycine maps [black 64, white 4064] onto [0, 4095] and truncates, so the counts
    /// are mapped so before they are compared.
    fn as_pycine_reads(frames: &[fluidnerf_core::Image], record: &str, file: &str) {
        let as_pycine = |c: f32| (f64::from(c) * 4095.0 / 4000.0).floor();
        for (k, (pixels, sum)) in recorded(record, file).into_iter().enumerate() {
            let img = &frames[k];
            for ((x, y), v) in pixels {
                assert_eq!(as_pycine(img.get(x, y)), f64::from(v), "{file}: frame {k} pixel ({x}, {y})");
            }
            assert_eq!(img.data.iter().map(|&c| as_pycine(c)).sum::<f64>(), sum, "{file}: frame {k}");
        }
    }

    #[test]
    fn eight_bit_frames_match_pycine_and_the_selection_keeps_times() {
        let video = read_video(&fixture("ramp_8bit.cine"), &VideoOptions::default()).expect("reads");
        for (k, (pixels, sum)) in recorded("check_cine_with_pycine.txt", "ramp_8bit.cine").into_iter().enumerate() {
            let img = &video.frames[k];
            for ((x, y), v) in pixels {
                assert_eq!(img.get(x, y), v, "frame {k} pixel ({x}, {y})");
            }
            assert_eq!(img.data.iter().map(|&c| f64::from(c)).sum::<f64>(), sum, "frame {k}");
        }
        let opts = VideoOptions { start: 1, every: 2, time_offset_s: 0.5, ..Default::default() };
        let video = read_video(&fixture("ramp_8bit.cine"), &opts).expect("reads");
        assert_eq!(video.times, [0.501, 0.503]);
        assert_eq!(video.frames[1].get(5, 7), ramp(5, 7, 3));
    }

    /// Frames packed at 12 bits per pixel (written by make_cine.py, top-down) read as the same
    /// counts as the 16-bit fixture's frames, and as pycine's development version reads them.
    #[test]
    fn packed_twelve_bit_frames_are_the_same_counts() {
        let packed = read_video(&fixture("ramp_12bit_packed.cine"), &VideoOptions::default()).expect("reads");
        let plain = read_video(&fixture("ramp_16bit.cine"), &VideoOptions::default()).expect("reads");
        assert_eq!((packed.info.width, packed.info.height, packed.info.frames_kept), (32, 24, 4));
        assert_eq!(packed.times, plain.times);
        for (k, (a, b)) in packed.frames.iter().zip(&plain.frames).enumerate() {
            assert_eq!(a.data, b.data, "frame {k}");
        }
        as_pycine_reads(&packed.frames, "check_cine_packed_with_pycine.txt", "ramp_12bit_packed.cine");
    }

    /// A packed frame whose size is not that of its pixels at 12 bits is refused, and a black
    /// level at the 12-bit full scale too.
    #[test]
    fn packed_frames_of_the_wrong_size_are_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut bytes = std::fs::read(fixture("ramp_12bit_packed.cine")).expect("reads the fixture");
        let offsets = u32::from_le_bytes(bytes[32..36].try_into().expect("4 bytes")) as usize;
        let first = u64::from_le_bytes(bytes[offsets..offsets + 8].try_into().expect("8 bytes")) as usize;
        put_u32(&mut bytes, first + 4, 1151);
        let path = dir.path().join("short.cine");
        std::fs::write(&path, &bytes).expect("writes");
        let e = read_video(&path, &VideoOptions::default()).expect_err("refused").to_string();
        assert!(e.contains("short.cine") && e.contains("image 0 holds 1151 bytes"), "{e}");
        let mut bytes = std::fs::read(fixture("ramp_12bit_packed.cine")).expect("reads the fixture");
        put_u32(&mut bytes, SETUP + 5732, 4095);
        std::fs::write(&path, &bytes).expect("writes");
        let e = read_video(&path, &VideoOptions::default()).expect_err("refused").to_string();
        assert!(e.contains("black level 4095") && e.contains("12-bit full scale"), "{e}");
    }

    /// The 16-bit fixture with `patch` applied to its bytes, written to `dir`.
    fn patched(dir: &Path, patch: impl FnOnce(&mut Vec<u8>)) -> PathBuf {
        let mut bytes = std::fs::read(fixture("ramp_16bit.cine")).expect("reads the fixture");
        patch(&mut bytes);
        let path = dir.join("patched.cine");
        std::fs::write(&path, bytes).expect("writes");
        path
    }

    /// Offsets in the fixture: the bitmap header at 44, the setup at 84.
    const BITMAP: usize = 44;
    const SETUP: usize = 84;

    fn put_u32(b: &mut [u8], at: usize, v: u32) {
        b[at..at + 4].copy_from_slice(&v.to_le_bytes());
    }

    /// Times count from the trigger: a file whose first image is number −2 begins 2 ms before it.
    #[test]
    fn times_count_from_the_trigger() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = patched(dir.path(), |b| put_u32(b, 16, (-2i32) as u32));
        let video = read_video(&path, &VideoOptions::default()).expect("reads");
        assert_eq!(video.times, [-0.002, -0.001, 0.0, 0.001]);
    }

    #[test]
    fn a_negative_height_is_read_top_down() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = patched(dir.path(), |b| put_u32(b, BITMAP + 8, (-24i32) as u32));
        let video = read_video(&path, &VideoOptions::default()).expect("reads");
        // The stored first row (the picture's bottom, y = 23) is now the top.
        assert_eq!(video.frames[0].get(3, 0), 10.0 * ramp(3, 23, 0));
    }

    #[test]
    fn frames_it_cannot_read_are_refused_with_the_reason() {
        let dir = tempfile::tempdir().expect("tempdir");
        let err = |patch: &dyn Fn(&mut Vec<u8>)| {
            let path = patched(dir.path(), patch);
            let e = read_video(&path, &VideoOptions::default()).expect_err("refused").to_string();
            assert!(e.contains("patched.cine"), "{e}");
            e
        };
        let e = err(&|b| put_u32(b, SETUP + 808, 3));
        assert!(e.contains("Bayer mosaic") && e.contains("code 3"), "{e}");
        let e = err(&|b| put_u32(b, BITMAP + 16, 256));
        assert!(e.contains("packed 10-bit"), "{e}");
        // The 16-bit frames' 1536 bytes are not the 1152 of 32 × 24 pixels packed at 12 bits.
        let e = err(&|b| put_u32(b, BITMAP + 16, 1024));
        assert!(e.contains("image 0 holds 1536 bytes") && e.contains("packed at 12 bits take 1152"), "{e}");
        let e = err(&|b| {
            put_u32(b, BITMAP + 16, 1024);
            put_u32(b, SETUP + 808, 3);
        });
        assert!(e.contains("Bayer mosaic"), "{e}");
        let e = err(&|b| b[BITMAP + 14..BITMAP + 16].copy_from_slice(&48u16.to_le_bytes()));
        assert!(e.contains("colour-interpolated"), "{e}");
        let e = err(&|b| put_u32(b, SETUP + 768, 0));
        assert!(e.contains("frame rate of 0"), "{e}");
        let e = err(&|b| put_u32(b, 20, 0));
        assert!(e.contains("no images"), "{e}");
        let e = err(&|b| b.truncate(b.len() - 100));
        assert!(e.contains("image 3") && e.contains("past the end of the file"), "{e}");
        // An image size that fits no row layout.
        let e = err(&|b| {
            let first = u64::from_le_bytes(b[84 + 12432..84 + 12432 + 8].try_into().expect("8 bytes")) as usize;
            put_u32(b, first + 4, 1000);
        });
        assert!(e.contains("image 0 holds 1000 bytes"), "{e}");
    }

    /// A pixel at the sensor's largest count (4095 of its 12 significant bits, stored in 16) is
    /// saturated and counted; one count below is not. Saturated frames of a recording were
    /// written out as float images, whose check knows no full scale, without a word.
    #[test]
    fn counts_at_the_sensors_full_scale_are_counted_as_saturated() {
        let dir = tempfile::tempdir().expect("tempdir");
        let with_first_pixel = |v: u16| {
            patched(dir.path(), |b| {
                let first =
                    u64::from_le_bytes(b[SETUP + 12432..SETUP + 12432 + 8].try_into().expect("8 bytes")) as usize;
                let annotation = u32::from_le_bytes(b[first..first + 4].try_into().expect("4 bytes")) as usize;
                b[first + annotation..first + annotation + 2].copy_from_slice(&v.to_le_bytes());
            })
        };
        let video = read_video(&with_first_pixel(4095), &VideoOptions::default()).expect("reads");
        assert_eq!(video.frames[0].get(0, 23), 4095.0 - 64.0, "the stored first row is the bottom");
        assert_eq!(video.info.saturated_pixels, 1);
        let video = read_video(&with_first_pixel(4094), &VideoOptions::default()).expect("reads");
        assert_eq!(video.info.saturated_pixels, 0);
        let video = read_video(&fixture("ramp_16bit.cine"), &VideoOptions::default()).expect("reads");
        assert_eq!(video.info.saturated_pixels, 0);
    }

    /// Pixels below the black level read as 0 and are counted.
    #[test]
    fn counts_below_the_black_level_are_clipped_and_counted() {
        let dir = tempfile::tempdir().expect("tempdir");
        // A black level of 300 is above the ramp's lowest stored values (64 + 10 v from 264).
        let path = patched(dir.path(), |b| put_u32(b, SETUP + 5732, 300));
        let video = read_video(&path, &VideoOptions::default()).expect("reads");
        let below =
            (0..24).flat_map(|y| (0..32).map(move |x| (x, y))).filter(|&(x, y)| 64.0 + 10.0 * ramp(x, y, 0) < 300.0);
        let n = below.clone().count();
        assert!(n > 0);
        for (x, y) in below {
            assert_eq!(video.frames[0].get(x, y), 0.0);
        }
        assert_eq!(video.frames[0].get(31, 23), 64.0 + 10.0 * ramp(31, 23, 0) - 300.0);
        assert_eq!(video.info.clipped_pixels, n as u64);
    }
}

/// Photron MRAW reading against fixtures written by pyMRAW (16-bit, with its text `.cih`) and
/// by fixtures/video/make_mraw.py (8-bit and packed 12-bit, with XML `.cihx` headers), all
/// read back by pyMRAW (check_mraw_with_pymraw.py and its output check_mraw_with_pymraw.txt):
/// four grey 32 × 24 frames at 1000 frames/s, pixel (x, y) of frame k holding 64 + 10 v
/// (16 and 12 bits) or v (8 bits), v = 20 + 4x + 3y + 10k.
mod mraw {
    use std::path::Path;

    use fluidnerf_io::video::{read_video, Decoder, RangeSource, VideoOptions};

    use super::{fixture, ramp, recorded};

    #[test]
    fn eight_twelve_and_sixteen_bit_frames_match_pymraw() {
        for (file, stored) in [
            ("ramp_16bit.mraw", (|v| 64.0 + 10.0 * v) as fn(f32) -> f32),
            ("ramp_12bit.mraw", |v| 64.0 + 10.0 * v),
            ("ramp_8bit.mraw", |v| v),
        ] {
            let video = read_video(&fixture(file), &VideoOptions::default()).expect(file);
            assert_eq!(video.info.decoder, Decoder::Mraw);
            assert_eq!(video.info.range_source, RangeSource::Raw);
            assert_eq!((video.info.width, video.info.height, video.info.frame_rate), (32, 24, Some(1000.0)));
            assert_eq!((video.info.frames_in_file, video.info.frames_kept), (4, 4));
            assert_eq!(video.times, [0.0, 0.001, 0.002, 0.003]);
            for (k, (pixels, sum)) in recorded("check_mraw_with_pymraw.txt", file).into_iter().enumerate() {
                let img = &video.frames[k];
                for ((x, y), v) in pixels {
                    assert_eq!(img.get(x, y), v, "{file} frame {k} pixel ({x}, {y})");
                    assert_eq!(v, stored(ramp(x, y, k)), "{file}: the fixture's own ramp");
                }
                assert_eq!(img.data.iter().map(|&c| f64::from(c)).sum::<f64>(), sum, "{file} frame {k}");
            }
        }
        let opts = VideoOptions { start: 1, every: 2, ..Default::default() };
        let video = read_video(&fixture("ramp_12bit.mraw"), &opts).expect("reads");
        assert_eq!(video.times, [0.001, 0.003]);
        assert_eq!(video.frames[1].get(5, 7), 64.0 + 10.0 * ramp(5, 7, 3));
    }

    /// A pixel at the largest count of the header's effective bits is saturated: 4095 of 12
    /// bits at the low side of 16-bit samples, 65520 when they sit at the high side.
    #[test]
    fn counts_at_the_effective_full_scale_are_counted_as_saturated() {
        let dir = tempfile::tempdir().expect("tempdir");
        let header = std::fs::read_to_string(fixture("ramp_16bit.cih")).expect("reads");
        let mraw = dir.path().join("rec.mraw");
        let read = |first: u16, side: &str| {
            let mut bytes = std::fs::read(fixture("ramp_16bit.mraw")).expect("reads");
            bytes[..2].copy_from_slice(&first.to_le_bytes());
            std::fs::write(&mraw, bytes).expect("writes");
            let text = header.replace("EffectiveBit Side : Lower", &format!("EffectiveBit Side : {side}"));
            std::fs::write(dir.path().join("rec.cih"), text).expect("writes");
            read_video(&mraw, &VideoOptions::default()).expect("reads").info.saturated_pixels
        };
        assert_eq!(read(4095, "Lower"), 1);
        assert_eq!(read(4094, "Lower"), 0);
        assert_eq!(read(4095, "Higher"), 0);
        assert_eq!(read(0xfff0, "Higher"), 1);
    }

    /// pyMRAW writes `EffectiveBit Depth : 12` and `EffectiveBit Side : Lower` into the header
    /// of every 16-bit file it saves: counts above 4095 contradict the header, and the file's
    /// full scale is then that of its 16-bit samples, 65535, for all its frames (a count of
    /// 4095 in a frame before the first one above it included).
    #[test]
    fn counts_above_the_effective_full_scale_make_the_samples_full_scale() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::copy(fixture("ramp_16bit.cih"), dir.path().join("rec.cih")).expect("copies");
        let mraw = dir.path().join("rec.mraw");
        // Counts at pixel indices of the whole file (a frame is 32 × 24 pixels).
        let read = |counts: &[(usize, u16)]| {
            let mut bytes = std::fs::read(fixture("ramp_16bit.mraw")).expect("reads");
            for &(at, v) in counts {
                bytes[2 * at..2 * at + 2].copy_from_slice(&v.to_le_bytes());
            }
            std::fs::write(&mraw, bytes).expect("writes");
            read_video(&mraw, &VideoOptions::default()).expect("reads").info.saturated_pixels
        };
        assert_eq!(read(&[(0, 20000), (1, 4095)]), 0);
        assert_eq!(read(&[(0, 20000), (1, 65535)]), 1);
        assert_eq!(read(&[(1, 4095), (2 * 32 * 24 + 5, 20000)]), 0, "a later frame's count tells");
        assert_eq!(read(&[(1, 4095)]), 1, "the header's full scale while no count exceeds it");
    }

    /// A copy of the 8-bit fixture in `dir` (`.mraw`, and the header `.cihx` with `edit`).
    fn copy(dir: &Path, edit: impl Fn(&str) -> String) -> std::path::PathBuf {
        let header = std::fs::read(fixture("ramp_8bit.cihx")).expect("reads");
        let text = String::from_utf8_lossy(&header).into_owned();
        std::fs::write(dir.join("rec.cihx"), edit(&text)).expect("writes");
        let mraw = dir.join("rec.mraw");
        std::fs::copy(fixture("ramp_8bit.mraw"), &mraw).expect("copies");
        mraw
    }

    #[test]
    fn headers_that_do_not_fit_are_refused_with_the_reason() {
        let dir = tempfile::tempdir().expect("tempdir");
        let err = |edit: &dyn Fn(&str) -> String| {
            let mraw = copy(dir.path(), edit);
            read_video(&mraw, &VideoOptions::default()).expect_err("refused").to_string()
        };
        let e = err(&|t| t.replace("<type>Mono</type>", "<type>Color</type>"));
        assert!(e.contains("rec.cihx") && e.contains("colour recording"), "{e}");
        let e = err(&|t| t.replace("<totalFrame>4</totalFrame>", "<totalFrame>5</totalFrame>"));
        assert!(e.contains("rec.mraw") && e.contains("3072 bytes, fewer than the 3840"), "{e}");
        let e = err(&|t| t.replace("<bit>8</bit>", "<bit>10</bit>"));
        assert!(e.contains("10 bits per pixel"), "{e}");
        let e = err(&|t| t.replace("<recordRate>1000</recordRate>", "<recordRate>0</recordRate>"));
        assert!(e.contains("not a frame rate"), "{e}");
        let e = err(&|t| t.replace("<width>32</width>", ""));
        assert!(e.contains("states no `imageDataInfo/resolution/width`"), "{e}");
        let e = err(&|t| t.replace("MRaw", "TIFF"));
        assert!(e.contains("file format is `TIFF`"), "{e}");
        let e = err(&|t| t.replace("</cih>", "</ci>"));
        assert!(e.contains("without a <cih> element"), "{e}");
        // Times count from the trigger.
        let mraw = copy(dir.path(), |t: &str| t.replace("<totalFrame>", "<startFrame>-3</startFrame><totalFrame>"));
        let video = read_video(&mraw, &VideoOptions::default()).expect("reads");
        assert_eq!(video.times, [-0.003, -0.002, -0.001, 0.0]);
        let e = err(&|t| t.replace("<totalFrame>", "<startFrame>x</startFrame><totalFrame>"));
        assert!(e.contains("`frameInfo/startFrame` is `x`"), "{e}");
        // Without its header.
        std::fs::remove_file(dir.path().join("rec.cihx")).expect("removes");
        let e = read_video(&dir.path().join("rec.mraw"), &VideoOptions::default()).expect_err("refused").to_string();
        assert!(e.contains("rec.cihx") && e.contains("rec.cih") && e.contains("no header of its own"), "{e}");
    }
}
