//! Pictures, plots, isosurfaces and self-contained HTML reports of fluidnerf reconstructions.
//!
//! # Conventions
//! - **World frame and units** as in `fluidnerf-core`: lengths in the scene's unit (usually mm),
//!   jets flow along +x. Axis labels carry the unit, colour bars the field's unit.
//! - **Panels** ([`Panel`]) hold a 2D f32 array, row-major, **row 0 at the bottom** (the
//!   extent's lower edge, as in a plot with `origin = "lower"`), so a slice of a volume reads
//!   with world axes pointing right and up. Camera images (row 0 at the top) are flipped by
//!   [`Panel::from_image`].
//! - **Slices** ([`slice()`]) through a [`Volume`](fluidnerf_core::Volume): normal to z shows
//!   (x → right, y → up); normal to y shows (x → right, z → up); normal to x shows
//!   (y → right, z → up). Cells are drawn nearest-neighbour, so voxels stay visible.
//! - **Colour maps** are perceptually uniform (viridis, magma, inferno, cividis) for fields and
//!   diverging (blue–white–red, symmetric about zero) for differences ([`Colormap`]).
//! - **Text** is drawn with the DejaVu Sans font compiled into the binary (the `dejavu` crate),
//!   so pictures look the same on every machine; no system font or fontconfig is used.
//! - **Files** are written atomically (a temporary file in the same folder, then a rename).
//!
//! # What is where
//! - [`panel`]: slices of volumes and heat-map figures ([`write_panels_png`],
//!   [`write_comparison_png`] for truth | reconstruction | difference).
//! - [`plot`]: convergence and sweep plots, PNG or SVG ([`convergence_plots`], [`write_plots`]).
//! - [`isosurface`]: watertight marching cubes ([`marching_cubes`]); write the mesh with
//!   `fluidnerf_io::mesh`.
//! - [`animation`]: colour-mapped camera images, orbit cameras about the flow axis, turntable
//!   GIFs.
//! - [`report`]: the self-contained `report.html` ([`write_report_html`]).
//!
//! The library never prints; problems come back as [`VizError`] and warnings go to `log`.

pub mod animation;
mod colormap;
mod error;
mod font;
pub mod isosurface;
mod output;
pub mod panel;
pub mod plot;
pub mod report;

pub use animation::{
    colorize, encode_image_png, orbit_cameras, orbit_cameras_about, write_turntable_gif, TurntableClipping,
};
pub use colormap::Colormap;
pub use error::VizError;
pub use isosurface::{enclosed_volume_within, marching_cubes, marching_cubes_within, TriMesh};

pub use panel::{
    comparison_groups, encode_panels_png, slice, write_comparison_png, write_panel_groups_png, write_panels_png, Axis,
    Panel, PanelGroup, PanelStyle, ValueRange,
};
pub use plot::{
    convergence_plots, encode_plots_png, encode_plots_svg, sweep_plot, write_plots, LinePlot, RunHistory, Series, Trace,
};
pub use report::{format_value, write_report_html, Figure, ImageData, Report, Table};
