//! Writes sample pictures of a synthetic jet into the folder given as the first argument
//! (default `gallery`): slices, a truth | reconstruction | difference comparison, convergence
//! plots and an isosurface. For looking at the pictures while changing the drawing code.

use std::path::PathBuf;

use fluidnerf_core::{Aabb, Volume};
use fluidnerf_viz::{slice, write_comparison_png, write_panels_png, Axis, Colormap, PanelStyle};
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
    Ok(())
}
