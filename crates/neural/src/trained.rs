//! Trained fields in world coordinates, and the named configurations of a reconstruction.
//!
//! A run directory written by `fluidnerf reconstruct --method fluidnerf|fast` holds
//! - `model.json`: [`ModelRecord`] — the field's configuration, its input dimension and its
//!   [`FieldMeta`] (box, value scale, time scale, empty-space mask);
//! - `weights.safetensors`: the parameters, one tensor per [`TrainableField::tensors`] entry.
//!
//! [`load_trained`] turns such a directory into a thread-safe [`ScalarField`] that can be
//! sampled at any resolution ([`fluidnerf_core::Volume::from_field`]) or rendered
//! ([`fluidnerf_core::render_image`]).

use std::path::Path;

use fluidnerf_core::{Aabb, ScalarField};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::dense::DenseGridField;
use crate::hashgrid::{HashGridConfig, HashGridField, MlpPrecision};
use crate::mlp::{Activation, MlpConfig, MlpField};
use crate::occupancy::{OccupancyConfig, OccupancyGrid};
use crate::train::{FieldMeta, Supersample, TrainConfig};
use crate::{NeuralError, TrainableField};

/// Rows per batch handed to the field when sampling in world coordinates.
const EVAL_CHUNK: usize = 1024;

/// The finest dense field a run may ask for, in cells along the box's longest side: 1024³
/// cells take 4 GiB, and four times that with the optimiser's state.
pub const MAX_DENSE_RESOLUTION: usize = 1024;

/// Settings of the dense voxel-grid field ([`DenseGridField`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseConfig {
    /// Cells along the longest box side. Default 64.
    pub resolution: usize,
    /// Initial value of every cell (field units, see [`FieldMeta::value_scale`]). Default 0.05.
    #[serde(deserialize_with = "fluidnerf_core::number::f32_setting")]
    pub initial: f32,
}

impl DenseConfig {
    /// Rejects settings no grid can use; the error names the key under `dense`.
    pub fn validate(&self) -> Result<(), NeuralError> {
        if !(1..=MAX_DENSE_RESOLUTION).contains(&self.resolution) {
            return Err(NeuralError::invalid(
                "dense.resolution",
                format!("must be 1 to {MAX_DENSE_RESOLUTION} cells, got {}", self.resolution),
            ));
        }
        if !(self.initial > 0.0 && self.initial.is_finite()) {
            return Err(NeuralError::invalid(
                "dense.initial",
                format!("must be a positive value, got {}", fluidnerf_core::num(self.initial)),
            ));
        }
        Ok(())
    }
}

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig { resolution: 64, initial: 0.05 }
    }
}

/// Which representation is trained.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub enum FieldConfig {
    /// Positional encoding + MLP (the dissertation's field).
    Mlp(MlpConfig),
    /// A multiresolution hash-grid encoding with a tiny MLP (instant-ngp).
    HashGrid(HashGridConfig),
    /// A trilinear voxel grid trained through the renderer.
    Dense(DenseConfig),
}

impl Default for FieldConfig {
    fn default() -> Self {
        FieldConfig::Mlp(MlpConfig::default())
    }
}

/// Everything a neural reconstruction is configured by: a named preset, then overrides.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NeuralConfig {
    pub field: FieldConfig,
    pub train: TrainConfig,
}

impl Default for NeuralConfig {
    fn default() -> Self {
        NeuralConfig::preset("faithful").unwrap_or_else(|| unreachable!())
    }
}

/// Total-variation weight of the `voxel` preset, chosen on the procedural jet (docs/claims.md).
pub const VOXEL_TV: f32 = 1e-4;

/// Names accepted by [`NeuralConfig::preset`].
pub const PRESETS: [&str; 6] = ["faithful", "ch7", "experimental", "fast", "dense", "voxel"];

impl NeuralConfig {
    /// A named configuration:
    /// - `faithful`: Table 5.1 — D 8, H 256, L 8, ReLU, N_c = N_f = 128, 1024 px/img, Adam
    ///   5e-4 → 5e-5 over 25 000 iterations, the §5.1.5 stopping rule;
    /// - `ch7`: as `faithful` with the chapter-7 optimum N_c = N_f = 64;
    /// - `experimental`: Table 8.3 — D 8, H 256, L 2, Swish, N_c = N_f = 64;
    /// - `fast`: the multiresolution hash-grid field (8 levels 16–128, 2¹⁶ entries, 2 features)
    ///   with a 2 × 64 MLP, empty-space skipping, 48 stratified samples per ray (no coarse
    ///   pass), 256 px/img, lr 2e-2 → 2e-3 over 2000 iterations (tuned on the 15-camera jet);
    /// - `dense`: a 64³ voxel grid trained through the renderer, with empty-space skipping;
    /// - `voxel`: the voxel baseline: `dense` with a total-variation prior
    ///   ([`crate::Prior`], weight [`VOXEL_TV`]).
    pub fn preset(name: &str) -> Option<Self> {
        let faithful = NeuralConfig { field: FieldConfig::Mlp(MlpConfig::table_5_1()), train: TrainConfig::default() };
        match name {
            "faithful" => Some(faithful),
            "ch7" => Some(NeuralConfig {
                train: TrainConfig { coarse_samples: 64, fine_samples: 64, ..faithful.train },
                ..faithful
            }),
            "experimental" => Some(NeuralConfig {
                field: FieldConfig::Mlp(MlpConfig {
                    space_freqs: 2,
                    activation: Activation::Swish,
                    ..MlpConfig::table_5_1()
                }),
                train: TrainConfig { coarse_samples: 64, fine_samples: 64, ..faithful.train },
            }),
            "fast" => Some(NeuralConfig {
                field: FieldConfig::HashGrid(HashGridConfig {
                    levels: 8,
                    log2_table_size: 16,
                    max_resolution: 128,
                    // bfloat16 products where the CPU has them (docs/training-engine.md,
                    // "The decoder's products in bfloat16").
                    mlp_precision: MlpPrecision::Bf16,
                    ..HashGridConfig::default()
                }),
                train: TrainConfig {
                    coarse_samples: 48,
                    fine_samples: 0,
                    rays_per_image: 256,
                    schedule: crate::optim::LrSchedule { initial: 2e-2, at_decay_iters: 2e-3, decay_iters: 2000 },
                    max_iterations: 2000,
                    stop: crate::train::StopRule { smoothing: 50, window: 300, tolerance: 0.01 },
                    occupancy: Some(OccupancyConfig::default()),
                    // Small enough that a chunk's activations stay in a core's L2 cache: 2048
                    // trained the demo scene 1.2–1.3× faster than 8192 at the same accuracy
                    // (docs/training-engine.md, "Chunks that fit the cache").
                    chunk_samples: 2048,
                    // Rays over each drawn pixel's area on clean images (docs/claims.md,
                    // "Rays over the pixel's area").
                    pixel_supersample: Supersample::Auto,
                    ..faithful.train
                },
            }),
            "dense" => Some(NeuralConfig {
                field: FieldConfig::Dense(DenseConfig::default()),
                train: TrainConfig {
                    coarse_samples: 96,
                    fine_samples: 0,
                    rays_per_image: 1024,
                    schedule: crate::optim::LrSchedule { initial: 2e-2, at_decay_iters: 2e-3, decay_iters: 2000 },
                    max_iterations: 2000,
                    stop: crate::train::StopRule { smoothing: 50, window: 300, tolerance: 0.01 },
                    occupancy: Some(OccupancyConfig::default()),
                    chunk_samples: 8192,
                    ..faithful.train
                },
            }),
            "voxel" => {
                let mut c = NeuralConfig::preset("dense")?;
                c.train.prior = crate::Prior { tv: VOXEL_TV, ..crate::Prior::default() };
                Some(c)
            }
            _ => None,
        }
    }
}

/// What `model.json` holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelRecord {
    pub field: FieldConfig,
    /// 3 for E(x), 4 for E(x, t).
    pub input_dim: usize,
    pub meta: FieldMeta,
}

/// How far outside the unit box (relative to its size) a point still counts as on its face.
const FACE_TOLERANCE: f32 = 1e-5;

/// A trained field seen in world coordinates and physical units (borrowing the field).
#[derive(Debug)]
pub struct WorldField<'a, F> {
    pub field: &'a F,
    pub meta: &'a FieldMeta,
    pub occupancy: Option<&'a OccupancyGrid>,
}

impl<F: TrainableField> ScalarField for WorldField<'_, F> {
    fn support(&self) -> Option<fluidnerf_core::Support<'_>> {
        self.occupancy.map(|g| g.support(self.meta.aabb))
    }

    fn detail_dims(&self) -> Option<[usize; 3]> {
        self.field.detail_dims()
    }

    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.eval_masked(points, time, out, true);
    }

    /// The network's values in the empty cells too (inside the box; zero outside it).
    fn eval_unmasked(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.eval_masked(points, time, out, false);
    }
}

impl<F: TrainableField> WorldField<'_, F> {
    /// [`ScalarField::eval`], with the occupancy mask applied when `masked`.
    fn eval_masked(&self, points: &[Vec3], time: f64, out: &mut [f32], masked: bool) {
        assert_eq!(points.len(), out.len(), "WorldField::eval: points and out differ in length");
        let dim = self.field.input_dim();
        let min = self.meta.aabb.min.as_vec3();
        let inv = (1.0 / self.meta.aabb.size()).as_vec3();
        let t = (time / self.meta.time_step) as f32;
        let scale = self.meta.value_scale as f32;
        let mut tape = self.field.new_tape();
        let mut inputs = Vec::with_capacity(EVAL_CHUNK * dim);
        let mut rows = Vec::with_capacity(EVAL_CHUNK);
        let mut vals = vec![0.0f32; EVAL_CHUNK];
        for (pts, outs) in points.chunks(EVAL_CHUNK).zip(out.chunks_mut(EVAL_CHUNK)) {
            inputs.clear();
            rows.clear();
            outs.fill(0.0);
            for (i, p) in pts.iter().enumerate() {
                let u = (*p - min) * inv;
                // Points on the box's faces count as inside despite rounding (a grid of the
                // box's vertices computes them from another origin).
                if !(u.cmpge(Vec3::splat(-FACE_TOLERANCE)) & u.cmple(Vec3::splat(1.0 + FACE_TOLERANCE))).all() {
                    continue;
                }
                let u = u.clamp(Vec3::ZERO, Vec3::ONE);
                let u = [u.x, u.y, u.z];
                if masked && self.occupancy.is_some_and(|g| !g.is_occupied(u)) {
                    continue;
                }
                inputs.extend_from_slice(&u);
                if dim == 4 {
                    inputs.push(t);
                }
                rows.push(i);
            }
            if rows.is_empty() {
                continue;
            }
            self.field.eval(&inputs, &mut vals[..rows.len()], &mut tape);
            for (&i, &v) in rows.iter().zip(&vals) {
                outs[i] = v * scale;
            }
        }
    }
}

/// An owned trained field in world coordinates (what [`load_trained`] returns).
#[derive(Debug)]
pub struct TrainedField<F> {
    pub field: F,
    pub meta: FieldMeta,
    pub occupancy: Option<OccupancyGrid>,
}

impl<F: TrainableField> TrainedField<F> {
    /// Wraps `field`, decoding the mask stored in `meta`.
    pub fn new(field: F, meta: FieldMeta) -> Result<Self, NeuralError> {
        let occupancy = match &meta.occupancy {
            Some(rec) => {
                Some(OccupancyGrid::from_record(rec).map_err(|why| NeuralError::invalid("meta.occupancy", why))?)
            }
            None => None,
        };
        Ok(TrainedField { field, meta, occupancy })
    }

    pub fn view(&self) -> WorldField<'_, F> {
        WorldField { field: &self.field, meta: &self.meta, occupancy: self.occupancy.as_ref() }
    }
}

impl<F: TrainableField> ScalarField for TrainedField<F> {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.view().eval(points, time, out);
    }

    fn eval_unmasked(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        self.view().eval_unmasked(points, time, out);
    }

    fn support(&self) -> Option<fluidnerf_core::Support<'_>> {
        self.occupancy.as_ref().map(|g| g.support(self.meta.aabb))
    }

    fn detail_dims(&self) -> Option<[usize; 3]> {
        self.field.detail_dims()
    }
}

/// Builds the (untrained) field `config` describes, for `input_dim` inputs, seeded.
pub fn build_field(config: &FieldConfig, aabb: &Aabb, input_dim: usize, seed: u64) -> Result<AnyField, NeuralError> {
    make_field(config, aabb, input_dim, Some(seed), usize::MAX)
}

/// The field `config` describes without drawing its initial values, for the weights in the
/// file `weights` that [`crate::weights::load_weights`] will then set, every one of them (it
/// refuses a file that lacks a tensor). A field of more `f32` parameters than the file can
/// hold is refused before it is allocated: a damaged or edited description could otherwise
/// claim gigabytes.
pub fn build_field_for_weights(
    config: &FieldConfig,
    aabb: &Aabb,
    input_dim: usize,
    weights: &Path,
) -> Result<AnyField, NeuralError> {
    let meta = std::fs::metadata(weights).map_err(|error| NeuralError::Io { path: weights.to_path_buf(), error })?;
    if meta.is_dir() {
        return Err(NeuralError::checkpoint(weights, "is a folder, not a safetensors file of weights"));
    }
    let len = meta.len();
    let room = usize::try_from(len / 4).unwrap_or(usize::MAX);
    make_field(config, aabb, input_dim, None, room).map_err(|e| match e {
        NeuralError::Invalid { what, why } if what == TOO_LARGE => {
            NeuralError::invalid(what, format!("{why}, more than {} holds ({len} bytes)", weights.display()))
        }
        e => e,
    })
}

/// What [`check_param_count`] calls a field too large for its weights.
const TOO_LARGE: &str = "field size";

/// Refuses a field of `count` parameters where at most `max` fit, before they are allocated.
pub(crate) fn check_param_count(count: usize, max: usize) -> Result<(), NeuralError> {
    if count > max {
        return Err(NeuralError::invalid(
            TOO_LARGE,
            format!("the field described has {count} parameters ({} bytes as f32)", count.saturating_mul(4)),
        ));
    }
    Ok(())
}

fn make_field(
    config: &FieldConfig,
    aabb: &Aabb,
    input_dim: usize,
    seed: Option<u64>,
    max_params: usize,
) -> Result<AnyField, NeuralError> {
    match config {
        FieldConfig::Mlp(c) => Ok(AnyField::Mlp(match seed {
            Some(seed) => MlpField::new(c, input_dim, seed)?,
            None => MlpField::zeroed(c, input_dim, max_params)?,
        })),
        FieldConfig::HashGrid(c) => Ok(AnyField::HashGrid(match seed {
            Some(seed) => HashGridField::new(c, input_dim, seed)?,
            None => HashGridField::zeroed(c, input_dim, max_params)?,
        })),
        FieldConfig::Dense(c) => {
            if input_dim != 3 {
                return Err(NeuralError::invalid("dense field", "only E(x) (3 inputs) is supported"));
            }
            c.validate()?;
            let dims = fluidnerf_core::Volume::dims_for(aabb, c.resolution);
            check_param_count(dims.iter().product(), max_params)?;
            Ok(AnyField::Dense(DenseGridField::new(dims, c.initial)))
        }
    }
}

/// One of the field types, chosen at run time from a [`FieldConfig`].
#[derive(Debug)]
pub enum AnyField {
    Mlp(MlpField),
    HashGrid(HashGridField),
    Dense(DenseGridField),
}

/// Calls `$body` with `$f` bound to the concrete field inside an [`AnyField`].
#[macro_export]
macro_rules! with_field {
    ($any:expr, $f:ident => $body:expr) => {
        match $any {
            $crate::trained::AnyField::Mlp($f) => $body,
            $crate::trained::AnyField::HashGrid($f) => $body,
            $crate::trained::AnyField::Dense($f) => $body,
        }
    };
}

/// Reads `run_dir/model.json` and `run_dir/weights.safetensors` and returns the trained
/// field in world coordinates with its box.
pub fn load_trained(run_dir: &Path) -> Result<(Box<dyn ScalarField + Send + Sync>, Aabb), NeuralError> {
    let model_path = run_dir.join("model.json");
    let text =
        std::fs::read_to_string(&model_path).map_err(|error| NeuralError::Io { path: model_path.clone(), error })?;
    let record: ModelRecord = serde_json::from_str(&text)
        .map_err(|e| NeuralError::checkpoint(&model_path, format!("malformed model description: {e}")))?;
    // The description's own problems name it, not the weights.
    let named = |e: NeuralError| NeuralError::checkpoint(&model_path, e.to_string());
    if let Some(why) = record.meta.problem() {
        return Err(NeuralError::checkpoint(&model_path, format!("meta: {why}")));
    }
    let aabb = record.meta.aabb;
    let weights = run_dir.join("weights.safetensors");
    // A problem of the weights file itself names it, not the description.
    let mut field = build_field_for_weights(&record.field, &aabb, record.input_dim, &weights).map_err(|e| match e {
        NeuralError::Checkpoint { .. } => e,
        e => named(e),
    })?;
    with_field!(&mut field, f => crate::weights::load_weights(&weights, f))?;
    let boxed: Box<dyn ScalarField + Send + Sync> = match field {
        AnyField::Mlp(f) => Box::new(TrainedField::new(f, record.meta).map_err(named)?),
        AnyField::HashGrid(f) => Box::new(TrainedField::new(f, record.meta).map_err(named)?),
        AnyField::Dense(f) => Box::new(TrainedField::new(f, record.meta).map_err(named)?),
    };
    Ok((boxed, aabb))
}
