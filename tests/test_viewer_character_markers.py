"""``facegeom view character --route markers``, rendered headless (EGL; no display, no GPU).

A real Live Link take plays on the actor and, through markers, on a scanned head (``lee_perry_smith.ply``, the
head ``test_character.py`` drives through markers). The head is given to ``facegeom transfer`` once for the
session (``scanned_head_rig``) and its stored registration handed to every view; the route itself (markers,
key frames, retargeting, deformer) is built by each view. Markers are dragged with the drive viewer's calls
(``begin_drag`` / ``drag_to`` / ``end_drag`` at a marker's screen position), widgets through
:class:`facegeom.viewer.app.Widgets` and ``polyscope.frame_tick()`` (the panel's own code path).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

ps = pytest.importorskip("polyscope")

from tests.conftest import assert_not_blank, changed, cli_error, read_png  # noqa: E402

HEAD = Path(__file__).parent / "data" / "heads" / "lee_perry_smith.ply"
START, FRAMES, KEYS = 100, 60, 4


@pytest.fixture(scope="module")
def head(scanned_head_rig):
    from facegeom.pipelines.character import read_head

    return read_head(scanned_head_rig)


@pytest.fixture(scope="module")
def registered(face_model, head, scanned_head_rig):
    from facegeom.pipelines.character import stored_registration

    V, F, _ = head
    return stored_registration(face_model, scanned_head_rig, V, F)


def make_view(face_model, take, head, registered, **kw):
    from facegeom.viewer.character_markers import MarkerCharacterView

    V, F, parts = head
    kw = {"start": START, "frames": FRAMES, "n_keys": KEYS, "character": registered, "echo": lambda line: None,
          "character_name": HEAD.name, **kw}
    return MarkerCharacterView(face_model, take, V, F, parts=parts, **kw)


def lone_marker(view) -> int:
    """The marker farthest on screen from every other one (a press near it grabs nothing else)."""
    xy = view.marker_screen()["character"]
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(xy)) * 1e9
    return int(np.argmax(d.min(axis=1)))


def drag(view, m: int, dy_px: float) -> None:
    """Drag marker ``m`` of the current key ``dy_px`` pixels down, pressing 2 px off its centre."""
    s = view.marker_screen()["character"][m]
    assert view.marker_at(s + [2.0, -1.0]) == ("character", m)
    assert view.begin_drag(s + [2.0, -1.0])
    view.drag_to(s + [2.0, -1.0 + dy_px / 2])
    view.end_drag(s + [2.0, -1.0 + dy_px])


# --------------------------------------------------------------------------- the view


def test_view_builds_plays_and_shows_markers_on_key_frames(scene, face_model, real_takes, head, registered, tmp_path):
    v = make_view(face_model, real_takes[0], head, registered, frame=0, save_path=tmp_path / "k.csv")
    assert v.keys.size == KEYS and v.copies() == ["actor", "character"] and v.n_frames == FRAMES
    off = int(next(t for t in range(FRAMES) if t not in v.keys))
    v.set_frame(off)
    v.setup_scene(1000, 560, headless=True)
    ps.frame_tick()
    st = v.state()
    assert st["keys"] == v.keys.tolist() and st["key"] is None and not st["editable"] and st["edited"] == 0
    assert not st["busy"] and st["labels_path"] == str(tmp_path / "k.csv")
    assert v.marker_screen() == {} and not ps.get_point_cloud("markers").is_enabled()
    # the character off the keys is the route's frame, in the model's frame (the registration undone)
    r = v.registration
    np.testing.assert_allclose(v.shown_faces()["character"] - v.shifts["character"],
                               (v.route.drive(off, off + 1)[0] - r.t) @ r.R / r.scale, atol=1e-9)
    first = read_png(v.screenshot(tmp_path / "off.png"))
    assert_not_blank(first)
    v.ui.set("key 2", True)  # the panel's key buttons: pause on the key, its markers shown
    ps.frame_tick()
    assert v.frame == v.keys[2] and not v.playing and v.state()["editable"]
    assert ps.get_point_cloud("markers").is_enabled() and len(v.marker_screen()["character"]) == 80
    second = read_png(v.screenshot(tmp_path / "key.png"))
    lo, hi = v.state()["copies"]["character"][0::2]
    assert changed(first, second, (lo, hi)) > 200  # another frame, and the markers drawn
    v.ui.set("next key >", True)
    ps.frame_tick()
    assert v.frame == v.keys[3]
    v.ui.set("next key >", True)  # wraps
    ps.frame_tick()
    assert v.frame == v.keys[0]
    v.ui.set("< prev key", True)
    ps.frame_tick()
    assert v.frame == v.keys[3]
    v.ui.set("play", True)  # playing: no markers
    ps.frame_tick()
    assert v.playing and v.marker_screen() == {} and not v.state()["editable"]
    time.sleep(0.2)
    ps.frame_tick()
    assert v.frame != v.keys[3]


def test_drag_at_a_key_moves_its_label_and_the_route_follows_in_the_background(scene, face_model, real_takes, head,
                                                                              registered, monkeypatch):
    from facegeom.pipelines.character_markers import MarkerRoute

    v = make_view(face_model, real_takes[0], head, registered, n_keys=6)
    v.setup_scene(1000, 560, headless=True)
    k = 2  # a key with keys on both sides (past the last key the retargeter extrapolates: an edit may grow there)
    v.go_to_key(k)
    ps.frame_tick()
    m = lone_marker(v)
    old_route, old_labels = v.route, v.labels.copy()
    tk = int(v.keys[k])
    far = int(np.argmax(np.abs(np.arange(FRAMES) - tk)))  # the frame of the window farthest from the key
    assert far not in v.keys
    slow = MarkerRoute.relabel

    def relabel(self, labels, retargeter=None):  # a slow machine: the refit takes a second
        time.sleep(1.0)
        return slow(self, labels, retargeter)

    monkeypatch.setattr(MarkerRoute, "relabel", relabel)
    drag(v, m, -10.0)  # 10 px up
    assert v.drags == 1 and v.marker == m
    moved = v.labels[k, m] - old_labels[k, m]
    up = v.to_display(v.labels[k, m])[1] - v.to_display(old_labels[k, m])[1]
    assert up > 0.3  # cm in the model's frame: up, as the mouse went
    dist = float(np.linalg.norm(moved))
    changed_markers = np.argwhere(np.any(v.labels != old_labels, axis=2))
    assert changed_markers.tolist() == [[k, m]]  # only that label
    st = v.state()
    assert st["edited"] == 1 and st["edited_per_key"][k] == 1 and st["busy"]
    mv = int(v.route.marker_vertices[m])
    # the key frame shows the new label at once (the head driven by the labels), before the route is back
    assert v.route is old_route
    now = v.head_face(tk)  # the head's units
    np.testing.assert_allclose(now, old_route.deform(v.labels[k][None])[0], atol=1e-9)  # driven by the labels
    # the deformer takes markers as measured (soft labels): the vertex follows the drag, not all the way
    assert float((now[mv] - old_route.drive(tk, tk + 1)[0][mv]) @ moved) > 0.3 * dist ** 2
    # the window keeps drawing and playing the old route while the refit runs
    v.play(True)
    t0, ticks, frame0 = time.monotonic(), v.ticks, v.frame
    while time.monotonic() - t0 < 0.5:
        ps.frame_tick()
    assert v.ticks - ticks >= 5 and v.frame != frame0 and v.route is old_route and v.state()["busy"]
    np.testing.assert_allclose(v.head_face(far), old_route.drive(far, far + 1)[0])
    v.play(False)
    t0 = time.monotonic()
    while v.state()["busy"] and time.monotonic() - t0 < 30:  # the window's loop installs the newest route
        ps.frame_tick()
        time.sleep(0.02)
    assert v.route is not old_route and v.refits >= 1 and not v.state()["busy"]
    np.testing.assert_array_equal(v.route.labels[k], v.labels[k])
    np.testing.assert_allclose(v.route.markers[tk], v.labels[k], atol=1e-4)  # the retargeted key frame: the labels
    np.testing.assert_allclose(v.route.drive(tk, tk + 1)[0], old_route.deform(v.labels[k][None])[0], atol=1e-4)
    change = {t: float(np.linalg.norm(v.route.markers[t, m] - old_route.markers[t, m])) for t in range(FRAMES)}
    assert change[tk] > 0.8 * dist
    # elsewhere the edit reaches the frames whose actor pose is like the key's (the retargeter maps poses, not
    # times: in a calm window that can be most frames), while every other key keeps its own labels
    for j, t in enumerate(v.keys):
        if j != k:
            assert change[int(t)] < 0.1 * change[tk]  # the other keys keep their labels


def test_no_drag_off_the_keys_or_while_playing_and_resets(scene, face_model, real_takes, head, registered):
    v = make_view(face_model, real_takes[0], head, registered)
    v.setup_scene(1000, 560, headless=True)
    v.go_to_key(0)
    m = lone_marker(v)
    where = v.marker_screen()["character"][m]
    before = v.labels.copy()
    v.set_frame(int(v.keys[0]) + 1)  # one frame off the key: nothing to grab where the marker was
    assert int(v.keys[0]) + 1 not in v.keys
    assert v.marker_at(where) is None and not v.begin_drag(where)
    v.drag_to(where + [0.0, -30.0])
    v.end_drag(where + [0.0, -30.0])
    v.set_frame(int(v.keys[0]))
    v.play(True)  # on the key but playing
    assert not v.begin_drag(where)
    v.play(False)
    np.testing.assert_array_equal(v.labels, before)
    assert v.version == 0 and v.drags == 0 and not v.state()["busy"] and v.state()["edited"] == 0
    # resets: the proposal back
    v.set_frame(int(v.keys[0]))
    drag(v, m, 12.0)
    v.set_label(0, (m + 1) % 80, v.labels[0, (m + 1) % 80] + [0.0, 0.002, 0.0])
    assert v.state()["edited"] == 2
    v.marker = m
    v.ui.set("reset marker", True)
    ps.frame_tick()
    np.testing.assert_array_equal(v.labels[0, m], v.route.proposed[0, m])
    assert v.state()["edited"] == 1
    v.ui.set("reset key", True)
    ps.frame_tick()
    np.testing.assert_array_equal(v.labels[0], v.route.proposed[0])
    assert v.state()["edited"] == 0
    v.wait()
    assert not v.state()["busy"]
    np.testing.assert_allclose(v.route.markers, make_view(face_model, real_takes[0], head, registered).route.markers)


# --------------------------------------------------------------------------- saving, and the command line


def test_saved_labels_read_back_and_drive_animate(scene, face_model, real_takes, head, registered, tmp_path, capsys,
                                                  scanned_head_rig):
    from facegeom.cli.main import main
    from facegeom.io.gltf import read_glb_animation
    from facegeom.io.key_labels import read_key_labels

    out = tmp_path / "labels.csv"
    lines = []
    v = make_view(face_model, real_takes[0], head, registered, save_path=out, echo=lines.append)
    v.setup_scene(1000, 560, headless=True)
    k = 2
    v.go_to_key(k)
    m = lone_marker(v)
    drag(v, m, 12.0)
    v.ui.set("save labels", True)
    ps.frame_tick()
    assert out.is_file() and lines and str(out.absolute()) in lines[-1]
    assert v.state()["saved"] == lines[-1]
    kl = read_key_labels(out, 80)
    np.testing.assert_array_equal(kl.frames, v.keys + START)  # take frames
    np.testing.assert_array_equal(kl.labels, v.labels)  # every marker of every key, the edited one included
    assert not np.array_equal(kl.labels[k, m], v.route.proposed[k, m])
    np.testing.assert_array_equal(kl.vertices, v.route.marker_vertices)
    assert HEAD.name in out.read_text().splitlines()[0]
    again = make_view(face_model, real_takes[0], head, registered, key_labels=kl)  # the file opened in the view
    np.testing.assert_array_equal(again.keys, v.keys)
    np.testing.assert_array_equal(again.labels, v.labels)
    assert again.state()["edited"] == 1 and again.edited[k, m]  # the markers at their proposal are not edits
    glb = tmp_path / "out.glb"
    main(["animate", "--take", str(real_takes[0]), "--character", str(scanned_head_rig), "--route", "markers",
          "--start", str(START), "--frames", str(FRAMES), "--key-labels", str(out), "-o", str(glb)])
    said = capsys.readouterr().out
    assert f"{KEYS} key frames" in said and glb.is_file()
    anim = read_glb_animation(glb)
    K, n = anim.deltas.shape[:2]
    tk = int(v.keys[k])
    at_key = 100.0 * (anim.neutral + (anim.weights[tk] @ anim.deltas.reshape(K, -1)).reshape(n, 3))  # the rig's cm
    mv = int(v.route.marker_vertices[m])
    dist = np.linalg.norm(v.labels[k, m] - v.route.proposed[k, m])
    assert np.linalg.norm(at_key[mv] - v.labels[k, m]) < 0.2 * dist  # the edited label drove the animation


def test_cli_mistakes_are_one_line(tmp_path, capsys, real_takes):
    take, png = str(real_takes[0]), str(tmp_path / "x.png")
    outside = tmp_path / "outside.csv"
    outside.write_text("frame,marker,x,y,z\n5,0,0.1,0.2,0.3\n7,0,0.1,0.2,0.3\n")
    one = tmp_path / "one.csv"
    one.write_text("frame,marker,x,y,z\n120,0,0.1,0.2,0.3\n")
    markers = ["--take", take, "--character", str(HEAD), "--route", "markers", "--start", "100", "--frames", "60"]
    for args, words in (
        ([*markers, "--key-labels", str(tmp_path / "none.csv")], "none.csv"),
        ([*markers, "--key-labels", str(outside)], "key frame 5 is outside the window"),
        ([*markers, "--keys", "x"], "--keys 'x'"),
        ([*markers, "--key-labels", str(one)], "at least 2 key frames"),
        ([*markers, "--frame", "60"], "--frame 60"),
        ([*markers, "--character-names", str(outside)], "--character-names"),
        ([*markers, "--save-key-labels", take], take),
        (["--take", take, "--character", str(HEAD), "--keys", "4"], "--keys goes with --route markers"),
        (["--take", take, "--character", str(HEAD), "--key-labels", str(outside)], "--key-labels goes with --route"),
    ):
        t0 = time.perf_counter()
        err = cli_error(capsys, ["view", "character", *args, "--screenshot", png])
        assert words in err, err
        assert time.perf_counter() - t0 < 5.0  # said before the head's registration (~9 s)
        assert not (tmp_path / "x.png").exists()
