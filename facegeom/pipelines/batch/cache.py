"""Per-process caches of the workers: the face model, and the file stamps that key the job states."""
from __future__ import annotations

import contextlib
import threading
from pathlib import Path

from facegeom.model import load_face_model

__all__ = ["load_model", "stamp"]

_MODELS: dict = {}  # face data path -> (files' sizes and times, FaceModel): one load per process and version
_MODELS_LOCK = threading.Lock()


def load_model(spec: dict):
    """The face model of a task, loaded once per process (reloaded when its files change).

    Parameters
    ----------
    spec : dict
        The task spec; ``spec["data"]`` is the face data bundle.

    Returns
    -------
    FaceModel
    """
    key = spec["data"]
    now = stamp([key])
    with _MODELS_LOCK:
        hit = _MODELS.get(key)
        if hit is None or hit[0] != now:
            _MODELS.clear()
            _MODELS[key] = hit = (now, load_face_model(key))
    return hit[1]


def stamp(paths) -> list:
    """Sizes and modification times of shared files: a changed file makes a new worker-cache key.

    Parameters
    ----------
    paths : iterable of str or None
        Files or folders (a folder stands for the files in it); None is skipped.

    Returns
    -------
    list of [str, int, int]
        ``[path, size, mtime_ns]`` per file found.
    """
    out = []
    for p in paths:
        if p is None:
            continue
        q = Path(p)
        files = sorted(q.iterdir()) if q.is_dir() else [q]
        for f in files:
            with contextlib.suppress(OSError):
                st = f.stat()
                out.append([str(f), st.st_size, st.st_mtime_ns])
    return out
