"""Track the faces in every video of a directory over a Ray cluster: one task per video.

    python examples/python/track_corpus.py VIDEOS_DIR --out RESULTS_DIR [--address auto]

Each video ``NAME.EXT`` is tracked by ``streampf.track_video`` in a Ray task that asks for one GPU
when the cluster has GPUs (else it runs on the CPU cores of its node). Its results go to
``RESULTS_DIR/NAME/``: ``states.csv`` (the command line's columns, docs/OUTPUT.md) and
``states.npz`` (the same columns as numpy arrays). Faces start from the rectangles in
``NAME.faces.csv`` beside the video when there is one (``x,y,width,height`` per face, as
``face track``'s faces.csv), else the detector finds them. At the end ``RESULTS_DIR/summary.csv``
lists every video: status, frames, tracks, seconds, and the error of a video that failed (the
other videos' results are kept).

On one machine, Ray starts a local instance. On a cluster, start Ray on every node (``ray start
--head`` on one, ``ray start --address HEAD:6379`` on the others, each with streampf installed)
and pass ``--address auto`` from a node of the cluster: the videos' directory and the results'
must be on storage every node sees (a shared file system).
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import ray

import streampf

VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".webm", ".mov", ".mpg", ".m4v"}
SUMMARY_COLUMNS = ["video", "status", "frames", "tracks", "seconds", "error"]


def find_videos(directory: Path) -> List[Path]:
    """The directory's video files, in name order."""
    return sorted(p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)


def sidecar_rectangles(video: Path) -> Optional[List[tuple]]:
    """The rectangles of ``NAME.faces.csv`` beside the video (a header line is optional)."""
    sidecar = video.with_name(video.stem + ".faces.csv")
    if not sidecar.exists():
        return None
    rects = []
    for line in sidecar.read_text().splitlines():
        if not line.strip():
            continue
        try:
            rects.append(tuple(float(v) for v in line.split(",")))
        except ValueError:
            if rects:
                raise ValueError(f"{sidecar}: {line!r} is not x,y,width,height") from None
    return rects


@ray.remote
def track_one(video: str, out: str, options: Dict) -> Dict:
    """Tracks one video into ``out``; never raises, so one bad video does not lose the others."""
    start = time.perf_counter()
    row = {"video": Path(video).name, "status": "ok", "frames": 0, "tracks": 0, "seconds": 0.0, "error": ""}
    try:
        states = streampf.track_video(
            video, out, faces=sidecar_rectangles(Path(video)), progress=False, **options
        )
        np.savez_compressed(Path(out) / "states.npz", **states)
        row["frames"] = int(np.unique(states["frame"]).size) if states["frame"].size else 0
        tracked = states["track"][~np.isnan(states["track"])] if states["track"].size else states["track"]
        row["tracks"] = int(np.unique(tracked).size)
    except Exception as e:  # noqa: BLE001 - reported per video in the summary
        row["status"] = "failed"
        row["error"] = f"{type(e).__name__}: {e}"
    row["seconds"] = round(time.perf_counter() - start, 3)
    return row


def track_corpus(
    directory: Path,
    out: Path,
    *,
    gpus_per_task: Optional[float] = None,
    options: Optional[Dict] = None,
) -> List[Dict]:
    """Tracks every video of ``directory`` as Ray tasks (Ray must be initialised); writes
    ``out/summary.csv`` and returns its rows."""
    videos = find_videos(directory)
    if not videos:
        raise FileNotFoundError(f"no video files ({', '.join(sorted(VIDEO_SUFFIXES))}) in {directory}")
    out.mkdir(parents=True, exist_ok=True)
    if gpus_per_task is None:
        gpus_per_task = 1 if ray.cluster_resources().get("GPU", 0) >= 1 else 0
    task = track_one.options(num_gpus=gpus_per_task)
    pending = [task.remote(str(v), str(out / v.stem), dict(options or {})) for v in videos]
    rows = ray.get(pending)
    with open(out / "summary.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=SUMMARY_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return rows


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("videos", type=Path, help="a directory of video files")
    parser.add_argument("--out", type=Path, required=True, help="where each video's results and summary.csv go")
    parser.add_argument("--address", help="a running Ray cluster ('auto': the one this node belongs to); default: a local instance")
    parser.add_argument("--backend", default="auto", choices=["auto", "cpu", "gpu", "all-gpus"])
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--gpus-per-task", type=float, help="default: 1 when the cluster has GPUs, else 0")
    args = parser.parse_args(argv)
    ray.init(address=args.address, include_dashboard=False)
    rows = track_corpus(
        args.videos,
        args.out,
        gpus_per_task=args.gpus_per_task,
        options={"backend": args.backend, "particles": args.particles},
    )
    failed = [r for r in rows if r["status"] != "ok"]
    print(f"{len(rows) - len(failed)} of {len(rows)} videos tracked; summary in {args.out / 'summary.csv'}")
    for r in failed:
        print(f"  {r['video']}: {r['error']}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
