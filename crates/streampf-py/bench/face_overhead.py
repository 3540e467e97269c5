"""The Python binding's overhead per frame: the face tracker driven from Python with numpy
frames against the same tracking through the Rust API alone (timed inside Rust), in the same
process on the same frames.

    python crates/streampf-py/bench/face_overhead.py [--frames 200] [--backend gpu] [--json OUT]

The synthetic four-face video at 1024×768 with 1000 particles per face (the paper's setting);
the first 20 frames of each run are warm-up. Prints and writes the medians and the overhead.
"""

import argparse
import json
import platform
import time

import numpy as np

import streampf
from streampf import _streampf

WARM_UP = 20


def python_step_times(video, backend, allow_software, particles):
    height, width = video["frames"].shape[1:]
    tracker = streampf.FaceTracker(
        width, height, max_faces=len(video["rects"]), particles=particles, backend=backend,
        allow_software=allow_software,
    )
    for rect in video["rects"]:
        tracker.add_face(video["frames"][0], tuple(float(v) for v in rect))
    times = []
    for frame in video["frames"]:
        start = time.perf_counter()
        tracker.step(frame)
        times.append(time.perf_counter() - start)
    return np.array(times), tracker.device


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--backend", default="auto")
    parser.add_argument("--allow-software", action="store_true")
    parser.add_argument("--rounds", type=int, default=3, help="alternating Python and Rust runs")
    parser.add_argument("--json")
    args = parser.parse_args()
    video = streampf.synthetic_faces(args.frames, width=1024, height=768, faces=4, half_width=60.0, max_yaw_deg=60.0, occlusion=True)
    rects = [tuple(float(v) for v in r) for r in video["rects"]]
    python_medians, rust_medians = [], []
    device = None
    for _ in range(args.rounds):
        times, device = python_step_times(video, args.backend, args.allow_software, args.particles)
        python_medians.append(float(np.median(times[WARM_UP:])))
        rust = _streampf._rust_face_step_times(
            video["frames"], rects, particles=args.particles, backend=args.backend, allow_software=args.allow_software
        )
        rust_medians.append(float(np.median(rust[WARM_UP:])))
    python_ms, rust_ms = 1e3 * min(python_medians), 1e3 * min(rust_medians)
    result = {
        "device": device,
        "host": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "faces": 4,
        "particles": args.particles,
        "frames": args.frames,
        "python_step_ms_median": python_ms,
        "rust_step_ms_median": rust_ms,
        "overhead_percent": 100.0 * (python_ms / rust_ms - 1.0),
        "python_medians_ms": [1e3 * m for m in python_medians],
        "rust_medians_ms": [1e3 * m for m in rust_medians],
    }
    print(json.dumps(result, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
