"""tools/on_face_check.py's judge: the faces a frame holds when gaps between two sightings of one
face are bridged (`--bridge`), drawn at random: a face the judge sees on both sides of a short
gap counts in between at the interpolated place, a longer gap or a different face does not."""

import random

import pytest
from conftest import load_script

judge = load_script("tools/on_face_check.py")


def box(cx, cy, width):
    return (cx - width / 2, cy - width / 2, cx + width / 2, cy + width / 2)


@pytest.mark.parametrize("seed", range(20))
def test_a_short_gap_is_bridged_at_the_interpolated_place(seed):
    rng = random.Random(seed)
    frames_total = rng.randint(12, 40)
    max_gap = rng.randint(1, 8)
    gap = rng.randint(1, max_gap)
    first = rng.randint(0, frames_total - gap - 2)
    later = first + gap + 1
    width = rng.uniform(20, 200)
    start = (rng.uniform(0, 640), rng.uniform(0, 480))
    # Moves by less than half its width over the gap, at most 1.4 times as wide.
    step = (rng.uniform(-0.2, 0.2) * width, rng.uniform(-0.2, 0.2) * width)
    end = (start[0] + step[0], start[1] + step[1])
    end_width = width * rng.uniform(1.0, 1.4)
    frames = [[] for _ in range(frames_total)]
    frames[first].append(box(*start, width))
    frames[later].append(box(*end, end_width))
    out = judge.bridged(frames, max_gap)
    for k in range(frames_total):
        if first < k < later:
            assert len(out[k]) == 1, (k, out[k])
            t = (k - first) / (later - first)
            expected = tuple(
                a + t * (b - a) for a, b in zip(box(*start, width), box(*end, end_width))
            )
            assert out[k][0] == pytest.approx(expected)
        else:
            assert out[k] == frames[k]


@pytest.mark.parametrize("seed", range(20))
def test_a_long_gap_or_another_face_is_not_bridged(seed):
    rng = random.Random(seed)
    max_gap = rng.randint(0, 8)
    width = rng.uniform(20, 200)
    frames = [[] for _ in range(30)]
    frames[2].append(box(300, 200, width))
    if rng.random() < 0.5:
        # The same face, one frame past the longest gap bridged.
        frames[2 + max_gap + 2].append(box(300, 200, width))
    elif rng.random() < 0.5:
        # Another face: more than half a width away.
        frames[3 + rng.randint(0, max_gap)].append(box(300 + width * rng.uniform(0.6, 3), 200, width))
    else:
        # Another face: twice as wide.
        frames[3 + rng.randint(0, max_gap)].append(box(300, 200, 2 * width))
    assert judge.bridged(frames, max_gap) == frames


def test_a_frame_holding_the_face_already_gets_no_second_box():
    frames = [[box(100, 100, 50)], [box(102, 100, 50)], [], [box(106, 100, 50)]]
    out = judge.bridged(frames, 4)
    assert [len(faces) for faces in out] == [1, 1, 1, 1]
    assert out[2][0] == pytest.approx(box(104, 100, 50))
