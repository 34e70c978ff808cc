//! Weights and training checkpoints as safetensors (little-endian f32, one tensor per entry of
//! [`TrainableField::tensors`]).
//!
//! - Weights: the field's tensors under their own names: the compact result of a run.
//! - Checkpoint: the same, plus the Adam moments as `adam.m.<name>` / `adam.v.<name>`, with
//!   the Adam step count, iteration, loss histories and training time in the safetensors
//!   metadata (`"learner"`, JSON), so [`crate::train::train`] continues exactly where it
//!   stopped.
//!
//! Functions return bytes / read paths; writing files atomically is the caller's business.

use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::ops::Range;
use std::path::Path;

use rayon::prelude::*;

use safetensors::tensor::{Dtype, Metadata, TensorView};
use safetensors::SafeTensorError;
use serde::{Deserialize, Serialize};

use crate::train::Learner;
use crate::{NeuralError, TrainableField};

fn as_bytes(v: &[f32]) -> &[u8] {
    bytemuck::cast_slice(v)
}

fn serialise(
    tensors: Vec<(String, Vec<usize>, &[f32])>,
    metadata: Option<HashMap<String, String>>,
) -> Result<Vec<u8>, NeuralError> {
    let views = tensors
        .into_iter()
        .map(|(name, shape, data)| {
            TensorView::new(Dtype::F32, shape, as_bytes(data))
                .map(|v| (name, v))
                .map_err(|e| NeuralError::invalid("tensor", e.to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    safetensors::serialize(views, metadata).map_err(|e| NeuralError::invalid("safetensors", e.to_string()))
}

/// The field's parameters as a safetensors file.
pub fn weights_bytes<F: TrainableField>(field: &F) -> Result<Vec<u8>, NeuralError> {
    weights_bytes_tagged(field, &[])
}

/// [`weights_bytes`] with `tags`: strings of the caller's, kept in the file's metadata as
/// `tag.<key>` (read back by [`checkpoint_tag`]), such as which window of a run the weights are.
pub fn weights_bytes_tagged<F: TrainableField>(field: &F, tags: &[(&str, String)]) -> Result<Vec<u8>, NeuralError> {
    let p = field.params();
    let tensors = field.tensors().into_iter().map(|(n, s, r)| (n, s, &p[r])).collect();
    let metadata = (!tags.is_empty()).then(|| tags.iter().map(|(k, v)| (format!("tag.{k}"), v.clone())).collect());
    serialise(tensors, metadata)
}

/// Read in pieces of this many values, over the threads: a field's tables are megabytes, and
/// every command that loads a field waits for them.
const PIECE: usize = 1 << 16;

/// The largest safetensors header read (the format's own limit).
const MAX_HEADER: u64 = 100 << 20;

/// Opens `path` and reads its safetensors header: the file, the header's JSON, and where the
/// tensors' data begins.
fn read_header(path: &Path) -> Result<(File, Vec<u8>, u64), NeuralError> {
    let io = |error: std::io::Error| match error.kind() {
        // read_exact's own message, "failed to fill whole buffer", says nothing of the file.
        std::io::ErrorKind::UnexpectedEof => {
            NeuralError::checkpoint(path, "the file is truncated: it ends inside its safetensors header")
        }
        _ => NeuralError::Io { path: path.to_path_buf(), error },
    };
    let mut file = File::open(path).map_err(io)?;
    let mut len = [0u8; 8];
    file.read_exact(&mut len).map_err(io)?;
    let len = u64::from_le_bytes(len);
    if len > MAX_HEADER {
        return Err(NeuralError::checkpoint(path, format!("a header of {len} bytes is not a safetensors header")));
    }
    let mut header = vec![0u8; len as usize];
    file.read_exact(&mut header).map_err(io)?;
    Ok((file, header, 8 + len))
}

/// A safetensors file whose tensors are read straight into their destination: the header is
/// read and checked against the file's length, and the data is read where it is wanted, with
/// no copy of the whole file in memory (a field's weights are megabytes, and every command
/// that loads a field waits for them).
struct TensorFile<'a> {
    path: &'a Path,
    file: File,
    header: Metadata,
    /// Where the tensors' data begins in the file.
    data_start: u64,
}

impl<'a> TensorFile<'a> {
    fn open(path: &'a Path) -> Result<Self, NeuralError> {
        let (file, header, data_start) = read_header(path)?;
        let header: Metadata = serde_json::from_slice(&header)
            .map_err(|e| damaged(path, SafeTensorError::InvalidHeaderDeserialization(e)))?;
        let len = file.metadata().map_err(|error| NeuralError::Io { path: path.to_path_buf(), error })?.len();
        if data_start + header.data_len() as u64 != len {
            return Err(damaged(path, SafeTensorError::MetadataIncompleteBuffer));
        }
        Ok(Self { path, file, header, data_start })
    }

    /// Where the data of tensor `name` begins, checked to be F32 of `shape`.
    fn locate(&self, name: &str, shape: &[usize]) -> Result<u64, NeuralError> {
        let Some(info) = self.header.info(name) else {
            let e = SafeTensorError::TensorNotFound(name.to_string());
            return Err(NeuralError::checkpoint(self.path, format!("tensor {name}: {e}")));
        };
        if info.dtype != Dtype::F32 || info.shape != shape {
            return Err(NeuralError::checkpoint(
                self.path,
                format!("tensor {name} is {:?} {:?}, the field expects F32 {shape:?}", info.dtype, info.shape),
            ));
        }
        Ok(self.data_start + info.data_offsets.0 as u64)
    }

    /// Reads the tensors `(name, shape, destination)` into their destinations, in pieces over
    /// the threads, and refuses a value that is not finite.
    fn read_into(&self, tensors: Vec<(String, Vec<usize>, &mut [f32])>) -> Result<(), NeuralError> {
        let mut pieces = Vec::new();
        let mut names = Vec::with_capacity(tensors.len());
        for (t, (name, shape, dst)) in tensors.into_iter().enumerate() {
            let mut at = self.locate(&name, &shape)?;
            for piece in dst.chunks_mut(PIECE) {
                let bytes = 4 * piece.len() as u64;
                pieces.push((t, at, piece));
                at += bytes;
            }
            names.push(name);
        }
        // Each piece read, put in the machine's order, and checked for NaN and infinity
        // without an early exit (so that the check vectorises) while it is in cache.
        let read = |(_, at, piece): &mut (usize, u64, &mut [f32])| -> std::io::Result<bool> {
            read_exact_at(&self.file, bytemuck::cast_slice_mut(piece), *at)?;
            if cfg!(target_endian = "big") {
                for d in piece.iter_mut() {
                    *d = f32::from_bits(u32::from_le(d.to_bits()));
                }
            }
            Ok(piece.iter().fold(true, |all, d| all & d.is_finite()))
        };
        let finite: Vec<std::io::Result<bool>> =
            if cfg!(unix) { pieces.par_iter_mut().map(read).collect() } else { pieces.iter_mut().map(read).collect() };
        let mut offsets = vec![0usize; names.len()];
        for ((t, _, piece), finite) in pieces.iter().zip(finite) {
            let io = |error: std::io::Error| match error.kind() {
                // The file was shortened since its length was checked.
                std::io::ErrorKind::UnexpectedEof => damaged(self.path, SafeTensorError::MetadataIncompleteBuffer),
                _ => NeuralError::Io { path: self.path.to_path_buf(), error },
            };
            if !finite.map_err(io)? {
                let i = piece.iter().position(|v| !v.is_finite()).unwrap_or(0);
                return Err(NeuralError::checkpoint(
                    self.path,
                    format!("tensor {}: value {} is {}; weights must be finite", names[*t], offsets[*t] + i, piece[i]),
                ));
            }
            offsets[*t] += piece.len();
        }
        Ok(())
    }
}

/// Fills `buf` from `file` at `offset`.
#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

/// Fills `buf` from `file` at `offset` (the pieces are read one after another here: the
/// file's position is shared).
#[cfg(not(unix))]
fn read_exact_at(mut file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    use std::io::Seek;
    file.seek(std::io::SeekFrom::Start(offset))?;
    file.read_exact(buf)
}

/// A file that safetensors cannot read: truncated (a partial copy) or not a safetensors file.
fn damaged(path: &Path, e: SafeTensorError) -> NeuralError {
    NeuralError::checkpoint(path, format!("the file is truncated or damaged, not a complete safetensors file ({e})"))
}

/// `buf` split into the disjoint `ranges`, in their order.
fn split_ranges<'b>(mut buf: &'b mut [f32], ranges: &[Range<usize>]) -> Vec<&'b mut [f32]> {
    let mut order: Vec<usize> = (0..ranges.len()).collect();
    order.sort_by_key(|&i| ranges[i].start);
    let mut parts: Vec<Option<&'b mut [f32]>> = (0..ranges.len()).map(|_| None).collect();
    let mut at = 0;
    for i in order {
        let r = &ranges[i];
        let rest = std::mem::take(&mut buf);
        let (_, tail) = rest.split_at_mut(r.start - at);
        let (part, tail) = tail.split_at_mut(r.len());
        parts[i] = Some(part);
        buf = tail;
        at = r.end;
    }
    parts.into_iter().map(|p| p.expect("every range split off")).collect()
}

/// Refuses a file holding a tensor that `field` has no place for (nor, for Adam's moments
/// `adam.m.<name>` / `adam.v.<name>`, a tensor of that name): the file is of a larger field. A
/// model.json or config.json edited to fewer layers would otherwise take the first layers of
/// the file's field and drop the rest without a word, and every tensor it kept would match.
fn refuse_unknown_tensors<F: TrainableField>(st: &Metadata, path: &Path, field: &F) -> Result<(), NeuralError> {
    let own: std::collections::HashSet<String> = field.tensors().into_iter().map(|(name, _, _)| name).collect();
    let known = |name: &str| {
        own.contains(name)
            || ["adam.m.", "adam.v."].iter().any(|p| name.strip_prefix(p).is_some_and(|n| own.contains(n)))
    };
    let mut unknown: Vec<String> = st.offset_keys().into_iter().filter(|n| !known(n)).collect();
    if unknown.is_empty() {
        return Ok(());
    }
    unknown.sort();
    let count = unknown.len();
    unknown.truncate(5);
    let more = if count > 5 { format!(" and {} more", count - 5) } else { String::new() };
    Err(NeuralError::checkpoint(
        path,
        format!(
            "holds {count} tensor(s) the field described does not have ({}{more}): the file is of another field \
             (more layers or levels) than its model.json or config.json describes",
            unknown.join(", ")
        ),
    ))
}

/// Loads weights written by [`weights_bytes`] (or a checkpoint) into `field`, which must have
/// the same architecture: a file lacking one of its tensors, or holding one it lacks, is
/// refused.
pub fn load_weights<F: TrainableField>(path: &Path, field: &mut F) -> Result<(), NeuralError> {
    let file = TensorFile::open(path)?;
    refuse_unknown_tensors(&file.header, path, field)?;
    let tensors = field.tensors();
    let ranges: Vec<Range<usize>> = tensors.iter().map(|(_, _, r)| r.clone()).collect();
    let dsts = split_ranges(field.params_mut(), &ranges);
    file.read_into(tensors.into_iter().zip(dsts).map(|((name, shape, _), dst)| (name, shape, dst)).collect())
}

#[derive(Serialize, Deserialize)]
struct LearnerMeta {
    iteration: usize,
    adam_step: u64,
    losses: Vec<f32>,
    holdout_losses: Vec<(usize, f32)>,
    train_time_s: f64,
}

/// A resumable checkpoint of `learner` (weights, Adam moments, histories).
pub fn checkpoint_bytes<F: TrainableField>(learner: &Learner<F>) -> Result<Vec<u8>, NeuralError> {
    checkpoint_bytes_tagged(learner, &[])
}

/// [`checkpoint_bytes`] with `tags`: strings of the caller's, kept in the file's metadata beside
/// the training state, for it to check when it resumes ([`checkpoint_tag`]).
pub fn checkpoint_bytes_tagged<F: TrainableField>(
    learner: &Learner<F>,
    tags: &[(&str, String)],
) -> Result<Vec<u8>, NeuralError> {
    let p = learner.field.params();
    let mut tensors = Vec::new();
    for (n, s, r) in learner.field.tensors() {
        tensors.push((format!("adam.m.{n}"), s.clone(), &learner.adam.m[r.clone()]));
        tensors.push((format!("adam.v.{n}"), s.clone(), &learner.adam.v[r.clone()]));
        tensors.push((n, s, &p[r]));
    }
    let meta = LearnerMeta {
        iteration: learner.iteration,
        adam_step: learner.adam.step,
        losses: learner.losses.clone(),
        holdout_losses: learner.holdout_losses.clone(),
        train_time_s: learner.train_time_s,
    };
    let json = serde_json::to_string(&meta).map_err(|e| NeuralError::invalid("checkpoint", e.to_string()))?;
    let mut metadata = HashMap::from([("learner".to_string(), json)]);
    for (key, value) in tags {
        metadata.insert(format!("tag.{key}"), value.clone());
    }
    serialise(tensors, Some(metadata))
}

/// The tag `key` of the checkpoint or weights file at `path` ([`checkpoint_bytes_tagged`],
/// [`weights_bytes_tagged`]); None when it has none.
/// Reads the file's header only (its first 8 bytes give the length of the JSON that follows).
pub fn checkpoint_tag(path: &Path, key: &str) -> Result<Option<String>, NeuralError> {
    let (_, header, _) = read_header(path)?;
    let header: serde_json::Value =
        serde_json::from_slice(&header).map_err(|e| NeuralError::checkpoint(path, format!("header: {e}")))?;
    Ok(header.get("__metadata__").and_then(|m| m.get(format!("tag.{key}"))).and_then(|v| v.as_str()).map(String::from))
}

/// Restores `learner` (whose field has the checkpoint's architecture) from `path`.
pub fn load_checkpoint<F: TrainableField>(path: &Path, learner: &mut Learner<F>) -> Result<(), NeuralError> {
    let file = TensorFile::open(path)?;
    let json = file
        .header
        .metadata()
        .as_ref()
        .and_then(|m| m.get("learner"))
        .ok_or_else(|| NeuralError::checkpoint(path, "no training state (weights only?)"))?;
    let meta: LearnerMeta =
        serde_json::from_str(json).map_err(|e| NeuralError::checkpoint(path, format!("training state: {e}")))?;
    // No run takes more iterations (nor Adam steps, one per iteration): larger counts would
    // wrap around when the run resumes, Adam's bias correction then dividing by zero.
    let max = fluidnerf_core::MAX_ITERATIONS;
    if meta.iteration > max || meta.adam_step > max as u64 {
        return Err(NeuralError::checkpoint(
            path,
            format!(
                "training state: iteration {} and Adam step {} must each be at most {max}, the most a run takes \
                 (the file is damaged or edited)",
                meta.iteration, meta.adam_step
            ),
        ));
    }
    refuse_unknown_tensors(&file.header, path, &learner.field)?;
    let n = learner.field.num_params();
    learner.adam.m.resize(n, 0.0);
    learner.adam.v.resize(n, 0.0);
    let tensors = learner.field.tensors();
    let ranges: Vec<Range<usize>> = tensors.iter().map(|(_, _, r)| r.clone()).collect();
    let mut wanted = Vec::with_capacity(3 * tensors.len());
    for (prefix, buf) in
        [("", learner.field.params_mut()), ("adam.m.", &mut learner.adam.m[..]), ("adam.v.", &mut learner.adam.v[..])]
    {
        for ((name, shape, _), dst) in tensors.iter().zip(split_ranges(buf, &ranges)) {
            wanted.push((format!("{prefix}{name}"), shape.clone(), dst));
        }
    }
    file.read_into(wanted)?;
    for (name, _, range) in tensors {
        let second = format!("adam.v.{name}");
        let moments = &learner.adam.v[range];
        // Averages of squared gradients: a negative one (a damaged or edited file) makes the
        // step's square root NaN, which training reports as a diverged loss, blaming the rate.
        if let Some(i) = moments.iter().position(|&v| v < 0.0) {
            return Err(NeuralError::checkpoint(
                path,
                format!(
                    "tensor {second}: value {i} is {}; Adam's second moments are averages of squared gradients \
                     and cannot be negative (the file is damaged or edited)",
                    moments[i]
                ),
            ));
        }
    }
    learner.adam.step = meta.adam_step;
    learner.iteration = meta.iteration;
    learner.losses = meta.losses;
    learner.holdout_losses = meta.holdout_losses;
    learner.train_time_s = meta.train_time_s;
    Ok(())
}

#[cfg(test)]
mod tests {
    use fluidnerf_core::Aabb;
    use glam::DVec3;

    use super::*;
    use crate::hashgrid::HashGridConfig;
    use crate::mlp::MlpConfig;
    use crate::trained::{build_field, build_field_for_weights, AnyField, DenseConfig, FieldConfig};

    /// A file of a deeper field than the one it is loaded into is refused, naming the tensors
    /// it has no place for: every tensor of the shallower field matches one of the file's, so
    /// only the file's extra layers tell the two apart. A checkpoint's Adam moments of the
    /// field's own tensors are no such extra.
    #[test]
    fn a_file_of_a_deeper_field_is_refused_naming_the_extra_tensors() {
        let aabb = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        let mlp = MlpConfig { depth: 3, width: 16, space_freqs: 2, skip: false, ..MlpConfig::default() };
        let deep = build_field(&FieldConfig::Mlp(mlp.clone()), &aabb, 3, 11).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let weights = dir.path().join("weights.safetensors");
        std::fs::write(&weights, crate::with_field!(&deep, f => weights_bytes(f)).unwrap()).unwrap();
        let AnyField::Mlp(deep) = deep else { panic!("an MLP") };
        let checkpoint = dir.path().join("checkpoint.safetensors");
        std::fs::write(&checkpoint, checkpoint_bytes(&Learner::new(deep.clone())).unwrap()).unwrap();

        let shallow = FieldConfig::Mlp(MlpConfig { depth: 2, ..mlp });
        let AnyField::Mlp(mut field) = build_field_for_weights(&shallow, &aabb, 3, &weights).unwrap() else { panic!() };
        let e = load_weights(&weights, &mut field).unwrap_err().to_string();
        assert!(e.contains("weights.safetensors") && e.contains("layers.2.bias, layers.2.weight"), "{e}");
        let mut learner = Learner::new(field);
        let e = load_checkpoint(&checkpoint, &mut learner).unwrap_err().to_string();
        assert!(e.contains("checkpoint.safetensors") && e.contains("adam.m.layers.2.bias"), "{e}");

        // The field the files were written from takes them, the checkpoint's moments included.
        let mut same = deep.clone();
        load_weights(&checkpoint, &mut same).unwrap();
        load_checkpoint(&checkpoint, &mut Learner::new(deep)).unwrap();
    }

    /// A checkpoint with a negative Adam second moment is refused naming the tensor: training
    /// would take the square root of it and stop with a NaN loss, reported as divergence.
    #[test]
    fn a_checkpoint_with_a_negative_second_moment_is_refused() {
        let aabb = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        let mlp = FieldConfig::Mlp(MlpConfig { depth: 2, width: 8, space_freqs: 2, ..MlpConfig::default() });
        let AnyField::Mlp(field) = build_field(&mlp, &aabb, 3, 5).unwrap() else { panic!("an MLP") };
        let mut learner = Learner::new(field.clone());
        let (_, _, range) = field.tensors().into_iter().find(|t| t.0 == "output.bias").unwrap();
        learner.adam.v[range.start] = -1.0;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("checkpoint.safetensors");
        std::fs::write(&path, checkpoint_bytes(&learner).unwrap()).unwrap();
        let e = load_checkpoint(&path, &mut Learner::new(field.clone())).unwrap_err().to_string();
        assert!(e.contains("checkpoint.safetensors: tensor adam.v.output.bias: value 0 is -1"), "{e}");
        learner.adam.v[range.start] = 0.0;
        std::fs::write(&path, checkpoint_bytes(&learner).unwrap()).unwrap();
        load_checkpoint(&path, &mut Learner::new(field)).unwrap();
    }

    fn grid(values: impl Fn(usize) -> f32) -> crate::dense::DenseGridField {
        crate::dense::DenseGridField::from_raw([2, 2, 2], (0..8).map(values).collect())
    }

    /// A checkpoint read back restores every part of the training state: weights, both Adam
    /// moments, the step and iteration counts, the loss histories and the time; its tags are
    /// read from the header.
    #[test]
    fn a_checkpoint_restores_the_whole_training_state() {
        let mut learner = Learner::new(grid(|i| i as f32 * 0.25 - 1.0));
        learner.adam.m = (0..8).map(|i| i as f32 * 0.01 - 0.03).collect();
        learner.adam.v = (0..8).map(|i| i as f32 * 1e-4).collect();
        learner.adam.step = 7;
        learner.iteration = 9;
        learner.losses = vec![0.5, 0.25];
        learner.holdout_losses = vec![(4, 0.3)];
        learner.train_time_s = 1.5;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("checkpoint.safetensors");
        std::fs::write(&path, checkpoint_bytes_tagged(&learner, &[("window", "2".to_string())]).unwrap()).unwrap();
        let mut restored = Learner::new(grid(|_| 0.0));
        load_checkpoint(&path, &mut restored).unwrap();
        assert_eq!(restored.field.params(), learner.field.params());
        assert_eq!((&restored.adam.m, &restored.adam.v), (&learner.adam.m, &learner.adam.v));
        assert_eq!((restored.adam.step, restored.iteration), (7, 9));
        assert_eq!((&restored.losses, &restored.holdout_losses), (&learner.losses, &learner.holdout_losses));
        assert_eq!(restored.train_time_s, 1.5);
        assert_eq!(checkpoint_tag(&path, "window").unwrap().as_deref(), Some("2"));
        assert_eq!(checkpoint_tag(&path, "other").unwrap(), None);
    }

    /// Weights read back are the saved ones, with their tags; a file of weights alone is no
    /// checkpoint.
    #[test]
    fn weights_round_trip_with_their_tags() {
        let field = grid(|i| (i as f32 * 0.7).sin());
        let dir = tempfile::tempdir().unwrap();
        let (tagged, plain) = (dir.path().join("tagged.safetensors"), dir.path().join("plain.safetensors"));
        let tags = [("window", "0..4".to_string()), ("frame", "3".to_string())];
        std::fs::write(&tagged, weights_bytes_tagged(&field, &tags).unwrap()).unwrap();
        std::fs::write(&plain, weights_bytes(&field).unwrap()).unwrap();
        for path in [&tagged, &plain] {
            let mut loaded = grid(|_| 0.0);
            load_weights(path, &mut loaded).unwrap();
            assert_eq!(loaded.params(), field.params());
        }
        assert_eq!(checkpoint_tag(&tagged, "window").unwrap().as_deref(), Some("0..4"));
        assert_eq!(checkpoint_tag(&tagged, "frame").unwrap().as_deref(), Some("3"));
        assert_eq!(checkpoint_tag(&plain, "window").unwrap(), None);
        let e = load_checkpoint(&plain, &mut Learner::new(grid(|_| 0.0))).unwrap_err().to_string();
        assert!(e.contains("plain.safetensors") && e.contains("no training state"), "{e}");
    }

    /// A weight that is not finite, a tensor of another shape, a header that is cut short or
    /// claims a length no header has, and a file that is missing are refused naming the file.
    #[test]
    fn bad_weights_files_are_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.safetensors");
        for bad in [f32::NAN, f32::INFINITY] {
            std::fs::write(&path, weights_bytes(&grid(|i| if i == 5 { bad } else { 0.5 })).unwrap()).unwrap();
            let e = load_weights(&path, &mut grid(|_| 0.0)).unwrap_err().to_string();
            assert!(e.contains("w.safetensors") && e.contains("value 5") && e.contains("must be finite"), "{e}");
        }
        std::fs::write(&path, weights_bytes(&grid(|_| 0.5)).unwrap()).unwrap();
        let mut other = crate::dense::DenseGridField::from_raw([3, 2, 2], vec![0.0; 12]);
        let e = load_weights(&path, &mut other).unwrap_err().to_string();
        assert!(e.contains("w.safetensors") && e.contains("the field expects F32"), "{e}");
        std::fs::write(&path, [16u8, 0, 0]).unwrap();
        let e = checkpoint_tag(&path, "x").unwrap_err().to_string();
        assert!(e.contains("w.safetensors") && e.contains("truncated"), "{e}");
        let mut huge = ((100u64 << 20) + 1).to_le_bytes().to_vec();
        huge.extend_from_slice(b"{}");
        std::fs::write(&path, &huge).unwrap();
        let e = checkpoint_tag(&path, "x").unwrap_err().to_string();
        assert!(e.contains("is not a safetensors header"), "{e}");
        let mut small = 2u64.to_le_bytes().to_vec();
        small.extend_from_slice(b"{}");
        std::fs::write(&path, &small).unwrap();
        assert_eq!(checkpoint_tag(&path, "x").unwrap(), None);
        let gone = dir.path().join("gone.safetensors");
        assert!(load_weights(&gone, &mut grid(|_| 0.0)).unwrap_err().to_string().contains("gone.safetensors"));
    }

    /// Weights larger than a piece of the parallel read come back whole, a bad value in a later
    /// piece is named by its index in the tensor, and a file whose length differs from what its
    /// header describes (cut short, or with bytes after its tensors) is refused.
    #[test]
    fn weights_read_in_pieces_come_back_whole_and_checked() {
        let dims = [64, 64, 48];
        let n = dims.iter().product::<usize>();
        assert!(n > 2 * super::PIECE, "the tensor spans several pieces");
        let big = |values: &dyn Fn(usize) -> f32| {
            crate::dense::DenseGridField::from_raw(dims, (0..n).map(values).collect::<Vec<f32>>())
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.safetensors");
        let saved = big(&|i| i as f32 * 0.25 - 7.0);
        let bytes = weights_bytes(&saved).unwrap();
        std::fs::write(&path, &bytes).unwrap();
        let mut loaded = big(&|_| 0.0);
        load_weights(&path, &mut loaded).unwrap();
        assert_eq!(loaded.params(), saved.params());

        let bad = 2 * super::PIECE + 123;
        std::fs::write(&path, weights_bytes(&big(&|i| if i == bad { f32::NAN } else { 1.0 })).unwrap()).unwrap();
        let e = load_weights(&path, &mut big(&|_| 0.0)).unwrap_err().to_string();
        assert!(e.contains(&format!("value {bad} is NaN")), "{e}");

        for wrong in [bytes[..bytes.len() - 4].to_vec(), [bytes.as_slice(), &[0u8; 4]].concat()] {
            std::fs::write(&path, &wrong).unwrap();
            let e = load_weights(&path, &mut big(&|_| 0.0)).unwrap_err().to_string();
            assert!(e.contains("w.safetensors") && e.contains("truncated or damaged"), "{e}");
        }
    }

    /// A field built without its initial draws and then loaded holds exactly the saved
    /// parameters, for every field kind, 3D and 4D: the tensors cover every parameter, so
    /// nothing of the zeroed build survives a load.
    #[test]
    fn weights_loaded_into_an_unset_field_are_the_saved_ones() {
        let aabb = Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        let grid = HashGridConfig { log2_table_size: 12, max_resolution: 64, ..HashGridConfig::default() };
        let mlp = MlpConfig { depth: 2, width: 16, space_freqs: 2, time_freqs: 2, ..MlpConfig::default() };
        let dense = DenseConfig { resolution: 8, initial: 0.3 };
        let cases = [
            (FieldConfig::HashGrid(grid.clone()), 3),
            (FieldConfig::HashGrid(HashGridConfig { static_levels: 2, ..grid }), 4),
            (FieldConfig::Mlp(mlp.clone()), 3),
            (FieldConfig::Mlp(mlp), 4),
            (FieldConfig::Dense(dense), 3),
        ];
        let dir = tempfile::tempdir().unwrap();
        for (k, (config, dim)) in cases.iter().enumerate() {
            let saved = build_field(config, &aabb, *dim, 11).unwrap();
            let path = dir.path().join(format!("w{k}.safetensors"));
            let bytes = crate::with_field!(&saved, f => weights_bytes(f)).unwrap();
            std::fs::write(&path, bytes).unwrap();
            let mut loaded = build_field_for_weights(config, &aabb, *dim, &path).unwrap();
            crate::with_field!(&mut loaded, f => load_weights(&path, f)).unwrap();
            let (a, b) = match (&saved, &loaded) {
                (AnyField::HashGrid(a), AnyField::HashGrid(b)) => (a.params(), b.params()),
                (AnyField::Mlp(a), AnyField::Mlp(b)) => (a.params(), b.params()),
                (AnyField::Dense(a), AnyField::Dense(b)) => (a.params(), b.params()),
                _ => panic!("case {k}: the kinds differ"),
            };
            assert!(a.iter().any(|&v| v != 0.0), "case {k}: the saved field is not all zero");
            assert_eq!(a.len(), b.len(), "case {k}");
            let differ = a.iter().zip(b).filter(|(x, y)| x.to_bits() != y.to_bits()).count();
            assert_eq!(differ, 0, "case {k}: {differ} parameters differ after the load");
        }
    }
}
