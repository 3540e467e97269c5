"""``track_video``: the command line's ``face track`` run in this process."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any, Dict, Iterable, Optional, Sequence, Tuple, Union

import numpy as np

from ._streampf import run_command

PathLike = Union[str, "os.PathLike[str]"]


def read_csv(path: PathLike) -> Dict[str, np.ndarray]:
    """A CSV file that streampf wrote, as one numpy array per column: numbers as float64 (an
    empty cell is NaN), text columns (a status) as str."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise ValueError(f"{path} is empty")
    header, body = rows[0], rows[1:]
    columns: Dict[str, np.ndarray] = {}
    for i, name in enumerate(header):
        cells = [row[i] if i < len(row) else "" for row in body]
        try:
            columns[name] = np.array([float(c) if c != "" else np.nan for c in cells], dtype=np.float64)
        except ValueError:
            columns[name] = np.array(cells, dtype=str)
    return columns


def track_video(
    path: PathLike,
    out: PathLike = "streampf-face-out",
    *,
    faces: Optional[Sequence[Tuple[float, float, float, float]]] = None,
    detect: Optional[bool] = None,
    overlay: Optional[PathLike] = None,
    backend: str = "auto",
    allow_software: bool = False,
    particles: int = 1000,
    max_faces: Optional[int] = None,
    max_frames: Optional[int] = None,
    seed: int = 1,
    progress: bool = True,
    extra_args: Iterable[str] = (),
    as_frame: bool = False,
) -> Union[Dict[str, np.ndarray], Any]:
    """Tracks the faces of a video file (or a directory of frames) as ``streampf face track``
    does, writing ``states.csv`` (and the overlay, when asked) under ``out``; returns
    ``states.csv`` as arrays (``read_csv``): one row per frame and track.

    ``faces``: rectangles (x, y, width, height) at the first frame; without them the detector
    finds the faces (``detect`` runs it as well when rectangles are given). ``overlay``: a
    directory (PNG frames) or a video file with the tracks drawn. ``progress`` shows the
    command line's progress bar. ``extra_args``: any other ``face track`` options, spelled as
    on the command line (``["--format", "openface"]`` also writes OpenFace 2.0's CSV columns to
    ``out/openface.csv``). ``as_frame``: ``states.csv`` as a pandas DataFrame instead (pandas is
    an optional extra, ``pip install streampf[pandas]``; checked before anything runs). Ctrl-C stops after the current frame, keeping what was written, and
    raises KeyboardInterrupt.
    """
    pandas = _pandas() if as_frame else None
    source = Path(path)
    if not source.exists():
        raise FileNotFoundError(f"no such video or frame directory: {source}")
    args = ["face", "track", str(source), "--out", str(out), "--backend", backend]
    args += ["--particles", str(particles), "--seed", str(seed)]
    for x, y, w, h in faces or ():
        args += ["--face", f"{x},{y},{w},{h}"]
    if detect:
        args.append("--detect")
    if overlay is not None:
        args += ["--overlay", str(overlay)]
    if allow_software:
        args.append("--allow-software")
    if max_faces is not None:
        args += ["--max-faces", str(max_faces)]
    if max_frames is not None:
        args += ["--max-frames", str(max_frames)]
    if not progress:
        args.append("--quiet")
    args += list(extra_args)
    run_command(args)
    if pandas is not None:
        return pandas.read_csv(Path(out) / "states.csv")
    return read_csv(Path(out) / "states.csv")


def _pandas() -> Any:
    """pandas, or an ImportError that says how to install it."""
    try:
        import pandas
    except ImportError as e:
        raise ImportError(
            "track_video(as_frame=True) needs pandas: pip install 'streampf[pandas]' (or pandas)"
        ) from e
    return pandas
