#!/usr/bin/env python3
"""Can a face's landmarks tell a camera's field of view? Two fits over a grid of angles.

Issue 39 asks for `--fov auto`; the log evidence over a grid of angles prefers weak perspective
on every clip (docs/ACCURACY.md, "Can the evidence choose the angle?"). This measures two other
signals, both from dlib's 68 landmarks on the first frames of a clip (its largest face a frame):

- `model`: each frame's pose fitted (OpenCV's EPnP, then Levenberg-Marquardt) to the face model's
  own 3D landmarks (the 51 inner ones: brows, nose, eyes, mouth; the outline's points slide
  round the face as it turns), through a pinhole of each angle. The perspective the model's
  depths imply, against the landmarks'.
- `rigid`: the 31 landmarks of the rigid part of the face (brows, nose, eyes) of every second
  frame fitted by one shape shared by all frames and a pose a frame (bundle adjustment, SciPy's
  least_squares), through a pinhole of each angle: the shape is the person's, not the model's,
  so only the frames' perspective against each other can prefer an angle.

Each prints the root-mean-square residual per coordinate (pixels) per angle; `weak` is a pinhole of 50 frame
widths, which is weak perspective within the landmarks' precision.

    cargo run --release -p face-tracker --example landmarks_3d > target/landmarks_3d.txt
    target/media/pose-venv/bin/python3 tools/fov_from_landmarks.py VIDEO target/landmarks_3d.txt
        [--max-frames 300] [--fovs 20,30,40,50,60,70,90]

Needs dlib with /usr/share/dlib/shape_predictor_68_face_landmarks.dat, OpenCV, NumPy and SciPy
(`cargo xtask fetch-media` puts them in target/media/pose-venv).
"""

import argparse
import math

import cv2
import numpy as np

PREDICTOR = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat"
INNER = list(range(17, 68))
RIGID = list(range(17, 48))
# Model coordinates are half-widths; OpenCV's EPnP wants points spread over more than that.
MODEL_SCALE = 100.0


def landmarks_of(video, max_frames):
    """The largest face's 68 landmarks in each frame where dlib finds a face, and the frame's size."""
    import dlib

    detector = dlib.get_frontal_face_detector()
    predictor = dlib.shape_predictor(PREDICTOR)
    capture = cv2.VideoCapture(video)
    if not capture.isOpened():
        raise SystemExit(f"cannot read the video {video}")
    found, size = [], None
    for _ in range(max_frames):
        ok, image = capture.read()
        if not ok:
            break
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        size = gray.shape[::-1]
        faces = detector(gray, 1)
        if faces:
            shape = predictor(gray, max(faces, key=lambda r: r.width()))
            found.append(np.array([(shape.part(i).x, shape.part(i).y) for i in range(68)], float))
    if not found:
        raise SystemExit(f"dlib found no face in {video}")
    return found, size


def camera(fov, size):
    """The pinhole of horizontal field of view `fov` degrees (None: weak perspective's stand-in)."""
    width, height = size
    focal = 50.0 * width if fov is None else (width / 2) / math.tan(math.radians(fov) / 2)
    return np.array([[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1]], float)


def model_points(model, rows):
    """The model's landmarks `rows` in OpenCV's camera frame (z away from the camera)."""
    u, v, height = model[rows, 0], model[rows, 1], model[rows, 2]
    return MODEL_SCALE * np.stack([u, v, -height], axis=1)


def pose_of(points, image_points, k):
    _, rvec, tvec = cv2.solvePnP(points, image_points, k, None, flags=cv2.SOLVEPNP_EPNP)
    return cv2.solvePnPRefineLM(points, image_points, k, None, rvec, tvec)


def model_fit(frames, size, model, fov):
    """RMS residual of each frame's pose fitted to the model's inner landmarks."""
    k = camera(fov, size)
    points = model_points(model, INNER)
    squares, count = 0.0, 0
    for landmarks in frames:
        seen = landmarks[INNER]
        rvec, tvec = pose_of(points, seen, k)
        projected, _ = cv2.projectPoints(points, rvec, tvec, k, None)
        squares += float(((projected[:, 0, :] - seen) ** 2).sum())
        count += seen.size
    return math.sqrt(squares / count)


def rotations(rvecs):
    """Rodrigues' formula for each row of `rvecs`."""
    theta = np.linalg.norm(rvecs, axis=1, keepdims=True) + 1e-12
    axis = rvecs / theta
    cross = np.zeros((len(rvecs), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2] = -axis[:, 2], axis[:, 1]
    cross[:, 1, 0], cross[:, 1, 2] = axis[:, 2], -axis[:, 0]
    cross[:, 2, 0], cross[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s, c = np.sin(theta)[:, :, None], np.cos(theta)[:, :, None]
    return np.eye(3)[None] + s * cross + (1 - c) * (cross @ cross)


def rigid_fit(frames, size, model, fov):
    """RMS residual of one shape (its first point and its size held, the gauge) and a pose per
    frame fitted to every second frame's rigid landmarks."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    k = camera(fov, size)
    focal, centre = k[0, 0], k[:2, 2]
    seen = np.stack([landmarks[RIGID] for landmarks in frames[::2]])
    count, points = seen.shape[:2]
    start_shape = model_points(model, RIGID)
    start_poses = []
    for landmarks in seen:
        rvec, tvec = pose_of(start_shape, landmarks, k)
        start_poses.append(np.concatenate([rvec[:, 0], tvec[:, 0]]))
    start = np.concatenate([np.ravel(start_poses), start_shape[1:].ravel()])

    def size_of(shape):
        return math.sqrt(((shape - shape.mean(axis=0)) ** 2).sum(axis=1).mean())

    def residuals(x):
        poses = x[: count * 6].reshape(count, 6)
        shape = np.vstack([start_shape[:1], x[count * 6 :].reshape(points - 1, 3)])
        placed = np.einsum("fij,nj->fni", rotations(poses[:, :3]), shape) + poses[:, None, 3:]
        projected = focal * placed[:, :, :2] / placed[:, :, 2:3] + centre
        gauge = 10.0 * (size_of(shape) - size_of(start_shape))
        return np.concatenate([(projected - seen).ravel(), [gauge]])

    sparsity = lil_matrix((count * points * 2 + 1, len(start)), dtype=int)
    for f in range(count):
        rows = slice(f * points * 2, (f + 1) * points * 2)
        sparsity[rows, f * 6 : (f + 1) * 6] = 1
        for n in range(1, points):
            cols = slice(count * 6 + (n - 1) * 3, count * 6 + n * 3)
            sparsity[f * points * 2 + 2 * n : f * points * 2 + 2 * n + 2, cols] = 1
    sparsity[-1, count * 6 :] = 1
    fit = least_squares(
        residuals, start, jac_sparsity=sparsity, method="trf", x_scale="jac", max_nfev=200
    )
    return math.sqrt(float((fit.fun[:-1] ** 2).mean()))


def angles(text):
    """--fovs: angles in degrees, each strictly between 0 and 180."""
    try:
        fovs = [float(f) for f in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of degrees")
    if not all(0.0 < f < 180.0 for f in fovs):
        raise argparse.ArgumentTypeError(f"every angle lies strictly between 0 and 180: {text}")
    return fovs


def positive(text):
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"at least 1, not {text}")
    return value


def read_model(path):
    """The 68 rows of (u, v, photographed height, generic height) the landmarks_3d example
    writes, or an exit naming what is wrong."""
    try:
        model = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as error:
        raise SystemExit(f"cannot read the 3D landmarks {path}: {error}")
    if model.shape[0] != 68 or model.shape[1] < 3 or not np.isfinite(model).all():
        raise SystemExit(
            f"{path}: expected 68 rows of finite u, v, height (the landmarks_3d example's), "
            f"got {model.shape[0]} rows of {model.shape[1]}"
        )
    return model


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("video")
    parser.add_argument("landmarks_3d", help="the face model's 3D landmarks (landmarks_3d example)")
    parser.add_argument("--max-frames", type=positive, default=300)
    parser.add_argument("--fovs", type=angles, default=angles("20,30,40,50,60,70,90"))
    args = parser.parse_args()
    model = read_model(args.landmarks_3d)
    fovs = [None] + args.fovs
    frames, size = landmarks_of(args.video, args.max_frames)
    print(f"{args.video}: {len(frames)} frames with a face, {size[0]}x{size[1]}")
    print("fit    " + " ".join(f"{'weak' if f is None else f'{f:g}°':>7}" for f in fovs) + "  best")
    for name, fit in [("model", model_fit), ("rigid", rigid_fit)]:
        rms = [fit(frames, size, model, fov) for fov in fovs]
        best = fovs[int(np.argmin(rms))]
        print(
            f"{name:6} "
            + " ".join(f"{r:7.4f}" for r in rms)
            + f"  {'weak' if best is None else f'{best:g}°'}",
            flush=True,
        )


if __name__ == "__main__":
    main()
