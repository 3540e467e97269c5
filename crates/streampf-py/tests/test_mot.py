"""`face track --synthetic --scenario`'s identity scores (face_tracker::mot: IDF1, IDP, IDR, MOTA,
identity switches) against py-motmetrics, the MOT benchmarks' reference implementation, on the
same files: the run's states.csv (its tracks) and mot_truth.csv (the scenario's true faces, with
the radius a track must lie within)."""

import csv
import re
import subprocess
from collections import defaultdict

import motmetrics
import numpy as np
import pytest

import streampf


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def motmetrics_scores(out):
    truth = defaultdict(list)
    for r in rows(out / "mot_truth.csv"):
        truth[int(r["frame"])].append((int(r["identity"]), float(r["x"]), float(r["y"]), float(r["radius"])))
    tracks = defaultdict(list)
    for r in rows(out / "states.csv"):
        if r["success"] == "1":
            # Scored by the person each track is (`identity`), as streampf scores them: a face
            # found again after its track ended keeps its identity under a new track number.
            tracks[int(r["frame"])].append((int(r["identity"]), float(r["tx"]), float(r["ty"])))
    frames = sorted(set(truth) | set(tracks))
    accumulator = motmetrics.MOTAccumulator(auto_id=True)
    for frame in frames:
        objects, hypotheses = truth[frame], tracks[frame]
        distances = np.full((len(objects), len(hypotheses)), np.nan)
        for i, (_, x, y, radius) in enumerate(objects):
            for j, (_, hx, hy) in enumerate(hypotheses):
                d = np.hypot(x - hx, y - hy)
                if d <= radius:
                    distances[i, j] = d
        accumulator.update([o[0] for o in objects], [h[0] for h in hypotheses], distances)
    names = ["idf1", "idp", "idr", "mota", "num_switches", "num_matches", "num_false_positives", "num_misses"]
    summary = motmetrics.metrics.create().compute(accumulator, metrics=names, name="run")
    return {name: summary[name].iloc[0] for name in names}


def printed_scores(text):
    m = re.search(
        r"identities: IDF1 ([\d.]+) \(IDP ([\d.]+), IDR ([\d.]+)\), (\d+) identity switches, MOTA (-?[\d.]+) "
        r"over (\d+) true face-frames \((\d+) matched, (\d+) missed, (\d+) false positives\)",
        text,
    )
    assert m, text
    idf1, idp, idr, switches, mota, gt, matched, missed, fp = m.groups()
    return {
        "idf1": float(idf1),
        "idp": float(idp),
        "idr": float(idr),
        "num_switches": int(switches),
        "mota": float(mota),
        # py-motmetrics counts a match that switched identity as a switch only.
        "num_matches": int(matched) - int(switches),
        "num_misses": int(missed),
        "num_false_positives": int(fp),
        "ground_truth": int(gt),
    }


def test_the_scenarios_scores_are_py_motmetrics_scores(tmp_path, streampf_cli):
    out = tmp_path / "scenario"
    run = subprocess.run(
        [streampf_cli, "face", "track", "--synthetic", "--scenario", "exits-and-crossings", "--frames", "90",
         "--width", "640", "--height", "480", "--backend", "cpu", "--particles", "200", "--out", str(out)],
        check=True, capture_output=True, text=True,
    )
    ours = printed_scores(run.stdout)
    reference = motmetrics_scores(out)
    for name in ["num_switches", "num_matches", "num_misses", "num_false_positives"]:
        assert ours[name] == reference[name], (name, ours, reference)
    for name in ["idf1", "idp", "idr", "mota"]:
        assert abs(ours[name] - reference[name]) <= 1e-6, (name, ours, reference)
    assert ours["num_matches"] + ours["num_switches"] + ours["num_misses"] == ours["ground_truth"]
    # The scenario's first face leaves and comes back: frames without it are no true faces.
    truth = rows(out / "mot_truth.csv")
    frames_with_face_0 = {int(r["frame"]) for r in truth if r["identity"] == "0"}
    assert 0 < len(frames_with_face_0) < 90


def random_run(rng, frames, identities, tracks):
    """Objects on random walks and tracks that follow them with noise, swap, drop out and
    appear from nowhere: every path of the scorers (switches, misses, false positives)."""
    truth, hypotheses = [], []
    position = rng.uniform(0, 400, size=(identities, 2))
    follows = rng.permutation(tracks)[:identities] if tracks >= identities else None
    for frame in range(frames):
        position += rng.normal(0, 8, size=position.shape)
        if frame % 7 == 6 and identities > 1:  # two tracks swap their objects
            a, b = rng.choice(identities, size=2, replace=False)
            if follows is not None:
                follows[a], follows[b] = follows[b], follows[a]
        for i in range(identities):
            if rng.random() < 0.85:
                truth.append((frame, i, *position[i], float(rng.uniform(10, 40))))
            if follows is not None and rng.random() < 0.8:
                hypotheses.append((frame, int(follows[i]), *(position[i] + rng.normal(0, 12, 2))))
        if rng.random() < 0.3:
            hypotheses.append((frame, 100 + frame, *rng.uniform(0, 400, 2)))
    return truth, hypotheses


def reference(truth, hypotheses):
    by_frame = defaultdict(lambda: ([], []))
    for row in truth:
        by_frame[row[0]][0].append(row[1:])
    for row in hypotheses:
        by_frame[row[0]][1].append(row[1:])
    accumulator = motmetrics.MOTAccumulator(auto_id=True)
    for frame in sorted(by_frame):
        objects, tracks = by_frame[frame]
        distances = np.full((len(objects), len(tracks)), np.nan)
        for i, (_, x, y, radius) in enumerate(objects):
            for j, (_, hx, hy) in enumerate(tracks):
                # The scorer reads f32 values: compare on the same numbers.
                d = np.hypot(np.float64(np.float32(x)) - np.float64(np.float32(hx)),
                             np.float64(np.float32(y)) - np.float64(np.float32(hy)))
                if d <= np.float32(radius):
                    distances[i, j] = d
        accumulator.update([o[0] for o in objects], [t[0] for t in tracks], distances)
    names = ["idf1", "idp", "idr", "mota", "num_switches", "num_matches", "num_false_positives", "num_misses"]
    summary = motmetrics.metrics.create().compute(accumulator, metrics=names, name="run")
    return {name: summary[name].iloc[0] for name in names}


def test_mot_scores_are_py_motmetrics_scores_on_fresh_random_runs():
    seed = int(np.random.default_rng().integers(2**63))
    rng = np.random.default_rng(seed)
    print(f"seed {seed}")  # a failure's output names its seed
    switches = 0
    for _ in range(12):
        truth, hypotheses = random_run(rng, int(rng.integers(1, 60)), int(rng.integers(1, 5)), int(rng.integers(1, 7)))
        ours = streampf.mot_scores(truth, hypotheses)
        theirs = reference(truth, hypotheses)
        for name in ["num_switches", "num_matches", "num_misses", "num_false_positives"]:
            assert ours[name] == theirs[name], (name, ours, theirs)
        for name in ["idf1", "idp", "idr", "mota"]:
            if np.isnan(theirs[name]):  # py-motmetrics' 0/0 (no objects, no tracks)
                continue
            # Equal infinities too: MOTA is 1 - errors / 0 = -inf for a run with no true face
            # and some track, in both.
            same = ours[name] == theirs[name] or abs(ours[name] - theirs[name]) <= 1e-9
            assert same, (name, ours, theirs)
        switches += ours["num_switches"]
    assert switches > 0, "no run switched identities: the comparison missed that path"


def test_mot_scores_refuses_bad_rows():
    with pytest.raises(ValueError, match="finite"):
        streampf.mot_scores([(0, 0, float("nan"), 1.0, 5.0)], [])
    with pytest.raises(ValueError, match="finite"):
        streampf.mot_scores([(0, 0, 1.0, 1.0, 1e39)], [])
    with pytest.raises(ValueError, match="twice"):
        streampf.mot_scores([], [(0, 1, 1.0, 1.0), (0, 1, 2.0, 2.0)])
    with pytest.raises(ValueError, match=">= 0"):
        streampf.mot_scores([(-1, 0, 1.0, 1.0, 5.0)], [])
