//! Scoring a reconstruction on the frames a scene holds out: the one measure of accuracy that
//! needs no ground truth, and the same for every method. `fluidnerf eval`, `fluidnerf study`
//! and the Python API's `Run.score_held_out` score through [`score_held_out`].

use std::path::Path;

use fluidnerf_core::{ScalarField, Scene};
use fluidnerf_metrics::{reproject, ReprojectionMetrics, ReprojectionOptions};

use crate::{PipelineError, RunReport};

/// The gain and offset the run of `report` (read from `path`) recorded for each frame
/// (`preprocessing.frames`), in frame order: `(1, 0)` for frames it recorded none for, and
/// empty for a run that recorded none (a report from before gains were recorded). A gain that
/// is not positive and finite, or an offset that is not finite, is refused, naming the file.
pub fn recorded_gains(report: &RunReport, path: &Path) -> Result<Vec<(f64, f64)>, PipelineError> {
    let Some(pre) = &report.preprocessing else { return Ok(Vec::new()) };
    let mut gains = vec![(1.0, 0.0); pre.frames.iter().map(|f| f.frame + 1).max().unwrap_or(0)];
    for f in &pre.frames {
        if !(f.gain.is_finite() && f.gain > 0.0 && f.offset.is_finite()) {
            return Err(PipelineError::file(
                path,
                format!("frame {} records the gain {} and offset {}", f.frame, f.gain, f.offset),
            ));
        }
        gains[f.frame] = (f.gain, f.offset);
    }
    Ok(gains)
}

/// Scores a reconstruction on every held-out frame of `scene`, in frame order. Each frame's
/// image is taken as a run fits the others (linearised, background subtracted, flat-fielded,
/// its mask applied) and divided by the gain `gains` records for it (after its offset; see
/// [`recorded_gains`]); the reconstruction at the frame's time (`field_at`) is rendered from its
/// camera and compared with it ([`fluidnerf_metrics::reproject`]). `done` is called after each
/// frame (a progress bar). Empty when the scene holds no frame out.
pub fn score_held_out<'f>(
    scene: &Scene,
    gains: &[(f64, f64)],
    field_at: impl Fn(Option<f64>) -> &'f dyn ScalarField,
    options: &ReprojectionOptions,
    mut done: impl FnMut(),
) -> Result<Vec<ReprojectionMetrics>, PipelineError> {
    let held_out: Vec<usize> = scene.holdout_frames().map(|(i, _)| i).collect();
    if held_out.is_empty() {
        return Ok(Vec::new());
    }
    let mut pre = fluidnerf_io::scene::load_preprocessed(scene)?;
    let mut scores = Vec::with_capacity(held_out.len());
    for i in held_out {
        let frame = &scene.frames[i];
        let path = scene.resolve(&frame.file_path);
        let measured = &mut pre.images[i];
        if let Some(&(gain, offset)) = gains.get(i).filter(|&&(g, b)| g != 1.0 || b != 0.0) {
            log::info!("held-out frame {i} ({}): divided by the gain {gain:.4} the run recorded", path.display());
            let (inv, b) = ((1.0 / gain) as f32, offset as f32);
            measured.data.iter_mut().for_each(|v| *v = (*v - b) * inv);
        }
        let r = reproject(field_at(frame.time), scene, i, measured, pre.masks[i].as_deref(), options)
            .map_err(|e| PipelineError::file(&path, format!("reprojecting onto held-out frame {i}: {e}")))?;
        scores.push(r.metrics);
        done();
    }
    Ok(scores)
}
