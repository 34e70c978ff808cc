//! Differentiable emission rendering (dissertation §5.1.3, Eq. 5.3–5.5).
//!
//! A pixel records `I = ∫_{s_near}^{s_far} Ω(s) A(s) E(s) ds` (Eq. 5.3): Ω the solid angle of
//! the aperture normalised to the focal plane, `(l_o / s)²`, and A the pixel's footprint area
//! in object space, `(pitch · s / l_i)²`. The quadrature over the sorted samples
//! `s_1 < … < s_N` is the trapezoid rule between neighbours with Ω·A taken at the midpoint
//! `s̄_j = (s_j + s_{j+1}) / 2` (Eq. 5.4):
//!
//! ```text
//! I ≈ Σ_{j=1}^{N−1} Ω(s̄_j) A(s̄_j) (s_{j+1} − s_j) (E_j + E_{j+1}) / 2  =  Σ_j w_j E_j
//! ```
//!
//! (Eq. 5.4 as printed calls the interval length "the distance between midpoints"; with the
//! trapezoid average `(E_j + E_{j+1}) / 2` only the sample spacing `s_{j+1} − s_j` makes it
//! the trapezoid rule the text names, so that is what is used.)
//!
//! **Ends.** The samples start up to one bin after `s_near` and stop up to one bin before
//! `s_far`; with [`Quadrature::close_ends`] (the default) the two end pieces are added with
//! the nearest sample's value (`E_1 (s_1 − s_near)` and `E_N (s_far − s_N)`), so the weights
//! sum to the chord length and a constant field integrates exactly. The dissertation's sum
//! omits them; `close_ends = false` reproduces that.
//!
//! **Pinhole reduction.** Ω·A is constant along a pinhole ray, `(l_o · pitch / l_i)²`, the
//! pixel footprint on the focal plane ([`fluidnerf_core::ThinLens::emission_weight`]). Scenes
//! fold that constant into `Scene::intensity_scale` (pixel = scale × ∫E ds), so the weights
//! here use the ratio `Ω(s)A(s) / Ω(l_o)A(l_o)`, which is 1 for every pinhole ray; the
//! thin-lens form is still evaluated as written when a camera carries a lens (tested to be 1).
//!
//! **Loss** (Eq. 5.5): `L = (1/N_pix) Σ_i (I_i − Î_i)²` over the pixels of an iteration, and its
//! exact backward `∂L/∂E_j = (2/N_pix)(I_i − Î_i) · w_j` for the samples of pixel `i`.

use fluidnerf_core::Camera;

/// How Ω(s)·A(s) varies along a ray, relative to its value on the focal plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EmissionModel {
    /// A pinhole without lens data: the ratio is 1.
    Pinhole,
    /// A thin lens: Ω = (l_o / s)², A = (pitch · s / l_i)².
    ThinLens { object_distance: f32, image_distance: f32, pixel_pitch: f32 },
}

impl EmissionModel {
    pub fn from_camera(camera: &Camera) -> Self {
        match &camera.lens {
            Some(lens) => EmissionModel::ThinLens {
                object_distance: lens.object_distance() as f32,
                image_distance: lens.image_distance() as f32,
                pixel_pitch: lens.pixel_pitch as f32,
            },
            None => EmissionModel::Pinhole,
        }
    }

    /// `Ω(s)A(s) / Ω(l_o)A(l_o)`.
    #[inline]
    pub fn relative_weight(&self, s: f32) -> f32 {
        match *self {
            EmissionModel::Pinhole => 1.0,
            EmissionModel::ThinLens { object_distance, image_distance, pixel_pitch } => {
                let omega = (object_distance / s).powi(2);
                let area = (pixel_pitch * s / image_distance).powi(2);
                let focal = (pixel_pitch * object_distance / image_distance).powi(2);
                omega * area / focal
            }
        }
    }
}

/// Quadrature options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quadrature {
    /// Add the end pieces `[s_near, s_1]` and `[s_N, s_far]` (see the module docs). Default true.
    pub close_ends: bool,
}

impl Default for Quadrature {
    fn default() -> Self {
        Quadrature { close_ends: true }
    }
}

/// Per-sample weights `w_j` (Eq. 5.4) such that `I = scale · Σ_j w_j E_j`, for sorted samples
/// `s` on `[near, far]`. `w` has the length of `s`.
pub fn quadrature_weights(
    s: &[f32],
    near: f32,
    far: f32,
    model: &EmissionModel,
    quad: &Quadrature,
    scale: f32,
    w: &mut [f32],
) {
    assert_eq!(s.len(), w.len(), "quadrature_weights: s and w differ in length");
    let n = s.len();
    w.fill(0.0);
    if n == 0 {
        return;
    }
    for j in 0..n - 1 {
        let ds = s[j + 1] - s[j];
        let half = 0.5 * ds * model.relative_weight(0.5 * (s[j] + s[j + 1])) * scale;
        w[j] += half;
        w[j + 1] += half;
    }
    if quad.close_ends {
        let lead = s[0] - near;
        if lead > 0.0 {
            w[0] += lead * model.relative_weight(0.5 * (near + s[0])) * scale;
        }
        let tail = far - s[n - 1];
        if tail > 0.0 {
            w[n - 1] += tail * model.relative_weight(0.5 * (s[n - 1] + far)) * scale;
        }
    }
}

/// The rendered pixel `Σ_j w_j E_j`.
#[inline]
pub fn render(w: &[f32], e: &[f32]) -> f32 {
    assert_eq!(w.len(), e.len(), "render: w and e differ in length");
    w.iter().zip(e).map(|(a, b)| a * b).sum()
}

/// Backward of [`render`]: `d_e[j] = d_pixel · w_j` (overwrites `d_e`).
#[inline]
pub fn render_backward(w: &[f32], d_pixel: f32, d_e: &mut [f32]) {
    assert_eq!(w.len(), d_e.len(), "render_backward: w and d_e differ in length");
    for (d, &wj) in d_e.iter_mut().zip(w) {
        *d = d_pixel * wj;
    }
}

/// One pixel's share of the MSE loss (Eq. 5.5) over `n_pix` pixels and its derivative with
/// respect to the rendered value: `((I − Î)² / n_pix, 2 (I − Î) / n_pix)`.
#[inline]
pub fn mse_term(rendered: f32, measured: f32, n_pix: usize) -> (f32, f32) {
    let r = rendered - measured;
    let inv = 1.0 / n_pix as f32;
    (r * r * inv, 2.0 * r * inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::ThinLens;

    #[test]
    fn constant_field_integrates_to_chord() {
        let s = [1.3f32, 1.9, 2.2, 3.7, 4.1];
        let mut w = [0.0; 5];
        quadrature_weights(&s, 1.0, 4.5, &EmissionModel::Pinhole, &Quadrature::default(), 1.0, &mut w);
        let i = render(&w, &[2.0; 5]);
        assert!((i - 2.0 * 3.5).abs() < 1e-5, "{i}");
        // Without the end pieces only [s_1, s_N] is covered.
        quadrature_weights(&s, 1.0, 4.5, &EmissionModel::Pinhole, &Quadrature { close_ends: false }, 1.0, &mut w);
        assert!((render(&w, &[2.0; 5]) - 2.0 * 2.8).abs() < 1e-5);
    }

    #[test]
    fn thin_lens_weight_is_constant_like_a_pinhole() {
        let lens = ThinLens::from_f_number(60.0, 3.5, -0.2, 0.01);
        let m = EmissionModel::ThinLens {
            object_distance: lens.object_distance() as f32,
            image_distance: lens.image_distance() as f32,
            pixel_pitch: lens.pixel_pitch as f32,
        };
        for s in [250.0f32, 340.0, 360.0, 420.0] {
            assert!((m.relative_weight(s) - 1.0).abs() < 1e-5, "at s = {s}: {}", m.relative_weight(s));
            // And it agrees with the core's absolute weight up to the focal-plane constant.
            let core = lens.emission_weight(s as f64) / lens.emission_weight(lens.object_distance());
            assert!((m.relative_weight(s) as f64 - core).abs() < 1e-5);
        }
    }

    #[test]
    fn rendering_backward_matches_finite_differences() {
        let s = [0.2f32, 0.5, 0.55, 0.9, 1.4, 1.7];
        let mut w = [0.0; 6];
        quadrature_weights(&s, 0.0, 2.0, &EmissionModel::Pinhole, &Quadrature::default(), 0.7, &mut w);
        let e = [0.1f32, 0.8, 0.4, 1.3, 0.2, 0.05];
        let measured = 0.6;
        let loss = |e: &[f32]| mse_term(render(&w, e), measured, 3).0 as f64;
        let (_, d_pix) = mse_term(render(&w, &e), measured, 3);
        let mut d_e = [0.0; 6];
        render_backward(&w, d_pix, &mut d_e);
        for j in 0..6 {
            let h = 1e-3;
            let mut p = e;
            p[j] += h;
            let lp = loss(&p);
            p[j] -= 2.0 * h;
            let lm = loss(&p);
            let fd = (lp - lm) / (2.0 * h as f64);
            assert!((fd - d_e[j] as f64).abs() < 1e-4, "sample {j}: fd {fd} vs {}", d_e[j]);
        }
    }
}
