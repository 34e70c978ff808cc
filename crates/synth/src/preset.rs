//! Named presets: the dissertation's data sets (chapter 6, Fig. 6.6) at sizes that run on a
//! workstation, plus a tiny demo. Every preset is a full [`SynthSettings`]; callers override
//! any field afterwards.
//!
//! The default, `planar15`, is sized to run in about a minute on a two-core machine: a 256³
//! truth (0.156 mm voxels), 256² px images (pixel footprint 0.156 mm, matching the voxels as
//! in the dissertation's 0.05 mm / 0.05 mm), thin lens with 128 rays per focal-plane voxel
//! (~2.8·10⁹ rays; about 60 CPU-seconds in all). The `dissertation` preset has Table 6.1's full size.
//!
//! The planar sets are subsets of one 120-camera ring (every 30th, 15th, …), as in the
//! dissertation, so a camera keeps its name across them; the 180° arc takes every 4th camera
//! of the same ring (15 cameras, 12° apart).
//!
//! The CFD sets (`plume*`, `cfdjet15`) image the solver's phantoms ([`crate::phantom::cfd`]):
//! the box is the simulation domain (24 × 36 × 24 mm, 0.5 mm cells, truth on the solver's own
//! 48 × 72 × 48 grid), the flow rises along world +y, and the cameras are subsets of a
//! 120-camera ring about y (image up = +y), pinhole, noiseless, 128² px over the 40 mm field of
//! view. They are a second phantom class for judging methods tuned on the procedural jets.

use crate::image::{ImageModel, PinholeSettings, ThinLensSettings};
use crate::phantom::PhantomKind;
use crate::rig::{Layout, LensSettings, RingAxis, Subset};
use crate::{SynthError, SynthSettings};

/// The preset `fluidnerf synth` uses when none is named.
pub const DEFAULT_PRESET: &str = "planar15";

/// Image side (pixels) and truth voxels per side of the planar presets.
const PIXELS: u32 = 256;
const VOXELS: usize = 256;

/// The presets' names, comma-separated (for messages).
pub(crate) fn preset_names() -> String {
    presets().iter().map(|(name, _)| *name).collect::<Vec<_>>().join(", ")
}

/// Names and one-line descriptions of every preset.
pub fn presets() -> Vec<(&'static str, &'static str)> {
    vec![
        ("demo", "tiny: jet, 15-camera ring, 96² px, 96³ truth, pinhole (seconds)"),
        ("planar15", "the dissertation's 15-camera planar ring, jet, thin lens, 256² px, 256³ truth (default)"),
        ("planar4", "4 cameras of the 120-camera ring, otherwise as planar15"),
        ("planar8", "8 cameras of the 120-camera ring, otherwise as planar15"),
        ("planar12", "12 cameras of the 120-camera ring, otherwise as planar15"),
        ("planar20", "20 cameras of the 120-camera ring, otherwise as planar15"),
        ("planar40", "40 cameras of the 120-camera ring, otherwise as planar15"),
        ("planar60", "60 cameras of the 120-camera ring, otherwise as planar15"),
        ("planar120", "the full 120-camera ring, otherwise as planar15"),
        ("arc180", "15 cameras over a 180° arc (12° apart), otherwise as planar15"),
        ("sphere15", "15 cameras on a Fibonacci sphere, otherwise as planar15"),
        ("jet-tr60", "starting jet at t* = 14, 15, 16, 60-camera ring, thin lens, 256² px, 256³ truth"),
        ("plume15", "CFD buoyant plume (PhiFlow) rising along +y, 15-camera ring about y, 128² px, pinhole, noiseless"),
        ("plume4", "4 cameras of the 120-camera ring about y, otherwise as plume15"),
        ("plume8", "8 cameras of the 120-camera ring about y, otherwise as plume15"),
        ("cfdjet15", "CFD forced round jet (PhiFlow) along +y, otherwise as plume15"),
        ("plume-tr", "CFD plume at solver steps 50, 52, 60, 12-camera ring about y, 64² px, pinhole"),
        (
            "real-like",
            "planar15 recorded like a laboratory rig: camera gains ±30 %, 5 % background, dark noise, one \
             background frame per camera, 8-bit sRGB JPEG; camera 7 held out",
        ),
        ("real-like-small", "real-like at demo size: 12 cameras, 64² px, 64³ truth, pinhole; camera 5 held out"),
        ("dissertation", "Table 6.1 at full size: 15 cameras, 800² px, 801³ truth, 500 rays per voxel (hours, ~10 GB)"),
    ]
}

fn ring120(every: usize, first: Option<usize>) -> SynthSettings {
    let mut s = SynthSettings {
        resolution: VOXELS,
        lens: LensSettings { resolution: [PIXELS, PIXELS], ..Default::default() },
        image: ImageModel::ThinLens(ThinLensSettings::default()),
        ..Default::default()
    };
    s.rig.layout = Layout::Ring { count: 120, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
    s.rig.subset = Subset { every, offset: 0, first };
    s
}

/// A CFD data set: the solver's phantom `kind` on its own grid and domain, `every`-th camera of
/// a 120-camera ring about y, pinhole, noiseless, 128² px.
fn cfd(kind: PhantomKind, every: usize) -> SynthSettings {
    let mut s = SynthSettings {
        aabb: crate::phantom::cfd::domain(),
        resolution: crate::phantom::cfd::CELLS.into_iter().max().unwrap_or(1),
        lens: LensSettings { resolution: [128, 128], ..Default::default() },
        image: ImageModel::Pinhole(PinholeSettings::default()),
        ..Default::default()
    };
    s.phantom.kind = kind;
    s.rig.layout = Layout::Ring { count: 120, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::Y };
    s.rig.subset = Subset { every, offset: 0, first: None };
    s
}

/// The settings of preset `name`.
pub fn preset(name: &str) -> Result<SynthSettings, SynthError> {
    let planar = |cams: usize| ring120(120 / cams, None);
    Ok(match name {
        "demo" => {
            let mut s = SynthSettings {
                resolution: 96,
                lens: LensSettings { resolution: [96, 96], ..Default::default() },
                image: ImageModel::Pinhole(PinholeSettings::default()),
                ..Default::default()
            };
            s.rig.layout = Layout::Ring { count: 15, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
            s
        }
        "planar15" => planar(15),
        "planar4" => planar(4),
        "planar8" => planar(8),
        "planar12" => planar(12),
        "planar20" => planar(20),
        "planar40" => planar(40),
        "planar60" => planar(60),
        "planar120" => planar(120),
        "arc180" => ring120(4, Some(15)),
        "sphere15" => {
            let mut s = planar(15);
            s.rig.layout = Layout::Sphere { count: 15 };
            s.rig.subset = Subset::default();
            s
        }
        "jet-tr60" => {
            let mut s = planar(60);
            s.rig.layout = Layout::Ring { count: 60, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
            s.rig.subset = Subset::default();
            s.phantom.kind = PhantomKind::JetTr;
            s.times = vec![14.0, 15.0, 16.0];
            s
        }
        "plume15" => cfd(PhantomKind::Plume, 8),
        "plume4" => cfd(PhantomKind::Plume, 30),
        "plume8" => cfd(PhantomKind::Plume, 15),
        "cfdjet15" => cfd(PhantomKind::CfdJet, 8),
        "plume-tr" => {
            let mut s = cfd(PhantomKind::Plume, 10);
            s.lens.resolution = [64, 64];
            s.times = vec![50.0, 52.0, 60.0];
            s
        }
        "real-like" => {
            let mut s = planar(15);
            s.real = Some(crate::RealLike::default());
            s.rig.holdout = vec![7];
            s
        }
        "real-like-small" => {
            let mut s = SynthSettings {
                resolution: 64,
                lens: LensSettings { resolution: [64, 64], ..Default::default() },
                image: ImageModel::Pinhole(PinholeSettings::default()),
                real: Some(crate::RealLike::default()),
                ..Default::default()
            };
            s.rig.layout = Layout::Ring { count: 12, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X };
            s.rig.holdout = vec![5];
            s
        }
        "dissertation" => {
            let mut s = planar(15);
            s.resolution = 801;
            s.lens.resolution = [800, 800];
            s.image = ImageModel::ThinLens(ThinLensSettings { rays_per_voxel: 500.0, threshold: 0.0 });
            s
        }
        other => return Err(SynthError::UnknownPreset(other.to_string())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_is_valid_and_round_trips() {
        for (name, _) in presets() {
            let s = preset(name).expect("preset");
            s.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
            let json = serde_json::to_string(&s).expect("serialise");
            let back: SynthSettings = serde_json::from_str(&json).expect("deserialise");
            assert_eq!(back, s, "{name}");
        }
        assert_eq!(preset("planar15").expect("preset").rig.count(), 15);
        assert_eq!(preset("planar4").expect("preset").rig.count(), 4);
        assert_eq!(preset("arc180").expect("preset").rig.count(), 15);
        assert_eq!(preset("plume15").expect("preset").rig.count(), 15);
        assert_eq!(preset("plume-tr").expect("preset").rig.count(), 12);
        for name in ["plume15", "plume4", "plume8", "cfdjet15", "plume-tr"] {
            let s = preset(name).expect("preset");
            assert_eq!(s.aabb, crate::phantom::cfd::domain(), "{name}: the box is the simulation domain");
            assert_eq!(s.truth_dims(&s.aabb), crate::phantom::cfd::CELLS, "{name}: truth on the solver's grid");
            assert!(matches!(s.rig.layout, Layout::Ring { axis: RingAxis::Y, .. }), "{name}: ring about +y");
        }
        assert!(matches!(preset("nope"), Err(SynthError::UnknownPreset(_))));
        let bad = r#"{"resolution": 64, "typo": 1}"#;
        assert!(serde_json::from_str::<SynthSettings>(bad).is_err());
        let bad = r#"{"image": {"model": "pinhole", "supersampel": 2}}"#;
        assert!(serde_json::from_str::<SynthSettings>(bad).is_err());
    }
}
