//! Scoring a reconstruction on the frames a scene holds out: the one measure of accuracy that
//! needs no ground truth, and the same for every method. `fluidnerf eval`, `fluidnerf study`
//! and the Python API's `Run.score_held_out` score through [`score_held_out`], a run folder
//! after [`check_run_on_scene`] and, through its volumes, each at its own instant
//! ([`volume_at`]).

use std::path::Path;

use fluidnerf_core::num;
use fluidnerf_core::{ScalarField, Scene, Volume};
use fluidnerf_metrics::{reproject, ReprojectionMetrics, ReprojectionOptions};

use crate::load::{other_box_note, other_scene_note, sample_time, LoadedRun};
use crate::{PipelineError, RunKind, RunReport};

/// Checks the run `run` before it is scored on `scene` at `scored`: the scene's entries it is
/// scored at, each with its time and what it is in words (`"the scene's truth volume
/// truth/truth_t02.npy"`, `"the scene's held-out frame images/cam004_t02.png"`). `use_volume`: through the volumes it wrote, not
/// its trained field (a voxel run is scored through its volume anyway).
///
/// Warns through `warn`, and goes on, when the run was made from another scene than `scene` or
/// fills another box (it is zero outside its own). Refuses a time-resolved run an entry without
/// a time (there is no telling which of its instants stands for it), or at a time its field
/// does not stand for ([`sample_time`]: outside its instants, or after the last instant a
/// stopped run trained, which no field or volume of it holds). Through its volumes, a run that
/// reached every instant is checked by [`volume_at`] instead: a volume held out at an end of
/// the recording stands for its own time. Warns of entries at held-out instants outside the
/// trained ones, where the field repeats its nearest trained instant
/// ([`crate::load::TimeSpan::held_note`]).
pub fn check_run_on_scene(
    run: &LoadedRun,
    scene: &Scene,
    use_volume: bool,
    scored: impl IntoIterator<Item = (Option<f64>, String)>,
    mut warn: impl FnMut(&str),
) -> Result<(), PipelineError> {
    let dir = &run.dir;
    if let Some(config) = &run.config {
        if let Some(note) = other_scene_note(dir, &config.scene, &scene.root, "scored against this one") {
            warn(&note);
        }
    }
    let what = format!("the run in {}", dir.display());
    if let Some(note) = other_box_note(&what, &run.aabb, scene, "it is zero outside it") {
        warn(&note);
    }
    let use_volume = use_volume || run.kind == RunKind::Volume;
    let Some(span) = run.time_span()?.filter(|s| !use_volume || !s.not_reached.is_empty()) else {
        return Ok(());
    };
    let mut times = Vec::new();
    for (time, what) in scored {
        let Some(t) = time else {
            return Err(PipelineError::RunDir {
                path: dir.clone(),
                why: format!(
                    "{what} has no time, but the run is time-resolved (instants {} … {}), and such a \
                     run is scored at each entry's time; give the entry its instant's `time`, or export an instant \
                     with `export --time` and score that volume",
                    num(span.first),
                    num(span.last)
                ),
            });
        };
        sample_time(Some(&span), Some(t), &format!("{}: {what}", dir.display()))?;
        times.push(t);
    }
    if let Some(note) = span.held_note(times) {
        warn(&format!("{}: {note}", dir.display()));
    }
    Ok(())
}

/// The volume of `volumes` (the run in `dir`'s, each with its time) that stands for `what`
/// (the scene's entry, in words, as for [`check_run_on_scene`]) at `time`: a static run's volume, or the time-resolved run's
/// volume of that very instant. Refused, naming the time, when the run wrote none there (the
/// volume of another instant would be scored in its place), or when `what` has no time.
pub fn volume_at<'v>(
    dir: &Path,
    volumes: &'v [(Option<f64>, Volume)],
    time: Option<f64>,
    what: &str,
) -> Result<&'v Volume, PipelineError> {
    let refuse = |why: String| PipelineError::RunDir { path: dir.to_path_buf(), why };
    if volumes.iter().all(|(t, _)| t.is_none()) {
        return volumes.first().map(|(_, v)| v).ok_or_else(|| refuse("holds no volume to score".into()));
    }
    let written = || volumes.iter().filter_map(|(t, _)| t.map(|t| num(t).to_string())).collect::<Vec<_>>().join(", ");
    let Some(t) = time else {
        return Err(refuse(format!(
            "{what} has no time, but the run's volumes are each of one instant ({}); give it its instant's `time`",
            written()
        )));
    };
    match volumes.iter().find(|(v, _)| v.is_some_and(|v| fluidnerf_core::scene::same_time(v, t))) {
        Some((_, volume)) => Ok(volume),
        None => Err(refuse(format!(
            "the run wrote no volume at t = {}, the time of {what} (it wrote them at t = {}); score its trained \
             field instead (leave out --use-volume; `use_volume=False` from Python)",
            num(t),
            written()
        ))),
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(value: f32) -> Volume {
        let aabb = fluidnerf_core::Aabb::cube(fluidnerf_core::glam::DVec3::ZERO, 1.0);
        Volume::from_vec([1, 1, 1], aabb, vec![value])
    }

    /// A held-out frame was scored against the volume nearest its time: another instant's
    /// where the run wrote none at its own, and the volume nearest t = 0 for a frame without a
    /// time. Only the volume of the frame's own instant stands for it.
    #[test]
    fn a_frame_is_scored_against_the_volume_of_its_own_instant_only() {
        let dir = Path::new("run");
        let what = "the scene's held-out frame images/cam004_t01.png";
        let series = [(Some(14.0), volume(1.0)), (Some(14.5), volume(2.0))];
        let at = |t: Option<f64>| volume_at(dir, &series, t, what).map(|v| v.data[0]);
        assert_eq!(at(Some(14.5)).expect("its own instant"), 2.0);
        assert_eq!(at(Some(14.5 + 1e-12)).expect("the same instant, as its text rounds it"), 2.0);
        let e = at(Some(14.25)).expect_err("no volume there").to_string();
        assert_eq!(
            e,
            "run: the run wrote no volume at t = 14.25, the time of the scene's held-out frame \
             images/cam004_t01.png (it wrote them at t = 14, 14.5); score its trained field instead (leave out \
             --use-volume; `use_volume=False` from Python)"
        );
        let e = at(None).expect_err("no time").to_string();
        assert!(
            e.starts_with(&format!("run: {what} has no time, but the run's volumes are each of one instant")),
            "{e}"
        );
        // A static run's one volume stands for every time.
        let only = [(None, volume(3.0))];
        for t in [None, Some(14.25)] {
            assert_eq!(volume_at(dir, &only, t, what).expect("static").data[0], 3.0);
        }
        assert!(volume_at(dir, &[], None, what).is_err(), "no volume at all");
    }
}
