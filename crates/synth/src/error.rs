//! The error type of the synth crate.

/// What can go wrong while generating a synthetic data set. Every variant is detected before
/// the expensive work starts, except [`SynthError::Cancelled`] and errors from `fluidnerf-core`.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// A setting is out of its valid range.
    #[error("invalid setting `{setting}`: {problem}")]
    Invalid { setting: String, problem: String },
    /// A camera of the rig does not see the reconstruction box at all.
    #[error("camera {index} ({name}) does not see the reconstruction box: place the rig around the box or enlarge the field of view")]
    CameraMissesBox { index: usize, name: String },
    /// A camera sees the box, but so small that no pixel's ray crosses it: its image would be
    /// black, and every command that reads the scene would refuse it.
    #[error(
        "camera {index} ({name}) images the reconstruction box smaller than its pixels are apart: no pixel's ray \
         crosses the box, so every command would refuse the scene; bring the rig closer (rig.distance_mm, \
         --distance), or give a smaller pixel pitch or more pixels"
    )]
    BoxBetweenPixels { index: usize, name: String },
    /// The data set would not fit in memory.
    #[error(
        "these settings need about {needed_mib} MiB of memory but only {available_mib} MiB are available: \
         {truth_mib} MiB for the truth (the resolution and the number of time steps) and {images_mib} MiB \
         for the images (their pixels, the number of cameras and of time steps); lower those"
    )]
    OutOfMemory { needed_mib: u64, available_mib: u64, truth_mib: u64, images_mib: u64 },
    /// No preset of this name.
    #[error("unknown preset `{0}`; the presets are {known}", known = crate::preset::preset_names())]
    UnknownPreset(String),
    /// A volume embedded in the crate does not decode (a broken build, not a user error).
    #[error("embedded phantom {name}: {problem}")]
    Embedded { name: String, problem: String },
    /// The progress callback asked to stop.
    #[error("cancelled")]
    Cancelled,
    /// Geometry or camera errors from `fluidnerf-core`.
    #[error(transparent)]
    Core(#[from] fluidnerf_core::CoreError),
}

impl SynthError {
    /// Shorthand for [`SynthError::Invalid`].
    pub fn invalid(setting: impl Into<String>, problem: impl Into<String>) -> Self {
        SynthError::Invalid { setting: setting.into(), problem: problem.into() }
    }
}
