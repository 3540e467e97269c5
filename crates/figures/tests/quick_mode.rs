//! `reproduce-figures --quick` end to end: every figure's CSV (columns, finite values, CPU
//! timings that grow with the problem), SVG (stamped quick mode and the adapter), PNG (decodes,
//! not blank) and the report; and the bad inputs that must fail before any work.
//!
//! The GPU series are required: without an adapter the test fails, unless the run opts out
//! explicitly with STREAMPF_ALLOW_NO_GPU=1 (then only the CPU series are checked).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use streampf_figures::experiments::EXPERIMENTS;
use streampf_figures::record::CSV_COLUMNS;

fn binary() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_reproduce-figures"));
    cmd.env("NODEVICE_SELECT", "1");
    cmd
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("streampf-figures-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

/// RFC 4180 fields of one line (quoted fields may hold commas and doubled quotes).
fn fields(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut field = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut field)),
            _ => field.push(c),
        }
    }
    out.push(field);
    out
}

struct Row {
    panel: String,
    series: String,
    kind: String,
    x: f64,
    y: f64,
    y_unit: String,
}

fn check_csv(path: &Path) -> Vec<Row> {
    let content =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = content.lines();
    let header = fields(lines.next().expect("a header"));
    assert_eq!(header, CSV_COLUMNS, "{}: columns", path.display());
    let col = |name: &str| CSV_COLUMNS.iter().position(|c| *c == name).unwrap();
    let mut rows = Vec::new();
    for (n, line) in lines.enumerate() {
        let f = fields(line);
        assert_eq!(
            f.len(),
            CSV_COLUMNS.len(),
            "{} row {n}: {line}",
            path.display()
        );
        let value = |name: &str| -> f64 {
            let v: f64 = f[col(name)].parse().unwrap_or_else(|_| {
                panic!("{} row {n}: {name} = {:?}", path.display(), f[col(name)])
            });
            assert!(v.is_finite(), "{} row {n}: {name} = {v}", path.display());
            v
        };
        let (y, low, high) = (value("y"), value("y_low"), value("y_high"));
        assert!(
            low <= y && y <= high,
            "{} row {n}: {low} <= {y} <= {high}",
            path.display()
        );
        assert!(value("repeats") >= 1.0);
        assert_eq!(f[col("mode")], "quick");
        for name in [
            "figure", "panel", "series", "x_unit", "y_unit", "host", "adapter", "commit", "date",
        ] {
            assert!(
                !f[col(name)].is_empty(),
                "{} row {n}: empty {name}",
                path.display()
            );
        }
        rows.push(Row {
            panel: f[col("panel")].clone(),
            series: f[col("series")].clone(),
            kind: f[col("kind")].clone(),
            x: value("x"),
            y,
            y_unit: f[col("y_unit")].clone(),
        });
    }
    assert!(!rows.is_empty(), "{}: no rows", path.display());
    rows
}

/// In every timing panel, each CPU series was measured at several sizes, each time positive,
/// and not one value repeated (a series copied from a constant would be). Whether the times
/// grow with the size is a speed claim, the figures' and the benchmarks' to make: on a shared
/// 2-core machine a small size can be timed while another process runs and take longer than a
/// large one.
fn check_cpu_timings_are_measured(name: &str, rows: &[Row]) {
    let mut series: BTreeMap<(String, String), Vec<(f64, f64)>> = BTreeMap::new();
    for r in rows
        .iter()
        .filter(|r| r.y_unit == "ms" && r.kind.starts_with("cpu"))
    {
        series
            .entry((r.panel.clone(), r.series.clone()))
            .or_default()
            .push((r.x, r.y));
    }
    for ((panel, s), points) in series {
        assert!(points.len() >= 2, "{name}/{panel}/{s}: one size only");
        assert!(
            points.iter().all(|&(_, y)| y > 0.0),
            "{name}/{panel}/{s}: a time of zero or less: {points:?}"
        );
        assert!(
            points.iter().any(|&(_, y)| y != points[0].1),
            "{name}/{panel}/{s}: the same time at every size: {points:?}"
        );
    }
}

/// Decodes, has the expected size and is a drawing, not a blank page.
fn check_png(path: &Path) {
    let image = image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8();
    assert!(
        image.width() >= 400 && image.height() >= 300,
        "{}",
        path.display()
    );
    let total = (image.width() * image.height()) as usize;
    let inked = image.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    let mut colours: Vec<[u8; 3]> = image.pixels().map(|p| p.0).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(
        inked * 100 > total,
        "{}: only {inked} of {total} pixels drawn",
        path.display()
    );
    assert!(
        colours.len() > 20,
        "{}: {} colours",
        path.display(),
        colours.len()
    );
}

#[test]
fn quick_mode_writes_every_csv_plot_and_the_report() {
    let out = scratch("quick");
    let output = binary()
        .args(["--quick", "--out"])
        .arg(&out)
        .output()
        .expect("the binary runs");
    let log = text(&output);
    assert!(output.status.success(), "{log}");
    let allow_no_gpu = std::env::var("STREAMPF_ALLOW_NO_GPU").is_ok_and(|v| v == "1");
    assert!(
        allow_no_gpu || !log.contains("GPU:  no GPU"),
        "no GPU adapter: install Mesa's lavapipe (`cargo xtask test` does), or set \
         STREAMPF_ALLOW_NO_GPU=1 to check the CPU series only\n{log}"
    );
    let report = std::fs::read_to_string(out.join("REPRODUCTION.md")).expect("the report");
    assert!(report.contains("**Quick mode**"));
    for e in &EXPERIMENTS {
        let stem = out.join("figures").join(e.name);
        let rows = check_csv(&stem.with_extension("csv"));
        check_cpu_timings_are_measured(e.name, &rows);
        if !allow_no_gpu && ["face-fig6", "face-fig7", "body-fig5", "resamplers"].contains(&e.name)
        {
            assert!(
                rows.iter().any(|r| r.kind == "gpu"),
                "{}: no GPU series",
                e.name
            );
        }
        check_png(&stem.with_extension("png"));
        let svg = std::fs::read_to_string(stem.with_extension("svg")).expect("the SVG");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(
            svg.contains("QUICK MODE"),
            "{}: no quick-mode stamp",
            e.name
        );
        assert!(
            report.contains(&format!("figures/{}.png", e.name)),
            "{} not in the report",
            e.name
        );
    }
    let accuracy = check_csv(&out.join("figures/accuracy-body.csv"));
    let mean = |kind: &str| {
        let v: Vec<f64> = accuracy
            .iter()
            .filter(|r| r.kind == kind && r.panel.starts_with("mean"))
            .map(|r| r.y)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    // The particle smoother sits on the exact (RTS) smoother at every frame of the random walk:
    // within a quarter of RTS's smallest sd there (0.27; measured 0.025 at most, 1 000 particles).
    let posterior = check_csv(&out.join("figures/posterior.csv"));
    let walk = |kind: &str| -> Vec<f64> {
        (posterior.iter())
            .filter(|r| r.kind == kind && r.panel.starts_with("a random walk"))
            .map(|r| r.y)
            .collect()
    };
    let (particle, exact) = (walk("smoothed"), walk("exact"));
    assert!(!particle.is_empty() && particle.len() == exact.len());
    for (t, (p, e)) in particle.iter().zip(&exact).enumerate() {
        assert!(
            (p - e).abs() < 0.25 * 0.27,
            "frame {t}: particle smoother {p}, RTS {e}"
        );
    }
    // The likelihood must beat diffusion alone, or the figure shows nothing.
    assert!(
        mean("tracked") < mean("flat"),
        "tracker {} cm, flat {} cm",
        mean("tracked"),
        mean("flat")
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn an_unknown_figure_name_fails_before_any_work() {
    let out = scratch("unknown");
    let output = binary()
        .args(["--quick", "--only", "face-fig6,fig99", "--out"])
        .arg(&out)
        .output()
        .expect("the binary runs");
    let log = text(&output);
    assert!(!output.status.success());
    assert!(log.contains("unknown figure name fig99"), "{log}");
    for e in &EXPERIMENTS {
        assert!(log.contains(e.name), "the error lists {}: {log}", e.name);
    }
    assert!(!out.exists(), "nothing is written for a bad --only");
}

#[test]
fn an_unwritable_output_fails_before_any_work() {
    let base = scratch("unwritable");
    std::fs::create_dir_all(&base).unwrap();
    // A directory cannot be made under a regular file, even as root.
    let file = base.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let output = binary()
        .args(["--quick", "--out"])
        .arg(file.join("out"))
        .output()
        .expect("the binary runs");
    let log = text(&output);
    assert!(!output.status.success());
    assert!(
        log.contains("--out") && log.contains("cannot create"),
        "{log}"
    );
    assert!(
        !log.contains("reproduce-figures (quick mode)"),
        "no work starts: {log}"
    );
    let _ = std::fs::remove_dir_all(&base);
}
