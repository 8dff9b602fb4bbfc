"""Shared fixtures: the real face data (the data lookup: $FACEGEOM_DATA, ../shared, the user cache) and small
synthetic meshes. `make test` fetches the data first when none is found (`facegeom data fetch --if-missing`)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from facegeom.errors import DataNotFoundError


@pytest.fixture(scope="session")
def face_model():
    from facegeom.model import load_face_model

    try:
        return load_face_model()
    except DataNotFoundError as exc:  # pragma: no cover - CI always has the data; `make test` fetches it
        pytest.skip(f"real face data not available (run `facegeom data fetch`): {exc}")


#: the untouched ICT-FaceKit files the importer and download tests use (a miniature checkout)
ICT_ORIGINAL_NAMES = ("vertex_indices.json", "generic_neutral_mesh.obj", "jawOpen.obj", "mouthSmile_L.obj",
                      "eyeBlink_R.obj", "identity000.obj", "identity001.obj")


def _ict_original_folder():
    """Where the seven original files are: ``original/`` next to the bundle found, else the cache's downloads."""
    from facegeom.model import download as dl
    from facegeom.model import locate_data

    places = []
    try:
        places.append(locate_data().parent / "original")
    except DataNotFoundError:
        pass
    places.append(dl.raw_folder(dl.read_registry()) / dl.MODEL_FOLDER)
    return next((p for p in places if all((p / n).is_file() for n in ICT_ORIGINAL_NAMES)), None)


@pytest.fixture(scope="session")
def original(tmp_path_factory):
    """A miniature ICT-FaceKit checkout: ``FaceXModel/`` with the seven files, and ``LICENSE`` when found
    (from ``original/`` beside the bundle in ../shared, or the files `facegeom data fetch` downloaded)."""
    import shutil

    from facegeom.model import download as dl

    folder = _ict_original_folder()
    if folder is None:  # pragma: no cover - `make test` fetches them when ../shared is absent
        pytest.skip("the original ICT-FaceKit files are not present (run `facegeom data fetch` or use ../shared)")
    root = tmp_path_factory.mktemp("ict-mini")
    mini = root / dl.MODEL_FOLDER
    mini.mkdir()
    for n in ICT_ORIGINAL_NAMES:
        shutil.copyfile(folder / n, mini / n)
    lic = next((p for p in (folder.parent / dl.LICENSE_COPY, folder.parent / dl.LICENSE_PATH) if p.is_file()), None)
    if lic is not None:
        shutil.copyfile(lic, root / dl.LICENSE_PATH)
    return mini


def take_files_or_skip(count: int = 1):
    """The real takes the takes lookup finds ($FACEGEOM_TAKES, ../shared, the cache `make test` fetches the public
    take into); skips, saying why, when there are fewer than ``count`` (a fresh machine has exactly one)."""
    from facegeom.io.takes import find_takes
    from facegeom.model import locate_takes

    try:
        files = find_takes(locate_takes())
    except DataNotFoundError as exc:  # pragma: no cover - `make test` fetches the public take
        pytest.skip(f"no real take (run `facegeom data fetch`): {exc}")
    if len(files) < count:
        pytest.skip(f"needs {count} real takes; {len(files)} found at {files[0].parent} (a fresh machine fetches one "
                    f"public take; more come from $FACEGEOM_TAKES)")
    return files


@pytest.fixture(scope="session")
def scanned_head_rig(face_model, tmp_path_factory):
    """The Lee Perry-Smith scan (``tests/data/heads``, CC BY 3.0) given to ``facegeom transfer`` once: its rig
    ``.npz`` (cm, Y up), the registration stored with it (what the marker route and its viewer reuse)."""
    from facegeom.cli.main import main

    out = tmp_path_factory.mktemp("scanned-head") / "lee_perry_smith.npz"
    main(["transfer", str(Path(__file__).parent / "data" / "heads" / "lee_perry_smith.ply"), "-o", str(out)])
    return out


@pytest.fixture(scope="session")
def real_takes():
    """The real take files of this machine (at least one; see :func:`take_files_or_skip`)."""
    return take_files_or_skip()


@pytest.fixture(scope="session")
def face_mesh(face_model):
    return face_model.neutral.copy(), face_model.triangles.copy()


@pytest.fixture(scope="module")
def headless():
    """Polyscope started headless (EGL on Mesa's software renderer) -> the backend name; skips where it cannot
    start, or only the mock backend (black images) is there; the scene is emptied after the module."""
    ps = pytest.importorskip("polyscope")
    from facegeom.viewer.app import init_polyscope

    try:
        backend = init_polyscope(headless=True)
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"headless rendering unavailable here (polyscope could not start EGL): {exc}")
    if backend == "openGL_mock":
        pytest.skip("only polyscope's mock backend is available: images would be black")
    yield backend
    ps.clear_user_callback()
    ps.remove_all_structures()


def two_grids():
    """Two disjoint bumped 5x5 grids (vertices 0-24 and 25-49): a mesh with two components."""
    V1, F1 = grid_mesh(5, 5, bump=0.2)
    return np.r_[V1, V1 + [3, 0, 0]], np.r_[F1, F1 + 25]


def grid_mesh(nx: int = 8, ny: int = 8, bump: float = 0.0):
    """A triangulated (nx x ny)-vertex grid on [0,1]^2, optionally bumped in z."""
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="xy")
    z = bump * np.sin(np.pi * x) * np.sin(np.pi * y)
    V = np.c_[x.ravel(), y.ravel(), z.ravel()]
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    F = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    return V.astype(np.float64), F.astype(np.int64)


@pytest.fixture
def grid():
    return grid_mesh()


# ----------------------------------------------------------------------------- Khronos glTF-Validator
VALIDATOR = "gltf-validator@2.0.0-dev.3.10"
VALIDATE_SCRIPT = Path(__file__).with_name("gltf_validate.js")


@pytest.fixture(scope="session")
def validator_env():
    """NODE_PATH holding the npm package gltf-validator, installed once into the user cache."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        pytest.skip("the Khronos glTF-Validator check needs node and npm on PATH")
    cache = Path(os.environ.get("FACEGEOM_CACHE", Path.home() / ".cache" / "facegeom")) / "node"
    modules = cache / "node_modules"
    if not (modules / "gltf-validator" / "package.json").exists():
        cache.mkdir(parents=True, exist_ok=True)
        try:
            r = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--prefix", str(cache), VALIDATOR],
                               capture_output=True, text=True, timeout=300)
        except subprocess.TimeoutExpired:
            pytest.skip("npm could not install gltf-validator within 5 minutes (no network?)")
        if r.returncode != 0:
            pytest.skip(f"npm could not install gltf-validator (no network?): {r.stderr.strip()[-200:]}")
    return dict(os.environ, NODE_PATH=str(modules))


def validate(env, path):
    """Run the Khronos glTF-Validator on ``path`` -> its ``issues`` dict (every message printed)."""
    r = subprocess.run(["node", str(VALIDATE_SCRIPT), str(path)], capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    issues = report["issues"]
    for m in issues["messages"]:
        print(f"validator {m['severity']} {m['code']} {m.get('pointer', '')}: {m['message']}")
    return issues


# ----------------------------------------------------------------------------- viewer tests' helpers
@pytest.fixture
def scene(headless):
    """A headless polyscope scene, emptied before and after the test."""
    import polyscope as ps

    ps.remove_all_structures()
    yield
    ps.clear_user_callback()
    ps.remove_all_structures()


def read_png(path) -> np.ndarray:
    """An image file as an ``(h, w, 3)`` RGB array."""
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB"))


def changed(a, b, cols=None) -> int:
    """Pixels that differ visibly between two renders (in the column range ``cols`` if given)."""
    d = np.abs(a.astype(int) - b.astype(int)).sum(axis=-1) > 30
    if cols is not None:
        d = d[:, max(int(cols[0]), 0):int(cols[1])]
    return int(d.sum())


def assert_not_blank(img):
    """The render shows something: not one colour, and more than 3 % of its pixels not white."""
    img = np.asarray(img, dtype=np.float64)[..., :3]
    assert img.std() > 10.0, "the image is blank"
    assert (np.abs(img - 255).sum(axis=-1) > 30).mean() > 0.03, "almost nothing is drawn"


def cli_error(capsys, argv) -> str:
    """Run ``facegeom ARGV`` in-process expecting a user's mistake: exit status 2 and one line ``facegeom: error:
    ...`` on stderr, no traceback -> that line."""
    from facegeom.cli.main import main

    with pytest.raises(SystemExit) as exc:
        main(list(argv))
    err = capsys.readouterr().err
    assert exc.value.code == 2, err
    assert len(err.strip().splitlines()) == 1 and err.startswith("facegeom: error: "), err
    assert "Traceback" not in err
    return err.strip()
