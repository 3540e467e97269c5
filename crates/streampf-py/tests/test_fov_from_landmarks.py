"""tools/fov_from_landmarks.py's two fits on landmarks that a known pinhole made: a random rigid
face turned through random poses, seen through a lens of a random angle, with a little noise. On
such landmarks both fits must choose the lens's angle from the grid (the real clips' failure to,
docs/ACCURACY.md, is then the landmarks' and the face model's, not the fits')."""

import math

import numpy as np
import pytest
from conftest import load_script

fov_tool = load_script("tools/fov_from_landmarks.py")
SIZE = (400, 300)
FOVS = [None, 30.0, 40.0, 50.0, 60.0, 70.0]


def random_face(rng):
    """68 rows of (u, v, height, unused): points over the face's width with a face's relief."""
    u = rng.uniform(-1.0, 1.0, 68)
    v = rng.uniform(-1.2, 1.2, 68)
    height = 0.6 * np.exp(-(u**2 + v**2)) + rng.uniform(-0.1, 0.1, 68)
    return np.stack([u, v, height, np.zeros(68)], axis=1)


def landmarks_through(model, fov, rng, frames=30, noise=0.05):
    """Each frame's 68 landmarks of `model` turned by up to 30° of yaw and 15° of pitch and roll,
    120 px wide near the frame's middle, through a pinhole of `fov` degrees."""
    k = fov_tool.camera(fov, SIZE)
    focal = k[0, 0]
    points = fov_tool.model_points(model, list(range(68)))
    width = np.ptp(points[:, 0])
    seen = []
    for _ in range(frames):
        turn = np.radians([rng.uniform(-15, 15), rng.uniform(-30, 30), rng.uniform(-10, 10)])
        rotation = fov_tool.rotations(turn[None, :])[0]
        depth = focal * width / 120.0
        shift = np.array([rng.uniform(-40, 40), rng.uniform(-30, 30), depth])
        shift[:2] *= depth / focal
        placed = points @ rotation.T + shift
        image = focal * placed[:, :2] / placed[:, 2:3] + k[:2, 2]
        seen.append(image + rng.normal(0.0, noise, image.shape))
    return seen


@pytest.mark.parametrize("seed", range(3))
def test_both_fits_choose_the_angle_the_landmarks_were_seen_through(seed):
    rng = np.random.default_rng(seed)
    true_fov = float(rng.choice([40.0, 50.0, 60.0]))
    model = random_face(rng)
    frames = landmarks_through(model, true_fov, rng)
    for name, fit in [("model", fov_tool.model_fit), ("rigid", fov_tool.rigid_fit)]:
        rms = [fit(frames, SIZE, model, fov) for fov in FOVS]
        chosen = FOVS[int(np.argmin(rms))]
        assert chosen == true_fov, f"{name}: chose {chosen} for {true_fov}, residuals {rms}"


def test_weak_perspective_is_chosen_for_a_distant_face():
    rng = np.random.default_rng(7)
    model = random_face(rng)
    frames = landmarks_through(model, None, rng)
    rms = [fov_tool.model_fit(frames, SIZE, model, fov) for fov in FOVS]
    assert int(np.argmin(rms)) == 0, rms
    assert math.isfinite(rms[0]) and rms[0] < 0.2, rms
