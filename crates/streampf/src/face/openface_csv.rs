//! `face track --format openface`: `openface.csv`, the columns of OpenFace 2.0's
//! `FeatureExtraction` (as `FaceLandmarkVidMulti` writes them, one row per face and frame) that
//! streampf measures, in OpenFace's units and conventions (`face_tracker::openface`), so that
//! scripts written for OpenFace's files read it unchanged. docs/OUTPUT.md lists the columns
//! side by side with `states.csv`'s.

use face_tracker::likelihood::Lens;
use face_tracker::openface::{OpenFaceCamera, millimetres_per_unit, openface_pose};
use face_tracker::{FaceEstimate, Template, TrackStatus};

use crate::run_output::CsvStream;

/// The file's name in --out.
pub(super) const OPENFACE_FILE: &str = "openface.csv";

/// The 68 landmarks' columns.
const LANDMARKS: usize = 68;

/// `openface.csv` as it is written, frame by frame.
pub(super) struct OpenFaceCsv {
    file: CsvStream,
    camera: OpenFaceCamera,
}

impl OpenFaceCsv {
    /// OpenFace's header: its names, separated by ", " as OpenFace writes them.
    pub(super) fn header() -> String {
        let mut names: Vec<String> = ["frame", "face_id", "timestamp", "confidence", "success"]
            .iter()
            .chain(&[
                "pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz",
            ])
            .map(|n| n.to_string())
            .collect();
        names.extend((0..LANDMARKS).map(|k| format!("x_{k}")));
        names.extend((0..LANDMARKS).map(|k| format!("y_{k}")));
        names.join(", ")
    }

    /// The file for a run of `width × height` frames seen through `lens`.
    pub(super) fn new(file: CsvStream, lens: &Lens, (width, height): (u32, u32)) -> Self {
        Self {
            file,
            camera: OpenFaceCamera::of(lens, width, height),
        }
    }

    /// A frame's rows: one per estimate (OpenFace's frames count from 1), the pose and the
    /// landmarks of each tracked face whose template has landmarks; a lost face, or one without
    /// landmarks, reads success 0 and zeros, as OpenFace writes a face it failed on.
    pub(super) fn add(
        &mut self,
        frame: usize,
        seconds: f64,
        templates: &[(usize, &Template)],
        estimates: &[FaceEstimate],
        lens: &Lens,
    ) -> anyhow::Result<()> {
        for e in estimates {
            let landmarks = templates
                .iter()
                .find(|(track, _)| *track == e.track)
                .and_then(|(_, t)| t.landmarks.as_deref());
            let measured = match (e.status, landmarks) {
                (TrackStatus::Tracking, Some(landmarks)) => self.measured(e, landmarks, lens),
                _ => None,
            };
            let (success, values) = match measured {
                Some(values) => (1, values),
                None => (0, vec!["0".to_string(); 6 + 2 * LANDMARKS]),
            };
            self.file.row(&format!(
                "{}, {}, {seconds:.3}, {:.3}, {success}, {}",
                frame + 1,
                e.track,
                e.confidence,
                values.join(", ")
            ))?;
        }
        self.file.end_frame()
    }

    /// The pose and landmark columns of a tracked face, `None` where they cannot be placed (a
    /// template whose eye corners coincide, a landmark at or behind the camera).
    fn measured(
        &self,
        e: &FaceEstimate,
        landmarks: &[[f32; 3]],
        lens: &Lens,
    ) -> Option<Vec<String>> {
        let pose = openface_pose(&e.state, millimetres_per_unit(landmarks)?, &self.camera)?;
        let posed = face_tracker::Pose::new(&e.state);
        let pixels = landmarks
            .iter()
            .map(|&p| posed.project_through(&nalgebra::Vector3::from(p), lens))
            .collect::<Option<Vec<_>>>()?;
        let mut values: Vec<String> = pose
            .translation_mm
            .iter()
            .chain(&pose.rotation)
            .map(|v| format!("{v:.6}"))
            .collect();
        values.extend(pixels.iter().map(|p| format!("{:.3}", p.x)));
        values.extend(pixels.iter().map(|p| format!("{:.3}", p.y)));
        Some(values)
    }
}
