"""The fast batched paths of SEM give what a direct, unvectorised implementation of the same algorithm gives.

The batched landmark greedy computes eq. 22's index from per-target precomputed camera-space terms, evaluates it
only where a candidate has a positive coefficient, and cuts one recorded pass for ``stop="ric"``; the orthogonal
mesh path works on orthonormalised selections. These tests compare them with plain per-target loops written
straight from the definitions (projection of the moved face, least squares by ``lstsq``).
"""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.methods.sem import SEMFitter, SEMLSFitter, sem_orthogonal_gram
from facegeom.model import FIT_LANDMARKS_23, BlendshapeRig, LandmarkTarget, PinholeCamera, look_at_camera


@pytest.fixture(scope="module")
def rig(face_model):
    return BlendshapeRig.from_face_model(face_model, face_model.random_identity(3))


def _greedy_reference(rig, ids, uv, cam, upper, min_gain=None):
    """SEM on landmarks, one target, straight from eqs. 18-22 with the camera's own projection."""
    B = rig.n_shapes
    P1 = cam.project(rig.neutral[ids])
    M = np.stack([(cam.project(rig.neutral[ids] + rig.deltas[b, ids]) - P1).ravel() for b in range(B)])
    nrm2 = (M * M).sum(axis=1)
    dT = (uv - P1).ravel()
    tt = dT @ dT
    e = np.zeros(B)
    alive = nrm2 > 1e-300
    order = []
    r_prev = 1.0
    for step in range(B):
        if not alive.any():
            break
        F = rig.neutral[ids] + np.tensordot(e, rig.deltas[:, ids], 1)
        res = (uv - cam.project(F)).ravel()
        proj = M @ res
        ei = np.where(proj > 1e-9 * np.sqrt(tt) * np.sqrt(nrm2), proj / nrm2, 0.0)
        if upper is not None:
            ei = np.minimum(ei, upper)
        if step > 0:
            for b in np.flatnonzero(alive & (ei > 0)):
                moved = cam.project(F + ei[b] * rig.deltas[b, ids])
                r = 1.0 - ((moved - P1).ravel() @ dT) / tt
                if abs(r) - abs(r_prev) > 1e-11:
                    alive[b] = False
        go = (alive & (ei > 0)).any()
        score = np.where(alive, proj / np.sqrt(nrm2), -np.inf)
        p = int(np.argmax(score))
        gain = 2 * ei[p] * proj[p] - ei[p] ** 2 * nrm2[p]
        if min_gain is not None and gain < min_gain:
            go = False
        alive[p] = False
        if not go:
            break
        e[p] += ei[p]
        order.append(p)
        F = rig.neutral[ids] + np.tensordot(e, rig.deltas[:, ids], 1)
        r_prev = 1.0 - ((cam.project(F) - P1).ravel() @ dT) / tt
    return e, order


def _landmark_targets(face_model, rig, count, seed, dense=False):
    rng = np.random.default_rng(seed)
    ids = face_model.landmarks[list(FIT_LANDMARKS_23)]
    out = []
    for _ in range(count):
        if dense:
            w = np.clip(rng.normal(0.15, 0.2, rig.n_shapes), 0, 1)
        else:
            w = np.where(rng.random(rig.n_shapes) < 0.08, rng.uniform(0.2, 1.0, rig.n_shapes), 0.0)
        V = rig.evaluate(w)
        cam = look_at_camera(V, yaw=rng.uniform(-25, 25), pitch=rng.uniform(-10, 10))
        out.append(LandmarkTarget(cam.project(V[ids]) + rng.normal(size=(ids.size, 2)), ids, cam))
    return out


@pytest.mark.parametrize("dense", [False, True])
def test_landmark_greedy_matches_a_direct_implementation(face_model, rig, dense):
    targets = _landmark_targets(face_model, rig, 4, 11 + dense, dense)
    for fitter in (SEMFitter(), SEMFitter(clamp=True, stop="ric"), SEMLSFitter(coefficients="greedy")):
        got = fitter.fit_many(rig, targets, chunk=3)
        for tg, r in zip(targets, got):
            e1, order1 = _greedy_reference(rig, tg.vertex_ids, tg.points2d, tg.camera, fitter._upper)
            if fitter.stop == "ric":  # the second pass of stop="ric", run again from the start
                F = rig.evaluate(e1, tg.vertex_ids)
                resid = ((tg.camera.project(F) - tg.points2d) ** 2).sum()
                thr = float(fitter._ric_threshold(rig, resid, tg.points2d.size, e1))
                e1, order1 = _greedy_reference(rig, tg.vertex_ids, tg.points2d, tg.camera, fitter._upper, thr)
            assert r.info["order"] == [int(i) for i in order1]
            np.testing.assert_allclose(r.weights, e1, atol=1e-9)


def _orthogonal_reference(c, G, tt, m, D, dT):
    """OMP with the ESim choice and a GCV cut, every coefficient vector re-solved by lstsq (no bounds)."""
    B = G.shape[0]
    sel, alive = [], np.diag(G) > 1e-300
    best = (tt / m, np.zeros(B), [])
    e = np.zeros(B)
    for _ in range(B):
        proj = c - G @ e
        score = np.where(alive, proj / np.sqrt(np.where(alive, np.diag(G), 1.0)), -np.inf)
        p = int(np.argmax(score))
        if not score[p] > 1e-9 * np.sqrt(tt):
            break
        alive[p] = False
        sel.append(p)
        x = np.linalg.lstsq(D[:, sel], dT, rcond=None)[0]
        e = np.zeros(B)
        e[sel] = x
        rss = float(((dT - D @ e) ** 2).sum())
        gcv = m * rss / (m - len(sel)) ** 2
        if gcv < best[0]:
            best = (gcv, e.copy(), list(sel))
    return best[1], best[2]


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), noise=st.sampled_from([0.0, 0.02, 0.3]), density=st.sampled_from([0.1, 0.5]))
def test_orthogonal_path_matches_explicit_least_squares(seed, noise, density):
    rng = np.random.default_rng(seed)
    n, B = 60, 12  # a small random "rig": 60 coordinates, 12 correlated shapes
    D = rng.normal(size=(n, B)) + 0.5 * rng.normal(size=(n, 1))
    w = np.where(rng.random(B) < density, rng.uniform(0.2, 1.0, B), 0.0)
    dT = D @ w + noise * rng.normal(size=n)
    G = D.T @ D
    e, order = sem_orthogonal_gram(D.T @ dT, G, dT @ dT, n)
    e_ref, order_ref = _orthogonal_reference(D.T @ dT, G, dT @ dT, n, D, dT)
    assert [int(i) for i in order if i >= 0] == order_ref
    np.testing.assert_allclose(e, e_ref, atol=1e-8 * max(1.0, np.abs(e_ref).max()))


def test_threads_give_the_one_thread_result(face_model, rig):
    targets = _landmark_targets(face_model, rig, 6, 5)
    unposed = [LandmarkTarget(t.points2d, t.vertex_ids, PinholeCamera(t.camera.focal, t.camera.cx, t.camera.cy))
               for t in targets]
    f = SEMLSFitter()
    one = f.fit_many(rig, unposed + targets, chunk=2, workers=1)
    two = f.fit_many(rig, unposed + targets, chunk=2, workers=2)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a.weights, b.weights)
        np.testing.assert_array_equal(a.info["camera"].t, b.info["camera"].t)
        assert a.info["order"] == b.info["order"]


def test_speed_experiment_tables(face_model, rig):
    from facegeom.bench import fit as bf
    from facegeom.registry import parse_methods

    specs = parse_methods("sem-ls;l2reg", "fitters", [])
    mesh = bf.run_mesh_throughput(rig, specs, count=40, one_by_one=3, repeats=2)
    assert [r["method"] for r in mesh] == ["sem-ls", "l2reg"]
    assert mesh[0]["path"] == "batched" and all(r["fits_per_s"] > 0 for r in mesh)
    marks = bf.run_landmark_throughput(face_model, specs[:1], count=8, repeats=2)
    assert marks[0]["estimated_pose"] > 0 and marks[0]["known_pose"] > 0
    table = bf.summarize({"landmark_speed": marks, "mesh_speed": mesh}, specs)
    assert "Landmark throughput" in table and "Mesh throughput" in table and "l2reg" in table
