"""Helpers shared by the benchmark protocols: timing, progress, fitter specs and face-area sampling.

(Method specs: :mod:`facegeom.registry`; reports: :mod:`facegeom.bench.report`.)
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.constants import FACE_AREA
from facegeom.errors import FacegeomError
from facegeom.registry import MethodSpec

__all__ = ["median_time", "available_specs", "face_area_triangles", "sample_surface", "progress_bar", "projector",
           "side_strip_seen", "PhotoAnnotator"]


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


class PhotoAnnotator:
    """Landmarks of a face as an annotator or a detector marks them in a photo (realistic protocols).

    The points of :data:`~facegeom.model.landmarks.SIDE_CONTOUR` go on the
    face's outline in the view (:func:`~facegeom.model.landmarks.silhouette_vertices`),
    the others on their vertices. ``outline=False``: every point on its vertex
    (the idealised protocol).

    Parameters
    ----------
    model : FaceModel
    indices : sequence of int
        The landmarks (indices into the 68) that are marked, in the target's row order.
    outline : bool
    """

    def __init__(self, model, indices, outline: bool = True):
        from facegeom.model.landmarks import SIDE_CONTOUR, contour_candidates

        self.lm = np.asarray(model.landmarks, dtype=np.int64)
        self.indices = list(indices)
        self.ids = self.lm[self.indices]  # what the fitters are told
        self.candidates = (contour_candidates(np.asarray(model.neutral, dtype=np.float64), self.lm,
                                              region=np.arange(FACE_AREA)) if outline else {})
        self.mask = np.isin(np.asarray(self.indices), SIDE_CONTOUR) if outline else None  # LandmarkTarget.outline

    def __call__(self, V, cam) -> np.ndarray:
        """The marked points ``(L, 2)`` (noise-free) of the face ``V (n, 3)`` seen by ``cam``."""
        from facegeom.model.landmarks import silhouette_vertices

        if not self.candidates:
            return cam.project(V[self.ids])
        seen = silhouette_vertices(lambda i: cam.project(V[i]), self.lm, self.candidates,
                                   float(cam.project(V[self.lm[[30]]])[0, 0]))
        return cam.project(V[seen[self.indices]])
