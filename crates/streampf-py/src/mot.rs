//! `streampf.mot_scores`: the MOT benchmarks' scores of any tracker's output against its ground
//! truth (`face_tracker::mot`, which `face track --synthetic --scenario` prints).

use std::collections::BTreeMap;

use face_tracker::mot::{MotFrame, TrackedFace, TrueFace, score};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::value_error;

/// IDF1, IDP, IDR, MOTA, identity switches and the counts behind them, from the true objects
/// `truth` — (frame, identity, x, y, radius) each: a track matches when within `radius` of the
/// centre — and the tracks' estimates `tracks` — (frame, track, x, y) each. A bad row (a
/// negative frame, a non-finite value, an identity or track twice in one frame) is a ValueError.
#[pyfunction]
pub fn mot_scores<'py>(
    py: Python<'py>,
    truth: Vec<(i64, i64, f64, f64, f64)>,
    tracks: Vec<(i64, i64, f64, f64)>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut frames: BTreeMap<u64, MotFrame> = BTreeMap::new();
    let whole = |what: &str, v: i64| {
        u64::try_from(v).map_err(|_| value_error(format!("{what} must be >= 0, got {v}")))
    };
    // Finite as the f32 the scorer holds (1e39 is finite in f64, not in f32).
    let finite = |what: &str, v: f64| match (v as f32).is_finite() {
        true => Ok(v as f32),
        false => Err(value_error(format!(
            "{what} must be finite (as an f32), got {v}"
        ))),
    };
    for (frame, identity, x, y, radius) in truth {
        let face = TrueFace {
            identity: whole("an identity", identity)?,
            centre: [finite("x", x)?, finite("y", y)?],
            radius: finite("a radius", radius)?,
        };
        let entry = frames.entry(whole("a frame", frame)?).or_default();
        if entry.truth.iter().any(|f| f.identity == face.identity) {
            return Err(value_error(format!(
                "identity {identity} twice in frame {frame}"
            )));
        }
        entry.truth.push(face);
    }
    for (frame, track, x, y) in tracks {
        let tracked = TrackedFace {
            track: whole("a track", track)?,
            centre: [finite("x", x)?, finite("y", y)?],
        };
        let entry = frames.entry(whole("a frame", frame)?).or_default();
        if entry.tracks.iter().any(|t| t.track == tracked.track) {
            return Err(value_error(format!("track {track} twice in frame {frame}")));
        }
        entry.tracks.push(tracked);
    }
    let frames: Vec<MotFrame> = frames.into_values().collect();
    let s = py.detach(|| score(&frames));
    let dict = PyDict::new(py);
    dict.set_item("idf1", s.idf1)?;
    dict.set_item("idp", s.idp)?;
    dict.set_item("idr", s.idr)?;
    dict.set_item("mota", s.mota)?;
    dict.set_item("num_switches", s.id_switches)?;
    // As py-motmetrics counts them: a match that switched identity is a switch, not a match.
    dict.set_item("num_matches", s.matches - s.id_switches)?;
    dict.set_item("num_misses", s.misses)?;
    dict.set_item("num_false_positives", s.false_positives)?;
    dict.set_item("num_objects", s.ground_truth)?;
    Ok(dict)
}
