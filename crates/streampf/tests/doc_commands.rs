//! Every shell command the documentation shows a user (README.md, CONTRIBUTING.md, docs/*.md)
//! still works as written: a `streampf` command line parses with the binary's own parser (every
//! subcommand, option and value), a `cargo xtask` command names a command and options the xtask
//! accepts, a bench, example, package or script it names exists. A block that only illustrates
//! (commands for another machine, a placeholder path) is marked by a line `<!-- illustrative -->`
//! just before it; any other command this test cannot check fails it, so a new command is either
//! checked or marked.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The documents a user reads.
fn documents() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md"), root().join("CONTRIBUTING.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root().join("docs"))
        .expect("docs/")
        .map(|e| e.expect("a docs entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

/// The shell commands of a document's `sh`/`bash`/`console` blocks, with their line numbers,
/// leaving out blocks marked illustrative.
fn commands(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut in_block = false;
    let mut checked = false;
    let mut previous = "";
    for (n, line) in text.lines().enumerate() {
        let trimmed = line.trim();
        if let Some(info) = trimmed.strip_prefix("```") {
            if in_block {
                in_block = false;
            } else {
                in_block = true;
                checked = matches!(info.trim(), "sh" | "bash" | "console" | "shell")
                    && previous != "<!-- illustrative -->";
            }
        } else if in_block && checked {
            let command = strip_comment(trimmed);
            for part in command.split("&&") {
                if !part.trim().is_empty() {
                    out.push((n + 1, part.trim().to_string()));
                }
            }
        }
        if !trimmed.is_empty() {
            previous = trimmed;
        }
    }
    out
}

/// A command without its trailing `# comment` (a `#` after whitespace, outside quotes).
fn strip_comment(line: &str) -> &str {
    let mut quote = None;
    let mut last = ' ';
    for (i, c) in line.char_indices() {
        match (quote, c) {
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), c) if c == q => quote = None,
            (None, '#') if last.is_whitespace() || i == 0 => return line[..i].trim_end(),
            _ => {}
        }
        last = c;
    }
    line
}

/// Splits a command into words as a shell would for these commands (quotes, no expansions).
fn words(command: &str) -> Vec<String> {
    let (mut out, mut word, mut quote, mut any) = (Vec::new(), String::new(), None, false);
    for c in command.chars() {
        match (quote, c) {
            (None, '"' | '\'') => (quote, any) = (Some(c), true),
            (Some(q), c) if c == q => quote = None,
            (None, c) if c.is_whitespace() => {
                if any {
                    out.push(std::mem::take(&mut word));
                    any = false;
                }
            }
            (_, c) => {
                word.push(c);
                any = true;
            }
        }
    }
    if any {
        out.push(word);
    }
    out
}

/// The xtask's usage text: its commands and their options.
fn xtask_usage() -> String {
    let main = std::fs::read_to_string(root().join("xtask/src/main.rs")).expect("xtask source");
    let start = main.find("const USAGE").expect("xtask USAGE");
    main[start..]
        .split("\";")
        .next()
        .unwrap_or_default()
        .to_string()
}

/// Whether `program` is a Python interpreter (on the path, or a virtual environment's).
fn is_python(program: &str) -> bool {
    let name = program.rsplit('/').next().unwrap_or(program);
    matches!(name, "python" | "python3")
}

/// Why `command` does not work as documented, or `None` when it does.
fn problem(command: &str, xtask: &str) -> Option<String> {
    let w = words(command);
    let w: Vec<&str> = w.iter().map(String::as_str).collect();
    let exists = |path: String| -> Option<String> {
        (!root().join(&path).exists()).then(|| format!("{path} does not exist"))
    };
    match w.as_slice() {
        ["cargo", "run", rest @ ..] if rest.contains(&"-p") && rest.contains(&"streampf") => {
            let args = rest.iter().skip_while(|a| **a != "--").skip(1);
            streampf::check_command_line(args)
                .err()
                .map(|e| e.to_string())
        }
        ["streampf", args @ ..] => streampf::check_command_line(args)
            .err()
            .map(|e| e.to_string()),
        ["cargo", "run", rest @ ..] if rest.contains(&"--example") => {
            let at = rest.iter().position(|a| *a == "--example");
            match at.and_then(|at| rest.get(at + 1)) {
                Some(name) => exists(format!("examples/{name}.rs")),
                None => Some("--example without a name".into()),
            }
        }
        ["cargo", "xtask", sub, options @ ..] => {
            let named = |end: &str| xtask.contains(&format!("\n  {sub}{end}"));
            if !(named(" ") || named("\n")) {
                return Some(format!("cargo xtask has no command {sub}"));
            }
            let unknown = (options.iter())
                .take_while(|o| **o != "--")
                .filter(|o| o.starts_with("--"))
                .find(|o| !xtask.contains(&format!("[{o}")) && !xtask.contains(&format!(" {o}")));
            unknown.map(|o| format!("cargo xtask {sub} takes no {o}"))
        }
        ["cargo", "bench", "--bench", name, ..] => exists(format!("benches/{name}.rs")),
        [
            "cargo",
            "bench" | "build" | "test" | "fmt" | "clippy" | "doc",
            ..,
        ] => None,
        ["pip" | "pip3", "install", path] if path.starts_with("./") => exists(path.to_string()),
        ["python" | "python3", "-c", ..] => None,
        [python, script, ..] if is_python(python) && script.ends_with(".py") => {
            exists(script.to_string())
        }
        _ => Some("not a command this test can check: mark its block <!-- illustrative -->".into()),
    }
}

#[test]
fn every_documented_command_works_as_written() {
    let xtask = xtask_usage();
    let mut failures = Vec::new();
    let mut checked = 0;
    for file in documents() {
        let text = std::fs::read_to_string(&file).expect("a document");
        for (line, command) in commands(&text) {
            checked += 1;
            if let Some(why) = problem(&command, &xtask) {
                let name = file
                    .strip_prefix(root())
                    .unwrap_or(&file)
                    .display()
                    .to_string();
                failures.push(format!("{name}:{line}: `{command}`: {why}"));
            }
        }
    }
    assert!(
        checked >= 20,
        "only {checked} commands found: is the parser of the docs broken?"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn the_checks_catch_what_they_are_for() {
    let xtask = xtask_usage();
    // A renamed option, a missing subcommand, a bench or example that is gone.
    for bad in [
        "cargo run --release -p streampf -- face track --synthetic --no-such-option",
        "streampf face follow --synthetic",
        "cargo xtask reproduce-figures --fast",
        "cargo xtask publish",
        "cargo xtask fetch",
        "cargo bench --bench no_such_bench",
        "cargo run --release --example no_such_example",
        "apt-get install something",
        "target/media/pose-venv/bin/python3 tools/no_such_tool.py",
    ] {
        assert!(problem(bad, &xtask).is_some(), "{bad} passed");
    }
    for good in [
        "cargo run --release -p streampf -- face track --synthetic --layers 3",
        "cargo run --release -p streampf -- face track --help",
        "cargo xtask test --no-gpu",
        "cargo run --release --example range_only -- --allow-software",
        "target/media/pose-venv/bin/python3 tools/head_pose_check.py V S --widest 300",
    ] {
        assert_eq!(problem(good, &xtask), None, "{good}");
    }
    let text = "x\n<!-- illustrative -->\n```sh\nanything at all\n```\n```sh\na b # c\n```\n";
    assert_eq!(commands(text), vec![(7, "a b".to_string())]);
    assert_eq!(
        words("say 'two words' \"and\" three"),
        ["say", "two words", "and", "three"]
    );
}
