//! Colour-mapped camera images and animated turntables (GIF).

use std::path::Path;

use fluidnerf_core::Image;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame, RgbaImage};

use crate::{output, Colormap, VizError};

/// An 8-bit RGB picture of `image` (row 0 at the top), values mapped linearly from `[lo, hi]`
/// onto `colormap`. Returns `width × height × 3` bytes.
pub fn colorize(image: &Image, colormap: Colormap, lo: f32, hi: f32) -> Vec<u8> {
    let span = if hi > lo { (hi - lo) as f64 } else { 1.0 };
    image.data.iter().flat_map(|&v| colormap.rgb((v - lo) as f64 / span)).collect()
}

/// [`colorize`]d `image` as PNG bytes.
pub fn encode_image_png(image: &Image, colormap: Colormap, lo: f32, hi: f32) -> Result<Vec<u8>, VizError> {
    let rgb = colorize(image, colormap, lo, hi);
    output::encode_rgb_png(&rgb, image.width as u32, image.height as u32, "colour-mapped image")
}

/// Writes an endlessly looping GIF of `frames` (all the same size), each colour-mapped on the
/// common range `[0, max]` of all frames (so brightness compares across frames), shown for
/// `frame_ms` milliseconds. GIF holds 256 colours per frame; the encoder quantises each frame.
pub fn write_turntable_gif(path: &Path, frames: &[Image], colormap: Colormap, frame_ms: u32) -> Result<(), VizError> {
    let Some(first) = frames.first() else {
        return Err(VizError::invalid("turntable", "there are no frames"));
    };
    if let Some(f) = frames.iter().find(|f| (f.width, f.height) != (first.width, first.height)) {
        return Err(VizError::invalid(
            "turntable",
            format!("frames differ in size ({}x{} and {}x{})", first.width, first.height, f.width, f.height),
        ));
    }
    let hi = frames.iter().flat_map(|f| f.data.iter()).copied().filter(|v| v.is_finite()).fold(0f32, f32::max);
    let hi = if hi > 0.0 { hi } else { 1.0 };
    let mut bytes = Vec::new();
    {
        let mut enc = GifEncoder::new_with_speed(&mut bytes, 10);
        let enc_err = |source| VizError::Encode { what: format!("turntable {}", path.display()), source };
        enc.set_repeat(Repeat::Infinite).map_err(enc_err)?;
        for f in frames {
            let rgb = colorize(f, colormap, 0.0, hi);
            let rgba: Vec<u8> = rgb.chunks_exact(3).flat_map(|c| [c[0], c[1], c[2], 255]).collect();
            let buf = RgbaImage::from_raw(f.width as u32, f.height as u32, rgba)
                .ok_or_else(|| VizError::invalid("turntable frame", "buffer size mismatch"))?;
            let frame = Frame::from_parts(buf, 0, 0, Delay::from_numer_denom_ms(frame_ms.max(10), 1));
            enc.encode_frame(frame).map_err(enc_err)?;
        }
    }
    output::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turntable_round_trips_frame_count() {
        let frames: Vec<Image> =
            (0..4).map(|k| Image::from_vec(8, 6, (0..48).map(|i| ((i + k * 5) % 48) as f32).collect())).collect();
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.gif");
        write_turntable_gif(&path, &frames, Colormap::Magma, 80).expect("writes");
        use image::AnimationDecoder;
        let file = std::io::BufReader::new(std::fs::File::open(&path).expect("opens"));
        let decoded =
            image::codecs::gif::GifDecoder::new(file).expect("a GIF").into_frames().collect_frames().expect("frames");
        assert_eq!(decoded.len(), 4);
        assert_eq!(decoded[0].buffer().dimensions(), (8, 6));
        assert!(write_turntable_gif(&path, &[], Colormap::Magma, 80).is_err());
    }
}
