"""Head pose from 2-D landmarks (PnP): closed-form start + batched Levenberg-Marquardt."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom.errors import InputError
from facegeom.model import PinholeCamera, estimate_pose, estimate_poses, project_many, reprojection_rms
from facegeom.model.pose import NEAR, in_front


def face_like_points(seed, n=23):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, 3)) * [4.0, 5.0, 1.5]  # a face-sized cloud (cm), roughly flat in depth
    return P


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), yaw=st.floats(-40, 40), pitch=st.floats(-25, 25), dist=st.floats(40, 120))
def test_exact_pose_is_recovered(seed, yaw, pitch, dist):
    P = face_like_points(seed)
    R = Rotation.from_euler("yx", [yaw, pitch], degrees=True).as_matrix()
    t = np.array([1.0, -2.0, -dist])
    cam = PinholeCamera(900.0, 320.0, 240.0, R, t)
    uv = cam.project(P)
    est = estimate_pose(P, uv, PinholeCamera(900.0, 320.0, 240.0))
    assert reprojection_rms(P, uv, est) < 1e-6
    np.testing.assert_allclose(est.R, R, atol=1e-6)
    np.testing.assert_allclose(est.t, t, atol=1e-4)


def test_batched_equals_single_and_noise_is_least_squares():
    rng = np.random.default_rng(3)
    K = 7
    P = np.stack([face_like_points(s) for s in range(K)])
    R = Rotation.from_euler("yx", rng.uniform(-30, 30, (K, 2)), degrees=True).as_matrix()
    t = np.c_[rng.normal(size=(K, 2)), -rng.uniform(50, 80, K)]
    f = rng.uniform(700, 1200, K)
    cx, cy = np.full(K, 320.0), np.full(K, 240.0)
    uv = project_many(P, R, t, f, cx, cy) + rng.normal(size=(K, 23, 2))
    Rb, tb = estimate_poses(P, uv, f, cx, cy)
    for k in range(K):
        one = estimate_pose(P[k], uv[k], PinholeCamera(f[k], cx[k], cy[k]))
        np.testing.assert_allclose(one.R, Rb[k], atol=1e-7)
        np.testing.assert_allclose(one.t, tb[k], atol=1e-6)
        # a least-squares optimum: the gradient of the reprojection error vanishes (small random perturbations do worse)
        base = reprojection_rms(P[k], uv[k], one)
        for _ in range(5):
            dR = Rotation.from_rotvec(rng.normal(size=3) * 1e-3).as_matrix()
            worse = PinholeCamera(f[k], cx[k], cy[k], dR @ one.R, one.t + rng.normal(size=3) * 1e-2)
            assert reprojection_rms(P[k], uv[k], worse) >= base - 1e-9


def test_bad_input():
    cam = PinholeCamera(900.0, 320.0, 240.0)
    P = face_like_points(0)
    with pytest.raises(InputError, match="at least 4 landmarks"):
        estimate_pose(P[:3], np.zeros((3, 2)), cam)
    with pytest.raises(InputError, match="NaN"):
        bad = P.copy()
        bad[2, 1] = np.nan
        estimate_pose(bad, np.zeros((23, 2)), cam)
    with pytest.raises(InputError, match="degenerate"):
        estimate_pose(np.zeros((6, 3)), np.zeros((6, 2)), cam)
    with pytest.raises(InputError, match=r"need \(N, 3\) points"):
        estimate_pose(P, np.zeros((22, 2)), cam)
    with pytest.raises(InputError, match="behind the camera"):
        project_many(P[None], np.eye(3)[None], np.array([[0.0, 0.0, 5.0]]), np.ones(1), np.zeros(1), np.zeros(1))


@pytest.mark.parametrize("yaw, dist", [(80.0, 8.0), (-80.0, 8.0), (-75.0, 7.0), (70.0, 7.0)])
def test_a_face_turned_near_a_wide_lens_gets_a_pose(face_model, yaw, dist):
    """The scaled-orthographic start put such a face closer than its own depth (landmarks behind the camera: an
    error); moved back along its line of sight, the refinement recovers the exact pose."""
    P = np.asarray(face_model.neutral[face_model.landmarks], dtype=np.float64)
    R = Rotation.from_euler("y", yaw, degrees=True).as_matrix()
    cam = PinholeCamera(200.0, 320.0, 240.0, R, -R @ P.mean(axis=0) + [0.0, 0.0, -dist])
    uv = cam.project(P)
    est = estimate_pose(P, uv, PinholeCamera(200.0, 320.0, 240.0))
    assert reprojection_rms(P, uv, est) < 1e-6
    np.testing.assert_allclose(est.R, R, atol=1e-6)


def test_a_point_at_the_lens_is_not_in_front():
    """A point nearer than NEAR x the mean depth counts as behind: its projection is 0 / 0."""
    assert in_front(np.array([5.0, 10.0, 15.0]))
    assert not in_front(np.array([1e-9, 10.0, 15.0]))
    assert not in_front(np.array([-1.0, 10.0, 15.0]))
    assert in_front(np.array([[2 * NEAR * 10.0, 10.0, 20.0]])).tolist() == [True]
