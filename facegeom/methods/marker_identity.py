"""The actor's identity from a marker capture itself, for solving on a face model's generic face.

A capture solved on the generic face of a face model (the ICT face) puts the
actor's own proportions into the expression weights: wider-set eyes read as
``eyeWide`` at 1.0 in every frame, a broader nose as ``noseSneer`` at 0.3.
The model can describe the actor: its identity modes ``U`` span people, its
expression deltas ``D`` the expressions, and

    Y_t  =  n + U a + D w_t + noise          (the markers of frame t in the face's frame)

with one identity ``a`` for the whole capture and an expression ``w_t`` in
``[0, 1]`` per frame. :func:`fit_capture_identity` finds ``a`` as the
maximum a-posteriori estimate over a few frames of the capture (the same
energy as :class:`~facegeom.methods.identity.IdentityFitter`'s for meshes)::

    E = sum_t |Y_t - n - U a - D w_t|^2 / sigma^2  +  |a|^2  +  sum_t (|w_t|^2 / s_w^2 + 2 l1 sum(w_t))

- ``|a|^2``: the model's identity coefficients are ~ N(0, 1);
- the expression's sparsity prior ``l1`` is what tells the two apart: a
  difference that stays through every frame costs ``l1`` in each of them as
  an expression and once as an identity, so it goes to the identity, while a
  movement that comes and goes stays an expression;
- ``sigma`` is the markers' noise (0.5 mm by default, an optical system's).

Frames: the capture is cut into ``frames`` equal stretches and each gives the
frame whose solve on the generic face is the most neutral (the least total
weight) among its frames with most markers found: the neutral-looking frames
carry the identity with the least expression in the way, the stretches keep
them spread over the take.

Solver: poses and shape alternate (``rounds``). With the poses held, the
energy is a convex quadratic in ``a`` and every ``w_t`` with box bounds, a
block-arrow system (``a`` couples the frames, the frames are independent
given ``a``); a primal-dual active-set method solves it exactly, each step
one Cholesky per frame and one of the identity's Schur complement (a generic
bounded least-squares solver on all ``frames x B`` weights at once took
10 s for 16 frames; this takes milliseconds). Each pose is then the weighted
Kabsch fit of the frame's fitted face to its markers.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import InputError
from facegeom.methods.marker_solve import _cross_matrix, _rodrigues, marker_noise, solve_markers
from facegeom.model.rig import BlendshapeRig

__all__ = ["CaptureIdentity", "NOISE_MM", "fit_capture_identity", "pick_frames"]

NOISE_MM = 0.5
"""Marker noise (standard deviation per coordinate, mm): an optical system's order of magnitude."""

FRAMES = 24
"""Frames of the capture the identity is fitted on (see the module docstring)."""

FOUND_SHARE = 0.9
"""A frame is a candidate when at least this share of its markers is found (or it has the most markers found)."""

EXPRESSION_SD = 1.0
"""``s_w``: the weights' range, as for meshes in :class:`~facegeom.methods.identity.IdentityFitter`."""

EXPRESSION_L1 = 5.0
"""``l1``: the sparsity prior's rate, :class:`~facegeom.methods.identity.IdentityFitter`'s default."""

CANDIDATES = 2
"""Without a solve of the whole capture, this many frames per fitted frame are solved on the generic face to
choose from (spread over the take)."""

ROUNDS = 8
"""Gauss-Newton rounds (pose, identity and expressions together) at most."""

ACTIVE_SET_STEPS = 60
"""Projected Newton steps at most per Gauss-Newton round (they settle in a handful)."""

PDAS_STEPS = 10
"""Primal-dual active-set steps tried first (exact when they settle, usually in 2-9; on a degenerate face they can
cycle, and the projected Newton steps take over)."""

BOUND_TOL = 1e-9
"""A weight this close to a bound, with its gradient pointing out, is held at the bound."""

AT_NOISE = 1.5
"""No fit when the generic face's median marker residual on the chosen frames is at most this many times the
markers' noise (:func:`~facegeom.methods.marker_solve.marker_noise`, an over-estimate): the residual a solve leaves
on the actor's own rig is about 1.5 times the noise per coordinate (3 coordinates, less the pose's and expression's
share), so there is no shape left for an identity to explain."""

BETTER = 0.9
"""The fitted identity is worth using (``info["better"]``) when the solve's median marker residual on the fitted
frames falls below this share of the generic face's: an actor the generic face already matches (a capture of the
generic face itself, whose residual is its noise) keeps the generic face, which the fit's priors would only bias
(weight error 0.006 on the generic face, 0.023 with a fitted identity, on such a capture of 600 frames)."""

POSE_DAMPING = 1e-6
"""The pose step's damping, relative to the identity prior's weight (a guard for a degenerate frame only)."""


@dataclass
class CaptureIdentity:
    """What :func:`fit_capture_identity` returns.

    Attributes
    ----------
    identity : (I,) float64
        The actor's identity coefficients.
    neutral : (n, 3) float64
        The actor's neutral: the model's moved by the identity.
    rig : BlendshapeRig (property)
        The actor's rig: :attr:`neutral` with the model's expressions.
    frames : (K,) int64
        The capture's frames the identity was fitted on.
    info : dict
        ``time_s``, ``rounds``, ``residual_mm`` (the median marker residual of
        a solve of the fitted frames, on the generic face then on the actor's),
        ``better`` (the actor's face lowers it below :data:`BETTER` of the
        generic face's: use it), ``skipped`` (no fit: the generic face's
        residual is at the markers' noise, :data:`AT_NOISE`), ``noise_mm``
        (the markers' noise estimated from the capture), ``moved_mm`` (RMS
        distance of the marker vertices between the generic and the actor's
        neutral).
    """

    identity: np.ndarray
    neutral: np.ndarray
    frames: np.ndarray
    info: dict = field(default_factory=dict)
    model: object = field(default=None, repr=False)

    @property
    def rig(self) -> BlendshapeRig:
        """The actor's rig (the model's expressions on :attr:`neutral`), built when read."""
        return BlendshapeRig.from_face_model(self.model, self.identity)


def pick_frames(X, weights, frames: int = FRAMES) -> np.ndarray:
    """The frames to fit on: per stretch of the capture, its most neutral well-found frame -> ``(K,)`` int64.

    ``X (T, p, 3)`` markers (NaN lost), ``weights (T, B)`` a solve of each frame
    (or of the candidates only: rows of NaN are skipped).
    """
    X = np.asarray(X, dtype=np.float64)
    T = X.shape[0]
    found = np.isfinite(X).all(axis=2).sum(axis=1)
    good = found >= min(FOUND_SHARE * X.shape[1], found.max())
    total = np.asarray(weights, dtype=np.float64).sum(axis=1)
    good &= np.isfinite(total)
    out = []
    for chunk in np.array_split(np.arange(T), min(frames, T)):
        c = chunk[good[chunk]]
        if c.size:
            out.append(int(c[np.argmin(total[c])]))
    return np.array(sorted(set(out)), dtype=np.int64)


def _candidate_solve(X, ids, generic, count):
    """Solve ``count`` frames spread over the capture on the generic face: weights, rotations, translations and
    marker residuals of every frame (NaN on the others)."""
    T = X.shape[0]
    usable = np.flatnonzero(np.isfinite(X).all(axis=2).sum(axis=1) >= 3)
    if usable.size == 0:
        raise InputError("no frame of the capture has 3 markers found")
    cand = usable[np.unique(np.linspace(0, usable.size - 1, min(count, usable.size)).round().astype(np.int64))]
    s = solve_markers(X[cand], ids, generic)
    W = np.full((T, generic.n_shapes), np.nan)
    R = np.full((T, 3, 3), np.nan)
    t = np.full((T, 3), np.nan)
    rms = np.full(T, np.nan)
    W[cand], R[cand], t[cand], rms[cand] = s.raw_weights, s.rotations, s.translations, s.rms
    return W, R, t, rms


def _at_markers(rig, neutral, ids) -> BlendshapeRig:
    """``rig``'s shapes on ``neutral``, restricted to the marker vertices ``ids`` (a few hundred numbers to solve on,
    not the whole head's)."""
    return BlendshapeRig(neutral[ids], rig.deltas[:, ids], rig.names, np.zeros((1, 3), np.int64))


def _aligned(X, R, t):
    """Markers into the face's frame: ``R^T (X - t)`` -> ``(K, p, 3)`` (NaN stays NaN)."""
    return np.einsum("kji,kpj->kpi", R, X - t[:, None])


def _skew_rows(F):
    """``(K, p, 3)`` points -> ``(K, 3p, 3)``: the rows of ``-[f]_x`` (the change of ``f`` under a small rotation)."""
    K, p, _ = F.shape
    return -_cross_matrix(F.reshape(-1, 3)).reshape(K, 3 * p, 3)


def w0_full(w0, K, m, nb):
    """The start's weights ``(K, nb)`` padded with the pose's zeros -> ``(K, m)``."""
    out = np.full((K, m), 0.5)
    out[:, :nb] = w0
    return out


def _mv(A, x):
    """Batched matrix-vector products ``(K, m, n) @ (K, n)`` -> ``(K, m)``."""
    return np.matmul(A, x[..., None])[..., 0]


def _shape_step(U, Dk, n0, Y, M, sig2, prior, lin, nb, w0, a0):
    """One Gauss-Newton step of the MAP energy with ``nb`` bounded weights per frame: ``a (I,)``, ``x (K, m)``.

    ``U (3p, I)`` identity modes, ``Dk (K, 3p, m)`` per frame the expression
    deltas (the first ``nb`` columns, in ``[0, 1]``) and the pose's Jacobian
    (the rest, free), ``n0 (3p,)``, ``Y (K, 3p)`` aligned markers (0 where
    lost), ``M (K, 3p)`` 1 where found, ``sig2`` = sigma^2 (the identity
    prior's weight once scaled), ``prior (m,)`` and ``lin (m,)`` the
    diagonal and linear prior terms (scaled by sigma^2), ``w0 (K, nb)`` and
    ``a0 (I,)`` the start. Projected Newton (Bertsekas): the weights at a bound whose gradient
    points out are held there, the normal equations of the others (scaled by
    sigma^2) solved exactly, and the step taken along the projection arc
    until the energy does not rise; done when a full step stays in the box
    with the same weights held::

        (sum_t U'M_tU + sig2 I) a + sum_t U'M_tD_t x_t = sum_t U'M_t r_t
        D_t'M_tU a + (D_t'M_tD_t + diag(prior)) x_t = D_t'M_t r_t - lin
    """
    K, _, m = Dk.shape
    I = U.shape[1]
    r = (Y - n0[None]) * M
    DM = Dk * M[..., None]
    Aa = (U * M.sum(axis=0)[:, None]).T @ U + sig2 * np.eye(I)
    Cw = np.matmul(DM.transpose(0, 2, 1), Dk) + np.diag(prior)[None]  # (K, m, m)
    Bc = np.matmul(U.T[None], DM)  # (K, I, m): the coupling
    ga = U.T @ r.sum(axis=0)
    gw = np.matmul(DM.transpose(0, 2, 1), r[..., None])[..., 0] - lin[None]
    bounded = np.zeros((K, m), bool)
    bounded[:, :nb] = True
    eye = np.eye(m)[None]
    Ua = U.T  # (I, 3p)

    def energy(a, x):
        res = (r - (a @ Ua)[None] - _mv(Dk, x)) * M
        return float((res ** 2).sum() + sig2 * a @ a + (x ** 2 * prior).sum() + 2.0 * (x * lin).sum())

    def solve_face(fixed, hi):
        """The minimiser with the ``fixed`` weights held at their bounds (1 where ``hi``, else 0) -> a, x."""
        b = np.where(hi, 1.0, 0.0)
        free = (~fixed).astype(np.float64)
        # the held weights' rows become x = b; their columns move to the right-hand sides
        C = Cw * free[:, :, None] * free[:, None, :] + eye * fixed[:, :, None]
        g = (gw - _mv(Cw, b)) * free + b
        Bf = Bc * free[:, None, :]
        Z = np.linalg.solve(C, np.concatenate([np.transpose(Bf, (0, 2, 1)), g[:, :, None]], axis=2))  # (K,m,I+1)
        Bflat = Bf.transpose(1, 0, 2).reshape(I, -1)  # (I, K m)
        S = Aa - Bflat @ Z[:, :, :I].reshape(-1, I)
        a_new = np.linalg.solve(S, ga - Bc.transpose(1, 0, 2).reshape(I, -1) @ b.ravel()
                                - Bflat @ Z[:, :, I].ravel())
        return a_new, Z[:, :, I] - Z[:, :, :I] @ a_new

    # primal-dual active set first: exact in a few steps when it settles
    lo = bounded & (w0_full(w0, K, m, nb) <= 0.0)
    hi = bounded & (w0_full(w0, K, m, nb) >= 1.0)
    for _ in range(PDAS_STEPS):
        fixed = lo | hi
        a, x = solve_face(fixed, hi)
        grad = (a @ Bc) + _mv(Cw, x) - gw
        new_lo = bounded & ((fixed & lo & (grad >= 0.0)) | (~fixed & (x <= 0.0)))
        new_hi = bounded & ((fixed & hi & (grad <= 0.0)) | (~fixed & (x >= 1.0)))
        if np.array_equal(new_lo, lo) and np.array_equal(new_hi, hi):
            return a, x  # KKT: the free weights inside the box, the held ones pushing out
        lo, hi = new_lo, new_hi
    # it cycles (it can on degenerate faces): projected Newton from the start, which never raises the energy
    x = np.zeros((K, m))
    x[:, :nb] = np.clip(w0, 0.0, 1.0)
    a = np.array(a0, dtype=np.float64)
    e = energy(a, x)
    sets = None
    for _ in range(ACTIVE_SET_STEPS):
        grad = (a @ Bc) + _mv(Cw, x) - gw  # dE/dx (scaled)
        hi = bounded & (x >= 1.0 - BOUND_TOL) & (grad < 0.0)
        fixed = bounded & (x <= BOUND_TOL) & (grad > 0.0) | hi
        if sets is not None and np.array_equal(fixed, sets[0]) and np.array_equal(hi, sets[1]) and sets[2]:
            break  # the last step solved this face exactly and stayed in the box: KKT
        a_new, x_new = solve_face(fixed, hi)
        inside = bool(((x_new[:, :nb] >= 0.0) & (x_new[:, :nb] <= 1.0)).all())
        step = 1.0
        while True:  # along the projection arc until the energy does not rise
            at = a + step * (a_new - a)
            xt = x + step * (x_new - x)
            xt[:, :nb] = np.clip(xt[:, :nb], 0.0, 1.0)
            et = energy(at, xt)
            if et <= e or step < 1e-4:
                break
            step *= 0.5
        sets = (fixed, hi, inside and step == 1.0)
        if et > e:  # no descent along the arc: the face is as good as it gets
            break
        a, x, e = at, xt, et
    return a, x


def fit_capture_identity(model, positions, vertex_ids, frames: int = FRAMES, noise_mm: float = NOISE_MM, rounds: int = ROUNDS,
                         generic: BlendshapeRig | None = None) -> CaptureIdentity:
    """Fit the actor's identity of ``model`` from a marker capture (see the module docstring).

    Parameters
    ----------
    model : FaceModel
        Neutral, identity modes and expression deltas (rig units, cm).
    positions : (T, p, 3)
        Markers in the rig's unit, NaN where lost.
    vertex_ids : (p,)
    frames : int >= 1
        Frames to fit on.
    noise_mm : float > 0
        Marker noise sigma per coordinate, mm.
    rounds : int >= 1
    generic : BlendshapeRig or None
        The model's generic face as a rig, if already built (else built here).

    Returns
    -------
    CaptureIdentity
    """
    t0 = time.perf_counter()
    if not getattr(model, "n_identities", 0):
        raise InputError("this face model has no identity modes to fit")
    if not (isinstance(frames, (int, np.integer)) and frames >= 1):
        raise InputError(f"frames must be a positive integer, got {frames!r}")
    if not (np.isfinite(noise_mm) and noise_mm > 0):
        raise InputError(f"noise_mm must be a positive number, got {noise_mm!r}")
    X = np.asarray(positions, dtype=np.float64)
    ids = np.asarray(vertex_ids, dtype=np.int64)
    generic = BlendshapeRig.from_face_model(model) if generic is None else generic
    weights, rotations, translations, rms = _candidate_solve(X, ids, generic, CANDIDATES * frames)
    pick = pick_frames(X, weights, frames)
    before = float(np.median(rms[pick])) * CM_TO_MM
    noise = marker_noise(X) * CM_TO_MM
    I = int(model.n_identities)
    if before <= AT_NOISE * noise:  # the generic face explains the markers to their noise: nothing to fit
        info = {"time_s": time.perf_counter() - t0, "rounds": 0, "frames": int(pick.size),
                "residual_mm": (before, before), "better": False, "skipped": True, "noise_mm": noise,
                "moved_mm": 0.0}
        return CaptureIdentity(np.zeros(I), generic.neutral, pick, info, model)
    Xk = X[pick]
    R, t = np.array(rotations[pick]), np.array(translations[pick])
    found = np.isfinite(Xk).all(axis=2)  # (K, p)
    p = ids.size
    U = np.asarray(model.identity_modes[:, ids], dtype=np.float64).reshape(-1, 3 * p).T  # (3p, I)
    D = generic.deltas[:, ids].reshape(-1, 3 * p).T  # (3p, B)
    n0 = generic.neutral[ids].reshape(-1)
    M = np.repeat(found, 3, axis=1).astype(np.float64)
    sig2 = (noise_mm / CM_TO_MM) ** 2
    w = np.clip(np.asarray(weights, dtype=np.float64)[pick], 0.0, 1.0)
    a = np.zeros(U.shape[1])
    Xz = np.where(found[..., None], Xk, 0.0)

    K, B = w.shape
    prior = np.r_[np.full(B, sig2 / EXPRESSION_SD ** 2), np.full(6, POSE_DAMPING * sig2)]
    lin = np.r_[np.full(B, sig2 * EXPRESSION_L1), np.zeros(6)]
    Dt = np.broadcast_to(D, (K,) + D.shape)
    trans = np.broadcast_to(np.tile(np.eye(3), (p, 1)), (K, 3 * p, 3))
    done = 0
    for done in range(1, int(rounds) + 1):
        Y = np.where(found[..., None], _aligned(Xk, R, t), 0.0).reshape(K, -1)
        F = ((n0 + U @ a)[None] + w @ D.T).reshape(K, p, 3)
        Dk = np.concatenate([Dt, _skew_rows(F), trans], axis=2)
        a_new, x = _shape_step(U, Dk, n0, Y, M, sig2, prior, lin, B, w, a)
        w, turn, shift = x[:, :B], x[:, B:B + 3], x[:, B + 3:]
        R = R @ _rodrigues(turn)
        t = t + np.einsum("kij,kj->ki", R, shift)
        change = float(np.linalg.norm(a_new - a))
        a = a_new
        if change < 1e-3 * max(1.0, float(np.linalg.norm(a))) and float(np.abs(turn).max()) < 1e-5:
            break
    if not np.isfinite(a).all():
        raise InputError("the identity fit of the capture did not converge (a non-finite coefficient)")
    neutral = model.identity_neutral(a)
    moved = np.linalg.norm(neutral[ids] - generic.neutral[ids], axis=1)
    # the solve's own residual on the fitted frames, the generic face's and the actor's: is the fit worth it?
    after = float(np.median(solve_markers(Xk, np.arange(p), _at_markers(generic, neutral, ids)).rms)) * CM_TO_MM
    info = {"time_s": time.perf_counter() - t0, "rounds": done, "frames": int(pick.size),
            "residual_mm": (before, after), "better": bool(after < BETTER * before), "skipped": False,
            "noise_mm": noise,
            "moved_mm": float(np.sqrt(np.mean(moved ** 2))) * CM_TO_MM}
    return CaptureIdentity(a, neutral, pick, info, model)
