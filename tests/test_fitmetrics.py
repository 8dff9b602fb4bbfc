"""Similarities and metrics of the SEM paper (facegeom.metrics)."""
from __future__ import annotations

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.metrics import (
    closest_point_rms,
    correlation_metrics,
    ersim,
    ersim_batch,
    esim,
    esim_batch,
    interocular_distance,
    landmark_ersim,
    landmark_normalized_error,
    mean_vertex_error_mm,
    mesh_ersim,
    motion_ersim,
    normalized_error,
    pointcloud_ersim,
    pointcloud_normalized_error,
    rms_distance,
    support_scores,
)
from facegeom.model import (
    EVAL_LANDMARKS_26,
    INNER_EYE_CORNERS,
    INNER_LANDMARKS_49,
    BlendshapeRig,
    LandmarkTarget,
    PinholeCamera,
    PointCloudTarget,
    look_at_camera,
)

rng = np.random.default_rng(7)
A = rng.normal(size=(6, 3))
B = rng.normal(size=(6, 3))
C = rng.normal(size=(6, 3))


# --------------------------------------------------------------------------- ESim, eq. (9)


def test_esim_hand_values():
    assert esim([1, 0], [1, 1]) == pytest.approx(1 / np.sqrt(2))
    assert esim([1, 0], [0, 3]) == pytest.approx(0.0)
    assert esim([1, 2, 3], [-2, -4, -6]) == pytest.approx(-1.0)


def test_esim_properties():
    assert esim(A, A) == pytest.approx(1.0)  # its maximum
    assert esim(A, B) == pytest.approx(esim(B, A))  # symmetric
    assert esim(3.5 * A, B) == pytest.approx(esim(A, B))  # scale-invariant: eq. (15) -> (16)
    assert esim(-A, B) == pytest.approx(-esim(A, B))
    for _ in range(20):
        x, y = rng.normal(size=(2, 30))
        assert -1.0 <= esim(x, y) <= 1.0
    # shapes do not matter, only the flat vectors
    assert esim(A, B) == pytest.approx(esim(A.ravel(), B.ravel()))


def test_esim_zero_and_bad_input():
    assert esim(np.zeros(4), np.ones(4)) == 0.0
    with pytest.raises(InputError, match="differ in size"):
        esim(np.ones(3), np.ones(4))
    with pytest.raises(InputError, match="NaN"):
        esim([1, np.nan], [1, 1])
    with pytest.raises(InputError, match="empty"):
        esim([], [])


# --------------------------------------------------------------------------- ERSim, eq. (10)


def test_ersim_hand_values():
    assert ersim([2, 0], [3, 4]) == pytest.approx(1.5)  # (6) / 4
    assert ersim([3, 4], [2, 0]) == pytest.approx(6 / 25)
    # Fig. 5: a motion twice the target's needs a multiplier of 0.5
    assert ersim(2 * A, A) == pytest.approx(0.5)
    assert ersim(0.5 * A, A) == pytest.approx(2.0)


def test_ersim_properties():
    assert ersim(A, A) == pytest.approx(1.0)
    # eq. (26): ERSim = |b| cos(alpha) / |a|, not symmetric
    na, nb = np.linalg.norm(A), np.linalg.norm(B)
    assert ersim(A, B) == pytest.approx(nb * esim(A, B) / na)
    assert ersim(A, B) / ersim(B, A) == pytest.approx(nb**2 / na**2)
    # linear in the second motion (the appendix's sum of ERSims)
    assert ersim(A, 2 * B + C) == pytest.approx(2 * ersim(A, B) + ersim(A, C))
    assert ersim(4 * A, B) == pytest.approx(ersim(A, B) / 4)
    assert ersim(np.zeros(3), [1, 2, 3]) == 0.0


def test_greedy_step_identities():
    """Eq. (18) and (28): e = ERSim(dB, dT) leaves a residual orthogonal to dB and energy 1 - cos^2."""
    dB, dT = A, B
    e = ersim(dB, dT)
    assert np.dot((dT - e * dB).ravel(), dB.ravel()) == pytest.approx(0.0, abs=1e-12)
    assert 1 - ersim(dT, e * dB) == pytest.approx(1 - esim(dB, dT) ** 2)
    # the appendix: E'_mot = 1 - ERSim(dT, sum e_i dB_i) = 1 - sum ERSim(dT, e_i dB_i)
    w = [0.3, -0.7]
    total = w[0] * A + w[1] * C
    assert ersim(dT, total) == pytest.approx(sum(ersim(dT, wi * X) for wi, X in zip(w, (A, C))))


def test_batches_match_scalars():
    M = np.stack([A, B, np.zeros_like(A), -2 * C])
    s = esim_batch(M, C)
    e = ersim_batch(M, C)
    for k in range(4):
        assert s[k] == pytest.approx(esim(M[k], C))
        assert e[k] == pytest.approx(ersim(M[k], C))
    assert s[2] == 0.0 and e[2] == 0.0
    assert s[3] == pytest.approx(-1.0) and e[3] == pytest.approx(-0.5)
    with pytest.raises(InputError, match="each motion has 18 values, the target motion 3"):
        esim_batch(M, [1, 2, 3])


def test_motion_ersim():
    B1 = np.zeros((2, 2))
    T = np.array([[1.0, 0], [0, 1]])
    assert motion_ersim(T, T, B1) == pytest.approx(1.0)
    assert motion_ersim(T, 0.5 * T, B1) == pytest.approx(0.5)
    assert mesh_ersim(B1 + 1, B1 + 1, B1 + 1) == 0.0  # no target motion
    assert motion_ersim(T + 5, [[1.0, 0], [0, 0]] + np.full((2, 2), 5), B1 + 5) == pytest.approx(0.5)


# --------------------------------------------------------------------------- NE, eqs. (29)-(32)


def test_rms_and_normalized_error():
    assert rms_distance([[0, 0], [3, 4]], [[0, 0], [0, 0]]) == pytest.approx(np.sqrt(12.5))
    assert normalized_error([[0, 0], [3, 4]], np.zeros((2, 2)), 5.0) == pytest.approx(np.sqrt(12.5) / 5)
    assert interocular_distance([0, 0, 0], [3, 4, 0]) == pytest.approx(5.0)
    with pytest.raises(InputError, match="zero"):
        interocular_distance([1, 1], [1, 1])
    with pytest.raises(InputError, match="> 0"):
        normalized_error([[0, 0]], [[1, 1]], 0)
    with pytest.raises(InputError, match="matching"):
        rms_distance([[0, 0]], [[0, 0, 0]])


def _flat_scene():
    """Unit focal length at the origin: a point (x, y, -1) projects to (x, -y)."""
    cam = PinholeCamera(1.0, 0.0, 0.0)
    V = np.array([[-1, 0, -1], [1, 0, -1], [0, -1, -1], [0.5, -2, -1], [9, 9, -1]], float)
    return cam, V


def test_landmark_normalized_error_hand_case():
    cam, V = _flat_scene()
    target = LandmarkTarget.from_mesh(V, [0, 1, 2, 3], cam)  # eye corners: vertices 0 and 1, 2 px apart
    fitted = V + [0.1, 0, 0]  # every landmark 0.1 px off
    ne = landmark_normalized_error(fitted, target, eye_vertex_ids=[0, 1])
    assert ne == pytest.approx(0.1 / 2)
    assert landmark_normalized_error(V, target, eye_vertex_ids=[0, 1]) == 0.0
    # only some rows; the normaliser still comes from the full target
    moved = V.copy()
    moved[3] += [0.3, 0.4, 0]
    assert landmark_normalized_error(moved, target, [0, 1], rows=[2, 3]) == pytest.approx(np.sqrt(0.25 / 2) / 2)
    assert landmark_normalized_error(moved, target, interocular=1.0, rows=[3]) == pytest.approx(0.5)
    with pytest.raises(InputError, match="vertex 4 is not among"):
        landmark_normalized_error(V, target, eye_vertex_ids=[0, 4])
    with pytest.raises(InputError, match="eye_vertex_ids"):
        landmark_normalized_error(V, target)


def test_pointcloud_metrics_hand_case():
    V = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [4, 4, 0]], float)
    cloud = PointCloudTarget(V + [0, 0, 0.3])
    assert closest_point_rms(V, cloud.points) == pytest.approx(0.3)
    assert closest_point_rms(V[:2], cloud.points, "cloud_to_mesh") == pytest.approx(np.sqrt((0.09 * 2 + 2 * 16.09) / 4))
    assert pointcloud_normalized_error(V, cloud, eye_vertex_ids=[0, 1]) == pytest.approx(0.3 / 4)
    assert pointcloud_normalized_error(V, cloud, [0, 1], vertex_ids=[2, 3]) == pytest.approx(0.3 / 4)
    with pytest.raises(InputError, match="direction"):
        closest_point_rms(V, cloud.points, "both")
    # ERSim(S_T - B_1, F - B_1) with closest points of the fitted face
    B1 = V - [0, 0, 1.0]
    assert pointcloud_ersim(V, B1, cloud) == pytest.approx(ersim(np.tile([0, 0, 1.3], (4, 1)), np.tile([0, 0, 1.0], (4, 1))))


# --------------------------------------------------------------------------- Corr, eq. (33)


def test_correlation_metrics_hand_values():
    d = np.zeros((4, 3, 3))
    d[0, 0] = [1, 0, 0]
    d[1, 0] = [1, 1, 0]
    d[2, 0] = [-2, 0, 0]
    d[3, 1] = [0, 0, 1]
    rig = BlendshapeRig(np.eye(3), d, ("a", "b", "c", "d"), [[0, 1, 2]])
    c = correlation_metrics(rig, [1, 0.5, 0.25, 3])
    # pairs: (a,b) +0.5, (a,c) -0.5, (b,c) -0.25, d orthogonal to all
    assert c.corr_pos == pytest.approx(0.5)
    assert c.corr_neg == pytest.approx(0.75)
    assert c.corr == pytest.approx(1.25) == pytest.approx(c.corr_pos + c.corr_neg)
    # a negative weight turns cancellation into redundancy
    c = correlation_metrics(rig, {"a": 1, "b": 0.5, "c": -0.25})
    assert (c.corr_pos, c.corr_neg) == pytest.approx((1.25, 0.0))
    # one active shape, or mutually orthogonal ones: no correlation
    assert correlation_metrics(rig, [0, 2, 0, 0]).corr == 0.0
    assert correlation_metrics(rig, [1, 0, 0, 1]).corr == 0.0
    # an explicit Gram matrix (e.g. of projected motions)
    G = np.array([[1.0, -3.0], [-3.0, 1.0]])
    assert correlation_metrics(None, [2.0, 1.0], gram=G) == pytest.approx((6.0, 0.0, 6.0))
    with pytest.raises(InputError, match=r"shape \(4,\)"):
        correlation_metrics(rig, [1, 2])
    with pytest.raises(InputError, match="rig or a gram"):
        correlation_metrics(None, [1, 2])


# --------------------------------------------------------------------------- ground-truth metrics


def test_mean_vertex_error_mm():
    V = rng.normal(size=(10, 3))
    W = V.copy()
    W[:5] += [0.1, 0, 0]  # 1 mm on half the vertices
    assert mean_vertex_error_mm(W, V) == pytest.approx(0.5)
    assert mean_vertex_error_mm(W, V, region=np.arange(5)) == pytest.approx(1.0)
    mask = np.zeros(10, bool)
    mask[5:] = True
    assert mean_vertex_error_mm(W, V, region=mask) == pytest.approx(0.0)
    with pytest.raises(InputError, match="differ in shape"):
        mean_vertex_error_mm(V[:3], V)
    with pytest.raises(InputError, match="no vertex"):
        mean_vertex_error_mm(V, V, region=np.zeros(10, bool))


def test_support_scores():
    s = support_scores([0.5, 0, 0.2, 0.0005], [0.4, 0.3, 0, 0])
    assert s.precision == pytest.approx(0.5) and s.recall == pytest.approx(0.5)
    assert s.mean_abs_error == pytest.approx((0.1 + 0.3 + 0.2 + 0.0005) / 4)
    perfect = support_scores([0, 1, 0], [0, 1, 0])
    assert perfect == (1.0, 1.0, 0.0)
    assert support_scores([0, 0], [0, 0]) == (1.0, 1.0, 0.0)
    assert support_scores([0, 0], [1, 0]).recall == 0.0
    with pytest.raises(InputError, match="w_fit has 2 weights, w_true 3"):
        support_scores([0, 0], [0, 0, 0])


# --------------------------------------------------------------------------- the real ICT rig


@pytest.fixture(scope="module")
def ict_rig(face_model):
    return BlendshapeRig.from_face_model(face_model)


def test_ict_similarities(ict_rig):
    i = ict_rig.shape_index
    jaw = ict_rig.deltas[i("jawOpen")]
    s = esim_batch(ict_rig.deltas, 0.6 * jaw)
    assert int(np.argmax(s)) == i("jawOpen") and s.max() == pytest.approx(1.0)
    assert ersim(jaw, 0.6 * jaw) == pytest.approx(0.6)
    # opening vs closing the eye: strongly opposite motions (the paper's Fig. 4b shows -0.81)
    assert esim(ict_rig.deltas[i("eyeBlink_L")], ict_rig.deltas[i("eyeWide_L")]) < -0.5
    c = correlation_metrics(ict_rig, {"jawOpen": 1.0, "mouthClose": 1.0})
    assert c.corr_pos == 0.0 and c.corr_neg > 0  # mouthClose cancels jawOpen's lip motion
    assert correlation_metrics(ict_rig, {"jawOpen": 1.0}).corr == 0.0


def test_ict_landmark_metrics(ict_rig):
    ids = ict_rig.landmark_vertices(INNER_LANDMARKS_49)
    true = ict_rig.evaluate({"jawOpen": 0.6, "mouthSmile_L": 0.5})
    cam = look_at_camera(ict_rig.neutral)
    target = LandmarkTarget.from_mesh(true, ids, cam)
    eyes = ict_rig.landmark_vertices(INNER_EYE_CORNERS)
    assert landmark_normalized_error(true, target, eyes) == pytest.approx(0.0, abs=1e-12)
    assert landmark_ersim(true, ict_rig.neutral, target) == pytest.approx(1.0)
    ne_neutral = landmark_normalized_error(ict_rig.neutral, target, eyes)
    assert 0.01 < ne_neutral < 1.0
    half = ict_rig.evaluate({"jawOpen": 0.3, "mouthSmile_L": 0.25})
    assert 0.3 < landmark_ersim(half, ict_rig.neutral, target) < 0.7
    rows = [INNER_LANDMARKS_49.index(k) for k in EVAL_LANDMARKS_26]
    assert landmark_normalized_error(half, target, eyes, rows=rows) > 0
