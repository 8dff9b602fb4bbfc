"""Expression weights from 2-D landmarks as a maximum a-posteriori estimate: the landmark path of ``sem-ls``.

Landmarks are few (23 to 68 points: 46 to 136 numbers) for 53 weights and a pose,
and real faces move most of their shapes a little (a frame of a real take has ~40
of 53 weights above 0.001). A selection that stops after a handful of shapes
leaves the rest of the face unexplained; least squares on all of them follows the
noise. The estimate here is the posterior mode of a Bayesian linear model, with
nothing tuned to a protocol:

- **prior**: each weight ``w_b ~ N(0, s^2)`` restricted to its range ``[0, 1]``
  with ``s`` = :data:`~facegeom.constants.EXPRESSION_WEIGHT_SD` (0.2,
  ``prior_sd``): the spread of the weights of real performances (the RMS of
  the 52 weights over real Live Link Face takes), learnt from how faces move,
  not from a benchmark. The marginal likelihood of real annotated photos
  agrees: maximised over ``s`` per photo with the bounds respected, it is at
  about 0.2 on average over 150 real faces;
- **on a face model's generic face** (a rig whose ``population`` is set) the
  person in the photo is not that face, and the weights must also carry the
  part of the person's shape the expression shapes reproduce. The prior is
  then ``N(0, C)`` with ``C`` = the performances' ``s^2 I`` plus the second
  moment of the weights that reproduce people drawn from the model's own
  identity prior (:func:`population_prior`: about 0.27 RMS per weight for the
  ICT model, 0.34 with the expression part): a property of the model, not of
  a benchmark;
- **noise**: Gaussian, ``sigma`` per pixel coordinate, *estimated from the
  photo* by maximising the marginal likelihood (type-II maximum likelihood,
  MacKay's fixed point ``1/sigma^2 = (N - gamma) / |r|^2`` with ``gamma`` the
  effective number of weights the data determine). Annotation noise, the
  person's identity and the annotation convention all land in ``sigma``: the
  noisier the photo, the more the prior rules;
- **projection**: the pinhole camera's projection is linearised at the current
  weights (Gauss-Newton: three steps in the first solve, one in each solve
  after a new pose, from the last weights) and each step's bounded quadratic
  solved exactly (:func:`box_qp`).

Sparsity is not the goal but falls out where the data allow it: the bounds put
the weights whose posterior mode would be negative at exactly zero. Tried and
not kept (see ``docs/benchmarks/fitting-real-faces.md``): the paper's greedy with a
noise-aware stop (~5 shapes where real faces move ~40; 1.16x L1Reg's error on
held-out landmarks of real photos), the same greedy with an evidence stop (also
~5 shapes), a prior scale chosen per photo by leave-one-landmark-out
cross-validation (noisy with 23 folds), and the weights' range as the scale
(``s = 1``: the best held-out landmarks of real photos with the generic face,
where expressions then stand in for the person's shape, but up to 2.2x the 3-D
error of ``s = 0.2`` on synthetic faces whose truth is known: it widened the
prior on every rig, where :func:`population_prior` widens it only on the
generic face, and only as much as the model's people differ), per-weight
evidence (ARD) and the population prior's scale by the evidence.

Everything is batched over ``K`` targets that share landmark vertices.
"""
from __future__ import annotations

import numpy as np

from facegeom.constants import EXPRESSION_WEIGHT_SD
from facegeom.model import project_many

__all__ = ["landmark_jacobian", "noise_precision", "box_qp", "map_weights", "population_prior", "PRIOR_SD",
           "GAUSS_NEWTON_STEPS", "WARM_STEPS"]

#: Standard deviation of the weights' Gaussian prior: the spread of real performances' weights.
PRIOR_SD = EXPRESSION_WEIGHT_SD

#: Gauss-Newton steps on the perspective projection of a first solve (the pose is re-estimated between solves).
GAUSS_NEWTON_STEPS = 3

#: Gauss-Newton steps of a solve that starts from the weights of the previous pose's solve.
WARM_STEPS = 1

#: prior_sd="evidence": rounds of the prior scale's fixed point per Gauss-Newton step, and the scales allowed.
EVIDENCE_ROUNDS = 8
EVIDENCE_SD_RANGE = (0.02, 5.0)

#: population_prior: people drawn from the model's identity prior, alignment rounds, every how many face vertices.
POPULATION_SAMPLES = 200
POPULATION_ROUNDS = 3
POPULATION_VERTEX_STEP = 7
POPULATION_SEED = 0

_POPULATION_CACHE: dict[int, tuple[object, np.ndarray]] = {}


def population_prior(model, expression_sd: float = PRIOR_SD) -> np.ndarray:
    """The covariance ``(B, B)`` of the weights the generic face needs to reproduce a person's expression.

    On the generic face (the population's mean) the weights carry two things:
    the expression, spread ``expression_sd`` per weight as in real
    performances, and the part of the person's own shape that the expression
    shapes can reproduce (a wider face looks like a little ``jawOpen`` and
    ``cheekPuff``). The second part is measured from the model itself, not from
    any benchmark: :data:`POPULATION_SAMPLES` people drawn from the model's
    identity prior (each coefficient N(0, 1), seeded), each aligned to the
    generic face by a similarity (pose and size are estimated in a fit, so the
    weights need not carry them) and fitted with weights in ``[0, 1]`` over the
    face area; the second moment of those weights. The sum of the two is the
    prior (mean zero, so the bounds keep the weights an expression does not
    use at zero). For the ICT model the identity part's RMS is about 0.27
    per weight and the two together 0.34; the shapes that stand in for a
    face's width and length are correlated. Cached per model.
    """
    hit = _POPULATION_CACHE.get(id(model))
    if hit is not None and hit[0] is model:
        return hit[1] + expression_sd ** 2 * np.eye(hit[1].shape[0])
    from facegeom.constants import FACE_AREA, ICT_VERTICES
    from facegeom.registration import kabsch

    n = model.n_vertices
    ids = np.arange(0, FACE_AREA if n == ICT_VERTICES else n, POPULATION_VERTEX_STEP)
    N0 = np.asarray(model.neutral, dtype=np.float64)[ids]
    D = np.asarray(model.expression_deltas, dtype=np.float64)[:, ids].reshape(len(model.expression_deltas), -1).T
    modes = np.asarray(model.identity_modes, dtype=np.float64)[:, ids]  # (I, m, 3)
    rng = np.random.default_rng(POPULATION_SEED)
    A = rng.standard_normal((POPULATION_SAMPLES, modes.shape[0]))
    people = N0[None] + np.tensordot(A, modes, 1)  # (S, m, 3)
    H = np.broadcast_to(D.T @ D, (POPULATION_SAMPLES,) + (D.shape[1],) * 2)
    W = np.zeros((POPULATION_SAMPLES, D.shape[1]))
    for _ in range(POPULATION_ROUNDS):
        face = N0[None] + (W @ D.T).reshape(POPULATION_SAMPLES, -1, 3)
        aligned = np.empty_like(people)
        for k in range(POPULATION_SAMPLES):  # similarity: the person onto the current generic face
            P, Q = people[k], face[k]
            R, _ = kabsch(P, Q)
            Pc, Qc = P - P.mean(axis=0), Q - Q.mean(axis=0)
            scale = float(((Pc @ R.T) * Qc).sum() / max((Pc * Pc).sum(), 1e-300))
            aligned[k] = scale * Pc @ R.T + Q.mean(axis=0)
        r = (aligned - N0[None]).reshape(POPULATION_SAMPLES, -1)
        W = box_qp(np.ascontiguousarray(H), r @ D, 0.0, 1.0, x0=W)
    M = W.T @ W / POPULATION_SAMPLES
    _POPULATION_CACHE[id(model)] = (model, M)
    return M + expression_sd ** 2 * np.eye(M.shape[0])


def landmark_jacobian(rig, ids, e, R, t, f, cx, cy):
    """Pixels of the current faces and their derivative by the weights.

    ``e (K, B)`` weights, cameras ``R (K, 3, 3)``, ``t (K, 3)``, ``f, cx, cy (K,)``.
    Returns ``P (K, n, 2)`` and ``J (K, 2n, B)`` (rows ``u0, v0, u1, v1, ...``).
    Raises :class:`~facegeom.errors.InputError` for a landmark behind its camera.
    """
    D = rig.deltas[:, ids]  # (B, n, 3)
    F = rig.neutral[ids][None] + np.tensordot(e, D, 1)  # (K, n, 3)
    P = project_many(F, R, t, f, cx, cy)
    pc = F @ np.transpose(R, (0, 2, 1)) + t[:, None, :]  # camera frame
    depth = -pc[..., 2]  # > 0 (project_many checked)
    Dc = np.einsum("kij,bnj->kbni", R, D)  # (K, B, n, 3) the shapes' motions in the camera frame
    inv = 1.0 / depth[:, None, :]
    du = f[:, None, None] * (Dc[..., 0] + pc[:, None, :, 0] * Dc[..., 2] * inv) * inv
    dv = -f[:, None, None] * (Dc[..., 1] + pc[:, None, :, 1] * Dc[..., 2] * inv) * inv
    K, B, n = du.shape
    J = np.stack([du, dv], axis=-1).reshape(K, B, 2 * n)
    return P, np.ascontiguousarray(np.transpose(J, (0, 2, 1)))


def noise_precision(J, y, alpha, iters: int = 100, tol: float = 1e-8):
    """``1 / sigma^2 (K,)``: the noise precision that maximises the marginal likelihood of ``y = J w + noise``.

    ``J (K, N, B)``, ``y (K, N)``; ``w ~ N(0, 1/alpha)`` per weight (bounds
    ignored here), noise ``N(0, sigma^2)`` per value. MacKay's fixed point
    ``beta = (N - gamma) / |y - J m|^2`` with the posterior mean ``m`` and
    ``gamma = sum beta l_i / (alpha + beta l_i)`` over the eigenvalues ``l_i``
    of ``J'J``. Everything depends on ``J`` through its singular values and
    the data's components along them, so the smaller of ``J'J`` and ``J J'``
    is decomposed.
    """
    K, N, B = J.shape
    if N < B:
        lam, U = np.linalg.eigh(np.matmul(J, np.transpose(J, (0, 2, 1))))
        lam = np.maximum(lam, 0.0)
        c2 = lam * np.matmul(np.transpose(U, (0, 2, 1)), y[..., None])[..., 0] ** 2  # (J'y)^2 along each direction
    else:
        lam, V = np.linalg.eigh(np.matmul(np.transpose(J, (0, 2, 1)), J))
        lam = np.maximum(lam, 0.0)
        Jty = np.matmul(np.transpose(J, (0, 2, 1)), y[..., None])[..., 0]
        c2 = np.matmul(np.transpose(V, (0, 2, 1)), Jty[..., None])[..., 0] ** 2
    yty = (y * y).sum(axis=1)
    beta = N / np.maximum(yty, 1e-300)
    cap = 1e12 * beta  # sigma at least 1e-6 of the data's RMS: data the weights can reproduce exactly stay finite
    live = np.ones(beta.shape, dtype=bool)  # a target whose fixed point has settled is left alone (a batch of
    alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), beta.shape)[:, None]
    for _ in range(iters):  # targets then gives each the value it gets alone)
        s = beta[:, None] * lam + alpha
        gamma = (beta[:, None] * lam / s).sum(axis=1)
        # |y - J m|^2 = y'y - 2 m'c + m' diag(lam) m with m = beta c / s
        rss = np.maximum(yty - (beta[:, None] * c2 * (2.0 * s - beta[:, None] * lam) / s ** 2).sum(axis=1), 1e-300)
        new = np.minimum(np.maximum(N - gamma, 1e-9) / rss, cap)
        done = np.abs(new - beta) <= tol * beta
        beta = np.where(live, new, beta)
        live &= ~done
        if not live.any():
            break
    return beta


def box_qp(H, g, lower: float = 0.0, upper=1.0, x0=None, iters: int = 60, tol: float = 1e-10):
    """``argmin 1/2 x'Hx - g'x`` over ``lower <= x <= upper`` for ``K`` problems at once -> ``(K, B)``.

    ``H (K, B, B)`` symmetric positive definite, ``g (K, B)``; ``upper=None``
    for no upper bound. Projected Newton (Bertsekas, 1982): the variables at a
    bound whose gradient pushes outwards are held, a Newton step is taken on the
    others, and the step is shortened along the projection arc until the energy
    falls enough (Armijo). A strictly convex box QP ends in a few steps; the
    stop is the projected gradient's size relative to the gradient's scale.
    """
    K, B = g.shape
    hi = np.inf if upper is None else float(upper)
    x = np.zeros((K, B)) if x0 is None else np.clip(np.asarray(x0, dtype=np.float64), lower, hi)
    scale = np.maximum(np.abs(g).max(axis=1), np.abs(np.einsum("kii->ki", H)).max(axis=1)) + 1e-300
    eye = np.eye(B)
    active = np.arange(K)
    for _ in range(iters):
        if active.size == 0:
            break
        Xa, Ha, ga = x[active], H[active], g[active]
        HX = np.matmul(Ha, Xa[..., None])[..., 0]
        grad = HX - ga
        held = ((Xa <= lower) & (grad > 0)) | ((Xa >= hi) & (grad < 0))
        pg = np.where(held, 0.0, grad)
        keep = np.abs(pg).max(axis=1) > tol * scale[active]
        if not keep.all():
            active, Xa, Ha, ga, HX, grad, held = (a[keep] for a in (active, Xa, Ha, ga, HX, grad, held))
            if active.size == 0:
                break
        free = ~held
        Hm = np.where(free[:, :, None] & free[:, None, :], Ha, 0.0) + eye * held[:, :, None]
        p = np.linalg.solve(Hm, np.where(free, -grad, 0.0)[..., None])[..., 0]
        E0 = (Xa * (0.5 * HX - ga)).sum(axis=1)
        step = np.ones(active.size)
        new = np.clip(Xa + p, lower, hi)
        for _ls in range(30):
            En = (new * (0.5 * np.matmul(Ha, new[..., None])[..., 0] - ga)).sum(axis=1)
            ok = En <= E0 + 1e-4 * (grad * (new - Xa)).sum(axis=1)
            if ok.all():
                break
            step = np.where(ok, step, 0.5 * step)
            new = np.where(ok[:, None], new, np.clip(Xa + step[:, None] * p, lower, hi))
        x[active] = new
    return x


def map_weights(rig, ids, L, R, t, f, cx, cy, prior_sd=PRIOR_SD, upper=1.0, e0=None,
                steps: int = GAUSS_NEWTON_STEPS, s0=None, prior_cov=None):
    """The posterior mode of the weights for ``K`` landmark targets seen by posed cameras.

    ``L (K, n, 2)`` pixels of the vertices ``ids``; cameras as
    :func:`landmark_jacobian`. ``prior_sd``: the weights' prior standard
    deviation, or ``"evidence"``: per target, the one that maximises the
    marginal likelihood with the bounds respected (MacKay's fixed point
    ``1/s^2 = gamma / |w|^2`` over the weights the bounds leave free, started
    from ``s0`` or :data:`PRIOR_SD`). ``prior_cov (B, B)``: a full covariance
    of the weights' Gaussian prior in place of ``prior_sd`` (e.g.
    :func:`population_prior` for the generic face). Returns ``(e (K, B),
    sigma (K,), s (K,))``: the weights, the noise estimated per target
    (pixels) and the prior's standard deviation used (with ``prior_cov``: the
    RMS of its diagonal).
    """
    K = L.shape[0]
    B = rig.n_shapes
    if prior_cov is not None:
        return _map_full(rig, ids, L, R, t, f, cx, cy, np.asarray(prior_cov, dtype=np.float64), upper, e0, steps)
    evidence = isinstance(prior_sd, str)
    if evidence and prior_sd != "evidence":
        raise ValueError(f"prior_sd must be a positive number or 'evidence', got {prior_sd!r}")
    start = PRIOR_SD if not evidence else (PRIOR_SD if s0 is None else s0)
    alpha = np.broadcast_to(1.0 / np.asarray(start if evidence else prior_sd, dtype=np.float64) ** 2, (K,)).copy()
    e = np.zeros((K, B)) if e0 is None else np.array(e0, dtype=np.float64)
    beta = np.ones(K)
    eye = np.eye(B)
    for _ in range(steps):
        P, J = landmark_jacobian(rig, ids, e, R, t, f, cx, cy)
        y = (L - P).reshape(K, -1) + np.matmul(J, e[..., None])[..., 0]  # the linearised model's data
        Jt = np.transpose(J, (0, 2, 1))
        JtJ = np.matmul(Jt, J)
        Jty = np.matmul(Jt, y[..., None])[..., 0]
        for _ in range(EVIDENCE_ROUNDS if evidence else 1):
            beta = noise_precision(J, y, alpha)
            H = beta[:, None, None] * JtJ + alpha[:, None, None] * eye
            e = box_qp(H, beta[:, None] * Jty, 0.0, upper, x0=e)
            if not evidence:
                break
            free = e > 1e-9
            lam = np.maximum(np.linalg.eigvalsh(np.where(free[:, :, None] & free[:, None, :], JtJ, 0.0)), 0.0)
            gamma = (beta[:, None] * lam / (alpha[:, None] + beta[:, None] * lam)).sum(axis=1)
            ww = (e * e).sum(axis=1)
            new = np.where(ww > 1e-12, gamma / np.maximum(ww, 1e-300), alpha)
            new = np.clip(new, 1.0 / EVIDENCE_SD_RANGE[1] ** 2, 1.0 / EVIDENCE_SD_RANGE[0] ** 2)
            settled = np.abs(new - alpha) <= 1e-3 * alpha
            alpha = new
            if settled.all():
                break
    return e, 1.0 / np.sqrt(beta), 1.0 / np.sqrt(alpha)


def _map_full(rig, ids, L, R, t, f, cx, cy, C, upper, e0, steps):
    """:func:`map_weights` under the prior ``N(0, C)`` in the bounds; the noise by the whitened marginal likelihood."""
    K, B = L.shape[0], rig.n_shapes
    if C.shape != (B, B):
        raise ValueError(f"prior_cov must be ({B}, {B}), got {C.shape}")
    Lc = np.linalg.cholesky(C)  # w = Lc z with z ~ N(0, I): the noise fixed point of the whitened model
    Pm = np.linalg.inv(C)
    e = np.zeros((K, B)) if e0 is None else np.array(e0, dtype=np.float64)
    beta = np.ones(K)
    for _ in range(steps):
        P, J = landmark_jacobian(rig, ids, e, R, t, f, cx, cy)
        y = (L - P).reshape(K, -1) + np.matmul(J, e[..., None])[..., 0]
        Jt = np.transpose(J, (0, 2, 1))
        beta = noise_precision(np.matmul(J, Lc), y, 1.0)
        H = beta[:, None, None] * np.matmul(Jt, J) + Pm
        e = box_qp(H, beta[:, None] * np.matmul(Jt, y[..., None])[..., 0], 0.0, upper, x0=e)
    return e, 1.0 / np.sqrt(beta), np.full(K, float(np.sqrt(np.diag(C).mean())))
