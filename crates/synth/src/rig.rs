//! Camera rigs: lens settings → intrinsics, and layouts of cameras around the box.
//!
//! # Conventions
//! World units are mm; the procedural jets flow along world **+x**, the CFD phantoms rise
//! along **+y**. Every camera looks at the box centre from the lens's object distance `l_o` (so
//! the focal plane passes through the centre). Around x, its image x axis runs along world +x
//! wherever possible (the jet runs left to right in the images); on a ring about y, its image
//! up is world +y (the plume rises in the images). Cameras carry the [`ThinLens`] they were made with. Camera `name`s number the
//! cameras of the whole layout (`cam000`, …) so that a subset keeps the names of its parent
//! layout (the dissertation's 4…60-camera sets are subsets of its 120-camera ring).

use fluidnerf_core::geometry::MAX_COORDINATE;
use fluidnerf_core::glam::{DAffine3, DMat3, DQuat, DVec3};
use fluidnerf_core::num;
use fluidnerf_core::{Aabb, Camera, Intrinsics, ThinLens};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, UnitSphere};
use serde::{Deserialize, Serialize};

use crate::SynthError;

/// Lens and sensor settings. Default: the dissertation's Table 6.1 (M = −0.2, f = 60 mm, f/3.5,
/// 0.01 mm pixels at 800 × 800, a 40 mm field of view), with the pixel pitch scaled so the field
/// of view stays 40 mm at other resolutions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LensSettings {
    /// Lateral magnification M (negative: a real, inverted image). Default −0.2.
    pub magnification: f64,
    /// Focal length f in mm. Default 60.
    pub focal_length_mm: f64,
    /// f-number f/d_a. Default 3.5.
    pub f_number: f64,
    /// Image width and height in pixels. Default 800 × 800.
    pub resolution: [u32; 2],
    /// Pixel pitch in mm. Default `0.01 · 800 / width` (a 40 mm wide field of view).
    pub pixel_pitch_mm: Option<f64>,
}

impl Default for LensSettings {
    fn default() -> Self {
        LensSettings {
            magnification: -0.2,
            focal_length_mm: 60.0,
            f_number: 3.5,
            resolution: [800, 800],
            pixel_pitch_mm: None,
        }
    }
}

impl LensSettings {
    pub fn validate(&self) -> Result<(), SynthError> {
        if !(self.magnification < 0.0 && self.magnification.is_finite()) {
            return Err(SynthError::invalid(
                "lens.magnification",
                format!("must be negative (a real image), got {}", num(self.magnification)),
            ));
        }
        if !(self.focal_length_mm > 0.0 && self.focal_length_mm.is_finite()) {
            return Err(SynthError::invalid(
                "lens.focal_length_mm",
                format!("must be positive, got {}", num(self.focal_length_mm)),
            ));
        }
        if !(self.f_number > 0.0 && self.f_number.is_finite()) {
            return Err(SynthError::invalid("lens.f_number", format!("must be positive, got {}", num(self.f_number))));
        }
        // N = 1 / (2 NA): below 0.5 the aperture grows without bound (6e301 mm at 1e-300), and
        // every voxel's light is spread off the sensor.
        if self.f_number < 0.5 {
            return Err(SynthError::invalid(
                "lens.f_number",
                format!(
                    "must be at least 0.5 (a lens in air has a numerical aperture of at most 1), got {}",
                    num(self.f_number)
                ),
            ));
        }
        if let Some(side) = self.resolution.into_iter().find(|&n| n < MIN_IMAGE_SIDE) {
            return Err(SynthError::invalid(
                "lens.resolution",
                format!(
                    "width and height must be at least {MIN_IMAGE_SIDE} pixels, got {} × {} ({side} is too few): \
                     held-out views are scored with a {MIN_IMAGE_SIDE}-pixel SSIM window, and the images' noise is \
                     estimated on pixels away from their edges",
                    self.resolution[0], self.resolution[1]
                ),
            ));
        }
        if let Some(p) = self.pixel_pitch_mm {
            if !(p > 0.0 && p.is_finite()) {
                return Err(SynthError::invalid("lens.pixel_pitch_mm", format!("must be positive, got {}", num(p))));
            }
        }
        // The focal length in pixels that the lens and the pitch give, as every scene's cameras
        // are held to (a pitch of 1e-12 mm gave 7.2e13 px: uniform images, and a scene that
        // every other command refused).
        let k = self.intrinsics();
        if k.fx > fluidnerf_core::MAX_INTRINSIC_PX {
            return Err(SynthError::invalid(
                "lens.pixel_pitch_mm",
                format!(
                    "a pitch of {} mm with a focal length of {} mm and magnification {} gives {} px, more than the {} px \
                     a camera's focal length may be; is the pitch in millimetres?",
                    num(self.pixel_pitch()),
                    num(self.focal_length_mm),
                    num(self.magnification),
                    num(k.fx),
                    num(fluidnerf_core::MAX_INTRINSIC_PX)
                ),
            ));
        }
        Ok(())
    }

    pub fn pixel_pitch(&self) -> f64 {
        self.pixel_pitch_mm.unwrap_or(0.01 * 800.0 / self.resolution[0] as f64)
    }

    pub fn thin_lens(&self) -> ThinLens {
        ThinLens::from_f_number(self.focal_length_mm, self.f_number, self.magnification, self.pixel_pitch())
    }

    /// Pinhole intrinsics: focal length `l_i / pitch` pixels, principal point at the image
    /// centre.
    pub fn intrinsics(&self) -> Intrinsics {
        let f = self.thin_lens().focal_length_px();
        let [w, h] = self.resolution;
        Intrinsics {
            width: w,
            height: h,
            fx: f,
            fy: f,
            cx: (w as f64 - 1.0) / 2.0,
            cy: (h as f64 - 1.0) / 2.0,
            skew: 0.0,
        }
    }

    /// Width and height of the field of view on the focal plane, mm.
    pub fn field_of_view_mm(&self) -> [f64; 2] {
        let fp = self.thin_lens().pixel_footprint();
        [self.resolution[0] as f64 * fp, self.resolution[1] as f64 * fp]
    }
}

/// Where the cameras are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "layout", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Layout {
    /// `count` cameras in the plane through the box centre perpendicular to `axis` (the flow
    /// axis), evenly spaced over `[start_deg, start_deg + arc_deg)` (`arc_deg` in (0, 360],
    /// `start_deg` within ±[`MAX_START_DEG`]). About x (the default):
    /// angle 0 is world +y, 90° is +z; about y: angle 0 is +z, 90° is +x.
    Ring {
        count: usize,
        arc_deg: f64,
        start_deg: f64,
        #[serde(default)]
        axis: RingAxis,
    },
    /// `count` cameras on a Fibonacci lattice over the sphere around the box centre (pole along
    /// world +z).
    Sphere { count: usize },
    /// Cameras at the given world positions (mm), each looking at its entry of `targets`
    /// (default: the box centre).
    Explicit {
        positions: Vec<[f64; 3]>,
        #[serde(default)]
        targets: Vec<[f64; 3]>,
    },
}

impl Default for Layout {
    fn default() -> Self {
        Layout::Ring { count: 15, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X }
    }
}

/// The world axis a ring goes around: the flow axis of the phantom.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RingAxis {
    /// The procedural jets' axis. Image x runs along world +x (the jet runs left to right).
    #[default]
    X,
    /// The CFD phantoms' axis (they rise along +y). Image up is world +y (the flow rises in
    /// the images).
    Y,
}

/// Keeps part of a layout: cameras `offset, offset + every, offset + 2 every, …`, at most
/// `first` of them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Subset {
    /// Default 1 (all).
    pub every: usize,
    /// Default 0.
    pub offset: usize,
    /// Default: no limit.
    pub first: Option<usize>,
}

impl Default for Subset {
    fn default() -> Self {
        Subset { every: 1, offset: 0, first: None }
    }
}

/// Random perturbation of the camera poses (seeded): Gaussian position noise per axis and a
/// rotation about a random axis by a Gaussian angle. The scene records the perturbed poses.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Jitter {
    /// Standard deviation of each position coordinate, mm, at most the cameras' distance from
    /// the point they look at. Default 0.
    pub position_mm: f64,
    /// Standard deviation of the rotation angle, degrees, at most [`MAX_JITTER_ROTATION_DEG`].
    /// Default 0.
    pub rotation_deg: f64,
}

/// A camera rig.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigSettings {
    pub layout: Layout,
    pub subset: Subset,
    pub jitter: Jitter,
    /// Cameras (indices into the rig after subsetting) held out for validation. Default none.
    pub holdout: Vec<usize>,
    /// Distance of every camera from the box centre, mm. Default: the lens's object distance.
    pub distance_mm: Option<f64>,
}

/// Most cameras a layout may have. The dissertation's largest rig has 120; a thousand, named
/// `cam000` … `cam999`, is more than any laboratory sets up, and beyond it a count is a slip
/// that would image (and write) that many views before anything else could say so.
pub const MAX_CAMERAS: usize = 1000;

/// Fewest pixels along an image's side: the held-out views of a scene are scored with the
/// windowed SSIM, whose default window is 7 pixels wide, and the images' noise estimate
/// ([`fluidnerf_core::Image::relative_noise`]) needs pixels off the edge.
pub const MIN_IMAGE_SIDE: u32 = 7;

/// The largest `start_deg` of a ring, either way: ten turns. Every ring starts within one turn,
/// so beyond that a start is a slip, and far beyond it the cameras' angles lose their spacing
/// in the floats they are computed in (at 1e30 degrees every camera of a ring stood at the
/// same angle, without a word).
pub const MAX_START_DEG: f64 = 3600.0;

/// The largest standard deviation of the cameras' random rotation ([`Jitter::rotation_deg`]):
/// half a turn. Beyond it a rotation is no perturbation of a pose but a random orientation.
pub const MAX_JITTER_ROTATION_DEG: f64 = 180.0;

/// One camera of a rig.
#[derive(Clone, Debug, PartialEq)]
pub struct RigCamera {
    pub name: String,
    pub camera: Camera,
    pub holdout: bool,
}

impl RigSettings {
    /// Number of cameras after subsetting.
    pub fn count(&self) -> usize {
        let total = match &self.layout {
            Layout::Ring { count, .. } | Layout::Sphere { count } => *count,
            Layout::Explicit { positions, .. } => positions.len(),
        };
        let every = self.subset.every.max(1);
        let n = if total > self.subset.offset { (total - self.subset.offset).div_ceil(every) } else { 0 };
        self.subset.first.map_or(n, |f| n.min(f))
    }

    /// Checks the settings that need no geometry.
    pub fn validate(&self) -> Result<(), SynthError> {
        let (key, total) = match &self.layout {
            Layout::Ring { count, .. } | Layout::Sphere { count } => ("rig.layout.count", *count),
            Layout::Explicit { positions, .. } => ("rig.layout.positions", positions.len()),
        };
        if total > MAX_CAMERAS {
            return Err(SynthError::invalid(
                key,
                format!("{total} cameras are more than a rig can sensibly have; give at most {MAX_CAMERAS}"),
            ));
        }
        match &self.layout {
            Layout::Ring { count, arc_deg, start_deg, .. } => {
                if *count == 0 {
                    return Err(SynthError::invalid("rig.layout.count", "a rig needs at least one camera"));
                }
                if !(*arc_deg > 0.0 && *arc_deg <= 360.0) {
                    return Err(SynthError::invalid(
                        "rig.layout.arc_deg",
                        format!("must be in (0, 360], got {}", num(*arc_deg)),
                    ));
                }
                if !start_deg.is_finite() {
                    return Err(SynthError::invalid("rig.layout.start_deg", "must be finite"));
                }
                if start_deg.abs() > MAX_START_DEG {
                    return Err(SynthError::invalid(
                        "rig.layout.start_deg",
                        format!(
                            "must lie in [-{max}, {max}] degrees (every ring starts within one turn), got {}",
                            num(*start_deg),
                            max = num(MAX_START_DEG)
                        ),
                    ));
                }
            }
            Layout::Sphere { count } if *count == 0 => {
                return Err(SynthError::invalid("rig.layout.count", "a rig needs at least one camera"));
            }
            Layout::Sphere { .. } => {}
            Layout::Explicit { positions, targets } => {
                if positions.is_empty() {
                    return Err(SynthError::invalid("rig.layout.positions", "a rig needs at least one camera"));
                }
                if positions.iter().chain(targets).flatten().any(|v| !v.is_finite()) {
                    return Err(SynthError::invalid("rig.layout.positions", "positions and targets must be finite"));
                }
                if let Some(v) = positions.iter().chain(targets).flatten().find(|v| v.abs() > MAX_COORDINATE) {
                    return Err(SynthError::invalid(
                        "rig.layout.positions",
                        format!(
                            "coordinate {} is beyond ±{} mm of the origin, where camera positions and rays have no \
                             finite length in the floats they are computed in",
                            num(*v),
                            num(MAX_COORDINATE)
                        ),
                    ));
                }
                if !targets.is_empty() && targets.len() != positions.len() {
                    return Err(SynthError::invalid(
                        "rig.layout.targets",
                        format!(
                            "{} targets for {} positions; give one per camera or none",
                            targets.len(),
                            positions.len()
                        ),
                    ));
                }
            }
        }
        if self.subset.every == 0 {
            return Err(SynthError::invalid("rig.subset.every", "must be at least 1"));
        }
        let n = self.count();
        if n == 0 {
            return Err(SynthError::invalid("rig.subset", "the subset keeps no camera"));
        }
        if let Some(&bad) = self.holdout.iter().find(|&&i| i >= n) {
            return Err(SynthError::invalid("rig.holdout", format!("camera {bad} does not exist (the rig has {n})")));
        }
        // A camera held out twice is a slip for another camera, which would be reconstructed from.
        if let Some(&twice) =
            self.holdout.iter().enumerate().find(|(k, i)| self.holdout[..*k].contains(i)).map(|(_, i)| i)
        {
            return Err(SynthError::invalid(
                "rig.holdout",
                format!("camera {twice} is given twice; give each camera once"),
            ));
        }
        if self.holdout.len() >= n && n > 0 && self.holdout.iter().collect::<std::collections::BTreeSet<_>>().len() >= n
        {
            return Err(SynthError::invalid(
                "rig.holdout",
                "every camera is held out; keep at least one for reconstruction",
            ));
        }
        for (name, v) in
            [("rig.jitter.position_mm", self.jitter.position_mm), ("rig.jitter.rotation_deg", self.jitter.rotation_deg)]
        {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(SynthError::invalid(name, format!("must be zero or positive, got {}", num(v))));
            }
        }
        if self.jitter.rotation_deg > MAX_JITTER_ROTATION_DEG {
            return Err(SynthError::invalid(
                "rig.jitter.rotation_deg",
                format!(
                    "must be at most {} degrees (a larger rotation is no perturbation of a pose), got {}",
                    num(MAX_JITTER_ROTATION_DEG),
                    num(self.jitter.rotation_deg)
                ),
            ));
        }
        if let Some(d) = self.distance_mm {
            if !(d > 0.0 && d.is_finite()) {
                return Err(SynthError::invalid("rig.distance_mm", format!("must be positive, got {}", num(d))));
            }
        }
        Ok(())
    }

    /// Builds the cameras around `aabb` with `lens`, jittered with `seed`, and checks that every
    /// camera sees the box (warning when one sees only part of it).
    pub fn build(&self, lens: &LensSettings, aabb: &Aabb, seed: u64) -> Result<Vec<RigCamera>, SynthError> {
        self.validate()?;
        lens.validate()?;
        aabb.validate()?;
        let centre = aabb.centre();
        let dist = self.distance_mm.unwrap_or_else(|| lens.thin_lens().object_distance());
        // Farther out, a camera's position has no finite length in 64-bit floats (its viewing
        // direction is undefined) and its rays none in the 32-bit floats of rendering.
        let ring_or_sphere = !matches!(self.layout, Layout::Explicit { .. });
        if ring_or_sphere && !(dist.is_finite() && dist <= MAX_COORDINATE) {
            let (key, what) = match self.distance_mm {
                Some(_) => ("rig.distance_mm", "the distance"),
                None => (
                    "lens.magnification",
                    "the lens's object distance f (1 - 1/M), from lens.magnification and lens.focal_length_mm,",
                ),
            };
            return Err(SynthError::invalid(
                key,
                format!(
                    "{what} {} mm is more than {} mm, where camera positions and rays have no finite length in \
                     the floats they are computed in",
                    num(dist),
                    num(MAX_COORDINATE)
                ),
            ));
        }
        let positions: Vec<DVec3> = match &self.layout {
            Layout::Ring { count, arc_deg, start_deg, axis } => (0..*count)
                .map(|i| {
                    let a = (start_deg + arc_deg * i as f64 / *count as f64).to_radians();
                    let dir = match axis {
                        RingAxis::X => DVec3::new(0.0, a.cos(), a.sin()),
                        RingAxis::Y => DVec3::new(a.sin(), 0.0, a.cos()),
                    };
                    centre + dist * dir
                })
                .collect(),
            Layout::Sphere { count } => {
                let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
                (0..*count)
                    .map(|i| {
                        let z = 1.0 - (2.0 * i as f64 + 1.0) / *count as f64;
                        let r = (1.0 - z * z).max(0.0).sqrt();
                        let phi = golden * i as f64;
                        centre + dist * DVec3::new(r * phi.cos(), r * phi.sin(), z)
                    })
                    .collect()
            }
            Layout::Explicit { positions, .. } => positions.iter().map(|p| DVec3::from(*p)).collect(),
        };
        let target_of = |index: usize| match &self.layout {
            Layout::Explicit { targets, .. } if !targets.is_empty() => DVec3::from(targets[index]),
            _ => centre,
        };
        // A shift beyond the cameras' distance from what they look at is no perturbation of a
        // pose (as a rotation beyond half a turn): a camera could land in the box or behind its
        // target, or, far out, be refused as blind to the box without the jitter being named.
        let nearest = match self.layout {
            Layout::Explicit { .. } => {
                positions.iter().enumerate().map(|(i, &p)| (p - target_of(i)).length()).fold(f64::INFINITY, f64::min)
            }
            _ => dist,
        };
        if self.jitter.position_mm > nearest {
            return Err(SynthError::invalid(
                "rig.jitter.position_mm",
                format!(
                    "must be at most {} mm, the cameras' distance from the point they look at (a larger shift is no \
                     perturbation of a pose), got {}",
                    num(nearest),
                    num(self.jitter.position_mm)
                ),
            ));
        }
        let intrinsics = lens.intrinsics();
        let thin = lens.thin_lens();
        let every = self.subset.every.max(1);
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x7269_6721);
        let pos_noise = Normal::new(0.0, self.jitter.position_mm)
            .map_err(|e| SynthError::invalid("rig.jitter.position_mm", e.to_string()))?;
        let rot_noise = Normal::new(0.0, self.jitter.rotation_deg.to_radians())
            .map_err(|e| SynthError::invalid("rig.jitter.rotation_deg", e.to_string()))?;
        let mut cams = Vec::new();
        for (index, &pos) in positions.iter().enumerate().skip(self.subset.offset).step_by(every) {
            if self.subset.first.is_some_and(|f| cams.len() >= f) {
                break;
            }
            let target = target_of(index);
            if (pos - target).length() < 1e-9 {
                return Err(SynthError::invalid("rig.layout", format!("camera {index} sits on the point it looks at")));
            }
            let forward = (target - pos).normalize();
            let mut up = match self.layout {
                Layout::Ring { axis: RingAxis::Y, .. } => DVec3::Y - forward * forward.y,
                _ => DVec3::X.cross(forward),
            };
            if up.length() < 1e-6 {
                up = DVec3::Z.cross(forward);
            }
            let mut camera = Camera::look_at(intrinsics, pos, target, up);
            camera.lens = Some(thin);
            if self.jitter.position_mm > 0.0 || self.jitter.rotation_deg > 0.0 {
                let dp = DVec3::new(pos_noise.sample(&mut rng), pos_noise.sample(&mut rng), pos_noise.sample(&mut rng));
                let axis = DVec3::from(<UnitSphere as Distribution<[f64; 3]>>::sample(&UnitSphere, &mut rng));
                let angle = rot_noise.sample(&mut rng);
                let rot = DMat3::from_quat(DQuat::from_axis_angle(axis, angle));
                let m = camera.world_from_camera.matrix3;
                camera.world_from_camera = DAffine3::from_mat3_translation(rot * m, pos + dp);
            }
            let k = cams.len();
            cams.push(RigCamera { name: format!("cam{index:03}"), camera, holdout: self.holdout.contains(&k) });
        }
        let mut partial = Vec::new();
        for (i, c) in cams.iter().enumerate() {
            // Such a scene would be written, then refused by every command that reads it.
            if aabb.contains(c.camera.centre()) {
                let (key, fix) = match self.layout {
                    Layout::Explicit { .. } => ("rig.layout.positions", "place it outside the box"),
                    _ => (
                        "rig.distance_mm",
                        "place the rig farther from the box's centre than its corners (--distance), or shrink the box",
                    ),
                };
                return Err(SynthError::invalid(
                    key,
                    format!(
                        "camera {i} ({}) at {:?} mm is inside the reconstruction box {:?}..{:?}; {fix}",
                        c.name,
                        c.camera.centre().to_array(),
                        aabb.min.to_array(),
                        aabb.max.to_array()
                    ),
                ));
            }
            let vis = c.camera.visibility(aabb);
            if vis.box_fraction_in_view == 0.0 && vis.pixel_fraction_on_box == 0.0 {
                return Err(SynthError::CameraMissesBox { index: i, name: c.name.clone() });
            }
            // Every command that reads a scene refuses a camera no pixel of which sees the box.
            if vis.pixel_fraction_on_box == 0.0 {
                return Err(SynthError::BoxBetweenPixels { index: i, name: c.name.clone() });
            }
            if vis.box_fraction_in_view < 1.0 {
                partial.push(vis.box_fraction_in_view);
            }
        }
        // With the dissertation's 40 mm field of view on a 40 mm box, the near corners of the
        // box always fall outside the image; only say so loudly when much of the box is unseen.
        if let Some(worst) = partial.iter().copied().reduce(f64::min) {
            let msg = format!(
                "{} of {} cameras see only part of the reconstruction box (the least {:.0} % of it)",
                partial.len(),
                cams.len(),
                100.0 * worst
            );
            if worst < 0.5 {
                log::warn!("{msg}");
            } else {
                log::info!("{msg}");
            }
        }
        Ok(cams)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Images smaller than the SSIM window that scores held-out views are refused naming the
    /// key; the window's size itself is taken.
    #[test]
    fn images_smaller_than_the_ssim_window_are_refused() {
        for resolution in [[1, 1], [6, 6], [64, 6], [0, 64]] {
            let lens = LensSettings { resolution, ..Default::default() };
            let e = lens.validate().expect_err("refused").to_string();
            assert!(e.contains("`lens.resolution`") && e.contains("at least 7 pixels"), "{resolution:?}: {e}");
        }
        LensSettings { resolution: [7, 7], ..Default::default() }.validate().expect("7 × 7 is taken");
    }

    /// A pixel pitch that makes the focal length longer than a scene's camera may have is
    /// refused naming the key (1e-12 mm wrote a scene of uniform images that info refused).
    #[test]
    fn a_pitch_that_gives_too_long_a_focal_length_is_refused() {
        let lens = LensSettings { pixel_pitch_mm: Some(1e-12), ..Default::default() };
        let e = lens.validate().expect_err("refused").to_string();
        assert!(e.contains("`lens.pixel_pitch_mm`") && e.contains("is the pitch in millimetres?"), "{e}");
        let fine = LensSettings { pixel_pitch_mm: Some(1e-4), ..Default::default() };
        fine.validate().expect("a 0.1 µm pitch is taken");
        assert!(fine.intrinsics().fx < fluidnerf_core::MAX_INTRINSIC_PX);
    }
    use approx::assert_relative_eq;

    fn box40() -> Aabb {
        Aabb::cube(DVec3::ZERO, 40.0)
    }

    #[test]
    fn a_layout_of_more_cameras_than_a_rig_can_have_is_refused() {
        let ring = |count| RigSettings {
            layout: Layout::Ring { count, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X },
            ..Default::default()
        };
        assert!(ring(MAX_CAMERAS).validate().is_ok());
        let e = ring(MAX_CAMERAS + 1).validate().expect_err("too many").to_string();
        assert!(e.contains("rig.layout.count") && e.contains("1001 cameras") && e.contains("at most 1000"), "{e}");
        let sphere = RigSettings { layout: Layout::Sphere { count: 1_000_000 }, ..Default::default() };
        assert!(sphere.validate().is_err());
        let explicit = RigSettings {
            layout: Layout::Explicit { positions: vec![[0.0, 0.0, 400.0]; MAX_CAMERAS + 1], targets: vec![] },
            ..Default::default()
        };
        let e = explicit.validate().expect_err("too many").to_string();
        assert!(e.contains("rig.layout.positions"), "{e}");
    }

    #[test]
    fn cameras_too_far_for_finite_rays_are_refused_not_a_panic() {
        let lens = LensSettings { resolution: [24, 24], ..Default::default() };
        let far = RigSettings { distance_mm: Some(1e300), ..Default::default() };
        let e = far.build(&lens, &box40(), 0).expect_err("too far").to_string();
        assert!(e.contains("rig.distance_mm") && e.contains("1e300"), "{e}");
        let tiny = LensSettings { magnification: -1e-300, ..lens.clone() };
        let e = RigSettings::default().build(&tiny, &box40(), 0).expect_err("too far").to_string();
        assert!(e.contains("lens.magnification"), "{e}");
        let explicit = RigSettings {
            layout: Layout::Explicit { positions: vec![[1e200, 1e200, 0.0]], targets: vec![] },
            ..Default::default()
        };
        let e = explicit.build(&lens, &box40(), 0).expect_err("too far").to_string();
        assert!(e.contains("rig.layout.positions") && e.contains("1e200"), "{e}");
    }

    #[test]
    fn default_lens_is_the_dissertations() {
        let lens = LensSettings::default();
        assert_relative_eq!(lens.field_of_view_mm()[0], 40.0, epsilon = 1e-9);
        let small = LensSettings { resolution: [200, 200], ..Default::default() };
        assert_relative_eq!(small.field_of_view_mm()[0], 40.0, epsilon = 1e-9);
        assert_relative_eq!(small.pixel_pitch(), 0.04, epsilon = 1e-12);
        assert_relative_eq!(lens.thin_lens().object_distance(), 360.0, epsilon = 1e-9);
    }

    #[test]
    fn ring_is_perpendicular_to_the_flow_and_images_run_along_x() {
        let rig = RigSettings {
            layout: Layout::Ring { count: 12, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X },
            ..Default::default()
        };
        let lens = LensSettings { resolution: [64, 64], ..Default::default() };
        let cams = rig.build(&lens, &box40(), 0).expect("rig");
        assert_eq!(cams.len(), 12);
        for c in &cams {
            let cam = &c.camera;
            assert_relative_eq!(cam.centre().x, 0.0, epsilon = 1e-9);
            assert_relative_eq!(cam.centre().length(), 360.0, epsilon = 1e-9);
            // The box centre projects to the principal point; +x world goes right in the image.
            let o = cam.project(DVec3::ZERO).expect("in front");
            let right = cam.project(DVec3::new(5.0, 0.0, 0.0)).expect("in front");
            assert_relative_eq!(o.x, 31.5, epsilon = 1e-9);
            assert!(right.x > o.x + 1.0 && (right.y - o.y).abs() < 1e-9);
        }
        // Evenly spaced: neighbours 30° apart.
        let a = cams[0].camera.centre().normalize();
        let b = cams[1].camera.centre().normalize();
        assert_relative_eq!(a.dot(b), 30f64.to_radians().cos(), epsilon = 1e-12);
    }

    #[test]
    fn ring_about_y_circles_the_plume_and_images_rise_along_y() {
        let layout = Layout::Ring { count: 12, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::Y };
        let rig = RigSettings { layout, ..Default::default() };
        let lens = LensSettings { resolution: [64, 64], ..Default::default() };
        let cams = rig.build(&lens, &box40(), 0).expect("rig");
        assert_eq!(cams.len(), 12);
        // Angle 0 is +z, 90° is +x.
        assert_relative_eq!(cams[0].camera.centre().z, 360.0, epsilon = 1e-9);
        assert_relative_eq!(cams[3].camera.centre().x, 360.0, epsilon = 1e-9);
        for c in &cams {
            let cam = &c.camera;
            assert_relative_eq!(cam.centre().y, 0.0, epsilon = 1e-9);
            assert_relative_eq!(cam.centre().length(), 360.0, epsilon = 1e-9);
            // +y world goes up in every image (smaller row), straight up.
            let o = cam.project(DVec3::ZERO).expect("in front");
            let above = cam.project(DVec3::new(0.0, 5.0, 0.0)).expect("in front");
            assert!(above.y < o.y - 1.0 && (above.x - o.x).abs() < 1e-9, "{}: {o} → {above}", c.name);
        }
    }

    #[test]
    fn subsets_keep_names_and_sphere_is_even() {
        let rig = RigSettings {
            layout: Layout::Ring { count: 120, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X },
            subset: Subset { every: 8, ..Default::default() },
            holdout: vec![3],
            ..Default::default()
        };
        assert_eq!(rig.count(), 15);
        let lens = LensSettings { resolution: [32, 32], ..Default::default() };
        let cams = rig.build(&lens, &box40(), 0).expect("rig");
        assert_eq!(cams.len(), 15);
        assert_eq!(cams[1].name, "cam008");
        assert!(cams[3].holdout && !cams[2].holdout);
        let sphere = RigSettings { layout: Layout::Sphere { count: 40 }, ..Default::default() };
        let cams = sphere.build(&lens, &box40(), 0).expect("rig");
        let mean: DVec3 = cams.iter().map(|c| c.camera.centre()).sum::<DVec3>() / 40.0;
        assert!(mean.length() < 0.05 * 360.0, "Fibonacci lattice is balanced, mean {mean}");
    }

    #[test]
    fn bad_rigs_are_rejected() {
        let lens = LensSettings { resolution: [32, 32], ..Default::default() };
        let zero = RigSettings {
            layout: Layout::Ring { count: 0, arc_deg: 360.0, start_deg: 0.0, axis: RingAxis::X },
            ..Default::default()
        };
        assert!(matches!(zero.build(&lens, &box40(), 0), Err(SynthError::Invalid { .. })));
        let positions = vec![[0.0, 360.0, 0.0], [0.0, 0.0, 360.0]];
        let seen = RigSettings {
            layout: Layout::Explicit { positions: positions.clone(), targets: vec![] },
            ..Default::default()
        };
        assert!(seen.build(&lens, &box40(), 0).is_ok());
        let away = Layout::Explicit { positions, targets: vec![[0.0, 0.0, 0.0], [0.0, 0.0, 720.0]] };
        let missed = RigSettings { layout: away, ..Default::default() };
        assert!(matches!(missed.build(&lens, &box40(), 0), Err(SynthError::CameraMissesBox { index: 1, .. })));
        // Far enough that the box falls between the pixels' rays: the scene would be refused.
        let far = RigSettings { distance_mm: Some(1e5), ..Default::default() };
        assert!(matches!(far.build(&lens, &box40(), 0), Err(SynthError::BoxBetweenPixels { index: 0, .. })));
        let holdout = RigSettings { holdout: vec![15], ..Default::default() };
        assert!(holdout.build(&lens, &box40(), 0).is_err());
        // One camera twice, as a configuration file may list it.
        let twice = RigSettings { holdout: vec![3, 5, 3], ..Default::default() };
        let e = twice.validate().expect_err("camera 3 twice").to_string();
        assert!(e.contains("rig.holdout") && e.contains("camera 3 is given twice"), "{e}");
        let jitter = RigSettings { jitter: Jitter { position_mm: -1.0, rotation_deg: 0.0 }, ..Default::default() };
        assert!(jitter.build(&lens, &box40(), 0).is_err());
        // Angles beyond any meaning are refused by key: at a start of 1e30 degrees every camera
        // of the ring stood at the same angle.
        for (start, ok) in [(-3600.0, true), (3600.0, true), (3600.5, false), (-1e30, false), (1e30, false)] {
            let ring = Layout::Ring { count: 4, arc_deg: 360.0, start_deg: start, axis: RingAxis::X };
            let r = RigSettings { layout: ring, ..Default::default() }.validate();
            match (ok, r) {
                (true, r) => r.unwrap_or_else(|e| panic!("{start}: {e}")),
                (false, r) => {
                    let e = r.expect_err("refused").to_string();
                    assert!(e.contains("rig.layout.start_deg") && e.contains("[-3600, 3600]"), "{e}");
                }
            }
        }
        for (rotation, ok) in [(180.0, true), (180.5, false), (1e30, false)] {
            let r = RigSettings { jitter: Jitter { position_mm: 0.0, rotation_deg: rotation }, ..Default::default() };
            match (ok, r.validate()) {
                (true, r) => r.unwrap_or_else(|e| panic!("{rotation}: {e}")),
                (false, r) => {
                    let e = r.expect_err("refused").to_string();
                    assert!(e.contains("rig.jitter.rotation_deg") && e.contains("at most 180 degrees"), "{e}");
                }
            }
        }
        // A shift beyond the cameras' distance from what they look at is no perturbation of a
        // pose: at 1e300 mm every camera was refused as blind to the box, the jitter unnamed.
        let lens32 = LensSettings { resolution: [32, 32], ..Default::default() };
        let jitter = |position_mm: f64, layout: Layout| RigSettings {
            layout,
            jitter: Jitter { position_mm, rotation_deg: 0.0 },
            ..Default::default()
        };
        jitter(2.0, Layout::default()).build(&lens32, &box40(), 0).expect("a small shift");
        for position in [360.5, 1e300] {
            let e = jitter(position, Layout::default()).build(&lens32, &box40(), 0).expect_err("refused").to_string();
            let says = format!(
                "invalid setting `rig.jitter.position_mm`: must be at most 360 mm, the cameras' distance from the point they look \
                 at (a larger shift is no perturbation of a pose), got {}",
                num(position)
            );
            assert!(e.contains(&says), "{e}");
        }
        let explicit = Layout::Explicit { positions: vec![[0.0, 360.0, 0.0], [0.0, 0.0, 200.0]], targets: vec![] };
        let e = jitter(250.0, explicit).build(&lens32, &box40(), 0).expect_err("refused").to_string();
        assert!(e.contains("must be at most 200 mm, the cameras' distance from the point they look at"), "{e}");
        // A camera inside the box: its scene would be written, then refused by every reader.
        let inside = RigSettings { distance_mm: Some(10.0), ..Default::default() };
        let e = inside.build(&lens, &box40(), 0).expect_err("a camera inside the box").to_string();
        assert!(e.contains("rig.distance_mm") && e.contains("camera 0 (cam000)") && e.contains("inside"), "{e}");
        let explicit = Layout::Explicit { positions: vec![[0.0, 360.0, 0.0], [5.0, 0.0, 0.0]], targets: vec![] };
        let inside = RigSettings { layout: explicit, ..Default::default() };
        let e = inside.build(&lens, &box40(), 0).expect_err("a camera inside the box").to_string();
        assert!(e.contains("rig.layout.positions") && e.contains("camera 1 (cam001)"), "{e}");
    }

    #[test]
    fn jitter_is_seeded_and_small() {
        let rig = RigSettings { jitter: Jitter { position_mm: 1.0, rotation_deg: 0.5 }, ..Default::default() };
        let lens = LensSettings { resolution: [32, 32], ..Default::default() };
        let a = rig.build(&lens, &box40(), 1).expect("rig");
        let b = rig.build(&lens, &box40(), 1).expect("rig");
        let c = rig.build(&lens, &box40(), 2).expect("rig");
        assert_eq!(a, b);
        assert_ne!(a, c);
        for cam in &a {
            assert!(cam.camera.validate().is_ok());
            assert!((cam.camera.centre().length() - 360.0).abs() < 6.0);
        }
    }
}
