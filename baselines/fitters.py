"""Blendshape-fitting baselines of the SEM paper (Kang et al., IEEE Access), Sec. III and V-A.

Four :class:`~facegeom.interfaces.Fitter` s, each ``fit(rig, target) -> FitResult``
for the three target kinds of :mod:`facegeom.model.rig`:

- :class:`L1RegFitter` (``L1Reg``) and :class:`L2RegFitter` (``L2Reg``): the
  delta-blendshape coefficients ``e`` in ``[0, 1]`` minimising eq. (7),
  ``E = E_data + w_l1 E_L1 + w_l2 E_L2`` with eq. (5)'s
  ``E_L1 = (1/B) sum |e_i|`` (linear, since ``e >= 0``) and
  ``E_L2 = (1/B) sum e_i^2``.
- :class:`PCAExpFitter` (``PCAExp``) and :class:`PCADelFitter` (``PCADel``):
  coefficients ``c`` of a PCA basis of the rig's shapes with the
  Mahalanobis prior ``w_prior sum_k c_k^2 / sigma_k^2``.

Data terms (``E_data``)
-----------------------
- :class:`~facegeom.model.targets.MeshTarget` (correspondence): ``sum_j w_j |f_j - t_j|^2 / sum_j w_j``
  (``w_j`` the target's per-vertex weights, all 1 by default: the ``(1/n) sum``
  of the brief).  Quadratic in the coefficients: evaluated with the Gram matrix,
  ``(e^T G e - 2 e^T D^T dT + |dT|^2) / n`` with ``D^T dT`` computed once.
- :class:`~facegeom.model.targets.PointCloudTarget`: eq. (3), ``(1/n) sum_j |f_j - p_j|^2``,
  ``p_j`` the target point closest to the vertex ``f_j`` (scipy ``cKDTree``),
  ICP style: correspondences and coefficients alternate (``icp_iterations``
  rounds at most, default 60; stops when the correspondences no longer change).
  Point-to-point ICP converges slowly (vertices slide along the surface): on a
  30,000-point cloud sampled from a rig face 10 rounds leave ~1 mm mean vertex
  error, ~55 rounds reach convergence (~0.005 mm).  With
  ``region`` (vertex ids or a boolean mask) only those vertices ``f_j`` take
  part (the face area a scan covers); otherwise all.
- :class:`~facegeom.model.targets.LandmarkTarget`: eq. (4), ``(1/L) sum_k |Pi(f_{v_k}) - l_k|^2``
  with the perspective projection of the target's camera; the analytic
  gradient uses ``camera.jacobian``.  An unposed camera (``camera.posed`` False)
  gets its pose estimated by :func:`facegeom.methods.fitting.fit_with_pose`
  (pose from the neutral, then alternation); the camera used is ``info["camera"]``.

Normalisation (so a weight means the same on every target kind)
---------------------------------------------------------------
Every data term is divided by the squared inter-ocular distance ``s^2`` in its
own unit, which makes it a squared *normalised error* (the NE of eqs. 31/32,
squared):

- 3-D targets: ``s`` = distance between the inner eye corners (68-landmarks 39
  and 42) of the rig's neutral, in the rig's unit (3.6 cm on ICT faces);
- landmarks: ``s`` = distance in pixels between the target's landmarks of
  those two vertices when both are in the target (eq. 31), else the distance
  between their projections on the neutral face with the (posed / estimated)
  camera.

A rig without landmark ids has no eye corners: ``s`` is then the RMS distance
of the neutral's vertices to their centroid (and for landmarks that length
times ``focal / depth`` of the landmark vertices' centroid).  ``info["scale"]``
reports the ``s`` used.  The regularisers are dimensionless (coefficients in
``[0, 1]``; ``c_k / sigma_k``), so ``E`` is dimensionless throughout.

Default weights and how they were chosen
----------------------------------------
By a small sweep on a seeded *validation* set that shares nothing with any
benchmark target: 4 ICT identities ``model.random_identity(rng)`` x 5 random
sparse expressions (2-6 active shapes, weights U(0.3, 1)) drawn from
``numpy.random.default_rng(20240607)``.  Each of the 20 faces gives a landmark
target (the 23 fitted landmarks of ``FIT_LANDMARKS_23``, a posed
``look_at_camera`` with yaw U(-20, 20) degrees, pixel noise N(0, 1.5 px)),
scored by the NE on the 26 *unused* landmarks (``EVAL_LANDMARKS_26``, the
paper's generalisation test), and a mesh target with vertex noise N(0, 1 mm),
scored by the mean vertex error against the noise-free face.  Grid: weights
``10^k``, ``k = -6 .. -1``, and for the PCA fitters ``n_components`` in
{10, 30, 53}.  Rule: the smallest sum of the two mean scores, each divided by
the best mean score of that target kind for that method.  Results (NE unused,
mesh error in mm) of the chosen values: L1Reg ``w_l1 = 1e-3`` (0.063, 0.024);
L2Reg ``w_l2 = 1e-4`` (0.073, 0.037); PCAExp ``(53, 1e-6)`` (0.065, 0.107);
PCADel ``(53, 1e-6)`` (0.065, 0.093).  Stronger weights lower the unused-landmark
NE (best 0.036-0.040 at ``1e-1`` / ``1e-4``) but cost far more on meshes
(e.g. L1Reg ``1e-2``: NE 0.042, mesh 0.14 mm).  The values are fixed
constants (``_DEFAULTS``), not re-tuned at run time.

Fast path
---------
``fit`` solves one target with scipy's ``minimize(method="L-BFGS-B", jac=True)``
(bounds ``[0, 1]`` for L1Reg / L2Reg, none for the PCA fitters; the PCA fitters
solve the quadratic mesh / point-cloud cases in closed form).  For many mesh
targets ``fit_many(rig, targets)`` (the results in one call): one BLAS
product gives every ``D^T dT``; the bounded quadratic programs are then solved
*exactly* together by a batched primal-dual active-set method (KKT conditions
checked; a target that does not converge in ``max_active_set`` rounds is handed
to L-BFGS-B).  The PCA fitters' mesh solution is a closed form for all targets.
"""
from __future__ import annotations

import time
from functools import partial
from numbers import Integral, Real

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from facegeom.errors import InputError
from facegeom.interfaces import FitResult, Params, as_handles, check_range
from facegeom.methods.fitting import check_fit_inputs, fit_with_pose
from facegeom.methods.marker_solve import split_markers
from facegeom.model import (
    INNER_EYE_CORNERS,
    BlendshapeRig,
    LandmarkTarget,
    MarkerTarget,
    MeshTarget,
    PinholeCamera,
    PointCloudTarget,
)

__all__ = ["L1RegFitter", "L2RegFitter", "PCAExpFitter", "PCADelFitter"]

# Chosen by the validation sweep described in the module docstring.
_DEFAULTS = dict(
    l1=1e-3,
    l2=1e-4,
    pca_exp=(53, 1e-6),  # (n_components, w_prior); n_components is capped at the rig's rank
    pca_del=(53, 1e-6),
)


# --------------------------------------------------------------------------- parameter checks


def _check_weight(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise InputError(f"{name} must be a number, got {value!r}")
    return check_range(name, value, 0, 1e6, "the energy is normalised: beyond it the data no longer count")


#: Upper bounds of the iteration counts, with the reason each is where it is.
_COUNT_LIMITS = {
    "icp_iterations": (10_000, "correspondence rounds stop when they repeat, within tens"),
    "alternations": (100, "pose / expression rounds settle within a few"),
    "max_iter": (1_000_000, "L-BFGS-B iterations of one solve"),
    "max_active_set": (10_000, "active-set rounds end within the number of shapes"),
    "chunk": (1_000_000, "targets solved together"),
}


def _check_count(value, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise InputError(f"{name} must be an integer, got {value!r}")
    hi, why = _COUNT_LIMITS[name]
    return check_range(name, value, minimum, hi, why, integer=True)


def _check_region(region):
    if region is None:
        return None
    r = np.asarray(region)
    if r.ndim != 1 or r.size == 0:
        raise InputError("region must be a non-empty 1-D array of vertex ids or a boolean mask")
    if r.dtype == bool:
        if not r.any():
            raise InputError("region mask selects no vertex")
        return r.copy()
    if not np.issubdtype(r.dtype, np.integer):
        raise InputError("region must hold integer vertex ids or be a boolean mask")
    return r.astype(np.int64)


def _region_ids(region, n: int) -> np.ndarray | None:
    if region is None:
        return None
    if region.dtype == bool:
        if region.shape != (n,):
            raise InputError(f"region mask must have shape ({n},), got {region.shape}")
        return np.flatnonzero(region)
    return as_handles(region, n, "region")


# --------------------------------------------------------------------------- the linear model


def _matvec(M, x):
    """``M @ x`` for a tall Fortran-ordered ``M``, as a 1-row GEMM (a threaded GEMV can be 20x slower)."""
    return (x[None] @ M.T)[0]


def _vecmat(v, M):
    """``M.T @ v`` for a tall Fortran-ordered ``M``, as a 1-row GEMM."""
    return (v[None] @ M)[0]


class _Model:
    """``face(x) = base + M x`` with a separable regulariser ``a . x + sum q_p x_p^2``.

    ``Mv (n, 3, P)`` is ``M`` per vertex; ``gram = M^T M``; ``bounds`` is
    ``(lo, hi)`` or None; ``to_weights(x)`` maps the coefficients to the rig's
    shape weights.
    """

    def __init__(self, rig, base, M, Mv, gram, a, q, bounded, wmap=None, w0=None):
        self.rig = rig
        self.base = base  # (n, 3)
        self.base_flat = base.reshape(-1)
        self.M = M  # (3n, P)
        self.Mv = Mv  # (n, 3, P)
        self.gram = gram  # (P, P)
        self.a = a  # (P,)
        self.q = q  # (P,)
        self.bounded = bounded
        self.wmap = wmap  # (B, P) or None (identity)
        self.w0 = w0  # (B,) or None
        self.P = M.shape[1]
        self.Mt_base = _vecmat(self.base_flat, M)  # for D^T dT = D^T T - D^T base
        self._region_cache: dict = {}

    def to_weights(self, x):
        if self.wmap is None:
            return np.array(x, dtype=np.float64)
        return self.w0 + x @ self.wmap.T

    def vertices(self, x):
        return self.base + _matvec(self.M, x).reshape(-1, 3)

    def reg(self, x):
        return float(self.a @ x + self.q @ (x * x))

    def region(self, ids):
        """``(base (k, 3), M (3k, P) Fortran-ordered, gram (P, P))`` restricted to vertex ``ids`` (None: all)."""
        if ids is None:
            return self.base, self.M, self.gram
        key = ids.tobytes()
        hit = self._region_cache.get(key)
        if hit is None:
            Mr = np.asfortranarray(self.Mv[ids].reshape(-1, self.P))
            hit = (self.base[ids], Mr, Mr.T @ Mr)
            self._region_cache = {key: hit}  # keep one region
        return hit


# --------------------------------------------------------------------------- scales


def _eye_ids(rig):
    if rig.landmark_ids is None:
        return None
    return rig.landmark_ids[list(INNER_EYE_CORNERS)]


def _scale3d(rig) -> float:
    eyes = _eye_ids(rig)
    if eyes is not None:
        s = float(np.linalg.norm(rig.neutral[eyes[0]] - rig.neutral[eyes[1]]))
        if s > 0:
            return s
    c = rig.neutral - rig.neutral.mean(axis=0)
    s = float(np.sqrt((c * c).sum(axis=1).mean()))
    if not s > 0:
        raise InputError("the rig's neutral face is a single point: no length scale")
    return s


def _scale2d(rig, target: LandmarkTarget, camera: PinholeCamera) -> float:
    eyes = _eye_ids(rig)
    if eyes is not None:
        pos = {int(v): i for i, v in enumerate(target.vertex_ids)}
        if int(eyes[0]) in pos and int(eyes[1]) in pos:
            s = float(np.linalg.norm(target.points2d[pos[int(eyes[0])]] - target.points2d[pos[int(eyes[1])]]))
            if s > 0:
                return s
        uv = camera.project(rig.neutral[eyes], "eye corner")
        s = float(np.linalg.norm(uv[0] - uv[1]))
        if s > 0:
            return s
    centre = rig.neutral[target.vertex_ids].mean(axis=0)
    depth = -float(camera.to_camera(centre[None])[0, 2])
    if not depth > 0:
        raise InputError("the landmarks are behind the camera")
    return _scale3d(rig) * camera.focal / depth


# --------------------------------------------------------------------------- solvers


def _lbfgsb(fun, x0, bounds, maxiter, ftol=0.0, gtol=1e-12):
    """scipy L-BFGS-B with an analytic gradient; returns (x, nit, success).

    ``ftol=0`` for the quadratic problems: their energy is shifted by a
    constant, so the relative-reduction test can stop early near ``E = 0``.
    """
    res = minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                   options=dict(maxiter=maxiter, ftol=ftol, gtol=gtol, maxcor=20))
    return res.x, int(res.nit), bool(res.success)


def _solve_quadratic(model: _Model, G, b, const, N, s2, x0, maxiter):
    """Minimise ``(x^T G x - 2 x^T b + const) / (N s^2) + reg(x)`` -> (x, nit, success, energy)."""
    k = 1.0 / (N * s2)
    H = 2.0 * (k * G + np.diag(model.q))  # the Hessian
    f = 2.0 * k * b - model.a  # E = 1/2 x^T H x - f^T x + const k
    if not model.bounded:
        x = np.linalg.solve(H, f)
        nit, ok = 0, True
    else:
        # scale the energy so that the largest Hessian diagonal is 1 (a meaningful gtol)
        h = float(np.max(np.diag(H)))
        h = h if h > 0 else 1.0
        Hs, fs = H / h, f / h

        def fun(x):
            g = Hs @ x - fs
            return 0.5 * float(x @ (g - fs)), g

        x, nit, ok = _lbfgsb(fun, np.clip(x0, 0.0, 1.0), [(0.0, 1.0)] * model.P, maxiter)
    e = float(0.5 * x @ H @ x - f @ x + k * const)
    return x, nit, ok, e


def _solve_landmarks(model: _Model, target: LandmarkTarget, camera: PinholeCamera, x0, maxiter):
    ids = target.vertex_ids
    base = model.base[ids]
    Mv = np.ascontiguousarray(model.Mv[ids])  # (L, 3, P)
    L = len(ids)
    s = _scale2d(model.rig, target, camera)
    k = 1.0 / (L * s * s)
    l2 = target.points2d
    a, q = model.a, model.q

    def fun(x):
        pts = base + np.einsum("kdp,p->kd", Mv, x)
        r = camera.project(pts, "landmark") - l2
        J = camera.jacobian(pts, "landmark")  # (L, 2, 3)
        E = k * float((r * r).sum()) + float(a @ x + q @ (x * x))
        g = 2.0 * k * np.einsum("kc,kcd,kdp->p", r, J, Mv) + a + 2.0 * q * x
        return E, g

    bounds = [(0.0, 1.0)] * model.P if model.bounded else None
    x0 = np.clip(x0, 0.0, 1.0) if model.bounded else x0
    x, nit, ok = _lbfgsb(fun, x0, bounds, maxiter, ftol=1e-12, gtol=1e-9)
    E = fun(x)[0]
    return x, nit, ok, E, s


def _solve_free(H, rhs, free):
    """Solve ``H_II x_I = rhs_I`` per row (``I`` = that row's free set) -> ``(T, P)``, 0 off ``I``.

    Rows are bucketed by the size of their free set (multiples of 8) and solved
    as padded ``(T_b, m, m)`` batches, much cheaper than ``(T, P, P)`` when few
    variables are free.
    """
    T, P = rhs.shape
    out = np.zeros((T, P))
    nf = free.sum(axis=1)
    order = np.argsort(~free, axis=1, kind="stable")  # free indices first
    sizes = np.minimum(-(-nf // 8) * 8, P)
    for m in np.unique(sizes):
        if m == 0:
            continue
        rows = np.flatnonzero(sizes == m)
        o = order[rows, :m]  # (t, m)
        valid = np.arange(m)[None, :] < nf[rows, None]  # padding beyond the free count
        A = H[o[:, :, None], o[:, None, :]]
        vv = valid[:, :, None] & valid[:, None, :]
        A = np.where(vv, A, 0.0)
        A[:, np.arange(m), np.arange(m)] = np.where(valid, A[:, np.arange(m), np.arange(m)], 1.0)
        b = np.where(valid, np.take_along_axis(rhs[rows], o, axis=1), 0.0)
        x = np.linalg.solve(A, b[..., None])[..., 0]
        sub = out[rows]
        np.put_along_axis(sub, o, np.where(valid, x, 0.0), axis=1)
        out[rows] = np.where(free[rows], sub, 0.0)
    return out


#: The ridge added to the box QP's Hessian, relative to its mean diagonal (see ``_solve_mesh_batch``).
_BOX_QP_RIDGE = 1e-10


def _batched_box_qp(H, F, lo=0.0, hi=1.0, max_rounds=60, backup=3):
    """Exactly minimise ``1/2 x^T H x - f_t^T x`` over ``lo <= x <= hi`` for every row ``f_t`` of ``F``.

    Block principal pivoting (a primal-dual active-set method with Murty's
    single-pivot backup rule, as in Kim & Park's NNLS solver), batched over the
    targets, which share the SPD Hessian ``H``.  A round exchanges every
    violated index of a target while its number of KKT violations keeps
    decreasing (or for ``backup`` more rounds), then only the last violated
    index, which prevents the cycling of the plain method on ill-conditioned
    ``H``.  Returns ``(X, converged (T,) bool)``; a converged row satisfies the
    KKT conditions (multipliers up to 1e-14).
    """
    T, P = F.shape
    X = np.linalg.solve(H, F.T).T  # unconstrained solutions: the initial active sets
    up = X > hi
    low = X < lo
    converged = np.ones(T, bool)
    idx = np.flatnonzero((up | low).any(axis=1))
    if idx.size == 0:
        return X, converged
    up, low = up[idx], low[idx]
    best = np.full(idx.size, P + 1)
    left = np.full(idx.size, backup)
    for _ in range(max_rounds):
        Ft = F[idx]
        free = ~(up | low)
        xa = np.where(up, hi, np.where(low, lo, 0.0))  # values of the fixed variables (0 on free ones)
        x = _solve_free(H, Ft - xa @ H, free) + xa
        lam = Ft - x @ H  # KKT multipliers (minus the gradient); 0 on free rows
        lam[free] = 0.0
        v_up = free & (x > hi + 1e-12)  # free variable beyond a bound -> fix it there
        v_lo = free & (x < lo - 1e-12)
        viol = v_up | v_lo | (up & (lam < -1e-14)) | (low & (lam > 1e-14))  # fixed with a wrong-sign multiplier -> free it
        ninf = viol.sum(axis=1)
        X[idx] = np.clip(x, lo, hi)
        better = ninf < best
        full = better | (left > 0)
        left = np.where(better, backup, np.where(full, left - 1, left))
        best = np.minimum(best, ninf)
        last = P - 1 - np.argmax(viol[:, ::-1], axis=1)  # Murty: the last violated index
        single = np.zeros_like(viol)
        single[np.arange(idx.size), last] = True
        change = viol & (full[:, None] | single)
        up = np.where(change, v_up, up)  # a released upper bound becomes free (v_up is False there)
        low = np.where(change, v_lo, low)
        keep = ninf > 0
        if not keep.any():
            return X, converged
        idx, up, low, best, left = idx[keep], up[keep], low[keep], best[keep], left[keep]
    converged[idx] = False
    return X, converged


# --------------------------------------------------------------------------- the base class


class _BaseFitter(Params):
    """Shared machinery: model cache, target dispatch, results."""

    _name = "base"

    def __init__(self, region=None, icp_iterations: int = 60, alternations: int = 3, max_iter: int = 1000,
                 max_active_set: int = 60):
        self.region = _check_region(region)
        self.icp_iterations = _check_count(icp_iterations, "icp_iterations")
        self.alternations = _check_count(alternations, "alternations", minimum=0)
        self.max_iter = _check_count(max_iter, "max_iter")
        self.max_active_set = _check_count(max_active_set, "max_active_set")
        self._cache = None

    def __repr__(self) -> str:
        keys = [k for k in self.__dict__ if not k.startswith("_")]
        args = ", ".join(f"{k}={getattr(self, k)!r}" for k in keys if k != "region")
        return f"{type(self).__name__}({args})"

    # subclasses build the model
    def _build(self, rig: BlendshapeRig) -> _Model:  # pragma: no cover - abstract
        raise NotImplementedError

    def _model(self, rig: BlendshapeRig) -> _Model:
        if self._cache is None or self._cache[0] is not rig or self._cache[1] != self._params():
            self._cache = (rig, self._params(), self._build(rig))
        return self._cache[2]

    def _params(self):
        return tuple(v for k, v in sorted(self.__dict__.items()) if not k.startswith("_") and k != "region")

    def _x0(self, model):
        return np.zeros(model.P)

    # ----------------------------------------------------------------- fit
    def fit(self, rig, target) -> FitResult:
        """Fit the rig's coefficients to one target.

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
            ``weights (B,)`` in the rig's shape order, ``vertices (n, 3)`` the
            fitted face; ``info``: ``method``, ``energy`` (eq. 7, normalised),
            ``data_energy``, ``scale`` (the normaliser ``s``), ``iterations``
            (optimizer iterations, summed), ``converged``, ``time_s`` (seconds);
            ``camera`` for landmarks, ``icp_iterations`` for point clouds.
        """
        if isinstance(target, MarkerTarget):  # capture markers: rigid pose + restricted mesh fit
            return split_markers(self, rig, [target])[0]
        t0 = time.perf_counter()
        rig, target = check_fit_inputs(rig, target)
        model = self._model(rig)
        info: dict = {"method": self._name}
        if isinstance(target, MeshTarget):
            x, info_t = self._fit_mesh(model, target)
        elif isinstance(target, LandmarkTarget):
            x, info_t = self._fit_landmarks(model, target)
        else:
            x, info_t = self._fit_cloud(model, target)
        info.update(info_t)
        info["time_s"] = time.perf_counter() - t0
        return FitResult(weights=model.to_weights(x), vertices=model.vertices(x), info=info)

    def _fit_mesh(self, model: _Model, target: MeshTarget):
        s = _scale3d(model.rig)
        dT = target.vertices.reshape(-1) - model.base_flat
        if target.weights is None:
            G, N = model.gram, float(model.rig.n_vertices)
            b = _vecmat(target.vertices.reshape(-1), model.M) - model.Mt_base
            const = float(dT @ dT)
        else:
            w3 = np.repeat(target.weights, 3)
            Mw = model.M * np.sqrt(w3)[:, None]
            G, N = Mw.T @ Mw, float(target.weights.sum())
            b = _vecmat(w3 * dT, model.M)
            const = float(w3 @ (dT * dT))
        x, nit, ok, E = _solve_quadratic(model, G, b, const, N, s * s, self._x0(model), self.max_iter)
        return x, dict(energy=E, data_energy=E - model.reg(x), scale=s, iterations=nit, converged=ok)

    def _fit_cloud(self, model: _Model, target: PointCloudTarget):
        s = _scale3d(model.rig)
        ids = _region_ids(self.region, model.rig.n_vertices)
        base, Mr, G = model.region(ids)
        N = float(base.shape[0])
        tree = cKDTree(target.points)
        x = self._x0(model)
        prev = None
        nit_total, ok, E, rounds = 0, True, np.inf, 0
        for rounds in range(1, self.icp_iterations + 1):
            F = base + _matvec(Mr, x).reshape(-1, 3)
            _, j = tree.query(F)
            if prev is not None and np.array_equal(j, prev):
                rounds -= 1
                break
            prev = j
            dP = (target.points[j] - base).reshape(-1)
            x, nit, ok, E = _solve_quadratic(model, G, _vecmat(dP, Mr), float(dP @ dP), N, s * s, x, self.max_iter)
            nit_total += nit
        # the energy with the final correspondences
        F = base + _matvec(Mr, x).reshape(-1, 3)
        d, _ = tree.query(F)
        data = float((d * d).mean()) / (s * s)
        return x, dict(energy=data + model.reg(x), data_energy=data, scale=s, iterations=nit_total,
                       converged=ok, icp_iterations=rounds)

    def _fit_landmarks(self, model: _Model, target: LandmarkTarget):
        state = dict(x=self._x0(model), nit=0, ok=True, E=np.nan, s=np.nan)

        def solve(camera):
            x, nit, ok, E, s = _solve_landmarks(model, target, camera, state["x"], self.max_iter)
            state.update(x=x, nit=state["nit"] + nit, ok=ok, E=E, s=s)
            return model.to_weights(x)

        _, camera = fit_with_pose(model.rig, target, solve, alternations=self.alternations)
        x = state["x"]
        return x, dict(energy=state["E"], data_energy=state["E"] - model.reg(x), scale=state["s"],
                       iterations=state["nit"], converged=state["ok"], camera=camera)

    # ----------------------------------------------------------------- many mesh targets
    batched_targets = frozenset({"mesh"})

    def fit_many(self, rig, targets, chunk: int = 1024) -> list[FitResult]:
        """Fit ``K`` targets at once: :func:`facegeom.interfaces.fit_many`'s fast path for meshes.

        Unweighted mesh targets are solved together (one BLAS product for all
        ``D^T dT``, then a batched exact solve); other targets go through
        :meth:`fit` one by one.

        Parameters
        ----------
        rig : BlendshapeRig
            ``B`` delta-blendshapes on ``n`` vertices.
        targets : sequence of K targets, or (K, n, 3) array
            Targets of any kind, or the meshes of ``K`` unweighted mesh targets.
        chunk : int
            Meshes per BLAS product.

        Returns
        -------
        list of K FitResult
            ``weights (B,)`` (the same as ``fit(...).weights`` up to the solver's
            tolerance); ``vertices (n, 3)`` evaluated on first read (for the PCA
            fitters the PCA reconstruction, as :meth:`fit`); ``info``: ``method``
            and ``time_s`` (the target's share of the batch's time) for the
            batched meshes, :meth:`fit`'s ``info`` for the others.
        """
        if not isinstance(rig, BlendshapeRig):
            raise InputError(f"rig must be a BlendshapeRig, got {type(rig).__name__}")
        chunk = _check_count(chunk, "chunk")
        n = rig.n_vertices
        if isinstance(targets, np.ndarray):
            arrays = np.asarray(targets, dtype=np.float64)
            if arrays.ndim != 3 or arrays.shape[1:] != (n, 3):
                raise InputError(f"target meshes must have shape (T, {n}, 3), got {arrays.shape}")
            others = []
            rows = np.arange(arrays.shape[0])
        else:
            targets = list(targets)
            solved = split_markers(self, rig, targets)  # MarkerTargets solved here, the others left None
            if all(r is not None for r in solved):
                return solved
            rows, meshes, others = [], [], []
            for i, t in enumerate(targets):
                if solved[i] is not None:
                    others.append(i)
                    continue
                check_fit_inputs(rig, t)
                if isinstance(t, MeshTarget) and t.weights is None:
                    rows.append(i)
                    meshes.append(t.vertices)
                else:
                    others.append(i)
            rows = np.asarray(rows, dtype=np.int64)
            arrays = np.stack(meshes) if meshes else np.zeros((0, n, 3))
        t0 = time.perf_counter()
        model = self._model(rig)
        X = np.empty((arrays.shape[0], model.P))
        W = np.empty((arrays.shape[0], rig.n_shapes))
        for start in range(0, arrays.shape[0], chunk):
            block = arrays[start:start + chunk].reshape(-1, 3 * n)
            Bm = block @ model.M - model.Mt_base[None]
            if not np.all(np.isfinite(Bm)):  # a NaN / inf coordinate spreads to its row of D^T T
                bad = start + int(np.flatnonzero(~np.isfinite(Bm).all(axis=1))[0])
                raise InputError(f"target mesh {int(rows[bad])} contains NaN or inf")
            Xc = self._solve_mesh_batch(model, Bm)
            X[start:start + chunk] = Xc
            W[start:start + chunk] = Xc @ model.wmap.T + model.w0 if model.wmap is not None else Xc
        info = {"method": self._name, "time_s": (time.perf_counter() - t0) / max(arrays.shape[0], 1)}
        out: list = [None] * (arrays.shape[0] + len(others))
        for j, i in enumerate(rows):
            out[i] = FitResult(W[j], partial(model.vertices, X[j]), dict(info))
        for i in others:
            out[i] = solved[i] if solved[i] is not None else self.fit(rig, targets[i])
        return out

    def _solve_mesh_batch(self, model: _Model, Bm: np.ndarray) -> np.ndarray:
        s = _scale3d(model.rig)
        k = 1.0 / (model.rig.n_vertices * s * s)
        H = 2.0 * (k * model.gram + np.diag(model.q))
        F = 2.0 * k * Bm - model.a[None]
        if not model.bounded:
            return np.linalg.solve(H, F.T).T
        # A shape equal to the neutral (a zero delta: Rocketbox's tongueOut moves no skin), a duplicate, or more
        # shapes than the data have coordinates (80 markers: 240) make the Gram matrix singular, and L1Reg has no
        # L2 term to lift it: a ridge of _BOX_QP_RIDGE x its mean diagonal keeps H positive definite (the active-set
        # solves need it) and picks, among equal minima, the one of least norm: a zero shape gets weight 0, a
        # duplicate pair shares its weight. Its bias is that fraction of a shape's own energy, far below rounding
        # of the fits themselves.
        scale = float(np.mean(np.diag(H)))
        H[np.diag_indices_from(H)] += _BOX_QP_RIDGE * (scale if scale > 0 else 1.0)  # no shape moves: any ridge
        X, ok = _batched_box_qp(H, F, max_rounds=self.max_active_set)
        if not ok.all():  # cycling (rare): L-BFGS-B from the last iterate
            for t in np.flatnonzero(~ok):
                X[t] = _solve_quadratic(model, model.gram, Bm[t], 0.0, model.rig.n_vertices, s * s,
                                        X[t], self.max_iter)[0]
        return X


# --------------------------------------------------------------------------- L1Reg / L2Reg


class _RegFitter(_BaseFitter):
    def _build(self, rig):
        B = rig.n_shapes
        D = rig.delta_matrix()
        Mv = rig.deltas.transpose(1, 2, 0)  # (n, 3, B) view
        return _Model(rig, rig.neutral, D, Mv, rig.gram(), np.full(B, self.w_l1 / B), np.full(B, self.w_l2 / B),
                      bounded=True)


class L1RegFitter(_RegFitter):
    """``L1Reg``: eq. (7) with the L1 regulariser, coefficients in ``[0, 1]``.

    ``E = E_data / s^2 + w_l1 (1/B) sum e_i + w_l2 (1/B) sum e_i^2`` (see the
    module docstring for ``E_data`` and ``s``).  The paper uses L1 and L2
    mutually exclusively, hence ``w_l2 = 0`` by default.

    Parameters
    ----------
    w_l1 : float >= 0
        Weight of the L1 term (default chosen by the validation sweep of the module docstring).
    w_l2 : float >= 0
        Weight of the L2 term.
    region : vertex ids or (n,) bool mask, optional
        Rig vertices matched to a point cloud (default all).
    icp_iterations : int
        Correspondence / solve rounds for point clouds (stops early when the
        correspondences repeat).
    alternations : int
        Pose / expression rounds for unposed landmark targets.
    max_iter : int
        L-BFGS-B iterations per solve.
    max_active_set : int
        Rounds of the batched active-set solver of :meth:`fit_many`.
    """

    _name = "L1Reg"

    def __init__(self, w_l1: float = _DEFAULTS["l1"], w_l2: float = 0.0, region=None, icp_iterations: int = 60,
                 alternations: int = 3, max_iter: int = 1000, max_active_set: int = 60):
        self.w_l1 = _check_weight(w_l1, "w_l1")
        self.w_l2 = _check_weight(w_l2, "w_l2")
        super().__init__(region, icp_iterations, alternations, max_iter, max_active_set)


class L2RegFitter(_RegFitter):
    """``L2Reg``: eq. (7) with the L2 regulariser, coefficients in ``[0, 1]``.

    ``E = E_data / s^2 + w_l2 (1/B) sum e_i^2``; other parameters as :class:`L1RegFitter`.
    """

    _name = "L2Reg"

    def __init__(self, w_l2: float = _DEFAULTS["l2"], region=None, icp_iterations: int = 60,
                 alternations: int = 3, max_iter: int = 1000, max_active_set: int = 60):
        self.w_l1 = 0.0
        self.w_l2 = _check_weight(w_l2, "w_l2")
        super().__init__(region, icp_iterations, alternations, max_iter, max_active_set)


# --------------------------------------------------------------------------- PCA


def _check_components(value):
    if isinstance(value, bool):
        raise InputError(f"n_components must be an int >= 1 or a variance fraction in (0, 1], got {value!r}")
    if isinstance(value, Integral):
        return check_range("n_components", value, 1, 100_000, "components of a rig's shapes", integer=True)
    if isinstance(value, Real):
        v = float(value)
        if not (0 < v <= 1):
            raise InputError(f"a fractional n_components must be in (0, 1], got {value!r}")
        return v
    raise InputError(f"n_components must be an int >= 1 or a variance fraction in (0, 1], got {value!r}")


class _PCAFitter(_BaseFitter):
    centred = True

    def __init__(self, n_components, w_prior, region=None, icp_iterations: int = 60, alternations: int = 3,
                 max_iter: int = 1000):
        self.n_components = _check_components(n_components)
        self.w_prior = _check_weight(w_prior, "w_prior")
        super().__init__(region, icp_iterations, alternations, max_iter)

    def _n_keep(self, s2):
        """Components kept: ``n_components`` (int) or the fewest reaching the variance fraction."""
        tol = s2[0] * 1e-12 if s2.size else 0.0
        rank = int((s2 > tol).sum())
        if rank == 0:
            raise InputError("the rig's shapes do not vary: no PCA basis")
        if isinstance(self.n_components, int):
            return min(self.n_components, rank)
        frac = np.cumsum(s2[:rank]) / s2[:rank].sum()
        return int(min(np.searchsorted(frac, self.n_components - 1e-12) + 1, rank))

    def _build(self, rig):
        D = rig.delta_matrix()  # (3n, B)
        B = rig.n_shapes
        if self.centred:
            # PCAExp: the B + 1 shapes neutral, neutral + dB_i; mean = neutral + mean delta
            mu = D.sum(axis=1) / (B + 1)
            X = np.c_[-mu[:, None], D - mu[:, None]]  # (3n, B + 1), centred shapes
            dof = B  # sample variance (N - 1 = B)
            base = rig.neutral + mu.reshape(-1, 3)
        else:
            # PCADel: uncentred PCA of the deltas (second moments about the neutral)
            X = D
            dof = B
            base = rig.neutral
        U, sv, _ = np.linalg.svd(X, full_matrices=False)
        K = self._n_keep(sv * sv)
        U = np.asfortranarray(U[:, :K])
        var = sv[:K] ** 2 / dof
        # weights: the least-squares blendshape weights of the PCA face, exact (it lies in span(D))
        sol, *_ = np.linalg.lstsq(D, np.c_[U, (base - rig.neutral).reshape(-1)], rcond=None)
        wmap, w0 = sol[:, :K], sol[:, K]
        model = _Model(rig, base, U, U.reshape(-1, 3, K), np.eye(K), np.zeros(K), self.w_prior / var,
                       bounded=False, wmap=wmap, w0=w0)
        model.variances = var
        return model


class PCAExpFitter(_PCAFitter):
    """``PCAExp``: PCA of all the rig's shapes, the neutral included (Sec. V-A).

    The ``B + 1`` shapes ``B_1`` (neutral) and ``B_1 + dB_i`` are centred on
    their mean ``m`` and decomposed (SVD); the face is ``m + U c`` with the
    first ``K`` principal directions ``U`` and variances
    ``sigma_k^2 = s_k^2 / B`` (sample variance).  Energy:
    ``E = E_data / s^2 + w_prior sum_k c_k^2 / sigma_k^2`` (Mahalanobis prior;
    ``c`` unbounded).  Mesh and point-cloud data terms are quadratic in ``c``
    and solved in closed form; landmarks by L-BFGS-B without bounds.

    ``weights``: the PCA face lies in ``neutral + span(dB)`` (every centred
    shape is a combination of deltas, and so is ``m - neutral``), so
    ``w = D^+ (m - neutral + U c)`` (least squares, exact: ``D w = m - neutral + U c``)
    reproduces it; ``vertices`` is the PCA reconstruction ``m + U c``.  The
    weights are unbounded (may leave ``[0, 1]``).  ``m - neutral`` maps to
    ``w = 1 / (B + 1)`` for every shape.

    Parameters
    ----------
    n_components : int >= 1 or float in (0, 1]
        Components kept (capped at the rank), or the fraction of the variance to keep.
    w_prior : float >= 0
        Weight of the Mahalanobis prior.
    region, icp_iterations, alternations, max_iter
        As :class:`L1RegFitter`.
    """

    _name = "PCAExp"
    centred = True

    def __init__(self, n_components=_DEFAULTS["pca_exp"][0], w_prior: float = _DEFAULTS["pca_exp"][1],
                 region=None, icp_iterations: int = 60, alternations: int = 3, max_iter: int = 1000):
        super().__init__(n_components, w_prior, region, icp_iterations, alternations, max_iter)


class PCADelFitter(_PCAFitter):
    """``PCADel``: PCA of the delta-blendshapes (Sec. V-A), uncentred.

    ``D = U S V^T`` (thin SVD of the ``(3n, B)`` delta matrix, *not* centred):
    the face is ``neutral + U c`` with ``sigma_k^2 = s_k^2 / B`` (second
    moment).  Uncentred, so that ``c = 0`` -- the prior's mode -- is the
    neutral face and the prior pulls towards "no expression", like the
    delta-blendshape regularisers; a centred PCA of the deltas would pull
    towards the *average* expression, which is PCAExp's behaviour (its mean is
    ``neutral + mean delta * B / (B + 1)``), so the two baselines would nearly
    coincide.  ``weights = D^+ U c = V S^{-1} c`` (exact); ``vertices`` the PCA
    reconstruction.  Energy, parameters and solvers as :class:`PCAExpFitter`.
    """

    _name = "PCADel"
    centred = False

    def __init__(self, n_components=_DEFAULTS["pca_del"][0], w_prior: float = _DEFAULTS["pca_del"][1],
                 region=None, icp_iterations: int = 60, alternations: int = 3, max_iter: int = 1000):
        super().__init__(n_components, w_prior, region, icp_iterations, alternations, max_iter)
