"""examples/python/track_corpus.py on a local Ray instance: four synthetic videos tracked in
parallel, each video's results the command line's own."""

import csv
import subprocess

import numpy as np
import pytest
import ray

import streampf
from conftest import load_script, rect_args, write_video


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=4, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_four_videos_tracked_as_ray_tasks_match_the_command_line(tmp_path, local_ray, streampf_cli):
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    videos = {}
    for seed in range(4):
        video = streampf.synthetic_faces(6, width=240, height=180, faces=1 + seed % 2, half_width=24.0, seed=20 + seed)
        path = corpus / f"clip{seed}.mp4"
        write_video(path, video["frames"])
        with open(corpus / f"clip{seed}.faces.csv", "w") as f:
            f.write("x,y,width,height\n")
            for r in video["rects"]:
                f.write(",".join(str(float(v)) for v in r) + "\n")
        videos[path] = video
    # Not a video: listed as failed, the others kept.
    (corpus / "broken.mp4").write_bytes(b"not a video")

    example = load_script("examples/python/track_corpus.py")
    out = tmp_path / "results"
    rows = example.track_corpus(corpus, out, options={"backend": "cpu", "particles": 64})

    by_video = {r["video"]: r for r in rows}
    assert by_video["broken.mp4"]["status"] == "failed" and by_video["broken.mp4"]["error"]
    with open(out / "summary.csv") as f:
        assert len(list(csv.DictReader(f))) == 5
    for path, video in videos.items():
        row = by_video[path.name]
        assert row["status"] == "ok", row
        assert (row["frames"], row["tracks"]) == (6, len(video["rects"]))
        cli_out = tmp_path / "cli" / path.stem
        subprocess.run(
            [streampf_cli, "face", "track", str(path), "--out", str(cli_out), "--backend", "cpu",
             "--particles", "64", "--seed", "1", "--quiet", *rect_args(video["rects"])],
            check=True,
        )
        ours = (out / path.stem / "states.csv").read_text()
        assert ours == (cli_out / "states.csv").read_text()
        arrays = np.load(out / path.stem / "states.npz")
        assert arrays["frame"].shape == (6 * len(video["rects"]),)
