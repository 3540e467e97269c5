"""streampf: GPU particle filtering (Condensation) for visual tracking.

The classes take and return numpy arrays:

- ``FaceTracker``: faces in ``uint8`` frames (H×W gray or H×W×3 colour), from rectangles you
  give and/or from the Viola–Jones detector; per-face 7-D poses with their spread, ESS and
  confidence out.
- ``BodyTracker``: an articulated body in N×3 ``float32`` points or 16-bit depth images.
- ``ParticleFilter``: the generic engine with your model as WGSL (the whole step on the GPU) or
  as a vectorised Python likelihood (CPU).
- ``track_video``: the command line's ``face track`` on a video file, results as arrays (or a
  pandas DataFrame); ``run_command``: any ``streampf`` command line in this process.
- ``devices()``: the GPU adapters; ``synthetic_faces`` / ``synthetic_body``: test sequences
  with their ground truth.

Bad arrays raise ``ValueError``; GPU failures ``RuntimeError``; every tracking call releases
the GIL, so trackers in different threads run at once.
"""

import os as _os

# Mesa's device-selection layer prints a warning on headless machines and selects nothing wgpu
# does not choose itself; the command line turns it off the same way.
_os.environ.setdefault("NODEVICE_SELECT", "1")

from ._streampf import (  # noqa: E402
    BodyTracker,
    FaceTracker,
    ParticleFilter,
    __version__,
    devices,
    mot_scores,
    run_command,
    synthetic_body,
    synthetic_faces,
)
from ._video import read_csv, track_video  # noqa: E402

STATE_NAMES = ("tx", "ty", "scale", "rx", "ry", "rz", "alpha")
"""The face state's columns: centre (pixels), scale, rotation (radians; R = Rx·Ry·Rz, rx pitch,
ry yaw, rz roll) and the template's contrast gain α."""

__all__ = [
    "BodyTracker",
    "FaceTracker",
    "ParticleFilter",
    "STATE_NAMES",
    "__version__",
    "devices",
    "mot_scores",
    "read_csv",
    "run_command",
    "synthetic_body",
    "synthetic_faces",
    "track_video",
]
