"""``facegeom view character``, rendered headless (EGL; no display, no GPU).

A real Live Link take plays on the actor (the generic ICT face) and on the MakeHuman test head
(``tests/data/heads/makehuman_arkit.npz``: 52 ARKit shapes, six parts, cm, Y up). The real takes carry no
head rotation, so the view's own tests give a copy of the take a head turn (yaw, pitch, roll curves): the
character must show ``neutral + weights[t] @ deltas`` turned by that frame's rotation, the weights and
rotations being :func:`facegeom.pipelines.character.take_onto_character`'s. Widgets are driven through
:class:`facegeom.viewer.app.Widgets` and ``polyscope.frame_tick()`` (the panel's own code path).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

ps = pytest.importorskip("polyscope")

from tests.conftest import assert_not_blank, changed, cli_error, read_png  # noqa: E402

HEAD = Path(__file__).parent / "data" / "heads" / "makehuman_arkit.npz"
START, FRAMES = 100, 90


def columns(view, name) -> tuple[float, float]:
    """Screen x range of the face ``name`` as drawn now."""
    P = view.shown_faces()[name]
    xy = view.world_to_screen(P)
    return float(xy[:, 0].min()), float(xy[:, 0].max())


@pytest.fixture(scope="module")
def character():
    from facegeom.model import BlendshapeRig

    return BlendshapeRig.from_npz(HEAD)


@pytest.fixture(scope="module")
def turning_take(real_takes):
    """The first real take with a head turn added: yaw, pitch and roll curves (radians), eyes still."""
    from facegeom.io.takes import read_take

    tk = read_take(real_takes[0])
    T = tk.n_frames
    s = np.linspace(0.0, 1.0, T)
    R = np.zeros((T, 9))
    R[:, 0] = 0.5 * np.sin(2 * np.pi * 7 * s)  # yaw
    R[:, 1] = 0.2 * np.sin(2 * np.pi * 5 * s + 1.0)  # pitch
    R[:, 2] = 0.1 * np.cos(2 * np.pi * 3 * s)  # roll
    return replace(tk, rotations=R)


def make_view(face_model, take, character, **kw):
    from facegeom.viewer.character import CharacterView

    return CharacterView(face_model, take, character, **{"start": START, "frames": FRAMES, **kw})


# --------------------------------------------------------------------------- the view


def test_set_frame_shows_the_mapped_weights_turned_by_the_head(scene, face_model, turning_take, character):
    from facegeom.io.takes import ict_weights
    from facegeom.pipelines.character import take_onto_character

    played = take_onto_character(turning_take, character, START, FRAMES)
    W, R = played.solve.weights, played.solve.rotations
    assert W.shape == (FRAMES, character.n_shapes) and R.shape == (FRAMES, 3, 3)
    v = make_view(face_model, turning_take, character, frame=3)
    assert v.n_frames == FRAMES and v.frame == 3 and v.copies() == ["actor", "character"]
    np.testing.assert_array_equal(v.weights, W)
    v.setup_scene(900, 500, headless=True)
    A = ict_weights(turning_take, face_model.expression_names)[START:START + FRAMES]
    c = character.neutral.mean(axis=0)
    busy = np.abs(W).sum(axis=1)
    angles = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    for t in (int(np.argmax(busy)), int(np.argmax(angles)), FRAMES - 1, 0):
        v.set_frame(t)
        assert v.frame == t
        shown = v.shown_faces()
        want = c + (character.neutral + np.tensordot(W[t], character.deltas, axes=1) - c) @ R[t].T
        np.testing.assert_allclose(shown["character"] - v.shifts["character"], want, atol=1e-9)
        actor = face_model.neutral + np.tensordot(A[t], np.asarray(face_model.expression_deltas, float), axes=1)
        np.testing.assert_allclose(shown["actor"] - v.shifts["actor"], actor, atol=1e-4)
        a_mm, c_mm = v.displacement_mm()  # the expression only: the turn moves no colour
        np.testing.assert_allclose(c_mm, np.linalg.norm(np.tensordot(W[t], character.deltas, axes=1), axis=1) * 10)
        assert a_mm.shape == (face_model.n_vertices,)
    assert angles.max() > 10.0  # the turn is really there, so the check above can fail on it
    turned = int(np.argmax(angles))
    assert np.abs(v.character_face(turned) - v.character_pose(turned)).max() > 0.5  # cm
    # the row: the actor on the left, the character on its right, not overlapping however the head turns
    right = max(float((v.actor_face(t) + v.shifts["actor"])[:, 0].max()) for t in range(FRAMES))
    left = min(float((v.character_face(t) + v.shifts["character"])[:, 0].min()) for t in range(FRAMES))
    assert right < left


def test_screenshots_at_two_frames_differ(scene, face_model, real_takes, character, tmp_path):
    from facegeom.pipelines.character import take_onto_character

    W = take_onto_character(real_takes[0], character, START, FRAMES).solve.weights
    quiet, busy = int(np.argmin(W.sum(axis=1))), int(np.argmax(W.sum(axis=1)))
    assert W[busy].sum() - W[quiet].sum() > 0.5  # two frames whose faces are visibly apart
    v = make_view(face_model, real_takes[0], character, frame=quiet)
    v.setup_scene(1000, 560, headless=True)
    first = read_png(v.screenshot(tmp_path / "quiet.png"))
    assert_not_blank(first)
    v.set_frame(busy)
    second = read_png(v.screenshot(tmp_path / "busy.png"))
    assert changed(first, second, columns(v, "character")) > 200
    assert changed(first, second, columns(v, "actor")) > 200
    v.set_frame(quiet)  # the same frame draws the same faces
    assert changed(first, read_png(v.screenshot(tmp_path / "again.png"))) < 50


def test_panel_scrubs_plays_and_lists_the_top_shapes(scene, face_model, real_takes, character):
    v = make_view(face_model, real_takes[0], character)
    v.setup_scene(900, 500, headless=True)
    ps.frame_tick()
    v.ui.set("frame", 40)  # scrubbing: the slider
    ps.frame_tick()
    assert v.frame == 40 and not v.playing
    v.ui.set(">", True)
    ps.frame_tick()
    assert v.frame == 41
    top = json.loads(json.dumps(v.state()))["top"]  # the --state file's JSON
    w = v.weights[41]
    assert 1 <= len(top) <= 5 and [n for n, _ in top] == [v.names[i] for i in np.argsort(-w, kind="stable")[:len(top)]]
    assert top[0][1] == pytest.approx(w.max())
    assert v.state()["time_s"] == pytest.approx((START + 41) / v.fps, abs=0.02)
    v.ui.set("speed", 4.0)
    ps.frame_tick()
    assert v.speed == 4.0
    v.ui.set("play", True)
    ps.frame_tick()
    assert v.playing
    time.sleep(0.3)  # 4x real time at 30 fps: ~36 frames
    ps.frame_tick()
    assert v.frame != 41
    v.ui.set("pause", True)
    ps.frame_tick()
    held = v.frame
    time.sleep(0.1)
    ps.frame_tick()
    assert not v.playing and v.frame == held


# --------------------------------------------------------------------------- the command line


def test_cli_writes_a_png(tmp_path, face_model, real_takes):
    out = tmp_path / "character.png"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["FACEGEOM_DATA"] = face_model.path
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "character", "--take", str(real_takes[0]),
                        "--character", str(HEAD), "--start", "50", "--frames", "60", "--frame", "30", "--size",
                        "900x500", "--screenshot", str(out)], capture_output=True, text=True, env=env, timeout=120)
    if r.returncode != 0 and ("could not start a renderer" in r.stderr or "EGL" in r.stderr):
        pytest.skip(f"headless rendering unavailable: {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr
    assert f"wrote {out}" in r.stdout and "frames 50..109" in r.stdout
    img = read_png(out)
    assert img.shape == (500, 900, 3)
    assert_not_blank(img)


def test_make_images_renders_the_character_view(tmp_path, face_model, real_takes):
    """``make images``' character picture (the README's): the stylised MakeHuman rig playing a real take."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "facegeom.viewer.make_images", "--out", str(tmp_path), "--only",
                        "character", "--size", "800x450", "--data", face_model.path, "--takes",
                        str(Path(real_takes[0]).parent)], capture_output=True, text=True, env=env, timeout=120)
    if r.returncode != 0 and ("could not start a renderer" in r.stderr or "EGL" in r.stderr):
        pytest.skip(f"headless rendering unavailable: {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr
    img = read_png(tmp_path / "view-character.png")
    assert img.shape == (450, 800, 3)
    assert_not_blank(img)


def test_cli_without_display_says_how_to_run_headless(real_takes):
    from facegeom.viewer.app import NO_DISPLAY

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "character", "--take", str(real_takes[0]),
                        "--character", str(HEAD)], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2 and r.stderr.strip() == f"facegeom: error: {NO_DISPLAY}" and r.stdout == ""


def test_cli_mistakes_are_one_line(tmp_path, capsys, real_takes):
    take, png = str(real_takes[0]), str(tmp_path / "x.png")
    for args, words in (
        (["--take", str(tmp_path / "none.csv"), "--character", str(HEAD)], "none.csv"),
        (["--take", take, "--character", str(tmp_path / "none.npz")], "not found"),
        (["--take", take, "--character-names", str(HEAD)], "--character-names goes with --character"),
        (["--take", take], "--character RIG"),
        (["--take", take, "--character", str(HEAD), "--start", "999999"], "start 999999"),
        (["--take", take, "--character", str(HEAD), "--start", "10", "--frames", "999999"], "runs past its end"),
        (["--take", take, "--character", str(HEAD), "--frames", "10", "--frame", "10"], "--frame 10"),
    ):
        err = cli_error(capsys, ["view", "character", *args, "--screenshot", png])
        assert words in err, err
        assert not (tmp_path / "x.png").exists()
