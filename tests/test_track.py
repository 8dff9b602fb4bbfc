"""`facegeom track`: a rendered video of known truth -> curves, head pose, gaze; its outputs and its refusals.

The clip is the face model itself (a random identity performing a real take's window with head motion and eye
movements, rendered by :mod:`facegeom.pipelines.video_clips`), so the head's true rotation and the true weights are
known. The bounds are loose on purpose (this tests that the pieces are wired right, the benchmark measures how
well): measured on this clip, head rotation 1-3 degrees (median), face error 0.5-1.2 of the neutral's.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("ai_edge_litert", reason="the face models need LiteRT: pip install 'facegeom[video]'")
pytest.importorskip("av", reason="reading video needs PyAV: pip install 'facegeom[video]'")


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=900,
                          cwd=cwd)


@pytest.fixture(scope="module")
def clip(face_model, tmp_path_factory):
    """A 45-frame 320 x 240 tune clip (rendered once for the module)."""
    from facegeom.errors import InputError
    from facegeom.pipelines.video_clips import build_clips

    folder = tmp_path_factory.mktemp("clip")
    try:
        (video,) = build_clips(folder, 1, seed=3, family="tune", frames=45, size=(320, 240), progress=False,
                               model=face_model)
    except InputError as exc:
        pytest.skip(f"no off-screen renderer here: {exc}")
    return video


def test_track_writes_every_output_and_follows_the_head(clip, face_model, tmp_path):
    from scipy.spatial.transform import Rotation

    from facegeom.io.takes import read_take
    from facegeom.pipelines.video_clips import load_truth

    out = tmp_path / "t"
    r = run("track", str(clip), "-o", f"{out}.csv", "-o", f"{out}.npz", "-o", f"{out}.glb", "--preview",
            f"{out}_preview.mp4")
    assert r.returncode == 0, r.stderr
    assert "45 frames" in r.stdout and "face in 45" in r.stdout and "frames per CPU second" in r.stdout
    assert ".tmp." not in r.stdout  # notes name the outputs, not the temporary files they were written into
    # into a pipe (no terminal, no bar): a line as the frames start, as the fit begins and as the preview is drawn
    assert "track: 1/45 frames" in r.stderr and "track: face points found in 45 of 45 frames; fitting" in r.stderr
    assert "track: drawing the preview" in r.stderr
    truth = load_truth(clip.parent / (clip.stem + ".truth.npz"))
    z = np.load(f"{out}.npz")
    T = 45
    assert z["weights"].shape == (T, face_model.n_expressions) and z["points"].shape == (T, 468, 2)
    assert z["landmarks"].shape == (T, 68, 2) and z["found"].all() and np.isfinite(z["residual"]).all()
    assert ((z["weights"] >= 0) & (z["weights"] <= 1)).all()
    angle = np.degrees(np.linalg.norm((Rotation.from_matrix(z["rotations"]) *
                                       Rotation.from_matrix(truth["rotations"]).inv()).as_rotvec(), axis=1))
    assert np.median(angle) < 6.0, np.median(angle)
    take = read_take(f"{out}.csv")
    assert take.n_frames == T and take.rotations is not None
    assert np.abs(take.rotations[:, 0]).max() > 0.01  # the head's yaw carried into the take
    from facegeom.io.video import open_video

    with open_video(f"{out}_preview.mp4") as v:
        assert sum(1 for _ in v) == T
    from facegeom.io.gltf import read_gltf_rig

    rig = read_gltf_rig(f"{out}.glb")
    assert len(rig.names) == face_model.n_expressions


def test_track_onto_a_character_and_with_the_actors_rig(clip, face_model, tmp_path):
    from facegeom.model.rig import BlendshapeRig

    character = BlendshapeRig.from_face_model(face_model, face_model.random_identity(5, 1.0))
    character.save_npz(tmp_path / "character.npz")
    r = run("track", str(clip), "--character", str(tmp_path / "character.npz"), "-o", str(tmp_path / "c.glb"),
            "--rig-out", str(tmp_path / "actor.npz"), "--frames", "20")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "c.glb").stat().st_size > 0 and (tmp_path / "actor.npz").is_file()
    r = run("track", str(clip), "--rig", str(tmp_path / "actor.npz"), "--focal", "300", "-o", str(tmp_path / "a.npz"),
            "--frames", "20")
    assert r.returncode == 0, r.stderr
    z = np.load(tmp_path / "a.npz")
    assert float(z["focal"]) == 300.0 and not bool(z["focal_estimated"]) and z["weights"].shape[0] == 20


def test_frames_without_a_face_are_bridged_and_reported(clip, tmp_path):
    from facegeom.io.video import VideoWriter, open_video

    gap = tmp_path / "gap.mp4"
    with open_video(clip) as v, VideoWriter(gap, v.fps, v.width, v.height) as w:
        for f in v:
            w.write(np.full_like(f.image, 90) if 15 <= f.index < 22 else f.image)
    r = run("track", str(gap), "-o", str(tmp_path / "g.npz"))
    assert r.returncode == 0, r.stderr
    assert "no face in 7 of 45 frames (longest gap 7)" in r.stdout
    z = np.load(tmp_path / "g.npz")
    assert not z["found"][15:22].any() and z["found"][:15].all() and z["found"][22:].all()
    assert np.isfinite(z["weights"]).all() and np.isnan(z["residual"][15:22]).all()


def test_bad_inputs_are_one_line_and_write_nothing(clip, face_model, tmp_path):
    from facegeom.io.video import VideoWriter
    from facegeom.model.rig import BlendshapeRig

    blank = tmp_path / "blank.mp4"
    with VideoWriter(blank, 30, 64, 48) as w:
        for _ in range(5):
            w.write(np.full((48, 64, 3), 120, np.uint8))
    (tmp_path / "notes.mp4").write_text("not a video")
    small = BlendshapeRig(neutral=np.eye(3), deltas=np.zeros((1, 3, 3)), names=("a",), triangles=np.array([[0, 1, 2]]))
    small.save_npz(tmp_path / "small.npz")
    cases = [
        ((str(blank), "-o", str(tmp_path / "o.csv")), "no face found in any of the video's 5 frames"),
        ((str(tmp_path / "notes.mp4"), "-o", str(tmp_path / "o.csv")), "notes.mp4"),
        ((str(tmp_path / "missing.mp4"), "-o", str(tmp_path / "o.csv")), "no such file"),
        ((str(clip), "-o", str(tmp_path / "o.txt")), "unsupported output"),
        ((str(clip), "--rig", str(tmp_path / "small.npz"), "-o", str(tmp_path / "o.csv")), "not the face model's"),
        ((str(clip), "--focal", "-3", "-o", str(tmp_path / "o.csv")), "focal length"),
        ((str(clip), "-o", str(clip)), "unsupported output"),
    ]
    for args, message in cases:
        r = run("track", *args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        lines = [x for x in r.stderr.strip().splitlines() if not x.startswith("track:")]
        assert len(lines) == 1 and message in lines[0], (args, r.stderr)
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "o.csv").exists() and not (tmp_path / "o.txt").exists()


def test_smoothing_halves_motion_at_its_cutoff():
    from facegeom.methods.marker_solve import smooth_curves
    from facegeom.pipelines.track import SMOOTH_HZ, cutoff_strength

    fps, T = 30.0, 3000
    t = np.arange(T) / fps
    lam = cutoff_strength(SMOOTH_HZ, fps)
    for hz, want in ((SMOOTH_HZ, 0.5), (0.5, 0.999), (12.0, 0.032)):  # 1 / (1 + lam (2 - 2 cos(2 pi hz / fps))^2)
        y = np.sin(2 * np.pi * hz * t)[:, None]
        z, _ = smooth_curves(y, lam)
        gain = np.abs(z[500:-500]).max()
        assert abs(gain - want) < 0.01, (hz, gain)


def test_bench_scores_a_clip_against_its_truth(clip, face_model):
    """`bench track`'s scoring: the rest reference scores a face error of exactly 1 (no expression), the track
    scores below the per-frame baseline's on the jitter, every number finite."""
    from facegeom.bench.track import clip_scores

    s = clip_scores(clip, face_model, methods=("track", "per-frame", "rest"))
    assert abs(s["rest"]["face"] - 1.0) < 1e-9 and s["rest"]["jitter"] == 0.0
    assert s["track"]["jitter"] < s["per-frame"]["jitter"]
    for m in s.values():
        assert all(np.isfinite(v) for k, v in m.items() if k != "moving")
    assert s["track"]["fps_cpu"] > 0 and 0.2 < s["track"]["focal_ratio"] < 5
