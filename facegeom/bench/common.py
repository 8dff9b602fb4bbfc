"""Helpers shared by the benchmark protocols: timing, progress, fitter specs and face-area sampling.

(Method specs: :mod:`facegeom.registry`; reports: :mod:`facegeom.bench.report`.)
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.constants import FACE_AREA
from facegeom.errors import FacegeomError
from facegeom.registry import MethodSpec

__all__ = ["median_time", "available_specs", "face_area_triangles", "sample_surface", "progress_bar", "projector"]


def median_time(fn, repeat: int = 5) -> tuple[float, object]:
    """Median wall time of ``fn()`` over ``repeat`` calls (seconds) and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def available_specs(specs: list[MethodSpec], echo=print) -> list[MethodSpec]:
    """The specs whose plugin can be built (an optional peer such as eos may be missing)."""
    out = []
    for s in specs:
        try:
            s.build("fitters")
        except FacegeomError as exc:
            echo(f"skipping {s.label}: {exc}")
            continue
        out.append(s)
    return out


def progress_bar(items, desc: str, progress: bool, unit: str = "fit"):
    """``items`` wrapped in a tqdm progress bar (shown when ``progress``)."""
    from tqdm import tqdm

    return tqdm(items, desc=desc, unit=unit, disable=not progress)


def projector(r, cam):
    """How a landmark fit sees the face: its estimated pinhole camera, or a peer's affine camera (eos)."""
    if "camera" in r.info:
        return r.info["camera"].project
    if "affine_camera" in r.info:
        A = np.asarray(r.info["affine_camera"], dtype=np.float64)
        return lambda X: np.c_[X, np.ones(len(X))] @ A[:2].T
    return cam.project


def side_strip_seen(model, hidden: float, side: int) -> np.ndarray:
    """``(n,)`` bool: the face area minus a side strip of ``hidden`` of its width (of the generic face).

    The strip is on the right (``side`` > 0, largest x) or the left; vertices
    off the face area are not seen. What a partial scan observes.
    """
    X = model.neutral[:FACE_AREA, 0]
    lo, hi = float(X.min()), float(X.max())
    cut = hidden * (hi - lo)
    seen = np.zeros(model.n_vertices, dtype=bool)
    seen[:FACE_AREA] = (X < hi - cut) if side > 0 else (X > lo + cut)
    return seen


def face_area_triangles(model) -> np.ndarray:
    """The triangles of the face area: those whose three vertices lie in ``[0, FACE_AREA)``.

    Parameters
    ----------
    model : FaceModel
        The ICT face model.

    Returns
    -------
    (m', 3) int64
        The matching rows of ``model.triangles``, in their order.
    """
    T = model.triangles
    return T[(T < FACE_AREA).all(axis=1)]


def sample_surface(V, tris, count, rng) -> np.ndarray:
    """``count`` points uniformly distributed (by area) on the triangles."""
    a, b, c = V[tris[:, 0]], V[tris[:, 1]], V[tris[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    k = rng.choice(len(tris), count, p=area / area.sum())
    u = rng.random((count, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    return a[k] + u[:, :1] * (b[k] - a[k]) + u[:, 1:] * (c[k] - a[k])
