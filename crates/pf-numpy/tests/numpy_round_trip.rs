//! Round trips against numpy itself: numpy reads what we write, we read what numpy writes (C and
//! Fortran order, float32 and float64, both byte orders), and every bad file is a clear error.
//!
//! Needs python3 with numpy (`cargo xtask test` installs it); without it the test fails with
//! instructions, unless the run opts out of real media explicitly with STREAMPF_NO_MEDIA=1.

use std::path::{Path, PathBuf};
use std::process::Command;

use pf_core::batch::BatchShape;
use pf_numpy::{
    NpyError, batch_from_particles, particles_array, read_f32, read_finite_f32, write_f32,
    write_particles,
};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pf-numpy-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs Python code with numpy as `np` and `d` the scratch directory; `None` when the run opted
/// out of media and numpy is missing.
fn python(dir: &Path, code: &str) -> Option<String> {
    let script = format!("import numpy as np, sys\nd = sys.argv[1]\n{code}");
    let out = Command::new("python3")
        .arg("-c")
        .arg(&script)
        .arg(dir)
        .output();
    let missing = match &out {
        Ok(o) => {
            !o.status.success()
                && String::from_utf8_lossy(&o.stderr).contains("No module named 'numpy'")
        }
        Err(_) => true,
    };
    if missing {
        if std::env::var("STREAMPF_NO_MEDIA").is_ok_and(|v| v == "1") {
            eprintln!("SKIPPED: no python3 with numpy and STREAMPF_NO_MEDIA=1");
            return None;
        }
        panic!(
            "these tests need python3 with numpy: `pip install numpy` (cargo xtask test installs it), or set STREAMPF_NO_MEDIA=1"
        );
    }
    let out = out.unwrap();
    assert!(
        out.status.success(),
        "python failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn numpy_reads_what_we_write() {
    let dir = scratch("write");
    let shape = BatchShape::new(3, 5, 4).unwrap();
    let states: Vec<f32> = (0..shape.state_len())
        .map(|i| i as f32 * 0.5 - 7.0)
        .collect();
    let log_weights: Vec<f32> = (0..15).map(|i| -(i as f32)).collect();
    write_particles(&dir, 12, &shape, &states, &log_weights).unwrap();
    // numpy's (T, M, D) element [t, m, d] is the batch layout's state_index(t, d, m).
    let code = "a = np.load(f'{d}/particles_000012.npy'); w = np.load(f'{d}/log_weights_000012.npy')\n\
                assert a.dtype == np.float32 and a.shape == (3, 5, 4), (a.dtype, a.shape)\n\
                t, m, dd = np.meshgrid(range(3), range(5), range(4), indexing='ij')\n\
                expected = ((t * 4 + dd) * 5 + m) * 0.5 - 7.0\n\
                assert np.array_equal(a, expected.astype(np.float32))\n\
                assert w.shape == (3, 5) and np.array_equal(w.ravel(), -np.arange(15, dtype=np.float32))\n\
                print('ok')";
    if let Some(out) = python(&dir, code) {
        assert_eq!(out.trim(), "ok");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn we_read_what_numpy_writes_in_every_order_and_float_type() {
    let dir = scratch("read");
    let code = "x = np.arange(24, dtype=np.float64).reshape(2, 3, 4) / 8 - 1\n\
                np.save(f'{d}/c32.npy', x.astype(np.float32))\n\
                np.save(f'{d}/f64_fortran.npy', np.asfortranarray(x))\n\
                np.save(f'{d}/big_endian.npy', x.astype('>f4'))\n\
                np.save(f'{d}/ints.npy', np.arange(6, dtype=np.int32))\n\
                np.save(f'{d}/nan.npy', np.array([1.0, np.nan], dtype=np.float32))\n\
                np.save(f'{d}/huge.npy', np.array([1.0, 1e300]))\n\
                np.save(f'{d}/objects.npy', np.array([{}, None], dtype=object), allow_pickle=True)\n\
                np.save(f'{d}/scalar.npy', np.float32(2.5))\n\
                open(f'{d}/truncated.npy', 'wb').write(open(f'{d}/c32.npy', 'rb').read()[:-10])\n\
                print(np.asfortranarray(x).flags['F_CONTIGUOUS'])";
    let Some(out) = python(&dir, code) else {
        return;
    };
    assert_eq!(out.trim(), "True");
    let expected: Vec<f32> = (0..24).map(|i| i as f32 / 8.0 - 1.0).collect();
    for name in ["c32.npy", "f64_fortran.npy", "big_endian.npy"] {
        let a = read_finite_f32(&dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(a.shape, vec![2, 3, 4], "{name}");
        assert_eq!(a.data, expected, "{name}");
    }
    let scalar = read_f32(&dir.join("scalar.npy")).unwrap();
    assert_eq!(
        (scalar.shape.len(), scalar.data.as_slice()),
        (0, &[2.5f32][..])
    );
    let err = read_f32(&dir.join("ints.npy")).unwrap_err();
    assert!(
        matches!(err, NpyError::Dtype { .. }) && err.to_string().contains("<i4"),
        "{err}"
    );
    let err = read_f32(&dir.join("objects.npy")).unwrap_err();
    assert!(matches!(err, NpyError::Dtype { .. }), "{err}");
    assert!(read_f32(&dir.join("nan.npy")).unwrap().data[1].is_nan());
    let err = read_finite_f32(&dir.join("nan.npy")).unwrap_err();
    assert!(matches!(err, NpyError::NotFinite { index: 1, .. }), "{err}");
    let err = read_f32(&dir.join("huge.npy")).unwrap_err();
    assert!(err.to_string().contains("does not fit in float32"), "{err}");
    let err = read_f32(&dir.join("truncated.npy")).unwrap_err();
    assert!(
        matches!(err, NpyError::Format { .. }) && err.to_string().contains("truncated"),
        "{err}"
    );
    let err = read_f32(&dir.join("missing.npy")).unwrap_err();
    assert!(
        matches!(err, NpyError::Io { .. }) && err.to_string().contains("missing.npy"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn random_arrays_survive_rust_numpy_rust() {
    let dir = scratch("random");
    let mut rng = pf_core::RandomStreams::new(17).stream(0, pf_core::Stage::Model(0));
    let mut written = Vec::new();
    for k in 0..6 {
        let rank = 1 + (rng.uniform() * 3.0) as usize;
        let shape: Vec<usize> = (0..rank).map(|_| (rng.uniform() * 6.0) as usize).collect();
        let len: usize = shape.iter().product();
        // Edges: zero-sized extents, ±0, subnormals, extremes.
        let data: Vec<f32> = (0..len)
            .map(|i| match i % 7 {
                0 => -0.0,
                1 => f32::MIN_POSITIVE / 4.0,
                2 => f32::MAX,
                _ => 1e3 * rng.gaussian_f32(),
            })
            .collect();
        let path = dir.join(format!("a{k}.npy"));
        write_f32(&path, &shape, &data).unwrap();
        written.push((path, shape, data));
    }
    // numpy loads each, checks it is float32 and C-contiguous, and saves it back transposed in
    // Fortran order (the same values, another layout).
    let code = "import glob\n\
                for p in sorted(glob.glob(f'{d}/a*.npy')):\n\
                \x20   a = np.load(p)\n\
                \x20   assert a.dtype == np.float32 and a.flags['C_CONTIGUOUS']\n\
                \x20   np.save(p.replace('.npy', '_back.npy'), np.asfortranarray(a))\n\
                print('ok')";
    let Some(out) = python(&dir, code) else {
        return;
    };
    assert_eq!(out.trim(), "ok");
    for (path, shape, data) in written {
        let back = read_f32(&path.with_file_name(format!(
            "{}_back.npy",
            path.file_stem().unwrap().to_string_lossy()
        )))
        .unwrap();
        assert_eq!(back.shape, shape);
        let same = back
            .data
            .iter()
            .zip(&data)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same && back.data.len() == data.len(), "{}", path.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn particles_of_the_wrong_shape_are_an_error() {
    let shape = BatchShape::new(2, 3, 4).unwrap();
    let array = particles_array(&BatchShape::new(2, 4, 3).unwrap(), &[0.0; 24]);
    let err = batch_from_particles(Path::new("cloud.npy"), &shape, &array).unwrap_err();
    assert!(err.to_string().contains("expected (2, 3, 4)"), "{err}");
    let err = write_f32(Path::new("/nonexistent-dir/x.npy"), &[2], &[1.0, 2.0]).unwrap_err();
    assert!(matches!(err, NpyError::Io { .. }), "{err}");
    let err = write_f32(Path::new("x.npy"), &[3], &[1.0, 2.0]).unwrap_err();
    assert!(err.to_string().contains("2 values for shape [3]"), "{err}");
}

#[test]
fn npz_archives_round_trip_with_numpy() {
    use pf_numpy::npz::{NpzReader, write_npz};
    let dir = scratch("npz");
    let mut rng = pf_core::RandomStreams::new(23).stream(0, pf_core::Stage::Model(0));
    let states: Vec<f32> = (0..2 * 5 * 3).map(|_| rng.gaussian_f32()).collect();
    let weights: Vec<f32> = (0..10).map(|i| -(i as f32) * 0.25).collect();
    let ours = dir.join("ours.npz");
    write_npz(
        &ours,
        &[
            ("particles", &[2, 5, 3], &states),
            ("log_weights", &[2, 5], &weights),
            ("empty", &[0, 4], &[]),
        ],
    )
    .unwrap();
    write_f32(&dir.join("particles.npy"), &[2, 5, 3], &states).unwrap();
    // numpy reads ours; writes its own, stored and compressed, in other layouts and dtypes.
    let code = "z = np.load(f'{d}/ours.npz')\n\
                assert sorted(z.files) == ['empty', 'log_weights', 'particles'], z.files\n\
                assert np.array_equal(z['particles'], np.load(f'{d}/particles.npy'))\n\
                assert z['log_weights'].dtype == np.float32 and z['empty'].shape == (0, 4)\n\
                assert np.array_equal(z['log_weights'], -np.arange(10, dtype=np.float32).reshape(2, 5) / 4)\n\
                x = np.arange(24, dtype=np.float64).reshape(2, 3, 4) / 8 - 1\n\
                np.savez(f'{d}/stored.npz', x=np.asfortranarray(x), ints=np.arange(3))\n\
                np.savez_compressed(f'{d}/compressed.npz', x=x.astype(np.float32), bad=np.array([0.0, np.inf]))\n\
                open(f'{d}/truncated.npz', 'wb').write(open(f'{d}/compressed.npz', 'rb').read()[:40])\n\
                print('ok')";
    let Some(out) = python(&dir, code) else {
        return;
    };
    assert_eq!(out.trim(), "ok");
    let expected: Vec<f32> = (0..24).map(|i| i as f32 / 8.0 - 1.0).collect();
    for file in ["stored.npz", "compressed.npz"] {
        let mut npz = NpzReader::open(&dir.join(file)).unwrap();
        let x = npz.read_finite_f32("x").unwrap();
        assert_eq!(
            (x.shape.as_slice(), &x.data),
            (&[2, 3, 4][..], &expected),
            "{file}"
        );
    }
    let mut stored = NpzReader::open(&dir.join("stored.npz")).unwrap();
    let err = stored.read_f32("ints").unwrap_err();
    assert!(
        matches!(err, NpyError::Dtype { .. }) && err.to_string().contains("ints.npy"),
        "{err}"
    );
    let err = stored.read_f32("y").unwrap_err();
    assert!(err.to_string().contains("no array named \"y\""), "{err}");
    let mut compressed = NpzReader::open(&dir.join("compressed.npz")).unwrap();
    let err = compressed.read_finite_f32("bad").unwrap_err();
    assert!(matches!(err, NpyError::NotFinite { index: 1, .. }), "{err}");
    let mut back = NpzReader::open(&ours).unwrap();
    assert_eq!(back.read_f32("particles").unwrap().data, states);
    for bad in ["truncated.npz", "particles.npy"] {
        let err = NpzReader::open(&dir.join(bad)).err().expect(bad);
        assert!(
            matches!(err, NpyError::Format { .. }) && err.to_string().contains(bad),
            "{err}"
        );
    }
    let err = write_npz(
        &dir.join("x.npz"),
        &[("a", &[1], &[1.0]), ("a", &[1], &[2.0])],
    )
    .unwrap_err();
    assert!(err.to_string().contains("repeated"), "{err}");
    let err = write_npz(&dir.join("x.npz"), &[("a", &[3], &[1.0])]).unwrap_err();
    assert!(err.to_string().contains("1 values for shape [3]"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
