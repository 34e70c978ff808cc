//! `fluidnerf study`: a grid of reconstructions — methods × camera counts × noise levels ×
//! camera layouts — on a synthetic phantom, or methods × camera counts on a scene of the
//! user's (`--scene`), every method under the same stopping policy and scored on the held-out
//! camera, with a table, plots and a report. Resumable: a cell whose run folder holds a
//! finished run is read back, not run again.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use fluidnerf_core::num;
use fluidnerf_pipeline::html::{self, RunSummary};
use fluidnerf_pipeline::rundir::FolderKind;
use fluidnerf_pipeline::{Method, MethodConfig, Overwrite, RunConfig, RunStatus, StopReason, StopRule, StoppingPolicy};
use fluidnerf_viz::report::{Figure, ImageData, Report, Table};
use fluidnerf_viz::{LinePlot, Series};
use serde::{Deserialize, Serialize};

use super::reconstruct::{MethodArg, StopArg};

/// Named grids.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StudyPreset {
    /// Training cameras 4, 8, 15, 30 and 40 on a 360° ring, noiseless (dissertation Fig. 7.7).
    Cameras,
    /// 15 cameras, image noise 0, 2.5, 5 and 10 % of each image's maximum (Fig. 7.10).
    Noise,
    /// 8 cameras on a 360° ring, a 180° arc and a sphere, noiseless (Figs. 7.8–7.9).
    Layout,
    /// A tiny grid that runs in seconds (4 and 6 cameras, 24² px, at most 20 iterations, the
    /// held-out camera scored every 5): a check that the command works, not a comparison.
    Smoke,
}

/// Camera layouts of the grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LayoutChoice {
    /// A ring around the flow axis over 360°.
    Ring360,
    /// A ring over a 180° arc (no camera faces another).
    Arc180,
    /// A Fibonacci lattice on a sphere.
    Sphere,
}

impl LayoutChoice {
    fn name(self) -> &'static str {
        match self {
            LayoutChoice::Ring360 => "ring360",
            LayoutChoice::Arc180 => "arc180",
            LayoutChoice::Sphere => "sphere",
        }
    }

    fn synth_args(self) -> &'static [&'static str] {
        match self {
            LayoutChoice::Ring360 => &["--layout", "ring", "--arc", "360"],
            LayoutChoice::Arc180 => &["--layout", "ring", "--arc", "180"],
            LayoutChoice::Sphere => &["--layout", "sphere"],
        }
    }
}

/// Run a grid of reconstructions on a synthetic phantom, or on a scene of yours, and compare
/// the methods.
///
/// Each cell synthesises a scene (the --scene-preset with the cell's camera count, layout and
/// noise; one more camera than the count is made and held out: it drives held-out early
/// stopping and scores reprojections) and reconstructs it with every method under one
/// stopping policy. With --scene, the cells are your scene and subsets of its cameras
/// (--cameras), its own held-out cameras in each. Each run is then scored as `fluidnerf eval`
/// scores it, through the volume it wrote on the output grid (a field's too, with
/// --use-volume; into the run's `metrics.json`): against the ground truth, and on the held-out
/// camera (the NRMSE of its image rendered from the volume), the same measure for every method
/// and one that needs no ground truth. Writes into OUT:
/// `scenes/`, `runs/SCENE/METHOD/` (`METHOD-seedS/` with --repeats; each with its config.json),
/// `study.json` and `study.csv` (one row per run),
/// plots of volume NRMSE and SSIM against the camera count and against noise, and
/// `report.html`. Where a cell holds fields (fluidnerf, fast, hybrid) and voxel methods (the
/// classical ones and the voxel baseline), each field's NRMSE is also given as a ratio to the
/// best voxel method's of its cell (with --repeats, of their means).
///
/// Rerunning the same command continues an interrupted study; --force starts it over.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output directory.
    #[arg(short, long)]
    pub out: PathBuf,
    /// The grid.
    #[arg(long, value_enum, default_value = "cameras")]
    pub preset: StudyPreset,
    /// Synthetic scene preset the cells start from (`fluidnerf synth --list-presets`).
    #[arg(long, default_value = "demo")]
    pub scene_preset: String,
    /// Study a scene of yours instead of a synthetic grid: a recording (`fluidnerf import`) or
    /// any static scene that holds at least one camera out (`"holdout": true`). Every method
    /// runs on it under the one stopping policy, which the held-out camera drives, and is scored
    /// on that camera's image, and against the scene's ground truth if it has one. Its
    /// images and noise are its own, so --preset, --scene-preset, --noise, --layouts and
    /// --pixels do not apply; --cameras gives counts of its training cameras to study, each a
    /// subset spread over their viewing lines (default: all of them). The scene is read, never
    /// written.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["preset", "scene_preset", "noise", "layouts", "pixels"])]
    pub scene: Option<PathBuf>,
    /// Methods, comma-separated; static ones only: a study refuses the time-resolved
    /// tr-fluidnerf, tr-fast and static-per-frame [default: fast,hybrid,asart: the grid field
    /// alone, the default method, and the classical baseline].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub methods: Option<Vec<MethodArg>>,
    /// Training camera counts, comma-separated, each 2 to 999 [default: the preset's]. With
    /// --scene: counts of the scene's training cameras, each cell a subset of them whose
    /// viewing lines are furthest apart (its held-out cameras kept) [default: all of them].
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub cameras: Option<Vec<usize>>,
    /// Image noise levels (fraction of each image's maximum, in [0, 1)), comma-separated
    /// [default: the preset's].
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub noise: Option<Vec<f64>>,
    /// Camera layouts, comma-separated [default: the preset's].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub layouts: Option<Vec<LayoutChoice>>,
    /// Image side in pixels, 8 to 1024 [default: 64, smoke 24].
    #[arg(long)]
    pub pixels: Option<u32>,
    /// Truth voxels along the longest side, also the output resolution, 4 to 512 [default: 64,
    /// smoke 16].
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Stopping rule of every method (see `reconstruct --help`); `auto` is the held-out rule,
    /// since every scene of a study holds a camera out.
    #[arg(long, value_enum, default_value = "held-out")]
    pub stop: StopArg,
    /// Iteration cap of every method [default: 1000000 under held-out and budget, so that the
    /// held-out rule or the time budget ends every run, not a method's own cap (SART 50,
    /// ASART 250, the grid fields 2000, the faithful network 25 000, ...); each method's own
    /// under own; smoke 20].
    #[arg(long, value_parser = super::parse_max_iterations)]
    pub max_iterations: Option<usize>,
    /// Seconds of work per run, the same for every method.
    #[arg(long, default_value_t = 60.0)]
    pub time_budget: f64,
    /// Seed of the scenes and the runs.
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = super::parse_seed)]
    pub seed: u64,
    /// Runs of each method in each cell, with the run seeds SEED, SEED + 1, …, on the same
    /// scene: the table adds each cell's mean and the range of its runs, and the plots show
    /// the means. A single run is one draw of the fields' random rays and weights (their
    /// volume NRMSE moves by a few per cent between seeds). The voxel methods without
    /// randomness (all but ART and MART) run once. 1 to 20.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=20))]
    pub repeats: u32,
    /// Give every voxel method the images' visual hull (`reconstruct --visual-hull`: voxels
    /// some camera sees dark, up to 4 noise deviations above the background, held at zero;
    /// dilated by a voxel), as the fields carve theirs. SART-TV keeps its weight, which
    /// over-smooths inside a hull, and the hybrid's own voxel start runs without one, which
    /// made the better hybrid (docs/claims.md).
    #[arg(long)]
    pub visual_hull: bool,
    /// Start over, replacing the scenes and runs of an earlier study in OUT (those its
    /// study.json lists; other files under its `scenes/` and `runs/` are kept).
    #[arg(long)]
    pub force: bool,
}

/// The lock file of a study's folder, held while a study writes into it.
const STUDY_LOCK: &str = ".study.lock";

/// The resolved grid, written to `study.json` and checked when a study is continued.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Grid {
    /// The named grid (none for a scene given).
    #[serde(skip_serializing_if = "Option::is_none")]
    preset: Option<StudyPreset>,
    /// The synthetic preset the cells' scenes are made from (empty for a scene given).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    scene_preset: String,
    methods: Vec<Method>,
    cameras: Vec<usize>,
    noise: Vec<f64>,
    layouts: Vec<LayoutChoice>,
    pixels: u32,
    resolution: usize,
    stopping: StoppingPolicy,
    seed: u64,
    /// Runs of each method that uses its seed, per cell (studies written before it: 1).
    #[serde(default = "one_repeat")]
    repeats: u32,
    /// The voxel methods held at zero outside the images' visual hull.
    #[serde(default)]
    visual_hull: bool,
    /// The scene studied instead of a synthetic grid (`--scene`, absolute).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scene: Option<PathBuf>,
    /// The training cameras of the scene given (0 without one).
    #[serde(default, skip_serializing_if = "is_zero")]
    scene_cameras: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn one_repeat() -> u32 {
    1
}

impl Grid {
    /// The run seeds of `method` in every cell: one per repeat for a method whose result
    /// depends on its seed, the study's own for the others.
    fn seeds(&self, method: Method) -> std::ops::Range<u64> {
        let n = if self.repeated(method) { u64::from(self.repeats) } else { 1 };
        self.seed..self.seed.saturating_add(n)
    }

    /// Whether `method` runs several times in each cell, once per seed.
    fn repeated(&self, method: Method) -> bool {
        self.repeats > 1 && method.uses_seed()
    }

    /// The run folder's name of `method` with `seed` in a cell's folder: the method's name, and
    /// the seed when the study repeats the method's runs.
    fn run_name(&self, method: Method, seed: u64) -> String {
        if self.repeated(method) {
            format!("{}-seed{seed}", method.name())
        } else {
            method.name().to_string()
        }
    }

    /// Runs of the whole grid.
    fn runs_total(&self) -> usize {
        let per_cell: usize = self.methods.iter().map(|&m| self.seeds(m).count()).sum();
        self.cells().len() * per_cell
    }

    /// The cells of the grid, in the order they run: layouts, then camera counts, then noise
    /// levels; one cell for a scene given (`--scene`).
    fn cells(&self) -> Vec<Cell> {
        if let Some(scene) = &self.scene {
            return self
                .cameras
                .iter()
                .map(|&cameras| {
                    let (name, source) = match cameras < self.scene_cameras {
                        true => (format!("{GIVEN_LAYOUT}-c{cameras:02}"), CellScene::Subset(scene.clone())),
                        false => (GIVEN_LAYOUT.into(), CellScene::Given(scene.clone())),
                    };
                    Cell { layout: GIVEN_LAYOUT.into(), cameras, noise: 0.0, name, scene: source }
                })
                .collect();
        }
        let mut cells = Vec::new();
        for &layout in &self.layouts {
            for &cameras in &self.cameras {
                for &noise in &self.noise {
                    cells.push(Cell {
                        layout: layout.name().into(),
                        cameras,
                        noise,
                        name: scene_name(layout, cameras, noise),
                        scene: CellScene::Synth(layout),
                    });
                }
            }
        }
        cells
    }
}

/// The layout column (and the run folder `runs/scene/`) of a scene given with `--scene`.
const GIVEN_LAYOUT: &str = "scene";

/// One cell of the grid: a scene, on which every method runs.
#[derive(Clone, Debug)]
struct Cell {
    layout: String,
    /// Training cameras (a scene given: its own).
    cameras: usize,
    /// Noise added to the images (a scene given: none, and 0 in the record).
    noise: f64,
    /// The folder of its scene under `scenes/` and of its runs under `runs/`.
    name: String,
    scene: CellScene,
}

/// Where a cell's scene comes from.
#[derive(Clone, Debug)]
enum CellScene {
    /// Synthesised by the study, with this layout.
    Synth(LayoutChoice),
    /// The scene given (`--scene`), read where it is.
    Given(PathBuf),
    /// A subset of the training cameras of the scene given, a scene the study writes
    /// ([`super::scene_subset`]).
    Subset(PathBuf),
}

impl Cell {
    /// The folder of the cell's scene.
    fn scene_dir(&self, out: &Path) -> PathBuf {
        match &self.scene {
            CellScene::Given(scene) => scene.clone(),
            _ => out.join("scenes").join(&self.name),
        }
    }

    /// The scene given with `--scene` that the cell's scene is or is made from.
    fn source(&self) -> Option<&Path> {
        match &self.scene {
            CellScene::Given(scene) | CellScene::Subset(scene) => Some(scene),
            CellScene::Synth(_) => None,
        }
    }

    /// The cell in words, for messages.
    fn describe(&self) -> String {
        match &self.scene {
            CellScene::Subset(scene) => {
                format!("{} of the training cameras of the scene {}", self.cameras, scene.display())
            }
            CellScene::Given(scene) => format!("the scene {}", scene.display()),
            CellScene::Synth(_) => {
                format!("the scene of {} cameras, noise {}, {}", self.cameras, self.noise, self.layout)
            }
        }
    }
}

/// Writes the scene of a cell that is a subset of the scene given, unless it is there with the
/// same cameras ([`super::scene_subset`]).
fn ensure_subset(cell: &Cell, dir: &Path) -> anyhow::Result<()> {
    let CellScene::Subset(source) = &cell.scene else { return Ok(()) };
    let scene = fluidnerf_io::scene::load_scene(source).with_context(|| format!("--scene {}", source.display()))?;
    let expected = super::scene_subset::spread_cameras(&scene, cell.cameras);
    if let Some(record) = subset_record(dir)? {
        if record.source == *source && record.training_frames == expected && dir.join("transforms.json").is_file() {
            return Ok(());
        }
        bail!(
            "{} holds a subset of other cameras or of another scene ({}: frames {:?} of {}, where this study takes \
             frames {expected:?} of {}); use --force to start over or another folder",
            dir.display(),
            dir.join(super::scene_subset::SUBSET_RECORD).display(),
            record.training_frames,
            record.source.display(),
            source.display()
        );
    }
    super::scene_subset::write_subset(source, &scene, &expected, dir)
        .with_context(|| format!("writing the scene of {}", cell.describe()))
}

/// The record of the subset scene in `dir`, if there is one.
fn subset_record(dir: &Path) -> anyhow::Result<Option<super::scene_subset::SubsetRecord>> {
    let path = dir.join(super::scene_subset::SUBSET_RECORD);
    if !path.is_file() {
        return Ok(None);
    }
    Ok(Some(fluidnerf_pipeline::rundir::read_json(&path)?))
}

/// One run of the grid.
#[derive(Clone, Debug, Serialize)]
struct Row {
    layout: String,
    cameras: usize,
    noise: f64,
    method: String,
    /// The run's seed.
    seed: u64,
    /// One of several runs of its method in its cell (with repeats, a method that uses its
    /// seed): the tables name its seed.
    #[serde(skip)]
    repeated: bool,
    /// Volume NRMSE against the ground truth, of the volume the run wrote (`eval`, with
    /// `--use-volume` for a field): every method on the one output grid.
    nrmse: Option<f64>,
    ssim_global: Option<f64>,
    /// NRMSE of the held-out camera's image rendered from the result (`eval`'s reprojection,
    /// the mean over the held-out cameras): the one score of a scene without ground truth, the
    /// same measure for every method.
    holdout_nrmse: Option<f64>,
    /// Lowest held-out loss seen (each method's own measure; compare within a method).
    best_holdout_loss: Option<f64>,
    kept_iteration: usize,
    iterations: usize,
    stop_reason: String,
    train_time_s: f64,
    result_bytes: u64,
    run: String,
}

#[derive(Serialize)]
struct StudyRecord<'a> {
    version: &'static str,
    /// `finished`, or `interrupted` when Ctrl-C stopped the study before its last run: `rows`
    /// then holds the runs made so far.
    status: &'static str,
    /// Runs of the whole grid; `rows` holds them all once the study is finished.
    runs_total: usize,
    grid: &'a Grid,
    stopping_rule: String,
    rows: &'a [Row],
    /// With repeats: each cell's and method's mean over its runs so far.
    #[serde(skip_serializing_if = "<[Mean]>::is_empty")]
    means: &'a [Mean],
    /// Each field's NRMSE against the best voxel method of its cell ([`against_best`]).
    #[serde(skip_serializing_if = "<[AgainstBest]>::is_empty")]
    against_best_voxel: &'a [AgainstBest],
}

/// A cell's and method's runs summed up ([`means`]).
#[derive(Debug, Serialize)]
struct Mean {
    layout: String,
    cameras: usize,
    noise: f64,
    method: String,
    runs: usize,
    nrmse: Option<f64>,
    nrmse_min: Option<f64>,
    nrmse_max: Option<f64>,
    ssim_global: Option<f64>,
    holdout_nrmse: Option<f64>,
    train_time_s: f64,
}

/// The mean of each cell's and method's runs among `rows`, in the order of their first run.
fn means(rows: &[Row]) -> Vec<Mean> {
    let key = |r: &Row| (r.layout.clone(), r.cameras, r.noise.to_bits(), r.method.clone());
    let mut keys = Vec::new();
    for r in rows {
        if !keys.contains(&key(r)) {
            keys.push(key(r));
        }
    }
    keys.iter()
        .map(|k| {
            let runs: Vec<&Row> = rows.iter().filter(|r| &key(r) == k).collect();
            let n = runs.len() as f64;
            // Over the runs that scored; none when any did not (a run without a truth).
            let all = |f: fn(&Row) -> Option<f64>| runs.iter().map(|r| f(r)).collect::<Option<Vec<f64>>>();
            let nrmse = all(|r| r.nrmse);
            Mean {
                layout: k.0.clone(),
                cameras: k.1,
                noise: f64::from_bits(k.2),
                method: k.3.clone(),
                runs: runs.len(),
                nrmse: nrmse.as_ref().map(|v| v.iter().sum::<f64>() / n),
                nrmse_min: nrmse.as_ref().map(|v| v.iter().copied().fold(f64::INFINITY, f64::min)),
                nrmse_max: nrmse.as_ref().map(|v| v.iter().copied().fold(f64::NEG_INFINITY, f64::max)),
                ssim_global: all(|r| r.ssim_global).map(|v| v.iter().sum::<f64>() / n),
                holdout_nrmse: all(|r| r.holdout_nrmse).map(|v| v.iter().sum::<f64>() / n),
                train_time_s: runs.iter().map(|r| r.train_time_s).sum::<f64>() / n,
            }
        })
        .collect()
}

/// A field's volume NRMSE in a cell against the best voxel method's there ([`against_best`]):
/// what the project's accuracy targets are stated in. In a cell without ground truth, its
/// held-out view NRMSE against the best voxel method's.
#[derive(Debug, Serialize)]
struct AgainstBest {
    layout: String,
    cameras: usize,
    noise: f64,
    method: String,
    /// What is compared: `volume` (NRMSE against the ground truth) or `held-out view` (NRMSE of
    /// the held-out camera's image rendered from the result).
    measure: &'static str,
    /// The field's NRMSE (its mean over its runs, with repeats).
    nrmse: f64,
    best_voxel_method: String,
    best_voxel_nrmse: f64,
    /// `nrmse / best_voxel_nrmse`: below 1 the field is the more accurate.
    ratio: f64,
}

/// Whether the method named `method` reconstructs a field ([`Method::is_field`]).
fn is_field(method: &str) -> bool {
    method.parse::<Method>().is_ok_and(Method::is_field)
}

/// For every field in every cell that also holds a voxel method: its NRMSE against the lowest
/// of the voxel methods' (each a mean over its runs, as `cells` holds them; the first of equal
/// ones): the volume NRMSE where the cell has it, else the held-out view NRMSE (a scene
/// without ground truth). Cells and fields without a score are left out.
fn against_best(cells: &[Mean]) -> Vec<AgainstBest> {
    let same_cell = |a: &Mean, b: &Mean| a.layout == b.layout && a.cameras == b.cameras && a.noise == b.noise;
    type Score = fn(&Mean) -> Option<f64>;
    let measures: [(&'static str, Score); 2] = [("volume", |m| m.nrmse), ("held-out view", |m| m.holdout_nrmse)];
    let mut out = Vec::new();
    for field in cells.iter().filter(|m| is_field(&m.method)) {
        let found = measures.iter().find_map(|&(measure, score)| {
            let nrmse = score(field)?;
            let best = cells
                .iter()
                .filter(|m| same_cell(m, field) && !is_field(&m.method))
                .filter_map(|m| score(m).map(|v| (m, v)))
                .fold(None, |best: Option<(&Mean, f64)>, (m, v)| match best {
                    Some((_, b)) if b <= v => best,
                    _ => Some((m, v)),
                })?;
            Some((measure, nrmse, best))
        });
        if let Some((measure, nrmse, (voxel, best_nrmse))) = found {
            out.push(AgainstBest {
                layout: field.layout.clone(),
                cameras: field.cameras,
                noise: field.noise,
                method: field.method.clone(),
                measure,
                nrmse,
                best_voxel_method: voxel.method.clone(),
                best_voxel_nrmse: best_nrmse,
                ratio: nrmse / best_nrmse,
            });
        }
    }
    out
}

/// [`against_best`] as a terminal table.
fn against_best_table(rows: &[AgainstBest]) -> String {
    let mut s = format!(
        "{:<8} {:>7} {:>6} {:<12} {:>7} {:<17} {:>7} {:>6}  {}\n",
        "layout", "cameras", "noise", "field", "NRMSE", "best voxel method", "NRMSE", "ratio", "of"
    );
    for a in rows {
        s += &format!(
            "{:<8} {:>7} {:>6} {:<12} {:>7.4} {:<17} {:>7.4} {:>6.2}  {}\n",
            a.layout,
            a.cameras,
            noise_text(&a.layout, a.noise),
            a.method,
            a.nrmse,
            a.best_voxel_method,
            a.best_voxel_nrmse,
            a.ratio,
            a.measure
        );
    }
    s
}

fn grid(args: &Args) -> anyhow::Result<Grid> {
    let (cameras, noise, layouts): (Vec<usize>, Vec<f64>, Vec<LayoutChoice>) = match args.preset {
        StudyPreset::Cameras => (vec![4, 8, 15, 30, 40], vec![0.0], vec![LayoutChoice::Ring360]),
        StudyPreset::Noise => (vec![15], vec![0.0, 0.025, 0.05, 0.1], vec![LayoutChoice::Ring360]),
        StudyPreset::Layout => {
            (vec![8], vec![0.0], vec![LayoutChoice::Ring360, LayoutChoice::Arc180, LayoutChoice::Sphere])
        }
        StudyPreset::Smoke => (vec![4, 6], vec![0.0], vec![LayoutChoice::Ring360]),
    };
    let smoke = args.preset == StudyPreset::Smoke;
    if !(args.time_budget > 0.0 && args.time_budget.is_finite()) {
        bail!("--time-budget must be a positive, finite number of seconds, got {}", num(args.time_budget));
    }
    // Every scene of a study holds a camera out and every method is static, so `auto` is the
    // held-out rule: recorded as such, as each run records it, so that the runs of a continued
    // study match the grid and the table names the rule that ran.
    let rule = match args.stop {
        StopArg::Auto => StopRule::HeldOut,
        stop => stop.into(),
    };
    // A scene given: its own training cameras (all, unless --cameras asks for fewer), and its
    // images as they are.
    let resolution = args.resolution.unwrap_or(if smoke { 16 } else { 64 });
    let given = args.scene.as_deref().map(given_scene).transpose()?;
    let (cameras, noise, layouts) = match &given {
        Some((_, training)) => (vec![*training], vec![0.0], Vec::new()),
        None => (cameras, noise, layouts),
    };
    let g = Grid {
        preset: given.is_none().then_some(args.preset),
        scene_preset: if given.is_some() { String::new() } else { args.scene_preset.clone() },
        methods: args
            .methods
            .as_ref()
            .map_or_else(|| vec![Method::Fast, Method::Hybrid, Method::Asart], |m| m.iter().map(|m| m.0).collect()),
        cameras: args.cameras.clone().unwrap_or(cameras),
        // -0 is the level 0: its rows, table and plots wrote it as "-0".
        noise: args.noise.clone().unwrap_or(noise).iter().map(|n| n + 0.0).collect(),
        layouts: args.layouts.clone().unwrap_or(layouts),
        pixels: args.pixels.unwrap_or(if smoke { 24 } else { 64 }),
        resolution,
        stopping: StoppingPolicy {
            rule,
            max_iterations: args.max_iterations.or(default_cap(smoke, args.stop)),
            time_budget_s: Some(args.time_budget),
            // The fields' own interval (25) is longer than the smoke grid's 20 iterations.
            holdout_every: (smoke && rule == StopRule::HeldOut).then_some(SMOKE_HOLDOUT_EVERY),
            ..StoppingPolicy::default()
        },
        seed: args.seed,
        repeats: args.repeats,
        visual_hull: args.visual_hull,
        scene_cameras: given.as_ref().map_or(0, |(_, n)| *n),
        scene: given.map(|(dir, _)| dir),
    };
    if g.methods.is_empty() || g.cameras.is_empty() || g.noise.is_empty() || (g.layouts.is_empty() && g.scene.is_none())
    {
        bail!("the grid is empty: give at least one method, camera count, noise level and layout");
    }
    // A value given twice would run the same cells twice and print the same rows twice.
    super::given_once("--methods", &g.methods)?;
    super::given_once("--cameras", &g.cameras)?;
    super::given_once("--noise", &g.noise)?;
    super::given_once("--layouts", &g.layouts.iter().map(|l| l.name()).collect::<Vec<_>>())?;
    // Before the names below, which a level out of range (NaN, negative) would share with 0.
    if let Some(n) = g.noise.iter().find(|n| !(**n >= 0.0 && **n < 1.0)) {
        bail!("--noise: {n} is not a fraction in [0, 1)");
    }
    // Scenes are named by their noise in thousandths: two levels named alike would share one
    // scene and its runs, so the second level's rows would be the first's.
    let named = |n: f64| scene_name(LayoutChoice::Ring360, 0, n);
    for (i, &a) in g.noise.iter().enumerate() {
        if let Some(&b) = g.noise[..i].iter().find(|&&b| named(b) == named(a)) {
            bail!(
                "--noise: {b} and {a} would share one scene folder (…-n{:03}: levels are named in thousandths); give \
                 levels at least 0.001 apart",
                (a * 1000.0).round() as u64
            );
        }
    }
    if let Some(m) = g.methods.iter().find(|m| m.family() == fluidnerf_pipeline::Family::Temporal) {
        bail!("--methods: {m} is time-resolved; a study compares static reconstructions");
    }
    // A method whose held-out interval is longer than the cap never scores the held-out camera:
    // it keeps its last iterate, while the table says the held-out rule stopped it.
    if let (StopRule::HeldOut, Some(cap)) = (g.stopping.rule, g.stopping.max_iterations) {
        if let Some(m) = g.methods.iter().find(|m| g.stopping.holdout_interval(m.family()) > cap) {
            bail!(
                "--max-iterations {cap}: {m} scores the held-out camera every {} iterations, so under --stop held-out \
                 it would never be scored and would keep its last iterate; give --max-iterations {} or more, or \
                 --stop budget",
                g.stopping.holdout_interval(m.family()),
                g.stopping.holdout_interval(m.family())
            );
        }
    }
    // Only the voxel methods take the hull (the fields carve their own): without one the option
    // would change nothing, while the grid and the report said it applied.
    if g.visual_hull && !g.methods.iter().any(|m| m.family() == fluidnerf_pipeline::Family::Classical) {
        let methods: Vec<&str> = g.methods.iter().map(|m| m.name()).collect();
        bail!(
            "--visual-hull applies to the voxel methods (asart, sart, tv, ...), and --methods {} has none: add one, or \
             leave out --visual-hull",
            methods.join(",")
        );
    }
    if let Some(scene) = &g.scene {
        if let Some(&c) = g.cameras.iter().find(|&&c| c < 2 || c > g.scene_cameras) {
            bail!(
                "--cameras: {c} is not a count of the {} training cameras of the scene {}; give counts from 2 to {}",
                g.scene_cameras,
                scene.display(),
                g.scene_cameras
            );
        }
        return Ok(g);
    }
    // Known before anything is made: an unknown one failed only when its first scene was
    // synthesised, leaving the study's folder behind.
    let scene = super::static_preset("--scene-preset", &g.scene_preset, "a study")?;
    // A real-like recording has its own dark noise; the sensor's noise does not apply.
    if scene.real.is_some() {
        if let Some(n) = g.noise.iter().find(|&&n| n != 0.0) {
            bail!(
                "--noise: {n} does not apply to {}, a real-like recording with its own dark noise; give --noise 0",
                g.scene_preset
            );
        }
    }
    if let Some(&c) = g.cameras.iter().find(|&&c| c < 2) {
        bail!("--cameras: {c} is too few; give at least 2 training cameras");
    }
    // Each scene has one camera more than its count, held out.
    let most = fluidnerf_synth::MAX_CAMERAS - 1;
    if let Some(&c) = g.cameras.iter().find(|&&c| c > most) {
        bail!(
            "--cameras: {c} training cameras (and the one held out) are more than a rig can sensibly have; give at \
             most {most}"
        );
    }
    if !(8..=1024).contains(&g.pixels) {
        bail!("--pixels must be between 8 and 1024, got {}", g.pixels);
    }
    if !(4..=512).contains(&g.resolution) {
        bail!("--resolution must be between 4 and 512, got {}", g.resolution);
    }
    check_scenes(&g)?;
    Ok(g)
}

/// The scene given with `--scene` in `dir`, checked for a study: its absolute folder and its
/// training cameras. Refused: a scene that cannot be read, one that holds no camera out (the
/// held-out rule and the score need one), one of several times (a study compares static
/// reconstructions), and one with fewer than two training cameras.
fn given_scene(dir: &Path) -> anyhow::Result<(PathBuf, usize)> {
    let scene = fluidnerf_io::scene::load_scene(dir).with_context(|| format!("--scene {}", dir.display()))?;
    let root = std::path::absolute(&scene.root)?;
    let held_out = scene.holdout_frames().count();
    let training = scene.training_frames().count();
    if held_out == 0 {
        bail!(
            "--scene {}: holds no camera out, and a study stops every method by a held-out camera and scores it \
             there; mark one frame `\"holdout\": true` in its transforms.json (or import it with --holdout)",
            root.display()
        );
    }
    let times = scene.times();
    if times.len() > 1 {
        bail!(
            "--scene {}: holds {} instants; a study compares static reconstructions of one instant",
            root.display(),
            times.len()
        );
    }
    if training < 2 {
        bail!("--scene {}: has {training} training camera; a study needs at least 2", root.display());
    }
    Ok((root, training))
}

/// Iterations between held-out evaluations of every method in the smoke grid, so that the
/// fields are scored within its 20 iterations.
const SMOKE_HOLDOUT_EVERY: usize = 5;

fn default_cap(smoke: bool, stop: StopArg) -> Option<usize> {
    if smoke {
        Some(20)
    } else {
        super::comparison_cap(stop)
    }
}

/// The grid of the study recorded in `record` (its `study.json`).
fn read_earlier_grid(record: &Path) -> anyhow::Result<Grid> {
    #[derive(Deserialize)]
    struct Earlier {
        grid: Grid,
    }
    // A damaged record (cut short, edited) cannot say which scenes and runs are the study's, so
    // --force cannot remove them either: say what to do instead of the reader's complaint.
    let folder = record.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let earlier: Earlier = fluidnerf_pipeline::rundir::read_json(record).with_context(|| {
        format!(
            "{} is damaged, so the study's settings, scenes and runs cannot be read from it; to start over remove \
             it with the study's scenes/ and runs/ in {}, or write the study into another folder",
            record.display(),
            folder.display()
        )
    })?;
    Ok(earlier.grid)
}

/// Removes the scenes and runs the study of grid `g` wrote into `out` (`--force`), and the
/// `scenes/`, `runs/` and per-scene run folders left empty; anything else in them (a run or a
/// note of the user's) is left as it is.
fn remove_earlier_study(out: &Path, g: &Grid) -> anyhow::Result<()> {
    let remove = |p: &Path| -> anyhow::Result<()> {
        if p.exists() {
            std::fs::remove_dir_all(p).with_context(|| format!("removing {}", p.display()))?;
        }
        Ok(())
    };
    let remove_if_empty = |p: &Path| {
        // A folder that still holds something is kept: the error says nothing useful then.
        if std::fs::read_dir(p).is_ok_and(|mut d| d.next().is_none()) {
            let _ = std::fs::remove_dir(p);
        }
    };
    for cell in g.cells() {
        // A scene given is the user's: only the scenes the study made go.
        if !matches!(cell.scene, CellScene::Given(_)) {
            remove(&out.join("scenes").join(&cell.name))?;
        }
        let runs = out.join("runs").join(&cell.name);
        for (method, seed) in g.methods.iter().flat_map(|&m| g.seeds(m).map(move |s| (m, s))) {
            remove(&runs.join(g.run_name(method, seed)))?;
        }
        let record = runs.join(SCENE_FILES);
        if record.is_file() {
            std::fs::remove_file(&record).with_context(|| format!("removing {}", record.display()))?;
        }
        remove_if_empty(&runs);
    }
    remove_if_empty(&out.join("scenes"));
    remove_if_empty(&out.join("runs"));
    Ok(())
}

fn scene_name(layout: LayoutChoice, cameras: usize, noise: f64) -> String {
    format!("{}-c{cameras:02}-n{:03}", layout.name(), (noise * 1000.0).round() as u64)
}

/// The `synth` line of a cell's scene, written into `dir`.
fn synth_line(g: &Grid, dir: &Path, layout: LayoutChoice, cameras: usize, noise: f64) -> Vec<String> {
    let mut line: Vec<String> =
        vec!["synth".into(), "-q".into(), "--force".into(), format!("--preset={}", g.scene_preset)];
    for (k, v) in [
        ("--cameras", (cameras + 1).to_string()),
        ("--holdout", "1".to_string()),
        ("--noise", noise.to_string()),
        ("--pixels", g.pixels.to_string()),
        ("--resolution", g.resolution.to_string()),
        ("--seed", g.seed.to_string()),
    ] {
        line.extend([k.to_string(), v]);
    }
    line.extend(layout.synth_args().iter().map(|s| s.to_string()));
    // Joined to its option: a folder whose name starts with '-' (`--out=-st`) was read as
    // options of the synth line.
    line.push(format!("--out={}", dir.to_string_lossy()));
    line
}

/// Synthesises the scene of a cell unless a finished one is there; its summary prints unless
/// the study is quiet.
fn ensure_scene(g: &Grid, dir: &Path, layout: LayoutChoice, cameras: usize, noise: f64) -> anyhow::Result<()> {
    use clap::Parser;
    if dir.join("transforms.json").is_file() && dir.join("synth.json").is_file() {
        return Ok(());
    }
    let argv = std::iter::once("fluidnerf".to_string()).chain(synth_line(g, dir, layout, cameras, noise));
    let super::Command::Synth(args) = crate::Cli::try_parse_from(argv).map_err(|e| anyhow::anyhow!("{e}"))?.command
    else {
        bail!("{}: not a synth line", dir.display());
    };
    let summary = super::synth::synthesise(&args).with_context(|| format!("synthesising {}", dir.display()))?;
    if !crate::progress::quiet() {
        #[allow(clippy::print_stdout)]
        {
            print!("{summary}");
        }
    }
    Ok(())
}

/// The settings `synth` resolves the scene of a cell to.
fn cell_settings(
    g: &Grid,
    layout: LayoutChoice,
    cameras: usize,
    noise: f64,
) -> anyhow::Result<fluidnerf_synth::SynthSettings> {
    use clap::Parser;
    let line = synth_line(g, Path::new("scene"), layout, cameras, noise);
    let cell = || format!("the scene of {} cameras, noise {noise}, {}", cameras, layout.name());
    let argv = std::iter::once("fluidnerf".to_string()).chain(line);
    let super::Command::Synth(args) =
        crate::Cli::try_parse_from(argv).map_err(|e| anyhow::anyhow!("{}: {e}", cell()))?.command
    else {
        bail!("{}: not a synth line", cell());
    };
    super::synth::resolve(&args).with_context(cell)
}

/// Checks the scene of every cell as `synth` would, and that it fits in memory, before anything
/// is made: a cell refused only when its turn came left the cells before it made and the study
/// unfinished.
fn check_scenes(g: &Grid) -> anyhow::Result<()> {
    for cell in g.cells() {
        let CellScene::Synth(layout) = cell.scene else { continue };
        let settings = cell_settings(g, layout, cell.cameras, cell.noise)?;
        let voxels = settings.truth_dims(&settings.aabb).iter().map(|&n| n as u64).product();
        settings.check_memory(voxels).with_context(|| {
            format!(
                "{} (--cameras {}, --pixels {}, --resolution {})",
                cell.describe(),
                cell.cameras,
                g.pixels,
                g.resolution
            )
        })?;
    }
    Ok(())
}

/// The configuration of a cell's run.
fn cell_config(g: &Grid, scene_dir: &Path, method: Method, seed: u64) -> anyhow::Result<RunConfig> {
    let mut config = RunConfig::new(std::path::absolute(scene_dir)?, method);
    config.resolution = g.resolution;
    config.seed = seed;
    config.stopping = g.stopping;
    if let MethodConfig::Classical(spec) = &mut config.method {
        spec.projector.visual_hull = g.visual_hull;
    }
    Ok(config)
}

/// The scene file of `scene_dir` modified last (its `transforms.json`, and the files of its
/// `images/` and `truth/`), with its modification time; None for a scene not there.
fn newest_scene_file(scene_dir: &Path) -> Option<(std::time::SystemTime, PathBuf)> {
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok().map(|t| (t, p.to_path_buf()));
    let listed = ["images", "truth"]
        .into_iter()
        .flat_map(|sub| std::fs::read_dir(scene_dir.join(sub)).into_iter().flatten().flatten().map(|e| e.path()));
    std::iter::once(scene_dir.join("transforms.json"))
        .chain(listed)
        .filter(|p| p.is_file())
        .filter_map(|p| modified(&p))
        .max_by_key(|(t, _)| *t)
}

/// The file in a cell's runs folder that records the scene files its runs were made from.
const SCENE_FILES: &str = "scene-files.json";

/// A scene's files by their path relative to its folder, each with the digest of its bytes.
type SceneFiles = std::collections::BTreeMap<String, String>;

/// The digest of each scene file of `scene_dir` that a study checks (its `transforms.json`, and
/// the files of its `images/` and `truth/`), by its path relative to the folder.
fn scene_files(scene_dir: &Path) -> anyhow::Result<SceneFiles> {
    let listed = ["images", "truth"]
        .into_iter()
        .flat_map(|sub| std::fs::read_dir(scene_dir.join(sub)).into_iter().flatten().flatten().map(|e| e.path()));
    let mut files = SceneFiles::new();
    for p in std::iter::once(scene_dir.join("transforms.json")).chain(listed).filter(|p| p.is_file()) {
        let bytes = std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?;
        let name = p.strip_prefix(scene_dir).unwrap_or(&p).to_string_lossy().replace('\\', "/");
        files.insert(name, fluidnerf_pipeline::bytes_digest(&bytes));
    }
    Ok(files)
}

/// The scene files recorded in the cell's runs folder `cell_runs` ([`SCENE_FILES`]); None when
/// none is recorded (a cell not yet run, or a study written before they were).
fn recorded_scene_files(cell_runs: &Path) -> anyhow::Result<Option<SceneFiles>> {
    let path = cell_runs.join(SCENE_FILES);
    if !path.is_file() {
        return Ok(None);
    }
    Ok(Some(fluidnerf_pipeline::rundir::read_json(&path)?))
}

/// Refuses the scene files `now` of `scene_dir` when they are not those `recorded` for the
/// finished runs in `cell_runs`: a file changed, removed or added, so that their results would
/// stand in the table for a scene they were not made from. Compared by contents: a scene the
/// study made again, the same, is the scene its runs were made from.
fn check_scene_files(
    scene_dir: &Path,
    cell_runs: &Path,
    recorded: &SceneFiles,
    now: &SceneFiles,
) -> anyhow::Result<()> {
    let changed = recorded.iter().find_map(|(name, digest)| match now.get(name) {
        Some(d) if d == digest => None,
        Some(_) => Some((name, "changed")),
        None => Some((name, "was removed")),
    });
    let added = || now.keys().find(|name| !recorded.contains_key(*name)).map(|name| (name, "was added"));
    if let Some((name, what)) = changed.or_else(added) {
        bail!(
            "{}: {what} after the runs in {} were made from the scene ({} records its files), so their results are \
             not of this scene; use --force to start over, or restore the file",
            scene_dir.join(name).display(),
            cell_runs.display(),
            cell_runs.join(SCENE_FILES).display()
        );
    }
    Ok(())
}

/// Refuses to continue a study whose scenes or finished runs in `out`, which it would read back
/// instead of making them again, were made with other settings than the grid's: the table would
/// mix the cells of two studies under one grid. Their own records are compared, not study.json,
/// which a study killed before it wrote one lacks. Returns the scene files it read and found as
/// recorded, by cell name, so that the study does not read them again.
fn check_earlier_cells(out: &Path, g: &Grid) -> anyhow::Result<std::collections::HashMap<String, SceneFiles>> {
    let mut checked_files = std::collections::HashMap::new();
    let other = |dir: &Path, what: &str, file: &Path, differences: String| {
        anyhow::anyhow!(
            "{} holds a {what} with other settings than this study's ({}: {differences}); use --force to start over \
             or another folder",
            dir.display(),
            file.display()
        )
    };
    for cell in g.cells() {
        let scene_dir = cell.scene_dir(out);
        let record = scene_dir.join("synth.json");
        if let (CellScene::Synth(layout), true) =
            (&cell.scene, scene_dir.join("transforms.json").is_file() && record.is_file())
        {
            let layout = *layout;
            let given = cell_settings(g, layout, cell.cameras, cell.noise)?;
            let value: serde_json::Value = fluidnerf_pipeline::rundir::read_json(&record)?;
            let saved: fluidnerf_synth::SynthSettings =
                serde_json::from_value(value.get("settings").cloned().unwrap_or_default())
                    .with_context(|| format!("{}: not the settings of a synthetic scene", record.display()))?;
            if saved != given {
                let differences = fluidnerf_pipeline::rundir::settings_differences(&saved, &given, 5);
                return Err(other(&scene_dir, "scene", &record, differences));
            }
        }
        if matches!(cell.scene, CellScene::Subset(_)) && scene_dir.is_dir() {
            // Checked (and refused when it holds other cameras) before any run is read back.
            ensure_subset(&cell, &scene_dir)?;
        }
        // A subset's images are the scene's given. Its files, by contents, as the cell's
        // runs recorded them; a study written before they were, by the files' times.
        let source = cell.source().unwrap_or(&scene_dir);
        let cell_runs = out.join("runs").join(&cell.name);
        let recorded = recorded_scene_files(&cell_runs)?;
        let newest = newest_scene_file(source);
        for (method, seed) in g.methods.iter().flat_map(|&m| g.seeds(m).map(move |s| (m, s))) {
            let run_dir = out.join("runs").join(&cell.name).join(g.run_name(method, seed));
            let report_file = run_dir.join("report.json");
            if !(report_file.is_file()
                && fluidnerf_pipeline::RunReport::read(&report_file)?.status == RunStatus::Finished)
            {
                continue;
            }
            // A scene file changed since the run was made (an image edited): the run is of
            // other images, and its result would stand in the table for these. A scene not
            // there is made again, and checked then.
            let made = std::fs::metadata(&report_file).and_then(|m| m.modified()).ok();
            if let Some(recorded) = &recorded {
                if !checked_files.contains_key(&cell.name) && source.join("transforms.json").is_file() {
                    let files = scene_files(source)?;
                    check_scene_files(source, &cell_runs, recorded, &files)?;
                    checked_files.insert(cell.name.clone(), files);
                }
            } else if let (Some((changed, file)), Some(made)) = (&newest, made) {
                if *changed > made + std::time::Duration::from_secs(1) {
                    bail!(
                        "{}: changed after the run {} was made from it, so its result is not of this scene; use \
                         --force to start over, or restore the file",
                        file.display(),
                        run_dir.display()
                    );
                }
            }
            let file = run_dir.join("config.json");
            let saved = RunConfig::read(&file)?;
            // Moved with its folder, a cell's scene keeps its name: a run of another cell's
            // scene (runs swapped between cells) would give this cell its result. A scene given
            // stays where it is: the run must name that very folder.
            let same_scene = match &cell.scene {
                CellScene::Given(given) => fluidnerf_pipeline::rundir::same_path(&saved.scene, given),
                _ => saved.scene.file_name() == scene_dir.file_name(),
            };
            if !same_scene {
                bail!(
                    "{} holds a run of another scene: its {} names {}, not {}; use --force to start over or another \
                     folder",
                    run_dir.display(),
                    file.display(),
                    saved.scene.display(),
                    cell.describe()
                );
            }
            let mut given = cell_config(g, &scene_dir, method, seed)?;
            // The version that wrote it is information only; a study folder moved since holds
            // its scenes elsewhere.
            given.fluidnerf_version.clone_from(&saved.fluidnerf_version);
            given.scene.clone_from(&saved.scene);
            if saved != given {
                let differences = fluidnerf_pipeline::rundir::settings_differences(&saved, &given, 5);
                return Err(other(&run_dir, "run", &file, differences));
            }
        }
    }
    Ok(checked_files)
}

pub fn run(args: Args) -> anyhow::Result<std::process::ExitCode> {
    let g = grid(&args)?;
    // The cells' synth and reconstruct lines name their folders as text: a path that is not
    // UTF-8 became another folder (its bytes replaced), so the scenes went elsewhere.
    super::recordable("the study's synth and reconstruct lines", [("--out", args.out.as_path())])?;
    let out = &args.out;
    if let Some(scene) = &g.scene {
        super::recordable("the study's reconstruct lines", [("--scene", scene.as_path())])?;
        // The runs would be written into the scene's folder, which a run refuses, and --force
        // would clear what the study wrote there.
        let resolved = |p: &Path| p.canonicalize().or_else(|_| std::path::absolute(p)).unwrap_or(p.to_path_buf());
        if resolved(out).starts_with(resolved(scene)) {
            bail!(
                "--out {}: is the scene's folder {} or inside it; write the study elsewhere",
                out.display(),
                scene.display()
            );
        }
    }
    let record = out.join("study.json");
    // A study writes its report.html, plots and table at the top of OUT: never into another
    // kind of fluidnerf folder (a run's report.html was replaced), nor over files of the same
    // names in a folder that holds no study.
    fluidnerf_pipeline::rundir::refuse_other_kind(out, FolderKind::Study, "study")?;
    if !record.is_file() {
        let written = ["report.html", "study.csv", "against_cameras.png", "against_noise.png"];
        if let Some(file) = written.into_iter().find(|f| out.join(f).exists()) {
            bail!(
                "{} holds {file} but no study.json, so it is not a study folder; a study would overwrite it: choose \
                 another output folder",
                out.display()
            );
        }
    }
    // One study at a time in a folder: two at once wrote their cells side by side and each its
    // own study.json over the other's. The lock holds until the study ends (or its process is
    // gone: a killed study's lock is stale and replaced).
    super::create_output_folder(out)?;
    let _lock = fluidnerf_pipeline::rundir::FileLock::take(out, &out.join(STUDY_LOCK))
        .with_context(|| format!("{}: another study is writing into this folder", out.display()))?;
    if args.force {
        // Only a study's own folders are removed: a folder that is not a study is left as it is.
        if !record.is_file() {
            if let Some(sub) = ["scenes", "runs"].into_iter().find(|s| out.join(s).exists()) {
                bail!(
                    "{} holds {sub}/ but no study.json, so it is not a study folder; --force replaces only an \
                     earlier study's scenes and runs: choose another output folder",
                    out.display()
                );
            }
        }
        if record.is_file() {
            remove_earlier_study(out, &read_earlier_grid(&record)?)?;
        }
    } else if record.is_file() {
        let earlier = read_earlier_grid(&record)?;
        if earlier != g {
            bail!(
                "{} holds a study with other settings ({}: {}); use --force to start over or another folder",
                out.display(),
                record.display(),
                fluidnerf_pipeline::rundir::settings_differences(&earlier, &g, 5)
            );
        }
    }
    // The scene files checked against the cells' records, read once.
    let mut checked_files = if args.force { Default::default() } else { check_earlier_cells(out, &g)? };
    // Recorded before the first cell: a study killed before it wrote its results (which write
    // study.json anew) is then continued by the same command or started over with --force, as
    // one stopped by Ctrl-C is; without it, its scenes/ and runs/ read as another folder's,
    // and --force refused them. Started over, the earlier record goes with the earlier study.
    if args.force || !record.is_file() {
        fluidnerf_pipeline::rundir::write_json(
            &record,
            &StudyRecord {
                version: env!("CARGO_PKG_VERSION"),
                status: "started",
                runs_total: g.runs_total(),
                grid: &g,
                stopping_rule: g.stopping.describe_rule(),
                rows: &[],
                means: &[],
                against_best_voxel: &[],
            },
        )?;
    }
    let start = Instant::now();
    let total = g.runs_total();
    let mut rows = Vec::with_capacity(total);
    let mut summaries: Vec<(Row, RunSummary)> = Vec::new();
    let mut k = 0;
    for cell in g.cells() {
        let scene_dir = cell.scene_dir(out);
        ensure_subset(&cell, &scene_dir)?;
        if let CellScene::Synth(layout) = cell.scene {
            match ensure_scene(&g, &scene_dir, layout, cell.cameras, cell.noise) {
                // Stopped as a run stopped by Ctrl-C is: the runs so far written, exit 130.
                Err(e) if matches!(e.downcast_ref(), Some(fluidnerf_synth::SynthError::Cancelled)) => {
                    return interrupted(out, &g, &rows, &summaries, total);
                }
                r => r?,
            }
        }
        // The scene files the cell's runs are made from, recorded before they are, and checked
        // against the record when finished runs are read back: a scene made again here (its
        // folder was removed) is checked now, by contents.
        let source = cell.source().unwrap_or(&scene_dir);
        let cell_runs = out.join("runs").join(&cell.name);
        let files = match checked_files.remove(&cell.name) {
            Some(files) => files,
            None => scene_files(source)?,
        };
        let any_finished = g.methods.iter().flat_map(|&m| g.seeds(m).map(move |s| (m, s))).any(|(m, s)| {
            let report_file = cell_runs.join(g.run_name(m, s)).join("report.json");
            fluidnerf_pipeline::RunReport::read(&report_file).is_ok_and(|r| r.status == RunStatus::Finished)
        });
        match recorded_scene_files(&cell_runs)? {
            Some(recorded) if any_finished => check_scene_files(source, &cell_runs, &recorded, &files)?,
            Some(recorded) if recorded == files => {}
            _ => {
                super::create_output_folder(&cell_runs)?;
                fluidnerf_pipeline::rundir::write_json(&cell_runs.join(SCENE_FILES), &files)?;
            }
        }
        for (method, seed) in g.methods.iter().flat_map(|&m| g.seeds(m).map(move |s| (m, s))) {
            k += 1;
            let run_dir = out.join("runs").join(&cell.name).join(g.run_name(method, seed));
            // A run stopped by Ctrl-C writes its report too: its cell is run again, not read
            // back as if its budget had been spent.
            let report_file = run_dir.join("report.json");
            let reported = report_file.is_file()
                && fluidnerf_pipeline::RunReport::read(&report_file)?.status == RunStatus::Finished;
            // A finished run whose result has since gone (a volume deleted to save space) is
            // run again: read back, it failed the study on every attempt.
            let finished = reported && fluidnerf_pipeline::RunDir::open(&run_dir).is_ok_and(|rd| rd.kind().is_some());
            #[allow(clippy::print_stdout)]
            {
                let noise = match cell.source() {
                    Some(_) => String::new(),
                    None => format!(" · noise {}", cell.noise),
                };
                println!(
                    "[{k}/{total}] {} · {} cameras{noise} · {}{}{}",
                    cell.layout,
                    cell.cameras,
                    method.label(),
                    if g.repeated(method) { format!(" · seed {seed}") } else { String::new() },
                    match (finished, reported) {
                        (true, _) => " (done earlier)",
                        (false, true) => " (done earlier, but its result is gone: run again)",
                        (false, false) => "",
                    }
                );
            }
            if !finished {
                let config = cell_config(&g, &scene_dir, method, seed)?;
                let report = super::reconstruct::run_config(&config, &run_dir, Overwrite::Force)?;
                if report.status == RunStatus::Interrupted {
                    return interrupted(out, &g, &rows, &summaries, total);
                }
            }
            // Every method scored through the volume it wrote, on the one output grid: a field
            // scored at the truth's voxel centres gained from a truth finer than that grid (a
            // scene given), and its held-out view was rendered from the field, not the volume.
            score_held_out(&run_dir, &scene_dir, method)?;
            let summary = html::summarise(&run_dir, method.label())?;
            let r = &summary.report;
            let (nrmse, ssim_global) = scored_volume(&run_dir)?.map_or((None, None), |(n, s)| (Some(n), Some(s)));
            let row = Row {
                layout: cell.layout.clone(),
                cameras: cell.cameras,
                noise: cell.noise,
                method: method.name().into(),
                seed,
                repeated: g.repeated(method),
                nrmse,
                ssim_global,
                holdout_nrmse: summary.holdout_nrmse,
                best_holdout_loss: r.history.holdout.iter().map(|h| h.loss).reduce(f64::min),
                kept_iteration: r.kept_iteration,
                iterations: r.iterations,
                stop_reason: r.stop_reason.name().into(),
                train_time_s: r.train_time_s,
                result_bytes: r.result_bytes,
                run: run_dir.strip_prefix(out).unwrap_or(&run_dir).display().to_string(),
            };
            rows.push(row.clone());
            summaries.push((row, summary));
        }
    }
    write_outputs(out, &g, &rows, &summaries, total)?;
    #[allow(clippy::print_stdout)]
    {
        println!("\n{}", text_table(&rows));
        let cells = means(&rows);
        if g.repeats > 1 {
            println!("{}", means_table(&cells));
        }
        let against = against_best(&cells);
        if !against.is_empty() {
            println!("each field against the best voxel method of its cell:\n{}", against_best_table(&against));
        }
        println!(
            "every method stopped by {}; {:.1} s; open {}",
            g.stopping.describe_rule(),
            start.elapsed().as_secs_f64(),
            out.join("report.html").display()
        );
    }
    Ok(std::process::ExitCode::SUCCESS)
}

/// Scores the run in `run_dir` of `method` on its scene in `scene_dir` (`eval`, into the run's
/// `metrics.json`), unless a score of the same kind written since its report is there (a study
/// continued): its row's volume scores and held-out view NRMSE. A field is scored through the
/// volume it wrote (`eval --use-volume`), as the voxel methods are: every method on the one
/// output grid.
fn score_held_out(run_dir: &Path, scene_dir: &Path, method: Method) -> anyhow::Result<()> {
    use clap::Parser;
    let use_volume = method.is_field();
    let modified = |name: &str| std::fs::metadata(run_dir.join(name)).and_then(|m| m.modified()).ok();
    if let (Some(scored), Some(made)) = (modified("metrics.json"), modified("report.json")) {
        let same_kind = fluidnerf_pipeline::rundir::read_json::<serde_json::Value>(&run_dir.join("metrics.json"))
            .is_ok_and(|v| v["settings"]["use_volume"].as_bool().unwrap_or(false) == use_volume);
        if scored >= made && same_kind {
            return Ok(());
        }
    }
    // Joined to its option, and the run after `--`: a folder whose name starts with '-' was
    // read as an option.
    let (run, scene) = (run_dir.to_string_lossy(), format!("--scene={}", scene_dir.to_string_lossy()));
    let mut argv = vec!["fluidnerf", "eval", "--no-regions", "--force", &scene];
    if use_volume {
        argv.push("--use-volume");
    }
    argv.extend(["--", &run]);
    let super::Command::Eval(mut args) = crate::Cli::try_parse_from(argv).map_err(|e| anyhow::anyhow!("{e}"))?.command
    else {
        bail!("{}: not an eval line", run_dir.display());
    };
    args.silent = true;
    super::eval::run(args).with_context(|| format!("scoring {} on its held-out camera", run_dir.display()))
}

/// The volume NRMSE and global SSIM `eval` wrote into the run's `metrics.json` (of its first
/// time step), when it scored a ground truth.
fn scored_volume(run_dir: &Path) -> anyhow::Result<Option<(f64, f64)>> {
    let metrics: fluidnerf_metrics::MetricsReport =
        fluidnerf_pipeline::rundir::read_json(&run_dir.join("metrics.json"))?;
    Ok(metrics.steps.first().map(|s| (s.global.nrmse, s.global.ssim_global)))
}

/// Ends a study stopped by Ctrl-C: writes the runs made so far and exits with 130.
fn interrupted(
    out: &Path,
    g: &Grid,
    rows: &[Row],
    summaries: &[(Row, RunSummary)],
    total: usize,
) -> anyhow::Result<std::process::ExitCode> {
    write_outputs(out, g, rows, summaries, total)?;
    #[allow(clippy::print_stdout)]
    {
        println!("interrupted; rerun the same command to continue the study");
    }
    Ok(std::process::ExitCode::from(130))
}

/// The method of a row, with its seed when it is one of several runs of its method.
fn method_label(r: &Row) -> String {
    if r.repeated {
        format!("{} s{}", r.method, r.seed)
    } else {
        r.method.clone()
    }
}

/// What ended a run, from its `stop_reason` name, in words for the report's table.
fn ended_by(stop_reason: &str) -> &str {
    StopReason::from_name(stop_reason).map_or(stop_reason, |r| r.words())
}

/// The terminal table's mark of a run that a cap or the budget ended, not its rule.
fn cut_mark(stop_reason: &str) -> &'static str {
    StopReason::from_name(stop_reason).map_or("", StopReason::mark)
}

fn text_table(rows: &[Row]) -> String {
    let mut s = format!(
        "{:<8} {:>7} {:>6} {:<12} {:>7} {:>7} {:>8} {:>10} {:>8}\n",
        "layout", "cameras", "noise", "method", "NRMSE", "SSIM", "held-out", "kept/iter", "time [s]"
    );
    for r in rows {
        let f = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.4}"));
        s += &format!(
            "{:<8} {:>7} {:>6} {:<12} {:>7} {:>7} {:>8} {:>10} {:>8.1}\n",
            r.layout,
            r.cameras,
            noise_text(&r.layout, r.noise),
            method_label(r),
            f(r.nrmse),
            f(r.ssim_global),
            f(r.holdout_nrmse),
            format!("{}/{}{}", r.kept_iteration, r.iterations, cut_mark(&r.stop_reason)),
            r.train_time_s
        );
    }
    if rows.iter().any(|r| r.stop_reason == "iteration-cap") {
        s += "* ended by the iteration cap (--max-iterations), not by the stopping rule\n";
    }
    if rows.iter().any(|r| r.stop_reason == "time-budget") {
        s += "t ended by the time budget (--time-budget), not by the stopping rule\n";
    }
    s
}

/// Each cell's and method's mean over its runs, with the range of their volume NRMSE.
fn means_table(means: &[Mean]) -> String {
    let mut s = format!(
        "{:<8} {:>7} {:>6} {:<12} {:>4} {:>7} {:>15} {:>7} {:>8} {:>8}\n",
        "layout", "cameras", "noise", "method", "runs", "NRMSE", "NRMSE range", "SSIM", "held-out", "time [s]"
    );
    for m in means {
        let f = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.4}"));
        s += &format!(
            "{:<8} {:>7} {:>6} {:<12} {:>4} {:>7} {:>15} {:>7} {:>8} {:>8.1}\n",
            m.layout,
            m.cameras,
            noise_text(&m.layout, m.noise),
            m.method,
            m.runs,
            f(m.nrmse),
            format!("{}–{}", f(m.nrmse_min), f(m.nrmse_max)),
            f(m.ssim_global),
            f(m.holdout_nrmse),
            m.train_time_s
        );
    }
    s
}

/// One line per (method, other axes) of `metric` against `axis`, through each cell's mean
/// (the run itself where a cell has one run of the method).
fn sweep_plot(rows: &[Mean], title: &str, axis: &str, metric: &str) -> Option<LinePlot> {
    let x_of = |r: &Mean| if axis == "cameras" { r.cameras as f64 } else { 100.0 * r.noise };
    let y_of = |r: &Mean| match metric {
        "NRMSE" => r.nrmse,
        "SSIM" => r.ssim_global,
        _ => r.holdout_nrmse,
    };
    let distinct: std::collections::BTreeSet<u64> = rows.iter().map(|r| x_of(r).to_bits()).collect();
    if distinct.len() < 2 {
        return None;
    }
    let mut keys: Vec<String> = Vec::new();
    let key = |r: &Mean| {
        let fixed = match axis {
            "cameras" => format!("noise {}", noise_text(&r.layout, r.noise)),
            _ => format!("{} cameras", r.cameras),
        };
        if r.layout == GIVEN_LAYOUT {
            // One scene, no noise added: the method says it all.
            r.method.clone()
        } else {
            format!("{} ({}, {fixed})", r.method, r.layout)
        }
    };
    for r in rows {
        if !keys.contains(&key(r)) {
            keys.push(key(r));
        }
    }
    let series: Vec<Series> = keys
        .iter()
        .map(|k| {
            let pts: Vec<(f64, f64)> =
                rows.iter().filter(|r| &key(r) == k).filter_map(|r| y_of(r).map(|y| (x_of(r), y))).collect();
            Series {
                label: k.clone(),
                x: pts.iter().map(|p| p.0).collect(),
                y: pts.iter().map(|p| p.1).collect(),
                mark: None,
            }
        })
        .collect();
    // Without a score of this kind (no ground truth, or no held-out score), no plot.
    if series.iter().all(|s| s.x.is_empty()) {
        return None;
    }
    Some(LinePlot {
        title: title.to_string(),
        x_label: if axis == "cameras" { "training cameras".into() } else { "image noise [% of max]".into() },
        y_label: match metric {
            "NRMSE" | "SSIM" => format!("volume {metric}"),
            _ => "held-out view NRMSE".into(),
        },
        log_x: false,
        log_y: false,
        markers: true,
        integer_x: axis == "cameras",
        series,
    })
}

/// The label of a run's line in the convergence plot: the layout too, since the runs at the
/// largest camera count of a layout sweep differ by their layouts only.
fn convergence_label(r: &Row) -> String {
    format!("{} ({}, {} cameras, noise {})", r.method, r.layout, r.cameras, noise_text(&r.layout, r.noise))
}

fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "layout,cameras,noise,method,seed,nrmse,ssim_global,holdout_nrmse,best_holdout_loss,kept_iteration,iterations,stop_reason,train_time_s,result_bytes,run\n",
    );
    let f = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
    for r in rows {
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.layout,
            r.cameras,
            r.noise,
            r.method,
            r.seed,
            f(r.nrmse),
            f(r.ssim_global),
            f(r.holdout_nrmse),
            f(r.best_holdout_loss),
            r.kept_iteration,
            r.iterations,
            r.stop_reason,
            r.train_time_s,
            r.result_bytes,
            r.run
        );
    }
    s
}

/// The noise column of a cell of layout `layout`: the level added, or a dash for a scene given,
/// whose images are used as they are (0 in the record: none added).
fn noise_text(layout: &str, noise: f64) -> String {
    if layout == GIVEN_LAYOUT {
        "–".into()
    } else {
        noise.to_string()
    }
}

/// A report table's row: the cell (layout, cameras, noise) and the method, then `rest`.
fn with_cell<const N: usize>(
    (layout, cameras, noise, method): (&str, usize, f64, String),
    rest: [String; N],
) -> Vec<String> {
    let mut row = vec![layout.to_string(), cameras.to_string(), noise_text(layout, noise), method];
    row.extend(rest);
    row
}

/// Writes the record, table, plots and report of the runs made so far: `rows` are all `total`
/// runs of the grid once the study is finished, fewer when Ctrl-C stopped it, which the
/// record and the report then say.
fn write_outputs(
    out: &Path,
    g: &Grid,
    rows: &[Row],
    summaries: &[(Row, RunSummary)],
    total: usize,
) -> anyhow::Result<()> {
    let finished = rows.len() == total;
    let cells = means(rows);
    let against = against_best(&cells);
    fluidnerf_pipeline::rundir::write_json(
        &out.join("study.json"),
        &StudyRecord {
            version: env!("CARGO_PKG_VERSION"),
            status: if finished { "finished" } else { "interrupted" },
            runs_total: total,
            grid: g,
            stopping_rule: g.stopping.describe_rule(),
            rows,
            means: if g.repeats > 1 { &cells } else { &[] },
            against_best_voxel: &against,
        },
    )?;
    fluidnerf_io::atomic_write(&out.join("study.csv"), |w| w.write_all(csv(rows).as_bytes()))?;
    let mut figures = Vec::new();
    for (axis, name) in [("cameras", "cameras"), ("noise", "noise")] {
        let plots: Vec<LinePlot> = ["NRMSE", "SSIM", "held-out NRMSE"]
            .iter()
            .filter_map(|m| sweep_plot(&cells, &format!("{m} against {name}"), axis, m))
            .collect();
        let file = out.join(format!("against_{name}.png"));
        if plots.is_empty() {
            // The plot of an earlier study in OUT (--force) over a sweep this one does not make
            // would stay beside this study's table and report as if it were this study's.
            if file.is_file() {
                std::fs::remove_file(&file).with_context(|| format!("removing {}", file.display()))?;
            }
            continue;
        }
        let png = fluidnerf_viz::encode_plots_png(&plots, 2)?;
        fluidnerf_io::atomic_write(&file, |w| w.write_all(&png))?;
        let volume = plots.iter().any(|p| p.y_label.starts_with("volume"));
        figures.push(Figure {
            caption: format!(
                "{} against {name}.",
                if volume {
                    "Volume NRMSE and global SSIM, and the held-out view's NRMSE,"
                } else {
                    "The held-out view's NRMSE"
                }
            ),
            image: ImageData::Png(png),
        });
    }
    let runs = if finished { "Every run".to_string() } else { format!("The {} of {total} runs made", rows.len()) };
    let mut table = Table::new(
        format!("{runs}, stopped by {}", g.stopping.describe_rule()),
        &[
            "layout",
            "cameras",
            "noise",
            "method",
            "NRMSE",
            "SSIM (global)",
            "held-out view NRMSE",
            "ended by",
            "kept / iterations",
            "time [s]",
            "result",
        ],
    );
    let f = |v: Option<f64>| v.map_or("–".into(), fluidnerf_viz::report::format_value);
    for r in rows {
        table.push_row(with_cell(
            (&r.layout, r.cameras, r.noise, method_label(r)),
            [
                f(r.nrmse),
                f(r.ssim_global),
                f(r.holdout_nrmse),
                ended_by(&r.stop_reason).to_string(),
                format!("{} / {}", r.kept_iteration, r.iterations),
                format!("{:.1}", r.train_time_s),
                fluidnerf_pipeline::bytes(r.result_bytes),
            ],
        ));
    }
    let mut tables = vec![table];
    if g.repeats > 1 {
        let mut mean_table = Table::new(
            format!(
                "Each method's mean over its runs with seeds {} to {} (one run of a method without randomness)",
                g.seed,
                g.seed.saturating_add(u64::from(g.repeats) - 1)
            ),
            &[
                "layout",
                "cameras",
                "noise",
                "method",
                "runs",
                "NRMSE",
                "NRMSE range",
                "SSIM (global)",
                "held-out view NRMSE",
                "time [s]",
            ],
        );
        for m in &cells {
            mean_table.push_row(with_cell(
                (&m.layout, m.cameras, m.noise, m.method.clone()),
                [
                    m.runs.to_string(),
                    f(m.nrmse),
                    format!("{} – {}", f(m.nrmse_min), f(m.nrmse_max)),
                    f(m.ssim_global),
                    f(m.holdout_nrmse),
                    format!("{:.1}", m.train_time_s),
                ],
            ));
        }
        tables.push(mean_table);
    }
    if !against.is_empty() {
        let mut t = Table::new(
            format!(
                "Each field against the best voxel method of its cell (volume NRMSE, or in a cell without ground \
                 truth the held-out view's{}; below 1 the field is the more accurate)",
                if g.repeats > 1 { ", means over the runs" } else { "" }
            ),
            &["layout", "cameras", "noise", "field", "NRMSE", "best voxel method", "its NRMSE", "ratio", "NRMSE of"],
        );
        for a in &against {
            t.push_row(with_cell(
                (&a.layout, a.cameras, a.noise, a.method.clone()),
                [
                    f(Some(a.nrmse)),
                    a.best_voxel_method.clone(),
                    f(Some(a.best_voxel_nrmse)),
                    format!("{:.2}", a.ratio),
                    a.measure.to_string(),
                ],
            ));
        }
        tables.push(t);
    }
    // At the largest camera count; with repeats, the first seed's runs.
    let histories: Vec<_> = summaries
        .iter()
        .filter(|(r, _)| r.cameras == *g.cameras.iter().max().unwrap_or(&0) && r.seed == g.seed)
        .map(|(r, s)| fluidnerf_viz::RunHistory { label: convergence_label(r), ..s.history.clone() })
        .collect();
    if !histories.is_empty() {
        let png = fluidnerf_viz::encode_plots_png(&fluidnerf_viz::convergence_plots(&histories), 2)?;
        figures.push(Figure { caption: "Convergence at the largest camera count.".into(), image: ImageData::Png(png) });
    }
    let (title, images, note) = match &g.scene {
        Some(scene) => {
            let held_out = fluidnerf_io::scene::load_scene(scene).map_or(0, |s| s.holdout_frames().count());
            (
                format!("fluidnerf study of the scene {}", scene.display()),
                format!(
                    "{} training cameras, {held_out} held out, output grid of {} voxels along the box's longest side",
                    match g.cameras.as_slice() {
                        [c] if *c == g.scene_cameras => c.to_string(),
                        counts => format!(
                            "{} of its {} (each a subset whose viewing lines are furthest apart)",
                            counts.iter().map(ToString::to_string).collect::<Vec<_>>().join(", "),
                            g.scene_cameras
                        ),
                    },
                    g.resolution
                ),
                "The scene's held-out cameras are left out of every reconstruction: they drive held-out early \
                 stopping, and each result is scored on their images (held-out view NRMSE), which needs no ground \
                 truth. The images are used as they are: no noise is added."
                    .to_string(),
            )
        }
        None => {
            // --resolution is the longest side: a box that is not a cube has fewer voxels along
            // the others (plume15 at 24: 16×24×16).
            let settings = cell_settings(g, g.layouts[0], g.cameras[0], g.noise[0])?;
            let dims = settings.truth_dims(&settings.aabb).map(|n| n.to_string()).join("×");
            (
                format!("fluidnerf study: {:?} on {}", g.preset.unwrap_or(StudyPreset::Cameras), g.scene_preset),
                format!("{}² px images, {dims} voxels of truth and output", g.pixels),
                "Each cell's scene has one more camera than its count, held out of every reconstruction: it drives \
                 held-out early stopping and uses no ground truth."
                    .to_string(),
            )
        }
    };
    let report = Report {
        title,
        subtitle: format!(
            "{images}, methods {}, every method stopped by {}{} · fluidnerf {}",
            g.methods.iter().map(|m| m.name()).collect::<Vec<_>>().join(", "),
            g.stopping.describe_rule(),
            match (g.visual_hull, g.methods.contains(&Method::Hybrid)) {
                (true, true) => ", the voxel methods (not the hybrid's own start) inside the images' visual hull",
                (true, false) => ", the voxel methods inside the images' visual hull",
                (false, _) => "",
            },
            env!("CARGO_PKG_VERSION")
        ),
        tables,
        figures,
        summary: if finished {
            Vec::new()
        } else {
            vec![(
                "status".into(),
                format!(
                    "interrupted after {} of {total} runs: the table and plots show those only; rerun the same \
                     command to continue the study",
                    rows.len()
                ),
            )]
        },
        settings: serde_json::to_value(g).ok(),
        notes: vec![
            note,
            "Every method is scored through the volume it wrote on the output grid, a field's too (eval \
             --use-volume): its volume NRMSE against the truth, and its held-out view rendered from that volume."
                .into(),
        ],
    };
    fluidnerf_viz::report::write_report_html(&out.join("report.html"), &report)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn mean(cameras: usize, method: &str, nrmse: Option<f64>) -> Mean {
        Mean {
            layout: "ring360".into(),
            cameras,
            noise: 0.05,
            method: method.into(),
            runs: 1,
            nrmse,
            nrmse_min: nrmse,
            nrmse_max: nrmse,
            ssim_global: None,
            holdout_nrmse: None,
            train_time_s: 1.0,
        }
    }

    /// Each field is set against the lowest NRMSE of the voxel methods of its own cell (the
    /// voxel baseline among them), never against another field's or another cell's; a cell
    /// without a voxel method, or a run without a score, gives no ratio.
    #[test]
    fn fields_are_set_against_the_best_voxel_method_of_their_cell() {
        let cells = [
            mean(4, "asart", Some(0.40)),
            mean(4, "voxel", Some(0.30)),
            mean(4, "tv", Some(0.32)),
            mean(4, "fast", Some(0.36)),
            mean(4, "hybrid", Some(0.24)),
            mean(8, "hybrid", Some(0.10)),
            mean(8, "mlem", None),
            mean(15, "fast", None),
            mean(15, "sart", Some(0.2)),
            mean(15, "fluidnerf", Some(0.25)),
        ];
        let got = against_best(&cells);
        let seen: Vec<(usize, &str, &str, f64)> =
            got.iter().map(|a| (a.cameras, a.method.as_str(), a.best_voxel_method.as_str(), a.ratio)).collect();
        assert_eq!(seen.len(), 3, "{seen:?}");
        assert_eq!((seen[0].0, seen[0].1, seen[0].2), (4, "fast", "voxel"));
        assert!((seen[0].3 - 1.2).abs() < 1e-12);
        assert_eq!((seen[1].0, seen[1].1, seen[1].2), (4, "hybrid", "voxel"));
        assert!((seen[1].3 - 0.8).abs() < 1e-12);
        assert_eq!((seen[2].0, seen[2].1, seen[2].2), (15, "fluidnerf", "sart"));
        assert!((seen[2].3 - 1.25).abs() < 1e-12);
        let table = against_best_table(&got);
        assert!(table.contains("hybrid        0.2400 voxel              0.3000   0.80"), "{table}");
    }

    /// In a cell without ground truth (a recording given with --scene) the fields are set
    /// against the voxel methods by their held-out views; where the volume is scored, by it.
    #[test]
    fn without_ground_truth_fields_are_set_against_voxel_methods_by_the_held_out_view() {
        let held_out =
            |method: &str, nrmse: Option<f64>, view: f64| Mean { holdout_nrmse: Some(view), ..mean(4, method, nrmse) };
        let cells = [held_out("asart", None, 0.30), held_out("mlem", None, 0.25), held_out("hybrid", None, 0.20)];
        let got = against_best(&cells);
        assert_eq!(got.len(), 1);
        assert_eq!((got[0].measure, got[0].best_voxel_method.as_str()), ("held-out view", "mlem"));
        assert!((got[0].ratio - 0.8).abs() < 1e-12);
        let table = against_best_table(&got);
        assert!(table.contains("0.2000 mlem               0.2500   0.80  held-out view"), "{table}");
        // With the truth: the volume, whatever the views say.
        let cells = [held_out("asart", Some(0.4), 0.30), held_out("hybrid", Some(0.5), 0.20)];
        let got = against_best(&cells);
        assert_eq!((got[0].measure, got[0].ratio), ("volume", 1.25));
    }

    fn cap(line: &[&str]) -> Option<usize> {
        let cli = Cli::try_parse_from(["study", "-o", "x"].iter().chain(line)).expect("arguments");
        grid(&cli.args).expect("grid").stopping.max_iterations
    }

    #[test]
    fn the_held_out_and_budget_rules_end_runs_instead_of_the_methods_own_caps() {
        assert_eq!(cap(&[]), Some(crate::commands::UNCAPPED), "held-out is the default rule");
        assert_eq!(cap(&["--stop", "held-out"]), Some(crate::commands::UNCAPPED));
        assert_eq!(cap(&["--stop", "budget"]), Some(crate::commands::UNCAPPED));
        assert_eq!(cap(&["--stop", "auto"]), Some(crate::commands::UNCAPPED));
        assert_eq!(cap(&["--stop", "own"]), None, "a method's own rule keeps its own cap");
        assert_eq!(cap(&["--max-iterations", "70"]), Some(70));
        assert_eq!(cap(&["--stop", "own", "--max-iterations", "70"]), Some(70));
        assert_eq!(cap(&["--preset", "smoke"]), Some(20));
    }

    /// Under the held-out rule every method scores the held-out camera within the cap: a cap
    /// below a method's interval left it never scored, keeping its last iterate.
    #[test]
    fn a_cap_below_a_methods_held_out_interval_is_refused() {
        let refusal = |line: &[&str]| {
            let cli = Cli::try_parse_from(["study", "-o", "x"].iter().chain(line)).expect("arguments");
            grid(&cli.args).map(|_| ()).map_err(|e| format!("{e:#}"))
        };
        let e = refusal(&["--methods", "fast,asart", "--max-iterations", "20"]).expect_err("a field capped at 20");
        assert!(e.contains("--max-iterations 20: fast scores the held-out camera every 25 iterations"), "{e}");
        let e = refusal(&["--preset", "smoke", "--max-iterations", "4"]).expect_err("below the smoke interval");
        assert!(e.contains("every 5 iterations"), "{e}");
        refusal(&["--methods", "fast", "--max-iterations", "25"]).expect("a cap of one interval");
        refusal(&["--methods", "fast", "--max-iterations", "20", "--stop", "budget"]).expect("no held-out rule");
        refusal(&["--methods", "asart", "--max-iterations", "20"]).expect("the voxel methods score every iteration");
        let smoke = |stop: &str| {
            let cli =
                Cli::try_parse_from(["study", "-o", "x", "--preset", "smoke", "--stop", stop]).expect("arguments");
            grid(&cli.args).expect("grid").stopping.holdout_every
        };
        assert_eq!(smoke("held-out"), Some(5), "the smoke grid's fields are scored within its 20 iterations");
        assert_eq!(smoke("budget"), None, "an interval is recorded only where the held-out rule applies");
    }

    /// A study stopped by Ctrl-C writes the runs made so far, and says so: its record and report
    /// read as those of a finished study with fewer runs.
    #[test]
    fn an_interrupted_study_says_so_in_its_record_and_report() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let cli = Cli::try_parse_from(["study", "-o", "x", "--preset", "smoke"]).expect("arguments");
        let g = grid(&cli.args).expect("grid");
        let read = |f: &str| std::fs::read_to_string(tmp.path().join(f)).expect("written");
        write_outputs(tmp.path(), &g, &[], &[], 6).expect("writes");
        let record: serde_json::Value = serde_json::from_str(&read("study.json")).expect("json");
        assert_eq!((record["status"].as_str(), record["runs_total"].as_u64()), (Some("interrupted"), Some(6)));
        let html = read("report.html");
        assert!(html.contains("interrupted after 0 of 6 runs") && html.contains("The 0 of 6 runs made"), "{html}");
        write_outputs(tmp.path(), &g, &[], &[], 0).expect("writes");
        assert!(
            read("study.json").contains(r#""status": "finished""#)
                || read("study.json").contains(r#""status":"finished""#)
        );
        assert!(!read("report.html").contains("interrupted"));
    }

    /// The `report.html` a study of the command `line` writes before any cell has run.
    fn empty_report(line: &[&str]) -> String {
        let tmp = tempfile::tempdir().expect("tempdir");
        let g = grid(&Cli::try_parse_from(line).expect("arguments").args).expect("grid");
        write_outputs(tmp.path(), &g, &[], &[], 0).expect("writes");
        std::fs::read_to_string(tmp.path().join("report.html")).expect("written")
    }

    /// The report states the voxels of the truth and output grids, which --resolution gives
    /// along the longest side only: a plume study at 24 said "24³" of a 16×24×16 grid.
    #[test]
    fn the_report_states_the_grid_of_a_box_that_is_not_a_cube() {
        let html =
            empty_report(&["study", "-o", "x", "--preset", "smoke", "--scene-preset", "plume15", "--resolution", "24"]);
        assert!(html.contains("24² px images, 16×24×16 voxels of truth and output"), "{html}");
    }

    /// A noise level of -0 is the level 0, and is written so.
    #[test]
    fn a_negative_zero_noise_level_is_zero() {
        let cli = Cli::try_parse_from(["study", "-o", "x", "--preset", "smoke", "--noise=-0,0.05"]).expect("arguments");
        let noise = grid(&cli.args).expect("grid").noise;
        assert_eq!(noise.iter().map(|n| n.to_string()).collect::<Vec<_>>(), ["0", "0.05"]);
    }

    /// Under --visual-hull the report says that the hybrid's own voxel start runs without the
    /// hull: it said the voxel methods ran inside it, the hybrid's start seemingly among them.
    #[test]
    fn the_report_says_the_hybrids_start_runs_without_the_hull() {
        let html =
            empty_report(&["study", "-o", "x", "--preset", "smoke", "--methods", "asart,hybrid", "--visual-hull"]);
        assert!(html.contains("the voxel methods (not the hybrid&#39;s own start) inside the images"), "{html}");
    }

    /// The help of --methods, which lists every method, says which of them a study refuses.
    #[test]
    fn the_help_names_the_methods_a_study_refuses() {
        use clap::CommandFactory;
        let help = Cli::command().render_long_help().to_string();
        let refused = ["tr-fluidnerf", "tr-fast", "static-per-frame"];
        assert!(help.contains("static ones only: a study refuses the time-resolved"), "{help}");
        for m in refused {
            let cli = Cli::try_parse_from(["study", "-o", "x", "--methods", m]).expect("arguments");
            assert!(grid(&cli.args).is_err(), "{m} is refused");
        }
    }

    /// The convergence plot tells apart runs that differ by their layout only (the layout
    /// grid: 8 cameras on three layouts, noiseless), which it labelled alike.
    #[test]
    fn the_convergence_plot_names_each_runs_layout() {
        let row = |layout: &str| scored_row((layout, 8, 0.0), "asart", None, None);
        assert_ne!(convergence_label(&row("ring360")), convergence_label(&row("sphere")));
        assert_eq!(convergence_label(&row("sphere")), "asart (sphere, 8 cameras, noise 0)");
    }

    /// A run's row of `method` in the cell `(layout, cameras, noise)`, with its volume and
    /// held-out view NRMSE.
    fn scored_row(cell: (&str, usize, f64), method: &str, nrmse: Option<f64>, view: Option<f64>) -> Row {
        Row {
            layout: cell.0.into(),
            cameras: cell.1,
            noise: cell.2,
            method: method.into(),
            seed: 0,
            repeated: false,
            nrmse,
            ssim_global: None,
            holdout_nrmse: view,
            best_holdout_loss: None,
            kept_iteration: 5,
            iterations: 5,
            stop_reason: "held-out".into(),
            train_time_s: 1.0,
            result_bytes: 1,
            run: "r".into(),
        }
    }

    /// The camera sweep's x axis counts cameras, so its ticks are whole numbers; the noise
    /// sweep's is a percentage.
    #[test]
    fn the_camera_sweep_plots_a_count_axis() {
        let row = |cameras: usize, noise: f64| Row {
            ssim_global: Some(0.8),
            ..scored_row(("ring", cameras, noise), "sart", Some(0.3), None)
        };
        let by_cameras = sweep_plot(&means(&[row(4, 0.0), row(5, 0.0)]), "t", "cameras", "NRMSE").expect("a sweep");
        assert!(by_cameras.integer_x);
        let by_noise = sweep_plot(&means(&[row(4, 0.0), row(4, 0.02)]), "t", "noise", "NRMSE").expect("a sweep");
        assert!(!by_noise.integer_x);
        // Without held-out scores, no held-out plot.
        assert!(sweep_plot(&means(&[row(4, 0.0), row(5, 0.0)]), "t", "cameras", "held-out NRMSE").is_none());
    }

    /// A scene of the user's without ground truth plots its held-out views against the camera
    /// count and no volume scores; its lines are named by method alone.
    #[test]
    fn a_scene_without_truth_plots_its_held_out_views() {
        let row = |cameras: usize, method: &str, view: f64| {
            scored_row((GIVEN_LAYOUT, cameras, 0.0), method, None, Some(view))
        };
        let cells =
            means(&[row(4, "asart", 0.2), row(8, "asart", 0.1), row(4, "hybrid", 0.15), row(8, "hybrid", 0.08)]);
        assert!(sweep_plot(&cells, "t", "cameras", "NRMSE").is_none());
        let views = sweep_plot(&cells, "t", "cameras", "held-out NRMSE").expect("held-out views");
        assert_eq!(views.y_label, "held-out view NRMSE");
        let lines: Vec<(&str, &[f64])> = views.series.iter().map(|s| (s.label.as_str(), s.y.as_slice())).collect();
        assert_eq!(lines, [("asart", &[0.2, 0.1][..]), ("hybrid", &[0.15, 0.08][..])]);
    }
}
