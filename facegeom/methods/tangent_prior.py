"""A marker prior with spatially varying amplitude for the self-tuned tangent deformer.

The ``beta="auto"`` smoother (``prior="uniform"``, the default) treats the markers' displacements as one
Gaussian field of prior covariance ``K^+`` (``K`` the labels' energy): every
marker's displacement is assumed equally large, so markers in still regions
(forehead, nose, temples) keep their noise. :class:`AmplitudeSmoother` models
the displacements as ``f = c 1 + A g`` with ``g ~ N(0, K^+)``, ``A = diag(a)``
a per-marker amplitude estimated from the markers themselves, ``c`` a free
constant (the energy's null space) and white marker noise. The posterior mean
is ``f = (I + lam Q)^-1 y`` with ``Q = P^T A^-1 K A^-1 P`` (``P`` removes the
free constant, see :meth:`AmplitudeSmoother._penalty`); ``lam`` is chosen by generalised
cross-validation over the spectrum of ``Q``, evaluated without its eigenvectors: one reduction of ``Q`` to
tridiagonal form ``Q = H T H^T`` per frame (``M`` markers), then every candidate's trace and residual from
tridiagonal factorizations of ``I + lam T`` (see :meth:`AmplitudeSmoother.smooth_many`); 2-3x faster than the
``(M, M)`` symmetric eigendecomposition per frame it replaced (40-120 markers, one thread), with the same result.

The amplitude: ``a = (G r + eps mean(r))^gamma`` normalised to mean 1, with
``r`` the lengths of the displacements after the default GCV smoothing and
``G`` a row-normalised Gaussian of the markers' rest distances (width
:data:`AMPLITUDE_WIDTH` times the markers' RMS distance from their
centroid). Everything here depends on the displacements only through
their lengths, so a rigid motion of all markers (zero displacements after
the alignment) still moves the face rigidly.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg.blas import dsyr2, dtbsv
from scipy.linalg.lapack import dormqr, dptsv, dpttrf, dsytrd

#: Width of the Gaussian that spreads the markers' displacement lengths over their neighbours, relative to the
#: markers' RMS distance from their centroid (so the prior does not depend on units): 0.27 is 2 cm on the ICT face
#: (RMS radius 7.0-8.2 cm for 40-120 random markers), chosen on seed 0 of the realistic protocol, where 1.5-3 cm
#: gave the same error within 1 %.
AMPLITUDE_WIDTH = 0.27

#: Exponent of the amplitude: 1.5 on seed 0 (1: 1 % worse at 0.5 mm noise, 2: 0.3 % worse).
AMPLITUDE_POWER = 1.5

#: Floor of the smoothed lengths, relative to their mean, so a marker that does not move keeps some prior variance
#: (0.03-0.1 gave the same error within 0.2 % on seed 0; 0.3: 1 % worse).
AMPLITUDE_FLOOR = 0.1

#: Negative eigenvalues of ``Q`` (relative to its mean eigenvalue) that the tridiagonal path may leave unclipped:
#: an ``(M, M)`` eigendecomposition clips its negative eigenvalues to 0, the tridiagonal path never sees them; below
#: this (an indefinite ``Q``) a frame takes the eigendecomposition, so the clipping stays exact. With a semi-definite
#: ``K`` they are rounding, ~1e-16 (the deformer's ``K = U diag(k) U^T``, ``k >= 0``, on the ICT face). One left
#: unclipped moves ``sum g`` by at most itself, against ``sum g >= 1 / (1 + lam)`` (some eigenvalue is >= the mean 1):
#: at most 1e-9 relative for ``lam <= 1000``.
_NEGATIVE_TOLERANCE = 1e-12

#: Rows (frames x candidates x markers) of the block-tridiagonal system that :meth:`AmplitudeSmoother.smooth_many`
#: solves at once: ~1 MB of right-hand sides, solutions and factors, which stays in cache (3,000-50,000 measured
#: within the noise at 40-120 markers).
_CHUNK_ROWS = 12_000


class AmplitudeSmoother:
    """Posterior mean of the markers' displacements under a prior of per-marker amplitude (see the module).

    Parameters
    ----------
    K : (M, M) float
        The labels' energy (symmetric positive semi-definite; constants in its null space).
    points : (M, 3) float
        The markers' rest positions (for the spatial smoothing of the amplitude).
    lambdas : (L,) float
        Candidate regularisations relative to the mean eigenvalue of ``Q``; 0 = exact interpolation.
    width, power, floor : float
        ``width`` relative to the markers' RMS distance from their centroid.
        See :data:`AMPLITUDE_WIDTH`, :data:`AMPLITUDE_POWER`, :data:`AMPLITUDE_FLOOR`.
    """

    def __init__(self, K: np.ndarray, points: np.ndarray, lambdas: np.ndarray, width: float = AMPLITUDE_WIDTH,
                 power: float = AMPLITUDE_POWER, floor: float = AMPLITUDE_FLOOR):
        self.K = np.array(K, dtype=np.float64)
        P = np.asarray(points, dtype=np.float64)
        D2 = ((P[:, None, :] - P[None, :, :]) ** 2).sum(axis=-1)
        w2 = (width * width) * max(float(((P - P.mean(axis=0)) ** 2).sum(axis=1).mean()), 1e-300)
        G = np.exp(-D2 / (2.0 * w2))
        self.G = G / G.sum(axis=1, keepdims=True)
        self.lambdas = np.asarray(lambdas, dtype=np.float64)
        self.power, self.floor = float(power), float(floor)

    def _penalty(self, w: np.ndarray) -> np.ndarray:
        """The prior's energy of the displacements ``f`` for weights ``w = 1 / a``: ``P^T W K W P``.

        ``f = c 1 + A g`` with ``g`` orthogonal to the constants (``K``'s null
        space): ``g = W P f`` with ``P = I - 1 w^T / sum(w)`` (the constant
        ``c = w^T f / sum(w)`` is free, and only it: the amplitude pattern ``a``
        itself is penalised). ``W K W 1 = W K (w - mean(w))`` because
        ``K 1 = 0``: computed from the centred ``w``, or rounding in ``K 1``
        would dominate when the amplitude is nearly uniform.
        """
        Q = w[:, None] * self.K * w[None, :]
        v = w - w.mean()
        Kv = self.K @ v
        q = w * Kv  # Q 1
        s = w.sum()
        u = w / s
        # P^T Q P = Q - q u^T - u q^T + (1^T Q 1) u u^T
        return Q - np.outer(q, u) - np.outer(u, q) + float(v @ Kv) * np.outer(u, u)

    def amplitude(self, F0: np.ndarray) -> np.ndarray:
        """Per-marker amplitudes ``(T, M)`` (mean 1 per frame) from first smoothed displacements ``F0 (T, M, 3)``."""
        r = np.sqrt(np.einsum("tmi,tmi->tm", F0, F0))
        s = r @ self.G.T + self.floor * r.mean(axis=1, keepdims=True)
        s = np.where(s > 0, s, 1.0) ** self.power
        return s / s.mean(axis=1, keepdims=True)

    def smooth_many(self, Y: np.ndarray, F0: np.ndarray, score0: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Smoothed displacements ``(T, M, 3)`` of raw ones ``Y (T, M, 3)``, the ``lam`` per frame, which were smoothed.

        ``F0`` are the same frames after the default smoothing (they set the
        amplitude). ``score0 (T,)``: the default smoothing's GCV score per frame
        (``M ||(I - S) y||^2 / (M - tr S)^2``, comparable across priors); a frame
        keeps ``F0`` (third output ``False``) where the amplitude prior's best
        score is not lower — so clean markers the default interpolates exactly
        stay exact unless this prior predicts them better.

        Per frame, with ``mu`` the eigenvalues of ``Q`` (clipped at 0) scaled to
        mean 1 and ``g = mu / (1 + lam mu)``: ``GCV(lam) = M sum g^2 |z|^2 /
        (sum g)^2`` (``z`` the frame in ``Q``'s eigenbasis), and the result is
        ``(I + lam Q / scale)^-1 y`` at the best ``lam``. Computed without the
        eigenbasis: ``Q = H T H^T`` (Householder, ``T`` tridiagonal;
        :meth:`_tridiagonal_many`), then ``sum g = tr(T (I + lam T)^-1)`` and
        ``sum g^2 |z|^2 = ||T (I + lam T)^-1 H^T y||^2`` for every candidate
        and frame of a chunk from one block-tridiagonal factorization
        (:meth:`_candidates_many`). Equal to the eigendecomposition
        (:meth:`_smooth_frame_eigh`) to rounding; frames whose ``Q`` has no
        positive trace or is not numerically semi-definite (where the clipping
        would matter) take the eigendecomposition itself.
        """
        T, m = Y.shape[:2]
        out = np.array(F0, dtype=np.float64)
        lam_out = np.zeros(T)
        used = np.zeros(T, dtype=bool)
        w = 1.0 / self.amplitude(F0)  # (T, M)
        lam = self.lambdas
        eigh = np.ones(T, dtype=bool)  # frames left to the eigendecomposition
        if m >= 3 and lam.size:
            Kt = np.ascontiguousarray(self.K.T)
            x, u = self._rank2(w)
            chunk = max(1, _CHUNK_ROWS // (lam.size * m))  # frames whose candidates are solved together
            for c0 in range(0, T, chunk):
                c1 = min(T, c0 + chunk)
                refl, d, e, Z, ok = self._tridiagonal_many(w[c0:c1], x[c0:c1], u[c0:c1], Kt,
                                                           np.asarray(Y[c0:c1], dtype=np.float64))
                g = np.flatnonzero(ok)
                if g.size < ok.size:
                    d, e, Z = d[g], e[g], Z[g]
                parts = [(g, self._candidates_many(d, e, Z))] if g.size else []
                if g.size > 1 and parts[0][1] is None:  # a failed factorization (e.g. negative lambdas): find it
                    parts = [(g[n:n + 1], self._candidates_many(d[n:n + 1], e[n:n + 1], Z[n:n + 1]))
                             for n in range(g.size)]
                for g, cand in parts:
                    if cand is None:
                        continue
                    X, sg, r = cand
                    score = m * r / sg ** 2  # (frames, L): GCV per candidate, as in _smooth_frame_eigh
                    best = np.argmin(score, axis=1)
                    for n, j in enumerate(g):
                        i = c0 + j
                        eigh[i] = False
                        if score0 is not None and not score[n, best[n]] < score0[i]:
                            continue
                        out[i] = self._apply_h(refl[j], X[:, n, best[n]].T)
                        lam_out[i], used[i] = lam[best[n]], True
        for i in np.flatnonzero(eigh):
            res = self._smooth_frame_eigh(w[i], Y[i], None if score0 is None else score0[i])
            if res is not None:
                out[i], lam_out[i] = res
                used[i] = True
        return out, lam_out, used

    def _smooth_frame_eigh(self, w: np.ndarray, y: np.ndarray, score0) -> tuple[np.ndarray, float] | None:
        """One frame of :meth:`smooth_many` by an eigendecomposition of ``Q``: ``(f, lam)``, or None (not smoothed)."""
        m, lam = y.shape[0], self.lambdas
        mu, V = np.linalg.eigh(self._penalty(w))
        mu = np.clip(mu, 0.0, None)
        scale = mu.mean()
        if not scale > 0:
            return None
        mu /= scale
        z = V.T @ y
        zz = np.einsum("mi,mi->m", z, z)
        # GCV(lam) = M ||(I - S) y||^2 / (M - tr S)^2 = M sum g^2 |z|^2 / (sum g)^2, g = mu / (1 + lam mu)
        g = mu[None, :] / (1.0 + lam[:, None] * mu[None, :])  # (L, M)
        score = m * ((g * g) @ zz) / g.sum(axis=1) ** 2
        best = int(np.argmin(score))
        if score0 is not None and not score[best] < score0:
            return None
        return V @ (z / (1.0 + lam[best] * mu)[:, None]), float(lam[best])

    def _rank2(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``x, u (T, M)`` with ``Q = W K W - x u^T - u x^T`` per frame (weights ``w (T, M)``; see :meth:`_penalty`).

        ``x = q - (1^T Q 1 / 2) u``: :meth:`_penalty`'s three outer products as one symmetric rank-2 update.
        """
        v = w - w.mean(axis=1, keepdims=True)
        Kv = v @ self.K.T  # K v per frame
        u = w / w.sum(axis=1, keepdims=True)
        return w * Kv - (0.5 * np.einsum("cm,cm->c", v, Kv))[:, None] * u, u

    def _tridiagonal_many(self, w: np.ndarray, x: np.ndarray, u: np.ndarray, Kt: np.ndarray, Y: np.ndarray):
        """``Q = H T H^T`` of each frame's penalty (weights ``w (C, M)``, :meth:`_rank2`'s ``x, u``), ``T`` scaled
        to mean eigenvalue 1.

        Returns ``refl`` (per frame ``(reflectors, tau)``: ``H = diag(1, H')``, ``H'`` the product of the ``M - 1``
        Householder reflectors of LAPACK's lower ``dsytrd``, stored as a QR factorization's, applied by ``dormqr``),
        ``d (C, M)`` and ``e (C, M)`` the diagonal and off-diagonal of ``T / scale`` (``e[:, -1] = 0``), ``Z = H^T Y
        (C, M, k)`` and ``ok (C,)``: False where ``Q`` has no positive trace or an eigenvalue below
        ``-_NEGATIVE_TOLERANCE`` times its mean, or the frame is not finite (those frames take the
        eigendecomposition, which clips). ``Kt``: ``K.T`` C-contiguous.
        """
        C, m = w.shape
        lwork = m if m < 64 else 8 * m  # dsytrd's block size 8 above 64 markers: the fastest measured
        d, e, Z = np.empty((C, m)), np.zeros((C, m)), np.empty_like(Y)
        Z[:, 0] = Y[:, 0]
        ok = np.ones(C, dtype=bool)
        refl = []
        for j in range(C):
            A = w[j][:, None] * Kt
            A *= w[j]
            # A.T = W K W, Fortran-contiguous; the rank-2 part on its lower triangle only (all dsytrd reads)
            A = dsyr2(-1.0, x[j], u[j], lower=1, a=A.T, overwrite_a=1)
            c, d[j], e[j, :-1], tau, info = dsytrd(A, lower=1, lwork=lwork, overwrite_a=1)
            a = np.asfortranarray(c[1:, :-1])
            refl.append((a, tau))
            ok[j] = info == 0
            Z[j, 1:] = dormqr("L", "T", a, tau, Y[j, 1:], lwork=32 * Y.shape[2])[0]
        tr = d.sum(axis=1)  # the eigenvalues' sum
        ok &= (tr > 0) & np.isfinite(Z).all(axis=(1, 2))  # (a non-finite frame would spill into the next blocks)
        s = m / np.where(ok, tr, m)
        d *= s[:, None]
        e *= s[:, None]
        if not ok.all():  # frames left out: harmless values, as they share the factorizations below
            d[~ok], e[~ok] = 1.0, 0.0
        # Sylvester: T + tol I is positive definite (its factorization exists) iff no eigenvalue is below -tol
        if dpttrf((d + _NEGATIVE_TOLERANCE).ravel(), e.ravel()[:-1])[2] != 0:
            for j in np.flatnonzero(ok):  # the rare indefinite frame: find it
                ok[j] = dpttrf(d[j] + _NEGATIVE_TOLERANCE, e[j, :-1])[2] == 0
        return refl, d, e, Z, ok

    def _candidates_many(self, d: np.ndarray, e: np.ndarray, Z: np.ndarray):
        """Every candidate's ``X = (I + lam T)^-1 z (k, C, L, M)``, ``sum g`` and ``sum g^2 |z|^2 (C, L)``.

        ``d, e (C, M)``: ``T``'s diagonal and off-diagonal per frame (``e[:, -1] = 0``); ``Z (C, M, k)``: ``H^T y``.
        All ``C L`` blocks form one block-diagonal tridiagonal system: ``dptsv`` factors ``I + lam T = L D L^T``
        (multipliers ``l``, pivots ``D``) and solves. With ``S = (I + lam T)^-1``: ``S_ii = 1 / D_i + l_i^2
        S_{i+1,i+1}`` (positive terms; one bidiagonal solve, ``dtbsv``) and ``S_{i,i+1} = -l_i S_{i+1,i+1}``, so
        ``sum g = tr(T S)`` needs only these two diagonals. None if the factorization fails (then the caller goes
        frame by frame, and a frame that still fails takes the eigendecomposition).
        """
        lam = self.lambdas
        (C, m), L, k = d.shape, lam.size, Z.shape[2]
        n = C * L * m
        D = (lam[None, :, None] * d[:, None, :]).ravel()  # the blocks of I + lam T
        D += 1.0
        E = (lam[None, :, None] * e[:, None, :]).ravel()  # zero between blocks (e[:, -1] = 0)
        B = np.empty((k, C, L, m))
        B[...] = Z.transpose(2, 0, 1)[:, :, None, :]
        # B's (k, n) rows are the right-hand sides: its transpose is Fortran-contiguous. The factors overwrite D, E
        pf, lf, X, info = dptsv(D, E[:-1], B.reshape(k, n).T, overwrite_d=1, overwrite_e=1, overwrite_b=1)
        if info != 0:
            return None
        if not np.shares_memory(lf, E):
            E[:-1] = lf
        mult = E.reshape(C, L, m)  # the multipliers l_i (0 at a block's end)
        band = np.zeros((2, n), order="F")
        np.multiply(E[:-1], E[:-1], out=band[0, 1:])
        np.negative(band[0], out=band[0])
        np.divide(1.0, pf, out=pf)
        Sd = dtbsv(1, band, pf, diag=1, overwrite_x=1).reshape(C, L, m)  # s_i - l_i^2 s_{i+1} = 1 / D_i
        mult[..., :-1] *= Sd[..., 1:]  # -S_{i,i+1}
        # tr(T S) = sum_i T_ii S_ii + 2 sum_i T_{i,i+1} S_{i,i+1}
        sg = np.matmul(Sd, d[:, :, None])[..., 0] - 2.0 * np.matmul(mult, e[:, :, None])[..., 0]
        X = X.T.reshape(k, C, L, m)  # C-contiguous
        R = X * d[:, None, :]  # T X per block and column
        T1 = X[..., 1:] * e[:, None, :-1]
        R[..., :-1] += T1
        R[..., 1:] += np.multiply(X[..., :-1], e[:, None, :-1], out=T1)
        return X, sg, np.einsum("kclm,kclm->cl", R, R)

    @staticmethod
    def _apply_h(refl, x: np.ndarray) -> np.ndarray:
        """``H x`` for ``x (M, k)`` (``refl``: one frame's reflectors and ``tau`` from :meth:`_tridiagonal_many`)."""
        a, tau = refl
        f = np.empty_like(x)
        f[0] = x[0]
        f[1:] = dormqr("L", "N", a, tau, x[1:], lwork=32 * max(x.shape[1], 1))[0]
        return f

    def smooth(self, y: np.ndarray, f0: np.ndarray, score0: float | None = None) -> tuple[np.ndarray, float, bool]:
        """:meth:`smooth_many` of one frame: ``y, f0 (M, 3)`` -> smoothed ``(M, 3)``, ``lam``, whether smoothed."""
        F, lam, used = self.smooth_many(y[None], f0[None], None if score0 is None else np.array([score0]))
        return F[0], float(lam[0]), bool(used[0])

    def candidates(self, y: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Every candidate's smoothed displacements ``(L, M, 3)`` for one frame ``y (M, 3)`` and amplitudes ``a (M,)``.

        For studies (an oracle over ``lam``, or amplitudes from the truth); the
        deformer uses :meth:`smooth`. Computed as in :meth:`smooth_many` (the
        eigendecomposition where that takes it).
        """
        y = np.asarray(y, dtype=np.float64)
        w = 1.0 / np.asarray(a, dtype=np.float64)
        m, L = y.shape[0], self.lambdas.size
        if m >= 3 and L:
            x, u = self._rank2(w[None])
            refl, d, e, Z, ok = self._tridiagonal_many(w[None], x, u, np.ascontiguousarray(self.K.T), y[None])
            cand = self._candidates_many(d, e, Z) if ok[0] else None
            if cand is not None:
                X = cand[0][:, 0]  # (k, L, M)
                k = X.shape[0]
                f = self._apply_h(refl[0], X.transpose(2, 1, 0).reshape(m, L * k))  # all candidates at once
                return f.reshape(m, L, k).transpose(1, 0, 2)
        mu, V = np.linalg.eigh(self._penalty(w))
        mu = np.clip(mu, 0.0, None)
        mu /= mu.mean() if mu.mean() > 0 else 1.0
        z = V.T @ y
        keep = 1.0 / (1.0 + self.lambdas[:, None] * mu[None, :])  # (L, M)
        return np.einsum("ij,lj,jd->lid", V, keep, z)
