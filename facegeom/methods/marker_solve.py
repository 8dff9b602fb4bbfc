"""Marker solve: 3-D capture markers -> blendshape weights of a rig, with the rigid head motion removed.

A :class:`~facegeom.model.targets.MarkerTarget` holds the positions of ``p``
known rig vertices in the capture's own rigid frame. The solve is

    X_j  ~  R (neutral_j + sum_b w_b dB_bj) + t          (j = 1..p markers)

in two parts that alternate (the landmark fits of :mod:`facegeom.methods.fitting`
do the same with a camera):

1. **rigid pose** ``(R, t)``: weighted Kabsch (orthogonal Procrustes, no
   scale) of the neutral onto the markers the rig's expressions move least
   (:func:`facegeom.methods.fitting.stable_rows`), so that an open jaw does
   not tilt the head; then a few Gauss-Newton steps on the pose *and* an
   unbounded, lightly damped expression together (:func:`_joint_pose`), so
   that expression motion is not absorbed into the pose (the pose is kept,
   the expression is left to the fitter). Optional further rounds
   (``alternations``) re-estimate the pose by Kabsch of the fitted face with
   Huber weights (``2.5`` robust sigmas) and refit the expression.
2. **expression** ``w``: the markers brought into the rig's frame,
   ``R^T (X - t)``, are a :class:`~facegeom.model.targets.MeshTarget` of the
   rig *restricted to the marker vertices* (:func:`marker_rig`), so every
   fitter solves it with its own mesh path, unchanged. Without confidences
   the targets of all frames are one batched
   :func:`~facegeom.interfaces.fit_many` call on an array, a lost marker
   imputed where the joint least-squares expression of step 1 (later: the
   fitted face) puts it -- exact on noise-free captures, and it keeps the
   baselines on their batched path (per-frame weighted fits were 100x slower
   for L1Reg / L2Reg); with confidences each frame is a weighted mesh target
   (weight = confidence, 0 for a lost marker).

Why this design: the expression problem is then exactly each fitter's own
(SEM's selection, the baselines' priors), no new solver is needed, and the
restricted rig has only ``3p`` rows, so a batched fit of 1,000 frames is a few
small matrix products.

:func:`solve_markers` runs it on a sequence ``(T, p, 3)`` and optionally
smooths the weight curves (:func:`smooth_curves`: a Whittaker smoother per
curve whose strength is chosen by generalised cross-validation).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import MAX_COORDINATE, FitResult, as_handles, batched_targets, fit_many
from facegeom.methods.fitting import stable_rows
from facegeom.model.rig import BlendshapeRig
from facegeom.model.targets import MarkerTarget, MeshTarget
from facegeom.registry import create

__all__ = ["MarkerSolve", "fit_markers", "marker_noise", "split_markers", "kabsch", "marker_rig", "smooth_curves", "solve_markers"]

HUBER = 2.5
"""Huber threshold of the pose weights, in robust sigmas (1.4826 x median residual)."""

GN_ITERATIONS = 8
"""Gauss-Newton steps of the joint pose refinement (it stops earlier once the pose no longer moves)."""

DAMPING = 1e-6
"""Step damping of the weights during the pose refinement, relative to the mean squared norm of a shape.

Measured on 300 synthetic frames (ict80, random weights and head poses): with
0.5 mm marker noise the weight error is 0.0183-0.0185 for any value in
``1e-2 .. 1e-9``; noise-free, ``1e-6`` reaches the exact pose (3e-14 rad) in
the :data:`GN_ITERATIONS` steps, ``1e-2`` is still 2.5e-4 rad away.
"""

ALTERNATIONS = 0
"""Default rounds of (robust Kabsch pose from the fitted face, expression refit) after the first fit.

0: the joint Gauss-Newton pose is already within ~1e-4 rad of the truth on
noise-free captures, and each round costs one more fit (see the module docstring).
"""

_RIGS: dict = {}

_DEFAULT: list = []


def _default_fitter():
    """The default fitter, ``sem-ls``, built once: by entry point (sem.py imports this module), whose lookup
    scans the installed packages' metadata (~5 ms a call, a few % of a 1,000-frame solve)."""
    if not _DEFAULT:
        _DEFAULT.append(create("fitters", "sem-ls"))
    return _DEFAULT[0]


def marker_rig(rig: BlendshapeRig, vertex_ids) -> BlendshapeRig:
    """The rig restricted to ``vertex_ids (p,)``: ``neutral[ids]``, ``deltas[:, ids]``, same shape names.

    It has no triangles of its own (one degenerate triangle stands in) and no
    landmark ids, so the baselines normalise by its RMS size. The last few
    restrictions are cached (a fitter caches its model per rig object).
    """
    ids = as_handles(vertex_ids, rig.n_vertices, "marker vertex_ids")
    key = (id(rig), ids.tobytes())
    hit = _RIGS.get(key)
    if hit is not None and hit[0] is rig:
        return hit[1]
    sub = BlendshapeRig(rig.neutral[ids], rig.deltas[:, ids], rig.names, np.zeros((1, 3), np.int64))
    if len(_RIGS) >= 8:
        _RIGS.pop(next(iter(_RIGS)))
    _RIGS[key] = (rig, sub)
    return sub


def kabsch(source, target, weights):
    """Weighted rigid fits ``R source + t ~ target`` for ``K`` point sets at once.

    Parameters
    ----------
    source, target : (K, p, 3)
        Corresponding points (rows with weight 0 may hold anything finite).
    weights : (K, p)
        Non-negative weights, at least 3 positive per set.

    Returns
    -------
    R : (K, 3, 3)
        Proper rotations (det +1).
    t : (K, 3)
    """
    A = np.asarray(source, dtype=np.float64)
    B = np.asarray(target, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    ws = w.sum(axis=1, keepdims=True)
    ws = np.where(ws > 0, ws, 1.0)
    ca = np.einsum("kp,kpi->ki", w, A) / ws
    cb = np.einsum("kp,kpi->ki", w, B) / ws
    H = np.matmul(((A - ca[:, None]) * w[..., None]).transpose(0, 2, 1), B - cb[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.matmul(U, Vt)))
    d[d == 0] = 1.0
    U[:, :, 2] *= d[:, None]
    R = np.matmul(U, Vt).transpose(0, 2, 1)
    t = cb - np.einsum("kij,kj->ki", R, ca)
    return R, t


def _huber(resid, w):
    """Huber weights of residuals ``(K, p)`` (only markers with ``w > 0`` set the scale)."""
    r = np.where(w > 0, resid, np.nan)
    sigma = 1.4826 * np.nanmedian(r, axis=1, keepdims=True)
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(resid > HUBER * sigma, HUBER * sigma / resid, 1.0)
    return np.nan_to_num(h, nan=1.0)


def _rodrigues(v):
    """Rotation matrices ``(K, 3, 3)`` of rotation vectors ``v (K, 3)``."""
    th = np.linalg.norm(v, axis=1)
    k = v / np.where(th > 0, th, 1.0)[:, None]
    Kx = np.zeros((v.shape[0], 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx = Kx - Kx.transpose(0, 2, 1)
    s, c = np.sin(th)[:, None, None], np.cos(th)[:, None, None]
    return np.eye(3)[None] + s * Kx + (1.0 - c) * np.matmul(Kx, Kx)


def _cross_matrix(v):
    """``[v]x (K, 3, 3)``: ``[v]x u = v x u`` for ``v (K, 3)``."""
    C = np.zeros((v.shape[0], 3, 3))
    C[:, 0, 1], C[:, 0, 2], C[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    return C - C.transpose(0, 2, 1)


def _weights_block_solver(D, mu, W):
    """``apply(X)`` = ``X_k (D^T W_k D + mu I)^-1`` for every frame ``k`` and ``X (K, r, B)`` (``W_k`` its weights).

    With weights of 0 and 1 only (lost markers, no confidences) a frame's block is the full one less its
    lost markers' rank-3 terms, ``A_k = A - U_k^T U_k`` (``U_k`` the lost markers' rows of ``D``), so by
    the Woodbury identity ``X A_k^-1 = X A^-1 + (X V_k^T) (I - U_k V_k^T)^-1 V_k`` with ``V_k = U_k A^-1``:
    one product with the full block's inverse for all frames, then products with ``3 l`` columns for a
    frame of ``l`` lost markers (frames with as many lost markers together), instead of an inversion of
    ``B`` unknowns per frame (on 1,000 frames of 80 markers, 5 % lost, the inversions alone took longer
    than the whole pose refinement does now). Frames that lost more than ``B / 6`` markers, and every frame
    with confidences, get their own block inverted.
    """
    K, p = W.shape
    B = D.shape[1]
    Dj = D.reshape(p, 3, B)

    def inverses(rows):  # each frame's block, inverted
        outer = np.einsum("jab,jac->jbc", Dj, Dj).reshape(p, B * B)  # D_j^T D_j per marker
        return np.linalg.inv((W[rows] @ outer).reshape(rows.size, B, B) + mu * np.eye(B)[None])

    if not np.all((W == 0.0) | (W == 1.0)):
        inv = inverses(np.arange(K))
        return lambda X: np.matmul(X, inv)
    Ai = np.linalg.inv(D.T @ D + mu * np.eye(B))
    DA = (D @ Ai).reshape(p, 3, B)  # the rows of V of every marker
    lost = W == 0.0
    n_lost = lost.sum(axis=1)
    groups = []
    # beyond B / 6 lost markers the update costs more than the inversion (and its system grows ill-conditioned)
    many = np.flatnonzero(3 * n_lost > B // 2)
    dense = (many, inverses(many)) if many.size else None
    for n in np.unique(n_lost[(n_lost > 0) & (3 * n_lost <= B // 2)]):
        rows = np.flatnonzero(n_lost == n)
        idx = np.nonzero(lost[rows])[1].reshape(rows.size, n)  # the lost markers of each frame
        # a marker stays lost for a run of frames: one factor per distinct set of lost markers
        idx, which = np.unique(idx, axis=0, return_inverse=True)
        U = Dj[idx].reshape(idx.shape[0], 3 * n, B)
        V = DA[idx].reshape(idx.shape[0], 3 * n, B)
        C = np.eye(3 * n)[None] - np.matmul(U, V.transpose(0, 2, 1))
        CiV = np.matmul(np.linalg.inv(C), V)  # 2-3x faster than solve(C, V) with B right-hand sides
        which = which.reshape(-1)
        groups.append((rows, V.transpose(0, 2, 1)[which], CiV[which]))

    def apply(X):
        out = (X.reshape(-1, B) @ Ai).reshape(X.shape)
        for rows, Vt, CiV in groups:
            out[rows] += np.matmul(np.matmul(X[rows], Vt), CiV)
        if dense is not None:
            out[dense[0]] = np.matmul(X[dense[0]], dense[1])
        return out

    return apply


def _joint_pose(sub: BlendshapeRig, X0, W, R, t, iterations: int = GN_ITERATIONS):
    """Refine ``(R, t)`` by Gauss-Newton on pose and (damped, unbounded) weights jointly.

    Minimises ``sum_j W_j |R^T (X_j - t) - neutral_j - D_j w|^2`` over
    ``R, t, w``; only the pose is kept (the fitter then solves the weights).
    Each step is damped towards the previous step's weights,
    ``+ mu |w - w_prev|^2`` (``mu`` = ``DAMPING`` x the mean squared norm of a
    shape), so that a combination of shapes that nearly moves the markers
    rigidly cannot jump into the pose in one step, while the fixed point is the
    undamped least-squares solution (no bias).
    """
    K, p = W.shape
    B = sub.n_shapes
    D = sub.deltas.transpose(1, 2, 0).reshape(3 * p, B)  # rows (marker, axis)
    # shapes that move none of the markers (every shape of a rig of tongue shapes, or of one shape equal to the
    # neutral) leave D^T D zero: any positive damping then keeps their weights at 0 and the solve regular
    mu = DAMPING * float(np.mean(np.einsum("rb,rb->b", D, D))) or DAMPING
    uniform = bool(np.all(W == 1.0))
    eps = np.zeros((3, 3, 3))  # Levi-Civita: S_j[a, c] = eps[a, c, d] y_j[d]
    eps[0, 1, 2] = eps[1, 2, 0] = eps[2, 0, 1] = 1.0
    eps[0, 2, 1] = eps[2, 1, 0] = eps[1, 0, 2] = -1.0
    M = np.einsum("jab,acd->jdbc", D.reshape(p, 3, B), eps).reshape(3 * p, B * 3)
    # the markers are kept coordinate-major, (K, 3, p) (with the 3 coordinates innermost every elementwise
    # operation ran a 3-long inner loop per marker: 10x slower); the products with D take its rows in that order,
    # and the rotation columns' products, Yw @ M3, come out as (K, 3, B)
    M3 = M.reshape(p, 3, B, 3).transpose(1, 0, 3, 2).reshape(3 * p, 3 * B)
    D3 = D.reshape(p, 3, B).transpose(1, 0, 2).reshape(3 * p, B)
    N3 = sub.neutral.T
    XT = np.ascontiguousarray(X0.transpose(0, 2, 1))
    # Schur complement on the 6 pose unknowns. The weights' block D^T W D + mu I depends on the frame's marker
    # weights only (not on the pose): one matrix for every frame when all weights are 1, else one per frame
    # (a lost marker has weight 0), each factored once (_weights_block_solver).
    Dj = D.reshape(p, 3, B)
    if uniform:
        Aww_inv = np.linalg.inv(D.T @ D + mu * np.eye(B))

        def solve_w(X):  # one product for all frames
            return (X.reshape(-1, B) @ Aww_inv).reshape(X.shape)

        DcT = np.broadcast_to(Dj.sum(axis=0), (K, 3, B))  # the translation columns' products, transposed
    else:
        solve_w = _weights_block_solver(D, mu, W)
        DcT = (W @ Dj.reshape(p, 3 * B)).reshape(K, 3, B)
    # sums over the markers as one product per frame: [Yw; w] [Y; r]^T holds Yw^T Y, Yw^T r, sum w y, sum w r
    L = np.empty((K, 4, p))
    L[:, 3] = 1.0 if uniform else W
    Yr = np.empty((K, 6, p))
    Y, r3 = Yr[:, :3], Yr[:, 3:]
    Wb = None if uniform else W[:, None, :]
    w3 = None if uniform else np.tile(W, 3)
    wsum = np.full(K, float(p)) if uniform else W.sum(axis=1)
    w_prev = np.zeros((K, B))
    eye3 = np.eye(3)[None]
    rhsT = np.empty((K, 7, B))  # [Awp^T; bw^T]: both solves with the weights' block at once
    for _ in range(iterations):
        np.matmul(R.transpose(0, 2, 1), XT - t[:, :, None], out=Y)  # R^T (X - t) for every marker of every frame
        np.subtract(Y, N3[None], out=r3)
        r = r3.reshape(K, -1)
        Yw = L[:, :3]
        if uniform:
            Yw[:] = Y
        else:
            np.multiply(Y, Wb, out=Yw)  # the weighted markers (a lost one at 0)
        C = np.matmul(L, Yr.transpose(0, 2, 1))  # (K, 4, 6)
        YY, YR, ys, rs = C[:, :3, :3], C[:, :3, 3:], C[:, 3, :3], C[:, 3, 3:]
        # the pose columns are S_j = -[y_j]x and I per marker
        rhsT[:, :3] = (Yw.reshape(K, -1) @ M3).reshape(K, 3, B)
        rhsT[:, 3:6] = DcT
        rhsT[:, 6] = (r if uniform else r * w3) @ D3 + mu * w_prev
        App = np.empty((K, 6, 6))
        App[:, :3, :3] = np.trace(YY, axis1=1, axis2=2)[:, None, None] * eye3 - YY
        App[:, :3, 3:] = _cross_matrix(ys)
        App[:, 3:, :3] = -App[:, :3, 3:]
        App[:, 3:, 3:] = wsum[:, None, None] * eye3
        # sum_j y_j x r_j: the antisymmetric part of sum_j y_j r_j^T
        bp = np.stack([YR[:, 1, 2] - YR[:, 2, 1], YR[:, 2, 0] - YR[:, 0, 2], YR[:, 0, 1] - YR[:, 1, 0],
                       rs[:, 0], rs[:, 1], rs[:, 2]], axis=1)
        AiT = solve_w(rhsT)  # rows: (Aww^-1 Awp)^T, then Aww^-1 bw
        AwpT, AiAwpT, Aib = rhsT[:, :6], AiT[:, :6], AiT[:, 6]
        S = App - np.matmul(AwpT, AiAwpT.transpose(0, 2, 1))
        z = np.linalg.solve(S, (bp - np.matmul(AwpT, Aib[..., None])[..., 0])[..., None])[..., 0]
        w_prev = Aib - np.matmul(z[:, None, :], AiAwpT)[:, 0]
        dth, dt = z[:, :3], z[:, 3:]
        t = t + np.matmul(R, dt[..., None])[..., 0]
        R = np.matmul(R, _rodrigues(dth))
        if np.abs(z).max() < 1e-9:
            break
    return R, t, w_prev


def _fit_group(fitter, sub: BlendshapeRig, stable, X, W, alternations: int):
    """Weights ``(K, B)``, ``R (K,3,3)``, ``t (K,3)`` for ``K`` frames of one marker set."""
    K, p = W.shape
    lost = ~(W > 0)
    X0 = np.where(lost[..., None], 0.0, X)
    plain = bool(np.all((W == 1.0) | lost))  # no confidences: lost markers are imputed, the fit stays batched
    batched = "mesh" in batched_targets(fitter)
    F = np.broadcast_to(sub.neutral, (K, p, 3))
    mask = np.zeros(p)
    mask[stable] = 1.0
    Wp = W * mask
    few = (Wp > 0).sum(axis=1) < 3  # too few stable markers found: start from every marker
    Wp[few] = W[few]
    R, t = kabsch(F, X0, Wp)
    R, t, w_ls = _joint_pose(sub, X0, W, R, t)
    D = sub.deltas.reshape(sub.n_shapes, -1)
    if lost.any():  # a lost marker starts where the joint least-squares expression puts it
        F = sub.neutral[None] + (w_ls @ D).reshape(K, p, 3)
    E = np.zeros((K, sub.n_shapes))
    for it in range(alternations + 1):
        Y = np.matmul(X0 - t[:, None], R)  # R^T (X - t): the rig's frame
        Y = np.where(lost[..., None], F, Y)
        if plain and batched:
            res = fit_many(fitter, sub, Y)
        elif plain:
            res = fit_many(fitter, sub, [MeshTarget(y) for y in Y])
        else:
            res = fit_many(fitter, sub, [MeshTarget(Y[k], W[k]) for k in range(K)])
        E = np.stack([r.weights for r in res])
        F = sub.neutral[None] + (E @ D).reshape(K, p, 3)
        if it < alternations:
            moved = np.matmul(F, R.transpose(0, 2, 1)) + t[:, None]
            h = _huber(np.linalg.norm(moved - X0, axis=2), W)
            R, t = kabsch(F, X0, W * h)
    gap = np.matmul(F, R.transpose(0, 2, 1)) + (t[:, None] - X0)  # R f + t - X
    resid = np.where(lost, np.nan, np.sqrt(np.einsum("kpi,kpi->kp", gap, gap)))
    return E, R, t, resid


def _check_targets(rig, targets):
    if not isinstance(rig, BlendshapeRig):
        raise InputError(f"rig must be a BlendshapeRig, got {type(rig).__name__}")
    out = []
    for k, tg in enumerate(targets):
        if not isinstance(tg, MarkerTarget):
            raise InputError(f"target {k} must be a MarkerTarget, got {type(tg).__name__}")
        out.append(tg.check(rig))
    return out


def _check_alternations(alternations):
    if isinstance(alternations, bool) or not isinstance(alternations, (int, np.integer)) or alternations < 0:
        raise InputError(f"alternations must be a non-negative integer, got {alternations!r}")


def _frames_valid(P, conf) -> bool:
    """Whether every frame of ``P (T, p, 3)`` (and ``conf (T, p)``) passes :class:`MarkerTarget`'s checks.

    Then :func:`solve_markers` hands the arrays to the solve as they are; otherwise it builds the per-frame
    targets, and the first frame that fails raises its own error (naming the frame).
    """
    with np.errstate(invalid="ignore"):
        if np.isinf(P).any() or (np.abs(P) > MAX_COORDINATE).any():
            return False
    usable = ~np.isnan(P).any(axis=2)
    if conf is not None:
        if not np.all(np.isfinite(conf)) or (conf < 0).any():
            return False
        usable &= conf > 0
    return bool((usable.sum(axis=1) >= 3).all())


def fit_markers(fitter, rig: BlendshapeRig, targets, alternations: int = ALTERNATIONS) -> list[FitResult]:
    """Fit ``K`` :class:`MarkerTarget` s with any fitter: rigid pose and expression, alternated.

    Targets sharing their marker vertices are solved together (one
    :func:`~facegeom.interfaces.fit_many` call per alternation).

    Parameters
    ----------
    fitter : Fitter
        Any fitter with a mesh path (``fit`` on a :class:`MeshTarget`).
    rig : BlendshapeRig
    targets : sequence of K MarkerTarget
    alternations : int
        Rounds of (robust Kabsch pose on the fitted face, expression refit)
        after the first fit (``alternations + 1`` expression fits in all).

    Returns
    -------
    list of K FitResult
        ``weights (B,)``; ``vertices (n, 3)`` the fitted face in the rig's
        frame; ``info``: ``rotation (3, 3)``, ``translation (3,)``, ``pose``
        (4x4: rig frame -> capture frame, ``X ~ R f + t``), ``rms`` (marker
        residual after the solve, rig units), ``lost`` (markers ignored),
        ``time_s`` (the target's share of its group's time).
    """
    _check_alternations(alternations)
    targets = _check_targets(rig, targets)
    groups: dict[bytes, list[int]] = {}
    for k, tg in enumerate(targets):
        groups.setdefault(tg.vertex_ids.tobytes(), []).append(k)
    out: list = [None] * len(targets)
    for rows in groups.values():
        t0 = time.perf_counter()
        ids = targets[rows[0]].vertex_ids
        X = np.stack([targets[k].positions for k in rows])
        W = np.stack([targets[k].marker_weights() for k in rows])
        E, R, t, resid = _fit_group(fitter, marker_rig(rig, ids), stable_rows(rig, ids), X, W, int(alternations))
        share = (time.perf_counter() - t0) / len(rows)
        for j, k in enumerate(rows):
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = R[j], t[j]
            found = resid[j][np.isfinite(resid[j])]
            out[k] = FitResult(E[j], partial(rig.evaluate, E[j]),
                               {"rotation": R[j], "translation": t[j], "pose": pose,
                                "rms": float(np.sqrt(np.mean(found ** 2))), "lost": int(targets[k].lost.sum()),
                                "time_s": share})
    return out


def split_markers(fitter, rig, targets) -> list:
    """A fitter's ``fit_many`` hook: solve the :class:`MarkerTarget` s among ``targets`` (together).

    Returns a list as long as ``targets`` with a :class:`FitResult` at each
    marker target and ``None`` elsewhere (left to the fitter's own paths).
    """
    rows = [k for k, tg in enumerate(targets) if isinstance(tg, MarkerTarget)]
    out: list = [None] * len(targets)
    if rows:
        for k, r in zip(rows, fit_markers(fitter, rig, [targets[k] for k in rows])):
            out[k] = r
    return out


# --------------------------------------------------------------------------- smoothing


def _dct_eigen(T: int) -> np.ndarray:
    """Eigenvalues of the second-difference penalty diagonalised by the DCT-II (reflecting ends)."""
    return (2.0 - 2.0 * np.cos(np.pi * np.arange(T) / T)) ** 2


def smooth_curves(Y, amount="auto", grid: int = 41):
    """Whittaker-smooth each column of ``Y (T, K)``; ``amount`` ``"auto"`` (GCV per curve) or a number.

    The smoother minimises ``|z - y|^2 + lam |D2 z|^2`` (``D2`` the second
    difference, reflecting ends), solved in the DCT basis where it is diagonal
    (Garcia, "Robust smoothing of gridded data in one and higher dimensions
    with missing values", 2010). With ``"auto"``, each curve's ``lam`` minimises
    the generalised cross-validation score ``T RSS / (T - tr H)^2`` over a
    log grid ``10^-2 .. 10^6``. Smoothed curves are clipped to the raw curve's
    range (a non-negative weight stays non-negative).

    Returns
    -------
    Z : (T, K) float64
    lam : (K,) float64
        The smoothing strength used per curve (0: left as is).
    """
    from facegeom.linalg import dct_ortho, idct_ortho

    Y = np.asarray(Y, dtype=np.float64)
    if Y.ndim != 2:
        raise InputError(f"curves must have shape (T, K), got {Y.shape}")
    T, K = Y.shape
    if T < 4:
        return Y.copy(), np.zeros(K)
    lam_eig = _dct_eigen(T)
    C = dct_ortho(Y)
    if isinstance(amount, str):
        if amount != "auto":
            raise InputError(f"smoothing must be 'auto', 'off' or a number >= 0, got {amount!r}")
        lams = np.logspace(-2, 6, grid)
        G = 1.0 / (1.0 + lams[:, None] * lam_eig[None])  # (L, T)
        rss = ((1.0 - G) ** 2) @ (C * C)  # (L, K)
        trace = G.sum(axis=1)  # (L,)
        gcv = T * rss / (T - trace)[:, None] ** 2
        lam = lams[np.argmin(gcv, axis=0)]
        flat = (C[1:] ** 2).sum(axis=0) <= 1e-24  # a constant curve: nothing to smooth
        lam[flat] = 0.0
    else:
        if isinstance(amount, bool) or not np.isfinite(float(amount)) or float(amount) < 0:
            raise InputError(f"smoothing must be 'auto', 'off' or a number >= 0, got {amount!r}")
        lam = np.full(K, float(amount))
    Z = idct_ortho(C / (1.0 + lam[None] * lam_eig[:, None]))
    return np.clip(Z, Y.min(axis=0), Y.max(axis=0)), lam


# --------------------------------------------------------------------------- sequences


def marker_noise(positions) -> float:
    """The markers' noise, estimated from the capture alone: standard deviation per coordinate (the positions'
    unit), NaN when no marker is found in three frames running.

    White noise of deviation ``s`` gives second differences in time of
    deviation ``sqrt(6) s``; a face and a head move smoothly from frame to
    frame, so the median of the absolute second differences (over 0.6745, a
    Gaussian's median absolute value) over ``sqrt(6)`` estimates ``s``. Motion
    adds to it: an over-estimate by about 0.3 mm on real takes at 30 fps with
    a moving head (0.7 at 0.5 mm noise, 1.1 at 1 mm), never an under-estimate.
    """
    d2 = np.diff(np.asarray(positions, dtype=np.float64), 2, axis=0)
    v = np.abs(d2[np.isfinite(d2)])
    return float(np.median(v) / 0.6745 / np.sqrt(6.0)) if v.size else float("nan")



@dataclass
class MarkerSolve:
    """The result of :func:`solve_markers` on ``T`` frames of a ``K``-shape rig.

    Attributes
    ----------
    weights : (T, K) float64
        Blendshape weights per frame (smoothed when asked).
    names : tuple of K str
        The rig's shape names.
    rotations : (T, 3, 3), translations : (T, 3)
        Rigid head motion per frame: capture ``X ~ R f + t`` for the rig face ``f``.
    raw_weights : (T, K) float64
        The per-frame weights before smoothing.
    smoothing : (K,) float64
        Whittaker strength used per curve (all 0: no smoothing).
    rms : (T,) float64
        Marker residual per frame after the solve (rig units; NaN for a frame
        without usable markers is impossible: a frame needs 3).
    lost : (T,) int64
        Markers ignored per frame (NaN positions).
    time_s : float
        Seconds for the whole solve.
    """

    weights: np.ndarray
    names: tuple
    rotations: np.ndarray
    translations: np.ndarray
    raw_weights: np.ndarray
    smoothing: np.ndarray
    rms: np.ndarray
    lost: np.ndarray
    time_s: float
    info: dict = field(default_factory=dict)

    @property
    def poses(self) -> np.ndarray:
        """``(T, 4, 4)`` homogeneous rig -> capture transforms."""
        T = self.rotations.shape[0]
        P = np.zeros((T, 4, 4))
        P[:, :3, :3], P[:, :3, 3], P[:, 3, 3] = self.rotations, self.translations, 1.0
        return P


def solve_markers(positions, vertex_ids, rig: BlendshapeRig, fitter=None, confidence=None, smooth="off",
                  alternations: int = ALTERNATIONS, chunk: int = 2000, progress=None) -> MarkerSolve:
    """Solve a marker sequence ``(T, p, 3)`` to rig weights ``(T, K)`` and rigid head motion.

    Parameters
    ----------
    positions : (T, p, 3)
        Marker positions per frame in the capture's frame and the rig's unit;
        NaN where a marker is lost.
    vertex_ids : (p,)
        The rig vertex of each marker.
    rig : BlendshapeRig
    fitter : Fitter or None
        Any fitter; default ``sem-ls`` (:class:`~facegeom.methods.sem.SEMLSFitter`).
    confidence : (p,) or (T, p) or None
        Per-marker weights ``>= 0``.
    smooth : "off", "auto" or float
        Temporal smoothing of the weight curves (:func:`smooth_curves`). Off by
        default: a per-frame solve keeps fast motion (blinks, lip closures) that
        any smoother would soften; ``auto`` picks the strength per curve by GCV.
    alternations : int
        Pose refinements per frame (see :func:`fit_markers`).
    chunk : int
        Frames solved together.
    progress : callable or None
        Called with ``(frames done, T)`` after each chunk.

    Returns
    -------
    MarkerSolve

    Raises
    ------
    InputError
        Wrong shapes, bad ids, a frame with fewer than 3 usable markers (naming the frame).
    """
    t0 = time.perf_counter()
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] == 0 or P.shape[1] == 0:
        raise InputError(f"marker positions must have shape (T, p, 3) with T, p >= 1, got {P.shape}")
    T, p = P.shape[:2]
    ids = as_handles(vertex_ids, rig.n_vertices, "marker vertex_ids")
    if ids.size != p:
        raise InputError(f"{p} markers per frame for {ids.size} vertex ids")
    if confidence is None:
        conf = None
    else:
        conf = np.asarray(confidence, dtype=np.float64)
        if conf.shape == (p,):
            conf = np.broadcast_to(conf, (T, p))
        if conf.shape != (T, p):
            raise InputError(f"marker confidence must have shape ({p},) or ({T}, {p}), got {conf.shape}")
    if not isinstance(chunk, (int, np.integer)) or isinstance(chunk, bool) or chunk < 1:
        raise InputError(f"chunk must be a positive integer, got {chunk!r}")
    if isinstance(smooth, str) and smooth not in ("off", "auto"):
        raise InputError(f"smoothing must be 'auto', 'off' or a number >= 0, got {smooth!r}")
    fitter = _default_fitter() if fitter is None else fitter
    E = np.empty((T, rig.n_shapes))
    R = np.empty((T, 3, 3))
    tr = np.empty((T, 3))
    rms = np.empty(T)
    lost = np.empty(T, np.int64)
    # frames that all pass MarkerTarget's checks are solved from the arrays: building and checking a target
    # per frame took a third of the whole solve's time on 1,000 frames of 80 markers
    fast = _frames_valid(P, conf)
    if fast:
        _check_alternations(alternations)
        if not isinstance(rig, BlendshapeRig):
            raise InputError(f"rig must be a BlendshapeRig, got {type(rig).__name__}")
        sub, stable = marker_rig(rig, ids), stable_rows(rig, ids)
    for start in range(0, T, chunk):
        if fast:
            sl = slice(start, min(start + chunk, T))
            gone = np.isnan(P[sl]).any(axis=2)
            Wk = np.ones(gone.shape) if conf is None else np.array(conf[sl])
            Wk[gone] = 0.0
            E[sl], R[sl], tr[sl], resid = _fit_group(fitter, sub, stable, P[sl], Wk, int(alternations))
            rms[sl], lost[sl] = np.sqrt(np.nanmean(resid ** 2, axis=1)), gone.sum(axis=1)
            if progress is not None:
                progress(sl.stop, T)
            continue
        targets = []
        for k in range(start, min(start + chunk, T)):
            try:
                targets.append(MarkerTarget(P[k], ids, None if conf is None else conf[k]))
            except InputError as exc:
                raise InputError(f"frame {k}: {exc.reason}") from None
        for j, r in enumerate(fit_markers(fitter, rig, targets, alternations)):
            k = start + j
            E[k], R[k], tr[k] = r.weights, r.info["rotation"], r.info["translation"]
            rms[k], lost[k] = r.info["rms"], r.info["lost"]
        if progress is not None:
            progress(min(start + chunk, T), T)
    if isinstance(smooth, str) and smooth == "off":
        W, lam = E.copy(), np.zeros(rig.n_shapes)
    else:
        W, lam = smooth_curves(E, smooth)
    return MarkerSolve(W, tuple(rig.names), R, tr, E, lam, rms, lost, time.perf_counter() - t0)
