"""Expression retargeting with the tangent framework (paper sections 3.2, 4.1, 4.2).

Data points are the frames of the actor's marker sequence, the local structure
of a frame is a temporal window (the frame and ``window`` frames before and
after, clipped at the ends), the labels are a few known frames of the
character. The alignment matrix and the solve are those of
:mod:`facegeom.tangent` (no second copy).

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

from .errors import InputError
from .interfaces import as_handles, as_sequence, check_fitted
from .tangent import TangentSolver, alignment_matrix


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
    return S, lab, np.ascontiguousarray(Yh)


def marker_affine_fit(S, lab, Yh, ridge: float = 1e-4) -> np.ndarray:
    """Per-marker affine least-squares map actor -> character fitted on the labelled frames.

    Ridge-regularised (``ridge`` times the largest squared singular value of the
    centred labelled positions), so markers that barely move get the mean offset.
    Returns the map applied to every frame, ``(T, p, 3)``.
    """
    P = S[lab]  # (L, p, 3)
    cP, cY = P.mean(axis=0), Yh.mean(axis=0)  # (p, 3)
    Pc, Yc = P - cP, Yh - cY
    C = np.einsum("lpi,lpj->pij", Pc, Pc)  # (p, 3, 3)
    Cy = np.einsum("lpi,lpj->pij", Pc, Yc)
    lam = ridge * np.linalg.eigvalsh(C)[:, -1] + 1e-30
    A = np.linalg.solve(C + lam[:, None, None] * np.eye(3), Cy)  # (p, 3, 3): Y = cY + (x - cP) @ A
    return cY[None] + np.einsum("tpi,pij->tpj", S - cP[None], A)


class TangentRetargeter:
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
    beta : float or None
        Label weight of eq. 18; ``None`` = hard constraints (labelled frames exact).
    field : {"position", "offset"}
        ``position`` (the paper): the unknown is the character's sequence ``Y``.
        ``offset``: the unknown is ``Y - X`` (character minus actor), asked to be
        locally an affine map of the actor's tangent coordinates.
    smoothness : float
        Weight of an added temporal second-difference energy on the unknown,
        relative to ``B`` after both are scaled to the same trace; ``0`` = the
        framework alone.
    """

    def __init__(self, strategy: str = "frame", window: int = 3, d: int = 3, beta: float | None = None,
                 field: str = "affine", smoothness: float = 0.1, rank_tol: float = 1e-6,
                 ridge: float = 1e-4):
        if strategy not in ("marker", "frame"):
            raise InputError(f"strategy must be 'marker' or 'frame', got {strategy!r}")
        if int(window) != window or window < 1:
            raise InputError(f"window must be a positive integer, got {window!r}")
        if int(d) != d or d < 1:
            raise InputError(f"d must be a positive integer, got {d!r}")
        if beta is not None and (not np.isfinite(beta) or beta <= 0):
            raise InputError(f"beta must be a positive number or None (hard constraints), got {beta!r}")
        if field not in ("position", "offset", "affine"):
            raise InputError(f"field must be 'position', 'offset' or 'affine', got {field!r}")
        if not np.isfinite(smoothness) or smoothness < 0:
            raise InputError(f"smoothness must be a non-negative number, got {smoothness!r}")
        self.strategy, self.window, self.d, self.beta = strategy, int(window), int(d), beta
        if not np.isfinite(ridge) or ridge < 0:
            raise InputError(f"ridge must be a non-negative number, got {ridge!r}")
        self.field, self.smoothness, self.rank_tol = field, float(smoothness), float(rank_tol)
        self.ridge = float(ridge)
        self.result_ = None

    def get_params(self) -> dict:
        return {k: getattr(self, k) for k in ("strategy", "window", "d", "beta", "field", "smoothness", "rank_tol", "ridge")}

    def __repr__(self) -> str:
        return "TangentRetargeter(" + ", ".join(f"{k}={v!r}" for k, v in self.get_params().items()) + ")"

    def fit(self, source, labelled_frames, target_labels) -> "TangentRetargeter":
        S, lab, Yh = check_retarget_inputs(source, labelled_frames, target_labels)
        T, p, _ = S.shape
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
        base = None
        if self.field == "offset":
            base = S
        elif self.field == "affine":
            base = marker_affine_fit(S, lab, Yh, self.ridge)
        if base is not None:
            base = base.transpose(1, 0, 2).reshape(p * T, 3) if self.strategy == "marker" else base.reshape(T, 3 * p)
        if self.smoothness > 0 and D2.shape[0]:
            Q = (D2.T @ D2).tocsr()
            tb = B.diagonal().sum()
            B = (B + (self.smoothness * (tb if tb > 0 else 1.0) / Q.diagonal().sum()) * Q).tocsr()
        solver = TangentSolver(B, labelled, self.beta, dense_map=False)
        if base is not None:
            Y = base + solver.solve(labels - base[labelled])
        else:
            Y = solver.solve(labels)
        if self.strategy == "marker":
            Y = Y.reshape(p, T, 3).transpose(1, 0, 2)
        else:
            Y = Y.reshape(T, p, 3)
        self.labelled_frames_ = lab
        self.result_ = np.ascontiguousarray(Y)
        return self

    def transform(self) -> np.ndarray:
        check_fitted(self, "result_")
        return self.result_.copy()
