//! LaVision DaVis images: `.im7` (DaVis 7 and later) and the older `.imx`, read without
//! LaVision's library. The layout was learnt from the MIT-licensed ReadIM (ReadIMX.cpp,
//! ReadIM7.cpp); this is an independent implementation.
//!
//! A file is a 256-byte header, the pixels of all its frames (one frame per camera and
//! exposure of one recorded instant: `2cameras.im7` of a double-frame PIV recording holds
//! camera 1's exposures A and B, then camera 2's), and attributes.
//!
//! - **Header.** `.im7`: `version`, `pack_type`, `buffer_format`, `isSparse` (i16 at 0, 2, 4,
//!   6), then `sizeX`, `sizeY`, `sizeZ`, `sizeF` (i32 at 8, 12, 16, 20), little-endian. A
//!   first i16 of 18 to 23 marks the older `.imx`/`.img` header: image type there, rows and
//!   columns at 10 and 12 (−1: the i32s at 228 and 232), frame count at 18 and the header's
//!   version byte at 33 (frames and z planes are counted from version 54 and 55).
//! - **Pixels**, row-major, row 0 at the top (as DaVis and ReadIM show them), frame after
//!   frame: 16-bit words (`buffer_format` −4, or 0 as ReadIM reads it), 32-bit floats (−3),
//!   or one byte per pixel (−2, uncompressed only). Stored uncompressed (`pack_type` 0), in
//!   LaVision's old difference coding (1: after a preview of `nx·ny` bytes, each byte the
//!   difference to the previous pixel, with escapes to 4-bit differences, single 16-bit words
//!   and runs of them), zlib-compressed (2: an i32 length, then one zlib stream of all the
//!   pixels) or packed at 12 bits (3: four pixels in three words, a row's last pixels, fewer
//!   than four, as plain words).
//! - **Attributes** follow the pixels: items of an i32 type and an i32 length, up to an item
//!   of type 0. Type 6 is text `name=value`; 1–4 and 7 the scales of x, y, z, intensity and
//!   frame (`_SCALE_X`, …: "factor offset", unit, description); 5, 11, 12 the comment, time
//!   and date; the numeric arrays (8–10, 13–17) are skipped. Text is Latin-1 (DaVis writes
//!   `µs`). `CameraName<k>` names frame k, as `1A: Imager Intense (…)`: camera 1, exposure A.
//!
//! **Values.** Pixels are read as stored, the camera's counts (or the floats DaVis computed),
//! like the frames of a cine or MRAW: no range mapping, no linearisation, and no intensity
//! scale applied (`_SCALE_I` is usually "1 0 counts"; [`DavisFile::intensity_scale`] gives it).
//!
//! **Refused**, each naming the file and the reason: vector fields (`.vc7`, `buffer_format`
//! above 0), volumes (`sizeZ` above 1), sparse buffers, double, colour and flagged-float
//! buffers, unknown compressions, and files whose pixels or attributes run past their end.

use std::io::Read;
use std::path::Path;

use fluidnerf_core::Image;

use crate::image::SampleKind;
use crate::IoError;

/// The header's size, in both layouts.
pub(crate) const HEADER_LEN: usize = 256;
/// Most pixels (all frames) a file may claim: 4 GiB as f32.
const MAX_PIXELS: usize = 1 << 30;

/// Extensions of DaVis images (lower case): they carry no signature, so they are told by name.
pub const DAVIS_EXTENSIONS: [&str; 2] = ["im7", "imx"];

/// Whether `p` is named like a DaVis image (`.im7`, `.imx`, in any case).
pub fn is_davis_path(p: &Path) -> bool {
    p.extension().and_then(|e| e.to_str()).is_some_and(|e| DAVIS_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// A DaVis image file: its frames, of one size and kind, and its attributes.
#[derive(Debug, Clone)]
pub struct DavisFile {
    pub width: usize,
    pub height: usize,
    /// Frame by frame, as stored (one per camera and exposure).
    pub frames: Vec<Image>,
    /// How the pixels were stored: 16-bit words, bytes, or floats.
    pub kind: SampleKind,
    /// `(name, value)` in file order; scales as `_SCALE_X` and so on.
    pub attributes: Vec<(String, String)>,
}

/// What `CameraName<k>` says of frame k: `1A: Imager …` is camera 1, exposure A; `2: …`
/// camera 2 of a single-exposure recording.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct FrameLabel {
    pub camera: u32,
    /// The exposure's letter of a multi-frame (double-frame PIV) recording.
    pub exposure: Option<char>,
}

impl std::fmt::Display for FrameLabel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.exposure {
            Some(e) => write!(f, "{}{e}", self.camera),
            None => write!(f, "{}", self.camera),
        }
    }
}

impl DavisFile {
    /// The value of attribute `name`, the last one when it is given twice.
    pub fn attribute(&self, name: &str) -> Option<&str> {
        self.attributes.iter().rev().find(|(n, _)| n == name).map(|(_, v)| v.as_str())
    }

    /// Frame `k`'s camera and exposure from its `CameraName<k>` attribute: the label before the
    /// colon, digits then at most one letter. None when the attribute is missing or unlike that.
    pub fn frame_label(&self, k: usize) -> Option<FrameLabel> {
        let name = self.attribute(&format!("CameraName{k}"))?;
        let label = name.split(':').next()?.trim();
        let digits = label.find(|c: char| !c.is_ascii_digit()).unwrap_or(label.len());
        let camera = label[..digits].parse().ok()?;
        let mut rest = label[digits..].chars();
        match (rest.next(), rest.next()) {
            (None, _) => Some(FrameLabel { camera, exposure: None }),
            (Some(c), None) if c.is_ascii_alphabetic() => Some(FrameLabel { camera, exposure: Some(c) }),
            _ => None,
        }
    }

    /// Every frame's camera and exposure ([`Self::frame_label`]) when every frame names one;
    /// frame k as camera k + 1 when none does; `Err(k)` when frame k names none while others do,
    /// so its camera is unknown.
    pub fn frame_labels(&self) -> Result<Vec<FrameLabel>, usize> {
        let named: Vec<Option<FrameLabel>> = (0..self.frames.len()).map(|k| self.frame_label(k)).collect();
        if named.iter().all(Option::is_none) {
            return Ok((1..=named.len() as u32).map(|camera| FrameLabel { camera, exposure: None }).collect());
        }
        match named.iter().position(Option::is_none) {
            Some(k) => Err(k),
            None => Ok(named.into_iter().flatten().collect()),
        }
    }

    /// The intensity scale `(factor, offset, unit)` of `_SCALE_I`, by which DaVis shows
    /// `factor · stored + offset`; None when absent or unreadable.
    pub fn intensity_scale(&self) -> Option<(f64, f64, String)> {
        let text = self.attribute("_SCALE_I")?;
        let mut lines = text.lines();
        let mut numbers = lines.next()?.split_whitespace().map(str::parse::<f64>);
        let (Some(Ok(factor)), Some(Ok(offset))) = (numbers.next(), numbers.next()) else { return None };
        Some((factor, offset, lines.next().unwrap_or("").trim().to_owned()))
    }
}

/// Reads the DaVis image `path`; see the module's documentation.
pub fn read_davis(path: &Path) -> Result<DavisFile, IoError> {
    let bytes = crate::read_input(path, "DaVis image")?;
    decode_davis(path, &bytes)
}

/// How the pixels are stored.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Sample {
    Word,
    Byte,
    Float,
}

impl Sample {
    fn bytes(self) -> usize {
        match self {
            Sample::Word => 2,
            Sample::Byte => 1,
            Sample::Float => 4,
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Sample::Word => "16-bit",
            Sample::Byte => "8-bit",
            Sample::Float => "32-bit float",
        }
    }
}

/// How the pixel data are packed.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Packing {
    Plain,
    OldImx,
    Zlib,
    Fixed12,
}

/// What a header says.
#[derive(Debug)]
struct Layout {
    width: usize,
    height: usize,
    frames: usize,
    sample: Sample,
    packing: Packing,
}

fn i16_at(b: &[u8], at: usize) -> i16 {
    i16::from_le_bytes([b[at], b[at + 1]])
}

fn i32_at(b: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// [`read_davis`] on bytes already in memory; `path` names them in errors.
pub fn decode_davis(path: &Path, bytes: &[u8]) -> Result<DavisFile, IoError> {
    let bad = |why: String| IoError::invalid(path, format!("malformed DaVis image: {why}"));
    if bytes.len() < HEADER_LEN {
        return Err(bad(format!(
            "its {} bytes are fewer than the {HEADER_LEN} of a DaVis header (a truncated file?)",
            bytes.len()
        )));
    }
    let old = (18..=23).contains(&i16_at(bytes, 0));
    let layout = if old { old_header(path, bytes)? } else { im7_header(path, bytes)? };
    let Layout { width, height, frames, sample, packing } = layout;
    let pixels = [width, height, frames].iter().try_fold(1usize, |n, &d| n.checked_mul(d)).filter(|&n| n <= MAX_PIXELS);
    let Some(pixels) = pixels else {
        return Err(bad(format!(
            "its header claims {frames} frame(s) of {width}×{height} pixels, too many to be real"
        )));
    };
    let data = &bytes[HEADER_LEN..];
    let claim = format!("{frames} frame(s) of {width}×{height} {} pixels", sample.describe());
    let short = |need: usize, how: &str| {
        bad(format!(
            "the header's {claim} take {need} bytes{how}, but the file holds {} after its {HEADER_LEN}-byte header \
             (a truncated file, or a header that does not fit its data)",
            data.len()
        ))
    };
    // Raw little-endian samples and the bytes they took.
    let (raw, used): (std::borrow::Cow<[u8]>, usize) = match packing {
        Packing::Plain => {
            let need = pixels * sample.bytes();
            let raw = data.get(..need).ok_or_else(|| short(need, ""))?;
            (raw.into(), need)
        }
        Packing::Fixed12 => {
            // Per row: three words per four pixels, a plain word per pixel left over.
            let row = width / 4 * 6 + width % 4 * 2;
            let need = row * height * frames;
            let packed = data.get(..need).ok_or_else(|| short(need, " packed at 12 bits"))?;
            let mut raw = Vec::with_capacity(pixels * 2);
            for r in packed.chunks_exact(row) {
                let (groups, rest) = r.split_at(width / 4 * 6);
                for g in groups.chunks_exact(6) {
                    let (a0, a1, a2) = (
                        u16::from_le_bytes([g[0], g[1]]),
                        u16::from_le_bytes([g[2], g[3]]),
                        u16::from_le_bytes([g[4], g[5]]),
                    );
                    for v in [a0 & 0x0fff, a0 >> 12 | (a1 & 0xff) << 4, a1 >> 8 | (a2 & 0x0f) << 8, a2 >> 4] {
                        raw.extend(v.to_le_bytes());
                    }
                }
                raw.extend_from_slice(rest);
            }
            (raw.into(), need)
        }
        Packing::Zlib => {
            if data.len() < 4 {
                return Err(short(4, " at least (the compressed length)"));
            }
            let packed_len = usize::try_from(i32_at(data, 0))
                .map_err(|_| bad(format!("its compressed length is {}", i32_at(data, 0))))?;
            let packed = data.get(4..4 + packed_len).ok_or_else(|| {
                bad(format!(
                    "its compressed pixels ({packed_len} bytes as it says) run past the end of the file, {} bytes \
                     after its header (a truncated file?)",
                    data.len()
                ))
            })?;
            let need = pixels * sample.bytes();
            // zlib inflates at most about 1032 to 1: a larger claim cannot be these bytes'.
            if need / 1032 > packed_len + 1 {
                return Err(bad(format!("the header's {claim} cannot come from {packed_len} compressed bytes")));
            }
            let mut raw = Vec::with_capacity(need);
            flate2::read::ZlibDecoder::new(packed)
                .take(need as u64)
                .read_to_end(&mut raw)
                .map_err(|e| bad(format!("its zlib-compressed pixels are corrupt ({e})")))?;
            if raw.len() < need {
                return Err(bad(format!(
                    "its zlib-compressed pixels inflate to {} bytes; the header's {claim} take {need}",
                    raw.len()
                )));
            }
            (raw.into(), 4 + packed_len)
        }
        Packing::OldImx => {
            let (words, used) = unpack_old_imx(data, pixels).map_err(|why| bad(format!("{why} ({claim})")))?;
            (words.iter().flat_map(|w| w.to_le_bytes()).collect::<Vec<u8>>().into(), used)
        }
    };
    let values: Vec<f32> = match (sample, packing) {
        (Sample::Float, _) => raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect(),
        (Sample::Byte, Packing::Plain) => raw.iter().map(|&b| f32::from(b)).collect(),
        _ => raw.chunks_exact(2).map(|b| f32::from(u16::from_le_bytes([b[0], b[1]]))).collect(),
    };
    let kind = match (sample, packing) {
        (Sample::Float, _) => SampleKind::Float,
        (Sample::Byte, Packing::Plain) => SampleKind::Integer(8),
        _ => SampleKind::Integer(16),
    };
    let attributes = read_attributes(&data[used..]).map_err(|why| bad(format!("its attributes {why}")))?;
    let frames = values.chunks_exact(width * height).map(|f| Image::from_vec(width, height, f.to_vec())).collect();
    Ok(DavisFile { width, height, frames, kind, attributes })
}

/// The frames' size `(width, height)` a DaVis header (`head`, the file's first bytes) states.
pub(crate) fn decode_dimensions(path: &Path, head: &[u8]) -> Result<(u32, u32), IoError> {
    let Some(head) = head.get(..HEADER_LEN) else {
        return Err(IoError::invalid(
            path,
            format!(
                "malformed DaVis image: its {} bytes are fewer than the {HEADER_LEN} of a DaVis header (a truncated \
                 file?)",
                head.len()
            ),
        ));
    };
    let layout = if (18..=23).contains(&i16_at(head, 0)) { old_header(path, head)? } else { im7_header(path, head)? };
    match (u32::try_from(layout.width), u32::try_from(layout.height)) {
        (Ok(w), Ok(h)) => Ok((w, h)),
        _ => Err(IoError::invalid(
            path,
            format!("malformed DaVis image: frames of {}×{} pixels", layout.width, layout.height),
        )),
    }
}

/// The size and storage a DaVis 7 (`.im7`) header states.
fn im7_header(path: &Path, h: &[u8]) -> Result<Layout, IoError> {
    let refuse = |why: String| IoError::invalid(path, format!("a DaVis image fluidnerf does not read: {why}"));
    let (pack, format, sparse) = (i16_at(h, 2), i16_at(h, 4), i16_at(h, 6));
    let sample = match format {
        -4 | 0 => Sample::Word,
        -3 => Sample::Float,
        -2 => Sample::Byte,
        1..=5 => {
            return Err(refuse(format!(
                "it holds a vector field (buffer format {format}), as DaVis writes PIV results (.vc7), not a camera \
                 image"
            )))
        }
        -5 => return Err(refuse("64-bit float pixels (buffer format -5); export the image as 16-bit or float".into())),
        -6 => return Err(refuse("float pixels with validity flags (buffer format -6)".into())),
        -10 | -11 => return Err(refuse(format!("colour pixels (buffer format {format}); record in grey"))),
        other => return Err(refuse(format!("an unknown buffer format {other}"))),
    };
    if sparse != 0 {
        return Err(refuse("a sparse buffer".into()));
    }
    let packing = match pack {
        0 => Packing::Plain,
        1 => Packing::OldImx,
        2 => Packing::Zlib,
        3 => Packing::Fixed12,
        other => return Err(refuse(format!("an unknown compression (pack type {other})"))),
    };
    if sample == Sample::Float && matches!(packing, Packing::OldImx | Packing::Fixed12) {
        return Err(refuse(format!("float pixels with a compression for 16-bit ones (pack type {pack})")));
    }
    // ReadIM reads byte pixels as bytes only uncompressed; compressed, they are words.
    let sample = if sample == Sample::Byte && packing != Packing::Plain { Sample::Word } else { sample };
    let (nx, ny, nz, nf) = (i32_at(h, 8), i32_at(h, 12), i32_at(h, 16), i32_at(h, 20));
    sizes(path, nx, ny, nz, nf).map(|(width, height, frames)| Layout { width, height, frames, sample, packing })
}

/// The size and storage an older DaVis (`.imx`, `.img`) header states.
fn old_header(path: &Path, h: &[u8]) -> Result<Layout, IoError> {
    let refuse = |why: String| IoError::invalid(path, format!("a DaVis image fluidnerf does not read: {why}"));
    let (kind, sub_type) = (i16_at(h, 0), i16_at(h, 14));
    let (sample, packing) = match kind {
        18 => (Sample::Word, Packing::Plain),
        19 => (Sample::Word, Packing::OldImx),
        20 => (Sample::Float, Packing::Plain),
        21 | 22 => return Err(refuse(format!("a sparse buffer (image type {kind})"))),
        _ => return Err(refuse(format!("byte-packed pixels (image type {kind})"))),
    };
    if sub_type != 0 {
        return Err(refuse(format!("it holds a vector field (image sub-type {sub_type}), not a camera image")));
    }
    let version = i32::from(h[33]);
    let counted = |from: i32| (from..100).contains(&version);
    let rows = match i16_at(h, 10) {
        -1 => i32_at(h, 228),
        r => i32::from(r),
    };
    let columns = match i16_at(h, 12) {
        -1 => i32_at(h, 232),
        c => i32::from(c),
    };
    let frames = if counted(54) { i32::from(i16_at(h, 18)) } else { 1 };
    let planes = if counted(55) { i32_at(h, 236) } else { 1 };
    // Before version 55 the rows count every frame's.
    let rows = if counted(55) || frames <= 0 { rows } else { rows / frames };
    sizes(path, columns, rows, planes, frames).map(|(width, height, frames)| Layout {
        width,
        height,
        frames,
        sample,
        packing,
    })
}

/// Checks a header's sizes: positive, and one plane (not a volume).
fn sizes(path: &Path, nx: i32, ny: i32, nz: i32, nf: i32) -> Result<(usize, usize, usize), IoError> {
    let positive = |v: i32| usize::try_from(v).ok().filter(|&v| v > 0);
    match (positive(nx), positive(ny), positive(nz), positive(nf)) {
        (Some(w), Some(h), Some(1), Some(f)) => Ok((w, h, f)),
        (Some(_), Some(_), Some(nz), Some(_)) => Err(IoError::invalid(
            path,
            format!("a DaVis image fluidnerf does not read: a volume of {nz} planes, not a camera image"),
        )),
        _ => Err(IoError::invalid(
            path,
            format!("malformed DaVis image: its header claims {nf} frame(s) of {nx}×{ny}×{nz} pixels"),
        )),
    }
}

/// Decodes LaVision's old difference coding of `pixels` 16-bit pixels from `data` (which
/// begins with the preview), returning them and the bytes used.
///
/// After the preview's size (two bytes) and its bytes, each byte is the signed difference to
/// the previous pixel (0 before the first), but for three codes: −128, one 16-bit word follows
/// (the pixel's value); 127, a count n follows, then n words; −127, 4-bit differences follow,
/// two per byte (high nibble first) until a low nibble of 8 returns to bytes.
fn unpack_old_imx(data: &[u8], pixels: usize) -> Result<(Vec<u16>, usize), String> {
    #[derive(PartialEq)]
    enum Mode {
        Bytes,
        HighNibble,
        LowNibble,
        Words,
    }
    let cut = |at: usize| format!("its compressed pixels end at byte {at} after the header (a truncated file?)");
    let mut at = 0usize;
    let next = |at: &mut usize| -> Result<u8, String> {
        let b = *data.get(*at).ok_or_else(|| cut(*at))?;
        *at += 1;
        Ok(b)
    };
    let (pw, ph) = (next(&mut at)?, next(&mut at)?);
    at += usize::from(pw) * usize::from(ph);
    // Each byte gives at most two pixels: a larger claim cannot be these bytes'.
    if pixels / 2 > data.len().saturating_sub(at) {
        return Err(format!("{} compressed bytes cannot hold {pixels} pixels", data.len().saturating_sub(at)));
    }
    // A nibble as a signed 4-bit number.
    let nibble = |n: u8| i16::from(((n << 4) as i8) >> 4);
    let mut out = Vec::with_capacity(pixels);
    let (mut mode, mut last, mut value, mut byte, mut words) = (Mode::Bytes, 0u16, 0u16, 0u8, 0u8);
    for _ in 0..pixels {
        if matches!(mode, Mode::Bytes | Mode::HighNibble) {
            byte = next(&mut at)?;
        }
        if mode == Mode::LowNibble {
            mode = Mode::HighNibble;
            if byte & 0x0f == 0x08 {
                mode = Mode::Bytes;
                byte = next(&mut at)?;
            } else {
                value = last.wrapping_add_signed(nibble(byte & 0x0f));
            }
        } else if mode == Mode::HighNibble {
            value = last.wrapping_add_signed(nibble(byte >> 4));
            mode = Mode::LowNibble;
        }
        if mode == Mode::Bytes {
            match byte as i8 {
                -128 => (mode, words) = (Mode::Words, 1),
                127 => (mode, words) = (Mode::Words, next(&mut at)?),
                -127 => {
                    byte = next(&mut at)?;
                    value = last.wrapping_add_signed(nibble(byte >> 4));
                    mode = Mode::LowNibble;
                }
                d => value = last.wrapping_add_signed(i16::from(d)),
            }
        }
        if mode == Mode::Words {
            value = u16::from_le_bytes([next(&mut at)?, next(&mut at)?]);
            // A count of 0 runs on for 256 words, as LaVision's reader takes it.
            words = words.wrapping_sub(1);
            if words == 0 {
                mode = Mode::Bytes;
            }
        }
        out.push(value);
        last = value;
    }
    Ok((out, at))
}

/// The attribute items in `data` up to the end item, as `(name, value)`; an empty `data` (no
/// attributes) gives none.
fn read_attributes(data: &[u8]) -> Result<Vec<(String, String)>, String> {
    // DaVis writes Latin-1 (`µs`); each byte is its code point.
    let text = |b: &[u8]| -> String { b.iter().take_while(|&&c| c != 0).map(|&c| char::from(c)).collect() };
    let mut out = Vec::new();
    let mut at = 0usize;
    while at < data.len() {
        let head = data.get(at..at + 8).ok_or_else(|| format!("are cut short at byte {at} of {}", data.len()))?;
        let (kind, len) = (i32_at(head, 0), i32_at(head, 4));
        at += 8;
        if kind == 0 {
            return Ok(out);
        }
        if !(1..=17).contains(&kind) {
            return Err(format!("hold an item of unknown type {kind} at byte {}", at - 8));
        }
        let body = usize::try_from(len)
            .ok()
            .and_then(|n| data.get(at..at.checked_add(n)?))
            .ok_or_else(|| format!("hold an item of {len} bytes that runs past the end of the file"))?;
        at += body.len();
        let scale = |name: &str| {
            // Scales separate their parts with NULs, which ReadIM turns into line breaks.
            let value: String = body.iter().map(|&c| if c == 0 { '\n' } else { char::from(c) }).collect();
            (name.to_owned(), value)
        };
        match kind {
            1 => out.push(scale("_SCALE_X")),
            2 => out.push(scale("_SCALE_Y")),
            3 => out.push(scale("_SCALE_Z")),
            4 => out.push(scale("_SCALE_I")),
            7 => out.push(scale("_SCALE_F")),
            5 => out.push(("_COMMENT".to_owned(), text(body))),
            11 => out.push(("_TIME".to_owned(), text(body))),
            12 => out.push(("_DATE".to_owned(), text(body))),
            6 => {
                let item = text(body);
                if let Some((name, value)) = item.split_once('=') {
                    out.push((name.to_owned(), value.to_owned()));
                }
            }
            // Numeric arrays and planes.
            _ => {}
        }
    }
    if out.is_empty() {
        Ok(out)
    } else {
        Err(format!("are cut short at byte {at}: the file ends before their end item (a truncated file?)"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A DaVis 7 header: `pack` and `format` as written, then the sizes.
    fn header(pack: i16, format: i16, (nx, ny, nz, nf): (i32, i32, i32, i32)) -> Vec<u8> {
        let mut h = vec![0u8; HEADER_LEN];
        h[2..4].copy_from_slice(&pack.to_le_bytes());
        h[4..6].copy_from_slice(&format.to_le_bytes());
        for (at, v) in [(8, nx), (12, ny), (16, nz), (20, nf)] {
            h[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
        h
    }

    fn attribute(kind: i32, body: &[u8]) -> Vec<u8> {
        let mut b = kind.to_le_bytes().to_vec();
        b.extend((body.len() as i32).to_le_bytes());
        b.extend(body);
        b
    }

    #[test]
    fn labels_name_camera_and_exposure() {
        let file = |names: &[&str]| DavisFile {
            width: 1,
            height: 1,
            frames: vec![],
            kind: SampleKind::Integer(16),
            attributes: names.iter().enumerate().map(|(k, n)| (format!("CameraName{k}"), n.to_string())).collect(),
        };
        let f = file(&["1A: Imager Intense (1376 x 1040 pixel)", "12: x", "Camera 3", "1AB: x"]);
        assert_eq!(f.frame_label(0), Some(FrameLabel { camera: 1, exposure: Some('A') }));
        assert_eq!(f.frame_label(1), Some(FrameLabel { camera: 12, exposure: None }));
        assert_eq!((f.frame_label(2), f.frame_label(3), f.frame_label(4)), (None, None, None));
        assert_eq!(f.frame_label(0).map(|l| l.to_string()).as_deref(), Some("1A"));
    }

    /// The 12-bit packing and zlib, which ReadIM's writer does not make, by hand: packed
    /// groups of four with a row's tail as words, and one zlib stream for all frames.
    #[test]
    fn fixed_12_bit_and_zlib_pixels() {
        let p = Path::new("hand.im7");
        // A 5×1 row: 4 pixels in three words, then one word.
        let px = [0x123u16, 0xabc, 0x0f0, 0xfff, 40000];
        let words = [px[0] | px[1] << 12, px[1] >> 4 | (px[2] & 0xff) << 8, px[2] >> 8 | px[3] << 4, px[4]];
        let mut b = header(3, -4, (5, 1, 1, 1));
        b.extend(words.iter().flat_map(|w| w.to_le_bytes()));
        b.extend(attribute(0, &[]));
        let f = decode_davis(p, &b).expect("12-bit packed");
        assert_eq!(f.frames[0].data, px.map(f32::from).to_vec());

        let values: Vec<f32> = vec![0.5, -2.0, 1e6, 3.25, 0.0, 7.0];
        let plain: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut z, &plain).expect("deflate");
        let packed = z.finish().expect("deflate");
        let mut b = header(2, -3, (3, 1, 1, 2));
        b.extend((packed.len() as i32).to_le_bytes());
        b.extend(&packed);
        b.extend(attribute(6, b"CameraName1=2: cam"));
        b.extend(attribute(0, &[]));
        let f = decode_davis(p, &b).expect("zlib floats");
        assert_eq!(f.kind, SampleKind::Float);
        assert_eq!((f.frames[0].data.clone(), f.frames[1].data.clone()), (values[..3].to_vec(), values[3..].to_vec()));
        assert_eq!(f.frame_label(1), Some(FrameLabel { camera: 2, exposure: None }));
        // Cut inside the stream, or a stream of fewer pixels than claimed.
        let mut cut = header(2, -3, (3, 1, 1, 2));
        cut.extend((packed.len() as i32).to_le_bytes());
        cut.extend(&packed[..packed.len() / 2]);
        let err = decode_davis(p, &cut).expect_err("cut").to_string();
        assert!(err.contains("hand.im7") && err.contains("run past the end of the file"), "{err}");
        let mut few = header(2, -3, (3, 2, 1, 2));
        few.extend((packed.len() as i32).to_le_bytes());
        few.extend(&packed);
        let err = decode_davis(p, &few).expect_err("too few").to_string();
        assert!(err.contains("inflate to 24 bytes") && err.contains("take 48"), "{err}");
    }

    /// Each code of the old difference coding, including a run of words and 4-bit differences
    /// ended by the low nibble 8.
    #[test]
    fn old_difference_coding() {
        // No preview; +5, -3, a word 1000, then nibbles +1 -2 +7 and the end, +100, two words.
        let stream = [0u8, 0, 5, 0xfd, 0x80, 0xe8, 0x03, 0x81, 0x1e, 0x78, 100, 0x7f, 2, 0x10, 0, 0xff, 0xff];
        let (px, used) = unpack_old_imx(&stream, 9).expect("decodes");
        assert_eq!(px, vec![5, 2, 1000, 1001, 999, 1006, 1106, 16, 65535]);
        assert_eq!(used, stream.len());
        assert!(unpack_old_imx(&stream[..10], 9).expect_err("cut").contains("truncated"));
    }
}
