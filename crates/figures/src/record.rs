//! What an experiment produces: a figure of one or more panels, each panel a set of named series
//! of measured points, and the CSV that holds every measurement with the run's provenance.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;

use crate::machine::Machine;
use crate::paper::PaperPoint;

/// One measurement: the median at `x` and its spread (for timings the interquartile range of the
/// repeats; for counts over seeds the same; a single value has `low == high == y`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub low: f64,
    pub high: f64,
    /// How many repeats the median was taken over.
    pub repeats: usize,
}

impl Point {
    /// The same measurement in other units (seconds to milliseconds, per sample to per J).
    pub fn scaled(self, factor: f64) -> Self {
        Self {
            y: self.y * factor,
            low: self.low * factor,
            high: self.high * factor,
            ..self
        }
    }

    /// A value with no spread (derived quantities, single runs).
    pub fn exact(x: f64, y: f64) -> Self {
        Self {
            x,
            y,
            low: y,
            high: y,
            repeats: 1,
        }
    }
}

/// A line on a panel.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    /// What kind of run made it, so that tests and readers can find the CPU baselines: "cpu-1"
    /// (one thread), "cpu-all" (all cores), "gpu", or "" for derived or accuracy series.
    pub kind: &'static str,
    pub points: Vec<Point>,
}

impl Series {
    pub fn new(name: impl Into<String>, kind: &'static str) -> Self {
        Self {
            name: name.into(),
            kind,
            points: Vec::new(),
        }
    }
}

/// One set of axes.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub x_unit: &'static str,
    pub y_label: String,
    pub y_unit: &'static str,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
    /// Values the paper reports on these axes (drawn as black crosses).
    pub paper: Vec<PaperPoint>,
    /// Whether the series are timings, so that a larger problem must take longer (checked by
    /// the quick-mode test on the CPU series).
    pub timing: bool,
}

impl Panel {
    /// Linear axes, no series yet; `x` and `y` are (label with its unit, unit).
    pub fn new(title: impl Into<String>, x: (&str, &'static str), y: (&str, &'static str)) -> Self {
        Self {
            title: title.into(),
            x_label: x.0.into(),
            x_unit: x.1,
            y_label: y.0.into(),
            y_unit: y.1,
            log_x: false,
            log_y: false,
            series: Vec::new(),
            paper: Vec::new(),
            timing: false,
        }
    }

    pub fn log_axes(mut self, x: bool, y: bool) -> Self {
        self.log_x = x;
        self.log_y = y;
        self
    }

    /// Marks the series as timings (a larger problem must take longer).
    pub fn timings(mut self) -> Self {
        self.timing = true;
        self
    }

    /// Every point's value times `factor`.
    pub fn scale_values(&mut self, factor: f64) {
        for s in &mut self.series {
            for p in &mut s.points {
                *p = p.scaled(factor);
            }
        }
    }

    pub fn series_mut(&mut self, name: &str, kind: &'static str) -> &mut Series {
        if let Some(i) = self.series.iter().position(|s| s.name == name) {
            return &mut self.series[i];
        }
        self.series.push(Series::new(name, kind));
        self.series.last_mut().expect("just pushed")
    }
}

/// A figure: what `--only` names, one CSV, one SVG, one PNG.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// File stem and `--only` name, e.g. `face-fig6`.
    pub name: &'static str,
    pub title: String,
    /// What was measured and how, a paragraph for the report.
    pub description: String,
    pub panels: Vec<Panel>,
}

/// The CSV's columns, in order. One row per measured point.
pub const CSV_COLUMNS: [&str; 17] = [
    "figure", "panel", "series", "kind", "x", "x_unit", "y", "y_low", "y_high", "y_unit",
    "repeats", "mode", "host", "adapter", "driver", "commit", "date",
];

/// Writes every point of the figure as a CSV row with the run's provenance.
pub fn write_csv(figure: &Figure, machine: &Machine, path: &Path) -> anyhow::Result<()> {
    let mut out = CSV_COLUMNS.join(",");
    out.push('\n');
    for panel in &figure.panels {
        for series in &panel.series {
            for p in &series.points {
                let fields = [
                    figure.name.to_string(),
                    panel.title.clone(),
                    series.name.clone(),
                    series.kind.to_string(),
                    number(p.x),
                    panel.x_unit.to_string(),
                    number(p.y),
                    number(p.low),
                    number(p.high),
                    panel.y_unit.to_string(),
                    p.repeats.to_string(),
                    machine.mode().to_string(),
                    machine.host.clone(),
                    machine.adapter_name(),
                    machine.driver(),
                    machine.commit.clone(),
                    machine.date.clone(),
                ];
                let row: Vec<String> = fields.iter().map(|f| quote(f)).collect();
                let _ = writeln!(out, "{}", row.join(","));
            }
        }
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}

fn number(v: f64) -> String {
    format!("{v:.6e}")
}

/// RFC 4180 quoting: fields with a comma, a quote or a line break are quoted, quotes doubled.
fn quote(field: &str) -> String {
    if field.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", field.replace('"', "\"\""))
    } else {
        field.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_with_commas_and_quotes_are_quoted() {
        assert_eq!(quote("plain"), "plain");
        assert_eq!(quote("a, b"), "\"a, b\"");
        assert_eq!(quote("say \"x\""), "\"say \"\"x\"\"\"");
    }

    #[test]
    fn numbers_round_trip() {
        for v in [0.0, 1.5e-7, 123456.789, -3.25] {
            let parsed: f64 = number(v).parse().unwrap();
            assert!((parsed - v).abs() <= 1e-6 * v.abs());
        }
    }
}
