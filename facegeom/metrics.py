"""Error metrics: face-driving vertex errors, and the similarities and errors of blendshape fitting of the SEM paper.

Kang, Song, Lee, Lee, "A Selective Expression Manipulation With Parametric 3D
Facial Model", IEEE Access.  Equation numbers below are the paper's.

Motions (``dF = F - F_0``) are compared as flat vectors in ``R^(3 n)`` (or
``R^(2 L)`` for projected landmarks): every function flattens its array
arguments, so ``(n, 3)`` meshes, ``(L, 2)`` landmark sets and flat vectors all
work.

- :func:`esim` -- expressional similarity, eq. (9): ``a.b / (|a| |b|)`` (cosine).
- :func:`ersim` -- relative similarity, eq. (10): ``a.b / |a|^2``.
- :func:`esim_batch`, :func:`ersim_batch` -- the same for many candidate motions
  against one target motion (eqs. 16, 18, 20, 21, 24).
- :func:`motion_ersim` and friends -- the ERSim *evaluation* metric of the
  appendix: ``ERSim(T - B_1, F - B_1)``.
- :func:`rms_distance`, :func:`closest_point_rms`, :func:`normalized_error`,
  :func:`landmark_normalized_error`, :func:`pointcloud_normalized_error` --
  eqs. (29)-(32).
- :func:`correlation_metrics` -- Corr of eq. (33) and its split Corr(+) / Corr(-).
- :func:`mean_vertex_error_mm`, :func:`support_scores` -- not in the paper:
  ground-truth comparisons for synthetic experiments.

Zero motions: eqs. (9) and (10) divide by ``|a|`` (and ``|b|``); a zero vector
has no direction, and we return ``0.0`` (no similarity, no coefficient) rather
than NaN, so a candidate that does not move the observed points is never
selected by an ``argmax`` over ESim and gets a zero ERSim coefficient.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import InputError
from facegeom.interfaces import as_handles, as_vertices

__all__ = [
    "face_errors_mm",
    "esim",
    "ersim",
    "esim_batch",
    "ersim_batch",
    "motion_ersim",
    "mesh_ersim",
    "landmark_ersim",
    "pointcloud_ersim",
    "rms_distance",
    "closest_point_rms",
    "interocular_distance",
    "normalized_error",
    "landmark_normalized_error",
    "pointcloud_normalized_error",
    "CorrelationMetrics",
    "correlation_metrics",
    "mean_vertex_error_mm",
    "SupportScores",
    "support_scores",
]


# --------------------------------------------------------------------------- helpers


def _flat(a, name: str) -> np.ndarray:
    v = np.asarray(a, dtype=np.float64).ravel()
    if v.size == 0:
        raise InputError(f"{name} is empty")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} contains NaN or inf")
    return v


def _pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    x, y = _flat(a, "first motion"), _flat(b, "second motion")
    if x.size != y.size:
        raise InputError(
            f"motions differ in size: {np.shape(a)} ({x.size} values) vs {np.shape(b)} ({y.size} values)")
    return x, y


def _batch(motions, target) -> tuple[np.ndarray, np.ndarray]:
    M = np.asarray(motions, dtype=np.float64)
    if M.ndim < 1 or M.shape[0] == 0:
        raise InputError(f"motions must have shape (K, ...) with K >= 1, got {M.shape}")
    M = M.reshape(M.shape[0], -1)
    t = _flat(target, "target motion")
    if M.shape[1] != t.size:
        raise InputError(f"each motion has {M.shape[1]} values, the target motion {t.size}")
    if not np.all(np.isfinite(M)):
        raise InputError("motions contain NaN or inf")
    return M, t


# --------------------------------------------------------------------------- similarities


def esim(a, b) -> float:
    """Expressional similarity, eq. (9): ``ESim(dF1, dF2) = dF1.dF2 / (|dF1| |dF2|)``.

    The cosine of the angle between two motions (eq. 26), in ``[-1, 1]``;
    symmetric, and invariant to positive scaling of either motion (which is
    why eq. 15 reduces to eq. 16).  ``0.0`` if either motion is zero.
    """
    x, y = _pair(a, b)
    nx, ny = np.linalg.norm(x), np.linalg.norm(y)
    if nx == 0.0 or ny == 0.0:
        return 0.0
    return float(np.clip(np.dot(x, y) / (nx * ny), -1.0, 1.0))


def ersim(a, b) -> float:
    """Relative similarity, eq. (10): ``ERSim(dF1, dF2) = dF1.dF2 / |dF1|^2``.

    The multiplier ``alpha`` that makes ``alpha * dF1`` the orthogonal
    projection of ``dF2`` on ``dF1`` (so ``ERSim(dF1, dF1) = 1``).  Not
    symmetric: ``ERSim(dF1, dF2) = |dF2| cos(alpha) / |dF1|`` (eq. 26); linear
    in ``dF2`` (the appendix's step from a sum of ERSims to the ERSim of a
    sum); ``ERSim(c dF1, dF2) = ERSim(dF1, dF2) / c``.  ``0.0`` if ``dF1`` is zero.
    """
    x, y = _pair(a, b)
    nx2 = float(np.dot(x, x))
    if nx2 == 0.0:
        return 0.0
    return float(np.dot(x, y) / nx2)


def esim_batch(motions, target) -> np.ndarray:
    """``s_k = ESim(motions[k], target)`` for ``motions (K, ...)`` -> ``(K,)`` (eqs. 16, 20, 24)."""
    M, t = _batch(motions, target)
    nm = np.linalg.norm(M, axis=1)
    nt = np.linalg.norm(t)
    den = nm * nt
    out = np.zeros(M.shape[0])
    ok = den > 0
    out[ok] = (M[ok] @ t) / den[ok]
    return np.clip(out, -1.0, 1.0)


def ersim_batch(motions, target) -> np.ndarray:
    """``ERSim(motions[k], target)`` for ``motions (K, ...)`` -> ``(K,)`` (the coefficients of eqs. 18, 21, 24)."""
    M, t = _batch(motions, target)
    n2 = np.einsum("ij,ij->i", M, M)
    out = np.zeros(M.shape[0])
    ok = n2 > 0
    out[ok] = (M[ok] @ t) / n2[ok]
    return out


def motion_ersim(target, fitted, initial) -> float:
    """The appendix's ERSim metric: ``ERSim(target - initial, fitted - initial)``.

    Normalised by the *target* motion: 1 when the fitted motion's projection
    on the target motion equals it (higher is better, ideally 1).
    """
    t, f = _pair(target, fitted)
    i = _flat(initial, "initial shape")
    if i.size != t.size:
        raise InputError(f"initial shape has {i.size} values, the target {t.size}")
    return ersim(t - i, f - i)


def mesh_ersim(fitted, neutral, target) -> float:
    """``ERSim(T - B_1, F - B_1)`` for a target mesh ``T`` in correspondence (appendix).

    ``fitted``, ``neutral`` and ``target`` are ``(n, 3)`` arrays (any shape with the
    same number of values works, see the module docstring).
    """
    return motion_ersim(target, fitted, neutral)


def landmark_ersim(fitted, neutral, target) -> float:
    """``ERSim(L_T - Pi(B_1), Pi(F) - Pi(B_1))`` for a :class:`~facegeom.model.targets.LandmarkTarget` (appendix).

    ``fitted`` and ``neutral`` are ``(n, 3)`` faces; both are projected by the
    target's camera onto its ``(L, 2)`` landmarks.
    """
    return motion_ersim(target.points2d, target.project(fitted), target.project(neutral))


def pointcloud_ersim(fitted, neutral, target, vertex_ids=None) -> float:
    """``ERSim(S_T - B_1, F - B_1)`` for a :class:`~facegeom.model.targets.PointCloudTarget` (appendix).

    The paper does not say how ``S_T`` is put in correspondence with ``B_1``;
    we use, as in eqs. (23)-(25), the target point closest to each fitted
    vertex ``f_k`` (restricted to ``vertex_ids`` ``(k,)`` if given).

    ``fitted`` and ``neutral`` are ``(n, 3)`` faces of the same shape.
    """
    F = as_vertices(fitted, "fitted vertices")
    B1 = as_vertices(neutral, "neutral")
    if F.shape != B1.shape:
        raise InputError(f"fitted {F.shape} and neutral {B1.shape} differ in shape")
    if vertex_ids is not None:
        ids = as_handles(vertex_ids, F.shape[0], "vertex_ids")
        F, B1 = F[ids], B1[ids]
    _, j = cKDTree(target.points).query(F)
    return ersim(target.points[j] - B1, F - B1)


# --------------------------------------------------------------------------- distances, NE


def rms_distance(pred, target) -> float:
    """Root-mean-square point distance, eqs. (29) / (30) once points correspond.

    ``(1/N sum_j |pred_j - target_j|^2)^(1/2)`` for ``(N, d)`` arrays.
    """
    p = np.asarray(pred, dtype=np.float64)
    q = np.asarray(target, dtype=np.float64)
    if p.ndim != 2 or p.shape != q.shape or p.shape[0] == 0:
        raise InputError(f"pred and target must be matching non-empty (N, d) arrays, got {p.shape} and {q.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise InputError("points contain NaN or inf")
    return float(np.sqrt(np.mean(np.sum((p - q) ** 2, axis=1))))


def closest_point_rms(vertices, points, direction: str = "mesh_to_cloud") -> float:
    """``d_Pnt`` of eq. (30): RMS distance to closest points.

    ``direction="mesh_to_cloud"`` (the paper's text: ``p_k`` is the point of
    ``S_T`` closest to the vertex ``f_k``; averaged over the given vertices)
    or ``"cloud_to_mesh"`` (each target point to its closest vertex).

    ``vertices`` is ``(n, 3)``, ``points`` ``(N, 3)``; the result is in their units.
    """
    V = as_vertices(vertices, "vertices")
    P = as_vertices(points, "point cloud")
    if direction == "mesh_to_cloud":
        d, _ = cKDTree(P).query(V)
    elif direction == "cloud_to_mesh":
        d, _ = cKDTree(V).query(P)
    else:
        raise InputError(f"direction must be 'mesh_to_cloud' or 'cloud_to_mesh', got {direction!r}")
    return float(np.sqrt(np.mean(d**2)))


def interocular_distance(a, b) -> float:
    """``|a - b|`` for two eye points (2-D or 3-D); InputError if zero or not finite."""
    x, y = _flat(a, "first eye point"), _flat(b, "second eye point")
    if x.size != y.size:
        raise InputError(f"eye points differ in dimension: {x.size} vs {y.size}")
    d = float(np.linalg.norm(x - y))
    if not d > 0:
        raise InputError("inter-ocular distance is zero: the two eye points coincide")
    return d


def normalized_error(pred, target, interocular: float) -> float:
    """NE, eqs. (31) / (32): ``rms_distance(pred, target) / interocular``."""
    io = float(interocular)
    if not (np.isfinite(io) and io > 0):
        raise InputError(f"inter-ocular distance must be > 0, got {interocular}")
    return rms_distance(pred, target) / io


def landmark_normalized_error(vertices, target, eye_vertex_ids=None, rows=None,
                              interocular: float | None = None) -> float:
    """NE on 2-D landmarks, eq. (31): ``d_lnd(F, L_T) / |l_I1 - l_I2|``.

    Parameters
    ----------
    vertices : (n, 3)
        The fitted face ``F``.
    target : LandmarkTarget
    eye_vertex_ids : (2,) vertex ids, optional
        The rig vertices of the two *inner* eye corners (the appendix: "I_i are
        the indices of the inner points of eyes"; 68-landmarks 39 and 42, e.g.
        ``rig.landmark_vertices(INNER_EYE_CORNERS)``).  Both must be among the
        target's landmarks; the normaliser is their distance in the *target*
        image (eq. 31 uses the target landmarks ``l``).
    rows : optional
        Rows of ``target`` to average over (e.g. the 26 unused points); the
        normaliser is still taken from the full target.
    interocular : float, optional
        Use this normaliser instead of ``eye_vertex_ids``.
    """
    if interocular is None:
        if eye_vertex_ids is None:
            raise InputError("give eye_vertex_ids (the inner eye corners) or interocular")
        r = target.rows_of(eye_vertex_ids)
        if r.size != 2:
            raise InputError(f"eye_vertex_ids must hold 2 vertex ids, got {r.size}")
        interocular = interocular_distance(target.points2d[r[0]], target.points2d[r[1]])
    t = target if rows is None else target.subset(rows)
    return normalized_error(t.project(vertices), t.points2d, interocular)


def pointcloud_normalized_error(vertices, target, eye_vertex_ids, vertex_ids=None,
                                direction: str = "mesh_to_cloud") -> float:
    """NE on a point cloud, eq. (32): ``d_Pnt(F, S_T) / |f_I3 - f_I4|``.

    The normaliser is the distance between the two inner eye corners
    ``eye_vertex_ids`` of the *fitted* mesh ``F`` (a scan has no labelled
    eye corners).  ``vertex_ids`` restricts the vertices ``f_k`` averaged over
    (e.g. the face region the scan covers); see :func:`closest_point_rms`.
    """
    V = as_vertices(vertices, "vertices")
    eye = as_handles(eye_vertex_ids, V.shape[0], "eye_vertex_ids")
    if eye.size != 2:
        raise InputError(f"eye_vertex_ids must hold 2 vertex ids, got {eye.size}")
    io = interocular_distance(V[eye[0]], V[eye[1]])
    W = V if vertex_ids is None else V[as_handles(vertex_ids, V.shape[0], "vertex_ids")]
    return closest_point_rms(W, target.points, direction) / io


# --------------------------------------------------------------------------- redundancy


class CorrelationMetrics(NamedTuple):
    """Corr of eq. (33) and its positive / negative parts (Table 3).

    ``corr = corr_pos + corr_neg``; ``corr_neg`` is reported as a magnitude (>= 0).
    Units: squared length units of the rig (cm^2 for ICT), summed over all vertices.
    """

    corr: float
    corr_pos: float
    corr_neg: float


def correlation_metrics(rig, weights, *, gram=None) -> CorrelationMetrics:
    """Redundancy of the blendshapes used by ``weights``, eq. (33).

    ``Corr(e_F) = sum_{i<j} |e_i e_j (dB_i . dB_j)|``, over all unordered
    pairs of delta-blendshapes (neutral excluded), so only pairs with both
    weights non-zero contribute.  ``Corr(+)`` sums the pairs with
    ``e_i e_j (dB_i . dB_j) > 0`` (redundant motions), ``Corr(-)`` the
    magnitudes of those ``< 0`` (motions cancelling each other); the two add up
    to Corr (as Tables 2 and 3 of the paper do).

    Parameters
    ----------
    rig : BlendshapeRig or None
        Supplies ``dB_i . dB_j`` as ``rig.gram()`` (full 3-D meshes).
    weights : (B,) or mapping name -> weight
    gram : (B, B), optional
        Use these inner products instead (e.g. of projected landmark motions).
    """
    if gram is None:
        if rig is None:
            raise InputError("give a rig or a gram matrix")
        G = rig.gram()
    else:
        G = np.asarray(gram, dtype=np.float64)
        if G.ndim != 2 or G.shape[0] != G.shape[1]:
            raise InputError(f"gram must be a square (B, B) matrix, got {G.shape}")
        if not np.all(np.isfinite(G)):
            raise InputError("gram contains NaN or inf")
    if rig is not None:
        w = rig.as_weights(weights)
        if G.shape[0] != w.size:
            raise InputError(f"gram is {G.shape} for {w.size} weights")
    else:
        w = _flat(weights, "weights")
        if G.shape[0] != w.size:
            raise InputError(f"gram is {G.shape} for {w.size} weights")
    terms = np.triu(np.outer(w, w) * G, k=1)
    pos = float(terms[terms > 0].sum())
    neg = float(np.abs(terms[terms < 0]).sum())
    return CorrelationMetrics(pos + neg, pos, neg)


# --------------------------------------------------------------------------- ground truth


def mean_vertex_error_mm(V, V_true, region=None) -> float:
    """Mean per-vertex Euclidean distance in millimetres (inputs in centimetres, x10).

    ``region``: vertex ids ``(k,)`` or a boolean mask ``(n,)`` to average over.
    Not a metric of the paper: for synthetic targets with known ground truth.
    """
    A = as_vertices(V, "V")
    B = as_vertices(V_true, "V_true")
    if A.shape != B.shape:
        raise InputError(f"V {A.shape} and V_true {B.shape} differ in shape")
    d = np.linalg.norm(A - B, axis=1)
    if region is not None:
        r = np.asarray(region)
        if r.dtype == bool:
            if r.shape != (A.shape[0],):
                raise InputError(f"region mask must have shape ({A.shape[0]},), got {r.shape}")
            if not r.any():
                raise InputError("region mask selects no vertex")
            d = d[r]
        else:
            d = d[as_handles(r, A.shape[0], "region")]
    return float(10.0 * d.mean())


class SupportScores(NamedTuple):
    """How well a fit recovers the active shapes of a known weight vector."""

    precision: float  # |fit support & true support| / |fit support| (1.0 if the fit uses none)
    recall: float  # |fit support & true support| / |true support| (1.0 if the truth uses none)
    mean_abs_error: float  # mean over all B shapes of |w_fit - w_true|


def support_scores(w_fit, w_true, tol: float = 1e-3) -> SupportScores:
    """Precision / recall of the support ``{b : |w_b| > tol}`` and the mean absolute coefficient error.

    ``w_fit`` and ``w_true`` are ``(B,)`` weight vectors; InputError if their sizes
    differ, they hold NaN / inf, or ``tol`` is negative.
    """
    a = _flat(w_fit, "w_fit")
    b = _flat(w_true, "w_true")
    if a.size != b.size:
        raise InputError(f"w_fit has {a.size} weights, w_true {b.size}")
    tol = float(tol)
    if not (np.isfinite(tol) and tol >= 0):
        raise InputError(f"tol must be >= 0, got {tol}")
    sa, sb = np.abs(a) > tol, np.abs(b) > tol
    hit = int(np.sum(sa & sb))
    precision = hit / int(sa.sum()) if sa.any() else 1.0
    recall = hit / int(sb.sum()) if sb.any() else 1.0
    return SupportScores(float(precision), float(recall), float(np.mean(np.abs(a - b))))


def face_errors_mm(Y: np.ndarray, T: np.ndarray, region: int = FACE_AREA) -> dict:
    """Vertex errors of a driven face ``Y`` against the truth ``T``, in mm (both ``(n, 3)``, centimetres).

    Returns a dict: ``mean_mm``, ``rms_mm``, ``max_mm`` of the vertex distances
    over the face area (vertices ``[0, region)``), ``mean_all_mm`` over all
    vertices, and the paper's Frobenius error ``frobenius_mm`` = ``||Y - T||_F``.
    """
    d = np.linalg.norm(Y - T, axis=1) * CM_TO_MM
    face = d[:region]
    return {
        "mean_mm": float(face.mean()),
        "rms_mm": float(np.sqrt((face ** 2).mean())),
        "max_mm": float(face.max()),
        "mean_all_mm": float(d.mean()),
        "frobenius_mm": float(np.linalg.norm(Y - T) * CM_TO_MM),
    }
