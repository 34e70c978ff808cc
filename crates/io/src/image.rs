//! Camera images as linear f32.
//!
//! # Reading
//! - 8- and 16-bit PNG, 8/16/32-bit integer and 32/64-bit float TIFF.
//! - Values stay linear and unscaled: integer images give their raw sensor counts as f32
//!   (a 16-bit PNG pixel stored as 40000 reads as 40000.0, never normalised to [0, 1] and never
//!   sRGB-decoded); float TIFF values are returned as stored.
//! - Colour images are reduced to luminance `Y = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709
//!   weights applied to the stored values, which are taken as linear) with a warning; an alpha
//!   channel is dropped.
//!
//! # Writing
//! - [`write_png16`]: 16-bit grayscale PNG with the explicit mapping
//!   `count = round(value / full_scale × 65535)`, clamped to `[0, 65535]`.
//! - [`write_png16_counts`]: values that already are integer counts `0..=65535` (synthetic
//!   sensors), stored exactly; anything else is an error.
//! - [`write_tiff_f32`]: 32-bit float grayscale TIFF, values exactly as in memory.
//!
//! Layout: [`Image`] is row-major, `data[row * width + col]`, row 0 at the top.

use std::io::Cursor;
use std::path::Path;

use fluidnerf_core::Image;
use image::{DynamicImage, ImageEncoder};

use crate::{atomic_write, IoError};

/// Reads a PNG or TIFF image (chosen by content, not extension) as linear f32.
pub fn read_image(path: &Path) -> Result<Image, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, "image file", e))?;
    if bytes.starts_with(b"II*\0")
        || bytes.starts_with(b"MM\0*")
        || bytes.starts_with(b"II+\0")
        || bytes.starts_with(b"MM\0+")
    {
        read_tiff(path, &bytes)
    } else if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        read_png(path, &bytes)
    } else {
        Err(IoError::invalid(
            path,
            "unreadable image: not a PNG or TIFF file (supported: 8/16-bit PNG, 16-bit and float TIFF)",
        ))
    }
}

fn read_png(path: &Path, bytes: &[u8]) -> Result<Image, IoError> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        .map_err(|e| IoError::invalid(path, format!("unreadable PNG: {e}")))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let (channels, data): (usize, Vec<f32>) = match img {
        DynamicImage::ImageLuma8(b) => (1, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageLumaA8(b) => (2, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageRgb8(b) => (3, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageRgba8(b) => (4, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageLuma16(b) => (1, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageLumaA16(b) => (2, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageRgb16(b) => (3, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageRgba16(b) => (4, b.into_raw().into_iter().map(f32::from).collect()),
        other => return Err(IoError::invalid(path, format!("unsupported PNG pixel type {:?}", other.color()))),
    };
    Ok(to_gray(path, w, h, channels, data))
}

fn read_tiff(path: &Path, bytes: &[u8]) -> Result<Image, IoError> {
    use tiff::decoder::{Decoder, DecodingResult};
    let bad = |e: tiff::TiffError| IoError::invalid(path, format!("unreadable TIFF: {e}"));
    let mut dec = Decoder::new(Cursor::new(bytes)).map_err(bad)?;
    let (w, h) = dec.dimensions().map_err(bad)?;
    let (w, h) = (w as usize, h as usize);
    let data: Vec<f32> = match dec.read_image().map_err(bad)? {
        DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::U32(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::F32(v) => v,
        DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
        DecodingResult::I8(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
        DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
        _ => {
            return Err(IoError::invalid(
                path,
                "unsupported TIFF sample type (use 8/16/32-bit integers or 32/64-bit floats)",
            ))
        }
    };
    let pixels = w * h;
    if pixels == 0 || data.len() % pixels != 0 || data.len() / pixels > 4 {
        return Err(IoError::invalid(path, format!("TIFF of {w}x{h} pixels holds {} samples", data.len())));
    }
    Ok(to_gray(path, w, h, data.len() / pixels, data))
}

/// Interleaved samples with `channels` per pixel (1 gray, 2 gray+alpha, 3 RGB, 4 RGBA) to gray.
fn to_gray(path: &Path, w: usize, h: usize, channels: usize, data: Vec<f32>) -> Image {
    match channels {
        1 => Image::from_vec(w, h, data),
        2 => {
            log::warn!("{}: dropping the alpha channel", path.display());
            Image::from_vec(w, h, data.chunks_exact(2).map(|p| p[0]).collect())
        }
        _ => {
            log::warn!(
                "{}: colour image reduced to luminance (0.2126 R + 0.7152 G + 0.0722 B of the stored values)",
                path.display()
            );
            let lum = data.chunks_exact(channels).map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]).collect();
            Image::from_vec(w, h, lum)
        }
    }
}

fn check_finite(path: &Path, image: &Image) -> Result<(), IoError> {
    match image.first_non_finite() {
        Some((col, row)) => Err(IoError::NonFinite {
            path: path.to_path_buf(),
            location: format!("pixel (col {col}, row {row})"),
            value: image.get(col, row),
        }),
        None => Ok(()),
    }
}

fn encode_png16(path: &Path, image: &Image, counts: &[u16]) -> Result<(), IoError> {
    let bytes: Vec<u8> = counts.iter().flat_map(|c| c.to_ne_bytes()).collect();
    atomic_write(path, |w| {
        image::codecs::png::PngEncoder::new(w)
            .write_image(&bytes, image.width as u32, image.height as u32, image::ExtendedColorType::L16)
            .map_err(std::io::Error::other)
    })
}

/// Writes a 16-bit grayscale PNG storing `round(value / full_scale × 65535)` clamped to
/// `[0, 65535]`, so `full_scale` maps to the largest count. Reading it back gives counts, i.e.
/// `value ≈ count × full_scale / 65535`. Non-finite values are an error.
pub fn write_png16(path: &Path, image: &Image, full_scale: f32) -> Result<(), IoError> {
    assert!(full_scale.is_finite() && full_scale > 0.0, "write_png16: full_scale must be positive, got {full_scale}");
    check_finite(path, image)?;
    let counts: Vec<u16> = image
        .data
        .iter()
        .map(|&v| (f64::from(v) / f64::from(full_scale) * 65535.0).round().clamp(0.0, 65535.0) as u16)
        .collect();
    encode_png16(path, image, &counts)
}

/// Writes a 16-bit grayscale PNG of values that already are integer counts `0..=65535`,
/// exactly. A value outside that range or with a fractional part is an error naming the pixel.
pub fn write_png16_counts(path: &Path, image: &Image) -> Result<(), IoError> {
    check_finite(path, image)?;
    if let Some(i) = image.data.iter().position(|&v| !(0.0..=65535.0).contains(&v) || v.fract() != 0.0) {
        return Err(IoError::invalid(
            path,
            format!(
                "pixel (col {}, row {}) is {}, not an integer count in 0..=65535",
                i % image.width,
                i / image.width,
                image.data[i]
            ),
        ));
    }
    let counts: Vec<u16> = image.data.iter().map(|&v| v as u16).collect();
    encode_png16(path, image, &counts)
}

/// Writes a 32-bit float grayscale TIFF (uncompressed), values exactly as in memory
/// (NaN and infinities included: this is also how tests make broken images).
pub fn write_tiff_f32(path: &Path, image: &Image) -> Result<(), IoError> {
    let mut buf = Cursor::new(Vec::new());
    tiff::encoder::TiffEncoder::new(&mut buf)
        .and_then(|mut enc| {
            enc.write_image::<tiff::encoder::colortype::Gray32Float>(
                image.width as u32,
                image.height as u32,
                &image.data,
            )
        })
        .map_err(|e| IoError::invalid(path, format!("TIFF encoding failed: {e}")))?;
    let bytes = buf.into_inner();
    atomic_write(path, |w| w.write_all(&bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize, scale: f32) -> Image {
        Image::from_vec(w, h, (0..w * h).map(|i| i as f32 * scale).collect())
    }

    #[test]
    fn png16_counts_round_trip_exactly_and_stay_unnormalised() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.png");
        let mut img = ramp(7, 5, 1000.0);
        img.set(0, 0, 65535.0);
        write_png16_counts(&p, &img).expect("write");
        assert_eq!(read_image(&p).expect("read"), img);
        img.set(1, 0, 0.5);
        let err = write_png16_counts(&p, &img).expect_err("fractional");
        assert!(err.to_string().contains("col 1, row 0"), "{err}");
    }

    #[test]
    fn png16_full_scale_mapping() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("b.png");
        let img = Image::from_vec(4, 1, vec![0.0, 1.0, 2.0, 3.0]);
        write_png16(&p, &img, 2.0).expect("write");
        assert_eq!(read_image(&p).expect("read").data, vec![0.0, 32768.0, 65535.0, 65535.0]);
    }

    #[test]
    fn png8_and_colour_png() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("g8.png");
        image::GrayImage::from_raw(3, 2, vec![0, 1, 2, 100, 200, 255]).expect("buf").save(&p).expect("save");
        assert_eq!(read_image(&p).expect("read").data, vec![0.0, 1.0, 2.0, 100.0, 200.0, 255.0]);
        let p = dir.path().join("rgb.png");
        image::RgbImage::from_raw(1, 1, vec![100, 100, 100]).expect("buf").save(&p).expect("save");
        let lum = read_image(&p).expect("read").data[0];
        assert!((lum - 100.0).abs() < 1e-3, "gray colour keeps its value, got {lum}");
    }

    #[test]
    fn float_tiff_round_trips_exactly_including_non_finite() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("f.tif");
        let mut img = ramp(6, 4, 0.123);
        img.set(2, 3, -1.5e-7);
        write_tiff_f32(&p, &img).expect("write");
        assert_eq!(read_image(&p).expect("read"), img);
        img.set(1, 1, f32::NAN);
        write_tiff_f32(&p, &img).expect("write");
        assert_eq!(read_image(&p).expect("read").first_non_finite(), Some((1, 1)));
    }

    #[test]
    fn tiff16_reads_counts() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("u16.tif");
        let data: Vec<u16> = vec![0, 1, 4095, 65535];
        let mut f = std::fs::File::create(&p).expect("create");
        tiff::encoder::TiffEncoder::new(&mut f)
            .expect("enc")
            .write_image::<tiff::encoder::colortype::Gray16>(2, 2, &data)
            .expect("write");
        drop(f);
        assert_eq!(read_image(&p).expect("read").data, vec![0.0, 1.0, 4095.0, 65535.0]);
    }

    #[test]
    fn unreadable_and_missing_files_are_named() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("junk.png");
        std::fs::write(&p, b"not an image").expect("write");
        let err = read_image(&p).expect_err("junk");
        assert!(err.to_string().contains("junk.png") && err.to_string().contains("not a PNG or TIFF"), "{err}");
        let err = read_image(&dir.path().join("none.png")).expect_err("missing");
        assert!(matches!(err, IoError::NotFound { .. }), "{err}");
        assert!(err.to_string().contains("none.png"), "{err}");
    }
}
