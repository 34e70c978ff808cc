//! Regions of interest: boxes in the reconstruction box's normalised coordinates, for metrics
//! per flow regime.
//!
//! The dissertation (Fig. 7.3a) scores the jet in three boxes along its axis (+x), left to
//! right: the **laminar** potential core, the **transition** region of shear-layer roll-up and
//! the **turbulent** far field. Its figure gives no coordinates, so the default
//! ([`Region::jet_thirds`]) splits the box into equal thirds along x, each spanning the full
//! y and z extent. Any other boxes can be given ([`Region::parse`]).
//!
//! A region is `[min, max)` in normalised coordinates (`0` = the box's `min` corner, `1` = its
//! `max` corner; per axis). A voxel belongs to a region when its centre lies inside, so regions
//! that tile `[0, 1]` partition the voxels.

use std::ops::Range;

use fluidnerf_core::num;
use fluidnerf_core::{Aabb, Volume};
use serde::{Deserialize, Serialize};

use crate::MetricsError;

/// A named box in box-normalised coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Region {
    pub name: String,
    /// Lower corner, `[x, y, z]` in `[0, 1]`.
    pub min: [f64; 3],
    /// Upper corner, `[x, y, z]` in `[0, 1]`, above `min` on every axis.
    pub max: [f64; 3],
}

impl Region {
    /// The slab `x ∈ [x0, x1)` (normalised) across the full y and z extent.
    pub fn along_x(name: impl Into<String>, x0: f64, x1: f64) -> Self {
        Region { name: name.into(), min: [x0, 0.0, 0.0], max: [x1, 1.0, 1.0] }
    }

    /// The default regions: laminar, transition and turbulent thirds of the box along +x.
    pub fn jet_thirds() -> Vec<Region> {
        vec![
            Region::along_x("laminar", 0.0, 1.0 / 3.0),
            Region::along_x("transition", 1.0 / 3.0, 2.0 / 3.0),
            Region::along_x("turbulent", 2.0 / 3.0, 1.0),
        ]
    }

    /// The laminar, transition and turbulent thirds along the box axis closest to `flow`
    /// (a direction in world coordinates), numbered from where the flow enters: for a flow
    /// along −y the laminar third is the one at the top of the box. Regions are boxes of the
    /// reconstruction box, so an oblique flow is scored along its dominant axis.
    pub fn jet_thirds_along(flow: fluidnerf_core::glam::DVec3) -> Vec<Region> {
        let a = flow.abs();
        let axis = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let forward = flow[axis] >= 0.0;
        ["laminar", "transition", "turbulent"]
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let (t0, t1) = if forward {
                    (k as f64 / 3.0, (k + 1) as f64 / 3.0)
                } else {
                    ((2 - k) as f64 / 3.0, (3 - k) as f64 / 3.0)
                };
                let (mut min, mut max) = ([0.0; 3], [1.0; 3]);
                min[axis] = t0;
                max[axis] = t1;
                Region { name: name.to_string(), min, max }
            })
            .collect()
    }

    /// Parses `NAME:X0:X1` (a slab along x) or `NAME:X0:X1:Y0:Y1:Z0:Z1` (a box), all in
    /// normalised coordinates, e.g. `core:0:0.3:0.3:0.7:0.3:0.7`.
    pub fn parse(spec: &str) -> Result<Region, MetricsError> {
        let bad = |why: &str| MetricsError::invalid(format!("region '{spec}'"), why.to_string());
        let mut parts = spec.split(':');
        let name = parts.next().filter(|n| !n.trim().is_empty()).ok_or_else(|| bad("needs a name"))?;
        let nums = parts
            .map(|p| p.trim().parse::<f64>().map_err(|_| bad(&format!("'{p}' is not a number"))))
            .collect::<Result<Vec<f64>, _>>()?;
        let region = match nums.as_slice() {
            [x0, x1] => Region::along_x(name.trim(), *x0, *x1),
            [x0, x1, y0, y1, z0, z1] => {
                Region { name: name.trim().to_string(), min: [*x0, *y0, *z0], max: [*x1, *y1, *z1] }
            }
            _ => return Err(bad("expected NAME:X0:X1 or NAME:X0:X1:Y0:Y1:Z0:Z1")),
        };
        region.validate()?;
        Ok(region)
    }

    /// Checks that the corners are finite, inside `[0, 1]` and ordered.
    pub fn validate(&self) -> Result<(), MetricsError> {
        for a in 0..3 {
            let (lo, hi) = (self.min[a], self.max[a]);
            if !(0.0..=1.0).contains(&lo) || !(0.0..=1.0).contains(&hi) || lo >= hi {
                return Err(MetricsError::invalid(
                    format!("region '{}'", self.name),
                    format!("axis {a}: need 0 <= min < max <= 1, got [{}, {})", num(lo), num(hi)),
                ));
            }
        }
        Ok(())
    }

    /// The region in world coordinates inside `aabb`.
    pub fn world_box(&self, aabb: &Aabb) -> Aabb {
        let size = aabb.size();
        let corner = |u: [f64; 3]| aabb.min + glam::DVec3::from_array(u) * size;
        Aabb::new(corner(self.min), corner(self.max))
    }

    /// The voxel index ranges `[i, j, k]` whose centres `(n + ½)/dims` lie in the region
    /// (possibly empty).
    pub fn voxel_ranges(&self, dims: [usize; 3]) -> [Range<usize>; 3] {
        std::array::from_fn(|a| {
            let n = dims[a] as f64;
            // Centre (i + ½)/n >= lo  ⇔  i >= lo·n − ½.
            let first = (self.min[a] * n - 0.5).ceil().max(0.0) as usize;
            let end = ((self.max[a] * n - 0.5).ceil().max(0.0) as usize).min(dims[a]);
            first.min(end)..end
        })
    }
}

/// Where the flow axis of the default regions came from ([`regions_flow_axis`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlowAxisFrom {
    /// Given by the user for this evaluation.
    Given,
    /// The scene's `flow_axis`.
    Recorded,
    /// Estimated from the ground truth ([`estimate_flow_axis`]).
    Estimated,
}

/// The flow axis that the default regions (the laminar, transition and turbulent thirds,
/// [`Region::jet_thirds_along`]) follow, and where it came from: `given`, else `recorded` (the
/// scene's `flow_axis`), else estimated from `truth`. None when none of them gives one: the
/// regions are then thirds along +x ([`Region::jet_thirds`]). `reconstruct`'s report and `eval`
/// both take their regions from here, so that a region's name means the same part of the box
/// in both.
pub fn regions_flow_axis(
    given: Option<fluidnerf_core::glam::DVec3>,
    recorded: Option<fluidnerf_core::glam::DVec3>,
    truth: Option<&Volume>,
) -> Option<(fluidnerf_core::glam::DVec3, FlowAxisFrom)> {
    given
        .map(|a| (a, FlowAxisFrom::Given))
        .or(recorded.map(|a| (a, FlowAxisFrom::Recorded)))
        .or_else(|| truth.and_then(estimate_flow_axis).map(|a| (a, FlowAxisFrom::Estimated)))
}

/// The default regions along [`regions_flow_axis`]'s answer.
pub fn default_regions(axis: Option<fluidnerf_core::glam::DVec3>) -> Vec<Region> {
    axis.map_or_else(Region::jet_thirds, Region::jet_thirds_along)
}

/// The flow direction of a jet or plume estimated from its field: the principal axis of the
/// intensity-weighted second moment of the voxel centres (the direction along which the field
/// is most elongated), pointing towards the end where the field is wider (a jet spreads as it
/// goes; the spread is the weighted mean squared distance from the axis, compared between the
/// two halves on either side of the centroid). None for an empty or nearly isotropic field.
pub fn estimate_flow_axis(volume: &Volume) -> Option<fluidnerf_core::glam::DVec3> {
    use fluidnerf_core::glam::{DMat3, DVec3};
    let [nx, ny, nz] = volume.dims;
    let spacing = volume.spacing();
    let each = |f: &mut dyn FnMut(DVec3, f64)| {
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let w = volume.data[(k * ny + j) * nx + i].max(0.0) as f64;
                    if w > 0.0 {
                        let p = volume.aabb.min + spacing * DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5);
                        f(p, w);
                    }
                }
            }
        }
    };
    let (mut total, mut first) = (0.0, DVec3::ZERO);
    each(&mut |p, w| {
        total += w;
        first += w * p;
    });
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    let mean = first / total;
    let mut m = DMat3::ZERO;
    each(&mut |p, w| {
        let d = p - mean;
        m += DMat3::from_cols(d * d.x, d * d.y, d * d.z) * w;
    });
    // The principal eigenvector by power iteration.
    let mut v = DVec3::new(1.0, 0.7, 0.4).normalize();
    for _ in 0..200 {
        let next = m * v;
        let len = next.length();
        if len.is_nan() || len <= 0.0 {
            return None;
        }
        v = next / len;
    }
    let lambda = v.dot(m * v);
    let trace = m.x_axis.x + m.y_axis.y + m.z_axis.z;
    if lambda.is_nan() || lambda <= 1.05 * 0.5 * (trace - lambda) {
        return None;
    }
    let (mut spread, mut weight) = ([0.0f64; 2], [0.0f64; 2]);
    each(&mut |p, w| {
        let d = p - mean;
        let along = d.dot(v);
        let side = usize::from(along >= 0.0);
        spread[side] += w * (d - along * v).length_squared();
        weight[side] += w;
    });
    let width = |s: usize| if weight[s] > 0.0 { spread[s] / weight[s] } else { 0.0 };
    Some(if width(1) >= width(0) { v } else { -v })
}

/// Copies the block `ranges` (`[i, j, k]`) out of an x-fastest array of `dims`; returns the
/// values (x fastest) and the block's dims.
pub fn extract(data: &[f32], dims: [usize; 3], ranges: &[Range<usize>; 3]) -> (Vec<f32>, [usize; 3]) {
    assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "extract: data does not match dims {dims:?}");
    assert!((0..3).all(|a| ranges[a].end <= dims[a]), "extract: ranges {ranges:?} exceed dims {dims:?}");
    let sub = [ranges[0].len(), ranges[1].len(), ranges[2].len()];
    let mut out = Vec::with_capacity(sub[0] * sub[1] * sub[2]);
    for k in ranges[2].clone() {
        for j in ranges[1].clone() {
            let row = (k * dims[1] + j) * dims[0];
            out.extend_from_slice(&data[row + ranges[0].start..row + ranges[0].end]);
        }
    }
    (out, sub)
}

/// The part of `volume` inside `region`, as a volume of its own (its box is the block of the
/// selected voxels). `None` if no voxel centre lies in the region.
pub fn extract_volume(volume: &Volume, region: &Region) -> Option<Volume> {
    let r = region.voxel_ranges(volume.dims);
    if r.iter().any(|r| r.is_empty()) {
        return None;
    }
    let (data, dims) = extract(&volume.data, volume.dims, &r);
    let sp = volume.spacing();
    let lo = glam::DVec3::new(r[0].start as f64, r[1].start as f64, r[2].start as f64);
    let hi = glam::DVec3::new(r[0].end as f64, r[1].end as f64, r[2].end as f64);
    let aabb = Aabb::new(volume.aabb.min + lo * sp, volume.aabb.min + hi * sp);
    Some(Volume::from_vec(dims, aabb, data))
}

#[cfg(test)]
mod tests {
    /// The default regions' flow axis: given, else recorded, else estimated; +x thirds when
    /// none is known.
    #[test]
    fn the_regions_flow_axis_is_given_then_recorded_then_estimated() {
        use fluidnerf_core::glam::DVec3;
        let aabb = fluidnerf_core::Aabb::new(DVec3::splat(-1.0), DVec3::splat(1.0));
        // Elongated along z and wider at +z: estimated as +z.
        let truth = Volume::from_fn([8, 8, 24], aabb, |p| {
            let r = (1.2 + p.z) * 0.3;
            if p.x * p.x + p.y * p.y < r * r {
                1.0
            } else {
                0.0
            }
        });
        let (x, y) = (Some(DVec3::X), Some(DVec3::Y));
        assert_eq!(regions_flow_axis(x, y, Some(&truth)), Some((DVec3::X, FlowAxisFrom::Given)));
        assert_eq!(regions_flow_axis(None, y, Some(&truth)), Some((DVec3::Y, FlowAxisFrom::Recorded)));
        let (axis, from) = regions_flow_axis(None, None, Some(&truth)).expect("estimated");
        assert_eq!(from, FlowAxisFrom::Estimated);
        assert!(axis.z > 0.99, "{axis:?}");
        assert_eq!(regions_flow_axis(None, None, None), None);
        assert_eq!(default_regions(None), Region::jet_thirds());
        assert_eq!(default_regions(Some(DVec3::Y)), Region::jet_thirds_along(DVec3::Y));
    }

    use super::*;

    /// A cone widening along −y: the estimate points along −y, and the regions start at the
    /// top (high y) of the box.
    #[test]
    fn the_flow_axis_is_the_cone_axis_towards_its_wide_end() {
        use fluidnerf_core::glam::DVec3;
        let aabb = Aabb::cube(DVec3::ZERO, 2.0);
        let cone = |p: DVec3| {
            let t = 0.5 * (1.0 - p.y); // 0 at the top, 1 at the bottom
            let r = 0.1 + 0.5 * t;
            if p.x * p.x + p.z * p.z < r * r {
                1.0f32
            } else {
                0.0
            }
        };
        let mut v = Volume::from_vec([24, 24, 24], aabb, vec![0.0; 24 * 24 * 24]);
        let s = v.spacing();
        for k in 0..24 {
            for j in 0..24 {
                for i in 0..24 {
                    let p = aabb.min + s * DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5);
                    v.data[(k * 24 + j) * 24 + i] = cone(p);
                }
            }
        }
        let axis = estimate_flow_axis(&v).expect("an axis");
        assert!(axis.dot(DVec3::NEG_Y) > 0.95, "{axis}");
        let regions = Region::jet_thirds_along(axis);
        assert_eq!(regions[0].name, "laminar");
        assert_eq!((regions[0].min[1], regions[0].max[1]), (2.0 / 3.0, 1.0));
        assert_eq!(Region::jet_thirds_along(DVec3::X), Region::jet_thirds());
        assert!(estimate_flow_axis(&Volume::from_vec([4, 4, 4], aabb, vec![0.0; 64])).is_none());
    }

    #[test]
    fn thirds_partition_the_voxels() {
        let dims = [10, 4, 3];
        let thirds = Region::jet_thirds();
        let counts: Vec<usize> = thirds.iter().map(|r| r.voxel_ranges(dims)[0].len()).collect();
        // Centres at 0.05, 0.15, …: 3 below 1/3, 4 in [1/3, 2/3), 3 above.
        assert_eq!(counts, vec![3, 4, 3]);
        let starts: Vec<usize> = thirds.iter().map(|r| r.voxel_ranges(dims)[0].start).collect();
        assert_eq!(starts, vec![0, 3, 7]);
        for r in &thirds {
            let rr = r.voxel_ranges(dims);
            assert_eq!((rr[1].len(), rr[2].len()), (4, 3));
        }
    }

    #[test]
    fn extract_picks_the_block() {
        let dims = [4, 3, 2];
        let data: Vec<f32> = (0..24).map(|v| v as f32).collect();
        let (sub, sd) = extract(&data, dims, &[1..3, 1..2, 1..2]);
        assert_eq!(sd, [2, 1, 1]);
        // Voxel (1, 1, 1) is index (1 * 3 + 1) * 4 + 1 = 17.
        assert_eq!(sub, vec![17.0, 18.0]);
    }

    #[test]
    fn parse_accepts_slabs_and_boxes() {
        let r = Region::parse("core:0:0.25").expect("slab");
        assert_eq!(r, Region::along_x("core", 0.0, 0.25));
        let r = Region::parse("box:0.1:0.2:0.3:0.4:0.5:0.6").expect("box");
        assert_eq!((r.min, r.max), ([0.1, 0.3, 0.5], [0.2, 0.4, 0.6]));
        assert!(Region::parse("x:0.5:0.2").is_err());
        assert!(Region::parse("x:0:2").is_err());
        assert!(Region::parse(":0:1").is_err());
        assert!(Region::parse("x:0:a").is_err());
        assert!(Region::parse("x:0:1:0").is_err());
    }

    #[test]
    fn extracted_volume_keeps_world_positions() {
        let aabb = Aabb::new(glam::DVec3::ZERO, glam::DVec3::new(3.0, 1.0, 1.0));
        let v = Volume::from_fn([9, 2, 2], aabb, |p| p.x as f32);
        let mid = extract_volume(&v, &Region::jet_thirds()[1]).expect("non-empty");
        assert_eq!(mid.dims, [3, 2, 2]);
        assert_eq!(mid.aabb.min.x, 1.0);
        assert_eq!(mid.aabb.max.x, 2.0);
        assert_eq!(mid.voxel_centre(0, 0, 0).x as f32, mid.get(0, 0, 0));
    }
}
