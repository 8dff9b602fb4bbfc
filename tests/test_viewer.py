"""The polyscope viewer, rendered headless (EGL on Mesa's software renderer; no display, no GPU).

Polyscope is started once for this module; every test resets the scene. Widgets are
driven through :class:`viewer.app.Widgets` (a queued value is reported by the
widget exactly as a user's change), and ``polyscope.frame_tick()`` runs the
panel callback, so marker nudges, dragging, parameter changes and playback go
through the same code as in the window.
"""
import os
import subprocess
import sys

import numpy as np
import pytest

ps = pytest.importorskip("polyscope")

from tests.conftest import assert_not_blank, changed, read_png  # noqa: E402

from facegeom.errors import InputError  # noqa: E402
from facegeom.viewer.app import NO_DISPLAY, check_display, display_available  # noqa: E402


def columns(view, name, V) -> tuple[float, float]:
    """Screen x range of the copy ``name`` of a face ``V``."""
    lo = view.world_to_screen([V[:, 0].min() + view.shifts[name][0], V[:, 1].mean(), V[:, 2].max()])
    hi = view.world_to_screen([V[:, 0].max() + view.shifts[name][0], V[:, 1].mean(), V[:, 2].max()])
    return lo[0], hi[0]


# --------------------------------------------------------------------------- no display


def test_display_detection(monkeypatch):
    assert not display_available({}, "linux")
    assert display_available({"DISPLAY": ":0"}, "linux")
    assert display_available({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    assert display_available({}, "darwin")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(InputError, match="--screenshot PATH"):
        check_display(None)
    check_display("out.png")  # headless with a screenshot is fine
    monkeypatch.setenv("DISPLAY", ":0")
    check_display(None)


@pytest.mark.parametrize("sub", ["drive", "retarget", "animate", "fit"])
def test_cli_without_display_says_how_to_run_headless(sub):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", sub], capture_output=True, text=True, env=env,
                       timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip() == f"facegeom: error: {NO_DISPLAY}"
    assert "Traceback" not in r.stderr and r.stdout == ""


def test_cli_screenshot(tmp_path, face_model):
    out = tmp_path / "drive.png"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["FACEGEOM_DATA"] = face_model.path
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "drive", "--methods", "rbf", "--marker", "57",
                        "--nudge", "0,-8,0", "--size", "900x500", "--screenshot", str(out)],
                       capture_output=True, text=True, env=env, timeout=120)
    if r.returncode != 0 and "could not start a renderer" in r.stderr:
        pytest.skip(f"headless rendering unavailable: {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr
    assert f"wrote {out}" in r.stdout
    img = read_png(out)
    assert img.shape == (500, 900, 3)
    assert_not_blank(img)


# --------------------------------------------------------------------------- drive


def test_drive_view_nudge_drag_and_parameters(scene, face_model, tmp_path):
    from facegeom.viewer.drive import DriveView

    v = DriveView(face_model, "rbf;tangent", seed=1, expression="jaw-open")
    v.setup_scene(1200, 700, headless=True)
    assert_not_blank(read_png(v.screenshot(tmp_path / "drive.png")))
    before = v.image()
    err_before = {m: v.errors(m)["mean_mm"] for m in v.selected}
    for _ in range(2):
        ps.frame_tick()
    assert v.ticks >= 2

    # nudge marker 57 (lower lip) 8 mm down through the panel's sliders
    v.ui.set("marker", 57)
    v.ui.set("dy (mm)", -8.0)
    ps.frame_tick()
    assert v.marker == 57
    np.testing.assert_allclose(v.offsets[57], [0.0, -0.8, 0.0])
    assert np.count_nonzero(v.offsets) == 1
    for m in v.selected:
        assert v.deform_ms[m] > 0
        assert v.errors(m)["mean_mm"] != pytest.approx(err_before[m])
        assert np.allclose(v.results[m][v.case.handles[57]], v.positions()[57], atol=1e-6)
    after = v.image()
    X, T = v.case.source, v.case.target
    for m in v.selected:  # every method's face (geometry and error colours) changed...
        assert changed(before, after, columns(v, m, X)) > 200, m
    assert changed(before, after, columns(v, "source", X)) == 0  # ...the source did not
    # on the target only markers changed (57 moved: the target shows where the methods are driven to; 0 is no
    # longer the selected one): the face is the same
    d = np.abs(before.astype(int) - after.astype(int)).sum(axis=-1) > 30
    lo, hi = columns(v, "target", T)
    ys, xs = np.nonzero(d[:, int(lo):int(hi)])
    spots = v.world_to_screen(np.array([v.case.labels[57], v.positions()[57], v.case.labels[0]]) + v.shifts["target"])
    near = np.hypot(xs[:, None] + int(lo) - spots[:, 0], ys[:, None] - spots[:, 1]).min(axis=1)
    assert xs.size > 0 and near.max() < 12.0

    # drag marker 10 on the tangent face 25 px to the right, pressing 4 px off its centre (a person's aim):
    # the marker moves with the mouse, by the mouse's motion, and does not jump to the cursor
    s = v.world_to_screen(v.positions()[10] + v.shifts["tangent"])
    assert v.marker_at(s + [4.0, -3.0]) == ("tangent", 10)
    assert v.begin_drag(s + [4.0, -3.0])
    assert v.marker == 10
    cam = np.asarray(ps.get_camera_view_matrix()).copy()
    v.drag_to(s + [29.0, -3.0])
    v.end_drag()
    np.testing.assert_allclose(v.world_to_screen(v.positions()[10] + v.shifts["tangent"]), s + [25.0, 0.0],
                               atol=0.5)
    off = v.offsets[10]
    assert off[0] > 0.5 and abs(off[1]) < 0.1 * off[0]
    assert np.allclose(v.results["rbf"][v.case.handles[10]], v.positions()[10], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(ps.get_camera_view_matrix()), cam)
    assert not v.begin_drag((3.0, 3.0))  # empty background: nothing grabbed
    # the target's markers are draggable too; a release applies the last mouse position
    t = v.world_to_screen(v.positions()[20] + v.shifts["target"])
    assert v.begin_drag(t) and v.marker == 20
    v.end_drag(t + [0.0, 15.0])
    assert v.offsets[20][1] < -0.2 and v.drags == 2
    state = v.state()
    assert state["marker"] == 20 and state["near_marker_mm"]["target"] == 0.0
    assert all(state["near_marker_mm"][m] > 1.0 for m in v.selected)

    # a parameter (tangent d) refits tangent only; switching a method on fits it
    rbf_fit, tangent_before = v.deformers["rbf"], v.results["tangent"].copy()
    v.ui.set("tangent d", 1)
    ps.frame_tick()
    assert v.tangent_d == 1 and v.deformers["tangent"].d == 1 and v.deformers["rbf"] is rbf_fit
    assert not np.allclose(v.results["tangent"], tangent_before)
    v.ui.set("biharmonic", True)
    ps.frame_tick()
    assert v.selected == ["rbf", "tangent", "biharmonic"] and ps.has_surface_mesh("biharmonic")
    assert np.allclose(v.results["biharmonic"][v.case.handles], v.positions(), atol=1e-6)
    v.ui.set("reset all", True)
    ps.frame_tick()
    assert not v.offsets.any()


# --------------------------------------------------------------------------- playback


def test_retarget_view_playback(scene, face_model, tmp_path):
    from facegeom.viewer.playback import RetargetView, load_sequence

    seq = load_sequence(face_model, synthetic=True, frames=40, seed=3)
    v = RetargetView(face_model, seq, "copy;tangent", labels=5)
    assert set(v.frame_err) == {"copy", "tangent"}
    assert all(e.shape == (40,) and np.isfinite(e).all() for e in v.frame_err.values())
    v.setup_scene(1200, 700, headless=True)
    assert_not_blank(read_png(v.screenshot(tmp_path / "retarget.png")))
    first = v.image()
    assert v.frame == 0  # a screenshot does not advance playback

    v.ui.set("play", True)
    ps.frame_tick()
    assert v.playing and v.frame == 1
    for _ in range(3):
        ps.frame_tick()
    assert v.frame == 4
    v.ui.set("pause", True)
    ps.frame_tick()
    assert not v.playing and v.frame == 4
    peak = int(np.argmax(np.linalg.norm(seq.source - seq.source[0], axis=2).mean(axis=1)))
    v.ui.set("frame", peak)
    ps.frame_tick()
    assert v.frame == peak
    assert changed(first, v.image(), columns(v, "actor", v.actor[peak])) > 200
    v.set_frame(0)
    assert changed(first, v.image()) == 0


def test_animate_view(scene, face_model, tmp_path):
    from facegeom.viewer.playback import AnimateView, load_sequence

    seq = load_sequence(face_model, synthetic=True, frames=30, seed=4)
    v = AnimateView(face_model, seq, "copy;tangent", "rbf", labels=5)
    assert v.faces["tangent"].shape == (30, face_model.n_vertices, 3)
    assert np.isfinite(v.frame_err["tangent"]).all()
    v.setup_scene(1200, 700, headless=True)
    assert_not_blank(read_png(v.screenshot(tmp_path / "animate.png")))
    first = v.image()
    peak = int(np.argmax(np.linalg.norm(seq.source - seq.source[0], axis=2).mean(axis=1)))
    v.ui.set(">", True)
    ps.frame_tick()
    assert v.frame == 1
    v.ui.set("frame", peak)
    ps.frame_tick()
    assert v.frame == peak
    after = v.image()
    assert changed(first, after, columns(v, "tangent", v.truth[peak])) > 200
    assert changed(first, after, columns(v, "character", v.truth[peak])) > 200


# --------------------------------------------------------------------------- fit


def test_fit_view(scene, face_model, tmp_path):
    from facegeom.viewer.fit import FitView

    v = FitView(face_model, "sem;l1reg;pcadel", case=2, kind="mesh")
    assert set(v.results) == {"sem", "l1reg", "pcadel"}
    for r in v.results.values():
        assert r.weights.shape == (face_model.n_expressions,)
    v.setup_scene(1200, 700, headless=True)
    assert_not_blank(read_png(v.screenshot(tmp_path / "fit.png")))
    for _ in range(2):  # the panel (histograms, named bars) draws without error
        ps.frame_tick()
    before = v.image()
    v.ui.set("colour max (mm)", 0.2)
    ps.frame_tick()
    assert v.vmax == pytest.approx(0.2)
    assert changed(before, v.image(), columns(v, "pcadel", v.case.truth)) > 200
    with pytest.raises(InputError, match="correspondence"):
        FitView(face_model, "sem", mesh=face_model.neutral[:100])


# --------------------------------------------------------------------------- background workers (no window)


def test_background_fits_match_in_process(face_model):
    """The window's worker processes give the very faces the in-process path gives, and a method that fails
    in its worker is reported, not raised; views stop their workers on close."""
    from facegeom.viewer.drive import DriveView
    from facegeom.viewer.fit import FitView

    bg = DriveView(face_model, "rbf;tangent;bad=laplacian:mode=nonsense", seed=1, background=True)
    try:
        assert bg.busy() and set(bg.pending()) == {"rbf", "tangent", "bad"}  # nothing fitted in this process
        bg.wait()
        assert not bg.pending() and bg.status == {"rbf": "ready", "tangent": "ready", "bad": "failed"}
        assert "nonsense" in bg.failed["bad"]
        ref = DriveView(face_model, "rbf;tangent", seed=1)
        for m in ("rbf", "tangent"):
            np.testing.assert_allclose(bg.results[m], ref.results[m], atol=1e-9)
        bg.nudge(10, [0.0, -5.0, 0.0])
        ref.nudge(10, [0.0, -5.0, 0.0])
        assert set(bg.pending()) == {"rbf", "tangent"}  # the new positions are on their way
        bg.wait()
        for m in ("rbf", "tangent"):
            np.testing.assert_allclose(bg.results[m], ref.results[m], atol=1e-9)
        assert bg.state()["at_marker_mm"]["tangent"] < 1e-6
    finally:
        bg.close()
    assert not bg.workers

    fb = FitView(face_model, "sem;l1reg", case=1, kind="mesh", background=True)
    try:
        fb.wait()
        fr = FitView(face_model, "sem;l1reg", case=1, kind="mesh")
        for m in ("sem", "l1reg"):
            np.testing.assert_allclose(fb.results[m].weights, fr.results[m].weights, atol=1e-9)
        assert fb.vmax == fr.vmax
    finally:
        fb.close()


def test_view_animate_plays_a_solved_glb_and_livelink_take(tmp_path, face_model):
    """`facegeom solve` output (.glb, .npz curves, Live Link .csv) plays in `view animate --input` (headless PNG)."""

    from facegeom.io.takes import ict_to_arkit, write_livelink_csv
    from facegeom.model import BlendshapeRig
    from facegeom.pipelines.solve import read_animation
    from facegeom.viewer.playback import CurvesView

    rig = BlendshapeRig.from_face_model(face_model)
    T = 12
    W = np.zeros((T, rig.n_shapes))
    W[:, rig.shape_index("jawOpen")] = np.linspace(0, 1, T)
    from facegeom.io.gltf import write_rig_glb

    write_rig_glb(tmp_path / "a.glb", rig.neutral * 0.01, rig.triangles, rig.deltas * 0.01, rig.names, W, 24.0)
    A, names = ict_to_arkit(W, rig.names)
    write_livelink_csv(tmp_path / "a.csv", A, names, 60.0)
    np.savez(tmp_path / "a.npz", weights=W[:, ::-1], names=np.array(rig.names[::-1]), fps=30.0)
    for f, fps in (("a.glb", 24.0), ("a.csv", 60.0), ("a.npz", 30.0)):
        anim = read_animation(tmp_path / f, rig)
        assert anim.n_frames == T and anim.fps == pytest.approx(fps)
        assert np.abs(anim.frame(T - 1) - rig.evaluate(W[-1])).max() < 1e-4, f  # float32 in .glb/.csv
        view = CurvesView(anim, frame=5)
        assert view.copies() == ["animation"] and view.frame == 5
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "animate", "--input", str(tmp_path / "a.glb"),
                        "--frame", "11", "--screenshot", str(tmp_path / "shot.png")], capture_output=True, text=True,
                       timeout=300, env={**os.environ, "DISPLAY": ""})
    if r.returncode != 0 and "EGL" in r.stderr + r.stdout:
        pytest.skip("no EGL for a headless render here")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "shot.png").stat().st_size > 10_000
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "animate", "--input", str(tmp_path / "a.obj"),
                        "--screenshot", str(tmp_path / "x.png")], capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "cannot play '.obj'" in r.stderr and "Traceback" not in r.stderr


def test_min_fit_seconds_parses_the_slow_machine_setting():
    from facegeom.viewer.workers import min_fit_seconds

    assert min_fit_seconds("laplacian", "laplacian=6") == 6.0
    assert min_fit_seconds("laplacian", "rbf=2, laplacian=1.5") == 1.5
    assert min_fit_seconds("tangent", "laplacian=6") == 0.0
    assert min_fit_seconds("laplacian", "laplacian=x") == 0.0 and min_fit_seconds("laplacian", "laplacian=-1") == 0.0
    assert min_fit_seconds("laplacian", "") == 0.0
