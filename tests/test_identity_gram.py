"""The cloud fit's Gram matrix updated from the last round's (only the vertices whose weight changed) equals the
full product, and a point-cloud identity fit gives the same identity either way."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.methods import identity as idm


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.integers(4, 60), st.integers(1, 12), st.floats(0.0, 1.0))
def test_the_updated_gram_is_the_full_product(seed, m, C, share):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3 * m, C)) * rng.uniform(0.1, 10.0)
    before = rng.integers(0, 4, size=m).astype(np.float64) * rng.uniform(0.0, 2.0)
    after = before.copy()
    moved = rng.random(m) < share
    after[moved] = rng.integers(0, 4, size=int(moved.sum())) * rng.uniform(0.0, 2.0)
    G = idm._weighted_gram(A, before)
    got = idm._updated_gram(A, G, before, after)
    want = idm._weighted_gram(A, after)
    scale = max(1.0, float(np.abs(want).max()))
    assert np.abs(got - want).max() <= 1e-12 * scale
    assert np.array_equal(got, got.T)
    if not moved.any() or np.array_equal(before, after):
        assert got is G  # nothing changed: nothing computed


def test_a_cloud_fit_gives_the_same_identity_updated_or_recomputed(face_model, monkeypatch):
    from facegeom.model.targets import PointCloudTarget
    from facegeom.methods.identity import IdentityFitter

    rng = np.random.default_rng(3)
    G = np.asarray(face_model.neutral, dtype=np.float64)
    a = 0.8 * rng.normal(size=face_model.n_identities)
    X = G + np.tensordot(a[:20], np.asarray(face_model.identity_modes)[:20], axes=1)
    pts = X[:6706][rng.random(6706) < 0.6] + rng.normal(scale=0.03, size=(1, 3))
    target = PointCloudTarget(pts)
    fits, default = {}, idm.GRAM_INCREMENTAL
    for share in (default, -1.0):  # -1: every round's Gram computed in full
        monkeypatch.setattr(idm, "GRAM_INCREMENTAL", share)
        calls = []
        full = idm._weighted_gram
        monkeypatch.setattr(idm, "_weighted_gram", lambda A, w: calls.append(1) or full(A, w))
        fits[share] = (IdentityFitter(cloud_passes=1, icp_iterations=40).fit(face_model, [target]), len(calls))
        monkeypatch.setattr(idm, "_weighted_gram", full)
    (inc, n_inc), (ref, n_ref) = fits[default], fits[-1.0]
    assert n_inc < n_ref / 4  # most rounds updated, not recomputed
    np.testing.assert_allclose(inc.identity, ref.identity, atol=1e-9)
    np.testing.assert_allclose(inc.weights, ref.weights, atol=1e-9)
