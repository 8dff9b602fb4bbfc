"""Head yaw, pitch and roll of a Live Link take from rotation matrices, against scipy's intrinsic YXZ Euler angles."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from facegeom.errors import InputError
from facegeom.io.takes import head_angles


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_angles_are_scipys_and_rebuild_the_rotation(seed):
    R = Rotation.random(200, random_state=seed).as_matrix()
    got = head_angles(R)
    assert np.abs(got - Rotation.from_matrix(R).as_euler("YXZ")).max() <= 1e-9
    assert np.abs(Rotation.from_euler("YXZ", got).as_matrix() - R).max() <= 1e-12
    assert (np.abs(got[:, 1]) <= np.pi / 2).all()


def test_a_head_looking_straight_up_keeps_its_turn_in_the_yaw():
    e = np.array([[0.3, np.pi / 2, 0.0], [-2.0, -np.pi / 2, 0.0]])
    R = Rotation.from_euler("YXZ", e).as_matrix()
    assert np.allclose(head_angles(R), e, atol=1e-9)


def test_nearly_orthonormal_rotations_and_bad_shapes():
    R = Rotation.from_euler("YXZ", [[0.1, 0.2, 0.3]]).as_matrix() * (1 + 1e-7)  # a slightly scaled rotation
    assert np.allclose(head_angles(R), [[0.1, 0.2, 0.3]], atol=1e-9)
    assert head_angles(np.zeros((0, 3, 3))).shape == (0, 3)
    with pytest.raises(InputError, match="rotations must be"):
        head_angles(np.zeros((4, 3)))
