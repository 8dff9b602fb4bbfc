"""glTF delivery checked in a real client: three.js (its own GLTFLoader and WebGLRenderer) in headless Chromium.

The file is drawn with its normals as colours (``MeshNormalMaterial``), so a wrong normal is a wrong colour. A rig
posed through its morph targets must draw as the same shape baked into a plain mesh with its own normals; a
sequence's ``.glb`` must draw its rest pose when nothing plays and each frame when its animation plays.

three.js (MIT) is not in the repository: its npm package is downloaded once into the user cache, pinned by version
and SHA-256 (the test skips, saying why, when it cannot be fetched).
"""
from __future__ import annotations

import functools
import hashlib
import http.server
import io
import shutil
import tarfile
import threading
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from tests.test_docs import chromium_path

THREE_URL = "https://registry.npmjs.org/three/-/three-0.187.0.tgz"
THREE_SHA256 = "ff540832ded0cfe919764d24a3d88f3e2a05f23303f876423e4f893841e90728"
THREE_FILES = ("build/three.module.js", "build/three.core.js", "examples/jsm/loaders/GLTFLoader.js",
               "examples/jsm/utils/BufferGeometryUtils.js", "examples/jsm/utils/SkeletonUtils.js")
PAGE = Path(__file__).parent / "clients" / "threejs_render.html"
SIZE = 256


def three_tarball() -> bytes:
    from facegeom.model.face import cache_folder

    path = cache_folder() / "clients" / Path(THREE_URL).name
    if not path.is_file():
        try:
            with urllib.request.urlopen(THREE_URL, timeout=60) as r:  # noqa: S310 - a pinned https URL
                data = r.read()
        except OSError as exc:
            pytest.skip(f"three.js could not be downloaded from {THREE_URL}: {exc}")
        if hashlib.sha256(data).hexdigest() != THREE_SHA256:
            pytest.fail(f"{THREE_URL} does not have the pinned SHA-256 {THREE_SHA256}")
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".part")
        tmp.write_bytes(data)
        tmp.replace(path)
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != THREE_SHA256:
        path.unlink()
        pytest.fail(f"the cached {path} was not the pinned three.js: removed, run again")
    return data


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    """A page drawing .glb files with three.js, served on loopback; yields ``(site folder, draw)``."""
    pytest.importorskip("playwright.sync_api", reason="playwright is not installed (the test extra has it)")
    exe = chromium_path()
    if exe is None:
        pytest.skip("no Chromium found (apt-get install chromium, or set $FACEGEOM_CHROMIUM to its executable)")
    site = tmp_path_factory.mktemp("three")
    with tarfile.open(fileobj=io.BytesIO(three_tarball()), mode="r:gz") as tar:
        for name in THREE_FILES:
            out = site / "three" / name
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(tar.extractfile(f"package/{name}").read())
    shutil.copy(PAGE, site / "index.html")

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(site)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    from playwright.sync_api import sync_playwright

    pw = sync_playwright().start()
    browser = pw.chromium.launch(executable_path=exe, args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                                                            "--ignore-gpu-blocklist"])
    page = browser.new_page()
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"http://127.0.0.1:{server.server_address[1]}/index.html")
    page.wait_for_function("window.ready === true", timeout=30_000)

    def draw(glb: Path, view, influences=None, time_s=None) -> dict:
        shutil.copy(glb, site / glb.name)
        r = page.evaluate("([u, i, s, v, t]) => renderGlb(u, i, s, v, t)",
                          [glb.name, [float(x) for x in (influences if influences is not None else [])], SIZE, [float(x) for x in view], time_s])
        assert not errors, errors
        r["image"] = np.array(r.pop("pixels"), dtype=np.uint8).reshape(SIZE, SIZE, 4)[::-1, :, :3].astype(float)
        return r

    yield site, draw
    browser.close()
    pw.stop()
    server.shutdown()


def view_of(V: np.ndarray) -> list[float]:
    lo, hi = V.min(axis=0), V.max(axis=0)
    return [*((lo + hi) / 2), float((hi - lo)[:2].max() * 0.55)]


def difference(a: dict, b: dict) -> tuple[float, float]:
    """Mean colour difference (0-255) and the share of pixels more than 20 apart, over the pixels either covers."""
    cover = (a["image"].sum(axis=2) > 0) | (b["image"].sum(axis=2) > 0)
    d = np.abs(a["image"] - b["image"]).max(axis=2)[cover]
    return float(d.mean()), float((d > 20).mean())


def baked(tmp_path: Path, name: str, V: np.ndarray, F: np.ndarray) -> Path:
    """A plain mesh (one zero target, no motion): three.js computes nothing, it draws the stored normals."""
    from facegeom.io.gltf import write_rig_glb

    return write_rig_glb(tmp_path / name, V, F, np.zeros((1, *V.shape)), ["none"], np.zeros((1, 1)), 30.0)


@pytest.fixture(scope="module")
def ict(face_model):
    from facegeom.model.rig import BlendshapeRig

    rig = BlendshapeRig.from_face_model(face_model)
    return rig, rig.neutral * 0.01, rig.triangles, rig.deltas * 0.01  # metres, as the .glb writers store them


@pytest.mark.parametrize("pose", [{"jawOpen": 1.0}, {"browInnerUp_L": 0.8, "browInnerUp_R": 0.8},
                                  {"mouthSmile_L": 1.0, "eyeBlink_L": 1.0}])
def test_a_rig_posed_by_its_morph_targets_shades_as_the_shape_itself(three, ict, tmp_path, pose):
    from facegeom.io.gltf import write_rig_glb

    _, draw = three
    rig, V, F, D = ict
    names = list(rig.names)
    w = np.zeros(len(names))
    for n, v in pose.items():
        w[names.index(n)] = v
    glb = write_rig_glb(tmp_path / "rig.glb", V, F, D, names, w[None], 30.0)
    shape = V + np.einsum("k,kvd->vd", w, D)
    view = view_of(V)
    got = draw(glb, view, influences=w)
    assert got["morphNormals"] and got["targets"] == len(names)
    want = draw(baked(tmp_path, "shape.glb", shape, F), view)
    rest = draw(baked(tmp_path, "rest.glb", V, F), view)
    assert difference(rest, want)[1] > 0.005  # the pose is visible in the normals: the comparison below can fail
    mean, far = difference(got, want)
    assert mean < 1.0 and far < 0.002, (mean, far)


def test_a_sequence_glb_rests_at_the_neutral_and_plays_its_frames(three, ict, tmp_path):
    """The marker route's encoding (principal axes): every weight at 0 draws the character's neutral, not the
    encoding's base; the animation at a frame's time draws that frame (positions within the bound, normals
    from the fitted normal targets)."""
    from facegeom.io.gltf import read_glb_animation, write_sequence_glb

    _, draw = three
    rig, V, F, D = ict
    names = list(rig.names)
    T = 40
    t = np.linspace(0, 1, T)[:, None]
    W = np.zeros((T, len(names)))
    W[:, names.index("jawOpen")] = 0.5 + 0.5 * np.sin(2 * np.pi * t[:, 0])
    W[:, names.index("mouthSmile_L")] = t[:, 0]
    W[:, names.index("browInnerUp_L")] = 1 - t[:, 0]
    X = V[None] + np.einsum("tk,kvd->tvd", W, D)
    glb, info = write_sequence_glb(tmp_path / "seq.glb", X, F, 30.0, tolerance=1e-4, rest=V)
    assert info["rest"] and info["max_error"] <= 1e-4 * 1.001
    back = read_glb_animation(glb)
    assert np.abs(back.neutral - V).max() < 1e-6 and back.names[0] == "base"
    assert np.abs(back.frames() - X).max() <= 1e-4 * 1.001
    view = view_of(V)
    at_rest = draw(glb, view)
    assert max(at_rest["influences"]) == 0.0
    mean, far = difference(at_rest, draw(baked(tmp_path, "rest.glb", V, F), view))
    assert mean < 1.0 and far < 0.002, (mean, far)
    for frame in (10, 25):
        played = draw(glb, view, time_s=frame / 30.0)
        want = draw(baked(tmp_path, f"f{frame}.glb", X[frame], F), view)
        mean, far = difference(played, want)
        assert mean < 2.0 and far < 0.01, (frame, mean, far)
