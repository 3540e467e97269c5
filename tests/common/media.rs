//! Real media for the tests (photographs, cascades, video), fetched by `cargo xtask fetch-media`
//! (which `cargo xtask test` runs). Without them a test fails with instructions, unless the run
//! opts out explicitly with `STREAMPF_NO_MEDIA=1`.

use std::path::{Path, PathBuf};

pub const HELP: &str = "run `cargo xtask fetch-media` (it installs Debian's opencv-data, opencv-doc and libdlib-data and OpenCV's and dlib's Python packages, and fetches the photographs into target/media), or set STREAMPF_NO_MEDIA=1 to skip the tests on real media explicitly";

/// `true` (and a note on stderr) when the run opted out of real media.
pub fn opted_out(test: &str) -> bool {
    let out = std::env::var_os("STREAMPF_NO_MEDIA").is_some_and(|v| v == "1");
    if out {
        eprintln!("{test}: skipped by request (STREAMPF_NO_MEDIA=1)");
    }
    out
}

/// Where the Haar cascades are: $STREAMPF_CASCADES, else opencv-data's directory.
pub fn cascade_dir() -> PathBuf {
    std::env::var_os("STREAMPF_CASCADES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/share/opencv4/haarcascades"))
}

/// A cascade file, or a panic with instructions when it is missing.
pub fn cascade_path(name: &str) -> PathBuf {
    let path = cascade_dir().join(name);
    assert!(path.is_file(), "{} is missing; {HELP}", path.display());
    path
}

/// The workspace's media directory (target/media).
pub fn media_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("target/media")
}

/// The photographs `cargo xtask fetch-media` put in target/media/images (PNG, name order), or a
/// panic with instructions when fewer than seven are there.
pub fn photographs() -> Vec<PathBuf> {
    let dir = media_dir().join("images");
    let mut images: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}; {HELP}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    images.sort();
    assert!(
        images.len() >= 7,
        "{} images in {}; {HELP}",
        images.len(),
        dir.display()
    );
    images
}
