"""``facegeom.linalg.box_lsq``: exact bounded least squares, as scipy's BVLS finds it, on random small problems."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import lsq_linear

from facegeom.linalg import box_lsq


@settings(max_examples=200, deadline=None, derandomize=True)
@given(n=st.integers(1, 40), seed=st.integers(0, 2 ** 32 - 1), upper=st.sampled_from([0.5, 1.0, 2.0]),
       tall=st.booleans(), spread=st.floats(0.1, 8.0))
def test_box_lsq_is_the_bounded_minimum(n, seed, upper, tall, spread):
    rng = np.random.default_rng(seed)
    m = n + 20 if tall else max(1, n // 2)  # wide problems have many minimisers: compare the cost only
    A = rng.normal(size=(m, n)) * rng.uniform(0.05, 3.0, n)
    b = rng.normal(size=m) * spread
    x = box_lsq(A, b, upper)
    assert x.shape == (n,) and x.min() >= 0.0 and x.max() <= upper
    ref = lsq_linear(A, b, bounds=(0.0, upper), method="bvls", tol=1e-13).x
    cost = lambda v: float(np.sum((A @ v - b) ** 2))  # noqa: E731
    assert cost(x) <= cost(ref) * (1 + 1e-9) + 1e-12
    g = A.T @ (A @ x - b)  # KKT: no feasible descent direction
    tol = 1e-7 * max(np.abs(g).max(), np.abs(A).max() * np.abs(b).max(), 1e-12)
    assert (g[x <= 0.0] >= -tol).all() and (g[x >= upper] <= tol).all()
    inside = (x > 0.0) & (x < upper)
    assert (np.abs(g[inside]) <= tol).all()


def test_box_lsq_takes_the_nnls_start_and_reaches_the_upper_bound():
    A = np.eye(3)
    b = np.array([3.0, -1.0, 0.5])
    np.testing.assert_allclose(box_lsq(A, b, 1.0), [1.0, 0.0, 0.5])
    np.testing.assert_allclose(box_lsq(A, b, 1.0, x0=np.array([3.0, 0.0, 0.5])), [1.0, 0.0, 0.5])
