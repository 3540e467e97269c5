#!/usr/bin/env python3
"""Checks that the face tracker's tracks sit on faces, against MediaPipe's Face Mesh.

The mesh (0.10.14, static image mode, up to eight faces a frame) is run on every frame on its
own; each face it finds is the box of its 468 landmarks in pixels. Against those boxes, from the
tracker's states.csv (rows with status `tracking`):

- on face: the share of tracking rows whose centre (tx, ty) lies in the middle half of a face
  found in that frame (within a quarter of the box's width and of its height of the box's centre).
  A row in a frame where the mesh finds no face counts as off the face, as does a row on a face
  the mesh misses (a profile, a face turned away): the mesh is the judge. With --judge
  mesh-or-detector a face MediaPipe's face detector finds (the full-range model, for faces
  farther from the camera; score 0.5 or more) counts too where its box's centre lies in no mesh
  box: the mesh misses small, blurred faces that the detector finds (Megamind.avi's background
  man, about 70 px wide). With --bridge N a face the judge saw on both sides of a gap of at
  most N frames, at nearly the same place and size (centres within half its width, widths within
  a factor 1.5), counts in the frames between too, its box interpolated: both judges miss
  Megamind.avi's background man in runs of up to seven frames between frames where they find him
  (he is there in each, blurred, looking down), as MOT ground truth interpolates a box between the
  frames annotated.
- faces carrying a track: the share of the mesh's faces at least --min-face pixels wide whose
  middle half holds a tracking row's centre.
- confidence ROC AUC: how well the rows' `confidence` tells on-face rows from off-face ones (the
  probability that an on-face row's confidence exceeds an off-face row's, ties counted half);
  0.5 is no better than chance.
- confidence 0 while tracking: the share of tracking rows whose confidence reads 0.

    python3 tools/on_face_check.py VIDEO STATES_CSV [--json OUT.json] [--min-face 40]
        [--max-frames N] [--faces FACES.json] [--judge mesh|mesh-or-detector] [--bridge N]

--faces caches the faces' boxes: read when the file exists, else written after the mesh ran
(the mesh takes a few seconds a hundred frames; the tracker's runs to compare need it once).
Needs mediapipe==0.10.14, numpy and OpenCV: `cargo xtask fetch-media` puts them in
target/media/pose-venv, so run it with target/media/pose-venv/bin/python3.
"""

import argparse
import csv
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from head_pose_check import frames_of  # noqa: E402  (the same frame reader as the pose check)


def mesh_boxes(video, max_frames=None):
    """Per frame, the (x0, y0, x1, y1) pixel box of each face MediaPipe's Face Mesh finds."""
    import cv2
    import mediapipe

    mesh = mediapipe.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=8)
    frames = []
    for image in frames_of(video, max_frames):
        height, width = image.shape[:2]
        found = mesh.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)).multi_face_landmarks or []
        boxes = []
        for face in found:
            xs = [p.x * width for p in face.landmark]
            ys = [p.y * height for p in face.landmark]
            boxes.append((min(xs), min(ys), max(xs), max(ys)))
        frames.append(boxes)
    return frames


def detector_boxes(video, max_frames=None):
    """Per frame, the (x0, y0, x1, y1) pixel box of each face MediaPipe's full-range face
    detector finds (score 0.5 or more)."""
    import cv2
    import mediapipe

    detector = mediapipe.solutions.face_detection.FaceDetection(
        model_selection=1, min_detection_confidence=0.5
    )
    frames = []
    for image in frames_of(video, max_frames):
        height, width = image.shape[:2]
        found = detector.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)).detections or []
        boxes = []
        for face in found:
            box = face.location_data.relative_bounding_box
            x0, y0 = box.xmin * width, box.ymin * height
            boxes.append((x0, y0, x0 + box.width * width, y0 + box.height * height))
        frames.append(boxes)
    return frames


def inside(x, y, box):
    return box[0] <= x <= box[2] and box[1] <= y <= box[3]


def judged_faces(found, judge):
    """Per frame, the faces the judge takes: the mesh's, and with `mesh-or-detector` each
    detector face whose centre lies in no mesh box."""
    if judge == "mesh":
        return found["mesh"]
    frames = []
    for mesh, detected in zip(found["mesh"], found["detector"]):
        extra = [
            box
            for box in detected
            if not any(inside((box[0] + box[2]) / 2, (box[1] + box[3]) / 2, m) for m in mesh)
        ]
        frames.append(list(mesh) + extra)
    return frames


def same_face(a, b):
    """Whether boxes a and b (x0, y0, x1, y1) are one face seen a few frames apart: centres within
    half the wider box's width, widths within a factor 1.5."""
    wa, wb = a[2] - a[0], b[2] - b[0]
    if wa <= 0 or wb <= 0 or max(wa, wb) > 1.5 * min(wa, wb):
        return False
    dx = (a[0] + a[2] - b[0] - b[2]) / 2
    dy = (a[1] + a[3] - b[1] - b[3]) / 2
    return (dx * dx + dy * dy) ** 0.5 <= max(wa, wb) / 2


def bridged(frames, max_gap):
    """The faces per frame with each gap of at most `max_gap` frames between two sightings of one
    face (same_face) filled by the box interpolated linearly between them, where that frame has
    no box of that face already."""
    out = [list(faces) for faces in frames]
    for first, faces in enumerate(frames):
        for box in faces:
            for later in range(first + 1, min(first + max_gap + 1, len(frames) - 1) + 1):
                seen = [other for other in frames[later] if same_face(box, other)]
                if not seen:
                    continue
                for k in range(first + 1, later):
                    t = (k - first) / (later - first)
                    between = tuple(a + t * (b - a) for a, b in zip(box, seen[0]))
                    if not any(same_face(between, other) for other in out[k]):
                        out[k].append(between)
                break
    return out


def tracking_rows(states_csv):
    """(frame, track, tx, ty, confidence) of every row with status `tracking`."""
    rows = []
    with open(states_csv, newline="") as f:
        for row in csv.DictReader(f):
            if row.get("status") != "tracking":
                continue
            rows.append(
                (
                    int(row["frame"]),
                    int(row["track"]),
                    float(row["tx"]),
                    float(row["ty"]),
                    float(row["confidence"]),
                )
            )
    return rows


def in_middle_half(x, y, box):
    x0, y0, x1, y1 = box
    return abs(x - (x0 + x1) / 2) <= (x1 - x0) / 4 and abs(y - (y0 + y1) / 2) <= (y1 - y0) / 4


def roc_auc(positive, negative):
    """P(a positive's score > a negative's), ties counted half (the Mann–Whitney U statistic over
    the pairs); None when either side is empty."""
    if not positive or not negative:
        return None
    scores = np.concatenate([positive, negative])
    order = scores.argsort(kind="mergesort")
    ranks = np.empty(len(scores))
    sorted_scores = scores[order]
    # Average ranks over ties (1-based).
    start = 0
    while start < len(scores):
        end = start
        while end + 1 < len(scores) and sorted_scores[end + 1] == sorted_scores[start]:
            end += 1
        ranks[order[start : end + 1]] = (start + end) / 2 + 1
        start = end + 1
    u = ranks[: len(positive)].sum() - len(positive) * (len(positive) + 1) / 2
    return float(u / (len(positive) * len(negative)))


def scores(boxes, rows, min_face):
    """The check's numbers for one run: the mesh's boxes per frame against the tracking rows."""
    on, off = [], []
    carried = set()
    for frame, _track, x, y, confidence in rows:
        faces = boxes[frame] if frame < len(boxes) else []
        hit = [i for i, box in enumerate(faces) if in_middle_half(x, y, box)]
        (on if hit else off).append(confidence)
        carried.update((frame, i) for i in hit)
    large = [
        (frame, i)
        for frame, faces in enumerate(boxes)
        for i, box in enumerate(faces)
        if box[2] - box[0] >= min_face
    ]
    tracked = len(on) + len(off)
    zero = sum(1 for row in rows if row[4] == 0.0)
    return {
        "tracking_rows": tracked,
        "on_face": len(on) / tracked if tracked else None,
        "faces": len(large),
        "faces_carrying_a_track": (
            sum(1 for face in large if face in carried) / len(large) if large else None
        ),
        "confidence_auc": roc_auc(on, off),
        "confidence_zero": zero / tracked if tracked else None,
        "frames": len(boxes),
        "frames_with_a_face": sum(1 for faces in boxes if faces),
    }


def percent(value):
    return "—" if value is None else f"{100 * value:.0f} %"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("video")
    parser.add_argument("states_csv")
    parser.add_argument("--json", help="write the numbers to this file")
    parser.add_argument("--min-face", type=float, default=40.0, help="pixels (default 40)")
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--faces", help="cache of the faces' boxes (JSON)")
    parser.add_argument(
        "--judge",
        choices=["mesh", "mesh-or-detector"],
        default="mesh",
        help="which faces count (default: the mesh's)",
    )
    parser.add_argument(
        "--bridge",
        type=int,
        default=0,
        help="count a face the judge saw on both sides of a gap of at most this many frames "
        "in the frames between (default 0: no bridging)",
    )
    args = parser.parse_args()
    if args.bridge < 0:
        parser.error("--bridge: a number of frames, 0 or more")

    found = {}
    if args.faces and os.path.exists(args.faces):
        with open(args.faces) as f:
            found = json.load(f)
        if isinstance(found, list):  # a cache of the mesh's boxes alone
            found = {"mesh": found}
    if "mesh" not in found:
        found["mesh"] = mesh_boxes(args.video, args.max_frames)
    if args.judge == "mesh-or-detector" and "detector" not in found:
        found["detector"] = detector_boxes(args.video, args.max_frames)
    if args.faces:
        with open(args.faces, "w") as f:
            json.dump(found, f)
    boxes = judged_faces(found, args.judge)
    if args.bridge > 0:
        boxes = bridged(boxes, args.bridge)
    result = scores(boxes, tracking_rows(args.states_csv), args.min_face)
    result["judge"] = args.judge
    result["bridge"] = args.bridge
    auc = result["confidence_auc"]
    print(
        f"{result['tracking_rows']} tracking rows over {result['frames']} frames "
        f"({result['frames_with_a_face']} with a face the judge ({args.judge}"
        f"{f', gaps of up to {args.bridge} frames bridged' if args.bridge else ''}) finds)\n"
        f"on face: {percent(result['on_face'])}\n"
        f"faces >= {args.min_face:g} px carrying a track: "
        f"{percent(result['faces_carrying_a_track'])} of {result['faces']}\n"
        f"confidence ROC AUC (on face against off): {'—' if auc is None else f'{auc:.2f}'}\n"
        f"confidence 0 while tracking: {percent(result['confidence_zero'])}"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
