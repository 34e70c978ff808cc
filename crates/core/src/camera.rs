//! Pinhole cameras with OpenCV lens distortion, and the thin-lens description used for
//! synthesis.
//!
//! Conventions (see the crate docs): OpenCV camera axes (x right, y down, z forward), pixel
//! centres at integer image coordinates. The distortion model and its coefficient order are
//! OpenCV's (`k1, k2, p1, p2, k3, k4, k5, k6`), with OpenCV's formulas:
//!
//! ```text
//! r² = x² + y²
//! a  = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
//! x_d = x a + 2 p1 x y + p2 (r² + 2 x²)
//! y_d = y a + p1 (r² + 2 y²) + 2 p2 x y
//! u = fx x_d + skew y_d + cx,   v = fy y_d + cy
//! ```
//!
//! (The dissertation's Eq. 8.6–8.7 print the tangential terms with typos; OpenCV is the
//! reference.)

use crate::num;
use glam::{DAffine3, DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::{Aabb, CoreError, Ray};

/// The most pixels of each side of the image that [`Camera::check_undistortion`] tries.
const BORDER_SAMPLES: usize = 4096;

/// Points on the way from the image centre to each border pixel's ray at which
/// [`Camera::check_undistortion`] checks that the distortion does not fold the image over.
const FOLD_SAMPLES: usize = 16;

/// Largest focal length, principal-point coordinate or skew [`Intrinsics::validate`] accepts,
/// in pixels: a 10⁹ px focal length is a 1 km lens on 1 µm pixels, whose whole field of view
/// across ten thousand pixels is 10⁻⁵ rad. Beyond it values have only been seen as mistakes (a
/// focal length in the wrong unit, a damaged file), and past 3.4·10³⁸ they are infinite in the
/// 32-bit floats the projectors and renderers compute in.
pub const MAX_INTRINSIC_PX: f64 = 1e9;

/// Pinhole intrinsics in pixels (OpenCV convention: pixel centres at integer coordinates).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels (columns).
    pub width: u32,
    /// Image height in pixels (rows).
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// The `K[0][1]` entry (zero for square-pixel sensors).
    #[serde(default)]
    pub skew: f64,
}

impl Intrinsics {
    /// Checks for positive size and focal lengths and finite values.
    pub fn validate(&self) -> Result<(), CoreError> {
        if self.width == 0 || self.height == 0 {
            return Err(CoreError::invalid("intrinsics", "image size must be positive"));
        }
        let all = [self.fx, self.fy, self.cx, self.cy, self.skew];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::invalid("intrinsics", "values must be finite"));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(CoreError::invalid(
                "intrinsics",
                format!("focal lengths must be positive (fx = {}, fy = {})", num(self.fx), num(self.fy)),
            ));
        }
        if all.iter().any(|v| v.abs() > MAX_INTRINSIC_PX) {
            return Err(CoreError::invalid(
                "intrinsics",
                format!(
                    "focal lengths, principal point and skew must lie within ±{} px (fx = {}, fy = {}, cx = {}, \
                     cy = {}, skew = {}); larger values have only ever been mistakes (a length in another unit, a \
                     damaged file), and the projections compute in 32-bit floats. Are they in pixels?",
                    num(MAX_INTRINSIC_PX),
                    num(self.fx),
                    num(self.fy),
                    num(self.cx),
                    num(self.cy),
                    num(self.skew)
                ),
            ));
        }
        Ok(())
    }

    /// The 3 × 3 matrix K, row-major as written on paper.
    pub fn k_rows(&self) -> [[f64; 3]; 3] {
        [[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]]
    }
}

/// OpenCV distortion coefficients (rational radial + tangential). All zero means none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
    pub k4: f64,
    pub k5: f64,
    pub k6: f64,
}

/// The OpenCV distortion of normalised coordinates `(x, y)` with the coefficients `[k1, k2, p1,
/// p2, k3, k4, k5, k6]`, and its Jacobian `[dxx, dxy, dyx, dyy]`, in one float type: f64 for
/// [`Distortion::apply_with_jacobian`], f32 for the projectors' voxel loops.
macro_rules! opencv_distortion {
    ($name:ident, $t:ty) => {
        #[doc = concat!("The OpenCV distortion and its Jacobian in `", stringify!($t), "` (see [`Distortion`]).")]
        #[inline(always)]
        pub fn $name(d: &[$t; 8], x: $t, y: $t) -> ($t, $t, [$t; 4]) {
            let [k1, k2, p1, p2, k3, k4, k5, k6] = *d;
            let r2 = x * x + y * y;
            let num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6));
            let a = num / den;
            let dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
            let dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2);
            let da = (dnum * den - num * dden) / (den * den);
            let xd = x * a + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let yd = y * a + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let dxx = a + 2.0 * x * x * da + 2.0 * p1 * y + 6.0 * p2 * x;
            let dxy = 2.0 * x * y * da + 2.0 * p1 * x + 2.0 * p2 * y;
            let dyy = a + 2.0 * y * y * da + 6.0 * p1 * y + 2.0 * p2 * x;
            (xd, yd, [dxx, dxy, dxy, dyy])
        }
    };
}
opencv_distortion!(distort_f64, f64);
opencv_distortion!(distort_f32, f32);

impl Distortion {
    /// From an OpenCV coefficient vector of length 4, 5, 8 (or more; thin-prism and tilt terms
    /// beyond the eighth are rejected because they are not modelled).
    pub fn from_opencv(coeffs: &[f64]) -> Result<Self, CoreError> {
        let n = coeffs.len();
        if !matches!(n, 0 | 4 | 5 | 8 | 12 | 14) {
            return Err(CoreError::invalid(
                "distortion coefficients",
                format!("OpenCV uses 4, 5, 8, 12 or 14 coefficients, got {n}"),
            ));
        }
        if n > 8 && coeffs[8..].iter().any(|&c| c != 0.0) {
            return Err(CoreError::invalid(
                "distortion coefficients",
                "thin-prism (s1..s4) and tilt (tauX, tauY) terms are not supported",
            ));
        }
        if coeffs.iter().any(|c| !c.is_finite()) {
            return Err(CoreError::invalid("distortion coefficients", "must be finite"));
        }
        let g = |i: usize| coeffs.get(i).copied().unwrap_or(0.0);
        Ok(Distortion { k1: g(0), k2: g(1), p1: g(2), p2: g(3), k3: g(4), k4: g(5), k5: g(6), k6: g(7) })
    }

    /// The coefficients in OpenCV order; 5 of them unless k4..k6 are used, then 8.
    pub fn to_opencv(&self) -> Vec<f64> {
        let mut v = vec![self.k1, self.k2, self.p1, self.p2, self.k3];
        if self.k4 != 0.0 || self.k5 != 0.0 || self.k6 != 0.0 {
            v.extend([self.k4, self.k5, self.k6]);
        }
        v
    }

    pub fn is_identity(&self) -> bool {
        *self == Distortion::default()
    }

    /// Distorts normalised image coordinates (OpenCV formulas).
    pub fn apply(&self, p: DVec2) -> DVec2 {
        self.apply_with_jacobian(p).0
    }

    /// Distorted coordinates and the Jacobian `d(x_d, y_d)/d(x, y)` as columns.
    pub fn apply_with_jacobian(&self, p: DVec2) -> (DVec2, DMat2x2) {
        let Distortion { k1, k2, p1, p2, k3, k4, k5, k6 } = *self;
        let (xd, yd, [dxx, dxy, dyx, dyy]) = distort_f64(&[k1, k2, p1, p2, k3, k4, k5, k6], p.x, p.y);
        (DVec2::new(xd, yd), DMat2x2 { dxx, dxy, dyx, dyy })
    }
}

/// A 2 × 2 Jacobian `[[dxx, dxy], [dyx, dyy]]` (row = output, column = input).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DMat2x2 {
    pub dxx: f64,
    pub dxy: f64,
    pub dyx: f64,
    pub dyy: f64,
}

/// A thin lens with a finite aperture, used to synthesise images with defocus blur
/// (dissertation §6.2, Eq. 6.4–6.17). Lengths are in world units (the scene's `units`).
///
/// With magnification `M < 0` (a real, inverted image) the Gaussian lens equation
/// `1/l_o + 1/l_i = 1/f` and `M = -l_i / l_o` give `l_i = f (1 - M)` and `l_o = f (1 - 1/M)`.
/// The pinhole camera equivalent has focal length `l_i / pixel_pitch` pixels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThinLens {
    /// Focal length f of the main lens.
    pub focal_length: f64,
    /// Aperture diameter d_a = f / f#.
    pub aperture_diameter: f64,
    /// Lateral magnification M (negative for a real image; −0.2 in the dissertation).
    pub magnification: f64,
    /// Sensor pixel pitch.
    pub pixel_pitch: f64,
}

impl ThinLens {
    /// From the usual lens settings: focal length, f-number, magnification, pixel pitch.
    pub fn from_f_number(focal_length: f64, f_number: f64, magnification: f64, pixel_pitch: f64) -> Self {
        ThinLens { focal_length, aperture_diameter: focal_length / f_number, magnification, pixel_pitch }
    }

    pub fn validate(&self) -> Result<(), CoreError> {
        let ok = self.focal_length > 0.0
            && self.aperture_diameter >= 0.0
            && self.pixel_pitch > 0.0
            && self.magnification < 0.0
            && [self.focal_length, self.aperture_diameter, self.magnification, self.pixel_pitch]
                .iter()
                .all(|v| v.is_finite());
        if ok {
            Ok(())
        } else {
            Err(CoreError::invalid(
                "thin lens",
                format!(
                    "needs focal length > 0, aperture >= 0, pixel pitch > 0 and magnification < 0 \
                     (got f = {}, d_a = {}, M = {}, pitch = {})",
                    num(self.focal_length),
                    num(self.aperture_diameter),
                    num(self.magnification),
                    num(self.pixel_pitch)
                ),
            ))
        }
    }

    pub fn f_number(&self) -> f64 {
        self.focal_length / self.aperture_diameter
    }

    /// Image distance l_i (lens to sensor) = f (1 − M).
    pub fn image_distance(&self) -> f64 {
        self.focal_length * (1.0 - self.magnification)
    }

    /// Object distance l_o (lens to focal plane) = f (1 − 1/M).
    pub fn object_distance(&self) -> f64 {
        self.focal_length * (1.0 - 1.0 / self.magnification)
    }

    /// The equivalent pinhole focal length in pixels, l_i / pitch.
    pub fn focal_length_px(&self) -> f64 {
        self.image_distance() / self.pixel_pitch
    }

    /// Side of one pixel's footprint on the focal plane, pitch / |M|.
    pub fn pixel_footprint(&self) -> f64 {
        self.pixel_pitch / self.magnification.abs()
    }

    /// Diameter (on the sensor, world units) of the blur circle of a point on the optical axis
    /// at object distance `s` (Gaussian optics): `d_a · l_i · |1/s' − 1/l_i|` with `s'` the
    /// image distance of the point, `1/s' = 1/f − 1/s`.
    pub fn blur_circle_diameter(&self, s: f64) -> f64 {
        let inv_img = 1.0 / self.focal_length - 1.0 / s;
        self.aperture_diameter * self.image_distance() * (inv_img - 1.0 / self.image_distance()).abs()
    }

    /// The emission weight Ω(s)·A(s) of Eq. 5.3–5.4 at distance `s` along a ray: the solid
    /// angle normalised to the focal plane, Ω = (l_o / s)², times the pixel's footprint area in
    /// object space, A = (pitch · s / l_i)². For a pinhole this is the constant
    /// `(pitch / |M|)²`, the pixel footprint on the focal plane (tested), which is why the
    /// rendering model reduces to a scaled line integral.
    pub fn emission_weight(&self, s: f64) -> f64 {
        let omega = (self.object_distance() / s).powi(2);
        let area = (self.pixel_pitch * s / self.image_distance()).powi(2);
        omega * area
    }
}

/// How a camera sees the reconstruction box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Visibility {
    /// Fraction of sample points spread through the box that project inside the image.
    pub box_fraction_in_view: f64,
    /// Fraction of the image's pixels whose rays cross the box.
    pub pixel_fraction_on_box: f64,
}

/// Largest orthonormality error ([`orthonormality_error`]) a camera's rotation may have:
/// [`Camera::validate`] refuses more.
pub const ROTATION_TOLERANCE: f64 = 1e-6;

/// Largest orthonormality error of a matrix that [`rounded_rotation`] takes for a rotation
/// written with few digits. Entries rounded to three decimals are off by up to 5·10⁻⁴ each,
/// which puts the error at about 10⁻³ at most; a matrix further off is not a rotation.
pub const ROUNDED_ROTATION_MAX: f64 = 5e-3;

/// The largest entry of `|mᵀm − I|`: 0 for a rotation or a reflection, NaN when `m` holds an
/// entry that is not finite (which `f64::max` would pass over).
pub fn orthonormality_error(m: DMat3) -> f64 {
    if !m.is_finite() {
        return f64::NAN;
    }
    (m.transpose() * m - DMat3::IDENTITY).to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()))
}

/// The rotation nearest to `m`, when `m` is a rotation up to the rounding of values written
/// with few digits: its orthonormality error lies above [`ROTATION_TOLERANCE`] and at most
/// [`ROUNDED_ROTATION_MAX`], and its determinant is positive. Returns that rotation (the
/// orthogonal factor of `m`'s polar decomposition, the closest rotation in the Frobenius norm)
/// and `m`'s error. `None` for a matrix that is a rotation already, or too far from one to be
/// a rounded one, which [`Camera::validate`] then judges.
pub fn rounded_rotation(m: DMat3) -> Option<(DMat3, f64)> {
    let error = orthonormality_error(m);
    if !(error > ROTATION_TOLERANCE && error <= ROUNDED_ROTATION_MAX && m.determinant() > 0.0) {
        return None;
    }
    // Newton's iteration for the polar factor, X ← (X + X⁻ᵀ) / 2: quadratic from a start this
    // close, so a few steps reach the rounding of f64.
    let mut x = m;
    for _ in 0..10 {
        let next = 0.5 * (x + x.inverse().transpose());
        let step = (next - x).to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()));
        x = next;
        if step < 1e-15 {
            break;
        }
    }
    Some((x, error))
}

/// A calibrated pinhole camera with lens distortion and an optional thin-lens description.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    pub distortion: Distortion,
    /// Rigid transform from camera coordinates (OpenCV axes) to world coordinates. Its
    /// translation is the camera centre (pinhole) in the world.
    pub world_from_camera: DAffine3,
    /// The thin lens behind the pinhole model, when known (synthetic scenes).
    pub lens: Option<ThinLens>,
}

impl Camera {
    /// A camera at `centre` looking at `target`, with `up` giving the image's upward direction
    /// (image rows grow along −up). Panics if `up` is parallel to the viewing direction.
    pub fn look_at(intrinsics: Intrinsics, centre: DVec3, target: DVec3, up: DVec3) -> Self {
        let z = (target - centre).normalize();
        let x = z.cross(up);
        assert!(x.length() > 1e-9, "Camera::look_at: up is parallel to the viewing direction");
        let x = x.normalize();
        let y = z.cross(x);
        Camera {
            intrinsics,
            distortion: Distortion::default(),
            world_from_camera: DAffine3::from_mat3_translation(DMat3::from_cols(x, y, z), centre),
            lens: None,
        }
    }

    pub fn width(&self) -> usize {
        self.intrinsics.width as usize
    }

    pub fn height(&self) -> usize {
        self.intrinsics.height as usize
    }

    /// Camera centre in world coordinates.
    pub fn centre(&self) -> DVec3 {
        self.world_from_camera.translation
    }

    /// Viewing direction (camera +z) in world coordinates.
    pub fn forward(&self) -> DVec3 {
        self.world_from_camera.matrix3.z_axis
    }

    /// The inverse pose, mapping world to camera coordinates (`x_cam = R x_world + t`).
    pub fn camera_from_world(&self) -> DAffine3 {
        self.world_from_camera.inverse()
    }

    /// Checks intrinsics, lens and that the rotation is orthonormal and right-handed.
    pub fn validate(&self) -> Result<(), CoreError> {
        self.intrinsics.validate()?;
        if let Some(lens) = &self.lens {
            lens.validate()?;
        }
        let m = self.world_from_camera.matrix3;
        // `f64::max` passes over NaN, so a rotation with a NaN entry would measure as orthonormal.
        if !m.is_finite() {
            return Err(CoreError::invalid("camera pose", "rotation must be finite"));
        }
        let err = orthonormality_error(m);
        if !err.is_finite() || err > ROTATION_TOLERANCE || m.determinant() < 0.0 {
            return Err(CoreError::invalid(
                "camera pose",
                format!(
                    "rotation is not a proper rotation (orthonormality error {err:.1e}, det {:.3})",
                    m.determinant()
                ),
            ));
        }
        if !self.world_from_camera.translation.is_finite() {
            return Err(CoreError::invalid("camera pose", "translation must be finite"));
        }
        Ok(())
    }

    /// Projects a world point to continuous pixel coordinates `(u, v)`, or `None` if the point is
    /// not in front of the camera. Points outside the image still get coordinates.
    pub fn project(&self, point_in_world: DVec3) -> Option<DVec2> {
        let p = self.camera_from_world().transform_point3(point_in_world);
        self.project_camera_point(p)
    }

    /// Like [`Camera::project`] for a point already in camera coordinates.
    pub fn project_camera_point(&self, point_in_camera: DVec3) -> Option<DVec2> {
        if point_in_camera.z <= 0.0 {
            return None;
        }
        let n = DVec2::new(point_in_camera.x / point_in_camera.z, point_in_camera.y / point_in_camera.z);
        let d = self.distortion.apply(n);
        let k = &self.intrinsics;
        Some(DVec2::new(k.fx * d.x + k.skew * d.y + k.cx, k.fy * d.y + k.cy))
    }

    /// Normalised, undistorted image coordinates `(x, y)` (a point `(x, y, 1)` in camera space)
    /// of pixel coordinates `(u, v)`. Inverts the distortion by Newton's method until the
    /// re-distorted point is within 1e-6 px of `(u, v)`.
    pub fn unproject_normalised(&self, u: f64, v: f64) -> Result<DVec2, CoreError> {
        let k = &self.intrinsics;
        let yd = (v - k.cy) / k.fy;
        let xd = (u - k.cx - k.skew * yd) / k.fx;
        let target = DVec2::new(xd, yd);
        if self.distortion.is_identity() {
            return Ok(target);
        }
        // Tolerance in normalised units equivalent to 1e-6 px.
        let tol = 1e-6 / k.fx.max(k.fy);
        let mut p = target;
        let mut residual = f64::INFINITY;
        for _ in 0..100 {
            let (d, j) = self.distortion.apply_with_jacobian(p);
            let r = d - target;
            residual = r.length();
            if residual < tol {
                return Ok(p);
            }
            let det = j.dxx * j.dyy - j.dxy * j.dyx;
            if !det.is_finite() || det.abs() < 1e-12 {
                break;
            }
            let step = DVec2::new((j.dyy * r.x - j.dxy * r.y) / det, (-j.dyx * r.x + j.dxx * r.y) / det);
            // Damp steps that would leave the region where the model is monotone.
            let max_step = 0.5 * (1.0 + p.length());
            let step = if step.length() > max_step { step * (max_step / step.length()) } else { step };
            p -= step;
        }
        Err(CoreError::UndistortionFailed { u, v, residual_px: residual * k.fx.max(k.fy) })
    }

    /// The ray through continuous pixel coordinates `(u, v)` (OpenCV: pixel centres at integers),
    /// starting at the camera centre, with a unit direction in world coordinates.
    pub fn pixel_ray(&self, u: f64, v: f64) -> Result<Ray, CoreError> {
        let n = self.unproject_normalised(u, v)?;
        let dir = self.world_from_camera.transform_vector3(DVec3::new(n.x, n.y, 1.0));
        Ok(Ray::new(self.centre(), dir))
    }

    /// Whether every pixel's ray can be found: the distortion is inverted at each pixel of the
    /// image's border, where a calibration invalid far from the image centre fails first, and
    /// must keep its orientation (a Jacobian of positive determinant) on the way from the centre
    /// out to each of those rays, so that it does not fold the image over. The first pixel whose
    /// undistortion fails, or that lies past a fold, is the error; a camera without distortion
    /// passes.
    pub fn check_undistortion(&self) -> Result<(), CoreError> {
        if self.distortion.is_identity() {
            return Ok(());
        }
        let (w, h) = (self.width(), self.height());
        // Every pixel of the border, or, on sides longer than BORDER_SAMPLES pixels, that many
        // spread evenly with both ends: the test stays cheap for any image size.
        let along = |n: usize| {
            let stride = n.div_ceil(BORDER_SAMPLES).max(1);
            (0..n).step_by(stride).chain(std::iter::once(n - 1))
        };
        let rows = [0, h - 1].into_iter().flat_map(move |v| along(w).map(move |u| (u, v)));
        let columns = [0, w - 1].into_iter().flat_map(move |u| along(h).map(move |v| (u, v)));
        for (u, v) in rows.chain(columns) {
            let n = self.unproject_normalised(u as f64, v as f64)?;
            // Newton may find a ray past a fold of the distortion (k1 = −1000 with 96 px at 864
            // px focal length folds 10.5 px from the centre, and the border's rays were found
            // beyond it): the distortion must keep its orientation from the centre out to it.
            for s in 1..=FOLD_SAMPLES {
                let t = s as f64 / FOLD_SAMPLES as f64;
                let (_, j) = self.distortion.apply_with_jacobian(t * n);
                let det = j.dxx * j.dyy - j.dxy * j.dyx;
                // NaN counts as a fold.
                if det.is_nan() || det <= 0.0 {
                    return Err(CoreError::DistortionFolds { u: u as f64, v: v as f64, fold: 100.0 * t });
                }
            }
        }
        Ok(())
    }

    /// How much of the box this camera sees: the fraction of a 9³ lattice of points in the box
    /// that project inside the image, and the fraction of a lattice of pixels (at most 64 × 64)
    /// whose rays cross the box. Pixels whose undistortion fails count as not seeing the box.
    /// A box imaged smaller than the lattice's spacing, which no lattice ray crosses, is looked
    /// for among the pixels under its image: the fraction is then that of the image's pixels.
    pub fn visibility(&self, aabb: &Aabb) -> Visibility {
        let (w, h) = (self.intrinsics.width as f64, self.intrinsics.height as f64);
        let n = 9;
        let mut inside = 0usize;
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let f = DVec3::new(i as f64, j as f64, k as f64) / (n - 1) as f64;
                    let p = aabb.min + f * aabb.size();
                    if let Some(uv) = self.project(p) {
                        if uv.x >= -0.5 && uv.y >= -0.5 && uv.x < w - 0.5 && uv.y < h - 0.5 {
                            inside += 1;
                        }
                    }
                }
            }
        }
        let (mw, mh) = self.probe_lattice();
        let on_box =
            (0..mh).flat_map(|j| (0..mw).map(move |i| (i, j))).filter(|&(i, j)| self.probe_hits(aabb, i, j)).count();
        let pixel_fraction_on_box = if on_box > 0 {
            on_box as f64 / (mw * mh) as f64
        } else {
            // A box imaged smaller than the lattice's spacing: count the pixels under its image.
            let hits = self.pixels_under_box_image(aabb).filter(|&(u, v)| self.pixel_hits(aabb, u, v)).count();
            hits as f64 / (self.width() * self.height()) as f64
        };
        Visibility { box_fraction_in_view: inside as f64 / (n * n * n) as f64, pixel_fraction_on_box }
    }

    /// Whether any pixel of [`Self::visibility`]'s lattice sees the box: the same answer as
    /// `pixel_fraction_on_box > 0`, found from the middle of the image outwards and stopped at
    /// the first ray that crosses it (a camera aimed at the box answers after one ray, where the
    /// fraction takes 4096).
    pub fn sees_box(&self, aabb: &Aabb) -> bool {
        let (mw, mh) = self.probe_lattice();
        let outwards = |m: usize| (0..m).map(move |k| if k % 2 == 0 { m / 2 + k / 2 } else { m / 2 - 1 - k / 2 });
        outwards(mh).any(|j| outwards(mw).any(|i| self.probe_hits(aabb, i, j)))
            || self.pixels_under_box_image(aabb).any(|(u, v)| self.pixel_hits(aabb, u, v))
    }

    /// The pixel centres (integer `(u, v)`) around the image of `aabb`: the bounding rectangle
    /// of the projections of its corners and centre, one pixel wider on each side and clipped to
    /// the image. A box imaged smaller than the probe lattice's spacing (a short focal length, a
    /// far or small box) falls between its probes, but not between these pixels. Empty when no
    /// corner is in front of the camera, or the rectangle is larger than the lattice would miss
    /// (more than 64 × 64 pixels).
    fn pixels_under_box_image(&self, aabb: &Aabb) -> impl Iterator<Item = (usize, usize)> {
        let (lo, hi, _) = self.box_image_bounds(aabb);
        let (w, h) = (self.width() as f64, self.height() as f64);
        let u0 = (lo.x.floor() - 1.0).max(0.0);
        let v0 = (lo.y.floor() - 1.0).max(0.0);
        let u1 = (hi.x.ceil() + 1.0).min(w - 1.0);
        let v1 = (hi.y.ceil() + 1.0).min(h - 1.0);
        let small = lo.x <= hi.x && u0 <= u1 && v0 <= v1 && (u1 - u0 + 1.0) * (v1 - v0 + 1.0) <= 4096.0;
        let (u0, v0, u1, v1) = if small { (u0 as usize, v0 as usize, u1 as usize, v1 as usize) } else { (1, 1, 0, 0) };
        (v0..=v1).flat_map(move |v| (u0..=u1).map(move |u| (u, v)))
    }

    /// The bounding rectangle `(min, max)` of the projections of the corners and centre of
    /// `aabb` that are in front of the camera, and whether all of them are.
    fn box_image_bounds(&self, aabb: &Aabb) -> (DVec2, DVec2, bool) {
        let corners = (0..8).map(|c| {
            DVec3::new(
                if c & 1 == 0 { aabb.min.x } else { aabb.max.x },
                if c & 2 == 0 { aabb.min.y } else { aabb.max.y },
                if c & 4 == 0 { aabb.min.z } else { aabb.max.z },
            )
        });
        let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        let mut all = true;
        for p in corners.chain([aabb.centre()]) {
            match self.project(p).filter(|uv| uv.is_finite()) {
                Some(uv) => {
                    lo = lo.min(uv);
                    hi = hi.max(uv);
                }
                None => all = false,
            }
        }
        (lo, hi, all)
    }

    /// How large, in pixels, the camera images `aabb` (the width and height of the rectangle its
    /// corners project to), if the box is wholly in front of the camera and its image overlaps
    /// the image; `None` otherwise. Explains why a camera whose view holds the box can still
    /// have no pixel's ray crossing it: an image less than a pixel wide or high can fall between
    /// the pixel centres.
    pub fn box_image_size(&self, aabb: &Aabb) -> Option<DVec2> {
        let (lo, hi, all) = self.box_image_bounds(aabb);
        let (w, h) = (self.width() as f64, self.height() as f64);
        let overlaps = hi.x >= -0.5 && hi.y >= -0.5 && lo.x < w - 0.5 && lo.y < h - 0.5;
        (all && overlaps).then(|| hi - lo)
    }

    /// Whether the ray through pixel centre `(u, v)` crosses `aabb`.
    pub fn pixel_hits(&self, aabb: &Aabb, u: usize, v: usize) -> bool {
        self.pixel_ray(u as f64, v as f64).is_ok_and(|ray| aabb.intersect(&ray).is_some())
    }

    /// The lattice of pixels that [`Self::visibility`] and [`Self::sees_box`] probe: at most
    /// 64 × 64, spread evenly over the image.
    fn probe_lattice(&self) -> (usize, usize) {
        let m = 64usize;
        (m.min(self.width()), m.min(self.height()))
    }

    /// Whether the ray of lattice pixel `(i, j)` crosses `aabb`.
    fn probe_hits(&self, aabb: &Aabb, i: usize, j: usize) -> bool {
        let (mw, mh) = self.probe_lattice();
        let (w, h) = (self.intrinsics.width as f64, self.intrinsics.height as f64);
        let u = (i as f64 + 0.5) / mw as f64 * w - 0.5;
        let v = (j as f64 + 0.5) / mh as f64 * h - 0.5;
        self.pixel_ray(u, v).is_ok_and(|ray| aabb.intersect(&ray).is_some())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn test_camera(dist: Distortion) -> Camera {
        let k = Intrinsics { width: 640, height: 480, fx: 500.0, fy: 510.0, cx: 319.5, cy: 241.0, skew: 0.7 };
        let mut cam = Camera::look_at(k, DVec3::new(300.0, -40.0, 80.0), DVec3::ZERO, DVec3::Z);
        cam.distortion = dist;
        cam
    }

    fn strong_distortion() -> Distortion {
        Distortion { k1: -0.28, k2: 0.09, p1: 1.2e-3, p2: -8e-4, k3: -0.012, k4: 0.01, k5: 0.0, k6: 0.002 }
    }

    #[test]
    fn pixel_ray_pixel_round_trip_over_whole_image() {
        for dist in [Distortion::default(), strong_distortion()] {
            let cam = test_camera(dist);
            let mut worst = 0.0f64;
            for v in (0..480).step_by(7).chain([479]) {
                for u in (0..640).step_by(7).chain([639]) {
                    let ray = cam.pixel_ray(u as f64, v as f64).expect("undistorts");
                    let back = cam.project(ray.at(250.0)).expect("in front");
                    worst = worst.max((back - DVec2::new(u as f64, v as f64)).length());
                }
            }
            assert!(worst < 1e-4, "worst round-trip error {worst} px");
        }
    }

    /// A pose whose rotation is not finite, or not a proper rotation, or whose translation is
    /// not finite, is refused; a NaN entry once measured as orthonormal (`f64::max` passes over
    /// NaN), so the pose was taken.
    #[test]
    fn validate_refuses_poses_that_are_not_rigid_motions() {
        assert!(test_camera(Distortion::default()).validate().is_ok());
        let with = |edit: fn(&mut DAffine3)| {
            let mut cam = test_camera(Distortion::default());
            edit(&mut cam.world_from_camera);
            cam.validate().map_err(|e| e.to_string())
        };
        let nan = with(|p| p.matrix3.x_axis.x = f64::NAN).unwrap_err();
        assert!(nan.contains("rotation must be finite"), "{nan}");
        let scaled = with(|p| p.matrix3 *= 2.0).unwrap_err();
        assert!(scaled.contains("not a proper rotation"), "{scaled}");
        let mirrored = with(|p| p.matrix3.x_axis *= -1.0).unwrap_err();
        assert!(mirrored.contains("not a proper rotation"), "{mirrored}");
        let far = with(|p| p.translation.y = f64::INFINITY).unwrap_err();
        assert!(far.contains("translation must be finite"), "{far}");
    }

    /// A rotation written with three or four decimals is taken back to the nearest rotation,
    /// which lies within the rounding of the one written; a rotation, a reflection and a
    /// scaled matrix are left to the camera's check.
    #[test]
    fn rounded_rotations_are_taken_to_the_nearest_rotation() {
        let exact = test_camera(Distortion::default()).world_from_camera.matrix3;
        for decimals in [3, 4] {
            let scale = 10f64.powi(decimals);
            let rounded = DMat3::from_cols_array(&exact.to_cols_array().map(|v| (v * scale).round() / scale));
            let (r, error) = rounded_rotation(rounded).expect("a rounded rotation");
            assert!(error > ROTATION_TOLERANCE && error <= ROUNDED_ROTATION_MAX, "{decimals} decimals: {error}");
            assert!(orthonormality_error(r) < 1e-14 && r.determinant() > 0.0);
            let off = (r - exact).to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()));
            assert!(off < 1.0 / scale, "{decimals} decimals: {off} from the exact rotation");
        }
        assert_eq!(rounded_rotation(exact), None, "a rotation already");
        assert_eq!(rounded_rotation(-exact), None, "a reflection");
        assert_eq!(rounded_rotation(exact * 1.01), None, "a scaled rotation is not rounding");
        assert!(orthonormality_error(DMat3::from_cols_array(&[f64::NAN; 9])).is_nan());
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = strong_distortion();
        let p = DVec2::new(0.31, -0.22);
        let (_, j) = d.apply_with_jacobian(p);
        let h = 1e-6;
        let ddx = (d.apply(p + DVec2::X * h) - d.apply(p - DVec2::X * h)) / (2.0 * h);
        let ddy = (d.apply(p + DVec2::Y * h) - d.apply(p - DVec2::Y * h)) / (2.0 * h);
        assert_relative_eq!(j.dxx, ddx.x, epsilon = 1e-7);
        assert_relative_eq!(j.dyx, ddx.y, epsilon = 1e-7);
        assert_relative_eq!(j.dxy, ddy.x, epsilon = 1e-7);
        assert_relative_eq!(j.dyy, ddy.y, epsilon = 1e-7);
    }

    #[test]
    fn principal_point_ray_is_forward() {
        let cam = test_camera(Distortion::default());
        let k = cam.intrinsics;
        let ray = cam.pixel_ray(k.cx, k.cy).expect("ray");
        assert_relative_eq!(ray.dir.dot(cam.forward()), 1.0, epsilon = 1e-12);
        // look_at aims the optical axis at the target.
        let uv = cam.project(DVec3::ZERO).expect("in front");
        assert_relative_eq!(uv.x, k.cx, epsilon = 1e-9);
        assert_relative_eq!(uv.y, k.cy, epsilon = 1e-9);
    }

    #[test]
    fn look_at_up_is_image_up() {
        let cam = test_camera(Distortion::default());
        let above = cam.project(DVec3::new(0.0, 0.0, 10.0)).expect("in front");
        assert!(above.y < cam.intrinsics.cy, "a point above the target must be higher in the image");
    }

    #[test]
    fn behind_camera_does_not_project() {
        let cam = test_camera(Distortion::default());
        assert!(cam.project(cam.centre() - cam.forward()).is_none());
    }

    #[test]
    fn undistortion_failure_is_an_error() {
        // Barrel distortion this strong folds over: far corners have no preimage.
        let mut cam = test_camera(Distortion { k1: -2.0, ..Default::default() });
        cam.intrinsics.fx = 100.0;
        cam.intrinsics.fy = 100.0;
        assert!(matches!(cam.pixel_ray(0.0, 0.0), Err(CoreError::UndistortionFailed { .. })));
    }

    #[test]
    fn thin_lens_dissertation_settings() {
        // Table 6.1: f = 60 mm, f/3.5, M = -0.2, pitch 0.01 mm, 800 px -> 40 mm field of view.
        let lens = ThinLens::from_f_number(60.0, 3.5, -0.2, 0.01);
        assert_relative_eq!(lens.image_distance(), 72.0, epsilon = 1e-12);
        assert_relative_eq!(lens.object_distance(), 360.0, epsilon = 1e-12);
        assert_relative_eq!(1.0 / lens.object_distance() + 1.0 / lens.image_distance(), 1.0 / 60.0, epsilon = 1e-15);
        assert_relative_eq!(800.0 * lens.pixel_footprint(), 40.0, epsilon = 1e-12);
        assert_relative_eq!(lens.aperture_diameter, 60.0 / 3.5, epsilon = 1e-12);
        assert_eq!(lens.blur_circle_diameter(lens.object_distance()), 0.0);
    }

    /// Off focus the blur circle is `d_a · (1 − l_i / s')` by hand: at 300 and at 450 mm the
    /// image lies at 75 and 69.23 mm, 0.04 of the aperture either way (0.686 mm).
    #[test]
    fn thin_lens_blur_and_pixel_focal_length_by_hand() {
        let lens = ThinLens::from_f_number(60.0, 3.5, -0.2, 0.01);
        assert_relative_eq!(lens.f_number(), 3.5, epsilon = 1e-12);
        assert_relative_eq!(lens.focal_length_px(), 7200.0, epsilon = 1e-9);
        for s in [300.0, 450.0] {
            assert_relative_eq!(lens.blur_circle_diameter(s), 0.04 * 60.0 / 3.5, epsilon = 1e-12);
        }
        assert!(lens.validate().is_ok());
        assert!(ThinLens { aperture_diameter: 0.0, ..lens }.validate().is_ok(), "a pinhole");
        for bad in [
            ThinLens { focal_length: 0.0, ..lens },
            ThinLens { focal_length: f64::INFINITY, ..lens },
            ThinLens { aperture_diameter: -1.0, ..lens },
            ThinLens { aperture_diameter: f64::NAN, ..lens },
            ThinLens { pixel_pitch: 0.0, ..lens },
            ThinLens { magnification: 0.0, ..lens },
            ThinLens { magnification: 0.2, ..lens },
            ThinLens { magnification: f64::NEG_INFINITY, ..lens },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn intrinsics_need_a_size_positive_focal_lengths_and_finite_values() {
        let k = Intrinsics { width: 4, height: 3, fx: 5.0, fy: 6.0, cx: 1.5, cy: 1.0, skew: 0.5 };
        assert!(k.validate().is_ok());
        assert_eq!(k.k_rows(), [[5.0, 0.5, 1.5], [0.0, 6.0, 1.0], [0.0, 0.0, 1.0]]);
        for bad in [
            Intrinsics { width: 0, ..k },
            Intrinsics { height: 0, ..k },
            Intrinsics { fx: 0.0, ..k },
            Intrinsics { fy: -1.0, ..k },
            Intrinsics { cx: f64::NAN, ..k },
            Intrinsics { cy: f64::INFINITY, ..k },
            Intrinsics { skew: f64::NAN, ..k },
            Intrinsics { fx: f64::INFINITY, ..k },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
        // Finite in f64 but beyond the bound (1e39 is infinite in f32): refused, naming it.
        let at_bound = Intrinsics { fx: MAX_INTRINSIC_PX, fy: MAX_INTRINSIC_PX, cx: -MAX_INTRINSIC_PX, ..k };
        assert!(at_bound.validate().is_ok());
        for bad in [
            Intrinsics { fx: 1e39, ..k },
            Intrinsics { fy: 2.0 * MAX_INTRINSIC_PX, ..k },
            Intrinsics { cx: -1e12, ..k },
            Intrinsics { cy: 1e300, ..k },
            Intrinsics { skew: 1e10, ..k },
        ] {
            let e = bad.validate().expect_err("beyond the bound").to_string();
            assert!(e.contains("within ±1000000000 px") && e.contains("Are they in pixels?"), "{e}");
        }
    }

    #[test]
    fn pinhole_emission_weight_is_constant() {
        let lens = ThinLens::from_f_number(60.0, 3.5, -0.2, 0.01);
        let expected = lens.pixel_footprint().powi(2);
        for s in [300.0, 340.0, 360.0, 381.0, 420.0] {
            assert_relative_eq!(lens.emission_weight(s), expected, max_relative = 1e-12);
        }
    }

    #[test]
    fn opencv_coefficient_order_round_trips() {
        let c = [0.1, -0.2, 0.003, -0.004, 0.05];
        let d = Distortion::from_opencv(&c).expect("valid");
        assert_eq!(d.p1, 0.003);
        assert_eq!(d.k3, 0.05);
        assert_eq!(d.to_opencv(), c.to_vec());
        assert!(Distortion::from_opencv(&[0.1, 0.2, 0.3]).is_err());
        let mut c14 = [0.0; 14];
        c14[9] = 0.1;
        assert!(Distortion::from_opencv(&c14).is_err());
        // Counts OpenCV never writes are refused as such, even when the extra terms are zero
        // (20 zeros were taken, 9 with a last non-zero blamed on the thin-prism terms).
        assert!(Distortion::from_opencv(&[0.0; 12]).is_ok() && Distortion::from_opencv(&[0.0; 14]).is_ok());
        for n in [6, 9, 13, 20] {
            let mut c = vec![0.0; n];
            c[n - 1] = 0.1;
            let e = Distortion::from_opencv(&c).expect_err("count").to_string();
            assert!(e.contains(&format!("OpenCV uses 4, 5, 8, 12 or 14 coefficients, got {n}")), "{e}");
            assert!(Distortion::from_opencv(&vec![0.0; n]).is_err(), "{n} zeros");
        }
    }

    #[test]
    fn visibility_of_centred_and_missed_boxes() {
        let cam = test_camera(Distortion::default());
        let seen = cam.visibility(&Aabb::cube(DVec3::ZERO, 40.0));
        assert_eq!(seen.box_fraction_in_view, 1.0);
        assert!(seen.pixel_fraction_on_box > 0.0 && seen.pixel_fraction_on_box < 1.0);
        let missed = cam.visibility(&Aabb::cube(DVec3::new(3000.0, 0.0, 0.0), 10.0));
        assert_eq!(missed.box_fraction_in_view, 0.0);
        assert_eq!(missed.pixel_fraction_on_box, 0.0);
    }

    /// A distortion that cannot be inverted at the image's edges is found at the first such
    /// pixel; one that can, and no distortion, pass.
    #[test]
    fn undistortion_is_checked_over_the_image_border() {
        assert!(test_camera(Distortion::default()).check_undistortion().is_ok());
        assert!(test_camera(strong_distortion()).check_undistortion().is_ok());
        let wild = test_camera(Distortion { k1: 1e300, ..Distortion::default() });
        let e = wild.check_undistortion().expect_err("fails at the corners");
        assert!(matches!(e, CoreError::UndistortionFailed { u: 0.0, v: 0.0, .. }), "{e}");
        // The same camera with pixels a millionth as large: a border of 4.8·10⁸ and 6.4·10⁸
        // pixels a side is sampled, not walked (2.2·10⁹ inversions would take minutes), and
        // passes as the camera does; its far corner is among the samples.
        let mut huge = test_camera(strong_distortion());
        let k = huge.intrinsics;
        let m = 1e6;
        huge.intrinsics = Intrinsics {
            width: k.width * 1_000_000,
            height: k.height * 1_000_000,
            fx: k.fx * m,
            fy: k.fy * m,
            cx: (k.cx + 0.5) * m - 0.5,
            cy: (k.cy + 0.5) * m - 0.5,
            skew: k.skew * m,
        };
        assert!(huge.check_undistortion().is_ok());
        huge.distortion = Distortion { k1: 1e300, ..Distortion::default() };
        let e = huge.check_undistortion().expect_err("fails at the corners");
        assert!(matches!(e, CoreError::UndistortionFailed { u: 0.0, v: 0.0, .. }), "{e}");
    }

    /// k1 = −1000 at 864 px focal length folds the image 10.5 px from its centre (`r (1 + k1 r²)`
    /// peaks at `r = (−3 k1)^(−1/2)`): Newton found the 96 px image's border rays past the fold,
    /// and the camera passed while pixels between failed. The fold is found, at the fraction of
    /// the way from the centre where the Jacobian turns; a fold beyond the image passes.
    #[test]
    fn a_distortion_that_folds_the_image_is_found() {
        let k = Intrinsics { width: 96, height: 96, fx: 864.0, fy: 864.0, cx: 47.5, cy: 47.5, skew: 0.0 };
        let mut cam = Camera::look_at(k, DVec3::new(360.0, 0.0, 0.0), DVec3::ZERO, DVec3::Z);
        cam.distortion = Distortion { k1: -1000.0, ..Distortion::default() };
        assert!(cam.unproject_normalised(0.0, 47.5).is_ok(), "a border ray is found, past the fold");
        let e = cam.check_undistortion().expect_err("folds");
        let CoreError::DistortionFolds { u, v, fold } = e else { panic!("{e}") };
        // The first border pixel, (0, 0): its ray lies at r ≈ 0.050 (the far branch), the fold
        // where 1 + 3 k1 r² = 0, at r = 0.018, 36 % of the way; the first sample past it is 6/16.
        assert_eq!((u, v), (0.0, 0.0));
        assert_eq!(fold, 100.0 * 6.0 / 16.0);
        assert!(e.to_string().contains("folds the image over between its centre and pixel (0.000, 0.000)"), "{e}");
        // Mild barrel distortion folds far outside this image.
        cam.distortion = Distortion { k1: -0.5, ..Distortion::default() };
        assert!(cam.check_undistortion().is_ok());
    }

    /// A camera of very short focal length (3 px over 96 px: a field of view of 172°) images a
    /// 40 mm box at 360 mm a third of a pixel across, between the probe lattice's rays but on
    /// the ray of the pixel at its centre: it sees the box. Moved to lie between pixel centres,
    /// no pixel's ray crosses it.
    #[test]
    fn a_wide_field_of_view_sees_a_box_imaged_smaller_than_a_pixel() {
        let k = Intrinsics { width: 96, height: 96, fx: 3.0, fy: 3.0, cx: 48.0, cy: 48.0, skew: 0.0 };
        let cam = Camera::look_at(k, DVec3::new(0.0, -360.0, 0.0), DVec3::ZERO, DVec3::Z);
        let aabb = Aabb::cube(DVec3::ZERO, 40.0);
        assert!(cam.sees_box(&aabb));
        let vis = cam.visibility(&aabb);
        assert_eq!(vis.box_fraction_in_view, 1.0);
        assert!(vis.pixel_fraction_on_box > 0.0, "{vis:?}");
        let between = Camera::look_at(Intrinsics { cx: 48.5, cy: 48.5, ..k }, cam.centre(), DVec3::ZERO, DVec3::Z);
        assert!(!between.sees_box(&aabb));
        assert_eq!(between.visibility(&aabb).pixel_fraction_on_box, 0.0);
        let size = between.box_image_size(&aabb).expect("in view");
        assert!(size.x > 0.3 && size.x < 0.4 && size.y > 0.3 && size.y < 0.4, "{size}");
    }

    /// `sees_box` answers what `pixel_fraction_on_box > 0` answers, for boxes in the middle,
    /// at the image's edges and corners, too small to meet a probed ray, and out of view.
    #[test]
    fn sees_box_agrees_with_the_pixel_fraction() {
        let cam = test_camera(Distortion::default());
        let mut seen = 0;
        for x in (-400..=400).step_by(50) {
            for y in (-400..=400).step_by(50) {
                for size in [0.05, 2.0, 40.0] {
                    let aabb = Aabb::cube(DVec3::new(x as f64, y as f64, 0.0), size);
                    let fraction = cam.visibility(&aabb).pixel_fraction_on_box;
                    assert_eq!(cam.sees_box(&aabb), fraction > 0.0, "box at ({x}, {y}) of side {size}: {fraction}");
                    seen += usize::from(fraction > 0.0);
                }
            }
        }
        assert!(seen > 10 && seen < 17 * 17 * 3 - 10, "the boxes must include seen and unseen ones: {seen}");
    }
}
