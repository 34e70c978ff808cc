//! The registry of classical methods: one enum holding each method's parameters, with the
//! operations every caller needs — validate, estimate memory, solve — so that front ends
//! (the run pipeline, benchmarks, scripts) never match on methods themselves.
//!
//! [`ProjectorConfig`] holds what all voxel methods share: the projector, its sampling, and the
//! optional visual-hull support mask.

use std::ops::ControlFlow;

use fluidnerf_core::num;
use fluidnerf_core::{Camera, Image};
use serde::{Deserialize, Serialize};

use crate::{
    art, asart, estimate_memory, mart, mlem, sart, sart_tikhonov, sart_tv, smart, visual_hull, Algorithm, ArtParams,
    AsartParams, ClassicalError, FootprintProjector, Grid, IterState, MartParams, MemoryEstimate, MlemParams, Problem,
    Projector, ProjectorKind, RayProjector, Report, SartParams, SmartParams, SplatProjector, Stopping, TikhonovParams,
    TvParams, DEFAULT_HULL_NOISE_SIGMAS, DEFAULT_HULL_THRESHOLD,
};

/// A classical method and its parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum ClassicalMethod {
    Asart(AsartParams),
    Art(ArtParams),
    Sart(SartParams),
    Mart(MartParams),
    Smart(SmartParams),
    Mlem(MlemParams),
    Tv(TvParams),
    Tikhonov(TikhonovParams),
}

/// The largest `tv_weight` of SART-TV: a TV step as large as the SART step it is tied to.
pub const MAX_TV_WEIGHT: f64 = 1.0;

/// The most TV descent steps per SART-TV iteration (the default is 20).
pub const MAX_TV_STEPS: usize = 1000;

/// The largest Tikhonov weight λ: an iteration then takes up to 2880 smoothing passes (μ ≤ 2),
/// and with μ = 1 already damps a wavelength of ten voxels by about three quarters.
pub const MAX_TIKHONOV_WEIGHT: f64 = 10.0;

/// The largest tolerance of the plateau rule ([`crate::Plateau::tolerance`]): a relative
/// variation of the residual as large as the residual itself.
pub const MAX_PLATEAU_TOLERANCE: f64 = 1.0;

impl ClassicalMethod {
    /// The method's defaults.
    pub fn default_for(algorithm: Algorithm) -> Self {
        match algorithm {
            Algorithm::Asart => ClassicalMethod::Asart(AsartParams::default()),
            Algorithm::Art => ClassicalMethod::Art(ArtParams::default()),
            Algorithm::Sart => ClassicalMethod::Sart(SartParams::default()),
            Algorithm::Mart => ClassicalMethod::Mart(MartParams::default()),
            Algorithm::Smart => ClassicalMethod::Smart(SmartParams::default()),
            Algorithm::Mlem => ClassicalMethod::Mlem(MlemParams::default()),
            Algorithm::Tv => ClassicalMethod::Tv(TvParams::default()),
            Algorithm::Tikhonov => ClassicalMethod::Tikhonov(TikhonovParams::default()),
        }
    }

    pub fn algorithm(&self) -> Algorithm {
        match self {
            ClassicalMethod::Asart(_) => Algorithm::Asart,
            ClassicalMethod::Art(_) => Algorithm::Art,
            ClassicalMethod::Sart(_) => Algorithm::Sart,
            ClassicalMethod::Mart(_) => Algorithm::Mart,
            ClassicalMethod::Smart(_) => Algorithm::Smart,
            ClassicalMethod::Mlem(_) => Algorithm::Mlem,
            ClassicalMethod::Tv(_) => Algorithm::Tv,
            ClassicalMethod::Tikhonov(_) => Algorithm::Tikhonov,
        }
    }

    /// The stopping rule.
    pub fn stopping(&self) -> &Stopping {
        match self {
            ClassicalMethod::Asart(p) => &p.stopping,
            ClassicalMethod::Art(p) => &p.stopping,
            ClassicalMethod::Sart(p) => &p.stopping,
            ClassicalMethod::Mart(p) => &p.stopping,
            ClassicalMethod::Smart(p) => &p.stopping,
            ClassicalMethod::Mlem(p) => &p.stopping,
            ClassicalMethod::Tv(p) => &p.stopping,
            ClassicalMethod::Tikhonov(p) => &p.stopping,
        }
    }

    pub fn stopping_mut(&mut self) -> &mut Stopping {
        match self {
            ClassicalMethod::Asart(p) => &mut p.stopping,
            ClassicalMethod::Art(p) => &mut p.stopping,
            ClassicalMethod::Sart(p) => &mut p.stopping,
            ClassicalMethod::Mart(p) => &mut p.stopping,
            ClassicalMethod::Smart(p) => &mut p.stopping,
            ClassicalMethod::Mlem(p) => &mut p.stopping,
            ClassicalMethod::Tv(p) => &mut p.stopping,
            ClassicalMethod::Tikhonov(p) => &mut p.stopping,
        }
    }

    /// The budget for views' rows kept between iterations, for the methods that keep them (ART
    /// and MART).
    pub fn row_cache_mib(&self) -> Option<u64> {
        match self {
            ClassicalMethod::Art(p) => Some(p.row_cache_mib),
            ClassicalMethod::Mart(p) => Some(p.row_cache_mib),
            _ => None,
        }
    }

    /// Whether the method back-projects its views in every iteration, so that footprints kept
    /// between projections ([`ProjectorConfig::kept_footprints_mib`]) save work. ART and MART
    /// work on the views' rows instead.
    pub fn back_projects(&self) -> bool {
        !matches!(self, ClassicalMethod::Art(_) | ClassicalMethod::Mart(_))
    }

    /// [`Self::row_cache_mib`], to change.
    pub fn row_cache_mib_mut(&mut self) -> Option<&mut u64> {
        match self {
            ClassicalMethod::Art(p) => Some(&mut p.row_cache_mib),
            ClassicalMethod::Mart(p) => Some(&mut p.row_cache_mib),
            _ => None,
        }
    }

    /// The relaxation factor μ, for the methods that have one (MLEM has none).
    pub fn relaxation_mut(&mut self) -> Option<&mut f64> {
        match self {
            ClassicalMethod::Asart(p) => Some(&mut p.relaxation),
            ClassicalMethod::Art(p) => Some(&mut p.relaxation),
            ClassicalMethod::Sart(p) => Some(&mut p.relaxation),
            ClassicalMethod::Mart(p) => Some(&mut p.relaxation),
            ClassicalMethod::Smart(p) => Some(&mut p.relaxation),
            ClassicalMethod::Mlem(_) => None,
            ClassicalMethod::Tv(p) => Some(&mut p.relaxation),
            ClassicalMethod::Tikhonov(p) => Some(&mut p.relaxation),
        }
    }

    /// Sets the seed of the methods that draw a random row order (ART, MART).
    pub fn set_seed(&mut self, seed: u64) {
        match self {
            ClassicalMethod::Art(p) => p.seed = seed,
            ClassicalMethod::Mart(p) => p.seed = seed,
            _ => {}
        }
    }

    /// Rejects parameters no run can use. `what` names are the configuration keys.
    pub fn validate(&self) -> Result<(), ClassicalError> {
        let stopping = self.stopping();
        let max = fluidnerf_core::MAX_ITERATIONS;
        if !(1..=max).contains(&stopping.max_iterations) {
            return Err(ClassicalError::invalid(
                "stopping.max_iterations",
                format!("must be 1 to {max} iterations, got {}", stopping.max_iterations),
            ));
        }
        if let Some(p) = stopping.plateau {
            // A span longer than any run would never stop it, and 2⁶⁴ − 1 overflowed the rule.
            let span = fluidnerf_core::MAX_ITERATION_SPAN;
            for (key, n) in [("stopping.plateau.window", p.window), ("stopping.plateau.smoothing", p.smoothing)] {
                if n > span {
                    return Err(ClassicalError::invalid(key, format!("must be at most {span} iterations, got {n}")));
                }
            }
            // The tolerance is a relative variation, (max − min) / mean of a residual that
            // falls as the run converges: a variation as large as the residual itself is no
            // plateau, and beyond 1 the rule stops a run right after its first window (1e300 did).
            if p.tolerance > MAX_PLATEAU_TOLERANCE {
                return Err(ClassicalError::invalid(
                    "stopping.plateau.tolerance",
                    format!(
                        "must be at most {} (a fraction of the residual; a larger one stops the run after its \
                         first window), got {}",
                        num(MAX_PLATEAU_TOLERANCE),
                        num(p.tolerance)
                    ),
                ));
            }
            if !(p.tolerance > 0.0 && p.tolerance.is_finite() && p.window > 0 && p.smoothing > 0) {
                return Err(ClassicalError::invalid(
                    "stopping.plateau",
                    format!(
                        "needs window > 0, smoothing > 0 and a positive tolerance, got window {}, smoothing {}, \
                         tolerance {}",
                        p.window,
                        p.smoothing,
                        num(p.tolerance)
                    ),
                ));
            }
        }
        let mut copy = self.clone();
        let algorithm = self.algorithm();
        if let Some(&mut mu) = copy.relaxation_mut() {
            // The multiplicative methods' exponent is at most 1 (Eqs. 2.25, 2.28). The additive
            // ones converge for μ in (0, 2): at 2 a row's step reflects the iterate across the
            // row's hyperplane instead of moving towards it, and the iteration need not settle.
            let multiplicative = matches!(algorithm, Algorithm::Mart | Algorithm::Smart);
            let (ok, range) =
                if multiplicative { (mu > 0.0 && mu <= 1.0, "(0, 1]") } else { (mu > 0.0 && mu < 2.0, "(0, 2)") };
            if !ok {
                return Err(ClassicalError::invalid(
                    "relaxation",
                    format!("for {algorithm:?} must be in {range}, got {}", num(mu)),
                ));
            }
        }
        let non_negative = |what: &str, v: f64| {
            if v >= 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(ClassicalError::invalid(what, format!("must be non-negative, got {}", num(v))))
            }
        };
        // `why` says what goes wrong beyond `max`.
        let at_most = |what: &str, v: f64, max: f64, why: &str| {
            if v <= max {
                Ok(())
            } else {
                Err(ClassicalError::invalid(what, format!("must be at most {} ({why}), got {}", num(max), num(v))))
            }
        };
        match self {
            ClassicalMethod::Tv(p) => {
                non_negative("tv_weight", p.tv_weight)?;
                // A TV step larger than the SART step it is tied to overshoots, and the
                // iteration diverges (on a blobs scene, 2 gave an NRMSE of 165 after 20
                // iterations, 10 one of 4e16) or, far beyond, sets every voxel to zero.
                at_most("tv_weight", p.tv_weight, MAX_TV_WEIGHT, "a TV step as large as the SART step")?;
                at_most("tv_steps", p.tv_steps as f64, MAX_TV_STEPS as f64, "TV steps per iteration")
            }
            ClassicalMethod::Tikhonov(p) => {
                non_negative("weight", p.weight)?;
                // Each iteration takes ⌈144 μ λ⌉ smoothing passes over the grid: a huge λ never
                // finishes its first iteration.
                at_most("weight", p.weight, MAX_TIKHONOV_WEIGHT, "an iteration smooths the grid in ⌈144 μ λ⌉ passes")
            }
            _ => Ok(()),
        }
    }

    /// Runs the method on `problem` from `init` (the method's own start if `None`).
    pub fn solve(
        &self,
        problem: &Problem,
        init: Option<&[f32]>,
        on_iter: impl FnMut(&IterState) -> ControlFlow<()>,
    ) -> Result<Report, ClassicalError> {
        match self {
            ClassicalMethod::Asart(p) => asart(problem, init, p, on_iter),
            ClassicalMethod::Art(p) => art(problem, init, p, on_iter),
            ClassicalMethod::Sart(p) => sart(problem, init, p, on_iter),
            ClassicalMethod::Mart(p) => mart(problem, init, p, on_iter),
            ClassicalMethod::Smart(p) => smart(problem, init, p, on_iter),
            ClassicalMethod::Mlem(p) => mlem(problem, init, p, on_iter),
            ClassicalMethod::Tv(p) => sart_tv(problem, init, p, on_iter),
            ClassicalMethod::Tikhonov(p) => sart_tikhonov(problem, init, p, on_iter),
        }
    }

    /// Estimated peak memory of solving on `grid` with `projector` and views of `view_sizes`.
    pub fn memory(
        &self,
        projector: &ProjectorConfig,
        grid: &Grid,
        cameras: &[Camera],
        threads: usize,
    ) -> MemoryEstimate {
        let sizes: Vec<(usize, usize)> = cameras.iter().map(|c| (c.width(), c.height())).collect();
        let kind = projector.resolve(grid, cameras);
        let row_cache_mib = self.row_cache_mib().unwrap_or(0);
        let mut estimate = estimate_memory(
            self.algorithm(),
            kind,
            grid,
            &sizes,
            threads,
            projector.subdivisions(grid, cameras),
            row_cache_mib.saturating_mul(1 << 20),
        );
        if self.back_projects() {
            estimate.projector = estimate.projector.saturating_add(projector.kept_footprint_bytes(grid, cameras));
        }
        estimate
    }
}

/// What every voxel method shares: the projector and the optional visual-hull support.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ProjectorConfig {
    /// Default `auto`: the footprint projector unless voxels image wider than it holds, then the
    /// ray projector ([`ProjectorConfig::resolve`]); `footprint`, `splat` (the dissertation's)
    /// and `ray` force one.
    pub kind: ProjectorKind,
    /// Sub-voxels per axis of the splat; 0 chooses from the voxel's image size
    /// ([`SplatProjector::auto_subdivisions`]). Default 0.
    pub splat_subdivisions: usize,
    /// Sampling step of the ray projector, in voxel sides. Default 0.5.
    pub ray_step: f64,
    /// Hold voxels at zero whose centre projects onto a dark pixel in any view. Default false.
    pub visual_hull: bool,
    /// Dark threshold of the hull, a fraction of each image's maximum. Default 0.02.
    pub hull_threshold: f64,
    /// Noise deviations above each image's background that still count as dark in the hull, when
    /// that is above `hull_threshold` ([`crate::dark_level`]). Default 4; a saved
    /// configuration without the key reads 0, the threshold alone, as it was run.
    #[serde(default)]
    pub hull_noise_sigmas: f64,
    /// Voxels by which the hull is dilated after carving ([`crate::visual_hull`]). Default 1;
    /// a saved configuration without the key reads 0, as it was run.
    #[serde(default)]
    pub hull_dilation: usize,
    /// MiB of footprints the footprint projector may keep between back projections, for views
    /// whose grid rows share a footprint axis (rings around the grid's `x` axis; see
    /// [`FootprintProjector::with_kept_footprints`]): about 20 bytes per voxel and view. The
    /// volumes do not depend on it. Default 0, none: on the demo scene (128³, 15 views, 30
    /// iterations) keeping them made ASART, MLEM and SART-TV 2–10 % faster for ten times the
    /// memory (530 MiB against 50), the back projection itself 1.5–1.9× (`docs/projectors.md`).
    pub kept_footprints_mib: u64,
}

impl Default for ProjectorConfig {
    fn default() -> Self {
        ProjectorConfig {
            kind: ProjectorKind::Auto,
            splat_subdivisions: 0,
            ray_step: 0.5,
            visual_hull: false,
            hull_threshold: DEFAULT_HULL_THRESHOLD,
            hull_noise_sigmas: DEFAULT_HULL_NOISE_SIGMAS,
            hull_dilation: 1,
            kept_footprints_mib: 0,
        }
    }
}

impl ProjectorConfig {
    /// Rejects settings out of range ([`ProjectorConfig::validate_ranges`]), then settings the
    /// configuration would ignore ([`ProjectorConfig::refuse_idle_settings`]).
    pub fn validate(&self) -> Result<(), ClassicalError> {
        self.validate_ranges()?;
        self.refuse_idle_settings()
    }

    /// Rejects settings out of range, whether the configuration uses them or not.
    pub fn validate_ranges(&self) -> Result<(), ClassicalError> {
        if self.splat_subdivisions > 16 {
            return Err(ClassicalError::invalid(
                "splat_subdivisions",
                format!("must be at most 16, got {}", self.splat_subdivisions),
            ));
        }
        if !(self.ray_step >= 0.01 && self.ray_step <= 4.0) {
            return Err(ClassicalError::invalid(
                "ray_step",
                format!("must be in [0.01, 4] voxel sides, got {}", num(self.ray_step)),
            ));
        }
        if !(self.hull_threshold >= 0.0 && self.hull_threshold < 1.0) {
            return Err(ClassicalError::invalid(
                "hull_threshold",
                format!("must be in [0, 1), got {}", num(self.hull_threshold)),
            ));
        }
        if self.hull_dilation > 16 {
            return Err(ClassicalError::invalid(
                "hull_dilation",
                format!("must be at most 16 voxels, got {}", self.hull_dilation),
            ));
        }
        if !(self.hull_noise_sigmas >= 0.0 && self.hull_noise_sigmas <= 100.0) {
            return Err(ClassicalError::invalid(
                "hull_noise_sigmas",
                format!("must be in [0, 100], got {}", num(self.hull_noise_sigmas)),
            ));
        }
        Ok(())
    }

    /// Refuses a setting of a projector this configuration does not use (`ray_step` beside the
    /// footprint or splat projector, `splat_subdivisions` beside any but the splat) and the
    /// hull's settings without `visual_hull`, when set away from their defaults: each would be
    /// ignored. A setting at its default is what every saved configuration holds, and the hull's
    /// `hull_noise_sigmas` and `hull_dilation` also read 0 where a configuration saved before
    /// them leaves them out, so those are taken.
    pub fn refuse_idle_settings(&self) -> Result<(), ClassicalError> {
        let d = ProjectorConfig::default();
        let kind = match self.kind {
            ProjectorKind::Auto => "auto",
            ProjectorKind::Footprint => "footprint",
            ProjectorKind::Splat => "splat",
            ProjectorKind::Ray => "ray",
        };
        // `auto` chooses the ray projector where voxels image wide, never the splat.
        if self.ray_step != d.ray_step && !matches!(self.kind, ProjectorKind::Ray | ProjectorKind::Auto) {
            return Err(ClassicalError::invalid(
                "ray_step",
                format!(
                    "{} sets the ray projector's step, but kind is {kind}, which casts no rays: it would be \
                     ignored; set kind ray (or auto), or leave ray_step at its default {}",
                    num(self.ray_step),
                    num(d.ray_step)
                ),
            ));
        }
        if self.splat_subdivisions != d.splat_subdivisions && self.kind != ProjectorKind::Splat {
            return Err(ClassicalError::invalid(
                "splat_subdivisions",
                format!(
                    "{} sets the splat projector's sub-voxels, but kind is {kind}: it would be ignored; set kind \
                     splat, or leave splat_subdivisions at its default {}",
                    self.splat_subdivisions, d.splat_subdivisions
                ),
            ));
        }
        if !self.visual_hull {
            let idle = [
                (
                    "hull_threshold",
                    self.hull_threshold != d.hull_threshold,
                    num(self.hull_threshold).to_string(),
                    num(d.hull_threshold).to_string(),
                ),
                (
                    "hull_noise_sigmas",
                    self.hull_noise_sigmas != d.hull_noise_sigmas && self.hull_noise_sigmas != 0.0,
                    num(self.hull_noise_sigmas).to_string(),
                    num(d.hull_noise_sigmas).to_string(),
                ),
                (
                    "hull_dilation",
                    self.hull_dilation != d.hull_dilation && self.hull_dilation != 0,
                    self.hull_dilation.to_string(),
                    d.hull_dilation.to_string(),
                ),
            ];
            if let Some((key, _, value, default)) = idle.into_iter().find(|k| k.1) {
                return Err(ClassicalError::invalid(
                    key,
                    format!(
                        "{value} sets the visual hull, which visual_hull false leaves unused: it would be ignored; \
                         set visual_hull true, or leave {key} at its default {default}"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Sub-voxels per axis the splat will use on `grid` seen by `cameras`.
    pub fn subdivisions(&self, grid: &Grid, cameras: &[Camera]) -> usize {
        match self.splat_subdivisions {
            0 => SplatProjector::auto_subdivisions(grid, cameras),
            n => n,
        }
    }

    /// The projector `kind` stands for on `grid` seen by `cameras`: `auto` becomes the
    /// footprint projector when the widest voxel footprint in any view
    /// ([`FootprintProjector::largest_footprint_px`]) is at most
    /// [`crate::AUTO_FOOTPRINT_MAX_PX`] pixels, else the ray projector (see the
    /// [`crate::projector`] docs for the measurements behind the rule); the others stay.
    pub fn resolve(&self, grid: &Grid, cameras: &[Camera]) -> ProjectorKind {
        match self.kind {
            ProjectorKind::Auto => {
                if FootprintProjector::largest_footprint_px(grid, cameras) <= crate::AUTO_FOOTPRINT_MAX_PX {
                    ProjectorKind::Footprint
                } else {
                    ProjectorKind::Ray
                }
            }
            kind => kind,
        }
    }

    /// The projector of `grid` seen by `cameras` ([`ProjectorConfig::resolve`] picks it).
    /// The renaming of the world's axes under which this projector's grid rows share their
    /// footprints ([`crate::AxisShift::for_rows`]): the identity unless it resolves to the
    /// footprint projector, the only one that shares them.
    pub fn row_shift(&self, grid: &Grid, cameras: &[Camera]) -> crate::AxisShift {
        if self.resolve(grid, cameras) == ProjectorKind::Footprint {
            crate::AxisShift::for_rows(cameras)
        } else {
            crate::AxisShift::IDENTITY
        }
    }

    pub fn build(
        &self,
        grid: Grid,
        cameras: &[Camera],
        intensity_scale: f64,
    ) -> Result<Box<dyn Projector>, ClassicalError> {
        Ok(match self.resolve(&grid, cameras) {
            ProjectorKind::Auto | ProjectorKind::Footprint => Box::new(
                FootprintProjector::new(grid, cameras, intensity_scale)?
                    .with_kept_footprints(self.kept_footprint_budget()),
            ),
            ProjectorKind::Splat => Box::new(
                SplatProjector::new(grid, cameras, intensity_scale)?
                    .with_subdivisions(self.subdivisions(&grid, cameras)),
            ),
            ProjectorKind::Ray => Box::new(RayProjector::new(grid, cameras, intensity_scale, self.ray_step)?),
        })
    }

    fn kept_footprint_budget(&self) -> u64 {
        self.kept_footprints_mib.saturating_mul(1 << 20)
    }

    /// Bytes the footprints kept by the projector of `grid` seen by `cameras` take once every
    /// view has been back-projected: at most [`Self::kept_footprints_mib`], 0 for the other
    /// projectors.
    pub fn kept_footprint_bytes(&self, grid: &Grid, cameras: &[Camera]) -> u64 {
        if self.kept_footprints_mib == 0 {
            return 0;
        }
        match self.resolve(grid, cameras) {
            ProjectorKind::Auto | ProjectorKind::Footprint => FootprintProjector::new(*grid, cameras, 1.0)
                .map_or(0, |p| p.with_kept_footprints(self.kept_footprint_budget()).kept_footprint_bytes()),
            _ => 0,
        }
    }

    /// The support mask, when the visual hull is on.
    pub fn support(&self, grid: &Grid, cameras: &[Camera], images: &[Image]) -> Option<Vec<bool>> {
        self.visual_hull.then(|| {
            visual_hull(grid, cameras, images, self.hull_threshold, self.hull_noise_sigmas, self.hull_dilation)
        })
    }
}

/// Largest side of a voxel's image, in pixels, over the views (at the box centre).
pub fn voxel_footprint_px(cameras: &[Camera], grid: &Grid) -> f64 {
    let side = grid.spacing().max_element();
    cameras
        .iter()
        .map(|c| {
            let depth = (grid.aabb.centre() - c.centre()).dot(c.forward()).max(1e-9);
            side * c.intrinsics.fx.max(c.intrinsics.fy) / depth
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_key() {
        let mut m = ClassicalMethod::default_for(Algorithm::Mart);
        *m.relaxation_mut().unwrap() = 1.5;
        let e = m.validate().unwrap_err().to_string();
        assert!(e.contains("relaxation") && e.contains("(0, 1]"), "{e}");
        let mut m = ClassicalMethod::default_for(Algorithm::Asart);
        m.stopping_mut().max_iterations = 0;
        assert!(m.validate().unwrap_err().to_string().contains("max_iterations"));
        assert!(ClassicalMethod::default_for(Algorithm::Mlem).validate().is_ok());
        let p = ProjectorConfig { ray_step: 0.0, ..Default::default() };
        assert!(p.validate().unwrap_err().to_string().contains("ray_step"));
    }

    /// A projector's own setting for another projector, or a hull setting without the hull,
    /// would be ignored: refused when away from its default, named by its key.
    #[test]
    fn a_setting_the_projector_does_not_use_is_refused_naming_its_key() {
        let d = ProjectorConfig::default();
        for (p, key, says) in [
            (ProjectorConfig { kind: ProjectorKind::Footprint, ray_step: 0.3, ..d.clone() }, "ray_step", "footprint"),
            (ProjectorConfig { kind: ProjectorKind::Splat, ray_step: 0.3, ..d.clone() }, "ray_step", "splat"),
            (
                ProjectorConfig { kind: ProjectorKind::Ray, splat_subdivisions: 2, ..d.clone() },
                "splat_subdivisions",
                "ray",
            ),
            (ProjectorConfig { hull_threshold: 0.1, ..d.clone() }, "hull_threshold", "visual_hull"),
            (ProjectorConfig { hull_noise_sigmas: 2.0, ..d.clone() }, "hull_noise_sigmas", "visual_hull"),
            (ProjectorConfig { hull_dilation: 3, ..d.clone() }, "hull_dilation", "visual_hull"),
        ] {
            let e = p.validate().expect_err(key).to_string();
            assert!(e.contains(key) && e.contains(says) && e.contains("would be ignored"), "{key}: {e}");
        }
        // Defaults, the 0 an older configuration reads for absent hull keys, and settings of
        // the projector and hull in use are taken.
        for p in [
            d.clone(),
            ProjectorConfig { hull_noise_sigmas: 0.0, hull_dilation: 0, ..d.clone() },
            ProjectorConfig { kind: ProjectorKind::Ray, ray_step: 0.3, ..d.clone() },
            ProjectorConfig { ray_step: 0.3, ..d.clone() },
            ProjectorConfig { kind: ProjectorKind::Splat, splat_subdivisions: 2, ..d.clone() },
            ProjectorConfig { visual_hull: true, hull_threshold: 0.1, hull_noise_sigmas: 2.0, hull_dilation: 3, ..d },
        ] {
            p.validate().unwrap_or_else(|e| panic!("{p:?}: {e}"));
        }
    }

    #[test]
    fn every_algorithm_round_trips() {
        for a in Algorithm::ALL {
            let m = ClassicalMethod::default_for(a);
            assert_eq!(m.algorithm(), a);
            m.validate().unwrap();
        }
    }

    /// Every range is closed or open where its documentation says: the limit itself is taken
    /// (or refused) and the next value beyond it refused.
    #[test]
    fn each_limit_is_taken_and_the_next_value_refused() {
        let with = |a: Algorithm, f: &dyn Fn(&mut ClassicalMethod)| {
            let mut m = ClassicalMethod::default_for(a);
            f(&mut m);
            m.validate()
        };
        let mu = |a, v: f64| with(a, &|m| *m.relaxation_mut().unwrap() = v);
        assert!(mu(Algorithm::Mart, 1.0).is_ok() && mu(Algorithm::Smart, 1.0).is_ok());
        assert!(mu(Algorithm::Mart, 1.0001).is_err() && mu(Algorithm::Mart, 0.0).is_err());
        assert!(mu(Algorithm::Sart, 1.99).is_ok() && mu(Algorithm::Art, 1.5).is_ok());
        assert!(mu(Algorithm::Sart, 2.0).is_err() && mu(Algorithm::Asart, 0.0).is_err());
        assert!(mu(Algorithm::Tv, f64::NAN).is_err());
        let max = fluidnerf_core::MAX_ITERATIONS;
        assert!(with(Algorithm::Sart, &|m| m.stopping_mut().max_iterations = max).is_ok());
        assert!(with(Algorithm::Sart, &|m| m.stopping_mut().max_iterations = max + 1).is_err());
        let span = fluidnerf_core::MAX_ITERATION_SPAN;
        let plateau = |p: crate::Plateau| with(Algorithm::Mlem, &move |m| m.stopping_mut().plateau = Some(p));
        let d = crate::Plateau::default();
        assert!(plateau(crate::Plateau { window: span, smoothing: span, ..d }).is_ok());
        let e = plateau(crate::Plateau { window: span + 1, ..d }).unwrap_err().to_string();
        assert!(e.contains("stopping.plateau.window"), "{e}");
        let e = plateau(crate::Plateau { smoothing: span + 1, ..d }).unwrap_err().to_string();
        assert!(e.contains("stopping.plateau.smoothing"), "{e}");
        assert!(plateau(crate::Plateau { tolerance: MAX_PLATEAU_TOLERANCE, ..d }).is_ok());
        assert!(plateau(crate::Plateau { tolerance: 1.0001, ..d }).is_err());
        for bad in [
            crate::Plateau { tolerance: 0.0, ..d },
            crate::Plateau { window: 0, ..d },
            crate::Plateau { smoothing: 0, ..d },
        ] {
            assert!(plateau(bad).is_err(), "{bad:?}");
        }
        let tv = |w: f64, steps: usize| {
            with(Algorithm::Tv, &move |m| {
                if let ClassicalMethod::Tv(p) = m {
                    (p.tv_weight, p.tv_steps) = (w, steps);
                }
            })
        };
        assert!(tv(MAX_TV_WEIGHT, MAX_TV_STEPS).is_ok() && tv(0.0, 0).is_ok());
        assert!(tv(1.0001, 20).is_err() && tv(-0.1, 20).is_err() && tv(0.2, MAX_TV_STEPS + 1).is_err());
        let tik = |w: f64| {
            with(Algorithm::Tikhonov, &move |m| {
                if let ClassicalMethod::Tikhonov(p) = m {
                    p.weight = w;
                }
            })
        };
        assert!(tik(MAX_TIKHONOV_WEIGHT).is_ok() && tik(0.0).is_ok());
        assert!(tik(10.001).is_err() && tik(-1e-9).is_err() && tik(f64::INFINITY).is_err());

        let d = ProjectorConfig { kind: ProjectorKind::Splat, visual_hull: true, ..Default::default() };
        let ok = |p: ProjectorConfig| p.validate_ranges().is_ok();
        assert!(ok(ProjectorConfig { splat_subdivisions: 16, ..d.clone() }));
        assert!(!ok(ProjectorConfig { splat_subdivisions: 17, ..d.clone() }));
        assert!(
            ok(ProjectorConfig { ray_step: 0.01, ..d.clone() }) && ok(ProjectorConfig { ray_step: 4.0, ..d.clone() })
        );
        assert!(!ok(ProjectorConfig { ray_step: 0.0099, ..d.clone() }));
        assert!(!ok(ProjectorConfig { ray_step: 4.01, ..d.clone() }));
        assert!(ok(ProjectorConfig { hull_threshold: 0.0, ..d.clone() }));
        assert!(!ok(ProjectorConfig { hull_threshold: 1.0, ..d.clone() }));
        assert!(!ok(ProjectorConfig { hull_threshold: -0.01, ..d.clone() }));
        assert!(ok(ProjectorConfig { hull_dilation: 16, ..d.clone() }));
        assert!(!ok(ProjectorConfig { hull_dilation: 17, ..d.clone() }));
        assert!(ok(ProjectorConfig { hull_noise_sigmas: 100.0, ..d.clone() }));
        assert!(!ok(ProjectorConfig { hull_noise_sigmas: 100.5, ..d.clone() }));
        assert!(!ok(ProjectorConfig { hull_noise_sigmas: -1.0, ..d }));
    }

    /// The settings only some methods have are reached through them alone.
    #[test]
    fn the_method_specific_settings_belong_to_their_methods() {
        for a in Algorithm::ALL {
            let mut m = ClassicalMethod::default_for(a);
            let rows = matches!(a, Algorithm::Art | Algorithm::Mart);
            assert_eq!(m.row_cache_mib(), rows.then_some(crate::ROW_CACHE_MIB), "{a:?}");
            assert_eq!(m.back_projects(), !rows, "{a:?}");
            if let Some(mib) = m.row_cache_mib_mut() {
                *mib = 7;
            }
            assert_eq!(m.row_cache_mib(), rows.then_some(7), "{a:?}");
            assert_eq!(m.relaxation_mut().is_some(), a != Algorithm::Mlem, "{a:?}");
            m.stopping_mut().max_iterations = 3;
            assert_eq!(m.stopping().max_iterations, 3, "{a:?}");
            m.set_seed(9);
            match m {
                ClassicalMethod::Art(p) => assert_eq!(p.seed, 9),
                ClassicalMethod::Mart(p) => assert_eq!(p.seed, 9),
                other => assert_eq!(other.stopping().max_iterations, 3),
            }
        }
    }

    /// A voxel of side 0.5 seen from 10 units along the view with a focal length of 60 px
    /// images 3 px wide; the widest view counts.
    #[test]
    fn a_voxels_footprint_is_its_side_times_the_focal_length_over_the_depth() {
        use fluidnerf_core::{Aabb, Intrinsics};
        use glam::DVec3;
        let k = |f: f64| Intrinsics { width: 32, height: 32, fx: f, fy: f / 2.0, cx: 15.5, cy: 15.5, skew: 0.0 };
        let grid = Grid::new([8, 4, 4], Aabb::new(DVec3::ZERO, DVec3::new(4.0, 2.0, 2.0)));
        let centre = grid.aabb.centre();
        let near = Camera::look_at(k(60.0), centre + DVec3::new(0.0, 0.0, 10.0), centre, DVec3::Y);
        let far = Camera::look_at(k(60.0), centre + DVec3::new(0.0, 20.0, 0.0), centre, DVec3::X);
        assert!((voxel_footprint_px(std::slice::from_ref(&near), &grid) - 3.0).abs() < 1e-9);
        assert!((voxel_footprint_px(&[far.clone(), near], &grid) - 3.0).abs() < 1e-9);
        assert!((voxel_footprint_px(&[far], &grid) - 1.5).abs() < 1e-9);
        assert_eq!(voxel_footprint_px(&[], &grid), 0.0);
    }

    /// `auto` is the footprint projector while voxels image small and the ray projector
    /// beyond; only the footprint projector renames the axes for its rows; the hull is
    /// built only when asked for.
    #[test]
    fn auto_picks_the_projector_by_the_voxels_image_size() {
        use fluidnerf_core::{Aabb, Image, Intrinsics};
        use glam::DVec3;
        let grid = Grid::new([8, 8, 8], Aabb::cube(DVec3::ZERO, 2.0));
        let ring = |f: f64| -> Vec<Camera> {
            let k = Intrinsics { width: 64, height: 64, fx: f, fy: f, cx: 31.5, cy: 31.5, skew: 0.0 };
            (0..3)
                .map(|i| {
                    let a = 0.3 + i as f64;
                    Camera::look_at(k, DVec3::new(9.0 * a.cos(), 0.0, 9.0 * a.sin()), DVec3::ZERO, DVec3::Y)
                })
                .collect()
        };
        let auto = ProjectorConfig::default();
        let small = ring(60.0);
        assert_eq!(auto.resolve(&grid, &small), ProjectorKind::Footprint);
        assert_eq!(auto.row_shift(&grid, &small), crate::AxisShift::to_x(1), "a ring around y");
        let wide = ring(2000.0);
        assert_eq!(auto.resolve(&grid, &wide), ProjectorKind::Ray);
        assert!(auto.row_shift(&grid, &wide).is_identity());
        let splat = ProjectorConfig { kind: ProjectorKind::Splat, ..Default::default() };
        assert_eq!(splat.resolve(&grid, &small), ProjectorKind::Splat);
        assert!(splat.row_shift(&grid, &small).is_identity());
        let images: Vec<Image> = small.iter().map(|_| Image::zeros(64, 64)).collect();
        assert!(auto.support(&grid, &small, &images).is_none());
        let hull = ProjectorConfig { visual_hull: true, ..Default::default() };
        let mask = hull.support(&grid, &small, &images).expect("asked for");
        assert_eq!(mask.len(), grid.len());
        assert!(mask.iter().all(|&m| !m), "dark images carve every voxel they see, dilation or not");
    }

    /// The memory estimate counts kept footprints for the methods that back-project every
    /// iteration, as much as the projector keeps (whole views within the budget), and none for
    /// ART and MART or without a budget.
    #[test]
    fn memory_counts_kept_footprints() {
        use fluidnerf_core::{Aabb, Intrinsics};
        use glam::DVec3;
        let k = Intrinsics { width: 32, height: 32, fx: 60.0, fy: 60.0, cx: 15.5, cy: 15.5, skew: 0.0 };
        // A ring around the grid's x axis: its rows share a footprint axis.
        let cameras: Vec<Camera> = (0..3)
            .map(|i| {
                let a = 0.4 + i as f64;
                Camera::look_at(k, DVec3::new(0.0, 9.0 * a.cos(), 9.0 * a.sin()), DVec3::ZERO, DVec3::X)
            })
            .collect();
        let grid = Grid::new([20, 18, 16], Aabb::cube(DVec3::ZERO, 4.0));
        let projector =
            |mib| ProjectorConfig { kind: ProjectorKind::Footprint, kept_footprints_mib: mib, ..Default::default() };
        let all = FootprintProjector::new(grid, &cameras, 1.0).expect("valid").with_kept_footprints(u64::MAX);
        assert_eq!(all.kept_footprint_views(), 3);
        let full = all.kept_footprint_bytes();
        assert_eq!(projector(1024).kept_footprint_bytes(&grid, &cameras), full);
        assert_eq!(projector(0).kept_footprint_bytes(&grid, &cameras), 0);
        let memory = |a, mib| ClassicalMethod::default_for(a).memory(&projector(mib), &grid, &cameras, 2).projector;
        assert_eq!(memory(Algorithm::Sart, 1024) - memory(Algorithm::Sart, 0), full);
        assert_eq!(memory(Algorithm::Mlem, 1024) - memory(Algorithm::Mlem, 0), full);
        assert_eq!(memory(Algorithm::Art, 1024), memory(Algorithm::Art, 0));
        assert_eq!(memory(Algorithm::Mart, 1024), memory(Algorithm::Mart, 0));
    }
}
