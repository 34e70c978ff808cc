//! Video recordings decoded into frames with their times.
//!
//! - **MJPEG in AVI** (RIFF `AVI `, the usual format of high-speed and machine-vision cameras)
//!   is read here: the stream header's `dwRate / dwScale` (else the main header's
//!   microseconds per frame) gives the frame rate, the `movi` list's `##dc`/`##db` chunks
//!   (including OpenDML `AVIX` extensions) the frames, each decoded as a JPEG (one that ends
//!   before its end-of-image marker is refused, as a JPEG file is). An empty chunk
//!   (a frame the camera dropped) gives no frame but keeps its time slot, as in ffmpeg. The file is
//!   walked chunk by chunk and only the kept frames are read, so a long recording never sits
//!   in memory whole.
//! - **Phantom cine** (`.cine`, high-speed cameras' raw recordings) is read here too, its grey
//!   frames as the sensor's linear counts above the black level, with no range mapping or
//!   linearisation; packed and colour frames are refused.
//! - **Photron MRAW** (`.mraw` with its `.cihx`/`.cih` header beside it) likewise: grey frames
//!   of 8, 12 (packed) or 16 bits as the sensor's linear counts.
//! - **Everything else** (MP4, MOV, MKV, WebM, H.264/H.265, AVI with other codecs) is decoded
//!   by an external `ffmpeg` (frames as 16-bit grey on a pipe, read one at a time) after
//!   `ffprobe` reports the size, the frames' time stamps and the colour range. When they are
//!   missing, the error names the file and says how to install them. [`FFMPEG_ENV`] and
//!   [`FFPROBE_ENV`] name other binaries.
//! - A file with a video extension whose first bytes are none of AVI (RIFF), MP4/MOV (ISO
//!   boxes) or Matroska/WebM (EBML) is refused before any decoder runs.
//!
//! **Range.** Video luma is often limited range ("TV", 16–235 for black–white). With
//! [`VideoRange::Auto`] the range is what the file states (`ffprobe`'s `color_range`: `tv` is
//! limited, `pc`/`jpeg` full, unstated limited, the video codecs' default; JPEG frames in an
//! AVI are full range, the JFIF default, unless marked `CS=ITU601` as libavcodec marks
//! limited-range JPEGs), or it is forced with `Full`/`Limited`. Limited-range
//! values map `16 → 0` and `235 → 255` (unit `0 → 1` on the 8-bit scale); values outside are
//! clipped and counted. [`VideoInfo`] records the range used and where it came from.
//!
//! **Values.** Frame values are on the 0..=255 scale of 8-bit images, linearised as the
//! scene's [`Linearisation`] says (applied to the range-mapped value), as `f32`. Colour video
//! is reduced to its luma.
//!
//! **Times.** A frame's time in seconds is its index times the frame period (AVI) or its
//! presentation time stamp (ffmpeg; the frame rate when a frame has none), plus
//! [`VideoOptions::time_offset_s`].

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use fluidnerf_core::{num, Image};

use crate::image::Linearisation;
use crate::IoError;

/// Environment variable naming the `ffmpeg` binary (default `ffmpeg` on the `PATH`).
pub const FFMPEG_ENV: &str = "FLUIDNERF_FFMPEG";
/// Environment variable naming the `ffprobe` binary (default `ffprobe` on the `PATH`).
pub const FFPROBE_ENV: &str = "FLUIDNERF_FFPROBE";

/// File extensions read as video.
pub const VIDEO_EXTENSIONS: [&str; 8] = ["avi", "mp4", "mov", "mkv", "m4v", "webm", "cine", "mraw"];

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
            "full" | "pc" => Ok(VideoRange::Full),
            "limited" | "tv" => Ok(VideoRange::Limited),
            _ => Err(format!("expected auto, full or limited, got `{s}`")),
        }
    }
}

impl std::fmt::Display for VideoRange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            VideoRange::Auto => "auto",
            VideoRange::Full => "full",
            VideoRange::Limited => "limited",
        })
    }
}

/// Where the range a video was read with came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RangeSource {
    /// [`VideoOptions::range`] forced it.
    Option,
    /// The file states it (`ffprobe`'s `color_range`, or a JPEG's `CS=ITU601` comment).
    File,
    /// JPEG frames, full range unless stated otherwise (JFIF).
    JpegDefault,
    /// The stream states no range; video codecs default to limited.
    VideoDefault,
    /// Raw sensor counts (a cine or MRAW file): no range applies.
    Raw,
}

/// Which decoder read a video.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Decoder {
    /// fluidnerf's own RIFF walk and JPEG decoder.
    MjpegAvi,
    /// An external `ffmpeg`.
    Ffmpeg,
    /// fluidnerf's own reader of Phantom cine files.
    Cine,
    /// fluidnerf's own reader of Photron MRAW files.
    Mraw,
}

impl std::fmt::Display for Decoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Decoder::MjpegAvi => "mjpeg-avi",
            Decoder::Ffmpeg => "ffmpeg",
            Decoder::Cine => "cine",
            Decoder::Mraw => "mraw",
        })
    }
}

/// Which frames to keep and how to read them. The default keeps every frame, range as the
/// file states, no time offset, values linear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VideoOptions {
    pub range: VideoRange,
    /// First frame kept (0-based). Default 0.
    pub start: usize,
    /// One past the last frame kept (None, the default: to the end).
    pub end: Option<usize>,
    /// Keep every n-th frame from `start` (≥ 1; 0 is taken as 1). Default 1.
    pub every: usize,
    /// Seconds added to every frame's time (to align cameras or a trigger). Default 0.
    pub time_offset_s: f64,
    /// Applied to the range-mapped value. Default linear.
    pub linearisation: Linearisation,
}

impl Default for VideoOptions {
    fn default() -> Self {
        VideoOptions {
            range: VideoRange::Auto,
            start: 0,
            end: None,
            every: 1,
            time_offset_s: 0.0,
            linearisation: Linearisation::Linear,
        }
    }
}

impl VideoOptions {
    pub(crate) fn keeps(&self, index: usize) -> bool {
        index >= self.start
            && self.end.is_none_or(|e| index < e)
            && (index - self.start).is_multiple_of(self.every.max(1))
    }

    /// Whether no frame at or after `index` is kept.
    pub(crate) fn done(&self, index: usize) -> bool {
        self.end.is_some_and(|e| index >= e)
    }
}

/// One decoded frame.
#[derive(Clone, Debug)]
pub struct VideoFrame {
    /// Index of the frame in the file (0-based, before the selection).
    pub index: usize,
    /// Seconds, including [`VideoOptions::time_offset_s`].
    pub time_s: f64,
    pub image: Image,
    /// A pixel's value when the recording was at the top of its scale: the 8-bit code 255 (235
    /// in limited range) after the range mapping and linearisation, or a raw recording's largest
    /// count less its black level. Pixels at or above it are saturated, counted by
    /// [`read_video_frames`] into [`VideoInfo::saturated_pixels`]. None when the decoder counts
    /// them itself: an MRAW's full scale is known only once all its frames are read (its
    /// header's effective bits hold unless a count exceeds them).
    pub full_scale: Option<f32>,
}

/// What reading a video did.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VideoInfo {
    pub decoder: Decoder,
    pub width: u32,
    pub height: u32,
    /// Frames per second as the file states it, if it does.
    pub frame_rate: Option<f64>,
    /// Frames in the file (for ffmpeg: as `ffprobe` counted them, else as decoded).
    pub frames_in_file: usize,
    /// Frames passed on after the selection.
    pub frames_kept: usize,
    /// The range the frames were read with (never `Auto`).
    pub range: VideoRange,
    pub range_source: RangeSource,
    /// Pixels clipped by the limited-range mapping, over the kept frames.
    pub clipped_pixels: u64,
    /// Pixels of the kept frames at their full scale ([`VideoFrame::full_scale`]): saturated,
    /// they recorded less light than arrived. Counted by [`read_video_frames`] for every
    /// decoder that states each frame's full scale (and leaves it 0), by the others (MRAW)
    /// themselves.
    pub saturated_pixels: u64,
    /// The rotation the file asks players to show its frames with, in degrees (a camera held
    /// on its side); the frames are read as stored regardless.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub display_rotation_deg: Option<f64>,
}

/// Decoded frames.
#[derive(Clone, Debug)]
pub struct Video {
    pub frames: Vec<Image>,
    /// Each kept frame's time in seconds (see the module docs).
    pub times: Vec<f64>,
    pub info: VideoInfo,
}

/// Reads the kept frames of a video file into memory (see the module docs and
/// [`read_video_frames`]).
pub fn read_video(path: &Path, opts: &VideoOptions) -> Result<Video, IoError> {
    let mut frames = Vec::new();
    let mut times = Vec::new();
    let info = read_video_frames(path, opts, |f| {
        frames.push(f.image);
        times.push(f.time_s);
        Ok(())
    })?;
    Ok(Video { frames, times, info })
}

/// Decodes the kept frames of a video file one at a time, in order, passing each to
/// `on_frame` (which may stop the reading by returning an error). At least one frame is kept,
/// else it is an error; so is a selection that ends past the file's last frame.
pub fn read_video_frames(
    path: &Path,
    opts: &VideoOptions,
    mut on_frame: impl FnMut(VideoFrame) -> Result<(), IoError>,
) -> Result<VideoInfo, IoError> {
    if !opts.time_offset_s.is_finite() {
        return Err(IoError::invalid(path, format!("time offset {} s is not finite", opts.time_offset_s)));
    }
    // Two kept frames at one time would be one camera twice at one instant: refused here,
    // naming the frames, where a large offset has swamped the frame interval.
    let mut last: Option<(usize, f64)> = None;
    // Counted here for every decoder, on the frames kept, as the scene's images are counted.
    let mut saturated = 0u64;
    let mut on_frame = |frame: VideoFrame| {
        match last {
            Some((index, time)) if index < frame.index && frame.time_s <= time => {
                let why = if opts.time_offset_s == 0.0 {
                    String::new()
                } else {
                    format!(
                        " (with the time offset of {} s added, which rounds the frame interval away)",
                        num(opts.time_offset_s)
                    )
                };
                return Err(IoError::invalid(
                    path,
                    format!(
                        "frame {} is at {} s, not after frame {index} at {} s{why}",
                        frame.index,
                        num(frame.time_s),
                        num(time)
                    ),
                ));
            }
            _ => last = Some((frame.index, frame.time_s)),
        }
        if let Some(full_scale) = frame.full_scale {
            saturated += frame.image.data.iter().filter(|&&v| v >= full_scale).count() as u64;
        }
        on_frame(frame)
    };
    crate::check_regular_file(path, "video file")?;
    // An MRAW has no header of its own to sniff: its extension says what it is.
    let mut info = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mraw")) {
        crate::mraw::read_mraw(path, opts, &mut on_frame)?
    } else {
        read_sniffed(path, opts, &mut on_frame)?
    };
    info.saturated_pixels += saturated;
    if info.frames_kept == 0 {
        return Err(IoError::invalid(
            path,
            format!(
                "no frame kept: the video has {} frame(s) and the selection starts at frame {}",
                info.frames_in_file, opts.start
            ),
        ));
    }
    // A selection past the end would otherwise be cut short without a word, and the recording
    // taken for the longer one asked for.
    if let Some(end) = opts.end.filter(|&end| end > info.frames_in_file) {
        return Err(IoError::invalid(
            path,
            format!(
                "the selection runs to frame {} but the video has only {} frame(s), 0 to {}: end the selection at \
                 {} at most, or leave its end open",
                end - 1,
                info.frames_in_file,
                info.frames_in_file - 1,
                info.frames_in_file
            ),
        ));
    }
    Ok(info)
}

/// Whether `path` is a raw recording of a high-speed camera (an MRAW, by its extension as its
/// reader knows it, or a file with a cine header), whose frames are the sensor's linear
/// counts: no range or linearisation applies to them. False for a file that cannot be read
/// (reading it says why).
pub fn is_raw_recording(path: &Path) -> bool {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("mraw")) {
        return true;
    }
    let mut head = Vec::with_capacity(12);
    File::open(path).and_then(|f| f.take(12).read_to_end(&mut head)).is_ok() && sniff(&head) == Container::Cine
}

/// Warns that `--video-range` and the linearisation do not apply to `path`, a raw recording
/// (`kind`: "a cine file") whose frames are linear sensor counts, when either is given.
pub(crate) fn warn_unused_by_raw(path: &Path, opts: &VideoOptions, kind: &str) {
    if opts.range != VideoRange::Auto {
        log::warn!("{}: --video-range has no effect on {kind}, whose frames are raw sensor counts", path.display());
    }
    if opts.linearisation != Linearisation::Linear {
        log::warn!(
            "{}: the linearisation has no effect on {kind}, whose frames are linear sensor counts",
            path.display()
        );
    }
}

/// Reads a video by the container its first bytes announce.
fn read_sniffed(
    path: &Path,
    opts: &VideoOptions,
    on_frame: &mut dyn FnMut(VideoFrame) -> Result<(), IoError>,
) -> Result<VideoInfo, IoError> {
    let mut head = Vec::with_capacity(12);
    File::open(path).and_then(|f| f.take(12).read_to_end(&mut head)).map_err(|e| IoError::io(path, "video file", e))?;
    if head.is_empty() {
        // Said as such: an interrupted copy or download leaves one, not a file of another kind.
        return Err(IoError::invalid(path, "the video file is empty (0 bytes)"));
    }
    Ok(match sniff(&head) {
        Container::Avi => match read_mjpeg_avi(path, opts, on_frame)? {
            Some(info) => info,
            None => read_with_ffmpeg(path, opts, on_frame)?,
        },
        Container::Cine => crate::cine::read_cine(path, opts, on_frame)?,
        Container::Unknown if crate::davis::is_davis_path(path) => {
            // Sent to ffmpeg, it was refused as needing ffmpeg, which reads no DaVis file either.
            return Err(IoError::invalid(
                path,
                "is a LaVision DaVis image (a frame of every camera at one recorded instant), not a video: read it \
                 as an image (`read_davis` from Python), or import a folder of them as a DaVis recording",
            ));
        }
        Container::Unknown if is_video(path) || head.len() < 12 => {
            return Err(IoError::invalid(
                path,
                "not a video file: it begins with neither a RIFF `AVI ` header, a Phantom cine header, an MP4/MOV \
                 box nor a Matroska/WebM header (damaged, or not what its extension says)",
            ))
        }
        Container::IsoBmff | Container::Matroska | Container::Unknown => read_with_ffmpeg(path, opts, on_frame)?,
    })
}

/// The container a file's first 12 bytes announce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Container {
    Avi,
    /// Phantom cine.
    Cine,
    /// MP4, MOV, M4V (ISO base media file format / QuickTime atoms).
    IsoBmff,
    /// MKV, WebM.
    Matroska,
    Unknown,
}

fn sniff(head: &[u8]) -> Container {
    if head.len() >= 12 && &head[0..4] == b"RIFF" && &head[8..12] == b"AVI " {
        Container::Avi
    } else if crate::cine::is_cine(head) {
        Container::Cine
    } else if head.starts_with(&[0x1A, 0x45, 0xDF, 0xA3]) {
        Container::Matroska
    } else if head.len() >= 8
        && [b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"pnot"].iter().any(|b| head[4..8] == b[..])
    {
        Container::IsoBmff
    } else {
        Container::Unknown
    }
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

/// What the top of the 8-bit scale (the code 255 in full range, 235 in limited) becomes after
/// [`Mapper::map`], whatever the linearisation: 255.
const FULL_SCALE_8BIT: f32 = 255.0;

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    b.get(at..at + 4).map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// An AVI file read chunk by chunk.
struct Riff {
    file: BufReader<File>,
}

impl Riff {
    /// `n` bytes at `at`; the caller keeps `at + n` within the file.
    fn read_at(&mut self, at: u64, n: usize) -> std::io::Result<Vec<u8>> {
        self.file.seek(SeekFrom::Start(at))?;
        let mut buf = vec![0; n];
        self.file.read_exact(&mut buf)?;
        Ok(buf)
    }
}

/// What the walk through the RIFF chunks found.
#[derive(Default)]
struct AviScan {
    micro_per_frame: u32,
    scale: u32,
    rate: u32,
    start: u32,
    width: u32,
    height: u32,
    handler: [u8; 4],
    compression: [u8; 4],
    video_stream: Option<usize>,
    streams: usize,
    /// Offset and length of each video frame's data.
    frames: Vec<(u64, usize)>,
}

/// Reads an AVI whose video stream is MJPEG; `None` for other codecs (left to ffmpeg).
fn read_mjpeg_avi(
    path: &Path,
    opts: &VideoOptions,
    on_frame: &mut dyn FnMut(VideoFrame) -> Result<(), IoError>,
) -> Result<Option<VideoInfo>, IoError> {
    let bad = |why: String| IoError::invalid(path, format!("malformed AVI: {why}"));
    let io = |e| IoError::io(path, "video file", e);
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut riff = Riff { file: BufReader::new(file) };
    let mut scan = AviScan::default();
    // The file is one or more RIFF chunks (`AVI `, then OpenDML `AVIX` extensions).
    let mut at = 0u64;
    while at + 12 <= len {
        let head = riff.read_at(at, 12).map_err(io)?;
        if &head[0..4] != b"RIFF" {
            break;
        }
        let size = u64::from(u32_at(&head, 4).unwrap_or(0));
        let end = at + 8 + size;
        if end > len {
            return Err(bad(format!(
                "the RIFF chunk at byte {at} claims {size} bytes but the file ends at byte {len} (a truncated file?)"
            )));
        }
        walk(&mut riff, at + 12, end, 0, &mut scan, &bad)?;
        at = end + (end & 1);
    }
    if scan.video_stream.is_none() {
        return Err(bad("no video stream (no `strh` header of type `vids`)".into()));
    }
    let mjpeg = |c: &[u8; 4]| c.eq_ignore_ascii_case(b"MJPG") || c.eq_ignore_ascii_case(b"AVRn") || c == b"jpeg";
    if !mjpeg(&scan.compression) && !mjpeg(&scan.handler) {
        return Ok(None);
    }
    // A frame's time is `n · num / den` seconds.
    let (num, den) = if scan.scale > 0 && scan.rate > 0 {
        (f64::from(scan.scale), f64::from(scan.rate))
    } else if scan.micro_per_frame > 0 {
        (f64::from(scan.micro_per_frame), 1e6)
    } else {
        return Err(bad(
            "zero frame rate: the video stream's dwRate/dwScale and the main header's microseconds per frame are \
             all zero"
                .into(),
        ));
    };
    if scan.frames.iter().all(|&(_, n)| n == 0) {
        return Err(bad("the `movi` list holds no video frames".into()));
    }
    let mut range = None;
    let mut mapper = Mapper { limited: false, linearisation: opts.linearisation, clipped: 0 };
    let mut size: Option<(u32, u32)> = None;
    let mut kept = 0;
    for (i, &(offset, n)) in scan.frames.iter().enumerate() {
        if opts.done(i) {
            break;
        }
        if !opts.keeps(i) || n == 0 {
            continue;
        }
        let data = riff.read_at(offset, n).map_err(io)?;
        // Checked here as for a JPEG file: the decoder would fill a cut frame with grey.
        if crate::image::jpeg_is_truncated(&data) {
            return Err(IoError::invalid(
                path,
                format!(
                    "frame {i}: truncated JPEG: its chunk's {n} bytes end before the end-of-image marker (a decoder \
                     would fill the missing part with grey)"
                ),
            ));
        }
        // The first kept frame decides the range for all.
        let (range, _) = *range.get_or_insert_with(|| match opts.range {
            VideoRange::Auto if jpeg_says_limited(&data) => (VideoRange::Limited, RangeSource::File),
            VideoRange::Auto => (VideoRange::Full, RangeSource::JpegDefault),
            forced => (forced, RangeSource::Option),
        });
        mapper.limited = range == VideoRange::Limited;
        let data = with_standard_huffman_tables(&data);
        // Compared before decoding: a damaged frame's header can claim millions of pixels, which
        // the decoder would allocate and fill with grey before the sizes were compared.
        let claimed = image::ImageReader::with_format(std::io::Cursor::new(&*data), image::ImageFormat::Jpeg)
            .into_dimensions()
            .map_err(|e| IoError::invalid(path, format!("frame {i}: not a decodable JPEG: {e}")))?;
        if let Some(first) = size.filter(|&first| first != claimed) {
            return Err(IoError::invalid(
                path,
                format!(
                    "frame {i} is {}×{} pixels; the first frame kept is {}×{}",
                    claimed.0, claimed.1, first.0, first.1
                ),
            ));
        }
        let img = image::load_from_memory_with_format(&data, image::ImageFormat::Jpeg)
            .map_err(|e| IoError::invalid(path, format!("frame {i}: not a decodable JPEG: {e}")))?
            .into_luma8();
        let (w, h) = img.dimensions();
        let first = *size.get_or_insert((w, h));
        if first != (w, h) {
            return Err(IoError::invalid(
                path,
                format!("frame {i} is {w}×{h} pixels; the first frame kept is {}×{}", first.0, first.1),
            ));
        }
        let mut image = Image::zeros(w as usize, h as usize);
        for (o, &v) in image.data.iter_mut().zip(img.as_raw()) {
            *o = mapper.map(f64::from(v));
        }
        let time_s = (f64::from(scan.start) + i as f64) * num / den + opts.time_offset_s;
        on_frame(VideoFrame { index: i, time_s, image, full_scale: Some(FULL_SCALE_8BIT) })?;
        kept += 1;
    }
    let (width, height) = size.unwrap_or((scan.width, scan.height));
    let (range, range_source) = range.unwrap_or((VideoRange::Full, RangeSource::JpegDefault));
    Ok(Some(VideoInfo {
        decoder: Decoder::MjpegAvi,
        width,
        height,
        frame_rate: Some(den / num),
        frames_in_file: scan.frames.len(),
        frames_kept: kept,
        range,
        range_source,
        clipped_pixels: mapper.clipped,
        saturated_pixels: 0,
        display_rotation_deg: None,
    }))
}

/// The Huffman tables of the JPEG standard (ITU-T T.81, Annex K.3) as one DHT segment:
/// luminance DC and AC (class and id `0x00`, `0x10`), chrominance DC and AC (`0x01`, `0x11`),
/// each as its 16 counts of codes per length, then its symbols.
const STANDARD_DHT: [u8; 420] = {
    const TABLES: [(u8, [u8; 16], &[u8]); 4] = [
        (0x00, [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0], &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]),
        (
            0x10,
            [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7d],
            &[
                0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61, 0x07, 0x22,
                0x71, 0x14, 0x32, 0x81, 0x91, 0xa1, 0x08, 0x23, 0x42, 0xb1, 0xc1, 0x15, 0x52, 0xd1, 0xf0, 0x24, 0x33,
                0x62, 0x72, 0x82, 0x09, 0x0a, 0x16, 0x17, 0x18, 0x19, 0x1a, 0x25, 0x26, 0x27, 0x28, 0x29, 0x2a, 0x34,
                0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54, 0x55,
                0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75, 0x76,
                0x77, 0x78, 0x79, 0x7a, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96,
                0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5,
                0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4,
                0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe1, 0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf1,
                0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
            ],
        ),
        (0x01, [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0], &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]),
        (
            0x11,
            [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77],
            &[
                0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71, 0x13,
                0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xa1, 0xb1, 0xc1, 0x09, 0x23, 0x33, 0x52, 0xf0, 0x15, 0x62,
                0x72, 0xd1, 0x0a, 0x16, 0x24, 0x34, 0xe1, 0x25, 0xf1, 0x17, 0x18, 0x19, 0x1a, 0x26, 0x27, 0x28, 0x29,
                0x2a, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54,
                0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75,
                0x76, 0x77, 0x78, 0x79, 0x7a, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94,
                0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3,
                0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2,
                0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea,
                0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
            ],
        ),
    ];
    let mut out = [0u8; 420];
    // Marker, then the segment's length (its bytes after the marker).
    out[0] = 0xFF;
    out[1] = 0xC4;
    out[2] = (418u16 >> 8) as u8;
    out[3] = (418u16 & 0xFF) as u8;
    let mut at = 4;
    let mut t = 0;
    while t < TABLES.len() {
        let (class_id, counts, symbols) = TABLES[t];
        out[at] = class_id;
        at += 1;
        let mut i = 0;
        while i < 16 {
            out[at] = counts[i];
            at += 1;
            i += 1;
        }
        let mut i = 0;
        while i < symbols.len() {
            out[at] = symbols[i];
            at += 1;
            i += 1;
        }
        t += 1;
    }
    assert!(at == 420, "the four tables fill the segment");
    out
};

/// `jpeg` with the standard Huffman tables ([`STANDARD_DHT`]) put before its scan when it
/// defines none: MJPEG cameras commonly leave them out of every frame (the AVI1 form of
/// MJPEG), relying on the decoder to use the standard ones, which JPEG decoders of still
/// images do not do. A JPEG with tables of its own, or whose markers cannot be walked, is
/// returned as it is (for the decoder to judge).
fn with_standard_huffman_tables(jpeg: &[u8]) -> std::borrow::Cow<'_, [u8]> {
    use std::borrow::Cow;
    if !jpeg.starts_with(&[0xFF, 0xD8]) {
        return Cow::Borrowed(jpeg);
    }
    let mut at = 2;
    while at + 1 < jpeg.len() {
        if jpeg[at] != 0xFF {
            return Cow::Borrowed(jpeg);
        }
        let marker = jpeg[at + 1];
        match marker {
            // Fill bytes before a marker.
            0xFF => at += 1,
            // Markers without a segment.
            0x01 | 0xD0..=0xD7 => at += 2,
            0xC4 => return Cow::Borrowed(jpeg),
            0xDA => {
                let mut out = Vec::with_capacity(jpeg.len() + STANDARD_DHT.len());
                out.extend_from_slice(&jpeg[..at]);
                out.extend_from_slice(&STANDARD_DHT);
                out.extend_from_slice(&jpeg[at..]);
                return Cow::Owned(out);
            }
            _ => {
                let Some(len) = jpeg.get(at + 2..at + 4).map(|b| usize::from(u16::from_be_bytes([b[0], b[1]]))) else {
                    return Cow::Borrowed(jpeg);
                };
                at += 2 + len;
            }
        }
    }
    Cow::Borrowed(jpeg)
}

/// Whether a JPEG's comments mark it limited range: libavcodec writes `CS=ITU601` into
/// JPEGs with 16–235 luma and reads it back the same way; JFIF itself is full range.
fn jpeg_says_limited(jpeg: &[u8]) -> bool {
    if !jpeg.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    let mut at = 2;
    // Segments up to the start of scan: marker, big-endian length (counting itself), payload.
    while let Some(&[0xFF, marker, hi, lo]) = jpeg.get(at..at + 4) {
        let len = usize::from(u16::from_be_bytes([hi, lo]));
        match marker {
            0xDA | 0xD9 => return false,
            0xFE if jpeg.get(at + 4..at + 2 + len).is_some_and(|c| c.starts_with(b"CS=ITU601")) => return true,
            _ if len < 2 => return false,
            _ => at += 2 + len,
        }
    }
    false
}

/// Walks the chunks in `from..to` of the file, descending into lists.
fn walk(
    riff: &mut Riff,
    from: u64,
    to: u64,
    depth: usize,
    scan: &mut AviScan,
    bad: &dyn Fn(String) -> IoError,
) -> Result<(), IoError> {
    // AVI nests lists three deep (`hdrl` › `strl`, `movi` › `rec `); far deeper is corrupt.
    if depth > 16 {
        return Err(bad(format!("lists nested more than 16 deep at byte {from}")));
    }
    let read = |riff: &mut Riff, at: u64, n: usize| riff.read_at(at, n).map_err(|e| bad(format!("byte {at}: {e}")));
    let mut at = from;
    while at + 8 <= to {
        let head = read(riff, at, 8)?;
        let id: [u8; 4] = [head[0], head[1], head[2], head[3]];
        let size = u64::from(u32_at(&head, 4).unwrap_or(0));
        let body = at + 8;
        let end = body + size;
        if end > to {
            return Err(bad(format!(
                "the chunk `{}` at byte {at} claims {size} bytes but its parent ends at byte {to} (a truncated \
                 file?)",
                String::from_utf8_lossy(&id)
            )));
        }
        // Header chunks are small; only their first fields are used.
        let header = |riff: &mut Riff| read(riff, body, size.min(64) as usize);
        match &id {
            b"LIST" if size >= 4 => walk(riff, body + 4, end, depth + 1, scan, bad)?,
            b"avih" => scan.micro_per_frame = u32_at(&header(riff)?, 0).unwrap_or(0),
            b"strh" => {
                let data = header(riff)?;
                if data.get(0..4) == Some(b"vids") && scan.video_stream.is_none() {
                    scan.video_stream = Some(scan.streams);
                    scan.handler = data.get(4..8).and_then(|s| s.try_into().ok()).unwrap_or_default();
                    scan.scale = u32_at(&data, 20).unwrap_or(0);
                    scan.rate = u32_at(&data, 24).unwrap_or(0);
                    scan.start = u32_at(&data, 28).unwrap_or(0);
                }
                scan.streams += 1;
            }
            b"strf" if scan.video_stream.is_some_and(|v| v + 1 == scan.streams) => {
                // BITMAPINFOHEADER: biWidth at 4, biHeight at 8 (negative: top-down), biCompression at 16.
                let data = header(riff)?;
                scan.width = u32_at(&data, 4).unwrap_or(0);
                scan.height = u32_at(&data, 8).map_or(0, |h| (h as i32).unsigned_abs());
                scan.compression = data.get(16..20).and_then(|s| s.try_into().ok()).unwrap_or_default();
            }
            _ => {
                // Stream data: `##dc` (compressed) or `##db` (uncompressed) of the video stream.
                if let Some(v) = scan.video_stream {
                    let tag = format!("{v:02}");
                    // An empty chunk is a dropped frame: no image, but it takes its time slot.
                    if id[..2] == *tag.as_bytes() && (&id[2..] == b"dc" || &id[2..] == b"db") {
                        scan.frames.push((body, size as usize));
                    }
                }
            }
        }
        at = end + (end & 1);
    }
    Ok(())
}

fn program(env: &str, default: &str) -> PathBuf {
    std::env::var_os(env).filter(|p| !p.is_empty()).map_or_else(|| PathBuf::from(default), PathBuf::from)
}

fn missing_program(path: &Path, program: &Path, error: &std::io::Error) -> IoError {
    IoError::invalid(
        path,
        format!(
            "decoding this video (a codec or container other than MJPEG in AVI) needs ffmpeg, and `{}` could not \
             be run ({error}). Install it (`apt install ffmpeg`, `dnf install ffmpeg`, `brew install ffmpeg` or \
             `conda install -c conda-forge ffmpeg`), point {FFMPEG_ENV} and {FFPROBE_ENV} at the binaries, or \
             convert the recording to an MJPEG AVI (read without ffmpeg) or to an image sequence",
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
    /// The display matrix's rotation (ffmpeg 5 and later), in degrees.
    #[serde(default)]
    side_data_list: Vec<ProbeSideData>,
    /// `rotate`, where older ffmpeg releases report the display rotation.
    #[serde(default)]
    tags: HashMap<String, String>,
}

#[derive(serde::Deserialize)]
struct ProbeSideData {
    rotation: Option<f64>,
}

impl ProbeStream {
    /// The rotation the file asks players to show its frames with, in degrees, if any.
    fn display_rotation(&self) -> Option<f64> {
        let side = self.side_data_list.iter().find_map(|d| d.rotation);
        let tag = self.tags.get("rotate").and_then(|r| r.trim().parse::<f64>().ok());
        side.or(tag).filter(|r| r.is_finite() && r.rem_euclid(360.0) != 0.0)
    }
}

#[derive(serde::Deserialize)]
struct ProbeFrame {
    best_effort_timestamp_time: Option<String>,
    pts_time: Option<String>,
}

/// `num/den` as frames per second, if both are positive.
fn parse_rate(r: &str) -> Option<f64> {
    let (a, b) = r.split_once('/')?;
    let (a, b): (f64, f64) = (a.parse().ok()?, b.parse().ok()?);
    (a > 0.0 && b > 0.0 && (a / b).is_finite()).then_some(a / b)
}

/// Fills `buf` from `r`; returns how many bytes arrived before the end of the stream.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match r.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

/// The last few kB of a program's error output, for a message.
fn tail(text: &[u8]) -> String {
    let text = String::from_utf8_lossy(text);
    let text = text.trim();
    let cut = text.len().saturating_sub(2000);
    let cut = (cut..text.len()).find(|&i| text.is_char_boundary(i)).unwrap_or(text.len());
    text[cut..].to_string()
}

fn read_with_ffmpeg(
    path: &Path,
    opts: &VideoOptions,
    on_frame: &mut dyn FnMut(VideoFrame) -> Result<(), IoError>,
) -> Result<VideoInfo, IoError> {
    let ffprobe = program(FFPROBE_ENV, "ffprobe");
    let out = Command::new(&ffprobe)
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .arg(
            "stream=width,height,color_range,avg_frame_rate:stream_side_data=rotation:stream_tags=rotate:\
             frame=best_effort_timestamp_time,pts_time",
        )
        .args(["-of", "json"])
        .arg(path)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| missing_program(path, &ffprobe, &e))?;
    if !out.status.success() {
        return Err(IoError::invalid(path, format!("ffprobe cannot read this file: {}", tail(&out.stderr))));
    }
    let probe: Probe = serde_json::from_slice(&out.stdout)
        .map_err(|e| IoError::invalid(path, format!("unexpected ffprobe output: {e}")))?;
    let Some(stream) = probe.streams.first() else {
        return Err(IoError::invalid(path, "no video stream"));
    };
    let (Some(w), Some(h)) = (stream.width, stream.height) else {
        return Err(IoError::invalid(path, "ffprobe reports no frame size for the video stream"));
    };
    if w == 0 || h == 0 {
        return Err(IoError::invalid(path, format!("the video stream's frame size is {w}×{h} pixels")));
    }
    let rate = stream.avg_frame_rate.as_deref().and_then(parse_rate);
    // A phone or action camera held on its side stores the sensor's frames and asks players to
    // turn them. ffmpeg would turn them (and swap their width and height) unless told not to;
    // they are read as stored, as a JPEG's EXIF orientation is, since the calibration is of
    // the sensor's pixels.
    let rotation = stream.display_rotation();
    if let Some(r) = rotation {
        log::warn!(
            "{}: the file asks players to show its frames turned by {r}°; fluidnerf reads them as stored (as the \
             sensor recorded them, {w}×{h} px), so the camera's calibration must be of the stored frames (a \
             calibration made from frames a player or ffmpeg turned is not)",
            path.display()
        );
    }
    let stamps: Vec<Option<f64>> = probe
        .frames
        .iter()
        .map(|f| f.best_effort_timestamp_time.as_deref().or(f.pts_time.as_deref()).and_then(|t| t.parse().ok()))
        .map(|t: Option<f64>| t.filter(|t| t.is_finite()))
        .collect();
    let (range, range_source) = match (opts.range, stream.color_range.as_deref()) {
        (VideoRange::Auto, Some("pc" | "jpeg")) => (VideoRange::Full, RangeSource::File),
        (VideoRange::Auto, Some("tv" | "mpeg")) => (VideoRange::Limited, RangeSource::File),
        (VideoRange::Auto, _) => (VideoRange::Limited, RangeSource::VideoDefault),
        (forced, _) => (forced, RangeSource::Option),
    };
    let mut mapper = Mapper { limited: range == VideoRange::Limited, linearisation: opts.linearisation, clipped: 0 };
    let frame_bytes = w as usize * h as usize * 2;
    let mut decode = |sync: &[&str], mapper: &mut Mapper| -> Result<(usize, usize, Vec<u8>), IoError> {
        let ffmpeg = program(FFMPEG_ENV, "ffmpeg");
        let mut cmd = Command::new(&ffmpeg);
        // `-noautorotate`: the frames as stored, whatever rotation the file asks for.
        cmd.args(["-v", "error", "-nostdin", "-noautorotate", "-i"])
            .arg(path)
            .args(["-map", "0:v:0", "-an", "-sn", "-f", "rawvideo", "-pix_fmt", "gray16le"])
            // Keep the stored code values: no range conversion inside ffmpeg.
            .args(["-vf", "scale=in_range=full:out_range=full"])
            // One output frame per decoded frame, none dropped or repeated.
            .args(sync);
        if let Some(end) = opts.end {
            cmd.args(["-frames:v", &end.to_string()]);
        }
        let mut child = cmd
            .arg("-")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| missing_program(path, &ffmpeg, &e))?;
        // Drained on its own thread: a full stderr pipe would stall ffmpeg and with it stdout.
        let mut stderr = child.stderr.take().expect("stderr is piped");
        let errors = std::thread::spawn(move || {
            let mut text = Vec::new();
            let _ = stderr.read_to_end(&mut text);
            text
        });
        let mut stdout = child.stdout.take().expect("stdout is piped");
        let mut buf = vec![0u8; frame_bytes];
        let mut decoded = 0;
        let mut kept = 0;
        let result = loop {
            let n = match read_full(&mut stdout, &mut buf) {
                Ok(n) => n,
                Err(e) => break Err(IoError::io(path, "ffmpeg output", e)),
            };
            if n == 0 {
                break Ok(());
            }
            if n < frame_bytes {
                break Err(IoError::invalid(path, format!("ffmpeg's output ends inside frame {decoded}")));
            }
            let i = decoded;
            decoded += 1;
            if !opts.keeps(i) {
                continue;
            }
            let time_s = match (stamps.get(i).copied().flatten(), rate) {
                (Some(t), _) => t,
                (None, Some(r)) => i as f64 / r,
                (None, None) => {
                    break Err(IoError::invalid(
                        path,
                        format!("frame {i} has no time stamp and the stream states no frame rate"),
                    ))
                }
            } + opts.time_offset_s;
            let mut image = Image::zeros(w as usize, h as usize);
            for (o, px) in image.data.iter_mut().zip(buf.chunks_exact(2)) {
                // 16-bit code values, 8-bit scale: 65535 ↔ 255 (ffmpeg widens n-bit samples to 16
                // bits by replicating the high bits, so 8-bit 235 arrives as 235 · 257).
                *o = mapper.map(f64::from(u16::from_le_bytes([px[0], px[1]])) / 257.0);
            }
            if let Err(e) = on_frame(VideoFrame { index: i, time_s, image, full_scale: Some(FULL_SCALE_8BIT) }) {
                break Err(e);
            }
            kept += 1;
        };
        if result.is_err() {
            // Stop a decoder whose frames are no longer wanted; it is this process's own child.
            let _ = child.kill();
        }
        drop(stdout);
        let status = child.wait().map_err(|e| IoError::io(path, "ffmpeg", e))?;
        let errors = errors.join().unwrap_or_default();
        result?;
        if !status.success() {
            return Err(IoError::invalid(path, format!("ffmpeg failed to decode it: {}", tail(&errors))));
        }
        Ok((decoded, kept, errors))
    };
    // `-fps_mode` arrived in ffmpeg 5.1; older releases know only `-vsync`, which newer ones
    // still accept but deprecate.
    let (decoded, kept) = match decode(&["-fps_mode", "passthrough"], &mut mapper) {
        Ok((decoded, kept, _)) => (decoded, kept),
        Err(IoError::Invalid { problem, .. }) if problem.contains("fps_mode") => {
            let (decoded, kept, _) = decode(&["-vsync", "passthrough"], &mut mapper)?;
            (decoded, kept)
        }
        Err(e) => return Err(e),
    };
    if decoded == 0 {
        return Err(IoError::invalid(path, "ffmpeg decoded no frames"));
    }
    Ok(VideoInfo {
        decoder: Decoder::Ffmpeg,
        width: w,
        height: h,
        frame_rate: rate,
        // ffprobe counts every frame; ffmpeg stops at the selection's end.
        frames_in_file: probe.frames.len().max(decoded),
        frames_kept: kept,
        range,
        range_source,
        clipped_pixels: mapper.clipped,
        saturated_pixels: 0,
        display_rotation_deg: rotation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The segments of a JPEG up to its scan, as (marker, its bytes from the marker on).
    fn segments(jpeg: &[u8]) -> Vec<(u8, std::ops::Range<usize>)> {
        let mut out = Vec::new();
        let mut at = 2;
        while jpeg[at + 1] != 0xDA {
            let len = usize::from(u16::from_be_bytes([jpeg[at + 2], jpeg[at + 3]]));
            out.push((jpeg[at + 1], at..at + 2 + len));
            at += 2 + len;
        }
        out
    }

    /// The standard tables are those a JPEG encoder writes by default (the `image` crate's, an
    /// independent transcription of Annex K.3), table by table; a frame stripped of its tables
    /// decodes with them to the same pixels as with its own, and a JPEG with tables is kept.
    #[test]
    fn a_jpeg_without_huffman_tables_takes_the_standard_ones() {
        let rgb =
            image::RgbImage::from_fn(40, 24, |x, y| image::Rgb([(6 * x) as u8, (10 * y) as u8, ((x * y) % 251) as u8]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90).encode_image(&rgb).expect("encodes");
        let tables = |dht: &[u8]| {
            // One or more tables after the marker and length: class/id, 16 counts, the symbols.
            let mut found = std::collections::BTreeMap::new();
            let mut at = 4;
            while at < dht.len() {
                let n: usize = dht[at + 1..at + 17].iter().map(|&c| usize::from(c)).sum();
                found.insert(dht[at], dht[at + 1..at + 17 + n].to_vec());
                at += 17 + n;
            }
            found
        };
        let theirs = segments(&jpeg).into_iter().filter(|(m, _)| *m == 0xC4).fold(
            std::collections::BTreeMap::new(),
            |mut all, (_, r)| {
                all.extend(tables(&jpeg[r]));
                all
            },
        );
        assert_eq!(theirs.len(), 4, "the encoder writes four tables");
        assert_eq!(tables(&STANDARD_DHT), theirs);

        let decoded = |bytes: &[u8]| image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg);
        let mut stripped = jpeg.clone();
        for (_, r) in segments(&jpeg).into_iter().filter(|(m, _)| *m == 0xC4).rev() {
            stripped.drain(r);
        }
        assert!(decoded(&stripped).is_err(), "a still-image decoder needs the tables");
        let mended = with_standard_huffman_tables(&stripped);
        assert_eq!(decoded(&mended).expect("decodes").to_rgb8(), decoded(&jpeg).expect("decodes").to_rgb8());
        assert!(matches!(with_standard_huffman_tables(&jpeg), std::borrow::Cow::Borrowed(_)));
        assert!(matches!(with_standard_huffman_tables(b"not a jpeg"), std::borrow::Cow::Borrowed(_)));
    }

    #[test]
    fn containers_are_told_apart_by_their_first_bytes() {
        assert_eq!(sniff(b"RIFF\x10\0\0\0AVI LIST"), Container::Avi);
        assert_eq!(sniff(b"RIFF\x10\0\0\0WAVEfmt "), Container::Unknown);
        assert_eq!(sniff(b"\0\0\0\x20ftypisom\0\0"), Container::IsoBmff);
        assert_eq!(sniff(b"\0\0\0\x08wide\0\0\0\0"), Container::IsoBmff);
        assert_eq!(sniff(&[0x1A, 0x45, 0xDF, 0xA3, 0x9F, 0x42, 0x86, 0x81, 1, 0, 0, 0]), Container::Matroska);
        assert_eq!(sniff(b"hello"), Container::Unknown);
        assert_eq!(sniff(b""), Container::Unknown);
    }

    #[test]
    fn selection_keeps_every_nth_frame_between_start_and_end() {
        let opts = VideoOptions { start: 2, end: Some(9), every: 3, ..VideoOptions::default() };
        let kept: Vec<usize> = (0..12).filter(|&i| opts.keeps(i)).collect();
        assert_eq!(kept, [2, 5, 8]);
        assert!(!opts.done(8) && opts.done(9));
        let all = VideoOptions { every: 0, ..VideoOptions::default() };
        assert!((0..5).all(|i| all.keeps(i)) && !all.done(usize::MAX));
    }

    #[test]
    fn limited_range_maps_16_to_0_and_235_to_255_and_counts_clipping() {
        let mut m = Mapper { limited: true, linearisation: Linearisation::Linear, clipped: 0 };
        assert_eq!(m.map(16.0), 0.0);
        assert_eq!(m.map(235.0), 255.0);
        assert!((m.map(125.5) - 127.5).abs() < 1e-4);
        assert_eq!(m.clipped, 0);
        assert_eq!((m.map(5.0), m.map(250.0)), (0.0, 255.0));
        assert_eq!(m.clipped, 2);
        let mut full = Mapper { limited: false, linearisation: Linearisation::Linear, clipped: 0 };
        assert_eq!((full.map(0.0), full.map(255.0), full.clipped), (0.0, 255.0, 0));
    }

    #[test]
    fn rates_parse_only_when_positive() {
        assert_eq!(parse_rate("30000/1001"), Some(30000.0 / 1001.0));
        assert_eq!(parse_rate("0/0"), None);
        assert_eq!(parse_rate("25/0"), None);
        assert_eq!(parse_rate("x"), None);
    }
}
