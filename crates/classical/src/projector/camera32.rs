//! A view's camera in f32 for the voxel loops of the voxel-driven projectors (the
//! separable-footprint projector and the splat): the camera-from-world rotation and
//! translation, the intrinsics and the OpenCV distortion, converted once per view.

pub(crate) use fluidnerf_core::camera::distort_f32 as distort;
use fluidnerf_core::Camera;

use super::Grid;

/// A camera in f32, ready for the voxel loop.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CameraF32 {
    pub width: usize,
    pub height: usize,
    /// Rows of the camera-from-world rotation.
    pub rot: [[f32; 3]; 3],
    pub trans: [f32; 3],
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub skew: f32,
    /// k1, k2, p1, p2, k3, k4, k5, k6.
    pub dist: [f32; 8],
    pub distorted: bool,
}

impl CameraF32 {
    pub fn new(camera: &Camera) -> Self {
        let cfw = camera.camera_from_world();
        let m = cfw.matrix3;
        // glam stores columns; row r of R is (m.x_axis[r], m.y_axis[r], m.z_axis[r]).
        let rot = [0, 1, 2].map(|r| [m.x_axis[r] as f32, m.y_axis[r] as f32, m.z_axis[r] as f32]);
        let t = cfw.translation;
        let k = camera.intrinsics;
        let d = camera.distortion;
        CameraF32 {
            width: camera.width(),
            height: camera.height(),
            rot,
            trans: [t.x as f32, t.y as f32, t.z as f32],
            fx: k.fx as f32,
            fy: k.fy as f32,
            cx: k.cx as f32,
            cy: k.cy as f32,
            skew: k.skew as f32,
            dist: [d.k1, d.k2, d.p1, d.p2, d.k3, d.k4, d.k5, d.k6].map(|v| v as f32),
            distorted: !d.is_identity(),
        }
    }

    /// Camera-frame position of the voxel row `(·, j, k)`'s first point (its centre moved by
    /// `offset` voxel sides) and the step per `i`.
    #[inline(always)]
    pub fn row_start(&self, grid: &GridF32, j: usize, k: usize, offset: [f32; 3]) -> ([f32; 3], [f32; 3]) {
        let y = grid.min[1] + (j as f32 + 0.5 + offset[1]) * grid.sp[1];
        let z = grid.min[2] + (k as f32 + 0.5 + offset[2]) * grid.sp[2];
        let x = grid.min[0] + (0.5 + offset[0]) * grid.sp[0];
        let r = &self.rot;
        let base = [0, 1, 2].map(|a| r[a][0] * x + r[a][1] * y + r[a][2] * z + self.trans[a]);
        let step = [0, 1, 2].map(|a| r[a][0] * grid.sp[0]);
        (base, step)
    }
}

/// A grid's corner and spacing in f32.
#[derive(Clone, Copy, Debug)]
pub(crate) struct GridF32 {
    pub min: [f32; 3],
    pub sp: [f32; 3],
}

impl GridF32 {
    pub fn new(grid: &Grid) -> Self {
        let sp = grid.spacing();
        GridF32 {
            min: [grid.aabb.min.x as f32, grid.aabb.min.y as f32, grid.aabb.min.z as f32],
            sp: [sp.x as f32, sp.y as f32, sp.z as f32],
        }
    }
}
