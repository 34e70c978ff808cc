//! Colour-mapped camera images, orbits of virtual cameras and animated turntables (GIF).
//!
//! Orbit cameras circle the flow axis (+x) through the box centre, looking at the centre, with
//! world +x pointing right in every image: a turntable shows the jet flowing left to right while
//! it turns about its own axis.

use std::path::Path;

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Camera, Image, Intrinsics};

use crate::{output, Colormap, VizError};

/// An 8-bit RGB picture of `image` (row 0 at the top), values mapped linearly from `[lo, hi]`
/// onto `colormap`. Returns `width × height × 3` bytes.
pub fn colorize(image: &Image, colormap: Colormap, lo: f32, hi: f32) -> Vec<u8> {
    image.data.iter().flat_map(|&v| colormap.rgb_in(v, lo, hi)).collect()
}

/// [`colorize`]d `image` as PNG bytes.
pub fn encode_image_png(image: &Image, colormap: Colormap, lo: f32, hi: f32) -> Result<Vec<u8>, VizError> {
    let rgb = colorize(image, colormap, lo, hi);
    output::encode_rgb_png(&rgb, image.width as u32, image.height as u32, "colour-mapped image")
}

/// The pixels a turntable ([`write_turntable_gif`]) shows in another colour than their value's:
/// those below its colour map's 0, shown as 0.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TurntableClipping {
    /// Pixels whose value lies below the colour map's lowest level (by more than half a level).
    pub negative: usize,
    /// The lowest of them; 0 when there is none.
    pub lowest: f32,
}

/// Writes an endlessly looping GIF of `frames` (all the same size), each colour-mapped on the
/// common range `[0, max]` of all frames (so brightness compares across frames), shown for
/// `frame_ms` milliseconds (rounded to the GIF's 10 ms, at least 10). GIF holds 256 colours:
/// the colour map is laid down once as a global palette of 255 evenly spaced colours, plus mid
/// grey for NaN, so every frame shows the same value in the same colour and no frame is
/// quantised. Negative values have no colour of their own and show as 0: returns how many
/// there were, for the caller to tell.
pub fn write_turntable_gif(
    path: &Path,
    frames: &[Image],
    colormap: Colormap,
    frame_ms: u32,
) -> Result<TurntableClipping, VizError> {
    const LEVELS: usize = 255;
    let Some(first) = frames.first() else {
        return Err(VizError::invalid("turntable", "there are no frames"));
    };
    if let Some(f) = frames.iter().find(|f| (f.width, f.height) != (first.width, first.height)) {
        return Err(VizError::invalid(
            "turntable",
            format!("frames differ in size ({}x{} and {}x{})", first.width, first.height, f.width, f.height),
        ));
    }
    let (Ok(width), Ok(height)) = (u16::try_from(first.width), u16::try_from(first.height)) else {
        return Err(VizError::invalid(
            "turntable",
            format!("frames of {}x{} px exceed the GIF's 65535 px per side", first.width, first.height),
        ));
    };
    let hi = frames.iter().flat_map(|f| f.data.iter()).copied().filter(|v| v.is_finite()).fold(0f32, f32::max);
    let scale = if hi > 0.0 { (LEVELS - 1) as f32 / hi } else { (LEVELS - 1) as f32 };
    let mut palette = Vec::with_capacity(3 * (LEVELS + 1));
    for i in 0..LEVELS {
        palette.extend(colormap.rgb(i as f64 / (LEVELS - 1) as f64));
    }
    palette.extend(colormap.rgb(f64::NAN));
    let enc_err = |error| VizError::EncodeGif { what: format!("turntable {}", path.display()), error };
    let mut bytes = Vec::new();
    let mut clipping = TurntableClipping::default();
    {
        let mut enc = gif::Encoder::new(&mut bytes, width, height, &palette).map_err(enc_err)?;
        enc.set_repeat(gif::Repeat::Infinite).map_err(enc_err)?;
        let mut indices = vec![0u8; first.data.len()];
        for f in frames {
            for (i, &v) in indices.iter_mut().zip(&f.data) {
                // As `colorize` maps it: clamped to the range, NaN grey.
                let level = (v * scale).round();
                if level < 0.0 {
                    clipping.negative += 1;
                    clipping.lowest = clipping.lowest.min(v);
                }
                *i = if v.is_nan() { LEVELS as u8 } else { level.clamp(0.0, (LEVELS - 1) as f32) as u8 };
            }
            let frame = gif::Frame {
                width,
                height,
                delay: (frame_ms.max(10).saturating_add(5) / 10).min(u16::MAX as u32) as u16,
                buffer: std::borrow::Cow::Borrowed(&indices),
                ..gif::Frame::default()
            };
            enc.write_frame(&frame).map_err(enc_err)?;
        }
    }
    output::write_atomic(path, &bytes)?;
    Ok(clipping)
}

/// `n` pinhole cameras evenly spaced on a circle about the line through the box centre along
/// +x, starting on the −z side (looking along +z) and turning right-handedly about +x. The
/// radius is three times the box's larger half-extent plus its cross-section radius (a mild
/// perspective); the focal length makes the box's projection, over the whole orbit, span 90 %
/// of `width_px`, and the height (even, at least 16 px) leaves the same margin vertically.
pub fn orbit_cameras(aabb: &Aabb, n: usize, width_px: u32) -> Vec<Camera> {
    orbit_cameras_about(aabb, n, width_px, DVec3::X)
}

/// [`orbit_cameras`] about the flow direction `flow` (world coordinates, any length) through the
/// box centre, the flow pointing right in every view. `flow = +x` gives [`orbit_cameras`].
pub fn orbit_cameras_about(aabb: &Aabb, n: usize, width_px: u32, flow: DVec3) -> Vec<Camera> {
    assert!(width_px >= 16, "orbit_cameras: width {width_px} px is too small");
    let largest = flow.abs().max_element();
    assert!(flow.is_finite() && largest > 0.0, "orbit_cameras: the flow direction must be finite and non-zero");
    // Scaled first, so that neither tiny nor huge components under- or overflow the length.
    let axis = (flow / largest).normalize();
    let centre = aabb.centre();
    // The box's half-length along the axis and its radius about it.
    let (mut half_axis, mut r_yz) = (0.0f64, 0.0f64);
    for c in aabb.corners() {
        let d = c - centre;
        let along = d.dot(axis);
        half_axis = half_axis.max(along.abs());
        r_yz = r_yz.max((d - along * axis).length());
    }
    let radius = 3.0 * half_axis.max(r_yz) + r_yz;
    // A basis (u, w) across the axis; for the x axis u = y, w = z.
    let w0 = if axis.dot(DVec3::Z).abs() < 0.9 { DVec3::Z } else { DVec3::Y };
    let w_dir = (w0 - w0.dot(axis) * axis).normalize();
    let u_dir = w_dir.cross(axis);
    let pose = |theta: f64| {
        // Position on the circle: −w at θ = 0, then towards −u (right-handed about the axis).
        let offset = (u_dir * theta.sin() - w_dir * theta.cos()) * radius;
        let forward = -offset.normalize();
        // Camera x = forward × up must be the flow axis, hence up = axis × forward.
        (centre + offset, axis.cross(forward))
    };
    // The box's largest extent in normalised image coordinates over a dense set of angles.
    let unit = Intrinsics { width: 2, height: 2, fx: 1.0, fy: 1.0, cx: 0.0, cy: 0.0, skew: 0.0 };
    let (mut max_u, mut max_v) = (1e-9f64, 1e-9f64);
    for i in 0..72 {
        let (eye, up) = pose(std::f64::consts::TAU * i as f64 / 72.0);
        let cam = Camera::look_at(unit, eye, centre, up);
        for corner in aabb.corners() {
            if let Some(p) = cam.project(corner) {
                max_u = max_u.max(p.x.abs());
                max_v = max_v.max(p.y.abs());
            }
        }
    }
    let w = width_px as f64;
    let f = 0.9 * 0.5 * w / max_u;
    let h = (2.0 * f * max_v / 0.9).ceil().max(16.0) as u32;
    let h = h + h % 2;
    let k = Intrinsics {
        width: width_px,
        height: h,
        fx: f,
        fy: f,
        cx: 0.5 * (w - 1.0),
        cy: 0.5 * (h as f64 - 1.0),
        skew: 0.0,
    };
    (0..n)
        .map(|i| {
            let (eye, up) = pose(std::f64::consts::TAU * i as f64 / n as f64);
            Camera::look_at(k, eye, centre, up)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// About −y, the flow runs right in every view and the box stays in the picture.
    #[test]
    fn orbit_about_another_axis_keeps_the_flow_to_the_right() {
        let aabb = Aabb::new(DVec3::new(-5.0, 0.0, -5.0), DVec3::new(5.0, 40.0, 5.0));
        let cams = orbit_cameras_about(&aabb, 6, 160, DVec3::NEG_Y);
        for cam in &cams {
            let upstream = cam.project(DVec3::new(0.0, 40.0, 0.0)).expect("in front");
            let downstream = cam.project(DVec3::new(0.0, 0.0, 0.0)).expect("in front");
            assert!(downstream.x > upstream.x + 60.0, "flow runs right: {upstream} → {downstream}");
            for corner in aabb.corners() {
                let p = cam.project(corner).expect("in front");
                assert!(p.x > 0.0 && p.x < 159.0 && p.y > 0.0 && p.y < cam.height() as f64 - 1.0, "{corner} → {p}");
            }
        }
        let x = orbit_cameras(&aabb, 3, 64);
        assert_eq!(x, orbit_cameras_about(&aabb, 3, 64, DVec3::new(2.0, 0.0, 0.0)));
        // Only the direction counts, however small or large the components.
        assert_eq!(x, orbit_cameras_about(&aabb, 3, 64, DVec3::new(1e-300, 0.0, 0.0)));
        let diagonal = orbit_cameras_about(&aabb, 3, 64, DVec3::new(1.0, 1.0, 0.0));
        assert_eq!(diagonal, orbit_cameras_about(&aabb, 3, 64, DVec3::new(1e200, 1e200, 0.0)));
    }

    #[test]
    fn orbit_sees_the_box_with_flow_to_the_right() {
        let aabb = Aabb::new(DVec3::new(0.0, -5.0, -5.0), DVec3::new(40.0, 5.0, 5.0));
        let cams = orbit_cameras(&aabb, 8, 200);
        assert_eq!(cams.len(), 8);
        for cam in &cams {
            let upstream = cam.project(DVec3::new(0.0, 0.0, 0.0)).expect("in front");
            let downstream = cam.project(DVec3::new(40.0, 0.0, 0.0)).expect("in front");
            assert!(downstream.x > upstream.x + 100.0, "flow runs right: {upstream} → {downstream}");
            for corner in aabb.corners() {
                let p = cam.project(corner).expect("in front");
                assert!(p.x > 0.0 && p.x < 199.0 && p.y > 0.0 && p.y < cam.height() as f64 - 1.0, "{corner} → {p}");
            }
            // The box spans most of the width.
            let us: Vec<f64> = aabb.corners().iter().map(|&c| cam.project(c).expect("in front").x).collect();
            let span = us.iter().fold(f64::MIN, |a, &b| a.max(b)) - us.iter().fold(f64::MAX, |a, &b| a.min(b));
            assert!(span > 150.0, "box spans {span} px of 200");
        }
        assert_eq!(cams[0].forward().z.signum(), 1.0, "first camera looks along +z");
    }

    /// The turntable decodes to its frames, each pixel in the colour map's colour for its value
    /// on the frames' common range (NaN grey), with the frame time asked for.
    #[test]
    fn turntable_round_trips_frames_and_colours() {
        let frames: Vec<Image> = (0..4)
            .map(|k| {
                let mut data: Vec<f32> = (0..48).map(|i| ((i + k * 5) % 48 * 5) as f32).collect();
                data[1] = 254.0;
                data[7] = f32::NAN;
                Image::from_vec(8, 6, data)
            })
            .collect();
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("t.gif");
        assert_eq!(write_turntable_gif(&path, &frames, Colormap::Magma, 80).expect("writes"), Default::default());
        let mut opts = gif::DecodeOptions::new();
        opts.set_color_output(gif::ColorOutput::RGBA);
        let mut dec = opts.read_info(std::fs::File::open(&path).expect("opens")).expect("a GIF");
        assert_eq!((dec.width(), dec.height()), (8, 6));
        let mut n = 0;
        while let Some(frame) = dec.read_next_frame().expect("a frame") {
            assert_eq!(frame.delay, 8, "80 ms in the GIF's 10 ms");
            let src = &frames[n];
            for (q, (&v, px)) in src.data.iter().zip(frame.buffer.chunks_exact(4)).enumerate() {
                // The values are whole numbers, on the palette's levels (the peak, 254, is the
                // top one), so the colour is the colour map's at the value exactly.
                let want = colorize(&Image::from_vec(1, 1, vec![v]), Colormap::Magma, 0.0, 254.0);
                assert_eq!(&px[..3], &want[..], "frame {n}, pixel {q} ({v})");
            }
            n += 1;
        }
        assert_eq!(n, 4);
        assert!(write_turntable_gif(&path, &[], Colormap::Magma, 80).is_err());
    }

    /// Negative values, shown as 0, are counted with the lowest of them, so that the caller
    /// can tell: they were shown as 0 without a word. Half a level below 0 still shows as 0.
    #[test]
    fn turntable_counts_the_negative_values_it_shows_as_zero() {
        let frames = [
            Image::from_vec(2, 2, vec![254.0, -0.4, 3.0, f32::NAN]),
            Image::from_vec(2, 2, vec![-3.0, 0.0, -0.6, 10.0]),
        ];
        let dir = tempfile::tempdir().expect("tempdir");
        let clipping = write_turntable_gif(&dir.path().join("t.gif"), &frames, Colormap::Magma, 80).expect("writes");
        assert_eq!(clipping, TurntableClipping { negative: 2, lowest: -3.0 });
    }
}
