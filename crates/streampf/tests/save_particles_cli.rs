//! `--save-particles DIR` on `face track` and `body track`: every frame's cloud and log-weights
//! as numpy files, checked by numpy itself (shapes, dtypes, normalised weights, the estimate as
//! the cloud's weighted mean). Needs python3 with numpy (`cargo xtask test` installs it), unless
//! the run opts out of media with STREAMPF_NO_MEDIA=1.

mod common;

use common::{ok, scratch, streampf};
use std::path::Path;
use std::process::Command;

/// Runs the numpy check `code` with `d` the particles directory and `out` the CSV directory.
fn numpy_check(dir: &Path, out: &Path, code: &str) {
    let script =
        format!("import numpy as np, sys\nd, out = sys.argv[1], sys.argv[2]\n{code}\nprint('ok')");
    let result = Command::new("python3")
        .arg("-c")
        .arg(&script)
        .arg(dir)
        .arg(out)
        .output();
    let no_numpy = result.as_ref().map_or(true, |o| {
        String::from_utf8_lossy(&o.stderr).contains("No module named 'numpy'")
    });
    if no_numpy {
        assert!(
            std::env::var("STREAMPF_NO_MEDIA").is_ok_and(|v| v == "1"),
            "this test needs python3 with numpy (cargo xtask test installs it), or STREAMPF_NO_MEDIA=1"
        );
        eprintln!("SKIPPED the numpy check: no numpy and STREAMPF_NO_MEDIA=1");
        return;
    }
    let o = result.unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "ok");
}

#[test]
fn face_track_saves_every_frames_particles_for_numpy() {
    let out = scratch("face-particles-out");
    let particles = out.join("particles");
    ok(&streampf(&[
        "face",
        "track",
        "--synthetic",
        "--frames",
        "4",
        "--faces",
        "2",
        "--width",
        "256",
        "--height",
        "192",
        "--particles",
        "64",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--save-particles",
        particles.to_str().unwrap(),
    ]));
    // Weights normalised per tracked slot; each track's first state columns near the cloud's
    // weighted mean (the CSV's estimate is the best-M' mean, so only roughly).
    numpy_check(&particles, &out, "
for f in range(4):
    p = np.load(f'{d}/particles_{f:06}.npy'); w = np.load(f'{d}/log_weights_{f:06}.npy'); t = np.load(f'{d}/tracks_{f:06}.npy')
    assert p.dtype == np.float32 and p.shape[1:] == (64, 7) and w.shape == p.shape[:2] and t.shape == (p.shape[0],), (p.shape, w.shape, t.shape)
    assert sorted(t[t >= 0].tolist()) == [0.0, 1.0], t
    rows = [l.split(',') for l in open(f'{out}/states.csv').read().splitlines()[1:]]
    for slot in np.flatnonzero(t >= 0):
        assert abs(np.logaddexp.reduce(w[slot])) < 1e-3, np.logaddexp.reduce(w[slot])
        mean = (np.exp(w[slot])[:, None] * p[slot]).sum(axis=0)
        row = [r for r in rows if int(r[0]) == f and r[2] != '' and int(r[2]) == int(t[slot])][0]
        assert np.hypot(*(mean[:2] - np.array(row[5:7], dtype=float))) < 10.0, (mean[:2], row[5:7])
");
    std::fs::remove_dir_all(&out).unwrap();
}

/// The body's cloud on `backend` (cpu, or gpu on any adapter, lavapipe included).
fn body_track_saves_samples(backend: &str) {
    let out = scratch(&format!("body-particles-{backend}"));
    let particles = out.join("particles");
    ok(&streampf(&[
        "body",
        "track",
        "--synthetic",
        "--frames",
        "3",
        "--capsules",
        "19",
        "--width",
        "96",
        "--height",
        "72",
        "--particles",
        "50",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--save-particles",
        particles.to_str().unwrap(),
    ]));
    // poses.csv's estimate is the weighted mean of the saved cloud, its sd_ columns the weighted
    // standard deviation about it (the root's translation), its ess 1/Σw².
    numpy_check(
        &particles,
        &out,
        "
poses = np.loadtxt(f'{out}/poses.csv', delimiter=',', skiprows=1)
header = open(f'{out}/poses.csv').readline().strip().split(',')
dims = sum(1 for c in header[1:] if not c.startswith('sd_') and c not in ('ess', 'log_evidence', 'confidence'))
sd = header.index('sd_root_tx')
ess = header.index('ess')
for f in range(3):
    p = np.load(f'{d}/particles_{f:06}.npy'); w = np.load(f'{d}/log_weights_{f:06}.npy')
    assert p.dtype == np.float32 and p.shape == (1, 50, dims) and w.shape == (1, 50)
    weights = np.exp(w[0].astype(np.float64))
    assert abs(weights.sum() - 1) < 1e-4
    mean = (weights[:, None] * p[0]).sum(axis=0)
    assert np.allclose(mean[:3], poses[f, 1:4], atol=1e-3), (mean[:3], poses[f, 1:4])
    spread = np.sqrt((weights[:, None] * (p[0] - mean) ** 2).sum(axis=0))
    assert np.allclose(spread[:3], poses[f, sd:sd + 3], rtol=1e-3, atol=1e-5), (spread[:3], poses[f, sd:sd + 3])
    assert abs(1 / (weights ** 2).sum() - poses[f, ess]) < 1e-2 * poses[f, ess]
",
    );
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn body_track_saves_every_frames_samples_for_numpy() {
    body_track_saves_samples("cpu");
}

/// The GPU path reads the cloud and log-weights back from the device.
#[test]
fn body_track_on_the_gpu_saves_the_device_cloud() {
    if pf_gpu::list_adapters().is_err()
        && std::env::var("STREAMPF_ALLOW_NO_GPU").is_ok_and(|v| v == "1")
    {
        eprintln!("SKIPPED: no GPU adapter and STREAMPF_ALLOW_NO_GPU=1");
        return;
    }
    body_track_saves_samples("gpu");
}

#[test]
fn an_unusable_save_particles_directory_is_a_clear_error() {
    let out = scratch("bad-particles");
    std::fs::create_dir_all(&out).unwrap();
    let file = out.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let bad = file.join("particles");
    let result = streampf(&[
        "body",
        "track",
        "--synthetic",
        "--frames",
        "2",
        "--capsules",
        "19",
        "--width",
        "64",
        "--height",
        "48",
        "--particles",
        "10",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--save-particles",
        bad.to_str().unwrap(),
    ]);
    assert!(!result.status.success());
    let text = String::from_utf8_lossy(&result.stderr);
    assert!(text.contains("--save-particles: creating"), "{text}");
    std::fs::remove_dir_all(&out).unwrap();
}
