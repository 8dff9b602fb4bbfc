"""The actor's identity fitted from a marker capture: the solver, the fit on random actors, the solve's default on
the generic face, and the warning when a rig does not fit the actor."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from facegeom.bench.solve import make_sequence, stuck_shapes
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import InputError
from facegeom.methods.marker_identity import _shape_step, fit_capture_identity, pick_frames
from facegeom.methods.marker_solve import marker_noise, solve_markers
from facegeom.model import BlendshapeRig
from facegeom.model.layouts import layout
from facegeom.pipelines.solve import fit_warning


def _energy(U, Dk, n0, Y, M, sig2, prior, lin, a, x):
    r = (Y - n0[None] - (U @ a)[None] - np.einsum("krm,km->kr", Dk, x)) * M
    return float((r ** 2).sum() + sig2 * a @ a + (x ** 2 * prior).sum() + 2 * (x * lin).sum())


def _reference(U, Dk, n0, Y, M, sig2, prior, lin, nb):
    """The same energy as one bounded least squares over (a, x) by scipy's BVLS (slow, exact)."""
    K, R, m = Dk.shape
    I = U.shape[1]
    rows, rhs = [], []
    for k in range(K):
        blk = np.zeros((R, I + K * m))
        blk[:, :I] = U * M[k][:, None]
        blk[:, I + k * m:I + (k + 1) * m] = Dk[k] * M[k][:, None]
        rows.append(blk)
        rhs.append((Y[k] - n0) * M[k])
    # the priors as rows: sig2 |a|^2, prior x^2 + 2 lin x = |sqrt(prior) x + lin / sqrt(prior)|^2 - const
    rows.append(np.c_[np.sqrt(sig2) * np.eye(I), np.zeros((I, K * m))])
    rhs.append(np.zeros(I))
    sp = np.tile(np.sqrt(prior), K)
    rows.append(np.c_[np.zeros((K * m, I)), np.diag(sp)])
    rhs.append(-np.tile(lin, K) / sp)
    A, b = np.vstack(rows), np.concatenate(rhs)
    lo = np.full(I + K * m, -np.inf)
    hi = np.full(I + K * m, np.inf)
    for k in range(K):
        lo[I + k * m:I + k * m + nb], hi[I + k * m:I + k * m + nb] = 0.0, 1.0
    z = lsq_linear(A, b, bounds=(lo, hi), method="bvls", tol=1e-14).x
    return z[:I], z[I:].reshape(K, m)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), K=st.integers(1, 4), nb=st.integers(1, 6), pose=st.integers(0, 3),
       I=st.integers(1, 5), l1=st.sampled_from([0.0, 0.5, 5.0]))
def test_the_shape_step_is_the_bounded_minimiser(seed, K, nb, pose, I, l1):
    """On random problems (overlapping identity and expression columns, lost rows, weights pushed past both
    bounds) the step's energy equals the exact bounded minimum's and its weights stay in [0, 1]."""
    rng = np.random.default_rng(seed)
    R, m = 12, nb + pose
    U = rng.normal(size=(R, I))
    base = rng.normal(size=(R, nb))
    Dk = np.stack([np.c_[base + 0.1 * rng.normal(size=(R, nb)), rng.normal(size=(R, pose))] for _ in range(K)])
    Dk[:, :, :nb] += 0.8 * U[:, :1]  # an expression that looks like the identity: the ambiguity the priors settle
    n0 = rng.normal(size=R)
    M = (rng.random((K, R)) > 0.15).astype(float)
    Y = (n0[None] + rng.normal(0, 2.0, (K, R))) * M
    sig2 = 0.3
    prior = np.r_[np.full(nb, 0.3), np.full(pose, 1e-6)]
    lin = np.r_[np.full(nb, 0.3 * l1), np.zeros(pose)]
    a, x = _shape_step(U, Dk, n0, Y, M, sig2, prior, lin, nb, rng.random((K, nb)), np.zeros(I))
    assert (x[:, :nb] >= 0).all() and (x[:, :nb] <= 1).all()
    ar, xr = _reference(U, Dk, n0, Y, M, sig2, prior, lin, nb)
    e, er = (_energy(U, Dk, n0, Y, M, sig2, prior, lin, *v) for v in ((a, x), (ar, xr)))
    assert e <= er + 1e-7 * max(1.0, abs(er)), (e, er)


@pytest.fixture(scope="module")
def actors(face_model):
    """Three random actors performing a 120-frame sequence of sparse expressions on two layouts, 0.5 mm noise,
    3 % lost: ``[(X, ids, W, actor_rig)]``."""
    rng = np.random.default_rng(4049)
    rig0 = BlendshapeRig.from_face_model(face_model)
    T = 120
    out = []
    for k in range(3):
        W = np.zeros((T, rig0.n_shapes))
        for b in rng.choice(rig0.n_shapes, 8, replace=False):  # each shape rises and falls once
            c, w = rng.uniform(0, T), rng.uniform(8, 30)
            W[:, b] = rng.uniform(0.4, 1.0) * np.exp(-0.5 * ((np.arange(T) - c) / w) ** 2)
        actor = BlendshapeRig.from_face_model(face_model, face_model.random_identity(rng))
        ids = layout(face_model, ("ict80", "random80", "ict80")[k], seed=k)
        X, _, _ = make_sequence(actor, ids, W, 0.05, 0.03, rng)
        out.append((X, ids, W, actor))
    return out


def test_random_actors_solve_as_on_their_own_rig(face_model, actors):
    """On the generic face with the identity fitted: no shape stuck above 0.5 where the truth stays at or below
    0.2, the weight error within 2x of the actor's own rig's; the generic face as it is sticks shapes and errs far
    more (so the check can fail); the fitted neutral is nearer the actor's than the generic one is."""
    generic = BlendshapeRig.from_face_model(face_model)
    for X, ids, W, actor in actors:
        own = np.abs(solve_markers(X, ids, actor, smooth="auto").weights - W).mean()
        fit = fit_capture_identity(face_model, X, ids)
        E = solve_markers(X, ids, fit.rig, smooth="auto").weights
        assert stuck_shapes(W, E) == []
        assert np.abs(E - W).mean() <= 2.0 * own, (np.abs(E - W).mean(), own)
        G = solve_markers(X, ids, generic, smooth="auto").weights
        assert np.abs(G - W).mean() > 3.0 * own
        d_fit = np.linalg.norm(fit.rig.neutral[:FACE_AREA] - actor.neutral[:FACE_AREA], axis=1).mean()
        d_gen = np.linalg.norm(generic.neutral[:FACE_AREA] - actor.neutral[:FACE_AREA], axis=1).mean()
        assert d_fit < 0.4 * d_gen
        before, after = fit.info["residual_mm"]
        assert after < 0.5 * before and fit.frames.size == 24 and fit.info["time_s"] < 10


def test_the_warning_tells_a_rig_that_does_not_fit_from_noise(face_model, actors):
    """The residual warning: silent on the actor's own rig at 0.5 and 1 mm noise, raised on the generic face."""
    generic = BlendshapeRig.from_face_model(face_model)
    rng = np.random.default_rng(7)
    for X, ids, W, actor in actors[:2]:
        X1, _, _ = make_sequence(actor, ids, W, 0.1, 0.03, rng)  # 1 mm
        for Xi in (X, X1):
            assert fit_warning(solve_markers(Xi, ids, actor).rms, marker_noise(Xi)) == ""
            line = fit_warning(solve_markers(Xi, ids, generic).rms, marker_noise(Xi), generic=True)
            assert line.startswith("warning: the rig does not fit the actor's face") and "identity" in line


def test_marker_noise_estimates_from_the_capture(face_model, actors):
    """The estimate never falls below the true noise and stays within 0.6 mm above it (a face's motion)."""
    X, ids, W, actor = actors[0]
    rng = np.random.default_rng(3)
    for sigma in (0.0, 0.05, 0.1):
        Xs, _, _ = make_sequence(actor, ids, W, sigma, 0.03, rng)
        est = marker_noise(Xs)
        assert sigma * 0.95 <= est <= sigma + 0.06, (sigma, est)
    assert np.isnan(marker_noise(np.full((2, 3, 3), 1.0)))


def test_pick_frames_takes_the_most_neutral_well_found_frame_per_stretch():
    X = np.zeros((20, 10, 3))
    X[3, :5] = np.nan  # half lost: never picked
    w = np.ones((20, 4))
    w[3] = 0.0  # the most neutral, but half lost
    w[7] = 0.1
    w[12] = np.nan  # not solved
    w[15] = 0.05
    picks = pick_frames(X, w, 2)
    assert picks.tolist() == [7, 15]


def test_bad_arguments_are_refused(face_model):
    X = np.zeros((5, 4, 3))
    ids = np.arange(4)
    with pytest.raises(InputError, match="frames"):
        fit_capture_identity(face_model, X, ids, frames=0)
    with pytest.raises(InputError, match="noise_mm"):
        fit_capture_identity(face_model, X, ids, noise_mm=-1.0)
    with pytest.raises(InputError, match="3 markers"):
        fit_capture_identity(face_model, np.full((5, 4, 3), np.nan), ids)


@pytest.fixture(scope="module")
def example_capture(tmp_path_factory, face_model):
    """The examples' ``capture.c3d`` (a random person performing the example take, mm, 1 % lost) and its truth."""
    from facegeom.io.c3d import write_c3d
    from facegeom.pipelines.examples import TAKE_FPS, make_examples

    ex = make_examples(face_model)
    d = tmp_path_factory.mktemp("identity")
    write_c3d(d / "capture.c3d", ex.capture[0], ex.capture[1], fps=TAKE_FPS, unit="mm")
    return d, ex.scene["weights"]


def _solve(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "facegeom", "solve", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def test_the_first_solve_example_gives_the_performance_not_the_actors_shape(example_capture):
    """``facegeom solve capture.c3d`` on the generic face: the actor's identity is fitted first (a note says so and
    how to turn it off), no shape sticks, the weights are within 0.03 of the truth; the .npz keeps the identity.
    With ``--identity off`` the generic face's mismatch sticks eyeWide near 1 in every frame and a warning says
    the rig does not fit the actor."""
    d, W = example_capture
    r = _solve(d / "capture.c3d", "-o", d / "curves.npz")
    assert r.returncode == 0, r.stderr
    assert "the actor's identity fitted from 24 frames of the capture" in r.stdout
    assert "pass --identity off to solve on the generic face as it is" in r.stdout and "warning" not in r.stdout
    z = np.load(d / "curves.npz")
    E = z["weights"]
    assert stuck_shapes(W, E) == [] and np.abs(E - W).mean() < 0.03
    assert z["identity"].shape == (100,) and np.abs(z["identity"]).max() > 0.1
    r = _solve(d / "capture.c3d", "-o", d / "generic.npz", "--identity", "off")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("warning:")]
    assert len(lines) == 1 and "the rig does not fit the actor's face" in lines[0]
    assert "solve without --identity off" in lines[0]
    z = np.load(d / "generic.npz")
    names = list(z["names"])
    assert stuck_shapes(W, z["weights"]) or np.median(z["weights"][:, names.index("eyeWide_R")]) > 0.9
    assert "identity" not in z.files


def test_a_rig_of_ones_own_is_used_as_it_is(example_capture, face_model, tmp_path):
    """``--rig`` (here the generic face saved as a file: no face model behind it) is solved on as it is, and its
    mismatch with the actor gets the warning with what to do instead."""
    d, W = example_capture
    BlendshapeRig.from_face_model(face_model).save_npz(tmp_path / "rig.npz")
    r = _solve(d / "capture.c3d", "--rig", tmp_path / "rig.npz", "-o", tmp_path / "c.npz")
    assert r.returncode == 0, r.stderr
    assert "identity fitted" not in r.stdout
    assert "warning: the rig does not fit the actor's face" in r.stdout and "actor's own rig (--rig)" in r.stdout


def test_identity_choice_is_checked(example_capture, face_model):
    from facegeom.pipelines.solve import solve_file

    d, _ = example_capture
    with pytest.raises(InputError, match="identity must be one of auto, off"):
        solve_file(d / "capture.c3d", BlendshapeRig.from_face_model(face_model), None, identity="on")
    r = _solve(d / "capture.c3d", "-o", d / "x.npz", "--identity", "on")
    assert r.returncode == 2 and "Invalid value for '--identity'" in r.stderr
