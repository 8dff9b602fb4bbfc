"""``facegeom view track``: a tracked video checked frame by frame, rendered headless (EGL; no display, no GPU).

The clip is a rendered face of known truth (:mod:`facegeom.pipelines.video_clips`), tracked once for the module.
The view must show the video's own frame ``i`` whatever order the frames are asked for in (played, scrubbed back,
jumped ahead: decoded in order, sought, cached), the fitted actor as the track's curves on the fitted identity
turned by the head pose, and the character playing the mapped curves.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

ps = pytest.importorskip("polyscope")
pytest.importorskip("av", reason="reading video needs PyAV: pip install 'facegeom[video]'")
pytest.importorskip("ai_edge_litert", reason="the face models need LiteRT: pip install 'facegeom[video]'")

from tests.conftest import assert_not_blank, changed, cli_error, read_png  # noqa: E402

FRAMES = 40


@pytest.fixture(scope="module")
def tracked(face_model, tmp_path_factory):
    """``(video, track.npz, frames)``: a 40-frame 320 x 240 clip (keyframes every 12 frames, so a jump seeks),
    tracked; ``frames`` every decoded frame in order."""
    from facegeom.errors import InputError
    from facegeom.io.video import open_video
    from facegeom.pipelines.track import track_video, write_track_npz
    from facegeom.pipelines.video_clips import build_clips

    folder = tmp_path_factory.mktemp("viewtrack")
    try:
        (video,) = build_clips(folder, 1, seed=5, family="holdout", frames=FRAMES, size=(320, 240), progress=False,
                               model=face_model)
    except InputError as exc:
        pytest.skip(f"no off-screen renderer here: {exc}")
    # re-encode with short key-frame intervals: jumps between them exercise the seek
    import av

    short = folder / "short_gop.mp4"
    with open_video(video) as r:
        frames = [f.image for f in r]
        fps = r.fps
    with av.open(str(short), "w") as out:
        s = out.add_stream("libx264", rate=round(fps))
        s.width, s.height, s.pix_fmt = 320, 240, "yuv420p"
        s.options = {"g": "12", "crf": "18"}
        for img in frames:
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(p)
        for p in s.encode():
            out.mux(p)
    with open_video(short) as r:
        frames = [f.image for f in r]
    result = track_video(short, face_model)
    npz = write_track_npz(folder / "track.npz", result)
    return short, npz, frames


def make_view(face_model, tracked, **kw):
    from facegeom.pipelines.track import read_track_npz
    from facegeom.viewer.track import TrackView

    video, npz, _ = tracked
    return TrackView(face_model, read_track_npz(npz), video, **kw)


def test_frames_come_back_exactly_in_any_order(face_model, tracked):
    from facegeom.pipelines.track import read_track_npz
    from facegeom.viewer.track import VideoFrames

    video, npz, frames = tracked
    tr = read_track_npz(npz)
    assert tr.n_frames == len(frames) == FRAMES
    vf = VideoFrames(video, tr.times, tr.width, tr.height, tr.fps)
    order = [0, 1, 2, 30, 31, 5, 39, 13, 12, 11, 25, 0, 38]
    for i in order:
        np.testing.assert_array_equal(vf.get(i), frames[i], err_msg=f"frame {i}")
    assert vf.seeks >= 5  # the jumps back sought instead of decoding from the start
    vf.cache.clear()
    for i in reversed(range(FRAMES)):  # scrubbing backwards, uncached
        np.testing.assert_array_equal(vf.get(i), frames[i], err_msg=f"frame {i}")
    vf.close()


def test_the_faces_are_the_tracks_curves_under_its_head_pose(scene, face_model, tracked):
    from facegeom.model import BlendshapeRig
    from facegeom.pipelines.track import read_track_npz

    tr = read_track_npz(tracked[1])
    character = BlendshapeRig.from_face_model(face_model, face_model.random_identity(7, 1.0))
    v = make_view(face_model, tracked, character=character, frame=10)
    person = BlendshapeRig.from_face_model(face_model, tr.identity)
    for t in (0, 10, 33):
        P = person.neutral + np.tensordot(tr.weights[t], person.deltas, axes=1)
        c = person.neutral.mean(axis=0)
        np.testing.assert_allclose(v.face(t), c + (P - c) @ tr.rotations[t].T, atol=1e-9)
        Q = character.neutral + np.tensordot(tr.weights[t], character.deltas, axes=1)  # same names: the identity map
        c = character.neutral.mean(axis=0)
        np.testing.assert_allclose(v.character_face(t), c + (Q - c) @ tr.rotations[t].T, atol=1e-9)
    # the frame's fit projected back lands on the points found in the frame (a few pixels: the fit's residual)
    from facegeom.pipelines.track import point_vertices

    keep, _, _ = point_vertices(face_model)
    gap = np.linalg.norm(v.fitted_points(10)[keep] - tr.points[10, keep], axis=1)
    assert np.median(gap) < 4.0 * max(tr.residual[10], 0.5), (np.median(gap), tr.residual[10])
    v.setup_scene(1200, 500, headless=True)
    assert v.copies() == ["video", "face", "character"]
    shown = v.shown_faces()
    assert shown["face"][:, 0].max() < shown["character"][:, 0].min()  # side by side, in order
    v.close()


def test_screenshots_follow_the_frame_and_the_switches(scene, face_model, tracked, tmp_path):
    v = make_view(face_model, tracked, frame=0)
    v.setup_scene(1000, 450, headless=True)
    first = read_png(v.screenshot(tmp_path / "a.png", include_ui=False))
    assert_not_blank(first)
    xy = v.world_to_screen(np.array([[v.shifts["video"][0] - v.panel_w / 2, 0, 0],
                                     [v.shifts["video"][0] + v.panel_w / 2, 0, 0]]))
    cols = (xy[:, 0].min(), xy[:, 0].max())
    v.set_frame(FRAMES - 1)
    second = read_png(v.screenshot(tmp_path / "b.png", include_ui=False))
    assert changed(first, second, cols) > 100  # another frame of the video
    v.set_frame(FRAMES - 1)
    v.set_overlay(wire=False, landmarks=False)
    bare = read_png(v.screenshot(tmp_path / "c.png", include_ui=False))
    assert changed(second, bare, cols) > 100  # the wireframe and the dots were drawn over the frame
    v.set_overlay(wire=True, landmarks=True)
    assert changed(second, read_png(v.screenshot(tmp_path / "d.png", include_ui=False))) < 50
    v.close()


def test_panel_scrubs_and_reports_the_frame(scene, face_model, tracked):
    from facegeom.pipelines.track import read_track_npz

    tr = read_track_npz(tracked[1])
    v = make_view(face_model, tracked)
    v.setup_scene(900, 500, headless=True)
    ps.frame_tick()
    v.ui.set("frame", 25)
    ps.frame_tick()
    assert v.frame == 25
    v.ui.set("<", True)
    ps.frame_tick()
    s = json.loads(json.dumps(v.state()))
    assert s["frame"] == 24 and s["found"] and s["time_s"] == pytest.approx(tr.times[24])
    assert s["residual_px"] == pytest.approx(tr.residual[24])
    w = tr.weights[24]
    assert [n for n, _ in s["top"]] == [tr.names[i] for i in np.argsort(-w, kind="stable")[:len(s["top"])]]
    v.ui.set("landmarks", False)
    ps.frame_tick()
    assert not v.show_landmarks and not v.state()["landmarks"]
    v.close()


# --------------------------------------------------------------------------- the command line


def test_cli_writes_a_png(tmp_path, face_model, tracked):
    video, npz, _ = tracked
    out = tmp_path / "track.png"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["FACEGEOM_DATA"] = face_model.path
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "track", str(npz), "--video", str(video), "--frame",
                        "7", "--size", "900x450", "--screenshot", str(out)], capture_output=True, text=True, env=env,
                       timeout=120)
    if r.returncode != 0 and ("could not start a renderer" in r.stderr or "EGL" in r.stderr):
        pytest.skip(f"headless rendering unavailable: {r.stderr.strip()}")
    assert r.returncode == 0, r.stderr
    assert f"wrote {out}" in r.stdout and f"{FRAMES} frames" in r.stdout
    img = read_png(out)
    assert img.shape == (450, 900, 3)
    assert_not_blank(img)


def test_cli_mistakes_are_one_line(tmp_path, capsys, tracked, face_model):
    from facegeom.io.video import VideoWriter

    video, npz, _ = tracked
    png = str(tmp_path / "x.png")
    other = tmp_path / "other.mp4"
    with VideoWriter(other, 30, 160, 120) as w:
        for _ in range(3):
            w.write(np.zeros((120, 160, 3), np.uint8))
    np.savez(tmp_path / "curves.npz", weights=np.zeros((3, 2)), names=np.array(["a", "b"]))
    z = dict(np.load(npz))
    z["identity"] = np.zeros(0)
    np.savez(tmp_path / "rigged.npz", **z)
    z = dict(np.load(npz))
    z["rotations"] = z["rotations"] * 2.0
    np.savez(tmp_path / "bent.npz", **z)
    for args, words in (
        ([str(tmp_path / "none.npz"), "--video", str(video)], "none.npz: no such file"),
        ([str(npz), "--video", str(tmp_path / "none.mp4")], "none.mp4: no such file"),
        ([str(npz), "--video", str(other)], "not the video tracked"),
        ([str(tmp_path / "curves.npz"), "--video", str(video)], "not a track"),
        ([str(tmp_path / "rigged.npz"), "--video", str(video)], "give the same --rig"),
        ([str(tmp_path / "bent.npz"), "--video", str(video)], "not rotations"),
        ([str(npz), "--video", str(video), "--frame", str(FRAMES)], f"--frame {FRAMES}"),
        ([str(npz), "--video", str(video), "--character-names", str(npz)], "--character-names goes with --character"),
    ):
        err = cli_error(capsys, ["view", "track", *args, "--screenshot", png])
        assert words in err, err
        assert not (tmp_path / "x.png").exists()
