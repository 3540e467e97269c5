//! A body run's written results: `BodyFiles` (poses.csv, joints.csv, errors.csv), a frame at a
//! time in all of them.

use crate::run_output::{CsvStream, ResumePoint};
use body_tracker::Skeleton;
use body_tracker::sequence::joint_columns;
use std::path::Path;

use super::{ERRORS_FILE, JOINTS_FILE, POSES_FILE};

/// poses.csv, joints.csv and (with ground truth) errors.csv, written a frame at a time.
pub(super) struct BodyFiles {
    pub(super) poses: CsvStream,
    pub(super) joints: CsvStream,
    pub(super) errors: Option<CsvStream>,
}

impl BodyFiles {
    /// The pose, its spread per value (`sd_` + the value's name), the ESS, the frame's log
    /// evidence and the confidence
    /// (docs/OUTPUT.md).
    pub(super) fn poses_header(skeleton: &Skeleton) -> String {
        let names = skeleton.pose_names();
        let spreads: Vec<String> = names.iter().map(|n| format!("sd_{n}")).collect();
        format!(
            "frame,{},{},ess,log_evidence,confidence",
            names.join(","),
            spreads.join(",")
        )
    }

    /// The files, new or (`resume`) an interrupted run's reopened at its resume point.
    pub(super) fn create(
        out: &Path,
        skeleton: &Skeleton,
        with_truth: bool,
        resume: Option<&ResumePoint>,
    ) -> anyhow::Result<Self> {
        let open = |name: &str, header: &str| match resume {
            Some(point) => CsvStream::resume(&out.join(name), header, point),
            None => CsvStream::create(&out.join(name), header),
        };
        let joints_header = format!("frame,{}", joint_columns(skeleton).join(","));
        Ok(Self {
            poses: open(POSES_FILE, &Self::poses_header(skeleton))?,
            joints: open(JOINTS_FILE, &joints_header)?,
            errors: with_truth
                .then(|| open(ERRORS_FILE, "frame,mean_joint_error_m"))
                .transpose()?,
        })
    }
}

pub(super) fn csv_row(frame: usize, values: &[f32]) -> String {
    let mut row = frame.to_string();
    for v in values {
        row.push(',');
        row.push_str(&v.to_string());
    }
    row
}
