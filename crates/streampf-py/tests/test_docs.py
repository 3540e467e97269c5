"""Every Python snippet of docs/PYTHON.md runs as written: the blocks in order, in one namespace,
as a reader pasting them would run them. Where the machine has only a software GPU adapter (CI's
Mesa lavapipe), the WGSL model is let use it, as it would use a hardware GPU."""

import re

import streampf

from conftest import REPO


def python_blocks(text):
    return re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)


def test_the_block_reader_finds_blocks():
    text = "a\n```python\nx = 1\n```\n```sh\nls\n```\n```python\ny = 2\n```\n"
    assert python_blocks(text) == ["x = 1\n", "y = 2\n"]


def test_every_python_snippet_of_the_python_doc_runs(gpu_backend, monkeypatch):
    blocks = python_blocks((REPO / "docs" / "PYTHON.md").read_text())
    assert len(blocks) >= 3, "docs/PYTHON.md lost its examples, or the block reader broke"
    original = streampf.ParticleFilter
    monkeypatch.setattr(
        streampf,
        "ParticleFilter",
        lambda *args, **kwargs: original(*args, **{"allow_software": True, **kwargs}),
    )
    namespace = {}
    for number, block in enumerate(blocks, 1):
        exec(compile(block, f"docs/PYTHON.md, python block {number}", "exec"), namespace)
    # What the snippets promise they make.
    assert namespace["estimate"].shape == (4, 2)
    assert set(namespace["result"]) >= {"pose", "spread", "joints", "ess", "confidence"}
