"""Registrations kept in the user cache: the same head, options, face data and code registered once.

Registering the ICT face onto a head (:func:`~facegeom.methods.transfer.register_head`) takes 10-40 s of CPU
(most of it the identity fit's 300 closest-point rounds), and a studio's day repeats it on the same head:
``facegeom transfer`` with another engine, ``facegeom view transfer`` after it, ``facegeom animate --route
markers`` onto a raw head for every take. The result depends only on its inputs, so it is kept in
``registrations/`` of the user cache (:func:`facegeom.model.face.cache_folder`, ``$FACEGEOM_CACHE``) under a key
that holds every one of them:

- the head's vertices and triangles (their bytes, as checked), the landmarks, the units asked, the surface
  samples and the identity fitter's extra parameters;
- the face model's arrays the registration reads (neutral, identity modes, expression deltas, triangles,
  landmarks);
- the code: every ``.py`` file of the ``facegeom`` package (its bytes), and the versions of numpy and scipy
  (their arithmetic can differ in the last bits between releases).

A registration that raised is not kept. A hit gives the same arrays, byte for byte, and the same progress
lines, after one saying where they come from. The newest :data:`KEEP` entries are kept (about 230 kB each); an
unreadable or foreign entry is ignored and replaced. ``FACEGEOM_REGISTRATION_CACHE=off`` turns the cache off.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np

__all__ = ["KEEP", "ENV_VAR", "registration_key", "load", "store", "enabled"]

KEEP = 64  # entries kept (the newest by modification time): ~15 MB
ENV_VAR = "FACEGEOM_REGISTRATION_CACHE"
_CODE: list = []  # the code's digest, computed once per process
_MODELS: dict = {}  # id(model) -> (model, digest of its arrays)


def enabled() -> bool:
    """Whether the cache is used (``$FACEGEOM_REGISTRATION_CACHE`` is not ``off``, ``0`` or ``no``)."""
    return os.environ.get(ENV_VAR, "").strip().lower() not in ("off", "0", "no", "false")


def _code_digest() -> str:
    if not _CODE:
        import scipy

        root = Path(__file__).resolve().parents[1]
        h = hashlib.sha256(f"numpy {np.__version__} scipy {scipy.__version__}".encode())
        for p in sorted(root.rglob("*.py")):
            h.update(p.relative_to(root).as_posix().encode())
            h.update(p.read_bytes())
        _CODE.append(h.hexdigest())
    return _CODE[0]


def _model_digest(model) -> str:
    held = _MODELS.get(id(model))
    if held is None or held[0] is not model:
        h = hashlib.sha256()
        for name in ("neutral", "identity_modes", "expression_deltas", "triangles", "landmarks"):
            a = getattr(model, name)
            a = np.ascontiguousarray(a() if callable(a) else a)
            h.update(f"{name} {a.dtype} {a.shape}".encode())
            h.update(a.tobytes())
        held = _MODELS[id(model)] = (model, h.hexdigest())
    return held[1]


def registration_key(model, V, F, landmarks, units, samples, fitter_params) -> str:
    """The cache key of a registration: a digest of everything it depends on (module docstring)."""
    h = hashlib.sha256()
    for a in (V, F):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype} {a.shape}".encode())
        h.update(a.tobytes())
    lm = None if landmarks is None else np.ascontiguousarray(np.asarray(landmarks, dtype=np.int64)).tobytes()
    h.update(repr((lm, units, int(samples), sorted((fitter_params or {}).items()))).encode())
    h.update(_model_digest(model).encode())
    h.update(_code_digest().encode())
    return h.hexdigest()


def _folder() -> Path:
    from facegeom.model.face import cache_folder

    return cache_folder() / "registrations"


def load(key: str):
    """``(arrays, report, lines, when)`` kept under ``key``, or None (absent, unreadable, another key inside)."""
    path = _folder() / f"{key}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None
            arrays = {k: z[k] for k in ("template", "R", "t", "identity", "scalars")}
            meta = json.loads(str(z["meta"]))
        os.utime(path)  # recently used: kept the longest
    except (OSError, ValueError, KeyError, json.JSONDecodeError):
        return None
    return arrays, meta["report"], meta["lines"], meta["when"]


def store(key: str, reg, lines: list[str]) -> None:
    """Keep the registration ``reg`` and its progress ``lines`` under ``key`` (best effort: a cache that cannot
    be written is not an error); the oldest entries beyond :data:`KEEP` are removed."""
    folder = _folder()
    tmp = folder / f".{key}.{os.getpid()}.tmp.npz"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        meta = json.dumps({"report": reg.report, "lines": list(lines),
                           "when": time.strftime("%Y-%m-%d %H:%M", time.localtime())}, default=_plain)
        np.savez(tmp, key=np.array(key), template=reg.template, R=reg.R, t=reg.t, identity=reg.identity,
                 scalars=np.array([reg.scale, reg.units, reg.mm_per_unit]), meta=np.array(meta))
        os.replace(tmp, folder / f"{key}.npz")
        entries = sorted(folder.glob("*.npz"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in entries[KEEP:]:
            old.unlink(missing_ok=True)
    except (OSError, TypeError, ValueError):
        tmp.unlink(missing_ok=True) if tmp.parent.is_dir() else None


def _plain(x):
    """JSON for the numpy scalars and arrays a report holds."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON: {type(x).__name__}")
