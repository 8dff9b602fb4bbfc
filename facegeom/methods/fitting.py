"""Shared pieces of blendshape fitting: target dispatch, pose alternation, results.

Every fitter (SEM in :mod:`facegeom.methods.sem`, the baselines in ``facegeom.baselines.fitters``)
takes a :class:`~facegeom.model.rig.BlendshapeRig` and one of the targets of
:mod:`facegeom.model.rig` and returns a :class:`~facegeom.interfaces.FitResult`
(``weights`` in the rig's shape order, ``vertices`` the fitted face, ``info``).

Landmark targets whose camera has no pose (``camera.posed`` is False) get the
rigid pose estimated from the landmarks on the neutral face first, then
alternately with the expression (:func:`fit_with_pose`), as in Sec. III of the
SEM paper.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import FitResult
from facegeom.model import (
    BlendshapeRig,
    LandmarkTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    estimate_pose,
    estimate_poses,
)

__all__ = ["align_scan", "check_fit_inputs", "fit_aligned", "fit_with_pose", "fit_with_poses", "mesh_off_frame",
           "result", "to_rig_frame"]

#: A scan is off the rig's frame when the rig face's median closest-point distance to it exceeds this fraction
#: of the face's RMS radius (ICT: 5 mm of 58.6 mm; in-frame scans of random people lie 2.2-2.6 mm away).
OFF_FRAME = 0.085
#: Meshes off the frame: the first pose from the vertices whose largest shape displacement is in this quantile.
STABLE_QUARTER = 0.25

TARGETS = (MeshTarget, LandmarkTarget, PointCloudTarget)


def check_fit_inputs(rig, target):
    """Validate ``rig`` and ``target`` (type, vertex counts, landmark ids) and return them."""
    if not isinstance(rig, BlendshapeRig):
        raise InputError(f"rig must be a BlendshapeRig, got {type(rig).__name__}")
    if not isinstance(target, TARGETS):
        raise InputError(f"target must be a MeshTarget, LandmarkTarget or PointCloudTarget, got {type(target).__name__}")
    if isinstance(target, (MeshTarget, LandmarkTarget)):
        target.check(rig)
    return rig, target


def fit_with_pose(rig: BlendshapeRig, target: LandmarkTarget, solve: Callable[[PinholeCamera], np.ndarray],
                  alternations: int = 3) -> tuple[np.ndarray, PinholeCamera]:
    """Solve the expression under a known pose, or alternate pose and expression.

    ``solve(camera) -> weights (B,)`` fits the expression for a posed camera.
    With an unposed camera: pose from the neutral face's most stable landmarks
    (:func:`stable_rows`), then
    ``alternations`` rounds of (expression, pose refined from the fitted face),
    and a final expression solve.
    """
    if target.camera.posed:
        return solve(target.camera), target.camera
    ids = target.vertex_ids
    stable = stable_rows(rig, ids)
    cam = estimate_pose(rig.neutral[ids[stable]], target.points2d[stable], target.camera)
    for _ in range(alternations):
        w = solve(cam)
        cam = estimate_pose(rig.evaluate(w, ids), target.points2d, target.camera, init=cam)
    return solve(cam), cam


def fit_with_poses(rig: BlendshapeRig, ids: np.ndarray, points2d: np.ndarray, intrinsics, solve,
                   alternations: int = 3):
    """:func:`fit_with_pose` for ``K`` unposed targets sharing the landmark vertices ``ids``, batched.

    ``points2d (K, n, 2)``; ``intrinsics = (focal, cx, cy)``, each ``(K,)``;
    ``solve(R (K,3,3), t (K,3)) -> weights (K, B)``. Returns ``(weights, R, t)``.
    """
    K = points2d.shape[0]
    stable = stable_rows(rig, ids)
    P0 = np.broadcast_to(rig.neutral[ids[stable]], (K, stable.size, 3))
    R, t = estimate_poses(P0, points2d[:, stable], *intrinsics)
    base, deltas = rig.neutral[ids], rig.deltas[:, ids]
    for _ in range(alternations):
        w = solve(R, t)
        R, t = estimate_poses(base[None] + np.tensordot(w, deltas, 1), points2d, *intrinsics, R0=R, t0=t)
    return solve(R, t), R, t


def align_scan(rig: BlendshapeRig, target: PointCloudTarget):
    """A scan in the rig's frame -> ``(target, alignment or None)``.

    When the rig's face (:func:`~facegeom.model.face_template`) lies farther
    from the scan than ``OFF_FRAME`` of its size (median closest-point
    distance), the scan is off the frame (exported by another tool: turned,
    moved): the face is posed on it by a global rigid search
    (:func:`~facegeom.registration.align_rigid`) and the scan is brought back,
    ``R^T (p - t)``; the alignment (``x -> R x + t``, rig -> scan) is returned
    with it. Otherwise the target is returned as it is with None. The scan
    must be in the rig's units (:func:`~facegeom.model.scan_scale`).
    """
    from scipy.spatial import cKDTree

    from facegeom.model import face_template
    from facegeom.registration import align_rigid, rms_radius

    F = face_template(rig)
    size = rms_radius(F)
    if np.median(cKDTree(target.points).query(F)[0]) <= OFF_FRAME * size:
        return target, None
    found = align_rigid(F, target.points)
    return to_rig_frame(target, found), found


def fit_aligned(rig: BlendshapeRig, target, fitter, alternations: int | None = None, tol: float = 1e-5):
    """Fit a mesh or a scan that may be off the rig's frame -> ``(FitResult, alignment or None)``.

    In the frame (:func:`align_scan` / :func:`mesh_off_frame` say so) it is
    ``fitter.fit(rig, target)``. Off the frame the neutral's pose is biased by
    the expression (an open jaw tilts it: a rig face with jawOpen 0.6, upside
    down in mm, fitted 0.43 after the search alone), so pose and expression
    alternate as for landmarks (:func:`fit_with_pose`): rounds of (the
    fitted face's pose, the expression in that frame) until the pose changes
    by less than ``tol`` (radians; translation relative to the face's size)
    or after ``alternations`` rounds (default: 30 for meshes, whose fits take
    milliseconds; 3 for scans). The alternation converges linearly (the
    expression takes up part of a tilt), so the start matters: a mesh starts
    from Kabsch on the quarter of the face the expressions move least
    (:func:`mesh_off_frame`), then Kabsch of the fitted face; a scan from the
    global search (:func:`align_scan`), then local ICP of the fitted face
    (:func:`~facegeom.registration.icp_rigid`).
    """
    from facegeom.model import face_template
    from facegeom.registration import RigidAlignment, icp_rigid, kabsch

    # Scans: the refinement pairs the fitted face's vertices with the scan only (``both=False``): on head scans
    # (about half the points off the face) the scan -> face pairs tilted it (sem-ls, 3 exact rig faces with
    # 0.5 mm noise in any frame: 1.2-2.5 mm from the face, 0.23-0.74 with one direction; in the frame 0.15-0.32);
    # on partial face scans the two were alike (0.4-1.4 against 0.6-1.5 mm). What stays is the alternation's
    # own bias (0.3-0.8 degrees): the expression fit is not exact, and its error tilts the next pose.
    if isinstance(target, MeshTarget):
        pose = mesh_off_frame(rig, target)
        inside = target if pose is None else to_rig_frame(target, pose)
    elif isinstance(target, PointCloudTarget):
        inside, pose = align_scan(rig, target)
    else:
        return fitter.fit(rig, target), None
    r = fitter.fit(rig, inside)
    if pose is None:
        return r, None
    if alternations is None:
        alternations = 30 if isinstance(target, MeshTarget) else 3
    size = float(np.ptp(face_template(rig), axis=0).max())
    for _ in range(alternations):
        F = face_template(rig, r.vertices)
        if isinstance(target, MeshTarget):
            R, t = kabsch(F, face_template(rig, target.vertices),
                          None if target.weights is None else face_template(rig, target.weights))
        else:
            R, t, _ = icp_rigid(F[::max(1, len(F) // 1500)], target.points, pose.R, pose.t, rounds=30, tol=1e-5,
                                both=False)
        step = max(float(np.abs(R - pose.R).max()), float(np.abs(t - pose.t).max()) / size)
        pose = RigidAlignment(R, t)
        r = fitter.fit(rig, to_rig_frame(target, pose))
        if step < tol:
            break
    return r, pose


def to_rig_frame(target, pose):
    """A mesh or cloud target in the rig's frame: ``R^T (x - t)`` for the pose ``x -> R x + t`` (rig -> target)."""
    if isinstance(target, MeshTarget):
        return MeshTarget((target.vertices - pose.t) @ pose.R, target.weights)
    normals = None if target.normals is None else target.normals @ pose.R
    return PointCloudTarget((target.points - pose.t) @ pose.R, normals)


def mesh_off_frame(rig: BlendshapeRig, target: MeshTarget):
    """The pose (rig -> mesh) of a mesh in correspondence that is off the rig's frame, else None.

    Off the frame: the face's vertices lie farther from the neutral's than
    ``OFF_FRAME`` of the face's size (median distance) *and* a rigid motion
    brings them at least twice as close; an expression alone (in the frame)
    is not explained by a rigid motion, so it is left alone. The pose is
    Kabsch on the quarter of the face's vertices the rig's shapes move least
    (their largest displacement; on dense random expressions 0.2-0.5 degrees
    from the truth, against 1.5-4.3 with every vertex).
    """
    from facegeom.model import face_template
    from facegeom.registration import RigidAlignment, kabsch, rms_radius

    F, T = face_template(rig), face_template(rig, target.vertices)
    size = rms_radius(F)
    before = float(np.median(np.linalg.norm(T - F, axis=1)))
    if before <= OFF_FRAME * size:
        return None
    reach = face_template(rig, np.linalg.norm(rig.deltas, axis=2).max(axis=0))
    stable = reach <= np.quantile(reach, STABLE_QUARTER)
    R, t = kabsch(F[stable], T[stable])
    after = float(np.median(np.linalg.norm(F @ R.T + t - T, axis=1)))
    return RigidAlignment(R, t) if after <= 0.5 * before else None


def stable_rows(rig: BlendshapeRig, ids: np.ndarray, fraction: float = 0.5, minimum: int = 6) -> np.ndarray:
    """Rows of ``ids`` whose vertices the expressions move least (at least ``minimum``, about ``fraction``).

    The first pose is estimated from these only, so that an expression on the
    target (an open jaw, raised brows) does not tilt it; the rig tells which
    landmarks are stable (largest displacement over all its delta-blendshapes).
    """
    reach = np.linalg.norm(rig.deltas[:, ids], axis=2).max(axis=0)  # (L,)
    k = min(len(ids), max(minimum, int(round(fraction * len(ids)))))
    return np.sort(np.argsort(reach, kind="stable")[:k])


def result(rig: BlendshapeRig, weights, **info) -> FitResult:
    """A :class:`FitResult` with the fitted face evaluated from ``weights``."""
    w = np.asarray(weights, dtype=np.float64)
    return FitResult(weights=w, vertices=rig.evaluate(w), info=dict(info))
