"""Shared fixtures. GPU tests ask for a GPU adapter and fail when there is none (unless
`cargo xtask test --no-gpu` set STREAMPF_ALLOW_NO_GPU=1, as for the Rust GPU tests): CI installs
Mesa's lavapipe, which they use with allow_software=True."""

import importlib.util
import os
from pathlib import Path

import pytest

import streampf

REPO = Path(__file__).resolve().parents[3]


def load_script(relative_path):
    """A script of the repository (a tool, an example) loaded as a module, by its path from the
    repository's root."""
    path = REPO / relative_path
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def gpu_backend():
    adapters = streampf.devices()
    if not adapters and os.environ.get("STREAMPF_ALLOW_NO_GPU") == "1":
        # `cargo xtask test --no-gpu`, as the Rust GPU tests: said, not silent.
        pytest.skip("no GPU adapter, and STREAMPF_ALLOW_NO_GPU=1 lets the GPU tests skip")
    assert adapters, (
        "no GPU adapter: the GPU tests need one (install Mesa's lavapipe: "
        "apt-get install mesa-vulkan-drivers libvulkan1)"
    )
    return dict(backend="gpu", allow_software=True)


@pytest.fixture(scope="session")
def streampf_cli():
    """The command-line binary the Python results are compared with (STREAMPF_BIN, or the
    workspace's debug or release build)."""
    candidates = [os.environ.get("STREAMPF_BIN")] if os.environ.get("STREAMPF_BIN") else []
    candidates += [REPO / "target" / "debug" / "streampf", REPO / "target" / "release" / "streampf"]
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return str(candidate)
    pytest.fail("the streampf binary is not built: run `cargo build -p streampf` (or set STREAMPF_BIN)")


@pytest.fixture(scope="session")
def two_face_video():
    """A short synthetic video of two faces at 320×240 with its ground truth."""
    return streampf.synthetic_faces(16, width=320, height=240, faces=2, half_width=30.0, max_yaw_deg=40.0)


def write_video(path: Path, frames) -> None:
    """Encodes gray frames (F, H, W) uint8 as a video file with FFmpeg (as the CLI's tests do)."""
    import shutil
    import subprocess

    ffmpeg = shutil.which("ffmpeg")
    assert ffmpeg, "FFmpeg is needed to write the test videos (apt-get install ffmpeg)"
    height, width = frames.shape[1:3]
    subprocess.run(
        [ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "gray", "-s", f"{width}x{height}",
         "-r", "25", "-i", "-", "-c:v", "libx264", "-qp", "0", "-pix_fmt", "yuv420p", str(path)],
        input=frames.tobytes(),
        check=True,
    )


def rect_args(rects):
    args = []
    for r in rects:
        args += ["--face", ",".join(str(float(v)) for v in r)]
    return args
