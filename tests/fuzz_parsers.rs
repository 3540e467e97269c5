//! Fuzzing of every parser a user can feed: Haar cascade XML, dlib's landmark model, .pts, PLY
//! (ASCII and binary), 16-bit depth PNG, camera and skeleton JSON, the numeric CSVs (ground
//! truth, poses), .npy / .npz, and image frames.
//!
//! A mutation fuzzer, not a coverage-guided one: each parser starts from valid files the project
//! writes itself and runs, until its time is up, on mutants of them (bit flips, interesting bytes,
//! cut, repeated and inserted runs, numbers replaced by extremes, truncation) and on random bytes.
//! A parser passes when no input panics it and every rejection is an error with a message.
//! Inputs that panic are kept in `target/fuzz-crashes/` to be replayed.
//!
//! `STREAMPF_FUZZ_SECONDS` (default 1) is the time per parser; `STREAMPF_FUZZ_SEED` fixes the
//! random seed (else it comes from the clock and is printed). docs/FUZZING.md has a longer run.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use body_tracker::camera::{DepthImage, Intrinsics, read_depth_png, write_depth_png};
use body_tracker::human::human_skeleton;
use body_tracker::ply::{parse_ply, ply_ascii, write_ply_binary};
use body_tracker::sequence::{read_numeric_csv, read_pose_csv};
use body_tracker::skeleton::Skeleton;
use face_tracker::GrayImage;
use face_tracker::detect::Cascade;
use face_tracker::landmarks::ShapePredictor;
use face_tracker::landmarks::pts::parse_pts;
use nalgebra::Vector3;

/// xorshift64*: the fuzzer's own small generator (fast, seedable, no dependency).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const INTERESTING: [&[u8]; 14] = [
    b"0",
    b"-1",
    b"1e30",
    b"-1e38",
    b"nan",
    b"inf",
    b"4294967296",
    b"18446744073709551616",
    b"\x00",
    b"\xff",
    b"\n",
    b",",
    b"\"",
    b"<",
];

/// One to four random mutations of `input`.
fn mutate(rng: &mut Rng, input: &[u8]) -> Vec<u8> {
    let mut out = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = out.len();
        match rng.below(8) {
            0 if len > 0 => {
                let i = rng.below(len);
                out[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                out[i] = rng.next() as u8;
            }
            2 if len > 0 => {
                let start = rng.below(len);
                let end = (start + 1 + rng.below(64)).min(len);
                out.drain(start..end);
            }
            3 if len > 0 => {
                let start = rng.below(len);
                let end = (start + 1 + rng.below(256)).min(len);
                let run = out[start..end].to_vec();
                let at = rng.below(len);
                out.splice(at..at, run);
            }
            4 => {
                let at = rng.below(len + 1);
                let bytes = INTERESTING[rng.below(INTERESTING.len())];
                out.splice(at..at, bytes.iter().copied());
            }
            5 => {
                // A decimal number replaced by an extreme one.
                let digits: Vec<usize> = (0..len).filter(|&i| out[i].is_ascii_digit()).collect();
                if let Some(&at) = digits.get(rng.below(digits.len())) {
                    let end = (at..len).find(|&i| !out[i].is_ascii_digit()).unwrap_or(len);
                    let bytes = INTERESTING[rng.below(8)];
                    out.splice(at..end, bytes.iter().copied());
                }
            }
            6 if len > 0 => out.truncate(rng.below(len)),
            _ => {
                let at = rng.below(len + 1);
                let noise: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.next() as u8).collect();
                out.splice(at..at, noise);
            }
        }
    }
    out
}

/// What one parser's run did.
struct Report {
    executions: u64,
    accepted: u64,
    /// Inputs that panicked the parser or were refused without a message.
    crashes: Vec<PathBuf>,
}

/// Runs `parse` on mutants of `seeds` (and on random bytes) for `budget`; a panic is a crash,
/// an `Err` must carry a message.
fn fuzz(
    name: &str,
    seeds: &[Vec<u8>],
    budget: Duration,
    rng: &mut Rng,
    parse: impl Fn(&[u8]) -> Result<(), String>,
) -> Report {
    let crash_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/fuzz-crashes");
    let mut report = Report {
        executions: 0,
        accepted: 0,
        crashes: Vec::new(),
    };
    let started = Instant::now();
    while started.elapsed() < budget {
        let input = if rng.below(16) == 0 {
            (0..rng.below(512)).map(|_| rng.next() as u8).collect()
        } else {
            let pick = rng.below(seeds.len());
            mutate(rng, &seeds[pick])
        };
        report.executions += 1;
        match catch_unwind(AssertUnwindSafe(|| parse(&input))) {
            Ok(Ok(())) => report.accepted += 1,
            Ok(Err(message)) if !message.trim().is_empty() => {}
            // A panic, or a rejection that says nothing: both are findings.
            Ok(Err(_)) | Err(_) => {
                std::fs::create_dir_all(&crash_dir).unwrap();
                let path = crash_dir.join(format!("{name}-{}.bin", report.crashes.len()));
                std::fs::write(&path, &input).unwrap();
                report.crashes.push(path);
            }
        }
    }
    report
}

/// This run's scratch directory.
fn scratch_dir() -> PathBuf {
    std::env::temp_dir().join(format!("streampf-fuzz-{}", std::process::id()))
}

/// A scratch file per parser for the parsers that read paths.
fn scratch_file(name: &str) -> PathBuf {
    let dir = scratch_dir();
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn through_file<E: std::fmt::Display>(
    name: &'static str,
    read: impl Fn(&Path) -> Result<(), E>,
) -> impl Fn(&[u8]) -> Result<(), String> {
    let path = scratch_file(name);
    move |bytes| {
        std::fs::write(&path, bytes).unwrap();
        read(&path).map_err(|e| e.to_string())
    }
}

/// dlib's integer and float encodings, for a small valid model.
fn pack(value: i64) -> Vec<u8> {
    let mut magnitude = value.unsigned_abs();
    let mut body = Vec::new();
    loop {
        body.push((magnitude & 0xff) as u8);
        magnitude >>= 8;
        if magnitude == 0 {
            break;
        }
    }
    let mut out = vec![body.len() as u8 | if value < 0 { 0x80 } else { 0 }];
    out.extend(body);
    out
}

fn pack_float(value: f32) -> Vec<u8> {
    let mut out = pack((f64::from(value) * 1_048_576.0).round() as i64);
    out.extend(pack(-20));
    out
}

/// A two-landmark dlib shape predictor: one level, one tree of one split, two leaves.
fn small_dlib_model() -> Vec<u8> {
    let column = |values: &[f32]| {
        let mut out = pack(-(values.len() as i64));
        out.extend(pack(-1));
        values.iter().for_each(|&v| out.extend(pack_float(v)));
        out
    };
    let mut b = pack(1);
    b.extend(column(&[0.25, 0.5, 0.75, 0.5]));
    for v in [1, 1, 1, 0, 1] {
        b.extend(pack(v));
    }
    b.extend(pack_float(10.0));
    b.extend(pack(2));
    b.extend(column(&[0.125, 0.0, 0.125, 0.0]));
    b.extend(column(&[-0.125, 0.0, -0.125, 0.0]));
    for v in [1, 2, 0, 1, 1, 2] {
        b.extend(pack(v));
    }
    (0..4).for_each(|_| b.extend(pack_float(0.0)));
    b
}

fn body_points() -> Vec<Vector3<f32>> {
    (0..40)
        .map(|i| {
            Vector3::new(
                i as f32 * 0.01 - 0.2,
                1.0 - i as f32 * 0.02,
                3.0 + (i % 5) as f32 * 0.01,
            )
        })
        .collect()
}

fn pts_text(points: usize) -> String {
    let mut text = format!("version: 1\nn_points: {points}\n{{\n");
    for k in 0..points {
        text.push_str(&format!("{}.5 {}.25\n", 100 + k, 200 - k));
    }
    text.push_str("}\n");
    text
}

fn cascade_seed() -> Option<Vec<u8>> {
    // The tracker's default cascade (opencv-data); mutants of it reach every part of the
    // parser.
    let path = "/usr/share/opencv4/haarcascades/haarcascade_frontalface_alt2.xml";
    match std::fs::read(path) {
        Ok(bytes) => Some(bytes),
        Err(_) if std::env::var("STREAMPF_NO_MEDIA").is_ok_and(|v| v == "1") => None,
        Err(e) => panic!(
            "{path}: {e}; `cargo xtask fetch-media` installs opencv-data (or set STREAMPF_NO_MEDIA=1)"
        ),
    }
}

/// The bytes of a file `write` makes (seeds in formats written through a path).
fn seed_file(name: &str, write: impl Fn(&Path)) -> Vec<u8> {
    let path = scratch_file(&format!("seed-{name}"));
    write(&path);
    std::fs::read(&path).unwrap()
}

#[test]
fn every_user_facing_parser_survives_mutated_and_random_input() {
    let seconds: f64 = std::env::var("STREAMPF_FUZZ_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1.0);
    let budget = Duration::from_secs_f64(seconds);
    let seed = std::env::var("STREAMPF_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .as_nanos() as u64
                | 1
        });
    eprintln!("fuzzing with STREAMPF_FUZZ_SEED={seed}, {seconds} s per parser");
    let mut rng = Rng(seed);

    let skeleton = human_skeleton(19).unwrap();
    let dofs = skeleton.dofs();
    let camera = Intrinsics::with_fov(32, 24, 60.0).unwrap();
    let pose_rows = |rows: usize| {
        let mut text = format!("frame,{}\n", skeleton.pose_names().join(","));
        for r in 0..rows {
            let values: Vec<String> = (0..dofs)
                .map(|d| format!("{}", (r * dofs + d) as f32 * 0.01))
                .collect();
            text.push_str(&format!("{r},{}\n", values.join(",")));
        }
        text.into_bytes()
    };
    let depth = DepthImage {
        width: 32,
        height: 24,
        depth: (0..32 * 24).map(|i| 1000 + (i % 97) as u16).collect(),
    };
    let frame =
        GrayImage::new(24, 16, (0..24 * 16).map(|i| (i * 7 % 251) as u8).collect()).unwrap();
    let npy = vec![seed_file("a.npy", |p| {
        pf_numpy::write_f32(
            p,
            &[3, 4, 2],
            &(0..24).map(|i| i as f32 * 0.5).collect::<Vec<_>>(),
        )
        .unwrap()
    })];
    let npz = vec![seed_file("a.npz", |p| {
        pf_numpy::npz::write_npz(
            p,
            &[
                ("x", &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
                ("y", &[1], &[7.0]),
            ],
        )
        .unwrap()
    })];

    type Parser = Box<dyn Fn(&[u8]) -> Result<(), String>>;
    let mut parsers: Vec<(&str, Vec<Vec<u8>>, Parser)> = vec![
        (
            "dlib-model",
            vec![small_dlib_model()],
            Box::new(|b| {
                ShapePredictor::from_bytes(b)
                    .map(drop)
                    .map_err(|e| e.to_string())
            }),
        ),
        (
            "pts",
            vec![pts_text(68).into_bytes(), pts_text(3).into_bytes()],
            Box::new(|b| parse_pts(&String::from_utf8_lossy(b)).map(drop)),
        ),
        (
            "ply",
            {
                let mut seeds = vec![ply_ascii(&body_points()).into_bytes()];
                seeds.extend(vec![seed_file("b.ply", |p| {
                    write_ply_binary(p, &body_points()).unwrap()
                })]);
                seeds
            },
            Box::new(|b| parse_ply(b).map(drop).map_err(|e| e.to_string())),
        ),
        (
            "depth-png",
            vec![seed_file("d.png", |p| write_depth_png(p, &depth).unwrap())],
            Box::new(through_file("depth.png", |p| read_depth_png(p).map(drop))),
        ),
        (
            "camera-json",
            vec![seed_file("camera.json", |p| camera.save(p).unwrap())],
            Box::new(through_file("camera.json", |p| {
                Intrinsics::load(p).map(drop)
            })),
        ),
        (
            "skeleton-json",
            vec![seed_file("skeleton.json", |p| skeleton.save(p).unwrap())],
            Box::new(through_file("skeleton.json", |p| {
                Skeleton::load(p).map(drop)
            })),
        ),
        (
            "pose-csv",
            vec![pose_rows(3)],
            Box::new(through_file("poses.csv", move |p| {
                read_pose_csv(p, dofs).map(drop)
            })),
        ),
        (
            "numeric-csv",
            vec![b"frame,face,a,b\n0,0,1.5,2\n1,0,-3,4e-3\n".to_vec()],
            Box::new(through_file("numbers.csv", |p| {
                read_numeric_csv(p, 4).map(drop)
            })),
        ),
        (
            "npy",
            npy,
            Box::new(through_file("x.npy", |p| pf_numpy::read_f32(p).map(drop))),
        ),
        (
            "npz",
            npz,
            Box::new(through_file("x.npz", |p| {
                pf_numpy::npz::NpzReader::open(p)
                    .and_then(|mut z| z.read_f32("x"))
                    .map(drop)
            })),
        ),
        (
            "image-frame",
            vec![seed_file("f.png", |p| frame.save_png(p).unwrap())],
            Box::new(through_file("frame.png", |p| GrayImage::load(p).map(drop))),
        ),
    ];
    if let Some(cascade) = cascade_seed() {
        parsers.push((
            "haar-cascade",
            vec![cascade],
            Box::new(|b| Cascade::parse(&String::from_utf8_lossy(b)).map(drop)),
        ));
    }
    // STREAMPF_FUZZ_ONLY=name,name: only those parsers (replaying a finding).
    if let Ok(only) = std::env::var("STREAMPF_FUZZ_ONLY") {
        parsers.retain(|(name, ..)| only.split(',').any(|o| o == *name));
    }
    for (name, seeds, parse) in &parsers {
        assert!(!seeds.is_empty(), "{name}: no seed");
        for (k, seed) in seeds.iter().enumerate() {
            assert_eq!(parse(seed), Ok(()), "{name}: seed {k} must parse");
        }
    }
    // STREAMPF_FUZZ_REPLAY=file (with STREAMPF_FUZZ_ONLY=name): run one saved input, panicking
    // as the parser does.
    if let Ok(replay) = std::env::var("STREAMPF_FUZZ_REPLAY") {
        let input = std::fs::read(&replay).unwrap();
        for (name, _, parse) in &parsers {
            eprintln!("{name}: {:?}", parse(&input));
        }
        return;
    }
    // Panics are caught and reported below; keep their messages off the log.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let reports: Vec<(&str, Report)> = parsers
        .iter()
        .map(|(name, seeds, parse)| (*name, fuzz(name, seeds, budget, &mut rng, parse)))
        .collect();
    std::panic::set_hook(hook);
    let mut crashed = Vec::new();
    for (name, report) in &reports {
        eprintln!(
            "{name:>14}: {:>9} executions, {:>7} accepted, {} crashes",
            report.executions,
            report.accepted,
            report.crashes.len()
        );
        assert!(report.executions > 0, "{name} never ran");
        crashed.extend(report.crashes.iter().cloned());
    }
    let _ = std::fs::remove_dir_all(scratch_dir());
    assert!(
        crashed.is_empty(),
        "inputs that panic a parser (replay them): {crashed:?}"
    );
}

/// The fuzzer's first findings, kept as regressions: rectangle coordinates beyond u32 (a width
/// of 2^64, a position of 1e300) overflowed the window check instead of failing it.
#[test]
fn cascade_rectangles_beyond_u32_are_errors() {
    let Some(seed) = cascade_seed() else {
        return;
    };
    let text = String::from_utf8(seed).unwrap();
    let first = text.find("<rects>").unwrap();
    let item = first + text[first..].find("<_>").unwrap() + 3;
    let start = item + text[item..].find(|c: char| !c.is_whitespace()).unwrap();
    for huge in ["18446744073709551616", "1e300"] {
        // "x y w h weight": the first field replaced.
        let end = start + text[start..].find(char::is_whitespace).unwrap();
        let mutated = format!("{}{huge}{}", &text[..start], &text[end..]);
        let Err(err) = Cascade::parse(&mutated) else {
            panic!("a rectangle at {huge} was accepted");
        };
        assert!(err.contains("outside the 20x20 window"), "{err}");
    }
}
