//! Heat-map panels: slices of volumes (or any 2D array) drawn with world axes in length units,
//! equal aspect ratio, a title and a colour bar in field units; several panels side by side,
//! e.g. truth | reconstruction | difference.
//!
//! Layout: panels stand in one row, top-aligned. A [`PanelGroup`] is a run of panels that share
//! a colour map and (unless [`ValueRange::PerPanel`]) one value range and one colour bar, drawn
//! to the right of the group. Each panel's plot area has the shape of its world extent (equal
//! axes); the longer side is [`PanelStyle::plot_size_px`] pixels, or up to 2.5 times that for
//! elongated extents.

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use fluidnerf_core::num;
use fluidnerf_core::{Aabb, Image, Volume};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use serde::{Deserialize, Serialize};

use crate::{font, output, Colormap, VizError};

/// A world axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// 0, 1 or 2.
    pub fn index(self) -> usize {
        self as usize
    }

    /// `"x"`, `"y"` or `"z"`.
    pub fn name(self) -> &'static str {
        ["x", "y", "z"][self.index()]
    }

    /// The world axes shown (horizontal, vertical) on a slice normal to `self`.
    pub fn in_plane(self) -> (Axis, Axis) {
        match self {
            Axis::X => (Axis::Y, Axis::Z),
            Axis::Y => (Axis::X, Axis::Z),
            Axis::Z => (Axis::X, Axis::Y),
        }
    }

    /// The world coordinate at `fraction` of the box along this axis (0 = min, 1 = max).
    pub fn position_at(self, aabb: &Aabb, fraction: f64) -> f64 {
        let a = self.index();
        aabb.min[a] + fraction * (aabb.max[a] - aabb.min[a])
    }
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Axis {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "x" => Ok(Axis::X),
            "y" => Ok(Axis::Y),
            "z" => Ok(Axis::Z),
            _ => Err(format!("unknown axis {s:?}; expected x, y or z")),
        }
    }
}

/// A 2D array to draw as a heat map with world axes.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// Cells along the horizontal axis.
    pub width: usize,
    /// Cells along the vertical axis.
    pub height: usize,
    /// Row-major values, `data[row * width + col]`, **row 0 at the bottom** (`extent[2]`).
    pub data: Vec<f32>,
    /// Drawn above the panel.
    pub title: String,
    /// Horizontal axis label with its unit, e.g. `"x [mm]"`.
    pub x_label: String,
    /// Vertical axis label with its unit.
    pub y_label: String,
    /// World extent of the array's outer cell edges: `[x_min, x_max, y_min, y_max]`.
    pub extent: [f64; 4],
}

impl Panel {
    /// A panel without title or labels. Panics if `data` does not hold `width × height` values
    /// or the extent is empty.
    pub fn new(width: usize, height: usize, data: Vec<f32>, extent: [f64; 4]) -> Self {
        assert!(width > 0 && height > 0, "Panel::new: {width}x{height} must be positive");
        assert_eq!(data.len(), width * height, "Panel::new: {width}x{height} needs {} values", width * height);
        assert!(
            extent[1] > extent[0] && extent[3] > extent[2] && extent.iter().all(|e| e.is_finite()),
            "Panel::new: extent {extent:?} must be finite and increasing"
        );
        Panel { width, height, data, title: String::new(), x_label: String::new(), y_label: String::new(), extent }
    }

    /// Sets the title.
    pub fn with_title(mut self, title: impl Into<String>) -> Self {
        self.title = title.into();
        self
    }

    /// Sets both axis labels (include the unit: `"x [mm]"`).
    pub fn with_labels(mut self, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        self.x_label = x_label.into();
        self.y_label = y_label.into();
        self
    }

    /// A camera image as a panel in pixel units (row 0 of the image, its top, ends up on top).
    pub fn from_image(image: &Image) -> Self {
        let (w, h) = (image.width, image.height);
        let mut data = Vec::with_capacity(w * h);
        for row in (0..h).rev() {
            data.extend_from_slice(&image.data[row * w..(row + 1) * w]);
        }
        Panel::new(w, h, data, [0.0, w as f64, 0.0, h as f64]).with_labels("u [px]", "v [px] (from bottom)")
    }

    /// `other − self`, cell by cell, with `self`'s labels and extent and an empty title.
    /// Panics if the shapes differ.
    pub fn difference(&self, other: &Panel) -> Panel {
        assert!(
            self.width == other.width && self.height == other.height,
            "Panel::difference: {}x{} vs {}x{}",
            self.width,
            self.height,
            other.width,
            other.height
        );
        let data = self.data.iter().zip(&other.data).map(|(a, b)| b - a).collect();
        Panel { data, title: String::new(), ..self.clone() }
    }

    /// Smallest and largest finite value, `None` if there is none.
    pub fn finite_range(&self) -> Option<(f32, f32)> {
        finite_range(self.data.iter().copied())
    }
}

fn finite_range(values: impl Iterator<Item = f32>) -> Option<(f32, f32)> {
    values
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| Some(acc.map_or((v, v), |(lo, hi): (f32, f32)| (lo.min(v), hi.max(v)))))
}

/// How the colour scale's limits are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ValueRange {
    /// From the smallest to the largest finite value over all panels of the group, one colour
    /// bar for the group (symmetric about zero for diverging maps).
    Shared,
    /// Each panel its own range and colour bar.
    PerPanel,
    /// Fixed limits; values outside saturate.
    Fixed { min: f32, max: f32 },
}

/// How panels are drawn.
#[derive(Clone, Debug, PartialEq)]
pub struct PanelStyle {
    /// Default [`Colormap::Viridis`].
    pub colormap: Colormap,
    /// Default [`ValueRange::Shared`].
    pub range: ValueRange,
    /// Colour-bar label with the field's unit, e.g. `"emission [1/mm]"`. Default `"value"`.
    pub colorbar_label: String,
    /// Pixels along the longer side of a panel's plot area. Default 320.
    pub plot_size_px: u32,
    /// A title over the whole figure. Default none.
    pub figure_title: Option<String>,
}

impl Default for PanelStyle {
    fn default() -> Self {
        PanelStyle {
            colormap: Colormap::Viridis,
            range: ValueRange::Shared,
            colorbar_label: "value".into(),
            plot_size_px: 320,
            figure_title: None,
        }
    }
}

/// Panels sharing a style (and, unless per-panel, a colour bar).
#[derive(Clone, Debug, PartialEq)]
pub struct PanelGroup {
    pub panels: Vec<Panel>,
    pub style: PanelStyle,
}

/// The slice of `volume` normal to `axis` at world coordinate `position`, interpolated
/// linearly between the two nearest planes of cell centres (as [`Volume::sample`] does) and
/// drawn with the cells of the other two axes. Orientation: see the crate docs. Axis labels
/// read `"x [units]"`; the title `"z = 12.50 mm"`.
pub fn slice(volume: &Volume, axis: Axis, position: f64, units: &str) -> Result<Panel, VizError> {
    let a = axis.index();
    let (lo, hi) = (volume.aabb.min[a], volume.aabb.max[a]);
    if !(position >= lo && position <= hi) {
        return Err(VizError::invalid(
            "slice position",
            format!("{axis} = {} {units} lies outside the volume's box [{}, {}]", num(position), num(lo), num(hi)),
        ));
    }
    let n = volume.dims[a];
    let g = ((position - lo) / (hi - lo) * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
    let i0 = g.floor() as usize;
    let i1 = (i0 + 1).min(n - 1);
    let w = (g - i0 as f64) as f32;
    let (h_axis, v_axis) = axis.in_plane();
    let (nh, nv) = (volume.dims[h_axis.index()], volume.dims[v_axis.index()]);
    let mut data = Vec::with_capacity(nh * nv);
    for r in 0..nv {
        for c in 0..nh {
            let at = |k: usize| {
                let mut ijk = [0usize; 3];
                ijk[a] = k;
                ijk[h_axis.index()] = c;
                ijk[v_axis.index()] = r;
                volume.get(ijk[0], ijk[1], ijk[2])
            };
            data.push(at(i0) * (1.0 - w) + at(i1) * w);
        }
    }
    let (hb, vb) = (h_axis.index(), v_axis.index());
    let extent = [volume.aabb.min[hb], volume.aabb.max[hb], volume.aabb.min[vb], volume.aabb.max[vb]];
    Ok(Panel::new(nh, nv, data, extent)
        .with_title(format!("{axis} = {} {units}", format_number(position)))
        .with_labels(format!("{h_axis} [{units}]"), format!("{v_axis} [{units}]")))
}

/// Truth | reconstruction | difference: the first two share `style` and one colour bar (the
/// range spans both unless `style.range` is fixed); the difference `reconstruction − truth` uses
/// the diverging map, symmetric about zero, with its own colour bar. Titles are prefixed with
/// "truth", "reconstruction" and "reconstruction − truth"; the difference's colour bar label
/// is `style.colorbar_label` prefixed with "Δ". Panics if the shapes differ.
pub fn comparison_groups(truth: &Panel, recon: &Panel, style: &PanelStyle) -> Vec<PanelGroup> {
    let prefixed = |p: &Panel, what: &str| {
        let title = if p.title.is_empty() { what.to_string() } else { format!("{what}, {}", p.title) };
        Panel { title, ..p.clone() }
    };
    let mut diff = truth.difference(recon);
    diff.title = if truth.title.is_empty() {
        "reconstruction − truth".into()
    } else {
        format!("reconstruction − truth, {}", truth.title)
    };
    let first = PanelStyle {
        range: if style.range == ValueRange::PerPanel { ValueRange::Shared } else { style.range },
        ..style.clone()
    };
    let second = PanelStyle {
        colormap: Colormap::Diverging,
        range: ValueRange::Shared,
        colorbar_label: format!("Δ {}", style.colorbar_label),
        figure_title: None,
        ..style.clone()
    };
    vec![
        PanelGroup { panels: vec![prefixed(truth, "truth"), prefixed(recon, "reconstruction")], style: first },
        PanelGroup { panels: vec![diff], style: second },
    ]
}

/// Draws `panels` in one row with `style` and writes a PNG (atomically).
pub fn write_panels_png(path: &Path, panels: &[Panel], style: &PanelStyle) -> Result<(), VizError> {
    write_panel_groups_png(path, &[PanelGroup { panels: panels.to_vec(), style: style.clone() }])
}

/// [`comparison_groups`] written to a PNG.
pub fn write_comparison_png(path: &Path, truth: &Panel, recon: &Panel, style: &PanelStyle) -> Result<(), VizError> {
    write_panel_groups_png(path, &comparison_groups(truth, recon, style))
}

/// Draws the groups left to right and writes a PNG (atomically). The figure title is the first
/// group's [`PanelStyle::figure_title`].
pub fn write_panel_groups_png(path: &Path, groups: &[PanelGroup]) -> Result<(), VizError> {
    let png = encode_panels_png(groups)?;
    output::write_atomic(path, &png)
}

/// Draws the groups left to right and returns the PNG bytes (for embedding in a report).
pub fn encode_panels_png(groups: &[PanelGroup]) -> Result<Vec<u8>, VizError> {
    let (rgb, w, h) = draw_groups(groups)?;
    output::encode_rgb_png(&rgb, w, h, "panel figure")
}

// Layout constants, in pixels.
const TITLE_H: u32 = 34;
const FIG_TITLE_H: u32 = 40;
const LEFT: u32 = 64;
const BOTTOM: u32 = 50;
const RIGHT: u32 = 16;
const GAP: u32 = 8;
const BAR_W: u32 = 18;
const BAR_TICKS: u32 = 58;
const BAR_LABELS: u32 = BAR_TICKS + 28;
const OUTER: u32 = 10;

/// A run of panels with one colour scale.
struct Block<'a> {
    panels: Vec<&'a Panel>,
    colormap: Colormap,
    lo: f32,
    hi: f32,
    label: &'a str,
}

fn blocks(groups: &[PanelGroup]) -> Vec<Block<'_>> {
    let mut out = Vec::new();
    for g in groups {
        let runs: Vec<Vec<&Panel>> = match g.style.range {
            ValueRange::PerPanel => g.panels.iter().map(|p| vec![p]).collect(),
            _ => vec![g.panels.iter().collect()],
        };
        for run in runs {
            let (lo, hi) = match g.style.range {
                ValueRange::Fixed { min, max } => (min, max),
                _ => {
                    let r = finite_range(run.iter().flat_map(|p| p.data.iter().copied())).unwrap_or((0.0, 1.0));
                    if g.style.colormap.is_diverging() {
                        let m = r.0.abs().max(r.1.abs());
                        (-m, m)
                    } else {
                        r
                    }
                }
            };
            let (lo, hi) = widen(lo, hi);
            out.push(Block { panels: run, colormap: g.style.colormap, lo, hi, label: &g.style.colorbar_label });
        }
    }
    out
}

/// Makes a degenerate or reversed range drawable.
fn widen(lo: f32, hi: f32) -> (f32, f32) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    if hi - lo > f32::EPSILON * lo.abs().max(hi.abs()).max(1e-30) {
        (lo, hi)
    } else {
        let d = (lo.abs() * 0.05).max(1e-6);
        (lo - d, hi + d)
    }
}

/// Plot-area size of a panel: equal axes, longer side `size`, at most 2.5 × `size` wide.
fn plot_dims(p: &Panel, size: u32) -> (u32, u32) {
    let aspect = (p.extent[1] - p.extent[0]) / (p.extent[3] - p.extent[2]);
    let s = size as f64;
    let (w, h) = if aspect >= 1.0 {
        let w = (s * aspect).min(2.5 * s);
        (w, w / aspect)
    } else {
        (s * aspect, s)
    };
    ((w.round() as u32).max(8), (h.round() as u32).max(8))
}

fn text_width(text: &str, size: f64, bold: bool) -> u32 {
    let style = if bold { FontStyle::Bold } else { FontStyle::Normal };
    FontDesc::new(FontFamily::Name(font::FAMILY), size, style).box_size(text).map_or(0, |(w, _)| w)
}

const TITLE_FONT: f64 = 17.0;
const LABEL_FONT: f64 = 15.0;
const TICK_FONT: f64 = 13.0;

struct PlacedPanel<'a> {
    panel: &'a Panel,
    x: u32,
    cell_w: u32,
    plot: (u32, u32),
}

struct PlacedBar {
    x: u32,
    height: u32,
    block: usize,
}

/// Renders the figure into an RGB buffer; returns it with its width and height.
fn draw_groups(groups: &[PanelGroup]) -> Result<(Vec<u8>, u32, u32), VizError> {
    font::ensure_registered()?;
    let blocks = blocks(groups);
    if blocks.iter().all(|b| b.panels.is_empty()) {
        return Err(VizError::invalid("panel figure", "there are no panels to draw"));
    }
    let size = groups[0].style.plot_size_px.max(64);
    let fig_title = groups[0].style.figure_title.as_deref().filter(|t| !t.is_empty());

    // Place the cells left to right.
    let mut panels = Vec::new();
    let mut bars = Vec::new();
    let mut x = OUTER;
    let mut max_plot_h = 0;
    for (b, block) in blocks.iter().enumerate() {
        let mut block_h = 0;
        for p in &block.panels {
            let plot = plot_dims(p, size);
            let need = LEFT + plot.0 + RIGHT;
            let cell_w = need.max(text_width(&p.title, TITLE_FONT, true) + 12);
            panels.push(PlacedPanel { panel: p, x, cell_w, plot });
            x += cell_w + GAP;
            block_h = block_h.max(plot.1);
        }
        if block.panels.is_empty() {
            continue;
        }
        bars.push(PlacedBar { x, height: block_h, block: b });
        x += GAP + BAR_W + BAR_LABELS + 3 * GAP;
        max_plot_h = max_plot_h.max(block_h);
    }
    let top = OUTER + fig_title.map_or(0, |_| FIG_TITLE_H);
    let mut width = x + OUTER - 3 * GAP;
    if let Some(t) = fig_title {
        width = width.max(text_width(t, 20.0, true) + 2 * OUTER);
    }
    let height = top + TITLE_H + max_plot_h + BOTTOM + OUTER;

    let mut buf = vec![255u8; (width * height * 3) as usize];
    let mut plot_rects = Vec::new();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| VizError::draw("background", e))?;
        if let Some(t) = fig_title {
            let style = TextStyle::from((font::FAMILY, 20.0, FontStyle::Bold).into_font())
                .pos(Pos::new(HPos::Center, VPos::Top));
            root.draw_text(t, &style, ((width / 2) as i32, OUTER as i32)).map_err(|e| VizError::draw("title", e))?;
        }
        for placed in &panels {
            let rect = draw_panel_frame(&root, placed, top)?;
            plot_rects.push(rect);
        }
        for bar in &bars {
            draw_colorbar_axes(&root, bar, &blocks[bar.block], top)?;
        }
        root.present().map_err(|e| VizError::draw("panel figure", e))?;
    }

    // Fill the plot areas with the cells, nearest-neighbour, and draw the colour bars.
    let mut block_of_panel = Vec::new();
    for (b, block) in blocks.iter().enumerate() {
        block_of_panel.extend(std::iter::repeat_n(b, block.panels.len()));
    }
    for ((placed, rect), &b) in panels.iter().zip(&plot_rects).zip(&block_of_panel) {
        let block = &blocks[b];
        let p = placed.panel;
        let (x0, y0, pw, ph) = *rect;
        for py in 0..ph {
            let row = p.height - 1 - (((py as f64 + 0.5) / ph as f64 * p.height as f64) as usize).min(p.height - 1);
            for px in 0..pw {
                let col = (((px as f64 + 0.5) / pw as f64 * p.width as f64) as usize).min(p.width - 1);
                let v = p.data[row * p.width + col];
                put(&mut buf, width, x0 + px, y0 + py, block.colormap.rgb_in(v, block.lo, block.hi));
            }
        }
        frame(&mut buf, width, *rect);
    }
    for bar in &bars {
        let block = &blocks[bar.block];
        let rect = (bar.x + GAP, top + TITLE_H, BAR_W, bar.height);
        for py in 0..rect.3 {
            let t = 1.0 - (py as f64 + 0.5) / rect.3 as f64;
            let c = block.colormap.rgb(t);
            for px in 0..rect.2 {
                put(&mut buf, width, rect.0 + px, rect.1 + py, c);
            }
        }
        frame(&mut buf, width, rect);
    }
    Ok((buf, width, height))
}

fn put(buf: &mut [u8], width: u32, x: u32, y: u32, c: [u8; 3]) {
    let i = ((y * width + x) * 3) as usize;
    buf[i..i + 3].copy_from_slice(&c);
}

/// A one-pixel dark frame just outside `rect`.
fn frame(buf: &mut [u8], width: u32, (x0, y0, w, h): (u32, u32, u32, u32)) {
    let height = buf.len() as u32 / 3 / width;
    let c = [40, 40, 40];
    let (xl, xr) = (x0.saturating_sub(1), (x0 + w).min(width - 1));
    let (yt, yb) = (y0.saturating_sub(1), (y0 + h).min(height - 1));
    for x in xl..=xr {
        put(buf, width, x, yt, c);
        put(buf, width, x, yb, c);
    }
    for y in yt..=yb {
        put(buf, width, xl, y, c);
        put(buf, width, xr, y, c);
    }
}

/// Draws a panel's title and axes; returns its plot area `(x, y, w, h)` in pixels.
fn draw_panel_frame<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    placed: &PlacedPanel<'_>,
    top: u32,
) -> Result<(u32, u32, u32, u32), VizError> {
    let p = placed.panel;
    let (pw, ph) = placed.plot;
    let cell_h = TITLE_H + ph + BOTTOM;
    let area = root.clone().shrink((placed.x, top), (placed.cell_w, cell_h));
    let title_style =
        TextStyle::from((font::FAMILY, TITLE_FONT, FontStyle::Bold).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    area.draw_text(&p.title, &title_style, ((placed.cell_w / 2) as i32, 6))
        .map_err(|e| VizError::draw("panel title", e))?;
    let spare = placed.cell_w - (LEFT + pw + RIGHT);
    let mut chart = ChartBuilder::on(&area)
        .margin_top(TITLE_H)
        .margin_left(spare / 2)
        .margin_right(RIGHT + spare - spare / 2)
        .x_label_area_size(BOTTOM)
        .y_label_area_size(LEFT)
        .build_cartesian_2d(p.extent[0]..p.extent[1], p.extent[2]..p.extent[3])
        .map_err(|e| VizError::draw("panel axes", e))?;
    let fx = tick_formatter(p.extent[0], p.extent[1]);
    let fy = tick_formatter(p.extent[2], p.extent[3]);
    let n_x = ((pw / 70).clamp(2, 10)) as usize;
    let n_y = ((ph / 50).clamp(2, 10)) as usize;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(n_x)
        .y_labels(n_y)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .label_style((font::FAMILY, TICK_FONT))
        .axis_desc_style((font::FAMILY, LABEL_FONT))
        .draw()
        .map_err(|e| VizError::draw("panel axes", e))?;
    let (xr, yr) = chart.plotting_area().get_pixel_range();
    Ok((xr.start as u32, yr.start as u32, (xr.end - xr.start) as u32, (yr.end - yr.start) as u32))
}

fn draw_colorbar_axes<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    bar: &PlacedBar,
    block: &Block<'_>,
    top: u32,
) -> Result<(), VizError> {
    let cell_h = TITLE_H + bar.height + BOTTOM;
    let area = root.clone().shrink((bar.x, top), (GAP + BAR_W + BAR_LABELS, cell_h));
    let (lo, hi) = (block.lo as f64, block.hi as f64);
    let mut chart = ChartBuilder::on(&area)
        .margin_top(TITLE_H)
        .margin_left(GAP)
        .margin_bottom(BOTTOM)
        .set_label_area_size(LabelAreaPosition::Right, BAR_LABELS)
        .build_cartesian_2d(0f64..1f64, lo..hi)
        .map_err(|e| VizError::draw("colour bar", e))?;
    let f = tick_formatter(lo, hi);
    let n = ((bar.height / 45).clamp(2, 10)) as usize;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        // plotters sizes ticks by the plotting area, a few pixels wide here: without a size of
        // their own they are a dot and the labels touch the bar (a `0.77` reads `.77`).
        .set_tick_mark_size(LabelAreaPosition::Right, 5)
        .y_labels(n)
        .y_label_formatter(&f)
        .label_style((font::FAMILY, TICK_FONT))
        .draw()
        .map_err(|e| VizError::draw("colour bar", e))?;
    // plotters would put the label at the far edge of the label area; keep it next to the
    // tick labels, reading upwards like the y-axis labels.
    let style = TextStyle::from((font::FAMILY, LABEL_FONT).into_font())
        .pos(Pos::new(HPos::Center, VPos::Center))
        .transform(FontTransform::Rotate270);
    let x = (GAP + BAR_W + BAR_TICKS) as i32 + (LABEL_FONT as i32) / 2 + 2;
    let y = (TITLE_H + bar.height / 2) as i32;
    area.draw_text(block.label, &style, (x, y)).map_err(|e| VizError::draw("colour bar label", e))?;
    Ok(())
}

/// Tick labels with as many decimals as the range needs, scientific notation for very large or
/// very small magnitudes.
pub(crate) fn tick_formatter(lo: f64, hi: f64) -> impl Fn(&f64) -> String {
    let span = (hi - lo).abs().max(f64::MIN_POSITIVE);
    let mag = lo.abs().max(hi.abs());
    let scientific = !(1e-3..1e5).contains(&mag);
    // Enough decimals for ticks as fine as span / 50; trailing zeros are trimmed.
    let decimals = (-(span / 50.0).log10()).ceil().clamp(0.0, 8.0) as usize;
    move |v: &f64| {
        if v.abs() < span * 1e-9 {
            "0".to_string()
        } else if scientific {
            format!("{v:.1e}")
        } else {
            trim_zeros(format!("{v:.decimals$}"))
        }
    }
}

fn trim_zeros(s: String) -> String {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A number with four significant digits and no trailing zeros.
pub(crate) fn format_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (3 - v.abs().log10().floor() as i32).clamp(0, 8) as usize;
    trim_zeros(format!("{v:.decimals$}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn volume() -> Volume {
        let aabb = Aabb::new(DVec3::new(0.0, -1.0, -2.0), DVec3::new(8.0, 1.0, 2.0));
        Volume::from_fn([16, 4, 8], aabb, |p| (p.x + 10.0 * p.y + 100.0 * p.z) as f32)
    }

    #[test]
    fn slice_orientation_and_interpolation() {
        let v = volume();
        // Normal to z at a plane between two cell centres: linear field is reproduced.
        let s = slice(&v, Axis::Z, 0.3, "mm").expect("inside");
        assert_eq!((s.width, s.height), (16, 4));
        assert_eq!(s.extent, [0.0, 8.0, -1.0, 1.0]);
        // Row 0 is the bottom (y = -0.75), column 0 the left (x = 0.25).
        assert!((s.data[0] - (0.25 - 7.5 + 30.0)).abs() < 1e-4, "{}", s.data[0]);
        assert!((s.data[3 * 16 + 15] - (7.75 + 7.5 + 30.0)).abs() < 1e-4);
        assert_eq!(s.x_label, "x [mm]");
        assert_eq!(s.title, "z = 0.3 mm");
        let s = slice(&v, Axis::X, 4.0, "mm").expect("inside");
        assert_eq!((s.width, s.height), (4, 8));
        assert_eq!((s.x_label.as_str(), s.y_label.as_str()), ("y [mm]", "z [mm]"));
        assert!((s.data[0] - (4.0 - 7.5 - 175.0)).abs() < 1e-3, "{}", s.data[0]);
        assert!(slice(&v, Axis::Y, 1.5, "mm").is_err());
    }

    #[test]
    fn figure_has_equal_axes_and_writes_png() {
        let v = volume();
        let s = slice(&v, Axis::Z, 0.0, "mm").expect("inside");
        assert_eq!(plot_dims(&s, 200), (500, 125));
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("p.png");
        write_comparison_png(&path, &s, &s.difference(&s), &PanelStyle::default()).expect("writes");
        let img = image::open(&path).expect("reads back").to_rgb8();
        assert!(img.width() > 3 * 300 && img.height() > 150, "{}x{}", img.width(), img.height());
    }

    #[test]
    fn camera_images_keep_their_top_row_on_top() {
        let img = Image::from_vec(3, 2, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        let p = Panel::from_image(&img);
        // Panel row 0 is the bottom, so the image's top row (1, 2, 3) is the panel's last row.
        assert_eq!(p.data, vec![4.0, 5.0, 6.0, 1.0, 2.0, 3.0]);
        assert_eq!(p.extent, [0.0, 3.0, 0.0, 2.0]);
    }

    /// The colour bar's ticks stand out from it and its labels keep clear of them: with
    /// plotters' own tick size, a dot here, the labels touched the bar.
    #[test]
    fn colour_bar_ticks_are_marks_and_labels_keep_clear() {
        let s = slice(&volume(), Axis::Z, 0.0, "mm").expect("inside");
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("p.png");
        write_panels_png(&path, std::slice::from_ref(&s), &PanelStyle::default()).expect("writes");
        let img = image::open(&path).expect("reads back").to_rgb8();
        let dark = |x: u32, y: u32| img.get_pixel(x, y).0.iter().all(|&c| c < 128);
        // The bar's right frame: the rightmost long run of frame-grey pixels in a column.
        let frame = |x: u32| (0..img.height()).filter(|&y| img.get_pixel(x, y).0 == [40, 40, 40]).collect::<Vec<_>>();
        let xr = (0..img.width()).rev().find(|&x| frame(x).len() > 100).expect("the colour bar's frame");
        let rows = frame(xr);
        let (top, bottom) = (rows[0], rows[rows.len() - 1]);
        let ticks = (top..=bottom).filter(|&y| dark(xr + 3, y)).count();
        assert!(ticks >= 2, "{ticks} tick(s) 3 px right of the bar");
        for x in xr + 6..xr + 9 {
            assert!((top..=bottom).all(|y| !dark(x, y)), "column {} px right of the bar holds text", x - xr);
        }
    }

    #[test]
    fn tick_labels_are_short() {
        let f = tick_formatter(0.0, 0.3);
        assert_eq!(f(&0.30000000000000004), "0.3");
        assert_eq!(f(&0.25), "0.25");
        assert_eq!(f(&-1e-17), "0");
        let f = tick_formatter(-20.0, 20.0);
        assert_eq!(f(&12.5), "12.5");
        assert_eq!(f(&-10.0), "-10");
        assert_eq!(format_number(12.5000001), "12.5");
        assert_eq!(format_number(-0.125), "-0.125");
    }
}
