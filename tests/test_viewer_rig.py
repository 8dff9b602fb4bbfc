"""``facegeom view rig`` and ``facegeom view transfer``, rendered headless (EGL; no display, no GPU).

The rig is the MakeHuman test head (``tests/data/heads/makehuman_arkit.npz``: 52 ARKit shapes, six parts,
cm, Y up); the transfer view registers that same file's neutral as a head, once for the module (~10 s).
Widgets are driven through :class:`facegeom.viewer.app.Widgets` and ``polyscope.frame_tick()``, the landmark
drag through the methods the mouse calls, so the tests run the panel's and the mouse's own code paths.
"""
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ps = pytest.importorskip("polyscope")

from tests.conftest import assert_not_blank, changed, read_png  # noqa: E402

from facegeom.errors import InputError  # noqa: E402
from facegeom.viewer.app import BUSY_FPS  # noqa: E402

HEAD = Path(__file__).parent / "data" / "heads" / "makehuman_arkit.npz"


def cli(*args, env_extra=None, timeout=120):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "facegeom", "view", *map(str, args)], capture_output=True,
                          text=True, env=env, timeout=timeout)


def skip_without_renderer(r):
    if r.returncode != 0 and ("could not start a renderer" in r.stderr or "EGL" in r.stderr):
        pytest.skip(f"headless rendering unavailable: {r.stderr.strip()}")


def one_line_error(r, *words):
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip()
    assert "\n" not in err and err.startswith("facegeom: error: ") and "Traceback" not in err, err
    for w in words:
        assert w in err, err


@pytest.fixture(scope="module")
def rig():
    from facegeom.model import BlendshapeRig

    return BlendshapeRig.from_npz(HEAD)


@pytest.fixture(scope="module")
def transferred(face_model):
    """The test head registered and its shapes transferred, once for the module: ``(V, F, parts, character,
    result)``."""
    from facegeom.model import BlendshapeRig
    from facegeom.viewer.rig import register_and_transfer

    r, _, _ = BlendshapeRig.read_npz(HEAD)
    ch, res = register_and_transfer(face_model, r.neutral, r.triangles, parts=r.parts, path=HEAD)
    return r.neutral, r.triangles, r.parts, ch, res


# --------------------------------------------------------------------------- view rig


@pytest.mark.parametrize("sub", ["rig", "transfer"])
def test_cli_without_display_says_how_to_run_headless(sub):
    from facegeom.viewer.app import NO_DISPLAY

    r = cli(sub, HEAD)
    one_line_error(r)
    assert r.stderr.strip() == f"facegeom: error: {NO_DISPLAY}" and r.stdout == ""


def test_rig_view_sliders_pose_and_colour(scene, rig, tmp_path):
    from facegeom.viewer.rig import RigView

    v = RigView(rig, path=HEAD, weights={"jawOpen": 1.0})
    assert v.picked == "jawOpen" and v.active() == {"jawOpen": 1.0}
    v.setup_scene(900, 500, headless=True)
    open_img = read_png(v.screenshot(tmp_path / "open.png"))
    assert_not_blank(open_img)
    j = rig.shape_index("jawOpen")
    np.testing.assert_allclose(v.shown_faces()["rig"], rig.neutral + rig.deltas[j])
    state = v.state()
    assert state["weights"] == {"jawOpen": 1.0}
    assert state["max_mm"] == pytest.approx(np.linalg.norm(rig.deltas[j], axis=1).max() * 10.0)

    v.ui.set("reset", True)  # the panel's reset: the neutral, no colour
    ps.frame_tick()
    assert not v.weights.any() and v.state()["max_mm"] == 0.0
    np.testing.assert_allclose(v.shown_faces()["rig"], rig.neutral)
    neutral_img = read_png(v.screenshot(tmp_path / "neutral.png"))
    assert changed(open_img, neutral_img) > 500

    v.ui.set("jawOpen", 0.5)  # the shape's own slider in the scrolled list
    ps.frame_tick()
    assert v.active() == {"jawOpen": 0.5}
    v.ui.set("shape", "eyeBlinkLeft")  # the quick pick: a combo, then its weight
    v.ui.set("weight", 0.75)
    ps.frame_tick()
    assert v.picked == "eyeBlinkLeft" and v.active() == {"jawOpen": 0.5, "eyeBlinkLeft": 0.75}
    assert "jawOpen" in v.ui.rects and "weight" in v.ui.rects
    with pytest.raises(InputError, match=r"makehuman_arkit\.npz: no blendshape called 'jawOpn'; did you mean "
                                         r"'jawOpen'"):
        v.set_weight("jawOpn", 1.0)


def test_cli_view_rig_screenshot_and_mistakes(tmp_path):
    one = cli("rig", HEAD, "--shape", "jawOpen", "--weight", "1", "--size", "800x500", "--screenshot",
              tmp_path / "w1.png")
    skip_without_renderer(one)
    assert one.returncode == 0, one.stderr
    zero = cli("rig", HEAD, "--shape", "jawOpen", "--weight", "0", "--size", "800x500", "--screenshot",
               tmp_path / "w0.png")
    assert zero.returncode == 0, zero.stderr
    a, b = read_png(tmp_path / "w1.png"), read_png(tmp_path / "w0.png")
    assert a.shape == (500, 800, 3)
    assert_not_blank(a)
    assert changed(a, b) > 500  # the open jaw: another shape and other colours

    r = cli("rig", HEAD, "--shape", "jawOpn", "--screenshot", tmp_path / "x.png")
    one_line_error(r, str(HEAD), "'jawOpn'", "'jawOpen'")
    one_line_error(cli("rig", tmp_path / "missing.npz", "--screenshot", tmp_path / "x.png"), "missing.npz")
    one_line_error(cli("rig", HEAD, "--weight", "0.5", "--screenshot", tmp_path / "x.png"), "--shape")
    assert not (tmp_path / "x.png").exists()


# --------------------------------------------------------------------------- view transfer


def test_transfer_view_landmarks_save_and_drag(scene, face_model, transferred, tmp_path):
    from facegeom.methods.transfer import read_head_landmarks
    from facegeom.viewer.rig import TransferView

    V, F, parts, ch, res = transferred
    save = tmp_path / "lm.csv"
    v = TransferView(face_model, ch, res, head_path=HEAD, save_path=save, weights={"jawOpen": 1.0})
    skin = set(ch.pieces[0].vertices.tolist())
    ids = v.landmarks
    assert ids.shape == (68,) and np.unique(ids).size == 68 and all(int(i) in skin for i in ids)
    # each landmark sits on the skin vertex closest to the registered template's landmark (a few
    # move to the next one when two would share a vertex)
    want = ch.registration.template[face_model.landmarks]
    sk = np.array(sorted(skin))
    nearest = sk[np.argmin(np.linalg.norm(V[sk][None] - want[:, None], axis=2), axis=1)]
    assert (ids == nearest).sum() >= 60

    v.setup_scene(1200, 700, headless=True)
    img = read_png(v.screenshot(tmp_path / "transfer.png"))
    assert_not_blank(img)
    faces = v.shown_faces()
    assert set(faces) == {"ict", "character"}
    j = list(face_model.expression_names).index("jawOpen")
    np.testing.assert_allclose(faces["ict"], face_model.neutral + face_model.expression_deltas[j])
    # one slider drives both: the character's jaw opens too
    moved = np.linalg.norm(faces["character"] - (v.rest + v.shifts["character"]), axis=1)
    assert moved.max() > 0.5  # cm

    # the overlay checkbox hides the registered template over the character (and only there)
    before = v.image()
    v.ui.set("registered template over the character", False)
    ps.frame_tick()
    assert not v.overlay and not ps.get_surface_mesh("template").is_enabled()
    after = v.image()
    xs = v.world_to_screen(np.array([[faces["ict"][:, 0].min(), 0, 10], [faces["ict"][:, 0].max(), 0, 10]]))[:, 0]
    assert changed(before, after) > 500 and changed(before, after, (xs[0] + 2, xs[1] - 2)) == 0

    # saving writes what `facegeom transfer --landmarks` reads: the same 68 ids
    assert v.save_landmarks() == save
    np.testing.assert_array_equal(read_head_landmarks(save, V.shape[0]), ids)

    # the mouse's path: grab landmark 33 (nose tip) and drag it 30 px down: it snaps to another skin vertex
    k = 33
    old = int(v.landmarks[k])
    s = v.world_to_screen(v.landmark_points()[k])
    assert v.landmark_at(s + [3.0, -2.0]) == k
    assert v.begin_drag(s + [3.0, -2.0]) and v.landmark == k and v.state()["dragging"]
    v.drag_to(s + [3.0, 28.0])
    v.end_drag()
    new = int(v.landmarks[k])
    assert new != old and new in skin and v.drags == 1
    p = v.world_to_screen(v.landmark_points()[k])
    assert 15.0 < p[1] - s[1] < 45.0 and abs(p[0] - s[0]) < 12.0
    assert np.unique(v.landmarks).size == 68
    v.ui.set("save landmarks", True)  # the panel's button
    ps.frame_tick()
    got = read_head_landmarks(save, V.shape[0])
    assert got[k] == new and (np.delete(got, k) == np.delete(ids, k)).all()
    assert not v.begin_drag((3.0, 3.0))  # the background: nothing grabbed
    with pytest.raises(InputError, match="already carries landmark"):
        v.set_landmark(0, int(v.landmarks[1]))


def test_transfer_view_reregisters_in_the_background(scene, face_model, transferred):
    from facegeom.viewer.rig import TransferView

    V, F, parts, ch, res = transferred
    v = TransferView(face_model, ch, res, head_path=HEAD, background=True)
    try:
        v.setup_scene(900, 500, headless=True)
        ps.frame_tick()
        assert "save landmarks" not in v.ui.rects  # no --save-landmarks: no button (the panel says why)
        with pytest.raises(InputError, match="--save-landmarks"):
            v.save_landmarks()
        v.set_landmark(33, int(v.landmarks[33]))  # no change: still 68 distinct landmarks
        edited = v.landmarks.copy()
        v.ui.set("re-register with these landmarks", True)
        ps.frame_tick()
        assert v.registering() and v.state()["registering"] and v.pending() == ["registration"]
        t0, ticks0, gaps = time.monotonic(), v.ticks, []
        while v.registering() and time.monotonic() - t0 < 120:
            t = time.monotonic()
            ps.frame_tick()  # the window keeps drawing meanwhile (a registration in this process: one 10 s frame)
            gaps.append(time.monotonic() - t)
            time.sleep(1.0 / BUSY_FPS)  # the window's frame rate while busy
        assert not v.registering(), "the background registration did not finish"
        assert v.ticks - ticks0 > 20 and np.median(gaps) < 0.25
        assert v.registrations == 2 and v.character is not ch
        np.testing.assert_array_equal(v.landmarks, edited)
        assert ps.has_surface_mesh("character") and ps.has_surface_mesh("template")
        assert any("registered again" in m for m in v.messages)
    finally:
        v.close()


def test_cli_view_transfer_mistakes_end_in_one_line(tmp_path, face_model):
    env = {"FACEGEOM_DATA": face_model.path}
    shot = tmp_path / "x.png"
    one_line_error(cli("transfer", tmp_path / "nope.obj", "--screenshot", shot, env_extra=env), "nope.obj")
    one_line_error(cli("transfer", HEAD, "--piece", "eye_L", "--screenshot", shot, env_extra=env),
                   "--piece takes NAME=ROLE")
    one_line_error(cli("transfer", HEAD, "--piece", "nose=eye", "--screenshot", shot, env_extra=env),
                   "no piece called 'nose'")
    one_line_error(cli("transfer", HEAD, "--shape", "jawOpn", "--screenshot", shot, env_extra=env),
                   "'jawOpn'", "'jawOpen'")
    assert not shot.exists()


def test_cli_view_transfer_screenshot(tmp_path, face_model):
    """The whole command: registration progress printed, then the side-by-side view rendered headless."""
    shot = tmp_path / "transfer.png"
    r = cli("transfer", HEAD, "--engine", "nearest", "--shape", "jawOpen", "--weight", "0.8", "--size", "1000x560",
            "--save-landmarks", tmp_path / "lm.csv", "--screenshot", shot, env_extra={"FACEGEOM_DATA": face_model.path},
            timeout=300)
    skip_without_renderer(r)
    assert r.returncode == 0, r.stderr
    for line in ("makehuman_arkit.npz: 4817 vertices", "rigid fit:", "identity fit:", "non-rigid fit:",
                 "transfer (nearest): 53 shapes", f"wrote {shot}"):
        assert line in r.stdout, r.stdout
    img = read_png(shot)
    assert img.shape == (560, 1000, 3)
    assert_not_blank(img)
    assert not (tmp_path / "lm.csv").exists()  # written only by the panel's button
