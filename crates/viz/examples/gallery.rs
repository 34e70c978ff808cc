//! Writes sample pictures of a synthetic jet into the folder given as the first argument
//! (default `gallery`): slices, a truth | reconstruction | difference comparison, convergence
//! plots and an isosurface. For looking at the pictures while changing the drawing code.

use std::path::PathBuf;

use fluidnerf_core::{Aabb, Volume};
use fluidnerf_viz::{
    convergence_plots, format_value, slice, sweep_plot, write_comparison_png, write_panels_png, write_plots,
    write_report_html, Axis, Colormap, Figure, ImageData, PanelStyle, Report, RunHistory, Series, Table, Trace,
};
use glam::DVec3;

fn jet(p: DVec3) -> f32 {
    // A plume along +x that widens and wobbles downstream.
    let s = 1.0 + 0.08 * p.x;
    let yc = 1.5 * (0.3 * p.x).sin();
    let r2 = ((p.y - yc) / s).powi(2) + (p.z / s).powi(2);
    ((-r2 / 8.0).exp() * (1.0 - (-(p.x + 2.0) / 6.0).exp()).max(0.0)) as f32
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "gallery".into()));
    std::fs::create_dir_all(&out)?;
    let aabb = Aabb::new(DVec3::new(0.0, -10.0, -10.0), DVec3::new(40.0, 10.0, 10.0));
    let truth = Volume::from_fn([64, 32, 32], aabb, jet);
    let recon = Volume::from_fn([64, 32, 32], aabb, |p| {
        jet(p) * (1.0 + 0.1 * (0.7 * p.y).sin() as f32) + 0.02 * (0.5 * p.x + p.z).cos() as f32
    });
    let style = PanelStyle { colorbar_label: "emission E [a.u./mm]".into(), ..Default::default() };
    let slices: Vec<_> = [(Axis::Z, 0.5), (Axis::Y, 0.5), (Axis::X, 0.5)]
        .iter()
        .map(|&(a, f)| slice(&truth, a, a.position_at(&aabb, f), "mm"))
        .collect::<Result<_, _>>()?;
    write_panels_png(
        &out.join("slices.png"),
        &slices,
        &PanelStyle { figure_title: Some("Synthetic jet, mid-plane slices".into()), ..style.clone() },
    )?;
    let t = slice(&truth, Axis::Z, 0.0, "mm")?;
    let r = slice(&recon, Axis::Z, 0.0, "mm")?;
    write_comparison_png(
        &out.join("compare_z.png"),
        &t,
        &r,
        &PanelStyle { colormap: Colormap::Magma, ..style.clone() },
    )?;
    let t = slice(&truth, Axis::X, 20.0, "mm")?;
    let r = slice(&recon, Axis::X, 20.0, "mm")?;
    write_comparison_png(&out.join("compare_x.png"), &t, &r, &style)?;
    let trace = |rate: f64, dt: f64, floor: f64| Trace {
        iteration: (0..200).map(f64::from).collect(),
        time_s: (0..200).map(|i| f64::from(i) * dt).collect(),
        value: (0..200).map(|i| floor + (-rate * f64::from(i)).exp()).collect(),
    };
    let runs = [
        RunHistory {
            label: "ASART".into(),
            loss_label: "residual".into(),
            loss: trace(0.05, 0.1, 0.01),
            nrmse: Some(trace(0.03, 0.1, 0.12)),
            ssim: Some(Trace {
                value: (0..200).map(|i| 0.9 - 0.6 * (-0.03 * f64::from(i)).exp()).collect(),
                ..trace(0.0, 0.1, 0.0)
            }),
            kept: None,
        },
        RunHistory {
            label: "FluidNeRF (fast)".into(),
            loss_label: "loss".into(),
            loss: trace(0.02, 0.4, 0.001),
            nrmse: Some(trace(0.02, 0.4, 0.05)),
            ssim: Some(Trace {
                value: (0..200).map(|i| 0.97 - 0.8 * (-0.02 * f64::from(i)).exp()).collect(),
                ..trace(0.0, 0.4, 0.0)
            }),
            // Kept by held-out early stopping before the end: marked on its curves.
            kept: Some(120.0),
        },
    ];
    let plots = convergence_plots(&runs);
    write_plots(&out.join("convergence.png"), &plots, 2)?;
    write_plots(&out.join("convergence.svg"), &plots, 2)?;
    let sweep = sweep_plot(
        "number of cameras",
        "NRMSE",
        false,
        vec![
            Series { label: "ASART".into(), x: vec![2.0, 4.0, 6.0, 8.0], y: vec![0.45, 0.25, 0.18, 0.15], mark: None },
            Series {
                label: "FluidNeRF".into(),
                x: vec![2.0, 4.0, 6.0, 8.0],
                y: vec![0.35, 0.15, 0.1, 0.08],
                mark: None,
            },
        ],
    );
    write_plots(&out.join("sweep.png"), &[sweep], 1)?;
    // A residual that falls by less than a decade: drawn on a linear axis.
    let narrow = RunHistory {
        label: "ASART".into(),
        loss_label: "relative residual".into(),
        loss: Trace { value: (0..25).map(|i| 0.16 + (-0.5 * f64::from(i)).exp()).collect(), ..trace(0.0, 0.1, 0.0) },
        nrmse: None,
        ssim: None,
        kept: None,
    };
    let narrow = RunHistory {
        loss: Trace {
            iteration: narrow.loss.iteration[..25].to_vec(),
            time_s: narrow.loss.time_s[..25].to_vec(),
            ..narrow.loss
        },
        ..narrow
    };
    write_plots(&out.join("narrow.png"), &convergence_plots(&[narrow]), 2)?;
    let mut table = Table::new("Against the ground truth", &["method", "NRMSE", "PSNR [dB]", "SSIM", "time [s]"]);
    table.push_row(vec![
        "ASART".into(),
        format_value(0.121),
        format_value(24.3),
        format_value(0.89),
        format_value(20.0),
    ]);
    table.push_row(vec![
        "FluidNeRF (fast)".into(),
        format_value(0.068),
        format_value(29.1),
        format_value(0.95),
        format_value(80.0),
    ]);
    let figure = |caption: &str, file: &str| -> Result<Figure, fluidnerf_viz::VizError> {
        Ok(Figure { caption: caption.into(), image: ImageData::from_file(&out.join(file))? })
    };
    let report = Report {
        title: "Synthetic jet: gallery".into(),
        subtitle: "made-up numbers, for checking the layout".into(),
        summary: vec![("scene".into(), "gallery jet".into()), ("resolution".into(), "64 × 32 × 32".into())],
        tables: vec![table],
        figures: vec![
            figure("Mid-plane slices of the truth", "slices.png")?,
            figure("Truth | reconstruction | difference at z = 0", "compare_z.png")?,
            figure("Convergence", "convergence.svg")?,
        ],
        settings: Some(serde_json::json!({"method": "fast", "seed": 0, "resolution": 64})),
        notes: vec!["The reconstruction here is the truth with a made-up error.".into()],
    };
    write_report_html(&out.join("report.html"), &report)?;
    Ok(())
}
