//! Volume NRMSE against a scene's ground truth during a run, for time-to-accuracy curves: a
//! fixed subset of the truth's voxel centres ([`TruthSample`]) and one point of the curve
//! ([`NrmsePoint`]), the same for neural and classical methods so their curves compare.

use fluidnerf_core::{glam::Vec3, ScalarField, Volume};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// One point of a run's NRMSE curve: after `iteration`, `train_time_s` seconds of the
/// method's own work (evaluations excluded), NRMSE `nrmse` (Eq. 6.18) over a [`TruthSample`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NrmsePoint {
    pub iteration: usize,
    pub train_time_s: f64,
    #[serde(deserialize_with = "crate::report::null_as_nan")]
    pub nrmse: f64,
}

/// Every `stride`-th voxel centre of the truth along each axis (the middle one of each group)
/// and the truth's values there: the whole truth up to [`TruthSample::MAX_SIDE`] voxels per
/// side, so that the curve's NRMSE is the run's reported one at the same iterate, and a
/// regular subset of a larger truth, cheap enough to evaluate every few iterations.
#[derive(Clone, Debug)]
pub struct TruthSample {
    points: Vec<Vec3>,
    values: Vec<f32>,
}

impl TruthSample {
    /// The largest truth, in voxels per side, sampled whole.
    pub const MAX_SIDE: usize = 128;

    pub fn new(truth: &Volume) -> Self {
        let stride = truth.dims.iter().map(|&n| n.div_ceil(Self::MAX_SIDE)).max().unwrap_or(1).max(1);
        let (mut points, mut values) = (Vec::new(), Vec::new());
        let [nx, ny, nz] = truth.dims;
        for k in (stride / 2..nz).step_by(stride) {
            for j in (stride / 2..ny).step_by(stride) {
                for i in (stride / 2..nx).step_by(stride) {
                    points.push(truth.voxel_centre(i, j, k).as_vec3());
                    values.push(truth.get(i, j, k));
                }
            }
        }
        TruthSample { points, values }
    }

    /// Points in the sample.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// NRMSE of `field` (at time 0) over the sample, evaluated in rayon's pool: in pieces of
    /// a quarter of a thread's share (at least [`Self::MIN_PIECE`] points), so that a thread
    /// that finishes early takes another piece.
    pub fn nrmse(&self, field: &(dyn ScalarField + Sync)) -> f64 {
        let mut est = vec![0.0f32; self.points.len()];
        let piece = self.points.len().div_ceil(4 * rayon::current_num_threads()).max(Self::MIN_PIECE);
        est.par_chunks_mut(piece).zip(self.points.par_chunks(piece)).for_each(|(o, p)| field.eval(p, 0.0, o));
        crate::nrmse(&est, &self.values)
    }

    /// The fewest points one evaluation in [`Self::nrmse`] is given.
    const MIN_PIECE: usize = 4096;
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::{glam::DVec3, Aabb};

    #[test]
    fn a_volume_scores_zero_against_itself_and_one_against_zero() {
        let aabb = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let dims = [10, 10, 10];
        let data: Vec<f32> = (0..1000).map(|i| (i % 7) as f32).collect();
        let truth = Volume::from_vec(dims, aabb, data);
        let sample = TruthSample::new(&truth);
        assert_eq!(sample.len(), 1000);
        assert!(!sample.is_empty());
        assert!(sample.nrmse(&truth) < 1e-6);
        let zero = Volume::zeros(dims, aabb);
        assert!((sample.nrmse(&zero) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn the_pieces_evaluated_in_parallel_give_what_one_evaluation_gives() {
        let aabb = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let dims = [48, 40, 36];
        let truth = Volume::from_fn(dims, aabb, |p| (p.x * 3.0 + p.y * p.z) as f32);
        let estimate = Volume::from_fn(dims, aabb, |p| (p.x * 2.9 + p.y * p.y * p.z) as f32);
        let sample = TruthSample::new(&truth);
        assert!(sample.len() > 4 * TruthSample::MIN_PIECE, "{} points: one piece", sample.len());
        let mut serial = vec![0.0f32; sample.len()];
        estimate.eval(&sample.points, 0.0, &mut serial);
        let expected = crate::nrmse(&serial, &sample.values);
        assert!(expected > 0.01, "{expected}");
        assert_eq!(sample.nrmse(&estimate), expected);
    }

    #[test]
    fn a_truth_up_to_the_largest_side_is_sampled_whole_and_a_larger_one_every_other_voxel() {
        let aabb = Aabb::new(DVec3::ZERO, DVec3::ONE);
        let side = TruthSample::MAX_SIDE;
        let whole = Volume::zeros([side, 4, 4], aabb);
        assert_eq!(TruthSample::new(&whole).len(), side * 16);
        // One voxel more: every other centre along each axis, from the second.
        let larger = Volume::from_fn([side + 1, 4, 4], aabb, |p| p.x as f32);
        let sample = TruthSample::new(&larger);
        assert_eq!(sample.len(), (side / 2) * 2 * 2);
        assert_eq!(sample.points[0], larger.voxel_centre(1, 1, 1).as_vec3());
    }
}
