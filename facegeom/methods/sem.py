"""Selective Expression Manipulation (SEM): greedy delta-blendshape selection (Kang et al., Sec. IV).

Starting from the neutral face ``F^1 = B_1``, each iteration ``t``

1. measures, for every remaining candidate ``dB_i``, its coefficient
   ``e_i = max(ERSim(dB_i, dT^t), 0)`` (eq. 18) against the remaining motion
   ``dT^t = T - F^t`` and the motional energy index from the initial face
   ``r(t, dB_i) = 1 - ERSim(dT, sum_k e^k dB^k + e_i dB_i)`` (eq. 19);
2. **excludes** (one-step backtracking) every candidate whose index would exceed
   in magnitude the index reached by the previous selection,
   ``|r(t-1, dB^{t-1})| < |r(t, dB_i)|`` -- a candidate that would undo the
   motion selected so far, or overshoot the target, is dropped for good;
3. **selects** the candidate of largest expressional similarity
   ``s_i = ESim(dB_i, dT^t)`` (eqs. 16-17), with coefficient ``e^t`` (eq. 18),
   ``F^{t+1} = F^t + e^t dB^t`` (eq. 13), and removes it from the candidates;

until no candidate remains. ``ESim`` and ``ERSim`` are eqs. 9 and 10
(:mod:`facegeom.metrics`). The first iteration has no previous index and
excludes nothing; the index of the empty selection is ``1``. (On landmarks a
target stops as soon as no remaining candidate has a positive coefficient: the
selections left would all add ``0`` and change nothing, so the coefficients are
those of the full run; only the reported order omits those zero selections.)

Targets
-------
- :class:`~facegeom.model.targets.MeshTarget` (Sec. IV-B): everything is an inner product
  of motions, so after ``c = D^T dT`` (one product per target) the whole
  selection runs on the precomputed Gram matrix ``G = D^T D`` of the deltas
  (:func:`sem_gram`, vectorised over many targets at once).
- :class:`~facegeom.model.targets.LandmarkTarget` (Sec. IV-C, eqs. 20-22): motions are
  2-D on the image, ``Pi(B_i) - Pi(B_1)`` for the candidates and
  ``L - Pi(F^t)`` for the target, with the current face projected exactly. An
  unposed camera gets its pose from the landmarks, then alternately with the
  expression (:func:`facegeom.methods.fitting.fit_with_pose`).
- :class:`~facegeom.model.targets.PointCloudTarget` (Sec. IV-D, eqs. 23-25): per
  candidate, closest points ``P_i`` of the face moved by that candidate alone
  (one ICP step from the coefficient on the current correspondences, a
  KD-tree), then ``s_i = ESim(dB_i, P_i - F^t)``, ``e = ERSim(dB, P_i - F^t)``,
  ``r = 1 - ERSim(P_i - F^1, B~_i)``; after each selection the selected
  coefficients are refined on the new correspondences (non-negative least
  squares), as the paper allows. Because every candidate has its own
  correspondences, the exclusion compares its index with and without the
  candidate on those same correspondences (with one fixed target, as for
  meshes and landmarks, that is exactly the previous selection's index).

Options beyond the paper (off by default, so the published algorithm runs):
``clamp=True`` bounds every coefficient to ``[0, 1]`` (eq. 1's constraint), and
``refit=True`` finishes with a bounded least-squares refit of the selected
shapes' coefficients on the data.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np
from threadpoolctl import threadpool_limits

from facegeom.errors import InputError
from facegeom.interfaces import FitResult, Params, check_range
from facegeom.linalg import box_lsq, box_qp_many
from facegeom.methods.fitting import check_fit_inputs, fit_with_poses, result
from facegeom.methods.landmark_map import GAUSS_NEWTON_STEPS, PRIOR_SD, WARM_STEPS, map_weights, population_prior
from facegeom.methods.marker_solve import split_markers
from facegeom.model import (
    BlendshapeRig,
    LandmarkTarget,
    MarkerTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
    project_many,
)

__all__ = ["SEMFitter", "SEMLSFitter", "sem_gram", "sem_orthogonal_gram", "sem_vectors"]


def _camera(intr, R, t, k) -> PinholeCamera:
    """Camera ``k`` of a batch (intrinsics ``(f, cx, cy)`` arrays, poses ``R, t``)."""
    U, _, Vt = np.linalg.svd(R[k])  # the nearest rotation, free of accumulated rounding
    return PinholeCamera(intr[0][k], intr[1][k], intr[2][k], U @ Vt, t[k])

_TINY = 1e-300
_BEHIND = "a fitted landmark went behind the camera (the expression moves it past the camera)"


def _by_weight(w) -> np.ndarray:
    """The shapes with a weight above zero, largest first (the order a MAP fit reports)."""
    idx = np.flatnonzero(w > 0)
    return idx[np.argsort(-w[idx], kind="stable")]


def _cut_path(order, step_e, step_gain, min_gain):
    """A recorded greedy path cut where a target's step first gains less than ``min_gain (K,)``.

    ``order, step_e, step_gain (K, B)`` as :meth:`SEMFitter._greedy_landmarks`
    returns them. The greedy with ``min_gain`` makes the same selections up
    to that step and stops there, so this is its result: ``e (K, B)``,
    ``order (K, B)``.
    """
    K, B = order.shape
    went = order >= 0
    low = went & (step_gain < min_gain[:, None])
    cut = np.where(low.any(axis=1), np.argmax(low, axis=1), went.sum(axis=1))
    keep = went & (np.arange(B)[None] < cut[:, None])
    e = np.zeros((K, B))
    kk, ss = np.nonzero(keep)
    e[kk, order[kk, ss]] = step_e[kk, ss]
    return e, np.where(keep, order, -1)


def sem_gram(c, G, tt, exclusion: bool = True, upper: float | None = None, select: str = "esim", min_gain=None):
    """SEM on motions known only through inner products, for ``K`` targets at once.

    Parameters
    ----------
    c : (K, B) or (B,)
        ``dT . dB_i`` for each target motion ``dT`` and candidate.
    G : (B, B)
        Gram matrix ``dB_i . dB_j``.
    tt : (K,) or scalar
        ``|dT|^2``.
    exclusion : bool
        The one-step backtracking exclusion (eq. 19 and its condition).
    upper : float or None
        Upper bound of a coefficient (``None``: the paper, only ``e >= 0``).
    select : {"esim", "gain"}
        ``esim`` (the paper, eq. 17): the largest expressional similarity.
        ``gain``: the largest decrease of the squared residual with the
        candidate's (bounded) coefficient, ``2 e p - e^2 |dB|^2``; without an
        upper bound it is ``ESim^2 |dT^t|^2``, the same choice, but with one a
        candidate that would need a coefficient far above the bound (a shape
        that barely moves the data) no longer wins on direction alone.
    min_gain : (K,) or scalar or None
        Stop a target's selection when the chosen candidate would decrease its
        squared residual by less than this (see ``SEMFitter(stop="ric")``).

    Returns
    -------
    e : (K, B) or (B,) coefficients
    order : (K, B) int, the selected candidates in selection order (-1 after the last)
    """
    c = np.asarray(c, dtype=np.float64)
    single = c.ndim == 1
    c = np.atleast_2d(c)
    K, B = c.shape
    G = np.asarray(G, dtype=np.float64)
    tt = np.broadcast_to(np.asarray(tt, dtype=np.float64), (K,))
    diag = np.diag(G).copy()
    moves = diag > _TINY
    inv_norm = np.where(moves, 1.0 / np.sqrt(np.where(moves, diag, 1.0)), 0.0)
    inv_diag = np.where(moves, 1.0 / np.where(moves, diag, 1.0), 0.0)
    inv_tt = np.where(tt > _TINY, 1.0 / np.where(tt > _TINY, tt, 1.0), 0.0)
    e = np.zeros((K, B))
    proj = c.copy()  # dT^t . dB_i, kept up to date
    explained = np.zeros(K)  # dT . (sum_k e^k dB^k)
    alive = np.broadcast_to(moves, (K, B)).copy()  # a shape that moves nothing is never a candidate
    r_prev = np.ones(K)
    order = np.full((K, B), -1, dtype=np.int64)
    rows = np.arange(K)
    for t in range(B):
        active = alive.any(axis=1)
        if not active.any():
            break
        # eq. 18 for every candidate; a projection at rounding level (the target already reached) counts as none
        ei = np.where(proj * inv_norm > 1e-9 * np.sqrt(tt)[:, None], proj * inv_diag, 0.0)
        if upper is not None:
            ei = np.minimum(ei, upper)
        if exclusion and t > 0:
            r = 1.0 - (explained[:, None] + ei * c) * inv_tt[:, None]  # eq. 19
            alive &= ~(np.abs(r) > np.abs(r_prev)[:, None])
            active = alive.any(axis=1)
            if not active.any():
                break
        if select == "gain":
            score = np.where(alive & (ei > 0), 2.0 * ei * proj - ei * ei * diag, np.where(alive, 0.0, -np.inf))
        else:
            score = np.where(alive, proj * inv_norm, -np.inf)  # ESim up to the common factor 1/|dT^t|
        pick = np.argmax(score, axis=1)
        if min_gain is not None:
            ep = ei[rows, pick]
            gain = 2.0 * ep * proj[rows, pick] - ep * ep * diag[pick]
            stop = active & (gain < min_gain)
            alive[stop] = False
            active = active & ~stop
        et = np.where(active, ei[rows, pick], 0.0)
        e[rows, pick] += et
        proj -= et[:, None] * G[pick]
        explained += et * c[rows, pick]
        r_prev = np.where(active, 1.0 - explained * inv_tt, r_prev)
        order[active, t] = pick[active]
        alive[rows[active], pick[active]] = False
    return (e[0], order[0]) if single else (e, order)


def sem_orthogonal_gram(c, G, tt, m, upper: float | None = None, chunk: int | None = None):
    """SEM's selection with least-squares coefficients and a GCV stop, for ``K`` targets at once.

    Each step selects, as the paper does, the remaining candidate of largest
    expressional similarity ``ESim(dB_i, dT^t)`` with the remaining motion
    (only candidates that move the face *towards* the target: positive
    projection). Unlike the paper's greedy, whose coefficient is frozen at
    selection (eq. 18), all selected coefficients are then re-solved by least
    squares on the data (orthogonal matching pursuit): the remaining motion is
    orthogonal to every selected shape, so a candidate correlated with the
    selection scores low and the selection stays weakly correlated without the
    exclusion step, and a dense target reaches least-squares accuracy.

    The path stops where generalised cross-validation,
    ``GCV(k) = m RSS(k) / (m - k)^2``, is smallest over the whole path (it
    estimates the leave-one-out prediction error without a noise estimate):
    few shapes where few explain the target, many where the data support them.

    Parameters
    ----------
    c : (K, B) or (B,)
        ``dT . dB_i`` per target and candidate.
    G : (B, B)
        Gram matrix ``dB_i . dB_j``.
    tt : (K,) or scalar
        ``|dT|^2``.
    m : int
        Number of measured values (``3 n`` for a mesh of ``n`` vertices).
    upper : float or None
        Upper bound of a coefficient (``None``: only ``e >= 0``). A target whose
        chosen least-squares coefficients leave ``[0, upper]`` is refitted on its
        selection with the bounds (bounded least squares).
    chunk : int or None
        Targets updated together (bounds the ``(chunk, B, B)`` work arrays).
        ``None``: as many as keep them near 32 MB (1,400 targets of 53
        shapes): each step of the selection is a few dozen array operations
        on all of them, so with fewer targets per chunk Python's share grows
        (256 took 50 % more time than 1,000 here).

    Returns
    -------
    e : (K, B) or (B,) coefficients
    order : (K, B) int, the selected candidates in selection order (-1 after the last)
    """
    c = np.asarray(c, dtype=np.float64)
    single = c.ndim == 1
    c = np.atleast_2d(c)
    K, B = c.shape
    G = np.asarray(G, dtype=np.float64)
    tt = np.broadcast_to(np.asarray(tt, dtype=np.float64), (K,))
    m = int(m)
    if chunk is None:
        chunk = max(64, 2 ** 22 // max(B * B, 1))
    E = np.zeros((K, B))
    orders = np.full((K, B), -1, dtype=np.int64)
    best_k = np.zeros(K, dtype=np.int64)
    for k0 in range(0, K, chunk):
        sl = slice(k0, k0 + chunk)
        E[sl], orders[sl], best_k[sl] = _orthogonal_chunk(c[sl], G, tt[sl], m)
    hi = np.inf if upper is None else upper
    bad = np.flatnonzero(((E < -1e-12) | (E > hi + 1e-12)).any(axis=1))
    if bad.size:  # bounded least squares on the chosen selection (all chunks together: fewer, larger batches)
        E[bad] = _bounded_gram_many(G, c[bad], orders[bad], best_k[bad], E[bad], hi)
    return (E[0], orders[0]) if single else (E, orders)


def _orthogonal_chunk(c, G, tt, m):
    """:func:`sem_orthogonal_gram` on one chunk of targets, before the bounds: ``e``, ``order``, path length.

    The selected shapes are orthonormalised as they come (Gram-Schmidt in the
    inner products, i.e. a Cholesky factor grown a row per step): row ``j`` of
    ``A (K, S, B)`` holds ``q_j . dB_i`` for the ``j``-th orthonormal direction
    ``q_j`` of a target's selection and every candidate, ``z_j = q_j . dT``.
    A step then costs ``O(j B)`` per target: the new row, the remaining
    projections ``p -= z_j A_j`` and ``RSS = |dT|^2 - sum z_j^2``. The
    least-squares coefficients are only needed where GCV was best: one
    triangular solve per target at the end, all targets at once. A target stops
    when no candidate moves towards it any more (on noisy data often well
    before the last shape); when half of the targets still selecting have
    stopped, the finished ones are dropped from the work arrays (as
    :meth:`SEMFitter._greedy_landmarks` does).
    """
    K, B = c.shape
    diag = np.diag(G).copy()
    moves = diag > _TINY
    inv_norm = 1.0 / np.sqrt(np.where(moves, diag, 1.0))
    scale = np.maximum(tt, _TINY)
    S = max(min(B, m - 1), 0)
    k_out = np.zeros(K, dtype=np.int64)
    A = np.zeros((K, S, B))  # A[k, j] = q_j . dB_i
    z = np.zeros((K, S))  # q_j . dT
    rank = np.zeros(K, dtype=np.int64)
    zz = np.zeros(K)  # sum of z_j^2: the part of |dT|^2 explained
    # dT^t . dB_i, the remaining motion against every candidate; -inf once it is no candidate (selected, or a
    # shape that moves nothing), so that the scores need no mask
    proj = np.where(moves, c, -np.inf)
    best_gcv = m * tt / float(m) ** 2  # the empty selection
    best_k = np.zeros(K, dtype=np.int64)
    active = np.ones(K, dtype=bool)
    level = 1e-9 * np.sqrt(scale)
    c, tt = c.copy(), tt.copy()
    gid = np.arange(K)  # the chunk's row of each work row

    # every target's factor and right-hand side, kept as they grow (in the chunk's rows): solved at the end, all at
    # once, up to each target's best GCV. Ut[k, j, :j + 1] is column j of the selection's Cholesky factor (the new
    # shape on the earlier directions, then its own norm), z_out[k, j] = z_j, p_out[k, j] its shape.
    Ut = np.zeros((K, S, S))
    z_out = np.zeros((K, S))
    p_out = np.zeros((K, S), dtype=np.int64)

    def finish(w):
        """The work rows ``w`` are done: keep their best GCV's path length."""
        k_out[gid[w]] = best_k[w]

    for step in range(S):
        n_act = int(active.sum())
        if n_act == 0:
            break
        if n_act <= active.size // 2:  # compact: note the finished targets' path lengths, drop them
            finish(np.flatnonzero(~active))
            keep = np.flatnonzero(active)
            A, z, rank, zz, proj = A[keep], z[keep], rank[keep], zz[keep], proj[keep]
            best_gcv, best_k, level, c, tt, gid = best_gcv[keep], best_k[keep], level[keep], c[keep], tt[keep], \
                gid[keep]
            active = np.ones(keep.size, dtype=bool)
        rows = np.arange(active.size)
        score = proj * inv_norm
        p = np.argmax(score, axis=1)
        # a projection at rounding level (the target already reached) is no motion towards it
        active &= score[rows, p] > level
        if not active.any():
            break
        proj[rows[active], p[active]] = -np.inf
        hi = step  # rank <= step: rows beyond are zero
        Ap = A[rows, :hi, p]  # (K, hi): the new shape on the selected directions
        schur = diag[p] - np.einsum("kj,kj->k", Ap, Ap)
        # a shape in the span of the selection adds nothing: skip it (and targets that stopped)
        ok = active & (schur > 1e-10 * diag[p])
        if not ok.any():
            continue
        # the new rows of every work row (no copy of A for the ones that go on: the stopped ones are at most half)
        row = G[p] - np.matmul(Ap[:, None, :], A[:, :hi])[:, 0]
        zn = c[rows, p] - np.einsum("kj,kj->k", Ap, z[:, :hi])
        if ok.all():
            a, pa = rows, p
        else:
            a = rows[ok]
            pa, row, zn = p[a], row[a], zn[a]
        sq = np.sqrt(schur[a])
        row /= sq[:, None]
        zn /= sq
        ra = rank[a]
        ga = gid[a]
        every = a.size == rows.size
        ix = slice(None) if every else a  # (a slice updates in place; an index array copies and scatters)
        if every and ra[0] == hi and (ra == hi).all():  # no skip so far (usual): slices, no scatter
            Ut[ga, hi, :hi] = Ap
            A[:, hi] = row
            z[:, hi] = zn
        else:
            Ut[ga, ra, :hi] = Ap[a]  # zero from the target's rank on
            A[a, ra] = row
            z[a, ra] = zn
        Ut[ga, ra, ra] = row[np.arange(a.size), pa]
        z_out[ga, ra], p_out[ga, ra] = zn, pa
        rank[ix] = ra + 1
        proj[ix] -= zn[:, None] * row
        zz[ix] += zn * zn
        rss = np.maximum(tt[ix] - zz[ix], 0.0)
        gcv = m * rss / (m - (ra + 1)).astype(np.float64) ** 2
        better = gcv < best_gcv[a]
        best_gcv[a[better]] = gcv[better]
        best_k[a[better]] = ra[better] + 1
    finish(np.arange(gid.size))
    e_out, order_out = _best_coefficients(Ut.transpose(0, 2, 1), z_out, p_out, k_out, B)
    return e_out, order_out, k_out


def _best_coefficients(U, z, picked, best_k, B):
    """Least-squares coefficients ``(K, B)`` and orders of selections cut at ``best_k``.

    ``U[k, :bk, :bk]`` is target ``k``'s Cholesky factor of its selection
    ``picked[k, :bk]`` (upper triangular up to rounding below the diagonal,
    which is not read), ``z[k, :bk]`` the right-hand side: one back
    substitution, vectorised over the targets (a row per step).
    """
    K = U.shape[0]
    kmax = int(best_k.max(initial=0))
    best_e = np.zeros((K, B))
    out_order = np.full((K, B), -1, dtype=np.int64)
    if kmax:
        use = np.arange(kmax)[None] < best_k[:, None]  # (K, kmax)
        x = np.zeros((K, kmax))  # 0 past a target's selection
        for i in range(kmax - 1, -1, -1):
            r = z[:, i] - np.einsum("kj,kj->k", U[:, i, i + 1:kmax], x[:, i + 1:])
            x[:, i] = np.where(use[:, i], r / np.where(use[:, i], U[:, i, i], 1.0), 0.0)
        kk, jj = np.nonzero(use)
        best_e[kk, picked[kk, jj]] = x[kk, jj]
        out_order[:, :kmax] = np.where(use, picked[:, :kmax], -1)
    return best_e, out_order


def _products(Tf, DN, min_rows: int = 64):
    """``Tf @ DN`` and the squared row norms of ``Tf (K, m)``, the targets split over the cores.

    Each core takes a block of targets with a one-thread BLAS product written
    as ``DN^T Tf^T`` (OpenBLAS's faster kernel for this tall, thin shape: ~40 %
    less CPU time than ``Tf @ DN`` here) and the norms of the same rows while
    they are in cache. On a machine shared with other jobs, BLAS's own threads
    wait for each other at every synchronisation; blocks of whole products do not.
    """
    K = Tf.shape[0]
    n_blocks = max(1, min(os.cpu_count() or 1, K // min_rows))
    bounds = np.linspace(0, K, n_blocks + 1).astype(int)
    blocks = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def block(sl):
        X = Tf[sl]
        return DN.T @ X.T, np.einsum("ij,ij->i", X, X)

    with threadpool_limits(limits=1, user_api="blas"):
        if n_blocks > 1:
            with ThreadPoolExecutor(n_blocks) as pool:
                outs = list(pool.map(block, blocks))
        else:
            outs = [block(blocks[0])]
    return np.concatenate([o[0] for o in outs], axis=1).T, np.concatenate([o[1] for o in outs])


def _bounded_gram_lsq(Gs, cs, upper):
    """``argmin e.Gs.e - 2 cs.e`` over ``0 <= e <= upper`` (via the Cholesky factor of ``Gs``)."""
    from scipy.linalg import cholesky, solve_triangular
    from scipy.optimize import nnls  # here, not at the top: importing scipy.optimize takes ~0.2 s

    n = Gs.shape[0]
    R = cholesky(Gs + 1e-12 * max(np.trace(Gs) / n, _TINY) * np.eye(n))
    y = solve_triangular(R, cs, trans="T")
    x = nnls(R, y)[0]  # the upper bound is rarely reached: try without it first (much faster)
    return x if x.max(initial=0.0) <= upper else box_lsq(R, y, upper, x0=x)


def _bounded_gram_many(G, c, order, size, start, upper):
    """:func:`_bounded_gram_lsq` of ``K`` targets on their selections, batched: coefficients ``(K, B)``.

    Row ``k`` minimises over the shapes ``order[k, :size[k]]`` with ``c[k]``; ``start (K, B)`` is its
    unconstrained least-squares solution (its coefficients outside the box start held at the bound).
    Targets are solved by :func:`~facegeom.linalg.box_qp_many` on the same regularised Gram matrices as
    :func:`_bounded_gram_lsq` (so the minimum is the same, not just close), selections of up to 4 sizes
    together, padded with identity rows (a padded unknown stays 0): a call per size cost more Python than
    solving; a target whose active set does not settle is solved by :func:`_bounded_gram_lsq`.
    """
    K, B = c.shape
    out = np.zeros((K, B))
    padded = -(-size // 4) * 4
    for n in np.unique(padded):
        rows = np.flatnonzero(padded == n)
        real = np.arange(n)[None] < size[rows, None]  # (k, n): the selection, then padding
        idx = np.where(real, order[rows, :n] if n <= B else np.pad(order[rows], ((0, 0), (0, n - B))), 0)
        both = real[:, :, None] & real[:, None, :]
        Gs = np.where(both, G[idx[:, :, None], idx[:, None, :]], 0.0)
        reg = 1e-12 * np.maximum(np.trace(Gs, axis1=1, axis2=2) / size[rows], _TINY)
        Gs[:, np.arange(n), np.arange(n)] += np.where(real, reg[:, None], 1.0)
        cs = np.where(real, np.take_along_axis(c[rows], idx, axis=1), 0.0)
        x0 = np.where(real, np.take_along_axis(start[rows], idx, axis=1), 0.0)
        x, ok = box_qp_many(Gs, cs, upper, x0)
        for j in np.flatnonzero(~ok):
            sel = idx[j, :size[rows[j]]]
            x[j] = 0.0
            x[j, :sel.size] = _bounded_gram_lsq(G[np.ix_(sel, sel)], cs[j, :sel.size], upper)
        kk, jj = np.nonzero(real)
        out[rows[kk], idx[kk, jj]] = x[kk, jj]
    return out


def sem_vectors(motions, target_motion, current_motion=None, exclusion: bool = True, upper: float | None = None):
    """SEM on explicit motion vectors (rows of ``motions (B, D)``, target ``(D,)``), via :func:`sem_gram`."""
    M = np.asarray(motions, dtype=np.float64)
    d = np.asarray(target_motion, dtype=np.float64).ravel()
    return sem_gram(M @ d, M @ M.T, float(d @ d), exclusion, upper)


def _region_ids(region) -> np.ndarray:
    """``region`` as vertex ids ``(r,)`` int64; a one-line error for anything else (text, nested lists, floats)."""
    r = np.asarray(region) if isinstance(region, (list, tuple, np.ndarray)) else None
    if r is None or r.ndim != 1 or not (r.size == 0 or np.issubdtype(r.dtype, np.integer)):
        raise InputError(f"region must be a list of vertex ids (integers), got {region!r}")
    return r.astype(np.int64)


class SEMFitter(Params):
    """Selective Expression Manipulation as a :class:`~facegeom.interfaces.Fitter`.

    Parameters
    ----------
    exclusion : bool
        One-step backtracking exclusion (the paper: on).
    clamp : bool
        Bound coefficients to ``[0, 1]`` (beyond the paper; off).
    refit : bool
        Finish with a bounded least-squares refit of the selected shapes (beyond the paper; off).
    select : {"esim", "gain"}
        Selection rule: the paper's largest ESim, or the largest decrease of the
        residual with the bounded coefficient (see :func:`sem_gram`).
    alternations : int
        Pose/expression alternations for landmark targets with an unknown pose.
    region : array of vertex ids or None
        Vertices used for point-cloud matching (default: all).
    max_points : int
        At most this many region vertices (an evenly strided subset) take part in
        point-cloud matching, for speed; ``0`` = all.
    stop : {"none", "ric"}
        ``none`` (the paper): select until no candidate remains. ``ric``: a
        first full pass estimates the noise ``sigma^2`` from its residual
        (per degree of freedom); a second pass stops when a selection would
        decrease the squared residual by less than ``2 ln(B) sigma^2`` -- the
        risk-inflation threshold of variable selection (Foster & George, 1994),
        about what the best of ``B`` pure-noise directions gains. Meshes and
        landmarks (point clouds: not applied).
    coefficients : {"greedy", "lsq", "map", "auto"}
        ``greedy`` (the paper, eq. 18): a coefficient is fixed when its shape is
        selected. ``lsq``: after each selection all selected coefficients are
        re-solved by (bounded) least squares, and the selection stops where
        generalised cross-validation is best (:func:`sem_orthogonal_gram`; on
        landmarks on the projected motions of eq. 20, on point clouds on the
        current correspondences); ``stop`` is then not used. ``map``
        (landmarks only): every weight at once, the posterior mode under a
        prior of the weights' range and a noise level estimated from the photo
        (:mod:`facegeom.methods.landmark_map`); ``stop`` is not used, and the
        selection order reported is the shapes by decreasing weight.
        ``auto``: ``lsq`` for meshes and point clouds, whose thousands of
        values determine every coefficient, ``map`` for landmarks, where a few
        dozen noisy values cannot.
    prior_sd : "auto", float > 0 or "evidence"
        ``coefficients="map"``: the weights' Gaussian prior. ``"auto"`` (default): on one person's rig (a
        fitted identity, a character) each weight's standard deviation is the spread of real performances'
        weights, 0.2; on a face model's generic face (``rig.population`` set) the prior also carries the
        person's shape the expression shapes reproduce, measured from the model's identity prior
        (:func:`~facegeom.methods.landmark_map.population_prior`). A number: that standard deviation on
        every rig. ``"evidence"``: per photo, the one the marginal likelihood prefers (started from 0.2; see
        :func:`~facegeom.methods.landmark_map.map_weights`).
    covered_only : bool
        Point clouds: only region vertices that are the nearest neutral vertex of
        at least one scan point take part, so parts the scan does not cover
        (ears, neck, the back of a cropped head) do not pull the fit.
    """

    def __init__(self, exclusion: bool = True, clamp: bool = False, refit: bool = False, alternations: int = 3,
                 region=None, max_points: int = 2000, select: str = "esim", covered_only: bool = True,
                 stop: str = "none", coefficients: str = "greedy", prior_sd="auto"):
        if prior_sd in ("evidence", "auto"):
            self.prior_sd = prior_sd
        elif isinstance(prior_sd, str):
            raise InputError(f"prior_sd must be 'auto', a positive number or 'evidence', got {prior_sd!r}")
        else:
            self.prior_sd = check_range("prior_sd", prior_sd, 0, 100, "the weights' range is [0, 1]", above=True)
        if coefficients not in ("greedy", "lsq", "map", "auto"):
            raise InputError(f"coefficients must be 'greedy' (the paper), 'lsq', 'map' or 'auto', "
                             f"got {coefficients!r}")
        self.coefficients = coefficients
        if stop not in ("none", "ric"):
            raise InputError(f"stop must be 'none' (the paper) or 'ric', got {stop!r}")
        self.stop = stop
        if not isinstance(covered_only, (bool, np.bool_)):
            raise InputError(f"covered_only must be true or false, got {covered_only!r}")
        self.covered_only = bool(covered_only)
        if select not in ("esim", "gain"):
            raise InputError(f"select must be 'esim' (the paper) or 'gain', got {select!r}")
        self.select = select
        for name, v in (("exclusion", exclusion), ("clamp", clamp), ("refit", refit)):
            if not isinstance(v, (bool, np.bool_)):
                raise InputError(f"{name} must be true or false, got {v!r}")
        alternations = check_range("alternations", alternations, 0, 100, "pose / expression rounds settle within a "
                                   "few", integer=True)
        max_points = check_range("max_points", max_points, 0, 1_000_000, "scan points sampled per fit: a million "
                                 "hold any face", integer=True)
        self.exclusion, self.clamp, self.refit = bool(exclusion), bool(clamp), bool(refit)
        self.alternations, self.max_points = int(alternations), int(max_points)
        self.region = None if region is None else _region_ids(region)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(exclusion={self.exclusion}, clamp={self.clamp}, refit={self.refit}, "
                f"stop={self.stop!r}, coefficients={self.coefficients!r})")

    def _lsq(self, kind: str) -> bool:
        """Whether targets of ``kind`` ("mesh", "landmarks", "points") get least-squares coefficients."""
        return self.coefficients == "lsq" or (self.coefficients in ("auto", "map") and kind != "landmarks")

    def _map(self) -> bool:
        """Whether landmark targets get the posterior mode of :mod:`facegeom.methods.landmark_map`."""
        return self.coefficients in ("map", "auto")

    @property
    def _upper(self):
        return 1.0 if self.clamp else None

    def _prior_sd(self):
        """The isotropic prior's standard deviation or "evidence" (``"auto"``: the performances' spread)."""
        return PRIOR_SD if self.prior_sd == "auto" else self.prior_sd

    def _prior_cov(self, rig):
        """``prior_sd="auto"`` on the generic face of a face model: the population's prior; else None."""
        pop = getattr(rig, "population", None)
        if self.prior_sd != "auto" or pop is None or tuple(pop.expression_names) != tuple(rig.names):
            return None
        return population_prior(pop)

    # ------------------------------------------------------------------ dispatch
    def fit(self, rig: BlendshapeRig, target) -> FitResult:
        """Fit the rig's coefficients to one target by greedy selection.

        Parameters
        ----------
        rig : BlendshapeRig
            Neutral ``(n, 3)`` and ``B`` delta-blendshapes ``(B, n, 3)``.
        target : MeshTarget, LandmarkTarget or PointCloudTarget
            A mesh ``(n, 3)`` in correspondence (optional weights ``(n,)``),
            landmarks ``(L, 2)`` of vertices ``(L,)`` with a camera, or points ``(N, 3)``.

        Returns
        -------
        FitResult
            ``weights (B,)``, ``vertices (n, 3)``; ``info``: ``order`` (selected
            shape ids in selection order), ``selected`` (their names, non-zero
            weights), ``time_s``; landmarks add ``camera`` and
            ``pose_estimated``, point clouds ``points_used`` and ``queries``.
        """
        if isinstance(target, MarkerTarget):  # capture markers: rigid pose + restricted mesh fit
            return split_markers(self, rig, [target])[0]
        rig, target = check_fit_inputs(rig, target)
        t0 = time.perf_counter()
        if isinstance(target, MeshTarget):
            e, info = self._fit_mesh(rig, target)
        elif isinstance(target, LandmarkTarget):
            e, info = self._fit_landmarks(rig, target)
        else:
            e, info = self._fit_points(rig, target)
        info["time_s"] = time.perf_counter() - t0
        info["selected"] = [rig.names[i] for i in np.flatnonzero(e > 0)]
        return result(rig, e, **info)

    batched_targets = frozenset({"mesh", "landmarks"})

    def fit_many(self, rig: BlendshapeRig, targets, chunk: int = 256, workers: int = 1) -> list[FitResult]:
        """Fit ``K`` targets at once: :func:`facegeom.interfaces.fit_many`'s fast paths.

        Unweighted mesh targets are solved together on the Gram matrix (one
        product for every ``D^T T``, then :func:`sem_gram` vectorised over the
        targets); landmark targets sharing their landmark vertices and
        posed-ness are solved together, ``chunk`` at a time (unknown poses in
        one batched Levenberg-Marquardt); other targets go through :meth:`fit`.

        Parameters
        ----------
        rig : BlendshapeRig
            ``B`` delta-blendshapes on ``n`` vertices.
        targets : sequence of K targets, or (K, n, 3) array
            Targets of any kind, or the meshes of ``K`` unweighted mesh targets.
        chunk : int
            Landmark targets solved together at most (keeps the ``(chunk, B, L, 3)``
            work arrays in cache).
        workers : int
            Threads solving landmark chunks side by side (numpy releases the GIL
            in its array operations). The default, 1, suits a machine whose
            cores are busy already (a batch job's workers, a shared machine:
            there 2 threads cost ~20 % more CPU time for no gain).

        Returns
        -------
        list of K FitResult
            ``weights (B,)``; ``vertices (n, 3)`` evaluated on first read; ``info``:
            ``time_s`` (the target's share of its batch's time), for landmarks
            also ``order``, ``camera`` and ``pose_estimated``. Targets fitted one
            by one carry :meth:`fit`'s ``info``.
        """
        if not isinstance(rig, BlendshapeRig):
            raise InputError(f"rig must be a BlendshapeRig, got {type(rig).__name__}")
        if isinstance(targets, np.ndarray):
            return self._mesh_results(rig, targets)
        targets = list(targets)
        out: list = split_markers(self, rig, targets)  # MarkerTargets solved here, the others left None
        targets = [tg if out[k] is not None else check_fit_inputs(rig, tg)[1] for k, tg in enumerate(targets)]
        meshes = [k for k, tg in enumerate(targets) if isinstance(tg, MeshTarget) and tg.weights is None]
        if meshes:
            for k, r in zip(meshes, self._mesh_results(rig, np.stack([targets[k].vertices for k in meshes]))):
                out[k] = r
        marks = [k for k, tg in enumerate(targets) if isinstance(tg, LandmarkTarget)]
        if marks:
            t0 = time.perf_counter()
            E, cams, orders = self._landmark_batches(rig, [targets[k] for k in marks], chunk, workers)
            share = (time.perf_counter() - t0) / len(marks)
            for j, k in enumerate(marks):
                out[k] = FitResult(E[j], partial(rig.evaluate, E[j]),
                                   {"order": orders[j], "camera": cams[j],
                                    "pose_estimated": not targets[k].camera.posed, "time_s": share})
        for k, tg in enumerate(targets):
            if out[k] is None:
                out[k] = self.fit(rig, tg)
        return out

    def _mesh_results(self, rig: BlendshapeRig, meshes: np.ndarray) -> list[FitResult]:
        t0 = time.perf_counter()
        E = self._mesh_batch(rig, meshes)
        info = {"time_s": (time.perf_counter() - t0) / max(len(E), 1)}
        return [FitResult(e, partial(rig.evaluate, e), dict(info)) for e in E]

    # ------------------------------------------------------------------ meshes
    def _fit_mesh(self, rig, target: MeshTarget):
        dT = target.vertices - rig.neutral
        if target.weights is None:
            c = rig.delta_matrix().T @ dT.ravel()
            G = rig.gram()
            tt = float((dT * dT).sum())
        else:
            w = np.repeat(target.weights, 3)
            D = rig.delta_matrix()
            c = D.T @ (w * dT.ravel())
            G = D.T @ (w[:, None] * D)
            tt = float((w * dT.ravel() ** 2).sum())
        if self._lsq("mesh"):
            m = dT.size if target.weights is None else 3 * int((target.weights > 0).sum())
            e, order = sem_orthogonal_gram(c, G, tt, m, self._upper)
            return e, {"order": [int(i) for i in order if i >= 0]}
        e, order = sem_gram(c, G, tt, self.exclusion, self._upper, self.select)
        if self.stop == "ric":
            resid = max(tt - 2.0 * e @ c + e @ G @ e, 0.0)
            e, order = sem_gram(c, G, tt, self.exclusion, self._upper, self.select,
                                self._ric_threshold(rig, resid, dT.size, e))
        if self.refit:
            e = self._refit_linear(rig.delta_matrix(), dT.ravel(), e, target.weights)
        return e, {"order": [int(i) for i in order if i >= 0]}

    def _mesh_batch(self, rig: BlendshapeRig, targets) -> np.ndarray:
        """Coefficients ``(K, B)`` for ``K`` corresponding target meshes ``(K, n, 3)`` at once (fast path)."""
        T = np.asarray(targets, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (rig.n_vertices, 3):
            raise InputError(f"targets must have shape (K, {rig.n_vertices}, 3), got {T.shape}")
        K = T.shape[0]
        D = rig.delta_matrix()
        n_flat = rig.neutral.reshape(-1)
        Tf = T.reshape(K, -1)
        # one GEMM gives every T . dB_i and T . n; |dT|^2 = |T|^2 - 2 T . n + |n|^2 (no (K, 3n) temporary;
        # the cancellation costs ~1e-16 |T|^2, far below any motion worth fitting)
        cn, t2 = _products(Tf, np.c_[D, n_flat])
        c = cn[:, :-1] - (n_flat @ D)[None]
        tt = np.maximum(t2 - 2.0 * cn[:, -1] + n_flat @ n_flat, 0.0)
        near = np.flatnonzero(tt <= 1e-10 * t2)  # (almost) the neutral itself: recompute exactly
        if near.size:
            d = Tf[near] - n_flat
            tt[near] = np.einsum("ij,ij->i", d, d)
            c[near] = d @ D
        if not (np.all(np.isfinite(tt)) and np.all(np.isfinite(c))):  # a NaN or inf anywhere in a target shows here
            bad = int(np.flatnonzero(~(np.isfinite(tt) & np.isfinite(c).all(axis=1)))[0])
            raise InputError(f"target {bad} contains NaN or inf")
        G = rig.gram()
        if self._lsq("mesh"):
            return sem_orthogonal_gram(c, G, tt, n_flat.size, self._upper)[0]
        e, _ = sem_gram(c, G, tt, self.exclusion, self._upper, self.select)
        if self.stop == "ric":
            resid = np.maximum(tt - 2.0 * np.einsum("kb,kb->k", e, c) + np.einsum("kb,bc,kc->k", e, G, e), 0.0)
            e, _ = sem_gram(c, G, tt, self.exclusion, self._upper, self.select,
                            self._ric_threshold(rig, resid, n_flat.size, e))
        if self.refit:
            e = np.stack([self._refit_linear(D, (T[k] - rig.neutral).ravel(), e[k], None) for k in range(K)])
        return e

    def _refit_linear(self, A, b, e, weights=None):
        from scipy.optimize import lsq_linear  # (imported here: see _bounded_gram_lsq)

        sel = np.flatnonzero(e > 0)
        if sel.size == 0:
            return e
        As = A[:, sel]
        if weights is not None:
            w = np.sqrt(np.repeat(weights, 3)) if As.shape[0] == 3 * weights.size else np.sqrt(weights)
            As, b = As * w[:, None], b * w
        out = np.zeros_like(e)
        out[sel] = lsq_linear(As, b, bounds=(0.0, 1.0 if self.clamp else np.inf)).x
        return out

    @staticmethod
    def _ric_threshold(rig, resid2, n_values, e):
        """``2 ln(B) sigma^2`` with ``sigma^2`` = residual / degrees of freedom of a first, full pass."""
        k = int((np.asarray(e) > 0).sum(axis=-1).max()) if np.ndim(e) == 1 else (np.asarray(e) > 0).sum(axis=-1)
        sigma2 = np.asarray(resid2) / np.maximum(n_values - k, 1)
        return 2.0 * np.log(rig.n_shapes) * sigma2

    # ------------------------------------------------------------------ landmarks
    def _fit_landmarks(self, rig, target: LandmarkTarget):
        e, cams, orders = self._landmarks_batch(rig, [target])
        return e[0], {"order": orders[0], "camera": cams[0], "pose_estimated": not target.camera.posed}

    def _landmark_batches(self, rig: BlendshapeRig, targets, chunk: int, workers: int = 1):
        """Coefficients ``(K, B)``, (estimated) cameras and selection orders for ``K`` checked landmark targets.

        The same computation as :meth:`fit` on each target, vectorised over the
        targets: targets sharing a set of landmark vertices are fitted together
        (their cameras may differ; unknown poses are estimated in one batched
        Levenberg-Marquardt, :func:`facegeom.model.pose.estimate_poses`).
        """
        E = np.zeros((len(targets), rig.n_shapes))
        cams: list = [None] * len(targets)
        orders: list = [None] * len(targets)
        groups: dict = {}
        for k, tg in enumerate(targets):
            groups.setdefault((tg.vertex_ids.tobytes(), tg.camera.posed), []).append(k)
        # chunks keep the (K, B, n, 3) work arrays in cache; they are independent, so they run on the cores
        # (numpy releases the GIL inside its array operations)
        chunks = [g[c0:c0 + chunk] for g in groups.values() for c0 in range(0, len(g), chunk)]
        n_workers = max(1, min(len(chunks), int(workers)))

        def one(rows):
            return self._landmarks_batch(rig, [targets[k] for k in rows])

        if n_workers > 1:
            with ThreadPoolExecutor(n_workers) as pool:
                outs = list(pool.map(one, chunks))
        else:
            outs = [one(rows) for rows in chunks]
        for rows, (e, cs, os_) in zip(chunks, outs):
            E[rows] = e
            for k, c, o in zip(rows, cs, os_):
                cams[k], orders[k] = c, o
        return E, cams, orders

    def _landmarks_batch(self, rig, targets):
        """Targets sharing vertex ids and posed-ness -> (e (K, B), cameras, selection orders)."""
        ids = targets[0].vertex_ids
        L = np.stack([tg.points2d for tg in targets])  # (K, n, 2)
        intr = [np.array([getattr(tg.camera, a) for tg in targets]) for a in ("focal", "cx", "cy")]
        orders = [None] * len(targets)

        warm = {}

        def solve(R, t):
            if self._map():  # the later solves of the pose alternation start from the last one's weights
                e, _, sd = map_weights(rig, ids, L, R, t, *intr, prior_sd=self._prior_sd(), upper=self._upper,
                                       e0=warm.get("e"), steps=WARM_STEPS if "e" in warm else GAUSS_NEWTON_STEPS,
                                       s0=warm.get("sd"), prior_cov=self._prior_cov(rig))
                warm["e"], warm["sd"] = e, sd
                orders[:] = [_by_weight(w) for w in e]
                return e
            if self._lsq("landmarks"):
                e, order = self._lsq_landmarks(rig, ids, L, R, t, *intr)
                orders[:] = order
                return e
            e, order, step_e, step_gain = self._greedy_landmarks(rig, ids, L, R, t, *intr)
            if self.stop == "ric":  # second pass: stop where a selection gains less than noise would
                F = rig.neutral[ids][None] + np.tensordot(e, rig.deltas[:, ids], 1)
                resid = ((project_many(F, R, t, *intr) - L) ** 2).sum(axis=(1, 2))
                # the second pass repeats the first up to its stop: cut the first instead of running it again
                e, order = _cut_path(order, step_e, step_gain, np.broadcast_to(
                    self._ric_threshold(rig, resid, L[0].size, e), (len(e),)).astype(np.float64))
            if self.refit:
                e = np.stack([self._refit_landmarks(rig, ids, L[k], _camera(intr, R, t, k), e[k])
                              for k in range(len(e))])
            orders[:] = order
            return e

        if targets[0].camera.posed:
            R = np.stack([tg.camera.R for tg in targets])
            t = np.stack([tg.camera.t for tg in targets])
            e = solve(R, t)
            cams = [tg.camera for tg in targets]
        else:
            e, R, t = fit_with_poses(rig, ids, L, intr, solve, self.alternations)
            U, _, Vt = np.linalg.svd(R)  # the nearest rotations, free of accumulated rounding (all at once)
            R = U @ Vt
            cams = [PinholeCamera(intr[0][k], intr[1][k], intr[2][k], R[k], t[k]) for k in range(len(targets))]
        return e, cams, [[int(i) for i in o if i >= 0] for o in orders]

    def _sem_landmarks(self, rig, ids, L, R, t, f, cx, cy, min_gain=None):
        """Eqs. 20-22 with the exact projection of the current face, for ``K`` targets at once.

        ``L (K, n, 2)`` landmarks of the vertices ``ids``; camera ``k`` is
        ``(R[k], t[k], f[k], cx[k], cy[k])``. Returns ``e (K, B)`` and the
        selection orders ``(K, B)`` (-1 after the last). ``min_gain (K,)``
        stops a target where its selection would gain less (``stop="ric"``):
        the selections up to there are those of the run without it, so that
        run is cut (:func:`_cut_path`) instead of being repeated.
        """
        e, order, step_e, step_gain = self._greedy_landmarks(rig, ids, L, R, t, f, cx, cy)
        if min_gain is None:
            return e, order
        return _cut_path(order, step_e, step_gain, np.broadcast_to(np.asarray(min_gain, dtype=np.float64), (len(e),)))

    def _greedy_landmarks(self, rig, ids, L, R, t, f, cx, cy):
        """The greedy of :meth:`_sem_landmarks` without a stop, recording every step.

        Returns ``e (K, B)``, ``order (K, B)`` and per step ``s`` of target
        ``k`` (where ``order[k, s] >= 0``) the coefficient it added,
        ``step_e[k, s]``, and the decrease of the squared residual it was
        credited with, ``step_gain[k, s] = 2 e p - e^2 |dB|^2`` (the quantity
        ``min_gain`` is compared with).

        Everything that does not change during the selection is computed once
        per target in camera space: the rotated deltas ``RD``, the candidates'
        projected motions ``M = Pi(B_i) - Pi(B_1)`` (eq. 20) and, for the
        exclusion test (eq. 22), ``b_in = RD_in,x dTu_n - RD_in,y dTv_n``.
        With ``x/d`` the perspective division, the index of the current face
        ``F^t`` moved by ``e_i dB_i`` is then
        ``1 - f (sum_n (a_n + e_i b_in) / (d_n + e_i RDd_in) - c0) / |dT|^2``
        (``a_n = x_n dTu_n - y_n dTv_n`` and ``d_n`` of ``F^t``,
        ``c0 = sum_n (x_n dTu_n - y_n dTv_n) / d_n`` of ``F^1``): a few
        operations on the (target, candidate) pairs with ``e_i > 0`` per step
        (with ``e_i = 0`` the index is the previous selection's). Targets that
        stopped are dropped from the work arrays once half of them have.
        """
        K, n = L.shape[:2]
        B = rig.n_shapes
        P1 = np.matmul(R, rig.neutral[ids].T) + t[:, :, None]  # (K, 3, n) camera space, coordinate-major
        if not np.all(P1[:, 2] < 0):
            k = int(np.argwhere(~(P1[:, 2] < 0))[0, 0])
            raise InputError(f"a landmark is behind the camera{f' (target {k})' if K > 1 else ''}")
        # rotated deltas (K, 3, B, n): one product for all targets
        RD = (R.reshape(3 * K, 3) @ rig.deltas[:, ids].reshape(-1, 3).T).reshape(K, 3, B, n)
        d1 = -P1[:, 2]
        X1, Y1 = P1[:, 0] / d1, P1[:, 1] / d1
        RDd = -RD[:, 2]  # depth change of each candidate at full weight
        dB = d1[:, None] + RDd
        if not np.all(dB > 0):
            raise InputError(_BEHIND)
        M = np.empty((K, B, 2 * n))  # (K, B, 2n): u then v, in place (no (K, B, n) temporaries)
        for j, (c1, sign) in enumerate(((X1, 1.0), (Y1, -1.0))):
            Mj = M[:, :, j * n:(j + 1) * n]
            np.add(P1[:, None, j], RD[:, j], out=Mj)
            Mj /= dB
            Mj -= c1[:, None]
            Mj *= sign * f[:, None, None]
        nrm2 = np.einsum("kbm,kbm->kb", M, M)
        moves = nrm2 > _TINY
        safe2 = np.where(moves, nrm2, 1.0)
        u1, v1 = cx[:, None] + f[:, None] * X1, cy[:, None] - f[:, None] * Y1  # Pi(F^1)
        dTu, dTv = L[..., 0] - u1, L[..., 1] - v1  # L - Pi(F^1)
        tt = np.einsum("kn,kn->k", dTu, dTu) + np.einsum("kn,kn->k", dTv, dTv)
        has_t = tt > _TINY
        w = {  # per-target work arrays, rows = targets gid
            "M": M, "RD": RD, "RDd": np.ascontiguousarray(RDd),
            "bq": RD[:, 0] * dTu[:, None] - RD[:, 1] * dTv[:, None],
            "PF": P1.copy(), "L": np.concatenate([L[..., 0], L[..., 1]], axis=1), "dTu": dTu, "dTv": dTv,
            "c0": np.einsum("kn,kn->k", X1, dTu) - np.einsum("kn,kn->k", Y1, dTv),
            "f": f, "cx": cx, "cy": cy, "nrm2": nrm2, "moves": moves, "safe2": safe2, "rsafe": np.sqrt(safe2),
            "level": 1e-9 * np.sqrt(tt)[:, None] * np.sqrt(safe2), "has_t": has_t,
            "inv_tt": np.where(has_t, 1.0 / np.where(has_t, tt, 1.0), 0.0), "alive": moves.copy(),
        }
        gid = np.arange(K)
        e = np.zeros((K, B))
        order = np.full((K, B), -1, dtype=np.int64)
        step_e = np.zeros((K, B))
        step_gain = np.full((K, B), np.inf)
        upper = self._upper
        act = np.flatnonzero(w["alive"].any(axis=1))  # rows of w still selecting
        for step in range(B):
            if act.size == 0:
                break
            if act.size <= gid.size // 2:  # compact the work arrays to the targets still selecting
                w = {key: v[act] for key, v in w.items()}
                gid, act = gid[act], np.arange(act.size)
            a = (lambda key: w[key]) if act.size == gid.size else (lambda key: w[key][act])
            PF, fa = a("PF"), a("f")
            d = -PF[:, 2]
            xd, yd = PF[:, 0] / d, PF[:, 1] / d
            res = a("L") - np.concatenate([a("cx")[:, None] + fa[:, None] * xd, a("cy")[:, None] - fa[:, None] * yd],
                                          axis=1)  # L - Pi(F^t)
            proj = np.einsum("kbm,km->kb", a("M"), res)  # (Pi(B_i) - Pi(B_1)) . (L - Pi(F^t))
            safe2 = a("safe2")
            # eq. 21 (clamped, eq. 18); a projection at rounding level counts as none
            ei = np.where(a("moves") & (proj > a("level")), proj / safe2, 0.0)
            if upper is not None:
                ei = np.minimum(ei, upper)
            al = a("alive").copy()
            if self.exclusion and step > 0:
                # only a candidate that moves the face can change the index: with e_i = 0 it stays the previous
                # selection's (in exact arithmetic), so only pairs with e_i > 0 are evaluated
                kk, bb = np.nonzero(al & a("has_t")[:, None] & (ei > 0))
                if kk.size:
                    c0, inv_tt = a("c0"), a("inv_tt")
                    rk = act[kk]  # rows of w
                    ep_ = ei[kk, bb][:, None]
                    den = ep_ * w["RDd"][rk, bb]
                    den += d[kk]  # depth of F^t + e_i dB_i
                    if not den.min() > 0:
                        raise InputError(_BEHIND)
                    an = PF[:, 0] * a("dTu") - PF[:, 1] * a("dTv")
                    num = ep_ * w["bq"][rk, bb]
                    num += an[kk]
                    num /= den
                    r = 1.0 - fa[kk] * (num.sum(axis=1) - c0[kk]) * inv_tt[kk]  # eq. 22
                    r_prev = 1.0 - fa * ((an / d).sum(axis=1) - c0) * inv_tt
                    # |r| > |r_prev| beyond rounding
                    worse = np.abs(r) - np.abs(r_prev[kk]) > 1e-11
                    al[kk[worse], bb[worse]] = False
            # once no alive candidate has a positive coefficient, every later selection adds 0 and leaves the
            # face, the residual and the index unchanged: the coefficients are final, stop this target here
            go = (al & (ei > 0)).any(axis=1)
            if self.select == "gain":
                score = np.where(al, 2.0 * ei * proj - ei * ei * safe2, -np.inf)
            else:
                score = np.where(al, proj / a("rsafe"), -np.inf)  # eq. 20
            pick = np.argmax(score, axis=1)
            rows = np.arange(act.size)
            ep = ei[rows, pick]
            gain = 2.0 * ep * proj[rows, pick] - ep * ep * a("nrm2")[rows, pick]
            al[rows, pick] = False
            al[~go] = False
            w["alive"][act] = al
            g, pg, gk = act[go], pick[go], gid[act[go]]
            e[gk, pg] += ep[go]
            order[gk, step] = pg
            step_e[gk, step] = ep[go]
            step_gain[gk, step] = gain[go]
            w["PF"][g] += ep[go][:, None, None] * w["RD"][g, :, pg]
            if not np.all(w["PF"][g, 2] < 0):
                raise InputError(_BEHIND)
            act = g[al[go].any(axis=1)]
        return e, order, step_e, step_gain

    def _lsq_landmarks(self, rig, ids, L, R, t, f, cx, cy):
        """``coefficients="lsq"`` on landmarks: :func:`sem_orthogonal_gram` on each target's projected motions.

        The motions are eq. 20's ``Pi(B_i) - Pi(B_1)`` of every candidate at full
        weight and the target's ``L - Pi(B_1)``, ``2 n`` values per target.
        """
        K, n = L.shape[:2]
        B = rig.n_shapes
        F1 = rig.neutral[ids]
        Fi = F1[None] + rig.deltas[:, ids]  # (B, n, 3)
        e = np.zeros((K, B))
        order = np.full((K, B), -1, dtype=np.int64)
        for k in range(K):
            one = [np.repeat(a[k:k + 1], B + 1, axis=0) for a in (R, t, f, cx, cy)]
            P = project_many(np.concatenate([F1[None], Fi]), *one)  # (B + 1, n, 2)
            A = (P[1:] - P[0]).reshape(B, -1)  # (B, 2n)
            b = (L[k] - P[0]).ravel()
            e[k], order[k] = sem_orthogonal_gram(A @ b, A @ A.T, float(b @ b), b.size, self._upper)
        return e, order

    def _refit_landmarks(self, rig, ids, L, cam, e):
        sel = np.flatnonzero(e > 0)
        if sel.size == 0:
            return e
        from scipy.optimize import least_squares

        def resid(x):
            w = np.zeros_like(e)
            w[sel] = x
            return (cam.project(rig.evaluate(w, ids), "landmark") - L).ravel()

        hi = 1.0 if self.clamp else np.inf
        x = least_squares(resid, np.minimum(e[sel], 1.0 if self.clamp else e[sel].max() + 1), bounds=(0.0, hi)).x
        out = np.zeros_like(e)
        out[sel] = x
        return out

    # ------------------------------------------------------------------ point clouds
    def _fit_points(self, rig, target: PointCloudTarget):
        from scipy.optimize import lsq_linear, nnls  # (imported here: see _bounded_gram_lsq)

        n = rig.n_vertices
        region = np.arange(n) if self.region is None else self.region
        if region.size == 0 or region.min() < 0 or region.max() >= n:
            raise InputError(f"region must hold vertex ids in [0, {n})")
        if self.max_points and region.size > self.max_points:
            region = region[np.linspace(0, region.size - 1, self.max_points).astype(np.int64)]
        from scipy.spatial import cKDTree  # point clouds only: a marker or landmark solve needs no spatial import

        tree = cKDTree(target.points)
        if self.covered_only:  # vertices the scan does not cover take no part (ears, neck of a cropped scan)
            nearest = cKDTree(rig.neutral[region]).query(target.points, workers=-1)[1]
            region = region[np.unique(nearest)]
            if region.size < 3:
                raise InputError("the point cloud covers fewer than 3 rig vertices (align it to the rig first)")
        F1 = rig.neutral[region]  # (m, 3)
        D = rig.deltas[:, region]  # (B, m, 3)
        B = rig.n_shapes
        nrm2 = np.einsum("bij,bij->b", D, D)
        moves = nrm2 > _TINY
        # vertices a candidate actually moves (others keep their correspondence)
        mag = np.linalg.norm(D, axis=2)  # (B, m)
        support = [np.flatnonzero(mag[b] > 1e-2 * mag[b].max()) if moves[b] else np.zeros(0, np.int64)
                   for b in range(B)]

        def closest(X):
            return target.points[tree.query(X, workers=-1)[1]]

        e = np.zeros(B)
        F = F1.copy()
        P = closest(F)
        alive = moves.copy()
        order = []
        gcv_path = self._lsq("points")  # GCV over the path on the current correspondences
        m_values = F1.size
        best = (m_values * float(((P - F) ** 2).sum()) / m_values ** 2, e.copy(), 0)
        upper = self._upper
        queries = 0
        for t in range(B):
            if not alive.any():
                break
            cand = np.flatnonzero(alive)
            s = np.full(B, -np.inf)
            ei = np.zeros(B)
            r = np.zeros(B)
            r0 = np.zeros(B)
            Pi_store = {}
            resid0 = P - F
            for i in cand:
                e0 = max(float((D[i] * resid0).sum()) / nrm2[i], 0.0)  # coefficient on the current matches
                if upper is not None:
                    e0 = min(e0, upper)
                Pi = P
                if e0 > 0 and support[i].size:  # eq. 23: one ICP step of the face moved by this candidate
                    Pi = P.copy()
                    sup = support[i]
                    Pi[sup] = closest(F[sup] + e0 * D[i, sup])
                    queries += sup.size
                m = Pi - F
                dot = float((D[i] * m).sum())
                s[i] = dot / np.sqrt(nrm2[i])  # eq. 24 (ESim up to 1/|m|, which differs per candidate)
                mn = float(np.sqrt((m * m).sum()))
                s[i] = s[i] / mn if mn > _TINY else -np.inf
                ei[i] = max(dot / nrm2[i], 0.0)
                if upper is not None:
                    ei[i] = min(ei[i], upper)
                Pi_store[i] = Pi
                if self.exclusion and t > 0:
                    dT1 = Pi - F1  # P_i - F^1
                    tt1 = float((dT1 * dT1).sum())
                    if tt1 > _TINY:
                        now = float((dT1 * (F - F1)).sum())  # the motion selected so far, B~ without the candidate
                        r[i] = 1.0 - (now + ei[i] * float((dT1 * D[i]).sum())) / tt1  # eq. 25
                        r0[i] = 1.0 - now / tt1  # the index before adding it, on the same correspondences
            if self.exclusion and t > 0:
                drop = cand[np.abs(r[cand]) > np.abs(r0[cand])]
                alive[drop] = False
                s[drop] = -np.inf
                if not alive.any():
                    break
            if not np.isfinite(s[cand]).any():  # no candidate moves the face towards the points: it fits already
                break
            i = int(np.argmax(s))
            e[i] += ei[i]
            order.append(i)
            alive[i] = False
            P = Pi_store[i]  # P^t
            sel = np.flatnonzero(e > 0)
            if sel.size:  # refine the selected coefficients on the updated correspondences
                A = D[sel].reshape(sel.size, -1).T
                if upper is None:
                    e[sel] = nnls(A, (P - F1).ravel())[0]
                else:
                    e[sel] = lsq_linear(A, (P - F1).ravel(), bounds=(0.0, upper)).x
            F = F1 + np.tensordot(e, D, axes=1)
            P = closest(F)
            queries += F.shape[0]
            if gcv_path:
                k_sel = int((e > 0).sum())
                if k_sel < m_values:
                    gcv = m_values * float(((P - F) ** 2).sum()) / (m_values - k_sel) ** 2
                    if gcv < best[0]:
                        best = (gcv, e.copy(), len(order))
        if gcv_path:
            e, order = best[1], order[:best[2]]
        return e, {"order": order, "points_used": int(region.size), "queries": queries}


class SEMLSFitter(SEMFitter):
    """SEM with least-squares coefficients where the data determine them: facegeom's default fitter (``sem-ls``).

    The paper's selection (largest ESim with the remaining motion) with
    ``coefficients="auto"``, ``clamp=True`` and ``stop="ric"``: meshes and
    point clouds get every selected coefficient re-solved by bounded least
    squares and a selection cut by generalised cross-validation (dense targets
    reach least-squares accuracy, sparse ones stay sparse); landmarks get the
    posterior mode of all weights under a prior of their range, with the
    photo's noise estimated from the photo (:mod:`facegeom.methods.landmark_map`;
    ``coefficients="greedy"`` is the paper's greedy with the noise-aware stop).
    Every parameter is :class:`SEMFitter`'s; only the defaults differ.
    """

    def __init__(self, exclusion: bool = True, clamp: bool = True, refit: bool = False, alternations: int = 3,
                 region=None, max_points: int = 2000, select: str = "esim", covered_only: bool = True,
                 stop: str = "ric", coefficients: str = "auto", prior_sd="auto"):
        super().__init__(exclusion, clamp, refit, alternations, region, max_points, select, covered_only, stop,
                         coefficients, prior_sd)
