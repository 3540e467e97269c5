//! PLY point clouds: both encodings read back what was written; bad files are clear errors.

use body_tracker::ply::{parse_ply, ply_ascii, read_ply, write_ply_binary};
use nalgebra::{Vector3, vector};
use proptest::prelude::*;

proptest! {
    #[test]
    fn ascii_and_binary_round_trip(points in prop::collection::vec((-1e3f32..1e3, -1e3f32..1e3, -1e3f32..1e3), 0..200)) {
        let points: Vec<Vector3<f32>> = points.into_iter().map(|(x, y, z)| vector![x, y, z]).collect();
        prop_assert_eq!(parse_ply(ply_ascii(&points).as_bytes()).unwrap(), points.clone());
        let path = std::env::temp_dir().join(format!("streampf-ply-{}-{}.ply", std::process::id(), points.len()));
        write_ply_binary(&path, &points).unwrap();
        prop_assert_eq!(read_ply(&path).unwrap(), points);
        std::fs::remove_file(&path).ok();
    }
}

#[test]
fn extra_properties_other_types_and_later_elements_are_handled() {
    let mut bytes = b"ply\r\nformat binary_little_endian 1.0\r\nelement vertex 2\r\nproperty uchar red\r\nproperty double x\r\nproperty float y\r\nproperty short z\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n".to_vec();
    for (r, x, y, z) in [(7u8, 1.5f64, -2.0f32, 3i16), (9, -0.25, 4.0, -6)] {
        bytes.push(r);
        bytes.extend_from_slice(&x.to_le_bytes());
        bytes.extend_from_slice(&y.to_le_bytes());
        bytes.extend_from_slice(&z.to_le_bytes());
    }
    bytes.extend_from_slice(&[3, 0, 0, 0, 0]); // the face, ignored
    assert_eq!(
        parse_ply(&bytes).unwrap(),
        vec![vector![1.5, -2.0, 3.0], vector![-0.25, 4.0, -6.0]]
    );
    let ascii = "ply\nformat ascii 1.0\ncomment scan\nelement vertex 1\nproperty float nx\nproperty float x\nproperty float y\nproperty float z\nend_header\n0.5 1 2 3\n";
    assert_eq!(
        parse_ply(ascii.as_bytes()).unwrap(),
        vec![vector![1.0, 2.0, 3.0]]
    );
}

#[test]
fn bad_files_are_clear_errors() {
    let cases: Vec<(&[u8], &str)> = vec![
        (b"", "empty"),
        (b"hello world", "end_header"),
        (b"plx\nformat ascii 1.0\nelement vertex 0\nend_header\n", "\"ply\""),
        (b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n", "binary_big_endian"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n", "no z"),
        (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n", "ends after 1 of 2"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 two 3\n", "not a number"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 nan 3\n", "not finite"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00", "vertex data"),
        (b"ply\nformat ascii 1.0\nelement vertex many\nproperty float x\nproperty float y\nproperty float z\nend_header\n", "not a number"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\nend_header\n", "unknown type"),
    ];
    for (bytes, expect) in cases {
        let err = parse_ply(bytes).unwrap_err().to_string();
        assert!(
            err.contains(expect),
            "{:?}: {err}",
            String::from_utf8_lossy(bytes)
        );
    }
    let missing = read_ply(std::path::Path::new("/no/such/cloud.ply"))
        .unwrap_err()
        .to_string();
    assert!(missing.contains("/no/such/cloud.ply"), "{missing}");
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(body in prop::collection::vec(any::<u8>(), 0..300), binary in any::<bool>(), count in 0usize..20) {
        let format = if binary { "binary_little_endian" } else { "ascii" };
        let mut bytes = format!("ply\nformat {format} 1.0\nelement vertex {count}\nproperty float x\nproperty float y\nproperty float z\nend_header\n").into_bytes();
        bytes.extend_from_slice(&body);
        let _ = parse_ply(&bytes);
        let _ = parse_ply(&body);
    }
}
