"""FaceTracker on synthetic frames: accuracy against the ground truth (the Rust tests' bounds),
colour frames, threads, and the arrays it refuses."""

import threading

import numpy as np
import pytest

import streampf

# The bounds of tests/face_tracking.rs (mean over the video and the faces).
MAX_TRANSLATION_PX = 3.0
MAX_ROTATION_DEG = 4.5


def rotation_error_deg(estimate, truth):
    """The angle of R_estimate^T R_truth in degrees (both R = Rx·Ry·Rz)."""

    def rotation(rx, ry, rz):
        cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
        x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
        y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        return x @ y @ z

    r = rotation(*estimate[3:6]).T @ rotation(*truth[3:6])
    return np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def track(video, frames=None, **options):
    """States per frame (F, K, 7) of a tracker started on the video's rectangles (with the
    generic head, the synthetic video's, unless ``face_model`` says otherwise)."""
    options.setdefault("face_model", "generic")
    frames = video["frames"] if frames is None else frames
    height, width = video["frames"].shape[1:3]
    tracker = streampf.FaceTracker(width, height, max_faces=len(video["rects"]), **options)
    for rect in video["rects"]:
        tracker.add_face(frames[0], tuple(float(v) for v in rect))
    states = []
    for frame in frames:
        result = tracker.step(frame)
        assert not result["lost"].any()
        assert list(result["track"]) == list(range(len(video["rects"])))
        states.append(result["state"])
    return np.stack(states), result


def check_accuracy(video, states):
    truth = video["truth"]
    translation = np.linalg.norm(states[..., :2] - truth[..., :2], axis=-1).mean()
    rotation = np.mean(
        [rotation_error_deg(e, t) for e, t in zip(states.reshape(-1, 7), truth.reshape(-1, 7))]
    )
    assert translation <= MAX_TRANSLATION_PX, translation
    assert rotation <= MAX_ROTATION_DEG, rotation


def test_tracks_two_faces_on_the_cpu(two_face_video):
    states, last = track(two_face_video, particles=256, backend="cpu")
    check_accuracy(two_face_video, states)
    # Every output has one row per track, finite, in its documented range.
    assert last["spread"].shape == (2, 7) and np.all(last["spread"] >= 0)
    assert np.all((last["confidence"] >= 0) & (last["confidence"] <= 1))
    assert np.all((last["ess"] >= 1) & (last["ess"] <= 256 + 1e-3))
    np.testing.assert_allclose(np.linalg.norm(last["quaternion"], axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(last["pitch_yaw_roll_deg"], np.degrees(last["state"][:, 3:6]), rtol=1e-5)


def test_tracks_two_faces_on_the_gpu(two_face_video, gpu_backend):
    states, _ = track(two_face_video, particles=256, **gpu_backend)
    check_accuracy(two_face_video, states)


def test_colour_frames_are_tracked_as_their_bt601_luma(two_face_video):
    gray = two_face_video["frames"][:4]
    # A tinted colour video, against its BT.601 luma computed here.
    rgb = np.stack([gray, gray, gray], axis=-1).astype(np.int32)
    rgb[..., 0] = np.clip(rgb[..., 0] + 20, 0, 255)
    rgb[..., 2] = np.clip(rgb[..., 2] - 20, 0, 255)
    rgb = rgb.astype(np.uint8)
    r, g, b = (rgb[..., c].astype(np.int64) for c in range(3))
    luma = ((299 * r + 587 * g + 114 * b + 500) // 1000).astype(np.uint8)
    assert not np.array_equal(luma, gray)
    video = dict(two_face_video)
    from_rgb, _ = track(video, frames=rgb, particles=64, backend="cpu")
    from_luma, _ = track(video, frames=luma, particles=64, backend="cpu")
    np.testing.assert_array_equal(from_rgb, from_luma)
    bgr = np.ascontiguousarray(rgb[..., ::-1])
    from_bgr, _ = track(video, frames=bgr, particles=64, backend="cpu", channel_order="bgr")
    np.testing.assert_array_equal(from_bgr, from_luma)


def test_two_threads_at_once_give_what_one_after_the_other_gives(two_face_video):
    frames = two_face_video["frames"][:6]
    alone = [track(two_face_video, frames=frames, particles=128, backend="cpu", seed=s)[0] for s in (1, 2)]
    results = [None, None]

    def run(i):
        results[i] = track(two_face_video, frames=frames, particles=128, backend="cpu", seed=i + 1)[0]

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for together, one in zip(results, alone):
        np.testing.assert_array_equal(together, one)


@pytest.mark.parametrize(
    "bad, message",
    [
        (lambda f: f.astype(np.float32), "dtype uint8"),
        (lambda f: f[:, :-1].copy(), "shape"),
        (lambda f: np.stack([f, f], axis=-1), "shape"),
        (lambda f: np.asfortranarray(f), "C-contiguous"),
        (lambda f: f.tolist(), "numpy array"),
    ],
)
def test_bad_frames_are_value_errors_and_change_nothing(two_face_video, bad, message):
    frames = two_face_video["frames"][:3]
    expected, _ = track(two_face_video, frames=frames, particles=64, backend="cpu")
    tracker = streampf.FaceTracker(
        320, 240, max_faces=2, particles=64, backend="cpu", face_model="generic"
    )
    for rect in two_face_video["rects"]:
        tracker.add_face(frames[0], tuple(float(v) for v in rect))
    states = []
    for frame in frames:
        with pytest.raises(ValueError, match=message):
            tracker.step(bad(frame))
        states.append(tracker.step(frame)["state"])
    assert tracker.frames == 3
    np.testing.assert_array_equal(np.stack(states), expected)


def test_a_close_camera_is_tracked_through_its_lens():
    # Two faces through an 80° lens: through it, the bounds of the weak-perspective video; the
    # paper's weak perspective reads the turns wrongly (tests/face_perspective.rs measures both).
    video = streampf.synthetic_faces(16, width=320, height=240, faces=2, half_width=30.0, max_yaw_deg=40.0, fov=80.0)
    states, _ = track(video, particles=256, backend="cpu", fov=80.0)
    check_accuracy(video, states)
    weak, _ = track(video, particles=256, backend="cpu")
    rotation = lambda s: np.mean(
        [rotation_error_deg(e, t) for e, t in zip(s.reshape(-1, 7), video["truth"].reshape(-1, 7))]
    )
    assert rotation(weak) > rotation(states), (rotation(weak), rotation(states))
    with pytest.raises(ValueError, match="field of view"):
        streampf.FaceTracker(320, 240, fov=0.0)
    with pytest.raises(ValueError, match="field of view"):
        streampf.synthetic_faces(2, fov=180.0)


def test_a_calibrated_camera_is_the_same_pinhole_as_its_field_of_view(tmp_path):
    # 80° across 320 pixels: fx = fy = 160 / tan(40°), the principal point the frame's middle.
    video = streampf.synthetic_faces(6, width=320, height=240, faces=1, half_width=30.0, fov=80.0)
    focal = float(np.float32(160.0 / np.tan(np.radians(40.0))))
    by_fov, _ = track(video, particles=64, backend="cpu", fov=80.0)
    by_camera, _ = track(video, particles=64, backend="cpu", camera=(focal, focal, 159.5, 119.5))
    np.testing.assert_allclose(by_camera, by_fov, atol=1e-3)
    # The same camera as OpenCV's FileStorage writes it, calibrated at twice the size.
    calibration = tmp_path / "camera.json"
    calibration.write_text(
        '{"image_width": 640, "image_height": 480, "camera_matrix": {"type_id": "opencv-matrix", '
        f'"rows": 3, "cols": 3, "dt": "d", "data": [{2 * focal!r}, 0, 319.5, 0, {2 * focal!r}, 239.5, 0, 0, 1]}}}}'
    )
    by_file, _ = track(video, particles=64, backend="cpu", camera=str(calibration))
    np.testing.assert_allclose(by_file, by_fov, atol=1e-3)
    with pytest.raises(ValueError, match="not both"):
        streampf.FaceTracker(320, 240, fov=60.0, camera=(300.0, 300.0, 160.0, 120.0))
    with pytest.raises(ValueError, match="square pixels"):
        streampf.FaceTracker(320, 240, camera=(300.0, 600.0, 160.0, 120.0))
    with pytest.raises(ValueError, match=r"\(fx, fy, cx, cy\)"):
        streampf.FaceTracker(320, 240, camera=(300.0, 300.0))
    with pytest.raises(ValueError, match="no-such-file"):
        streampf.FaceTracker(320, 240, camera=str(tmp_path / "no-such-file.yml"))


def test_the_face_model_is_chosen_by_the_command_lines_rule(two_face_video):
    # Frames from arrays are real frames: the photographed head, as `face track` picks for a
    # video; the generic head (the synthetic video's) when asked for.
    assert streampf.FaceTracker(320, 240, backend="cpu").face_model == "photographed"
    generic = streampf.FaceTracker(320, 240, backend="cpu", face_model="generic")
    assert generic.face_model == "generic"
    photographed = streampf.FaceTracker(320, 240, backend="cpu", face_model="photographed")
    assert photographed.face_model == "photographed"
    # The two heads give the points different depths: different estimates on the same frames.
    frames = two_face_video["frames"][:4]
    a, _ = track(two_face_video, frames=frames, particles=64, backend="cpu")
    b, _ = track(two_face_video, frames=frames, particles=64, backend="cpu", face_model="auto")
    assert not np.array_equal(a, b)
    with pytest.raises(ValueError, match="face_model.*auto, generic, photographed"):
        streampf.FaceTracker(320, 240, face_model="mesh")


def test_bad_settings_and_rectangles_are_value_errors(two_face_video):
    frame = two_face_video["frames"][0]
    with pytest.raises(ValueError, match="backend"):
        streampf.FaceTracker(320, 240, backend="tpu")
    with pytest.raises(ValueError, match="particles"):
        streampf.FaceTracker(320, 240, particles=0)
    # Negative and huge counts: a ValueError naming the argument, not PyO3's OverflowError.
    for name, bad in [("particles", -5), ("max_faces", -1), ("seed", -1)]:
        with pytest.raises(ValueError, match=f"{name} must be a whole number >= 0, got {bad}"):
            streampf.FaceTracker(320, 240, **{name: bad})
    with pytest.raises(ValueError, match="width is too large"):
        streampf.FaceTracker(2**40, 240)
    with pytest.raises(ValueError, match="frames must be a whole number >= 0"):
        streampf.synthetic_faces(-3)
    with pytest.raises(ValueError, match="channel_order"):
        streampf.FaceTracker(320, 240, channel_order="yuv")
    tracker = streampf.FaceTracker(320, 240, max_faces=1, particles=64, backend="cpu")
    with pytest.raises(ValueError, match="rectangle"):
        tracker.add_face(frame, (10.0, 10.0, float("nan"), 40.0))
    with pytest.raises(ValueError):
        tracker.add_face(frame, (300.0, 200.0, 100.0, 100.0))  # outside the frame
    with pytest.raises(FileNotFoundError, match="cascade"):
        streampf.FaceTracker(320, 240, detect=True, cascade="/nonexistent/cascade.xml")


def test_particles_come_back_per_slot(two_face_video):
    tracker = streampf.FaceTracker(320, 240, max_faces=2, particles=50, backend="cpu")
    frame = two_face_video["frames"][0]
    for rect in two_face_video["rects"]:
        tracker.add_face(frame, tuple(float(v) for v in rect))
    result = tracker.step(frame)
    states, log_weights = tracker.particles()
    assert states.shape == (2, 50, 7) and log_weights.shape == (2, 50)
    np.testing.assert_allclose(np.exp(log_weights).sum(axis=1), 1, rtol=1e-4)
    # The estimate lies within the cloud.
    for slot in result["slot"]:
        assert states[slot, :, 0].min() <= result["state"][slot, 0] <= states[slot, :, 0].max()


def test_smoothing_gives_every_tracked_face_frame_with_an_interval(two_face_video):
    video = two_face_video
    frames = video["frames"][:10]
    height, width = frames.shape[1:3]
    tracker = streampf.FaceTracker(
        width, height, max_faces=2, particles=300, backend="cpu", face_model="generic", smooth=True
    )
    for rect in video["rects"]:
        tracker.add_face(frames[0], tuple(float(v) for v in rect))
    assert tracker.smoothed()["mean"].shape == (0, 7)
    states = [tracker.step(frame)["state"] for frame in frames]
    s = tracker.smoothed()
    assert list(s["frame"]) == [f for f in range(10) for _ in range(2)]
    assert list(s["track"]) == [0, 1] * 10
    assert s["mean"].shape == s["lower"].shape == s["upper"].shape == (20, 7)
    # An angle's ends are offsets about its circular mean: every interval holds its mean.
    assert np.all(s["lower"] <= s["mean"]) and np.all(s["mean"] <= s["upper"])
    # The smoothed centres stay near the filtered ones (a few pixels, not a different face).
    filtered = np.stack(states).reshape(-1, 7)
    assert np.abs(s["mean"][:, :2] - filtered[:, :2]).max() < 10.0
    # Smoothing reads the state so far and leaves the tracker as it was: it tracks on.
    assert tracker.step(video["frames"][10])["state"].shape == (2, 7)
    assert tracker.smoothed()["mean"].shape == (22, 7)
    with pytest.raises(ValueError, match="smooth=True"):
        streampf.FaceTracker(width, height, backend="cpu").smoothed()


def smoothed_two_faces(video, motion, count=8):
    """Two faces of ``video`` tracked over its first ``count`` frames and smoothed whole with
    ``motion``: the smoothed rows and the filtered states, (2 count, 7)."""
    frames = video["frames"][:count]
    height, width = frames.shape[1:3]
    tracker = streampf.FaceTracker(
        width, height, max_faces=2, particles=300, backend="cpu", face_model="generic",
        smooth=True, smooth_motion=motion,
    )
    for rect in video["rects"]:
        tracker.add_face(frames[0], tuple(float(v) for v in rect))
    states = [tracker.step(frame)["state"] for frame in frames]
    return tracker.smoothed(), np.stack(states).reshape(-1, 7)


def test_the_evidence_chooses_the_smoothing_motion(two_face_video):
    (own, _), (auto, filtered) = [smoothed_two_faces(two_face_video, m) for m in (None, "auto")]
    assert np.array_equal(own["frame"], auto["frame"])
    assert np.array_equal(own["track"], auto["track"])
    # The chosen motion's means, each inside its interval, and that interval takes in the
    # tracker's motion's (the evidence cannot see errors that persist from frame to frame).
    assert np.all(auto["lower"] <= auto["mean"]) and np.all(auto["mean"] <= auto["upper"])
    # (Up to a twentieth of its width: the two smoothers' weights differ by the Gauss
    # transform's rounding, which can move a quantile by a particle.)
    slack = 0.05 * (own["upper"] - own["lower"])
    assert np.all(auto["lower"] <= own["lower"] + slack)
    assert np.all(auto["upper"] >= own["upper"] - slack)
    # Near the filtered faces, not a different face.
    assert np.abs(auto["mean"][:, :2] - filtered[:, :2]).max() < 10.0


def test_a_slower_smoothing_motion_narrows_the_intervals(two_face_video):
    video = two_face_video
    height, width = video["frames"].shape[1:3]
    own, slow = [smoothed_two_faces(video, m)[0] for m in (1.0, 0.25)]
    assert np.array_equal(own["frame"], slow["frame"])
    # A track's last frame is its filtered cloud whatever the motion.
    last = own["frame"] == 7
    assert last.any() and not last.all()
    assert np.array_equal(own["mean"][last], slow["mean"][last])
    width_of = lambda s: float(np.sum((s["upper"] - s["lower"])[~last]))
    assert width_of(slow) < width_of(own)
    for bad in [0.0, -1.0, 1e-50, 1e9, float("nan"), float("inf")]:
        with pytest.raises(ValueError, match="smooth_motion"):
            streampf.FaceTracker(width, height, backend="cpu", smooth=True, smooth_motion=bad)
    for bad in ["fast", "", "0.0"]:
        with pytest.raises(ValueError, match="smooth_motion"):
            streampf.FaceTracker(width, height, backend="cpu", smooth=True, smooth_motion=bad)
    with pytest.raises(TypeError, match="smooth_motion"):
        streampf.FaceTracker(width, height, backend="cpu", smooth=True, smooth_motion=[1.0])
    # Nothing to scale without a smoother.
    with pytest.raises(ValueError, match="smooth=True"):
        streampf.FaceTracker(width, height, backend="cpu", smooth_motion=0.5)
    with pytest.raises(ValueError, match="smooth=True"):
        streampf.FaceTracker(width, height, backend="cpu", smooth_motion="auto")
    with pytest.raises(ValueError, match="smooth=True"):
        streampf.BodyTracker(backend="cpu", smooth_motion=0.5)


def test_a_lag_smooths_each_face_frame_as_frames_come(two_face_video):
    """``smooth_lag=3``: step k returns frame k - 3 of both tracks smoothed, and ``smoothed()``
    every frame so far: the rows the steps returned, then the last three smoothed by what
    follows them. The evidence's motion works with a lag too; bad lags are clear errors."""
    video = two_face_video
    frames = video["frames"][:10]
    height, width = frames.shape[1:3]
    lag = 3
    for motion in (None, "auto"):
        tracker = streampf.FaceTracker(
            width, height, max_faces=2, particles=300, backend="cpu", face_model="generic",
            smooth_lag=lag, smooth_motion=motion,
        )
        for rect in video["rects"]:
            tracker.add_face(frames[0], tuple(float(v) for v in rect))
        due, states = [], []
        for k, frame in enumerate(frames):
            out = tracker.step(frame)
            states.append(out["state"])
            rows = out["smoothed"]
            expected = [k - lag] * 2 if k >= lag else []
            assert list(rows["frame"]) == expected and list(rows["track"]) == [0, 1][: len(expected)]
            assert rows["mean"].shape == (len(expected), 7)
            assert np.all(rows["lower"] <= rows["mean"]) and np.all(rows["mean"] <= rows["upper"])
            due.append(rows)
        s = tracker.smoothed()
        assert list(s["frame"]) == [f for f in range(10) for _ in range(2)]
        assert list(s["track"]) == [0, 1] * 10
        online = np.concatenate([rows["mean"] for rows in due])
        np.testing.assert_array_equal(s["mean"][: len(online)], online)
        if motion is None:
            # A track's last frame is smoothed by nothing after it, as whole-track smoothing
            # leaves it; the frames before moved by at most the lag's worth of later frames.
            whole, _ = smoothed_two_faces({**video, "frames": frames}, None, len(frames))
            np.testing.assert_array_equal(s["mean"][-2:], whole["mean"][-2:])
            assert not np.array_equal(s["mean"][:2], whole["mean"][:2])
        # Near the filtered faces, not a different face.
        filtered = np.stack(states).reshape(-1, 7)
        assert np.abs(s["mean"][:, :2] - filtered[:, :2]).max() < 10.0
    # Without a lag the step has no rows to give.
    plain = streampf.FaceTracker(width, height, backend="cpu", smooth=True)
    plain.add_face(frames[0], tuple(float(v) for v in video["rects"][0]))
    assert "smoothed" not in plain.step(frames[0])
    for bad in [0, -1, 1001]:
        with pytest.raises(ValueError, match="smooth_lag"):
            streampf.FaceTracker(width, height, backend="cpu", smooth_lag=bad)
    with pytest.raises(ValueError, match="choose one"):
        streampf.FaceTracker(width, height, backend="cpu", smooth=True, smooth_lag=3)


def test_small_faces_are_enlarged_by_default():
    """Heads 40 px wide (under the default 46): the default enlarges them (the same states as
    ``enlarge_below=46``), ``enlarge_below=0`` takes them at their own size (other templates,
    so other states), and a bad width is refused before anything runs."""
    video = streampf.synthetic_faces(20, width=320, height=240, faces=2, half_width=20.0)
    assert np.all(video["rects"][:, 2] < 46)
    default, _ = track(video, particles=128, backend="cpu")
    explicit, _ = track(video, particles=128, backend="cpu", enlarge_below=46)
    own_size, _ = track(video, particles=128, backend="cpu", enlarge_below=0)
    np.testing.assert_array_equal(default, explicit)
    assert not np.array_equal(default, own_size)
    translation = np.linalg.norm(default[..., :2] - video["truth"][..., :2], axis=-1).mean()
    assert translation <= MAX_TRANSLATION_PX, translation
    for bad in [-1.0, float("nan"), float("inf"), 1e300]:
        with pytest.raises(ValueError, match="enlarge_below"):
            streampf.FaceTracker(320, 240, enlarge_below=bad)
    for bad in [True, "wide"]:
        with pytest.raises(TypeError, match="enlarge_below"):
            streampf.FaceTracker(320, 240, enlarge_below=bad)
