//! Sequences on disk: a directory of frames (PLY point clouds, or 16-bit depth PNGs with the
//! camera's intrinsics), with optional ground truth, and the CSV files the tracker writes.
//!
//! A sequence directory holds:
//! - frames: `*.ply`, or `*.png` depth images, taken in name order;
//! - `camera.json`: [`Intrinsics`] (needed for depth PNGs; the camera is at the origin);
//! - `skeleton.json` (optional): the skeleton to track; else the default human;
//! - `ground_truth.csv` (optional): `frame` and one column per pose value, one row per frame;
//!   its first row also initialises the tracker.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;

use crate::camera::{Intrinsics, file_error, read_depth_png, write_depth_png};
use crate::error::BodyError;
use crate::ply::{read_ply, write_ply_binary};
use crate::skeleton::Skeleton;
use crate::synth::{SynthConfig, pose_at, render};

pub const CAMERA_FILE: &str = "camera.json";
pub const SKELETON_FILE: &str = "skeleton.json";
pub const GROUND_TRUTH_FILE: &str = "ground_truth.csv";
pub const GROUND_TRUTH_JOINTS_FILE: &str = "ground_truth_joints.csv";

/// How the frames of a directory are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameFormat {
    Ply,
    DepthPng,
}

/// A sequence directory, its frames listed.
#[derive(Debug, Clone)]
pub struct SequenceDir {
    pub dir: PathBuf,
    pub format: FrameFormat,
    pub frames: Vec<PathBuf>,
    pub camera: Option<Intrinsics>,
}

impl SequenceDir {
    /// Lists the frames of `dir`. PLY files win when both kinds are present.
    pub fn open(dir: &Path) -> Result<Self, BodyError> {
        let entries = std::fs::read_dir(dir).map_err(|e| file_error(dir, e))?;
        let mut ply = Vec::new();
        let mut png = Vec::new();
        for entry in entries {
            let path = entry.map_err(|e| file_error(dir, e))?.path();
            match path.extension().and_then(|e| e.to_str()) {
                Some(e) if e.eq_ignore_ascii_case("ply") => ply.push(path),
                Some(e) if e.eq_ignore_ascii_case("png") => png.push(path),
                _ => {}
            }
        }
        let camera_path = dir.join(CAMERA_FILE);
        let camera = if camera_path.exists() {
            Some(Intrinsics::load(&camera_path)?)
        } else {
            None
        };
        let (format, mut frames) = if !ply.is_empty() {
            (FrameFormat::Ply, ply)
        } else if !png.is_empty() {
            if camera.is_none() {
                return Err(file_error(
                    dir,
                    format!("depth PNG frames need the camera intrinsics in {CAMERA_FILE}"),
                ));
            }
            (FrameFormat::DepthPng, png)
        } else {
            return Err(file_error(
                dir,
                "no frames: expected *.ply point clouds or *.png depth images",
            ));
        };
        frames.sort();
        Ok(Self {
            dir: dir.to_path_buf(),
            format,
            frames,
            camera,
        })
    }

    /// The points of frame `i`, in the camera frame.
    pub fn read_frame(&self, i: usize) -> Result<Vec<Vector3<f32>>, BodyError> {
        let path = self.frames.get(i).ok_or_else(|| {
            BodyError::InvalidInput(format!(
                "frame {i} asked of a sequence of {}",
                self.frames.len()
            ))
        })?;
        match self.format {
            FrameFormat::Ply => read_ply(path),
            FrameFormat::DepthPng => {
                let camera = self
                    .camera
                    .as_ref()
                    .ok_or_else(|| file_error(&self.dir, format!("{CAMERA_FILE} is missing")))?;
                read_depth_png(path)?
                    .to_points(camera)
                    .map_err(|e| file_error(path, e))
            }
        }
    }

    /// The skeleton in `skeleton.json`, if there is one.
    pub fn skeleton(&self) -> Result<Option<Skeleton>, BodyError> {
        let path = self.dir.join(SKELETON_FILE);
        path.exists().then(|| Skeleton::load(&path)).transpose()
    }

    /// The ground-truth poses in `ground_truth.csv`, if there is one.
    pub fn ground_truth(&self, skeleton: &Skeleton) -> Result<Option<Vec<Vec<f32>>>, BodyError> {
        let path = self.dir.join(GROUND_TRUTH_FILE);
        if !path.exists() {
            return Ok(None);
        }
        let rows = read_pose_csv(&path, skeleton.dofs())?;
        Ok(Some(rows))
    }
}

/// The largest magnitude a pose value may have: metres for the root's position, radians for
/// every angle. A value beyond it is a unit mistake or a corrupt file, not a pose.
pub const MAX_POSE_MAGNITUDE: f32 = 1000.0;

/// Reads pose rows (`frame` then `dofs` values, a header line first), refusing values beyond
/// [`MAX_POSE_MAGNITUDE`] with the line they are on.
pub fn read_pose_csv(path: &Path, dofs: usize) -> Result<Vec<Vec<f32>>, BodyError> {
    let rows = read_numeric_csv(path, dofs + 1)?;
    for (n, row) in rows.iter().enumerate() {
        if let Some(v) = row[1..].iter().find(|v| v.abs() > MAX_POSE_MAGNITUDE) {
            return Err(file_error(
                path,
                format!(
                    "row {}: pose value {v:e} is beyond ±{MAX_POSE_MAGNITUDE} (metres for the root's position, radians for angles)",
                    n + 1
                ),
            ));
        }
    }
    Ok(rows.into_iter().map(|r| r[1..].to_vec()).collect())
}

/// Reads a CSV with a header line and `columns` numbers per row.
pub fn read_numeric_csv(path: &Path, columns: usize) -> Result<Vec<Vec<f32>>, BodyError> {
    let text = std::fs::read_to_string(path).map_err(|e| file_error(path, e))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let header = lines
        .next()
        .ok_or_else(|| file_error(path, "the file is empty"))?;
    let header_columns = header.1.split(',').count();
    if header_columns != columns {
        return Err(file_error(
            path,
            format!("the header has {header_columns} columns; expected {columns}"),
        ));
    }
    lines
        .map(|(n, line)| {
            let values: Vec<f32> = line
                .split(',')
                .map(|v| v.trim().parse::<f32>())
                .collect::<Result<_, _>>()
                .map_err(|e| file_error(path, format!("line {}: {e}", n + 1)))?;
            if values.len() != columns {
                return Err(file_error(
                    path,
                    format!(
                        "line {} has {} values; expected {columns}",
                        n + 1,
                        values.len()
                    ),
                ));
            }
            if let Some(v) = values.iter().find(|v| !v.is_finite()) {
                return Err(file_error(path, format!("line {}: value {v}", n + 1)));
            }
            Ok(values)
        })
        .collect()
}

/// Writes a CSV: `header`, then one row per entry of `rows`, each led by its index.
pub fn write_csv(path: &Path, header: &[String], rows: &[Vec<f32>]) -> Result<(), BodyError> {
    use std::fmt::Write;
    let mut text = String::from("frame");
    for h in header {
        text.push(',');
        text.push_str(h);
    }
    text.push('\n');
    for (i, row) in rows.iter().enumerate() {
        let _ = write!(text, "{i}");
        for v in row {
            let _ = write!(text, ",{v}");
        }
        text.push('\n');
    }
    std::fs::write(path, text).map_err(|e| file_error(path, e))
}

/// CSV column names for the joint positions: `{bone}_x, _y, _z` for every tracked joint.
pub fn joint_columns(skeleton: &Skeleton) -> Vec<String> {
    skeleton
        .joint_bones()
        .into_iter()
        .flat_map(|i| {
            let name = &skeleton.bones()[i].name;
            ["x", "y", "z"].map(|a| format!("{name}_{a}"))
        })
        .collect()
}

/// Flattens joint positions for a CSV row.
pub fn joint_row(joints: &[Vector3<f32>]) -> Vec<f32> {
    joints.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
}

/// Renders a synthetic sequence into `dir`: frames (PLY or depth PNG), `camera.json`,
/// `skeleton.json`, `ground_truth.csv` and `ground_truth_joints.csv`. Calls `progress` after
/// each frame.
pub fn write_synthetic(
    dir: &Path,
    skeleton: &Skeleton,
    config: &SynthConfig,
    format: FrameFormat,
    mut progress: impl FnMut(usize),
) -> Result<(), BodyError> {
    config.validate()?;
    std::fs::create_dir_all(dir).map_err(|e| file_error(dir, e))?;
    config.camera.save(&dir.join(CAMERA_FILE))?;
    skeleton.save(&dir.join(SKELETON_FILE))?;
    let mut poses = Vec::with_capacity(config.frames);
    let mut joints = Vec::with_capacity(config.frames);
    for frame in 0..config.frames {
        let theta = pose_at(skeleton, config, frame)?;
        let rendered = render(skeleton, &theta, config, frame)?;
        match format {
            FrameFormat::Ply => {
                write_ply_binary(&dir.join(format!("frame_{frame:05}.ply")), &rendered.points)?
            }
            FrameFormat::DepthPng => {
                write_depth_png(&dir.join(format!("depth_{frame:05}.png")), &rendered.depth)?
            }
        }
        joints.push(joint_row(&skeleton.tracked_joint_positions(&theta)?));
        poses.push(theta);
        progress(frame);
    }
    write_csv(&dir.join(GROUND_TRUTH_FILE), &skeleton.pose_names(), &poses)?;
    write_csv(
        &dir.join(GROUND_TRUTH_JOINTS_FILE),
        &joint_columns(skeleton),
        &joints,
    )
}
