"""A head in pieces driven through markers on its skin: eyes, teeth and tongue follow by their roles.

The head here is the ICT face (the skin) with two eyeballs, upper and lower teeth blocks and a lash card added
as separate pieces, registered onto itself (the identity registration), so the roles are found as on any head
and the skin's motion is known exactly (the model's own expressions). The route end to end on the MakeHuman
head (six parts) is in ``tests/test_character.py``.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.constants import CM_TO_MM
from facegeom.methods.pieces import PieceMotion, classify_pieces, split_pieces
from facegeom.methods.transfer import Character, HeadRegistration, stored_character, character_arrays
from facegeom.registration import kabsch


def _sphere(centre, radius, n=8):
    """A UV sphere (closed, triangles) -> (V, F)."""
    th, ph = np.meshgrid(np.linspace(0.2, np.pi - 0.2, n), np.linspace(0, 2 * np.pi, 2 * n, endpoint=False),
                         indexing="ij")
    V = np.c_[np.sin(th).ravel() * np.cos(ph).ravel(), np.sin(th).ravel() * np.sin(ph).ravel(), np.cos(th).ravel()]
    F = []
    for i in range(n - 1):
        for j in range(2 * n):
            a, b = i * 2 * n + j, i * 2 * n + (j + 1) % (2 * n)
            F += [[a, b, a + 2 * n], [b, b + 2 * n, a + 2 * n]]
    return centre + radius * V, np.array(F)


def _box(centre, size):
    """A box (8 vertices, 12 triangles) -> (V, F)."""
    c = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return centre + c * np.asarray(size), F


@pytest.fixture(scope="module")
def head(face_model):
    """The ICT face with eyes, teeth and a lash card as pieces, and its identity registration."""
    m = face_model
    G = np.asarray(m.neutral, dtype=np.float64)
    lm = np.asarray(m.landmarks)
    parts = [(G, np.asarray(m.triangles(), dtype=np.int64) if callable(m.triangles) else m.triangles)]
    r = 1.2
    for ids in (lm[42:48], lm[36:42]):
        parts.append(_sphere(G[ids].mean(axis=0) - [0.0, 0.0, r], r))
    lips = G[lm[[62, 66]]].mean(axis=0)
    parts.append(_box(lips + [0.0, 0.6, -1.5], (2.5, 0.6, 1.0)))  # upper teeth: above the lips' line
    parts.append(_box(lips + [0.0, -0.8, -1.5], (2.5, 0.6, 1.0)))  # lower teeth: below
    parts.append(_box(G[lm[37]] + [0.0, 0.05, 0.05], (0.8, 0.02, 0.3)))  # a lash card on the right upper lid
    V, F, at = [], [], 0
    for Vp, Fp in parts:
        V.append(Vp)
        F.append(Fp + at)
        at += len(Vp)
    V, F = np.vstack(V), np.vstack(F)
    reg = HeadRegistration(G, parts[0][1], G.copy(), 1.0, np.eye(3), np.zeros(3), 1.0, CM_TO_MM,
                           np.zeros(m.n_identities))
    pieces = split_pieces(V, F)
    classify_pieces(m, reg, V, pieces)
    return V, F, pieces, reg


def test_roles_are_found_and_the_skin_alone_is_driven(face_model, head):
    V, F, pieces, reg = head
    roles = sorted(p.role for p in pieces)
    assert roles == ["eye", "eye", "follow", "jaw", "skin", "stay"]
    pm = PieceMotion.build(face_model, reg, V, F, pieces)
    assert pm.skin.size == face_model.n_vertices and pm.skin_faces.max() < pm.skin.size
    assert [g[0] for g in pm.groups] == ["skull", "jaw"]
    jaw = [p for p in pieces if p.role == "jaw"][0]
    assert set(pm.groups[1][1].tolist()) == set(jaw.vertices.tolist())
    skull = set(pm.groups[0][1].tolist())
    for p in pieces:
        if p.role in ("eye", "stay"):
            assert set(p.vertices.tolist()) <= skull
    assert PieceMotion.build(face_model, reg, V[:face_model.n_vertices], F[:len(reg.head_faces)],
                             pieces[:1]) is None  # the skin is the whole head: nothing to follow


def _skin_frames(model, names_weights):
    D = np.asarray(model.expression_deltas, dtype=np.float64)
    G = np.asarray(model.neutral, dtype=np.float64)
    out = []
    for nw in names_weights:
        w = np.zeros(len(model.expression_names))
        for name, x in nw.items():
            w[list(model.expression_names).index(name)] = x
        out.append(G + np.einsum("k,kvc->vc", w, D))
    return np.stack(out)


def test_the_jaw_opens_the_lower_teeth_and_the_skull_keeps_the_rest(face_model, head):
    V, F, pieces, reg = head
    pm = PieceMotion.build(face_model, reg, V, F, pieces)
    S = _skin_frames(face_model, [{}, {"jawOpen": 1.0}, {"mouthSmile_L": 1.0, "browInnerUp_L": 1.0}])
    X = pm.frames(S, V)
    np.testing.assert_allclose(X[0], V, atol=1e-12)  # the rest skin: every piece at rest
    by = {p.role: p for p in pieces}
    lower = by["jaw"].vertices
    drop = (X[1, lower] - V[lower])[:, 1].mean()
    assert drop < -0.3  # the lower teeth come down with the jaw (cm)
    for p in pieces[1:]:
        for t in range(3):  # every piece but the follower moves rigidly
            if p.role == "follow":
                continue
            R, tt = kabsch(V[p.vertices], X[t, p.vertices])
            assert np.abs(V[p.vertices] @ R.T + tt - X[t, p.vertices]).max() < 1e-9
    for p in (by["stay"],) + tuple(q for q in pieces if q.role == "eye"):
        # no head motion: the skull's pieces stay (the eyes within 0.5 mm, the teeth 0.3: the skull's patch is fitted robustly)
        assert np.abs(X[1:, p.vertices] - V[p.vertices]).max() < 0.06
    lash = by["follow"].vertices
    lid = np.linalg.norm(X[:, lash] - V[lash], axis=2).max()
    assert lid < 1.0  # the card copies the lid's small motion, not the jaw's


def test_a_head_stored_with_its_skin_only_finds_the_same_roles(face_model, head):
    V, F, pieces, reg = head
    arrays = character_arrays(reg, pieces[0].vertices)
    stored = stored_character(face_model, V, F, arrays)
    assert len(stored.pieces) == 1
    full = PieceMotion.build(face_model, reg, V, F, pieces)
    again = PieceMotion.build(face_model, stored.registration, V, F, stored.pieces)
    assert [g[0] for g in again.groups] == [g[0] for g in full.groups]
    for a, b in zip(again.groups, full.groups):
        assert sorted(a[1].tolist()) == sorted(b[1].tolist())
    assert sorted(again.follow.tolist()) == sorted(full.follow.tolist())


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.integers(1, 6))
def test_the_linear_frames_are_the_frames(face_model, head, seed, q):
    """Coefficients on the widened basis give exactly :meth:`PieceMotion.frames` of the skin's frames."""
    V, F, pieces, reg = head
    pm = PieceMotion.build(face_model, reg, V, F, pieces)
    rng = np.random.default_rng(seed)
    basis = rng.normal(size=(q + 4, pm.skin.size))
    basis[q:q + 3] = pm.rest.T  # the rest shape's coordinates and a row of ones, as the tangent deformer's
    basis[q + 3] = 1.0
    C = np.zeros((5, 3, q + 4))
    C[:, :, :q] = 0.01 * rng.normal(size=(5, 3, q))
    C[:, :, q:q + 3] = np.eye(3) + 0.02 * rng.normal(size=(5, 3, 3))
    C[:, :, q + 3] = rng.normal(size=(5, 3))
    S = np.swapaxes(np.matmul(C, basis), 1, 2)
    C2, B2 = pm.linear(C, basis, V)
    np.testing.assert_allclose(np.swapaxes(np.matmul(C2, B2), 1, 2), pm.frames(S, V), atol=1e-9)
    assert pm.linear(C[:2], basis, V)[1] is B2  # the widened basis is built once per basis
