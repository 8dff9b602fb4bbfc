"""Identity fitting from partial, noisy point clouds (facegeom.methods.identity, issue 18 §1(d))."""
import numpy as np
import pytest

from facegeom.bench.identity import partial_scan as bench_partial_scan
from facegeom.constants import FACE_AREA
from facegeom.methods.identity import IdentityFitter
from facegeom.model import PointCloudTarget


def face_mm(A, B):
    """Mean vertex distance over the face area, mm (the model is in cm)."""
    return float(np.linalg.norm(A[:FACE_AREA] - B[:FACE_AREA], axis=1).mean() * 10)


def partial_scan(model, V, rng, points=10000, strip=0.25, side=1, noise_cm=0.05):
    """Points sampled by area on the face area of ``V`` minus a side strip of ``strip`` of its width, plus noise."""
    return bench_partial_scan(model, V, rng, points, strip, side, noise_cm)


@pytest.fixture(scope="module")
def scan(face_model):
    rng = np.random.default_rng(18)
    a = face_model.random_identity(rng)
    w = np.zeros(face_model.n_expressions)
    w[[face_model.expression_index("jawOpen"), face_model.expression_index("mouthSmile_L")]] = [0.4, 0.5]
    V = face_model.face(a, w)
    return a, w, V, partial_scan(face_model, V, rng)


@pytest.fixture(scope="module")
def scan_fit(face_model, scan):
    return IdentityFitter().fit(face_model, PointCloudTarget(scan[3]))


def test_partial_scan_identity_beats_the_generic_neutral(face_model, scan, scan_fit):
    """A quarter of the face hidden: the fitted identity is much nearer the truth than the generic neutral.

    Before the trimmed ICP the hidden side was pulled onto the scan's edge: the
    face turned by 11-14 degrees and the fitted neutral ended farther from the
    person than the generic one.
    """
    a, w, V, _ = scan
    truth = face_model.face(a)
    generic = face_mm(face_model.face(), truth)
    assert face_mm(scan_fit.rig.neutral, truth) < 0.8 * generic
    assert face_mm(scan_fit.posed_vertices(), V) < 0.8 * face_mm(face_model.face(), V)
    angle = np.degrees(np.arccos(np.clip((np.trace(scan_fit.rotations[0]) - 1) / 2, -1, 1)))
    assert angle < 4.0  # the scan is in the model's frame: no turn
    assert scan_fit.info["rms"][0] < 1.5  # mm, at the kept pairs


def test_partial_scan_hidden_side_follows_the_identity(face_model, scan, scan_fit):
    """The unseen strip is extrapolated by the identity, not dragged onto the scan's edge.

    (Before the trimmed ICP: 36 mm on the hidden strip against 4.0 for the
    generic face; with one annealing pass 4.2 against a seen part of 2.8;
    with three passes 3.1 against 1.2. The test asked for the hidden strip
    within 1.25x the generic face's error and 2x the seen part's; the seen
    part now fits far better than the identity can extrapolate, so the
    second bound is replaced by the stricter first one at 1.0x.)
    """
    a, w, V, _ = scan
    X = face_model.neutral[:FACE_AREA, 0]
    hidden = X >= X.max() - 0.25 * (X.max() - X.min())
    err = np.linalg.norm(scan_fit.posed_vertices()[:FACE_AREA] - V[:FACE_AREA], axis=1) * 10
    generic = np.linalg.norm(face_model.face()[:FACE_AREA] - V[:FACE_AREA], axis=1) * 10
    assert err[hidden].mean() < generic[hidden].mean()
    assert err[~hidden].mean() < 0.5 * generic[~hidden].mean()


def test_scan_side_does_not_matter(face_model, scan):
    """Mirror test: hiding the other side gives an identity about as good (no bias towards one side)."""
    a, w, V, _ = scan
    rng = np.random.default_rng(19)
    truth = face_model.face(a)
    fits = [IdentityFitter().fit(face_model, PointCloudTarget(partial_scan(face_model, V, rng, side=s)))
            for s in (-1, 1)]
    errs = [face_mm(f.rig.neutral, truth) for f in fits]
    generic = face_mm(face_model.face(), truth)
    assert max(errs) < 0.85 * generic


def test_partial_scan_off_the_model_frame(face_model, scan):
    """A partial scan turned by 10 degrees and moved by 6 mm: the rigid alignment first keeps the identity good.

    (Without it the shape rounds explained the turn with the identity: neutral
    6.4 mm from the person's for a 15 % strip, generic 3.7.)
    """
    from scipy.spatial.transform import Rotation

    a, w, V, _ = scan
    P = partial_scan(face_model, V, np.random.default_rng(5), strip=0.15)
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    R = Rotation.from_rotvec(np.radians(10.0) * axis).as_matrix()
    T = np.array([0.5, -0.25, 0.15])
    fit = IdentityFitter().fit(face_model, PointCloudTarget(P @ R.T + T))
    truth = face_model.face(a)
    assert face_mm(fit.rig.neutral, truth) < 0.8 * face_mm(face_model.face(), truth)
    assert np.degrees(np.arccos(np.clip((np.trace(fit.rotations[0].T @ R) - 1) / 2, -1, 1))) < 4.0


def test_partial_scan_in_any_orientation(face_model, scan):
    """A partial scan turned by 150 degrees and moved by 40 cm: the global rigid search finds the pose.

    (The former local ICP from the model frame lost turns of 20 degrees and
    more; the fit then explained the turn with the identity.) This case (an
    open jaw, a fifth hidden) is hard: the neutral ends 3.5 mm from the
    person's, 3.0 when the scan is given in the model's frame, 1.8 turned by
    10 degrees, 2.6 by 40; the generic neutral is 3.7 mm away. The fit's
    outcome depends on its start, and the test asks what holds from any.
    """
    from scipy.spatial.transform import Rotation

    a, w, V, _ = scan
    P = partial_scan(face_model, V, np.random.default_rng(6), strip=0.2)
    R = Rotation.from_euler("xyz", [150.0, -30.0, 60.0], degrees=True).as_matrix()
    T = np.array([40.0, -12.0, 25.0])
    fit = IdentityFitter().fit(face_model, PointCloudTarget(P @ R.T + T))
    truth = face_model.face(a)
    assert np.degrees(np.arccos(np.clip((np.trace(fit.rotations[0].T @ R) - 1) / 2, -1, 1))) < 4.0
    assert face_mm(fit.rig.neutral, truth) < face_mm(face_model.face(), truth)
    assert face_mm(fit.posed_vertices(), V @ R.T + T) < face_mm(face_model.face(), V)


def test_head_scan_in_millimetres_any_orientation(face_model):
    """A whole-head scan (face, ears, neck; about half the points off the face area), turned and moved.

    The points beyond the face area's edge matched its edge vertices and pulled
    the face outwards (neutral 7-14 mm from the person's, the generic one
    2.5-7); now pairs of scan points with a vertex within 1 cm of the edge are
    not used (the vertices still reach the scan): 0.8-1 mm in the model frame.
    """
    from scipy.spatial.transform import Rotation

    from facegeom.bench.common import sample_surface
    from facegeom.registration import units_factor

    rng = np.random.default_rng(21)
    a = face_model.random_identity(rng)
    V = face_model.face(a)
    P = sample_surface(V, face_model.triangles, 20000, rng) + rng.normal(size=(20000, 3)) * 0.05
    R = Rotation.from_euler("xyz", [-60.0, 100.0, 20.0], degrees=True).as_matrix()
    Q = (P @ R.T + [30.0, 5.0, -20.0]) * 10.0  # mm
    Q = Q * units_factor(Q, face_model.face()[:FACE_AREA])
    fit = IdentityFitter().fit(face_model, PointCloudTarget(Q))
    assert fit.info["searched"] == [True]
    assert face_mm(fit.rig.neutral, V) < 0.5 * face_mm(face_model.face(), V)
    assert np.degrees(np.arccos(np.clip((np.trace(fit.rotations[0].T @ R) - 1) / 2, -1, 1))) < 3.0


def test_weighted_gram_equals_the_direct_product():
    """The syrk Gram of the cloud rounds equals A^T diag(w) A, with and without zero weights."""
    from facegeom.methods.identity import _weighted_gram

    rng = np.random.default_rng(3)
    A = rng.normal(size=(60, 7))
    for w in (rng.random(20) + 0.1, np.where(rng.random(20) < 0.3, 0.0, rng.random(20))):
        G = _weighted_gram(A, w)
        assert np.allclose(G, A.T @ (A * np.repeat(w, 3)[:, None]), rtol=1e-12, atol=1e-12)
        assert np.array_equal(G, G.T)
