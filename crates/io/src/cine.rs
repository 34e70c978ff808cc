//! Phantom cine recordings (`.cine`, Vision Research high-speed cameras), read without ffmpeg.
//!
//! A cine file is a `CINEFILEHEADER` (44 bytes, `"CI"` first), a `BITMAPINFOHEADER` (the
//! frames' size and storage), the camera's `SETUP` (frame rate, bit depth, black and white
//! levels), a table of 64-bit offsets, one per image, and the images, each after an
//! annotation whose last four bytes give the image's size. Rows are stored bottom-up, as in a
//! BMP, unless the height is negative. The offsets of the `SETUP` fields read here are those of
//! the vendor's structure as pycine lays it out (packed, 1-byte aligned).
//!
//! **Values.** Frames are read as the sensor stored them: linear counts, minus the black level
//! the `SETUP` states (clamped at 0, the pixels below it counted as clipped), as `f32`. No
//! linearisation or range mapping applies (unlike 8-bit video), so 12-bit data keeps its 12
//! bits.
//!
//! **Read:** grey frames of 8 or 16 bits per pixel, uncompressed, and grey frames packed at 12
//! bits per pixel (`biCompression` 1024, "P12L": two pixels in three bytes, the first pixel's
//! eight high bits, then its four low bits with the second's four high bits, then the second's
//! eight low bits), linear like the 16-bit ones. Packed frames are stored top-down, unlike the
//! others, as pycine and the PIMS reader of Dustin Kleckner read them. **Refused**, each with
//! its reason: packed 10-bit frames (`biCompression` 256, stored through the camera's
//! logarithmic 10-bit table; save the cine from PCC as 16-bit or 12-bit packed), colour
//! sensors' Bayer mosaics and colour-interpolated frames (fluidnerf does not demosaic).
//!
//! **Times.** Frame `i` (from 0, the first image saved in the file) is at
//! `(FirstImageNo + i) / FrameRate` seconds from the trigger, plus the time offset:
//! `FirstImageNo` is the first saved image's number counted from the trigger (negative for
//! images before it), so cameras triggered together whose files keep different ranges of
//! images give their frames the same times at the same instants.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use fluidnerf_core::Image;

use crate::video::{Decoder, RangeSource, VideoFrame, VideoInfo, VideoOptions, VideoRange};
use crate::IoError;

/// `CINEFILEHEADER`: size and the offsets of the fields read.
const FILE_HEADER_LEN: usize = 44;
const OFF_FIRST_IMAGE_NO: usize = 16;
const OFF_IMAGE_COUNT: usize = 20;
const OFF_IMAGE_HEADER: usize = 24;
const OFF_SETUP: usize = 28;
const OFF_IMAGE_OFFSETS: usize = 32;
/// `BITMAPINFOHEADER`: size and fields.
const BITMAP_LEN: usize = 40;
const BI_WIDTH: usize = 4;
const BI_HEIGHT: usize = 8;
const BI_BIT_COUNT: usize = 14;
const BI_COMPRESSION: usize = 16;
/// `biCompression` of frames packed at 10 bits per pixel through a logarithmic table (refused).
const PACKED_10: u32 = 256;
/// `biCompression` of frames packed at 12 bits per pixel, linear ("P12L").
const PACKED_12L: u32 = 1024;
/// `SETUP`: the fields read, as offsets from its start.
const SETUP_FRAME_RATE16: usize = 0;
const SETUP_LENGTH: usize = 142;
const SETUP_FRAME_RATE: usize = 768;
const SETUP_CFA: usize = 808;
const SETUP_REAL_BPP: usize = 896;
const SETUP_BLACK_LEVEL: usize = 5732;

/// How a frame's bytes hold its pixels.
#[derive(Clone, Copy)]
enum Layout {
    /// Two pixels in three bytes, top-down, one run across rows.
    Packed12,
    /// Rows of 8- or 16-bit pixels this many bytes apart, bottom-up unless the height is negative.
    Rows(usize),
}

/// Whether `head` (the file's first bytes) begins like a cine file.
pub(crate) fn is_cine(head: &[u8]) -> bool {
    head.len() >= 4 && &head[0..2] == b"CI" && usize::from(u16::from_le_bytes([head[2], head[3]])) >= FILE_HEADER_LEN
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn i32_at(b: &[u8], at: usize) -> i32 {
    i32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Reads the cine file `path`, passing each kept frame to `on_frame`; see the module's
/// documentation for what is read and how.
pub(crate) fn read_cine(
    path: &Path,
    opts: &VideoOptions,
    on_frame: &mut dyn FnMut(VideoFrame) -> Result<(), IoError>,
) -> Result<VideoInfo, IoError> {
    let bad = |why: String| IoError::invalid(path, format!("malformed cine file: {why}"));
    let io = |e| IoError::io(path, "cine file", e);
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut file = BufReader::new(file);
    // Makes `buf` the `n` bytes from byte `at`, growing it only when it is too short, so that
    // the frames share one buffer; `what` is formatted only for an error.
    let mut read_into = |at: u64, n: usize, buf: &mut Vec<u8>, what: &dyn std::fmt::Display| {
        // Checked before any allocation: a corrupt offset or size can claim anything.
        if at.checked_add(n as u64).is_none_or(|end| end > len) {
            return Err(bad(format!(
                "the {what} ({n} bytes at byte {at}) runs past the end of the file at byte {len}"
            )));
        }
        file.seek(SeekFrom::Start(at)).map_err(io)?;
        buf.resize(n, 0);
        file.read_exact(buf).map_err(io)
    };
    let mut read_at = |at: u64, n: usize, what: &str| -> Result<Vec<u8>, IoError> {
        let mut buf = Vec::new();
        read_into(at, n, &mut buf, &what)?;
        Ok(buf)
    };
    let header = read_at(0, FILE_HEADER_LEN, "file header")?;
    let count = u32_at(&header, OFF_IMAGE_COUNT) as usize;
    // The first saved image's number counted from the trigger (negative before it).
    let first_image_no = i32_at(&header, OFF_FIRST_IMAGE_NO);
    if count == 0 {
        return Err(bad("it holds no images (ImageCount 0)".into()));
    }
    let bitmap = read_at(u64::from(u32_at(&header, OFF_IMAGE_HEADER)), BITMAP_LEN, "image header")?;
    let width = i32_at(&bitmap, BI_WIDTH);
    let height = i32_at(&bitmap, BI_HEIGHT);
    let bits = u16_at(&bitmap, BI_BIT_COUNT);
    let compression = u32_at(&bitmap, BI_COMPRESSION);
    let (w, h) = (width.unsigned_abs() as usize, height.unsigned_abs() as usize);
    if width <= 0 || h == 0 || w.checked_mul(h).is_none_or(|n| n > 1 << 28) {
        return Err(bad(format!("frames of {width}×{height} pixels")));
    }
    let setup_at = u64::from(u32_at(&header, OFF_SETUP));
    let setup_head = read_at(setup_at, SETUP_LENGTH + 2, "camera setup")?;
    let setup_len = usize::from(u16_at(&setup_head, SETUP_LENGTH));
    if setup_len <= SETUP_REAL_BPP + 4 {
        return Err(bad(format!(
            "its camera setup is {setup_len} bytes long, too short to state the frame rate and bit depth (a cine \
             of a Phantom software older than 2002?)"
        )));
    }
    let setup = read_at(setup_at, setup_len.min(SETUP_BLACK_LEVEL + 4), "camera setup")?;
    let cfa = u32_at(&setup, SETUP_CFA) & 0x00ff_ffff;
    // Whether the frames are packed at 12 bits per pixel.
    let packed = compression == PACKED_12L;
    match (compression, bits) {
        (0, 8 | 16) | (PACKED_12L, _) if cfa != 0 => {
            return Err(IoError::invalid(
                path,
                format!(
                    "a colour sensor's raw frames (colour filter array code {cfa}): each is a Bayer mosaic, which \
                     fluidnerf does not demosaic; record with a monochrome camera, or convert the frames to grey \
                     images (one folder per camera) with the camera's software"
                ),
            ))
        }
        (0, 8 | 16) | (PACKED_12L, _) => {}
        (0, 24 | 48) => {
            return Err(IoError::invalid(
                path,
                format!(
                    "colour-interpolated frames ({bits} bits per pixel), which fluidnerf does not read: save the \
                     cine as grey, or convert its frames to grey images"
                ),
            ))
        }
        (PACKED_10, _) => {
            return Err(IoError::invalid(
                path,
                format!(
                    "packed 10-bit frames (compression {compression}), stored through the camera's logarithmic \
                     10-bit table, which fluidnerf does not unpack: save the cine from the camera's software with 16 \
                     bits per pixel, or packed at 12 bits"
                ),
            ))
        }
        _ => return Err(bad(format!("{bits} bits per pixel with compression {compression}"))),
    }
    let rate = match u32_at(&setup, SETUP_FRAME_RATE) {
        0 => u32::from(u16_at(&setup, SETUP_FRAME_RATE16)),
        r => r,
    };
    if rate == 0 {
        return Err(bad("its camera setup states a frame rate of 0 frames per second".into()));
    }
    let real_bpp = u32_at(&setup, SETUP_REAL_BPP);
    let black = if setup.len() >= SETUP_BLACK_LEVEL + 4 { u32_at(&setup, SETUP_BLACK_LEVEL) } else { 0 };
    let stored_bits = if packed { 12 } else { bits };
    let full_scale = (1u32 << stored_bits) - 1;
    if black >= full_scale {
        return Err(bad(format!("its black level {black} is at or above the {stored_bits}-bit full scale")));
    }
    // The sensor's largest count: that of its significant bits (12 in 16-bit frames) when the
    // setup states a number of them that fits the frames and its black level, else the frames'.
    let sensor_max = Some(real_bpp)
        .filter(|b| (1..=u32::from(stored_bits)).contains(b))
        .map(|b| (1u32 << b) - 1)
        .filter(|&m| m > black)
        .unwrap_or(full_scale);
    let saturated_at = (sensor_max - black) as f32;
    crate::video::warn_unused_by_raw(path, opts, "a cine file");
    let offsets_at = u64::from(u32_at(&header, OFF_IMAGE_OFFSETS));
    let offsets: Vec<u64> = read_at(offsets_at, 8 * count, "image offset table")?
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    let bytes_per_pixel = usize::from(bits / 8);
    let row_bytes = w * bytes_per_pixel;
    let mut clipped = 0u64;
    let mut kept = 0;
    // The current frame's stored bytes and its 4-byte fields: one buffer each for all frames.
    let (mut data, mut word) = (Vec::new(), Vec::with_capacity(4));
    for (i, &offset) in offsets.iter().enumerate() {
        if opts.done(i) {
            break;
        }
        if !opts.keeps(i) {
            continue;
        }
        read_into(offset, 4, &mut word, &format_args!("annotation of image {i}"))?;
        let annotation_len = u64::from(u32_at(&word, 0));
        if annotation_len < 8 {
            return Err(bad(format!("image {i}'s annotation claims {annotation_len} bytes, fewer than its own 8")));
        }
        read_into(offset + annotation_len - 4, 4, &mut word, &format_args!("size of image {i}"))?;
        let size = u32_at(&word, 0) as usize;
        // Rows are packed, or padded to four bytes as in a BMP; 12-bit pixels run on across rows.
        let padded = row_bytes.div_ceil(4) * 4;
        let layout = if packed {
            let want = (3 * w * h).div_ceil(2);
            if size != want {
                return Err(bad(format!("image {i} holds {size} bytes; {w}×{h} pixels packed at 12 bits take {want}")));
            }
            Layout::Packed12
        } else if size == row_bytes * h {
            Layout::Rows(row_bytes)
        } else if size == padded * h {
            Layout::Rows(padded)
        } else {
            return Err(bad(format!(
                "image {i} holds {size} bytes; {w}×{h} pixels of {bits} bits take {} (or {} with rows padded to \
                 four bytes)",
                row_bytes * h,
                padded * h
            )));
        };
        read_into(offset + annotation_len, size, &mut data, &format_args!("image {i}"))?;
        let mut image = Image::zeros(w, h);
        let mut put = |o: &mut f32, v: u32| {
            if v < black {
                clipped += 1;
            }
            *o = v.saturating_sub(black) as f32;
        };
        match layout {
            // Top-down, the pixels one run of pairs; an odd count's last pair is half of one.
            Layout::Packed12 => {
                for (pair, b) in image.data.chunks_mut(2).zip(data.chunks(3)) {
                    let b = [b[0], b.get(1).copied().unwrap_or(0), b.get(2).copied().unwrap_or(0)];
                    put(&mut pair[0], u32::from(b[0]) << 4 | u32::from(b[1]) >> 4);
                    if let Some(o) = pair.get_mut(1) {
                        put(o, u32::from(b[1] & 0x0f) << 8 | u32::from(b[2]));
                    }
                }
            }
            Layout::Rows(stride) => {
                for (r, row) in data.chunks_exact(stride).enumerate() {
                    // Bottom-up unless the height is negative.
                    let y = if height > 0 { h - 1 - r } else { r };
                    let out = &mut image.data[y * w..(y + 1) * w];
                    if bits == 8 {
                        out.iter_mut().zip(&row[..row_bytes]).for_each(|(o, &v)| put(o, u32::from(v)));
                    } else {
                        out.iter_mut()
                            .zip(row[..row_bytes].chunks_exact(2))
                            .for_each(|(o, v)| put(o, u32::from(u16::from_le_bytes([v[0], v[1]]))));
                    }
                }
            }
        }
        let time_s = (f64::from(first_image_no) + i as f64) / f64::from(rate) + opts.time_offset_s;
        on_frame(VideoFrame { index: i, time_s, image, full_scale: Some(saturated_at) })?;
        kept += 1;
    }
    log::debug!(
        "{}: cine of {w}×{h} px, {stored_bits} bits per pixel{} ({real_bpp} significant), black level {black}, {rate} \
         frames/s",
        path.display(),
        if packed { " packed" } else { "" }
    );
    Ok(VideoInfo {
        decoder: Decoder::Cine,
        width: w as u32,
        height: h as u32,
        frame_rate: Some(f64::from(rate)),
        frames_in_file: count,
        frames_kept: kept,
        range: VideoRange::Full,
        range_source: RangeSource::Raw,
        clipped_pixels: clipped,
        saturated_pixels: 0,
        display_rotation_deg: None,
    })
}
