//! Photron MRAW recordings (`NAME.mraw` with its header `NAME.cihx` or `NAME.cih` beside it),
//! read without ffmpeg.
//!
//! The header gives the frames' size, their count, the recording rate and the bits per pixel;
//! the `.mraw` holds the frames one after another with no header of its own: 8 bits per pixel,
//! 16 bits (little-endian) or 12 bits packed two pixels in three bytes (the first pixel's high
//! eight bits, then its low four bits with the second pixel's high four, then the second's low
//! eight). A `.cih` is text, one `Key : value` per line up to the first empty line; a `.cihx`
//! holds a `<cih>` XML element (after a binary preamble in some files).
//!
//! **Values.** Frames are read as the sensor stored them: linear counts, as `f32`, with no
//! range mapping or linearisation (12-bit data keeps its 12 bits). A 16-bit file whose
//! effective bits sit at the high side of the word is read as stored, as pyMRAW reads it.
//!
//! **Saturation.** A pixel is saturated at the largest count of the header's effective bits
//! (`EffectiveBit Depth`, shifted up when `EffectiveBit Side` is `Higher`), else of the
//! samples' bits. A file with counts above that effective full scale contradicts its header
//! (pyMRAW writes `EffectiveBit Depth : 12`, `EffectiveBit Side : Lower` into every 16-bit
//! file it saves, whatever its counts): a warning names the file, the header's keys and the
//! largest count, and the samples' full scale (65535 for 16 bits) is the file's instead.
//!
//! **Read:** monochrome frames of 8, 12 or 16 bits. **Refused**, each with its reason: colour
//! recordings (a Bayer mosaic or interpolated colour), which fluidnerf does not demosaic, and
//! headers whose file format is not MRAW.
//!
//! **Times.** Frame `i` of the file is at `(start + i) / rate` seconds from the trigger, plus
//! the time offset, where `start` is the header's first frame number (`Start Frame`,
//! `frameInfo/startFrame`; negative before the trigger, 0 when unstated), so cameras whose files
//! begin at other frames give their frames the same times at the same instants.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use fluidnerf_core::Image;

use crate::video::{Decoder, RangeSource, VideoFrame, VideoInfo, VideoOptions, VideoRange};
use crate::IoError;

/// What a `.cih`/`.cihx` header says.
#[derive(Debug, PartialEq)]
struct Header {
    width: usize,
    height: usize,
    frames: usize,
    rate: f64,
    /// The first frame's number counted from the trigger (negative before it); 0 unstated.
    start_frame: i64,
    bits: u32,
    /// The sensor's significant bits within each sample, and whether they sit at its high side
    /// (`EffectiveBit Depth`, `EffectiveBit Side`); None when unstated.
    effective_bits: Option<(u32, bool)>,
    /// The keys and values that state `effective_bits`, as the header writes them.
    effective_stated: String,
    /// Whether the camera recorded grey frames.
    mono: bool,
    file_format: String,
}

/// The header beside `mraw`: `NAME.cihx`, else `NAME.cih`.
fn header_path(mraw: &Path) -> Result<PathBuf, IoError> {
    let (cihx, cih) = (mraw.with_extension("cihx"), mraw.with_extension("cih"));
    if cihx.is_file() {
        Ok(cihx)
    } else if cih.is_file() {
        Ok(cih)
    } else {
        Err(IoError::invalid(
            mraw,
            format!(
                "a Photron MRAW holds no header of its own: its size, frame count and rate are in {} or {}, \
                 which is not there; keep the header the camera's software saved with it",
                cihx.display(),
                cih.display()
            ),
        ))
    }
}

/// Parses a header file: `.cihx` (XML) or `.cih` (text).
fn read_header(path: &Path) -> Result<Header, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, "MRAW header", e))?;
    let text = String::from_utf8_lossy(&bytes);
    let xml = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("cihx"));
    let field = |key: &str| -> Result<String, IoError> {
        let found = if xml { xml_field(path, &text, key)? } else { cih_field(&text, key) };
        found.ok_or_else(|| IoError::invalid(path, format!("the header states no `{key}`")))
    };
    let number = |key: &str| -> Result<f64, IoError> {
        let v = field(key)?;
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| IoError::invalid(path, format!("`{key}` is `{v}`, not a number")))
    };
    let count = |key: &str| -> Result<usize, IoError> {
        let v = field(key)?;
        v.trim()
            .parse::<usize>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| IoError::invalid(path, format!("`{key}` is `{v}`, not a positive whole number")))
    };
    let keys: [&str; 7] = if xml {
        [
            "imageDataInfo/resolution/width",
            "imageDataInfo/resolution/height",
            "frameInfo/totalFrame",
            "recordInfo/recordRate",
            "imageDataInfo/colorInfo/bit",
            "imageDataInfo/colorInfo/type",
            "imageFileInfo/fileFormat",
        ]
    } else {
        ["Image Width", "Image Height", "Total Frame", "Record Rate(fps)", "Color Bit", "Color Type", "File Format"]
    };
    let colour_type = if xml { xml_field(path, &text, keys[5])? } else { cih_field(&text, keys[5]) };
    let start_key = if xml { "frameInfo/startFrame" } else { "Start Frame" };
    let start = if xml { xml_field(path, &text, start_key)? } else { cih_field(&text, start_key) };
    let start_frame = match start {
        None => 0,
        Some(v) => v
            .trim()
            .parse::<i64>()
            .ok()
            .filter(|n| n.unsigned_abs() < 1 << 53)
            .ok_or_else(|| IoError::invalid(path, format!("`{start_key}` is `{v}`, not a frame number")))?,
    };
    let (depth_key, side_key) = if xml {
        ("imageDataInfo/effectiveBit/depth", "imageDataInfo/effectiveBit/side")
    } else {
        ("EffectiveBit Depth", "EffectiveBit Side")
    };
    let stated = |key: &str| if xml { xml_field(path, &text, key) } else { Ok(cih_field(&text, key)) };
    let (depth, side) = (stated(depth_key)?, stated(side_key).ok().flatten());
    // Only for counting saturated pixels: a depth that does not parse is left unused.
    let effective_bits = depth
        .as_deref()
        .and_then(|v| v.trim().parse::<u32>().ok())
        .map(|d| (d, side.as_deref().is_some_and(|s| s.trim().eq_ignore_ascii_case("higher"))));
    let effective_stated = [(depth_key, depth), (side_key, side)]
        .into_iter()
        .filter_map(|(key, v)| {
            let v = v?;
            Some(if xml { format!("`{key}` {}", v.trim()) } else { format!("`{key} : {}`", v.trim()) })
        })
        .collect::<Vec<_>>()
        .join(", ");
    let header = Header {
        width: count(keys[0])?,
        height: count(keys[1])?,
        frames: count(keys[2])?,
        rate: number(keys[3])?,
        start_frame,
        bits: count(keys[4])? as u32,
        effective_bits,
        effective_stated,
        // Not every header states it; one that does not is taken for grey.
        mono: colour_type.is_none_or(|t| t.trim().to_ascii_lowercase().starts_with("mono")),
        file_format: field(keys[6])?,
    };
    if header.rate <= 0.0 {
        return Err(IoError::invalid(path, format!("`{}` is {}: not a frame rate", keys[3], header.rate)));
    }
    Ok(header)
}

/// The value of `key` in a `.cih`'s `Key : value` lines (up to the first empty line).
fn cih_field(text: &str, key: &str) -> Option<String> {
    text.lines()
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_once(" : "))
        .find(|(k, _)| k.trim() == key)
        .map(|(_, v)| v.trim().to_owned())
}

/// The text of the element at `key` (a path of element names below `<cih>`) in a `.cihx`.
fn xml_field(path: &Path, text: &str, key: &str) -> Result<Option<String>, IoError> {
    let (Some(start), Some(end)) = (text.find("<cih>"), text.rfind("</cih>")) else {
        return Err(IoError::invalid(path, "a .cihx header without a <cih> element"));
    };
    let doc = roxmltree::Document::parse(&text[start..end + "</cih>".len()])
        .map_err(|e| IoError::invalid(path, format!("the <cih> element is not well-formed XML: {e}")))?;
    let mut node = doc.root_element();
    for name in key.split('/') {
        match node.children().find(|c| c.has_tag_name(name)) {
            Some(c) => node = c,
            None => return Ok(None),
        }
    }
    Ok(node.text().map(str::to_owned))
}

/// Reads the MRAW recording `path`, passing each kept frame to `on_frame`; see the module's
/// documentation for what is read and how.
pub(crate) fn read_mraw(
    path: &Path,
    opts: &VideoOptions,
    on_frame: &mut dyn FnMut(VideoFrame) -> Result<(), IoError>,
) -> Result<VideoInfo, IoError> {
    let header_file = header_path(path)?;
    let header = read_header(&header_file)?;
    if !header.file_format.eq_ignore_ascii_case("mraw") {
        return Err(IoError::invalid(
            &header_file,
            format!(
                "its file format is `{}`, not MRAW: the frames were saved in another form (read those files \
                 instead)",
                header.file_format
            ),
        ));
    }
    if !header.mono {
        return Err(IoError::invalid(
            &header_file,
            "a colour recording: its frames are a Bayer mosaic or colour, which fluidnerf does not demosaic; \
             record with a monochrome camera, or convert the frames to grey images (one folder per camera)",
        ));
    }
    let (w, h, bits) = (header.width, header.height, header.bits);
    if w.checked_mul(h).is_none_or(|n| n > 1 << 28) {
        return Err(IoError::invalid(&header_file, format!("frames of {w}×{h} pixels")));
    }
    let frame_bytes = match bits {
        8 => w * h,
        16 => 2 * w * h,
        12 if (w * h) % 2 == 0 => w * h * 3 / 2,
        12 => {
            return Err(IoError::invalid(
                &header_file,
                format!("12-bit frames of {w}×{h} pixels, an odd count, which two-pixel packing cannot hold"),
            ))
        }
        other => {
            return Err(IoError::invalid(
                &header_file,
                format!("{other} bits per pixel; MRAW frames of 8, 12 or 16 bits are read"),
            ))
        }
    };
    crate::video::warn_unused_by_raw(path, opts, "an MRAW file");
    let io = |e| IoError::io(path, "MRAW file", e);
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let need = (header.frames as u64).saturating_mul(frame_bytes as u64);
    if len < need {
        return Err(IoError::invalid(
            path,
            format!(
                "{len} bytes, fewer than the {need} that {} says its {} frames of {w}×{h} pixels at {bits} bits take \
                 (a truncated file, or the header of another recording)",
                header_file.display(),
                header.frames
            ),
        ));
    }
    if len > need {
        log::warn!(
            "{}: {} bytes after the {} frames {} announces are left unread",
            path.display(),
            len - need,
            header.frames,
            header_file.display()
        );
    }
    // The sensor's largest count as stored: of its effective bits when the header states a
    // number of them that fits the samples (shifted up when they sit at the high side), unless
    // a count exceeds it, else of the samples' bits. Which one holds is known only once every
    // frame is read, so the saturated pixels are counted at both.
    let ones = |n: u32| (1u32 << n) - 1;
    let samples_full_scale = ones(bits) as f32;
    let effective_full_scale = match header.effective_bits {
        Some((d, high)) if (1..=bits).contains(&d) => (ones(d) << if high { bits - d } else { 0 }) as f32,
        _ => samples_full_scale,
    };
    let (mut at_effective, mut at_samples, mut largest) = (0u64, 0u64, 0f32);
    let mut file = BufReader::new(file);
    let mut data = vec![0u8; frame_bytes];
    let mut kept = 0;
    for i in 0..header.frames {
        if opts.done(i) {
            break;
        }
        if !opts.keeps(i) {
            continue;
        }
        file.seek(SeekFrom::Start(i as u64 * frame_bytes as u64)).map_err(io)?;
        file.read_exact(&mut data).map_err(io)?;
        let mut image = Image::zeros(w, h);
        match bits {
            8 => image.data.iter_mut().zip(&data).for_each(|(o, &v)| *o = f32::from(v)),
            16 => image
                .data
                .iter_mut()
                .zip(data.chunks_exact(2))
                .for_each(|(o, v)| *o = f32::from(u16::from_le_bytes([v[0], v[1]]))),
            _ => {
                for (o, b) in image.data.chunks_exact_mut(2).zip(data.chunks_exact(3)) {
                    let (b0, b1, b2) = (u16::from(b[0]), u16::from(b[1]), u16::from(b[2]));
                    o[0] = f32::from((b0 << 4) | (b1 >> 4));
                    o[1] = f32::from(((b1 & 0x0f) << 8) | b2);
                }
            }
        }
        for &v in &image.data {
            largest = largest.max(v);
            at_effective += u64::from(v >= effective_full_scale);
            at_samples += u64::from(v >= samples_full_scale);
        }
        let time_s = (header.start_frame as f64 + i as f64) / header.rate + opts.time_offset_s;
        on_frame(VideoFrame { index: i, time_s, image, full_scale: None })?;
        kept += 1;
    }
    let saturated_pixels = if largest > effective_full_scale {
        log::warn!(
            "{}: its header {} states {} (a full scale of {effective_full_scale}), but counts reach {largest}: the \
             header contradicts the data (pyMRAW writes these effective bits into every 16-bit file); the full \
             scale of its {bits}-bit samples, {samples_full_scale}, is taken instead: only counts at it are \
             saturated",
            path.display(),
            header_file.display(),
            header.effective_stated,
        );
        at_samples
    } else {
        at_effective
    };
    Ok(VideoInfo {
        decoder: Decoder::Mraw,
        width: w as u32,
        height: h as u32,
        frame_rate: Some(header.rate),
        frames_in_file: header.frames,
        frames_kept: kept,
        range: VideoRange::Full,
        range_source: RangeSource::Raw,
        clipped_pixels: 0,
        saturated_pixels,
        display_rotation_deg: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cih_lines_are_read_up_to_the_first_empty_line() {
        let text = "#Camera Information Header\nImage Width : 32\nColor Type : Mono\n\nImage Height : 9\n";
        assert_eq!(cih_field(text, "Image Width").as_deref(), Some("32"));
        assert_eq!(cih_field(text, "Color Type").as_deref(), Some("Mono"));
        assert_eq!(cih_field(text, "Image Height"), None, "after the header's end");
    }
}
