"""FaceTracker with the detector on a real video (OpenCV's Megamind.avi from Debian's
opencv-doc, installed by `cargo xtask fetch-media`), in colour as OpenCV decodes it (BGR)."""

from pathlib import Path

import numpy as np
import pytest

import streampf

MEGAMIND = Path("/usr/share/doc/opencv-doc/examples/data/Megamind.avi")
CASCADE = Path("/usr/share/opencv4/haarcascades/haarcascade_frontalface_alt2.xml")


def megamind_frames(count):
    assert MEGAMIND.exists() and CASCADE.exists(), "run `cargo xtask fetch-media` (opencv-doc, opencv-data)"
    try:
        import cv2  # decodes the video; installed by `cargo xtask fetch-media`
    except ImportError:
        pytest.fail("OpenCV's Python package is needed (cargo xtask fetch-media installs it)")
    capture = cv2.VideoCapture(str(MEGAMIND))
    frames = []
    while len(frames) < count:
        ok, frame = capture.read()
        assert ok, f"{MEGAMIND} ended after {len(frames)} frames"
        frames.append(frame)
    return frames


def test_the_detector_starts_tracks_on_a_real_video_in_bgr():
    frames = megamind_frames(40)
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
    # Each row says who the track is (no one was lost and found again: the track's number).
    assert np.array_equal(result["identity"], result["track"]), result
    assert tracked >= 20, tracked
    with pytest.raises(ValueError, match="shape"):
        tracker.step(np.ascontiguousarray(frames[0][:, :, :2]))


def test_the_detector_on_the_gpu_starts_the_same_tracks(gpu_backend):
    """The tracker on the CPU, its detector on the CPU or on the GPU: the same faces found at
    the same frames, so the same estimates."""
    frames = megamind_frames(24)
    height, width = frames[0].shape[:2]
    runs = {}
    for detector in ["cpu", "gpu"]:
        tracker = streampf.FaceTracker(
            width, height, detect=True, particles=100, backend="cpu", detector=detector,
            allow_software=gpu_backend["allow_software"], channel_order="bgr",
        )
        steps = [tracker.step(frame) for frame in frames]
        runs[detector] = (
            [sorted(int(t) for t in s["started"]) for s in steps],
            np.concatenate([s["state"].ravel() for s in steps]),
        )
    assert any(runs["cpu"][0]), "the CPU detector started no track"
    assert runs["gpu"][0] == runs["cpu"][0]
    np.testing.assert_array_equal(runs["gpu"][1], runs["cpu"][1])
    with pytest.raises(ValueError, match="detector must be"):
        streampf.FaceTracker(width, height, detect=True, detector="tpu")


def test_a_scene_cut_ends_the_tracks_the_detector_does_not_find_again():
    """Megamind.avi cuts from its first shot to another at frame 98: the first shot's tracks end
    there (``lost``) with the default ``scene_cut``; with ``scene_cut=None`` one goes on."""
    frames = megamind_frames(110)[85:]  # the first shot's last frames and the cut
    height, width = frames[0].shape[:2]

    def running_after_the_cut(scene_cut):
        tracker = streampf.FaceTracker(
            width, height, detect=True, particles=200, backend="cpu", channel_order="bgr",
            scene_cut=scene_cut,
        )
        tracks_before = set()
        for index, frame in enumerate(frames):
            result = tracker.step(frame)
            running = {int(t) for t, lost in zip(result["track"], result["lost"]) if not lost}
            if index + 85 == 97:
                tracks_before = running
        return tracks_before, running

    before, after = running_after_the_cut(0.25)
    assert before, "no face tracked before the cut"
    assert not before & after, (before, after)
    before, after = running_after_the_cut(None)
    assert before & after, (before, after)
    for detect in [True, False]:
        with pytest.raises(ValueError, match="scene_cut"):
            streampf.FaceTracker(width, height, detect=detect, backend="cpu", scene_cut=2.5)
