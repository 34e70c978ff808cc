//! Self-contained HTML reports: one file that opens from disk anywhere, with the run's key
//! facts, metrics tables, pictures (embedded as base64 `data:` URIs) and resolved settings. No
//! scripts, fonts or style sheets are fetched.

use std::path::Path;

use base64::Engine;

use crate::{output, VizError};

/// A picture to embed.
#[derive(Clone, Debug, PartialEq)]
pub enum ImageData {
    Png(Vec<u8>),
    Gif(Vec<u8>),
    Svg(String),
}

impl ImageData {
    /// Reads a `.png`, `.gif` or `.svg` file (by extension).
    pub fn from_file(path: &Path) -> Result<Self, VizError> {
        let read_err = |error| VizError::Read { path: path.to_path_buf(), error };
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        match ext.as_str() {
            "png" => Ok(ImageData::Png(std::fs::read(path).map_err(read_err)?)),
            "gif" => Ok(ImageData::Gif(std::fs::read(path).map_err(read_err)?)),
            "svg" => Ok(ImageData::Svg(std::fs::read_to_string(path).map_err(read_err)?)),
            _ => Err(VizError::invalid(
                "report picture",
                format!("{}: only .png, .gif and .svg pictures can be embedded", path.display()),
            )),
        }
    }

    fn data_uri(&self) -> String {
        let b64 = base64::engine::general_purpose::STANDARD;
        match self {
            ImageData::Png(b) => format!("data:image/png;base64,{}", b64.encode(b)),
            ImageData::Gif(b) => format!("data:image/gif;base64,{}", b64.encode(b)),
            ImageData::Svg(s) => format!("data:image/svg+xml;base64,{}", b64.encode(s.as_bytes())),
        }
    }
}

/// A captioned picture.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    pub caption: String,
    pub image: ImageData,
}

/// A table of text cells; cells that parse as numbers are right-aligned.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub caption: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// An empty table with a caption and column names.
    pub fn new(caption: impl Into<String>, header: &[&str]) -> Self {
        Table { caption: caption.into(), header: header.iter().map(|h| h.to_string()).collect(), rows: Vec::new() }
    }

    /// Appends a row (panics if its length differs from the header's).
    pub fn push_row(&mut self, row: Vec<String>) {
        assert_eq!(
            row.len(),
            self.header.len(),
            "Table::push_row: {} cells for {} columns",
            row.len(),
            self.header.len()
        );
        self.rows.push(row);
    }
}

/// A number for a table: four significant digits, scientific for very small or large values.
pub fn format_value(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e6).contains(&a) {
        format!("{v:.3e}")
    } else {
        crate::panel::format_number(v)
    }
}

/// The content of a report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Report {
    /// Page heading, e.g. `"FluidNeRF reconstruction of jet_small"`.
    pub title: String,
    /// A line under the heading (scene, date, version).
    pub subtitle: String,
    /// Key facts shown first as `name: value` pairs (method, time, resolution, …).
    pub summary: Vec<(String, String)>,
    /// Metrics tables.
    pub tables: Vec<Table>,
    /// Pictures in order: slices, comparisons, convergence plots.
    pub figures: Vec<Figure>,
    /// The resolved settings of the run, shown as JSON.
    pub settings: Option<serde_json::Value>,
    /// Free-text remarks shown at the end.
    pub notes: Vec<String>,
}

/// Writes `report` as one self-contained HTML file (atomically).
pub fn write_report_html(path: &Path, report: &Report) -> Result<(), VizError> {
    output::write_atomic(path, render_html(report).as_bytes())
}

fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

fn is_numeric(s: &str) -> bool {
    let t = s.trim().trim_end_matches('%').trim_end_matches(" s").trim_end_matches(" dB");
    !t.is_empty() && t.parse::<f64>().is_ok()
}

const CSS: &str = r#"
:root { --fg: #1d2329; --muted: #5b6670; --line: #d9dee3; --accent: #2a6f97; --stripe: #f5f7f9; }
* { box-sizing: border-box; }
body { margin: 0; color: var(--fg); background: #fff;
  font: 15px/1.5 -apple-system, "Segoe UI", "DejaVu Sans", Helvetica, Arial, sans-serif; }
main { max-width: 1280px; margin: 0 auto; padding: 28px 32px 60px; }
h1 { font-size: 26px; margin: 0 0 4px; }
.subtitle { color: var(--muted); margin: 0 0 22px; }
h2 { font-size: 19px; margin: 34px 0 12px; padding-bottom: 6px; border-bottom: 2px solid var(--line); }
dl.summary { display: grid; grid-template-columns: repeat(auto-fill, minmax(220px, 1fr)); gap: 10px 18px; margin: 0; }
dl.summary div { border-left: 3px solid var(--accent); padding: 4px 10px; background: var(--stripe); }
dl.summary dt { font-size: 12px; color: var(--muted); text-transform: uppercase; letter-spacing: .04em; }
dl.summary dd { margin: 0; font-size: 17px; font-weight: 600; font-variant-numeric: tabular-nums; }
table { border-collapse: collapse; margin: 6px 0 18px; font-variant-numeric: tabular-nums; }
caption { text-align: left; font-weight: 600; padding: 4px 0 8px; }
th, td { padding: 6px 14px; border-bottom: 1px solid var(--line); text-align: left; }
th { background: #eef1f4; font-weight: 600; }
tbody tr:nth-child(even) { background: var(--stripe); }
td.num { text-align: right; font-family: "DejaVu Sans Mono", Menlo, Consolas, monospace; font-size: 14px; }
figure { margin: 0 0 26px; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--line); border-radius: 4px; }
figcaption { color: var(--muted); margin-top: 6px; }
details { margin-top: 8px; }
summary { cursor: pointer; color: var(--accent); }
pre { background: var(--stripe); border: 1px solid var(--line); border-radius: 4px; padding: 12px 14px;
  overflow-x: auto; font: 13px/1.45 "DejaVu Sans Mono", Menlo, Consolas, monospace; }
footer { margin-top: 40px; color: var(--muted); font-size: 13px; }
"#;

fn render_html(r: &Report) -> String {
    let mut h = String::new();
    h.push_str("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n");
    h.push_str("<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n");
    h.push_str(&format!("<title>{}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<main>\n", esc(&r.title)));
    h.push_str(&format!("<h1>{}</h1>\n", esc(&r.title)));
    if !r.subtitle.is_empty() {
        h.push_str(&format!("<p class=\"subtitle\">{}</p>\n", esc(&r.subtitle)));
    }
    if !r.summary.is_empty() {
        h.push_str("<dl class=\"summary\">\n");
        for (k, v) in &r.summary {
            h.push_str(&format!("<div><dt>{}</dt><dd>{}</dd></div>\n", esc(k), esc(v)));
        }
        h.push_str("</dl>\n");
    }
    if !r.tables.is_empty() {
        h.push_str("<h2>Metrics</h2>\n");
        for t in &r.tables {
            h.push_str("<table>\n");
            if !t.caption.is_empty() {
                h.push_str(&format!("<caption>{}</caption>\n", esc(&t.caption)));
            }
            h.push_str("<thead><tr>");
            for c in &t.header {
                h.push_str(&format!("<th>{}</th>", esc(c)));
            }
            h.push_str("</tr></thead>\n<tbody>\n");
            for row in &t.rows {
                h.push_str("<tr>");
                for c in row {
                    let class = if is_numeric(c) { " class=\"num\"" } else { "" };
                    h.push_str(&format!("<td{class}>{}</td>", esc(c)));
                }
                h.push_str("</tr>\n");
            }
            h.push_str("</tbody>\n</table>\n");
        }
    }
    if !r.figures.is_empty() {
        h.push_str("<h2>Pictures</h2>\n");
        for f in &r.figures {
            h.push_str(&format!(
                "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>\n",
                f.image.data_uri(),
                esc(&f.caption),
                esc(&f.caption)
            ));
        }
    }
    if let Some(settings) = &r.settings {
        let json = serde_json::to_string_pretty(settings).unwrap_or_else(|_| settings.to_string());
        h.push_str("<h2>Settings</h2>\n<details open><summary>Resolved settings (rerun with <code>--config</code>)</summary>\n");
        h.push_str(&format!("<pre>{}</pre>\n</details>\n", esc(&json)));
    }
    if !r.notes.is_empty() {
        h.push_str("<h2>Notes</h2>\n<ul>\n");
        for n in &r.notes {
            h.push_str(&format!("<li>{}</li>\n", esc(n)));
        }
        h.push_str("</ul>\n");
    }
    h.push_str(&format!(
        "<footer>Written by fluidnerf {}. This file is self-contained: pictures are embedded.</footer>\n",
        env!("CARGO_PKG_VERSION")
    ));
    h.push_str("</main>\n</body>\n</html>\n");
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_is_self_contained_and_escaped() {
        let mut t = Table::new("Against the truth", &["method", "NRMSE", "PSNR [dB]"]);
        t.push_row(vec!["ASART <voxel>".into(), format_value(0.1234567), format_value(21.5)]);
        let r = Report {
            title: "Jet & friends".into(),
            subtitle: "scene jet_small".into(),
            summary: vec![("time".into(), "12.3 s".into())],
            tables: vec![t],
            figures: vec![Figure { caption: "a slice".into(), image: ImageData::Png(vec![137, 80, 78, 71]) }],
            settings: Some(serde_json::json!({"seed": 0, "method": "fast"})),
            notes: vec![],
        };
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("report.html");
        write_report_html(&path, &r).expect("writes");
        let html = std::fs::read_to_string(&path).expect("reads");
        assert!(html.contains("Jet &amp; friends") && html.contains("ASART &lt;voxel&gt;"));
        assert!(html.contains("<td class=\"num\">0.1235</td>"));
        assert!(html.contains("src=\"data:image/png;base64,iVBORw==\""));
        assert!(html.contains("&quot;seed&quot;: 0"));
        // Nothing is fetched from elsewhere.
        assert!(!html.contains("http://") && !html.contains("https://") && !html.contains("<script"));
        assert_eq!(format_value(1.5e-7), "1.500e-7");
    }
}
