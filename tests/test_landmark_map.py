"""The posterior-mode landmark fit of ``sem-ls`` (facegeom/methods/landmark_map.py): its pieces and what it recovers."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from facegeom.methods.landmark_map import box_qp, landmark_jacobian, map_weights, noise_precision
from facegeom.model import BlendshapeRig, LandmarkTarget, PinholeCamera, look_at_camera
from facegeom.model.pose import project_many


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(2, 12), st.integers(1, 30), st.sampled_from([1.0, None]))
def test_box_qp_matches_bounded_least_squares(seed, B, rows, upper):
    """The batched projected Newton solves ``min |Ax - b|^2 + a|x|^2`` in the box as BVLS does."""
    rng = np.random.default_rng(seed)
    K = 3
    A = rng.normal(size=(K, rows, B)) * rng.uniform(0.1, 10)
    b = rng.normal(size=(K, rows)) * rng.uniform(0.1, 10)
    a = 10.0 ** rng.uniform(-3, 1)
    H = np.einsum("kri,krj->kij", A, A) + a * np.eye(B)
    g = np.einsum("kri,kr->ki", A, b)
    x = box_qp(H, g, 0.0, upper)
    hi = np.inf if upper is None else upper
    for k in range(K):
        M = np.vstack([A[k], np.sqrt(a) * np.eye(B)])
        ref = lsq_linear(M, np.r_[b[k], np.zeros(B)], bounds=(0.0, hi), method="bvls", tol=1e-14).x
        assert x[k].min() >= 0.0 and (upper is None or x[k].max() <= upper)

        def f(z):
            return 0.5 * z @ H[k] @ z - g[k] @ z
        assert f(x[k]) <= f(ref) + 1e-9 * max(1.0, abs(f(ref)))
        np.testing.assert_allclose(x[k], ref, atol=1e-6 * max(1.0, np.abs(ref).max()))


def test_noise_precision_finds_the_noise_of_a_linear_model():
    rng = np.random.default_rng(3)
    K, N, B, sigma = 4, 4000, 20, 0.7
    J = rng.normal(size=(K, N, B))
    w = rng.uniform(0, 1, size=(K, B))
    y = np.einsum("knb,kb->kn", J, w) + rng.normal(size=(K, N)) * sigma
    beta = noise_precision(J, y, 1.0)
    np.testing.assert_allclose(1.0 / np.sqrt(beta), sigma, rtol=0.05)
    # fewer values than weights: the smaller Gram J J' gives the same fixed point as J'J
    Js, ys = J[:, :15], rng.normal(size=(K, 15)) * sigma  # noise the prior's weights cannot reproduce
    small = noise_precision(Js, ys, 50.0)
    lam, V = np.linalg.eigh(np.einsum("knb,knc->kbc", Js, Js))
    c2 = np.einsum("kbi,kb->ki", V, np.einsum("knb,kn->kb", Js, ys)) ** 2
    beta = np.full(K, 15 / (ys * ys).sum(axis=1))
    for _ in range(500):
        s = beta[:, None] * lam + 50.0
        rss = (ys * ys).sum(axis=1) - (beta[:, None] * c2 * (2 * s - beta[:, None] * lam) / s ** 2).sum(axis=1)
        beta = (15 - (beta[:, None] * lam / s).sum(axis=1)) / rss
    np.testing.assert_allclose(small, beta, rtol=1e-6)
    exact = noise_precision(Js, np.einsum("knb,kb->kn", Js, w), 1.0)  # data the weights reproduce: finite
    assert np.isfinite(exact).all() and (exact > 0).all()


@pytest.fixture(scope="module")
def rig(face_model):
    return BlendshapeRig.from_face_model(face_model)


def test_the_jacobian_is_the_derivative_of_the_projection(rig):
    rng = np.random.default_rng(1)
    ids = np.asarray(rig.landmark_ids)[17:]
    e = rng.uniform(0, 0.5, size=(2, rig.n_shapes))
    cams = [look_at_camera(rig.neutral, focal=900.0, image_size=(640, 480), yaw=y) for y in (-25.0, 10.0)]
    R = np.stack([c.R for c in cams])
    t = np.stack([c.t for c in cams])
    f, cx, cy = (np.array([getattr(c, a) for c in cams]) for a in ("focal", "cx", "cy"))
    P, J = landmark_jacobian(rig, ids, e, R, t, f, cx, cy)
    for b in (0, 7, rig.n_shapes - 1):
        h = 1e-6
        e2 = e.copy()
        e2[:, b] += h
        P2 = project_many(rig.neutral[ids][None] + np.tensordot(e2, rig.deltas[:, ids], 1), R, t, f, cx, cy)
        np.testing.assert_allclose(J[:, :, b], ((P2 - P) / h).reshape(2, -1), atol=1e-4)


def test_map_weights_recover_exact_landmarks_and_hold_the_bounds(rig):
    """Noise-free landmarks of all 68 points: the noise estimate falls towards zero and the prior with it."""
    rng = np.random.default_rng(5)
    ids = np.asarray(rig.landmark_ids)
    w = np.zeros(rig.n_shapes)
    w[rng.choice(rig.n_shapes, 6, replace=False)] = rng.uniform(0.2, 0.9, 6)
    cam = look_at_camera(rig.evaluate(w), focal=1000.0, image_size=(800, 800), yaw=15.0)
    L = cam.project(rig.evaluate(w)[ids])[None]
    args = [a[None] for a in (cam.R, cam.t)] + [np.array([getattr(cam, a)]) for a in ("focal", "cx", "cy")]
    e, sigma, _ = map_weights(rig, ids, L, *args, steps=6)
    assert e.min() >= 0.0 and e.max() <= 1.0
    F = rig.evaluate(e[0])[ids]
    assert np.abs(cam.project(F) - L[0]).max() < 0.05 and sigma[0] < 0.05


def test_sem_ls_fits_dense_landmarks_better_than_the_greedy_on_a_known_face(rig, face_model):
    """A dense expression (30 shapes at 0.05-0.4) seen by 40 landmarks with 1 px noise and the pose unknown:
    the default's posterior mode lands nearer the true face than the paper's greedy with the noise-aware stop."""
    from facegeom.constants import FACE_AREA
    from facegeom.methods.sem import SEMLSFitter

    rng = np.random.default_rng(8)
    ids = np.asarray(rig.landmark_ids)[list(range(0, 17, 2)) + list(range(17, 48))]
    errs = {"map": [], "greedy": []}
    for _ in range(6):
        w = np.zeros(rig.n_shapes)
        on = rng.choice(rig.n_shapes, 30, replace=False)
        w[on] = rng.uniform(0.05, 0.4, on.size)
        V = rig.evaluate(w)
        cam = look_at_camera(V, focal=1000.0, image_size=(800, 800), yaw=rng.uniform(-25, 25))
        tg = LandmarkTarget(cam.project(V[ids]) + rng.normal(size=(ids.size, 2)),
                            ids, PinholeCamera(cam.focal, cam.cx, cam.cy))
        for how in errs:
            r = SEMLSFitter(coefficients="auto" if how == "map" else "greedy").fit(rig, tg)
            errs[how].append(np.linalg.norm(r.vertices[:FACE_AREA] - V[:FACE_AREA], axis=1).mean())
    assert np.mean(errs["map"]) < np.mean(errs["greedy"]), errs


def test_sem_ls_landmark_batch_equals_one_at_a_time(rig):
    """``fit_many`` fits targets sharing their landmark vertices together; each equals its own fit up to the
    iterative solvers' stops (the batched pose estimate runs until every target's pose has settled)."""
    from facegeom.methods.sem import SEMLSFitter

    rng = np.random.default_rng(2)
    ids = np.asarray(rig.landmark_ids)[17:]
    targets = []
    for k in range(5):
        w = rng.uniform(0, 0.3, rig.n_shapes) * (rng.random(rig.n_shapes) < 0.5)
        V = rig.evaluate(w)
        cam = look_at_camera(V, focal=800.0 + 100 * k, image_size=(640, 480), yaw=rng.uniform(-30, 30))
        targets.append(LandmarkTarget(cam.project(V[ids]) + rng.normal(size=(ids.size, 2)) * 0.5, ids,
                                      PinholeCamera(cam.focal, cam.cx, cam.cy)))
    f = SEMLSFitter()
    many = f.fit_many(rig, targets, chunk=3)
    for tg, r in zip(targets, many):
        one = f.fit(rig, tg)
        np.testing.assert_allclose(r.weights, one.weights, atol=1e-6)
        assert r.info["order"] == one.info["order"]
        assert all(r.weights[i] > 0 for i in r.info["order"])


def test_the_prior_scale_by_the_evidence_stays_in_range_and_bad_values_are_refused(rig):
    from facegeom.errors import InputError
    from facegeom.methods.landmark_map import EVIDENCE_SD_RANGE
    from facegeom.methods.sem import SEMLSFitter

    rng = np.random.default_rng(4)
    ids = np.asarray(rig.landmark_ids)
    w = rng.uniform(0, 0.4, rig.n_shapes) * (rng.random(rig.n_shapes) < 0.6)
    V = rig.evaluate(w)
    cam = look_at_camera(V, focal=900.0, image_size=(640, 480), yaw=12.0)
    L = (cam.project(V[ids]) + rng.normal(size=(ids.size, 2)))[None]
    args = [a[None] for a in (cam.R, cam.t)] + [np.array([getattr(cam, a)]) for a in ("focal", "cx", "cy")]
    e, sigma, sd = map_weights(rig, ids, L, *args, prior_sd="evidence")
    assert EVIDENCE_SD_RANGE[0] <= sd[0] <= EVIDENCE_SD_RANGE[1] and 0.3 < sigma[0] < 3.0
    assert e.min() >= 0 and e.max() <= 1
    r = SEMLSFitter(prior_sd="evidence").fit(rig, LandmarkTarget(L[0], ids, PinholeCamera(cam.focal, cam.cx, cam.cy)))
    assert np.isfinite(r.weights).all()
    for bad in ("wide", 0.0, -1.0, float("inf"), True):
        with pytest.raises(InputError, match="prior_sd"):
            SEMLSFitter(prior_sd=bad)


# ----------------------------------------------------------------------------- the generic face's population prior
def test_population_prior_is_a_property_of_the_model(face_model):
    """The weights' covariance on the generic face: symmetric, positive definite, at least the performances'
    spread on the diagonal, the person's shape adding a spread the size of a weight's typical value; seeded, so the
    same model always gets the same prior (and the second call is the cached one)."""
    import time

    from facegeom.methods.landmark_map import PRIOR_SD, population_prior

    C = population_prior(face_model)
    B = face_model.n_expressions
    assert C.shape == (B, B)
    np.testing.assert_allclose(C, C.T, atol=1e-12)
    assert np.linalg.eigvalsh(C).min() >= PRIOR_SD ** 2 * (1 - 1e-9)
    shape_part = np.sqrt(np.diag(C - PRIOR_SD ** 2 * np.eye(B)).mean())
    assert 0.15 < shape_part < 0.45, shape_part
    t0 = time.perf_counter()
    again = population_prior(face_model)
    assert time.perf_counter() - t0 < 0.05
    np.testing.assert_array_equal(again, C)
    np.testing.assert_allclose(population_prior(face_model, 0.5) - C, (0.25 - PRIOR_SD ** 2) * np.eye(B), atol=1e-12)


def test_only_the_generic_face_stands_for_a_population(face_model):
    from facegeom.model.units import RigFrame

    generic = BlendshapeRig.from_face_model(face_model)
    assert generic.population is face_model
    assert BlendshapeRig.from_face_model(face_model, face_model.random_identity(1)).population is None
    assert generic.with_name_map(None).population is face_model
    assert generic.in_frame(RigFrame("mm", "y", "a test's", "a test's")).population is face_model
    assert generic.renamed(["jawOpen", "eyeBlinkLeft"])[0].population is None  # other shapes: another prior


def test_a_full_covariance_of_the_performances_spread_is_the_isotropic_prior(rig):
    rng = np.random.default_rng(9)
    ids = np.asarray(rig.landmark_ids)[17:]
    w = rng.uniform(0, 0.4, rig.n_shapes) * (rng.random(rig.n_shapes) < 0.5)
    V = rig.evaluate(w)
    cam = look_at_camera(V, focal=900.0, image_size=(640, 480), yaw=-14.0)
    L = (cam.project(V[ids]) + rng.normal(size=(ids.size, 2)))[None]
    args = [a[None] for a in (cam.R, cam.t)] + [np.array([getattr(cam, a)]) for a in ("focal", "cx", "cy")]
    e1, s1, _ = map_weights(rig, ids, L, *args, prior_sd=0.3)
    e2, s2, sd = map_weights(rig, ids, L, *args, prior_cov=0.09 * np.eye(rig.n_shapes))
    np.testing.assert_allclose(e2, e1, atol=1e-6)
    np.testing.assert_allclose(s2, s1, rtol=1e-6)
    np.testing.assert_allclose(sd, 0.3)


def test_the_generic_face_lets_the_weights_carry_the_persons_shape(rig, face_model):
    """Photos of other people (random identities of the model, a few shapes, 1 px, 23 landmarks, pose unknown):
    on the generic face the population prior (the default) predicts the 26 landmarks it was not given better
    than the performances' spread alone, and a person's own rig keeps the performances' spread."""
    from facegeom.methods.sem import SEMLSFitter
    from facegeom.model import EVAL_LANDMARKS_26, FIT_LANDMARKS_23

    lm = np.asarray(face_model.landmarks)
    fit_ids, held = lm[list(FIT_LANDMARKS_23)], lm[list(EVAL_LANDMARKS_26)]
    rng = np.random.default_rng(21)
    err = {"auto": [], 0.2: []}
    for _ in range(12):
        person = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng))
        assert SEMLSFitter()._prior_cov(person) is None
        w = np.zeros(rig.n_shapes)
        w[rng.choice(rig.n_shapes, 6, replace=False)] = rng.uniform(0.1, 0.5, 6)
        V = person.evaluate(w)
        cam = look_at_camera(V, focal=1000.0, image_size=(800, 800), yaw=rng.uniform(-20, 20))
        tg = LandmarkTarget(cam.project(V[fit_ids]) + rng.normal(size=(fit_ids.size, 2)), fit_ids,
                            PinholeCamera(cam.focal, cam.cx, cam.cy))
        io = np.linalg.norm(cam.project(V[lm[[39]]]) - cam.project(V[lm[[42]]]))
        for sd in err:
            r = SEMLSFitter(prior_sd=sd).fit(rig, tg)
            d = r.info["camera"].project(r.vertices[held]) - cam.project(V[held])
            err[sd].append(np.sqrt((d ** 2).sum(axis=1).mean()) / io)
    assert np.mean(err["auto"]) < np.mean(err[0.2]), err
