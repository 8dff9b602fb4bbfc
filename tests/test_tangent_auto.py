"""The self-tuned TangentDeformer (``beta="auto"``, the default): GCV-chosen soft labels per deform."""
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom.errors import InputError, SolveError
from facegeom.methods.tangent import AUTO_LAMBDAS, AUTO_POWERS, TangentDeformer, TangentSolver

from .conftest import grid_mesh


def _bend(V):
    """A smooth deformation of the grid: a sine bend across x growing along y, and a shear."""
    W = V.copy()
    x, y = V[:, 0] / V[:, 0].max(), V[:, 1] / V[:, 1].max()
    W[:, 2] += 0.3 * np.sin(2 * x) * y
    W[:, 0] += 0.05 * y
    return W


def _case():
    V, F = grid_mesh(15, 15, bump=0.3)
    h = np.random.default_rng(0).choice(len(V), 30, replace=False)
    return V, F, h, _bend(V)


def test_clean_markers_are_interpolated_exactly():
    V, F, h, T = _case()
    d = TangentDeformer().fit(V, F, h)
    Y = d.deform(T[h])
    assert d.lambda_ == 0.0  # GCV picks the smallest regularisation: exact interpolation
    np.testing.assert_allclose(Y[h], T[h], atol=1e-12)
    np.testing.assert_allclose(Y, TangentDeformer(beta=None).fit(V, F, h).deform(T[h]), atol=1e-12)


def test_noise_is_smoothed_and_the_error_drops():
    V, F, h, T = _case()
    auto, exact = TangentDeformer().fit(V, F, h), TangentDeformer(beta=None).fit(V, F, h)
    err_auto, err_exact, lams = [], [], []
    for seed in range(8):
        P = T[h] + np.random.default_rng(seed).normal(0.0, 0.03, (h.size, 3))
        err_auto.append(np.linalg.norm(auto.deform(P) - T, axis=1).mean())
        lams.append(auto.lambda_)
        err_exact.append(np.linalg.norm(exact.deform(P) - T, axis=1).mean())
    assert min(lams) > 0  # every noisy frame is smoothed
    assert np.mean(err_auto) < 0.8 * np.mean(err_exact)


def test_auto_equals_soft_labels_of_the_chosen_weight():
    """The smoother is eq. 18 with soft labels: the chosen lambda's result equals TangentSolver with that beta."""
    V, F, h, T = _case()
    P = T[h] + np.random.default_rng(1).normal(0.0, 0.03, (h.size, 3))
    d = TangentDeformer(align="none", smoothness=0.0, d=3, field="position", select="gcv",
                        prior="uniform").fit(V, F, h)
    Y = d.deform(P)
    assert d.power_ == 1.0
    k = np.clip(np.linalg.eigvalsh(d.solver_.schur_complement()), 0, None)
    beta = k.mean() / d.lambda_  # lambda is relative to the mean eigenvalue of the labels' energy
    Y_soft = TangentDeformer(align="none", smoothness=0.0, d=3, field="position", beta=beta).fit(V, F, h).deform(P)
    np.testing.assert_allclose(Y, Y_soft, atol=1e-9)


def test_deform_many_reports_lambda_per_frame():
    V, F, h, T = _case()
    d = TangentDeformer().fit(V, F, h)
    noise = np.random.default_rng(2).normal(0.0, 0.03, (h.size, 3))
    P = np.stack([T[h], T[h] + noise])
    Y = d.deform_many(P)
    assert d.lambda_.shape == (2,) and d.lambda_[0] == 0.0 and d.lambda_[1] > 0
    assert set(d.lambda_) <= set(AUTO_LAMBDAS)
    np.testing.assert_allclose(Y[1], d.deform(P[1]), atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       shift=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3))
def test_rigid_motion_of_all_markers_moves_the_face_rigidly(rotvec, shift):
    V, F, h, _ = _case()
    R = Rotation.from_rotvec(rotvec).as_matrix()
    moved = V @ R.T + shift
    np.testing.assert_allclose(TangentDeformer().fit(V, F, h).deform(moved[h]), moved, atol=1e-8)


def test_parameter_validation():
    for bad in ("automatic", "", 0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="beta"):
            TangentDeformer(beta=bad)
    s = TangentSolver(np.array([[1.0, -1.0], [-1.0, 1.0]]), [0], beta=1.0)
    with pytest.raises(SolveError, match="hard constraints"):
        s.schur_complement()
    assert TangentDeformer().beta == "auto" and TangentDeformer().get_params()["beta"] == "auto"


def test_deform_time_budget_on_the_face(face_model):
    """Loose: the budget is 2 ms per deform and 0.5 s per fit at 9.4k vertices (5x here: shared machines)."""
    from threadpoolctl import threadpool_limits

    from facegeom.model import layout

    m = face_model
    h = layout(m, "random120", 7)
    d = TangentDeformer()
    t = time.perf_counter()
    d.fit(m.neutral, m.triangles, h)
    fit_s = time.perf_counter() - t
    P = m.face(None, {"jawOpen": 0.5})[h] + np.random.default_rng(0).normal(0, 0.02, (h.size, 3))
    times = []
    with threadpool_limits(1):  # two BLAS threads on a loaded 2-core machine stall the (n, k) product
        for _ in range(15):
            t = time.perf_counter()
            d.deform(P)
            times.append(time.perf_counter() - t)
    assert min(times) < 0.010 and fit_s < 2.5


def test_robust_kabsch_ignores_the_markers_an_expression_moves():
    from facegeom.methods.tangent import kabsch, kabsch_many, robust_kabsch, robust_kabsch_many

    rng = np.random.default_rng(3)
    P = rng.normal(size=(60, 3))
    R = Rotation.from_rotvec([0.2, -0.4, 0.1]).as_matrix()
    Q = P @ R.T + [1.0, 2.0, -1.0]
    R1, t1 = robust_kabsch(P, Q)  # a rigid motion is recovered exactly
    np.testing.assert_allclose(R1, R, atol=1e-12)
    np.testing.assert_allclose(t1, [1.0, 2.0, -1.0], atol=1e-12)
    moved = Q.copy()
    moved[:15] += [0.0, -0.8, 0.3]  # an "expression" drags a quarter of the markers
    plain_err = np.abs(kabsch(P, moved)[0] - R).max()
    robust_err = np.abs(robust_kabsch(P, moved)[0] - R).max()
    assert robust_err < 0.2 * plain_err
    frames = np.stack([Q, moved, moved + [0.1, 0, 0]])
    for m in (60, 59):  # the batched median: an even and an odd number of markers
        Rm, tm = robust_kabsch_many(P[:m], frames[:, :m])
        for i, F in enumerate(frames[:, :m]):
            Ri, ti = robust_kabsch(P[:m], F)
            np.testing.assert_allclose(Rm[i], Ri, atol=1e-10)
            np.testing.assert_allclose(tm[i], ti, atol=1e-10)
    Rw, tw = kabsch_many(P, frames, np.ones((3, 60)))
    np.testing.assert_allclose(Rw, kabsch_many(P, frames)[0], atol=1e-12)
    with pytest.raises(InputError, match="align"):
        TangentDeformer(align="robustly")


def test_ml_selection_smooths_noise_and_keeps_clean_markers_close():
    """``select="ml"``: REML over the weight and the spectral power; noisy frames are smoothed, clean ones hardly."""
    V, F, h, T = _case()
    ml, exact = TangentDeformer(select="ml").fit(V, F, h), TangentDeformer(beta=None).fit(V, F, h)
    err_ml, err_exact = [], []
    for seed in range(8):
        P = T[h] + np.random.default_rng(seed).normal(0.0, 0.03, (h.size, 3))
        err_ml.append(np.linalg.norm(ml.deform(P) - T, axis=1).mean())
        assert ml.lambda_ > 0 and ml.power_ in AUTO_POWERS
        err_exact.append(np.linalg.norm(exact.deform(P) - T, axis=1).mean())
    assert np.mean(err_ml) < 0.8 * np.mean(err_exact)
    clean = ml.deform(T[h])
    assert np.abs(clean[h] - T[h]).max() < 0.01 * np.abs(T[h] - V[h]).max()  # clean markers are (nearly) met
    with pytest.raises(InputError, match="select"):
        TangentDeformer(select="reml")


def test_gcv_smoother_in_eigen_coefficients_equals_the_label_basis():
    """deform maps the smoothed eigen-coefficients with U^T map; the same as smoothing the labels, then the map."""
    V, F, h, T = _case()
    d = TangentDeformer(align="none", prior="uniform").fit(V, F, h)
    Z = T[h] - V[h] + np.random.default_rng(4).normal(0.0, 0.03, (h.size, 3))
    Zs, g = d.smoother_.smooth(Z)
    np.testing.assert_allclose(d.deform(T[h] + Z - (T[h] - V[h])), d.solver_.solve(Zs) + V, atol=1e-12)
    assert d.lambda_ == d.smoother_.lambdas[g] > 0


# ---------------------------------------------------------------- the amplitude prior (issue 19 §2, an option)
def _half_moving_case():
    """The grid with a smooth bulge on one half and the other half still: displacements of very unequal size."""
    V, F = grid_mesh(15, 15, bump=0.3)
    h = np.random.default_rng(5).choice(len(V), 40, replace=False)
    x = V[:, 0] / V[:, 0].max()
    T = V.copy()
    T[:, 2] += 0.4 * np.clip(x - 0.5, 0.0, None) ** 2 * 4.0 * np.sin(np.pi * V[:, 1] / V[:, 1].max())
    return V, F, h, T, x


def test_amplitude_prior_smooths_still_regions_more():
    V, F, h, T, x = _half_moving_case()
    amp = TangentDeformer(prior="amplitude").fit(V, F, h)
    uni = TangentDeformer(prior="uniform").fit(V, F, h)
    still = x < 0.4
    e_amp, e_uni, s_amp, s_uni = [], [], [], []
    for seed in range(8):
        P = T[h] + np.random.default_rng(seed).normal(0.0, 0.02, (h.size, 3))
        da, du = np.linalg.norm(amp.deform(P) - T, axis=1), np.linalg.norm(uni.deform(P) - T, axis=1)
        assert amp.lambda_ > 0
        e_amp.append(da.mean())
        e_uni.append(du.mean())
        s_amp.append(da[still].mean())
        s_uni.append(du[still].mean())
    assert np.mean(s_amp) < 0.9 * np.mean(s_uni)  # the still half keeps less of the noise
    assert np.mean(e_amp) < np.mean(e_uni)


def test_amplitude_smoother_is_the_posterior_mean_of_its_prior():
    """The eigenbasis GCV path equals the direct solve (I + lam Q)^-1 y, Q the energy of A^-1 (f - c 1)."""
    V, F, h, T, _ = _half_moving_case()
    d = TangentDeformer(prior="amplitude", align="none").fit(V, F, h)
    sm = d.amplitude_
    y = T[h] - V[h] + np.random.default_rng(6).normal(0.0, 0.02, (h.size, 3))
    f0 = d.smoother_.smooth(y)[0]
    f, lam, used = sm.smooth(y, f0)
    assert lam > 0 and used
    w = 1.0 / sm.amplitude(f0[None])[0]
    P = np.eye(h.size) - np.outer(np.ones(h.size), w) / w.sum()  # f = c 1 + A g, g orthogonal to constants
    Q = P.T @ (w[:, None] * sm.K * w[None, :]) @ P
    mu = np.clip(np.linalg.eigvalsh(Q), 0.0, None)
    direct = np.linalg.solve(np.eye(h.size) + lam / mu.mean() * Q, y)
    np.testing.assert_allclose(f, direct, atol=1e-10)
    np.testing.assert_allclose((f - y).mean(axis=0), 0.0, atol=1e-10)  # no pull on the constant (the mean)
    a = sm.amplitude(f0[None])[0]
    assert abs(a.mean() - 1.0) < 1e-12 and (a > 0).all()


def test_amplitude_deform_many_equals_deform_and_clean_frames_stay_exact():
    V, F, h, T, _ = _half_moving_case()
    d = TangentDeformer(prior="amplitude").fit(V, F, h)
    assert d.amplitude_ is not None and TangentDeformer().fit(V, F, h).amplitude_ is None
    rng = np.random.default_rng(7)
    P = np.stack([T[h], T[h] + rng.normal(0.0, 0.02, (h.size, 3)), T[h] + rng.normal(0.0, 0.01, (h.size, 3))])
    Y = d.deform_many(P)
    lams = d.lambda_.copy()
    assert lams[0] == 0.0 and lams[1] > 0
    for i in range(3):
        np.testing.assert_allclose(Y[i], d.deform(P[i]), atol=1e-12)
        assert d.lambda_ == lams[i]
    np.testing.assert_allclose(Y[0][h], T[h], atol=1e-12)  # clean markers: exact interpolation
    with pytest.raises(InputError, match="prior"):
        TangentDeformer(prior="student")


@settings(max_examples=10, deadline=None)
@given(rotvec=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       shift=st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3))
def test_amplitude_prior_is_equivariant_to_rigid_motions_of_noisy_markers(rotvec, shift):
    """Moving noisy markers rigidly moves the driven face by the same motion (the prior sees only lengths)."""
    V, F, h, T, _ = _half_moving_case()
    d = TangentDeformer(prior="amplitude").fit(V, F, h)
    P = T[h] + np.random.default_rng(8).normal(0.0, 0.02, (h.size, 3))
    R = Rotation.from_rotvec(rotvec).as_matrix()
    Y = d.deform(P)
    assert d.lambda_ > 0
    np.testing.assert_allclose(d.deform(P @ R.T + shift), Y @ R.T + shift, atol=1e-8)
