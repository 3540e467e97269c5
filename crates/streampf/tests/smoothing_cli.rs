//! `--smooth full` and `--smooth-lag L` (smoothed.csv) for the face and the body: a row for
//! every tracked frame, each value's mean within its interval, the lag giving the rows of the
//! whole run, the summary's comparison with the filter, a run stopped by a device fault keeping
//! the smoothed rows of the frames it wrote, and bad options refused.

mod common;

use common::{failure, ok, scratch, skipped_for_no_gpu, streampf};
use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

fn rows(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

/// Every value's interval is ordered and its mean lies near it (`NAME`, `NAME_lo`, `NAME_hi`
/// from column `first`; angles too, their ends being offsets about the mean): within the
/// interval widened by its own width on each side and 2 % of the mean. Not strictly within: a cloud
/// smoothed from the ancestry may hold over 97.5 % of its weight on a few particles, and then
/// the weighted mean can lie just outside the 2.5-97.5 % quantiles, pulled by the samples that
/// hold under 2.5 % of the weight (measured on the body's 150 samples at a lag of 2: 1.3e-4 below
/// an interval 2.3e-3 wide, 1.5e-5 off one of width 0, and 2.0e-3 off one of width 0 after the
/// survival rule's bisection went to ten steps), so the reach is 2 % of the mean's magnitude.
fn check_intervals(header: &[String], rows: &[Vec<String>], first: usize) {
    assert_eq!((header.len() - first) % 3, 0, "{header:?}");
    for row in rows {
        assert_eq!(row.len(), header.len(), "{row:?}");
        for k in (first..header.len()).step_by(3) {
            assert_eq!(header[k + 1], format!("{}_lo", header[k]));
            let [mean, lo, hi]: [f64; 3] = std::array::from_fn(|i| row[k + i].parse().unwrap());
            let reach = (hi - lo) + 2e-2 * (1.0 + mean.abs());
            assert!(
                lo <= hi && lo - reach <= mean && mean <= hi + reach,
                "{}: {lo} {mean} {hi}",
                header[k]
            );
        }
    }
}

/// 12 synthetic frames of 200 particles a face on `backend` (`--allow-software` with a GPU), with
/// the `smoothing` options.
fn face_command(out: &Path, backend: &str, smoothing: &[&str]) -> std::process::Output {
    let mut args = vec![
        "face",
        "track",
        "--synthetic",
        "--max-frames",
        "12",
        "--particles",
        "200",
        "--backend",
        backend,
        "--out",
        out.to_str().unwrap(),
    ];
    if backend != "cpu" {
        args.push("--allow-software");
    }
    args.extend(smoothing);
    streampf(&args)
}

fn face_run(out: &Path, smoothing: &[&str]) -> String {
    ok(&face_command(out, "cpu", smoothing))
}

#[test]
fn face_smoothing_writes_a_row_per_tracked_face_frame_whole_run_or_lagged() {
    let dir = scratch("face-smoothing");
    let text = face_run(&dir.join("full"), &["--smooth", "full"]);
    assert!(
        text.contains("smoothed over the whole run: mean translation error"),
        "{text}"
    );
    assert!(
        text.contains("the smoothed 95 % intervals held the truth"),
        "{text}"
    );
    let (header, full) = rows(&dir.join("full/smoothed.csv"));
    assert_eq!(&header[..5], ["frame", "track", "tx", "tx_lo", "tx_hi"]);
    check_intervals(&header, &full, 2);
    // One smoothed row per tracked row of states.csv.
    let (states_header, states) = rows(&dir.join("full/states.csv"));
    let status = states_header.iter().position(|c| c == "status").unwrap();
    let tracked: BTreeSet<(String, String)> = (states.iter())
        .filter(|r| r[status] == "tracking")
        .map(|r| (r[0].clone(), r[2].clone()))
        .collect();
    let smoothed: BTreeSet<(String, String)> =
        full.iter().map(|r| (r[0].clone(), r[1].clone())).collect();
    assert_eq!(smoothed, tracked);
    assert_eq!(full.len(), tracked.len());
    // The lag writes the same frames, online.
    let text = face_run(
        &dir.join("lag"),
        &["--smooth-lag", "3", "--lag-smoother", "ancestry"],
    );
    assert!(
        text.contains("smoothed with a lag of 3 frames (from the ancestry)"),
        "{text}"
    );
    assert!(text.contains("smoothing from the ancestry kept"), "{text}");
    let (_, lagged) = rows(&dir.join("lag/smoothed.csv"));
    let keys = |rows: &[Vec<String>]| -> BTreeSet<(String, String)> {
        rows.iter().map(|r| (r[0].clone(), r[1].clone())).collect()
    };
    assert_eq!(keys(&lagged), tracked);
    // A track's last frame is its filtered cloud in both: the same numbers.
    let last = |rows: &[Vec<String>]| rows.iter().find(|r| r[0] == "11" && r[1] == "0").cloned();
    assert_eq!(last(&full), last(&lagged));
    // The marginal smoother over each window (the default for the annealed face): the same
    // rows, and the same last frame.
    let text = face_run(&dir.join("marginal"), &["--smooth-lag", "3"]);
    assert!(
        text.contains("smoothed with a lag of 3 frames (the marginal smoother)"),
        "{text}"
    );
    let (_, marginal) = rows(&dir.join("marginal/smoothed.csv"));
    assert_eq!(keys(&marginal), tracked);
    assert_eq!(last(&full), last(&marginal));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A GPU run smooths on its GPU (`pf_gpu::smooth::OnGpu`): the same rows, each mean within its
/// interval, and the whole run's rows beside the lagged ones agree at a track's last frame.
#[test]
fn face_smoothing_on_the_gpu_writes_every_tracked_row() {
    let dir = scratch("face-smoothing-gpu");
    let full = face_command(&dir.join("full"), "gpu", &["--smooth", "full"]);
    if !full.status.success() && skipped_for_no_gpu(&failure(&full)) {
        return;
    }
    let text = ok(&full);
    assert!(text.contains("smoothed over the whole run"), "{text}");
    let (header, smoothed) = rows(&dir.join("full/smoothed.csv"));
    check_intervals(&header, &smoothed, 2);
    let (states_header, states) = rows(&dir.join("full/states.csv"));
    let status = states_header.iter().position(|c| c == "status").unwrap();
    let tracked = states.iter().filter(|r| r[status] == "tracking").count();
    assert_eq!(smoothed.len(), tracked);
    ok(&face_command(
        &dir.join("lag"),
        "gpu",
        &["--smooth-lag", "3"],
    ));
    let (_, lagged) = rows(&dir.join("lag/smoothed.csv"));
    assert_eq!(lagged.len(), tracked);
    let last = |rows: &[Vec<String>]| rows.iter().find(|r| r[0] == "11" && r[1] == "0").cloned();
    assert_eq!(last(&smoothed), last(&lagged));
    // From the ancestry the lag window stays on the GPU: only its summaries come back.
    let ancestry = ok(&face_command(
        &dir.join("ancestry"),
        "gpu",
        &["--smooth-lag", "3", "--lag-smoother", "ancestry"],
    ));
    assert!(
        ancestry.contains("(from the ancestry, on the GPU)"),
        "{ancestry}"
    );
    let (_, traced) = rows(&dir.join("ancestry/smoothed.csv"));
    assert_eq!(traced.len(), tracked);
    check_intervals(&header, &traced, 2);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A device lost mid-run with the lag window on it: the rows smoothed before the fault are kept,
/// and the frames still waiting in the window (whose particles were on the lost device) are named
/// on stderr, not silently dropped.
#[test]
fn a_device_fault_names_the_frames_its_lag_window_held() {
    let dir = scratch("face-lag-fault");
    let out = dir.join("fault");
    let run = Command::new(env!("CARGO_BIN_EXE_streampf"))
        .args([
            "face",
            "track",
            "--synthetic",
            "--frames",
            "12",
            "--particles",
            "200",
            "--backend",
            "gpu",
            "--allow-software",
            "--smooth-lag",
            "3",
            "--lag-smoother",
            "ancestry",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ])
        .env("NODEVICE_SELECT", "1")
        .env("STREAMPF_SIMULATE_GPU_FAULT_AT", "6")
        .output()
        .unwrap();
    let err = failure(&run);
    if skipped_for_no_gpu(&err) {
        return;
    }
    assert!(
        err.contains("device was lost") && err.contains("frame 6"),
        "{err}"
    );
    for track in 0..4 {
        assert!(
            err.contains(&format!("track {track}'s frames 3-5 were not smoothed")),
            "{err}"
        );
    }
    let (_, smoothed) = rows(&out.join("smoothed.csv"));
    let mut frames: Vec<&str> = smoothed.iter().map(|r| r[0].as_str()).collect();
    frames.dedup();
    assert_eq!(frames, ["0", "1", "2"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn body_smoothing_writes_every_frame_and_a_device_fault_keeps_the_written_ones() {
    let dir = scratch("body-smoothing");
    let out = dir.join("cpu");
    let text = ok(&streampf(&[
        "body",
        "track",
        "--synthetic",
        "--max-frames",
        "6",
        "--particles",
        "150",
        "--backend",
        "cpu",
        "--smooth-lag",
        "2",
        "--lag-smoother",
        "ancestry",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert!(
        text.contains(
            "smoothed with a lag of 2 frames (from the ancestry): mean joint position error"
        ),
        "{text}"
    );
    let (header, smoothed) = rows(&out.join("smoothed.csv"));
    assert_eq!(
        &header[..4],
        ["frame", "root_tx", "root_tx_lo", "root_tx_hi"]
    );
    check_intervals(&header, &smoothed, 1);
    let frames: Vec<&str> = smoothed.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(frames, ["0", "1", "2", "3", "4", "5"]);
    // A device lost at frame 4: frames 0-3 were written, and smoothed (on the CPU: the GPU
    // smoother hands a track its lost device cannot smooth to the CPU).
    let out = dir.join("fault");
    let run = Command::new(env!("CARGO_BIN_EXE_streampf"))
        .args([
            "body",
            "track",
            "--synthetic",
            "--max-frames",
            "8",
            "--particles",
            "150",
            "--backend",
            "gpu",
            "--allow-software",
            "--smooth",
            "full",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ])
        .env("NODEVICE_SELECT", "1")
        .env("STREAMPF_SIMULATE_GPU_FAULT_AT", "4")
        .output()
        .unwrap();
    let err = failure(&run);
    if !skipped_for_no_gpu(&err) {
        assert!(
            err.contains("device was lost") && err.contains("frame 4"),
            "{err}"
        );
        // The run says the smoother went over to the CPU.
        assert!(err.contains("smoothed on the CPU"), "{err}");
        let (_, smoothed) = rows(&out.join("smoothed.csv"));
        let frames: Vec<&str> = smoothed.iter().map(|r| r[0].as_str()).collect();
        assert_eq!(frames, ["0", "1", "2", "3"]);
        // From the ancestry on the GPU the lag window stays there: every frame smoothed.
        let out = dir.join("on-gpu");
        let text = ok(&streampf(&[
            "body",
            "track",
            "--synthetic",
            "--max-frames",
            "6",
            "--particles",
            "150",
            "--backend",
            "gpu",
            "--allow-software",
            "--smooth-lag",
            "2",
            "--lag-smoother",
            "ancestry",
            "--out",
            out.to_str().unwrap(),
        ]));
        assert!(text.contains("(from the ancestry, on the GPU)"), "{text}");
        let (header, smoothed) = rows(&out.join("smoothed.csv"));
        check_intervals(&header, &smoothed, 1);
        let frames: Vec<&str> = smoothed.iter().map(|r| r[0].as_str()).collect();
        assert_eq!(frames, ["0", "1", "2", "3", "4", "5"]);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_smoothing_options_are_refused() {
    for args in [
        &["--smooth", "full", "--smooth-lag", "2"][..],
        &["--smooth-lag", "0"],
        &["--smooth", "partial"],
        &["--smooth-lag", "three"],
    ] {
        let mut all = vec!["face", "track", "--synthetic"];
        all.extend(args);
        let err = failure(&streampf(&all));
        assert!(err.contains("--smooth"), "{args:?}: {err}");
    }
    for args in [
        &["--smooth", "full", "--smooth-motion", "0"][..],
        &["--smooth", "full", "--smooth-motion", "-0.5"],
        &["--smooth", "full", "--smooth-motion", "NaN"],
        &["--smooth", "full", "--smooth-motion", "inf"],
        &["--smooth-lag", "2", "--smooth-motion", "slow"],
        &["--smooth", "full", "--smooth-motion", "automatic"],
        &["--smooth-motion", "auto"],
        // Too small a scale leaves σ 0 (a value left out), too large one overflows.
        &["--smooth", "full", "--smooth-motion", "1e-44"],
        &["--smooth", "full", "--smooth-motion", "1e9"],
        // Nothing to scale without a smoother, nor with the ancestry smoother.
        &["--smooth-motion", "0.5"],
        &[
            "--smooth-lag",
            "2",
            "--lag-smoother",
            "ancestry",
            "--smooth-motion",
            "0.5",
        ],
    ] {
        for what in ["face", "body"] {
            let dir = scratch("bad-smoothing-motion");
            let mut all = vec![what, "track", "--synthetic", "--max-frames", "2"];
            all.extend(["--out", dir.to_str().unwrap()]);
            all.extend(args);
            let err = failure(&streampf(&all));
            assert!(err.contains("--smooth-motion"), "{what} {args:?}: {err}");
            // Refused before the run touched its output.
            assert!(!dir.join("states.csv").exists() && !dir.join("poses.csv").exists());
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    for args in [
        &["--lag-smoother", "marginal"][..],
        &["--smooth-lag", "2", "--lag-smoother", "sideways"],
    ] {
        let mut all = vec!["face", "track", "--synthetic"];
        all.extend(args);
        let err = failure(&streampf(&all));
        assert!(err.contains("--lag-smoother"), "{args:?}: {err}");
    }
}

/// `--smooth-motion` below 1 holds the smoother to slower motion: the same rows, each mean within
/// its interval, a track's last frame (its filtered cloud) unchanged, and narrower intervals
/// before it.
#[test]
fn a_slower_smoothing_motion_narrows_the_intervals_and_keeps_the_last_frame() {
    let dir = scratch("face-smoothing-motion");
    face_run(&dir.join("own"), &["--smooth", "full"]);
    face_run(
        &dir.join("slow"),
        &["--smooth", "full", "--smooth-motion", "0.25"],
    );
    let (header, own) = rows(&dir.join("own/smoothed.csv"));
    let (_, slow) = rows(&dir.join("slow/smoothed.csv"));
    check_intervals(&header, &slow, 2);
    let keys = |rows: &[Vec<String>]| -> Vec<(String, String)> {
        rows.iter().map(|r| (r[0].clone(), r[1].clone())).collect()
    };
    assert_eq!(keys(&own), keys(&slow));
    let last = |rows: &[Vec<String>]| rows.iter().find(|r| r[0] == "11" && r[1] == "0").cloned();
    assert!(last(&own).is_some());
    assert_eq!(last(&own), last(&slow));
    // The summed width of every value's interval over the frames before the last.
    let width = |rows: &[Vec<String>]| -> f64 {
        rows.iter()
            .filter(|r| r[0] != "11")
            .flat_map(|r| {
                (2..header.len()).step_by(3).map(move |k| {
                    let lo: f64 = r[k + 1].parse().unwrap();
                    let hi: f64 = r[k + 2].parse().unwrap();
                    hi - lo
                })
            })
            .sum()
    };
    assert!(
        width(&slow) < width(&own),
        "{} against {}",
        width(&slow),
        width(&own)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The rows of `auto`'s smoothed.csv (the motion chosen by the evidence) are `own`'s (the
/// tracker's motion), each mean within its interval and each interval taking in `own`'s (up to
/// a twentieth of its width: the two smoothers' weights differ by the Gauss transform's
/// rounding).
fn takes_in_the_trackers_motion(own: &Path, auto: &Path) {
    let (header, mut own) = rows(&own.join("smoothed.csv"));
    let (_, mut auto) = rows(&auto.join("smoothed.csv"));
    check_intervals(&header, &auto, 2);
    let key = |r: &Vec<String>| (r[1].parse::<u64>().unwrap(), r[0].parse::<u64>().unwrap());
    own.sort_by_key(key);
    auto.sort_by_key(key);
    let keys = |rows: &[Vec<String>]| -> Vec<(u64, u64)> { rows.iter().map(key).collect() };
    assert_eq!(keys(&own), keys(&auto));
    let number = |r: &[String], k: usize| -> f64 { r[k].parse().unwrap() };
    for (o, a) in own.iter().zip(&auto) {
        for k in (2..header.len()).step_by(3) {
            let slack = 0.05 * (number(o, k + 2) - number(o, k + 1));
            assert!(
                number(a, k + 1) <= number(o, k + 1) + slack,
                "{}: {a:?} against {o:?}",
                header[k]
            );
            assert!(
                number(a, k + 2) >= number(o, k + 2) - slack,
                "{}: {a:?} against {o:?}",
                header[k]
            );
        }
    }
}

/// `--smooth-lag L --smooth-motion auto`: each window's first frame under the motion the
/// evidence of the track's frames so far chooses; the same rows as the marginal lag smoother at
/// the tracker's motion, every interval taking in its, and the run naming the motion chosen.
#[test]
fn the_evidence_chooses_the_lag_smoothing_motion_as_frames_come() {
    let dir = scratch("face-smoothing-lag-auto");
    face_run(
        &dir.join("own"),
        &["--smooth-lag", "3", "--lag-smoother", "marginal"],
    );
    let text = face_run(
        &dir.join("auto"),
        &["--smooth-lag", "3", "--smooth-motion", "auto"],
    );
    assert!(
        text.contains("the evidence chose the smoother's motion"),
        "{text}"
    );
    takes_in_the_trackers_motion(&dir.join("own"), &dir.join("auto"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--smooth-motion auto`: the same rows as the tracker's own motion, each mean within its
/// interval, each interval taking in the tracker's motion's (up to a twentieth of its width: the
/// two smoothers' weights differ by the Gauss transform's rounding), the run naming the motion
/// the evidence chose for every value; the body's too.
#[test]
fn the_evidence_chooses_the_smoothing_motion_face_and_body() {
    let dir = scratch("face-smoothing-auto");
    face_run(&dir.join("own"), &["--smooth", "full"]);
    let text = face_run(
        &dir.join("auto"),
        &["--smooth", "full", "--smooth-motion", "auto"],
    );
    let line = (text.lines())
        .find(|l| l.starts_with("the evidence chose the smoother's motion"))
        .unwrap_or_else(|| panic!("{text}"));
    for name in ["tx", "ty", "scale", "rx", "ry", "rz", "alpha"] {
        assert!(line.contains(&format!(" {name} ")), "{line}");
    }
    takes_in_the_trackers_motion(&dir.join("own"), &dir.join("auto"));
    let body = dir.join("body");
    let text = ok(&streampf(&[
        "body",
        "track",
        "--synthetic",
        "--max-frames",
        "4",
        "--particles",
        "200",
        "--backend",
        "cpu",
        "--smooth",
        "full",
        "--smooth-motion",
        "auto",
        "--out",
        body.to_str().unwrap(),
    ]));
    assert!(
        text.contains("the evidence chose the smoother's motion"),
        "{text}"
    );
    let (header, rows_body) = rows(&body.join("smoothed.csv"));
    assert_eq!(rows_body.len(), 4);
    check_intervals(&header, &rows_body, 1);
    std::fs::remove_dir_all(&dir).unwrap();
}
