//! # parser-fuzz: the parsers a user can feed, as fuzz targets
//!
//! Each [`Target`] names one parser, runs it on bytes (through a scratch file for the parsers
//! that read paths) and carries valid seed inputs the project writes itself. Two fuzzers use the
//! same targets: the mutation fuzzer of `tests/fuzz_parsers.rs` (in the test suite) and the
//! coverage-guided AFL++ harness in `fuzz/` (`cargo xtask fuzz`). A target passes when no input
//! panics it and every input it refuses gets an error with a message (`Err` holds the message).

use std::path::{Path, PathBuf};

use body_tracker::camera::{DepthImage, Intrinsics, read_depth_png, write_depth_png};
use body_tracker::human::human_skeleton;
use body_tracker::ply::{parse_ply, ply_ascii, write_ply_binary};
use body_tracker::sequence::{read_numeric_csv, read_pose_csv};
use body_tracker::skeleton::Skeleton;
use face_tracker::GrayImage;
use face_tracker::camera::Calibration;
use face_tracker::detect::Cascade;
use face_tracker::landmarks::ShapePredictor;
use face_tracker::landmarks::pts::parse_pts;
use nalgebra::Vector3;

/// A parse of some bytes: `Err` holds the parser's message.
pub type Parse = Box<dyn Fn(&[u8]) -> Result<(), String>>;

/// One parser: its name, valid seeds, and the parse of some bytes.
pub struct Target {
    pub name: &'static str,
    pub seeds: Vec<Vec<u8>>,
    pub parse: Parse,
}

/// Every target; path-reading parsers write their input under `scratch` (a directory that
/// exists).
pub fn targets(scratch: &Path) -> Result<Vec<Target>, String> {
    let mut targets = face_targets(scratch)?;
    targets.extend(body_targets(scratch)?);
    targets.extend(numpy_targets(scratch)?);
    Ok(targets)
}

/// A seed written by the project's own writer: `write` saves it under `scratch`, then it is read
/// back as bytes.
fn seed_file(
    scratch: &Path,
    name: &str,
    write: &dyn Fn(&Path) -> Result<(), String>,
) -> Result<Vec<u8>, String> {
    let path = scratch.join(format!("seed-{name}"));
    write(&path)?;
    std::fs::read(&path).map_err(|e| e.to_string())
}

/// A parse of a parser that reads a path: the bytes go to `scratch/name` first.
fn through(scratch: &Path, name: &str, read: fn(&Path) -> Result<(), String>) -> Parse {
    let path = scratch.join(name);
    Box::new(move |bytes| {
        std::fs::write(&path, bytes).map_err(|e| format!("scratch file: {e}"))?;
        read(&path)
    })
}

/// A calibration as OpenCV's calibration sample writes it (`face track --calibration`).
const OPENCV_CALIBRATION_YAML: &str = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n\
    camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 6.5746697944293521e+02, 0., 3.1950000000000000e+02, 0.,\n       6.5746697944293521e+02, 2.3950000000000000e+02, 0., 0., 1. ]\n\
    distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ -4.18e-01, 5.07e-01, 0., 0., -5.78e-01 ]\n";

/// The same in OpenCV's JSON.
const OPENCV_CALIBRATION_JSON: &str = r#"{"imageSize": [640, 480], "cameraMatrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d", "data": [657.5, 0.0, 319.5, 0.0, 657.5, 239.5, 0.0, 0.0, 1.0]}, "distCoeffs": [0.1, 0.0, 0.0, 0.0]}"#;

/// A cascade of two stages and three features (a two-node tree, stumps, a three-rectangle
/// feature, the `tilted` flag) in OpenCV's format, modelled on its frontal-face cascade
/// (`haarcascade_frontalface_alt2.xml`, whose first classifier and feature it keeps; the
/// detection tests load the file itself): the cascade target's seed. The 540 kB file itself parsed at about 160 inputs/s in the mutation
/// fuzzer, and AFL++ ran it 322 times in its 10 s: too slow to fuzz.
pub const SMALL_CASCADE: &str = r#"<?xml version="1.0"?>
<opencv_storage>
<cascade type_id="opencv-cascade-classifier"><stageType>BOOST</stageType>
  <featureType>HAAR</featureType>
  <height>20</height>
  <width>20</width>
  <stageParams>
    <maxWeakCount>2</maxWeakCount></stageParams>
  <featureParams>
    <maxCatCount>0</maxCatCount></featureParams>
  <stageNum>2</stageNum>
  <stages>
    <_>
      <maxWeakCount>2</maxWeakCount>
      <stageThreshold>3.5069230198860168e-01</stageThreshold>
      <weakClassifiers>
        <_>
          <internalNodes>
            0 1 0 4.3272329494357109e-03 -1 -2 1 1.3076160103082657e-02</internalNodes>
          <leafValues>
            3.8381900638341904e-02 8.9652568101882935e-01
            2.6293140649795532e-01</leafValues></_>
        <_>
          <internalNodes>
            0 -1 2 5.2434601821005344e-04</internalNodes>
          <leafValues>
            1.0216630250215530e-01 6.9103831052780151e-01</leafValues></_></weakClassifiers></_>
    <_>
      <maxWeakCount>1</maxWeakCount>
      <stageThreshold>-1.2e-01</stageThreshold>
      <weakClassifiers>
        <_>
          <internalNodes>
            0 -1 1 -9.2708261217921972e-04</internalNodes>
          <leafValues>
            1.9536970555782318e-01 -8.2586747407913208e-01</leafValues></_></weakClassifiers></_></stages>
  <features>
    <_>
      <rects>
        <_>
          2 7 16 4 -1.</_>
        <_>
          2 9 16 2 2.</_></rects>
      <tilted>0</tilted></_>
    <_>
      <rects>
        <_>
          3 3 9 16 -1.</_>
        <_>
          6 3 3 16 3.</_></rects></_>
    <_>
      <rects>
        <_>
          0 0 6 6 -1.</_>
        <_>
          0 0 3 3 2.</_>
        <_>
          3 3 3 3 2.</_></rects></_></features></cascade>
</opencv_storage>
"#;

/// The face tracker's inputs: the landmark model, `.pts` files, frames and the Haar cascade.
fn face_targets(scratch: &Path) -> Result<Vec<Target>, String> {
    let frame = GrayImage::new(24, 16, (0..24 * 16).map(|i| (i * 7 % 251) as u8).collect())
        .map_err(|e| e.to_string())?;
    let targets = vec![
        Target {
            name: "dlib-model",
            seeds: vec![small_dlib_model()],
            parse: Box::new(|b| {
                ShapePredictor::from_bytes(b)
                    .map(drop)
                    .map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "pts",
            seeds: vec![pts_text(68).into_bytes(), pts_text(3).into_bytes()],
            parse: Box::new(|b| parse_pts(&String::from_utf8_lossy(b)).map(drop)),
        },
        Target {
            name: "opencv-calibration",
            seeds: vec![
                OPENCV_CALIBRATION_YAML.as_bytes().to_vec(),
                OPENCV_CALIBRATION_JSON.as_bytes().to_vec(),
            ],
            parse: Box::new(|b| {
                Calibration::parse(&String::from_utf8_lossy(b))
                    .map(drop)
                    .map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "image-frame",
            seeds: vec![seed_file(scratch, "f.png", &|p| {
                frame.save_png(p).map_err(|e| e.to_string())
            })?],
            parse: through(scratch, "frame.png", |p| {
                GrayImage::load(p).map(drop).map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "haar-cascade",
            seeds: vec![SMALL_CASCADE.as_bytes().to_vec()],
            parse: Box::new(|b| Cascade::parse(&String::from_utf8_lossy(b)).map(drop)),
        },
    ];
    Ok(targets)
}

/// The body tracker's inputs: point clouds, depth images, camera and skeleton files, CSVs.
fn body_targets(scratch: &Path) -> Result<Vec<Target>, String> {
    let skeleton = human_skeleton(19).map_err(|e| e.to_string())?;
    let dofs = skeleton.dofs();
    let camera = Intrinsics::with_fov(32, 24, 60.0).map_err(|e| e.to_string())?;
    let depth = DepthImage {
        width: 32,
        height: 24,
        depth: (0..32 * 24).map(|i| 1000 + (i % 97) as u16).collect(),
    };
    let pose_path = scratch.join("poses.csv");
    Ok(vec![
        Target {
            name: "ply",
            seeds: vec![
                ply_ascii(&body_points()).into_bytes(),
                seed_file(scratch, "b.ply", &|p| {
                    write_ply_binary(p, &body_points()).map_err(|e| e.to_string())
                })?,
            ],
            parse: Box::new(|b| parse_ply(b).map(drop).map_err(|e| e.to_string())),
        },
        Target {
            name: "depth-png",
            seeds: vec![seed_file(scratch, "d.png", &|p| {
                write_depth_png(p, &depth).map_err(|e| e.to_string())
            })?],
            parse: through(scratch, "depth.png", |p| {
                read_depth_png(p).map(drop).map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "camera-json",
            seeds: vec![seed_file(scratch, "camera.json", &|p| {
                camera.save(p).map_err(|e| e.to_string())
            })?],
            parse: through(scratch, "camera.json", |p| {
                Intrinsics::load(p).map(drop).map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "skeleton-json",
            seeds: vec![seed_file(scratch, "skeleton.json", &|p| {
                skeleton.save(p).map_err(|e| e.to_string())
            })?],
            parse: through(scratch, "skeleton.json", |p| {
                Skeleton::load(p).map(drop).map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "pose-csv",
            seeds: vec![pose_csv_seed(&skeleton)],
            parse: Box::new(move |b| {
                std::fs::write(&pose_path, b).map_err(|e| format!("scratch file: {e}"))?;
                read_pose_csv(&pose_path, dofs)
                    .map(drop)
                    .map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "numeric-csv",
            seeds: vec![b"frame,face,a,b\n0,0,1.5,2\n1,0,-3,4e-3\n".to_vec()],
            parse: through(scratch, "numbers.csv", |p| {
                read_numeric_csv(p, 4).map(drop).map_err(|e| e.to_string())
            }),
        },
    ])
}

/// Three frames of poses for `skeleton`, as `body track` writes them.
fn pose_csv_seed(skeleton: &Skeleton) -> Vec<u8> {
    let dofs = skeleton.dofs();
    let mut csv = format!("frame,{}\n", skeleton.pose_names().join(","));
    for r in 0..3 {
        let values: Vec<String> = (0..dofs)
            .map(|d| ((r * dofs + d) as f32 * 0.01).to_string())
            .collect();
        csv.push_str(&format!("{r},{}\n", values.join(",")));
    }
    csv.into_bytes()
}

/// numpy's files: `.npy` arrays and `.npz` archives.
fn numpy_targets(scratch: &Path) -> Result<Vec<Target>, String> {
    Ok(vec![
        Target {
            name: "npy",
            seeds: vec![seed_file(scratch, "a.npy", &|p| {
                let values: Vec<f32> = (0..24).map(|i| i as f32 * 0.5).collect();
                pf_numpy::write_f32(p, &[3, 4, 2], &values).map_err(|e| e.to_string())
            })?],
            parse: through(scratch, "x.npy", |p| {
                pf_numpy::read_f32(p).map(drop).map_err(|e| e.to_string())
            }),
        },
        Target {
            name: "npz",
            seeds: vec![seed_file(scratch, "a.npz", &|p| {
                let arrays: [(&str, &[usize], &[f32]); 2] = [
                    ("x", &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
                    ("y", &[1], &[7.0]),
                ];
                pf_numpy::npz::write_npz(p, &arrays).map_err(|e| e.to_string())
            })?],
            parse: through(scratch, "x.npz", |p| {
                let mut npz = pf_numpy::npz::NpzReader::open(p).map_err(|e| e.to_string())?;
                npz.read_f32("x").map(drop).map_err(|e| e.to_string())
            }),
        },
    ])
}

/// A scratch directory for one fuzzing process.
pub fn scratch_dir(label: &str) -> PathBuf {
    std::env::temp_dir().join(format!("streampf-{label}-{}", std::process::id()))
}

/// dlib's integer encoding (`pack_int`).
fn pack(value: i64) -> Vec<u8> {
    let mut magnitude = value.unsigned_abs();
    let mut body = Vec::new();
    loop {
        body.push((magnitude & 0xff) as u8);
        magnitude >>= 8;
        if magnitude == 0 {
            break;
        }
    }
    let mut out = vec![body.len() as u8 | if value < 0 { 0x80 } else { 0 }];
    out.extend(body);
    out
}

/// dlib's float encoding: a mantissa and a binary exponent.
fn pack_float(value: f32) -> Vec<u8> {
    let mut out = pack((f64::from(value) * 1_048_576.0).round() as i64);
    out.extend(pack(-20));
    out
}

/// A two-landmark dlib shape predictor: one level, one tree of one split, two leaves.
fn small_dlib_model() -> Vec<u8> {
    let column = |values: &[f32]| {
        let mut out = pack(-(values.len() as i64));
        out.extend(pack(-1));
        values.iter().for_each(|&v| out.extend(pack_float(v)));
        out
    };
    let mut b = pack(1);
    b.extend(column(&[0.25, 0.5, 0.75, 0.5]));
    for v in [1, 1, 1, 0, 1] {
        b.extend(pack(v));
    }
    b.extend(pack_float(10.0));
    b.extend(pack(2));
    b.extend(column(&[0.125, 0.0, 0.125, 0.0]));
    b.extend(column(&[-0.125, 0.0, -0.125, 0.0]));
    for v in [1, 2, 0, 1, 1, 2] {
        b.extend(pack(v));
    }
    (0..4).for_each(|_| b.extend(pack_float(0.0)));
    b
}

fn body_points() -> Vec<Vector3<f32>> {
    (0..40)
        .map(|i| {
            Vector3::new(
                i as f32 * 0.01 - 0.2,
                1.0 - i as f32 * 0.02,
                3.0 + (i % 5) as f32 * 0.01,
            )
        })
        .collect()
}

fn pts_text(points: usize) -> String {
    let mut text = format!("version: 1\nn_points: {points}\n{{\n");
    for k in 0..points {
        text.push_str(&format!("{}.5 {}.25\n", 100 + k, 200 - k));
    }
    text.push_str("}\n");
    text
}
