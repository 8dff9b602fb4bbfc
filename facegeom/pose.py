"""Rigid head pose from 2-D landmarks under a pinhole camera with known intrinsics (PnP).

The pose ``(R, t)`` maps the face into camera space (``x_cam = R x + t``, the
convention of :class:`facegeom.rig.PinholeCamera`). It is initialised in closed
form under a scaled-orthographic camera (an affine fit of the centred 2-D
points, orthonormalised) and refined by Levenberg-Marquardt on the perspective
reprojection error (scipy ``least_squares``, rotation as a rotation vector).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .errors import InputError
from .rig import PinholeCamera

__all__ = ["estimate_pose", "reprojection_rms"]


def _project(points, rvec, t, f, cx, cy):
    pc = Rotation.from_rotvec(rvec).apply(points) + t
    depth = -pc[:, 2]
    return np.c_[cx + f * pc[:, 0] / depth, cy - f * pc[:, 1] / depth], depth


def _initial(points, uv, f, cx, cy):
    """Scaled-orthographic pose: ``(u - cx, -(v - cy)) ~ s * R[:2] (x - c)``."""
    c = points.mean(axis=0)
    X = points - c
    q = np.c_[uv[:, 0] - cx, -(uv[:, 1] - cy)]
    qc = q.mean(axis=0)
    M, *_ = np.linalg.lstsq(X, q - qc, rcond=None)  # (3, 2): q ~ X @ M
    U, s, Vt = np.linalg.svd(M.T, full_matrices=False)  # rows of R[:2] ~ M.T / scale
    r12 = U @ Vt
    scale = float(s.mean())
    if not np.isfinite(scale) or scale <= 0:
        raise InputError("the landmarks are degenerate (all at one point): no pose can be estimated")
    r3 = np.cross(r12[0], r12[1])
    R = np.vstack([r12, r3])
    if np.linalg.det(R) < 0:
        R[2] *= -1
    depth = f / scale
    # the centroid maps to (qc / scale) laterally at depth `depth` in front of the camera (z = -depth)
    t = np.r_[qc / scale, -depth] - R @ c
    return R, t


def estimate_pose(points3d, points2d, camera: PinholeCamera, init: PinholeCamera | None = None,
                  max_nfev: int = 50) -> PinholeCamera:
    """Pose of ``points3d (N, 3)`` seen at pixels ``points2d (N, 2)``; returns a posed camera.

    ``init`` (a posed camera) starts the refinement from its pose instead of the
    closed-form initialisation (used when alternating with the expression).
    At least 4 non-collinear points are needed.
    """
    P = np.asarray(points3d, dtype=np.float64)
    q = np.asarray(points2d, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or q.shape != (P.shape[0], 2):
        raise InputError(f"pose: need (N, 3) points and (N, 2) pixels, got {P.shape} and {q.shape}")
    if P.shape[0] < 4:
        raise InputError(f"pose: at least 4 landmarks are needed, got {P.shape[0]}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(q))):
        raise InputError("pose: landmarks contain NaN or inf")
    f, cx, cy = camera.focal, camera.cx, camera.cy
    if init is not None and init.posed:
        R0, t0 = np.asarray(init.R), np.asarray(init.t)
    else:
        R0, t0 = _initial(P, q, f, cx, cy)
    x0 = np.r_[Rotation.from_matrix(R0).as_rotvec(), t0]

    def resid(x):
        uv, depth = _project(P, x[:3], x[3:], f, cx, cy)
        r = (uv - q).ravel()
        if np.any(depth <= 0):  # behind the camera: a large, smooth penalty keeps the solver in front
            r = r + 1e6 * np.repeat(np.minimum(depth, 0) ** 2, 2)
        return r

    sol = least_squares(resid, x0, method="lm", max_nfev=max_nfev * 7, x_scale="jac")
    R = Rotation.from_rotvec(sol.x[:3]).as_matrix()
    t = sol.x[3:]
    if np.any(-(P @ R.T + t)[:, 2] <= 0):
        raise InputError("pose: no pose puts every landmark in front of the camera")
    return camera.with_pose(R, t)


def reprojection_rms(points3d, points2d, camera: PinholeCamera) -> float:
    """RMS pixel distance between ``camera.project(points3d)`` and ``points2d``."""
    d = camera.project(points3d) - np.asarray(points2d, dtype=np.float64)
    return float(np.sqrt((d ** 2).sum(axis=1).mean()))
