"""The README's "Python API" examples run: each ```python block, in its own interpreter, in an empty folder.

A README example that no longer matches the code fails here (and so in CI).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
HEADING = "## Python API"


def python_blocks(text: str, heading: str = HEADING) -> list[str]:
    """The ```python blocks of the section under ``heading`` (up to the next ``## `` heading)."""
    start = text.index(heading + "\n")
    end = text.find("\n## ", start + len(heading))
    section = text[start:] if end < 0 else text[start:end]
    return re.findall(r"^```python\n(.*?)^```$", section, flags=re.DOTALL | re.MULTILINE)


BLOCKS = python_blocks(README.read_text(encoding="utf-8"))


def test_the_section_has_the_three_tasks():
    joined = "\n".join(BLOCKS)
    assert len(BLOCKS) >= 3
    for name in ("TangentDeformer", "TangentRetargeter", "SEMLSFitter"):
        assert name in joined, name


def test_the_extractor_stops_at_the_next_section():
    text = "# t\n## Python API\n```python\nA\n```\n```bash\nB\n```\n## Next\n```python\nC\n```\n"
    assert python_blocks(text) == ["A\n"]


@pytest.mark.parametrize("index", range(len(BLOCKS)), ids=lambda i: f"block{i + 1}")
def test_readme_example_runs(index, tmp_path, face_model):
    env = {**os.environ, "FACEGEOM_DATA": face_model.path}
    r = subprocess.run([sys.executable, "-c", BLOCKS[index]], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300, check=False)
    assert r.returncode == 0, f"README Python API block {index + 1} failed:\n{BLOCKS[index]}\n{r.stderr[-3000:]}"
    assert r.stdout.strip(), "an example should print what it found"
