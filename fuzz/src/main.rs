//! `parsers NAME`: one parser-fuzz target under AFL++ (persistent mode); a panic is a crash.
//! `parsers --write-seeds DIR`: every target's seeds into DIR/NAME/ for afl-fuzz's `-i`.

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scratch = parser_fuzz::scratch_dir("afl");
    if let Err(e) = std::fs::create_dir_all(&scratch) {
        eprintln!("creating {}: {e}", scratch.display());
        std::process::exit(2);
    }
    let targets = parser_fuzz::targets(&scratch).unwrap_or_else(|e| {
        eprintln!("building the targets: {e}");
        std::process::exit(2);
    });
    match args.get(1).map(String::as_str) {
        Some("--write-seeds") => {
            let Some(dir) = args.get(2) else {
                eprintln!("usage: parsers --write-seeds DIR");
                std::process::exit(2);
            };
            for t in &targets {
                let target_dir = std::path::Path::new(dir).join(t.name);
                std::fs::create_dir_all(&target_dir).expect("creating the seed directory");
                for (k, seed) in t.seeds.iter().enumerate() {
                    std::fs::write(target_dir.join(format!("seed-{k}")), seed)
                        .expect("writing a seed");
                }
                println!("{}", t.name);
            }
        }
        Some(name) => {
            let Some(target) = targets.iter().find(|t| t.name == name) else {
                let names: Vec<&str> = targets.iter().map(|t| t.name).collect();
                eprintln!("no target {name:?}; the targets are {names:?}");
                std::process::exit(2);
            };
            // The parsers hold no state a caught panic could leave broken (a scratch path).
            let parse = std::panic::AssertUnwindSafe(&target.parse);
            afl::fuzz!(|data: &[u8]| {
                // A refusal must say why; a panic is AFL's crash.
                if let Err(message) = (*parse)(data) {
                    assert!(!message.trim().is_empty(), "refused without a message");
                }
            });
        }
        None => {
            eprintln!("usage: parsers NAME | parsers --write-seeds DIR");
            std::process::exit(2);
        }
    }
}
