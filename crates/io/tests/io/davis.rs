//! DaVis images read exactly as LaVision's ReadIM reads them, and malformed ones refused by
//! name. The fixtures in `fixtures/davis/` were written by ReadIM's own writers (the old IMX
//! packing, uncompressed words and floats, the older `.imx` header) or packed by hand where
//! ReadIM writes no such packing (zlib, 12-bit), and `make_davis_with_readim.txt` holds every
//! pixel as ReadIM reads each back (make_davis_with_readim.py made both).

use std::path::{Path, PathBuf};

use fluidnerf_io::davis::{read_davis, FrameLabel};
use fluidnerf_io::image::{read_dimensions, read_image_with, Linearisation, SampleKind};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/davis")
}

/// What ReadIM read from one fixture.
struct Expected {
    name: String,
    width: usize,
    height: usize,
    float: bool,
    /// Frame k's label (`-` when the file names none).
    cameras: Vec<String>,
    frames: Vec<Vec<f64>>,
}

fn expected() -> Vec<Expected> {
    let text = std::fs::read_to_string(fixtures().join("make_davis_with_readim.txt")).expect("the recorded values");
    let mut out: Vec<Expected> = Vec::new();
    for line in text.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        if words[0] == "frame" {
            let values = words[2..].iter().map(|v| v.parse().expect("a number")).collect();
            out.last_mut().expect("a file first").frames.push(values);
            continue;
        }
        // NAME width W height H frames F kind K cameras L
        out.push(Expected {
            name: words[0].to_owned(),
            width: words[2].parse().expect("width"),
            height: words[4].parse().expect("height"),
            float: words[8] == "float",
            cameras: words[10].split(',').map(str::to_owned).collect(),
            frames: Vec::new(),
        });
    }
    assert_eq!(out.len(), 6, "six fixtures recorded");
    out
}

#[test]
fn every_pixel_is_readims() {
    for e in expected() {
        let path = fixtures().join(&e.name);
        let f = read_davis(&path).unwrap_or_else(|err| panic!("{}: {err}", e.name));
        assert_eq!((f.width, f.height, f.frames.len()), (e.width, e.height, e.frames.len()), "{}", e.name);
        assert_eq!(f.kind, if e.float { SampleKind::Float } else { SampleKind::Integer(16) }, "{}", e.name);
        for (k, (ours, theirs)) in f.frames.iter().zip(&e.frames).enumerate() {
            assert_eq!(ours.data.len(), theirs.len(), "{} frame {k}", e.name);
            for (i, (&a, &b)) in ours.data.iter().zip(theirs).enumerate() {
                // Bit for bit: -0.0 stays -0.0; ReadIM's floats print exactly as f64.
                assert_eq!(a.to_bits(), (b as f32).to_bits(), "{} frame {k} pixel {i}: {a} vs {b}", e.name);
            }
            let label = f.frame_label(k).map_or_else(|| "-".to_owned(), |l| l.to_string());
            assert_eq!(label, e.cameras[k], "{} frame {k}", e.name);
        }
    }
}

/// A file of one frame is a camera's image (any depth, never linearised) with its size in
/// the header; one of several is refused naming its cameras.
#[test]
fn one_frame_is_an_image_and_several_are_refused() {
    let e = expected();
    let word = fixtures().join("word.im7");
    let (img, kind) = read_image_with(&word, Linearisation::Srgb).expect("one frame");
    assert_eq!(kind, SampleKind::Integer(16));
    assert_eq!(img.data.iter().map(|&v| f64::from(v)).collect::<Vec<_>>(), e[0].frames[0]);
    assert_eq!(read_dimensions(&word).expect("size"), (15, 5));
    assert_eq!(read_dimensions(&fixtures().join("word_old.imx")).expect("size"), (15, 5));
    let (img, _) = read_image_with(&fixtures().join("fixed12.im7"), Linearisation::Linear).expect("12-bit");
    assert_eq!(img.get(2, 1), 4095.0);
    let err = read_image_with(&fixtures().join("three_cameras_imx.im7"), Linearisation::Linear)
        .expect_err("three frames")
        .to_string();
    assert!(err.contains("three_cameras_imx.im7") && err.contains("3 frames (cameras and exposures 1, 2, 3"), "{err}");
    let err =
        read_image_with(&fixtures().join("float.im7"), Linearisation::Linear).expect_err("two frames").to_string();
    assert!(err.contains("2 frames (cameras and exposures 1A, 1B"), "{err}");
    let f = read_davis(&fixtures().join("float.im7")).expect("reads");
    assert_eq!(f.frame_label(1), Some(FrameLabel { camera: 1, exposure: Some('B') }));
    assert_eq!(f.intensity_scale().map(|(a, b, _)| (a, b)), Some((1.0, 0.0)));
}

/// Cut short anywhere, a file is refused naming it, never read short or panicking.
#[test]
fn truncated_files_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    for name in ["word.im7", "three_cameras_imx.im7", "float.im7", "word_old.imx", "zlib.im7", "fixed12.im7"] {
        let bytes = std::fs::read(fixtures().join(name)).expect("fixture");
        let p = dir.path().join(name);
        for cut in (0..bytes.len() - 1).step_by(7).chain([bytes.len() - 1]) {
            std::fs::write(&p, &bytes[..cut]).expect("write");
            match read_davis(&p) {
                Ok(f) => {
                    // Only a cut that removes the attributes whole leaves a readable image.
                    assert!(f.attributes.is_empty(), "{name} cut at {cut} read with attributes");
                }
                Err(e) => {
                    let e = e.to_string();
                    assert!(e.contains(name) && e.contains("malformed DaVis image"), "{name} cut at {cut}: {e}");
                }
            }
        }
    }
    let p = dir.path().join("short.im7");
    std::fs::write(&p, [0u8; 100]).expect("write");
    let err = read_davis(&p).expect_err("short").to_string();
    assert!(err.contains("short.im7") && err.contains("100 bytes are fewer than the 256"), "{err}");
    let cut = std::fs::read(fixtures().join("word.im7")).expect("fixture");
    std::fs::write(&p, &cut[..256 + 100]).expect("write");
    let err = read_davis(&p).expect_err("cut pixels").to_string();
    assert!(err.contains("1 frame(s) of 15×5 16-bit pixels take 150 bytes") && err.contains("holds 100"), "{err}");
}

/// Bytes written over a file at an offset.
type Edit<'a> = (usize, &'a [u8]);

/// Headers that do not fit the file, or describe what fluidnerf does not read, are refused
/// naming the file and the problem.
#[test]
fn bad_and_unsupported_headers_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let word = std::fs::read(fixtures().join("word.im7")).expect("fixture");
    let p = dir.path().join("bad.im7");
    let with = |edits: &[Edit]| {
        let mut b = word.clone();
        for (at, v) in edits {
            b[*at..*at + v.len()].copy_from_slice(v);
        }
        std::fs::write(&p, &b).expect("write");
        read_davis(&p).expect_err("refused").to_string()
    };
    let cases: [(&[Edit], &str); 10] = [
        (&[(20, &4i32.to_le_bytes())], "4 frame(s) of 15×5 16-bit pixels take 600 bytes"),
        (&[(8, &1000i32.to_le_bytes())], "take 10000 bytes"),
        (&[(8, &(-3i32).to_le_bytes())], "claims 1 frame(s) of -3×5×1 pixels"),
        (&[(8, &i32::MAX.to_le_bytes()), (12, &i32::MAX.to_le_bytes())], "too many to be real"),
        (&[(16, &2i32.to_le_bytes())], "a volume of 2 planes"),
        (&[(2, &9i16.to_le_bytes())], "unknown compression (pack type 9)"),
        (&[(4, &2i16.to_le_bytes())], "vector field"),
        (&[(4, &(-5i16).to_le_bytes())], "64-bit float"),
        (&[(4, &(-11i16).to_le_bytes())], "colour pixels"),
        (&[(6, &1i16.to_le_bytes())], "sparse buffer"),
    ];
    for (edits, want) in cases {
        let err = with(edits);
        assert!(err.contains("bad.im7") && err.contains(want), "want {want:?}: {err}");
    }
    // Attributes of an unknown type, or running past the end.
    let mut b = word.clone();
    b.truncate(256 + 150);
    b.extend(99i32.to_le_bytes());
    b.extend(0i32.to_le_bytes());
    std::fs::write(&p, &b).expect("write");
    let err = read_davis(&p).expect_err("bad attribute").to_string();
    assert!(err.contains("attributes hold an item of unknown type 99"), "{err}");
    b.truncate(256 + 150);
    b.extend(6i32.to_le_bytes());
    b.extend(1000i32.to_le_bytes());
    std::fs::write(&p, &b).expect("write");
    let err = read_davis(&p).expect_err("long attribute").to_string();
    assert!(err.contains("runs past the end of the file"), "{err}");
}
