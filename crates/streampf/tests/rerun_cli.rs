//! `--rerun FILE.rrd`: the recordings of the synthetic runs, opened with rerun's own Python SDK
//! (rerun-sdk, the version the crate is pinned to; `cargo xtask test` installs it), hold the
//! entities docs/OUTPUT.md lists, one row a frame, with the expected instance counts. Built
//! without the `rerun` feature, `--rerun` is a clear error.

mod common;

use common::{scratch, streampf};

#[cfg(not(feature = "rerun"))]
#[test]
fn without_the_feature_rerun_is_a_clear_error_before_any_work() {
    let out = scratch("rerun-off");
    let err = common::failure(&streampf(&[
        "face",
        "track",
        "--synthetic",
        "--rerun",
        out.join("run.rrd").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    assert!(err.contains("--features rerun"), "{err}");
    assert!(!out.exists(), "a refused run wrote {}", out.display());
}

#[cfg(feature = "rerun")]
mod recording {
    use super::*;
    use common::ok;
    use serde_json::Value;
    use std::path::Path;

    /// `cargo xtask test --no-media` (STREAMPF_NO_MEDIA=1) leaves the Python references,
    /// rerun's SDK among them, uninstalled: the reading is then skipped, saying so.
    fn sdk_opted_out() -> bool {
        let out = std::env::var_os("STREAMPF_NO_MEDIA").is_some_and(|v| v == "1");
        if out {
            eprintln!("skipped reading the recording with rerun's SDK (STREAMPF_NO_MEDIA=1)");
        }
        out
    }

    /// What the SDK reads from `path` (see tests/python/rerun_contents.py).
    fn contents(path: &Path) -> Value {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/rerun_contents.py");
        let output = std::process::Command::new("python3")
            .arg(&script)
            .arg(path)
            .output()
            .expect("python3 runs");
        assert!(
            output.status.success(),
            "reading {} with rerun's SDK failed (pip install rerun-sdk==0.36.3; `cargo xtask \
             test` installs it):\n{}",
            path.display(),
            String::from_utf8_lossy(&output.stderr)
        );
        serde_json::from_slice(&output.stdout).expect("JSON from rerun_contents.py")
    }

    fn entity<'a>(recording: &'a Value, path: &str) -> &'a Value {
        recording["entities"]
            .get(path)
            .unwrap_or_else(|| panic!("no entity {path} in {recording}"))
    }

    /// The entity was logged once in each of frames 0..n.
    fn every_frame(recording: &Value, path: &str, n: u64) {
        let frames: Vec<u64> = entity(recording, path)["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f.as_u64().unwrap())
            .collect();
        assert_eq!(frames, (0..n).collect::<Vec<_>>(), "{path}");
    }

    /// The instances in each row of the entity's `column`.
    fn instances(recording: &Value, path: &str, column: &str) -> Vec<u64> {
        entity(recording, path)["instances"][column]
            .as_array()
            .unwrap_or_else(|| panic!("{path} has no {column}: {}", entity(recording, path)))
            .iter()
            .map(|n| n.as_u64().unwrap())
            .collect()
    }

    #[test]
    fn the_face_recording_holds_frames_tracks_particles_and_time_series() {
        let out = scratch("rerun-face");
        let rrd = out.join("faces.rrd");
        let text = ok(&streampf(&[
            "face",
            "track",
            "--synthetic",
            "--faces",
            "2",
            "--frames",
            "3",
            "--width",
            "320",
            "--height",
            "240",
            "--particles",
            "64",
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
            "--rerun",
            rrd.to_str().unwrap(),
        ]));
        assert!(text.contains("tracked 2 faces"), "{text}");
        assert!(rrd.metadata().unwrap().len() > 10_000);
        if sdk_opted_out() {
            return;
        }
        let recording = contents(&rrd);
        assert_eq!(recording["application_id"], "streampf face track");
        assert_eq!(recording["recordings"], 1);
        every_frame(&recording, "/video/frame", 3);
        for track in 0..2 {
            let base = format!("/video/faces/{track}");
            for part in ["points", "axes", "box", "particles"] {
                every_frame(&recording, &format!("{base}/{part}"), 3);
            }
            assert_eq!(
                instances(
                    &recording,
                    &format!("{base}/particles"),
                    "Points2D:positions"
                ),
                [64, 64, 64]
            );
            assert_eq!(
                instances(&recording, &format!("{base}/axes"), "LineStrips2D:strips"),
                [3, 3, 3]
            );
            let points = instances(&recording, &format!("{base}/points"), "Points2D:positions");
            assert!(
                points.iter().all(|&n| (50..=300).contains(&n)),
                "{points:?}"
            );
            for series in [
                "ess",
                "confidence",
                "residual",
                "translation_error_px",
                "rotation_error_deg",
            ] {
                every_frame(&recording, &format!("/metrics/faces/{track}/{series}"), 3);
            }
        }
    }

    #[test]
    fn the_body_recording_holds_points_skeletons_samples_and_time_series() {
        let out = scratch("rerun-body");
        let rrd = out.join("body.rrd");
        ok(&streampf(&[
            "body",
            "track",
            "--synthetic",
            "--frames",
            "3",
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
            out.to_str().unwrap(),
            "--rerun",
            rrd.to_str().unwrap(),
        ]));
        assert!(rrd.metadata().unwrap().len() > 10_000);
        if sdk_opted_out() {
            return;
        }
        let recording = contents(&rrd);
        assert_eq!(recording["application_id"], "streampf body track");
        for path in [
            "/world/points",
            "/world/estimate",
            "/world/truth",
            "/world/particles",
        ] {
            every_frame(&recording, path, 3);
        }
        for skeleton in ["/world/estimate", "/world/truth"] {
            assert_eq!(
                instances(&recording, skeleton, "Capsules3D:lengths"),
                [19, 19, 19]
            );
        }
        assert_eq!(
            instances(&recording, "/world/particles", "Points3D:positions"),
            [50, 50, 50]
        );
        let points = instances(&recording, "/world/points", "Points3D:positions");
        assert!(points.iter().all(|&n| n > 100), "{points:?}");
        for series in [
            "/metrics/ess",
            "/metrics/confidence",
            "/metrics/joint_error_m",
        ] {
            every_frame(&recording, series, 3);
        }
    }
}
