//! Fuzzing of every parser a user can feed: Haar cascade XML, dlib's landmark model, .pts, PLY
//! (ASCII and binary), 16-bit depth PNG, camera and skeleton JSON, the numeric CSVs (ground
//! truth, poses), .npy / .npz, and image frames.
//!
//! The targets and their seeds are the `parser-fuzz` crate's, shared with the coverage-guided
//! AFL++ harness in `fuzz/` (`cargo xtask fuzz`). This is the mutation fuzzer that needs nothing
//! installed: each parser starts from valid files the project writes itself and runs, until its time is up, on mutants of them (bit flips, interesting bytes,
//! cut, repeated and inserted runs, numbers replaced by extremes, truncation) and on random bytes.
//! A parser passes when no input panics it and every rejection is an error with a message.
//! Inputs that panic are kept in `target/fuzz-crashes/` to be replayed.
//!
//! `STREAMPF_FUZZ_SECONDS` (default 1) is the time per parser; `STREAMPF_FUZZ_SEED` fixes the
//! random seed (else it comes from the clock and is printed). docs/FUZZING.md has a longer run.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use face_tracker::detect::Cascade;
use parser_fuzz::{SMALL_CASCADE, Target, targets};

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
    let scratch = parser_fuzz::scratch_dir("fuzz");
    std::fs::create_dir_all(&scratch).unwrap();
    let mut parsers = targets(&scratch).unwrap();
    // STREAMPF_FUZZ_ONLY=name,name: only those parsers (replaying a finding).
    if let Ok(only) = std::env::var("STREAMPF_FUZZ_ONLY") {
        parsers.retain(|t| only.split(',').any(|o| o == t.name));
    }
    for Target { name, seeds, parse } in &parsers {
        assert!(!seeds.is_empty(), "{name}: no seed");
        for (k, seed) in seeds.iter().enumerate() {
            assert_eq!(parse(seed), Ok(()), "{name}: seed {k} must parse");
        }
    }
    // STREAMPF_FUZZ_REPLAY=file (with STREAMPF_FUZZ_ONLY=name): run one saved input, panicking
    // as the parser does.
    if let Ok(replay) = std::env::var("STREAMPF_FUZZ_REPLAY") {
        let input = std::fs::read(&replay).unwrap();
        for t in &parsers {
            eprintln!("{}: {:?}", t.name, (t.parse)(&input));
        }
        return;
    }
    // Panics are caught and reported below; keep their messages off the log.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let reports: Vec<(&str, Report)> = parsers
        .iter()
        .map(|t| (t.name, fuzz(t.name, &t.seeds, budget, &mut rng, &t.parse)))
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
    let _ = std::fs::remove_dir_all(&scratch);
    assert!(
        crashed.is_empty(),
        "inputs that panic a parser (replay them): {crashed:?}"
    );
}

/// The fuzzer's first findings, kept as regressions: rectangle coordinates beyond u32 (a width
/// of 2^64, a position of 1e300) overflowed the window check instead of failing it.
/// On the small cascade seed, so that the check runs wherever the tests do.
#[test]
fn cascade_rectangles_beyond_u32_are_errors() {
    let text = SMALL_CASCADE;
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
