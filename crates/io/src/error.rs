//! The error type of the io crate. Every message names the file and the problem.

use std::path::PathBuf;

use fluidnerf_core::CoreError;

/// What can go wrong reading or writing fluidnerf's files.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The operating system refused a read, write or rename.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file the scene (or the caller) refers to does not exist.
    #[error("{what} not found: {path}")]
    NotFound { what: &'static str, path: PathBuf },
    /// Not JSON, or JSON of the wrong shape (the message carries line and column).
    #[error("{path}: malformed JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// The file is readable but its content is wrong or unsupported.
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
    /// A frame's camera is invalid (bad intrinsics, not a rotation, ...).
    #[error("{path}: frame {frame} ({file_path}): {source}")]
    Camera {
        path: PathBuf,
        frame: usize,
        file_path: PathBuf,
        #[source]
        source: CoreError,
    },
    /// A frame's camera has no pixel whose ray crosses the reconstruction box.
    #[error(
        "{path}: frame {frame} ({file_path}): the camera does not see the reconstruction box \
         (no pixel's ray crosses the aabb); check its pose and the aabb"
    )]
    CameraMissesBox { path: PathBuf, frame: usize, file_path: PathBuf },
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

    /// Wraps an I/O error, turning "not found" into [`IoError::NotFound`].
    pub fn io(path: impl Into<PathBuf>, what: &'static str, source: std::io::Error) -> Self {
        let path = path.into();
        if source.kind() == std::io::ErrorKind::NotFound {
            IoError::NotFound { what, path }
        } else {
            IoError::Io { path, source }
        }
    }
}
