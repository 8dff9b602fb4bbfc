"""Retargeting baselines: copy-motion reference, RBF maps and the temporal Laplacian method."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import RBFInterpolator

from facegeom.baselines.rbf import KERNELS
from facegeom.errors import InputError
from facegeom.interfaces import Params, check_fitted, check_range
from facegeom.methods.tangent import TangentSolver
from facegeom.methods.tangent_retarget import check_retarget_inputs, temporal_windows

__all__ = ["CopyRetargeter", "RBFRetargeter", "LaplacianRetargeter"]


class CopyRetargeter(Params):
    """Reference: the actor's motion copied onto the character.

    ``Y_t = X_t + o`` with the per-marker offset ``o`` (character minus actor)
    averaged over the labelled frames: the actor's motion, unchanged, placed on
    the character's markers.
    """

    def __init__(self):
        self.result_ = None

    def fit(self, source, labelled_frames, target_labels) -> "CopyRetargeter":
        """Place the actor's motion on the character: ``Y_t = X_t + o``, stored in ``result_``.

        ``o (p, 3)`` is the mean over the labelled frames of
        ``target_labels - source[labelled_frames]``.

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
        """
        S, lab, Yh = check_retarget_inputs(source, labelled_frames, target_labels)
        offset = (Yh - S[lab]).mean(axis=0)
        self.result_ = S + offset[None]
        return self

    def transform(self) -> np.ndarray:
        """Return the character sequence computed by :meth:`fit`.

        Returns
        -------
        (T, p, 3) float64
            A copy of ``result_``.

        Raises
        ------
        NotFittedError
            Called before :meth:`fit` (an :class:`~facegeom.errors.InputError`).
        """
        check_fitted(self, "result_")
        return self.result_.copy()


def _principal_frame(P: np.ndarray, rel_tol: float, abs_tol: float):
    """Centre, axes (r, D) and scale of the significant principal directions of ``P (L, D)``."""
    c = P.mean(axis=0)
    U, s, Vt = np.linalg.svd(P - c, full_matrices=False)
    if s.size == 0 or s[0] <= abs_tol:
        return c, Vt[:0], 1.0
    r = int(((s > rel_tol * s[0]) & (s > abs_tol)).sum())
    scale = s[0] / np.sqrt(P.shape[0])
    return c, Vt[:r], scale


class RBFRetargeter(Params):
    """Scattered-data map from actor marker positions to character marker positions.

    Trained on the labelled frames with scipy's :class:`~scipy.interpolate.RBFInterpolator`
    and applied to every frame.

    Parameters
    ----------
    strategy : {"marker", "frame"}
        ``marker``: one map per marker, from its 3-D position to the character's
        (the strong baseline); ``frame``: one map from the whole frame (``3p``
        numbers) to the character's frame.
    kernel : str
        An RBFInterpolator kernel; ``linear`` by default (no shape parameter).
    degree : int
        Degree of the added polynomial (1 = affine part, exact for affine maps).
    smoothing : float
        Smoothing of the fit, relative to the (normalised) inputs.
    rel_tol : float
        Inputs are expressed in their own principal axes, keeping the directions
        whose singular value exceeds ``rel_tol`` times the largest and scaled to
        unit spread: a marker that barely moves, or moves along a line or in a
        plane over the labelled frames, gets a well-posed map in the dimensions
        it actually spans instead of a singular system. A marker that does not
        move at all (spread at most ``1e-6`` times the whole sequence's spread:
        rounding noise) gets a constant map.
    """

    def __init__(self, strategy: str = "marker", kernel: str = "linear", degree: int = 1,
                 smoothing: float = 1e-8, rel_tol: float = 1e-3):
        if strategy not in ("marker", "frame"):
            raise InputError(f"strategy must be 'marker' or 'frame', got {strategy!r}")
        smoothing = check_range("smoothing", smoothing, 0, 1e6, "beyond it only the polynomial part is left")
        degree = check_range("degree", degree, -1, 3, "a degree-d polynomial in 3-D has (d+1)(d+2)(d+3)/6 terms: "
                             "3 needs 20 markers already", integer=True)
        if not isinstance(kernel, str) or kernel not in KERNELS:
            raise InputError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
        rel_tol = check_range("rel_tol", rel_tol, 0, 1, "relative to the largest singular value")
        self.strategy, self.kernel, self.degree = strategy, kernel, int(degree)
        self.smoothing, self.rel_tol = float(smoothing), float(rel_tol)
        self.result_ = None

    def _map(self, P_train, Q_train, P_all, abs_tol):
        c, axes, scale = _principal_frame(P_train, self.rel_tol, abs_tol)
        if axes.shape[0] == 0:
            return np.broadcast_to(Q_train.mean(axis=0), (P_all.shape[0], Q_train.shape[1])).copy()
        Z_train = (P_train - c) @ axes.T / scale
        Z_all = (P_all - c) @ axes.T / scale
        degree = self.degree
        # the polynomial needs at least (r + 1) points for degree 1; fall back to constants
        if degree >= 1 and P_train.shape[0] < axes.shape[0] + 1 + 1:
            degree = 0
        try:
            f = RBFInterpolator(Z_train, Q_train, kernel=self.kernel, degree=degree, smoothing=self.smoothing)
        except ValueError as exc:  # e.g. a kernel that needs epsilon
            raise InputError(f"RBF retargeting: {exc}") from None
        return f(Z_all)

    def fit(self, source, labelled_frames, target_labels) -> "RBFRetargeter":
        """Train the RBF map(s) on the labelled frames and apply them to every frame (stored in ``result_``).

        ``strategy="marker"``: one map per marker, from its 3-D positions to the
        character's; ``"frame"``: one map from the whole frame (``3p`` numbers).
        Inputs are expressed in their significant principal axes (``rel_tol``, with
        an absolute floor of ``1e-6`` times the sequence's RMS spread times
        ``sqrt(L)``); an input that does not move maps to the mean of its labels,
        and the polynomial falls back to degree 0 when there are too few labelled
        frames for an affine part.

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
            out-of-range frame ids, or a kernel ``RBFInterpolator`` rejects (e.g. one that needs ``epsilon``).
        """
        S, lab, Yh = check_retarget_inputs(source, labelled_frames, target_labels)
        T, p, _ = S.shape
        spread = float(np.sqrt(((S - S.mean(axis=(0, 1))) ** 2).sum(axis=2).mean()))
        abs_tol = 1e-6 * spread * np.sqrt(lab.size)
        if self.strategy == "frame":
            Y = self._map(S[lab].reshape(lab.size, -1), Yh.reshape(lab.size, -1), S.reshape(T, -1), abs_tol)
            self.result_ = Y.reshape(T, p, 3)
        else:
            Y = np.empty_like(S)
            for j in range(p):
                Y[:, j] = self._map(S[lab, j], Yh[:, j], S[:, j], abs_tol)
            self.result_ = Y
        return self

    def transform(self) -> np.ndarray:
        """Return the character sequence computed by :meth:`fit`.

        Returns
        -------
        (T, p, 3) float64
            A copy of ``result_``.

        Raises
        ------
        NotFittedError
            Called before :meth:`fit` (an :class:`~facegeom.errors.InputError`).
        """
        check_fitted(self, "result_")
        return self.result_.copy()


class LaplacianRetargeter(Params):
    """Temporal Laplacian editing: keep the actor's differential coordinates in time.

    Every marker trajectory keeps its temporal differential coordinates
    ``delta_t = x_t - mean(x_{t-w..t+w} without t)`` while the labelled frames are
    met exactly: ``min ||L Y - L X||^2`` subject to ``Y[labels] = Y_hat``. The
    solution is the actor's motion plus an offset field that is biharmonic in
    time and interpolates the label offsets.

    Parameters
    ----------
    window : int
        Neighbours on each side in the temporal Laplacian.
    """

    def __init__(self, window: int = 1):
        self.window = check_range("window", window, 1, 1000, "frames on each side: 1000 is 40 s at 25 fps",
                                  integer=True)
        self.result_ = None

    def fit(self, source, labelled_frames, target_labels) -> "LaplacianRetargeter":
        """Add to the actor's motion the offset field, smooth in time, that meets the labelled frames exactly.

        Minimises ``||L Y - L X||^2`` (``X`` the source) with ``Y = Y_hat`` on the labelled
        frames. Builds the temporal Laplacian ``L = I - D^-1 A`` (``A``: the ``window``
        frames on each side, clipped at the ends), factorizes ``L^T L`` with the
        labelled frames as hard constraints and solves once for the offsets
        ``target_labels - source[labelled_frames]`` of all ``3p`` coordinates;
        ``result_ = source + offsets``.

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
        A = temporal_windows(T, self.window).astype(np.float64)
        A.setdiag(0.0)
        A.eliminate_zeros()
        deg = np.asarray(A.sum(axis=1)).ravel()
        L = sp.identity(T, format="csr") - sp.diags(1.0 / deg) @ A
        solver = TangentSolver((L.T @ L).tocsr(), lab, None, dense_map=False)
        Z = solver.solve((Yh - S[lab]).reshape(lab.size, 3 * p))
        self.result_ = S + Z.reshape(T, p, 3)
        return self

    def transform(self) -> np.ndarray:
        """Return the character sequence computed by :meth:`fit`.

        Returns
        -------
        (T, p, 3) float64
            A copy of ``result_``.

        Raises
        ------
        NotFittedError
            Called before :meth:`fit` (an :class:`~facegeom.errors.InputError`).
        """
        check_fitted(self, "result_")
        return self.result_.copy()
