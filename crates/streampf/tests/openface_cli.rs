//! `face track --format openface`: openface.csv read with the column list of OpenFace 2.0's
//! documentation (its `FeatureExtraction` output format), and round-tripped against the run's
//! own states.csv and landmarks.csv. Needs dlib's landmark model (`cargo xtask fetch-media`).

mod common;

use std::collections::HashMap;
use std::path::Path;

use common::{failure, ok, scratch, streampf};

const MODEL: &str = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";

/// The columns of OpenFace 2.0's CSV that streampf writes, in OpenFace's order and spelling
/// (its wiki's "Output Format" page lists `frame, face_id, timestamp, confidence, success`, the
/// gaze columns, `pose_Tx … pose_Rz`, then `x_0 … x_67`, `y_0 … y_67`, then the 3D landmarks,
/// shape parameters and action units).
fn openface_columns() -> Vec<String> {
    let mut names: Vec<String> = [
        "frame",
        "face_id",
        "timestamp",
        "confidence",
        "success",
        "pose_Tx",
        "pose_Ty",
        "pose_Tz",
        "pose_Rx",
        "pose_Ry",
        "pose_Rz",
    ]
    .map(String::from)
    .to_vec();
    names.extend((0..68).map(|k| format!("x_{k}")));
    names.extend((0..68).map(|k| format!("y_{k}")));
    names
}

/// A CSV as rows of named values (`sep` between fields, as the file writes them).
fn read(path: &Path, sep: &str) -> (Vec<String>, Vec<HashMap<String, String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(sep).map(String::from).collect();
    let rows = lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(sep).map(String::from))
                .collect()
        })
        .collect();
    (header, rows)
}

fn number(row: &HashMap<String, String>, column: &str) -> f64 {
    row[column]
        .trim()
        .parse()
        .unwrap_or_else(|e| panic!("{column}: {e}"))
}

#[test]
fn openface_csv_has_openfaces_columns_and_round_trips_to_states_and_landmarks() {
    if std::env::var_os("STREAMPF_NO_MEDIA").is_some_and(|v| v == "1") {
        eprintln!("face track --format openface: skipped by request (STREAMPF_NO_MEDIA=1)");
        return;
    }
    assert!(
        Path::new(MODEL).is_file(),
        "{MODEL} is missing: run `cargo xtask fetch-media`"
    );
    let data = scratch("openface-data");
    let out = scratch("openface-out");
    let (d, o) = (data.to_str().unwrap(), out.to_str().unwrap());
    ok(&streampf(&[
        "face", "synth", "--out", d, "--frames", "3", "--faces", "2", "--width", "480", "--height",
        "360",
    ]));
    let track = |extra: &[&str]| {
        let mut args = vec![
            "face",
            "track",
            d,
            "--landmarks",
            MODEL,
            "--landmarks-out",
            "--particles",
            "200",
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            o,
        ];
        args.extend_from_slice(extra);
        streampf(&args)
    };
    let text = ok(&track(&["--format", "openface", "--fov", "60"]));
    assert!(text.contains("openface.csv"), "{text}");
    let (header, rows) = read(&out.join("openface.csv"), ", ");
    assert_eq!(header, openface_columns());
    let (_, states) = read(&out.join("states.csv"), ",");
    let (_, landmarks) = read(&out.join("landmarks.csv"), ",");
    assert_eq!(rows.len(), 3 * 2, "one row per face and frame");
    // The camera OpenFace reads the pose through: --fov 60 on a 480-pixel-wide frame, the
    // principal point at the middle of the pixel grid.
    let focal = 240.0 / (30.0f64).to_radians().tan();
    let (cx, cy) = (239.5, 179.5);
    for row in &rows {
        let frame = number(row, "frame") as usize - 1;
        let face = row["face_id"].trim().to_string();
        let state = states
            .iter()
            .find(|s| s["frame"] == frame.to_string() && s["track"] == face)
            .expect("a states.csv row for each openface.csv row");
        let points = landmarks
            .iter()
            .find(|s| s["frame"] == frame.to_string() && s["track"] == face)
            .expect("a landmarks.csv row for each tracked face");
        assert_eq!(row["success"].trim(), "1");
        let close = |a: f64, b: f64, tol: f64, what: &str| {
            assert!(
                (a - b).abs() <= tol,
                "frame {frame} face {face} {what}: {a} vs {b}"
            );
        };
        close(
            number(row, "timestamp"),
            number(state, "timestamp"),
            5e-4,
            "timestamp",
        );
        close(
            number(row, "confidence"),
            number(state, "confidence"),
            5e-4,
            "confidence",
        );
        // Pitch and yaw change sign (OpenFace's z points away from the camera), roll does not.
        close(
            number(row, "pose_Rx"),
            -number(state, "rx"),
            1e-5,
            "pose_Rx",
        );
        close(
            number(row, "pose_Ry"),
            -number(state, "ry"),
            1e-5,
            "pose_Ry",
        );
        close(number(row, "pose_Rz"), number(state, "rz"), 1e-5, "pose_Rz");
        // The head's centre projects onto (tx, ty) through OpenFace's camera, in front of it at
        // a head's distance for 60-pixel faces seen at 60°: about a metre or two.
        let (tx, ty, tz) = (
            number(row, "pose_Tx"),
            number(row, "pose_Ty"),
            number(row, "pose_Tz"),
        );
        assert!((300.0..5000.0).contains(&tz), "pose_Tz {tz} mm");
        close(
            focal * tx / tz + cx,
            number(state, "tx"),
            0.05,
            "tx from pose_T",
        );
        close(
            focal * ty / tz + cy,
            number(state, "ty"),
            0.05,
            "ty from pose_T",
        );
        for k in 0..68 {
            close(
                number(row, &format!("x_{k}")),
                number(points, &format!("x{k}")),
                2e-3,
                "x",
            );
            close(
                number(row, &format!("y_{k}")),
                number(points, &format!("y{k}")),
                2e-3,
                "y",
            );
        }
    }
    // OUTPUT.md documents every column beside states.csv's.
    let doc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/OUTPUT.md"))
            .unwrap();
    assert!(doc.contains("`openface.csv`") && doc.contains("`pose_Rx`, `pose_Ry`, `pose_Rz`"));
    // Without a landmark model there is no face size: a clear error, nothing tracked.
    let err = failure(&streampf(&[
        "face",
        "track",
        d,
        "--generic-model",
        "--format",
        "openface",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.join("none").to_str().unwrap(),
    ]));
    assert!(
        err.contains("--format openface needs dlib's 68-landmark model"),
        "{err}"
    );
    std::fs::remove_dir_all(&data).unwrap();
}
