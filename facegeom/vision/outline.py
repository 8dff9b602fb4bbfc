"""The jaw contour of the 68 landmarks on the face's outline in the image, from the 468 face-mesh points.

Annotators (and other landmark detectors) put the 17 jaw-contour points of the
68-point convention on the face's *outline* in the photo, which moves over the
cheek as the head turns; the face model's contour vertices are the outline of
a face seen from the front. The 468 face-mesh points are fixed points of the
face, so the contour is found per image, as :mod:`facegeom.model.landmarks`
does for a fitted face model:

- once: MediaPipe's canonical mesh is cut by the horizontal plane through each
  side-contour landmark (:data:`facegeom.model.landmarks.SIDE_CONTOUR`; the chin
  6-10 stays where it is), on the landmark's side of the face; the cut is a
  chain of points on the mesh's edges (two points and a blend each);
- per image: those points are placed by the detected 468 points and the one
  farthest out along the face's left-right axis (the eye line) is the outline
  (on the side turned towards the camera it is the mesh's own border, on the
  side turned away the cheek's silhouette);
- then the jaw is moved from the model's contour to where annotators draw it
  (:func:`facegeom.model.landmarks.to_annotation_convention`, measured on real
  annotated faces).
"""
from __future__ import annotations

from functools import cache

import numpy as np

from facegeom.model.landmarks import SIDE_CONTOUR, to_annotation_convention
from facegeom.vision.correspondence import canonical_mesh, landmarks68_map
from facegeom.vision.mesh import LEFT_EYE_CORNERS, RIGHT_EYE_CORNERS

__all__ = ["contour_cuts", "outline_jaw"]

INNER_FRACTION = 0.35  # cut points nearer the face's middle than this fraction of the landmark's |x| are not outline


@cache
def contour_cuts() -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """For each side-contour landmark, the cut of the canonical mesh at its height -> ``{k: (a, b, t)}``.

    Cut point ``j`` lies at ``(1 - t[j]) * P[a[j]] + t[j] * P[b[j]]`` for mesh points ``P``.
    """
    V, F = canonical_mesh()
    L = landmarks68_map().points(V)
    edges = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    ya, yb = V[edges[:, 0], 1], V[edges[:, 1], 1]
    out = {}
    for k in SIDE_CONTOUR:
        y, x = L[k, 1], L[k, 0]
        cross = (ya - y) * (yb - y) <= 0
        cross &= ya != yb
        e = edges[cross]
        t = (y - V[e[:, 0], 1]) / (V[e[:, 1], 1] - V[e[:, 0], 1])
        px = (1 - t) * V[e[:, 0], 0] + t * V[e[:, 1], 0]
        keep = np.sign(px) == np.sign(x)
        keep &= np.abs(px) >= INNER_FRACTION * abs(x)
        out[k] = (e[keep, 0].copy(), e[keep, 1].copy(), t[keep].copy())
    return out


def outline_jaw(points: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """The 68 landmarks with the side jaw contour on the outline in the image, in the annotators' convention.

    Parameters
    ----------
    points : (468, 2+) float
        The detected face-mesh points (image pixels).
    landmarks : (68, 2) float
        The landmarks from :func:`facegeom.vision.correspondence.landmarks68_from_mesh_points`.

    Returns
    -------
    (68, 2) float64
    """
    P = np.asarray(points, dtype=np.float64)[:, :2]
    out = np.array(landmarks, dtype=np.float64)
    axis = P[LEFT_EYE_CORNERS[0]] - P[RIGHT_EYE_CORNERS[0]]  # the subject's right -> left, along the eye line
    n = float(np.linalg.norm(axis))
    if not n > 0:
        return out
    axis /= n
    for k, (a, b, t) in contour_cuts().items():
        if a.size == 0:
            continue
        C = (1 - t)[:, None] * P[a] + t[:, None] * P[b]
        side = 1.0 if k > 8 else -1.0  # 0-7: the subject's right (-x), 9-16: the left
        j = int(np.argmax(side * (C @ axis)))
        out[k] = C[j]
    return to_annotation_convention(out, out)
