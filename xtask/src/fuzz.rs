//! `cargo xtask fuzz [--seconds N] [--only NAME,...]`: the coverage-guided fuzzing of every parser
//! a user can feed, with AFL++ through cargo-afl. Installs cargo-afl when it is missing, builds the
//! instrumented harness in `fuzz/`, writes each target's seeds, runs afl-fuzz on each target for
//! N seconds (default 10), prints the executions, the corpus it grew and the crashes, and fails
//! when any target crashed (the inputs are in `fuzz/target/afl/NAME/default/crashes/`).

use std::path::Path;
use std::process::Command;

use anyhow::{Context, bail};

use crate::run;

pub fn fuzz(args: &[String]) -> anyhow::Result<()> {
    let (seconds, only) = fuzz_options(args)?;
    ensure_cargo_afl()?;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz");
    run(
        // Its own target directory (fuzz/target), whatever CARGO_TARGET_DIR says: the harness is
        // looked for there, and its instrumented build must not evict the workspace's.
        Command::new("cargo")
            .args(["afl", "build", "--release"])
            .current_dir(&dir)
            .env_remove("CARGO_TARGET_DIR"),
        "building the AFL++ harness (cargo afl build, in fuzz/)",
    )?;
    let harness = dir.join("target/release/parsers");
    let seeds = dir.join("target/afl-seeds");
    let names = write_seeds(&harness, &seeds, only.as_deref())?;
    println!(
        "{:>14} {:>11} {:>7} {:>8}",
        "target", "executions", "corpus", "crashes"
    );
    let crashed = fuzz_all(&harness, &seeds, &dir, &names, seconds)?;
    if !crashed.is_empty() {
        bail!("inputs that crash a parser are in: {}", crashed.join(", "));
    }
    Ok(())
}

/// Fuzzes every target of `names` for `seconds`, one afl-fuzz per core at a time (each target
/// keeps its N seconds; 13 targets at 10 s took about 75 s on a 2-core machine instead of 140),
/// printing each target's line of the table in order; returns the crash folders of those that
/// crashed.
fn fuzz_all(
    harness: &Path,
    seeds: &Path,
    dir: &Path,
    names: &[String],
    seconds: u64,
) -> anyhow::Result<Vec<String>> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut crashed = Vec::new();
    for batch in names.chunks(cores) {
        let results: Vec<anyhow::Result<(String, u64)>> = std::thread::scope(|scope| {
            let running: Vec<_> = batch
                .iter()
                .map(|name| {
                    let out = dir.join("target/afl").join(name);
                    scope.spawn(move || fuzz_one(harness, seeds, &out, name, seconds))
                })
                .collect();
            running
                .into_iter()
                .map(|t| {
                    t.join()
                        .unwrap_or_else(|_| Err(anyhow::anyhow!("a fuzzing thread panicked")))
                })
                .collect()
        });
        for (name, result) in batch.iter().zip(results) {
            let (line, crashes) = result?;
            println!("{line}");
            if crashes > 0 {
                let out = dir.join("target/afl").join(name);
                crashed.push(out.join("default/crashes").display().to_string());
            }
        }
    }
    Ok(crashed)
}

/// `--seconds N` (default 10) and `--only NAME,...`.
fn fuzz_options(args: &[String]) -> anyhow::Result<(u64, Option<Vec<String>>)> {
    let mut seconds = 10u64;
    let mut only: Option<Vec<String>> = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        match a.as_str() {
            "--seconds" => {
                seconds = it
                    .next()
                    .and_then(|v| v.parse().ok())
                    .filter(|&s| s > 0)
                    .context("--seconds takes a whole number of seconds above 0")?;
            }
            "--only" => {
                let names = it.next().context("--only takes NAME,NAME,...")?;
                only = Some(names.split(',').map(str::to_string).collect());
            }
            other => bail!("unknown option {other:?} for `fuzz` (--seconds N, --only NAME,...)"),
        }
    }
    Ok((seconds, only))
}

/// Has the harness write every target's seeds into `seeds`; the targets to fuzz (those `only`
/// names, or all).
fn write_seeds(
    harness: &Path,
    seeds: &Path,
    only: Option<&[String]>,
) -> anyhow::Result<Vec<String>> {
    let _ = std::fs::remove_dir_all(seeds);
    let listed = Command::new(harness)
        .arg("--write-seeds")
        .arg(seeds)
        .output()
        .context("writing the seeds")?;
    if !listed.status.success() {
        bail!(
            "writing the seeds: {}",
            String::from_utf8_lossy(&listed.stderr)
        );
    }
    let names: Vec<String> = String::from_utf8_lossy(&listed.stdout)
        .lines()
        .map(str::to_string)
        .filter(|n| only.is_none_or(|o| o.contains(n)))
        .collect();
    if names.is_empty() {
        bail!(
            "no target matches --only (the targets: {})",
            String::from_utf8_lossy(&listed.stdout).replace('\n', " ")
        );
    }
    Ok(names)
}

/// Fuzzes target `name` for `seconds` into `out`; returns its line of the table and the crashes
/// it saved.
fn fuzz_one(
    harness: &Path,
    seeds: &Path,
    out: &Path,
    name: &str,
    seconds: u64,
) -> anyhow::Result<(String, u64)> {
    let _ = std::fs::remove_dir_all(out);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let log = std::fs::File::create(out.with_extension("log"))?;
    run(
        Command::new("cargo")
            .args(["afl", "fuzz", "-V", &seconds.to_string(), "-i"])
            .arg(seeds.join(name))
            .arg("-o")
            .arg(out)
            .arg("--")
            .arg(harness)
            .arg(name)
            // No terminal UI; no tuning of the machine (CI has no say over CPU governors or
            // where cores are dumped).
            .env("AFL_NO_UI", "1")
            .env("AFL_SKIP_CPUFREQ", "1")
            .env("AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES", "1")
            // Several run at once (above); binding each to a core fails when a core looks busy.
            .env("AFL_NO_AFFINITY", "1")
            .stdout(log.try_clone()?)
            .stderr(log),
        &format!(
            "afl-fuzz on {name} (log: {})",
            out.with_extension("log").display()
        ),
    )?;
    let stats = std::fs::read_to_string(out.join("default/fuzzer_stats"))
        .with_context(|| format!("{name}: afl-fuzz wrote no statistics"))?;
    let stat = |key: &str| -> u64 {
        stats
            .lines()
            .find_map(|l| l.split_once(':').filter(|(k, _)| k.trim() == key))
            .and_then(|(_, v)| v.trim().parse().ok())
            .unwrap_or(0)
    };
    let crashes = stat("saved_crashes");
    let line = format!(
        "{name:>14} {:>11} {:>7} {crashes:>8}",
        stat("execs_done"),
        stat("corpus_count")
    );
    Ok((line, crashes))
}

/// cargo-afl (which builds AFL++ when it is installed) unless it is there.
fn ensure_cargo_afl() -> anyhow::Result<()> {
    let present = Command::new("cargo")
        .args(["afl", "--version"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !present {
        eprintln!("xtask: installing cargo-afl (it builds AFL++)");
        run(
            Command::new("cargo").args(["install", "cargo-afl"]),
            "cargo install cargo-afl",
        )?;
    }
    Ok(())
}
