//! Image formation: the ideal pinhole line integral ([`pinhole`]) and the dissertation's thin
//! lens with a finite aperture ([`thin_lens`]). Both produce images in the same units, the line
//! integral `∫E ds` in field units × mm (times a scale factor), so they can be swapped.

pub mod pinhole;
pub mod thin_lens;

use serde::{Deserialize, Serialize};

pub use pinhole::PinholeSettings;
pub use thin_lens::{Emitters, ThinLensSettings};

/// Which image model to use, with its settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "kebab-case", deny_unknown_fields)]
pub enum ImageModel {
    /// Ideal, anti-aliased pinhole line integrals.
    Pinhole(PinholeSettings),
    /// Rays from every voxel through a finite aperture (defocus blur, shot-like noise).
    ThinLens(ThinLensSettings),
}

impl Default for ImageModel {
    fn default() -> Self {
        ImageModel::Pinhole(PinholeSettings::default())
    }
}

impl ImageModel {
    pub fn validate(&self) -> Result<(), crate::SynthError> {
        match self {
            ImageModel::Pinhole(s) => s.validate(),
            ImageModel::ThinLens(s) => s.validate(),
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            ImageModel::Pinhole(_) => "pinhole",
            ImageModel::ThinLens(_) => "thin-lens",
        }
    }
}
