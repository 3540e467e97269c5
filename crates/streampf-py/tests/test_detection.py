"""FaceTracker with the detector on a real video (OpenCV's Megamind.avi from Debian's
opencv-doc, installed by `cargo xtask fetch-media`), in colour as OpenCV decodes it (BGR)."""

from pathlib import Path

import numpy as np
import pytest

import streampf

MEGAMIND = Path("/usr/share/doc/opencv-doc/examples/data/Megamind.avi")
CASCADE = Path("/usr/share/opencv4/haarcascades/haarcascade_frontalface_alt2.xml")


def test_the_detector_starts_tracks_on_a_real_video_in_bgr():
    assert MEGAMIND.exists() and CASCADE.exists(), "run `cargo xtask fetch-media` (opencv-doc, opencv-data)"
    try:
        import cv2  # decodes the video; installed by `cargo xtask fetch-media`
    except ImportError:
        pytest.fail("OpenCV's Python package is needed (cargo xtask fetch-media installs it)")
    capture = cv2.VideoCapture(str(MEGAMIND))
    frames = []
    while len(frames) < 40:
        ok, frame = capture.read()
        assert ok, f"{MEGAMIND} ended after {len(frames)} frames"
        frames.append(frame)
    height, width = frames[0].shape[:2]
    tracker = streampf.FaceTracker(
        width, height, detect=True, particles=200, backend="cpu", channel_order="bgr"
    )
    started, tracked = set(), 0
    for frame in frames:
        result = tracker.step(frame)
        started.update(int(t) for t in result["started"])
        tracked += int((~result["lost"]).sum())
    # The face in the first shot is found (two detector runs confirm it) and followed.
    assert started, "no track was started"
    assert tracked >= 20, tracked
    with pytest.raises(ValueError, match="shape"):
        tracker.step(np.ascontiguousarray(frames[0][:, :, :2]))
