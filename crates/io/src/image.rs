//! Camera images as linear f32.
//!
//! # Reading
//! - 8- and 16-bit PNG, 8-bit JPEG (baseline and progressive), 8/16/32-bit integer and
//!   16/32/64-bit float TIFF (greyscale or RGB; CMYK, YCbCr and L*a*b* TIFFs are refused). The
//!   format is chosen by content, not by extension, but for LaVision DaVis images (`.im7`,
//!   `.imx`), which carry no signature: a file of one frame is read as stored (16-bit words,
//!   bytes or floats, see [`crate::davis`]); one of several frames (every camera of an
//!   instant) is refused here, since it is no one camera's image (`fluidnerf import` splits
//!   such files into the cameras' images).
//! - Values stay unscaled: integer images give their sensor counts as f32 (a 16-bit PNG pixel
//!   stored as 40000 reads as 40000.0, never normalised to [0, 1]); float TIFF values are
//!   returned as stored.
//! - 8-bit images (PNG, TIFF, JPEG) go through an explicit [`Linearisation`]: `linear` (the
//!   default: counts as stored), `srgb` (the sRGB transfer curve of IEC 61966-2-1 undone) or a
//!   gamma `g` (`count^g`), each keeping 255 at 255: `value = 255 · f(count / 255)`. Cameras
//!   that write JPEG almost always store sRGB-encoded values; scientific cameras store linear
//!   counts. 16-bit, 32-bit and float images are always read as linear, and DaVis images of
//!   any depth are the camera's counts as stored (like the frames of a cine or MRAW).
//! - TIFFs tagged `PhotometricInterpretation = WhiteIsZero` (tag 262 = 0: 0 is white, the
//!   stored values are a negative) are read as the TIFF standard defines when the samples are
//!   unsigned integers, `value = 2^bits − 1 − stored`, with one warning per run, since a
//!   radiometric camera writing this tag is unusual and an inverted measurement looks
//!   plausible. Float and signed samples have no maximum to invert from (a decoder would
//!   return `1 − v`, garbage for radiometric floats), so such TIFFs are refused naming the
//!   file and the tag.
//! - Colour images are reduced to luminance `Y = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709
//!   weights applied to the linearised values) with one warning per run; an alpha channel is
//!   dropped, with one warning per run when it is not fully opaque (alpha often marks pixels to
//!   leave out, which is a mask's job): PNG and JPEG, and TIFF alpha (`ExtraSamples` 1 or 2,
//!   or an RGBA or grey+alpha image without the tag) of unsigned or float samples.
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
use std::path::{Path, PathBuf};

use fluidnerf_core::Image;
use image::{DynamicImage, ImageEncoder};

use crate::{atomic_write, IoError};

/// How 8-bit pixel values become linear intensities (see the module docs). Written in scene
/// files and given on the command line as `"linear"`, `"srgb"` or a gamma such as `2.2`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Linearisation {
    /// Counts as stored.
    #[default]
    Linear,
    /// The sRGB transfer curve undone: `c ≤ 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055)^2.4`.
    Srgb,
    /// `c^gamma`, with `gamma` positive and finite.
    Gamma(f64),
}

impl Linearisation {
    /// The linear value of an 8-bit count, on the same 0..=255 scale.
    pub fn apply(self, count: u8) -> f32 {
        let c = f64::from(count) / 255.0;
        let linear = match self {
            Linearisation::Linear => return f32::from(count),
            Linearisation::Srgb if c <= 0.04045 => c / 12.92,
            Linearisation::Srgb => ((c + 0.055) / 1.055).powf(2.4),
            Linearisation::Gamma(g) => c.powf(g),
        };
        (255.0 * linear) as f32
    }

    /// The linear value of a code value `x` in `[0, 1]` (a video's range-mapped luma), on the
    /// 0..=255 scale of 8-bit counts.
    pub fn apply_unit(self, x: f64) -> f32 {
        let linear = match self {
            Linearisation::Linear => x,
            Linearisation::Srgb if x <= 0.04045 => x / 12.92,
            Linearisation::Srgb => ((x + 0.055) / 1.055).powf(2.4),
            Linearisation::Gamma(g) => x.powf(g),
        };
        (255.0 * linear) as f32
    }

    fn table(self) -> [f32; 256] {
        std::array::from_fn(|i| self.apply(i as u8))
    }
}

impl std::fmt::Display for Linearisation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Linearisation::Linear => f.write_str("linear"),
            Linearisation::Srgb => f.write_str("srgb"),
            Linearisation::Gamma(g) => write!(f, "gamma {g}"),
        }
    }
}

/// The gammas a linearisation takes: beyond them `(v/255)^γ` of an 8-bit value is 0 or 1 but
/// for a few levels, the images black or white.
const GAMMA_MIN: f64 = 0.1;
const GAMMA_MAX: f64 = 10.0;

impl std::str::FromStr for Linearisation {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "linear" => Ok(Linearisation::Linear),
            "srgb" => Ok(Linearisation::Srgb),
            other => match other.strip_prefix("gamma").unwrap_or(other).trim().parse::<f64>() {
                Ok(g) if (GAMMA_MIN..=GAMMA_MAX).contains(&g) => Ok(Linearisation::Gamma(g)),
                Ok(g) if g.is_finite() && g > 0.0 => Err(format!(
                    "`{s}` is a gamma outside {GAMMA_MIN}..{GAMMA_MAX}, which would leave an 8-bit image black or \
                     white but for a few levels; cameras encode with gammas of about 1.8 to 2.6"
                )),
                _ => Err(format!("`{s}` is not a linearisation: use linear, srgb or a positive gamma such as 2.2")),
            },
        }
    }
}

impl serde::Serialize for Linearisation {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Linearisation::Gamma(g) => s.serialize_f64(*g),
            other => s.serialize_str(&other.to_string()),
        }
    }
}

impl<'de> serde::Deserialize<'de> for Linearisation {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Name(String),
            Gamma(f64),
        }
        let text = match Raw::deserialize(d)? {
            Raw::Name(s) => s,
            Raw::Gamma(g) => g.to_string(),
        };
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// How the samples of an image file are stored: mixing kinds in one scene is refused (an 8-bit
/// image among 16-bit ones would read about 257 times too dark).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SampleKind {
    /// Integers of this many bits (signed or not).
    Integer(u8),
    /// 32- or 64-bit floats.
    Float,
}

impl SampleKind {
    /// "an 8-bit", "a 16-bit", "a floating-point": for messages.
    pub fn with_article(self) -> String {
        match self {
            SampleKind::Integer(8 | 11 | 18) => format!("an {self}"),
            _ => format!("a {self}"),
        }
    }

    /// The largest count of integer images (`2^bits − 1`, on the scale they are read on, 8-bit
    /// ones linearised included); None for floats, which have no full scale.
    pub fn full_scale(self) -> Option<f32> {
        match self {
            SampleKind::Integer(bits) => Some(((1u64 << bits.min(63)) - 1) as f32),
            SampleKind::Float => None,
        }
    }

    /// Pixels of `image` (read as this kind) at its full scale: saturated.
    pub fn saturated(self, image: &Image) -> usize {
        self.full_scale().map_or(0, |full| image.data.iter().filter(|&&v| v >= full).count())
    }
}

impl std::fmt::Display for SampleKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SampleKind::Integer(bits) => write!(f, "{bits}-bit"),
            SampleKind::Float => f.write_str("floating-point"),
        }
    }
}

/// Reads a PNG, JPEG, TIFF or DaVis image (chosen by content; DaVis by extension) as f32; 8-bit
/// values are taken as linear counts. See [`read_image_with`].
pub fn read_image(path: &Path) -> Result<Image, IoError> {
    read_image_with(path, Linearisation::Linear).map(|(image, _)| image)
}

/// Reads a PNG, JPEG, TIFF or DaVis image (chosen by content; DaVis by extension) as f32,
/// applying `linearisation` to 8-bit PNG, JPEG and TIFF samples, and says how its samples were
/// stored.
pub fn read_image_with(path: &Path, linearisation: Linearisation) -> Result<(Image, SampleKind), IoError> {
    let bytes = crate::read_input(path, "image file")?;
    decode_image(path, &bytes, linearisation)
}

/// [`read_image_with`] on bytes already in memory; `path` names them in errors.
pub fn decode_image(path: &Path, bytes: &[u8], linearisation: Linearisation) -> Result<(Image, SampleKind), IoError> {
    if is_tiff(bytes) {
        read_tiff(path, bytes, linearisation)
    } else if bytes.starts_with(PNG_MAGIC) {
        read_with_image_crate(path, bytes, image::ImageFormat::Png, linearisation)
    } else if bytes.starts_with(JPEG_MAGIC) {
        if jpeg_is_truncated(bytes) {
            return Err(IoError::invalid(
                path,
                format!(
                    "truncated JPEG: its {} bytes end before the end-of-image marker (a decoder would fill the \
                     missing part with grey)",
                    bytes.len()
                ),
            ));
        }
        read_with_image_crate(path, bytes, image::ImageFormat::Jpeg, linearisation)
    } else if crate::davis::is_davis_path(path) {
        let file = crate::davis::decode_davis(path, bytes)?;
        let kind = file.kind;
        one_davis_frame(path, file).map(|image| (image, kind))
    } else if bytes.is_empty() {
        // "Not a PNG" would send one looking for the wrong format.
        Err(IoError::invalid(path, "the image file is empty (0 bytes)"))
    } else {
        Err(IoError::invalid(
            path,
            "unreadable image: not a PNG, JPEG, TIFF or DaVis (.im7, .imx) file (supported: 8/16-bit PNG, 8-bit \
             JPEG, 8/16/32-bit and float TIFF, DaVis images of one frame)",
        ))
    }
}

/// The image of a DaVis file of one frame; a file of several (every camera of an instant, or
/// a double-frame exposure) is no one camera's image and is refused, saying what it holds.
fn one_davis_frame(path: &Path, mut file: crate::davis::DavisFile) -> Result<Image, IoError> {
    if file.frames.len() == 1 {
        return Ok(file.frames.remove(0));
    }
    let labels: Vec<String> =
        (0..file.frames.len()).map(|k| file.frame_label(k).map_or_else(|| "?".into(), |l| l.to_string())).collect();
    Err(IoError::invalid(
        path,
        format!(
            "a DaVis image of {} frames (cameras and exposures {} by its attributes), not one camera's image: give \
             `fluidnerf import` the folder of such files as --images, and it splits each into the cameras' images \
             (see docs/real-data.md)",
            file.frames.len(),
            labels.join(", ")
        ),
    ))
}

/// Whether a JPEG's bytes end before its end-of-image marker ([`jpeg_end`]): decoders fill the
/// missing blocks with grey and report no error.
pub(crate) fn jpeg_is_truncated(bytes: &[u8]) -> bool {
    jpeg_end(bytes) == JpegEnd::Truncated
}

/// What [`jpeg_end`] found.
#[derive(Debug, PartialEq, Eq)]
enum JpegEnd {
    /// The end-of-image marker, where the data say it is.
    Complete,
    /// The bytes ran out first.
    Truncated,
    /// A byte where a marker should be: left to the decoder, which tolerates some damage.
    Unparsed,
}

/// Walks a JPEG's marker segments and entropy-coded scans to its end-of-image marker. Decoders
/// fill a truncated file's missing blocks with grey and report no error, so a file cut short
/// (an interrupted copy, say) would otherwise be read as an image.
fn jpeg_end(b: &[u8]) -> JpegEnd {
    let mut i = 2; // after the start-of-image marker
    loop {
        match b.get(i) {
            None => return JpegEnd::Truncated,
            Some(0xFF) => {}
            Some(_) => return JpegEnd::Unparsed,
        }
        // Fill bytes (0xFF) may precede a marker's code.
        while b.get(i + 1) == Some(&0xFF) {
            i += 1;
        }
        let Some(&code) = b.get(i + 1) else { return JpegEnd::Truncated };
        i += 2;
        match code {
            0xD9 => return JpegEnd::Complete,
            0xD0..=0xD7 | 0x01 => continue,
            0x00 => return JpegEnd::Unparsed,
            _ => {}
        }
        let (Some(&hi), Some(&lo)) = (b.get(i), b.get(i + 1)) else { return JpegEnd::Truncated };
        let len = usize::from(u16::from_be_bytes([hi, lo]));
        if len < 2 {
            return JpegEnd::Unparsed;
        }
        i += len;
        if code == 0xDA {
            // The scan's data run to the next marker other than a stuffed 0xFF00 or a restart.
            loop {
                let Some(at) = b.get(i..).and_then(|rest| rest.iter().position(|&x| x == 0xFF)) else {
                    return JpegEnd::Truncated;
                };
                i += at;
                match b.get(i + 1) {
                    None => return JpegEnd::Truncated,
                    Some(0x00 | 0xD0..=0xD7) => i += 2,
                    Some(_) => break,
                }
            }
        }
    }
}

const PNG_MAGIC: &[u8] = b"\x89PNG\r\n\x1a\n";
const JPEG_MAGIC: &[u8] = b"\xff\xd8\xff";

fn is_tiff(bytes: &[u8]) -> bool {
    bytes.starts_with(b"II*\0")
        || bytes.starts_with(b"MM\0*")
        || bytes.starts_with(b"II+\0")
        || bytes.starts_with(b"MM\0+")
}

/// The size `(width, height)` of a PNG, JPEG, TIFF or DaVis image, read from its header only.
pub fn read_dimensions(path: &Path) -> Result<(u32, u32), IoError> {
    use std::io::Read;
    crate::check_regular_file(path, "image file")?;
    let mut file = std::fs::File::open(path).map_err(|e| IoError::io(path, "image file", e))?;
    let mut head = [0u8; 8];
    let n = file.read(&mut head).map_err(|e| IoError::io(path, "image file", e))?;
    let head = &head[..n];
    let reader = std::io::BufReader::new(std::fs::File::open(path).map_err(|e| IoError::io(path, "image file", e))?);
    if is_tiff(head) {
        let mut dec =
            tiff::decoder::Decoder::new(reader).map_err(|e| IoError::invalid(path, format!("unreadable TIFF: {e}")))?;
        dec.dimensions().map_err(|e| IoError::invalid(path, format!("unreadable TIFF: {e}")))
    } else if head.starts_with(PNG_MAGIC) || head.starts_with(JPEG_MAGIC) {
        image::ImageReader::new(reader)
            .with_guessed_format()
            .map_err(|e| IoError::io(path, "image file", e))?
            .into_dimensions()
            .map_err(|e| IoError::invalid(path, format!("unreadable image header: {e}")))
    } else if crate::davis::is_davis_path(path) {
        let mut head = Vec::new();
        let file = std::fs::File::open(path).map_err(|e| IoError::io(path, "image file", e))?;
        file.take(crate::davis::HEADER_LEN as u64)
            .read_to_end(&mut head)
            .map_err(|e| IoError::io(path, "image file", e))?;
        crate::davis::decode_dimensions(path, &head)
    } else if head.is_empty() {
        Err(IoError::invalid(path, "the image file is empty (0 bytes)"))
    } else {
        Err(IoError::invalid(path, "unreadable image: not a PNG, JPEG, TIFF or DaVis (.im7, .imx) file"))
    }
}

/// Extensions of the image files fluidnerf reads (lower case); DaVis's last.
pub const IMAGE_EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "tif", "tiff", "im7", "imx"];

/// Whether `p` is named like an image fluidnerf reads (its extension in any case).
pub fn has_image_extension(p: &Path) -> bool {
    p.extension().and_then(|e| e.to_str()).is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// For an image path that names no file, the one image file in the same folder with the same
/// name stem and another (or no) extension: `r_0` or `r_0.jpg` finds `r_0.png`. `Ok(None)` when
/// there is none or the folder cannot be listed; an error naming the candidates when there are
/// several.
pub fn find_image_by_stem(path: &Path) -> Result<Option<PathBuf>, String> {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else { return Ok(None) };
    // `frame.0001` has no image extension: its whole name is the stem.
    let stem = if has_image_extension(path) { path.file_stem().unwrap_or(name) } else { name };
    let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let Ok(entries) = std::fs::read_dir(dir) else { return Ok(None) };
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| has_image_extension(p) && p.file_stem() == Some(stem) && p.is_file())
        .collect();
    found.sort();
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => Err(format!(
            "{} names no file, and several images share its stem: {}",
            path.display(),
            found.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        )),
    }
}

fn read_with_image_crate(
    path: &Path,
    bytes: &[u8],
    format: image::ImageFormat,
    linearisation: Linearisation,
) -> Result<(Image, SampleKind), IoError> {
    let name = if format == image::ImageFormat::Png { "PNG" } else { "JPEG" };
    if format == image::ImageFormat::Jpeg {
        warn_of_exif_orientation(path, bytes);
    }
    let img = image::load_from_memory_with_format(bytes, format)
        .map_err(|e| IoError::invalid(path, format!("unreadable {name}: {e}")))?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    let lut = linearisation.table();
    let lin = |v: Vec<u8>| -> Vec<f32> { v.into_iter().map(|c| lut[usize::from(c)]).collect() };
    let kind = if matches!(
        img,
        DynamicImage::ImageLuma8(_)
            | DynamicImage::ImageLumaA8(_)
            | DynamicImage::ImageRgb8(_)
            | DynamicImage::ImageRgba8(_)
    ) {
        SampleKind::Integer(8)
    } else {
        SampleKind::Integer(16)
    };
    let (channels, data): (usize, Vec<f32>) = match img {
        DynamicImage::ImageLuma8(b) => (1, lin(b.into_raw())),
        DynamicImage::ImageLumaA8(b) => (2, lin(b.into_raw())),
        DynamicImage::ImageRgb8(b) => (3, lin(b.into_raw())),
        DynamicImage::ImageRgba8(b) => (4, lin(b.into_raw())),
        DynamicImage::ImageLuma16(b) => (1, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageLumaA16(b) => (2, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageRgb16(b) => (3, b.into_raw().into_iter().map(f32::from).collect()),
        DynamicImage::ImageRgba16(b) => (4, b.into_raw().into_iter().map(f32::from).collect()),
        other => return Err(IoError::invalid(path, format!("unsupported {name} pixel type {:?}", other.color()))),
    };
    if w * h == 0 {
        return Err(IoError::invalid(path, format!("{name} of {w}x{h} pixels is empty")));
    }
    // Alpha reads through the same table as the values: full opacity is the largest count.
    let opaque = if kind == SampleKind::Integer(8) { lut[255] } else { f32::from(u16::MAX) };
    warn_of_alpha(path, channels, &data, opaque);
    Ok((to_gray(path, w, h, channels, data, Some(opaque)), kind))
}

/// Reads the first page of a TIFF. `WhiteIsZero` images are inverted as the standard defines
/// for unsigned integers (with a warning) and refused for float and signed samples, which have
/// no maximum to invert from: see [`check_white_is_zero`].
fn read_tiff(path: &Path, bytes: &[u8], linearisation: Linearisation) -> Result<(Image, SampleKind), IoError> {
    use tiff::decoder::{Decoder, DecodingResult};
    use tiff::ColorType;
    let bad = |e: tiff::TiffError| IoError::invalid(path, format!("unreadable TIFF: {e}"));
    let mut dec = Decoder::new(Cursor::new(bytes)).map_err(bad)?;
    let (w, h) = dec.dimensions().map_err(bad)?;
    let (w, h) = (w as usize, h as usize);
    // Refuse before decoding: a corrupt header can claim an absurd size.
    if w.checked_mul(h).is_none_or(|n| n == 0 || n > 1 << 30) {
        return Err(IoError::invalid(path, format!("TIFF claims {w}x{h} pixels")));
    }
    // Grey (with extra samples, which are dropped) and RGB are read; the samples of other
    // colour models (CMYK, YCbCr, CIE L*a*b*) would be taken for RGB and give garbage.
    let colortype = dec.colortype().map_err(bad)?;
    // Samples of other widths come back packed (1, 2, 4 bits: several pixels to a byte, read
    // as too few samples) or are refused by the decoder with its own words (10, 12, 14 bits).
    let bits = colortype.bit_depth();
    if ![8, 16, 32, 64].contains(&bits) {
        return Err(IoError::invalid(
            path,
            format!(
                "a TIFF of {bits} bit(s) per sample, which fluidnerf does not read (8, 16 or 32-bit integers, 16, 32 \
                 or 64-bit floats): write the image, or the mask, with 8 or 16 bits per sample (a 10 to 14-bit camera's \
                 counts go into 16-bit samples as they are)"
            ),
        ));
    }
    let grey = match colortype {
        ColorType::Gray(_) | ColorType::GrayA(_) | ColorType::Multiband { .. } => true,
        ColorType::RGB(_) | ColorType::RGBA(_) => false,
        other => {
            let model = match other {
                ColorType::CMYK(_) | ColorType::CMYKA(_) => "CMYK",
                ColorType::YCbCr(_) => "YCbCr",
                ColorType::Lab(_) => "CIE L*a*b*",
                ColorType::Palette(_) => "palette",
                _ => "unknown",
            };
            return Err(IoError::invalid(
                path,
                format!(
                    "a TIFF of the {model} colour model, which fluidnerf does not convert; write the image as \
                     greyscale (or RGB)"
                ),
            ));
        }
    };
    check_white_is_zero(path, &mut dec)?;
    // ExtraSamples (338): 1 associated, 2 unassociated alpha; 0 (unspecified) is not alpha.
    // Without the tag, the decoder's reading of a fourth (or second) sample as alpha stands.
    let extra = dec.find_tag_unsigned_vec::<u16>(tiff::tags::Tag::ExtraSamples).map_err(bad)?.unwrap_or_default();
    let alpha = match extra.as_slice() {
        [] => matches!(colortype, ColorType::RGBA(_) | ColorType::GrayA(_)),
        kinds => matches!(kinds, [1] | [2]),
    };
    let lut = linearisation.table();
    // `read_image` reads the first plane alone of a planar (`PlanarConfiguration` 2) image: the
    // red of an RGB picture, taken silently for its grey. All planes are read here and then
    // interleaved as a chunky image's samples are.
    let mut decoded = DecodingResult::U8(Vec::new());
    let layout = dec.read_image_to_buffer(&mut decoded).map_err(bad)?;
    if decoded.as_buffer(0).as_bytes().len() < layout.complete_len {
        return Err(IoError::invalid(
            path,
            format!(
                "a planar TIFF of {} planes too large to read whole ({} bytes); write it with its samples \
                 interleaved (PlanarConfiguration 1), or as greyscale",
                layout.planes, layout.complete_len
            ),
        ));
    }
    // Full opacity as the samples read: the largest count (through the table for 8 bits), 1 for
    // floats; signed samples have none.
    let opaque = match &decoded {
        DecodingResult::U8(_) => Some(lut[255]),
        DecodingResult::U16(_) => Some(f32::from(u16::MAX)),
        DecodingResult::U32(_) => Some(u32::MAX as f32),
        DecodingResult::F16(_) | DecodingResult::F32(_) | DecodingResult::F64(_) => Some(1.0),
        _ => None,
    };
    let (data, kind): (Vec<f32>, SampleKind) = match decoded {
        DecodingResult::U8(v) => (v.into_iter().map(|c| lut[usize::from(c)]).collect(), SampleKind::Integer(8)),
        DecodingResult::U16(v) => (v.into_iter().map(f32::from).collect(), SampleKind::Integer(16)),
        DecodingResult::U32(v) => (v.into_iter().map(|x| x as f32).collect(), SampleKind::Integer(32)),
        DecodingResult::F16(v) => (v.into_iter().map(f32::from).collect(), SampleKind::Float),
        DecodingResult::F32(v) => (v, SampleKind::Float),
        DecodingResult::F64(v) => (v.into_iter().map(|x| x as f32).collect(), SampleKind::Float),
        DecodingResult::I8(v) => (v.into_iter().map(f32::from).collect(), SampleKind::Integer(8)),
        DecodingResult::I16(v) => (v.into_iter().map(f32::from).collect(), SampleKind::Integer(16)),
        DecodingResult::I32(v) => (v.into_iter().map(|x| x as f32).collect(), SampleKind::Integer(32)),
        _ => {
            return Err(IoError::invalid(
                path,
                "unsupported TIFF sample type (use 8/16/32-bit integers or 16/32/64-bit floats)",
            ))
        }
    };
    let pixels = w * h;
    if pixels == 0 || data.len() % pixels != 0 || data.len() / pixels > 4 {
        return Err(IoError::invalid(path, format!("TIFF of {w}x{h} pixels holds {} samples", data.len())));
    }
    let data = if layout.planes > 1 && data.len() == pixels * layout.planes {
        let planes = layout.planes;
        (0..pixels * planes).map(|i| data[(i % planes) * pixels + i / planes]).collect()
    } else {
        data
    };
    // Further pages of the same size are a stack (frames, or a z-stack), not one image: reading
    // the first alone would lose the rest silently. Smaller pages (thumbnails, a pyramid's
    // reduced levels) are skipped.
    let mut stacked = 0usize;
    while dec.more_images() && stacked < 1 << 16 {
        dec.next_image().map_err(bad)?;
        if dec.dimensions().map_err(bad)? == (w as u32, h as u32) {
            stacked += 1;
        }
    }
    if stacked > 0 {
        return Err(IoError::invalid(
            path,
            format!(
                "a TIFF stack: {} more page(s) of {w}x{h} pixels after the first; fluidnerf reads one image per \
                 file: write each page to a file of its own (one per camera, or per frame of a recording)",
                stacked
            ),
        ));
    }
    let channels = data.len() / pixels;
    let with_alpha = if grey { 2 } else { 4 };
    if let Some(opaque) = opaque.filter(|_| alpha && channels == with_alpha) {
        warn_of_alpha(path, channels, &data, opaque);
    }
    if grey && channels > 1 {
        log::debug!("{}: dropping {} extra sample(s) per pixel", path.display(), channels - 1);
        return Ok((Image::from_vec(w, h, data.chunks_exact(channels).map(|p| p[0]).collect()), kind));
    }
    // Integer samples have a full scale; floats none.
    let full = opaque.filter(|_| kind.full_scale().is_some());
    Ok((to_gray(path, w, h, channels, data, full), kind))
}

/// Refuses the `WhiteIsZero` TIFFs (tag 262, PhotometricInterpretation, = 0) that cannot be
/// read as light, and warns once per run about the others.
///
/// For unsigned integer samples the standard's reading, `2^bits − 1 − stored`, is exact and is
/// what the decoder returns: it is kept, but a radiometric camera writing a negative is unusual
/// and an inverted measurement still looks plausible, so the user is told. Float samples have
/// no maximum: the decoder would return `1 − v`, which is garbage unless the image happened to
/// be normalised to [0, 1]; signed samples have no defined inversion; grey with extra samples
/// is not inverted by the decoder at all. These are refused naming the file and the tag.
fn check_white_is_zero<R: std::io::Read + std::io::Seek>(
    path: &Path,
    dec: &mut tiff::decoder::Decoder<R>,
) -> Result<(), IoError> {
    use tiff::tags::Tag;
    let bad = |e: tiff::TiffError| IoError::invalid(path, format!("unreadable TIFF: {e}"));
    const WHITE_IS_ZERO: u16 = 0;
    if dec.find_tag_unsigned::<u16>(Tag::PhotometricInterpretation).map_err(bad)? != Some(WHITE_IS_ZERO) {
        return Ok(());
    }
    let refuse = |what: &str| {
        IoError::invalid(
            path,
            format!(
                "TIFF tag PhotometricInterpretation (262) is WhiteIsZero (0, a negative) with {what}, which has no \
                 maximum to invert from; write the image as BlackIsZero (1) with its values as measured"
            ),
        )
    };
    // SampleFormat (339): 1 unsigned (the default), 2 signed, 3 float; one value per sample.
    let formats = dec.find_tag_unsigned_vec::<u16>(Tag::SampleFormat).map_err(bad)?.unwrap_or_default();
    if formats.contains(&3) {
        return Err(refuse("floating-point samples"));
    }
    if formats.iter().any(|&f| f != 1) {
        return Err(refuse("signed (or undefined) integer samples"));
    }
    let samples = dec.find_tag_unsigned::<u16>(Tag::SamplesPerPixel).map_err(bad)?.unwrap_or(1);
    if samples > 1 {
        return Err(IoError::invalid(
            path,
            format!(
                "TIFF tag PhotometricInterpretation (262) is WhiteIsZero (0, a negative) with {samples} samples per \
                 pixel, which the decoder does not invert; write the image as BlackIsZero (1) greyscale"
            ),
        ));
    }
    // Datasets hold hundreds of images: say it once per run, not once per file.
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        log::warn!(
            "{}: TIFF tag PhotometricInterpretation is WhiteIsZero (a negative): its counts are read inverted, \
             as the TIFF standard defines (2^bits − 1 − stored); check the camera meant it, since an inverted \
             measurement still looks plausible; further such images are not reported",
            path.display()
        );
    }
    Ok(())
}

/// The EXIF orientation of a JPEG other than "as stored", if it has one: a camera held on its
/// side writes its pixels as the sensor reads them and a tag telling viewers to turn them.
pub fn exif_orientation(bytes: &[u8]) -> Option<image::metadata::Orientation> {
    use image::ImageDecoder as _;
    let mut decoder = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(bytes)).ok()?;
    decoder.orientation().ok().filter(|o| *o != image::metadata::Orientation::NoTransforms)
}

/// Warns (once per run) of a JPEG whose EXIF orientation turns or flips it for display:
/// fluidnerf reads the pixels as stored, while tools that show the picture turned (OpenCV's
/// `imread` among them) calibrate the turned picture, which a square image does not reveal.
fn warn_of_exif_orientation(path: &Path, bytes: &[u8]) {
    let Some(orientation) = exif_orientation(bytes) else { return };
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        log::warn!(
            "{}: its EXIF orientation asks viewers to show it turned or flipped ({orientation:?}); fluidnerf reads \
             the pixels as stored, so the camera's calibration must be of the stored picture (OpenCV's imread \
             turns it unless given IMREAD_IGNORE_ORIENTATION); further such images are not reported",
            path.display()
        );
    }
}

/// How many pixels of interleaved samples with `channels` per pixel (2 gray+alpha, 4 RGBA)
/// are less than fully opaque (alpha below `opaque`); 0 without an alpha channel.
fn translucent_pixels(channels: usize, data: &[f32], opaque: f32) -> usize {
    if !matches!(channels, 2 | 4) {
        return 0;
    }
    data.chunks_exact(channels).filter(|p| p[channels - 1] < opaque).count()
}

/// Warns (once per run) of an image whose alpha channel is not fully opaque: alpha often marks
/// the pixels to leave out, and fluidnerf drops it, using every pixel as measured.
fn warn_of_alpha(path: &Path, channels: usize, data: &[f32], opaque: f32) {
    let translucent = translucent_pixels(channels, data, opaque);
    if translucent == 0 {
        return;
    }
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    if !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        log::warn!(
            "{}: its alpha channel is not fully opaque ({translucent} of {} pixels), and fluidnerf ignores alpha: \
             every pixel is used as measured. If the alpha marks pixels to leave out, give them as a mask \
             (`mask_path` in transforms.json); further such images are not reported",
            path.display(),
            data.len() / channels
        );
    }
}

/// Interleaved samples with `channels` per pixel (1 gray, 2 gray+alpha, 3 RGB, 4 RGBA) to gray.
/// `full`: the samples' full scale (integer samples), at which a colour channel is clipped.
fn to_gray(path: &Path, w: usize, h: usize, channels: usize, data: Vec<f32>, full: Option<f32>) -> Image {
    match channels {
        1 => Image::from_vec(w, h, data),
        2 => {
            log::debug!("{}: dropping the alpha channel", path.display());
            Image::from_vec(w, h, data.chunks_exact(2).map(|p| p[0]).collect())
        }
        _ => {
            // Datasets hold hundreds of colour images: say it once per run, not once per file.
            static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
            if !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
                log::warn!(
                    "{}: colour images are reduced to luminance (0.2126 R + 0.7152 G + 0.0722 B of the \
                     linearised values; alpha dropped); further colour images are not reported",
                    path.display()
                );
            }
            // A channel at full scale was clipped, though the luminance, below full scale, is not
            // counted as saturated: a red dye or flame at R = 255 reads as 54 and passed unseen.
            if let Some(full) = full {
                let clipped = data.chunks_exact(channels).filter(|p| p[..3].iter().any(|&c| c >= full)).count();
                static WARNED_CLIPPED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
                if clipped > 0 && !WARNED_CLIPPED.swap(true, std::sync::atomic::Ordering::Relaxed) {
                    log::warn!(
                        "{}: {clipped} pixel(s) have a colour channel at full scale, clipped in that channel: their \
                         luminance, below full scale, is not counted as saturated, but the line-integral model does \
                         not hold there; mask them (mask_path) or record with less exposure; further colour images \
                         with clipped channels are not reported",
                        path.display()
                    );
                }
            }
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

/// Writes an 8-bit grayscale JPEG of `value / full_scale` through the sRGB transfer curve
/// (what a camera's JPEG holds), clamped to `[0, 255]`: reading it back with
/// [`Linearisation::Srgb`] gives `value × 255 / full_scale` up to quantisation and compression.
/// `quality` is 1..=100. Non-finite values are an error.
pub fn write_jpeg_srgb(path: &Path, image: &Image, full_scale: f32, quality: u8) -> Result<(), IoError> {
    assert!(full_scale.is_finite() && full_scale > 0.0, "write_jpeg_srgb: full_scale must be positive");
    check_finite(path, image)?;
    let encode = |x: f64| if x <= 0.0031308 { 12.92 * x } else { 1.055 * x.powf(1.0 / 2.4) - 0.055 };
    let counts: Vec<u8> = image
        .data
        .iter()
        .map(|&v| (255.0 * encode((f64::from(v) / f64::from(full_scale)).clamp(0.0, 1.0))).round() as u8)
        .collect();
    atomic_write(path, |w| {
        image::codecs::jpeg::JpegEncoder::new_with_quality(w, quality.clamp(1, 100))
            .write_image(&counts, image.width as u32, image.height as u32, image::ExtendedColorType::L8)
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

    /// Fully opaque pixels are the largest count through the reading's table (8-bit) or 65535
    /// (16-bit); any lower alpha is counted, and images without alpha count none.
    #[test]
    fn translucent_pixels_are_counted_against_full_opacity() {
        let lut = Linearisation::Srgb.table();
        let grey_alpha = [lut[10], lut[255], lut[200], lut[254], lut[0], lut[0]];
        assert_eq!(translucent_pixels(2, &grey_alpha, lut[255]), 2);
        let rgba16 = [1.0, 2.0, 3.0, 65535.0, 4.0, 5.0, 6.0, 65534.0];
        assert_eq!(translucent_pixels(4, &rgba16, f32::from(u16::MAX)), 1);
        assert_eq!(translucent_pixels(3, &[0.0; 6], 1.0), 0);
        assert_eq!(translucent_pixels(1, &[0.0; 6], 1.0), 0);
    }

    /// A grey+alpha PNG is read as its grey values, the alpha left out.
    #[test]
    fn a_grey_and_alpha_png_reads_its_grey_values() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("ga.png");
        let pixels: Vec<u8> = [(7u8, 255u8), (9, 0), (11, 128), (13, 255)].iter().flat_map(|&(v, a)| [v, a]).collect();
        image::GrayAlphaImage::from_raw(2, 2, pixels).expect("2x2").save(&path).expect("writes");
        let (image, kind) = read_image_with(&path, Linearisation::Linear).expect("reads");
        assert_eq!(kind, SampleKind::Integer(8));
        assert_eq!(image.data, [7.0, 9.0, 11.0, 13.0]);
    }

    #[test]
    fn gammas_are_taken_within_their_range_and_refused_beyond_it() {
        for (text, gamma) in [("2.2", 2.2), ("gamma 1.8", 1.8), ("0.1", 0.1), ("10", 10.0)] {
            assert_eq!(text.parse::<Linearisation>(), Ok(Linearisation::Gamma(gamma)), "{text}");
        }
        for text in ["1e308", "1e-308", "0.05", "11"] {
            let e = text.parse::<Linearisation>().expect_err(text);
            assert!(e.contains(&format!("`{text}` is a gamma outside 0.1..10")), "{e}");
        }
        for text in ["0", "-1", "nan", "inf", "log"] {
            let e = text.parse::<Linearisation>().expect_err(text);
            assert!(e.contains("is not a linearisation"), "{e}");
        }
    }

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

    /// A stack of pages of one size is refused by name; a smaller page after the image (a
    /// thumbnail) is not a stack.
    #[test]
    fn tiff_stacks_are_refused_and_thumbnails_skipped() {
        let dir = tempfile::tempdir().expect("tempdir");
        let write = |pages: &[(u32, u32)]| {
            let mut f = std::io::Cursor::new(Vec::new());
            let mut enc = tiff::encoder::TiffEncoder::new(&mut f).expect("encoder");
            for &(w, h) in pages {
                let data: Vec<u16> = (0..w * h).map(|i| i as u16).collect();
                enc.write_image::<tiff::encoder::colortype::Gray16>(w, h, &data).expect("page");
            }
            let p = dir.path().join(format!("{}.tif", pages.len()));
            std::fs::write(&p, f.into_inner()).expect("write");
            p
        };
        let stack = write(&[(4, 3), (4, 3), (4, 3)]);
        let err = read_image(&stack).expect_err("a stack").to_string();
        assert!(err.contains("3.tif") && err.contains("2 more page(s) of 4x3"), "{err}");
        let thumbnail = write(&[(4, 3), (2, 1)]);
        let img = read_image(&thumbnail).expect("image and thumbnail");
        assert_eq!((img.width, img.height, img.get(3, 2)), (4, 3, 11.0));
    }

    /// A little-endian TIFF of `w`×`h` pixels of `samples` 8-bit samples each (interleaved),
    /// photometric interpretation `photometric`, written by hand: the encoder writes no grey
    /// image with extra samples.
    fn tiff_by_hand(w: u32, h: u32, samples: u16, photometric: u16, data: &[u8]) -> Vec<u8> {
        tiff_by_hand_as(w, h, samples, (8, 1), photometric, data)
    }

    /// [`tiff_by_hand`] with `(bits, format)` per sample: SampleFormat 1 unsigned, 2 signed,
    /// 3 float; `data` holds the samples' little-endian bytes.
    fn tiff_by_hand_as(
        w: u32,
        h: u32,
        samples: u16,
        (bits, format): (u16, u16),
        photometric: u16,
        data: &[u8],
    ) -> Vec<u8> {
        let mut b = b"II*\0".to_vec();
        b.extend((8 + data.len() as u32).to_le_bytes());
        b.extend(data);
        let mut entries: Vec<(u16, u16, u32)> = vec![
            (256, 4, w),
            (257, 4, h),
            (258, 3, u32::from(bits)),
            (259, 3, 1),
            (262, 3, u32::from(photometric)),
            (273, 4, 8),
            (277, 3, u32::from(samples)),
            (278, 4, h),
            (279, 4, data.len() as u32),
        ];
        if format != 1 {
            entries.push((339, 3, u32::from(format)));
        }
        b.extend((entries.len() as u16).to_le_bytes());
        for (tag, kind, value) in entries {
            b.extend(tag.to_le_bytes());
            b.extend(kind.to_le_bytes());
            b.extend(1u32.to_le_bytes());
            if kind == 3 {
                b.extend((value as u16).to_le_bytes());
                b.extend([0, 0]);
            } else {
                b.extend(value.to_le_bytes());
            }
        }
        b.extend(0u32.to_le_bytes());
        b
    }

    /// An RGB TIFF of `w`×`h` 8-bit pixels stored plane by plane (PlanarConfiguration 2: all
    /// red samples, then green, then blue, one strip per plane), written by hand: the encoder
    /// writes chunky images only.
    fn planar_rgb_tiff(w: u32, h: u32, planes: [&[u8]; 3]) -> Vec<u8> {
        let plane = w * h;
        let mut b = b"II*\0".to_vec();
        let ifd = 8 + 3 * plane + 12 + 12 + 6;
        b.extend(ifd.to_le_bytes());
        for p in planes {
            assert_eq!(p.len(), plane as usize);
            b.extend(p);
        }
        let offsets = 8 + 3 * plane;
        b.extend([8, 8 + plane, 8 + 2 * plane].iter().flat_map(|o| o.to_le_bytes()));
        b.extend([plane; 3].iter().flat_map(|c| c.to_le_bytes()));
        b.extend([8u16; 3].iter().flat_map(|c| c.to_le_bytes()));
        let entries: [(u16, u16, u32, u32); 10] = [
            (256, 4, 1, w),
            (257, 4, 1, h),
            (258, 3, 3, offsets + 24),
            (259, 3, 1, 1),
            (262, 3, 1, 2),
            (273, 4, 3, offsets),
            (277, 3, 1, 3),
            (278, 4, 1, h),
            (279, 4, 3, offsets + 12),
            (284, 3, 1, 2),
        ];
        b.extend((entries.len() as u16).to_le_bytes());
        for (tag, kind, count, value) in entries {
            b.extend(tag.to_le_bytes());
            b.extend(kind.to_le_bytes());
            b.extend(count.to_le_bytes());
            b.extend(if kind == 3 && count == 1 { u32::from(value as u16) } else { value }.to_le_bytes());
        }
        b.extend(0u32.to_le_bytes());
        b
    }

    /// A planar RGB TIFF was read as its red plane alone, taken for a grey image without a
    /// word; its three planes now give the luminance a chunky RGB TIFF gives.
    #[test]
    fn planar_rgb_tiffs_read_every_plane() {
        let (red, green, blue) = ([100u8, 0, 0, 0], [0u8, 100, 0, 0], [0u8, 0, 100, 200]);
        let bytes = planar_rgb_tiff(2, 2, [&red, &green, &blue]);
        let (img, kind) = decode_image(Path::new("planar.tif"), &bytes, Linearisation::Linear).expect("planar RGB");
        assert_eq!(kind, SampleKind::Integer(8));
        let expected = [21.26f32, 71.52, 7.22, 14.44];
        assert!(img.data.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-3), "{:?}", img.data);
    }

    /// 16-bit float samples (SampleFormat 3), as written by HDR and machine-vision tools, were
    /// refused as an "unsupported TIFF sample type"; they are read as the floats they hold.
    #[test]
    fn half_float_tiffs_are_read() {
        struct GrayF16;
        impl tiff::encoder::colortype::ColorType for GrayF16 {
            type Inner = u16;
            const TIFF_VALUE: tiff::tags::PhotometricInterpretation =
                tiff::tags::PhotometricInterpretation::BlackIsZero;
            const BITS_PER_SAMPLE: &'static [u16] = &[16];
            const SAMPLE_FORMAT: &'static [tiff::tags::SampleFormat] = &[tiff::tags::SampleFormat::IEEEFP];
            fn horizontal_predict(row: &[u16], result: &mut Vec<u16>) {
                result.extend_from_slice(row);
            }
        }
        // IEEE 754 half precision: 0, 0.5, 1, 1.5 and 65504 (the largest finite half).
        let halves = [0x0000u16, 0x3800, 0x3c00, 0x3e00, 0x7bff, 0x0000];
        let mut bytes = Cursor::new(Vec::new());
        tiff::encoder::TiffEncoder::new(&mut bytes)
            .expect("encoder")
            .write_image::<GrayF16>(3, 2, &halves)
            .expect("half floats");
        let (img, kind) =
            decode_image(Path::new("half.tif"), bytes.get_ref(), Linearisation::Linear).expect("reads half floats");
        assert_eq!(kind, SampleKind::Float);
        assert_eq!(img.data, vec![0.0, 0.5, 1.0, 1.5, 65504.0, 0.0]);
    }

    /// Grey samples with extra ones keep the grey one; CMYK and YCbCr samples, which would be
    /// taken for RGB, are refused naming the colour model.
    #[test]
    fn tiff_colour_models_other_than_grey_and_rgb_are_refused() {
        let p = Path::new("model.tif");
        let grey_extra: Vec<u8> = (0..6u8).flat_map(|i| [10 * i, 200, 255]).collect();
        let (img, kind) =
            decode_image(p, &tiff_by_hand(3, 2, 3, 1, &grey_extra), Linearisation::Linear).expect("grey and extras");
        assert_eq!((img.data, kind), (vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0], SampleKind::Integer(8)));
        let mut cmyk = Cursor::new(Vec::new());
        tiff::encoder::TiffEncoder::new(&mut cmyk)
            .expect("encoder")
            .write_image::<tiff::encoder::colortype::CMYK8>(2, 2, &[0u8, 0, 0, 255].repeat(4))
            .expect("CMYK");
        let err = decode_image(p, cmyk.get_ref(), Linearisation::Linear).expect_err("CMYK").to_string();
        assert!(err.contains("model.tif") && err.contains("CMYK colour model"), "{err}");
        let ycbcr = tiff_by_hand(2, 1, 3, 6, &[128, 128, 128, 200, 128, 128]);
        let err = decode_image(p, &ycbcr, Linearisation::Linear).expect_err("YCbCr").to_string();
        assert!(err.contains("model.tif") && err.contains("YCbCr colour model"), "{err}");
    }

    /// Samples of 1, 2 or 4 bits came back packed and were refused as a TIFF holding "2 samples"
    /// for its 8 pixels; 12-bit ones with the decoder's "color type Gray(12) is unsupported".
    /// Both are now refused saying how many bits the TIFF has and what is read.
    /// A JPEG with an APP1 EXIF segment after its start-of-image marker, whose IFD0 holds the
    /// orientation tag (274) with `value`, written by hand as a camera writes it.
    fn jpeg_with_orientation(value: u16) -> Vec<u8> {
        let mut plain = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut plain)
            .encode(&[0u8; 64], 8, 8, image::ExtendedColorType::L8)
            .expect("encodes");
        let mut tiff = b"II*\0\x08\0\0\0".to_vec();
        tiff.extend_from_slice(&1u16.to_le_bytes()); // one entry
        tiff.extend_from_slice(&274u16.to_le_bytes()); // Orientation
        tiff.extend_from_slice(&3u16.to_le_bytes()); // SHORT
        tiff.extend_from_slice(&1u32.to_le_bytes()); // one value
        tiff.extend_from_slice(&value.to_le_bytes());
        tiff.extend_from_slice(&[0, 0, 0, 0, 0, 0]); // padding, no next IFD
        let mut app1 = b"Exif\0\0".to_vec();
        app1.extend_from_slice(&tiff);
        let mut out = plain[..2].to_vec();
        out.extend_from_slice(&[0xff, 0xe1]);
        out.extend_from_slice(&u16::try_from(app1.len() + 2).expect("short").to_be_bytes());
        out.extend_from_slice(&app1);
        out.extend_from_slice(&plain[2..]);
        out
    }

    #[test]
    fn a_jpegs_exif_orientation_is_found() {
        use image::metadata::Orientation;
        assert_eq!(exif_orientation(&jpeg_with_orientation(6)), Some(Orientation::Rotate90));
        assert_eq!(exif_orientation(&jpeg_with_orientation(3)), Some(Orientation::Rotate180));
        assert_eq!(exif_orientation(&jpeg_with_orientation(1)), None, "as stored");
        let mut plain = Vec::new();
        image::codecs::jpeg::JpegEncoder::new(&mut plain)
            .encode(&[0u8; 64], 8, 8, image::ExtendedColorType::L8)
            .expect("encodes");
        assert_eq!(exif_orientation(&plain), None, "no EXIF");
        // The pixels are read as stored either way.
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("turned.jpg");
        std::fs::write(&path, jpeg_with_orientation(6)).expect("writes");
        let image = read_image(&path).expect("reads");
        assert_eq!((image.width, image.height), (8, 8));
    }

    #[test]
    fn tiff_samples_of_other_widths_are_refused_naming_the_bits() {
        let p = Path::new("bilevel.tif");
        for (bits, photometric, data) in [
            (1, 1, vec![0b1010_0000, 0b0101_0000]),
            (1, 0, vec![0b1010_0000, 0b0101_0000]),
            (4, 1, vec![0x0f, 0xf0, 0x12, 0x34]),
        ] {
            let err = decode_image(p, &tiff_by_hand_as(4, 2, 1, (bits, 1), photometric, &data), Linearisation::Linear)
                .expect_err("packed samples")
                .to_string();
            assert!(err.contains("bilevel.tif") && err.contains(&format!("{bits} bit(s) per sample")), "{err}");
        }
        let twelve = [0x00, 0x01, 0x00, 0xff, 0xf8, 0x00, 0x12, 0x34, 0x56, 0x78, 0x9a, 0xbc];
        let err = decode_image(p, &tiff_by_hand_as(4, 2, 1, (12, 1), 1, &twelve), Linearisation::Linear)
            .expect_err("12-bit samples")
            .to_string();
        assert!(err.contains("12 bit(s) per sample") && err.contains("16-bit samples"), "{err}");
    }

    /// WhiteIsZero integers read as the standard's negative (`2^bits − 1 − stored`); floats and
    /// signed integers, which have no maximum to invert from, are refused naming the file and
    /// the tag, as is grey with extra samples.
    #[test]
    fn tiff_white_is_zero_inverts_integers_and_refuses_floats() {
        let p = Path::new("negative.tif");
        let (img, kind) =
            decode_image(p, &tiff_by_hand(2, 1, 1, 0, &[0, 200]), Linearisation::Linear).expect("8-bit negative");
        assert_eq!((img.data, kind), (vec![255.0, 55.0], SampleKind::Integer(8)));
        let u16s: Vec<u8> = [0u16, 1000].iter().flat_map(|v| v.to_le_bytes()).collect();
        let (img, _) = decode_image(p, &tiff_by_hand_as(2, 1, 1, (16, 1), 0, &u16s), Linearisation::Linear)
            .expect("16-bit negative");
        assert_eq!(img.data, vec![65535.0, 64535.0]);
        let f32s: Vec<u8> = [0.25f32, 300.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let (img, kind) = decode_image(p, &tiff_by_hand_as(2, 1, 1, (32, 3), 1, &f32s), Linearisation::Linear)
            .expect("BlackIsZero float");
        assert_eq!((img.data, kind), (vec![0.25, 300.0], SampleKind::Float));
        let err = decode_image(p, &tiff_by_hand_as(2, 1, 1, (32, 3), 0, &f32s), Linearisation::Linear)
            .expect_err("WhiteIsZero float")
            .to_string();
        assert!(
            err.contains("negative.tif") && err.contains("PhotometricInterpretation") && err.contains("floating-point"),
            "{err}"
        );
        let i16s: Vec<u8> = [-5i16, 7].iter().flat_map(|v| v.to_le_bytes()).collect();
        let err = decode_image(p, &tiff_by_hand_as(2, 1, 1, (16, 2), 0, &i16s), Linearisation::Linear)
            .expect_err("WhiteIsZero signed")
            .to_string();
        assert!(err.contains("negative.tif") && err.contains("WhiteIsZero") && err.contains("signed"), "{err}");
        let err = decode_image(p, &tiff_by_hand(2, 1, 2, 0, &[0, 9, 200, 9]), Linearisation::Linear)
            .expect_err("WhiteIsZero with an extra sample")
            .to_string();
        assert!(err.contains("negative.tif") && err.contains("WhiteIsZero") && err.contains("2 samples"), "{err}");
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
        assert!(
            err.to_string().contains("junk.png") && err.to_string().contains("not a PNG, JPEG, TIFF or DaVis"),
            "{err}"
        );
        // An empty file (a copy that failed) is called empty, not of another format.
        let p = dir.path().join("empty.png");
        std::fs::write(&p, b"").expect("write");
        for err in [read_image(&p).expect_err("empty").to_string(), read_dimensions(&p).expect_err("empty").to_string()]
        {
            assert!(err.contains("empty.png: the image file is empty (0 bytes)"), "{err}");
        }
        let err = read_image(&dir.path().join("none.png")).expect_err("missing");
        assert!(matches!(err, IoError::NotFound { .. }), "{err}");
        assert!(err.to_string().contains("none.png"), "{err}");
    }

    /// A JPEG cut short anywhere after its headers is refused; whole ones, with or without
    /// bytes after the end marker, progressive ones and ones with restart markers are read.
    #[test]
    fn truncated_jpegs_are_refused() {
        use image::ImageEncoder;
        let (w, h) = (37u32, 23u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
        let mut whole = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut whole, 90)
            .write_image(&rgb, w, h, image::ExtendedColorType::Rgb8)
            .expect("jpeg");
        let p = Path::new("cut.jpg");
        assert_eq!(jpeg_end(&whole), JpegEnd::Complete);
        decode_image(p, &whole, Linearisation::Srgb).expect("a whole JPEG");
        let mut padded = whole.clone();
        padded.extend_from_slice(&[0; 7]);
        decode_image(p, &padded, Linearisation::Srgb).expect("bytes after the end marker");
        for cut in [whole.len() - 1, whole.len() - 2, whole.len() * 2 / 3, 300, 40] {
            let err = decode_image(p, &whole[..cut], Linearisation::Srgb).expect_err("cut").to_string();
            assert!(err.contains("cut.jpg") && err.contains(&format!("truncated JPEG: its {cut} bytes")), "{err}");
        }
        // Restart markers inside a scan, and a stuffed 0xFF00, are scan data.
        let scan = [0xFF, 0xD8, 0xFF, 0xDA, 0, 2, 1, 0xFF, 0, 2, 0xFF, 0xD3, 4, 0xFF, 0xD9];
        assert_eq!(jpeg_end(&scan), JpegEnd::Complete);
        assert_eq!(jpeg_end(&scan[..12]), JpegEnd::Truncated);
        assert_eq!(jpeg_end(&[0xFF, 0xD8, 0xFF, 0xE0, 0, 4, 0, 0, 7]), JpegEnd::Unparsed);
    }

    #[test]
    fn jpeg_reads_with_the_chosen_linearisation() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("flat.jpg");
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 100)
            .write_image(&[128u8; 16 * 8], 16, 8, image::ExtendedColorType::L8)
            .expect("encodes");
        std::fs::write(&p, &bytes).expect("write");
        // The sRGB curve of IEC 61966-2-1 and a plain gamma, by hand, on the 0..=255 scale.
        let c: f64 = 128.0 / 255.0;
        let srgb = 255.0 * ((c + 0.055) / 1.055).powf(2.4);
        let gamma = 255.0 * c.powf(2.2);
        for (lin, expected) in
            [(Linearisation::Linear, 128.0), (Linearisation::Srgb, srgb), (Linearisation::Gamma(2.2), gamma)]
        {
            let (img, kind) = read_image_with(&p, lin).expect("reads");
            assert_eq!(kind, SampleKind::Integer(8));
            assert_eq!((img.width, img.height), (16, 8));
            // JPEG is lossy; a flat block may move by one count (about 0.5 after sRGB decoding).
            assert!(img.data.iter().all(|&v| (f64::from(v) - expected).abs() < 1.01), "{lin}: {:?}", &img.data[..4]);
        }
        assert!((srgb - 55.0).abs() < 0.1 && (gamma - 55.98).abs() < 0.1, "{srgb} {gamma}");
        assert_eq!(read_dimensions(&p).expect("size"), (16, 8));
        // 16-bit images are never linearised.
        let p16 = dir.path().join("a.png");
        write_png16_counts(&p16, &Image::from_vec(1, 1, vec![1000.0])).expect("write");
        assert_eq!(read_image_with(&p16, Linearisation::Srgb).expect("reads").0.data, vec![1000.0]);
    }

    #[test]
    fn linearisation_parses_and_round_trips() {
        assert_eq!("sRGB".parse::<Linearisation>(), Ok(Linearisation::Srgb));
        assert_eq!("2.2".parse::<Linearisation>(), Ok(Linearisation::Gamma(2.2)));
        assert_eq!("linear".parse::<Linearisation>(), Ok(Linearisation::Linear));
        assert!("-1".parse::<Linearisation>().is_err() && "log".parse::<Linearisation>().is_err());
        for l in [Linearisation::Linear, Linearisation::Srgb, Linearisation::Gamma(1.8)] {
            let text = serde_json::to_string(&l).expect("json");
            assert_eq!(serde_json::from_str::<Linearisation>(&text).expect("back"), l, "{text}");
        }
        assert_eq!(Linearisation::Srgb.apply(255), 255.0);
        assert_eq!(Linearisation::Srgb.apply(0), 0.0);
    }

    /// The two forms of each linearisation agree at every 8-bit count, and the sRGB curve's
    /// linear toe and a gamma give the values worked out by hand.
    #[test]
    fn counts_and_unit_code_values_linearise_alike() {
        for lin in [Linearisation::Linear, Linearisation::Srgb, Linearisation::Gamma(2.0)] {
            for c in 0..=255u8 {
                let (a, b) = (lin.apply(c), lin.apply_unit(f64::from(c) / 255.0));
                assert!((a - b).abs() <= 1e-4 * a.max(1.0), "{lin} at {c}: {a} against {b}");
            }
        }
        // 10/255 lies on the toe (below 0.04045): 255 · (10/255) / 12.92 = 10 / 12.92.
        assert!((Linearisation::Srgb.apply(10) - 10.0 / 12.92).abs() < 1e-5);
        assert!((Linearisation::Srgb.apply_unit(0.04045) - (255.0 * 0.04045 / 12.92) as f32).abs() < 1e-5);
        // 51/255 = 0.2, squared 0.04: 10.2.
        assert!((Linearisation::Gamma(2.0).apply(51) - 10.2).abs() < 1e-4);
        assert!((Linearisation::Gamma(2.0).apply_unit(0.5) - 63.75).abs() < 1e-4);
        assert_eq!(Linearisation::Linear.apply_unit(0.5), 127.5);
        assert_eq!(Linearisation::Linear.apply(37), 37.0);
    }

    /// Messages say "an 8-bit" and "a 16-bit"; integer kinds saturate at 2^bits − 1, floats never.
    #[test]
    fn sample_kinds_name_themselves_and_their_full_scale() {
        assert_eq!(SampleKind::Integer(8).with_article(), "an 8-bit");
        assert_eq!(SampleKind::Integer(11).with_article(), "an 11-bit");
        assert_eq!(SampleKind::Integer(16).with_article(), "a 16-bit");
        assert_eq!(SampleKind::Float.with_article(), "a floating-point");
        assert_eq!(SampleKind::Integer(8).full_scale(), Some(255.0));
        assert_eq!(SampleKind::Integer(12).full_scale(), Some(4095.0));
        assert_eq!(SampleKind::Integer(16).full_scale(), Some(65535.0));
        assert_eq!(SampleKind::Float.full_scale(), None);
        let image = Image::from_vec(4, 1, vec![254.0, 255.0, 256.0, 4095.0]);
        assert_eq!(SampleKind::Integer(8).saturated(&image), 3);
        assert_eq!(SampleKind::Integer(12).saturated(&image), 1);
        assert_eq!(SampleKind::Integer(16).saturated(&image), 0);
        assert_eq!(SampleKind::Float.saturated(&image), 0);
    }

    #[test]
    fn image_extensions_are_recognised_in_any_letter_case() {
        for name in ["a.png", "a.PNG", "b.Jpg", "c.jpeg", "d.tif", "e.TIFF", "f.im7", "g.IMX"] {
            assert!(has_image_extension(Path::new(name)), "{name}");
        }
        for name in ["a.txt", "png", "a.png.bak", "frame.0001"] {
            assert!(!has_image_extension(Path::new(name)), "{name}");
        }
    }

    /// A path naming no file finds the one image of its stem, with another extension or none;
    /// several are an error naming them, and other files are not images.
    #[test]
    fn an_image_is_found_by_its_stem() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        for name in ["r_0.png", "r_0.txt", "frame.0001.tif", "two.png", "two.jpg"] {
            std::fs::write(d.join(name), b"x").expect("write");
        }
        std::fs::create_dir(d.join("dir.png")).expect("mkdir");
        assert_eq!(find_image_by_stem(&d.join("r_0")), Ok(Some(d.join("r_0.png"))));
        assert_eq!(find_image_by_stem(&d.join("r_0.jpg")), Ok(Some(d.join("r_0.png"))));
        assert_eq!(find_image_by_stem(&d.join("frame.0001")), Ok(Some(d.join("frame.0001.tif"))));
        assert_eq!(find_image_by_stem(&d.join("r_1.png")), Ok(None));
        assert_eq!(find_image_by_stem(&d.join("dir")), Ok(None), "a folder is no image");
        let e = find_image_by_stem(&d.join("two.tif")).expect_err("two candidates");
        assert!(e.contains("two.jpg") && e.contains("two.png") && e.contains("share its stem"), "{e}");
        assert_eq!(find_image_by_stem(&d.join("missing/r_0.png")), Ok(None));
    }

    /// The header gives width then height, for every format read.
    #[test]
    fn dimensions_are_read_as_width_then_height() {
        let dir = tempfile::tempdir().expect("tempdir");
        let image = ramp(7, 3, 10.0);
        let png = dir.path().join("a.png");
        write_png16_counts(&png, &image).expect("png");
        let tiff = dir.path().join("a.tif");
        write_tiff_f32(&tiff, &image).expect("tiff");
        let jpeg = dir.path().join("a.jpg");
        write_jpeg_srgb(&jpeg, &image, 100.0, 90).expect("jpeg");
        for p in [&png, &tiff, &jpeg] {
            assert_eq!(read_dimensions(p).expect("size"), (7, 3), "{}", p.display());
            let read = read_image(p).expect("image");
            assert_eq!((read.width, read.height), (7, 3), "{}", p.display());
        }
        let junk = dir.path().join("a.bin");
        std::fs::write(&junk, b"not an image at all").expect("write");
        let e = read_dimensions(&junk).expect_err("junk").to_string();
        assert!(e.contains("a.bin") && e.contains("not a PNG, JPEG, TIFF or DaVis"), "{e}");
    }

    /// A JPEG written through the sRGB curve reads back, with the curve undone, as the values
    /// on the 0..=255 scale; 0 and full scale and beyond clamp to 0 and 255.
    #[test]
    fn an_srgb_jpeg_reads_back_linear() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.jpg");
        // Flat 8 × 8 blocks so that compression keeps each value.
        let values = [0.0f32, 50.0, 200.0, 400.0];
        let data: Vec<f32> = (0..8 * 32).map(|i| values[(i % 32) / 8]).collect();
        write_jpeg_srgb(&p, &Image::from_vec(32, 8, data), 200.0, 100).expect("write");
        let (read, kind) = read_image_with(&p, Linearisation::Srgb).expect("read");
        assert_eq!(kind, SampleKind::Integer(8));
        for (k, expected) in [0.0f32, 63.75, 255.0, 255.0].into_iter().enumerate() {
            let v = read.get(8 * k + 4, 4);
            assert!((v - expected).abs() < 1.5, "block {k}: {v} against {expected}");
        }
    }
}
