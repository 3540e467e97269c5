//! `--scenario exits-and-crossings`: `face synth` writes ground truth only for the faces in the
//! picture, which `face track DIR` reads (a face away has no row, not a bad one); `face track
//! --synthetic --scenario` finds the faces with the detector and prints the identity scores,
//! writing the true faces it scored against (mot_truth.csv). The scores themselves are held to
//! py-motmetrics in the Python suite (`test_mot.py`).

mod common;

use common::{ok, scratch, streampf};

#[test]
fn a_scenarios_ground_truth_leaves_out_faces_away_and_its_run_prints_identity_scores() {
    let data = scratch("scenario-data");
    let out = scratch("scenario-out");
    let (d, o) = (data.to_str().unwrap(), out.to_str().unwrap());
    let size = ["--frames", "60", "--width", "320", "--height", "240"];
    let mut synth = vec![
        "face",
        "synth",
        "--out",
        d,
        "--scenario",
        "exits-and-crossings",
    ];
    synth.extend_from_slice(&size);
    ok(&streampf(&synth));
    let truth = std::fs::read_to_string(data.join("ground_truth.csv")).unwrap();
    let face_0: Vec<usize> = truth
        .lines()
        .skip(1)
        .filter(|l| l.split(',').nth(1) == Some("0"))
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert!(
        face_0.len() < 60 && face_0.len() > 10,
        "face 0 in {} frames",
        face_0.len()
    );
    assert!(
        face_0.windows(2).any(|w| w[1] > w[0] + 1),
        "face 0 never leaves and returns"
    );
    assert!(!truth.contains("NaN"));
    // The directory tracks, its errors measured where the faces are known.
    let text = ok(&streampf(&[
        "face",
        "track",
        d,
        "--backend",
        "cpu",
        "--particles",
        "100",
        "--quiet",
        "--out",
        o,
    ]));
    assert!(text.contains("mean translation error"), "{text}");
    // The scenario run scores identities.
    let scored = out.join("scored");
    let mut track = vec![
        "face",
        "track",
        "--synthetic",
        "--scenario",
        "exits-and-crossings",
        "--backend",
        "cpu",
        "--particles",
        "100",
        "--out",
        scored.to_str().unwrap(),
    ];
    track.extend_from_slice(&size);
    let text = ok(&streampf(&track));
    assert!(text.contains("identities: IDF1 "), "{text}");
    let mot = std::fs::read_to_string(scored.join("mot_truth.csv")).unwrap();
    assert_eq!(mot.lines().next(), Some("frame,identity,x,y,radius"));
    let rows = mot.lines().count() - 1;
    assert_eq!(
        rows,
        truth.lines().count() - 1,
        "the same true faces as face synth's"
    );
    std::fs::remove_dir_all(&data).unwrap();
}

/// The identity scenario made smaller (four people over 300 frames at 640×480, heads 75 px wide,
/// the walking head at 19 px a frame: the full-size video shrunk) on the CPU, 1000 particles a
/// face, the detector finding them: the goal of an IDF1 of at least 0.95 and at most one
/// identity switch per 1 000 true face-frames. docs/ACCURACY.md ("Identities") gives the full
/// size, 1024×768, on the CPU and on a GPU. The walked-out head's track left on the background
/// ends (`face_tracker::auto::faint`, `auto::pinned`): on seed 2, 23 false positives with the
/// rules, 33 with the pinned rule alone, 231 and an identity switch without either (IDF1 0.84;
/// the bound below tells the three apart).
#[test]
fn the_identity_scenario_keeps_who_is_who() {
    let scores = scenario_scores(&SMALLER, &["--seed", "2"]);
    assert_meets_the_identity_goal(&scores);
    assert!(
        score_before(&scores, " false positives") <= 28.0,
        "{scores}"
    );
}

/// The same on a GPU (Mesa's lavapipe in CI): the tracker's steps on the GPU, the detector on
/// the CPU (the GPU detector has its own tests, and on lavapipe it would add a third to the
/// run's time).
#[test]
fn the_identity_scenario_keeps_who_is_who_on_a_gpu() {
    let out = scratch("scenario-gpu");
    let mut args = scenario_args(&out, &SMALLER, &["--seed", "3"]);
    let backend = args.iter().position(|a| *a == "--backend").unwrap() + 1;
    args.splice(
        backend..=backend,
        ["gpu", "--allow-software", "--detector", "cpu"],
    );
    let run = streampf(&args);
    let err = String::from_utf8_lossy(&run.stderr);
    if !run.status.success() && common::skipped_for_no_gpu(&err) {
        return;
    }
    let text = ok(&run);
    std::fs::remove_dir_all(&out).unwrap();
    assert!(text.contains("on GPU: "), "{text}");
    assert_meets_the_identity_goal(&identity_scores(&text));
}

/// The scenario's size in the tests: 640×480 (its heads and their walk scale with the frame).
const SMALLER: [&str; 4] = ["--width", "640", "--height", "480"];

/// An IDF1 of at least 0.95 and at most one identity switch per 1 000 true face-frames.
fn assert_meets_the_identity_goal(scores: &str) {
    let idf1: f64 = scores.split_whitespace().next().unwrap().parse().unwrap();
    let switches = score_before(scores, " identity switches");
    let face_frames = score_before(scores, " true face-frames");
    // Four faces over 300 frames, the walking one away for a third of them.
    assert!(face_frames > 1000.0, "{scores}");
    assert!(idf1 >= 0.95, "{scores}");
    assert!(switches * 1000.0 <= face_frames, "{scores}");
}

/// The identity scores `face track --synthetic --scenario exits-and-crossings --backend cpu`
/// prints with `size` and `args` (the text after "identities: IDF1 ").
fn scenario_scores(size: &[&str], args: &[&str]) -> String {
    let out = scratch(&format!("scenario-{}", args.join("-")));
    let text = ok(&streampf(&scenario_args(&out, size, args)));
    std::fs::remove_dir_all(&out).unwrap();
    identity_scores(&text)
}

/// The command line of a scenario run on the CPU writing into `out`.
fn scenario_args<'a>(out: &'a std::path::Path, size: &[&'a str], args: &[&'a str]) -> Vec<&'a str> {
    let mut all = vec![
        "face",
        "track",
        "--synthetic",
        "--scenario",
        "exits-and-crossings",
        "--backend",
        "cpu",
        "--out",
        out.to_str().unwrap(),
    ];
    all.extend_from_slice(size);
    all.extend_from_slice(args);
    all
}

/// The identity scores a run printed (the text after "identities: IDF1 ").
fn identity_scores(text: &str) -> String {
    text.lines()
        .find_map(|l| l.strip_prefix("identities: IDF1 "))
        .unwrap_or_else(|| panic!("no identity scores in {text}"))
        .to_string()
}

/// The number just before `marker` in the scores.
fn score_before(scores: &str, marker: &str) -> f64 {
    let head = &scores[..scores.find(marker).unwrap_or_else(|| panic!("{scores}"))];
    let word = head.split_whitespace().last().unwrap();
    word.parse()
        .unwrap_or_else(|_| panic!("{word} in {scores}"))
}

/// At 640×480 with heads 80 px wide over 200 frames (the scenario squeezed: its walking head
/// back while the heads are turned away from the detector) the walking head's track, left on
/// the background when its head walked out, ends (`face_tracker::auto::faint`, `auto::pinned`)
/// instead of staying there: on seed 1, 24 false positives with the rules, 149 and an identity
/// switch without them (the bound below tells the two apart). And where two walking heads
/// cross, the track that jumps onto the other head goes back to its own (`auto::duplicates`,
/// walking back): two identity switches without it, none with it. On seed 2 the returning
/// head, turned away from the detector, walks in front of a standing head and carries its track
/// off; the track goes back to its place once its template fits there better
/// (`auto::carried`): IDF1 0.922 with it, 0.719 without.
#[test]
fn a_track_left_on_the_background_ends_and_crossing_heads_keep_their_tracks() {
    let size = ["--width", "640", "--height", "480", "--face-width", "80"];
    let scores = scenario_scores(&size, &["--frames", "200", "--seed", "1"]);
    assert!(
        score_before(&scores, " false positives") <= 60.0,
        "{scores}"
    );
    assert_eq!(score_before(&scores, " identity switches"), 0.0, "{scores}");
    let carried = scenario_scores(&size, &["--frames", "200", "--seed", "2"]);
    let idf1: f64 = carried.split_whitespace().next().unwrap().parse().unwrap();
    assert!(idf1 >= 0.85, "{carried}");
}
