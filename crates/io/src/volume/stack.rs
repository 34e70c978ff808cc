//! Volumes as ImageJ TIFF stacks: one 32-bit float page per z-slice, calibrated so that Fiji
//! and ImageJ show the voxels at their size and place in world units (see the parent module's
//! docs for the layout).

use std::io::{BufReader, Seek, Write};
use std::path::Path;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Volume};
use tiff::encoder::{Rational, TiffEncoder, TiffKind};
use tiff::tags::Tag;
use tiff::TiffResult;

use crate::IoError;

/// Past this many bytes of pixels a stack is written as BigTIFF, whose offsets are 64-bit;
/// classic TIFF reaches 4 GiB, and its directories need room after the data.
const CLASSIC_TIFF_DATA_LIMIT: u64 = (1 << 32) - (1 << 24);

/// The most pages read from one file (a z-stack this deep would be unusual; a corrupt file's
/// chain of directories is cut here).
const MAX_PAGES: usize = 1 << 16;

/// The most voxels read from one stack (8 GiB of f32): compressed pages can claim far more
/// than the file holds.
const MAX_VOXELS: usize = 1 << 31;

/// ImageJ's name for a length unit: it knows micrometres as `micron`, and a TIFF description
/// is ASCII, so other characters are escaped as Java's `\uXXXX`.
fn imagej_unit(unit: &str) -> String {
    match unit {
        "um" | "µm" | "μm" | "micron" | "microns" | "micrometre" | "micrometer" => "micron".into(),
        _ => unit.chars().map(|c| if c.is_ascii() { c.to_string() } else { format!("\\u{:04X}", c as u32) }).collect(),
    }
}

/// Metres in one `unit` of length, for the units a calibration is converted between (ImageJ's
/// `micron` and its `\u00B5m` escape are micrometres).
fn metres_per(unit: &str) -> Option<f64> {
    Some(match unit {
        "nm" => 1e-9,
        "µm" | "μm" | "um" | "micron" | "microns" | "\\u00B5m" => 1e-6,
        "mm" => 1e-3,
        "cm" => 1e-2,
        "m" => 1.0,
        _ => return None,
    })
}

/// Whether `unit` is a length that calibrations are converted from and to (nm, µm, mm, cm, m).
pub fn is_length_unit(unit: &str) -> bool {
    metres_per(unit).is_some()
}

/// ImageJ's word for a stack without a physical calibration.
fn is_pixel_unit(unit: &str) -> bool {
    matches!(unit, "pixel" | "pixels" | "")
}

/// The best rational approximation of `x > 0` with 32-bit numerator and denominator
/// (continued fractions), as TIFF stores resolutions.
fn rational(x: f64) -> Rational {
    let (mut h0, mut h1, mut k0, mut k1) = (0u64, 1u64, 1u64, 0u64);
    let mut r = x;
    let mut best = Rational { n: (x.round().clamp(1.0, u32::MAX as f64)) as u32, d: 1 };
    for _ in 0..64 {
        let a = r.floor();
        if a > u32::MAX as f64 {
            break;
        }
        let a = a as u64;
        let (h2, k2) = (a.saturating_mul(h1).saturating_add(h0), a.saturating_mul(k1).saturating_add(k0));
        if h2 > u32::MAX as u64 || k2 > u32::MAX as u64 {
            break;
        }
        best = Rational { n: h2 as u32, d: k2 as u32 };
        let frac = r - a as f64;
        if frac.abs() < 1e-12 || ((h2 as f64 / k2 as f64) - x).abs() <= x * 1e-15 {
            break;
        }
        (h0, h1, k0, k1) = (h1, h2, k1, k2);
        r = 1.0 / frac;
    }
    best
}

/// The ImageJ description of `volume`'s stack: its slice count, unit, slice spacing, display
/// range and origin (in pixels, ImageJ's convention: pixel `i` spans `[i, i + 1)` and sits at
/// `(i − xorigin) · pixel width`), so that voxel `(i, j, k)` spans
/// `[min + (i, j, k) · h, min + (i + 1, j + 1, k + 1) · h]` in world units.
fn imagej_description(volume: &Volume, unit: &str) -> String {
    let [_, _, nz] = volume.dims;
    let h = volume.spacing();
    let origin = -volume.aabb.min / h;
    let (lo, hi) = volume.min_max();
    let mut d = String::from("ImageJ=1.11a\n");
    if nz > 1 {
        d += &format!("images={nz}\nslices={nz}\n");
    }
    d += &format!("unit={}\nspacing={}\nloop=false\n", imagej_unit(unit), h.z);
    if lo.is_finite() && hi.is_finite() {
        d += &format!("min={lo}\nmax={hi}\n");
    }
    d += &format!("xorigin={}\nyorigin={}\nzorigin={}\n", origin.x, origin.y, origin.z);
    d
}

/// Writes `volume` as a TIFF stack that ImageJ and Fiji open as a calibrated 32-bit stack
/// (page `k` is z-slice `k`, row `j` the y index, column `i` the x index; NumPy's `tifffile`
/// reads it as shape `(nz, ny, nx)`). `unit` names the world's length unit. Stacks of more
/// than 4 GiB are written as BigTIFF, which Fiji opens through Bio-Formats.
pub fn write_tiff_stack(path: &Path, volume: &Volume, unit: &str) -> Result<(), IoError> {
    let big = (volume.data.len() as u64).saturating_mul(4) > CLASSIC_TIFF_DATA_LIMIT;
    write_stack(path, volume, unit, big)
}

fn write_stack(path: &Path, volume: &Volume, unit: &str, big: bool) -> Result<(), IoError> {
    let description = imagej_description(volume, unit);
    let tiff_error = |e: tiff::TiffError| std::io::Error::other(format!("TIFF encoding failed: {e}"));
    crate::atomic_write_seekable(path, |w| {
        if big {
            write_pages(TiffEncoder::new_big(w).map_err(tiff_error)?, volume, &description)
        } else {
            write_pages(TiffEncoder::new(w).map_err(tiff_error)?, volume, &description)
        }
        .map_err(tiff_error)
    })
}

/// All pages' pixels first, in one block (ImageJ reads an `images=N` stack as contiguous
/// pages from the first page's offset), then one directory per page pointing into it.
fn write_pages<W: Write + Seek, K: TiffKind>(
    mut enc: TiffEncoder<W, K>,
    volume: &Volume,
    description: &str,
) -> TiffResult<()> {
    let [nx, ny, nz] = volume.dims;
    let h = volume.spacing();
    let page_bytes = (nx * ny * 4) as u64;
    let mut start = 0u64;
    for k in 0..nz {
        let mut dir = enc.image_directory()?;
        if k == 0 {
            start = dir.write_data(&volume.data[..])?;
            dir.write_tag(Tag::ImageDescription, description)?;
            dir.write_tag(Tag::XResolution, rational(1.0 / h.x))?;
            dir.write_tag(Tag::YResolution, rational(1.0 / h.y))?;
            // 1: no absolute unit; the resolutions count pixels per the description's `unit`.
            dir.write_tag(Tag::ResolutionUnit, 1u16)?;
        }
        dir.write_tag(Tag::NewSubfileType, 0u32)?;
        dir.write_tag(Tag::ImageWidth, nx as u32)?;
        dir.write_tag(Tag::ImageLength, ny as u32)?;
        dir.write_tag(Tag::BitsPerSample, 32u16)?;
        dir.write_tag(Tag::Compression, 1u16)?;
        dir.write_tag(Tag::PhotometricInterpretation, 1u16)?;
        dir.write_tag(Tag::SamplesPerPixel, 1u16)?;
        dir.write_tag(Tag::RowsPerStrip, ny as u32)?;
        dir.write_tag(Tag::StripOffsets, K::convert_offset(start + k as u64 * page_bytes)?)?;
        dir.write_tag(Tag::StripByteCounts, K::convert_offset(page_bytes)?)?;
        dir.write_tag(Tag::SampleFormat, 3u16)?;
        dir.finish()?;
    }
    Ok(())
}

/// What an ImageJ description says of the stack's geometry.
#[derive(Default)]
struct Calibration {
    imagej: bool,
    spacing: Option<f64>,
    origin: [Option<f64>; 3],
    /// `channels`, `frames`: a hyperstack of more than one volume.
    channels: usize,
    frames: usize,
    /// `images`: the pages of the stack, as ImageJ counts them.
    images: Option<usize>,
    /// `spacing` as written, whether or not it is a depth.
    spacing_text: Option<String>,
    /// `unit`: the length unit of the calibration, as written.
    unit: Option<String>,
}

fn parse_description(text: &str) -> Calibration {
    let mut c = Calibration { channels: 1, frames: 1, ..Default::default() };
    c.imagej = text.starts_with("ImageJ=");
    for line in text.lines() {
        let Some((key, value)) = line.split_once('=') else { continue };
        let value = value.trim().trim_end_matches('\0');
        let number = value.parse::<f64>().ok().filter(|v| v.is_finite());
        match key.trim() {
            "spacing" => {
                c.spacing = number.filter(|&v| v > 0.0);
                c.spacing_text = Some(value.to_string());
            }
            "xorigin" => c.origin[0] = number,
            "yorigin" => c.origin[1] = number,
            "zorigin" => c.origin[2] = number,
            "channels" => c.channels = number.map_or(1, |v| v as usize),
            "frames" => c.frames = number.map_or(1, |v| v as usize),
            "images" => c.images = number.map(|v| v as usize),
            "unit" => c.unit = Some(value.to_string()),
            _ => {}
        }
    }
    c
}

/// A resolution tag's pixels per unit, when present, positive and finite.
fn resolution<R: std::io::Read + Seek>(dec: &mut tiff::decoder::Decoder<R>, tag: Tag) -> Option<f64> {
    use tiff::decoder::ifd::Value;
    let value = match dec.find_tag(tag).ok()?? {
        Value::List(mut v) if v.len() == 1 => v.remove(0),
        v => v,
    };
    let per_unit = match value {
        Value::Rational(n, d) if d != 0 => n as f64 / d as f64,
        Value::Float(x) => x as f64,
        Value::Double(x) => x,
        _ => return None,
    };
    (per_unit.is_finite() && per_unit > 0.0).then_some(per_unit)
}

/// The length unit a TIFF stack's ImageJ calibration is in, when it has one that is a length
/// (not ImageJ's `pixel`), named as fluidnerf names it (`µm` for `micron` and its other
/// spellings). A reader without a scene takes the stack's numbers in this unit, which the
/// caller must then label them with, or convert them to its own ([`read_tiff_stack`]'s `unit`).
pub fn tiff_stack_unit(path: &Path) -> Result<Option<String>, IoError> {
    use tiff::decoder::Decoder;
    crate::check_regular_file(path, "volume file")?;
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "volume file", e))?;
    let mut dec =
        Decoder::new(BufReader::new(file)).map_err(|e| IoError::invalid(path, format!("unreadable TIFF: {e}")))?;
    let calibration = parse_description(&dec.get_tag_ascii_string(Tag::ImageDescription).unwrap_or_default());
    Ok(calibration.unit.filter(|u| calibration.imagej && !is_pixel_unit(u)).map(|u| match metres_per(&u) {
        Some(1e-6) => "µm".to_string(),
        _ => u,
    }))
}

/// Reads a TIFF stack (one greyscale page per z-slice, all of one size; 16/32/64-bit float or
/// 8/16-bit unsigned samples) as a volume. Its box comes from the file's ImageJ calibration
/// (pixel size from the resolution tags, slice spacing and origin from the description, as
/// [`write_tiff_stack`] and Fiji write them), converted to the world's length `unit` when
/// both are lengths fluidnerf knows (nm, µm, mm, cm, m) and refused when they differ
/// otherwise; a stack without one (or calibrated in ImageJ's `pixel`) fills `aabb`, and is
/// refused when none is given. `unit` None takes the calibration as it is.
pub fn read_tiff_stack(path: &Path, aabb: Option<Aabb>, unit: Option<&str>) -> Result<Volume, IoError> {
    use tiff::decoder::{Decoder, DecodingResult};
    use tiff::ColorType;
    crate::check_regular_file(path, "volume file")?;
    let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "volume file", e))?;
    let bad = |e: tiff::TiffError| IoError::invalid(path, format!("unreadable TIFF: {e}"));
    let mut dec = Decoder::new(BufReader::new(file)).map_err(bad)?;
    let (w, h) = dec.dimensions().map_err(bad)?;
    let (nx, ny) = (w as usize, h as usize);
    if nx.checked_mul(ny).is_none_or(|n| n == 0 || n > 1 << 30) {
        return Err(IoError::invalid(path, format!("TIFF claims pages of {nx}x{ny} pixels")));
    }
    let description = dec.get_tag_ascii_string(Tag::ImageDescription).unwrap_or_default();
    let calibration = parse_description(&description);
    if calibration.channels > 1 || calibration.frames > 1 {
        return Err(IoError::invalid(
            path,
            format!(
                "an ImageJ hyperstack of {} channel(s) and {} frame(s); a volume file holds one: save each as a \
                 stack of its own (in Fiji, Image > Duplicate or Image > Stacks > Tools > Make Substack)",
                calibration.channels, calibration.frames
            ),
        ));
    }
    let pixel = [resolution(&mut dec, Tag::XResolution), resolution(&mut dec, Tag::YResolution)];
    let mut data: Vec<f32> = Vec::new();
    let mut nz = 0usize;
    loop {
        let size = dec.dimensions().map_err(bad)?;
        if size != (w, h) {
            return Err(IoError::invalid(
                path,
                format!(
                    "page {} is {}x{} pixels, page 1 {nx}x{ny}; a volume's slices are of one size",
                    nz + 1,
                    size.0,
                    size.1
                ),
            ));
        }
        let colour = dec.colortype().map_err(bad)?;
        if !matches!(colour, ColorType::Gray(_)) {
            return Err(IoError::invalid(
                path,
                format!(
                    "page {} is of colour type {colour:?}; a volume's slices are greyscale, one sample per pixel",
                    nz + 1
                ),
            ));
        }
        let page = match dec.read_image().map_err(bad)? {
            DecodingResult::F16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::F32(v) => v,
            DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
            _ => {
                return Err(IoError::invalid(
                    path,
                    format!(
                        "page {}: unsupported sample type (use 16/32/64-bit floats or 8/16-bit unsigned integers)",
                        nz + 1
                    ),
                ))
            }
        };
        if page.len() != nx * ny {
            return Err(IoError::invalid(
                path,
                format!("page {} holds {} samples for {nx}x{ny} pixels", nz + 1, page.len()),
            ));
        }
        if data.len() + page.len() > MAX_VOXELS {
            return Err(IoError::invalid(
                path,
                format!(
                    "page {}: the stack holds more than {MAX_VOXELS} voxels (8 GiB), the most a volume is read with",
                    nz + 1
                ),
            ));
        }
        data.extend_from_slice(&page);
        nz += 1;
        if !dec.more_images() {
            break;
        }
        if nz == MAX_PAGES {
            return Err(IoError::invalid(path, format!("more than {MAX_PAGES} pages")));
        }
        dec.next_image().map_err(bad)?;
    }
    // ImageJ saves a stack beyond 4 GiB with one directory, the other slices' pixels following
    // the first page's: reading the pages alone would give its first slice as the volume.
    if let Some(images) = calibration.images.filter(|&n| calibration.imagej && n != nz) {
        return Err(IoError::invalid(
            path,
            format!(
                "its ImageJ description counts {images} images, but the file holds {nz} page(s): ImageJ writes a \
                 stack beyond 4 GiB with one directory, which is not read; give the volume as a .npy or .vti, \
                 or as stacks below 4 GiB"
            ),
        ));
    }
    // A calibrated stack whose slice depth is no depth would be stretched over the box given,
    // as if it held no calibration.
    if let (true, [Some(_), Some(_)], Some(text), None) =
        (calibration.imagej && nz > 1, pixel, &calibration.spacing_text, calibration.spacing)
    {
        return Err(IoError::invalid(
            path,
            format!(
                "its ImageJ calibration's slice spacing {text:?} is no positive depth; set the voxel depth (in \
                 Fiji, Image > Properties)"
            ),
        ));
    }
    let dims = [nx, ny, nz];
    let pixel_units = calibration.unit.as_deref().is_some_and(is_pixel_unit);
    let calibrated_in = calibration.unit.as_deref().filter(|_| !pixel_units);
    let box_from_file = match (calibration.imagej && !pixel_units, pixel, calibration.spacing) {
        (true, [Some(px), Some(py)], spacing) if spacing.is_some() || nz == 1 => {
            let h = DVec3::new(1.0 / px, 1.0 / py, spacing.unwrap_or(1.0 / px));
            let origin = DVec3::new(
                calibration.origin[0].unwrap_or(0.0),
                calibration.origin[1].unwrap_or(0.0),
                calibration.origin[2].unwrap_or(0.0),
            );
            // The calibration's unit in the world's: a stack calibrated in µm read into a scene
            // in mm would otherwise be a thousand times too large.
            let scale = match (calibrated_in, unit) {
                (Some(from), Some(to)) if from != to => match (metres_per(from), metres_per(to)) {
                    (Some(a), Some(b)) => a / b,
                    _ => {
                        return Err(IoError::invalid(
                            path,
                            format!(
                                "its ImageJ calibration is in `{from}` and the scene's length unit is `{to}`: \
                                 only nm, µm (micron), mm, cm and m are converted; set the stack's unit to the \
                                 scene's (in Fiji, Image > Properties)"
                            ),
                        ))
                    }
                },
                _ => 1.0,
            };
            // + 0: an origin of 0 gave a corner of -0, written as such.
            let min = -origin * h * scale + DVec3::ZERO;
            let size = DVec3::new(nx as f64, ny as f64, nz as f64) * h * scale;
            Some(Aabb { min, max: min + size })
        }
        _ => None,
    };
    let aabb = match (box_from_file, aabb) {
        (Some(b), _) => {
            b.validate().map_err(|e| IoError::invalid(path, format!("its ImageJ calibration gives a box that {e}")))?;
            b
        }
        (None, Some(b)) => {
            if let Some(why) = super::uneven_cells(dims, &b) {
                log::warn!("{}: {why}", path.display());
            }
            b
        }
        (None, None) => {
            return Err(IoError::invalid(
                path,
                "a TIFF stack without an ImageJ calibration (pixel size, slice spacing) holds no box; give the scene \
                 whose box it fills",
            ))
        }
    };
    Ok(Volume::from_vec(dims, aabb, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(dims: [usize; 3], aabb: Aabb) -> Volume {
        let n = dims.iter().product::<usize>();
        Volume::from_vec(dims, aabb, (0..n).map(|i| (i as f32 * 0.37).sin() * 5.0).collect())
    }

    #[test]
    fn rationals_approximate_resolutions_to_double_precision() {
        for x in [1.0, 2.4, 1.0 / 0.41666666666666663, 96.0 / 40.0, 3.0e-4, 12345.678, std::f64::consts::PI] {
            let r = rational(x);
            let y = r.n as f64 / r.d as f64;
            assert!((y - x).abs() <= x * 1e-9, "{x}: {}/{} = {y}", r.n, r.d);
        }
        let r = rational(2.4);
        assert_eq!((r.n, r.d), (12, 5));
    }

    #[test]
    fn a_stack_round_trips_values_and_box() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.tif");
        let aabb = Aabb { min: DVec3::new(-20.0, -7.5, 3.0), max: DVec3::new(20.0, 12.5, 18.0) };
        let v = volume([16, 8, 6], aabb);
        write_tiff_stack(&p, &v, "mm").expect("write");
        let back = read_tiff_stack(&p, None, None).expect("read");
        assert_eq!(back.dims, v.dims);
        assert_eq!(back.data, v.data);
        for (a, b) in [(back.aabb.min, v.aabb.min), (back.aabb.max, v.aabb.max)] {
            assert!((a - b).abs().max_element() < 1e-9, "{a} vs {b}");
        }
        // A given box does not override the file's own.
        let other = Aabb { min: DVec3::ZERO, max: DVec3::ONE };
        assert!((read_tiff_stack(&p, Some(other), None).expect("read").aabb.min - aabb.min).length() < 1e-9);
    }

    #[test]
    fn a_bigtiff_stack_round_trips_as_the_classic_one() {
        let dir = tempfile::tempdir().expect("tempdir");
        let aabb = Aabb { min: DVec3::new(-1.0, 0.0, 2.0), max: DVec3::new(3.0, 1.5, 4.0) };
        let v = volume([8, 3, 4], aabb);
        let (classic, big) = (dir.path().join("c.tif"), dir.path().join("b.tif"));
        write_stack(&classic, &v, "mm", false).expect("classic");
        write_stack(&big, &v, "mm", true).expect("big");
        assert_eq!(&std::fs::read(&big).expect("bytes")[2..4], &43u16.to_le_bytes(), "BigTIFF's version number");
        for p in [classic, big] {
            let back = read_tiff_stack(&p, None, None).expect("read");
            assert_eq!((back.dims, &back.data), (v.dims, &v.data));
            assert!((back.aabb.max - aabb.max).abs().max_element() < 1e-9);
        }
    }

    #[test]
    fn a_single_slice_and_a_unit_imagej_does_not_spell_alike_round_trip() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.tif");
        let aabb = Aabb { min: DVec3::new(0.0, 0.0, 0.0), max: DVec3::new(3.0, 2.0, 0.5) };
        let v = volume([6, 4, 1], aabb);
        write_tiff_stack(&p, &v, "µm").expect("write");
        let back = read_tiff_stack(&p, None, None).expect("read");
        assert_eq!((back.dims, &back.data), (v.dims, &v.data));
        assert!((back.aabb.max - aabb.max).abs().max_element() < 1e-9);
        let text = String::from_utf8_lossy(&std::fs::read(&p).expect("bytes")).to_string();
        assert!(text.contains("unit=micron\n"), "{text}");
        assert_eq!(imagej_unit("m²"), "m\\u00B2");
    }

    /// A calibration in another length unit than the scene's is converted to the scene's
    /// (a stack in µm read into a scene in mm was a thousand times too large), one in a unit
    /// that does not convert is refused naming both, and ImageJ's `pixel` is no calibration.
    #[test]
    fn a_calibration_in_another_unit_is_converted_or_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let aabb = Aabb { min: DVec3::new(-200.0, 0.0, 100.0), max: DVec3::new(400.0, 300.0, 400.0) };
        let v = volume([6, 3, 3], aabb);
        let microns = dir.path().join("um.tif");
        write_tiff_stack(&microns, &v, "µm").expect("write");
        let mm = read_tiff_stack(&microns, None, Some("mm")).expect("read");
        for (a, b) in [(mm.aabb.min, aabb.min * 1e-3), (mm.aabb.max, aabb.max * 1e-3)] {
            assert!((a - b).abs().max_element() < 1e-12, "{a} vs {b}");
        }
        let same = read_tiff_stack(&microns, None, Some("µm")).expect("read");
        assert!((same.aabb.max - aabb.max).abs().max_element() < 1e-9, "{}", same.aabb.max);
        let furlongs = dir.path().join("f.tif");
        write_tiff_stack(&furlongs, &v, "furlong").expect("write");
        let err = read_tiff_stack(&furlongs, None, Some("mm")).expect_err("no conversion").to_string();
        assert!(
            err.contains("f.tif")
                && err.contains("its ImageJ calibration is in `furlong` and the scene's length unit is `mm`"),
            "{err}"
        );
        let pixels = dir.path().join("p.tif");
        write_tiff_stack(&pixels, &v, "pixel").expect("write");
        let given = Aabb::cube(DVec3::ZERO, 2.0);
        assert_eq!(read_tiff_stack(&pixels, Some(given), Some("mm")).expect("read").aabb, given);
    }

    #[test]
    fn pages_follow_each_other_as_imagej_reads_an_images_stack() {
        // ImageJ reads `images=N` pages as one block from the first page's strip; the pixels
        // of page k must sit k pages after it.
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.tif");
        let v = volume([5, 3, 4], Aabb::cube(DVec3::ZERO, 1.0));
        write_tiff_stack(&p, &v, "mm").expect("write");
        let bytes = std::fs::read(&p).expect("bytes");
        let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).expect("decoder");
        let first = dec.find_tag_unsigned::<u64>(Tag::StripOffsets).expect("tag").expect("offset") as usize;
        let block: Vec<f32> = bytes[first..first + v.data.len() * 4]
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        assert_eq!(block, v.data);
    }

    #[test]
    fn a_stack_without_calibration_fills_the_given_box_or_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("plain.tif");
        let mut f = std::fs::File::create(&p).expect("create");
        let mut enc = TiffEncoder::new(&mut f).expect("encoder");
        for k in 0..3u16 {
            let page: Vec<u16> = (0..12).map(|i| i + 100 * k).collect();
            enc.write_image::<tiff::encoder::colortype::Gray16>(4, 3, &page).expect("page");
        }
        drop(f);
        let err = read_tiff_stack(&p, None, None).expect_err("no box").to_string();
        assert!(err.contains("plain.tif") && err.contains("holds no box"), "{err}");
        let aabb = Aabb { min: DVec3::ZERO, max: DVec3::new(4.0, 3.0, 3.0) };
        let v = read_tiff_stack(&p, Some(aabb), None).expect("read");
        assert_eq!(v.dims, [4, 3, 3]);
        assert_eq!(v.get(1, 2, 2), (9 + 200) as f32);
        assert_eq!(v.aabb.max, aabb.max);
    }

    #[test]
    fn pages_of_other_sizes_and_colour_pages_are_refused_naming_the_page() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("mixed.tif");
        let mut f = std::fs::File::create(&p).expect("create");
        let mut enc = TiffEncoder::new(&mut f).expect("encoder");
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(4, 3, &[0.0; 12]).expect("page");
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(2, 3, &[0.0; 6]).expect("page");
        drop(f);
        let err = read_tiff_stack(&p, Some(Aabb::cube(DVec3::ZERO, 1.0)), None).expect_err("sizes").to_string();
        assert!(err.contains("page 2 is 2x3 pixels, page 1 4x3"), "{err}");
        let p = dir.path().join("rgb.tif");
        let mut f = std::fs::File::create(&p).expect("create");
        TiffEncoder::new(&mut f)
            .expect("encoder")
            .write_image::<tiff::encoder::colortype::RGB8>(2, 2, &[0; 12])
            .expect("page");
        drop(f);
        let err = read_tiff_stack(&p, Some(Aabb::cube(DVec3::ZERO, 1.0)), None).expect_err("colour").to_string();
        assert!(err.contains("page 1 is of colour type") && err.contains("greyscale"), "{err}");
    }

    /// Writes `pages` float pages of 2 × 2 ones, the first with the ImageJ `description` and,
    /// when given, a resolution of that many pixels per unit.
    fn write_imagej_pages(p: &Path, pages: usize, description: &str, per_unit: Option<u32>) {
        let mut f = std::fs::File::create(p).expect("create");
        let mut enc = TiffEncoder::new(&mut f).expect("encoder");
        for k in 0..pages {
            let mut page = enc.new_image::<tiff::encoder::colortype::Gray32Float>(2, 2).expect("page");
            if k == 0 {
                page.encoder().write_tag(Tag::ImageDescription, description).expect("description");
                if let Some(n) = per_unit {
                    page.resolution(tiff::tags::ResolutionUnit::None, Rational { n, d: 1 });
                }
            }
            page.write_data(&[1.0; 4]).expect("pixels");
        }
    }

    #[test]
    fn a_hyperstack_of_several_frames_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("frames.tif");
        write_imagej_pages(&p, 2, "ImageJ=1.54f\nimages=2\nchannels=1\nslices=1\nframes=2\nhyperstack=true\n", None);
        let err = read_tiff_stack(&p, Some(Aabb::cube(DVec3::ZERO, 1.0)), None).expect_err("frames").to_string();
        assert!(err.contains("frames.tif") && err.contains("1 channel(s) and 2 frame(s)"), "{err}");
        let c = parse_description("ImageJ=1.54f\nimages=3\nslices=3\nunit=mm\nspacing=0.5\nxorigin=-4\n\0");
        assert_eq!((c.imagej, c.spacing, c.origin[0], c.origin[1]), (true, Some(0.5), Some(-4.0), None));
    }

    #[test]
    fn an_imagej_stack_of_more_images_than_pages_is_refused() {
        // ImageJ saves a stack beyond 4 GiB with one directory, its other slices following the
        // first page's pixels: it was read as its first slice alone.
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("one.tif");
        write_imagej_pages(&p, 1, "ImageJ=1.54f\nimages=3\nslices=3\nunit=mm\nspacing=1.5\n", Some(1));
        let err = read_tiff_stack(&p, Some(Aabb::cube(DVec3::ZERO, 1.0)), None).expect_err("one page").to_string();
        assert!(
            err.contains("one.tif")
                && err.contains("its ImageJ description counts 3 images, but the file holds 1 page(s)"),
            "{err}"
        );
    }

    #[test]
    fn an_imagej_slice_spacing_that_is_no_depth_is_refused() {
        // A calibrated stack whose spacing is 0 (or no number) was stretched over the box given
        // as if it held no calibration, or refused as holding none.
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("flat.tif");
        write_imagej_pages(&p, 2, "ImageJ=1.54f\nimages=2\nslices=2\nunit=mm\nspacing=0\n", Some(2));
        for aabb in [None, Some(Aabb::cube(DVec3::ZERO, 1.0))] {
            let err = read_tiff_stack(&p, aabb, None).expect_err("spacing 0").to_string();
            assert!(
                err.contains("flat.tif")
                    && err.contains("its ImageJ calibration's slice spacing \"0\" is no positive depth"),
                "{err}"
            );
        }
    }

    /// Voxels of three different sides come back with each side on its own axis.
    #[test]
    fn a_stack_of_voxels_unlike_on_every_axis_keeps_each_axis_its_size() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.tif");
        // Voxels of 0.5 × 1.5 × 0.4.
        let aabb = Aabb { min: DVec3::new(1.0, -3.0, 0.2), max: DVec3::new(5.0, 0.0, 2.2) };
        let v = volume([8, 2, 5], aabb);
        write_tiff_stack(&p, &v, "mm").expect("write");
        let back = read_tiff_stack(&p, None, Some("mm")).expect("read");
        assert_eq!((back.dims, &back.data), (v.dims, &v.data));
        for (a, b) in [(back.aabb.min, aabb.min), (back.aabb.max, aabb.max)] {
            assert!((a - b).abs().max_element() < 1e-9, "{a} vs {b}");
        }
        let text = String::from_utf8_lossy(&std::fs::read(&p).expect("bytes")).to_string();
        assert!(text.contains("ImageJ=1.11a\nimages=5\nslices=5\nunit=mm\nspacing=0.4\n"), "{text}");
        assert!(text.contains(&format!("min={}\nmax={}\n", v.min_max().0, v.min_max().1)), "{text}");
        assert!(text.contains("xorigin=-2\nyorigin=2\nzorigin=-0.5"), "{text}");
        // One slice: no page count.
        let one = dir.path().join("one.tif");
        write_tiff_stack(&one, &volume([8, 2, 1], aabb), "mm").expect("write");
        let text = String::from_utf8_lossy(&std::fs::read(&one).expect("bytes")).to_string();
        assert!(text.contains("ImageJ=1.11a\nunit=mm\nspacing=2\n"), "{text}");
    }

    /// Every length unit known converts to every other by its size in metres.
    #[test]
    fn calibrations_convert_between_all_known_length_units() {
        let dir = tempfile::tempdir().expect("tempdir");
        let aabb = Aabb { min: DVec3::ZERO, max: DVec3::new(4.0, 2.0, 2.0) };
        let v = volume([4, 2, 2], aabb);
        for (from, to, factor) in [
            ("m", "mm", 1e3),
            ("cm", "mm", 10.0),
            ("nm", "µm", 1e-3),
            ("um", "nm", 1e3),
            ("mm", "m", 1e-3),
            ("micron", "cm", 1e-4),
        ] {
            let p = dir.path().join(format!("{from}.tif"));
            write_tiff_stack(&p, &v, from).expect("write");
            let back = read_tiff_stack(&p, None, Some(to)).expect("read");
            let expected = aabb.max * factor;
            assert!((back.aabb.max - expected).abs().max_element() < 1e-9 * factor, "{from} → {to}: {}", back.aabb.max);
        }
        assert_eq!(metres_per("\\u00B5m"), Some(1e-6), "ImageJ's escape of µm");
        assert_eq!(imagej_unit("um"), "micron");
        assert_eq!(imagej_unit("mm"), "mm");
    }

    /// One calibrated slice without a spacing is as deep as it is wide; several are refused
    /// the box from the calibration and fill the one given.
    #[test]
    fn a_single_calibrated_slice_without_a_spacing_is_as_deep_as_wide() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("one.tif");
        write_imagej_pages(&p, 1, "ImageJ=1.54f\nunit=mm\nxorigin=1\n", Some(4));
        let v = read_tiff_stack(&p, None, None).expect("read");
        assert_eq!(v.aabb, Aabb { min: DVec3::new(-0.25, 0.0, 0.0), max: DVec3::new(0.25, 0.5, 0.25) });
        let two = dir.path().join("two.tif");
        write_imagej_pages(&two, 2, "ImageJ=1.54f\nimages=2\nunit=mm\n", Some(4));
        let given = Aabb::cube(DVec3::ZERO, 1.0);
        assert_eq!(read_tiff_stack(&two, Some(given), None).expect("read").aabb, given);
        // Without the ImageJ mark the description is no calibration.
        let plain = dir.path().join("plain.tif");
        write_imagej_pages(&plain, 1, "unit=mm\nspacing=2\n", Some(4));
        assert_eq!(read_tiff_stack(&plain, Some(given), None).expect("read").aabb, given);
    }
}
