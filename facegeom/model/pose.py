"""Rigid head pose from 2-D landmarks under a pinhole camera with known intrinsics (PnP).

The pose ``(R, t)`` maps the face into camera space (``x_cam = R x + t``, the
convention of :class:`facegeom.model.camera.PinholeCamera`). It is initialised in closed
form under a scaled-orthographic camera (an affine fit of the centred 2-D
points, orthonormalised; moved back along its line of sight when a large face
seen through a short focal length would reach behind the camera) and refined
by Levenberg-Marquardt on the perspective reprojection error, whose steps never
put a point behind the camera (such a step counts as a rise of the error).

The refinement is written for many targets at once (:func:`estimate_poses`):
six unknowns per target, so every step is a batch of ``6 x 6`` normal
equations (analytic Jacobian, rotation updated on the left by a rotation
vector, Marquardt's diagonal damping adapted per target). One target is the
batch of one (:func:`estimate_pose`), so single and batched fits agree.
"""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.model.camera import PinholeCamera

__all__ = ["NEAR", "estimate_pose", "estimate_poses", "in_front", "project_many", "reprojection_rms"]

NEAR = 0.01
"""A point nearer the camera than this fraction of the points' mean depth counts as behind it (the pose solvers).

Such a point sits at the lens, where the projection is singular (0 / 0): a pose with a landmark there can match
that landmark's pixel exactly and the rest badly, and the next Gauss-Newton system is numerically singular."""


def in_front(depth) -> np.ndarray:
    """Whether each set of depths ``(..., N)`` is in front of its camera: all ``> NEAR`` times their mean."""
    d = np.asarray(depth, dtype=np.float64)
    return np.all(d > NEAR * np.abs(d.mean(axis=-1, keepdims=True)), axis=-1) & np.all(d > 0, axis=-1)


def project_many(X, R, t, f, cx, cy, what: str = "landmark"):
    """Pixels of points ``X (K, ..., 3)`` seen by ``K`` cameras (``R (K,3,3)``, ``t (K,3)``, ``f, cx, cy (K,)``).

    Raises :class:`InputError` naming the first point behind its camera.
    """
    K = X.shape[0]
    Xf = X.reshape(K, int(np.prod(X.shape[1:-1])), 3)
    pc = Xf @ np.transpose(R, (0, 2, 1)) + t[:, None, :]
    depth = -pc[..., 2]
    if not np.all(depth > 0):
        k, i = np.argwhere(~(depth > 0))[0]
        where = f" (target {k})" if K > 1 else ""
        raise InputError(f"{what} {i % X.shape[-2] if X.ndim > 2 else i} is behind the camera{where} "
                         f"(depth {depth[k, i]:.6g}; the camera looks down -z)")
    u = cx[:, None] + f[:, None] * pc[..., 0] / depth
    v = cy[:, None] - f[:, None] * pc[..., 1] / depth
    return np.stack([u, v], axis=-1).reshape(X.shape[:-1] + (2,))


def _initial(P, q, f, cx, cy):
    """Scaled-orthographic pose for each target: ``(u - cx, -(v - cy)) ~ s R[:2] (x - c)``. -> R (K,3,3), t (K,3)."""
    c = P.mean(axis=1, keepdims=True)
    X = P - c  # (K, N, 3)
    Q = np.stack([q[..., 0] - cx[:, None], -(q[..., 1] - cy[:, None])], axis=-1)
    qc = Q.mean(axis=1)  # (K, 2)
    M = np.linalg.pinv(X) @ (Q - qc[:, None])  # (K, 3, 2): Q ~ X M (minimum norm for planar point sets)
    U, s, Vt = np.linalg.svd(np.transpose(M, (0, 2, 1)), full_matrices=False)  # (K,2,2), (K,2), (K,2,3)
    r12 = U @ Vt
    scale = s.mean(axis=1)
    bad = ~(np.isfinite(scale) & (scale > 0))
    if bad.any():
        raise InputError("the landmarks are degenerate (all at one point): no pose can be estimated")
    R = np.concatenate([r12, np.cross(r12[:, 0], r12[:, 1])[:, None]], axis=1)
    depth = f / scale
    # a face large in the image of a short focal length sits closer than its own depth extent: move it back along
    # the ray through its centre (its image stays centred there) until its nearest point is half as far as the centre
    front = np.einsum("kj,knj->kn", R[:, 2], X).max(axis=1)  # how far each face reaches towards the camera
    back = 2.0 * front > depth
    depth = np.where(back, 2.0 * front, depth)
    shift = np.where(back[:, None], qc * (depth / f)[:, None], qc / scale[:, None])
    t = np.concatenate([shift, -depth[:, None]], axis=1) - np.einsum("kij,kj->ki", R, c[:, 0])
    return R, t


def _residual(P, q, R, t, f, cx, cy):
    """Residuals ``(K, N, 2)``, camera-space points ``(K, N, 3)`` and depths; ``inf`` cost where a point is behind."""
    pc = P @ np.transpose(R, (0, 2, 1)) + t[:, None, :]
    depth = -pc[..., 2]
    ok = in_front(depth)
    d = np.where(depth > 0, depth, 1.0)
    uv = np.stack([cx[:, None] + f[:, None] * pc[..., 0] / d, cy[:, None] - f[:, None] * pc[..., 1] / d], axis=-1)
    r = uv - q
    cost = np.where(ok, np.einsum("kni,kni->k", r, r), np.inf)
    return r, pc, d, cost


def estimate_poses(points3d, points2d, focal, cx, cy, R0=None, t0=None, iterations: int = 50):
    """Poses of ``K`` point sets ``points3d (K, N, 3)`` seen at ``points2d (K, N, 2)`` -> ``R (K,3,3), t (K,3)``.

    ``focal, cx, cy``: scalars or ``(K,)``. ``R0, t0``: initial poses (default:
    the closed-form scaled-orthographic one). Levenberg-Marquardt stops per
    target when a step (taken or rejected) changes the cost by less than ``1e-12`` relative.
    """
    from scipy.spatial.transform import Rotation  # (here: scipy.spatial takes 0.3 s to import)

    P = np.asarray(points3d, dtype=np.float64)
    q = np.asarray(points2d, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or q.shape != P.shape[:2] + (2,):
        raise InputError(f"pose: need (K, N, 3) points and (K, N, 2) pixels, got {P.shape} and {q.shape}")
    K, N = P.shape[:2]
    if N < 4:
        raise InputError(f"pose: at least 4 landmarks are needed, got {N}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(q))):
        raise InputError("pose: landmarks contain NaN or inf")
    f, cx, cy = (np.broadcast_to(np.asarray(a, dtype=np.float64), (K,)) for a in (focal, cx, cy))
    if R0 is None:
        R, t = _initial(P, q, f, cx, cy)
    else:
        R, t = np.array(R0, dtype=np.float64).reshape(K, 3, 3), np.array(t0, dtype=np.float64).reshape(K, 3)
    r, pc, d, cost = _residual(P, q, R, t, f, cx, cy)
    if not np.all(np.isfinite(cost)):
        k = int(np.flatnonzero(~np.isfinite(cost))[0])
        raise InputError(f"pose: the initial pose puts landmarks behind the camera (target {k})")
    lam = np.full(K, 1e-3)
    active = np.ones(K, dtype=bool)
    eye6 = np.eye(6)
    for _ in range(iterations):
        if not active.any():
            break
        a = np.flatnonzero(active)
        pa, da, fa = pc[a], d[a], f[a]
        # d(u, v)/d(camera point): u = cx + f x / d, v = cy - f y / d, d = -z
        Jp = np.zeros(pa.shape[:2] + (2, 3))
        Jp[..., 0, 0] = fa[:, None] / da
        Jp[..., 0, 2] = fa[:, None] * pa[..., 0] / da ** 2
        Jp[..., 1, 1] = -fa[:, None] / da
        Jp[..., 1, 2] = -fa[:, None] * pa[..., 1] / da ** 2
        # camera point = R x + t; left perturbation exp([w]) R: d pc / d w = -[R x]_x, d pc / d t = I
        y = pa - t[a][:, None, :]  # R x
        skew = np.zeros(y.shape[:2] + (3, 3))
        skew[..., 0, 1], skew[..., 0, 2] = y[..., 2], -y[..., 1]
        skew[..., 1, 0], skew[..., 1, 2] = -y[..., 2], y[..., 0]
        skew[..., 2, 0], skew[..., 2, 1] = y[..., 1], -y[..., 0]  # = -[y]_x
        J = np.concatenate([Jp @ skew, Jp], axis=-1).reshape(a.size, -1, 6)  # (k, 2N, 6)
        H = np.einsum("kni,knj->kij", J, J)
        g = np.einsum("kni,kn->ki", J, r[a].reshape(a.size, -1))
        diag = np.einsum("kii->ki", H)
        A = H + (lam[a][:, None] * np.maximum(diag, 1e-12))[:, :, None] * eye6
        try:
            step = -np.linalg.solve(A, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -np.stack([np.linalg.lstsq(Ai, gi, rcond=None)[0] for Ai, gi in zip(A, g)])
        Rn = Rotation.from_rotvec(step[:, :3]).as_matrix() @ R[a]
        tn = t[a] + step[:, 3:]
        rn, pcn, dn, costn = _residual(P[a], q[a], Rn, tn, f[a], cx[a], cy[a])
        better = costn < cost[a]
        b = a[better]
        R[b], t[b], r[b], pc[b], d[b] = Rn[better], tn[better], rn[better], pcn[better], dn[better]
        small = np.abs(cost[a] - costn) <= 1e-12 * np.maximum(cost[a], 1e-300)
        tiny = np.abs(step).max(axis=1) <= 1e-12
        cost[b] = costn[better]
        lam[a] = np.where(better, lam[a] / 3.0, lam[a] * 4.0)
        # converged: a step, taken or not, that changes the cost by rounding only (at the minimum, raising the
        # damping until a rounding-level decrease turns up would only spend iterations)
        active[a[small | tiny | (lam[a] > 1e12)]] = False
    return R, t


def estimate_pose(points3d, points2d, camera: PinholeCamera, init: PinholeCamera | None = None,
                  iterations: int = 50) -> PinholeCamera:
    """Pose of ``points3d (N, 3)`` seen at pixels ``points2d (N, 2)``; returns a posed camera.

    ``init`` (a posed camera) starts the refinement from its pose instead of the
    closed-form initialisation (used when alternating with the expression).
    At least 4 non-collinear points are needed.
    """
    P = np.asarray(points3d, dtype=np.float64)
    q = np.asarray(points2d, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or q.shape != (P.shape[0], 2):
        raise InputError(f"pose: need (N, 3) points and (N, 2) pixels, got {P.shape} and {q.shape}")
    R0 = t0 = None
    if init is not None and init.posed:
        R0, t0 = np.asarray(init.R)[None], np.asarray(init.t)[None]
    R, t = estimate_poses(P[None], q[None], camera.focal, camera.cx, camera.cy, R0, t0, iterations)
    return camera.with_pose(_orthonormal(R[0]), t[0])


def _orthonormal(R):
    """The nearest rotation (repairs rounding accumulated by many left-multiplied updates)."""
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def reprojection_rms(points3d, points2d, camera: PinholeCamera) -> float:
    """RMS pixel distance between ``camera.project(points3d)`` ``(L, 3)`` and ``points2d`` ``(L, 2)``."""
    d = camera.project(points3d) - np.asarray(points2d, dtype=np.float64)
    return float(np.sqrt((d ** 2).sum(axis=1).mean()))
