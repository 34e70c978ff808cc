//! `fluidnerf export`: samples a reconstruction onto a grid of any resolution and box and writes
//! it for other tools (`.npy`, `.vti`, raw, TIFF stacks), as slice pictures (optionally next to the truth and
//! the difference) and as isosurface meshes. Also home of the reconstruction loader that
//! `render` shares.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::ValueEnum;
use fluidnerf_core::glam::DVec3;
use fluidnerf_core::num;
use fluidnerf_core::{Aabb, ScalarField, Scene, Volume};
use fluidnerf_pipeline::rundir::{refuse_other_kind, FolderKind};
use fluidnerf_viz::{Axis, Colormap, PanelStyle};
use serde::Serialize;

/// The most voxels along an export's longest side (as for a reconstruction).
const MAX_RESOLUTION: usize = 4096;

/// Mesh file formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Binary little-endian PLY.
    Ply,
    /// Wavefront OBJ (text).
    Obj,
}

/// Export a reconstruction: volumes, slice pictures, comparisons and isosurfaces.
///
/// Samples the reconstruction onto a grid and writes volumes for NumPy, ParaView, MATLAB and
/// ImageJ/Fiji,
/// slice pictures with a colour bar, truth | reconstruction | difference panels, and
/// isosurfaces as meshes.
///
/// With none of --npy, --vti, --raw, --tiff, --slices or --isosurface, writes `volume.npy`,
/// `volume.vti` and slices through the middle of the box along x, y and z. Always writes
/// `export.json` (the resolved settings). Existing outputs in OUT need --force.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The reconstruction: a volume file (`.npy` filling the scene's box, `.vti`, `.raw` with
    /// its JSON sidecar, or a `.tif` stack, calibrated or filling the scene's box) or a run folder of any kind (a trained neural field, static or
    /// time-resolved, is sampled exactly; a voxel run gives its volume).
    pub recon: PathBuf,
    /// The scene (folder holding `transforms.json`, or the file): gives the box of `.npy`
    /// volumes and the length unit.
    #[arg(short, long)]
    pub scene: Option<PathBuf>,
    /// Output directory; created if missing.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Voxels along the longest side of the export box, 1 to 4096; the other sides take the
    /// whole number of voxels nearest to cubic cells, so a side that is no whole number of
    /// them has cells a little longer or shorter along it (export.json records the spacing).
    /// Default: a volume's own grid when the box is unchanged, else 128.
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Export box in world units as `XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX`. Default: the
    /// reconstruction's box.
    #[arg(long = "box", value_name = "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX", allow_hyphen_values = true)]
    pub bbox: Option<String>,
    /// Time at which a time-resolved field is sampled, between its first and last instants.
    /// Default: its first instant. `export.json`, the `.vti` (`TimeValue`, ParaView's time) and
    /// the raw sidecar record the instant, also of a volume file whose instant is recorded (a
    /// run's frame, an earlier export).
    #[arg(long, allow_hyphen_values = true)]
    pub time: Option<f64>,
    /// A trained field's voxel is the mean of N³ points spread evenly over it (its cell
    /// average, a box filter against aliasing when the field holds detail finer than a voxel);
    /// 1 samples the voxel's centre; at most 8.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=8))]
    pub average: u16,
    /// Write `volume.npy` (shape `(nz, ny, nx)`, f32).
    #[arg(long)]
    pub npy: bool,
    /// Write `volume.vti` (VTK ImageData for ParaView; values at voxel centres).
    #[arg(long)]
    pub vti: bool,
    /// Write `volume.raw` (f32, x fastest) with its JSON sidecar.
    #[arg(long)]
    pub raw: bool,
    /// Write `volume.tif`: a 32-bit float TIFF stack, one page per z-slice, calibrated for
    /// ImageJ and Fiji (voxel size in the length unit, and the box's origin).
    #[arg(long)]
    pub tiff: bool,
    /// Slice pictures as AXIS=FRACTION of the box (0 = min side, 1 = max side), e.g.
    /// `x=0.5,z=0.25`; comma-separated or repeated. Each goes to `slice_<axis>_<fraction>.png`.
    #[arg(long, value_delimiter = ',', value_name = "AXIS=FRACTION")]
    pub slices: Vec<String>,
    /// Ground-truth volume (`.npy` filling the scene's box, or the reconstruction's without
    /// --scene; `.vti`, `.raw` or `.tif`): slices are also drawn as truth | reconstruction | difference
    /// (`compare_<axis>_<fraction>.png`). A truth of another instant than the export's (as the
    /// scene lists it, or as the file records it) is refused.
    #[arg(long, value_name = "TRUTH")]
    pub compare: Option<PathBuf>,
    /// Extract the isosurface at this field value by marching cubes (`isosurface.ply`). Its
    /// area and enclosed volume are printed; where the surface leaves the box it is open, and
    /// the volume is that of the region above the value inside the outermost voxel centres.
    #[arg(long, value_name = "VALUE", allow_hyphen_values = true)]
    pub isosurface: Option<f32>,
    /// Mesh formats of the isosurface; comma-separated (with --isosurface).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "ply", requires = "isosurface")]
    pub mesh: Vec<MeshFormat>,
    /// Colour map of the slices: viridis, magma, inferno, cividis, gray [default: viridis].
    #[arg(long, value_parser = parse_field_colormap)]
    pub colormap: Option<Colormap>,
    /// Colour-bar label of the slices, with the field's unit [default: emission E [a.u.]].
    #[arg(long)]
    pub value_label: Option<String>,
    /// Length unit of the export's box, axis labels and TIFF calibration. Default: the scene's,
    /// else the run's, else a calibrated TIFF stack's own, else mm. Another than the scene's or
    /// the run's is refused; a calibrated stack is converted to it (between nm, µm, mm, cm and
    /// m). A .npy, .vti or .raw records no unit: this names it.
    #[arg(long, value_parser = super::import::parse_units)]
    pub units: Option<String>,
    /// Overwrite existing outputs in OUT.
    #[arg(long)]
    pub force: bool,
}

/// A loaded reconstruction.
pub(crate) enum Source {
    Volume(Volume),
    /// A trained field; `times`: the instants of a time-resolved one.
    Field {
        field: Box<dyn ScalarField + Send + Sync>,
        aabb: Aabb,
        times: Option<fluidnerf_pipeline::load::TimeSpan>,
    },
}

impl Source {
    pub(crate) fn aabb(&self) -> Aabb {
        match self {
            Source::Volume(v) => v.aabb,
            Source::Field { aabb, .. } => *aabb,
        }
    }

    pub(crate) fn field(&self) -> &dyn ScalarField {
        match self {
            Source::Volume(v) => v,
            Source::Field { field, .. } => field.as_ref(),
        }
    }

    /// The time at which to sample the source for `what` (`--time`, a frame): `given`, refused
    /// when not finite or outside a time-resolved field's instants (where the field only
    /// repeats its first or last one, or a stopped run never trained); else that field's first
    /// instant, and 0 for the others.
    pub(crate) fn sample_time(&self, given: Option<f64>, what: &str) -> anyhow::Result<f64> {
        let span = match self {
            Source::Field { times, .. } => times.as_ref(),
            Source::Volume(_) => None,
        };
        Ok(fluidnerf_pipeline::load::sample_time(span, given, what)?)
    }

    /// Warns once, naming `path`, when `times` (the instants sampled) include a run's held-out
    /// instants outside its trained ones, where its field repeats the nearest trained instant.
    pub(crate) fn warn_held(&self, times: impl IntoIterator<Item = f64>, path: &Path) {
        if let Source::Field { times: Some(span), .. } = self {
            if let Some(note) = span.held_note(times) {
                log::warn!("{}: {note}", path.display());
            }
        }
    }

    /// Warns that `--time` (`given`) changes nothing when the source is fixed in time: a volume,
    /// or a field of space alone.
    /// Whether the source changes with time (a time-resolved field): only then does a time
    /// select anything, and only then do `export.json` and `render.json` record one.
    pub(crate) fn is_time_resolved(&self) -> bool {
        matches!(self, Source::Field { times: Some(_), .. })
    }

    pub(crate) fn warn_time_unused(&self, given: Option<f64>, path: &Path) {
        let Some(t) = given else { return };
        match self {
            Source::Volume(_) => log::warn!("--time {t} has no effect: {} is a volume, fixed in time", path.display()),
            Source::Field { times: None, .. } => {
                log::warn!("--time {t} has no effect: {} is a static field, fixed in time", path.display())
            }
            Source::Field { times: Some(_), .. } => {}
        }
    }

    pub(crate) fn describe(&self) -> String {
        match self {
            Source::Volume(v) => format!("a {}x{}x{} volume", v.dims[0], v.dims[1], v.dims[2]),
            Source::Field { .. } => "a trained field".to_string(),
        }
    }
}

/// The extensions [`read_volume`] reads, lower case.
const VOLUME_EXTENSIONS: [&str; 5] = ["npy", "vti", "raw", "tif", "tiff"];

/// Reads a volume file by extension; `.npy` needs `aabb`. A calibrated TIFF stack's box is
/// converted to the scene's length `unit`, when given.
pub(crate) fn read_volume(path: &Path, aabb: Option<Aabb>, unit: Option<&str>) -> anyhow::Result<Volume> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let v = match ext.as_str() {
        "npy" => {
            let Some(aabb) = aabb else {
                bail!("{}: a .npy volume holds no box; give the scene with --scene", path.display());
            };
            fluidnerf_io::volume::read_npy(path, aabb)
        }
        "vti" => fluidnerf_io::volume::read_vti(path),
        "raw" => fluidnerf_io::volume::read_raw(path),
        "tif" | "tiff" => fluidnerf_io::volume::read_tiff_stack(path, aabb, unit),
        // A path that names nothing (a typo, a run folder not made yet) is not a format problem.
        _ if !path.exists() => bail!("{}: no such file or directory", path.display()),
        // A folder (a synthetic scene's `truth/`, a run folder): name the volumes inside it.
        _ if path.is_dir() => {
            let mut inside: Vec<String> = std::fs::read_dir(path)
                .map(|entries| {
                    entries
                        .filter_map(|e| e.ok())
                        .map(|e| e.file_name().to_string_lossy().into_owned())
                        .filter(|n| {
                            let ext = Path::new(n).extension().and_then(|e| e.to_str()).unwrap_or("");
                            VOLUME_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str())
                        })
                        .collect()
                })
                .unwrap_or_default();
            inside.sort();
            // A scene folder: name its ground truth, which is what a user giving it means.
            let truth: Vec<String> = fluidnerf_io::scene::read_scene_draft(path)
                .map(|d| d.truth.iter().map(|t| d.root.join(&t.file_path).display().to_string()).collect())
                .unwrap_or_default();
            let hint = match (inside.as_slice(), truth.as_slice()) {
                (_, [one]) => format!("it is a scene; its ground truth is {one}"),
                (_, [_, ..]) => format!("it is a scene; its ground truth volumes are {}", truth.join(", ")),
                ([], []) => "it holds no .npy, .vti, .raw or .tif file".to_string(),
                ([one], []) => format!("give the file inside it, {}", path.join(one).display()),
                (many, []) => format!("give one of the files inside it: {}", many.join(", ")),
            };
            bail!("{}: a folder, not a volume file; {hint}", path.display())
        }
        _ => bail!("{}: unknown volume format (expected .npy, .vti, .raw or .tif)", path.display()),
    }
    .with_context(|| format!("reading the volume {}", path.display()))?;
    fluidnerf_io::volume::check_finite(path, &v)?;
    Ok(v)
}

/// Loads RECON: a volume file, or a run folder of any kind (a trained field, static or of
/// space and time, sampled exactly; a voxel run's volume).
pub(crate) fn load_source(path: &Path, scene: Option<&Scene>, unit: Option<&str>) -> anyhow::Result<Source> {
    if path.is_dir() {
        let run = fluidnerf_pipeline::load::LoadedRun::open(path, scene.map(|s| s.aabb))?;
        return Ok(match run.kind {
            fluidnerf_pipeline::RunKind::Volume => Source::Volume(run.first_volume()?),
            _ => Source::Field { field: run.field()?, aabb: run.aabb, times: run.time_span()? },
        });
    }
    if !path.exists() {
        bail!("{}: no such file or directory", path.display());
    }
    Ok(Source::Volume(read_volume(path, scene.map(|s| s.aabb), unit.or(scene.map(|s| s.units.as_str())))?))
}

/// The instant of a time-resolved field the volume file `path` holds, when that is recorded,
/// and where: in the file itself (a `.vti`'s `TimeValue`, a raw volume's sidecar), for one of a
/// run's frames (`RUN/frames/volume_NNN.npy|.vti`, listed with its time in `RUN/report.json`),
/// or for a volume `export` wrote (listed in the `export.json` beside it, with its time). Where
/// it is recorded, in words, and the time.
pub(crate) fn recorded_volume_time(path: &Path) -> Option<(String, f64)> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let own = match ext.as_str() {
        "vti" => fluidnerf_io::volume::vti_time(path).map(|t| ("its TimeValue field data".to_string(), t)),
        "raw" => fluidnerf_io::volume::raw_time(path)
            .map(|t| (fluidnerf_io::volume::raw_sidecar_path(path).display().to_string(), t)),
        _ => None,
    };
    if own.is_some() {
        return own;
    }
    let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if folder.file_name().is_some_and(|name| name == "frames") {
        let run = folder.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let report_path = run.join("report.json");
        let report = fluidnerf_pipeline::RunReport::read(&report_path).ok()?;
        let stem = path.file_stem()?.to_str()?;
        let own = format!("frames/{stem}");
        let record = report.volumes.iter().find(|v| Path::new(&v.file).with_extension("") == Path::new(&own))?;
        return Some((report_path.display().to_string(), record.time?));
    }
    let export_path = folder.join("export.json");
    let record: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&export_path).ok()?).ok()?;
    let name = path.file_name()?;
    let listed = record["outputs"].as_array()?.iter().filter_map(|o| o.as_str());
    if !listed.into_iter().any(|o| Path::new(o).file_name() == Some(name)) {
        return None;
    }
    Some((export_path.display().to_string(), record["time"].as_f64()?))
}

/// The instant of the ground-truth volume `path`, and where it is recorded: the time the scene
/// in `scene_root` lists it at, else the one the file records ([`recorded_volume_time`]).
pub(crate) fn truth_time(path: &Path, scene_root: Option<&Path>) -> Option<(String, f64)> {
    let given = std::fs::canonicalize(path).ok()?;
    if let Some(draft) = scene_root.and_then(|root| fluidnerf_io::scene::read_scene_draft(root).ok()) {
        let listed = draft
            .truth
            .iter()
            .find(|t| std::fs::canonicalize(draft.root.join(&t.file_path)).ok().as_ref() == Some(&given));
        if let Some(t) = listed {
            return t.time.map(|time| ("the scene lists it at that time".to_string(), time));
        }
    }
    recorded_volume_time(path)
}

/// Refuses the ground truth `path` given with `option` when it is of another instant than the
/// reconstruction's (`instant`: its time, and where that comes from): scored or drawn beside
/// it, the difference would be the flow's change between the two instants.
pub(crate) fn refuse_truth_of_another_instant(
    option: &str,
    path: &Path,
    scene_root: Option<&Path>,
    instant: (f64, &str),
) -> anyhow::Result<()> {
    let Some((place, truth_at)) = truth_time(path, scene_root) else { return Ok(()) };
    let (at, from) = instant;
    if fluidnerf_core::scene::same_time(truth_at, at) {
        return Ok(());
    }
    bail!(
        "{option} {}: the truth is at t = {} ({place}), but the reconstruction is at t = {} ({from}); give the truth \
         of t = {}, or the reconstruction of t = {}",
        path.display(),
        num(truth_at),
        num(at),
        num(at),
        num(truth_at)
    )
}

/// The share of `a`'s volume that lies inside `b`.
fn overlap_fraction(a: &Aabb, b: &Aabb) -> f64 {
    let common = (a.max.min(b.max) - a.min.max(b.min)).max(DVec3::ZERO);
    common.x * common.y * common.z / (a.size().x * a.size().y * a.size().z)
}

/// Whether two boxes are the same to within `slack` or a billionth of the larger's longest side:
/// a box typed in decimals, or read back from a file's origin and spacing, may differ in its
/// last bits.
fn same_box(a: &Aabb, b: &Aabb, slack: f64) -> bool {
    let tolerance = slack.max(1e-9 * a.size().max(b.size()).max_element());
    (a.min - b.min).abs().max((a.max - b.max).abs()).max_element() <= tolerance
}

/// Whether `path` is named as a TIFF stack.
fn is_tiff(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "tif" | "tiff"))
}

/// The length unit a run folder's `report.json` records for its scene, and the words naming
/// it; None for a volume file or a folder without a report.
fn run_units(recon: &Path) -> anyhow::Result<Option<(String, String)>> {
    let report = recon.join("report.json");
    if !(recon.is_dir() && report.is_file()) {
        return Ok(None);
    }
    let r = fluidnerf_pipeline::RunReport::read(&report)?;
    Ok(Some((r.units, format!("the run {}", recon.display()))))
}

/// Parses `AXIS=FRACTION`.
fn parse_slice(s: &str) -> anyhow::Result<(Axis, f64)> {
    let (a, f) = s.split_once('=').with_context(|| format!("--slices {s:?}: expected AXIS=FRACTION, e.g. z=0.5"))?;
    let axis: Axis = a.parse().map_err(|e: String| anyhow::anyhow!("--slices {s:?}: {e}"))?;
    let fraction: f64 = f.trim().parse().with_context(|| format!("--slices {s:?}: {f:?} is not a number"))?;
    if !(0.0..=1.0).contains(&fraction) {
        bail!("--slices {s:?}: the fraction must lie in [0, 1] (0 = min side of the box, 1 = max side)");
    }
    Ok((axis, fraction))
}

/// `--colormap`: a sequential map; the diverging one is kept for the comparisons' differences.
fn parse_field_colormap(s: &str) -> Result<Colormap, String> {
    let sequential: Vec<&str> = Colormap::ALL.iter().filter(|c| !c.is_diverging()).map(|c| c.name()).collect();
    match s.parse::<Colormap>() {
        Ok(c) if !c.is_diverging() => Ok(c),
        Ok(_) => Err(format!(
            "the diverging map is kept for differences; choose a sequential map for the field: {}",
            sequential.join(", ")
        )),
        Err(_) => Err(format!("unknown colour map {s:?}; expected one of {}", sequential.join(", "))),
    }
}

/// The file names of the outputs an earlier export listed in its `export.json` (`settings`),
/// those only that an export writes: with --force, the ones not written again would be left
/// beside the new outputs as if `export.json` described them.
fn earlier_outputs(settings: &Path) -> Vec<PathBuf> {
    let Ok(text) = std::fs::read_to_string(settings) else { return Vec::new() };
    let Ok(record) = serde_json::from_str::<serde_json::Value>(&text) else { return Vec::new() };
    let listed = record["outputs"].as_array().map(Vec::as_slice).unwrap_or_default();
    let ours = |name: &str| {
        matches!(
            name,
            "volume.npy"
                | "volume.vti"
                | "volume.raw"
                | "volume.raw.json"
                | "volume.tif"
                | "isosurface.ply"
                | "isosurface.obj"
        ) || ((name.starts_with("slice_") || name.starts_with("compare_")) && name.ends_with(".png"))
    };
    listed
        .iter()
        .filter_map(|p| Path::new(p.as_str()?).file_name())
        .filter(|n| n.to_str().is_some_and(ours))
        .map(PathBuf::from)
        .collect()
}

/// The settings written to `export.json`.
#[derive(Serialize)]
struct Settings<'a> {
    version: &'static str,
    reconstruction: &'a Path,
    scene: Option<&'a Path>,
    aabb: Aabb,
    dims: [usize; 3],
    /// The voxel's size along x, y and z.
    spacing: [f64; 3],
    /// A trained field's voxel as the mean of `average³` points (`--average`); None for a
    /// volume, resampled trilinearly.
    average: Option<usize>,
    /// The instant the export holds: the one sampled from a time-resolved field, or the one a
    /// volume file records ([`recorded_volume_time`]); None for a source fixed in time.
    time: Option<f64>,
    units: &'a str,
    colormap: Colormap,
    value_label: &'a str,
    slices: Vec<(Axis, f64)>,
    compare: Option<&'a Path>,
    isosurface: Option<f32>,
    mesh: &'a [MeshFormat],
    outputs: Vec<String>,
}

#[allow(clippy::print_stdout)]
pub fn run(args: Args) -> anyhow::Result<()> {
    // Validate the arguments before any work.
    let given = [("--scene", &args.scene), ("--compare", &args.compare)];
    let given = given.iter().filter_map(|(o, p)| Some((*o, p.as_deref()?)));
    super::recordable("export.json", std::iter::once(("RECON", args.recon.as_path())).chain(given))?;
    refuse_other_kind(&args.out, FolderKind::Export, "export")?;
    super::refuse_unwritable_output(&args.out)?;
    let meshes: Vec<&str> = args.mesh.iter().map(|m| if *m == MeshFormat::Ply { "ply" } else { "obj" }).collect();
    super::given_once("--mesh", &meshes)?;
    let mut slices: Vec<(Axis, f64)> = args.slices.iter().map(|s| parse_slice(s)).collect::<anyhow::Result<_>>()?;
    let nothing_chosen =
        !args.npy && !args.vti && !args.raw && !args.tiff && slices.is_empty() && args.isosurface.is_none();
    let (npy, vti, raw) = (args.npy || nothing_chosen, args.vti || nothing_chosen, args.raw);
    if nothing_chosen {
        slices = vec![(Axis::X, 0.5), (Axis::Y, 0.5), (Axis::Z, 0.5)];
    }
    if let (Some(truth), true) = (&args.compare, slices.is_empty()) {
        bail!(
            "--compare {}: the truth is drawn beside slices only, and none are asked for; add --slices (e.g. \
             --slices z=0.5)",
            truth.display()
        );
    }
    if let Some(n) = args.resolution.filter(|n| !(1..=MAX_RESOLUTION).contains(n)) {
        bail!("--resolution must be between 1 and {MAX_RESOLUTION} voxels, got {n}");
    }
    // They style the slice pictures only: without any, they would change nothing.
    let styles = [("--colormap", args.colormap.is_some()), ("--value-label", args.value_label.is_some())];
    if let (Some((option, _)), true) = (styles.iter().find(|(_, given)| *given), slices.is_empty()) {
        bail!("{option} styles the slice pictures, and none are asked for; add --slices (e.g. --slices z=0.5)");
    }
    let colormap = args.colormap.unwrap_or(Colormap::Viridis);
    let value_label = args.value_label.clone().unwrap_or_else(|| "emission E [a.u.]".into());
    let export_box = match &args.bbox {
        Some(text) => {
            let b: Vec<f64> = text
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .with_context(|| format!("--box {text:?}: expected six numbers XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX"))?;
            if b.len() != 6 {
                bail!("--box {text:?}: expected six numbers XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX, got {}", b.len());
            }
            let aabb = Aabb { min: DVec3::new(b[0], b[1], b[2]), max: DVec3::new(b[3], b[4], b[5]) };
            aabb.validate().context("--box")?;
            Some(aabb)
        }
        None => None,
    };
    if let Some(v) = args.isosurface {
        if !v.is_finite() {
            bail!("--isosurface must be a finite value");
        }
    }

    let scene = match &args.scene {
        Some(p) => {
            Some(fluidnerf_io::scene::load_scene(p).with_context(|| format!("reading the scene {}", p.display()))?)
        }
        None => None,
    };
    // Exports go apart from the scene's inputs, whether the scene is given or the run records it.
    let scene_root = match &scene {
        Some(s) => Some(s.root.clone()),
        None => super::recorded_scene(&args.recon)?.and_then(|p| super::scene_folder(&p)),
    };
    if let Some(root) = &scene_root {
        fluidnerf_pipeline::rundir::refuse_among_scene_inputs(&args.out, root)?;
    }
    // The boxes, axis labels and the TIFF stack's calibration are in the reconstruction's length
    // unit: the scene's, else the one a run folder's report records. --units names the unit of
    // a volume file that records none; another unit than the recorded one would label the
    // numbers falsely (a stack in mm calibrated as metres reads back a thousand times too large).
    let recorded_units = match &scene {
        Some(s) => Some((s.units.clone(), format!("the scene {}", s.root.display()))),
        None => run_units(&args.recon)?,
    };
    // A calibrated TIFF stack records its own unit: its numbers are in it, and were labelled
    // mm (or --units) without a scene, a stack in µm coming out a thousand times too large.
    let stack_unit = match (&recorded_units, is_tiff(&args.recon)) {
        (None, true) => fluidnerf_io::volume::tiff_stack_unit(&args.recon)?,
        _ => None,
    };
    let units = match (&args.units, recorded_units, &stack_unit) {
        (Some(given), Some((unit, whose)), _) if *given != unit => bail!(
            "--units {given}: {whose} is in {unit}, and the export's box, axis labels and TIFF calibration are in \
             its unit; leave out --units (it names the unit of a volume file that records none)"
        ),
        (Some(given), _, Some(stack)) if given != stack && !fluidnerf_io::volume::is_length_unit(given) => bail!(
            "--units {given}: {} is calibrated in {stack}, and only nm, µm, mm, cm and m are converted; leave out \
             --units to export in {stack}",
            args.recon.display()
        ),
        (Some(given), _, _) => given.clone(),
        (None, Some((unit, _)), _) => unit,
        (None, None, Some(stack)) => stack.clone(),
        (None, None, None) => "mm".into(),
    };
    // The stack's box in the export's unit (read_tiff_stack converts between lengths).
    let source = load_source(&args.recon, scene.as_ref(), stack_unit.as_ref().map(|_| units.as_str()))?;
    let time = source.sample_time(args.time, "--time")?;
    source.warn_held([time], &args.recon);
    source.warn_time_unused(args.time, &args.recon);
    // The instant exported: sampled from a time-resolved field, or recorded for a volume file
    // (one of a run's frames, an earlier export), which the files and export.json carry on, so
    // that `eval` scores it against its own instant's truth.
    let (instant, instant_from) = match &source {
        Source::Field { times: Some(_), .. } => {
            let from = if args.time.is_some() { "--time" } else { "the run's first instant, --time's default" };
            (Some(time), from.to_string())
        }
        Source::Volume(_) if args.recon.is_file() => match recorded_volume_time(&args.recon) {
            Some((place, t)) => (Some(t), place),
            None => (None, String::new()),
        },
        _ => (None, String::new()),
    };
    if args.average > 1 && matches!(source, Source::Volume(_)) {
        log::warn!(
            "--average {} has no effect: {} is a volume, resampled trilinearly; cell averages are taken of trained \
             fields",
            args.average,
            args.recon.display()
        );
    }

    // The export grid.
    if let Some(b) = export_box {
        let r = source.aabb();
        if !b.overlaps(&r) {
            bail!(
                "--box {:?}..{:?} does not overlap the reconstruction's box {:?}..{:?}: the export would hold only zeros",
                b.min.to_array(),
                b.max.to_array(),
                r.min.to_array(),
                r.max.to_array()
            );
        }
        let outside = 1.0 - overlap_fraction(&b, &r);
        if outside > 1e-6 {
            log::warn!(
                "--box reaches beyond the reconstruction's box {} .. {}: the export is zero there, {:.0} % of its \
                 volume",
                num(r.min.to_array()),
                num(r.max.to_array()),
                100.0 * outside
            );
        }
    }
    // The reconstruction's own box given as --box (typed from the scene, or from `info`'s
    // three decimals) is no other box: a volume keeps its grid, as without --box.
    let own_cell = match &source {
        Source::Volume(v) => v.spacing().min_element(),
        Source::Field { .. } => 0.0,
    };
    let export_box = export_box.filter(|b| !same_box(b, &source.aabb(), 1e-3 * own_cell));
    let aabb = export_box.unwrap_or_else(|| source.aabb());
    if let Some(n) = args.resolution {
        // The volume, and a copy as the files are written.
        let voxels: u64 = Volume::dims_for(&aabb, n).iter().map(|&d| d as u64).product();
        super::check_memory(|| format!("--resolution {n} ({voxels} voxels)"), 8 * voxels)?;
    }
    let volume = match (&source, args.resolution, export_box) {
        (Source::Volume(v), None, None) => v.clone(),
        (Source::Volume(v), res, _) => {
            let dims = Volume::dims_for(&aabb, res.unwrap_or(128));
            v.resample(dims, aabb)
        }
        (Source::Field { field, .. }, res, _) => {
            let dims = Volume::dims_for(&aabb, res.unwrap_or(128));
            crate::progress::sampled(dims, aabb, field.as_ref(), time, args.average as usize)
                .with_context(|| format!("{}", args.recon.display()))?
        }
    };
    let truth = match &args.compare {
        Some(p) => {
            // A .npy truth holds no box: it fills the scene's, which is the reconstruction's
            // when no scene is given (a run records its scene's box).
            // A calibrated truth's box in the export's unit, the run's when no scene is given:
            // taken as it was, a truth in cm beside a run in mm was drawn ten times too small.
            let t =
                read_volume(p, Some(scene.as_ref().map_or_else(|| source.aabb(), |s| s.aabb)), Some(units.as_str()))?;
            // A truth apart from the exported box is zero on every slice: its panels would be
            // drawn empty beside the reconstruction, as if it held no field there.
            let b = &volume.aabb;
            if !t.aabb.overlaps(b) {
                bail!(
                    "--compare {}: the truth fills the box {} .. {}, which does not overlap the exported box {} .. {}: \
                     its slices would be empty; give the truth of this reconstruction",
                    p.display(),
                    fluidnerf_core::num(t.aabb.min.to_array()),
                    fluidnerf_core::num(t.aabb.max.to_array()),
                    fluidnerf_core::num(b.min.to_array()),
                    fluidnerf_core::num(b.max.to_array())
                );
            }
            let outside = 1.0 - overlap_fraction(b, &t.aabb);
            if outside > 1e-6 {
                log::warn!(
                    "--compare {}: the truth fills the box {} .. {}, {:.0} % of the exported box lies outside it: \
                     its panels are zero there, and the difference shows the reconstruction as error",
                    p.display(),
                    num(t.aabb.min.to_array()),
                    num(t.aabb.max.to_array()),
                    100.0 * outside
                );
            }
            if let Some(t) = instant {
                refuse_truth_of_another_instant("--compare", p, scene_root.as_deref(), (t, &instant_from))?;
            }
            Some(if t.dims == volume.dims && t.aabb == volume.aabb { t } else { t.resample(volume.dims, volume.aabb) })
        }
        None => None,
    };

    // Outputs, refused if present unless --force.
    let out = &args.out;
    let mut outputs: Vec<PathBuf> = Vec::new();
    if npy {
        outputs.push(out.join("volume.npy"));
    }
    if vti {
        outputs.push(out.join("volume.vti"));
    }
    if raw {
        outputs.push(out.join("volume.raw"));
        outputs.push(fluidnerf_io::volume::raw_sidecar_path(&out.join("volume.raw")));
    }
    if args.tiff {
        outputs.push(out.join("volume.tif"));
    }
    let slice_name = |prefix: &str, (a, f): (Axis, f64)| out.join(format!("{prefix}_{a}_{f:.3}.png"));
    for (k, &s) in slices.iter().enumerate() {
        if let Some(same) = slices[..k].iter().find(|&&o| slice_name("slice", o) == slice_name("slice", s)) {
            bail!(
                "--slices {}={} and {}={} would both write {}; give slices at least 0.001 apart",
                same.0,
                same.1,
                s.0,
                s.1,
                slice_name("slice", s).display()
            );
        }
        outputs.push(slice_name("slice", s));
        if truth.is_some() {
            outputs.push(slice_name("compare", s));
        }
    }
    if args.isosurface.is_some() {
        for m in &args.mesh {
            outputs.push(out.join(match m {
                MeshFormat::Ply => "isosurface.ply",
                MeshFormat::Obj => "isosurface.obj",
            }));
        }
    }
    let settings_path = out.join("export.json");
    if !args.force {
        if let Some(p) = outputs.iter().chain([&settings_path]).find(|p| p.exists()) {
            bail!("{} exists; pass --force to overwrite it", p.display());
        }
    }
    // --force overwrites files; a folder in an output's place would stop the export part way,
    // the outputs before it overwritten and export.json not.
    if let Some(p) = outputs.iter().chain([&settings_path]).find(|p| p.exists() && !p.is_file()) {
        bail!("{} exists and is not a file; --force overwrites earlier outputs, not folders: move it", p.display());
    }
    // Read before it is replaced: an earlier export's outputs this one does not write again are
    // removed once it has written its own.
    let earlier = earlier_outputs(&settings_path);
    // The files read, a raw volume's sidecar with it: exported over (`export e/volume.npy -o e
    // --force`), or removed as an earlier export's output, the input was lost.
    let inputs = std::iter::once((args.recon.as_path(), "the reconstruction read"))
        .chain(args.compare.as_deref().map(|p| (p, "the ground truth given with --compare")));
    for (input, what) in inputs {
        let sidecar = fluidnerf_io::volume::raw_sidecar_path(input);
        let read = [Some(input), input.extension().is_some_and(|e| e == "raw").then_some(sidecar.as_path())];
        for (file, p) in read
            .into_iter()
            .flatten()
            .flat_map(|f| outputs.iter().cloned().chain(earlier.iter().map(|n| out.join(n))).map(move |p| (f, p)))
        {
            fluidnerf_pipeline::rundir::refuse_input_file(&p, file, what)?;
        }
    }
    // The mesh before any file: a surface whose mesh memory cannot hold is refused with nothing
    // written (a surface through noise crosses nearly every cell, and a failed allocation aborts).
    let mesh = match args.isosurface {
        Some(iso) => {
            let limit = fluidnerf_pipeline::available_memory().unwrap_or(u64::MAX);
            let Some(mesh) = fluidnerf_viz::marching_cubes_within(&volume, iso, limit) else {
                bail!(
                    "--isosurface {}: the surface crosses so many of the {} voxels that its mesh would need more than \
                     the {} of memory available; give a value nearer the field's extremes, or a lower --resolution",
                    num(iso),
                    volume.data.len(),
                    fluidnerf_pipeline::bytes(limit)
                );
            };
            // Where the surface leaves the box it is open, and its own sum is no volume: the
            // region's is taken with the surface closed on the box's faces.
            let enclosed = if mesh.is_watertight() {
                Some(mesh.enclosed_volume())
            } else {
                fluidnerf_viz::enclosed_volume_within(&volume, iso, limit)
            };
            Some((iso, mesh, enclosed))
        }
        None => None,
    };
    super::create_output_folder(out)?;

    let [nx, ny, nz] = volume.dims;
    println!("{}: {} sampled on {nx}x{ny}x{nz} voxels", args.recon.display(), source.describe());
    if npy {
        let p = out.join("volume.npy");
        fluidnerf_io::volume::write_npy(&p, &volume).with_context(|| format!("writing {}", p.display()))?;
    }
    if vti {
        let p = out.join("volume.vti");
        fluidnerf_io::volume::write_vti_at(&p, &volume, instant).with_context(|| format!("writing {}", p.display()))?;
    }
    if raw {
        let p = out.join("volume.raw");
        fluidnerf_io::volume::write_raw_at(&p, &volume, instant).with_context(|| format!("writing {}", p.display()))?;
    }
    if args.tiff {
        let p = out.join("volume.tif");
        fluidnerf_io::volume::write_tiff_stack(&p, &volume, &units)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    let style = PanelStyle { colormap, colorbar_label: value_label.clone(), ..Default::default() };
    for &(axis, fraction) in &slices {
        let position = axis.position_at(&volume.aabb, fraction);
        let panel = fluidnerf_viz::slice(&volume, axis, position, &units)?;
        let p = slice_name("slice", (axis, fraction));
        fluidnerf_viz::write_panels_png(&p, std::slice::from_ref(&panel), &style)
            .with_context(|| format!("writing {}", p.display()))?;
        if let Some(t) = &truth {
            let truth_panel = fluidnerf_viz::slice(t, axis, position, &units)?;
            let p = slice_name("compare", (axis, fraction));
            fluidnerf_viz::write_comparison_png(&p, &truth_panel, &panel, &style)
                .with_context(|| format!("writing {}", p.display()))?;
        }
    }
    if let Some((iso, mesh, enclosed)) = mesh {
        for m in &args.mesh {
            let (p, r) = match m {
                MeshFormat::Ply => {
                    let p = out.join("isosurface.ply");
                    let r = fluidnerf_io::mesh::write_ply(&p, &mesh.vertices, &mesh.triangles);
                    (p, r)
                }
                MeshFormat::Obj => {
                    let p = out.join("isosurface.obj");
                    let r = fluidnerf_io::mesh::write_obj(&p, &mesh.vertices, &mesh.triangles);
                    (p, r)
                }
            };
            r.with_context(|| format!("writing {}", p.display()))?;
        }
        if mesh.triangles.is_empty() {
            let (lo, hi) = volume.min_max();
            println!(
                "isosurface at {}: empty, area 0: the exported values range over [{}, {}], so no cell crosses it; the \
                 mesh file holds no triangles",
                num(iso),
                num(lo),
                num(hi)
            );
        } else {
            println!(
                "isosurface at {}: {} vertices, {} triangles, area {:.4} {units}², enclosed volume {}{}",
                num(iso),
                mesh.vertices.len(),
                mesh.triangles.len(),
                mesh.area(),
                enclosed
                    .map_or("not computed (too large for the memory available)".into(), |v| format!("{v:.4} {units}³")),
                if mesh.is_watertight() {
                    ""
                } else {
                    " (the surface is open where it leaves the box; the volume is the region's inside the outermost \
                     voxel centres)"
                }
            );
        }
    }
    let settings = Settings {
        version: env!("CARGO_PKG_VERSION"),
        reconstruction: &args.recon,
        scene: args.scene.as_deref(),
        aabb: volume.aabb,
        dims: volume.dims,
        spacing: volume.spacing().to_array(),
        average: matches!(source, Source::Field { .. }).then_some(args.average as usize),
        time: instant,
        units: &units,
        colormap,
        value_label: &value_label,
        slices: slices.clone(),
        compare: args.compare.as_deref(),
        isosurface: args.isosurface,
        mesh: &args.mesh,
        outputs: outputs.iter().map(|p| p.display().to_string()).collect(),
    };
    let text = serde_json::to_string_pretty(&settings)?;
    fluidnerf_io::atomic_write(&settings_path, |w| w.write_all(text.as_bytes()))
        .with_context(|| format!("writing {}", settings_path.display()))?;
    let written: Vec<&std::ffi::OsStr> = outputs.iter().filter_map(|p| p.file_name()).collect();
    for name in earlier.iter().filter(|n| !written.contains(&n.as_os_str())) {
        let p = out.join(name);
        match std::fs::remove_file(&p) {
            Ok(()) => println!("removed {}, an output of the earlier export", p.display()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => log::warn!("cannot remove {}, an output of the earlier export: {e}", p.display()),
        }
    }
    for p in &outputs {
        println!("wrote {}", p.display());
    }
    Ok(())
}
