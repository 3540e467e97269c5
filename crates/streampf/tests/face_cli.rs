//! `streampf face synth` and `streampf face track` as a user runs them.

mod common;

use common::{failure, number_after, ok, scratch, streampf};

const SMALL: [&str; 8] = [
    "--frames", "8", "--faces", "2", "--width", "480", "--height", "360",
];

#[test]
fn synth_then_track_a_directory_with_overlays() {
    let data = scratch("data");
    let out = scratch("out");
    let overlay = scratch("overlay");
    let d = data.to_str().unwrap();
    let mut args = vec!["face", "synth", "--out", d];
    args.extend(SMALL);
    assert!(ok(&streampf(&args)).contains("wrote 8 frames of 480x360 with 2 faces"));
    // The frames in colour (a warm tint), so that the overlay has colour to keep.
    for entry in std::fs::read_dir(&data).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "png") {
            let gray = image::open(&path).unwrap().to_luma8();
            let tinted = image::RgbImage::from_fn(gray.width(), gray.height(), |x, y| {
                let v = f32::from(gray.get_pixel(x, y).0[0]);
                image::Rgb([v as u8, (0.85 * v) as u8, (0.6 * v) as u8])
            });
            tinted.save(&path).unwrap();
        }
    }
    let text = ok(&streampf(&[
        "face",
        "track",
        d,
        "--out",
        out.to_str().unwrap(),
        "--overlay",
        overlay.to_str().unwrap(),
        "--particles",
        "200",
        "--backend",
        "cpu",
        "--quiet",
    ]));
    assert!(
        number_after(&text, "mean translation error:") < 5.0,
        "{text}"
    );
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    assert_eq!(states.lines().count(), 1 + 8 * 2);
    assert!(
        states.starts_with(
            "frame,timestamp,track,success,status,tx,ty,scale,rx,ry,rz,alpha,residual"
        )
    );
    let overlays = std::fs::read_dir(&overlay).unwrap().count();
    assert_eq!(overlays, 8);
    let frame = image::open(overlay.join("overlay_00003.png"))
        .unwrap()
        .to_rgb8();
    // The posed points and labels are drawn in the tracks' colours (track 0 yellow, track 1
    // cyan: no axis's pure red, green or blue).
    let count = |colour: [u8; 3]| frame.pixels().filter(|p| p.0 == colour).count();
    assert!(count([255, 200, 0]) > 50 && count([0, 220, 220]) > 50);
    // The picture keeps the input's colour: the background is warm, not gray.
    let corner = frame.get_pixel(470, 350).0;
    assert!(corner[0] > corner[2] + 10, "{corner:?}");
    // The frame number is written top left: white ink on a black box.
    let label = |x: u32, y: u32| frame.get_pixel(x, y).0;
    let box_pixels: Vec<[u8; 3]> = (4..20)
        .flat_map(|y| (4..120).map(move |x| (x, y)))
        .map(|(x, y)| label(x, y))
        .collect();
    assert!(box_pixels.contains(&[255, 255, 255]));
    assert!(box_pixels.contains(&[0, 0, 0]));
    // --face overrides faces.csv: one face only.
    let rects = std::fs::read_to_string(data.join("faces.csv")).unwrap();
    let first = rects.lines().nth(1).unwrap();
    let text = ok(&streampf(&[
        "face",
        "track",
        d,
        "--out",
        out.to_str().unwrap(),
        "--face",
        first,
        "--particles",
        "100",
        "--backend",
        "cpu",
    ]));
    assert!(
        text.contains("tracking 1 face from its rectangle through 8 frames of 480x360"),
        "{text}"
    );
    for dir in [data, out, overlay] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn track_synthetic_prints_errors_and_frame_rate() {
    let out = scratch("synthetic");
    let mut args = vec![
        "face",
        "track",
        "--synthetic",
        "--out",
        out.to_str().unwrap(),
        "--particles",
        "200",
        "--backend",
        "cpu",
    ];
    args.extend(SMALL);
    let text = ok(&streampf(&args));
    assert!(
        text.contains(
            "tracking 2 faces from their rectangles through 8 frames of 480x360, 200 particles each, on CPU"
        ),
        "{text}"
    );
    assert!(number_after(&text, "mean rotation error:") < 8.0, "{text}");
    assert!(text.contains("frames/s"));
    // Faces from rectangles only: each track is an identity of its own, states.csv's last
    // column.
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    assert!(
        states.lines().next().unwrap().ends_with(",qz,identity"),
        "{states}"
    );
    for row in states.lines().skip(1) {
        let cells: Vec<&str> = row.split(',').collect();
        assert_eq!(cells[2], cells[cells.len() - 1], "{row}");
    }
    // --face-width draws the heads that wide: the tracker's rectangles (the heads' own at
    // scale 1) are that wide in the first frame's rows of states.csv, S = 1 there.
    let text = ok(&streampf(
        &[args.as_slice(), &["--face-width", "50"]].concat(),
    ));
    assert!(number_after(&text, "mean rotation error:") < 30.0, "{text}");
    let synth = scratch("synthetic-small");
    ok(&streampf(&[
        "face",
        "synth",
        "--out",
        synth.to_str().unwrap(),
        "--face-width",
        "50",
        "--frames",
        "1",
        "--faces",
        "2",
        "--width",
        "480",
        "--height",
        "360",
    ]));
    let faces = std::fs::read_to_string(synth.join("faces.csv")).unwrap();
    let rows: Vec<&str> = faces.lines().skip(1).collect();
    assert_eq!(rows.len(), 2, "{faces}");
    for row in rows {
        let width: f32 = row.split(',').nth(2).unwrap().parse().unwrap();
        assert!((width - 50.0).abs() < 0.5, "{row}");
    }
    std::fs::remove_dir_all(&synth).unwrap();
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn bad_face_inputs_are_clear_errors() {
    let data = scratch("bad");
    let d = data.to_str().unwrap();
    let err = failure(&streampf(&["face", "track", d]));
    assert!(err.contains(d), "{err}");
    std::fs::create_dir_all(&data).unwrap();
    assert!(failure(&streampf(&["face", "track", d])).contains("no image frames"));
    // Frames without rectangles; then a zero-size rectangle; then an unreadable frame.
    let mut args = vec!["face", "synth", "--out", d];
    args.extend(SMALL);
    ok(&streampf(&args));
    // Without faces.csv the detector starts the tracks: a cascade that is not there, or not a
    // cascade, is a clear error.
    std::fs::remove_file(data.join("faces.csv")).unwrap();
    let cascade = data.join("cascade.xml");
    for contents in [None, Some("<opencv_storage><cascade>")] {
        if let Some(text) = contents {
            std::fs::write(&cascade, text).unwrap();
        }
        let path = cascade.to_str().unwrap();
        let err = failure(&streampf(&[
            "face",
            "track",
            d,
            "--cascade",
            path,
            "--backend",
            "cpu",
        ]));
        assert!(err.contains("cascade.xml"), "{contents:?}: {err}");
    }
    let err = failure(&streampf(&[
        "face",
        "track",
        d,
        "--face",
        "10,10,0,40",
        "--backend",
        "cpu",
    ]));
    assert!(err.contains("at least 8x8"), "{err}");
    let err = failure(&streampf(&[
        "face",
        "track",
        d,
        "--face",
        "10,10,40",
        "--backend",
        "cpu",
    ]));
    assert!(err.contains("x,y,width,height"), "{err}");
    // A frame that is not an image: skipped with a warning (its track coasts), or with
    // --strict the end of the run, after the frames before it were written.
    std::fs::write(data.join("frame_00003.png"), "not a png").unwrap();
    let out = data.join("out");
    let o = out.to_str().unwrap();
    let face = [
        "--face",
        "100,80,90,110",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
    ];
    let run = streampf(&[&["face", "track", d][..], &face].concat());
    let text = ok(&run);
    assert!(text.contains("1 unreadable frame skipped (3"), "{text}");
    let warning = String::from_utf8_lossy(&run.stderr);
    assert!(
        warning.contains("skipping frame 3") && warning.contains("frame_00003.png"),
        "{warning}"
    );
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    assert!(
        states
            .lines()
            .any(|l| l.starts_with("3,0.120000,0,0,skipped,")),
        "{states}"
    );
    let skipped = std::fs::read_to_string(out.join("skipped.csv")).unwrap();
    assert!(
        skipped.lines().nth(1).is_some_and(|l| l.starts_with("3,")),
        "{skipped}"
    );
    let err = failure(&streampf(
        &[&["face", "track", d, "--strict"][..], &face].concat(),
    ));
    assert!(
        err.contains("frame_00003.png") && err.contains("--strict"),
        "{err}"
    );
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    let frames: Vec<&str> = states
        .lines()
        .skip(1)
        .map(|l| &l[..l.find(',').unwrap()])
        .collect();
    assert_eq!(
        frames,
        ["0", "1", "2"],
        "the rows of the frames before the bad one"
    );
    // An odd-sized frame in the middle of a video: skipped as an unreadable one is
    // (tests/reliability_cli.rs), or with --strict the end of the run.
    image::GrayImage::new(100, 100)
        .save(data.join("frame_00003.png"))
        .unwrap();
    let err = failure(&streampf(
        &[&["face", "track", d, "--strict"][..], &face].concat(),
    ));
    assert!(err.contains("100x100"), "{err}");
    // Ground truth with a fractional frame index, and with a value that is not a number.
    let header = "frame,face,tx,ty,scale,rx,ry,rz,alpha";
    for (row, expect) in [
        ("0.5,0,1,1,1,0,0,0,1", "whole numbers"),
        ("0,0,NaN,1,1,0,0,0,1", "NaN"),
    ] {
        std::fs::write(data.join("ground_truth.csv"), format!("{header}\n{row}\n")).unwrap();
        let err = failure(&streampf(&[
            "face",
            "track",
            d,
            "--face",
            "100,80,90,110",
            "--backend",
            "cpu",
        ]));
        assert!(
            err.contains("ground_truth.csv") && err.contains(expect),
            "{err}"
        );
    }
    // Face maps of the wrong kinds.
    let rgb = data.join("rgb.png");
    image::RgbImage::new(9, 9).save(&rgb).unwrap();
    let err = failure(&streampf(&[
        "face",
        "track",
        "--synthetic",
        "--heightmap",
        rgb.to_str().unwrap(),
        "--normalmap",
        rgb.to_str().unwrap(),
    ]));
    assert!(err.contains("gray"), "{err}");
    for bad in [
        vec!["face", "track", "--synthetic", "--heightmap", "h.png"],
        vec!["face", "track", "--synthetic", "--faces", "0"],
        vec!["face", "track", "--synthetic", "--width", "10"],
        vec!["face", "track", "--synthetic", "--max-yaw", "120"],
        vec!["face", "track", "--synthetic", "--face-width", "8"],
        vec!["face", "track", "--synthetic", "--face-width", "800"],
        vec!["face", "track", "--synthetic", "--particles", "0"],
        vec!["face", "track"],
    ] {
        let err = failure(&streampf(&bad));
        assert!(err.len() > 10, "{bad:?}: {err}");
    }
    // --face-depth: a scale in range, and only where the photographed head is the model.
    for (depth, expected) in [
        ("0", "give a scale from 0.25 to 4"),
        ("4.5", "give a scale from 0.25 to 4"),
        ("NaN", "give a scale from 0.25 to 4"),
        ("deep", "invalid float"),
    ] {
        let err = failure(&streampf(&[
            "face",
            "track",
            "--synthetic",
            "--face-model",
            "photographed",
            "--face-depth",
            depth,
        ]));
        assert!(err.contains(expected), "{depth}: {err}");
    }
    // --fov: the camera's horizontal field of view, 1 to 170 degrees.
    for fov in ["0", "171", "NaN", "wide"] {
        let err = failure(&streampf(&["face", "track", "--synthetic", "--fov", fov]));
        assert!(
            err.contains("give the field of view in degrees, 1 to 170")
                || err.contains("invalid float"),
            "{fov}: {err}"
        );
    }
    for model in ["auto", "generic"] {
        let mut args = vec!["face", "track", "--synthetic", "--face-depth", "1.1"];
        args.extend(SMALL);
        args.extend(["--face-model", model, "--backend", "cpu"]);
        let err = failure(&streampf(&args));
        assert!(err.contains("the generic head"), "{model}: {err}");
    }
    std::fs::remove_dir_all(&data).unwrap();
}

#[test]
fn track_with_user_face_maps() {
    // The generic head written as maps, then read back as a user's own model.
    let dir = scratch("maps");
    std::fs::create_dir_all(&dir).unwrap();
    let model = face_tracker::model::FaceModel::generic(65).unwrap();
    let max = model.heights.iter().cloned().fold(0.0f32, f32::max);
    let height = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(65, 65, |x, y| {
        image::Luma([(model.heights[(y * 65 + x) as usize] / max * 65535.0).round() as u16])
    });
    height.save(dir.join("height.png")).unwrap();
    let normal = image::RgbImage::from_fn(65, 65, |x, y| {
        let n = model.normals[(y * 65 + x) as usize];
        image::Rgb(n.map(|c| ((c + 1.0) / 2.0 * 255.0).round() as u8))
    });
    normal.save(dir.join("normal.png")).unwrap();
    let out = dir.join("out");
    let max_text = max.to_string();
    let mut args = vec![
        "face",
        "track",
        "--synthetic",
        "--out",
        out.to_str().unwrap(),
        "--particles",
        "200",
        "--backend",
        "cpu",
        "--heightmap",
        dir.join("height.png").to_str().unwrap(),
        "--normalmap",
        dir.join("normal.png").to_str().unwrap(),
        "--height-scale",
        &max_text,
    ]
    .into_iter()
    .map(String::from)
    .collect::<Vec<_>>();
    args.extend(SMALL.map(String::from));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let text = ok(&streampf(&args));
    assert!(
        number_after(&text, "mean translation error:") < 5.0,
        "{text}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// On a machine whose only adapters are software ones (Mesa's lavapipe, as in CI), the trackers
/// say in the command line's words how to use one anyway; with a hardware GPU the same runs
/// track on it.
#[test]
fn software_only_adapters_are_explained_in_the_command_lines_words() {
    let devices = ok(&streampf(&["devices"]));
    let software_only = devices.contains("only software adapters");
    let out = scratch("software-note");
    let o = out.to_str().unwrap();
    let run = |backend: &str| {
        streampf(&[
            "face",
            "track",
            "--synthetic",
            "--faces",
            "1",
            "--frames",
            "1",
            "--width",
            "160",
            "--height",
            "120",
            "--backend",
            backend,
            "--out",
            o,
        ])
    };
    let gpu = run("gpu");
    let auto = run("auto");
    if software_only {
        let err = failure(&gpu);
        assert!(err.contains("add --allow-software"), "{err}");
        assert!(!err.contains("ContextOptions"), "{err}");
        let note = String::from_utf8_lossy(&auto.stderr);
        assert!(auto.status.success(), "{note}");
        assert!(
            note.contains("tracking on the CPU") && note.contains("--backend gpu --allow-software"),
            "{note}"
        );
    } else {
        ok(&gpu);
        assert!(ok(&auto).contains("tracked 1 face"));
    }
}

/// On a GPU, faces from rectangles run with two frames in flight; `--save-particles` reads the
/// particles every frame, so it steps one frame at a time. Both write the same states, errors
/// and overlay frames, byte for byte.
#[test]
fn frames_in_flight_write_what_one_frame_at_a_time_writes() {
    let run = |name: &str, extra: &[&str]| {
        let out = scratch(name);
        let (o, overlay) = (out.join("out"), out.join("overlay"));
        let mut args = vec![
            "face",
            "track",
            "--synthetic",
            "--particles",
            "100",
            "--backend",
            "gpu",
            "--allow-software",
            "--quiet",
            "--out",
            o.to_str().unwrap(),
            "--overlay",
            overlay.to_str().unwrap(),
        ];
        args.extend(SMALL);
        args.extend(extra);
        (streampf(&args), out)
    };
    let (streamed, streamed_dir) = run("in-flight", &[]);
    if !streamed.status.success() && common::skipped_for_no_gpu(&failure(&streamed)) {
        return;
    }
    assert!(ok(&streamed).contains("(two frames in flight)"));
    let particles = scratch("in-flight-particles");
    let (alone, alone_dir) = run(
        "one-at-a-time",
        &["--save-particles", particles.to_str().unwrap()],
    );
    assert!(!ok(&alone).contains("in flight"));
    let read = |dir: &std::path::Path, file: &str| std::fs::read(dir.join(file)).unwrap();
    for file in ["out/states.csv", "out/errors.csv"] {
        assert_eq!(read(&streamed_dir, file), read(&alone_dir, file), "{file}");
    }
    assert_eq!(
        String::from_utf8(read(&streamed_dir, "out/states.csv"))
            .unwrap()
            .lines()
            .count(),
        1 + 8 * 2
    );
    for frame in 0..8 {
        let file = format!("overlay/overlay_{frame:05}.png");
        assert_eq!(
            read(&streamed_dir, &file),
            read(&alone_dir, &file),
            "{file}"
        );
    }
    for dir in [streamed_dir, alone_dir, particles] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

/// `--gpus N` chooses how many of several GPUs a run uses: refused with --backend cpu or gpu,
/// beyond the GPUs there are, or at 0; on lavapipe (one adapter) `--gpus 1` runs. The body's
/// option is the same code (`streampf::gpu::by_load`).
#[test]
fn gpus_is_checked_against_the_backend_and_the_machine() {
    let out = scratch("gpus-option");
    let o = out.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "face",
            "track",
            "--synthetic",
            "--faces",
            "1",
            "--frames",
            "2",
            "--width",
            "160",
            "--height",
            "120",
            "--particles",
            "50",
            "--out",
            o,
        ];
        args.extend_from_slice(extra);
        streampf(&args)
    };
    for backend in ["cpu", "gpu"] {
        let err = failure(&run(&["--backend", backend, "--gpus", "2"]));
        assert!(err.contains("--gpus chooses how many GPUs"), "{err}");
    }
    let err = failure(&run(&["--backend", "all-gpus", "--gpus", "0"]));
    assert!(err.contains("--gpus"), "{err}");
    let too_many = run(&[
        "--backend",
        "all-gpus",
        "--allow-software",
        "--gpus",
        "1024",
    ]);
    let stderr = String::from_utf8_lossy(&too_many.stderr).to_string();
    if common::skipped_for_no_gpu(&stderr) {
        return;
    }
    let err = failure(&too_many);
    assert!(err.contains("this machine has"), "{err}");
    let one = run(&["--backend", "all-gpus", "--allow-software", "--gpus", "1"]);
    assert!(ok(&one).contains("tracked 1 face"));
    let body = streampf(&[
        "body",
        "track",
        "--synthetic",
        "--frames",
        "2",
        "--backend",
        "cpu",
        "--gpus",
        "2",
        "--out",
        o,
    ]);
    let err = failure(&body);
    assert!(err.contains("--gpus chooses how many GPUs"), "{err}");
}

/// `--camera fx,fy,cx,cy` and `--calibration FILE` (OpenCV's YAML, at twice the frames' size)
/// see the faces through the same pinhole as `--fov`: a video rendered through a 60° lens gives
/// the same states.csv, byte for byte, through all three. Bad cameras are clear errors.
#[test]
fn camera_and_calibration_track_as_the_field_of_view_does() {
    let data = scratch("camera-data");
    let d = data.to_str().unwrap();
    let mut args = vec!["face", "synth", "--out", d, "--fov", "60"];
    args.extend(SMALL);
    ok(&streampf(&args));
    let focal = face_tracker::likelihood::Lens::focal_length_for(60.0, 480).unwrap();
    let track = |name: &str, camera: &[&str]| {
        let out = scratch(name);
        let mut args = vec![
            "face",
            "track",
            d,
            "--particles",
            "100",
            "--backend",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(camera);
        let run = streampf(&args);
        (
            ok(&run),
            String::from_utf8_lossy(&run.stderr).to_string(),
            out,
        )
    };
    let (_, _, by_fov) = track("camera-fov", &["--fov", "60"]);
    let intrinsics = format!("{focal},{focal},239.5,179.5");
    let (_, said, by_camera) = track("camera-matrix", &["--camera", &intrinsics]);
    assert!(said.contains("a 60.0° horizontal field of view"), "{said}");
    // The calibration made at 960x720 (twice the frames), with distortion: scaled, and noted.
    let calibration = data.join("calibration.yml");
    std::fs::write(
        &calibration,
        format!(
            "%YAML:1.0\n---\nimage_width: 960\nimage_height: 720\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {f2}, 0., 479.5, 0., {f2}, 359.5, 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ -0.1, 0.01, 0., 0., 0. ]\n",
            f2 = 2.0 * focal
        ),
    )
    .unwrap();
    let (_, said, by_file) = track(
        "camera-file",
        &["--calibration", calibration.to_str().unwrap()],
    );
    assert!(
        said.contains("lens distortion") && said.contains("60.0°"),
        "{said}"
    );
    let states = |dir: &std::path::Path| std::fs::read_to_string(dir.join("states.csv")).unwrap();
    assert_eq!(states(&by_fov), states(&by_camera));
    assert_eq!(states(&by_fov), states(&by_file));
    // An off-centre principal point is a different camera: other states.
    let (_, _, shifted) = track(
        "camera-shifted",
        &["--camera", &format!("{focal},{focal},300,179.5")],
    );
    assert_ne!(states(&by_fov), states(&shifted));
    // A calibration of another shape than the frames (640x360 against 480x360).
    let other_shape = data.join("other-shape.yml");
    std::fs::write(
        &other_shape,
        "image_width: 640\nimage_height: 360\nK: [500, 0, 320, 0, 500, 240, 0, 0, 1]\n",
    )
    .unwrap();
    for (bad, says) in [
        (vec!["--camera", "500,500,320"], "four numbers"),
        (vec!["--camera", "500,900,320,240"], "square pixels"),
        (
            vec!["--camera", "500,500,320,240", "--fov", "60"],
            "cannot be used with",
        ),
        (
            vec!["--calibration", "/no/such/calibration.yml"],
            "calibration.yml",
        ),
        (
            vec!["--calibration", other_shape.to_str().unwrap()],
            "another shape",
        ),
    ] {
        let out = scratch("camera-bad");
        let mut args = vec![
            "face",
            "track",
            d,
            "--backend",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(&bad);
        let err = failure(&streampf(&args));
        assert!(err.contains(says), "{bad:?}: {err}");
    }
}
