"""Rigid registration of a template to a scan in any frame and units (facegeom.registration)."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom.constants import FACE_AREA
from facegeom.errors import InputError
from facegeom.registration import align_rigid, icp_rigid, kabsch, trim_outliers, units_factor


def angle_deg(A, B):
    """Angle of the rotation between ``A`` and ``B``, degrees."""
    return float(np.degrees(Rotation.from_matrix(A.T @ B).magnitude()))


@pytest.fixture(scope="module")
def face(face_model):
    return face_model.face()[:FACE_AREA].astype(np.float64)


def scan_of(face, rng, hidden=0.2, noise=0.05, points=6000):
    """Points near the vertices of ``face`` minus a side strip of ``hidden`` of its width, plus noise (cm)."""
    X = face[:, 0]
    keep = face[X < X.max() - hidden * (X.max() - X.min())]
    P = keep[rng.integers(0, len(keep), points)]
    return P + rng.normal(size=P.shape) * noise


# ----------------------------------------------------------------------------- pieces
@settings(max_examples=40, deadline=None)
@given(d=st.lists(st.floats(0.0, 10.0, allow_nan=False), min_size=8, max_size=60), k=st.integers(-8, 8))
def test_trim_keeps_the_median_and_is_scale_free(d, k):
    """Property: at least half the pairs are kept, the nearest always, and a change of unit changes nothing.

    (Scaled by a power of two, so the scaling is exact in floating point; a
    zero spread has an absolute floor, so it is left out of the unit check.)
    """
    d = np.asarray(d)
    keep = trim_outliers(d)
    assert keep.sum() >= (d.size + 1) // 2
    assert keep[np.argmin(d)]
    if np.median(np.abs(d - np.median(d))) > 0:
        assert np.array_equal(trim_outliers(d * 2.0 ** k), keep)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(8, 200), far=st.floats(50.0, 1e6), seed=st.integers(0, 2**16))
def test_trim_drops_a_far_outlier(n, far, seed):
    """Property: one distance far beyond a noisy bulk is dropped, the bulk's median kept."""
    rng = np.random.default_rng(seed)
    d = np.abs(rng.normal(1.0, 0.1, n))
    d[0] = far
    keep = trim_outliers(d)
    assert not keep[0]
    assert keep[np.argsort(d)[n // 2]]


def test_trim_few_pairs_keeps_all():
    """Too few pairs for a spread: nothing is dropped."""
    assert trim_outliers(np.array([0.1, 5.0, 100.0])).all()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_kabsch_recovers_a_rigid_motion_and_never_reflects(seed):
    """Property: paired points under a rigid motion give it back; a mirrored copy still gives a rotation."""
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(12, 3))
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3) * 10
    R1, t1 = kabsch(P, P @ R.T + t, rng.random(12) + 0.1)
    assert np.allclose(R1, R, atol=1e-9) and np.allclose(t1, t, atol=1e-8)
    Rm, _ = kabsch(P, P * [-1.0, 1.0, 1.0])
    assert np.isclose(np.linalg.det(Rm), 1.0)


def test_local_icp_recovers_a_small_turn(face):
    """Local ICP from the identity: a scan of the template turned by 15 degrees and moved is put back."""
    rng = np.random.default_rng(1)
    P = scan_of(face, rng)
    R = Rotation.from_rotvec(np.radians(15.0) * np.array([0.0, 1.0, 0.0])).as_matrix()
    t = np.array([1.0, -2.0, 0.5])
    R1, t1, rounds = icp_rigid(face[::5], P @ R.T + t, rounds=300, tol=1e-7)
    assert angle_deg(R1, R) < 1.5  # point-to-point ICP slides slowly: ~140 rounds here
    assert np.linalg.norm(t1 - t) < 0.2
    assert rounds < 300


# ----------------------------------------------------------------------------- the global search
@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**16), hidden=st.floats(0.0, 0.25))
def test_global_search_finds_any_orientation(face, seed, hidden):
    """Property: a partial scan of the template in any orientation and position is posed within 2 degrees.

    (Local ICP fails on about half of the turns of 45 degrees and more.)
    """
    rng = np.random.default_rng(seed)
    P = scan_of(face, rng, hidden)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3) * 50
    found = align_rigid(face, P @ R.T + t)
    assert angle_deg(found.R, R) < 2.0
    assert np.linalg.norm(found.t - t) < 0.5  # cm
    assert found.score < 0.15 and found.runner_up > found.score


def test_global_search_on_another_person(face_model, face):
    """A random person with an expression, a quarter hidden, turned upside down: the mean face finds the pose."""
    rng = np.random.default_rng(7)
    w = np.zeros(face_model.n_expressions)
    w[face_model.expression_index("mouthSmile_L")] = 0.7
    V = face_model.face(face_model.random_identity(rng), w)[:FACE_AREA]
    R = Rotation.from_euler("zyx", [175.0, 20.0, -35.0], degrees=True).as_matrix()
    found = align_rigid(face, scan_of(V, rng, 0.25) @ R.T + [0.0, 30.0, -80.0])
    assert angle_deg(found.R, R) < 6.0


def test_align_rigid_rejects_bad_input(face):
    with pytest.raises(InputError, match="scan must have shape"):
        align_rigid(face, np.zeros((2, 3)))
    bad = face.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="template has NaN"):
        align_rigid(bad, face)


# ----------------------------------------------------------------------------- units
@settings(max_examples=40, deadline=None)
@given(k=st.integers(-4, 4), seed=st.integers(0, 2**16), size=st.floats(0.5, 2.5))
def test_units_factor_undoes_a_power_of_ten(face, k, seed, size):
    """Property: a face (of any person's size within 2.5x, anywhere, any orientation) in other units comes back."""
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    P = (face[::7] * size @ R.T + rng.normal(size=3) * 100) * 10.0 ** k
    assert units_factor(P, face) == pytest.approx(10.0 ** -k)


def test_units_factor_needs_an_extent(face):
    with pytest.raises(InputError, match="no extent"):
        units_factor(np.ones((10, 3)), face)


@settings(max_examples=60, deadline=None)
@given(P=st.lists(st.tuples(*[st.floats(-1e300, 1e300, allow_nan=False, allow_infinity=False)] * 3),
                  min_size=1, max_size=12))
def test_hostile_scans_give_a_factor_or_an_input_error(face, P):
    """Fuzz: any finite points (coincident, collinear, near overflow) -> a power of ten or InputError."""
    P = np.asarray(P, dtype=np.float64)
    try:
        f = units_factor(P, face[::50])
    except InputError:
        return
    assert f > 0 and np.isfinite(f) and np.log10(f) == round(np.log10(f))


@settings(max_examples=15, deadline=None)
@given(n=st.integers(3, 40), seed=st.integers(0, 2**16), kind=st.sampled_from(["coincident", "line", "huge", "tiny"]))
def test_degenerate_scans_align_without_crashing(face, n, seed, kind):
    """Fuzz: degenerate scans give a finite rotation and translation (or InputError), never a crash or NaN."""
    rng = np.random.default_rng(seed)
    P = {"coincident": np.ones((n, 3)), "line": np.outer(rng.random(n), [1.0, 2.0, 3.0]),
         "huge": rng.normal(size=(n, 3)) * 1e150, "tiny": rng.normal(size=(n, 3)) * 1e-150}[kind]
    with np.errstate(all="raise"):  # no silent overflow or invalid operations either
        try:
            found = align_rigid(face[::40], P)
        except InputError:
            return
    assert np.isfinite(found.R).all() and np.isfinite(found.t).all()
    assert np.allclose(found.R @ found.R.T, np.eye(3), atol=1e-9)
