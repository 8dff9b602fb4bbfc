"""`facegeom demo` end to end, as a user runs it: every step announced in order, the pictures and animations it
names exist and read back, the performances move, and the heads it ships are the test heads byte for byte."""
from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
STEPS = ("example inputs", "a face driven by 80 markers", "a photograph", "a scanned head", "an optical capture",
         "a real Live Link Face take", "a video of a person", "pictures")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_shipped_heads_are_the_test_heads_and_have_their_sources():
    from facegeom.cli import demo

    for path in (demo.SCAN, demo.STYLISED):
        assert path.is_file(), path
        assert _sha(path) == _sha(ROOT / "tests" / "data" / "heads" / path.name), path.name
        assert _sha(path) in (path.parent / "SOURCES.md").read_text()
    sources = (demo.HEADS / "SOURCES.md").read_text()
    assert "CC BY 3.0" in sources or "Attribution 3.0" in sources
    assert "CC0" in sources


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory, face_model):
    out = tmp_path_factory.mktemp("demo") / "facegeom-demo"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["FACEGEOM_DATA"] = face_model.path
    env["OPENBLAS_NUM_THREADS"] = "1"
    r = subprocess.run([sys.executable, "-m", "facegeom", "demo", "--out", str(out)], capture_output=True, text=True,
                       timeout=900, env=env, check=False)
    return out, r


def test_demo_runs_every_step_in_order_and_ends_with_its_results(demo_run):
    out, r = demo_run
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    lines = r.stdout.splitlines()
    announced = [m for m in (re.match(r"\[\s*([0-9.]+) s\] (.*)", line) for line in lines) if m]
    times = [float(m.group(1)) for m in announced]
    assert times == sorted(times) and times[0] == 0.0
    texts = [m.group(2) for m in announced]
    for step, text in zip(STEPS, texts):
        assert text.startswith(step), (step, text)
    assert texts[-1] == "done" and len(texts) == len(STEPS) + 1
    last = lines[-1]
    assert last.startswith(f"results in {out}: pictures driven.png, performances.png, photo.png; "
                           "animations capture_on_head.glb, take_on_character.glb, video_on_head.glb; "
                           "videos video_preview.mp4; meshes driven.ply, photo_fit.obj"), last
    for name in ("driven.png", "performances.png", "photo.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name


def test_demo_results_read_back_and_move(demo_run, face_model):
    from facegeom.io import read_mesh
    from facegeom.io.gltf import read_glb_animation

    out, r = demo_run
    assert r.returncode == 0
    V0, F0 = read_mesh(out / "examples" / "face.obj")
    V1, F1 = read_mesh(out / "driven.ply")
    assert np.array_equal(F0, F1) and 0.1 < np.abs(V1 - V0).max() < 5.0  # cm: a smile, not a blow-up
    for name, frames in (("capture_on_head.glb", 120), ("take_on_character.glb", 120), ("video_on_head.glb", 120)):
        a = read_glb_animation(out / name)
        assert a.weights.shape[0] == frames and np.isfinite(a.weights).all(), name
        assert a.weights.max() > 0.3 and a.weights.std(axis=0).max() > 0.05, name  # it performs
        assert len(a.names) >= 50, name
    head = read_glb_animation(out / "capture_on_head.glb")
    assert head.neutral.shape[0] == 8844  # the scanned head's own vertices
    character = read_glb_animation(out / "take_on_character.glb")
    assert character.neutral.shape[0] >= 4817  # the stylised character (its eyes, teeth and tongue are parts)
    assert (out / "video_preview.mp4").stat().st_size > 10_000
