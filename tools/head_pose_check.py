#!/usr/bin/env python3
"""Checks the face tracker's head pose on a real video against an independent per-frame estimate.

Two references, neither of which knows anything of the tracker:

- `mesh` (the default): MediaPipe's Face Mesh (0.10.14, the last release that bundles its models),
  run on every frame on its own (static image mode). It places 468 landmarks in 3D on each face,
  its depth learned from 3D face data. Each face's rotation is the rigid rotation (Kabsch) that
  best takes the clip's mean mesh (a generalised Procrustes mean over every face found) onto
  that face's mesh. Angles are thus relative to the clip's mean head pose.
- `six-point`: dlib's face detector and 68 landmarks, then OpenCV's solvePnP (SQPnP) with a
  generic six-point 3D face (nose tip, chin, the eyes' outer corners, the mouth's corners) and a
  pinhole camera whose focal length is the frame's width. Kept for comparison: it reads yaw two
  to four times as large as the mesh does (docs/ACCURACY.md says why: its six points do not fit a
  real face's proportions, and its nose stands out less than a real one).

Both rotations are split as the tracker's is, R = Rx(pitch)·Ry(yaw)·Rz(roll), in the tracker's
frame (x right, y down, z towards the camera). OpenCV's camera looks along +z, which mirrors z and
so negates pitch and yaw (S·R·S with S = diag(1, 1, −1)): the six-point reference's pitch and yaw
are negated to compare. The mesh's z (smaller nearer the camera) is negated as it is read.

For each track of the tracker's states.csv, frames where a reference face's centre lies within a
quarter of the face's width of the track's centre are paired. Per axis the check reports the
Pearson correlation r, the ratio of the tracker's spread to the reference's (sd ratio) and the
mean absolute difference after removing each series' mean (an offset between the reference's
frontal pose and the tracker's, whose angles are relative to the pose at its template, is
expected and is not an error).

A reference's landmarks jitter from frame to frame, which caps r on small motions. `--smooth N`
also compares against the reference's running median over N frames (centred, paired frames only):
the slow head motion that a tracker should follow.

A talking head turns far only now and then, so a whole clip's spread is mostly small motion.
`--widest N` also reports, per axis, the N consecutive paired frames over which the reference
(its running median with --smooth) moves furthest: which frames, how far the reference turns
there about its own mean, and the comparison over them. The stretch is chosen by the
reference's motion alone, never by the tracker's agreement with it.

`--tracked-video SMALL` pairs a run on a resized copy of VIDEO (a face made small, say) with
the reference found on VIDEO itself: the track's centre is scaled by the ratio of the frame sizes.

Per axis it also reports the jitter, the median |change| from one paired frame to the next, of
the tracker and of the reference. STATES_CSV may be a smoothed.csv (`face track --smooth full`
or `--smooth-lag L`) to check the smoothed trajectory.

    python3 tools/head_pose_check.py VIDEO STATES_CSV [--reference mesh|six-point]
        [--json OUT.json] [--min-frames 30] [--max-frames N] [--smooth 5] [--widest 300]
        [--tracked-video SMALL.mp4]

The mesh needs mediapipe==0.10.14 and the six-point reference dlib and its model at
/usr/share/dlib/shape_predictor_68_face_landmarks.dat (Debian's libdlib-data); both need numpy and
OpenCV. `cargo xtask fetch-media` puts them in target/media/pose-venv: run the check with
target/media/pose-venv/bin/python3.
"""

import argparse
import csv
import json
import math
import sys

import cv2
import numpy as np

PREDICTOR = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat"

# A generic face in millimetres (x right, y down, z away from the camera), the six points in the
# 68-landmark numbering: nose tip 30, chin 8, left eye's outer corner 36, right eye's outer
# corner 45, mouth corners 48 and 54.
MODEL_POINTS = np.array(
    [
        (0.0, 0.0, 0.0),
        (0.0, 63.6, 12.5),
        (-43.3, -32.7, 26.0),
        (43.3, -32.7, 26.0),
        (-28.9, 28.9, 24.1),
        (28.9, 28.9, 24.1),
    ],
    dtype=np.float64,
)
LANDMARKS = [30, 8, 36, 45, 48, 54]
AXES = ("pitch", "yaw", "roll")


def angles_xyz(rotation):
    """(rx, ry, rz) in degrees with R = Rx(rx)·Ry(ry)·Rz(rz)."""
    ry = math.asin(max(-1.0, min(1.0, rotation[0, 2])))
    rx = math.atan2(-rotation[1, 2], rotation[2, 2])
    rz = math.atan2(-rotation[0, 1], rotation[0, 0])
    return tuple(math.degrees(a) for a in (rx, ry, rz))


def frames_of(video, max_frames=None):
    """The video's frames (BGR), the first `max_frames` of them when given."""
    capture = cv2.VideoCapture(video)
    if not capture.isOpened():
        sys.exit(f"cannot open {video}")
    count = 0
    while max_frames is None or count < max_frames:
        ok, image = capture.read()
        if not ok:
            return
        count += 1
        yield image


def kabsch(points, model):
    """The rotation R that best takes `model` onto `points` (both centred; rows are points):
    points ≈ model·Rᵀ."""
    u, _, vt = np.linalg.svd(model.T @ points)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def mesh_reference(video, max_frames=None):
    """Per frame, (centre_x, centre_y, width, (pitch, yaw, roll)) for each face MediaPipe's Face
    Mesh finds: the rotation from the clip's mean mesh to the face's mesh."""
    import mediapipe

    mesh = mediapipe.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=8)
    meshes = []
    for image in frames_of(video, max_frames):
        height, width = image.shape[:2]
        found = mesh.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)).multi_face_landmarks or []
        # Pixels, with z towards the camera (MediaPipe's z grows away from it, in x's scale).
        meshes.append(
            [
                np.array([(p.x * width, p.y * height, -p.z * width) for p in face.landmark])
                for face in found
            ]
        )
    centred = [face - face.mean(axis=0) for faces in meshes for face in faces]
    if not centred:
        sys.exit(f"MediaPipe's Face Mesh found no face in {video}")
    # The generalised Procrustes mean: align every mesh to the current mean, average, repeat.
    mean = centred[0]
    for _ in range(3):
        mean = np.mean([face @ kabsch(face, mean) for face in centred], axis=0)
    return [
        [
            (
                *face[:, :2].mean(axis=0),
                np.ptp(face[:, 0]),
                angles_xyz(kabsch(face - face.mean(axis=0), mean)),
            )
            for face in faces
        ]
        for faces in meshes
    ]


def six_point_reference(video, max_frames=None):
    """Per frame, a list of (centre_x, centre_y, width, (pitch, yaw, roll)) for each face found."""
    import dlib

    detector = dlib.get_frontal_face_detector()
    predictor = dlib.shape_predictor(PREDICTOR)
    frames = []
    for image in frames_of(video, max_frames):
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        height, width = gray.shape
        camera = np.array(
            [[width, 0, width / 2], [0, width, height / 2], [0, 0, 1]], dtype=np.float64
        )
        faces = []
        for rect in detector(gray, 1):
            shape = predictor(gray, rect)
            image_points = np.array(
                [(shape.part(i).x, shape.part(i).y) for i in LANDMARKS], dtype=np.float64
            )
            ok, rvec, _ = cv2.solvePnP(
                MODEL_POINTS, image_points, camera, None, flags=cv2.SOLVEPNP_SQPNP
            )
            if not ok:
                continue
            rotation, _ = cv2.Rodrigues(rvec)
            pitch, yaw, roll = angles_xyz(rotation)
            centre = ((rect.left() + rect.right()) / 2, (rect.top() + rect.bottom()) / 2)
            # In the tracker's frame (z towards the camera): pitch and yaw change sign.
            faces.append((centre[0], centre[1], rect.width(), (-pitch, -yaw, roll)))
        frames.append(faces)
    return frames


def frame_size(video):
    """(width, height) of a video's first frame; exits with a message when it cannot be read."""
    for image in frames_of(video, 1):
        return image.shape[1], image.shape[0]
    sys.exit(f"could not read a frame of {video}")


def resize_factors(video, tracked_video):
    """How much larger VIDEO's frames are than TRACKED_VIDEO's, in x and in y."""
    (width, height), (small_width, small_height) = frame_size(video), frame_size(tracked_video)
    return width / small_width, height / small_height


def tracker_rows(states_csv):
    """{track: [(frame, tx, ty, (pitch, yaw, roll))]} of the rows being tracked: from states.csv,
    or from smoothed.csv (`face track --smooth full` or `--smooth-lag L`: every row is a tracked
    face's, its angles rx, ry, rz in radians, the same convention as states.csv's *_deg)."""
    tracks = {}
    with open(states_csv, newline="") as f:
        for row in csv.DictReader(f):
            if "status" not in row:
                angles = tuple(math.degrees(float(row[a])) for a in ("rx", "ry", "rz"))
            elif row["status"] != "tracking":
                continue
            else:
                angles = tuple(float(row[f"{a}_deg"]) for a in AXES)
            tracks.setdefault(int(row["track"]), []).append(
                (int(row["frame"]), float(row["tx"]), float(row["ty"]), angles)
            )
    return tracks


def compare(ours, theirs):
    """r, sd ratio (ours / theirs) and mean |difference| after removing each series' mean."""
    a, b = np.asarray(ours), np.asarray(theirs)
    sd_a, sd_b = a.std(), b.std()
    r = float(np.corrcoef(a, b)[0, 1]) if sd_a > 0 and sd_b > 0 else float("nan")
    return {
        "r": r,
        "sd_ratio": float(sd_a / sd_b) if sd_b > 0 else float("nan"),
        "tracker_sd_deg": float(sd_a),
        "reference_sd_deg": float(sd_b),
        "mean_abs_diff_deg": float(np.abs((a - a.mean()) - (b - b.mean())).mean()),
    }


def frame_to_frame_jitter(frames, values):
    """The median |change| from one frame to the next, over consecutive paired frames only."""
    frames, values = np.asarray(frames), np.asarray(values)
    steps = np.flatnonzero(np.diff(frames) == 1)
    return float(np.median(np.abs(values[steps + 1] - values[steps]))) if len(steps) else float("nan")


def smoothed(frames, values, window):
    """The running median of `values` over the paired frames within window // 2 of each frame."""
    frames, values = np.asarray(frames), np.asarray(values)
    half = window // 2
    return np.array(
        [np.median(values[np.abs(frames - f) <= half], axis=0) for f in frames]
    )


def widest_stretch(frames, ours, theirs, length):
    """Over the `length` consecutive pairs where `theirs` spans the widest range (max - min;
    the earliest such stretch on a tie): the frames, the reference's extremes about its mean
    there, and the comparison. Every pair when there are fewer than `length`."""
    theirs = np.asarray(theirs)
    length = min(length, len(theirs))
    spans = [np.ptp(theirs[start : start + length]) for start in range(len(theirs) - length + 1)]
    start = int(np.argmax(spans))
    window = slice(start, start + length)
    reference = theirs[window]
    return {
        "first_frame": int(frames[start]),
        "last_frame": int(frames[start + length - 1]),
        "pairs": length,
        "reference_below_mean_deg": float(reference.min() - reference.mean()),
        "reference_above_mean_deg": float(reference.max() - reference.mean()),
        **compare(np.asarray(ours)[window], reference),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video")
    parser.add_argument("states_csv")
    parser.add_argument(
        "--reference",
        choices=("mesh", "six-point"),
        default="mesh",
        help="the independent estimate to compare with (see above)",
    )
    parser.add_argument("--json", help="write the results here too")
    parser.add_argument("--min-frames", type=int, default=30)
    parser.add_argument("--max-frames", type=int, help="read only the first N frames")
    parser.add_argument(
        "--smooth", type=int, default=1, help="also compare with the reference's N-frame median"
    )
    parser.add_argument(
        "--widest",
        type=int,
        metavar="N",
        help="also compare, per axis, over the N paired frames where the reference moves furthest",
    )
    parser.add_argument(
        "--tracked-video",
        metavar="SMALL",
        help="the video the tracker ran on, a resized copy of VIDEO (the reference runs on VIDEO)",
    )
    args = parser.parse_args()
    for name in ("min_frames", "max_frames", "smooth", "widest"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, not {value}")
    poses = mesh_reference if args.reference == "mesh" else six_point_reference
    reference = poses(args.video, args.max_frames)
    scale_x, scale_y = (
        resize_factors(args.video, args.tracked_video) if args.tracked_video else (1.0, 1.0)
    )
    results = {}
    for track, rows in sorted(tracker_rows(args.states_csv).items()):
        pairs = []
        for frame, tx, ty, angles in rows:
            if frame >= len(reference):
                continue
            tx, ty = tx * scale_x, ty * scale_y
            near = [
                f
                for f in reference[frame]
                if math.hypot(f[0] - tx, f[1] - ty) <= 0.25 * f[2]
            ]
            if len(near) == 1:
                pairs.append((frame, angles, near[0][3]))
        if len(pairs) < args.min_frames:
            continue
        frames = [p[0] for p in pairs]
        ours = np.array([p[1] for p in pairs])
        theirs = np.array([p[2] for p in pairs])
        results[track] = {"frames": len(pairs)}
        for k, axis in enumerate(AXES):
            results[track][axis] = compare(ours[:, k], theirs[:, k])
            results[track][axis]["tracker_jitter_deg"] = frame_to_frame_jitter(frames, ours[:, k])
            results[track][axis]["reference_jitter_deg"] = frame_to_frame_jitter(frames, theirs[:, k])
        if args.smooth > 1:
            slow = smoothed(frames, theirs, args.smooth)
            results[track]["smoothed"] = {
                "window": args.smooth,
                "reference_jitter_sd_deg": dict(zip(AXES, (theirs - slow).std(axis=0).tolist())),
            }
            for k, axis in enumerate(AXES):
                results[track]["smoothed"][axis] = compare(ours[:, k], slow[:, k])
        if args.widest:
            against = slow if args.smooth > 1 else theirs
            results[track]["widest"] = {
                axis: widest_stretch(frames, ours[:, k], against[:, k], args.widest)
                for k, axis in enumerate(AXES)
            }
    if not results:
        sys.exit(f"no track had {args.min_frames} frames paired with the reference")
    for track, result in results.items():
        print(
            f"track {track}: {result['frames']} frames paired with the {args.reference} reference"
        )
        print_axes(result)
        if "smoothed" in result:
            jitter = result["smoothed"]["reference_jitter_sd_deg"]
            print(
                f"  against the reference's {args.smooth}-frame median (its jitter sd: "
                + ", ".join(f"{a} {jitter[a]:.1f}°" for a in AXES)
                + ")"
            )
            print_axes(result["smoothed"])
        if "widest" in result:
            median = f"{args.smooth}-frame median" if args.smooth > 1 else "reference"
            print(f"  over the {args.widest} paired frames where the {median} moves furthest:")
            for axis, c in result["widest"].items():
                print(
                    f"  {axis:5}: frames {c['first_frame']}-{c['last_frame']}, reference "
                    f"{c['reference_below_mean_deg']:+.1f}° to {c['reference_above_mean_deg']:+.1f}° "
                    f"about its mean; r {c['r']:.2f}, sd ratio {c['sd_ratio']:.2f}, mean "
                    f"|difference| after offset {c['mean_abs_diff_deg']:.1f}°"
                )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)


def print_axes(result):
    for axis in AXES:
        c = result[axis]
        jitter = (
            f", jitter (median |frame-to-frame change|) {c['tracker_jitter_deg']:.2f}° vs "
            f"{c['reference_jitter_deg']:.2f}°"
            if "tracker_jitter_deg" in c
            else ""
        )
        print(
            f"  {axis:5}: r {c['r']:.2f}, sd {c['tracker_sd_deg']:.1f}° vs "
            f"{c['reference_sd_deg']:.1f}° (ratio {c['sd_ratio']:.2f}), mean |difference| "
            f"after offset {c['mean_abs_diff_deg']:.1f}°{jitter}"
        )


if __name__ == "__main__":
    main()
