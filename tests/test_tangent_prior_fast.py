"""AmplitudeSmoother's tridiagonal GCV path equals the eigendecomposition it replaced (kept here as the reference)."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.methods.tangent import AUTO_LAMBDAS, TangentDeformer, _AutoSmoother
from facegeom.methods.tangent_prior import AmplitudeSmoother

from .conftest import grid_mesh


def reference_smooth_many(sm: AmplitudeSmoother, Y, F0, score0=None):
    """``AmplitudeSmoother.smooth_many`` as it was: one ``(M, M)`` eigendecomposition per frame."""
    T, m = Y.shape[:2]
    out = np.array(F0, dtype=np.float64)
    lam_out = np.zeros(T)
    used = np.zeros(T, dtype=bool)
    w = 1.0 / sm.amplitude(F0)  # (T, M)
    lam = sm.lambdas
    for i in range(T):
        mu, V = np.linalg.eigh(sm._penalty(w[i]))
        mu = np.clip(mu, 0.0, None)
        scale = mu.mean()
        if not scale > 0:
            continue
        mu /= scale
        z = V.T @ Y[i]
        zz = np.einsum("mi,mi->m", z, z)
        g = mu[None, :] / (1.0 + lam[:, None] * mu[None, :])  # (L, M)
        score = m * ((g * g) @ zz) / g.sum(axis=1) ** 2
        best = int(np.argmin(score))
        if score0 is not None and not score[best] < score0[i]:
            continue
        out[i] = V @ (z / (1.0 + lam[best] * mu)[:, None])
        lam_out[i], used[i] = lam[best], True
    return out, lam_out, used


def reference_candidates(sm: AmplitudeSmoother, y, a):
    mu, V = np.linalg.eigh(sm._penalty(1.0 / np.asarray(a, dtype=np.float64)))
    mu = np.clip(mu, 0.0, None)
    mu /= mu.mean() if mu.mean() > 0 else 1.0
    z = V.T @ y
    keep = 1.0 / (1.0 + sm.lambdas[:, None] * mu[None, :])
    return np.einsum("ij,lj,jd->lid", V, keep, z)


def _laplacian_energy(M, rng):
    """A connected weighted graph's Laplacian ``Lg`` (``Lg 1 = 0``), its energy ``Lg^2 + 0.1 Lg`` and the points."""
    P = rng.normal(size=(M, 3))
    W = np.exp(-((P[:, None] - P[None]) ** 2).sum(-1) / 0.5) * (rng.random((M, M)) < 0.4)
    W[np.arange(M - 1), np.arange(1, M)] += 0.1 + rng.random(M - 1)  # a chain: connected (null space = constants)
    W = np.triu(W, 1)
    W = W + W.T
    Lg = np.diag(W.sum(axis=1)) - W
    return Lg @ Lg + 0.1 * Lg, P


def _deformer_like(K, P):
    """The smoother pair as :class:`TangentDeformer` builds it (``prior="amplitude"``): energy through its eigenbasis."""
    auto = _AutoSmoother(K, "gcv")
    return auto, AmplitudeSmoother(auto.U @ (auto.k[:, None] * auto.U.T), P, AUTO_LAMBDAS)


def _assert_same(sm, Y, F0, score0=None, tol=1e-9):
    got = sm.smooth_many(Y, F0, score0)
    ref = reference_smooth_many(sm, Y, F0, score0)
    scale = max(np.abs(Y).max(), np.abs(F0).max(), 1e-300)
    assert np.abs(got[0] - ref[0]).max() <= tol * scale
    np.testing.assert_array_equal(got[2], ref[2])  # the same frames smoothed
    np.testing.assert_array_equal(got[1], ref[1])  # with the same lam
    return float(np.abs(got[0] - ref[0]).max() / scale), got


@pytest.mark.parametrize("M", [5, 40, 120])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tridiagonal_gcv_equals_the_eigendecomposition(M, seed):
    rng = np.random.default_rng(seed)
    K, P = _laplacian_energy(M, rng)
    auto, sm = _deformer_like(K, P)
    T = 6
    Y = rng.normal(0.0, 1.0, (T, M, 3)) * 10.0 ** rng.uniform(-3, 1) + rng.normal(0.0, 0.5, (T, 1, 3))
    C, _ = auto.coefficients_many(Y)
    F0 = np.matmul(auto.U, C)  # the default smoothing, as in deform_many
    _, (_, lam, used) = _assert_same(sm, Y, F0)
    assert used.all() and (lam > 0).any()
    _assert_same(sm, Y, F0, auto.score)
    _assert_same(sm, Y, F0, auto.score * rng.uniform(0.3, 3.0, T))
    _, (out, _, used) = _assert_same(sm, Y, F0, np.zeros(T))  # never lower: nothing smoothed
    assert not used.any() and (out == F0).all()


def _reference_best_score(sm, y, f0):
    """The reference's lowest GCV score of one frame (as in :func:`reference_smooth_many`)."""
    mu = np.clip(np.linalg.eigvalsh(sm._penalty(1.0 / sm.amplitude(f0[None])[0])), 0.0, None)
    V = np.linalg.eigh(sm._penalty(1.0 / sm.amplitude(f0[None])[0]))[1]
    mu /= mu.mean()
    zz = ((V.T @ y) ** 2).sum(axis=1)
    g = mu[None, :] / (1.0 + sm.lambdas[:, None] * mu[None, :])
    return float((y.shape[0] * ((g * g) @ zz) / g.sum(axis=1) ** 2).min())


def test_frames_of_both_outcomes_against_score0():
    rng = np.random.default_rng(3)
    K, P = _laplacian_energy(40, rng)
    auto, sm = _deformer_like(K, P)
    Y = rng.normal(size=(8, 40, 3))
    F0 = np.matmul(auto.U, auto.coefficients_many(Y)[0])
    # score0 just above each frame's best amplitude score on even frames, just below on odd ones
    best = np.array([_reference_best_score(sm, Y[i], F0[i]) for i in range(8)])
    score0 = best * np.where(np.arange(8) % 2 == 0, 1.0 + 1e-6, 1.0 - 1e-6)
    _, (_, _, used) = _assert_same(sm, Y, F0, score0)
    np.testing.assert_array_equal(used, np.arange(8) % 2 == 0)


def test_degenerate_cases():
    rng = np.random.default_rng(4)
    # M = 3: a triangle
    K, P = _laplacian_energy(3, rng)
    auto, sm = _deformer_like(K, P)
    Y = rng.normal(size=(6, 3, 3))
    F0 = np.matmul(auto.U, auto.coefficients_many(Y)[0])
    _assert_same(sm, Y, F0)
    _assert_same(sm, Y, F0, auto.score)
    # all amplitudes equal (equal displacement lengths; zero displacements: the floor), M = 5 and 40
    for M in (5, 40):
        K, P = _laplacian_energy(M, rng)
        _, sm = _deformer_like(K, P)
        Y = rng.normal(size=(4, M, 3))
        for F0 in (np.ones_like(Y), np.zeros_like(Y)):
            assert np.allclose(sm.amplitude(F0), 1.0)
            _assert_same(sm, Y, F0)
            _assert_same(sm, Y, F0, np.full(4, 0.5))
        # zero markers: every score 0, the first candidate (lam = 0) in both
        _, (out, lam, used) = _assert_same(sm, np.zeros_like(Y), Y)
        assert used.all() and (lam == 0).all() and (out == 0).all()
    # no energy at all: Q = 0, nothing smoothed (both skip the frames)
    sm = AmplitudeSmoother(np.zeros((6, 6)), rng.normal(size=(6, 3)), AUTO_LAMBDAS)
    Y = rng.normal(size=(3, 6, 3))
    _, (out, _, used) = _assert_same(sm, Y, Y + 1.0)
    assert not used.any() and (out == Y + 1.0).all()
    # M = 1 and 2: the eigendecomposition
    for M in (1, 2):
        sm = AmplitudeSmoother(np.eye(M) - 1.0 / M, rng.normal(size=(M, 3)), AUTO_LAMBDAS)
        Y = rng.normal(size=(3, M, 3))
        _assert_same(sm, Y, Y)


def test_an_indefinite_energy_takes_the_eigendecomposition(monkeypatch):
    """Where the clipping of negative eigenvalues matters (not a semi-definite K), the result is still the same."""
    calls = []
    eigh = AmplitudeSmoother._smooth_frame_eigh
    monkeypatch.setattr(AmplitudeSmoother, "_smooth_frame_eigh", lambda self, *a: calls.append(1) or eigh(self, *a))
    rng = np.random.default_rng(5)
    M = 30
    J = np.eye(M) - 1.0 / M
    S = rng.normal(size=(M, M))
    K = J @ (S + S.T) @ J  # K 1 = 0, eigenvalues of both signs
    sm = AmplitudeSmoother(K, rng.normal(size=(M, 3)), AUTO_LAMBDAS)
    Y = rng.normal(size=(5, M, 3))
    F0 = Y + 0.1 * rng.normal(size=Y.shape)
    _assert_same(sm, Y, F0)
    _assert_same(sm, Y, F0, np.full(5, 0.5))
    assert len(calls) == 10  # every frame
    calls.clear()
    K2, P = _laplacian_energy(M, rng)
    _, good = _deformer_like(K2, P)
    _assert_same(good, Y, F0)
    assert not calls  # a semi-definite energy: never


def test_the_deformers_energy_on_a_mesh():
    V, F = grid_mesh(15, 15, bump=0.3)
    rng = np.random.default_rng(6)
    for k in (12, 40, 90):
        h = rng.choice(len(V), k, replace=False)
        d = TangentDeformer(prior="amplitude").fit(V, F, h)
        Y = 0.05 * np.sin(3.0 * V[h][None, :, :1] + rng.uniform(0, 3, (7, 1, 1))) + rng.normal(0, 0.01, (7, k, 3))
        C, _ = d.smoother_.coefficients_many(Y)
        F0 = np.matmul(d.smoother_.U, C)
        _assert_same(d.amplitude_, Y, F0)
        _assert_same(d.amplitude_, Y, F0, d.smoother_.score)


def test_chunks_and_single_frames_agree():
    """Frames are solved in chunks: the result does not depend on which frames share one."""
    import facegeom.methods.tangent_prior as tp

    rng = np.random.default_rng(7)
    K, P = _laplacian_energy(40, rng)
    auto, sm = _deformer_like(K, P)
    Y = rng.normal(size=(50, 40, 3))
    F0 = np.matmul(auto.U, auto.coefficients_many(Y)[0])
    whole = sm.smooth_many(Y, F0, auto.score)
    old = tp._CHUNK_ROWS
    try:
        tp._CHUNK_ROWS = 1  # one frame per chunk
        single = sm.smooth_many(Y, F0, auto.score)
    finally:
        tp._CHUNK_ROWS = old
    np.testing.assert_allclose(whole[0], single[0], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(whole[1], single[1])
    np.testing.assert_array_equal(whole[2], single[2])
    f, lam, used = sm.smooth(Y[3], F0[3], float(auto.score[3]))
    assert np.abs(f - whole[0][3]).max() <= 1e-12 and lam == whole[1][3] and used == whole[2][3]


@pytest.mark.parametrize("M", [3, 5, 40, 120])
def test_candidates_equal_the_eigendecomposition(M):
    rng = np.random.default_rng(8)
    K, P = _laplacian_energy(M, rng)
    _, sm = _deformer_like(K, P)
    y = rng.normal(size=(M, 3))
    for a in (rng.uniform(0.2, 3.0, M), np.ones(M)):
        got, ref = sm.candidates(y, a), reference_candidates(sm, y, a)
        assert got.shape == ref.shape == (AUTO_LAMBDAS.size, M, 3)
        assert np.abs(got - ref).max() <= 1e-9 * np.abs(y).max()
    sm0 = AmplitudeSmoother(np.zeros((M, M)), P, AUTO_LAMBDAS)  # no energy: every candidate is y
    np.testing.assert_allclose(sm0.candidates(y, np.ones(M)), reference_candidates(sm0, y, np.ones(M)), atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), M=st.sampled_from([3, 4, 7, 20, 40, 80]),
       log_scale=st.floats(-4.0, 3.0), offset=st.floats(-5.0, 5.0), power=st.sampled_from([1.0, 1.5, 2.0]),
       with_score0=st.booleans())
def test_property_same_as_the_eigendecomposition(seed, M, log_scale, offset, power, with_score0):
    rng = np.random.default_rng(seed)
    K, P = _laplacian_energy(M, rng)
    auto = _AutoSmoother(K, "gcv")
    sm = AmplitudeSmoother(auto.U @ (auto.k[:, None] * auto.U.T), P, AUTO_LAMBDAS, power=power)
    T = 4
    Y = (rng.normal(size=(T, M, 3)) + offset * rng.normal(size=(T, 1, 3))) * 10.0 ** log_scale
    F0 = np.matmul(auto.U, auto.coefficients_many(Y)[0])
    _assert_same(sm, Y, F0, auto.score * rng.uniform(0.5, 2.0, T) if with_score0 else None)


@pytest.mark.parametrize("lambdas", [[-0.3, 0.0, 0.1, 1.0, 10.0], [-1e-3, 0.0, 1.0], [0.0], [5.0, 0.5]])
def test_other_candidate_lists(lambdas):
    """Any candidates: a negative one that makes I + lam Q indefinite sends its frames to the eigendecomposition."""
    rng = np.random.default_rng(9)
    K, P = _laplacian_energy(30, rng)
    auto = _AutoSmoother(K, "gcv")
    sm = AmplitudeSmoother(auto.U @ (auto.k[:, None] * auto.U.T), P, np.array(lambdas))
    Y = rng.normal(size=(12, 30, 3))
    F0 = Y * rng.uniform(0.0, 2.0, (12, 30, 1)) ** 3  # very unequal amplitudes: the spectra differ between frames
    auto.coefficients_many(Y)
    _assert_same(sm, Y, F0)
    _assert_same(sm, Y, F0, auto.score)


def test_a_negative_candidate_for_some_frames_only(monkeypatch):
    """Frames whose I + lam Q stays definite keep the tridiagonal path, the others take the eigendecomposition."""
    rng = np.random.default_rng(10)
    K, P = _laplacian_energy(30, rng)
    auto = _AutoSmoother(K, "gcv")
    Ks = auto.U @ (auto.k[:, None] * auto.U.T)
    Y = rng.normal(size=(12, 30, 3))
    F0 = Y * rng.uniform(0.0, 2.0, (12, 30, 1)) ** 3
    probe = AmplitudeSmoother(Ks, P, AUTO_LAMBDAS)
    top = []  # each frame's largest eigenvalue of Q relative to the mean
    for w in 1.0 / probe.amplitude(F0):
        mu = np.linalg.eigvalsh(probe._penalty(w))
        top.append(mu[-1] / np.clip(mu, 0.0, None).mean())
    sm = AmplitudeSmoother(Ks, P, np.r_[-1.0 / np.median(top), AUTO_LAMBDAS])  # indefinite for half the frames
    calls = []
    eigh = AmplitudeSmoother._smooth_frame_eigh
    monkeypatch.setattr(AmplitudeSmoother, "_smooth_frame_eigh", lambda self, *a: calls.append(1) or eigh(self, *a))
    _assert_same(sm, Y, F0)
    assert 0 < len(calls) < 12


def test_a_non_finite_frame_stays_alone():
    """A frame with NaN markers (or NaN amplitudes) comes out as the eigendecomposition makes it; the others as ever."""
    rng = np.random.default_rng(11)
    K, P = _laplacian_energy(20, rng)
    auto, sm = _deformer_like(K, P)
    Y = rng.normal(size=(6, 20, 3))
    F0 = np.matmul(auto.U, auto.coefficients_many(Y)[0])
    Y[2, 4, 1] = np.nan
    for score0 in (None, auto.score):
        got, ref = sm.smooth_many(Y, F0, score0), reference_smooth_many(sm, Y, F0, score0)
        np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-12)  # NaN where the reference has NaN
        np.testing.assert_array_equal(got[1], ref[1])
        np.testing.assert_array_equal(got[2], ref[2])
    assert np.isnan(got[0][2]).all() or (got[0][2] == F0[2]).all()
