//! The markdown report: the run's provenance, the papers' values beside ours (quoted as the
//! papers', with the ratio and the hardware of both), then each figure with its plot and its
//! numbers.

use std::fmt::Write as _;

use crate::machine::Machine;
use crate::paper;
use crate::record::{Figure, Panel, Point};

/// Significant figures for the tables.
fn num(v: f64) -> String {
    if !v.is_finite() {
        return "–".into();
    }
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

fn cell(p: &Point) -> String {
    if p.high > p.low {
        format!("{} ({}–{})", num(p.y), num(p.low), num(p.high))
    } else {
        num(p.y)
    }
}

fn point_at<'a>(figures: &'a [Figure], figure: &str, series: &str, x: f64) -> Option<&'a Point> {
    figures
        .iter()
        .find(|f| f.name == figure)?
        .panels
        .iter()
        .flat_map(|p| &p.series)
        .find(|s| s.name == series)?
        .points
        .iter()
        .find(|p| p.x == x)
}

fn series_points<'a>(figures: &'a [Figure], figure: &str, series: &str) -> Vec<&'a Point> {
    figures
        .iter()
        .filter(|f| f.name == figure)
        .flat_map(|f| &f.panels)
        .flat_map(|p| &p.series)
        .filter(|s| s.name == series)
        .flat_map(|s| &s.points)
        .collect()
}

pub fn write(figures: &[Figure], machine: &Machine) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# The papers' figures, reproduced\n");
    let _ = writeln!(
        out,
        "Written by `cargo xtask reproduce-figures{}` (the `streampf-figures` crate); every \
         number below was measured in that one run. Each figure's measurements are in \
         `figures/NAME.csv` (one row per measurement, with the host, adapter, driver and \
         commit), its plot in `figures/NAME.png` and `.svg`.\n",
        if machine.quick { " --quick" } else { "" }
    );
    if machine.quick {
        let _ = writeln!(
            out,
            "**Quick mode**: small sizes, for checking that everything runs. These are not the \
             papers' sizes and say nothing about speed on real hardware.\n"
        );
    }
    let _ = writeln!(out, "- Mode: {}", machine.mode());
    let _ = writeln!(out, "- GPU: {}", machine.adapter_name());
    if !machine.driver().is_empty() {
        let _ = writeln!(out, "- Driver: {}", machine.driver());
    }
    let _ = writeln!(out, "- Host: {}", machine.host);
    let _ = writeln!(out, "- Commit: {}", machine.commit);
    let _ = writeln!(out, "- Date: {}\n", machine.date);
    write_paper_table(&mut out, figures, machine);
    for figure in figures {
        write_figure(&mut out, figure);
    }
    out
}

fn write_paper_table(out: &mut String, figures: &[Figure], machine: &Machine) {
    let ours_hw = format!("{}; {}", machine.adapter_name(), machine.host);
    let _ = writeln!(out, "## The papers' values beside ours\n");
    let _ = writeln!(
        out,
        "The papers' values are quoted as the papers give them; they ran on the papers' own \
         hardware (CUDA GPUs and CPUs of 2008 and 2010, described in each paper's experiments \
         section). The face paper is {}; the body paper is {}.\n",
        paper::FACE_PAPER,
        paper::BODY_PAPER
    );
    let _ = writeln!(
        out,
        "| source | the paper's value | paper's hardware | ours | our hardware | ours / paper |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|");
    let mut rows = 0;
    for figure in figures {
        for panel in &figure.panels {
            for p in &panel.paper {
                let ours = point_at(figures, figure.name, p.our_series, p.x);
                let (value, ratio) = match ours {
                    Some(o) => (
                        format!(
                            "{} {} ({}, x = {})",
                            num(o.y),
                            panel.y_unit,
                            p.our_series,
                            p.x
                        ),
                        format!("{}×", num(o.y / p.y)),
                    ),
                    None => ("not measured".into(), "–".into()),
                };
                let _ = writeln!(
                    out,
                    "| {} | {}: about {} {} at {} {} | the paper's | {value} | {ours_hw} | {ratio} |",
                    p.source,
                    p.label,
                    num(p.y),
                    panel.y_unit,
                    p.x,
                    panel.x_unit
                );
                rows += 1;
            }
        }
    }
    if let Some(row) = face_claim_row(figures) {
        let claim = paper::face_speedup_claim();
        let _ = writeln!(
            out,
            "| {} | \"{}\" | the paper's | {row} | {ours_hw} | – |",
            claim.source, claim.quote
        );
        rows += 1;
    }
    if let Some(row) = body_claim_row(figures) {
        let claim = paper::body_speedup_claim();
        let _ = writeln!(
            out,
            "| {} | \"{}\" | the paper's | {row} | {ours_hw} | – |",
            claim.source, claim.quote
        );
        rows += 1;
    }
    if rows == 0 {
        let _ = writeln!(
            out,
            "| – | (no figure with a paper value was run) | | | | |"
        );
    }
    out.push('\n');
}

/// Our largest whole-step speed-up of the GPU over one CPU thread and over all cores (Fig. 7).
fn face_claim_row(figures: &[Figure]) -> Option<String> {
    let gpu = series_points(figures, "face-fig7", "GPU (packed kernel)");
    let one = series_points(figures, "face-fig7", "CPU, one thread");
    let best = gpu
        .iter()
        .filter_map(|g| {
            let o = one.iter().find(|o| o.x == g.x)?;
            Some((o.y / g.y, g.x))
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))?;
    Some(format!(
        "GPU whole step {}× faster than one CPU thread at {} faces (Fig. 7)",
        num(best.0),
        best.1
    ))
}

/// Our fast kernel's speed-up over one thread at the most points (Fig. 6).
fn body_claim_row(figures: &[Figure]) -> Option<String> {
    let fast = series_points(figures, "body-fig6", "GPU, fast kernel");
    let last = fast.iter().max_by(|a, b| a.x.total_cmp(&b.x))?;
    Some(format!(
        "fast GPU kernel {}× faster than one thread (Listing 1.2) at {} points (Fig. 6)",
        num(last.y),
        last.x
    ))
}

fn write_figure(out: &mut String, figure: &Figure) {
    let _ = writeln!(out, "## {}\n", figure.title);
    let _ = writeln!(out, "{}\n", figure.description);
    let _ = writeln!(
        out,
        "![{}](figures/{}.png)\n\n[CSV](figures/{}.csv) · [SVG](figures/{}.svg)\n",
        figure.title, figure.name, figure.name, figure.name
    );
    for panel in &figure.panels {
        write_panel(out, panel);
    }
}

/// A panel as a table: x down, one column per series, median (quartiles). Long series (per-frame
/// errors) are summarised by their mean and maximum instead.
fn write_panel(out: &mut String, panel: &Panel) {
    let mut xs: Vec<f64> = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.x))
        .collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    let _ = writeln!(out, "{} ({}):\n", panel.title, panel.y_label);
    if xs.len() > 12 {
        let _ = writeln!(
            out,
            "| series | points | mean ({u}) | median ({u}) | max ({u}) |\n|---|---|---|---|---|",
            u = panel.y_unit
        );
        for s in &panel.series {
            let mut v: Vec<f64> = s.points.iter().map(|p| p.y).collect();
            v.sort_by(f64::total_cmp);
            let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
            let median = v.get(v.len() / 2).copied().unwrap_or(f64::NAN);
            let max = v.last().copied().unwrap_or(f64::NAN);
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} |",
                s.name,
                v.len(),
                num(mean),
                num(median),
                num(max)
            );
        }
        out.push('\n');
        return;
    }
    write_table(out, panel, &xs);
    if panel.timing && panel.log_x && panel.log_y {
        write_exponents(out, panel);
    }
}

/// The slope of log y against log x by least squares: 1 is linear growth, 0 a constant cost.
pub fn growth_exponent(points: &[Point]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| p.x > 0.0 && p.y > 0.0)
        .map(|p| (p.x.ln(), p.y.ln()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let (mx, my) = logs
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let sxx: f64 = logs.iter().map(|(x, _)| (x - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|(x, y)| (x - mx) * (y - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

fn write_exponents(out: &mut String, panel: &Panel) {
    let parts: Vec<String> = panel
        .series
        .iter()
        .filter_map(|s| Some(format!("{} {:.2}", s.name, growth_exponent(&s.points)?)))
        .collect();
    if !parts.is_empty() {
        let _ = writeln!(
            out,
            "Growth exponent (least-squares slope of log time against log {}; 1 is linear): {}.\n",
            panel.x_unit,
            parts.join("; ")
        );
    }
}

fn write_table(out: &mut String, panel: &Panel, xs: &[f64]) {
    let names: Vec<&str> = panel.series.iter().map(|s| s.name.as_str()).collect();
    let _ = writeln!(out, "| {} | {} |", panel.x_label, names.join(" | "));
    let _ = writeln!(out, "|---|{}", "---|".repeat(names.len()));
    for &x in xs {
        let cells: Vec<String> = panel
            .series
            .iter()
            .map(|s| s.points.iter().find(|p| p.x == x).map_or("–".into(), cell))
            .collect();
        let x = if x.fract() == 0.0 {
            format!("{x:.0}")
        } else {
            num(x)
        };
        let _ = writeln!(out, "| {x} | {} |", cells.join(" | "));
    }
    out.push('\n');
}

#[cfg(test)]
mod tests {
    use super::{growth_exponent, num};
    use crate::record::Point;

    #[test]
    fn growth_exponent_of_power_laws() {
        let points = |k: f64| -> Vec<Point> {
            [10.0, 100.0, 1000.0]
                .map(|x: f64| Point::exact(x, 3.0 * x.powf(k)))
                .to_vec()
        };
        for k in [0.0, 1.0, 2.0] {
            assert!((growth_exponent(&points(k)).unwrap() - k).abs() < 1e-9);
        }
        assert_eq!(growth_exponent(&points(1.0)[..1]), None);
    }

    #[test]
    fn numbers_are_rounded_for_reading() {
        assert_eq!(num(1234.5), "1234");
        assert_eq!(num(12.345), "12.3");
        assert_eq!(num(1.2345), "1.23");
        assert_eq!(num(0.012345), "0.012");
        assert_eq!(num(f64::NAN), "–");
    }
}
