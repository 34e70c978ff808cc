//! `fluidnerf render`: renders a reconstruction (line integrals along camera rays, the imaging
//! model of the reconstruction) from the scene's cameras or from an orbit of virtual cameras,
//! to 16-bit PNG or 32-bit float TIFF, and an orbit as a turntable GIF.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::ValueEnum;
use fluidnerf_classical::projector::{FootprintProjector, Grid, Projector};
use fluidnerf_core::scene::same_time;
use fluidnerf_core::{num, render_image, Aabb, Baked, Camera, Image, RenderSettings, ScalarField, Support, Volume};
use fluidnerf_pipeline::rundir::{refuse_other_kind, FolderKind};
use fluidnerf_viz::Colormap;
use rayon::prelude::*;
use serde::Serialize;

use super::export::{load_source, Source};

/// The most views of an orbit.
const MAX_ORBIT_VIEWS: usize = 3600;
/// The widest orbit view, in pixels.
const MAX_WIDTH: u32 = 16384;

/// Image file formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageFormat {
    /// 16-bit grayscale PNG; counts scale so the brightest pixel of all views is 65535 (the
    /// factor is recorded in `render.json`: value = count × full_scale / 65535). Negative
    /// values have no count and are written as 0, with a warning.
    Png16,
    /// 32-bit float grayscale TIFF with the rendered values exactly.
    Tiff,
}

/// Render a reconstruction from the scene's cameras or from an orbit of virtual cameras.
///
/// Pixel values are `intensity_scale × ∫E ds` along each pixel's ray through the box, the same
/// model the reconstruction was fitted to, so a scene camera's rendering compares directly with
/// its image; with the footprint projector (by default where a pixel spans the cells it
/// projects, see `--projector`), that integral over each pixel's area. Views of
/// scene cameras go to `view_<index>.<ext>` (three digits, `view_000`), orbit views to
/// `orbit_<k>.<ext>` (`orbit_000`) plus
/// `turntable.gif`. Writes `render.json` with the resolved settings.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The reconstruction: a volume file (`.npy` filling the scene's box, `.vti`, `.raw` with
    /// its JSON sidecar, or a `.tif` stack, calibrated or filling the scene's box) or a
    /// reconstruction run directory (trained field, else its volume).
    pub recon: PathBuf,
    /// The scene (folder holding `transforms.json`, or the file): cameras, box and intensity
    /// scale [default: for a run folder, the scene its `config.json` records].
    #[arg(short, long)]
    pub scene: Option<PathBuf>,
    /// Output directory; created if missing.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Scene frames to render, by index in the scene (comma-separated or repeated). Default:
    /// every frame, unless --orbit is given.
    #[arg(long, value_delimiter = ',', value_name = "INDEX")]
    pub camera: Vec<usize>,
    /// Render N views on a circle about the flow axis through the box centre, flow pointing
    /// right, and write them as a turntable GIF; 1 to 3600 views. The axis is --flow-axis, else
    /// the scene's `flow_axis`, else +x.
    #[arg(long, value_name = "N")]
    pub orbit: Option<usize>,
    /// The flow direction x,y,z (world) the orbit circles [default: the scene's `flow_axis`,
    /// else +x].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, requires = "orbit")]
    pub flow_axis: Option<Vec<f64>>,
    /// Width of orbit views in pixels, 16 to 16384 (the height follows the box's cross-section).
    #[arg(long, default_value_t = 320, requires = "orbit")]
    pub width: u32,
    /// Image format of the views.
    #[arg(long, value_enum, default_value = "png16")]
    pub format: ImageFormat,
    /// How a pixel is computed. `rays`: the line integral along the ray through the pixel's
    /// centre (or `--supersample` rays), with the volume read trilinearly, the model the
    /// neural fields are trained with. `footprint`: the separable-footprint projector of the
    /// classical methods, each voxel a box integrated exactly over each pixel's area; a
    /// trained field is first sampled on a grid (`--bake`), twice as fine as its finest level
    /// by default. It costs voxels × views rather than rays × samples, so it is many times
    /// faster for large images and orbits; where pixels are wider than the field's detail it is
    /// also closer to what a camera records than one ray per pixel (`docs/performance.md`).
    /// `auto`: `footprint` where the cells it would project (a volume's voxels; a field's
    /// finest level, else a grid twice as fine, or the `--bake N` grid) image at most 1.5 px
    /// wide in every view, the field then sampled on those cells; `rays` otherwise, and
    /// whenever `--supersample`, `--step` or `--bake off` asks for rays. `render.json` records
    /// the choice.
    #[arg(long, value_enum, default_value = "auto")]
    pub projector: RenderProjector,
    /// Rays per pixel along each image axis (anti-aliasing; `--projector rays` only).
    #[arg(long, default_value_t = 1)]
    pub supersample: usize,
    /// Quadrature step along each ray in world units (`--projector rays` only). Default: half
    /// the voxel size for a volume (enough for its trilinear interpolant), the box's smallest
    /// side / 256 for a trained field.
    #[arg(long)]
    pub step: Option<f64>,
    /// Time at which a time-resolved field is rendered, between its first and last instants.
    /// Default: each frame's own time; for orbit views the field's first instant.
    #[arg(long, allow_hyphen_values = true)]
    pub time: Option<f64>,
    /// How a trained field is evaluated: `off` evaluates the network at every sample of every
    /// ray (exact); `N` samples it once on a grid with N cells along the box's longest side
    /// (at the cells' vertices for `--projector rays`, read back trilinearly with the field's
    /// empty space still skipped; at their centres for `--projector footprint`); `auto`,
    /// with `--projector rays`, bakes on twice the resolution of the field's finest grid level
    /// (a `fast` or `dense` field) when the views' samples outnumber twice the grid's
    /// vertices (inside the field's hull, when it has one: the network evaluations each way),
    /// else renders exactly; with `--projector footprint` it always samples the
    /// field at the cell centres of a grid twice as fine as its finest level (on the grid
    /// `--projector auto` chose when it chose the footprint projector). Baking is
    /// several times faster for orbits and all-camera renders; on the demo jet's `fast` field
    /// the baked images differ from exact ones by 0.3–0.4 % NRMSE, and with the footprint
    /// projector at the finest level's own resolution (`--bake 128`) by 1.6 %, in a fifth of
    /// the time (`docs/performance.md`).
    #[arg(long, default_value = "auto", value_parser = parse_bake)]
    pub bake: Bake,
    /// Colour map of the turntable GIF, from 0 to the brightest pixel of all views (negative
    /// pixels show as 0, with a warning).
    #[arg(long, default_value = "magma", requires = "orbit")]
    pub colormap: Colormap,
    /// Display time of each turntable frame in milliseconds: 10 to 655350, in steps of 10 (a
    /// GIF counts hundredths of a second; other values are rounded).
    #[arg(long, default_value_t = 80, requires = "orbit")]
    pub frame_ms: u32,
    /// Overwrite existing outputs in OUT; the views and turntable of an earlier render there
    /// that this one does not write (listed in its render.json) are removed.
    #[arg(long)]
    pub force: bool,
}

/// How pixels are computed (`--projector`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RenderProjector {
    /// The footprint projector where the cells image at most 1.5 px wide, else rays.
    Auto,
    /// Line integrals along rays through the pixel centres (trilinear volumes).
    Rays,
    /// The separable-footprint projector: box voxels integrated over each pixel's area.
    Footprint,
}

/// How a trained field is evaluated (`--bake`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bake {
    Auto,
    Off,
    Cells(usize),
}

fn parse_bake(s: &str) -> Result<Bake, String> {
    match s {
        "auto" => Ok(Bake::Auto),
        "off" => Ok(Bake::Off),
        _ => match s.parse::<usize>() {
            Ok(n) if (2..=2048).contains(&n) => Ok(Bake::Cells(n)),
            _ => Err(format!("expected `auto`, `off` or a number of cells from 2 to 2048, got `{s}`")),
        },
    }
}

#[derive(Serialize)]
struct Settings<'a> {
    version: &'static str,
    reconstruction: &'a Path,
    scene: &'a Path,
    /// The scene's frames rendered (`--camera`, else every frame); empty for an orbit.
    cameras: Vec<usize>,
    orbit: Option<usize>,
    /// The turntable's display time per frame, as the GIF holds it (orbits only).
    #[serde(skip_serializing_if = "Option::is_none")]
    frame_ms: Option<u32>,
    /// The width of the orbit views (orbits only: a scene camera's views are its own size).
    #[serde(skip_serializing_if = "Option::is_none")]
    width: Option<u32>,
    format: ImageFormat,
    projector: RenderProjector,
    supersample: usize,
    step: Option<f64>,
    /// The instant rendered: that of a time-resolved field, or the one a volume file records;
    /// None for a source fixed in time, and for a time-resolved field's scene views at several
    /// times (each at its frame's time, without --time). Views all at
    /// one instant give it, also when the scene's frames hold no time (a time-resolved field
    /// seen through a static scene's cameras): render.json said null, not which instant.
    time: Option<f64>,
    /// The instant of each view, in the order of `cameras`, when a time-resolved field's views
    /// are at several instants (`time` is then null); absent otherwise.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    times: Vec<f64>,
    /// The grid a trained field was sampled on for rendering (None: rendered exactly).
    baked: Option<[usize; 3]>,
    intensity_scale: f64,
    /// For 16-bit PNG: value = count × full_scale / 65535.
    full_scale: Option<f32>,
    outputs: Vec<String>,
}

/// One view to render.
struct View {
    camera: Camera,
    time: f64,
    file_stem: String,
}

/// The samples (of length `step`) that the views of the busiest time draw inside `hull`, with
/// `ss × ss` rays per pixel: what rendering them exactly costs in network evaluations,
/// estimated from every 8th ray along each image axis.
fn samples_in_hull(hull: Support<'_>, views: &[View], aabb: &Aabb, ss: usize, step: f64) -> f64 {
    const STRIDE: u32 = 8;
    let mut per_time: Vec<(f64, f64)> = Vec::new();
    let mut cells = Vec::new();
    let hull = hull.walk();
    for v in views {
        let (w, h) = (v.camera.width(), v.camera.height());
        let (mut length, mut rays) = (0.0, 0usize);
        for row in (0..h).step_by(STRIDE as usize) {
            for col in (0..w).step_by(STRIDE as usize) {
                rays += 1;
                let Ok(ray) = v.camera.pixel_ray(col as f64, row as f64) else { continue };
                let Some((s0, s1)) = aabb.intersect(&ray) else { continue };
                cells.clear();
                hull.occupied_intervals(&ray, s0, s1, &mut cells);
                length += cells.iter().map(|(a, b)| b - a).sum::<f64>();
            }
        }
        let samples = length / rays.max(1) as f64 * (w * h) as f64 * (ss * ss) as f64 / step;
        match per_time.iter_mut().find(|(t, _)| *t == v.time) {
            Some((_, sum)) => *sum += samples,
            None => per_time.push((v.time, samples)),
        }
    }
    per_time.into_iter().map(|(_, s)| s).fold(0.0, f64::max)
}

#[allow(clippy::print_stdout)]
pub fn run(args: Args) -> anyhow::Result<()> {
    refuse_other_kind(&args.out, FolderKind::Render, "render")?;
    super::refuse_unwritable_output(&args.out)?;
    let scene = args.scene.as_deref().map(|p| ("--scene", p));
    super::recordable("render.json", std::iter::once(("RECON", args.recon.as_path())).chain(scene))?;
    if let Some(n) = args.orbit.filter(|n| !(1..=MAX_ORBIT_VIEWS).contains(n)) {
        bail!("--orbit must be between 1 and {MAX_ORBIT_VIEWS} views, got {n}");
    }
    if args.orbit.is_some() && !args.camera.is_empty() {
        bail!("give either --camera or --orbit, not both");
    }
    super::given_once("--camera", &args.camera)?;
    if let Some(step) = args.step {
        if !(step > 0.0 && step.is_finite()) {
            bail!("--step must be positive, got {}", num(step));
        }
    }
    if !(1..=fluidnerf_core::render::MAX_SUPERSAMPLE).contains(&args.supersample) {
        bail!(
            "--supersample must be between 1 and {} rays per pixel along each axis, got {}",
            fluidnerf_core::render::MAX_SUPERSAMPLE,
            args.supersample
        );
    }
    if args.projector == RenderProjector::Footprint {
        if args.supersample > 1 {
            bail!(
                "--supersample applies to --projector rays; the footprint projector integrates each pixel's whole area"
            );
        }
        if args.step.is_some() {
            bail!("--step applies to --projector rays; the footprint projector takes no samples along rays");
        }
    }
    if !(10..=655_350).contains(&args.frame_ms) {
        bail!("--frame-ms must be between 10 and 655350 (a GIF counts hundredths of a second), got {}", args.frame_ms);
    }
    if !(16..=MAX_WIDTH).contains(&args.width) {
        bail!("--width must be between 16 and {MAX_WIDTH} px, got {}", args.width);
    }
    let scene_path = super::scene_or_recorded(args.scene.as_deref(), std::slice::from_ref(&args.recon))?;
    let scene = fluidnerf_io::scene::load_scene(&scene_path)
        .with_context(|| format!("reading the scene {}", scene_path.display()))?;
    fluidnerf_pipeline::rundir::refuse_among_scene_inputs(&args.out, &scene.root)?;
    // Checked here, not by the renderer at the first view, when the output folder is made.
    if let Some(problem) =
        args.step.and_then(|s| fluidnerf_core::render::step_out_of_range(&scene.aabb, s, &scene.units))
    {
        bail!("--step {problem}");
    }
    let flow = match &args.flow_axis {
        Some(a) if a.len() == 3 && a.iter().all(|v| v.is_finite()) && a.iter().any(|&v| v != 0.0) => {
            fluidnerf_core::glam::DVec3::new(a[0], a[1], a[2])
        }
        Some(a) => bail!("--flow-axis needs a non-zero direction x,y,z, got {a:?}"),
        None => fluidnerf_io::scene::recorded(&scene)
            .context("the scene's flow_axis")?
            .flow_axis
            .unwrap_or(fluidnerf_core::glam::DVec3::X),
    };
    // Each view's time as asked (`--time`, else its frame's); resolved once the source is read.
    let mut asked: Vec<(Option<f64>, String)> = Vec::new();
    let mut views: Vec<View> = match args.orbit {
        Some(n) => fluidnerf_viz::orbit_cameras_about(&scene.aabb, n, args.width, flow)
            .into_iter()
            .enumerate()
            .map(|(k, camera)| {
                asked.push((args.time, "--time".into()));
                View { camera, time: 0.0, file_stem: format!("orbit_{k:03}") }
            })
            .collect(),
        None => {
            let indices: Vec<usize> =
                if args.camera.is_empty() { (0..scene.frames.len()).collect() } else { args.camera.clone() };
            let mut views = Vec::new();
            for i in indices {
                let Some(frame) = scene.frames.get(i) else {
                    bail!("--camera {i}: the scene has {} frames (0..{})", scene.frames.len(), scene.frames.len());
                };
                asked.push(match args.time {
                    Some(t) => (Some(t), "--time".into()),
                    None => (frame.time, format!("frame {i} ({})", frame.file_path.display())),
                });
                views.push(View { camera: frame.camera.clone(), time: 0.0, file_stem: format!("view_{i:03}") });
            }
            views
        }
    };
    if views.is_empty() {
        bail!("{}: the scene has no frames to render", scene_path.display());
    }
    let ext = match args.format {
        ImageFormat::Png16 => "png",
        ImageFormat::Tiff => "tif",
    };
    let out = &args.out;
    let mut outputs: Vec<PathBuf> = views.iter().map(|v| out.join(format!("{}.{ext}", v.file_stem))).collect();
    if args.orbit.is_some() {
        outputs.push(out.join("turntable.gif"));
    }
    let settings_path = out.join("render.json");
    if !args.force {
        if let Some(p) = outputs.iter().chain([&settings_path]).find(|p| p.exists()) {
            bail!("{} exists; pass --force to overwrite it", p.display());
        }
    }
    // An earlier render's files that this one does not write: left beside the new render.json,
    // which would not list them, they would pass for this render's views.
    let stale = if args.force { stale_outputs(&settings_path, &outputs) } else { Vec::new() };
    // A volume read from a file of the render folder (a TIFF stack named as a view) was
    // written over, or removed as a view of the earlier render.
    for p in outputs.iter().chain(&stale) {
        fluidnerf_pipeline::rundir::refuse_input_file(p, &args.recon, "the reconstruction read")?;
    }
    let source = load_source(&args.recon, Some(&scene), None)?;
    // Checked before the output folder is made: the views would hold infinities and NaN.
    if let Source::Volume(v) = &source {
        if let Some(problem) = fluidnerf_core::render::integrals_overflow(v, scene.intensity_scale) {
            bail!("{}: {problem}", args.recon.display());
        }
    }
    // A run rendered with another scene's cameras and box is seldom what was meant.
    if args.scene.is_some() {
        if let Some(made_from) = super::recorded_scene(&args.recon)? {
            super::warn_of_other_scene(&args.recon, &made_from, &scene.root, "rendered from this one's cameras");
        }
    }
    let what = args.recon.display().to_string();
    super::warn_of_other_box(&what, &source.aabb(), &scene, "is it a reconstruction of this scene?");
    // The times first, as `export` does: a --time refused there (not a finite number) was
    // first warned of as having no effect.
    for (view, (time, what)) in views.iter_mut().zip(&asked) {
        view.time = source.sample_time(*time, what)?;
    }
    source.warn_held(views.iter().map(|v| v.time), &args.recon);
    source.warn_time_unused(args.time, &args.recon);
    // A volume of one instant (one of a run's frames, an export of one time): drawn through the
    // cameras of frames at another, warned of below.
    let volume_instant = match &source {
        Source::Volume(_) if args.recon.is_file() => super::export::recorded_volume_time(&args.recon),
        _ => None,
    };
    // One volume (or static field) seen through cameras of several instants: each view shows
    // the same field, whatever its frame's time.
    let instants = scene.times().len();
    if !source.is_time_resolved()
        && volume_instant.is_none()
        && args.orbit.is_none()
        && args.time.is_none()
        && instants > 1
    {
        let shown: Vec<f64> = asked.iter().filter_map(|&(t, _)| t).collect();
        if shown.iter().any(|&t| !same_time(t, shown[0])) {
            log::warn!(
                "{} is fixed in time, but the views asked are of frames at several of the scene's {instants} \
                 instants: each shows the same field, whatever its frame's time; render a time-resolved run, or each \
                 instant's volume with --camera",
                args.recon.display()
            );
        }
    }
    if let (Some((place, at)), None) = (&volume_instant, args.orbit) {
        let mut other: Vec<f64> = asked.iter().filter_map(|&(t, _)| t).filter(|&t| !same_time(t, *at)).collect();
        other.sort_by(f64::total_cmp);
        other.dedup_by(|a, b| same_time(*a, *b));
        if !other.is_empty() {
            let listed: Vec<String> = other.iter().map(|&t| num(t).to_string()).collect();
            log::warn!(
                "{} holds the field at t = {} ({place}), but views asked are of frames at t = {}: they show it, not \
                 the field of their own instant; give --camera of the frames at t = {}",
                args.recon.display(),
                num(*at),
                listed.join(", "),
                num(*at)
            );
        }
    }
    if args.bake != Bake::Auto && matches!(source, Source::Volume(_)) {
        log::warn!(
            "--bake has no effect: {} is a volume, rendered as it is; baking samples trained fields",
            args.recon.display()
        );
    }
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    // The images alone, first: choosing the projector and the bake walks every pixel's ray
    // through a field's hull, which for views too large to hold took minutes before the same
    // refusal.
    let pixels: u64 = views.iter().map(|v| (v.camera.width() * v.camera.height()) as u64).sum();
    super::check_memory(|| format!("rendering {} views of {pixels} pixels in all", views.len()), 8 * pixels)?;
    // The grid `--projector auto` chose for the footprint projector, if it chose it.
    let auto_grid = match args.projector {
        RenderProjector::Auto => auto_footprint(&args, &source, &scene.aabb, &cameras),
        _ => None,
    };
    let footprint = match args.projector {
        RenderProjector::Footprint => true,
        RenderProjector::Rays => false,
        RenderProjector::Auto => auto_grid.is_some(),
    };
    // Resolved here, so that render.json records the step the rays took (a field's was null).
    let step = match &source {
        _ if footprint => None,
        Source::Volume(v) => Some(args.step.unwrap_or(0.5 * v.spacing().min_element())),
        Source::Field { .. } => Some(args.step.unwrap_or(scene.aabb.size().min_element() / 256.0)),
    };
    // Baking: per distinct time, when it pays (see `--bake`).
    let ss = args.supersample.max(1);
    let bake_dims = match (&source, args.bake) {
        (Source::Volume(_), _) => None,
        (Source::Field { .. }, Bake::Off) if footprint => {
            bail!("--projector footprint renders a grid: give --bake auto or a number of cells, not off")
        }
        (_, Bake::Off) => None,
        (Source::Field { .. }, Bake::Cells(n)) => Some(Volume::dims_for(&scene.aabb, n)),
        (Source::Field { .. }, Bake::Auto) => {
            let doubled = source.field().detail_dims().map(|d| d.map(|n| 2 * n));
            match doubled {
                None if footprint => bail!(
                    "{}: this field has no grid of its own to bake on; with --projector footprint give --bake N \
                     (cells along the box's longest side)",
                    args.recon.display()
                ),
                // Chosen because those cells image at most a pixel and a half.
                _ if footprint && args.projector == RenderProjector::Auto => auto_grid,
                _ if footprint => doubled,
                _ => doubled.filter(|dims| {
                    let step = step.unwrap_or(scene.aabb.size().min_element() / 256.0);
                    let vertices = dims.iter().map(|n| n + 1).product::<usize>() as f64;
                    match source.field().support() {
                        // Inside the hull: the network evaluations each way.
                        Some(hull) => {
                            let occupied = hull.cells.iter().filter(|&&c| c).count() as f64 / hull.cells.len() as f64;
                            samples_in_hull(hull, &views, &scene.aabb, ss, step) >= 2.0 * occupied * vertices
                        }
                        None => {
                            let samples_per_ray = scene.aabb.size().length() / step;
                            let busiest = views
                                .iter()
                                .map(|v| {
                                    views
                                        .iter()
                                        .filter(|o| o.time == v.time)
                                        .map(|o| o.camera.width() * o.camera.height())
                                        .sum::<usize>()
                                })
                                .max()
                                .unwrap_or(0);
                            (busiest * ss * ss) as f64 * samples_per_ray >= 2.0 * vertices
                        }
                    }
                }),
            }
        }
    };
    // The footprint projector, from the grid it will project (checked before anything is
    // written: voxels may image too wide for it).
    let projector = match (footprint, &source, bake_dims) {
        (false, ..) => None,
        (true, Source::Volume(volume), _) => Some(Grid::new(volume.dims, volume.aabb)),
        (true, Source::Field { .. }, dims) => {
            Some(Grid::new(dims.expect("footprint renders of a field have a bake grid"), scene.aabb))
        }
    }
    .map(|grid| {
        FootprintProjector::new(grid, &cameras, scene.intensity_scale)
            .context("--projector footprint (--projector rays renders any voxel size)")
    })
    .transpose()?;
    // Every image is kept (as floats, and coloured for a turntable), and a field is sampled on
    // one grid at a time; the footprint projector lists the grid's non-empty chunks of sixteen
    // voxels (8 bytes each) for the views it draws together.
    let grid: u64 = bake_dims.map_or(0, |d| d.iter().map(|&n| n as u64 + 1).product());
    let chunk_lists = match (&source, footprint) {
        (_, false) => 0,
        (Source::Volume(v), true) => v.data.len() as u64 / 2,
        (Source::Field { .. }, true) => grid / 2,
    };
    super::check_memory(
        || format!("rendering {} views of {pixels} pixels in all", views.len()),
        8 * pixels + 4 * grid + chunk_lists,
    )?;
    let bar = crate::progress::bar(views.len() as u64, "render");
    let mut images: Vec<Image> = Vec::with_capacity(views.len());
    let mut baked: Option<(f64, Baked)> = None;
    // With the footprint projector a field is sampled at the cell centres of the projector's
    // grid (each voxel a box of the field's value), once per distinct time.
    let mut sampled: Option<(f64, Volume)> = None;
    for (i, v) in views.iter().enumerate() {
        if crate::interrupt::requested() {
            bail!("interrupted");
        }
        if footprint {
            // Views are projected in groups of one time, where the volume's empty chunks are
            // found once for the group; `i` opens a group or is in one already drawn.
            if i < images.len() {
                continue;
            }
            let p = projector.as_ref().expect("built for footprint renders");
            let volume = match &source {
                Source::Volume(volume) => volume,
                Source::Field { .. } => {
                    if sampled.as_ref().is_none_or(|(t, _)| *t != v.time) {
                        let g = p.grid();
                        sampled = Some((v.time, Volume::from_field(g.dims, g.aabb, source.field(), v.time)));
                    }
                    &sampled.as_ref().expect("sampled just above").1
                }
            };
            let group: Vec<usize> =
                (i..views.len()).take(FOOTPRINT_GROUP).take_while(|&j| views[j].time == v.time).collect();
            let mut drawn: Vec<Image> =
                group.iter().map(|&j| Image::zeros(views[j].camera.width(), views[j].camera.height())).collect();
            let mut outs: Vec<&mut [f32]> = drawn.iter_mut().map(|img| img.data.as_mut_slice()).collect();
            p.forward_views(&group, &volume.data, &mut outs);
            bar.inc(drawn.len() as u64);
            images.extend(drawn);
            continue;
        }
        let settings = RenderSettings { supersample: ss, time: v.time, scale: scene.intensity_scale, step };
        let field: &dyn ScalarField = match bake_dims {
            Some(dims) => {
                if baked.as_ref().is_none_or(|(t, _)| *t != v.time) {
                    baked = Some((v.time, Baked::on_vertices(source.field(), dims, scene.aabb, v.time)));
                }
                &baked.as_ref().expect("baked just above").1
            }
            None => source.field(),
        };
        let img = render_image(field, &v.camera, &scene.aabb, &settings)
            .with_context(|| format!("rendering {}", v.file_stem))?;
        images.push(img);
        bar.inc(1);
    }
    bar.finish_and_clear();

    // A field whose finite weights are so large that its values overflow draws infinite or NaN
    // pixels (loading refuses non-finite weights themselves); a TIFF would keep them.
    for (v, img) in views.iter().zip(&images) {
        if let Some(at) = img.data.iter().position(|x| !x.is_finite()) {
            bail!(
                "{}: view {} is {} at pixel (col {}, row {}): the reconstruction's values overflow 32-bit floats (finite \
                 weights or voxels so large that their sums do not fit); the file is damaged or was edited",
                args.recon.display(),
                v.file_stem,
                img.data[at],
                at % img.width,
                at / img.width
            );
        }
    }
    let peak = images.iter().flat_map(|i| i.data.iter()).copied().fold(0f32, f32::max);
    // Views that are all black although the source is not empty show nothing of it: it lies
    // outside every view (another scene's box or cameras). Written, they would pass for a
    // render of an empty volume.
    if images.iter().all(|i| i.data.iter().all(|&v| v == 0.0)) {
        if let Some(largest) = largest_value(&source, views[0].time) {
            let aabb = source.aabb();
            bail!(
                "{}: every rendered view is black (all pixels 0), yet it is not empty (values up to {}): none of it \
                 lies in any view. It fills the box {} .. {}; the scene's box is {} .. {}: is it a reconstruction \
                 of this scene?",
                args.recon.display(),
                num(largest),
                num(aabb.min.to_array()),
                num(aabb.max.to_array()),
                num(scene.aabb.min.to_array()),
                num(scene.aabb.max.to_array())
            );
        }
    }
    let full_scale = (args.format == ImageFormat::Png16).then_some(if peak > 0.0 { peak } else { 1.0 });
    // A 16-bit PNG holds no negative count: the pixels of a reconstruction with negative values
    // that would round below 0 are written as 0.
    if let Some(fs) = full_scale {
        let below = |v: f32| f64::from(v) / f64::from(fs) * 65535.0 < -0.5;
        let (count, lowest) = images
            .iter()
            .flat_map(|i| i.data.iter())
            .filter(|&&v| below(v))
            .fold((0usize, 0f32), |(n, lo), &v| (n + 1, lo.min(v)));
        if count > 0 {
            log::warn!(
                "{count} pixel(s) of the views are negative (down to {lowest}: the reconstruction holds negative \
                 values), and a 16-bit PNG holds no negative count, so they are written as 0; --format tiff keeps \
                 them"
            );
        }
    }
    // The folder is made once the views are drawn: a render refused or interrupted on the way
    // leaves none behind (its writability was checked at the start).
    super::create_output_folder(out)?;
    // Encoded and written on every core (a PNG's compression is most of a small view's cost);
    // a view that could not be written is named.
    images
        .par_iter()
        .zip(&outputs)
        .map(|(img, path)| {
            match full_scale {
                Some(fs) => fluidnerf_io::image::write_png16(path, img, fs),
                None => fluidnerf_io::image::write_tiff_f32(path, img),
            }
            .with_context(|| format!("writing {}", path.display()))
        })
        .collect::<anyhow::Result<Vec<()>>>()?;
    if args.orbit.is_some() {
        let p = out.join("turntable.gif");
        let clipping = fluidnerf_viz::write_turntable_gif(&p, &images, args.colormap, args.frame_ms)
            .with_context(|| format!("writing {}", p.display()))?;
        // The turntable's colour map starts at 0: negative pixels take the colour of 0.
        if clipping.negative > 0 {
            log::warn!(
                "{} pixel(s) of the orbit views are negative (down to {}: the reconstruction holds negative \
                 values), below the turntable's colour map, which starts at 0, so {} shows them as 0; --format \
                 tiff keeps their values in the views",
                clipping.negative,
                clipping.lowest,
                p.display()
            );
        }
    }
    // Views all at one instant give it once in render.json, else each view's (views is not empty).
    let one_instant = views.iter().all(|v| v.time == views[0].time);
    let settings = Settings {
        version: env!("CARGO_PKG_VERSION"),
        reconstruction: &args.recon,
        scene: &scene_path,
        // An empty list read as "none" where every frame was rendered.
        cameras: match (args.orbit, args.camera.is_empty()) {
            (Some(_), _) => Vec::new(),
            (None, true) => (0..scene.frames.len()).collect(),
            (None, false) => args.camera.clone(),
        },
        orbit: args.orbit,
        frame_ms: args.orbit.map(|_| (args.frame_ms + 5) / 10 * 10),
        width: args.orbit.map(|_| args.width),
        format: args.format,
        projector: if footprint { RenderProjector::Footprint } else { RenderProjector::Rays },
        supersample: args.supersample.max(1),
        step,
        // A time-resolved field's: the time asked, or that of its orbit views (all at one). A
        // source fixed in time has none, whatever --time said (it was warned of as unused).
        time: if source.is_time_resolved() {
            args.time.or(one_instant.then(|| views[0].time))
        } else {
            volume_instant.map(|(_, t)| t)
        },
        times: match source.is_time_resolved() && !one_instant {
            true => views.iter().map(|v| v.time).collect(),
            false => Vec::new(),
        },
        baked: bake_dims,
        intensity_scale: scene.intensity_scale,
        full_scale,
        outputs: outputs.iter().map(|p| p.display().to_string()).collect(),
    };
    let text = serde_json::to_string_pretty(&settings)?;
    fluidnerf_io::atomic_write(&settings_path, |w| w.write_all(text.as_bytes()))
        .with_context(|| format!("writing {}", settings_path.display()))?;
    for p in &stale {
        std::fs::remove_file(p).with_context(|| format!("removing {}, a view of the earlier render", p.display()))?;
    }
    if !stale.is_empty() {
        log::info!("removed {} file(s) of the earlier render in {} that this one replaces", stale.len(), out.display());
    }
    let mut how = match bake_dims {
        Some([x, y, z]) if footprint => format!(", sampled on {x}x{y}x{z} cells"),
        Some([x, y, z]) => format!(", sampled on {x}x{y}x{z} cells (--bake off renders it exactly)"),
        // `--bake auto` chose not to: say why, since the user may expect a bake.
        None if args.bake == Bake::Auto
            && matches!(source, Source::Field { .. })
            && source.field().detail_dims().is_some() =>
        {
            ", exactly: a bake would not halve the network's evaluations".to_string()
        }
        None => String::new(),
    };
    if footprint {
        how.push_str(", footprint projector");
    }
    println!(
        "rendered {} {} of {} ({}{how}); brightest pixel {peak:.4}",
        views.len(),
        if views.len() == 1 { "view" } else { "views" },
        args.recon.display(),
        source.describe()
    );
    for p in &outputs {
        println!("wrote {}", p.display());
    }
    Ok(())
}

/// The value of `source` at `time` largest in magnitude, if it is not empty: a volume's
/// largest voxel, a field's largest sample at the cells of a coarse grid over its box.
fn largest_value(source: &Source, time: f64) -> Option<f32> {
    let sampled;
    let data = match source {
        Source::Volume(v) => &v.data,
        Source::Field { field, aabb, .. } => {
            sampled = Volume::from_field(Volume::dims_for(aabb, 32), *aabb, field.as_ref(), time);
            &sampled.data
        }
    };
    data.iter().copied().filter(|v| v.is_finite() && *v != 0.0).reduce(|a, b| if b.abs() > a.abs() { b } else { a })
}

/// Widest image of a cell, in pixels, up to which `--projector auto` takes the footprint
/// projector. There a pixel spans about a cell or more, so integrating box cells over its area
/// is closer to what the camera records than a ray through its centre, and a field sampled on
/// its finest level's cells loses little (`docs/performance.md`).
pub const AUTO_FOOTPRINT_MAX_PX: f64 = 1.5;

/// Views the footprint projector draws together, sharing one pass over the volume to find its
/// empty chunks; few enough that an interruption is seen soon.
const FOOTPRINT_GROUP: usize = 16;

/// The grid `--projector auto` renders with the footprint projector, if it does (see
/// [`Args::projector`]): nothing asks for rays, and the cells it would project image at most
/// [`AUTO_FOOTPRINT_MAX_PX`] wide in every view. For a field baked by default those are the
/// finest level's cells, or else the cells of a grid twice as fine (the grid the footprint
/// projector samples a field on when asked for it); rays where both image wider.
fn auto_footprint(args: &Args, source: &Source, aabb: &Aabb, cameras: &[Camera]) -> Option<[usize; 3]> {
    if args.supersample > 1 || args.step.is_some() {
        return None;
    }
    let fits = |dims: [usize; 3], aabb: Aabb| {
        let px = FootprintProjector::largest_footprint_px(&Grid::new(dims, aabb), cameras);
        log::debug!("--projector auto: cells of a {dims:?} grid image at most {px:.2} px wide");
        px <= AUTO_FOOTPRINT_MAX_PX
    };
    let candidates: Vec<[usize; 3]> = match (source, args.bake) {
        (Source::Volume(v), _) => return fits(v.dims, v.aabb).then_some(v.dims),
        (Source::Field { .. }, Bake::Off) => return None,
        (Source::Field { .. }, Bake::Cells(n)) => vec![Volume::dims_for(aabb, n)],
        (Source::Field { .. }, Bake::Auto) => match source.field().detail_dims() {
            Some(dims) => vec![dims, dims.map(|n| 2 * n)],
            None => return None,
        },
    };
    candidates.into_iter().find(|&dims| fits(dims, *aabb))
}

/// The files an earlier render listed in `settings` (its `render.json`) that the new render's
/// `outputs` do not hold: views and turntables in the same folder, found by their names there
/// (a render.json records them as the command was given them). Anything else is left alone.
fn stale_outputs(settings: &Path, outputs: &[PathBuf]) -> Vec<PathBuf> {
    let Some(folder) = settings.parent() else { return Vec::new() };
    let Some(listed) = std::fs::read_to_string(settings)
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
        .and_then(|v| v.get("outputs").and_then(|o| o.as_array()).cloned())
    else {
        return Vec::new();
    };
    let new: std::collections::HashSet<&std::ffi::OsStr> = outputs.iter().filter_map(|p| p.file_name()).collect();
    let ours = |name: &std::ffi::OsStr| {
        Path::new(name).extension().and_then(|e| e.to_str()).is_some_and(|e| ["png", "tif", "gif"].contains(&e))
    };
    let mut stale: Vec<PathBuf> = listed
        .iter()
        .filter_map(|p| p.as_str().and_then(|p| Path::new(p).file_name()))
        .filter(|name| ours(name) && !new.contains(name))
        .map(|name| folder.join(name))
        .filter(|p| p.is_file())
        .collect();
    stale.sort();
    stale.dedup();
    stale
}
