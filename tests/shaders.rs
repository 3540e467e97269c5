//! Every WGSL file of the workspace, checked without a GPU: each parses and validates with naga
//! (with the libraries it is compiled with), none in `shaders/` is left out, ARCHITECTURE.md's
//! kernel table names every entry point and the launcher of each tracker kernel where the file's
//! name says it is, and every Rust item a shader's comments name exists.
//!
//! `shaders/` is organised by owner: `engine/` (pf-gpu's stages), `face/` and `body/` (the
//! trackers'). A tracker kernel `shaders/<owner>/<name>.wgsl` is launched by
//! `<owner>_tracker::<name>::gpu` (the file `crates/<owner>-tracker/src/<name>/gpu.rs`), beside
//! its CPU twin in `<name>/mod.rs`, which holds the source as `<name>::SHADER`.

use std::path::{Path, PathBuf};

use pf_gpu::kernels::{sources, stage_source, validate_wgsl};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The libraries prepended to other files (`stage_source`, and the stages' own in
/// `pf_gpu::kernels::sources`), checked as part of those.
const LIBRARIES: [&str; 7] = [
    "engine/philox.wgsl",
    "engine/common.wgsl",
    "engine/lag_cloud.wgsl",
    "engine/lag_params.wgsl",
    "engine/move_particle.wgsl",
    "engine/normalise_target.wgsl",
    "engine/resample_target.wgsl",
];

/// Every shader file but the libraries (its path under `shaders/`) with the source it is
/// compiled as.
fn every_module() -> Vec<(&'static str, String)> {
    let mut modules: Vec<(&str, String)> = sources::STAGES
        .iter()
        .map(|(file, stage)| (*file, stage_source(stage)))
        .map(|(file, source)| (engine_path(file), source))
        .collect();
    modules.extend([
        (
            "engine/random.wgsl",
            [sources::PHILOX, sources::RANDOM].join("\n"),
        ),
        (
            "face/likelihood.wgsl",
            stage_source(face_tracker::likelihood::SHADER),
        ),
        ("engine/smooth.wgsl", pf_gpu::smooth::SHADER.to_string()),
        ("face/detect.wgsl", face_tracker::detect::SHADER.to_string()),
        (
            "body/likelihood.wgsl",
            body_tracker::likelihood::SHADER.to_string(),
        ),
        (
            "body/skeleton.wgsl",
            body_tracker::skeleton::SHADER.to_string(),
        ),
    ]);
    modules
}

fn engine_path(file: &str) -> &'static str {
    Box::leak(format!("engine/{file}").into_boxed_str())
}

fn wgsl_files_on_disk() -> Vec<String> {
    let dir = root().join("shaders");
    let mut files = Vec::new();
    for owner in std::fs::read_dir(&dir).unwrap().flatten() {
        let owner_path = owner.path();
        if !owner_path.is_dir() {
            files.push(owner.file_name().to_string_lossy().into_owned());
            continue;
        }
        for file in std::fs::read_dir(&owner_path).unwrap().flatten() {
            files.push(format!(
                "{}/{}",
                owner.file_name().to_string_lossy(),
                file.file_name().to_string_lossy()
            ));
        }
    }
    files.sort();
    files
}

#[test]
fn every_shader_parses_and_validates() {
    for (file, source) in every_module() {
        if let Err(message) = validate_wgsl(&source) {
            panic!("shaders/{file}:\n{message}");
        }
    }
}

#[test]
fn every_wgsl_file_in_shaders_is_covered() {
    // A new shader file must be added to `every_module` (and to ARCHITECTURE.md's table), in a
    // folder named for its owner.
    let mut known: Vec<String> = every_module().into_iter().map(|(f, _)| f.into()).collect();
    known.extend(LIBRARIES.map(String::from));
    known.sort();
    assert_eq!(wgsl_files_on_disk(), known);
}

fn kernel_table() -> String {
    let doc = std::fs::read_to_string(root().join("ARCHITECTURE.md")).unwrap();
    doc.split("## Kernels")
        .nth(1)
        .and_then(|s| s.split("\n## ").next())
        .expect("ARCHITECTURE.md has a Kernels section")
        .to_string()
}

#[test]
fn architecture_kernel_table_names_every_entry_point() {
    let table = kernel_table();
    let mut missing = Vec::new();
    for (file, source) in every_module() {
        let module = pf_gpu::wgpu::naga::front::wgsl::parse_str(&source).unwrap();
        for entry in &module.entry_points {
            let named = table.lines().any(|l| {
                l.starts_with(&format!("| `{file}`")) && l.contains(&format!("`{}`", entry.name))
            });
            if !named {
                missing.push(format!("{file}: {}", entry.name));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md's kernel table lacks {missing:?}"
    );
}

/// The file a tracker kernel's launcher must live in, by the kernel's path under `shaders/`
/// (`face/likelihood.wgsl` → `crates/face-tracker/src/likelihood/gpu.rs`), and the module path
/// the table must name it by; `None` for the engine's kernels.
fn launcher_of(file: &str) -> Option<(PathBuf, String)> {
    let (owner, name) = file.strip_suffix(".wgsl")?.split_once('/')?;
    if owner == "engine" {
        return None;
    }
    Some((
        root().join(format!("crates/{owner}-tracker/src/{name}/gpu.rs")),
        format!("{owner}_tracker::{name}::gpu::"),
    ))
}

#[test]
fn every_tracker_kernel_is_launched_from_the_module_named_like_it() {
    let table = kernel_table();
    let mut wrong = Vec::new();
    for (file, _) in every_module() {
        let Some((launcher_file, module)) = launcher_of(file) else {
            continue;
        };
        let Ok(code) = std::fs::read_to_string(&launcher_file) else {
            wrong.push(format!("{file}: no {}", launcher_file.display()));
            continue;
        };
        for row in table
            .lines()
            .filter(|l| l.starts_with(&format!("| `{file}`")))
        {
            // The launcher column: the row's second cell, naming `<module><Item>` first.
            let launcher = row.split('|').nth(2).unwrap_or_default();
            let named = launcher
                .split('`')
                .nth(1)
                .and_then(|path| path.strip_prefix(module.as_str()));
            match named {
                Some(item) if defines(&code, item) => {}
                _ => wrong.push(format!(
                    "{file}: the launcher cell {launcher:?} should name `{module}Item`, an item \
                     defined in {}",
                    launcher_file.display()
                )),
            }
        }
    }
    assert!(wrong.is_empty(), "{wrong:#?}");
}

fn defines(code: &str, item: &str) -> bool {
    ["fn ", "struct ", "enum ", "trait ", "const ", "type "]
        .iter()
        .any(|kind| code.contains(&format!("{kind}{item}")))
}

/// The Rust items a shader's comments name (`pf_core::batch::diffuse`, `a::{b, c}`): the last
/// segment of each path.
fn named_items(comment: &str) -> Vec<String> {
    let mut names = Vec::new();
    for start in ["pf_core::", "pf_gpu::", "body_tracker::", "face_tracker::"] {
        for (at, _) in comment.match_indices(start) {
            let rest = &comment[at..];
            let end = rest
                .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .unwrap_or(rest.len());
            let path = rest[..end].trim_end_matches(':');
            if rest[end..].starts_with('{') && path.len() < end {
                let group = &rest[end + 1..rest.find('}').unwrap_or(rest.len())];
                names.extend(group.split(',').map(|n| n.trim().to_string()));
            } else if let Some(last) = path.rsplit("::").next() {
                names.push(last.to_string());
            }
        }
    }
    names
}

#[test]
fn every_rust_item_a_shader_names_exists() {
    let mut code = String::new();
    let mut files = Vec::new();
    for krate in ["pf-core", "pf-gpu", "body-tracker", "face-tracker"] {
        let mut stack = vec![root().join("crates").join(krate).join("src")];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).unwrap().flatten() {
                let path = entry.path();
                if path.is_dir() {
                    stack.push(path.clone());
                    files.push(path.file_name().unwrap().to_string_lossy().into_owned());
                } else {
                    files.push(path.file_stem().unwrap().to_string_lossy().into_owned());
                    code.push_str(&std::fs::read_to_string(&path).unwrap());
                }
            }
        }
    }
    let mut missing = Vec::new();
    for file in wgsl_files_on_disk() {
        let source = std::fs::read_to_string(root().join("shaders").join(&file)).unwrap();
        let comments: String = source
            .lines()
            .filter_map(|l| l.trim_start().strip_prefix("//"))
            .collect::<Vec<_>>()
            .join(" ");
        for name in named_items(&comments) {
            let defined = [
                "fn ", "struct ", "enum ", "trait ", "mod ", "type ", "const ",
            ]
            .iter()
            .any(|kind| code.contains(&format!("{kind}{name}")))
                || files.contains(&name);
            if !defined {
                missing.push(format!("{file}: {name}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "shader comments name items that do not exist: {missing:?}"
    );
}

/// pf-gpu is the generic engine: no code line of it names a tracker's things (comments that say
/// what the engine is for may).
#[test]
fn the_engine_crate_knows_no_tracker() {
    let tracker_word = [
        "face",
        "faces",
        "capsule",
        "capsules",
        "skeleton",
        "skeletons",
    ];
    let mut found = Vec::new();
    let mut stack = vec![root().join("crates/pf-gpu/src")];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            for (n, line) in text.lines().enumerate() {
                let code = line.split("//").next().unwrap_or_default();
                let hit = code
                    .split(|c: char| !(c.is_alphanumeric() || c == '_'))
                    .any(|word| tracker_word.contains(&word.to_lowercase().as_str()));
                if hit {
                    found.push(format!("{}:{}: {}", path.display(), n + 1, line.trim()));
                }
            }
        }
    }
    assert!(found.is_empty(), "{found:#?}");
}
