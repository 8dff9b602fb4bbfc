"""The batched paths that make marker captures with gaps fast give what the per-frame computations give.

* :func:`facegeom.linalg.box_qp_many` (a primal-dual active set over many small bounded least-squares
  problems at once) against the per-problem :func:`facegeom.linalg.box_lsq` / ``_bounded_gram_lsq``;
* SEM's orthogonal selection with bounds (``sem_orthogonal_gram``: all targets of all chunks refitted together,
  finished targets dropped from the work arrays) against a per-target loop written from the definitions;
* the joint pose's per-frame weights block with lost markers (the Woodbury update of the full block's inverse)
  against ``numpy.linalg.inv`` of each frame's block;
* :func:`solve_markers` from the arrays against the per-frame :class:`MarkerTarget` path, on captures with
  runs of lost markers, with and without confidences; bad frames still raise their own one-line errors.
"""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import nnls

from facegeom.errors import InputError
from facegeom.linalg import box_lsq, box_qp_many
from facegeom.methods import sem
from facegeom.methods.marker_solve import (
    DAMPING,
    _joint_pose,
    _weights_block_solver,
    fit_markers,
    marker_rig,
    solve_markers,
)
from facegeom.model import BlendshapeRig, MarkerTarget
from facegeom.registry import create


@pytest.fixture(scope="module")
def rig(face_model):
    return BlendshapeRig.from_face_model(face_model)


@pytest.fixture(scope="module")
def ids(face_model):
    extra = np.arange(3, 6706, 300)
    return np.unique(np.r_[face_model.landmarks, extra]).astype(np.int64)


def _spd(rng, K, n, spread):
    """``K`` random SPD matrices ``(K, n, n)`` with correlated columns (condition up to ~1e4)."""
    A = rng.normal(size=(K, n + 5, n)) * rng.uniform(0.05, spread, (K, 1, n)) + 0.5 * rng.normal(size=(K, n + 5, 1))
    return np.matmul(A.transpose(0, 2, 1), A), A


# --------------------------------------------------------------------------- box_qp_many


@settings(max_examples=60, deadline=None, derandomize=True)
@given(n=st.integers(1, 30), K=st.integers(1, 12), seed=st.integers(0, 2 ** 32 - 1),
       upper=st.sampled_from([0.5, 1.0, np.inf]), spread=st.floats(0.2, 4.0), start=st.booleans())
def test_box_qp_many_is_box_lsq_on_each_problem(n, K, seed, upper, spread, start):
    rng = np.random.default_rng(seed)
    Q, A = _spd(rng, K, n, spread)
    b = rng.normal(size=(K, n + 5)) * 2.0
    c = np.einsum("kmi,km->ki", A, b)
    x0 = np.linalg.solve(Q, c[..., None])[..., 0] if start else None
    x, ok = box_qp_many(Q, c, upper, x0)
    assert x.shape == (K, n) and ok.dtype == bool
    assert (x >= 0).all() and (x <= upper).all()
    for k in range(K):
        if not ok[k]:  # the caller's fallback: only checked to be flagged, never silently wrong
            continue
        ref = box_lsq(A[k], b[k], upper) if np.isfinite(upper) else nnls(A[k], b[k])[0]
        np.testing.assert_allclose(x[k], ref, atol=1e-9 * max(1.0, np.abs(ref).max()))
    assert ok.mean() >= 0.5  # a settled active set is the rule (random non-M-matrices included)


def test_box_qp_many_flags_what_it_cannot_settle_and_pads_with_identity():
    Q = np.array([[[2.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 1.0]]])
    c = np.array([[4.0, -1.0], [0.5, 0.0]])  # second problem: one real unknown, one padded (identity, c = 0)
    x, ok = box_qp_many(Q, c, 1.0)
    np.testing.assert_allclose(x, [[1.0, 0.0], [0.5, 0.0]])
    assert ok.all()
    x, ok = box_qp_many(Q, c, 1.0, rounds=0)  # no round: nothing settled, the caller must solve them
    assert not ok.any()


# --------------------------------------------------------------------------- SEM's bounded orthogonal path


def _bounded_reference(c, G, tt, m, upper):
    """Per target: OMP with the ESim choice and the GCV cut on the Gram products (the definitions), then the
    per-target bounded refit ``_bounded_gram_lsq`` when a coefficient leaves the box."""
    K, B = c.shape
    E = np.zeros((K, B))
    orders = []
    for k in range(K):
        sel, alive = [], np.diag(G) > 1e-300
        best = (tt[k] / m, np.zeros(B), [])
        e = np.zeros(B)
        for _ in range(min(B, m - 1)):
            proj = c[k] - G @ e
            score = np.where(alive, proj / np.sqrt(np.where(alive, np.diag(G), 1.0)), -np.inf)
            p = int(np.argmax(score))
            if not score[p] > 1e-9 * np.sqrt(tt[k]):
                break
            alive[p] = False
            sel.append(p)
            x = np.linalg.solve(G[np.ix_(sel, sel)], c[k, sel])
            e = np.zeros(B)
            e[sel] = x
            rss = max(tt[k] - 2 * e @ c[k] + e @ G @ e, 0.0)
            gcv = m * rss / (m - len(sel)) ** 2
            if gcv < best[0]:
                best = (gcv, e.copy(), list(sel))
        e, sel = best[1], best[2]
        if sel and (e.min() < -1e-12 or e.max() > upper + 1e-12):
            e = np.zeros(B)
            e[sel] = sem._bounded_gram_lsq(G[np.ix_(sel, sel)], c[k, sel], upper)
        E[k] = e
        orders.append(sel)
    return E, orders


@settings(max_examples=12, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), noise=st.sampled_from([0.02, 0.3]), chunk=st.sampled_from([None, 1, 7]))
def test_bounded_orthogonal_path_is_the_per_target_computation(seed, noise, chunk):
    rng = np.random.default_rng(seed)
    n, B, K = 90, 16, 30  # a random "rig" of correlated shapes, targets with weights beyond [0, 1] and noise
    D = rng.normal(size=(n, B)) + 0.5 * rng.normal(size=(n, 1))
    W = np.where(rng.random((K, B)) < 0.5, rng.uniform(-0.3, 1.3, (K, B)), 0.0)
    dT = W @ D.T + noise * rng.normal(size=(K, n))
    G = D.T @ D
    c, tt = dT @ D, np.einsum("ki,ki->k", dT, dT)
    e, order = sem.sem_orthogonal_gram(c, G, tt, n, upper=1.0, chunk=chunk)
    e_ref, order_ref = _bounded_reference(c, G, tt, n, 1.0)
    assert [[int(i) for i in o if i >= 0] for o in order] == order_ref
    np.testing.assert_allclose(e, e_ref, atol=1e-9)
    assert (e >= 0).all() and (e <= 1.0).all()


@settings(max_examples=25, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2 ** 32 - 1), K=st.integers(1, 20), upper=st.sampled_from([1.0, np.inf]))
def test_bounded_gram_many_is_bounded_gram_lsq_per_target(seed, K, upper):
    rng = np.random.default_rng(seed)
    B = 14
    D = rng.normal(size=(40, B)) + 0.4 * rng.normal(size=(40, 1))
    G = D.T @ D
    c = rng.normal(size=(K, B)) * 20.0
    size = rng.integers(1, B + 1, K)
    order = np.full((K, B), -1)
    for k in range(K):
        order[k, :size[k]] = rng.permutation(B)[:size[k]]
    start = rng.normal(size=(K, B))
    got = sem._bounded_gram_many(G, c, order, size, start, upper)
    for k in range(K):
        idx = order[k, :size[k]]
        want = np.zeros(B)
        want[idx] = sem._bounded_gram_lsq(G[np.ix_(idx, idx)], c[k, idx], upper)
        np.testing.assert_allclose(got[k], want, atol=1e-9 * max(1.0, np.abs(want).max()))


# --------------------------------------------------------------------------- the joint pose's weights block


def _gappy_weights(rng, K, p, share, runs=True):
    """``(K, p)`` marker weights 1, with 0 for lost markers in runs of frames (a capture's gaps)."""
    W = np.ones((K, p))
    while (W == 0).mean() < share:
        j, a = rng.integers(p), rng.integers(K)
        W[a:a + (rng.integers(1, 8) if runs else 1), j] = 0.0
    return W


@settings(max_examples=20, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2 ** 32 - 1), share=st.sampled_from([0.0, 0.05, 0.1, 0.3]), confidence=st.booleans())
def test_weights_block_solver_is_each_frames_inverse(rig, ids, seed, share, confidence):
    rng = np.random.default_rng(seed)
    sub = marker_rig(rig, ids)
    K, p, B = 25, ids.size, sub.n_shapes
    W = _gappy_weights(rng, K, p, share)
    if confidence:
        W *= rng.uniform(0.2, 2.0, W.shape)
    D = sub.deltas.transpose(1, 2, 0).reshape(3 * p, B)
    mu = DAMPING * float(np.mean((D * D).sum(axis=0)))
    X = rng.normal(size=(K, 7, B))
    got = _weights_block_solver(D, mu, W)(X)
    w3 = np.repeat(W, 3, axis=1)
    for k in range(K):
        Ak = D.T @ (D * w3[k][:, None]) + mu * np.eye(B)
        want = X[k] @ np.linalg.inv(Ak)
        np.testing.assert_allclose(got[k], want, rtol=1e-7, atol=1e-9 * np.abs(want).max())


def test_joint_pose_with_runs_of_lost_markers_equals_each_frame_alone(rig, ids):
    """Frames solved together (grouped by their lost markers) give what each frame solved alone gives."""
    rng = np.random.default_rng(3)
    sub = marker_rig(rig, ids)
    K, p = 30, ids.size
    W = _gappy_weights(rng, K, p, 0.08)
    X = sub.neutral[None] + np.einsum("kb,bpi->kpi", rng.uniform(0, 0.6, (K, sub.n_shapes)) *
                                      (rng.random((K, sub.n_shapes)) < 0.2), sub.deltas)
    X = X + 0.05 * rng.normal(size=(K, 1, 3))
    X0 = np.where(W[..., None] > 0, X, 0.0)
    start = (np.broadcast_to(np.eye(3), (K, 3, 3)).copy(), np.zeros((K, 3)))
    R, t, w = _joint_pose(sub, X0, W, *start, iterations=4)
    for k in range(0, K, 7):
        Rk, tk, wk = _joint_pose(sub, X0[k:k + 1], W[k:k + 1], start[0][k:k + 1], start[1][k:k + 1], iterations=4)
        np.testing.assert_allclose(R[k], Rk[0], atol=1e-12)
        np.testing.assert_allclose(t[k], tk[0], atol=1e-10)
        np.testing.assert_allclose(w[k], wk[0], atol=1e-7)


# --------------------------------------------------------------------------- solve_markers on captures with gaps


def _capture_with_gaps(rig, ids, T, share, rng):
    W = np.clip(rng.uniform(-0.3, 0.9, (T, rig.n_shapes)), 0, 1) * (rng.random((T, rig.n_shapes)) < 0.3)
    F = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    X = F + np.array([0.3, -0.2, 1.0]) + 0.01 * rng.normal(size=F.shape)
    lost = _gappy_weights(rng, T, ids.size, share) == 0
    X[lost] = np.nan
    return X, W


@pytest.mark.parametrize("confidence", [False, True])
def test_solve_from_arrays_equals_the_per_frame_targets(rig, ids, confidence):
    rng = np.random.default_rng(11)
    X, _ = _capture_with_gaps(rig, ids, 40, 0.05, rng)
    conf = rng.uniform(0.5, 1.5, (40, ids.size)) if confidence else None
    s = solve_markers(X, ids, rig, confidence=conf)
    fitter = create("fitters", "sem-ls")
    targets = [MarkerTarget(X[k], ids, None if conf is None else conf[k]) for k in range(40)]
    res = fit_markers(fitter, rig, targets)
    np.testing.assert_allclose(s.weights, np.stack([r.weights for r in res]), atol=1e-12)
    np.testing.assert_allclose(s.rotations, np.stack([r.info["rotation"] for r in res]), atol=1e-13)
    np.testing.assert_allclose(s.rms, [r.info["rms"] for r in res], rtol=1e-12)
    assert s.lost.tolist() == [r.info["lost"] for r in res]


def test_gaps_keep_the_frames_batched_and_accurate(rig, ids, monkeypatch):
    """5 % of the samples lost in runs: the weights stay as accurate as without gaps, and the per-target
    bounded fallback (a Python loop of NNLS) runs for almost no frame."""
    calls = []
    real = sem._bounded_gram_lsq
    monkeypatch.setattr(sem, "_bounded_gram_lsq", lambda *a: calls.append(1) or real(*a))
    rng = np.random.default_rng(4)
    X, W = _capture_with_gaps(rig, ids, 200, 0.05, rng)
    s = solve_markers(X, ids, rig)
    assert s.lost.sum() > 0.04 * X.shape[0] * ids.size
    assert len(calls) <= 2
    assert np.abs(s.weights - W).mean() < 0.03


@pytest.mark.parametrize("bad, match", [
    ("inf", "frame 2: marker 5 has an infinite coordinate"),
    ("few", "frame 3: only 2 usable markers"),
    ("far", "frame 1: marker 0 has a coordinate of"),
    ("confidence", "frame 0: marker confidence must be >= 0"),
])
def test_bad_frames_still_raise_their_own_error(rig, ids, bad, match):
    X = np.broadcast_to(rig.neutral[ids], (5, ids.size, 3)).copy()
    conf = None
    if bad == "inf":
        X[2, 5, 1] = np.inf
    elif bad == "few":
        X[3, 2:] = np.nan
    elif bad == "far":
        X[1, 0, 0] = 1e15
    else:
        conf = np.ones((5, ids.size))
        conf[0, 4] = -1.0
    with pytest.raises(InputError, match=match):
        solve_markers(X, ids, rig, confidence=conf)
