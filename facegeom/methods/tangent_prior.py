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
cross-validation in the eigenbasis of ``Q`` (one ``(M, M)`` symmetric
eigendecomposition per frame, ``M`` markers).

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
        """
        T, m = Y.shape[:2]
        out = np.array(F0, dtype=np.float64)
        lam_out = np.zeros(T)
        used = np.zeros(T, dtype=bool)
        w = 1.0 / self.amplitude(F0)  # (T, M)
        lam = self.lambdas
        for i in range(T):  # one eigendecomposition per frame (a loop: numpy's stacked eigh is slower)
            mu, V = np.linalg.eigh(self._penalty(w[i]))
            mu = np.clip(mu, 0.0, None)
            scale = mu.mean()
            if not scale > 0:
                continue
            mu /= scale
            z = V.T @ Y[i]
            zz = np.einsum("mi,mi->m", z, z)
            # GCV(lam) = M ||(I - S) y||^2 / (M - tr S)^2 = M sum g^2 |z|^2 / (sum g)^2, g = mu / (1 + lam mu)
            g = mu[None, :] / (1.0 + lam[:, None] * mu[None, :])  # (L, M)
            score = m * ((g * g) @ zz) / g.sum(axis=1) ** 2
            best = int(np.argmin(score))
            if score0 is not None and not score[best] < score0[i]:
                continue
            out[i] = V @ (z / (1.0 + lam[best] * mu)[:, None])
            lam_out[i], used[i] = lam[best], True
        return out, lam_out, used

    def smooth(self, y: np.ndarray, f0: np.ndarray, score0: float | None = None) -> tuple[np.ndarray, float, bool]:
        """:meth:`smooth_many` of one frame: ``y, f0 (M, 3)`` -> smoothed ``(M, 3)``, ``lam``, whether smoothed."""
        F, lam, used = self.smooth_many(y[None], f0[None], None if score0 is None else np.array([score0]))
        return F[0], float(lam[0]), bool(used[0])

    def candidates(self, y: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Every candidate's smoothed displacements ``(L, M, 3)`` for one frame ``y (M, 3)`` and amplitudes ``a (M,)``.

        For studies (an oracle over ``lam``, or amplitudes from the truth); the
        deformer uses :meth:`smooth`.
        """
        mu, V = np.linalg.eigh(self._penalty(1.0 / np.asarray(a, dtype=np.float64)))
        mu = np.clip(mu, 0.0, None)
        mu /= mu.mean() if mu.mean() > 0 else 1.0
        z = V.T @ y
        keep = 1.0 / (1.0 + self.lambdas[:, None] * mu[None, :])  # (L, M)
        return np.einsum("ij,lj,jd->lid", V, keep, z)
