//! Line plots: convergence histories (loss or residual, NRMSE, SSIM against iteration and wall
//! time, several runs per plot) and metrics against a swept parameter; PNG or SVG.
//!
//! A figure is a grid of [`LinePlot`]s, filled row by row. Logarithmic axes drop non-positive
//! values (with a `log` warning) since they have no place on them, and fall back to linear
//! when the data span less than a decade (too little for labelled powers of ten). Series colours follow the
//! Tableau 10 palette, in order.

use std::path::Path;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{font, output, VizError};

/// One curve.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Series {
    /// Legend entry (empty: no legend entry).
    pub label: String,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    /// A point of the curve drawn as a dot: the iterate a run kept, where it is not its last.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mark: Option<(f64, f64)>,
}

/// One plot of a figure.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LinePlot {
    pub title: String,
    /// With the unit, e.g. `"wall time [s]"`.
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    /// Draw a marker at every point (for sweeps with few points).
    pub markers: bool,
    /// The x values are counts (cameras, iterations): a linear x axis puts its ticks at whole
    /// numbers only, never at 4.5 cameras.
    #[serde(default)]
    pub integer_x: bool,
    pub series: Vec<Series>,
}

/// A sampled history of one quantity during a run: value `value[i]` after iteration
/// `iteration[i]`, `time_s[i]` seconds of wall time after the start.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Trace {
    pub iteration: Vec<f64>,
    pub time_s: Vec<f64>,
    pub value: Vec<f64>,
}

/// The convergence history of one run, for [`convergence_plots`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunHistory {
    /// Legend entry, e.g. `"ASART"` or `"FluidNeRF (fast)"`.
    pub label: String,
    /// What the loss trace measures, e.g. `"training loss"` or `"relative residual"`.
    pub loss_label: String,
    pub loss: Trace,
    /// NRMSE against the ground truth, where known.
    pub nrmse: Option<Trace>,
    /// SSIM against the ground truth, where known.
    pub ssim: Option<Trace>,
    /// The iteration whose result the run kept, where it is not its last (held-out early
    /// stopping): the plots mark it on every curve that holds it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kept: Option<f64>,
}

/// One row of the convergence figure: quantity, log scale, (run label, trace) pairs.
type PlotRow<'a> = (String, bool, Vec<(&'a str, &'a Trace, Option<f64>)>);

/// Plots of the runs' convergence, for a figure of two columns: one row per quantity (the loss
/// or residual on a log scale; NRMSE on a log scale and SSIM, if any run has them), against
/// iteration (left) and wall time (right).
pub fn convergence_plots(runs: &[RunHistory]) -> Vec<LinePlot> {
    let mut labels: Vec<&str> = runs.iter().map(|r| r.loss_label.as_str()).filter(|l| !l.is_empty()).collect();
    labels.dedup();
    let loss_label = if labels.len() == 1 { labels[0].to_string() } else { "loss or residual".to_string() };
    let mut rows: Vec<PlotRow<'_>> =
        vec![(loss_label, true, runs.iter().map(|r| (r.label.as_str(), &r.loss, r.kept)).collect())];
    let nrmse: Vec<_> = runs.iter().filter_map(|r| r.nrmse.as_ref().map(|t| (r.label.as_str(), t, r.kept))).collect();
    if !nrmse.is_empty() {
        rows.push(("NRMSE".into(), true, nrmse));
    }
    let ssim: Vec<_> = runs.iter().filter_map(|r| r.ssim.as_ref().map(|t| (r.label.as_str(), t, r.kept))).collect();
    if !ssim.is_empty() {
        rows.push(("SSIM".into(), false, ssim));
    }
    let mut plots = Vec::new();
    for (quantity, log_y, traces) in rows {
        for by_time in [false, true] {
            let series = traces
                .iter()
                .map(|&(label, t, kept)| {
                    let x = if by_time { &t.time_s } else { &t.iteration };
                    let mark = kept
                        .and_then(|k| t.iteration.iter().position(|&i| i == k))
                        .and_then(|at| Some((*x.get(at)?, *t.value.get(at)?)));
                    Series { label: label.to_string(), x: x.clone(), y: t.value.clone(), mark }
                })
                .collect();
            plots.push(LinePlot {
                title: format!("{quantity} vs {}", if by_time { "wall time" } else { "iteration" }),
                x_label: if by_time { "wall time [s]".into() } else { "iteration".into() },
                y_label: quantity.clone(),
                log_x: false,
                log_y,
                markers: false,
                integer_x: !by_time,
                series,
            });
        }
    }
    plots
}

/// A metric against a swept parameter, one series per method, with markers.
pub fn sweep_plot(parameter_label: &str, metric_label: &str, log_x: bool, series: Vec<Series>) -> LinePlot {
    LinePlot {
        title: format!("{metric_label} vs {parameter_label}"),
        x_label: parameter_label.to_string(),
        y_label: metric_label.to_string(),
        log_x,
        log_y: false,
        markers: true,
        integer_x: false,
        series,
    }
}

/// Size of one plot of a figure, in pixels.
const PLOT_W: u32 = 560;
const PLOT_H: u32 = 380;

fn grid(plots: &[LinePlot], columns: usize) -> Result<(usize, usize), VizError> {
    if plots.is_empty() {
        return Err(VizError::invalid("plot figure", "there are no plots to draw"));
    }
    let cols = columns.clamp(1, plots.len());
    Ok((plots.len().div_ceil(cols), cols))
}

/// Writes the plots as a grid of `columns` columns: SVG if `path` ends in `.svg`, else PNG.
pub fn write_plots(path: &Path, plots: &[LinePlot], columns: usize) -> Result<(), VizError> {
    let is_svg = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    if is_svg {
        output::write_atomic(path, encode_plots_svg(plots, columns)?.as_bytes())
    } else {
        output::write_atomic(path, &encode_plots_png(plots, columns)?)
    }
}

/// The plots as PNG bytes.
pub fn encode_plots_png(plots: &[LinePlot], columns: usize) -> Result<Vec<u8>, VizError> {
    font::ensure_registered()?;
    let (rows, cols) = grid(plots, columns)?;
    let (w, h) = (PLOT_W * cols as u32, PLOT_H * rows as u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        draw_figure(&root, plots, rows, cols)?;
        root.present().map_err(|e| VizError::draw("plot figure", e))?;
    }
    output::encode_rgb_png(&buf, w, h, "plot figure")
}

/// The plots as an SVG document (text as `<text>` elements in a sans-serif font).
pub fn encode_plots_svg(plots: &[LinePlot], columns: usize) -> Result<String, VizError> {
    font::ensure_registered()?;
    let (rows, cols) = grid(plots, columns)?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (PLOT_W * cols as u32, PLOT_H * rows as u32)).into_drawing_area();
        draw_figure(&root, plots, rows, cols)?;
        root.present().map_err(|e| VizError::draw("plot figure", e))?;
    }
    Ok(svg)
}

fn draw_figure<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    plots: &[LinePlot],
    rows: usize,
    cols: usize,
) -> Result<(), VizError> {
    root.fill(&WHITE).map_err(|e| VizError::draw("plot background", e))?;
    let areas = root.split_evenly((rows, cols));
    for (plot, area) in plots.iter().zip(&areas) {
        draw_plot(area, plot)?;
    }
    Ok(())
}

/// The largest magnitude a plot draws: an axis padded around values near `f64::MAX` would reach
/// infinity, and its ticks would never end.
const PLOT_LIMIT: f64 = 1e300;

fn plottable(v: f64) -> bool {
    v.is_finite() && v.abs() <= PLOT_LIMIT
}

/// The points of a series that can be drawn on the plot's axes.
fn drawable(plot: &LinePlot, s: &Series) -> Vec<(f64, f64)> {
    let pts: Vec<(f64, f64)> =
        s.x.iter()
            .zip(&s.y)
            .map(|(&x, &y)| (x, y))
            .filter(|&(x, y)| plottable(x) && plottable(y) && (!plot.log_x || x > 0.0) && (!plot.log_y || y > 0.0))
            .collect();
    let dropped = s.x.len().min(s.y.len()) - pts.len();
    if dropped > 0 {
        log::warn!(
            "plot {:?}: {dropped} points of {:?} are not finite, beyond ±{PLOT_LIMIT:e}, or not positive on a log axis",
            plot.title,
            s.label
        );
    }
    pts
}

fn axis_range(values: impl Iterator<Item = f64>, log: bool) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !(lo.is_finite() && hi.is_finite()) {
        return if log { 0.1..10.0 } else { 0.0..1.0 };
    }
    if log {
        let (lo, hi) = if hi / lo < 1.01 { (lo / 1.5, hi * 1.5) } else { (lo, hi) };
        lo / 1.15..hi * 1.15
    } else {
        let pad = if hi > lo { 0.04 * (hi - lo) } else { 0.5 * lo.abs().max(1e-9) };
        lo - pad..hi + pad
    }
}

/// The most decades a logarithmic axis spans; more fall back to a linear axis. Between
/// values of 10⁻³⁰⁰ and 10³⁰⁰ the axis's padded ratio overflows to infinity, and plotters'
/// search for its ticks would never end.
const MAX_DECADES: f64 = 100.0;

/// The decades the drawable positive values spread over (0 without any). A logarithmic axis
/// takes at least one, since plotters labels it only at powers of ten and a narrower range
/// would show no numbers at all, and at most [`MAX_DECADES`].
fn decades(values: impl Iterator<Item = f64>) -> f64 {
    let (lo, hi) =
        values.filter(|&v| v > 0.0 && plottable(v)).fold((f64::INFINITY, 0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if hi > 0.0 {
        hi.log10() - lo.log10()
    } else {
        0.0
    }
}

fn draw_plot<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, plot: &LinePlot) -> Result<(), VizError> {
    // A log axis over less than a decade, or over more than `MAX_DECADES`, falls back to linear.
    let log_axis = |on: bool, values: &dyn Fn(&Series) -> &[f64]| {
        on && (1.0..=MAX_DECADES).contains(&decades(plot.series.iter().flat_map(|s| values(s).iter().copied())))
    };
    let log_x = log_axis(plot.log_x, &|s| &s.x);
    let log_y = log_axis(plot.log_y, &|s| &s.y);
    let adjusted;
    let plot = if (log_x, log_y) == (plot.log_x, plot.log_y) {
        plot
    } else {
        adjusted = LinePlot { log_x, log_y, ..plot.clone() };
        &adjusted
    };
    let data: Vec<Vec<(f64, f64)>> = plot.series.iter().map(|s| drawable(plot, s)).collect();
    let xr = axis_range(data.iter().flatten().map(|p| p.0), plot.log_x);
    let yr = axis_range(data.iter().flatten().map(|p| p.1), plot.log_y);
    match (plot.log_x, plot.log_y) {
        (false, false) if plot.integer_x => draw_chart(area, plot, &data, IntegerAxis::new(&xr), yr.clone(), &xr, &yr),
        (false, true) if plot.integer_x => {
            draw_chart(area, plot, &data, IntegerAxis::new(&xr), yr.clone().log_scale(), &xr, &yr)
        }
        (false, false) => draw_chart(area, plot, &data, xr.clone(), yr.clone(), &xr, &yr),
        (true, false) => draw_chart(area, plot, &data, xr.clone().log_scale(), yr.clone(), &xr, &yr),
        (false, true) => draw_chart(area, plot, &data, xr.clone(), yr.clone().log_scale(), &xr, &yr),
        (true, true) => draw_chart(area, plot, &data, xr.clone().log_scale(), yr.clone().log_scale(), &xr, &yr),
    }
}

/// A linear axis with its ticks at whole numbers only (see [`integer_ticks`]).
struct IntegerAxis {
    inner: plotters::coord::types::RangedCoordf64,
    ticks: Vec<f64>,
}

impl IntegerAxis {
    fn new(range: &std::ops::Range<f64>) -> Self {
        IntegerAxis { inner: range.clone().into(), ticks: integer_ticks(range, 7) }
    }
}

impl Ranged for IntegerAxis {
    type FormatOption = plotters::coord::ranged1d::NoDefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }

    fn key_points<Hint: plotters::coord::ranged1d::KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        // No light mesh lines between the ticks: they would sit at fractional counts.
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.ticks.clone()
        }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.inner.range()
    }
}

impl ValueFormatter<f64> for IntegerAxis {
    fn format_ext(&self, value: &f64) -> String {
        self.inner.format_ext(value)
    }
}

/// At most `max` whole numbers in `range`, a round step (1, 2, 5, 10, 20, ...) apart.
fn integer_ticks(range: &std::ops::Range<f64>, max: usize) -> Vec<f64> {
    let (lo, hi) = (range.start.ceil(), range.end.floor());
    // Also for a NaN bound.
    if lo.partial_cmp(&hi).is_none_or(|o| o == std::cmp::Ordering::Greater) {
        return Vec::new();
    }
    let max = max.max(1) as f64;
    let mut step = 1.0;
    for factor in [2.0, 2.5, 2.0].iter().cycle() {
        if ((hi / step).floor() - (lo / step).ceil()) < max {
            break;
        }
        step *= factor;
    }
    if !step.is_finite() {
        return Vec::new();
    }
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

fn draw_chart<DB, X, Y>(
    area: &DrawingArea<DB, Shift>,
    plot: &LinePlot,
    data: &[Vec<(f64, f64)>],
    x_spec: X,
    y_spec: Y,
    xr: &std::ops::Range<f64>,
    yr: &std::ops::Range<f64>,
) -> Result<(), VizError>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| VizError::draw(&format!("plot {:?}", plot.title), e);
    let mut chart = ChartBuilder::on(area)
        .caption(&plot.title, (font::FAMILY, 17.0, FontStyle::Bold))
        .margin(12)
        .x_label_area_size(46)
        .y_label_area_size(64)
        .build_cartesian_2d(x_spec, y_spec)
        .map_err(err)?;
    let fx = axis_formatter(xr, plot.log_x);
    let fy = axis_formatter(yr, plot.log_y);
    chart
        .configure_mesh()
        .light_line_style(RGBColor(246, 246, 246))
        .bold_line_style(RGBColor(215, 215, 215))
        .x_labels(7)
        .y_labels(7)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_desc(plot.x_label.as_str())
        .y_desc(plot.y_label.as_str())
        .label_style((font::FAMILY, 13.0))
        .axis_desc_style((font::FAMILY, 15.0))
        .draw()
        .map_err(err)?;
    let mut any_label = false;
    for (k, (s, pts)) in plot.series.iter().zip(data).enumerate() {
        let c = colorous::TABLEAU10[k % 10];
        let color = RGBColor(c.r, c.g, c.b);
        let line = chart.draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2))).map_err(err)?;
        if !s.label.is_empty() {
            any_label = true;
            line.label(s.label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
        }
        if plot.markers {
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, color.filled()))).map_err(err)?;
        }
        // Drawn only where its curve can be: a point the axes cannot show is left out.
        if let Some(p) = s.mark.filter(|&(x, y)| pts.contains(&(x, y))) {
            chart.draw_series(std::iter::once(Circle::new(p, 5, color.filled()))).map_err(err)?;
        }
    }
    if any_label {
        chart
            .configure_series_labels()
            .position(legend_corner(data, xr, yr, plot.log_x, plot.log_y))
            .label_font((font::FAMILY, 13.0))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

/// The plot corner with the fewest data points, so that the legend hides as little as possible.
fn legend_corner(
    data: &[Vec<(f64, f64)>],
    xr: &std::ops::Range<f64>,
    yr: &std::ops::Range<f64>,
    log_x: bool,
    log_y: bool,
) -> SeriesLabelPosition {
    let unit = |v: f64, r: &std::ops::Range<f64>, log: bool| {
        if log {
            (v.ln() - r.start.ln()) / (r.end.ln() - r.start.ln())
        } else {
            (v - r.start) / (r.end - r.start)
        }
    };
    // Corners as (position, x region, y region): the legend covers about 40 % × 35 %.
    let corners = [
        (SeriesLabelPosition::UpperRight, 0.6..=1.0, 0.65..=1.0),
        (SeriesLabelPosition::LowerRight, 0.6..=1.0, 0.0..=0.35),
        (SeriesLabelPosition::UpperLeft, 0.0..=0.4, 0.65..=1.0),
        (SeriesLabelPosition::LowerLeft, 0.0..=0.4, 0.0..=0.35),
    ];
    let mut best = (usize::MAX, SeriesLabelPosition::UpperRight);
    for (pos, xs, ys) in corners {
        let n = data
            .iter()
            .flatten()
            .filter(|&&(x, y)| xs.contains(&unit(x, xr, log_x)) && ys.contains(&unit(y, yr, log_y)))
            .count();
        if n < best.0 {
            best = (n, pos);
        }
    }
    best.1
}

/// Tick labels: as many decimals as a linear range needs; compact scientific for log axes.
fn axis_formatter(range: &std::ops::Range<f64>, log: bool) -> Box<dyn Fn(&f64) -> String> {
    if log {
        Box::new(|v: &f64| {
            let e = v.abs().log10();
            if (-3.0..4.0).contains(&e) {
                crate::panel::format_number(*v)
            } else {
                format!("{v:.0e}")
            }
        })
    } else {
        Box::new(crate::panel::tick_formatter(range.start, range.end))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn runs() -> Vec<RunHistory> {
        let trace = |rate: f64, dt: f64| Trace {
            iteration: (0..50).map(f64::from).collect(),
            time_s: (0..50).map(|i| f64::from(i) * dt).collect(),
            value: (0..50).map(|i| (-rate * f64::from(i)).exp()).collect(),
        };
        vec![
            RunHistory {
                label: "ASART".into(),
                loss_label: "residual".into(),
                loss: trace(0.1, 0.2),
                nrmse: Some(trace(0.05, 0.2)),
                ssim: None,
                kept: None,
            },
            RunHistory {
                label: "FluidNeRF".into(),
                loss_label: "loss".into(),
                loss: trace(0.2, 0.5),
                nrmse: Some(trace(0.08, 0.5)),
                ssim: Some(Trace { value: vec![0.5; 50], ..trace(0.0, 0.5) }),
                kept: Some(20.0),
            },
        ]
    }

    #[test]
    fn convergence_layout() {
        let plots = convergence_plots(&runs());
        assert_eq!(plots.len(), 6, "three quantities × (iteration, time)");
        assert_eq!(plots[0].y_label, "loss or residual");
        assert!(plots[0].log_y && !plots[4].log_y);
        assert_eq!(plots[4].series.len(), 1, "only one run has SSIM");
        assert_eq!(plots[1].series[1].x[2], 1.0, "second column is wall time");
        // The second run's kept iterate, marked on its curves by iteration and by time.
        let nrmse_20 = (-0.08f64 * 20.0).exp();
        assert_eq!(plots[2].series[1].mark, Some((20.0, nrmse_20)));
        assert_eq!(plots[3].series[1].mark, Some((10.0, nrmse_20)));
        assert_eq!(plots[4].series[0].mark, Some((20.0, 0.5)));
        assert_eq!(plots[2].series[0].mark, None, "the first run kept its last iterate");
        // An iteration its curve does not hold marks nothing.
        let mut other = runs();
        other[1].kept = Some(20.5);
        assert!(convergence_plots(&other).iter().all(|p| p.series.iter().all(|s| s.mark.is_none())));
    }

    #[test]
    fn writes_png_and_svg() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut plots = convergence_plots(&runs());
        plots[0].series[0].y[3] = -1.0; // dropped on the log axis, with a warning
        write_plots(&dir.path().join("c.png"), &plots, 2).expect("png");
        let img = image::open(dir.path().join("c.png")).expect("reads").to_rgb8();
        assert_eq!((img.width(), img.height()), (2 * PLOT_W, 3 * PLOT_H));
        write_plots(&dir.path().join("c.svg"), &plots, 2).expect("svg");
        let svg = std::fs::read_to_string(dir.path().join("c.svg")).expect("reads");
        assert!(svg.starts_with("<svg") && svg.contains("FluidNeRF") && svg.contains("wall time [s]"));
        // The kept iterate's dots are the figure's only circles (its curves have no markers).
        assert_eq!(svg.matches("<circle").count(), 6, "one dot on each of the second run's six curves");
        let sweep = sweep_plot(
            "cameras",
            "NRMSE",
            false,
            vec![Series { label: "ASART".into(), x: vec![2.0, 4.0, 8.0], y: vec![0.4, 0.2, 0.1], mark: None }],
        );
        write_plots(&dir.path().join("s.png"), &[sweep], 1).expect("png");
        assert!(decades([0.01, 0.5].into_iter()) >= 1.0 && decades([0.15, 1.1, -3.0].into_iter()) < 1.0);
    }

    #[test]
    fn values_near_the_largest_float_are_left_out_and_the_plot_finishes() {
        let dir = tempfile::tempdir().expect("tempdir");
        for (log, big) in [(true, 1e308), (false, 1.7e308), (true, 1e299), (false, -1e299)] {
            let series = |x: Vec<f64>, y: Vec<f64>| vec![Series { label: "run".into(), x, y, mark: None }];
            let mut plot = sweep_plot("time", "NRMSE", log, series(vec![1.0, 2.0, 3.0], vec![big, 0.4, 0.3]));
            plot.log_y = log;
            write_plots(&dir.path().join("y.png"), &[plot], 1).expect("plots huge values");
            let mut plot = sweep_plot("time", "NRMSE", log, series(vec![1.0, big.abs(), 3.0], vec![0.5, 0.4, 0.3]));
            write_plots(&dir.path().join("x.svg"), &[plot.clone()], 1).expect("plots huge times");
            plot.integer_x = true;
            write_plots(&dir.path().join("x.svg"), &[plot], 1).expect("plots huge counts");
        }
        assert!(plottable(1e300) && !plottable(1.0001e300) && !plottable(f64::NAN) && plottable(-3.0));
    }

    /// Values 310 decades apart on a log axis: its padded ratio overflowed and the plot never
    /// finished. Over more than a hundred decades the axis is linear.
    #[test]
    fn a_log_axis_over_hundreds_of_decades_is_drawn_linear_and_finishes() {
        let dir = tempfile::tempdir().expect("tempdir");
        let series = |x: Vec<f64>, y: Vec<f64>| vec![Series { label: "run".into(), x, y, mark: None }];
        let mut plot = sweep_plot("time", "NRMSE", true, series(vec![0.1, 0.2], vec![1e300, 1e-10]));
        plot.log_y = true;
        write_plots(&dir.path().join("y.svg"), &[plot], 1).expect("plots");
        let plot = sweep_plot("time", "NRMSE", true, series(vec![1e-10, 1e300], vec![0.9, 0.5]));
        write_plots(&dir.path().join("x.svg"), &[plot], 1).expect("plots");
        assert!(decades([1e-10, 1e300].into_iter()) > MAX_DECADES);
        assert!(decades([1e-50, 1e49, 1e301, f64::INFINITY, -1e200].into_iter()) <= MAX_DECADES);
        assert!(decades([0.0, -1.0].into_iter()) <= MAX_DECADES);
    }

    /// The numbers along the x axis of a one-plot SVG: the numeric labels on one line.
    fn x_tick_labels(svg: &str) -> Vec<String> {
        let mut by_row: std::collections::BTreeMap<String, Vec<String>> = Default::default();
        for element in svg.split("<text ").skip(1) {
            let Some((attributes, rest)) = element.split_once('>') else { continue };
            let label = rest.split('<').next().unwrap_or("").trim().to_string();
            let row = attributes.split("y=\"").nth(1).and_then(|r| r.split('"').next()).unwrap_or("");
            if label.parse::<f64>().is_ok() {
                by_row.entry(row.to_string()).or_default().push(label);
            }
        }
        by_row.into_values().max_by_key(Vec::len).unwrap_or_default()
    }

    /// Camera and iteration counts are whole numbers, and so are the ticks of their axis:
    /// plotters' own ticks over 4 … 5 cameras would read 4.2, 4.4, ...
    #[test]
    fn a_count_axis_has_whole_number_ticks() {
        let cameras = |integer_x: bool, x: Vec<f64>, log_y: bool| {
            let n = x.len();
            let plot = LinePlot {
                log_y,
                integer_x,
                series: vec![Series {
                    label: "SART".into(),
                    x,
                    y: (1..=n).map(|k| 0.5 / k as f64).collect(),
                    mark: None,
                }],
                ..Default::default()
            };
            x_tick_labels(&encode_plots_svg(&[plot], 1).expect("svg"))
        };
        let fractional = cameras(false, vec![4.0, 5.0], false);
        assert!(fractional.iter().any(|l| l.contains('.')), "plotters' ticks: {fractional:?}");
        assert_eq!(cameras(true, vec![4.0, 5.0], false), ["4", "5"]);
        assert_eq!(cameras(true, vec![4.0, 5.0], true), ["4", "5"], "also beside a log y axis");
        assert_eq!(cameras(true, vec![4.0], false), ["2", "3", "4", "5", "6"], "one count, padded");
        let many = cameras(true, vec![0.0, 250.0, 500.0, 1000.0], false);
        assert_eq!(many, ["0", "200", "400", "600", "800", "1000"], "at most 7, a round step apart");
        let iterations = &convergence_plots(&runs())[0];
        assert!(iterations.integer_x && iterations.x_label == "iteration");
        assert!(!convergence_plots(&runs())[1].integer_x, "wall time is no count");
        assert_eq!(integer_ticks(&(0.2..0.8), 7), Vec::<f64>::new());
        assert_eq!(integer_ticks(&(-3.5..3.5), 7), [-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0]);
    }
}
