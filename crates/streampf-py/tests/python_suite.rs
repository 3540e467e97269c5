//! Runs the Python package's pytest suite (the `test_*.py` files beside this one) against the
//! extension module this very build made, so that `cargo test` — and the README's `cargo xtask
//! test` — tests the Python API with no second compile: the module is copied next to the
//! package's Python sources into a scratch directory put on PYTHONPATH.
//!
//! Needs Python 3.9+ with numpy, pytest, ray, pandas and motmetrics (`cargo xtask test` installs them); a missing one
//! fails the test, naming it.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The build's `target/<profile>` directory: this test runs from its `deps/`.
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test's own path");
    exe.parent()
        .and_then(Path::parent)
        .expect("the test runs from target/<profile>/deps")
        .to_path_buf()
}

/// The extension module this build made (`lib_streampf.so`, `lib_streampf.dylib` or
/// `_streampf.dll`).
fn extension_module(profile: &Path) -> PathBuf {
    let deps = profile.join("deps");
    ["lib_streampf.so", "lib_streampf.dylib", "_streampf.dll"]
        .iter()
        .map(|name| deps.join(name))
        .find(|p| p.exists())
        .unwrap_or_else(|| panic!("the extension module was not built in {}", deps.display()))
}

/// The package as an installed wheel lays it out: `streampf/` with its Python files and the
/// module as `_streampf.abi3.so` (`.pyd` on Windows).
fn assemble_package(module: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("python-package");
    let package = root.join("streampf");
    let _ = std::fs::remove_dir_all(&package);
    std::fs::create_dir_all(&package).expect("creating the scratch package");
    let sources = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/streampf");
    for entry in std::fs::read_dir(&sources).expect("the package's Python sources") {
        let path = entry.expect("a directory entry").path();
        if path.is_file() {
            std::fs::copy(&path, package.join(path.file_name().expect("a file name")))
                .expect("copying a Python source");
        }
    }
    let name = if cfg!(windows) {
        "_streampf.pyd"
    } else {
        "_streampf.abi3.so"
    };
    std::fs::copy(module, package.join(name)).expect("copying the extension module");
    root
}

#[test]
fn the_python_suite_passes() {
    let profile = profile_dir();
    let package = assemble_package(&extension_module(&profile));
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let missing = Command::new(&python)
        .args(["-c", "import numpy, pytest, ray, pandas, motmetrics"])
        .output()
        .expect("running Python (set PYTHON to its path)");
    assert!(
        missing.status.success(),
        "the Python suite needs numpy, pytest, ray, pandas and motmetrics (`cargo xtask test` \
         installs them: pip install numpy pytest ray pandas motmetrics):\n{}",
        String::from_utf8_lossy(&missing.stderr)
    );
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let mut pythonpath = std::ffi::OsString::from(&package);
    if let Some(existing) = std::env::var_os("PYTHONPATH") {
        pythonpath.push(":");
        pythonpath.push(existing);
    }
    let status = Command::new(&python)
        // The ten slowest tests are listed, so that a CI run shows where its Python minutes go.
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .arg("--durations=10")
        .arg(&tests)
        .env("PYTHONPATH", pythonpath)
        .env("STREAMPF_BIN", profile.join("streampf"))
        .env("NODEVICE_SELECT", "1")
        .status()
        .expect("running pytest");
    assert!(status.success(), "the Python suite failed ({status})");
}
