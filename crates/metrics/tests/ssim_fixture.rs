//! Windowed SSIM against values recorded from `skimage.metrics.structural_similarity` by
//! `fixtures/make_ssim_fixture.py` (which documents the arrays; this file rebuilds them
//! bit-for-bit and checks their sums first).

use fluidnerf_metrics::{ssim_2d, ssim_3d, SsimParams};
use serde_json::Value;

/// The fixture script's `pattern`, for a numpy shape (slowest axis first), x fastest.
fn pattern(shape: &[usize], variant: u32) -> Vec<f32> {
    let n: usize = shape.iter().product();
    let mix = (0.25 + 0.1 * variant as f64) as f32;
    (0..n)
        .map(|lin| {
            let mut h = (lin as u32).wrapping_mul(2_654_435_761).wrapping_add(variant.wrapping_mul(40_503));
            h = (h ^ (h >> 13)).wrapping_mul(1_274_126_177);
            h ^= h >> 16;
            let noise = (h % 1024) as f32 / 1024.0;
            let mut rest = lin;
            let mut idx = vec![0usize; shape.len()];
            for a in (0..shape.len()).rev() {
                idx[a] = rest % shape[a];
                rest /= shape[a];
            }
            let mut smooth = 0f32;
            for a in 0..shape.len() {
                let c = idx[a] as f32 / shape[a] as f32;
                smooth += c * (0.5 + 0.25 * a as f64) as f32;
            }
            smooth + mix * noise
        })
        .collect()
}

#[test]
fn windowed_ssim_matches_skimage() {
    let text = include_str!("fixtures/ssim_skimage.json");
    let fixture: Value = serde_json::from_str(text).expect("fixture is valid JSON");
    let cases = fixture["cases"].as_array().expect("cases");
    assert_eq!(cases.len(), 4);
    for case in cases {
        let name = case["name"].as_str().expect("name");
        let shape: Vec<usize> =
            case["shape"].as_array().expect("shape").iter().map(|v| v.as_u64().expect("dim") as usize).collect();
        let (a, b) = (pattern(&shape, 1), pattern(&shape, 2));
        let sum = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>();
        assert!(
            (sum(&a) - case["sum_a"].as_f64().expect("sum_a")).abs() < 1e-9,
            "{name}: array a differs from the script's"
        );
        assert!(
            (sum(&b) - case["sum_b"].as_f64().expect("sum_b")).abs() < 1e-9,
            "{name}: array b differs from the script's"
        );
        let base =
            if case["gaussian"].as_bool().expect("gaussian") { SsimParams::gaussian() } else { SsimParams::default() };
        let params = SsimParams { data_range: case["data_range"].as_f64(), ..base };
        let got = match shape.len() {
            2 => ssim_2d(&a, &b, shape[1], shape[0], &params),
            _ => ssim_3d(&a, &b, [shape[2], shape[1], shape[0]], &params),
        }
        .expect("window fits");
        let want = case["ssim"].as_f64().expect("ssim");
        assert!((got - want).abs() < 1e-4, "{name}: {got} vs skimage {want}");
        // Both sides work in f64 on the same f32 inputs: agreement to rounding (measured
        // ≤ 5e-15).
        assert!((got - want).abs() < 1e-12, "{name}: {got} vs skimage {want} (diff {:.2e})", (got - want).abs());
    }
}
