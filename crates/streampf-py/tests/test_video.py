"""track_video: the command line's `face track` in this process, against the binary itself."""

import subprocess

import numpy as np
import pytest

import streampf
from conftest import rect_args, write_video


@pytest.fixture(scope="module")
def video(tmp_path_factory, two_face_video):
    path = tmp_path_factory.mktemp("video") / "two_faces.mp4"
    write_video(path, two_face_video["frames"][:8])
    return path


def test_track_video_writes_what_the_command_line_writes(video, two_face_video, tmp_path, streampf_cli):
    rects = [tuple(float(v) for v in r) for r in two_face_video["rects"]]
    overlay = tmp_path / "overlay"
    states = streampf.track_video(
        video, tmp_path / "py", faces=rects, backend="cpu", particles=64, overlay=overlay, progress=False
    )
    subprocess.run(
        [streampf_cli, "face", "track", str(video), "--out", str(tmp_path / "cli"), "--backend", "cpu",
         "--particles", "64", "--seed", "1", "--quiet", *rect_args(two_face_video["rects"])],
        check=True,
    )
    assert (tmp_path / "py" / "states.csv").read_text() == (tmp_path / "cli" / "states.csv").read_text()
    # One row per frame and face; the arrays are the file's columns.
    assert states["frame"].shape == (16,)
    assert set(np.unique(states["track"])) == {0.0, 1.0}
    assert (states["status"] == "tracking").all()
    assert len(list(overlay.glob("*.png"))) == 8


def test_as_frame_is_a_pandas_dataframe_of_states_csv(video, two_face_video, tmp_path):
    import pandas  # the test extra: installed for the suite (cargo xtask test), never skipped

    rects = [tuple(float(v) for v in r) for r in two_face_video["rects"]]
    frame = streampf.track_video(
        video, tmp_path / "df", faces=rects, backend="cpu", particles=64, progress=False, as_frame=True
    )
    assert isinstance(frame, pandas.DataFrame)
    arrays = streampf.read_csv(tmp_path / "df" / "states.csv")
    assert list(frame.columns) == list(arrays)
    assert len(frame) == 16
    np.testing.assert_array_equal(frame["tx"].to_numpy(), arrays["tx"])
    assert (frame["status"] == "tracking").all()
    # A query as py-feat's users write them: one face's mean yaw.
    yaw = frame.groupby("track")["yaw_deg"].mean()
    assert sorted(yaw.index) == [0, 1] and yaw.notna().all()


def test_a_bad_command_is_a_value_error_and_writes_nothing(video, tmp_path):
    out = tmp_path / "never"
    with pytest.raises(ValueError, match="--particles"):
        streampf.track_video(video, out, backend="cpu", particles=0, progress=False)
    with pytest.raises(ValueError, match="unexpected argument"):
        streampf.track_video(video, out, backend="cpu", extra_args=["--no-such-option"], progress=False)
    assert not out.exists()
    with pytest.raises(FileNotFoundError):
        streampf.track_video(tmp_path / "missing.mp4", out)
    assert not out.exists()


def test_a_failed_run_is_a_runtime_error_with_the_command_lines_message(tmp_path):
    not_a_video = tmp_path / "noise.mp4"
    not_a_video.write_bytes(b"\0" * 1000)
    with pytest.raises(RuntimeError, match="noise.mp4"):
        streampf.track_video(not_a_video, tmp_path / "out", backend="cpu", faces=[(1, 1, 40, 50)], progress=False)


def test_a_gpu_fault_is_a_runtime_error_and_keeps_the_frames_before_it(
    video, two_face_video, tmp_path, gpu_backend, monkeypatch
):
    # The command line's fault injection: the device is lost before frame 3.
    monkeypatch.setenv("STREAMPF_SIMULATE_GPU_FAULT_AT", "3")
    rects = [tuple(float(v) for v in r) for r in two_face_video["rects"]]
    with pytest.raises(RuntimeError, match="(?i)lost"):
        streampf.track_video(video, tmp_path / "out", faces=rects, particles=64, progress=False, **gpu_backend)
    states = streampf.read_csv(tmp_path / "out" / "states.csv")
    assert sorted(set(states["frame"])) == [0.0, 1.0, 2.0]
