//! Volume metrics of a reconstruction against ground truth, globally and per region, and the
//! serialisable report (`MetricsReport`) that `fluidnerf eval` writes as JSON and CSV.
//!
//! Each set of [`VolumeMetrics`] holds NRMSE (Eq. 6.18), PSNR, the global SSIM (Eq. 6.19 over
//! all voxels as one window) and the windowed 3D SSIM (skimage's form, see [`crate::ssim`]),
//! all over the truth's voxel centres. Regions use the whole truth's data range, so their PSNR
//! and SSIM are comparable with the global figures.
//!
//! Reading them: the windowed SSIM averages over every window, and windows in empty space
//! (zero in both volumes) score 1, so in a mostly empty box it stays near 1 even for a blurred
//! reconstruction (a 1.5-voxel Gaussian blur of the 96³ demo jet: NRMSE 0.33, windowed SSIM
//! 0.986, global SSIM 0.944). NRMSE, normalised by the truth's energy, and the global SSIM are
//! the more discriminating figures; the dissertation reports NRMSE.

use fluidnerf_core::{Aabb, ScalarField, Volume};
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::reprojection::ReprojectionMetrics;
use crate::{
    data_range_of, nrmse, nrmse_undefined, psnr, region, ssim_3d, ssim_global, MetricsError, Region, SsimParams,
};

/// The metrics of one array pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VolumeMetrics {
    /// Number of voxels compared.
    pub voxels: usize,
    /// Eq. 6.18; lower is better, 0 perfect; NaN (`null` in JSON) when undefined.
    #[serde(deserialize_with = "null_as_nan")]
    pub nrmse: f64,
    /// Why `nrmse` is undefined, when it is ([`crate::NRMSE_UNDEFINED`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nrmse_undefined: Option<String>,
    /// `10 log₁₀(R² / MSE)` in dB; higher is better.
    #[serde(deserialize_with = "null_as_inf")]
    pub psnr_db: f64,
    /// Eq. 6.19 over the whole array as one window; 1 perfect.
    #[serde(deserialize_with = "null_as_nan")]
    pub ssim_global: f64,
    /// Mean windowed SSIM; `None` when the array is smaller than the window.
    pub ssim_windowed: Option<f64>,
    /// The data range `R` used by PSNR and SSIM.
    pub data_range: f64,
}

/// Settings of the volume metrics.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VolumeMetricOptions {
    /// Regions scored separately. Default: [`Region::jet_thirds`].
    pub regions: Vec<Region>,
    /// Windowed SSIM settings (its `data_range` is ignored: see `data_range`). Default: skimage's.
    pub ssim: SsimParams,
    /// Data range of PSNR and SSIM. Default (`None`): the truth's `max − min`.
    pub data_range: Option<f64>,
}

impl Default for VolumeMetricOptions {
    fn default() -> Self {
        VolumeMetricOptions { regions: Region::jet_thirds(), ssim: SsimParams::default(), data_range: None }
    }
}

/// Metrics of one region.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RegionMetrics {
    pub region: Region,
    /// The box of the region's voxels in world units (whole voxels, so it may differ from the
    /// region's nominal box by up to half a voxel).
    pub bounds: Aabb,
    pub metrics: VolumeMetrics,
}

/// Volume metrics at one time step (or of a static reconstruction).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepMetrics {
    /// Time in the scene's unit, `None` for static scenes.
    pub time: Option<f64>,
    /// Truth grid `[nx, ny, nz]` the metrics were computed on.
    pub dims: [usize; 3],
    pub global: VolumeMetrics,
    pub regions: Vec<RegionMetrics>,
}

/// Everything `fluidnerf eval` measures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MetricsReport {
    /// Volume metrics per time step (empty without ground truth).
    pub steps: Vec<StepMetrics>,
    /// Reprojection metrics per held-out frame (empty without held-out frames).
    pub reprojection: Vec<ReprojectionMetrics>,
}

/// Metrics of two equally shaped arrays (`estimate` against `truth`, x fastest, `dims`).
pub fn array_metrics(
    estimate: &[f32],
    truth: &[f32],
    dims: [usize; 3],
    ssim: &SsimParams,
    data_range: f64,
) -> Result<VolumeMetrics, MetricsError> {
    let windowed = match ssim_3d(estimate, truth, dims, &SsimParams { data_range: Some(data_range), ..*ssim }) {
        Ok(v) => Some(v),
        Err(MetricsError::TooSmall { .. }) => None,
        Err(e) => return Err(e),
    };
    let nrmse = nrmse(estimate, truth);
    Ok(VolumeMetrics {
        voxels: truth.len(),
        nrmse,
        nrmse_undefined: nrmse_undefined(nrmse),
        psnr_db: psnr(estimate, truth, data_range),
        ssim_global: ssim_global(estimate, truth, data_range),
        ssim_windowed: windowed,
        data_range,
    })
}

/// A region whose truth holds less than this fraction of the whole truth's energy (`Σ Ê²`) has
/// no NRMSE: it divides by that energy, which is then zero or floating-point dust.
pub const REGION_ENERGY_FLOOR: f64 = 1e-12;

/// Why a region has no NRMSE ([`REGION_ENERGY_FLOOR`]).
pub const REGION_NRMSE_UNDEFINED: &str =
    "the truth holds less than 10⁻¹² of its energy in this region, and NRMSE divides by that energy";

/// `Σ v²`, in f64.
fn energy(values: &[f32]) -> f64 {
    values.iter().map(|&v| f64::from(v) * f64::from(v)).sum()
}

/// The subset name of the whole volume's row in [`MetricsReport::rows`] (and so in tables and
/// CSV files); no region may take it, or its row would read as the whole volume's.
pub const WHOLE_VOLUME: &str = "all";

/// Scores `estimate` against `truth` over the truth's voxel centres, globally and per region.
/// An estimate on another grid or box is first resampled trilinearly at the truth's voxel
/// centres ([`Volume::resample`]; zero outside the estimate's box).
pub fn evaluate_volume(
    estimate: &Volume,
    truth: &Volume,
    time: Option<f64>,
    options: &VolumeMetricOptions,
) -> Result<StepMetrics, MetricsError> {
    for (i, r) in options.regions.iter().enumerate() {
        r.validate()?;
        if r.name == WHOLE_VOLUME {
            return Err(MetricsError::invalid(
                format!("region '{}'", r.name),
                format!("'{WHOLE_VOLUME}' names the whole volume's row; give the region another name"),
            ));
        }
        // Results go by the region's name.
        if options.regions[..i].iter().any(|q| q.name == r.name) {
            return Err(MetricsError::invalid(
                format!("region '{}'", r.name),
                "the name is given twice; give each region its own name",
            ));
        }
    }
    if let Some(r) = options.data_range {
        if !(r > 0.0 && r.is_finite()) {
            return Err(MetricsError::invalid(
                "data range",
                format!("must be positive, got {}", fluidnerf_core::num(r)),
            ));
        }
    }
    let resampled;
    let est = if estimate.dims == truth.dims && estimate.aabb == truth.aabb {
        estimate
    } else {
        log::info!("resampling the reconstruction ({:?}) onto the truth grid ({:?})", estimate.dims, truth.dims);
        resampled = estimate.resample(truth.dims, truth.aabb);
        &resampled
    };
    let range = options.data_range.unwrap_or_else(|| data_range_of(&truth.data));
    let global = array_metrics(&est.data, &truth.data, truth.dims, &options.ssim, range)?;
    let truth_energy = energy(&truth.data);
    let mut regions = Vec::with_capacity(options.regions.len());
    for r in &options.regions {
        let ranges = r.voxel_ranges(truth.dims);
        if ranges.iter().any(|r| r.is_empty()) {
            log::warn!("region '{}' holds no voxel centre of the {:?} truth grid; skipped", r.name, truth.dims);
            continue;
        }
        let (e, dims) = region::extract(&est.data, truth.dims, &ranges);
        let (t, _) = region::extract(&truth.data, truth.dims, &ranges);
        let mut metrics = array_metrics(&e, &t, dims, &options.ssim, range)?;
        if !metrics.nrmse.is_nan() && energy(&t) < REGION_ENERGY_FLOOR * truth_energy {
            // Floating-point dust (a Gaussian's far tail, say) would make the ratio astronomic.
            metrics.nrmse = f64::NAN;
            metrics.nrmse_undefined = Some(REGION_NRMSE_UNDEFINED.to_string());
        }
        if metrics.ssim_windowed.is_none() {
            log::warn!("region '{}' ({dims:?} voxels) is smaller than the SSIM window; no windowed SSIM", r.name);
        }
        let sp = truth.spacing();
        let lo = DVec3::new(ranges[0].start as f64, ranges[1].start as f64, ranges[2].start as f64);
        let hi = DVec3::new(ranges[0].end as f64, ranges[1].end as f64, ranges[2].end as f64);
        let bounds = Aabb::new(truth.aabb.min + lo * sp, truth.aabb.min + hi * sp);
        regions.push(RegionMetrics { region: r.clone(), bounds, metrics });
    }
    Ok(StepMetrics { time, dims: truth.dims, global, regions })
}

/// Scores a continuous field (a trained network, an analytic phantom, or a volume on any grid)
/// against each truth step: the field is sampled at the truth's voxel centres at the step's
/// time (time 0 for a static truth), as the dissertation interrogates FluidNeRF, then scored
/// with [`evaluate_volume`].
pub fn evaluate_field(
    field: &dyn ScalarField,
    truth: &[(Option<f64>, Volume)],
    options: &VolumeMetricOptions,
) -> Result<Vec<StepMetrics>, MetricsError> {
    truth
        .iter()
        .map(|(time, t)| {
            let sampled = Volume::from_field(t.dims, t.aabb, field, time.unwrap_or(0.0));
            evaluate_volume(&sampled, t, *time, options)
        })
        .collect()
}

/// JSON has no NaN: serde_json writes non-finite numbers as `null`; this reads `null` back as
/// NaN (an undefined NRMSE or SSIM).
pub(crate) fn null_as_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Reads `null` back as +∞ (the PSNR of a perfect estimate).
pub(crate) fn null_as_inf<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
}

/// One line of the flat table view of a report (terminal and CSV).
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// `volume` or `reprojection`.
    pub kind: &'static str,
    pub time: Option<f64>,
    /// `all`, a region name, or a frame label.
    pub subset: String,
    /// Voxels or pixels compared.
    pub count: usize,
    pub nrmse: f64,
    /// Why `nrmse` is undefined (NaN), when it is.
    pub nrmse_undefined: Option<String>,
    pub psnr_db: f64,
    pub ssim_global: f64,
    /// Windowed SSIM (3D for volumes, 2D for images).
    pub ssim_windowed: Option<f64>,
}

impl MetricsReport {
    /// The report as flat rows: per time step the whole volume then each region, then each
    /// held-out frame.
    pub fn rows(&self) -> Vec<Row> {
        let mut rows = Vec::new();
        for s in &self.steps {
            let mut push = |subset: &str, m: &VolumeMetrics| {
                rows.push(Row {
                    kind: "volume",
                    time: s.time,
                    subset: subset.to_string(),
                    count: m.voxels,
                    nrmse: m.nrmse,
                    nrmse_undefined: m.nrmse_undefined.clone(),
                    psnr_db: m.psnr_db,
                    ssim_global: m.ssim_global,
                    ssim_windowed: m.ssim_windowed,
                });
            };
            push(WHOLE_VOLUME, &s.global);
            for r in &s.regions {
                push(&r.region.name, &r.metrics);
            }
        }
        for p in &self.reprojection {
            rows.push(Row {
                kind: "reprojection",
                time: p.time,
                subset: p.label(),
                count: p.pixels,
                nrmse: p.nrmse,
                nrmse_undefined: p.nrmse_undefined.clone(),
                psnr_db: p.psnr_db,
                ssim_global: p.ssim_global,
                ssim_windowed: Some(p.ssim_windowed),
            });
        }
        rows
    }

    /// CSV with a header line: `kind,time,subset,count,nrmse,psnr_db,ssim_global,ssim_windowed`.
    /// Missing values (static time, no windowed SSIM) are empty fields; infinities and NaN are
    /// written as `inf` and `NaN`.
    pub fn to_csv(&self) -> String {
        let mut s = String::from("kind,time,subset,count,nrmse,psnr_db,ssim_global,ssim_windowed\n");
        let opt = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
        for r in self.rows() {
            let subset = if r.subset.contains([',', '"', '\n']) {
                format!("\"{}\"", r.subset.replace('"', "\"\""))
            } else {
                r.subset.clone()
            };
            s.push_str(&format!(
                "{},{},{},{},{},{},{},{}\n",
                r.kind,
                opt(r.time),
                subset,
                r.count,
                r.nrmse,
                r.psnr_db,
                r.ssim_global,
                opt(r.ssim_windowed)
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn aabb() -> Aabb {
        Aabb::new(DVec3::ZERO, DVec3::new(3.0, 1.0, 1.0))
    }

    fn blob(p: DVec3) -> f32 {
        (-(p - DVec3::new(1.5, 0.5, 0.5)).length_squared() * 4.0).exp() as f32
    }

    #[test]
    fn two_regions_of_one_name_are_refused() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let regions = vec![Region::along_x("a", 0.0, 0.5), Region::along_x("a", 0.5, 1.0)];
        let e = evaluate_volume(&t, &t, None, &VolumeMetricOptions { regions, ..Default::default() })
            .expect_err("refused")
            .to_string();
        assert!(e.contains("region 'a'") && e.contains("given twice"), "{e}");
    }

    #[test]
    fn a_region_named_as_the_whole_volume_is_refused() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let regions = vec![Region::along_x(WHOLE_VOLUME, 0.0, 0.5)];
        let e = evaluate_volume(&t, &t, None, &VolumeMetricOptions { regions, ..Default::default() })
            .expect_err("refused")
            .to_string();
        assert!(e.contains("region 'all'") && e.contains("whole volume"), "{e}");
    }

    #[test]
    fn perfect_reconstruction_scores_perfectly_everywhere() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let s = evaluate_volume(&t, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        assert_eq!(s.global.nrmse, 0.0);
        assert_eq!(s.global.psnr_db, f64::INFINITY);
        assert!((s.global.ssim_global - 1.0).abs() < 1e-12);
        assert!((s.global.ssim_windowed.expect("fits") - 1.0).abs() < 1e-12);
        assert_eq!(s.regions.len(), 3);
        assert_eq!(s.regions.iter().map(|r| r.metrics.voxels).sum::<usize>(), 24 * 8 * 8);
        assert_eq!((s.regions[1].bounds.min.x, s.regions[1].bounds.max.x), (1.0, 2.0));
    }

    #[test]
    fn regional_errors_localise_and_sum_to_the_global_error() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        // Error only in the turbulent third.
        let e = Volume::from_fn([24, 8, 8], aabb(), |p| blob(p) + if p.x > 2.0 { 0.1 } else { 0.0 });
        let s = evaluate_volume(&e, &t, Some(2.0), &VolumeMetricOptions::default()).expect("evaluates");
        assert_eq!(s.regions[0].metrics.nrmse, 0.0);
        assert_eq!(s.regions[1].metrics.nrmse, 0.0);
        assert!(s.regions[2].metrics.nrmse > 0.0);
        // Squared errors and energies add up over a partition.
        let energy = |v: &[f32]| v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>();
        let total: f64 = Region::jet_thirds()
            .iter()
            .map(|r| {
                let (tt, _) = region::extract(&t.data, t.dims, &r.voxel_ranges(t.dims));
                s.regions.iter().find(|m| m.region.name == r.name).expect("scored").metrics.nrmse.powi(2) * energy(&tt)
            })
            .sum();
        assert!((total / energy(&t.data) - s.global.nrmse.powi(2)).abs() < 1e-9);
        assert_eq!(s.time, Some(2.0));
    }

    /// A region holding floating-point dust of the truth (here 10⁻²⁰ of its peak) has no NRMSE,
    /// where dividing by that energy gave 10³⁷ on a real jet; a dim region keeps its NRMSE.
    #[test]
    fn a_region_of_floating_point_dust_has_no_nrmse() {
        let truth = |p: DVec3| match p.x {
            x if x < 1.0 => 1e-20,
            x if x < 2.0 => blob(p),
            _ => 1e-3,
        };
        let t = Volume::from_fn([24, 8, 8], aabb(), truth);
        let e = Volume::from_fn([24, 8, 8], aabb(), |p| truth(p) + 1e-4);
        let s = evaluate_volume(&e, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        let [laminar, transition, turbulent] = [0, 1, 2].map(|i| &s.regions[i].metrics);
        assert!(laminar.nrmse.is_nan());
        assert_eq!(laminar.nrmse_undefined.as_deref(), Some(REGION_NRMSE_UNDEFINED));
        assert!(transition.nrmse > 0.0 && transition.nrmse_undefined.is_none());
        assert!((turbulent.nrmse - 0.1).abs() < 1e-6, "{}", turbulent.nrmse);
        assert!(s.global.nrmse.is_finite());
    }

    /// The floor compares sums of squares: a region at 10⁻⁷ of the peak holds 10⁻¹⁴ of the
    /// truth's energy per voxel and has no NRMSE, although the sum of its values is far above
    /// 10⁻¹² of the truth's.
    #[test]
    fn the_region_floor_compares_energies() {
        let truth = |p: DVec3| if p.x < 1.0 { 1e-7 } else { blob(p) };
        let t = Volume::from_fn([24, 8, 8], aabb(), truth);
        let e = Volume::from_fn([24, 8, 8], aabb(), |p| truth(p) * 1.1);
        let s = evaluate_volume(&e, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        assert!(s.regions[0].metrics.nrmse.is_nan(), "{}", s.regions[0].metrics.nrmse);
        assert!((s.regions[1].metrics.nrmse - 0.1).abs() < 1e-6, "{}", s.regions[1].metrics.nrmse);
    }

    /// A truth that is zero throughout has no NRMSE, and the report says why.
    #[test]
    fn an_all_zero_truth_has_no_nrmse_and_says_why() {
        let t = Volume::zeros([24, 8, 8], aabb());
        let e = Volume::from_fn([24, 8, 8], aabb(), blob);
        let s = evaluate_volume(&e, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        assert!(s.global.nrmse.is_nan());
        assert_eq!(s.global.nrmse_undefined.as_deref(), Some(crate::NRMSE_UNDEFINED));
        let same = evaluate_volume(&t, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        assert!(same.global.nrmse.is_nan() && same.global.nrmse_undefined.is_some());
    }

    /// A data range that is not a positive number is refused by name, not turned into a
    /// PSNR or SSIM of NaN.
    #[test]
    fn a_data_range_that_is_not_positive_is_refused() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        for r in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let options = VolumeMetricOptions { data_range: Some(r), ..Default::default() };
            let e = evaluate_volume(&t, &t, None, &options).expect_err("refused").to_string();
            assert!(e.contains("data range") && e.contains("must be positive"), "{r}: {e}");
        }
    }

    /// The data range given is the one PSNR and both SSIMs use, the windowed SSIM included
    /// (whose own settings carry a range of their own that is ignored).
    #[test]
    fn the_data_range_given_is_used_by_every_measure() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let e = Volume::from_fn([24, 8, 8], aabb(), |p| blob(p) * 0.9 + 0.02);
        let ssim = SsimParams { data_range: Some(1000.0), ..Default::default() };
        let options = VolumeMetricOptions { data_range: Some(5.0), ssim, regions: vec![] };
        let s = evaluate_volume(&e, &t, None, &options).expect("evaluates");
        let with = |r: f64| SsimParams { data_range: Some(r), ..Default::default() };
        let windowed = ssim_3d(&e.data, &t.data, t.dims, &with(5.0)).expect("fits");
        assert_eq!(s.global.data_range, 5.0);
        assert_eq!(s.global.ssim_windowed, Some(windowed));
        assert_eq!(s.global.ssim_global, ssim_global(&e.data, &t.data, 5.0));
        assert_eq!(s.global.psnr_db, psnr(&e.data, &t.data, 5.0));
        let default = ssim_3d(&e.data, &t.data, t.dims, &with(data_range_of(&t.data))).expect("fits");
        assert!((windowed - default).abs() > 1e-4, "{windowed} against {default}");
    }

    /// An estimate on the truth's grid size but in another box is resampled too: its voxels are
    /// not the truth's, though there are as many of them.
    #[test]
    fn an_estimate_of_the_same_size_in_another_box_is_resampled() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let shifted = Aabb::new(DVec3::new(0.5, 0.0, 0.0), DVec3::new(3.5, 1.0, 1.0));
        let e = Volume::from_fn([24, 8, 8], shifted, blob);
        let options = VolumeMetricOptions { regions: vec![], ..Default::default() };
        let s = evaluate_volume(&e, &t, None, &options).expect("evaluates");
        let by_hand = nrmse(&e.resample(t.dims, t.aabb).data, &t.data);
        assert_eq!(s.global.nrmse, by_hand);
        assert!(s.global.nrmse < 0.1, "{}", s.global.nrmse);
        assert!(nrmse(&e.data, &t.data) > 0.3, "the raw arrays differ: {}", nrmse(&e.data, &t.data));
    }

    #[test]
    fn other_grids_are_resampled_onto_the_truth() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let fine = Volume::from_fn([48, 16, 16], aabb(), blob);
        let s = evaluate_volume(&fine, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        assert_eq!(s.global.voxels, t.len());
        assert!(s.global.nrmse < 0.02, "NRMSE {}", s.global.nrmse);
    }

    #[test]
    fn fields_are_sampled_at_each_step_time() {
        let truth: Vec<(Option<f64>, Volume)> = [0.0, 1.0]
            .iter()
            .map(|&t| (Some(t), Volume::from_fn([24, 8, 8], aabb(), |p| blob(p - DVec3::new(0.2 * t, 0.0, 0.0)))))
            .collect();
        let moving = |p: glam::Vec3, t: f64| blob(p.as_dvec3() - DVec3::new(0.2 * t, 0.0, 0.0));
        let steps = evaluate_field(&moving, &truth, &VolumeMetricOptions::default()).expect("evaluates");
        assert_eq!(steps.len(), 2);
        for s in &steps {
            assert!(s.global.nrmse < 1e-6, "step {:?}: NRMSE {}", s.time, s.global.nrmse);
        }
        // A field frozen at t = 0 is right at the first step only.
        let frozen = |p: glam::Vec3, _t: f64| blob(p.as_dvec3());
        let steps = evaluate_field(&frozen, &truth, &VolumeMetricOptions::default()).expect("evaluates");
        assert!(steps[0].global.nrmse < 1e-6 && steps[1].global.nrmse > 0.05);
    }

    #[test]
    fn csv_lists_every_row() {
        let t = Volume::from_fn([24, 8, 8], aabb(), blob);
        let s = evaluate_volume(&t, &t, None, &VolumeMetricOptions::default()).expect("evaluates");
        let report = MetricsReport { steps: vec![s], reprojection: vec![] };
        let csv = report.to_csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 5);
        assert!(lines[1].starts_with("volume,,all,1536,0,inf,1,1"), "{}", lines[1]);
        assert!(lines[2].starts_with("volume,,laminar,"));
        let json = serde_json::to_string(&report).expect("serialises");
        assert!(json.contains("\"psnr_db\":null"));
        let back: MetricsReport = serde_json::from_str(&json).expect("reads back");
        assert_eq!(back.steps[0].global.psnr_db, f64::INFINITY);
        assert_eq!(back.steps[0].regions.len(), 3);
    }
}
