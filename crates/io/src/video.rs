//! Video recordings decoded into frames with their times.
//!
//! - **MJPEG in AVI** (RIFF `AVI `, the usual format of high-speed and machine-vision cameras)
//!   is read here: the stream header's `dwRate / dwScale` (else the main header's
//!   microseconds per frame) gives the frame rate, the `movi` list's `##dc`/`##db` chunks
//!   (including OpenDML `AVIX` extensions) the frames, each decoded as a JPEG.
//! - **Everything else** (MP4, MOV, MKV, H.264/H.265, AVI with other codecs) is decoded by an
//!   external `ffmpeg` (frames as 16-bit grey on a pipe) after `ffprobe` reports the size, the
//!   frames' time stamps and the colour range. When they are missing, the error says how to
//!   install them. [`FFMPEG_ENV`] and [`FFPROBE_ENV`] name other binaries.
//!
//! **Range.** Video luma is often limited range ("TV", 16–235 for black–white). With
//! [`VideoRange::Auto`] the range is what the file states (`ffprobe`'s `color_range`; JPEG
//! frames are full range), or it is forced with `Full`/`Limited`. Limited-range values map
//! `16 → 0` and `235 → 255`; values outside are clipped and counted.
//!
//! Frame values are on the 0..=255 scale of 8-bit images, linearised as the scene's
//! [`Linearisation`] says (applied to the range-mapped value), as `f32`.

use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use fluidnerf_core::Image;

use crate::image::Linearisation;
use crate::IoError;

/// Environment variable naming the `ffmpeg` binary (default `ffmpeg` on the `PATH`).
pub const FFMPEG_ENV: &str = "FLUIDNERF_FFMPEG";
/// Environment variable naming the `ffprobe` binary (default `ffprobe` on the `PATH`).
pub const FFPROBE_ENV: &str = "FLUIDNERF_FFPROBE";

/// File extensions read as video.
pub const VIDEO_EXTENSIONS: [&str; 6] = ["avi", "mp4", "mov", "mkv", "m4v", "webm"];

/// Whether `path` has a video file's extension.
pub fn is_video(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| VIDEO_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The luma range of the frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VideoRange {
    /// As the file states (JPEG frames: full).
    #[default]
    Auto,
    /// 0–255.
    Full,
    /// 16–235.
    Limited,
}

impl std::str::FromStr for VideoRange {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(VideoRange::Auto),
            "full" => Ok(VideoRange::Full),
            "limited" | "tv" => Ok(VideoRange::Limited),
            _ => Err(format!("expected auto, full or limited, got `{s}`")),
        }
    }
}

/// Which frames to keep and how to read them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VideoOptions {
    pub range: VideoRange,
    /// First frame kept (0-based).
    pub start: usize,
    /// One past the last frame kept (None: to the end).
    pub end: Option<usize>,
    /// Keep every n-th frame from `start` (≥ 1).
    pub every: usize,
    pub linearisation: Linearisation,
}

impl Default for VideoOptions {
    fn default() -> Self {
        VideoOptions { range: VideoRange::Auto, start: 0, end: None, every: 1, linearisation: Linearisation::Linear }
    }
}

impl VideoOptions {
    fn keeps(&self, index: usize) -> bool {
        index >= self.start && self.end.is_none_or(|e| index < e) && (index - self.start) % self.every.max(1) == 0
    }
}

/// Decoded frames.
#[derive(Clone, Debug)]
pub struct Video {
    pub frames: Vec<Image>,
    /// Each kept frame's time in seconds from the start of the recording.
    pub times: Vec<f64>,
    /// The range the frames were read with (never `Auto`).
    pub range: VideoRange,
    /// Pixels clipped by the limited-range mapping.
    pub clipped: u64,
    /// How the frames were decoded: `"mjpeg-avi"` or `"ffmpeg"`.
    pub decoder: &'static str,
}

/// Reads the frames of a video file (see the module docs).
pub fn read_video(path: &Path, opts: &VideoOptions) -> Result<Video, IoError> {
    let mut head = [0u8; 12];
    let n = std::fs::File::open(path)
        .and_then(|mut f| f.read(&mut head))
        .map_err(|e| IoError::io(path, "video file", e))?;
    if n == 12 && &head[0..4] == b"RIFF" && &head[8..12] == b"AVI " {
        let bytes = std::fs::read(path).map_err(|e| IoError::io(path, "video file", e))?;
        if let Some(video) = read_mjpeg_avi(path, &bytes, opts)? {
            return Ok(video);
        }
    }
    read_with_ffmpeg(path, opts)
}

/// Maps one 8-bit-scale luma value (possibly fractional, for 16-bit sources) to the frame's
/// value, counting clipped pixels.
struct Mapper {
    limited: bool,
    linearisation: Linearisation,
    clipped: u64,
}

impl Mapper {
    fn map(&mut self, v: f64) -> f32 {
        let unit = if self.limited {
            let u = (v - 16.0) / 219.0;
            if !(0.0..=1.0).contains(&u) {
                self.clipped += 1;
            }
            u.clamp(0.0, 1.0)
        } else {
            (v / 255.0).clamp(0.0, 1.0)
        };
        self.linearisation.apply_unit(unit)
    }
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    b.get(at..at + 4).map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// What the walk through the RIFF chunks found.
#[derive(Default)]
struct AviScan<'a> {
    micro_per_frame: u32,
    scale: u32,
    rate: u32,
    start: u32,
    handler: [u8; 4],
    compression: [u8; 4],
    video_stream: Option<usize>,
    streams: usize,
    frames: Vec<&'a [u8]>,
}

/// Reads an AVI whose video stream is MJPEG; `None` for other codecs (left to ffmpeg).
fn read_mjpeg_avi(path: &Path, bytes: &[u8], opts: &VideoOptions) -> Result<Option<Video>, IoError> {
    let bad = |why: String| IoError::invalid(path, format!("malformed AVI: {why}"));
    let mut scan = AviScan::default();
    // The file is one or more RIFF chunks (`AVI `, then OpenDML `AVIX` extensions).
    let mut at = 0;
    while at + 12 <= bytes.len() {
        let size = u32_at(bytes, at + 4).expect("bounds checked") as usize;
        if &bytes[at..at + 4] != b"RIFF" {
            break;
        }
        let end = (at + 8).checked_add(size).filter(|&e| e <= bytes.len()).ok_or_else(|| {
            bad(format!("the RIFF chunk at byte {at} claims {size} bytes; the file ends at {}", bytes.len()))
        })?;
        walk(bytes, at + 12, end, 0, &mut scan, &bad)?;
        at = end + (end & 1);
    }
    let Some(_) = scan.video_stream else {
        return Err(bad("no video stream (`strh` of type `vids`)".into()));
    };
    let mjpeg = |c: &[u8; 4]| c.eq_ignore_ascii_case(b"MJPG") || c.eq_ignore_ascii_case(b"AVRn") || c == b"jpeg";
    if !mjpeg(&scan.compression) && !mjpeg(&scan.handler) {
        return Ok(None);
    }
    // A frame's time is `n · num / den` seconds.
    let (num, den) = if scan.scale > 0 && scan.rate > 0 {
        (scan.scale as f64, scan.rate as f64)
    } else if scan.micro_per_frame > 0 {
        (scan.micro_per_frame as f64, 1e6)
    } else {
        return Err(bad("no frame rate: the stream's dwRate/dwScale and the main header's period are zero".into()));
    };
    if scan.frames.is_empty() {
        return Err(bad("the `movi` list holds no video frames".into()));
    }
    let mut mapper =
        Mapper { limited: opts.range == VideoRange::Limited, linearisation: opts.linearisation, clipped: 0 };
    let mut frames = Vec::new();
    let mut times = Vec::new();
    let mut size: Option<(u32, u32)> = None;
    for (i, data) in scan.frames.iter().enumerate() {
        if !opts.keeps(i) {
            continue;
        }
        let img = image::load_from_memory_with_format(data, image::ImageFormat::Jpeg)
            .map_err(|e| IoError::invalid(path, format!("frame {i}: not a decodable JPEG: {e}")))?
            .into_luma8();
        let (w, h) = img.dimensions();
        if *size.get_or_insert((w, h)) != (w, h) {
            return Err(IoError::invalid(path, format!("frame {i} is {w}×{h}; the first frame kept is {:?}", size)));
        }
        let mut out = Image::zeros(w as usize, h as usize);
        for (o, &v) in out.data.iter_mut().zip(img.as_raw()) {
            *o = mapper.map(f64::from(v));
        }
        frames.push(out);
        times.push((scan.start as f64 + i as f64) * num / den);
    }
    if frames.is_empty() {
        return Err(IoError::invalid(
            path,
            format!(
                "no frame kept: the video has {} frames and the selection starts at {}",
                scan.frames.len(),
                opts.start
            ),
        ));
    }
    let range = if mapper.limited { VideoRange::Limited } else { VideoRange::Full };
    Ok(Some(Video { frames, times, range, clipped: mapper.clipped, decoder: "mjpeg-avi" }))
}

/// Walks the chunks in `bytes[from..to]`, descending into lists.
fn walk<'a>(
    bytes: &'a [u8],
    from: usize,
    to: usize,
    depth: usize,
    scan: &mut AviScan<'a>,
    bad: &dyn Fn(String) -> IoError,
) -> Result<(), IoError> {
    // AVI nests lists three deep (`hdrl` › `strl`, `movi` › `rec `); far deeper is corrupt.
    if depth > 16 {
        return Err(bad(format!("lists nested more than 16 deep at byte {from}")));
    }
    let mut at = from;
    while at + 8 <= to {
        let id: [u8; 4] = bytes[at..at + 4].try_into().expect("4 bytes");
        let size = u32_at(bytes, at + 4).expect("bounds checked") as usize;
        let body = at + 8;
        let end = body.checked_add(size).filter(|&e| e <= to).ok_or_else(|| {
            bad(format!(
                "the chunk `{}` at byte {at} claims {size} bytes; its parent ends at byte {to} (a truncated file?)",
                String::from_utf8_lossy(&id)
            ))
        })?;
        let data = &bytes[body..end];
        match &id {
            b"LIST" if size >= 4 => walk(bytes, body + 4, end, depth + 1, scan, bad)?,
            b"avih" => scan.micro_per_frame = u32_at(data, 0).unwrap_or(0),
            b"strh" => {
                let is_video = data.get(0..4) == Some(b"vids");
                if is_video && scan.video_stream.is_none() {
                    scan.video_stream = Some(scan.streams);
                    scan.handler = data.get(4..8).and_then(|s| s.try_into().ok()).unwrap_or_default();
                    scan.scale = u32_at(data, 20).unwrap_or(0);
                    scan.rate = u32_at(data, 24).unwrap_or(0);
                    scan.start = u32_at(data, 28).unwrap_or(0);
                }
                scan.streams += 1;
            }
            b"strf" if scan.video_stream == Some(scan.streams.saturating_sub(1)) => {
                scan.compression = data.get(16..20).and_then(|s| s.try_into().ok()).unwrap_or_default();
            }
            _ => {
                // Stream data: `##dc` (compressed) or `##db` (uncompressed) of the video stream.
                if let Some(v) = scan.video_stream {
                    let tag = format!("{v:02}");
                    if id[..2] == *tag.as_bytes() && (&id[2..] == b"dc" || &id[2..] == b"db") && !data.is_empty() {
                        scan.frames.push(data);
                    }
                }
            }
        }
        at = end + (end & 1);
    }
    Ok(())
}

fn program(env: &str, default: &str) -> PathBuf {
    std::env::var_os(env).map_or_else(|| PathBuf::from(default), PathBuf::from)
}

fn missing_program(path: &Path, program: &Path, error: &std::io::Error) -> IoError {
    IoError::invalid(
        path,
        format!(
            "decoding this video needs ffmpeg, and `{}` could not be run ({error}). Install it \
             (`apt install ffmpeg`, `dnf install ffmpeg`, `brew install ffmpeg` or `conda install -c \
             conda-forge ffmpeg`), point {FFMPEG_ENV} and {FFPROBE_ENV} at the binaries, or convert the \
             recording to an MJPEG AVI (read without ffmpeg) or to an image sequence",
            program.display()
        ),
    )
}

#[derive(serde::Deserialize)]
struct Probe {
    #[serde(default)]
    streams: Vec<ProbeStream>,
    #[serde(default)]
    frames: Vec<ProbeFrame>,
}

#[derive(serde::Deserialize)]
struct ProbeStream {
    width: Option<u32>,
    height: Option<u32>,
    color_range: Option<String>,
    avg_frame_rate: Option<String>,
}

#[derive(serde::Deserialize)]
struct ProbeFrame {
    best_effort_timestamp_time: Option<String>,
    pts_time: Option<String>,
}

fn read_with_ffmpeg(path: &Path, opts: &VideoOptions) -> Result<Video, IoError> {
    let ffprobe = program(FFPROBE_ENV, "ffprobe");
    let out = Command::new(&ffprobe)
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .arg("stream=width,height,color_range,avg_frame_rate:frame=best_effort_timestamp_time,pts_time")
        .args(["-of", "json"])
        .arg(path)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| missing_program(path, &ffprobe, &e))?;
    if !out.status.success() {
        return Err(IoError::invalid(
            path,
            format!("ffprobe cannot read this file: {}", String::from_utf8_lossy(&out.stderr).trim()),
        ));
    }
    let probe: Probe = serde_json::from_slice(&out.stdout)
        .map_err(|e| IoError::invalid(path, format!("unexpected ffprobe output: {e}")))?;
    let Some(stream) = probe.streams.first() else {
        return Err(IoError::invalid(path, "no video stream"));
    };
    let (Some(w), Some(h)) = (stream.width, stream.height) else {
        return Err(IoError::invalid(path, "ffprobe reports no frame size"));
    };
    if w == 0 || h == 0 {
        return Err(IoError::invalid(path, format!("frame size {w}×{h}")));
    }
    let rate = stream.avg_frame_rate.as_deref().and_then(|r| {
        let (a, b) = r.split_once('/')?;
        let (a, b): (f64, f64) = (a.parse().ok()?, b.parse().ok()?);
        (a > 0.0 && b > 0.0).then_some(a / b)
    });
    let stamps: Vec<Option<f64>> = probe
        .frames
        .iter()
        .map(|f| f.best_effort_timestamp_time.as_deref().or(f.pts_time.as_deref()).and_then(|t| t.parse().ok()))
        .collect();
    let limited = match opts.range {
        VideoRange::Full => false,
        VideoRange::Limited => true,
        // ffmpeg's "tv" is limited range; JPEG-based ("pc"/"jpeg") and unstated are taken as
        // stated or full only when the decoder says so, else limited (what video codecs default to).
        VideoRange::Auto => !matches!(stream.color_range.as_deref(), Some("pc" | "jpeg")),
    };
    let ffmpeg = program(FFMPEG_ENV, "ffmpeg");
    let mut child = Command::new(&ffmpeg)
        .args(["-v", "error", "-nostdin", "-i"])
        .arg(path)
        .args(["-map", "0:v:0", "-f", "rawvideo", "-pix_fmt", "gray16le"])
        // Keep the stored code values: no range conversion inside ffmpeg.
        .args(["-vf", "scale=in_range=full:out_range=full", "-fps_mode", "passthrough", "-"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| missing_program(path, &ffmpeg, &e))?;
    let mut raw = Vec::new();
    child
        .stdout
        .take()
        .expect("stdout is piped")
        .read_to_end(&mut raw)
        .map_err(|e| IoError::io(path, "ffmpeg output", e))?;
    let status = child.wait_with_output().map_err(|e| IoError::io(path, "ffmpeg", e))?;
    if !status.status.success() {
        return Err(IoError::invalid(
            path,
            format!("ffmpeg failed to decode it: {}", String::from_utf8_lossy(&status.stderr).trim()),
        ));
    }
    let frame_bytes = w as usize * h as usize * 2;
    let count = raw.len() / frame_bytes;
    if count == 0 {
        return Err(IoError::invalid(path, "ffmpeg decoded no frames"));
    }
    let mut mapper = Mapper { limited, linearisation: opts.linearisation, clipped: 0 };
    let mut frames = Vec::new();
    let mut times = Vec::new();
    for (i, chunk) in raw.chunks_exact(frame_bytes).enumerate() {
        if !opts.keeps(i) {
            continue;
        }
        let time = match (stamps.get(i).copied().flatten(), rate) {
            (Some(t), _) => t,
            (None, Some(r)) => i as f64 / r,
            (None, None) => {
                return Err(IoError::invalid(path, format!("frame {i} has no time stamp and the stream no frame rate")))
            }
        };
        let mut out = Image::zeros(w as usize, h as usize);
        for (o, px) in out.data.iter_mut().zip(chunk.chunks_exact(2)) {
            // 16-bit code values, 8-bit scale: 65535 ↔ 255 (ffmpeg scales n-bit to 16 bits by
            // shifting, so 8-bit 235 arrives as 235 · 257).
            *o = mapper.map(f64::from(u16::from_le_bytes([px[0], px[1]])) / 257.0);
        }
        frames.push(out);
        times.push(time);
    }
    if frames.is_empty() {
        return Err(IoError::invalid(
            path,
            format!("no frame kept: the video has {count} frames and the selection starts at {}", opts.start),
        ));
    }
    let range = if limited { VideoRange::Limited } else { VideoRange::Full };
    Ok(Video { frames, times, range, clipped: mapper.clipped, decoder: "ffmpeg" })
}
