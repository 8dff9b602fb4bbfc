"""Head pose and expression weights of one person, frame after frame, from 2-D points seen by a pinhole camera.

The video path of facegeom: a person's rig (their identity, fitted once from
the video itself) is known, so every frame has only its rigid pose (6
numbers) and its ``B`` expression weights to find from ``K`` tracked points
(a few hundred of the face-mesh model's 468, each on a rig vertex). That is a
small bounded non-linear least-squares problem, solved here by Gauss-Newton
from the previous frame's answer, in a few milliseconds:

    E(R, t, w) = sum_k |pi(R (n_k + D_k w) + t) - u_k|^2 / sigma^2
               + sum_b w_b^2 / s_w^2  +  sum_b (w_b - w_prev,b)^2 / s_t^2,     0 <= w <= 1

- ``sigma`` (pixels) is the points' noise: it weighs the data against the
  priors, so a noisier track leans more on them;
- ``s_w`` is the spread of real performances' weights
  (:data:`facegeom.constants.EXPRESSION_WEIGHT_SD`, learnt from recorded
  takes): the Gaussian prior of the weights;
- ``s_t`` ties a frame's weights to the previous frame's (a random walk of
  that step size per frame; ``None`` leaves frames independent). The offline
  path leaves it off and smooths the finished curves instead, with no lag
  (:func:`facegeom.methods.marker_solve.smooth_curves`).

Each step linearises the projection (analytic Jacobian; the rotation is
updated on the left by a rotation vector), solves the ``(6 + B)`` normal
equations, and keeps the weights in ``[0, 1]`` by an active set: weights that
would leave the box are held at the bound they hit and the rest re-solved,
until no held weight wants back in.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.constants import EXPRESSION_WEIGHT_SD
from facegeom.errors import InputError
from facegeom.model.camera import PinholeCamera
from facegeom.model.pose import estimate_pose

__all__ = ["FrameSolver", "FramePose"]

ITERATIONS = 4  # Gauss-Newton steps per frame from the previous frame's answer (converged to ~1e-4 px after 3)
DAMPING = 1e-6  # Levenberg damping of the pose, relative to its normal matrix's diagonal


def _rotvec_to_matrix(r: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(r))
    if a < 1e-12:
        return np.eye(3)
    k = r / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * (K @ K)


@dataclass
class FramePose:
    """One frame's answer: the face's rotation and translation into the camera, its weights, its residual."""

    R: np.ndarray
    t: np.ndarray
    w: np.ndarray
    rms: float


class FrameSolver:
    """Pose and bounded expression weights of a known rig from the 2-D positions of some of its vertices.

    Parameters
    ----------
    neutral : (n, 3) float
        The person's neutral face (their rig's).
    deltas : (B, n, 3) float
        The rig's expression shapes as offsets.
    vertex_ids : (K,) int or (K, 3) int
        The rig vertex each tracked point lies on; with ``bary``, the triangle (three vertex ids) it lies in.
    camera : PinholeCamera
        The intrinsics (the pose is what is solved).
    noise_px : float
        The points' noise, pixels (see the module docstring).
    weight_sd : float
        ``s_w``, the weights' prior spread.
    temporal_sd : float or None
        ``s_t``, the per-frame step of the weights' random walk; None: frames independent.
    iterations : int
        Gauss-Newton steps at most per frame.
    bary : (K, 3) float, optional
        Barycentric weights of the points in their triangles (``vertex_ids`` then (K, 3)).
    point_weights : (K,) float, optional
        Each point's weight in every frame, ``(sigma / sigma_k)^2`` for a point whose own noise is ``sigma_k``
        (inverse-variance weighting; the face-mesh model places some points far better than others). A frame's
        own ``point_weights`` multiply these.
    """

    def __init__(self, neutral, deltas, vertex_ids, camera: PinholeCamera, noise_px: float = 2.0,
                 weight_sd: float = EXPRESSION_WEIGHT_SD, temporal_sd: float | None = None,
                 iterations: int = ITERATIONS, bary=None, point_weights=None):
        ids = np.asarray(vertex_ids, dtype=np.int64)
        N = np.asarray(neutral, dtype=np.float64)
        D = np.asarray(deltas, dtype=np.float64)
        if bary is None:
            if ids.ndim != 1 or ids.size < 6 or ids.min() < 0 or ids.max() >= N.shape[0]:
                raise InputError(f"vertex_ids must be at least 6 ids of the rig's {N.shape[0]} vertices")
        else:
            bary = np.asarray(bary, dtype=np.float64)
            if ids.ndim != 2 or ids.shape[1] != 3 or ids.shape[0] < 6 or bary.shape != ids.shape or \
                    ids.min() < 0 or ids.max() >= N.shape[0]:
                raise InputError(f"with bary, vertex_ids must be (P, 3) triangles (P >= 6) of the rig's "
                                 f"{N.shape[0]} vertices and bary (P, 3) their weights")
        if not (noise_px > 0 and np.isfinite(noise_px)):
            raise InputError(f"noise_px must be a positive number, not {noise_px!r}")
        if not (weight_sd > 0):
            raise InputError(f"weight_sd must be positive, not {weight_sd!r}")
        if temporal_sd is not None and not (temporal_sd > 0):
            raise InputError(f"temporal_sd must be positive or None, not {temporal_sd!r}")
        self.ids = ids
        if bary is None:
            self.N = N[ids]  # (K, 3)
            self.D = np.ascontiguousarray(D[:, ids].transpose(1, 2, 0))  # (K, 3, B)
        else:  # points inside triangles: the barycentric blend of their corners
            self.N = np.einsum("pk,pkd->pd", bary, N[ids])
            self.D = np.ascontiguousarray(np.einsum("pk,bpkd->pdb", bary, D[:, ids]))
        self.B = D.shape[0]
        self.camera = camera
        self.sigma = float(noise_px)
        self.weight_sd = float(weight_sd)
        self.temporal_sd = None if temporal_sd is None else float(temporal_sd)
        self.iterations = int(iterations)
        self.point_weights = None
        if point_weights is not None:
            pw = np.asarray(point_weights, dtype=np.float64)
            if pw.shape != (self.N.shape[0],) or not np.isfinite(pw).all() or (pw < 0).any():
                raise InputError(f"point_weights must be {self.N.shape[0]} non-negative numbers, one per point")
            self.point_weights = pw

    # ------------------------------------------------------------------ pieces
    def shape(self, w: np.ndarray) -> np.ndarray:
        """The tracked vertices ``(K, 3)`` of the face with weights ``w``."""
        return self.N + self.D @ w

    def project(self, R, t, w) -> np.ndarray:
        """The tracked vertices' pixels ``(K, 2)`` for pose ``(R, t)`` and weights ``w``."""
        X = self.shape(w) @ R.T + t
        s = -X[:, 2]
        c = self.camera
        return np.stack([c.cx + c.focal * X[:, 0] / s, c.cy - c.focal * X[:, 1] / s], axis=1)

    def initial_pose(self, uv: np.ndarray, w=None) -> tuple[np.ndarray, np.ndarray]:
        """A pose from scratch (PnP on the face with weights ``w``, default neutral)."""
        w = np.zeros(self.B) if w is None else w
        cam = estimate_pose(self.shape(w), uv, self.camera)
        return np.asarray(cam.R), np.asarray(cam.t)

    # ------------------------------------------------------------------ solve
    def solve(self, uv, R=None, t=None, w=None, w_prev=None, point_weights=None) -> FramePose:
        """One frame: pose and weights from the points ``uv (K, 2)``, starting at ``(R, t, w)``.

        ``w_prev``: the previous frame's weights for the temporal term (with ``temporal_sd``).
        ``point_weights (K,)``: per-point confidence in ``[0, 1]`` (0 drops a point).
        """
        uv = np.asarray(uv, dtype=np.float64)
        K = self.N.shape[0]
        if uv.shape != (K, 2) or not np.isfinite(uv).all():
            raise InputError(f"the points must be ({K}, 2) finite pixels, not {uv.shape}")
        w = np.zeros(self.B) if w is None else np.clip(np.asarray(w, dtype=np.float64), 0.0, 1.0)
        if R is None or t is None:
            R, t = self.initial_pose(uv, w)
        R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
        frame_pw = np.ones(K) if point_weights is None else np.asarray(point_weights, dtype=np.float64)
        pw = frame_pw if self.point_weights is None else frame_pw * self.point_weights
        sw = np.repeat(pw, 2) / self.sigma ** 2  # per residual: confidence / sigma^2
        prior = np.full(self.B, 1.0 / self.weight_sd ** 2)
        target = np.zeros(self.B)
        if self.temporal_sd is not None and w_prev is not None:
            tw = 1.0 / self.temporal_sd ** 2
            target = tw * np.asarray(w_prev, dtype=np.float64) / (prior + tw)
            prior = prior + tw
        c = self.camera
        f = c.focal
        for _ in range(self.iterations):
            Y = self.shape(w)  # (K, 3) face frame
            RY = Y @ R.T
            X = RY + t
            s = -X[:, 2]
            if np.any(s <= 1e-9):
                R, t = self.initial_pose(uv, w)
                continue
            u = c.cx + f * X[:, 0] / s
            v = c.cy - f * X[:, 1] / s
            r = np.empty(2 * K)
            r[0::2] = u - uv[:, 0]
            r[1::2] = v - uv[:, 1]
            # d(u, v) / dX: (K, 2, 3)
            Pk = np.zeros((K, 2, 3))
            Pk[:, 0, 0] = f / s
            Pk[:, 0, 2] = f * X[:, 0] / s ** 2
            Pk[:, 1, 1] = -f / s
            Pk[:, 1, 2] = -f * X[:, 1] / s ** 2
            # dX/domega = -[RY]x = [[0, RY2, -RY1], [-RY2, 0, RY0], [RY1, -RY0, 0]] ; dX/dt = I ; dX/dw = R D
            Jrot = np.empty((K, 2, 3))
            for i in range(2):
                a0, a1, a2 = Pk[:, i, 0], Pk[:, i, 1], Pk[:, i, 2]
                Jrot[:, i, 0] = -a1 * RY[:, 2] + a2 * RY[:, 1]
                Jrot[:, i, 1] = a0 * RY[:, 2] - a2 * RY[:, 0]
                Jrot[:, i, 2] = -a0 * RY[:, 1] + a1 * RY[:, 0]
            PR = Pk @ R  # (K, 2, 3)
            Jw = PR[:, :, 0, None] * self.D[:, None, 0, :]
            Jw += PR[:, :, 1, None] * self.D[:, None, 1, :]
            Jw += PR[:, :, 2, None] * self.D[:, None, 2, :]
            Jw_rot, Jt, Jw = Jrot.reshape(2 * K, 3), Pk.reshape(2 * K, 3), Jw.reshape(2 * K, self.B)
            J = np.concatenate([Jw_rot, Jt, Jw], axis=1)
            Jsw = J * sw[:, None]
            H = J.T @ Jsw
            g = Jsw.T @ r
            # priors on w: prior * (w - target)^2
            nb = 6
            H[nb:, nb:] += np.diag(prior)
            g[nb:] += prior * (w - target)
            H[:nb, :nb] += DAMPING * np.diag(np.diag(H[:nb, :nb]) + 1e-12)
            step = self._bounded_step(H, g, w)
            R = _rotvec_to_matrix(step[:3]) @ R
            t = t + step[3:6]
            w = np.clip(w + step[6:], 0.0, 1.0)
            if np.abs(step[:3]).max() < 1e-6 and np.abs(step[6:]).max() < 1e-4:  # converged (0.0001 in a weight)
                break
        res = self.project(R, t, w) - uv
        rms = float(np.sqrt(np.average((res ** 2).sum(1), weights=frame_pw + 1e-12)))  # plain pixels
        return FramePose(R, t, w, rms)

    def _bounded_step(self, H, g, w) -> np.ndarray:
        """The Newton step ``-H^-1 g`` with the weights kept in ``[0, 1]``.

        An active set on the weights: those whose step would leave the box are held at the bound they cross and
        the others re-solved with them fixed, until none leaves (at most ``B`` rounds; usually one or two).
        """
        n = H.shape[0]
        held = np.zeros(n, dtype=bool)
        step = np.zeros(n)
        for _ in range(self.B + 1):
            free = ~held
            rhs = g[free] + H[np.ix_(free, held)] @ step[held]
            try:
                step[free] = -np.linalg.solve(H[np.ix_(free, free)], rhs)
            except np.linalg.LinAlgError:
                step[free] = -np.linalg.lstsq(H[np.ix_(free, free)], rhs, rcond=None)[0]
            nw = w + step[6:]
            out = ((nw < 0.0) | (nw > 1.0)) & free[6:]
            if not out.any():
                break
            k = np.flatnonzero(out)
            held[6 + k] = True
            step[6 + k] = np.clip(nw[k], 0.0, 1.0) - w[k]
        return step
