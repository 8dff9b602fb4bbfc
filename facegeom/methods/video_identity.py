"""A person's identity and the camera's focal length from tracked 2-D points of a few video frames.

The face model is linear in the identity coefficients ``a`` and the expression
weights ``w``; a video shows one person under one camera, so ``a`` and the
focal length ``f`` are shared by every frame while each frame has its own
pose and expression. :func:`fit_identity_frames` alternates two cheap solves
on ``K`` chosen frames:

1. per frame, pose and bounded weights with ``a`` and ``f`` fixed
   (:class:`facegeom.methods.frame_solver.FrameSolver`);
2. ``a`` and ``log f`` with the poses and weights fixed: one Gauss-Newton step
   of the reprojection error over all frames with the identity prior
   ``|a|^2`` (ICT's coefficients are N(0, 1)) tempered by ``K`` -- the frames
   count as one image's worth of evidence for the identity, because each
   brings its own pose and expression (the Neyman-Scott effect measured in
   :mod:`facegeom.methods.identity`) -- and a weak prior on the focal length
   (``log f`` with a standard deviation of :data:`FOCAL_LOG_SD` about
   :data:`FOCAL_PRIOR` times the frame's larger side).

The focal length is seen through perspective: a face that turns or comes
nearer changes shape in the image by an amount that depends on ``f``. With
little head motion it stays near its prior; with motion it moves to the data.
Its step moves along the *dolly zoom*: the focal length and every face's
distance scale together, so the faces keep their size in the image and only
the perspective changes. (A step in ``f`` alone, with the depths fixed,
mostly rescales the faces, which the next pose step undoes: the alternation
then crawls; measured on the tune clips, 12 rounds left the focal length
within 2 % of its prior's centre whatever the truth.)

Why not :class:`facegeom.methods.identity.IdentityFitter`: its general path
(meshes, clouds, outlines, Occam's factor, any number of landmarks) took 12 s
for 10 frames of 432 points on this project's 2-core machine; this
specialised solve takes well under a second and shares the per-frame solver
the tracker uses anyway.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.constants import EXPRESSION_WEIGHT_SD
from facegeom.errors import InputError
from facegeom.methods.frame_solver import FramePose, FrameSolver
from facegeom.model.camera import PinholeCamera

__all__ = ["IdentityFrames", "fit_identity_frames", "FOCAL_LOG_SD", "FOCAL_PRIOR"]

OFFSET_SD = None  # per-point offsets off by default: on the tune clips they made the face error worse (1.01 -> 1.27
# of the neutral's with a 2 mm prior, 1.24 with 0.5 mm): the calm frames still hold expression, which they absorb
FOCAL_PRIOR = 0.75
"""The focal length's prior centre, in the frame's larger side: a horizontal field of view of 67 degrees, the middle
of phone front cameras (about 23-26 mm equivalent, 70-75 degrees) and webcams (60-78 degrees)."""
FOCAL_LOG_SD = 0.35  # prior sd of log(focal / centre): 0.7x-1.4x at one sd (horizontal fields of view ~50-85 degrees)
ROUNDS = 6  # alternations of (frames, identity) -- the identity moves less than 0.01 cm after 5 on the tune clips


@dataclass
class IdentityFrames:
    """The result of :func:`fit_identity_frames`.

    Attributes
    ----------
    identity : (I,) float64
        The identity coefficients.
    neutral : (n, 3) float64
        The person's neutral face.
    focal : float
        The focal length, pixels.
    poses : list of FramePose
        The chosen frames' poses and weights.
    rms : float
        The reprojection error over the chosen frames, pixels.
    offsets : (P, 3) float64
        Each point's offset from where the map puts it, in the face's frame (cm; zeros when not fitted).
    """

    identity: np.ndarray
    neutral: np.ndarray
    focal: float
    poses: list
    rms: float
    offsets: np.ndarray


def fit_identity_frames(points, vertex_ids, width: int, height: int, neutral, deltas, modes=None,
                        focal: float | None = None, noise_px: float = 2.0, rounds: int = ROUNDS,
                        weight_sd: float = EXPRESSION_WEIGHT_SD, offset_sd: float | None = OFFSET_SD,
                        bary=None, point_weights=None) -> IdentityFrames:
    """Identity (and focal length, unless given) of the person seen in ``points``.

    Parameters
    ----------
    points : (K, P, 2) float
        The tracked points of ``K`` frames (pixels, 0-based).
    vertex_ids : (P,) int or (P, 3) int
        The face vertex each point lies on; with ``bary``, the triangle it lies in.
    width, height : int
        The frame size (the principal point is its centre).
    neutral : (n, 3) float
        The generic neutral face (with ``modes``), or the person's own (without: only the focal length and
        the frames' poses are fitted).
    deltas : (B, n, 3) float
        The expression shapes.
    modes : (I, n, 3) float, optional
        The identity modes (coefficients ~ N(0, 1)); None: the identity is ``neutral``.
    focal : float, optional
        The focal length in pixels when known; otherwise estimated.
    noise_px : float
        The points' noise (pixels): the data's weight against the priors.
    offset_sd : float or None
        Also fit a 3-D offset per point (cm, Gaussian prior of this spread; None: no offsets): where the
        face-mesh model puts a point on this person's face and where the map (made once on the face model's
        geometry) expects it differ by a few millimetres, the same in every frame. Left in, that difference
        reads as a constant expression; fitted on the chosen (calm) frames, it is absorbed once.
    bary : (P, 3) float, optional
        Barycentric weights of the points in their triangles.
    point_weights : (P,) float, optional
        Each point's weight in the frames' pose and expression solves, ``(noise_px / its own noise)^2`` (see
        :class:`~facegeom.methods.frame_solver.FrameSolver`); default all 1. The identity's own step weighs the
        points alike: the smooth cheeks and forehead, the vaguest points, carry most of the face's shape (on
        the benchmark's clips, weighing them down there too raised the face error by 10-15 %).
    """
    X = np.asarray(points, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 2 or X.shape[0] < 1 or not np.isfinite(X).all():
        raise InputError(f"points must be (K, P, 2) finite pixels, not {X.shape}")
    ids = np.asarray(vertex_ids, dtype=np.int64)
    K, P = X.shape[:2]
    w3 = None if bary is None else np.asarray(bary, dtype=np.float64)
    base = np.asarray(neutral, dtype=np.float64)
    modes = np.zeros((0, base.shape[0], 3)) if modes is None else np.asarray(modes)
    I = modes.shape[0]
    if w3 is None:
        M = np.asarray(modes[:, ids], dtype=np.float64).transpose(1, 2, 0)  # (P, 3, I)
    else:
        M = np.einsum("pk,ipkd->pdi", w3, np.asarray(modes[:, ids], dtype=np.float64))
    D = np.asarray(deltas, dtype=np.float64)
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    f0 = FOCAL_PRIOR * float(max(width, height))
    estimate_f = focal is None
    f = f0 if focal is None else float(focal)
    a = np.zeros(I)
    off = np.zeros((P, 3))
    sigma2 = float(noise_px) ** 2
    poses: list[FramePose | None] = [None] * K
    for _ in range(max(1, rounds)):
        face = base + np.tensordot(a, modes, axes=1) if I else base
        solver = FrameSolver(face, D, ids, PinholeCamera(f, cx, cy), noise_px=noise_px, weight_sd=weight_sd,
                             bary=w3, point_weights=point_weights)
        solver.N = solver.N + off
        for k in range(K):
            p = poses[k]
            poses[k] = solver.solve(X[k]) if p is None else solver.solve(X[k], p.R, p.t, p.w)
        # one Gauss-Newton step on (a, log f) with the poses and weights fixed
        n_par = I + (1 if estimate_f else 0)
        if n_par == 0:
            if offset_sd is not None:
                off = _offsets(X, poses, solver, f, cx, cy, sigma2, offset_sd, off)
                continue
            break
        H = np.zeros((n_par, n_par))
        g = np.zeros(n_par)
        for k in range(K):
            p = poses[k]
            Y = solver.shape(p.w)
            Xc = Y @ p.R.T + p.t
            s = -Xc[:, 2]
            u = cx + f * Xc[:, 0] / s
            v = cy - f * Xc[:, 1] / s
            r = np.empty(2 * P)
            r[0::2], r[1::2] = u - X[k, :, 0], v - X[k, :, 1]
            Pk = np.zeros((P, 2, 3))
            Pk[:, 0, 0] = f / s
            Pk[:, 0, 2] = f * Xc[:, 0] / s ** 2
            Pk[:, 1, 1] = -f / s
            Pk[:, 1, 2] = -f * Xc[:, 1] / s ** 2
            PR = Pk @ p.R
            Ja = PR[:, :, 0, None] * M[:, None, 0, :]
            Ja += PR[:, :, 1, None] * M[:, None, 1, :]
            Ja += PR[:, :, 2, None] * M[:, None, 2, :]
            J = Ja.reshape(2 * P, I)
            if estimate_f:  # the dolly-zoom direction: f and the face's depth scale together (see below)
                jf = np.empty(2 * P)
                jf[0::2] = u - cx + Pk[:, 0, 2] * p.t[2]
                jf[1::2] = v - cy + Pk[:, 1, 2] * p.t[2]
                J = np.concatenate([J, jf[:, None]], axis=1)
            H += J.T @ J / sigma2
            g += J.T @ r / sigma2
        H[:I, :I] += K * np.eye(I)  # the identity prior, tempered by the number of frames
        g[:I] += K * a
        if estimate_f:
            lf = np.log(f / f0)
            H[I, I] += 1.0 / FOCAL_LOG_SD ** 2
            g[I] += lf / FOCAL_LOG_SD ** 2
        step = -np.linalg.solve(H, g)
        a = a + step[:I]
        if estimate_f:
            ds = float(np.clip(step[I], -0.5, 0.5))
            f = float(f * np.exp(ds))
            for p in poses:  # each face moves away as the lens gets longer: its size in the image stays
                p.t = p.t * np.array([1.0, 1.0, np.exp(ds)])
        if offset_sd is not None:
            off = _offsets(X, poses, solver, f, cx, cy, sigma2, offset_sd, off)
    face = base + np.tensordot(a, modes, axes=1) if I else base
    solver = FrameSolver(face, D, ids, PinholeCamera(f, cx, cy), noise_px=noise_px, weight_sd=weight_sd,
                         bary=w3, point_weights=point_weights)
    solver.N = solver.N + off
    poses = [solver.solve(X[k], p.R, p.t, p.w) for k, p in enumerate(poses)]
    rms = float(np.sqrt(np.mean([p.rms ** 2 for p in poses])))
    return IdentityFrames(a, face, f, poses, rms, off)


def _offsets(X, poses, solver, f, cx, cy, sigma2, sd, off) -> np.ndarray:
    """The per-point offsets (cm, face frame) that best explain the residuals of the frames' fits, with the
    Gaussian prior ``N(0, sd^2)`` per coordinate: one 3 x 3 solve per point (the poses and weights fixed)."""
    P = X.shape[1]
    H = np.zeros((P, 3, 3))
    g = np.zeros((P, 3))
    base = solver.N - off  # the faces without the current offsets
    for k, p in enumerate(poses):
        Y = base + solver.D @ p.w + off
        Xc = Y @ p.R.T + p.t
        s = -Xc[:, 2]
        r = np.stack([cx + f * Xc[:, 0] / s - X[k, :, 0], cy - f * Xc[:, 1] / s - X[k, :, 1]], axis=1)
        Pk = np.zeros((P, 2, 3))
        Pk[:, 0, 0] = f / s
        Pk[:, 0, 2] = f * Xc[:, 0] / s ** 2
        Pk[:, 1, 1] = -f / s
        Pk[:, 1, 2] = -f * Xc[:, 1] / s ** 2
        J = Pk @ p.R  # (P, 2, 3): d pixel / d offset
        H += np.einsum("pij,pik->pjk", J, J) / sigma2
        g += np.einsum("pij,pi->pj", J, r) / sigma2
    H += np.eye(3)[None] / sd ** 2
    g += off / sd ** 2
    return off - np.linalg.solve(H, g[..., None])[..., 0]
