//! Damaged weights, checkpoints and model descriptions are refused with an error naming the
//! file, never a panic or an allocation the file could not fill: each reader gets a valid small
//! file cut short at many lengths, with its header's length and offsets set to stressing values,
//! and with each number of its JSON replaced by 0, -1 and huge ones.

use std::path::Path;

use fluidnerf_core::Aabb;
use fluidnerf_neural::dense::DenseGridField;
use fluidnerf_neural::train::{FieldMeta, Learner};
use fluidnerf_neural::trained::{DenseConfig, FieldConfig, ModelRecord};
use fluidnerf_neural::weights::{checkpoint_bytes, checkpoint_tag, load_checkpoint, load_weights, weights_bytes};
use glam::DVec3;

/// Writes `bytes` to a new file at `path`: overwriting one in place may make the file system
/// flush it to disk, thousands of times slower.
fn put(path: &Path, bytes: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, bytes).expect("writes");
}

/// Copies of the text `seed` with each of its numbers replaced by 0, -1 and huge values.
fn renumbered(seed: &[u8]) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < seed.len() {
        if seed[i].is_ascii_digit() {
            let start = i;
            while i < seed.len() && (seed[i].is_ascii_digit() || seed[i] == b'.') {
                i += 1;
            }
            for r in [&b"0"[..], b"-1", b"4294967295", b"18446744073709551615", b"99999999999999999999999", b"1e308"] {
                out.push([&seed[..start], r, &seed[i..]].concat());
            }
        } else {
            i += 1;
        }
    }
    out
}

/// Cuts of `seed` at every length of its header and a spread of the rest, copies with its
/// 8-byte header length set to stressing values, and copies with each number of its JSON
/// header replaced.
fn damaged(seed: &[u8]) -> Vec<Vec<u8>> {
    let header = 8 + u64::from_le_bytes(seed[..8].try_into().expect("8 bytes")) as usize;
    let mut out: Vec<Vec<u8>> =
        (0..header).chain((header..seed.len()).step_by(7)).map(|n| seed[..n].to_vec()).collect();
    for len in [0, 1, 2, header as u64 - 9, header as u64 - 7, seed.len() as u64, 1 << 40, u64::MAX] {
        let mut v = seed.to_vec();
        v[..8].copy_from_slice(&len.to_le_bytes());
        out.push(v);
    }
    let (head, rest) = seed.split_at(header);
    out.extend(
        renumbered(&head[8..]).into_iter().map(|json| [&(json.len() as u64).to_le_bytes()[..], &json, rest].concat()),
    );
    out
}

fn field() -> DenseGridField {
    DenseGridField::from_raw([3, 3, 3], (0..27).map(|i| i as f32 * 0.1).collect())
}

#[test]
fn damaged_weights_and_checkpoints_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("weights.safetensors");
    for seed in [weights_bytes(&field()).expect("bytes"), checkpoint_bytes(&Learner::new(field())).expect("bytes")] {
        for v in damaged(&seed) {
            put(&p, &v);
            let _ = load_weights(&p, &mut field());
            let _ = load_checkpoint(&p, &mut Learner::new(field()));
            let _ = checkpoint_tag(&p, "x");
        }
    }
}

#[test]
fn damaged_model_descriptions_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let record = ModelRecord {
        field: FieldConfig::Dense(DenseConfig { resolution: 3, initial: 0.1 }),
        input_dim: 3,
        meta: FieldMeta { aabb, value_scale: 2.5, time_step: 1.0, occupancy: None },
    };
    put(&dir.path().join("weights.safetensors"), &weights_bytes(&field()).expect("bytes"));
    let json = serde_json::to_vec(&record).expect("json");
    let model = dir.path().join("model.json");
    for v in renumbered(&json) {
        put(&model, &v);
        let _ = fluidnerf_neural::trained::load_trained(dir.path());
    }
}

/// A description edited or damaged to a far larger field than its weights is refused naming
/// both files, before the field is allocated (gigabytes, for the largest of each kind).
#[test]
fn a_description_larger_than_its_weights_is_refused_before_allocating() {
    let dir = tempfile::tempdir().expect("tempdir");
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    put(&dir.path().join("weights.safetensors"), &weights_bytes(&field()).expect("bytes"));
    let mlp = fluidnerf_neural::MlpConfig { depth: 64, width: 4096, ..Default::default() };
    let grid = fluidnerf_neural::HashGridConfig {
        levels: 32,
        features_per_level: 8,
        log2_table_size: 24,
        max_resolution: 1 << 16,
        ..Default::default()
    };
    let dense = DenseConfig { resolution: 1024, initial: 0.1 };
    for field in [FieldConfig::Dense(dense), FieldConfig::Mlp(mlp), FieldConfig::HashGrid(grid)] {
        let meta = FieldMeta { aabb, value_scale: 2.5, time_step: 1.0, occupancy: None };
        put(
            &dir.path().join("model.json"),
            &serde_json::to_vec(&ModelRecord { field, input_dim: 3, meta }).expect("json"),
        );
        let e = fluidnerf_neural::trained::load_trained(dir.path()).err().expect("refused").to_string();
        assert!(e.contains("model.json") && e.contains("weights.safetensors") && e.contains("parameters"), "{e}");
    }
}

/// Counts no run reaches would wrap around when the run resumes (and Adam's bias correction
/// divide by zero): they are refused naming the file.
#[test]
fn a_checkpoint_with_impossible_counts_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("checkpoint.safetensors");
    for (iteration, step) in [(usize::MAX, 10), (10, u64::MAX), (fluidnerf_core::MAX_ITERATIONS + 1, 0)] {
        let mut learner = Learner::new(field());
        (learner.iteration, learner.adam.step) = (iteration, step);
        put(&p, &checkpoint_bytes(&learner).expect("bytes"));
        let e = load_checkpoint(&p, &mut Learner::new(field())).expect_err("refused").to_string();
        assert!(e.contains("checkpoint.safetensors") && e.contains("at most"), "{e}");
    }
}
