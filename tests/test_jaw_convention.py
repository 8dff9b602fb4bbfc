"""Where annotators put the jaw contour against the model's (facegeom.model.landmarks.JAW_CONVENTION)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.io import read_pts
from facegeom.model.landmarks import JAW_CONVENTION, MIRROR_68, to_annotation_convention, to_model_convention

TAKEO = Path(__file__).parent / "data" / "photos" / "takeo.pts"


def test_the_table_is_left_right_symmetric_and_lower_and_wider():
    d = np.asarray(JAW_CONVENTION)
    assert d.shape == (17, 2)
    np.testing.assert_allclose(d[:, 0], -d[[MIRROR_68[j] for j in range(17)], 0])
    np.testing.assert_allclose(d[:, 1], d[[MIRROR_68[j] for j in range(17)], 1])
    assert (d[:, 1] > 0).all() and (d[:8, 0] < 0).all() and (d[9:, 0] > 0).all()


@settings(max_examples=60, deadline=None)
@given(st.floats(-np.pi, np.pi), st.floats(0.05, 20.0), st.floats(-1e4, 1e4), st.floats(-1e4, 1e4))
def test_the_shift_turns_and_scales_with_the_face_and_round_trips(angle, scale, tx, ty):
    """A photo turned in plane, scaled and moved gets the same shift turned and scaled: the convention belongs to
    the face, not to the image axes; the inner points never move; model -> annotation is the inverse."""
    P = read_pts(TAKEO)
    c, s = np.cos(angle), np.sin(angle)
    A = np.array([[c, -s], [s, c]]) * scale
    Q = P @ A.T + [tx, ty]
    mq = to_model_convention(Q)
    np.testing.assert_allclose(mq[17:], Q[17:])
    np.testing.assert_allclose(mq - Q, (to_model_convention(P) - P) @ A.T, atol=1e-6 * scale * 100)
    np.testing.assert_allclose(to_annotation_convention(mq, Q), Q, atol=1e-9 * (1 + abs(tx) + abs(ty) + scale * 300))


def test_a_face_without_a_frame_is_left_as_it_is():
    P = np.zeros((68, 2))
    np.testing.assert_array_equal(to_model_convention(P), P)
    np.testing.assert_array_equal(to_annotation_convention(P, P), P)


def test_the_shift_moves_the_contour_up_and_in_by_the_table():
    P = read_pts(TAKEO)
    io = np.linalg.norm(P[39] - P[42])
    d = to_model_convention(P)[:17] - P[:17]
    assert np.allclose(np.linalg.norm(d, axis=1) / io, np.linalg.norm(np.asarray(JAW_CONVENTION), axis=1), rtol=1e-9)
    assert d[8, 1] < 0  # the chin moves up in the image (v grows downwards)
