"""Prefactorized sparse symmetric positive definite solves.

``factorize_spd(A)`` factors once and returns an object whose ``solve(b)`` only
back-substitutes. Backend: cholespy's sparse Cholesky (fastest back-substitution
measured here, see ``../shared/PLATFORM-NOTES.md``), falling back to scipy's
SuperLU when cholespy is missing or fails (e.g. the matrix is not positive
definite to working precision).
"""
from __future__ import annotations

import numpy as np

from facegeom.errors import SolveError
from facegeom.native import quiet_native

__all__ = ["SPDSolver", "banded_inverse_diagonal", "box_lsq", "box_qp_many", "dct_ortho", "factorize_solve_spd",
           "factorize_spd", "idct_ortho"]

try:  # optional fast backend
    from cholespy import CholeskySolverD, MatrixType
except Exception:  # pragma: no cover - exercised only where cholespy is absent
    CholeskySolverD = None


class SPDSolver:
    """A factorized sparse SPD matrix. Use :func:`factorize_spd` to build one.

    Attributes
    ----------
    n : int
        Size of the matrix.
    backend : str
        ``"cholespy"`` or ``"splu"``.
    """

    def __init__(self, n: int, backend: str, impl):
        """Wrap a backend's factor (done by :func:`factorize_spd`).

        Parameters
        ----------
        n : int
            Size of the factored ``(n, n)`` matrix.
        backend : {"cholespy", "splu"}
            The library that made ``impl``.
        impl : cholespy.CholeskySolverD or scipy.sparse.linalg.SuperLU
            The factor; :meth:`solve` calls its ``solve``.
        """
        self.n = n
        self.backend = backend
        self._impl = impl

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` by back-substitution.

        Parameters
        ----------
        b : (n,) or (n, r) float array
            One right-hand side or ``r`` of them (converted to contiguous float64).

        Returns
        -------
        x : float64 array, the shape of ``b``

        Raises
        ------
        ValueError
            ``b`` does not have ``n`` rows.
        """
        b = np.ascontiguousarray(b, dtype=np.float64)
        if b.shape[0] != self.n:
            raise ValueError(f"right-hand side has {b.shape[0]} rows, the matrix {self.n}")
        if self.backend == "cholespy":
            x = np.empty_like(b)
            self._impl.solve(b, x)
            return x
        return self._impl.solve(b)


#: With a caller's right-hand sides solved accurately, a random one may leave at most this relative residual:
#: rounding in a regular but ill-conditioned system (1.6e-6 for a temporal smoothness between labels 2,000 frames
#: apart), not a null space (a singular system leaves a fixed share of a random right-hand side, 0.4 for an
#: affine field pinned by one label).
ILL_CONDITIONED_RESIDUAL = 1e-3


def _check_solution(A, solver: SPDSolver, tol: float = 1e-6, probe=None, rhs=None):
    """A cheap probe: does the factor solve a system accurately? Returns ``(ok, x)``.

    ``b`` is random, not ``A @ x``: for a singular ``A`` it is (almost surely)
    outside the range, so no factor can give a small residual. ``probe``: the
    right-hand sides the caller will solve (``(n,)`` or ``(n, k)``); when they
    are solved to ``tol``, a random ``b`` need only be solved to
    :data:`ILL_CONDITIONED_RESIDUAL` (a regular system too ill-conditioned for
    an arbitrary right-hand side, still refused when singular). ``rhs``
    (``(n, k)``, optional): right-hand sides the caller solves now, solved in
    the same back-substitution as the random one (one pass over the factor, not
    two) and, without ``probe``, the probe themselves; ``x`` is their solution
    (None without ``rhs``).
    """
    def residual(b, y):
        if not np.all(np.isfinite(y)):
            return np.inf
        return float(np.linalg.norm(A @ y - b) / max(np.linalg.norm(b), 1e-300))

    n = A.shape[0]
    b = np.random.default_rng(0).standard_normal(n)
    x = None
    if rhs is None:
        y = solver.solve(b)
    else:  # the random column last: the caller's columns are grouped as in a solve of their own
        k = rhs.shape[1]
        both = np.empty((n, k + 1))
        both[:, :k] = rhs
        both[:, k] = b
        y = solver.solve(both)
        x, y = y[:, :k], y[:, k]
        if probe is None and np.any(rhs):
            probe = rhs
    rand = residual(b, y)
    if rand <= tol:
        return True, x
    if probe is None or not rand <= ILL_CONDITIONED_RESIDUAL:
        return False, x
    probe = np.asarray(probe, dtype=np.float64).reshape(n, -1)
    yp = x if probe is rhs else solver.solve(probe)
    return residual(probe, yp) <= tol, x


def factorize_spd(A, backend: str = "auto", probe=None) -> SPDSolver:
    """Factor the sparse symmetric positive definite matrix ``A`` once.

    Parameters
    ----------
    A : (n, n) scipy sparse matrix
        Symmetric positive definite.
    backend : {"auto", "cholespy", "splu"}
        ``auto`` tries cholespy and falls back to SuperLU.
    probe : (n,) or (n, k) array, optional
        Right-hand sides the caller will solve: when they are solved accurately, a regular matrix too
        ill-conditioned for an arbitrary right-hand side is accepted (e.g. a temporal smoothness between
        labels thousands of frames apart); a singular one is still refused.

    Returns
    -------
    SPDSolver

    Raises
    ------
    SolveError
        If the matrix is singular (no backend gives an accurate solution).
    """
    return _factorize(A, backend, probe, None)[0]


def factorize_solve_spd(A, b, backend: str = "auto", probe=None) -> tuple[SPDSolver, np.ndarray]:
    """:func:`factorize_spd` and the solution of ``A x = b``, with one back-substitution pass fewer.

    The factor's accuracy check solves a random right-hand side; here it is
    solved together with ``b`` (one multi-right-hand-side pass over the factor
    instead of two), and ``b`` is the check's ``probe`` unless one is given (or ``b`` is zero).
    ``x`` equals ``factorize_spd(A, backend, probe).solve(b)`` up to rounding.

    Parameters
    ----------
    A : (n, n) scipy sparse matrix
        Symmetric positive definite.
    b : (n,) or (n, k) float array
    backend, probe
        As for :func:`factorize_spd`.

    Returns
    -------
    solver : SPDSolver
    x : float64 array, the shape of ``b``

    Raises
    ------
    SolveError
        If the matrix is singular (no backend gives an accurate solution).
    """
    b = np.asarray(b, dtype=np.float64)
    if b.shape[0] != A.shape[0]:
        raise ValueError(f"right-hand side has {b.shape[0]} rows, the matrix {A.shape[0]}")
    s, x = _factorize(A, backend, probe, b.reshape(b.shape[0], -1))
    return s, x.reshape(b.shape)


def _factorize(A, backend: str, probe, rhs):
    """:func:`factorize_spd`, solving ``rhs (n, k)`` (or None) with the check: ``(solver, x)``."""
    import scipy.sparse as sp  # here: the dense helpers below (a solve's bounded refits) need no sparse import
    import scipy.sparse.linalg as spla

    A = sp.csr_matrix(A, dtype=np.float64)
    n = A.shape[0]
    if A.shape != (n, n):
        raise ValueError(f"matrix must be square, got {A.shape}")
    A.sum_duplicates()
    A.sort_indices()
    tried = []
    if backend in ("auto", "cholespy") and CholeskySolverD is not None:
        try:
            with quiet_native():
                impl = CholeskySolverD(
                    n,
                    A.indptr.astype(np.int32),
                    A.indices.astype(np.int32),
                    np.ascontiguousarray(A.data),
                    MatrixType.CSR,
                )
            s = SPDSolver(n, "cholespy", impl)
            ok, x = _check_solution(A, s, probe=probe, rhs=rhs)
            if ok:
                return s, x
            tried.append("cholespy (inaccurate factor)")
        except Exception as exc:  # noqa: BLE001 - any backend failure means: fall back
            tried.append(f"cholespy ({exc})")
    if backend in ("auto", "splu"):
        try:
            impl = spla.splu(A.tocsc())
            s = SPDSolver(n, "splu", impl)
            ok, x = _check_solution(A, s, probe=probe, rhs=rhs)
            if ok:
                return s, x
            tried.append("splu (inaccurate factor)")
        except RuntimeError as exc:
            tried.append(f"splu ({exc})")
    raise SolveError("the system matrix is singular or not positive definite; tried: " + "; ".join(tried))


def _dct_scale(N: int) -> np.ndarray:
    """The orthonormal DCT-II's row scale ``2 f_k``: ``f_0 = sqrt(1 / 4N)``, ``f_k = sqrt(1 / 2N)``."""
    f = np.full(N, 2.0 * np.sqrt(1.0 / (2.0 * N)))
    f[0] = 2.0 * np.sqrt(1.0 / (4.0 * N))
    return f


def dct_ortho(x) -> np.ndarray:
    """The orthonormal DCT-II of the columns of ``x (N, ...)`` (``scipy.fft.dct(x, 2, norm="ortho", axis=0)``).

    ``y_k = 2 f_k sum_n x_n cos(pi k (2n + 1) / 2N)``, by one complex FFT of
    length ``N`` of the samples reordered (the even ones, then the odd ones
    backwards: Makhoul, 1980). numpy's FFT: a command that smooths a few curves
    does not import ``scipy.fft`` (0.1-0.2 s). Equal to scipy's to a few ulps.
    """
    x = np.asarray(x, dtype=np.float64)
    N = x.shape[0]
    v = np.concatenate([x[0::2], x[1::2][::-1]], axis=0)
    turn = np.exp(-0.5j * np.pi * np.arange(N) / N).reshape((N,) + (1,) * (x.ndim - 1))
    scale = _dct_scale(N).reshape(turn.shape)
    return (np.fft.fft(v, axis=0) * turn).real * scale


def idct_ortho(y) -> np.ndarray:
    """The inverse of :func:`dct_ortho` (``scipy.fft.idct(y, 2, norm="ortho", axis=0)``), along axis 0."""
    y = np.asarray(y, dtype=np.float64)
    N = y.shape[0]
    shape = (N,) + (1,) * (y.ndim - 1)
    X = y / _dct_scale(N).reshape(shape)
    back = np.zeros_like(X)  # X_(N-k), X_N = 0
    back[1:] = X[1:][::-1]
    v = np.fft.ifft((X - 1j * back) * np.exp(0.5j * np.pi * np.arange(N) / N).reshape(shape), axis=0).real
    x = np.empty_like(v)
    h = (N + 1) // 2
    x[0::2], x[1::2] = v[:h], v[h:][::-1]
    return x


def banded_inverse_diagonal(U: np.ndarray) -> np.ndarray:
    """Diagonal of ``A^-1`` from the banded Cholesky factor of ``A`` (Takahashi's selected inversion), in O(n b^2).

    With ``A = U^T U`` (``U`` upper triangular with ``b`` super-diagonals), the
    inverse ``Z`` satisfies ``U Z = U^-T``, lower triangular with diagonal
    ``1 / U_ii``. Read row by row from the bottom, that gives the entries of
    ``Z`` inside the band of ``A`` from entries already known:
    ``Z_ij = -sum_k U_ik Z_kj / U_ii`` for ``0 < j - i <= b`` and
    ``Z_ii = (1 / U_ii - sum_k U_ik Z_ik) / U_ii`` (``k = i+1 .. i+b``). No
    entry outside the band is formed, so time and memory are linear in ``n``;
    the result is exact up to rounding (no sampling). The recursion is
    sequential: one Python loop over the rows, vectorised over a batch of
    ``G`` factors of the same size (e.g. the candidates of a grid search).

    Parameters
    ----------
    U : (b + 1, n) or (G, b + 1, n) float array
        Upper Cholesky factor(s) in LAPACK upper banded storage, as returned by
        :func:`scipy.linalg.cholesky_banded` with ``lower=False``:
        ``U[b + i - j, j] = U_ij`` for ``i <= j <= i + b``.

    Returns
    -------
    (n,) or (G, n) float64
        ``diag(A^-1)`` of each factor (its sum is the trace of the inverse).
    """
    U = np.asarray(U, dtype=np.float64)
    single = U.ndim == 2
    if single:
        U = U[None]
    G, b1, n = U.shape
    b = b1 - 1
    # sup[o][:, i] = U[i, i + o] (o = 0 .. b), zero past the end
    sup = np.zeros((b1, G, n))
    for o in range(b1):
        sup[o, :, : n - o] = U[:, b - o, o:]
    sup = np.ascontiguousarray(sup.transpose(2, 0, 1))  # (n, b + 1, G): one row's coefficients together
    out = np.empty((n, G))
    # below[a, o] = Z[i + 1 + a, i + 1 + a + o] for the b rows under row i (a ring of the last b rows)
    below = np.zeros((b, b1, G))
    for i in range(n - 1, -1, -1):
        u = sup[i]
        m = min(b, n - 1 - i)
        row = np.zeros((b1, G))  # row[o] = Z[i, i + o]
        for o in range(m, 0, -1):  # Z[i + k, i + o] = below[min(k, o) - 1, |o - k|]
            acc = sum(u[k] * (below[k - 1, o - k] if k <= o else below[o - 1, k - o]) for k in range(1, m + 1))
            row[o] = -acc / u[0]
        row[0] = (1.0 / u[0] - (u[1:m + 1] * row[1:m + 1]).sum(axis=0)) / u[0]
        out[i] = row[0]
        if b:
            below[1:] = below[:-1]
            below[0] = row
    return out[:, 0] if single else np.ascontiguousarray(out.T)


def box_lsq(A: np.ndarray, b: np.ndarray, upper: float, x0: np.ndarray | None = None, rounds: int = 50) -> np.ndarray:
    """``argmin |A x - b|`` over ``0 <= x <= upper``: the exact bounded least squares of a small dense problem.

    An active set on the upper bound around scipy's NNLS (Lawson-Hanson, compiled): the coefficients held at
    ``upper`` are moved to the right-hand side and NNLS solves the others; a coefficient NNLS puts above the
    bound joins the held ones, and a held one whose gradient says the cost falls as it comes down leaves
    them, one at a time, until the KKT conditions hold. For the blendshape fits' 2-60 unknowns this is about
    five times faster than scipy's BVLS (``lsq_linear(method="bvls")``), whose iterations run in Python, and
    30 times faster than its default TRF, which also stops short of the exact minimum. After ``rounds``
    changes of the held set (never seen) it hands over to BVLS.

    Parameters
    ----------
    A : (m, n) float
    b : (m,) float
    upper : float
        The upper bound of every coefficient (the lower is 0).
    x0 : (n,) float, optional
        ``nnls(A, b)``'s solution when the caller has it already (its first round).
    """
    from scipy.optimize import lsq_linear, nnls

    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    n = A.shape[1]
    held = np.zeros(n, bool)
    x = nnls(A, b)[0] if x0 is None else np.asarray(x0, dtype=np.float64)
    for _ in range(rounds):
        over = ~held & (x > upper)
        if over.any():
            held |= over
        else:
            g = A.T @ (A @ x - b)
            leave = held & (g > 1e-12 * max(float(np.abs(g).max()), 1e-300))
            if not leave.any():
                return np.clip(x, 0.0, upper)  # (rounding may leave -1e-18)
            held[int(np.argmax(np.where(leave, g, -np.inf)))] = False
        x = np.full(n, float(upper))
        free = ~held
        if free.any():
            x[free] = nnls(A[:, free], b - A[:, held] @ x[held])[0]
    return np.clip(lsq_linear(A, b, bounds=(0.0, upper), method="bvls", tol=1e-12).x, 0.0, upper)


def box_qp_many(Q: np.ndarray, c: np.ndarray, upper: float, start: np.ndarray | None = None, rounds: int = 30):
    """``argmin x.Q.x - 2 c.x`` over ``0 <= x <= upper`` for ``K`` small dense problems at once.

    The same minimum as :func:`box_lsq` on a factor of ``Q`` (``|R x - y|^2`` with ``R^T R = Q``,
    ``R^T y = c``), found by a primal-dual active set (Hintermueller, Ito & Kunisch, "The primal-dual
    active set strategy as a semismooth Newton method", 2003) vectorised over the problems: every round
    solves, for every problem still changing, the equality-constrained minimum with its held coefficients
    at their bounds (one batched ``numpy.linalg.solve``), then a held coefficient whose multiplier has the
    wrong sign is freed and a free one outside the box is held, all at once. A good start (the
    unconstrained minimum: its coefficients outside the box start held) needs 1-3 rounds. Why not a loop
    of NNLS calls: with a few dozen unknowns a compiled NNLS takes ~0.1 ms, the Python around it more,
    while a batched solve of a thousand such problems takes ~10 ms. The strategy can cycle on a
    non-M-matrix ``Q``, so a problem that has not settled after ``rounds`` is reported (``ok`` False) for
    the caller to solve on its own.

    Parameters
    ----------
    Q : (K, n, n) float
        Symmetric positive definite (pad a smaller problem with identity rows and zero ``c``: its padding
        stays 0).
    c : (K, n) float
    upper : float
        The upper bound of every coefficient (``inf``: none; the lower is 0).
    start : (K, n) float, optional
        A guess (e.g. the unconstrained minimum): its coefficients below 0 start held at 0, those above
        ``upper`` at ``upper``. Default: none held.
    rounds : int
        Active-set rounds at most.

    Returns
    -------
    x : (K, n) float64
        The minimum, clipped to the box (rounding may leave -1e-18).
    ok : (K,) bool
        Whether the KKT conditions hold (within rounding); where not, ``x`` is only the last round's.
    """
    Q = np.asarray(Q, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64)
    K, n = c.shape
    upper = float(upper)
    if start is None:
        lo = np.zeros((K, n), bool)
        hi = np.zeros((K, n), bool)
    else:
        lo = start < 0.0
        hi = start > upper
    x = np.zeros((K, n))
    ok = np.zeros(K, bool)
    eye = np.eye(n, dtype=bool)
    work = np.arange(K)  # problems still changing
    for _ in range(rounds):
        if work.size == 0:
            break
        Qw, cw, low, high = Q[work], c[work], lo[work], hi[work]
        free = ~(low | high)
        xb = np.where(high, upper, 0.0)  # held coefficients at their bounds, free ones 0
        rhs = np.where(free, cw - np.einsum("kij,kj->ki", Qw, xb), xb)
        # the held rows and columns become identity rows: one regular system of the same size per problem
        M = np.where(free[:, :, None] & free[:, None, :], Qw, 0.0)
        M[:, eye] += ~free
        try:
            xw = np.linalg.solve(M, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular Q: leave these problems to the caller
            break
        g = np.einsum("kij,kj->ki", Qw, xw) - cw  # half the gradient: the multiplier of a held coefficient
        # tolerances at rounding level of the problem's scale (an exact tie at a bound must not flip back and forth)
        tx = 1e-12 * np.maximum(np.abs(xw).max(axis=1, initial=0.0), 1.0)[:, None]
        tg = 1e-12 * np.maximum(np.abs(cw).max(axis=1, initial=0.0),
                                np.abs(np.einsum("kij,kj->ki", Qw, xw)).max(axis=1, initial=0.0))[:, None]
        tg = np.maximum(tg, 1e-300)
        new_lo = (free & (xw < -tx)) | (low & (g >= -tg))
        new_hi = (free & (xw > upper + tx)) | (high & (g <= tg))
        x[work] = xw
        same = ((new_lo == low) & (new_hi == high)).all(axis=1)
        ok[work[same]] = True
        lo[work], hi[work] = new_lo, new_hi
        work = work[~same]
    return np.clip(x, 0.0, upper), ok
