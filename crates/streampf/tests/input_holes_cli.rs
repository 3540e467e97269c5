//! Inputs that used to be taken silently or explained badly: each is now a clear error in the
//! option's own units, or a stated behaviour checked here.

mod common;

use common::{failure, ok, scratch, streampf};

const SMALL_FACES: [&str; 6] = ["--faces", "1", "--width", "320", "--height", "240"];

fn synth_faces(dir: &std::path::Path, frames: &str) {
    let mut args = vec!["face", "synth", "--out", dir.to_str().unwrap()];
    args.extend(SMALL_FACES);
    args.extend(["--frames", frames]);
    ok(&streampf(&args));
}

#[test]
fn face_inputs_are_taken_as_stated() {
    let dir = scratch("face-holes");
    let frames = dir.join("frames");
    let f = frames.to_str().unwrap();
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    // A shorter synth into the same directory replaces the longer one's frames.
    synth_faces(&frames, "8");
    synth_faces(&frames, "4");
    let pngs = std::fs::read_dir(&frames)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .path()
                .extension()
                .is_some_and(|x| x == "png")
        })
        .count();
    assert_eq!(pngs, 4);
    // faces.csv without a header: its first line is a rectangle, not a header.
    let rects = std::fs::read_to_string(frames.join("faces.csv")).unwrap();
    let rect = rects.lines().nth(1).unwrap().to_string();
    std::fs::write(frames.join("faces.csv"), format!("{rect}\n")).unwrap();
    // An old errors.csv in a reused --out goes (this run has no ground truth to write one).
    std::fs::remove_file(frames.join("ground_truth.csv")).unwrap();
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("errors.csv"), "stale\n").unwrap();
    let text = ok(&streampf(&[
        "face",
        "track",
        f,
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
    ]));
    assert!(text.contains("tracked 1 face through 4 frames"), "{text}");
    assert!(!out.join("errors.csv").exists());
    // More rectangles than --max-faces.
    let err = failure(&streampf(&[
        "face",
        "track",
        f,
        "--face",
        "10,10,80,80",
        "--face",
        "150,10,80,80",
        "--max-faces",
        "1",
        "--backend",
        "cpu",
        "--out",
        o,
    ]));
    assert!(
        err.contains("2 face rectangles") && err.contains("--max-faces is 1"),
        "{err}"
    );
    // The smallest frame the options allow renders, with every face.
    let tiny = dir.join("tiny");
    ok(&streampf(&[
        "face",
        "synth",
        "--out",
        tiny.to_str().unwrap(),
        "--width",
        "160",
        "--height",
        "120",
        "--faces",
        "16",
        "--frames",
        "1",
    ]));
    // Options checked in their own units, and before anything is created.
    let err = failure(&streampf(&[
        "face",
        "synth",
        "--out",
        o,
        "--max-yaw",
        "1000",
    ]));
    assert!(
        err.contains("--max-yaw must be within ±90 degrees, got 1000"),
        "{err}"
    );
    let fresh = dir.join("never-created");
    let err = failure(&streampf(&[
        "face",
        "track",
        f,
        "--backend",
        "cpu",
        "--overlay",
        "annotated.txt",
        "--out",
        fresh.to_str().unwrap(),
    ]));
    assert!(err.contains("annotated.txt"), "{err}");
    assert!(
        !fresh.exists(),
        "--out was created before --overlay was checked"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn body_and_demo_inputs_are_refused_clearly() {
    let dir = scratch("body-holes");
    let d = dir.to_str().unwrap();
    ok(&streampf(&[
        "body", "synth", "--out", d, "--frames", "3", "--width", "160", "--height", "120",
    ]));
    let truth = dir.join("ground_truth.csv");
    let text = std::fs::read_to_string(&truth).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    lines[2] = lines[2].replacen(",", ",1e30,", 1);
    let fields = lines[2].split(',').count();
    lines[2] = lines[2]
        .split(',')
        .take(fields - 1)
        .collect::<Vec<_>>()
        .join(",");
    std::fs::write(&truth, lines.join("\n") + "\n").unwrap();
    let err = failure(&streampf(&[
        "body",
        "track",
        d,
        "--backend",
        "cpu",
        "--out",
        d,
    ]));
    assert!(
        err.contains("ground_truth.csv") && err.contains("row 2") && err.contains("1e30"),
        "{err}"
    );
    let err = failure(&streampf(&["body", "track", "--synthetic", "--fov", "179"]));
    assert!(err.contains("less than 179 degrees, got 179"), "{err}");
    let err = failure(&streampf(&[
        "demo",
        "--targets",
        "65535",
        "--particles",
        "10000000",
    ]));
    assert!(err.contains("particles in all"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
