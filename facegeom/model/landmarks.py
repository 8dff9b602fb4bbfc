"""The 68 Multi-PIE landmark index sets used by fitting and its benchmarks.

Indices are into the 68 Multi-PIE / iBUG landmarks (``BlendshapeRig.landmark_ids``,
``FaceModel.landmarks``); the paper is the SEM paper (Kang et al., IEEE Access).

:data:`INNER_LANDMARKS_49` are the 49 inner points the paper evaluates on (17-67
without the inner lip corners 60 and 64).  The paper splits them into 23
*used* (fitted) and 26 *unused* (evaluation only) points (Fig. 6) but does not
list them; :data:`FIT_LANDMARKS_23` / :data:`EVAL_LANDMARKS_26` is our fixed
split.  Both halves are mirror-symmetric (left/right) and both cover every
region, so a method cannot score well on the unused points by overfitting one
region:

=============  ==============================  ================================
region         fit (23)                        eval (26)
=============  ==============================  ================================
brows          17 19 21 22 24 26 (ends, mid)   18 20 23 25
nose           27 30 31 33 35 (top, tip, base) 28 29 32 34
eyes           36 37 39 42 44 45 (corners,     38 40 41 43 46 47 (other lids,
               one upper-lid point each)       all lower lid points)
outer lips     48 51 54 57 (corners, mids)     49 50 52 53 55 56 58 59
inner lips     62 66 (mid points)              61 63 65 67
=============  ==============================  ================================

The inner eye corners 39 / 42 (the paper's inter-ocular normaliser, eq. 31)
are in the fitted set. :data:`INNER_EYE_CORNERS` and :data:`OUTER_EYE_CORNERS`
give those and the outer corners 36 / 45 (right eye first); :data:`MIRROR_68`
maps each landmark to its left/right mirror.

The jaw contour (0-16) is not a set of fixed points on the face: annotators and
detectors put it on the face's *outline* in the photo, which moves over the
cheek as the head turns. :data:`SIDE_CONTOUR` are the contour points that
follow the outline (the chin 6-10 is kept fixed), :func:`contour_candidates`
the vertices each may land on, :func:`silhouette_vertices` where each lies in
one view (the candidate farthest out in the image).
"""
from __future__ import annotations

import numpy as np

__all__ = ['INNER_LANDMARKS_49', 'FIT_LANDMARKS_23', 'EVAL_LANDMARKS_26', 'INNER_EYE_CORNERS', 'OUTER_EYE_CORNERS',
           'MIRROR_68', 'SIDE_CONTOUR', 'CONTOUR_BAND', 'contour_candidates', 'silhouette_vertices',
           'JAW_CONVENTION', 'to_model_convention', 'to_annotation_convention']


INNER_LANDMARKS_49: tuple[int, ...] = tuple(i for i in range(17, 68) if i not in (60, 64))


FIT_LANDMARKS_23: tuple[int, ...] = (
    17, 19, 21, 22, 24, 26,  # brows: outer ends, middles, inner ends
    27, 30, 31, 33, 35,  # nose: top of the bridge, tip, base (both wings, centre)
    36, 37, 39, 42, 44, 45,  # eyes: four corners + one upper-lid point per eye
    48, 51, 54, 57,  # outer lips: corners, upper / lower middle
    62, 66,  # inner lips: upper / lower middle (mouth opening)
)


EVAL_LANDMARKS_26: tuple[int, ...] = tuple(i for i in INNER_LANDMARKS_49 if i not in FIT_LANDMARKS_23)


INNER_EYE_CORNERS: tuple[int, int] = (39, 42)  # right eye inner, left eye inner


OUTER_EYE_CORNERS: tuple[int, int] = (36, 45)  # right eye outer, left eye outer


def _mirror_68() -> tuple[int, ...]:
    m = list(range(68))
    pairs = [(i, 16 - i) for i in range(8)]  # jaw
    pairs += [(17 + i, 26 - i) for i in range(5)]  # brows
    pairs += [(31, 35), (32, 34)]  # nose base
    pairs += [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)]  # eyes
    pairs += [(48, 54), (49, 53), (50, 52), (55, 59), (56, 58)]  # outer lips
    pairs += [(60, 64), (61, 63), (65, 67)]  # inner lips
    for a, b in pairs:
        m[a], m[b] = b, a
    return tuple(m)


MIRROR_68: tuple[int, ...] = _mirror_68()
"""Left/right mirror of the 68 landmark indices (``MIRROR_68[36] == 45``)."""


#: The jaw-contour landmarks that follow the face's outline in a photo (both sides; the chin 6-10 stays fixed).
SIDE_CONTOUR: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 11, 12, 13, 14, 15, 16)

#: Half height of a contour point's band of candidate vertices, relative to the height of the 68 landmarks' box
#: (0.5 cm on the ICT face, about a third of the spacing of neighbouring contour points).
CONTOUR_BAND = 0.033


def contour_candidates(vertices, landmark_ids, region=None, band: float = CONTOUR_BAND) -> dict[int, np.ndarray]:
    """For each landmark of :data:`SIDE_CONTOUR`, the vertices its outline point may land on -> ``{index: ids}``.

    A candidate lies on the same side of the face (the sign of ``x``, the
    face's left-right axis, +z towards the viewer, +y up), within ``band`` x
    the landmarks' height of the landmark's own height, and between the face's
    middle and the landmark sideways (the outline of a turned face moves in
    over the cheek; past the landmark, towards the ear, it stays at the
    landmark: the contour of the 68-point convention runs in front of the
    ear). The landmark's own vertex is always a candidate.

    Parameters
    ----------
    vertices : (n, 3) float
        A face in the model's frame (the mean face).
    landmark_ids : (68,) int
        The 68 landmarks' vertex ids.
    region : (r,) int, optional
        Vertices allowed as candidates (default: all).
    band : float
        See :data:`CONTOUR_BAND`.
    """
    V = np.asarray(vertices, dtype=np.float64)
    lm = np.asarray(landmark_ids, dtype=np.int64)
    pool = np.arange(V.shape[0]) if region is None else np.unique(np.asarray(region, dtype=np.int64))
    P = V[pool]
    height = float(np.ptp(V[lm, 1])) * band
    centre_x = float(V[lm[[27, 28, 29, 30]], 0].mean())  # the nose bridge: the face's middle
    out = {}
    for k in SIDE_CONTOUR:
        x, y = V[lm[k], 0] - centre_x, V[lm[k], 1]
        dx = P[:, 0] - centre_x
        keep = (np.abs(P[:, 1] - y) <= height) & (np.sign(dx) == np.sign(x)) & (np.abs(dx) <= abs(x))
        keep &= np.abs(dx) >= 0.5 * abs(x)  # the outer half: the outline never reaches the nose
        ids = np.union1d(pool[keep], [lm[k]])
        out[k] = ids.astype(np.int64)
    return out


def silhouette_vertices(projected, landmark_ids, candidates: dict, centre_u: float) -> np.ndarray:
    """The vertex each contour landmark lies on in one view: the candidate farthest out in the image.

    Parameters
    ----------
    projected : callable
        ``projected(ids) -> (len(ids), 2)`` pixel positions of vertices (the
        posed face seen by the camera).
    landmark_ids : (L,) int
        The vertex ids of the 68 landmarks (or of those fitted, in 68 order for the contour).
    candidates : dict
        From :func:`contour_candidates`.
    centre_u : float
        The face's middle in the image (e.g. the nose's ``u``): "out" is away from it.

    Returns
    -------
    (68,) int
        ``landmark_ids`` with each :data:`SIDE_CONTOUR` entry replaced by its outline vertex.
    """
    ids = np.array(landmark_ids, dtype=np.int64)
    for k, cand in candidates.items():
        u = projected(cand)[:, 0]
        u0 = projected(np.array([ids[k]]))[0, 0]
        side = 1.0 if u0 >= centre_u else -1.0
        ids[k] = cand[int(np.argmax(side * u))]
    return ids


JAW_CONVENTION: tuple[tuple[float, float], ...] = (
    (-0.19, 0.25), (-0.13, 0.28), (-0.09, 0.32), (-0.08, 0.35), (-0.13, 0.24), (-0.20, 0.13), (-0.17, 0.10),
    (-0.14, 0.07), (0.00, 0.09), (0.14, 0.07), (0.17, 0.10), (0.20, 0.13), (0.13, 0.24), (0.08, 0.35),
    (0.09, 0.32), (0.13, 0.28), (0.19, 0.25),
)
"""Where annotators put the 17 jaw-contour points of the 68-point convention, relative to the model's.

Per point ``(dx, dy)`` in inter-ocular distances (the annotated inner eye
corners 39-42) in the photo's face frame: ``x`` along the outer eye corners
(36 -> 45), ``y`` perpendicular, towards the chin. Annotators mark the jaw
lower and wider than the ICT face's landmark vertices and outline: 0.25-0.35
below on the sides, 0.07-0.13 at the chin, 0.1-0.2 wider. Measured as the mean
difference between the annotated contour and the outline of a joint identity
fit of the 51 inner points, over 150 real faces (AFLW2000-3D re-annotated, the
half the defaults were chosen on; ``facegeom bench photos --jaw-offsets
--part design --cases 150``), made left-right symmetric. The face-to-face
spread is about as large as the offset on the sides (identity, pose): the
table is the convention's average, not a person's.
"""


def _jaw_frame(points):
    P = np.asarray(points, dtype=np.float64)
    ex = P[45] - P[36]
    n = float(np.linalg.norm(ex))
    io = float(np.linalg.norm(P[39] - P[42]))
    if not (n > 0 and io > 0):
        return None
    x = ex / n
    return x, np.array([-x[1], x[0]]), io


def to_model_convention(points) -> np.ndarray:
    """68 annotated points ``(68, 2)`` with the jaw contour moved to where the model has it (:data:`JAW_CONVENTION`).

    The inner points are returned as they are; so is everything when the eye
    corners coincide (no face frame).
    """
    P = np.array(points, dtype=np.float64)
    frame = _jaw_frame(P)
    if frame is None:
        return P
    x, y, io = frame
    d = np.asarray(JAW_CONVENTION)
    P[:17] -= io * (d[:, :1] * x + d[:, 1:] * y)
    return P


def to_annotation_convention(predicted, annotated) -> np.ndarray:
    """Predicted jaw points ``(68, 2)`` of the model moved to where annotators put them (the inverse shift).

    The face frame is the annotation's (``annotated (68, 2)``), as in
    :func:`to_model_convention`.
    """
    P = np.array(predicted, dtype=np.float64)
    frame = _jaw_frame(annotated)
    if frame is None:
        return P
    x, y, io = frame
    d = np.asarray(JAW_CONVENTION)
    P[:17] += io * (d[:, :1] * x + d[:, 1:] * y)
    return P
