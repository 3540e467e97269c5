//! docs/OUTPUT.md documents every column the trackers write, and nothing they do not: the
//! headers of the files a run writes are compared with the document's tables.

mod common;

use common::{ok, scratch, streampf};
use std::path::Path;

/// The document's section whose heading contains `title`, up to the next `## ` heading.
fn section<'a>(doc: &'a str, title: &str) -> &'a str {
    let start = doc
        .find(&format!("## {title}"))
        .unwrap_or_else(|| panic!("OUTPUT.md has no section {title:?}"));
    let rest = &doc[start + 3..];
    &rest[..rest.find("\n## ").unwrap_or(rest.len())]
}

/// The column names a section's table lists in its first column: each `name` in backticks, and
/// `a` … `b` for the header's columns from a to b.
fn documented(section: &str, header: &[String]) -> Vec<String> {
    let mut names = Vec::new();
    for row in section.lines().filter(|l| l.starts_with("| `")) {
        let first = row.split('|').nth(1).unwrap_or_default();
        let quoted: Vec<&str> = first.split('`').skip(1).step_by(2).collect();
        if first.contains('…') && quoted.len() == 2 {
            let position = |name: &str| {
                header
                    .iter()
                    .position(|h| h == name)
                    .unwrap_or_else(|| panic!("the range's end {name} is not a column"))
            };
            let (a, b) = (position(quoted[0]), position(quoted[1]));
            names.extend(header[a..=b].iter().cloned());
        } else {
            names.extend(quoted.iter().map(|q| q.to_string()));
        }
    }
    names
}

fn header(path: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .next()
        .unwrap_or_default()
        .split(',')
        .map(str::to_string)
        .collect()
}

fn output_doc() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/OUTPUT.md");
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn assert_same(file: &str, mut written: Vec<String>, mut documented: Vec<String>) {
    written.sort();
    documented.sort();
    documented.dedup();
    assert_eq!(
        written, documented,
        "{file}: the columns written (left) against those OUTPUT.md documents (right)"
    );
}

#[test]
fn every_face_column_is_documented_and_every_documented_column_written() {
    let out = scratch("output-doc-face");
    let o = out.to_str().unwrap();
    ok(&streampf(&[
        "face",
        "track",
        "--synthetic",
        "--faces",
        "1",
        "--width",
        "320",
        "--height",
        "240",
        "--max-frames",
        "2",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
    ]));
    let doc = output_doc();
    let states = header(&out.join("states.csv"));
    let listed = documented(section(&doc, "`face track`: `states.csv`"), &states);
    assert_same("states.csv", states, listed);
    let errors = header(&out.join("errors.csv"));
    let listed = documented(section(&doc, "`face track`: `errors.csv`"), &errors);
    assert_same("errors.csv", errors, listed);
}

#[test]
fn every_body_column_is_documented() {
    let out = scratch("output-doc-body");
    let o = out.to_str().unwrap();
    ok(&streampf(&[
        "body",
        "track",
        "--synthetic",
        "--frames",
        "2",
        "--capsules",
        "19",
        "--width",
        "96",
        "--height",
        "72",
        "--particles",
        "50",
        "--layers",
        "1",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
    ]));
    let doc = output_doc();
    // poses.csv: `frame`, the pose values, `sd_` + each of them, `ess`, `log_evidence`,
    // `confidence`.
    let poses = header(&out.join("poses.csv"));
    let poses_doc = section(&doc, "`body track`: `poses.csv`");
    const TAIL: [&str; 3] = ["ess", "log_evidence", "confidence"];
    for name in ["frame"].iter().chain(&TAIL) {
        assert!(
            poses_doc.contains(&format!("| `{name}` |")),
            "{name} undocumented"
        );
    }
    assert!(poses_doc.contains("one column per pose value") && poses_doc.contains("`sd_`"));
    let values: Vec<&String> = poses
        .iter()
        .filter(|c| c.as_str() != "frame" && !TAIL.contains(&c.as_str()) && !c.starts_with("sd_"))
        .collect();
    assert_eq!(poses.len(), 1 + TAIL.len() + 2 * values.len(), "{poses:?}");
    for v in &values {
        assert!(poses.contains(&format!("sd_{v}")), "no sd_{v}");
    }
    assert_eq!(poses[0], "frame");
    assert_eq!(&poses[poses.len() - TAIL.len()..], TAIL);
    // joints.csv and errors.csv: as their paragraph says.
    let joints = header(&out.join("joints.csv"));
    assert_eq!(joints[0], "frame");
    assert!(joints[1..].chunks(3).all(|xyz| {
        let stem = xyz[0].trim_end_matches("_x");
        xyz.len() == 3 && xyz[1] == format!("{stem}_y") && xyz[2] == format!("{stem}_z")
    }));
    assert_eq!(
        header(&out.join("errors.csv")),
        ["frame", "mean_joint_error_m"]
    );
    let joints_doc = section(&doc, "`body track`: `joints.csv` and `errors.csv`");
    assert!(joints_doc.contains("`JOINT_x`, `JOINT_y`, `JOINT_z`"));
    assert!(joints_doc.contains("`frame,mean_joint_error_m`"));
}
