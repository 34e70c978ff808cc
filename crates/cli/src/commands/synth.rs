//! `fluidnerf synth`: generates a synthetic data set (phantom, cameras, images, ground truth)
//! from a named preset with any setting overridden.

use std::fmt::Write as _;
use std::io::Write as _;
use std::ops::ControlFlow;
use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::ValueEnum;
use fluidnerf_core::glam::DVec3;
use fluidnerf_core::Aabb;
use fluidnerf_synth::{
    generate, preset, presets, ImageModel, Layout, PhantomKind, PinholeSettings, Subset, SynthSettings,
    ThinLensSettings, DEFAULT_PRESET,
};

/// What `--help` says about the outputs (the struct's doc comment is shadowed by the
/// subcommand's).
const OUTPUTS: &str = "Starts from a preset (--list-presets; default planar15, the dissertation's \
15-camera planar ring around a turbulent jet) and applies the options given; later options \
override earlier ones. Writes into OUT: transforms.json (cameras, box, intensity scale), \
images/*.png (16-bit sensor counts: counts - dark offset = intensity_scale x line integral of E \
in mm; 8-bit JPEGs for the real-like presets), truth/*.npy (the ground truth on the voxel grid, \
shape (nz, ny, nx)), background/ and flat/ when the images have a background or vignetting to \
correct (the real-like presets), preview.png (a central slice of the truth and one camera \
image) and synth.json (the resolved settings; rerun with --config). The same seed gives the \
same bytes.";

/// Every option of [`Args`] but `--list-presets`: each says what to synthesise, and
/// `--list-presets` synthesises nothing, so it refuses them, naming the one given (the list was
/// printed and the rest ignored: a user who asked for a scene got none, and no error).
const SYNTHESIS_OPTIONS: &[&str] = &[
    "out",
    "preset",
    "config",
    "force",
    "seed",
    "phantom",
    "truth_volume",
    "resolution",
    "aabb",
    "times",
    "cfd_step",
    "layout",
    "cameras",
    "arc",
    "every",
    "first",
    "holdout",
    "jitter_position",
    "jitter_rotation",
    "distance",
    "pixels",
    "magnification",
    "focal_length",
    "f_number",
    "pixel_pitch",
    "model",
    "supersample",
    "analytic",
    "rays_per_voxel",
    "noise",
    "full_well",
    "dark_offset",
    "bit_depth",
    "full_scale_fraction",
    "real_like",
    "gain_spread",
    "background_level",
    "dark_noise",
    "background_frames",
    "jpeg_quality",
    "vignetting",
    "flat_frames",
];

/// Phantoms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum PhantomArg {
    /// Static turbulent round jet: laminar core, shear-layer roll-up, turbulent far field.
    Jet,
    /// Starting jet whose leading vortex ring travels through the box (time-resolved).
    JetTr,
    /// Uniform ball (closed-form projections).
    Ball,
    /// Gaussian blobs (closed-form projections).
    Blobs,
    /// Half-value ball plus Gaussian blobs.
    BallAndBlobs,
    /// CFD buoyant plume (PhiFlow), rising along +y in its own 24 × 36 × 24 mm domain; static,
    /// or at the solver steps given with --times.
    Plume,
    /// CFD forced round jet (PhiFlow), along +y in the same domain; static or at --times.
    CfdJet,
}

/// Camera layouts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LayoutArg {
    /// A ring perpendicular to the flow axis (x for the procedural jets, y for the CFD
    /// phantoms).
    Ring,
    /// A Fibonacci lattice on a sphere.
    Sphere,
}

/// Image models.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ModelArg {
    /// Ideal, anti-aliased pinhole line integrals.
    Pinhole,
    /// The dissertation's thin lens: rays from every voxel through a finite aperture.
    ThinLens,
}

/// Generate a synthetic data set with known ground truth.
///
/// A phantom (a turbulent jet, a starting jet, a CFD plume or jet, simple shapes or your own
/// volume) is imaged by a
/// camera rig (planar ring, arc or sphere) through a pinhole or a thin lens with a finite
/// aperture, with sensor noise, and written as a scene that every other command reads. Start
/// from a preset and override any setting; the resolved settings are saved next to the scene.
#[derive(clap::Args, Debug)]
#[command(args_override_self = true, after_long_help = OUTPUTS)]
pub struct Args {
    /// Output directory; created if missing. One that already holds a scene needs --force.
    #[arg(short, long, required_unless_present = "list_presets")]
    pub out: Option<PathBuf>,
    /// Preset to start from (see --list-presets).
    #[arg(short, long, default_value = DEFAULT_PRESET)]
    pub preset: String,
    /// List the presets and exit; it synthesises nothing, so no other option of the command
    /// goes with it.
    #[arg(long, conflicts_with_all = SYNTHESIS_OPTIONS)]
    pub list_presets: bool,
    /// Start from a `synth.json` written by an earlier run instead of a preset (options given
    /// here still override it).
    #[arg(long, conflicts_with = "preset")]
    pub config: Option<PathBuf>,
    /// Write into OUT although it already holds a scene or other files: the scene's files
    /// (transforms.json, images/, truth/, previews) replace any of the same names there, and
    /// other files are left as they are. A run's or an export's folder is refused even so.
    #[arg(long)]
    pub force: bool,
    /// Seed for the phantom, pose jitter, thin-lens rays and noise [default: the preset's, 0].
    #[arg(long, allow_negative_numbers = true, value_parser = super::parse_seed)]
    pub seed: Option<u64>,

    /// Phantom [default: the preset's].
    #[arg(long, value_enum, help_heading = "Phantom")]
    pub phantom: Option<PhantomArg>,
    /// Use this volume (.npy of shape (nz, ny, nx) filling --aabb, .vti, which holds its own
    /// box, or a .tif stack, which holds its own when calibrated for ImageJ and else fills
    /// --aabb) as the ground truth, on its own grid.
    #[arg(long, help_heading = "Phantom", conflicts_with = "phantom")]
    pub truth_volume: Option<PathBuf>,
    /// Truth voxels along the box's longest side [default: the preset's].
    #[arg(long, help_heading = "Phantom")]
    pub resolution: Option<usize>,
    /// Reconstruction box in mm as minx,miny,minz,maxx,maxy,maxz [default: the 40 mm cube
    /// centred at the origin; the simulation domain for the CFD phantoms, which stay in it].
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, help_heading = "Phantom")]
    pub aabb: Option<Vec<f64>>,
    /// Frame times, comma separated: t* = t U / D for jet-tr [default: 14,15,16]; stored
    /// solver steps (40, 50, 52, 60) for plume and cfd-jet [default: none, static]. Given in
    /// any order, they are sorted: the frames follow time.
    #[arg(long, value_delimiter = ',', help_heading = "Phantom")]
    pub times: Option<Vec<f64>>,
    /// Solver step of a static plume or cfd-jet: 40, 50, 52 or 60 [default: 60].
    #[arg(long, help_heading = "Phantom")]
    pub cfd_step: Option<u32>,

    /// Camera layout [default: the preset's].
    #[arg(long, value_enum, help_heading = "Cameras")]
    pub layout: Option<LayoutArg>,
    /// Number of cameras of the layout (clears the preset's subset).
    #[arg(long, help_heading = "Cameras")]
    pub cameras: Option<usize>,
    /// Arc of a ring in degrees, e.g. 180 [default: 360].
    #[arg(long, help_heading = "Cameras")]
    pub arc: Option<f64>,
    /// Keep every k-th camera of the layout.
    #[arg(long, help_heading = "Cameras")]
    pub every: Option<usize>,
    /// Keep at most the first n cameras (after --every).
    #[arg(long, help_heading = "Cameras")]
    pub first: Option<usize>,
    /// Cameras held out for validation, comma separated: names (`cam007`) or indices after
    /// subsetting.
    #[arg(long, value_delimiter = ',', help_heading = "Cameras")]
    pub holdout: Option<Vec<String>>,
    /// Standard deviation of random camera position errors, mm, at most the cameras' distance
    /// from the point they look at [default: 0].
    #[arg(long, help_heading = "Cameras")]
    pub jitter_position: Option<f64>,
    /// Standard deviation of random camera rotation errors, degrees, at most 180 [default: 0].
    #[arg(long, help_heading = "Cameras")]
    pub jitter_rotation: Option<f64>,
    /// Camera distance from the box centre, mm [default: the lens's object distance, 360].
    #[arg(long, help_heading = "Cameras")]
    pub distance: Option<f64>,
    /// Image width and height in pixels (square images); the pixel pitch follows so the field
    /// of view stays 40 mm unless --pixel-pitch is given; at least 7, the SSIM window that
    /// scores held-out views [default: the preset's].
    #[arg(long, help_heading = "Cameras")]
    pub pixels: Option<u32>,
    /// Lateral magnification [default: -0.2].
    #[arg(long, allow_hyphen_values = true, help_heading = "Cameras")]
    pub magnification: Option<f64>,
    /// Focal length, mm [default: 60].
    #[arg(long, help_heading = "Cameras")]
    pub focal_length: Option<f64>,
    /// f-number [default: 3.5].
    #[arg(long, help_heading = "Cameras")]
    pub f_number: Option<f64>,
    /// Pixel pitch, mm [default: 0.01 × 800 / pixels].
    #[arg(long, help_heading = "Cameras")]
    pub pixel_pitch: Option<f64>,

    /// Image model [default: the preset's].
    #[arg(long, value_enum, help_heading = "Images")]
    pub model: Option<ModelArg>,
    /// Pinhole: rays per pixel along each axis [default: 2].
    #[arg(long, help_heading = "Images")]
    pub supersample: Option<usize>,
    /// Pinhole: render the continuous phantom instead of its voxel grid (slow, exact).
    #[arg(long, help_heading = "Images")]
    pub analytic: bool,
    /// Thin lens: rays cast per voxel on the focal plane (N_rays of Eq. 6.7) [default: 128].
    #[arg(long, help_heading = "Images")]
    pub rays_per_voxel: Option<f64>,

    /// Gaussian noise σ as a fraction of each image's maximum, e.g. 0.05 [default: 0].
    #[arg(long, allow_hyphen_values = true, help_heading = "Sensor")]
    pub noise: Option<f64>,
    /// Photo-electrons at full scale; enables photon (Poisson) noise [default: none].
    #[arg(long, help_heading = "Sensor")]
    pub full_well: Option<f64>,
    /// Dark offset added to every pixel before rounding and clipping, counts; noise below the
    /// offset is then recorded, not clipped at zero. At most the headroom above the brightest
    /// pixel ((1 − full-scale fraction) × full scale), which would otherwise be clipped. The
    /// scene records the offset as its `background`, which a reconstruction subtracts [default:
    /// 0].
    #[arg(long, help_heading = "Sensor")]
    pub dark_offset: Option<f64>,
    /// Sensor bit depth: 8, 10, 12 or 16 [default: 16].
    #[arg(long, help_heading = "Sensor")]
    pub bit_depth: Option<u32>,
    /// Brightest noiseless pixel as a fraction of full scale [default: 0.8].
    #[arg(long, help_heading = "Sensor")]
    pub full_scale_fraction: Option<f64>,

    /// Record like a laboratory rig: per-camera gains, a background, dark noise, background
    /// frames and 8-bit sRGB JPEG images (the `real-like` presets turn it on, and so does any
    /// option of this section given without it; `false` turns it off, giving the same data set
    /// as linear 16-bit PNG counts, and refuses those options).
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL", help_heading = "Real-like recording")]
    pub real_like: Option<bool>,
    /// Camera gains drawn uniformly in 1 ± this, then scaled to mean 1 over the training
    /// cameras [default: 0.3].
    #[arg(long, help_heading = "Real-like recording")]
    pub gain_spread: Option<f64>,
    /// Mean background level as a fraction of the brightest signal pixel [default: 0.05].
    #[arg(long, help_heading = "Real-like recording")]
    pub background_level: Option<f64>,
    /// σ of the dark noise as a fraction of the brightest signal pixel [default: 0.005].
    #[arg(long, help_heading = "Real-like recording")]
    pub dark_noise: Option<f64>,
    /// Background frames recorded per camera [default: 1].
    #[arg(long, help_heading = "Real-like recording")]
    pub background_frames: Option<usize>,
    /// JPEG quality, 1..=100 [default: 95].
    #[arg(long, help_heading = "Real-like recording")]
    pub jpeg_quality: Option<u8>,
    /// Vignetting: the fraction by which each camera's sensitivity falls from its (off-centre)
    /// optical centre to the farthest image corner, in [0, 0.9]; with it every camera also
    /// records flat-field frames and the scene its `flat_field` [default: 0].
    #[arg(long, help_heading = "Real-like recording")]
    pub vignetting: Option<f64>,
    /// Flat-field frames recorded per camera when there is vignetting [default: 1].
    #[arg(long, help_heading = "Real-like recording")]
    pub flat_frames: Option<usize>,
}

/// `--holdout` entries as indices after subsetting: an index, or a camera's name (`cam007`).
fn holdout_indices(given: &[String], s: &SynthSettings) -> anyhow::Result<Vec<usize>> {
    let names: Option<Vec<String>> = if given.iter().all(|g| g.parse::<usize>().is_ok()) {
        None
    } else {
        let cams = s.rig.build(&s.lens, &s.aabb, s.seed).context("--holdout: the camera rig")?;
        Some(cams.into_iter().map(|c| c.name).collect())
    };
    given
        .iter()
        .map(|g| match (g.parse::<usize>(), &names) {
            (Ok(i), _) => Ok(i),
            (Err(_), Some(names)) => names.iter().position(|n| n == g).ok_or_else(|| {
                anyhow::anyhow!("--holdout: no camera named `{g}` in the rig (cameras: {})", names.join(", "))
            }),
            (Err(_), None) => bail!("--holdout: `{g}` is neither an index nor a camera name"),
        })
        .collect::<anyhow::Result<Vec<usize>>>()
        .and_then(|indices| {
            match indices.iter().enumerate().find_map(|(i, a)| indices[..i].iter().position(|b| b == a).map(|j| (j, i)))
            {
                Some((j, i)) if given[j] == given[i] => {
                    bail!("--holdout: {} is given twice; give each camera once", given[i])
                }
                Some((j, i)) => {
                    bail!("--holdout: {} and {} name the same camera; give each camera once", given[j], given[i])
                }
                None => Ok(indices),
            }
        })
}

/// Applies the command-line overrides to `s`.
fn apply_overrides(args: &Args, s: &mut SynthSettings) -> anyhow::Result<()> {
    if let Some(seed) = args.seed {
        s.seed = seed;
    }
    if let Some(p) = args.phantom {
        let kind = match p {
            PhantomArg::Jet => PhantomKind::Jet,
            PhantomArg::JetTr => PhantomKind::JetTr,
            PhantomArg::Ball => PhantomKind::Ball,
            PhantomArg::Blobs => PhantomKind::Blobs,
            PhantomArg::BallAndBlobs => PhantomKind::BallAndBlobs,
            PhantomArg::Plume => PhantomKind::Plume,
            PhantomArg::CfdJet => PhantomKind::CfdJet,
        };
        let was_cfd = s.phantom.kind.cfd_case().is_some();
        let is_cfd = kind.cfd_case().is_some();
        // t* and solver steps do not translate into each other.
        if was_cfd != is_cfd || !kind.takes_times() {
            s.times.clear();
        }
        if kind.is_time_resolved() && s.times.is_empty() {
            s.times = vec![14.0, 15.0, 16.0];
        }
        if is_cfd && !was_cfd {
            s.aabb = fluidnerf_synth::phantom::cfd::domain();
            s.resolution = fluidnerf_synth::phantom::cfd::CELLS.into_iter().max().unwrap_or(1);
        }
        if let Layout::Ring { axis, .. } = &mut s.rig.layout {
            *axis = kind.flow_axis();
        }
        s.phantom.kind = kind;
        // A volume of the user's that the new phantom replaces (from a `synth.json` given to
        // --config) is no longer read, so it is not recorded either.
        s.phantom.volume_path = None;
        // Likewise the other phantoms' settings, which the phantom's own check would refuse.
        s.phantom.reset_unused();
    }
    if let Some(path) = &args.truth_volume {
        s.phantom.kind = PhantomKind::Volume;
        s.phantom.volume_path = Some(path.clone());
        s.phantom.reset_unused();
        s.times.clear();
    }
    if let Some(r) = args.resolution {
        s.resolution = r;
    }
    if let Some(b) = &args.aabb {
        if b.len() != 6 {
            bail!("--aabb takes 6 numbers (minx,miny,minz,maxx,maxy,maxz), got {}", b.len());
        }
        let min = DVec3::new(b[0], b[1], b[2]);
        let max = DVec3::new(b[3], b[4], b[5]);
        let aabb = Aabb { min, max };
        aabb.validate().context("--aabb")?;
        s.aabb = aabb;
    }
    if let Some(t) = &args.times {
        s.times = t.clone();
    }
    // A volume of the user's is the truth as it is: its grid, and a .vti's box, are its own.
    if let (PhantomKind::Volume, Some(path)) = (s.phantom.kind, &s.phantom.volume_path) {
        // What the file is comes first: the options' complaints assume a volume.
        let format = fluidnerf_pipeline::synthetic::truth_volume_format(path)?;
        if let Some(r) = args.resolution {
            bail!(
                "--resolution {r}: the truth volume {} is imaged on its own grid; resample it first (e.g. fluidnerf \
                 export --resolution {r}), or leave --resolution out",
                path.display()
            );
        }
        if format == "vti" && args.aabb.is_some() {
            bail!(
                "--aabb: the truth volume {} is a .vti, which holds its own box; leave --aabb out, or give the volume \
                 as a .npy, which fills the box given",
                path.display()
            );
        }
    }
    if let Some(step) = args.cfd_step {
        s.phantom.cfd_step = Some(step);
    }
    let count = args.cameras;
    let current = s.rig.count();
    match (args.layout, &s.rig.layout) {
        (Some(LayoutArg::Sphere), Layout::Sphere { .. }) | (Some(LayoutArg::Ring), Layout::Ring { .. }) | (None, _) => {
        }
        (Some(LayoutArg::Sphere), _) => {
            s.rig.layout = Layout::Sphere { count: current };
            s.rig.subset = Subset::default();
        }
        (Some(LayoutArg::Ring), _) => {
            s.rig.layout =
                Layout::Ring { count: current, arc_deg: 360.0, start_deg: 0.0, axis: s.phantom.kind.flow_axis() };
            s.rig.subset = Subset::default();
        }
    }
    if let Some(n) = count {
        match &mut s.rig.layout {
            Layout::Ring { count, .. } | Layout::Sphere { count } => *count = n,
            Layout::Explicit { .. } => bail!("--cameras needs a ring or sphere layout"),
        }
        s.rig.subset = Subset::default();
    }
    if let Some(arc) = args.arc {
        match &mut s.rig.layout {
            Layout::Ring { arc_deg, .. } => *arc_deg = arc,
            _ => bail!("--arc needs a ring layout"),
        }
    }
    if let Some(k) = args.every {
        s.rig.subset.every = k;
    }
    if let Some(n) = args.first {
        s.rig.subset.first = Some(n);
    }
    if let Some(h) = &args.holdout {
        s.rig.holdout = holdout_indices(h, s)?;
    }
    let real_given = args.gain_spread.is_some()
        || args.background_level.is_some()
        || args.dark_noise.is_some()
        || args.background_frames.is_some()
        || args.jpeg_quality.is_some()
        || args.vignetting.is_some()
        || args.flat_frames.is_some();
    if args.real_like == Some(false) {
        if real_given {
            bail!("--real-like false: the real-like options (--gain-spread, ...) do not apply");
        }
        s.real = None;
    }
    if args.real_like == Some(true) || real_given {
        let r = s.real.get_or_insert_with(Default::default);
        if let Some(v) = args.gain_spread {
            r.gain_spread = v;
        }
        if let Some(v) = args.background_level {
            r.background = v;
        }
        if let Some(v) = args.dark_noise {
            r.dark_noise = v;
        }
        if let Some(v) = args.background_frames {
            r.background_frames = v;
        }
        if let Some(v) = args.jpeg_quality {
            r.jpeg_quality = v;
        }
        if let Some(v) = args.vignetting {
            r.vignetting = v;
        }
        if let Some(v) = args.flat_frames {
            r.flat_frames = v;
        }
        // Flat-field frames are recorded only to correct a vignetting.
        if args.flat_frames.is_some() && r.vignetting == 0.0 {
            bail!("--flat-frames: flat-field frames are recorded only with vignetting; give --vignetting too");
        }
    }
    if let Some(v) = args.jitter_position {
        s.rig.jitter.position_mm = v;
    }
    if let Some(v) = args.jitter_rotation {
        s.rig.jitter.rotation_deg = v;
    }
    if let Some(v) = args.distance {
        s.rig.distance_mm = Some(v);
    }
    if let Some(px) = args.pixels {
        s.lens.resolution = [px, px];
    }
    if let Some(v) = args.magnification {
        s.lens.magnification = v;
    }
    if let Some(v) = args.focal_length {
        s.lens.focal_length_mm = v;
    }
    if let Some(v) = args.f_number {
        s.lens.f_number = v;
    }
    if let Some(v) = args.pixel_pitch {
        s.lens.pixel_pitch_mm = Some(v);
    }
    match args.model {
        Some(ModelArg::Pinhole) if !matches!(s.image, ImageModel::Pinhole(_)) => {
            s.image = ImageModel::Pinhole(PinholeSettings::default());
        }
        Some(ModelArg::ThinLens) if !matches!(s.image, ImageModel::ThinLens(_)) => {
            s.image = ImageModel::ThinLens(ThinLensSettings::default());
        }
        _ => {}
    }
    match &mut s.image {
        ImageModel::Pinhole(p) => {
            if let Some(n) = args.supersample {
                p.supersample = n;
            }
            if args.analytic {
                p.analytic = true;
            }
            if args.rays_per_voxel.is_some() {
                bail!("--rays-per-voxel applies to the thin-lens model; add --model thin-lens");
            }
        }
        ImageModel::ThinLens(t) => {
            if let Some(n) = args.rays_per_voxel {
                t.rays_per_voxel = n;
            }
            if args.supersample.is_some() || args.analytic {
                bail!("--supersample and --analytic apply to the pinhole model; add --model pinhole");
            }
        }
    }
    if let Some(v) = args.noise {
        s.sensor.gaussian_noise = v;
    }
    if let Some(v) = args.full_well {
        s.sensor.full_well = Some(v);
    }
    if let Some(v) = args.dark_offset {
        s.sensor.dark_offset = v;
    }
    if let Some(v) = args.bit_depth {
        s.sensor.bit_depth = v;
    }
    if let Some(v) = args.full_scale_fraction {
        s.sensor.full_scale_fraction = v;
    }
    Ok(())
}

/// The settings `args` ask for: the --config file or the preset, with the options applied,
/// validated.
pub(crate) fn resolve(args: &Args) -> anyhow::Result<SynthSettings> {
    let mut settings = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
            let value: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
                anyhow::anyhow!("{}: not valid JSON: {}", path.display(), fluidnerf_io::json::describe_error(&text, &e))
            })?;
            // Another fluidnerf file is named for what it is, not by the first key it has.
            use fluidnerf_pipeline::rundir::JsonFileKind;
            if let Some(kind) = JsonFileKind::of(&value).filter(|k| *k != JsonFileKind::SynthSettings) {
                bail!(
                    "{}: is {}, not the settings of a synthetic scene (the synth.json beside a scene that synth \
                     wrote)",
                    path.display(),
                    kind.describe()
                );
            }
            // synth.json records the seed at its top beside `settings.seed`, the one read: a seed
            // edited at the top alone would be passed over without a word (--seed overrides both).
            if let (Some(top), Some(used)) = (value.get("seed"), value.get("settings").and_then(|s| s.get("seed"))) {
                if top != used && args.seed.is_none() {
                    bail!(
                        "{}: `seed` {top} and `settings.seed` {used} disagree; the scene is made with `settings.seed` \
                         (the top-level `seed` records it): edit both alike, or give --seed",
                        path.display()
                    );
                }
            }
            // A synth.json holds the settings under `settings`; a file of the settings alone works too.
            let (inner, under) = match value.get("settings") {
                Some(settings) => (settings.clone(), "settings."),
                None => (value, ""),
            };
            // Named by the key's path in the file, which serde's own message leaves out.
            fluidnerf_pipeline::rundir::from_json_value::<SynthSettings>(inner).map_err(|e| {
                let why = match e {
                    fluidnerf_pipeline::PipelineError::Invalid { why, .. } => {
                        why.replacen("at `", &format!("at `{under}"), 1)
                    }
                    other => other.to_string(),
                };
                anyhow::anyhow!("{}: not a valid synth configuration: {why}", path.display())
            })?
        }
        None => preset(&args.preset)?,
    };
    apply_overrides(args, &mut settings)?;
    settings.validate().map_err(|e| name_option(args, e))?;
    Ok(settings)
}

/// `e`, named by the option that set its key when that option was given: a value from the
/// command line is named by what the user typed, not only by the key it sets.
fn name_option(args: &Args, e: fluidnerf_synth::SynthError) -> anyhow::Error {
    let fluidnerf_synth::SynthError::Invalid { setting, .. } = &e else { return e.into() };
    let options = [
        ("resolution", "--resolution", args.resolution.is_some()),
        ("times", "--times", args.times.is_some()),
        ("phantom.cfd_step", "--cfd-step", args.cfd_step.is_some()),
        ("rig.layout.count", "--cameras", args.cameras.is_some()),
        ("rig.layout.arc_deg", "--arc", args.arc.is_some()),
        ("rig.subset.every", "--every", args.every.is_some()),
        // Only a first count of 0 keeps no camera; otherwise the subset's offset does.
        ("rig.subset", "--first", args.first == Some(0)),
        ("rig.holdout", "--holdout", args.holdout.is_some()),
        ("rig.jitter.position_mm", "--jitter-position", args.jitter_position.is_some()),
        ("rig.jitter.rotation_deg", "--jitter-rotation", args.jitter_rotation.is_some()),
        ("rig.distance_mm", "--distance", args.distance.is_some()),
        ("lens.resolution", "--pixels", args.pixels.is_some()),
        ("lens.magnification", "--magnification", args.magnification.is_some()),
        ("lens.focal_length_mm", "--focal-length", args.focal_length.is_some()),
        ("lens.f_number", "--f-number", args.f_number.is_some()),
        ("lens.pixel_pitch_mm", "--pixel-pitch", args.pixel_pitch.is_some()),
        ("image.supersample", "--supersample", args.supersample.is_some()),
        ("image.rays_per_voxel", "--rays-per-voxel", args.rays_per_voxel.is_some()),
        ("sensor.gaussian_noise", "--noise", args.noise.is_some()),
        ("sensor.full_well", "--full-well", args.full_well.is_some()),
        ("sensor.dark_offset", "--dark-offset", args.dark_offset.is_some()),
        ("sensor.bit_depth", "--bit-depth", args.bit_depth.is_some()),
        ("sensor.full_scale_fraction", "--full-scale-fraction", args.full_scale_fraction.is_some()),
        ("real.gain_spread", "--gain-spread", args.gain_spread.is_some()),
        ("real.background", "--background-level", args.background_level.is_some()),
        ("real.dark_noise", "--dark-noise", args.dark_noise.is_some()),
        ("real.background_frames", "--background-frames", args.background_frames.is_some()),
        ("real.jpeg_quality", "--jpeg-quality", args.jpeg_quality.is_some()),
        ("real.vignetting", "--vignetting", args.vignetting.is_some()),
        ("real.flat_frames", "--flat-frames", args.flat_frames.is_some()),
    ];
    match options.iter().find(|&&(key, _, given)| given && key == setting) {
        Some((_, option, _)) => anyhow::Error::new(e).context(format!("{option} on the command line")),
        // Otherwise the setting is the --config file's.
        None => match &args.config {
            Some(file) => anyhow::Error::new(e).context(format!("the settings of {}", file.display())),
            None => e.into(),
        },
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let text = if args.list_presets {
        let mut text = String::new();
        // The descriptions in one column, past the longest name.
        let width = presets().iter().map(|(name, _)| name.chars().count()).max().unwrap_or(0);
        for (name, what) in presets() {
            let mark = if name == DEFAULT_PRESET { "*" } else { " " };
            let _ = writeln!(text, "{mark} {name:<width$}  {what}");
        }
        text
    } else {
        synthesise(&args)?
    };
    std::io::stdout().lock().write_all(text.as_bytes()).context("cannot write to stdout")
}

/// Writes the scene `args` asks for and returns its summary (what was written, for stdout).
pub(crate) fn synthesise(args: &Args) -> anyhow::Result<String> {
    let Some(out) = args.out.clone() else { bail!("--out is required") };
    let mut settings = resolve(args)?;
    // The frames are made in time order; the recorded times and the summary follow them.
    let reordered = settings.times.windows(2).any(|w| w[0] > w[1]);
    settings.times.sort_by(f64::total_cmp);
    fluidnerf_pipeline::rundir::refuse_other_kind(&out, fluidnerf_pipeline::rundir::FolderKind::Scene, "synth")?;
    super::refuse_unwritable_output(&out)?;
    let scene_file = out.join("transforms.json");
    // Even with --force it could not be written, and would fail as "Is a directory".
    if scene_file.is_dir() {
        bail!("{}: is a folder, where the scene file goes; move it away or write elsewhere", scene_file.display());
    }
    if scene_file.exists() && !args.force {
        bail!("{} already holds a scene; pass --force to overwrite it", out.display());
    }
    // A scene's files (images, truth, previews) would replace whatever of the same name is there.
    if !args.force && std::fs::read_dir(&out).is_ok_and(|mut d| d.next().is_some()) {
        bail!(
            "{} is not empty; write the scene into a new or empty folder, or pass --force to write into it (the \
             scene's files replace any of the same names)",
            out.display()
        );
    }
    if let Some(path) = &settings.phantom.volume_path {
        fluidnerf_pipeline::synthetic::refuse_truth_among_outputs(path, &out, "--truth-volume")?;
    }
    let volume = match &settings.phantom.volume_path {
        Some(path) if settings.phantom.kind == PhantomKind::Volume => {
            Some(fluidnerf_pipeline::synthetic::read_truth_volume(path, settings.aabb, fluidnerf_synth::UNITS)?)
        }
        _ => None,
    };
    // A calibrated TIFF stack, like a .vti, holds its own box.
    if let (Some(v), Some(path), Some(_)) = (&volume, &settings.phantom.volume_path, &args.aabb) {
        if v.aabb != settings.aabb {
            bail!(
                "--aabb: the truth volume {} is a TIFF stack calibrated with its own box ({:?} .. {:?}); leave --aabb \
                 out, or give the volume as a .npy, which fills the box given",
                path.display(),
                v.aabb.min.to_array(),
                v.aabb.max.to_array()
            );
        }
    }
    crate::interrupt::install();
    let started = std::time::Instant::now();
    let total = settings.time_steps().len() * (1 + settings.rig.count());
    let bar = crate::progress::bar(total as u64, "synth");
    let syn = generate(&settings, volume, |p| {
        bar.set_position(p.done as u64);
        bar.set_message(p.stage);
        if crate::interrupt::requested() {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    })
    .map_err(|e| name_option(args, e))?;
    bar.finish_and_clear();
    let elapsed = started.elapsed().as_secs_f64();

    // A folder that held nothing before gets nothing of an unfinished scene: its partial files
    // made the same command fail (a folder not empty) until given --force.
    let was_empty = std::fs::read_dir(&out).map_or(true, |mut d| d.next().is_none());
    let existed = out.exists();
    let clear = |e: anyhow::Error| -> anyhow::Error {
        if !was_empty {
            return e;
        }
        let removed = if existed {
            std::fs::read_dir(&out).into_iter().flatten().flatten().try_for_each(|entry| {
                let p = entry.path();
                if p.is_dir() && !p.is_symlink() {
                    std::fs::remove_dir_all(&p)
                } else {
                    std::fs::remove_file(&p)
                }
            })
        } else {
            std::fs::remove_dir_all(&out)
        };
        match removed {
            Ok(()) => e.context(format!("nothing of the scene was left in {}", out.display())),
            Err(_) => e,
        }
    };
    super::create_output_folder(&out)?;
    fluidnerf_pipeline::synthetic::write_synthesis(&syn, &out)
        .with_context(|| format!("cannot write the scene into {}", out.display()))
        .map_err(clear)?;
    // The scene's own records follow its files. When they cannot be written (a full disk), the
    // scene file goes again: a folder synth failed to finish must not load as a scene.
    let preset = if args.config.is_some() { None } else { Some(args.preset.as_str()) };
    if let Err(e) = fluidnerf_pipeline::synthetic::write_records(&syn, &out, preset, elapsed) {
        let e = anyhow::Error::from(e);
        if was_empty {
            return Err(clear(e));
        }
        let scene_file = out.join(fluidnerf_io::scene::SCENE_FILE);
        let _ = std::fs::remove_file(&scene_file);
        return Err(e.context(format!(
            "the scene in {} is unfinished, and its {} was removed",
            out.display(),
            fluidnerf_io::scene::SCENE_FILE
        )));
    }

    let [w, h] = settings.lens.resolution;
    let dims = syn.truth[0].1.dims;
    let held = syn.cameras.iter().filter(|c| c.holdout).count();
    let mut text = String::new();
    let _ = writeln!(text, "wrote {}", out.display());
    let _ = writeln!(
        text,
        "  phantom   {:?}, truth {}×{}×{} voxels of {:.4} mm{}",
        settings.phantom.kind,
        dims[0],
        dims[1],
        dims[2],
        syn.truth[0].1.spacing().x,
        match syn.truth.len() {
            1 if syn.truth[0].0.is_none() && settings.phantom.kind.cfd_case().is_some() => format!(
                ", solver step {}",
                settings.phantom.cfd_step.unwrap_or(fluidnerf_synth::phantom::cfd::DEFAULT_STEP)
            ),
            1 if syn.truth[0].0.is_none() => String::new(),
            n if settings.phantom.kind.cfd_case().is_some() => format!(", {n} solver steps {:?}", settings.times),
            n => format!(", {n} times t* = {:?}", settings.times),
        } + if reordered { " (sorted into time order)" } else { "" }
    );
    let _ = writeln!(
        text,
        "  cameras   {} ({} held out), {w}×{h} px, field of view {:.1} mm, {} model",
        syn.cameras.len(),
        held,
        settings.lens.field_of_view_mm()[0],
        settings.image.name()
    );
    if let Some(r) = &syn.real {
        let _ = writeln!(
            text,
            "  real-like gains {} (training mean 1), {} background frame(s){} per camera, 8-bit sRGB JPEG",
            r.gains.iter().map(|g| format!("{g:.3}")).collect::<Vec<_>>().join(", "),
            r.backgrounds.first().map_or(0, Vec::len),
            match r.flats.first().map_or(0, Vec::len) {
                0 => String::new(),
                n => format!(
                    " and {n} flat-field frame(s) (vignetting {})",
                    fluidnerf_core::num(settings.real.as_ref().map_or(0.0, |r| r.vignetting))
                ),
            }
        );
    }
    let kind = match &syn.real {
        Some(r) => format!("8-bit sRGB JPEG (quality {}), before the gains:", r.jpeg_quality),
        // The counts are stored unscaled, so a sensor of fewer bits still writes 16-bit PNGs.
        None if settings.sensor.bit_depth == 16 => "16-bit PNG,".to_string(),
        None => format!("16-bit PNG of {}-bit counts,", settings.sensor.bit_depth),
    };
    let _ = writeln!(
        text,
        "  images    {} × {kind} intensity_scale {:.6e} counts per mm, noise σ {} of max{}",
        syn.frames.len(),
        syn.intensity_scale,
        settings.sensor.gaussian_noise,
        settings.sensor.full_well.map(|fw| format!(", photon noise at {fw} e⁻ full well")).unwrap_or_default()
    );
    let _ = writeln!(
        text,
        "  work      {:.3e} rays in {:.1} s (truth {:.1} s, images {:.1} s, sensor {:.1} s)",
        syn.stats.rays as f64, elapsed, syn.stats.truth_seconds, syn.stats.image_seconds, syn.stats.sensor_seconds
    );
    // A real-like recording's background frames and flat-field frames have folders of their own.
    let recorded = |folder: &str, any: bool| if any { format!("{folder}/, ") } else { String::new() };
    let _ = writeln!(
        text,
        "  files     transforms.json, images/, {}{}truth/, preview.png, synth.json",
        recorded("background", syn.real.as_ref().is_some_and(|r| r.backgrounds.iter().any(|b| !b.is_empty()))),
        recorded("flat", syn.real.as_ref().is_some_and(|r| r.flats.iter().any(|f| !f.is_empty())))
    );
    Ok(text)
}

#[cfg(test)]
mod tests {
    /// `--list-presets` refuses every other option of the command, those added later too: each
    /// is in [`super::SYNTHESIS_OPTIONS`], which names nothing else.
    #[test]
    fn list_presets_conflicts_with_every_other_option() {
        let cmd = <super::Args as clap::Args>::augment_args(clap::Command::new("synth"));
        let mut options: Vec<&str> =
            cmd.get_arguments().map(|a| a.get_id().as_str()).filter(|&id| id != "list_presets").collect();
        let mut listed = super::SYNTHESIS_OPTIONS.to_vec();
        options.sort_unstable();
        listed.sort_unstable();
        assert_eq!(options, listed);
    }
}
