//! The error type of the io crate. Every message names the file and the problem.

use std::path::PathBuf;

use fluidnerf_core::CoreError;

/// What can go wrong reading or writing fluidnerf's files.
///
/// Each message is complete on its own: the underlying error is part of the message and is
/// not also exposed as `source()`, so a chain printer (`{:#}`) never shows a cause twice.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system refused a read, write or rename.
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    /// A file the scene (or the caller) refers to does not exist.
    #[error("{what} not found: {path}")]
    NotFound { what: &'static str, path: PathBuf },
    /// Not JSON (the message carries line and column, and names a NaN or an infinity found
    /// where a number was expected: see [`IoError::json`]).
    #[error("{path}: malformed JSON: {error}")]
    Json { path: PathBuf, error: String },
    /// A key of a structured file is missing or has the wrong type or value. `location` names
    /// the key path (`frames[3].fl_x`) and, for scene frames, the frame and its image.
    #[error("{path}: {location}: {problem}")]
    Key { path: PathBuf, location: String, problem: String },
    /// The file is readable but its content is wrong or unsupported.
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
    /// A frame's camera is invalid (bad intrinsics, not a rotation, ...).
    #[error("{path}: frame {frame} ({file_path}): {error}")]
    Camera { path: PathBuf, frame: usize, file_path: PathBuf, error: CoreError },
    /// A frame's camera has no pixel whose ray crosses the reconstruction box.
    #[error(
        "{path}: frame {frame} ({file_path}): the camera does not see the reconstruction box \
         (no pixel's ray crosses the aabb); check its pose and the aabb"
    )]
    CameraMissesBox { path: PathBuf, frame: usize, file_path: PathBuf },
    /// A frame's camera has the box in view, but images it less than a pixel wide or high, so
    /// that it falls between the centres of its pixels: no pixel's ray crosses it, and the
    /// image says nothing about it.
    #[error(
        "{path}: frame {frame} ({file_path}): the reconstruction box is in the camera's view but \
         its image, {width_px:.2} × {height_px:.2} px, falls between pixel centres, so no pixel's ray \
         crosses the aabb; check the focal length (fl_x, fl_y: a short one images the box small), \
         the camera's distance and the aabb"
    )]
    BoxBetweenPixels { path: PathBuf, frame: usize, file_path: PathBuf, width_px: f64, height_px: f64 },
    /// An image's size disagrees with the intrinsics of its frame.
    #[error(
        "{path}: image is {found_width}x{found_height} pixels but frame {frame}'s intrinsics \
         say {expected_width}x{expected_height} (w x h)"
    )]
    ImageSize {
        path: PathBuf,
        frame: usize,
        found_width: usize,
        found_height: usize,
        expected_width: usize,
        expected_height: usize,
    },
    /// A pixel (or voxel) is NaN or infinite.
    #[error("{path}: value at {location} is {value}; values must be finite")]
    NonFinite { path: PathBuf, location: String, value: f32 },
}

impl IoError {
    /// Shorthand for [`IoError::Invalid`].
    pub fn invalid(path: impl Into<PathBuf>, problem: impl Into<String>) -> Self {
        IoError::Invalid { path: path.into(), problem: problem.into() }
    }

    /// The [`IoError::Json`] of `error`, met parsing `text` read from `path`: a NaN or an
    /// infinity (which Python's `json.dump` writes) is named with its key, not left as
    /// "expected value".
    pub fn json(path: impl Into<PathBuf>, text: &str, error: &serde_json::Error) -> Self {
        IoError::Json { path: path.into(), error: crate::json::describe_error(text, error) }
    }

    /// Wraps an I/O error, turning "not found" into [`IoError::NotFound`].
    pub fn io(path: impl Into<PathBuf>, what: &'static str, source: std::io::Error) -> Self {
        let path = path.into();
        if source.kind() == std::io::ErrorKind::NotFound {
            IoError::NotFound { what, path }
        } else {
            IoError::Io { path, error: source }
        }
    }
}
