"""Expression retargeting with the tangent framework (paper sections 3.2, 4.1, 4.2).

Data points are the frames of the actor's marker sequence, the local structure
of a frame is a temporal window (the frame and ``window`` frames before and
after, clipped at the ends), the labels are a few known frames of the
character. The alignment matrix and the solve are those of
:mod:`facegeom.methods.tangent` (no second copy).

Two strategies, as in the paper:

- ``marker`` (the paper's default): every marker's trajectory is a data set of
  its own (``T`` points in 3-D); the ``p`` problems are stacked into one
  block-diagonal system and solved at once, then assembled into frames.
- ``frame``: a frame is one point in ``3p`` dimensions; one ``T x T`` system
  with ``3p`` right-hand sides.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.sparse import csgraph

from facegeom.errors import InputError
from facegeom.interfaces import Params, as_handles, as_sequence, check_fitted, check_range
from facegeom.linalg import banded_inverse_diagonal, factorize_spd
from facegeom.methods.tangent import TangentSolver, alignment_matrix


def temporal_windows(T: int, half: int) -> sp.csr_matrix:
    """Boolean ``(T, T)`` matrix: row ``t`` = frames ``[t - half, t + half]`` clipped to ``[0, T)``."""
    if T < 1:
        raise InputError("a sequence needs at least one frame")
    offs = np.arange(-half, half + 1)
    rows = np.repeat(np.arange(T), offs.size)
    cols = (np.arange(T)[:, None] + offs[None, :]).ravel()
    keep = (cols >= 0) & (cols < T)
    return sp.csr_matrix((np.ones(int(keep.sum()), bool), (rows[keep], cols[keep])), shape=(T, T))


def evenly_spread(T: int, L: int) -> np.ndarray:
    """``L`` labelled frames evenly spread over ``T`` (``round(linspace(0, T-1, L))``, unique)."""
    return np.unique(np.round(np.linspace(0, T - 1, L)).astype(np.int64))


def second_difference(T: int) -> sp.csr_matrix:
    """``(T-2, T)`` second-difference operator (``x[t-1] - 2 x[t] + x[t+1]``)."""
    if T < 3:
        return sp.csr_matrix((0, T))
    return sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(T - 2, T), format="csr")


def check_retarget_inputs(source, labelled_frames, target_labels):
    """Validate ``fit`` arguments; return ``(S (T,p,3), labels (L,), Y_hat (L,p,3))``."""
    S = as_sequence(source, "source")
    T, p, _ = S.shape
    lab = as_handles(labelled_frames, T, "labelled_frames")
    if lab.size < 2:
        raise InputError(f"at least two labelled frames are needed, got {lab.size}")
    Yh = np.asarray(target_labels, dtype=np.float64)
    if Yh.ndim != 3 or Yh.shape[2] != 3:
        raise InputError(f"target_labels must have shape (L, p, 3), got {Yh.shape}")
    if Yh.shape[0] != lab.size:
        raise InputError(f"{lab.size} labelled frames but {Yh.shape[0]} target label frames")
    if Yh.shape[1] != p:
        raise InputError(f"the source has {p} markers per frame but the target labels have {Yh.shape[1]}")
    bad = ~np.isfinite(Yh).all(axis=(1, 2))
    if bad.any():
        raise InputError(f"target label frame {int(np.flatnonzero(bad)[0])} contains NaN or inf")
    as_sequence(Yh, "target_labels")  # coordinates no geometry reaches
    return S, lab, np.ascontiguousarray(Yh)


BETA_GRID = (0.0, 1e-3, 1e-2, 0.1, 1.0, 10.0, 100.0, 1e4)

DEFAULT_SMOOTHNESS = 0.1
"""The retargeter's default temporal second-difference weight (``smoothness``)."""

HORIZON_FRAMES = 300.0
"""Frames over which a labelled frame's correction of the base map fades (:func:`horizon_ridge`).

Without it the correction between labelled frames far apart, and beyond the
first and last one, follows the null space of the second difference, a
straight line in time: on a 100,000-frame take with 10 labels thousands of
frames apart the system was numerically singular (refused), and on 10,000
frames the frames before the first label drifted (0.10 cm RMS against 0.006
with the horizon, a synthetic character of the actor's markers). 300 frames
(10 s at 30 fps) is above the longest gap between labels of the retargeting
benchmarks (1,000 frames with 5 labels: 250), whose errors it changes by less
than 1e-6 relative."""


def horizon_ridge(B, D2, horizon: float, smoothness: float) -> sp.csr_matrix:
    """The ridge that makes a label's correction fade over ``horizon`` frames: ``w H^-4 I``.

    ``w`` is the weight of the second-difference energy ``|D2 y|^2`` at
    ``smoothness`` (relative to ``B``, as :class:`TangentRetargeter` scales it):
    at the temporal frequency ``1 / H`` that energy, ``w (2 - 2 cos(1/H))^2 ~ w H^-4``,
    equals the ridge's, so slower changes of the correction (the straight line
    between labels far apart) are damped towards the base map and faster ones
    are left to the framework.
    """
    Q = (D2.T @ D2).tocsr()
    tb = B.diagonal().sum()
    w = smoothness * (tb if tb > 0 else 1.0) / Q.diagonal().sum()
    return sp.identity(B.shape[0], format="csr") * (w * float(horizon) ** -4.0)


def loo_label_weight(B, labelled, residual, grid=BETA_GRID,
                     zero_score: float | None = None, noise: float | None = None) -> tuple[float, np.ndarray]:
    """Choose the label weight ``beta`` of eq. 18 by leave-one-label-out prediction (or by risk, given the noise).

    For every candidate ``beta`` (``grid`` times the mean diagonal of ``B``) the
    solution at the labelled points is a linear smoother of the labels,
    ``Y_lab = S r``; the prediction of label ``i`` from the others is then
    ``r_i - (r_i - (S r)_i) / (1 - S_ii)`` in closed form. The candidate with the
    smallest summed squared leave-one-out error wins: noisy labels get a small
    weight (they are smoothed), clean labels a large one (nearly interpolated).
    A candidate ``0`` means no correction of the base field at all; its score is
    ``zero_score`` (the base field's own leave-one-out error) when given, else
    the squared residual.

    With ``noise`` (the labels' noise ``sigma``, standard deviation per
    coordinate) the largest weight (the labels reproduced) replaces that choice
    when its risk is lower. Leave-one-label-out only scores how well the other
    labels predict a label, so it cannot see that a clean label is best
    reproduced exactly, and picks a tiny weight on clean data. The risk of the
    fitted labels is Stein's unbiased estimate
    ``||r - S r||^2 + 2 sigma^2 D tr S - M D sigma^2`` (``D`` columns of ``r``;
    the candidate ``0``: ``||r||^2 - M D sigma^2``). Only these two candidates
    are compared, not the risk's own minimum: the risk is reliable when the
    noise is far from the residual's size (clean labels against their map's
    error, or noise that dominates), and between those only
    leave-one-label-out's choice is kept (the risk over every candidate picked "no
    correction" on clean synthetic data whose map error was as small as the
    noise estimate; the comparison reproduces labels only when their residual
    energy clearly exceeds the noise's).

    Only ``S r`` and the diagonal of ``S = beta A^-1[lab, lab]``
    (``A = B + beta E E^T``) are needed, never ``S`` itself nor a dense inverse:
    per candidate, one sparse factorization of ``A`` (banded in time for the
    retargeting windows, so linear in the number of points) and one solve.
    With at most ``D`` labels (the frame strategy) its right-hand sides are the
    ``M`` label indicators, giving ``S`` whole; otherwise (the marker strategy:
    ``p`` independent trajectories) they are ``beta E r`` for ``S r`` and ``C``
    indicator columns, the ``c``-th holding the ``c``-th label of every
    connected part of ``B`` (parts do not interact, so one column serves all of
    them), for the diagonal; ``C`` is the largest number of labels in one part
    (the labelled frames).

    Parameters
    ----------
    B : (N, N) sparse symmetric positive semidefinite matrix
        The alignment matrix (with any added energy).
    labelled : (M,) int
        Distinct labelled points.
    residual : (M, D) float array
        The labels minus the base field at the labelled points.
    grid : sequence of float
        Candidates, relative to the mean diagonal of ``B``.
    zero_score : float, optional
        The score of a candidate ``0`` (leave-one-out scores only).
    noise : float, optional
        The labels' noise (standard deviation per coordinate, the data's
        units): reproduce the labels where the risk says so (above).

    Returns
    -------
    beta : float
        The chosen absolute weight.
    scores : (len(grid),) or (2, len(grid)) float64
        The leave-one-out scores per candidate; with ``noise``, a second row
        with the risks.

    Raises
    ------
    SolveError
        A connected part of ``B`` holds no label, or a system is singular.
    """
    B = sp.csr_matrix(B, dtype=np.float64)
    N = B.shape[0]
    scale = B.diagonal().mean()
    scale = scale if scale > 0 else 1.0
    labelled = np.asarray(labelled, dtype=np.int64)
    M = labelled.size
    r = np.asarray(residual, dtype=np.float64).reshape(M, -1)
    TangentSolver._check_components(B, labelled)
    D = r.shape[1]
    if M <= D:  # few labels (the frame strategy): the whole S from M unit columns
        C, colour = M, np.arange(M)
        rhs = np.zeros((N, M))
        rhs[labelled, colour] = 1.0
    else:  # many labels in separate parts (the marker strategy): beta E r, plus one column per colour
        _, comp = csgraph.connected_components(B != 0, directed=False)
        # colour of a label = its rank among the labels of its part: labels of one colour never interact
        order = np.argsort(comp[labelled], kind="stable")
        part = comp[labelled][order]
        first = np.r_[0, np.flatnonzero(np.diff(part)) + 1]
        colour = np.empty(M, np.int64)
        colour[order] = np.arange(M) - np.repeat(first, np.diff(np.r_[first, M]))
        C = int(colour.max()) + 1
        rhs = np.zeros((N, D + C))
        rhs[labelled, D + colour] = 1.0
    scores, risk = np.empty(len(grid)), np.empty(len(grid))
    s2 = 0.0 if noise is None else float(noise) ** 2
    for k, g in enumerate(grid):
        if g == 0:  # no correction at all: each label is predicted as 0
            scores[k] = float((r ** 2).sum()) if zero_score is None else float(zero_score)
            risk[k] = float((r ** 2).sum()) - M * D * s2
            continue
        beta = g * scale
        A = B + sp.csr_matrix((np.full(M, beta), (labelled, labelled)), shape=(N, N))
        if C == M and rhs.shape[1] == M:
            # (checked on these right-hand sides: labels far apart in a long take leave the system regular but
            # too ill-conditioned for an arbitrary one)
            S = beta * factorize_spd(A, probe=rhs).solve(rhs)[labelled]  # (M, M)
            Sr, Sdiag = S @ r, np.diag(S)
        else:
            rhs[labelled, :D] = beta * r
            X = factorize_spd(A, probe=rhs).solve(rhs)
            Sr = X[labelled, :D]  # (S r) = beta A^-1[lab, lab] r
            Sdiag = beta * X[labelled, D + colour]
        denom = np.maximum(1.0 - Sdiag, 1e-9)
        scores[k] = float((((r - Sr) / denom[:, None]) ** 2).sum())
        risk[k] = float(((r - Sr) ** 2).sum()) + 2.0 * s2 * D * float(Sdiag.sum()) - M * D * s2  # Stein's estimate
    best = int(np.argmin(scores))
    if noise is None:
        return float(grid[best] * scale), scores
    top = int(np.argmax(grid))
    if risk[top] < risk[best]:  # clean labels: reproduce them
        best = top
    return float(grid[best] * scale), np.stack([scores, risk])


#: Factor on the estimated label noise before it weighs the labels (:func:`label_noise_estimate`). The risk is
#: lopsided: given a noise below ~0.8x the true one it reproduces noisy labels (seed 0 of the realistic protocol,
#: 0.2 mm, 10 labels: 0.13 mm assumed gave 0.79x the best baseline instead of 0.68x, 0.16 mm 0.69x), while on clean
#: labels a larger factor costs little (the estimate there is ~0.002 mm); the estimate spreads by about +-10 %
#: between sequences. So 1.5 keeps a wide margin from the cliff.
LABEL_NOISE_SAFETY = 1.5


def label_noise_estimate(residuals: np.ndarray, points: np.ndarray) -> float:
    """The labels' white noise (standard deviation per coordinate) from the spatial roughness of their residuals.

    ``residuals (L, p, 3)``: per labelled frame, the labels minus a map's
    (leave-one-label-out) prediction; ``points (p, 3)``: the markers' positions.
    A map's error is spatially smooth (neighbouring markers move alike and are
    mapped alike), label noise is not: the difference of a marker's residual
    and its nearest neighbour's holds twice the noise variance and little of
    the error. With ``d`` that difference, ``|d|^2 ~ 2 sigma^2 chi^2_3``, so
    ``sigma^2 = median |d|^2 / (2 x 2.366)`` (2.366: the median of ``chi^2_3``;
    the median resists markers whose map error is rough). Fewer than two
    markers: NaN (no neighbour, no estimate).
    """
    from scipy.spatial import cKDTree

    E = np.asarray(residuals, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    if P.shape[0] < 2 or E.size == 0:
        return float("nan")
    nn = cKDTree(P).query(P, k=2)[1][:, 1]
    d2 = ((E - E[:, nn]) ** 2).sum(axis=2)
    return float(np.sqrt(np.median(d2) / (2.0 * CHI2_3_MEDIAN)))


CHI2_3_MEDIAN = 2.365973884375338
"""The median of a chi-square variable with 3 degrees of freedom."""


RIDGE_GRID = (1e-4, 1e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0, 3.0, 10.0)


POOL_SIZES = (4, 8)


def neighbour_maps(rest, C, Cy, sizes=POOL_SIZES):
    """Pooled linear maps of each marker's nearest neighbours (the marker itself left out).

    For every size ``k`` in ``sizes`` and every marker ``j``: the one linear map
    that best takes the centred labelled motion of the ``k`` markers nearest to
    ``j`` on the actor's mean frame ``rest`` (``j`` excluded) to the character's,
    ``(sum C_k)^-1 sum Cy_k``. Neighbouring markers are moved by the same
    muscles, so their maps agree; leaving ``j`` out keeps ``j``'s own
    leave-one-label-out score of a map shrunk towards it honest.

    Returns a list of ``(p, 3, 3)`` arrays, one per size.
    """
    p = rest.shape[0]
    out = []
    if p < 2:
        return out
    d2 = ((rest[:, None] - rest[None]) ** 2).sum(axis=2)
    np.fill_diagonal(d2, np.inf)
    order = np.argsort(d2, axis=1)
    eye = np.eye(3)
    for k in sizes:
        nb = order[:, :min(int(k), p - 1)]  # (p, k)
        Cn, Cyn = C[nb].sum(axis=1), Cy[nb].sum(axis=1)
        tr = np.trace(Cn, axis1=1, axis2=2)[:, None, None]
        out.append(np.linalg.solve(Cn + (1e-9 * tr + 1e-300) * eye, Cyn))
    return out


def marker_affine_fit(S, lab, Yh, ridge: float | str = 1e-4, return_loo: bool = False, pool=POOL_SIZES,
                      shared: bool = False):
    """Per-marker affine map actor -> character fitted on the labelled frames.

    For marker ``j``: ``Y = cY_j + (x - cP_j) @ A_j``. ``A_j`` is the ridge
    solution shrunk towards ``A0``, the one linear map that best takes every
    marker's centred motion to the character's (pooled over all markers, so
    well determined): a marker that barely moves, or whose labels are noisy,
    follows the face-wide map instead of a singular or noisy one of its own.
    The ridge is ``ridge`` times the largest eigenvalue of the marker's centred
    labelled scatter. Everything is invariant to a rigid motion of the actor.

    ``ridge="auto"`` picks the ridge per marker from :data:`RIDGE_GRID` by
    closed-form leave-one-label-out error: noisy labels make it shrink towards
    ``A0``, clean ones let each marker's own map through. With ``shared`` one
    candidate (ridge and prior) is chosen for all markers, by the summed
    leave-one-out error: with few noisy labels a per-marker choice among many
    candidates partly fits the noise of that marker's own labels.

    Returns the map applied to every frame, ``(T, p, 3)``, and with
    ``return_loo`` also the leave-one-out residuals at the labels ``(L, p, 3)``.
    """
    P = S[lab]  # (L, p, 3)
    L = P.shape[0]
    cP, cY = P.mean(axis=0), Yh.mean(axis=0)  # (p, 3)
    Pc, Yc = P - cP, Yh - cY
    C = np.einsum("lpi,lpj->pij", Pc, Pc)  # (p, 3, 3)
    Cy = np.einsum("lpi,lpj->pij", Pc, Yc)
    top = np.linalg.eigvalsh(C)[:, -1] + 1e-30
    eye = np.eye(3)
    Cs = C.sum(axis=0)
    A0 = np.linalg.solve(Cs + 1e-9 * np.trace(Cs) * eye + 1e-300 * eye, Cy.sum(axis=0))  # face-wide linear map
    priors = [np.broadcast_to(A0, C.shape)]
    if ridge == "auto" and pool:
        priors += neighbour_maps(S.mean(axis=0), C, Cy, pool)

    def solve(lam, prior):
        try:
            Ainv = np.linalg.inv(C + lam[:, None, None] * eye)
        except np.linalg.LinAlgError:  # ridge 0 and labels in a plane or on a line: the least-norm map
            Ainv = np.linalg.pinv(C + lam[:, None, None] * eye, hermitian=True)
        A = Ainv @ (Cy + lam[:, None, None] * prior)
        res = Yc - np.einsum("lpi,pij->lpj", Pc, A)
        H = np.einsum("lpi,pij,lpj->lp", Pc, Ainv, Pc) + 1.0 / L  # leverage of each label
        return A, res / np.maximum(1.0 - H, 1e-9)[..., None]

    if ridge == "auto":
        fits = [solve(g * top, prior) for prior in priors for g in RIDGE_GRID]
        scores = np.array([(loo ** 2).sum(axis=(0, 2)) for _, loo in fits])  # (G, p)
        k = np.full(scores.shape[1], scores.sum(axis=1).argmin()) if shared else scores.argmin(axis=0)
        A = np.stack([fits[kj][0][j] for j, kj in enumerate(k)])
        loo = np.stack([fits[kj][1][:, j] for j, kj in enumerate(k)], axis=1)
    else:
        A, loo = solve(float(ridge) * top, priors[0])
    out = cY[None] + np.einsum("tpi,pij->tpj", S - cP[None], A)
    return (out, loo) if return_loo else out


KERNEL_WIDTHS = (0.5, 1.0, 2.0, 4.0)
KERNEL_RIDGES = (1e-6, 1e-4, 1e-3, 1e-2, 0.1, 1.0)


def marker_kernel_fit(S, lab, residual, loo_base, widths=KERNEL_WIDTHS, ridges=KERNEL_RIDGES, shared: bool = False):
    """Per-marker Gaussian kernel ridge correction of a base map, chosen by leave-one-label-out error.

    The per-marker affine map (:func:`marker_affine_fit`) misses the curvature of
    the actor -> character map (a marker's 3-D path is a nonlinear function of
    the expression weights on both faces). For every marker ``j`` this fits the
    base map's residual at the labels ``residual[:, j]`` as a function of the
    actor's marker position with kernel ridge regression, Gaussian kernel of
    width ``w`` times the median distance between the marker's labelled
    positions and ridge ``g`` times the kernel's largest eigenvalue. Widths are
    relative to the data so the grid is scale free; the ridge grid reaches from
    near interpolation (clean labels) to heavy smoothing (noisy labels).

    The candidate (or "no correction", scored by ``loo_base``, the base's own
    leave-one-out residuals) with the smallest closed-form leave-one-label-out
    error ``alpha_i / [(K + lam I)^-1]_ii`` is kept, per marker: a marker whose
    labels carry no learnable curvature keeps the base map.

    Parameters
    ----------
    S : (T, p, 3) float array
        The actor's (smoothed) markers.
    lab : (L,) int
        Labelled frames.
    residual : (L, p, 3) float array
        Labels minus the base map at the labelled frames.
    loo_base : (L, p, 3) float array
        Leave-one-label-out residuals of the base map.
    widths, ridges : sequence of float
        The candidates.
    shared : bool
        Choose one candidate for every moving marker (the one whose summed
        leave-one-out error over the markers beats the base's), instead of one
        per marker.

    Returns
    -------
    correction : (T, p, 3) float64
        To be added to the base map at every frame.
    loo : (L, p, 3) float64
        Leave-one-label-out residuals of the corrected map (per marker, of the chosen candidate).
    """
    T, p, _ = S.shape
    L = lab.size
    P = S[lab].transpose(1, 0, 2)  # (p, L, 3)
    R = np.asarray(residual, dtype=np.float64).transpose(1, 0, 2)  # (p, L, 3)
    D2 = ((P[:, :, None, :] - P[:, None, :, :]) ** 2).sum(axis=3)  # (p, L, L)
    iu = np.triu_indices(L, 1)
    med = np.median(np.sqrt(D2[:, iu[0], iu[1]]), axis=1) if L > 1 else np.ones(p)  # (p,)
    moving = med > 0
    med = np.where(moving, med, 1.0)
    best = (np.asarray(loo_base, dtype=np.float64).transpose(1, 0, 2) ** 2).sum(axis=(1, 2))  # (p,)
    best_loo = np.asarray(loo_base, dtype=np.float64).transpose(1, 0, 2).copy()
    choice = np.full(p, -1)
    choice_alpha = np.zeros((p, L, 3))
    choice_width = np.ones(p)
    for w in widths:
        h2 = (w * med) ** 2
        K = np.exp(-D2 / (2.0 * h2[:, None, None]))
        s, U = np.linalg.eigh(K)
        top = s[:, -1]
        Ut = U.transpose(0, 2, 1)
        Ur = Ut @ R  # U^T r, (p, L, 3)
        U2 = U ** 2
        for k, g in enumerate(ridges):
            inv = 1.0 / (np.maximum(s, 0.0) + g * top[:, None])  # (p, L)
            alpha = U @ (inv[:, :, None] * Ur)  # (K + lam I)^-1 r
            Gdiag = (U2 @ inv[:, :, None])[:, :, 0]  # diagonal of (K + lam I)^-1
            loo = alpha / Gdiag[..., None]
            score = (loo ** 2).sum(axis=(1, 2))
            if shared:  # one candidate for every marker: compare the summed scores
                better = np.full(p, score[moving].sum() + best[~moving].sum() < best.sum()) & moving
            else:
                better = (score < best) & moving
            best = np.where(better, score, best)
            best_loo[better] = loo[better]
            choice_alpha[better] = alpha[better]
            choice_width[better] = w * med[better]
            choice[better] = k
    out = np.zeros((T, p, 3))
    for j in np.flatnonzero(choice >= 0):
        d2 = ((S[:, j, None, :] - P[j][None]) ** 2).sum(axis=2)  # (T, L)
        out[:, j] = np.exp(-d2 / (2.0 * choice_width[j] ** 2)) @ choice_alpha[j]
    return out, best_loo.transpose(1, 0, 2)


#: Labels count as clean when their noise variance is below this fraction of the base map's held-out residual
#: energy (the residual is then mostly the map's error). Clean labels get the whole-frame kernel correction
#: (:func:`frame_kernel_fit`, which noise would partly fit) and, with ``select="auto"``, the per-marker choice of
#: the maps' ridges and kernels; other labels the shared choice. On the realistic protocol (seed 0) clean sequences
#: measure 0.00-0.03 and those with 0.2 mm noise 0.9-1.07; with 0.1 every noisy fit of seeds 0 and 3 stayed without
#: the whole-frame correction, 0.3 already let some through (1.3 % worse at 10 noisy labels).
CLEAN_LABELS_MAX_NOISE = 0.1


def frame_kernel_fit(S, lab, residual, loo_base, widths=KERNEL_WIDTHS, ridges=KERNEL_RIDGES, shared: bool = False):
    """A Gaussian kernel ridge correction of a base map on the *whole* actor frame, chosen per marker by leave-one-out.

    :func:`marker_kernel_fit` learns each marker's residual from that
    marker's own position; the character's motion also depends on the rest of
    the face (a stylised character's jaw and eyes follow the whole
    expression). Here every marker's residual at the labels
    ``residual (L, p, 3)`` is fitted as a function of the whole actor frame
    (``3p`` numbers) with kernel ridge regression: a Gaussian of width ``w``
    times the median distance between the labelled frames, ridge ``g`` times
    the kernel's largest eigenvalue (one ``(L, L)`` kernel for all markers).
    A marker takes the candidate whose closed-form leave-one-label-out error
    beats ``loo_base``'s (its current map's), or keeps its map. ``shared``:
    one candidate for all markers, by the summed error.

    Returns the correction ``(T, p, 3)`` and the leave-one-out residuals ``(L, p, 3)``
    of the corrected map. Linear in the number of frames.
    """
    T, p, _ = S.shape
    L = lab.size
    loo_base = np.asarray(loo_base, dtype=np.float64)
    out = np.zeros((T, p, 3))
    if L < 3:
        return out, loo_base
    X = S.reshape(T, 3 * p)
    Xl = X[lab]
    D2 = np.maximum(((Xl[:, None, :] - Xl[None, :, :]) ** 2).sum(axis=2), 0.0)  # (L, L)
    med = float(np.median(np.sqrt(D2[np.triu_indices(L, 1)])))
    if not med > 0:
        return out, loo_base
    R = np.asarray(residual, dtype=np.float64).reshape(L, p * 3)
    base_score = (loo_base ** 2).sum(axis=(0, 2))  # (p,)
    best, best_loo = base_score.copy(), loo_base.copy()
    pick = np.full(p, -1)
    alphas, cands = [], []
    for w in widths:
        K = np.exp(-D2 / (2.0 * (w * med) ** 2))
        top = float(np.linalg.eigvalsh(K)[-1])
        for g in ridges:
            Ai = np.linalg.inv(K + g * top * np.eye(L))
            alpha = Ai @ R  # (L, 3p)
            loo = (alpha / np.diag(Ai)[:, None]).reshape(L, p, 3)
            score = (loo ** 2).sum(axis=(0, 2))
            if shared:
                better = np.full(p, score.sum() < best.sum())
            else:
                better = score < best
            best = np.where(better, score, best)
            best_loo[:, better] = loo[:, better]
            pick[better] = len(cands)
            alphas.append(alpha.reshape(L, p, 3))
            cands.append(w)
    if (pick < 0).all():
        return out, best_loo
    Dt = np.maximum((X ** 2).sum(axis=1)[:, None] - 2.0 * X @ Xl.T + (Xl ** 2).sum(axis=1)[None, :], 0.0)  # (T, L)
    for c in np.unique(pick[pick >= 0]):
        js = np.flatnonzero(pick == c)
        Kt = np.exp(-Dt / (2.0 * (cands[c] * med) ** 2))
        out[:, js] = np.einsum("tl,ljk->tjk", Kt, alphas[c][:, js])
    return out, best_loo


class TangentRetargeter(Params):
    """Expression retargeting with the tangent framework (a :class:`~facegeom.interfaces.Retargeter`).

    Parameters
    ----------
    strategy : {"marker", "frame"}
        Per-marker trajectories (paper's default) or whole frames as data points.
    window : int
        Frames on each side of a frame in its local structure (the window has
        ``2 * window + 1`` frames, fewer at the ends).
    d : int
        Number of tangent directions of each window's local PCA.
    beta : float, "auto" or None
        Label weight of eq. 18; ``None`` = hard constraints (labelled frames
        exact); ``"auto"`` (default) = chosen per fit among "no correction of
        the affine base" and a range of weights (:func:`loo_label_weight`), by
        the risk given the labels' noise (``label_noise``): clean labels are
        reproduced (nearly) exactly, noisy ones are smoothed instead of copied
        into the result.
    field : {"affine", "position", "offset"}
        ``position`` (the paper): the unknown is the character's sequence ``Y``.
        ``offset``: the unknown is ``Y - X`` (character minus actor), asked to be
        locally an affine map of the actor's tangent coordinates.
        ``affine`` (default): the same with ``Y - A(X)``, ``A`` a per-marker
        affine map fitted on the labels (:func:`marker_affine_fit`).
    smoothness : float
        Weight of an added temporal second-difference energy on the unknown,
        relative to ``B`` after both are scaled to the same trace; ``0`` = the
        framework alone.
    rank_tol : float
        Relative singular-value threshold of the local PCA (directions below it
        are not tangent directions).
    ridge : float or "auto"
        Ridge of the per-marker affine map (towards copying the actor's motion);
        ``"auto"`` (default) per marker by leave-one-label-out error.
    source_smoothing : float or "auto"
        Temporal Whittaker smoothing of the actor's markers before anything else
        (:func:`whittaker_smooth`); ``0`` = none. ``"auto"`` (default): six
        candidate sources, the capture as given or its low-rank denoising across
        markers (:func:`lowrank_denoise`), each unsmoothed, smoothed with the
        weight that generalised cross-validation picks on the capture, or a
        tenth of it; the one whose base map best predicts held-out labelled
        frames (leave-one-label-out, closed form) is used. GCV alone over-smooths
        clean captures of real takes (their fast jitter is motion the character
        shares); the labels tell. With ``field`` other than ``"affine"``,
        ``"auto"`` is the GCV weight alone.
    kernel : bool
        Add to the per-marker affine base map a per-marker Gaussian kernel
        ridge correction chosen by leave-one-label-out error
        (:func:`marker_kernel_fit`; default ``True``): the curvature of the
        actor -> character map that an affine map misses.
    pool : bool
        Pool across markers (default ``False``): with ``ridge="auto"`` each
        marker's affine map may also be shrunk towards the pooled map of its
        nearest neighbouring markers (:func:`neighbour_maps`), not only towards
        the face-wide one; the prior and ridge are chosen per marker by
        leave-one-label-out error. Off by default: on ``facegeom bench
        retarget`` it did not beat the face-wide prior consistently.
    select : {"auto", "shared", "marker"}
        How the ``"auto"`` ridge of the affine maps and the kernel corrections'
        widths and ridges are chosen by leave-one-label-out error: one candidate
        for all markers by the summed error (``"shared"``), or one per marker
        (``"marker"``). A per-marker choice among many candidates from few
        noisy labels partly fits each marker's own label noise, so
        ``"shared"`` is better with noise (0.2 mm: 1-6 % at 10 labels, 11-19 %
        at 5; ``facegeom bench retarget``, seeds 0-3) but loses clean accuracy
        (up to 25 % with evenly spread labels). ``"auto"`` (default): the
        per-marker choice for labels that look clean
        (:data:`CLEAN_LABELS_MAX_NOISE`, judged on a per-marker fit to the
        capture as given), the shared one otherwise; with ``label_noise=None``
        always per marker.
    horizon : float or None
        Frames over which a labelled frame's correction of the base field
        fades (default :data:`HORIZON_FRAMES`, :func:`horizon_ridge`): far from
        every label the result is the base field, not a straight line drawn
        in time from labels thousands of frames away. ``None``: no fading (a
        long take with few labels may then be refused as singular).
    label_noise : "auto", float or None
        The labels' noise (standard deviation per coordinate, the data's units)
        that ``beta="auto"`` weighs the labels by (Stein's unbiased risk, see
        :func:`loo_label_weight`). ``"auto"`` (default): estimated from the
        spatial roughness of the base map's leave-one-label-out residuals
        (:func:`label_noise_estimate`, times :data:`LABEL_NOISE_SAFETY`); a
        number: known (``0`` = exact labels, reproduced); ``None``: no noise
        model, ``beta`` by leave-one-label-out prediction alone (the former
        default; it cannot see that clean labels are best reproduced, and
        lost 5-10 % on clean data). Labels whose noise is small against
        the base map's held-out error (:data:`CLEAN_LABELS_MAX_NOISE`) also get
        the whole-frame kernel correction (:func:`frame_kernel_fit`; with
        ``kernel=True``). Without an affine base map (``field`` other than
        ``"affine"``) ``"auto"`` is ``None``.

    Attributes
    ----------
    result_ : (T, p, 3) float64
        The character's sequence.
    beta_ : float
        The label weight used (0 = the base field, no correction).
    label_noise_ : float or None
        The noise the weight was chosen with (after the safety factor), or
        ``None`` (leave-one-label-out).
    select_ : str
        The selection rule used (``"marker"`` or ``"shared"``).

    The ``"auto"`` defaults are what makes the method degrade gracefully
    with noisy labels and noisy source markers (``facegeom bench noise``); on
    noise-free data the exact configuration (``beta=None, ridge=1e-4,
    source_smoothing=0``) is about as accurate (within 4 % either way on the
    clean runs of ``facegeom bench retarget``, seed 0, 10 and 20 labels).
    """

    def __init__(self, strategy: str = "frame", window: int = 3, d: int = 3, beta: float | str | None = "auto",
                 field: str = "affine", smoothness: float = DEFAULT_SMOOTHNESS, rank_tol: float = 1e-6,
                 ridge: float | str = "auto", source_smoothing: float | str = "auto", kernel: bool = True,
                 pool: bool = False, select: str = "auto", label_noise: float | str | None = "auto",
                 horizon: float | None = HORIZON_FRAMES):
        if strategy not in ("marker", "frame"):
            raise InputError(f"strategy must be 'marker' or 'frame', got {strategy!r}")
        window = check_range("window", window, 1, 1000, "frames on each side: 1000 is 40 s at 25 fps", integer=True)
        d = check_range("d", d, 1, 100, "tangent directions of a window's local PCA", integer=True)
        if beta is not None and beta != "auto":
            if isinstance(beta, str):
                raise InputError(f"beta must be a positive number, 'auto' or None (hard constraints), got {beta!r}")
            beta = check_range("beta", beta, 1e-6, 1e12, "below it the labels no longer hold the solution and the "
                                   "system is singular; beyond it they are hard constraints: use None")
        if field not in ("position", "offset", "affine"):
            raise InputError(f"field must be 'position', 'offset' or 'affine', got {field!r}")
        smoothness = check_range("smoothness", smoothness, 0, 1e6, "a weight relative to the framework's term, "
                                 "which vanishes beyond it")
        self.strategy, self.window, self.d, self.beta = strategy, int(window), int(d), beta
        if ridge != "auto":
            ridge = check_range("ridge", ridge, 0, 1e6, "relative to each marker's largest spread: beyond it every map "
                                "is the face-wide one") if not isinstance(ridge, str) else ridge
            if isinstance(ridge, str):
                raise InputError(f"ridge must be a non-negative number or 'auto', got {ridge!r}")
        rank_tol = check_range("rank_tol", rank_tol, 0, 1, "relative to the largest singular value")
        self.field, self.smoothness, self.rank_tol = field, float(smoothness), float(rank_tol)
        self.ridge = ridge if ridge == "auto" else float(ridge)
        if source_smoothing != "auto":
            if isinstance(source_smoothing, str):
                raise InputError(f"source_smoothing must be a non-negative number or 'auto', got {source_smoothing!r}")
            source_smoothing = check_range("source_smoothing", source_smoothing, 0, 1e12, "beyond it the smoothed "
                                           "capture is a straight line in time")
        self.source_smoothing = source_smoothing
        if not isinstance(kernel, (bool, np.bool_)):
            raise InputError(f"kernel must be true or false, got {kernel!r}")
        self.kernel = bool(kernel)
        if not isinstance(pool, (bool, np.bool_)):
            raise InputError(f"pool must be true or false, got {pool!r}")
        self.pool = bool(pool)
        if select not in ("auto", "shared", "marker"):
            raise InputError(f"select must be 'auto', 'shared' or 'marker', got {select!r}")
        self.select = select
        if label_noise is not None and label_noise != "auto":
            if isinstance(label_noise, str):
                raise InputError(f"label_noise must be 'auto', a non-negative number or None, got {label_noise!r}")
            label_noise = check_range("label_noise", label_noise, 0, 1e6, "in the data's units: no capture is that "
                                      "noisy")
        self.label_noise = label_noise if label_noise in (None, "auto") else float(label_noise)
        if horizon is not None:
            horizon = check_range("horizon", horizon, 1, 1e9, "frames over which a label's correction fades; None: "
                                  "it never fades")
        self.horizon = None if horizon is None else float(horizon)
        self.result_ = None

    def __repr__(self) -> str:
        return "TangentRetargeter(" + ", ".join(f"{k}={v!r}" for k, v in self.get_params().items()) + ")"

    def fit(self, source, labelled_frames, target_labels) -> "TangentRetargeter":
        """Solve the tangent-alignment system for the whole character sequence.

        Smooths (and with ``"auto"`` possibly low-rank denoises) the source first
        when ``source_smoothing`` asks (the weight used is stored in
        ``source_smoothing_``); builds the alignment matrix ``B`` of the
        temporal windows (the ``p`` marker trajectories as one block-diagonal system
        for ``strategy="marker"``, frames as points in ``3p`` dimensions for
        ``"frame"``), plus the second-difference energy when ``smoothness > 0``;
        takes the base field (none, the source, or the per-marker affine map of
        :func:`marker_affine_fit`, per ``field``) and the label weight (``beta``, or
        chosen by leave-one-label-out for ``"auto"``; stored in ``beta_``); then
        solves once for the labels' residual against the base (no solve when the
        chosen weight is 0: the base field is kept). The sequence is stored in
        ``result_``.

        Parameters
        ----------
        source : (T, p, 3) float64
            The actor's markers per frame.
        labelled_frames : (L,) int64
            At least two distinct frame ids in ``[0, T)``.
        target_labels : (L, p, 3) float64
            The character's markers on those frames.

        Returns
        -------
        self

        Raises
        ------
        InputError
            Bad shapes, NaN or inf, fewer than two labelled frames, repeated or
            out-of-range frame ids.
        SolveError
            The system cannot be solved with these labels.
        """
        S, lab, Yh = check_retarget_inputs(source, labelled_frames, target_labels)
        T, p, _ = S.shape
        self.select_ = self.select
        if self.select == "auto":  # per marker for clean labels, shared for noisy ones: judged on the capture as given
            self.select_ = "marker"
            if self.field == "affine" and self.label_noise is not None:
                if not self._labels_clean(self._base_map(S, lab, Yh, shared=False)[1], Yh):
                    self.select_ = "shared"
        self.source_smoothing_ = 0.0
        fitted = None
        if self.source_smoothing == "auto" and self.field == "affine":
            S, self.source_smoothing_, fitted = self._choose_smoothing(S, lab, Yh)
        elif self.source_smoothing:
            S, self.source_smoothing_ = whittaker_smooth(S, self.source_smoothing)
        Wt = temporal_windows(T, self.window)
        if self.strategy == "marker":
            X = S.transpose(1, 0, 2).reshape(p * T, 3)  # point j*T + t
            R = sp.kron(sp.identity(p, format="csr"), Wt, format="csr")
            labelled = (np.arange(p)[:, None] * T + lab[None, :]).ravel()
            labels = Yh.transpose(1, 0, 2).reshape(p * lab.size, 3)
            D2 = sp.kron(sp.identity(p, format="csr"), second_difference(T), format="csr")
        else:
            X = S.reshape(T, 3 * p)
            R = Wt
            labelled = lab
            labels = Yh.reshape(lab.size, 3 * p)
            D2 = second_difference(T)
        B = alignment_matrix(X, R, self.d, rank_tol=self.rank_tol)
        base = loo = None
        if self.field == "offset":
            base = S
        elif self.field == "affine":
            base, loo = fitted if fitted is not None else self._base_map(S, lab, Yh)
            base, loo = self._frame_correction(S, lab, Yh, base, loo)
        if base is not None:
            base = base.transpose(1, 0, 2).reshape(p * T, 3) if self.strategy == "marker" else base.reshape(T, 3 * p)
        fade = None  # the horizon's ridge, scaled on the framework's own B
        if self.horizon is not None and D2.shape[0]:
            fade = horizon_ridge(B, D2, self.horizon, self.smoothness or DEFAULT_SMOOTHNESS)
        if self.smoothness > 0 and D2.shape[0]:
            Q = (D2.T @ D2).tocsr()
            tb = B.diagonal().sum()
            B = (B + (self.smoothness * (tb if tb > 0 else 1.0) / Q.diagonal().sum()) * Q).tocsr()
        if fade is not None:
            B = (B + fade).tocsr()
        r = labels if base is None else labels - base[labelled]
        beta = self.beta
        self.label_noise_ = None
        if beta == "auto":
            noise = self.label_noise
            if noise == "auto":  # estimated from the base map's held-out residuals (none without a base map)
                noise = None if loo is None else LABEL_NOISE_SAFETY * label_noise_estimate(loo, Yh.mean(axis=0))
                noise = noise if noise is not None and np.isfinite(noise) else None  # one marker: no estimate
            self.label_noise_ = noise
            beta, _ = loo_label_weight(B, labelled, r, zero_score=None if loo is None else float((loo ** 2).sum()),
                                       noise=noise)
        self.beta_ = beta
        if beta == 0:  # 'auto' found the labels' residual to be noise: keep the base field
            Y = np.zeros_like(base if base is not None else X)
        else:
            Y = TangentSolver(B, labelled, beta, dense_map=False).solve(r)
        if base is not None:
            Y = base + Y
        if self.strategy == "marker":
            Y = Y.reshape(p, T, 3).transpose(1, 0, 2)
        else:
            Y = Y.reshape(T, p, 3)
        self.labelled_frames_ = lab
        self.result_ = np.ascontiguousarray(Y)
        return self

    def _base_map(self, S, lab, Yh, shared: bool | None = None):
        """The per-marker base map (affine, plus the kernel correction when asked) and its leave-one-out residuals.

        ``shared``: the selection rule (default: the one :meth:`fit` chose, ``select_``).
        """
        shared = getattr(self, "select_", self.select) == "shared" if shared is None else shared
        base, loo = marker_affine_fit(S, lab, Yh, self.ridge, return_loo=True,
                                      pool=POOL_SIZES if self.pool else (), shared=shared)
        if self.kernel:
            corr, loo = marker_kernel_fit(S, lab, Yh - base[lab], loo, shared=shared)
            base = base + corr
        return base, loo

    def _frame_correction(self, S, lab, Yh, base, loo):
        """The whole-frame kernel correction of the base map, for clean labels only (:data:`CLEAN_LABELS_MAX_NOISE`).

        Applied once, on the source the labels chose: inside that choice its
        flexible fit made smoothed sources look better than they were.
        """
        if not self.kernel or not self._labels_clean(loo, Yh):
            return base, loo
        corr, loo = frame_kernel_fit(S, lab, Yh - base[lab], loo, shared=self.select_ == "shared")
        return base + corr, loo

    def _labels_clean(self, loo, Yh) -> bool:
        """Whether the labels' noise (``label_noise``, or estimated) is small against the held-out residuals ``loo``."""
        noise = self.label_noise
        if noise == "auto":
            noise = label_noise_estimate(loo, Yh.mean(axis=0))
        return noise is not None and bool(noise ** 2 < CLEAN_LABELS_MAX_NOISE * float((loo ** 2).mean()))

    def _choose_smoothing(self, S, lab, Yh):
        """Source smoothing chosen by the labels: none, a tenth of the GCV weight, or the GCV weight.

        GCV on the capture alone cannot tell tracking jitter from fast real
        motion that the character shares (real takes are themselves jittery), so
        it over-smooths clean captures. The labels can: for each candidate the
        base map's leave-one-label-out error is computed (closed form, cheap),
        and the candidate whose map best predicts held-out labelled frames wins.
        Returns the smoothed source, the weight and the base map fitted on it.
        """
        best = None
        for S0 in (S, lowrank_denoise(S)):
            Sg, lam = whittaker_smooth(S0, "auto")
            for g, Sc in ((0.0, S0), (lam / 10.0, None), (lam, Sg)):
                if Sc is None:
                    Sc, _ = whittaker_smooth(S0, g)
                fit = self._base_map(Sc, lab, Yh)
                score = float((fit[1] ** 2).sum())
                if best is None or score < best[0]:
                    best = (score, Sc, g, fit)
        return best[1], best[2], best[3]

    def transform(self) -> np.ndarray:
        """Return the character sequence computed by :meth:`fit`.

        Returns
        -------
        (T, p, 3) float64
            A copy of ``result_`` (the labelled frames exact when ``beta`` is None).

        Raises
        ------
        NotFittedError
            Called before :meth:`fit` (an :class:`~facegeom.errors.InputError`).
        """
        check_fitted(self, "result_")
        return self.result_.copy()


LAMBDA_GRID = tuple(10.0 ** np.arange(-2, 4.01, 0.5))


def whittaker_smooth(S: np.ndarray, lam: float | str = "auto", grid=LAMBDA_GRID) -> tuple[np.ndarray, float]:
    """Temporal Whittaker smoother of a marker sequence ``(T, p, 3)``.

    Solves ``(I + lam D2^T D2) X = S`` for every coordinate (``D2`` the second
    difference). ``lam="auto"`` picks one ``lam`` for the whole sequence from
    ``grid`` by generalised cross-validation, ``|(I - H) S|^2 / (1 - tr H / T)^2``:
    tracking jitter is removed, fast real motion (a jaw opening in a few frames) kept.

    The matrix is pentadiagonal: every candidate costs one banded Cholesky
    factorization, one banded solve for all ``3p`` coordinates and the exact
    trace of ``H = (I + lam D2^T D2)^-1`` from the factor
    (:func:`~facegeom.linalg.banded_inverse_diagonal`), so time and memory are
    linear in ``T``.

    Parameters
    ----------
    S : (T, ...) float array
        The sequence, time first (e.g. ``(T, p, 3)``).
    lam : float or "auto"
        The weight, or ``"auto"`` for generalised cross-validation over ``grid``.
    grid : sequence of float
        Candidates of ``"auto"``.

    Returns
    -------
    X : float64 array, the shape of ``S``
        The smoothed sequence.
    lam : float
        The weight used.
    """
    S = np.asarray(S, dtype=np.float64)
    T = S.shape[0]
    if T < 3 or lam == 0:
        return S.copy(), 0.0
    Q = (second_difference(T).T @ second_difference(T)).tocsr()
    qband = np.zeros((3, T))  # upper banded storage: qband[2 - o, o:] = diagonal o of Q
    for o in range(3):
        qband[2 - o, o:] = Q.diagonal(o)
    flat = S.reshape(T, -1)

    def factor(g):
        ab = g * qband
        ab[2] += 1.0
        return cholesky_banded(ab, lower=False, check_finite=False)

    if lam == "auto":
        factors = np.stack([factor(g) for g in grid])  # (G, 3, T)
        traces = banded_inverse_diagonal(factors).sum(axis=1)  # tr H per candidate, one pass for all
        best, lam, X = np.inf, grid[0], None
        for g, U, trace in zip(grid, factors, traces):
            Xg = cho_solve_banded((U, False), flat, check_finite=False)
            score = float(((flat - Xg) ** 2).sum()) / (1.0 - trace / T) ** 2
            if score < best:
                best, lam, X = score, float(g), Xg
    else:
        X = cho_solve_banded((factor(float(lam)), False), flat, check_finite=False)
    return X.reshape(S.shape), float(lam)


def lowrank_denoise(S: np.ndarray) -> np.ndarray:
    """Remove white capture noise from a marker sequence by hard-thresholding its singular values across markers.

    A face's markers move together (a few dozen expressions drive every
    marker), so the centred ``(T, 3p)`` matrix of a capture is nearly low rank
    while tracking noise spreads over every singular value. The threshold is
    Gavish and Donoho's optimal hard threshold for unknown noise level,
    ``omega(beta) * median(singular values)`` with ``beta`` the aspect ratio
    (their cubic approximation of ``omega``): no parameter to tune, and a clean
    capture keeps essentially all of its energy.

    Parameters
    ----------
    S : (T, ...) float array
        The sequence, time first.

    Returns
    -------
    float64 array, the shape of ``S``
        The denoised sequence (``S`` itself, copied, when it has fewer than 3 frames).
    """
    S = np.asarray(S, dtype=np.float64)
    T = S.shape[0]
    X = S.reshape(T, -1)
    if T < 3 or X.shape[1] < 3:
        return S.copy()
    mean = X.mean(axis=0)
    Xc = X - mean
    wide = Xc.shape[0] <= Xc.shape[1]  # eigenvectors of the smaller Gram matrix (much cheaper than an SVD)
    ev, V = np.linalg.eigh(Xc @ Xc.T if wide else Xc.T @ Xc)
    sv = np.sqrt(np.maximum(ev, 0.0))
    beta = min(X.shape) / max(X.shape)
    omega = 0.56 * beta ** 3 - 0.95 * beta ** 2 + 1.82 * beta + 1.43
    Vk = V[:, sv > omega * np.median(sv)]
    out = Vk @ (Vk.T @ Xc) if wide else (Xc @ Vk) @ Vk.T
    return (mean + out).reshape(S.shape)
