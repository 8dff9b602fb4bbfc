"""The orthonormal DCT-II on numpy's FFT (what the curve smoothing of `facegeom solve` uses) against scipy's."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.fft import dct, idct

from facegeom.linalg import dct_ortho, idct_ortho


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 400), st.integers(1, 5), st.integers(0, 2 ** 32 - 1))
def test_dct_matches_scipy_and_inverts(N, K, seed):
    x = np.random.default_rng(seed).normal(size=(N, K)) * 10.0 ** np.random.default_rng(seed).integers(-3, 4)
    y = dct_ortho(x)
    ref = dct(x, type=2, norm="ortho", axis=0)
    size = np.abs(x).max()
    assert np.abs(y - ref).max() <= 1e-13 * size * np.sqrt(N)
    assert np.abs(idct_ortho(y) - idct(y, type=2, norm="ortho", axis=0)).max() <= 1e-13 * size * np.sqrt(N)
    assert np.abs(idct_ortho(y) - x).max() <= 1e-13 * size * np.sqrt(N)


def test_one_dimensional_and_orthonormal():
    x = np.arange(7.0)
    assert dct_ortho(x).shape == (7,)
    assert np.isclose(np.linalg.norm(dct_ortho(x)), np.linalg.norm(x))  # an orthonormal transform keeps the norm
    assert np.allclose(dct_ortho(np.ones(5)), [np.sqrt(5.0), 0, 0, 0, 0])
