//! Drawing a figure with plotters: one chart per panel, stacked, with labelled axes (units in
//! the labels), log axes where the panel asks, error bars for the spread, a legend, the papers'
//! points as black crosses, and the run's stamp (mode, adapter, host, commit) at the foot. The
//! same drawing goes to SVG and to PNG; text is drawn with the embedded DejaVu Sans, so the PNG
//! looks the same on a machine without fonts.

use std::ops::Range;
use std::path::Path;
use std::sync::Once;

use anyhow::{Context, anyhow};
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

use crate::machine::Machine;
use crate::record::{Figure, Panel};

/// Colours that read on white and apart from each other (matplotlib's tab10).
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

const WIDTH: u32 = 1100;
const PANEL_HEIGHT: u32 = 460;
const TITLE_HEIGHT: u32 = 44;
const FOOTER_HEIGHT: u32 = 30;

fn plot_error(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow!("drawing the plot: {e}")
}

/// Registers the embedded font once per process (plotters' text needs a registered font).
fn register_font() -> anyhow::Result<()> {
    static ONCE: Once = Once::new();
    let mut result = Ok(());
    ONCE.call_once(|| {
        let fonts = [
            (FontStyle::Normal, dejavu::sans::regular()),
            (FontStyle::Bold, dejavu::sans::bold()),
        ];
        for (style, bytes) in fonts {
            if plotters::style::register_font("sans-serif", style, bytes).is_err() {
                result = Err(anyhow!("the embedded DejaVu Sans font did not load"));
            }
        }
    });
    result
}

fn size(figure: &Figure) -> (u32, u32) {
    let panels = figure.panels.len().max(1) as u32;
    (WIDTH, TITLE_HEIGHT + panels * PANEL_HEIGHT + FOOTER_HEIGHT)
}

/// Writes the figure as an SVG and a PNG.
pub fn write_plots(
    figure: &Figure,
    machine: &Machine,
    svg: &Path,
    png: &Path,
) -> anyhow::Result<()> {
    register_font()?;
    let (w, h) = size(figure);
    {
        let root = SVGBackend::new(svg, (w, h)).into_drawing_area();
        draw(&root, figure, machine)?;
        root.present().map_err(plot_error)?;
    }
    let mut pixels = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
        draw(&root, figure, machine)?;
        root.present().map_err(plot_error)?;
    }
    let image = image::RgbImage::from_raw(w, h, pixels)
        .ok_or_else(|| anyhow!("the plot's pixel buffer has the wrong size"))?;
    image
        .save(png)
        .with_context(|| format!("writing {}", png.display()))
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    figure: &Figure,
    machine: &Machine,
) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(plot_error)?;
    let (title, rest) = root.split_vertically(TITLE_HEIGHT);
    title
        .draw_text(
            &figure.title,
            &("sans-serif", 22)
                .into_font()
                .style(FontStyle::Bold)
                .color(&BLACK),
            (14, 12),
        )
        .map_err(plot_error)?;
    let body_height = rest.dim_in_pixel().1.saturating_sub(FOOTER_HEIGHT);
    let (body, footer) = rest.split_vertically(body_height);
    let stamp_color = if machine.quick {
        RED
    } else {
        RGBColor(90, 90, 90)
    };
    footer
        .draw_text(
            &machine.stamp(),
            &("sans-serif", 13).into_font().color(&stamp_color),
            (14, 8),
        )
        .map_err(plot_error)?;
    let areas = body.split_evenly((figure.panels.len().max(1), 1));
    for (area, panel) in areas.iter().zip(&figure.panels) {
        draw_panel_axes(area, panel)?;
    }
    Ok(())
}

/// The value range of a panel's axis, padded; log axes keep to positive values.
fn range(values: impl Iterator<Item = f64>, log: bool, from_zero: bool) -> Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return if log { 0.1..10.0 } else { 0.0..1.0 };
    }
    if log {
        (lo / 1.5)..(hi * 1.5)
    } else {
        let lo = if from_zero { lo.min(0.0) } else { lo };
        let pad = ((hi - lo) * 0.06).max(1e-9);
        (lo - if from_zero && lo == 0.0 { 0.0 } else { pad })..(hi + pad)
    }
}

fn draw_panel_axes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
) -> anyhow::Result<()> {
    let xs = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.x))
        .chain(panel.paper.iter().map(|p| p.x));
    let ys = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter().flat_map(|p| [p.y, p.low, p.high]))
        .chain(panel.paper.iter().map(|p| p.y));
    let x = range(xs, panel.log_x, false);
    let y = range(ys, panel.log_y, true);
    match (panel.log_x, panel.log_y) {
        (true, true) => draw_panel(area, panel, x.log_scale(), y.log_scale()),
        (true, false) => draw_panel(area, panel, x.log_scale(), y),
        (false, true) => draw_panel(area, panel, x, y.log_scale()),
        (false, false) => draw_panel(area, panel, x, y),
    }
}

/// A series' colour: series that differ only by ", tracker" / ", flat likelihood" share one, the
/// flat one drawn lighter.
fn colours(panel: &Panel) -> Vec<RGBAColor> {
    let mut groups: Vec<&str> = Vec::new();
    panel
        .series
        .iter()
        .map(|s| {
            // "face 2, plain filter" and "face 2, flat likelihood" share face 2's colour.
            let group = match s.kind {
                "tracked" | "plain" | "flat" => {
                    s.name.rsplit_once(", ").map_or(&*s.name, |(g, _)| g)
                }
                _ => &s.name,
            };
            let index = groups.iter().position(|g| *g == group).unwrap_or_else(|| {
                groups.push(group);
                groups.len() - 1
            });
            let colour = PALETTE[index % PALETTE.len()].to_rgba();
            match s.kind {
                "flat" => colour.mix(0.35),
                "plain" => colour.mix(0.7),
                _ => colour,
            }
        })
        .collect()
}

/// Tick labels: whole numbers without decimals, thousands as "10k", small values with the
/// digits they need.
fn axis_label(v: f64) -> String {
    let a = v.abs();
    if a >= 10_000.0 && (v / 1000.0).fract() == 0.0 {
        format!("{}k", v / 1000.0)
    } else if v.fract() == 0.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 0.1 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn draw_panel<DB, X, Y>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    x: X,
    y: Y,
) -> anyhow::Result<()>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 17))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(78)
        .build_cartesian_2d(x, y)
        .map_err(plot_error)?;
    chart
        .configure_mesh()
        .x_desc(&panel.x_label)
        .y_desc(&panel.y_label)
        .axis_desc_style(("sans-serif", 15))
        .label_style(("sans-serif", 13))
        .light_line_style(RGBColor(235, 235, 235))
        .x_labels(8)
        .x_label_formatter(&|v| axis_label(*v))
        .y_label_formatter(&|v| axis_label(*v))
        .draw()
        .map_err(plot_error)?;
    for (series, colour) in panel.series.iter().zip(colours(panel)) {
        let points: Vec<(f64, f64)> = series.points.iter().map(|p| (p.x, p.y)).collect();
        let width = if series.kind == "tracked" { 2 } else { 1 };
        chart
            .draw_series(LineSeries::new(points.clone(), colour.stroke_width(width)))
            .map_err(plot_error)?
            .label(series.name.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 22, y)], colour.stroke_width(2))
            });
        if points.len() <= 40 {
            chart
                .draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                .map_err(plot_error)?;
        }
        let bars =
            series.points.iter().filter(|p| p.high > p.low).map(|p| {
                ErrorBar::new_vertical(p.x, p.low, p.y, p.high, colour.stroke_width(1), 6)
            });
        chart.draw_series(bars).map_err(plot_error)?;
    }
    for paper in &panel.paper {
        chart
            .draw_series(std::iter::once(Cross::new(
                (paper.x, paper.y),
                7,
                BLACK.stroke_width(2),
            )))
            .map_err(plot_error)?
            .label(format!("{} ({})", paper.label, paper.source))
            .legend(|(x, y)| Cross::new((x + 11, y), 5, BLACK.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(160, 160, 160))
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(plot_error)?;
    Ok(())
}
