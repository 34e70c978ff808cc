//! Atomic file output and PNG encoding.

use std::path::Path;

use crate::VizError;

/// Writes `bytes` to `path` atomically (through [`fluidnerf_io::atomic_write`]), so a reader
/// never sees a half-written file.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), VizError> {
    fluidnerf_io::atomic_write(path, |w| w.write_all(bytes))?;
    Ok(())
}

/// Encodes an 8-bit RGB buffer (`width × height × 3`, row 0 at the top) as PNG.
pub(crate) fn encode_rgb_png(rgb: &[u8], width: u32, height: u32, what: &str) -> Result<Vec<u8>, VizError> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|error| VizError::Encode { what: what.to_string(), error })?;
    Ok(out)
}
