//! `fluidnerf eval`: scores a reconstruction against the scene's ground truth (volume NRMSE,
//! PSNR, global and windowed SSIM, globally and per region, per time step) and against the
//! scene's held-out images (reprojection), prints a table and writes JSON and CSV.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::ValueEnum;
use fluidnerf_core::glam::DVec3;
use fluidnerf_core::num;
use fluidnerf_core::scene::same_time;
use fluidnerf_core::{Aabb, ScalarField, Scene, Volume};
use fluidnerf_metrics::{
    evaluate_volume, regions_flow_axis, FlowAxisFrom, MetricsReport, Region, ReprojectionOptions, SsimParams,
    SsimWindow, VolumeMetricOptions,
};
use serde::Serialize;

use super::export::{read_volume, recorded_volume_time};

/// The local window of the windowed SSIM.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Window {
    /// Equal weights in a cube (square for images) of --ssim-size voxels per side
    /// (skimage's default).
    Uniform,
    /// Gaussian weights, sigma 1.5 voxels, 11 taps (skimage's gaussian_weights=True).
    Gaussian,
}

/// Score a reconstruction against ground truth and held-out camera images.
///
/// Volume metrics (over the truth's voxel centres; a reconstruction on another grid is
/// resampled trilinearly): NRMSE (dissertation Eq. 6.18), PSNR, SSIM over the whole volume as
/// one window (Eq. 6.19) and the windowed 3D SSIM (as skimage), for the whole box and for each
/// region, at every time step of the truth. Reprojection: the reconstruction is rendered from
/// every held-out camera and compared with its image (NRMSE, PSNR, global and windowed 2D SSIM).
///
/// A run folder of a neural reconstruction (static or time-resolved) is scored through its
/// trained field: sampled exactly at the truth's voxel centres (at each step's time) and
/// rendered directly for the held-out views; a voxel run through its volume.
///
/// Prints a table; writes JSON (with the settings) and CSV. When RECON is a run directory and
/// neither --json nor --csv is given, writes `metrics.json` and `metrics.csv` into it.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The reconstruction: a volume file (`.npy` filling the scene's box, `.vti`, `.raw`
    /// with its JSON sidecar, or a `.tif` stack, calibrated or filling the scene's box) or a reconstruction run directory (a trained field, or
    /// `volume.npy`). For a time-resolved scene give one volume per truth time step, in the
    /// order the scene lists its truth, or one run directory (a time-resolved field).
    #[arg(required = true, num_args = 1..)]
    pub recon: Vec<PathBuf>,
    /// The scene: a folder holding `transforms.json`, or the file itself [default: for a run
    /// folder, the scene its `config.json` records].
    #[arg(short, long)]
    pub scene: Option<PathBuf>,
    /// Ground-truth volume to use instead of the scene's (`.npy` filling the scene's box,
    /// `.vti`, `.raw`, or a `.tif` stack, calibrated or filling the scene's box).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Regions scored separately, as NAME:X0:X1 (a slab along the box's x) or
    /// NAME:X0:X1:Y0:Y1:Z0:Z1, in coordinates normalised to the box (0 = min corner,
    /// 1 = max corner); comma-separated or repeated. Each NAME once, and not `all` (the whole
    /// volume's row). Default: laminar, transition and turbulent thirds of the box along the
    /// flow axis (--flow-axis, else the scene's flow_axis, else estimated from the truth, else
    /// +x).
    #[arg(long, value_delimiter = ',', conflicts_with = "no_regions")]
    pub regions: Vec<String>,
    /// The flow direction x,y,z (world) for the default regions: the laminar, transition and
    /// turbulent thirds along the box axis nearest to it, from where the flow enters
    /// [default: the scene's `flow_axis`, else estimated from the truth (the principal axis of
    /// the field, towards where it widens), else +x].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, conflicts_with_all = ["no_regions", "regions"])]
    pub flow_axis: Option<Vec<f64>>,
    /// For a neural run directory, score its sampled `volume.npy` instead of the trained field
    /// (a voxel run is scored through its volume anyway: a warning says so): every method on
    /// one output grid, as `study` and `demo` score them. The field, scored at the truth's voxel
    /// centres and rendered at the held-out pixels, is not bound to that grid.
    #[arg(long)]
    pub use_volume: bool,
    /// Score the whole volume only.
    #[arg(long)]
    pub no_regions: bool,
    /// Window of the windowed SSIM.
    #[arg(long, value_enum, default_value = "uniform")]
    pub ssim_window: Window,
    /// Side of the uniform SSIM window in voxels (odd, at least 3) [default: 7].
    #[arg(long)]
    pub ssim_size: Option<usize>,
    /// Data range R of PSNR and SSIM for the volume metrics. Default: the truth's max - min.
    #[arg(long)]
    pub data_range: Option<f64>,
    /// Rays per pixel along each image axis when rendering held-out views (1 to 64) [default: 2].
    #[arg(long, conflicts_with = "no_reprojection")]
    pub supersample: Option<usize>,
    /// Skip the reprojection onto held-out cameras.
    #[arg(long)]
    pub no_reprojection: bool,
    /// Write the metrics and settings as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the metrics table as CSV here.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Overwrite existing output files: earlier results only, never a file of the scene or of
    /// the run, nor a volume being read.
    #[arg(long)]
    pub force: bool,
    /// Writes the files only, printing nothing: for a command that scores its own runs (`study`).
    #[arg(skip)]
    pub silent: bool,
}

/// The settings written next to the metrics.
#[derive(Serialize)]
struct Settings<'a> {
    version: &'static str,
    reconstruction: &'a [PathBuf],
    /// A neural run scored through its written volume (`--use-volume`), not its field.
    use_volume: bool,
    scene: PathBuf,
    truth: Option<&'a Path>,
    volume: &'a VolumeMetricOptions,
    reprojection: Option<&'a ReprojectionOptions>,
}

/// The JSON output: the settings and the report (whose fields sit at the top level, so the file
/// also reads as a `MetricsReport`).
#[derive(Serialize)]
struct Output<'a> {
    settings: Settings<'a>,
    #[serde(flatten)]
    report: &'a MetricsReport,
    /// The scene's frame times without ground truth, not scored ([`Scene::times_without_truth`]).
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    times_without_truth: &'a [f64],
}

/// A reconstruction, as the metrics need it.
enum Recon {
    /// One volume per truth time step (or one for all), with the step's time; and for a
    /// time-resolved run scored through its volumes, every volume it wrote with its time, from
    /// which each held-out frame is drawn at its own instant.
    Volumes(Vec<(Option<f64>, Volume)>, Option<Vec<(Option<f64>, Volume)>>),
    /// A trained field (static or time-resolved) in world coordinates.
    Field(Box<dyn ScalarField + Send + Sync>),
}

impl Recon {
    /// The reconstruction to compare with `truth`, step `step` at `time`: a stored volume, or
    /// the field sampled at the truth's voxel centres.
    fn volume_for_step(&self, step: usize, truth: &Volume, time: Option<f64>) -> anyhow::Result<Cow<'_, Volume>> {
        Ok(match self {
            Recon::Volumes(v, _) => Cow::Borrowed(&v[step.min(v.len() - 1)].1),
            Recon::Field(f) => {
                Cow::Owned(crate::progress::sampled(truth.dims, truth.aabb, f.as_ref(), time.unwrap_or(0.0), 1)?)
            }
        })
    }

    /// The field to render for a frame at `time`: the field, the one volume, or the volume of
    /// that very instant ([`Recon::refuse_frames_without_volume`] has checked there is one).
    fn field_at(&self, time: Option<f64>) -> &dyn ScalarField {
        match self {
            Recon::Field(f) => f.as_ref(),
            Recon::Volumes(v, all) => {
                let volumes = all.as_deref().unwrap_or(v);
                if let [(_, only)] = volumes {
                    return only;
                }
                let at = |(t, _): &&(Option<f64>, Volume)| match (t, time) {
                    (Some(t), Some(time)) => same_time(*t, time),
                    _ => false,
                };
                volumes.iter().find(at).map_or(&volumes[0].1, |(_, v)| v)
            }
        }
    }

    /// Refuses to reproject a held-out frame of `scene` (those in `holdouts`) at an instant no
    /// volume holds, when there are several: drawn from the volume of the nearest step, it was
    /// scored against another instant's field without a word. `run` names the run the volumes
    /// are of, when they are a run's.
    fn refuse_frames_without_volume(
        &self,
        scene: &Scene,
        holdouts: &[usize],
        run: Option<&Path>,
    ) -> anyhow::Result<()> {
        let Recon::Volumes(v, all) = self else { return Ok(()) };
        let volumes = all.as_deref().unwrap_or(v);
        if volumes.len() < 2 {
            return Ok(());
        }
        for &i in holdouts {
            let frame = &scene.frames[i];
            let held = volumes.iter().any(|(t, _)| matches!((t, frame.time), (Some(t), Some(f)) if same_time(*t, f)));
            if held {
                continue;
            }
            let times: Vec<String> = volumes.iter().filter_map(|(t, _)| t.map(|t| num(t).to_string())).collect();
            let at = frame.time.map_or("without a time".to_string(), |t| format!("at t = {}", num(t)));
            let instead = match run {
                Some(_) => "score the run's trained field instead (leave out --use-volume)",
                None => "give --no-reprojection, or a volume of that instant",
            };
            bail!(
                "the scene's held-out frame {} ({}) is {at}, and no volume given is of that instant (they are of t = \
                 {}): it would be drawn from another instant's; {instead}",
                i,
                frame.file_path.display(),
                times.join(", ")
            );
        }
        Ok(())
    }
}

#[allow(clippy::print_stdout)]
pub fn run(args: Args) -> anyhow::Result<()> {
    // Validate everything before the work starts.
    let default_regions = args.regions.is_empty() && !args.no_regions;
    let mut regions: Vec<Region> = if args.no_regions {
        Vec::new()
    } else if args.regions.is_empty() {
        Region::jet_thirds()
    } else {
        args.regions.iter().map(|s| Region::parse(s)).collect::<Result<_, _>>().context("--regions")?
    };
    // Rows and JSON entries go by the region's name.
    if let Some((_, r)) = regions.iter().enumerate().find(|&(i, r)| regions[..i].iter().any(|q| q.name == r.name)) {
        bail!("--regions: the name {} is given twice; give each region its own name", r.name);
    }
    if let Some(r) = regions.iter().find(|r| r.name == fluidnerf_metrics::WHOLE_VOLUME) {
        bail!(
            "--regions: the name {} is the whole volume's row in the table and the CSV; give the region another name",
            r.name
        );
    }
    // One volume file for two steps is a slip (a glob or a copied line): each step would be
    // scored against the other's reconstruction.
    for (i, p) in args.recon.iter().enumerate() {
        if let Some(first) = args.recon[..i].iter().find(|q| fluidnerf_pipeline::rundir::same_path(q, p)) {
            bail!(
                "RECON: {} is given twice (as {} and {}); give one volume per time step, each once, or one volume \
                 for all",
                p.display(),
                first.display(),
                p.display()
            );
        }
    }
    let ssim_size = args.ssim_size.unwrap_or(7);
    let window = match args.ssim_window {
        Window::Uniform => SsimWindow::Uniform { size: ssim_size },
        Window::Gaussian if args.ssim_size.is_some() => bail!(
            "--ssim-size {ssim_size} sets the side of the uniform window; the gaussian window's is fixed (sigma 1.5 \
             voxels, 11 taps): leave out --ssim-size or --ssim-window gaussian"
        ),
        Window::Gaussian => SsimWindow::Gaussian { sigma: 1.5 },
    };
    if ssim_size < 3 || ssim_size.is_multiple_of(2) {
        bail!(
            "--ssim-size must be odd and at least 3 (a 1-voxel window has no sample variance, so its SSIM is \
             undefined), got {ssim_size}"
        );
    }
    let supersample = args.supersample.unwrap_or(2);
    if !(1..=fluidnerf_core::render::MAX_SUPERSAMPLE).contains(&supersample) {
        bail!(
            "--supersample must be between 1 and {} rays per pixel along each axis, got {supersample}",
            fluidnerf_core::render::MAX_SUPERSAMPLE,
        );
    }
    if let Some(r) = args.data_range {
        // A huge range's square overflowed the metrics' constants (PSNR infinite, SSIM NaN), a
        // tiny one's vanished (SSIM NaN), unannounced.
        let k = fluidnerf_metrics::SsimParams::default();
        if let Some(why) = fluidnerf_metrics::data_range_problem(r, [k.k1, k.k2]) {
            bail!("--data-range {why}");
        }
    }
    if let Some(a) = &args.flow_axis {
        if a.len() != 3 || a.iter().any(|v| !v.is_finite()) || a.iter().all(|&v| v == 0.0) {
            bail!("--flow-axis needs a non-zero direction x,y,z, got {a:?}");
        }
    }
    let ssim = SsimParams { window, ..Default::default() };
    let reprojection_options = ReprojectionOptions { supersample, step: None, ssim };

    let scene_path = super::scene_or_recorded(args.scene.as_deref(), &args.recon)?;
    let scene = fluidnerf_io::scene::load_scene(&scene_path)
        .with_context(|| format!("reading the scene {}", scene_path.display()))?;
    let holdouts: Vec<usize> =
        if args.no_reprojection { Vec::new() } else { scene.holdout_frames().map(|(i, _)| i).collect() };
    // The windowed 2D SSIM needs its window inside every held-out image: refused now, not after
    // the volumes are scored.
    let side = window.size();
    if let Some(&i) = holdouts.iter().find(|&&i| {
        let camera = &scene.frames[i].camera;
        camera.width().min(camera.height()) < side
    }) {
        let (frame, camera) = (&scene.frames[i], &scene.frames[i].camera);
        // The widest odd window that fits, where one of at least 3 does.
        let fits = camera.width().min(camera.height());
        let widest = if fits.is_multiple_of(2) { fits.saturating_sub(1) } else { fits };
        let (what, instead) = match args.ssim_window {
            Window::Uniform => (format!("--ssim-size {side}"), format!("give --ssim-size {widest} or less, or ")),
            Window::Gaussian => (
                format!("--ssim-window gaussian ({side} px wide)"),
                format!("give --ssim-window uniform --ssim-size {widest} or less, or "),
            ),
        };
        let instead = if widest >= 3 { instead } else { String::new() };
        bail!(
            "{what}: the held-out frame {i} ({}) is only {}x{} px, smaller than the SSIM window; {instead}give \
             --no-reprojection",
            frame.file_path.display(),
            camera.width(),
            camera.height()
        );
    }
    let run_dir = (args.recon.len() == 1 && args.recon[0].is_dir()).then(|| args.recon[0].clone());
    let (json_path, csv_path) = match (&args.json, &args.csv, &run_dir) {
        (None, None, Some(dir)) => (Some(dir.join("metrics.json")), Some(dir.join("metrics.csv"))),
        (j, c, _) => (j.clone(), c.clone()),
    };
    // One file under two spellings (`a.json`, `./a.json`) would have the CSV replace the JSON.
    if let (Some(json), Some(csv)) = (&json_path, &csv_path) {
        if fluidnerf_pipeline::rundir::same_path(json, csv) {
            bail!("--json {} and --csv {} name the same file; give two", json.display(), csv.display());
        }
    }
    if let Some(json) = &json_path {
        let record = json.display().to_string();
        let recon = args.recon.iter().map(|p| ("RECON", p.as_path()));
        let given = [("--scene", &args.scene), ("--truth", &args.truth)];
        super::recordable(&record, recon.chain(given.iter().filter_map(|(o, p)| Some((*o, p.as_deref()?)))))?;
    }
    let outputs = [
        (if args.json.is_some() { "--json" } else { "the JSON output" }, &json_path, "metrics.json"),
        (if args.csv.is_some() { "--csv" } else { "the CSV output" }, &csv_path, "metrics.csv"),
    ];
    let outputs: Vec<(&str, &PathBuf, &str)> =
        outputs.iter().filter_map(|&(o, p, name)| p.as_ref().map(|p| (o, p, name))).collect();
    for &(option, p, _) in &outputs {
        refuse_inputs(p, &scene_path, run_dir.as_deref(), &args).with_context(|| option.to_string())?;
    }
    for &(option, p, name) in &outputs {
        // A folder is no file to replace, --force or not: writing failed only after the scoring.
        if p.is_dir() {
            let instead = match option.starts_with("--") {
                true => format!("give the name of a file to write, e.g. {}", p.join(name).display()),
                false => "move it away, or give --json and --csv".to_string(),
            };
            bail!("{option} {}: is a folder; {instead}", p.display());
        }
        if p.exists() && !args.force {
            bail!("{} exists; pass --force to overwrite it", p.display());
        }
        // `--force` replaces earlier results: a file of another kind (another scene's
        // transforms.json, an image) named by mistake is not one.
        let csv = name == "metrics.csv";
        if p.exists() && !earlier_metrics(p, csv) {
            bail!(
                "{option} {}: exists and is not the {} of an earlier evaluation; --force replaces only those: give \
                 another file",
                p.display(),
                if csv { "CSV table" } else { "JSON metrics" }
            );
        }
        // Checked now, not after the scoring: the folder must exist and take a new file.
        let folder = p.parent().filter(|f| !f.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
        if !folder.is_dir() {
            let what = if folder.exists() { "is a file, not a folder" } else { "does not exist" };
            bail!("{}: the folder {} {what}", p.display(), folder.display());
        }
        fluidnerf_io::check_writable(p)
            .with_context(|| format!("{option} {}: cannot write into its folder {}", p.display(), folder.display()))?;
    }

    // The instant one volume file records (a run's frame, an export of one time), read once:
    // the truth it is scored against, its steps and its held-out frames follow it.
    let lone_instant = match args.recon.as_slice() {
        [recon] if recon.is_file() => recorded_volume_time(recon),
        _ => None,
    };
    let truth: Vec<(Option<f64>, Volume)> = match &args.truth {
        Some(path) => {
            let volume = read_volume(path, Some(scene.aabb), Some(&scene.units))?;
            let what = format!("--truth {}", path.display());
            super::warn_of_other_box(
                &what,
                &volume.aabb,
                &scene,
                "the metrics cover that box only, and the reconstruction is zero outside its own",
            );
            // A volume of one instant scored against the truth of another: the difference would
            // be the flow's change between them.
            if let Some((place, at)) = &lone_instant {
                let from = format!("{place} records it for {}", args.recon[0].display());
                super::export::refuse_truth_of_another_instant("--truth", path, Some(&scene.root), (*at, &from))?;
            }
            vec![(None, volume)]
        }
        None => fluidnerf_io::scene::load_truth(&scene)
            .with_context(|| format!("reading the ground truth of {}", scene_path.display()))?,
    };
    // The windowed SSIM of the whole volume needs its window inside the truth's grid: an
    // explicit --ssim-size wider than it left the column empty without a word.
    if let Some((i, (_, t))) = truth.iter().enumerate().find(|(_, (_, t))| t.dims.iter().any(|&n| n < side)) {
        let [nx, ny, nz] = t.dims;
        let smallest = nx.min(ny).min(nz);
        let widest = if smallest.is_multiple_of(2) { smallest.saturating_sub(1) } else { smallest };
        let file = match (&args.truth, scene.truth.get(i)) {
            (Some(p), _) => p.clone(),
            (None, Some(r)) => scene.resolve(&r.file_path),
            (None, None) => scene_path.clone(),
        };
        let what = match args.ssim_window {
            Window::Uniform => format!("--ssim-size {side}"),
            Window::Gaussian => format!("--ssim-window gaussian ({side} voxels wide)"),
        };
        let instead = if widest >= 3 { format!("; give --ssim-size {widest} or less") } else { String::new() };
        if args.ssim_size.is_some() {
            bail!(
                "{what}: the ground truth {} is only {nx}x{ny}x{nz} voxels, smaller than the SSIM window{instead}",
                file.display()
            );
        }
        log::warn!(
            "the ground truth {} is only {nx}x{ny}x{nz} voxels, smaller than the {side}-voxel SSIM window: no windowed \
             SSIM{instead}",
            file.display()
        );
    }
    // NRMSE is relative to the truth's norm: undefined for an all-zero truth.
    for (i, (_, t)) in truth.iter().enumerate() {
        let file = match (&args.truth, scene.truth.get(i)) {
            (Some(p), _) => p.clone(),
            (None, Some(r)) => scene.resolve(&r.file_path),
            (None, None) => scene_path.clone(),
        };
        // A region asked for is scored: one between the truth's voxel centres was warned of and
        // left out of the table.
        if !default_regions {
            if let Some(r) = regions.iter().find(|r| r.voxel_ranges(t.dims).iter().any(|a| a.is_empty())) {
                let [x, y, z] = t.dims;
                bail!(
                    "--regions: {} holds no voxel centre of the {x}×{y}×{z} truth grid ({}); widen it to hold one",
                    r.name,
                    file.display()
                );
            }
        }
        if t.data.iter().all(|&v| v == 0.0) {
            bail!(
                "{}: every voxel of the ground truth is zero, so the NRMSE (relative to the truth's norm) is \
                 undefined; give a truth that holds the field",
                file.display()
            );
        }
    }
    // The regions follow the flow: given, recorded in the scene, or estimated from the truth.
    if default_regions {
        let recorded = fluidnerf_io::scene::recorded(&scene).context("the scene's flow_axis")?.flow_axis;
        let given = args.flow_axis.as_ref().map(|a| DVec3::new(a[0], a[1], a[2]));
        let flow = regions_flow_axis(given, recorded, truth.first().map(|(_, t)| t));
        match flow {
            Some((axis, from)) => {
                let from = match from {
                    FlowAxisFrom::Given => "--flow-axis",
                    FlowAxisFrom::Recorded => "the scene's flow_axis",
                    FlowAxisFrom::Estimated => "estimated from the truth",
                };
                log::info!("flow axis {:?} ({from}): laminar, transition, turbulent thirds along it", axis.to_array());
            }
            None => log::info!("no flow axis given, recorded or estimable: regions are thirds along +x"),
        }
        regions = fluidnerf_metrics::default_regions(flow.map(|(axis, _)| axis));
    }
    let volume_options = VolumeMetricOptions { regions, ssim, data_range: args.data_range };
    // The truth at each step scored. One truth without a time stands for every frame time of a
    // time-resolved run, as the run scored it (and `reconstruct` said so), and for each of as
    // many volumes as frame times: eval refused both.
    let per_frame_volumes = args.recon.len() > 1 && args.recon.len() == scene.times().len();
    let timeless = fluidnerf_pipeline::timeless_truth(&scene).filter(|_| args.truth.is_none());
    let timeless_for_run = timeless.is_some()
        && (per_frame_volumes
            || run_dir.as_deref().is_some_and(|dir| {
                fluidnerf_pipeline::load::LoadedRun::open(dir, Some(scene.aabb))
                    .is_ok_and(|run| run.kind == fluidnerf_pipeline::RunKind::Temporal)
            }));
    let truth_steps: Vec<(Option<f64>, &Volume)> = match truth.as_slice() {
        [(None, only)] if timeless_for_run => {
            if let Some(message) = &timeless {
                log::warn!("{message}");
            }
            scene.times().into_iter().map(|t| (Some(t), only)).collect()
        }
        _ => truth.iter().map(|(t, v)| (*t, v)).collect(),
    };
    // One volume file of one instant (one of a run's frames, an export of one time) is scored
    // at that instant's truth alone: at every step, it was scored against the others too.
    let truth_steps = match (args.recon.as_slice(), truth_steps.len(), &lone_instant) {
        ([recon], 2.., Some((place, at))) => {
            let at = *at;
            let Some(step) = truth_steps.iter().find(|(t, _)| t.is_some_and(|t| same_time(t, at))) else {
                let times: Vec<String> =
                    truth_steps.iter().filter_map(|(t, _)| t.map(|t| num(t).to_string())).collect();
                bail!(
                    "{}: it holds the field at t = {} ({place}), and the scene's ground truth is at t = {}, none \
                     of them that instant; give the truth of t = {} with --truth",
                    recon.display(),
                    num(at),
                    times.join(", "),
                    num(at)
                );
            };
            log::info!("{}: scored at t = {} ({place}), its instant", recon.display(), num(at));
            vec![*step]
        }
        // A volume of one instant against a truth without a time: scored as a steady flow's.
        ([recon], 1, Some((place, at))) if truth_steps[0].0.is_none() && args.truth.is_none() => {
            log::warn!(
                "{} holds the field at t = {} ({place}), and the scene's ground truth has no time: it is scored \
                 against it as against a steady flow's; if the truth is of one instant, give it that `time`",
                recon.display(),
                num(*at)
            );
            truth_steps
        }
        _ => truth_steps,
    };
    // The time steps the reconstruction volumes stand for: the truth's, else the frames'.
    let step_times: Vec<Option<f64>> = if truth.is_empty() {
        scene.times().into_iter().map(Some).collect()
    } else {
        truth_steps.iter().map(|(t, _)| *t).collect()
    };
    // Times the scene's truth does not cover are not scored, and said so.
    let without_truth = if args.truth.is_some() { Vec::new() } else { scene.times_without_truth() };
    let listed = |times: &[f64]| times.iter().map(|&t| num(t).to_string()).collect::<Vec<_>>().join(", ");
    let lone_time = lone_instant.as_ref().map(|(_, t)| *t);
    let (recon, recon_boxes) =
        load_recon(&args.recon, &scene, args.use_volume, args.truth.as_deref(), &step_times, lone_time)?;
    refuse_truth_apart(&truth, &recon_boxes, args.truth.as_deref(), &scene)?;
    if let Recon::Volumes(volumes, _) = &recon {
        if volumes.len() > 1 && volumes.len() != step_times.len() {
            let steps = if truth.is_empty() { "frame times" } else { "ground-truth time steps" };
            let gaps = if without_truth.is_empty() {
                String::new()
            } else {
                format!(" (none at t = {}, which is not scored)", listed(&without_truth))
            };
            bail!(
                "{} reconstruction volumes given but the scene has {} {steps}{gaps}; give one volume, or one per \
                 step in the order the scene lists them",
                volumes.len(),
                step_times.len()
            );
        }
        if volumes.len() > 1 {
            refuse_frames_out_of_order(&args.recon, &step_times)?;
        }
        if volumes.len() == 1 && truth_steps.len() > 1 {
            log::warn!(
                "one reconstruction volume for {} truth time steps: the same volume is scored at every step",
                truth_steps.len()
            );
        }
    }
    // Checked before any scoring: the views rendered for reprojection would hold infinities, and
    // their metrics were written as infinite and NaN.
    if let (false, Recon::Volumes(volumes, all)) = (holdouts.is_empty(), &recon) {
        for (i, (_, v)) in all.as_deref().unwrap_or(volumes).iter().enumerate() {
            if let Some(problem) = fluidnerf_core::render::integrals_overflow(v, scene.intensity_scale) {
                let file = if run_dir.is_some() { &args.recon[0] } else { &args.recon[i] };
                bail!("{}: reprojected onto the held-out views: {problem}, or give --no-reprojection", file.display());
            }
        }
    }
    recon.refuse_frames_without_volume(&scene, &holdouts, run_dir.as_deref())?;
    if truth.is_empty() && holdouts.is_empty() {
        bail!(
            "nothing to evaluate: the scene {} has no ground truth and no held-out frames (give --truth)",
            scene_path.display()
        );
    }
    // Without held-out frames the table simply had no reprojection rows, and a --supersample
    // given for them was dropped unannounced.
    if holdouts.is_empty() && !args.no_reprojection {
        let unused = match args.supersample {
            Some(n) => format!("; --supersample {n} has no effect"),
            None => String::new(),
        };
        log::warn!(
            "the scene {} holds no frame out (`\"holdout\": true`): only the volume is scored, no reprojection{unused}",
            scene_path.display()
        );
    }

    let mut report = MetricsReport::default();
    for (step, &(time, t)) in truth_steps.iter().enumerate() {
        let estimate = recon.volume_for_step(step, t, time).with_context(|| format!("{}", args.recon[0].display()))?;
        // A field whose finite weights are so large that its values overflow (render refuses
        // it) was scored: NRMSE 2.6e38, a windowed SSIM of 1.85e20, reprojections of inf and NaN.
        if let (Recon::Field(_), Some(_)) =
            (&recon, fluidnerf_core::render::integrals_overflow(&estimate, scene.intensity_scale))
        {
            let largest = estimate.data.iter().fold(0f32, |m, x| m.max(x.abs()));
            bail!(
                "{}: the field reaches {largest:.3e} at the truth's voxel centres, so its line integrals overflow \
                 32-bit floats: its weights are finite but far too large; the weights file is damaged or was edited",
                args.recon[0].display()
            );
        }
        let metrics = evaluate_volume(&estimate, t, time, &volume_options)
            .with_context(|| format!("scoring time step {step}"))?;
        report.steps.push(metrics);
    }
    // One volume of one instant is reprojected onto the held-out frames of that instant only:
    // drawn for the others, it was scored against another instant's images without a word.
    let single_instant = match &recon {
        Recon::Volumes(v, None) if v.len() == 1 => v[0].0,
        _ => None,
    };
    let reprojected: Cow<'_, Scene> = match single_instant {
        Some(at) if !holdouts.is_empty() => {
            let mut s = scene.clone();
            let mut left_out = Vec::new();
            for f in s.frames.iter_mut().filter(|f| f.holdout && f.time.is_some_and(|t| !same_time(t, at))) {
                f.holdout = false;
                left_out.push(f.file_path.display().to_string());
            }
            if !left_out.is_empty() {
                log::warn!(
                    "{} holds the field at t = {}: the held-out frames of other instants are not reprojected ({})",
                    args.recon[0].display(),
                    num(at),
                    left_out.join(", ")
                );
            }
            Cow::Owned(s)
        }
        _ => Cow::Borrowed(&scene),
    };
    let reprojected_frames = if holdouts.is_empty() { 0 } else { reprojected.holdout_frames().count() };
    if reprojected_frames > 0 {
        // The held-out images as a run fits the others, divided by the gain the run recorded
        // for them.
        let gains = match &run_dir {
            Some(dir) if dir.join("report.json").is_file() => {
                let path = dir.join("report.json");
                fluidnerf_pipeline::score::recorded_gains(&fluidnerf_pipeline::RunReport::read(&path)?, &path)?
            }
            _ => Vec::new(),
        };
        let bar = crate::progress::bar(reprojected_frames as u64, "reprojecting");
        report.reprojection = fluidnerf_pipeline::score::score_held_out(
            &reprojected,
            &gains,
            |time| recon.field_at(time),
            &reprojection_options,
            || bar.inc(1),
        )
        .with_context(|| format!("scoring the held-out frames of the scene {}", scene_path.display()))?;
        bar.finish_and_clear();
    }

    let settings = Settings {
        version: env!("CARGO_PKG_VERSION"),
        reconstruction: &args.recon,
        use_volume: args.use_volume,
        scene: scene_path.clone(),
        truth: args.truth.as_deref(),
        volume: &volume_options,
        reprojection: (!args.no_reprojection).then_some(&reprojection_options),
    };
    // The files first, then the table: a reader of the table that goes away (`eval … | head`)
    // ends the program at its next print, which left the files unwritten.
    if let Some(path) = &json_path {
        let output = Output { settings, report: &report, times_without_truth: &without_truth };
        let mut text = serde_json::to_string_pretty(&output)?;
        text.push('\n');
        fluidnerf_io::atomic_write(path, |w| w.write_all(text.as_bytes()))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &csv_path {
        let text = report.to_csv();
        fluidnerf_io::atomic_write(path, |w| w.write_all(text.as_bytes()))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if args.silent {
        return Ok(());
    }
    print_table(&report);
    if !without_truth.is_empty() && !truth.is_empty() {
        println!(
            "not scored: no ground truth at t = {} (the scene's truth covers {} of its {} frame times)",
            listed(&without_truth),
            scene.times().len() - without_truth.len(),
            scene.times().len()
        );
    }

    for path in json_path.iter().chain(&csv_path) {
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Refuses volume files given for the time steps `step_times` (one each, in order) when one is a
/// run's frame written at another time ([`recorded_volume_time`]): given out of order (or for a
/// scene whose truth is at other times), it would be scored against another instant's truth.
fn refuse_frames_out_of_order(paths: &[PathBuf], step_times: &[Option<f64>]) -> anyhow::Result<()> {
    let listed = || step_times.iter().flatten().map(|&t| num(t).to_string()).collect::<Vec<_>>().join(", ");
    for (i, (path, step)) in paths.iter().zip(step_times).enumerate() {
        let (Some((report, written)), Some(step)) = (recorded_volume_time(path), step) else { continue };
        if fluidnerf_core::scene::same_time(written, *step) {
            continue;
        }
        let at = paths
            .iter()
            .zip(step_times)
            .position(|(_, t)| t.is_some_and(|t| fluidnerf_core::scene::same_time(t, written)))
            .map_or("no time step of the scene has that time".to_string(), |j| {
                format!("the scene's time step {} has that time", j + 1)
            });
        bail!(
            "RECON {}: it was written at t = {} ({}), but it is given as volume {} of {}, for the time step at \
             t = {}; {at}. Give one volume per time step in the order of the steps' times ({})",
            path.display(),
            num(written),
            report,
            i + 1,
            paths.len(),
            num(*step),
            listed()
        );
    }
    Ok(())
}

/// Whether the file at `path` is what `eval` writes: its CSV table (`csv`), which starts with
/// the table's header, or its JSON metrics, an object with the evaluation's `settings`.
fn earlier_metrics(path: &Path, csv: bool) -> bool {
    use std::io::{BufRead, Read};
    let Ok(file) = std::fs::File::open(path) else { return false };
    if csv {
        let mut first = String::new();
        return std::io::BufReader::new(file).read_line(&mut first).is_ok()
            && first.starts_with("kind,time,subset,count,nrmse");
    }
    // Metrics files are small; a large file is something else.
    let mut text = String::new();
    if file.take(64 << 20).read_to_string(&mut text).is_err() {
        return false;
    }
    serde_json::from_str::<serde_json::Value>(&text)
        .is_ok_and(|v| v.get("settings").and_then(|s| s.get("reconstruction")).is_some())
}

/// Refuses `out` as an output file when it is a file this evaluation reads or that belongs to
/// the scene or the run: the scene file and what it lists (images, masks, background and
/// flat-field frames, truth) or records, the files the run in `run_dir` wrote, the volume files
/// given, and their sidecars. `--force` replaces earlier results, never the inputs they were made from.
fn refuse_inputs(out: &Path, scene_path: &Path, run_dir: Option<&Path>, args: &Args) -> anyhow::Result<()> {
    use fluidnerf_pipeline::rundir::{refuse_input_file, refuse_run_file, refuse_scene_file};
    refuse_scene_file(out, &fluidnerf_io::scene::scene_file_path(scene_path))?;
    if let Some(dir) = run_dir {
        refuse_run_file(out, dir)?;
    }
    let volumes = args.recon.iter().filter(|_| run_dir.is_none()).map(|p| (p, "a reconstruction volume being scored"));
    for (volume, what) in volumes.chain(args.truth.iter().map(|p| (p, "the ground truth given with --truth"))) {
        refuse_input_file(out, volume, what)?;
        let sidecar = fluidnerf_io::volume::raw_sidecar_path(volume);
        if volume.extension().is_some_and(|e| e.eq_ignore_ascii_case("raw")) {
            refuse_input_file(out, &sidecar, &format!("the JSON sidecar of {}", volume.display()))?;
        }
    }
    Ok(())
}

/// Loads the reconstruction arguments: volume files, or one run folder of any kind (its
/// trained field, static or of space and time, unless `use_volume`; else its volumes).
/// `step_times`: the times of the time steps scored, in order (the truth's, else the frames');
/// `lone_time`: the instant one volume file given alone records.
fn load_recon(
    paths: &[PathBuf],
    scene: &Scene,
    use_volume: bool,
    truth: Option<&Path>,
    step_times: &[Option<f64>],
    lone_time: Option<f64>,
) -> anyhow::Result<(Recon, Vec<(String, Aabb)>)> {
    if let [dir] = paths {
        if dir.is_dir() {
            let run = fluidnerf_pipeline::load::LoadedRun::open(dir, Some(scene.aabb))?;
            let what = format!("the run in {}", dir.display());
            // A volume given with --truth has no time: a time-resolved run would be scored at
            // time 0 (its first instant, or its first volume), whatever instant the file holds.
            if let (Some(file), Some(span)) = (truth, run.time_span()?) {
                bail!(
                    "--truth {}: a volume without a time, but the run in {} is time-resolved (instants {} … {}), \
                     so there is no telling which of its instants to score against it; score the run against the \
                     scene's truth, whose entries have times, or export the instant with `export --time` and \
                     score that volume",
                    file.display(),
                    dir.display(),
                    num(span.first),
                    num(span.last)
                );
            }
            if use_volume && run.kind == fluidnerf_pipeline::RunKind::Volume {
                log::warn!(
                    "--use-volume has no effect: {} is a voxel run, scored through its volume anyway",
                    dir.display()
                );
            }
            // The run against the scene, as Python's `score_held_out` checks it: another scene
            // or box warned of; a time-resolved field repeats its first or last instant outside
            // them (its volumes may stand for held-out times there), and a stopped run has
            // neither field nor volumes at the instants it did not reach. One truth without a
            // time is scored at the frames' times (checked below).
            let timeless = fluidnerf_pipeline::timeless_truth(scene).is_some();
            let truth_entries =
                scene.truth.iter().filter(|_| !timeless).map(|t| (t.time, "truth volume", &t.file_path));
            let entries = truth_entries.chain(scene.frames.iter().map(|f| (f.time, "frame", &f.file_path)));
            let entries = entries.map(|(t, what, path)| (t, format!("the scene's {what} {}", path.display())));
            fluidnerf_pipeline::score::check_run_on_scene(&run, scene, use_volume, entries, |m| log::warn!("{m}"))?;
            let use_volume = use_volume || run.kind == fluidnerf_pipeline::RunKind::Volume;
            if use_volume {
                let volumes = run.volumes()?;
                let boxes = vec![(what, run.aabb)];
                if volumes.iter().all(|(t, _)| t.is_none()) {
                    return Ok((Recon::Volumes(volumes, None), boxes));
                }
                let steps = volumes_at_steps(dir, &volumes, step_times)?;
                return Ok((Recon::Volumes(steps, Some(volumes)), boxes));
            }
            return Ok((Recon::Field(run.field()?), vec![(what, run.aabb)]));
        }
    }
    if let Some(p) = paths.iter().find(|p| p.is_dir()) {
        bail!("{}: give one run folder, or volume files", p.display());
    }
    if use_volume {
        bail!(
            "--use-volume applies to a run folder (it scores the run's volume instead of its trained field); volume \
             files are scored as they are: leave it out"
        );
    }
    let mut volumes = Vec::with_capacity(paths.len());
    let mut boxes = Vec::with_capacity(paths.len());
    for (i, p) in paths.iter().enumerate() {
        let volume = read_volume(p, Some(scene.aabb), Some(&scene.units))?;
        super::warn_of_other_box(&p.display().to_string(), &volume.aabb, scene, "the volume is zero outside it");
        boxes.push((p.display().to_string(), volume.aabb));
        // Several stand each for its time step; one for the instant it records, if any.
        let time = match paths.len() {
            1 => lone_time,
            _ => step_times.get(i).copied().flatten(),
        };
        volumes.push((time, volume));
    }
    Ok((Recon::Volumes(volumes, None), boxes))
}

/// Refuses a ground truth whose box does not overlap a reconstruction's (`boxes`, named): the
/// reconstruction is zero on every voxel of that truth, so every metric would score zeros
/// against it, an NRMSE of 1 reported as a result. A truth in a box only partly shared is
/// warned of where it is read.
fn refuse_truth_apart(
    truth: &[(Option<f64>, Volume)],
    boxes: &[(String, Aabb)],
    given: Option<&Path>,
    scene: &Scene,
) -> anyhow::Result<()> {
    for (i, (_, t)) in truth.iter().enumerate() {
        let Some((what, b)) = boxes.iter().find(|(_, b)| !b.overlaps(&t.aabb)) else {
            continue;
        };
        let file = match (given, scene.truth.get(i)) {
            (Some(p), _) => format!("--truth {}", p.display()),
            (None, Some(r)) => format!("the ground truth {}", scene.resolve(&r.file_path).display()),
            (None, None) => "the ground truth".to_string(),
        };
        bail!(
            "{file} fills the box {} .. {}, which does not overlap the box {} .. {} of {what}: the reconstruction is \
             zero on every voxel of the truth, so every metric would score nothing against it; give the truth of \
             this scene, or a volume in its box",
            num(t.aabb.min.to_array()),
            num(t.aabb.max.to_array()),
            num(b.min.to_array()),
            num(b.max.to_array())
        );
    }
    Ok(())
}

/// The volumes of the time-resolved run in `dir` (each with its time) that stand for the time
/// steps `step_times`, in the steps' order, each with its time: the run writes its series in
/// increasing time, with volumes at held-out times the scene may have no truth for, so the
/// position of a volume in the series is not the step it stands for. Refused, naming the time,
/// when a step has no volume ([`fluidnerf_pipeline::score::volume_at`]).
fn volumes_at_steps(
    dir: &Path,
    volumes: &[(Option<f64>, Volume)],
    step_times: &[Option<f64>],
) -> anyhow::Result<Vec<(Option<f64>, Volume)>> {
    let at = |(i, &t): (usize, &Option<f64>)| -> anyhow::Result<(Option<f64>, Volume)> {
        let what = format!("the scene's time step {}", i + 1);
        Ok((t, fluidnerf_pipeline::score::volume_at(dir, volumes, t, &what)?.clone()))
    };
    step_times.iter().enumerate().map(at).collect()
}

/// Formats a metric for the table: fixed decimals, `inf`, or `-` (an undefined NRMSE is
/// `undefined`, with its reason under the table).
fn fmt(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.decimals$}"),
        Some(v) if v.is_nan() => "nan".into(),
        Some(v) => format!("{}inf", if v < 0.0 { "-" } else { "" }),
        None => "-".into(),
    }
}

#[allow(clippy::print_stdout)]
fn print_table(report: &MetricsReport) {
    let rows = report.rows();
    let subset_w = rows.iter().map(|r| r.subset.len()).max().unwrap_or(6).max(6);
    println!(
        "{:<12} {:>8} {:<subset_w$} {:>10} {:>9} {:>9} {:>11} {:>13}",
        "kind", "time", "subset", "count", "NRMSE", "PSNR dB", "SSIM global", "SSIM windowed"
    );
    for r in &rows {
        println!(
            "{:<12} {:>8} {:<subset_w$} {:>10} {:>9} {:>9} {:>11} {:>13}",
            r.kind,
            r.time.map_or("-".to_string(), |t| format!("{t}")),
            r.subset,
            r.count,
            if r.nrmse_undefined.is_some() { "undefined".to_string() } else { fmt(Some(r.nrmse), 4) },
            fmt(Some(r.psnr_db), 2),
            fmt(Some(r.ssim_global), 4),
            fmt(r.ssim_windowed, 4),
        );
    }
    // One note per reason, naming the rows it stands for.
    let mut notes: Vec<(&str, Vec<String>)> = Vec::new();
    for r in &rows {
        if let Some(why) = &r.nrmse_undefined {
            let row = match r.time {
                Some(t) => format!("{} {} at t = {t}", r.kind, r.subset),
                None => format!("{} {}", r.kind, r.subset),
            };
            match notes.iter_mut().find(|(w, _)| w == why) {
                Some((_, list)) => list.push(row),
                None => notes.push((why, vec![row])),
            }
        }
    }
    for (why, list) in notes {
        println!("NRMSE undefined for {}: {why}", list.join(", "));
    }
}
