"""Seeded ground-truth scenarios of the comparisons, shared by ``facegeom bench`` and the viewer.

- Face driving: :func:`driving_cases` -- a random identity (source, neutral)
  and the same identity with an expression (target); :func:`realistic_driving_cases`
  -- the same with dense expressions from real takes and a random marker layout per case.
- Blendshape fitting: :func:`fitting_cases` -- a random identity with a sparse
  random expression and a head pose.

The retargeting sequences are built by :mod:`facegeom.model.performance`.
Every random choice comes from the ``seed``; the same seed gives the same cases.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.model.expressions import NAMED, named_expression, random_sparse_expression

__all__ = ["ExpressionCase", "driving_cases", "RealisticDrivingCase", "realistic_driving_cases", "SparseExpressionCase",
           "fitting_cases"]


@dataclass
class ExpressionCase:
    """One face-driving case: an identity, neutral and with an expression.

    Attributes
    ----------
    index : int
        Position of the case in its list.
    kind : str
        The named expression (a key of :data:`facegeom.model.expressions.NAMED`) or ``"random-sparse"``.
    identity : (I,) float64
        Identity coefficients (``FaceModel.random_identity``).
    expression : dict
        Expression weights by shape name.
    """

    index: int
    kind: str
    identity: np.ndarray
    expression: dict


def driving_cases(model, count: int = 50, seed: int = 0) -> list[ExpressionCase]:
    """``count`` driving cases: in every 5, 3 named expressions (cycled in :data:`NAMED` order) and 2 random sparse.

    Named expressions get an intensity ~ U(0.7, 1.0); random sparse ones 2-6
    shapes with weights ~ U(0.3, 1) (:func:`random_sparse_expression`).

    Parameters
    ----------
    model : FaceModel
        The face model (identities and expression names).
    count : int
        Number of cases.
    seed : int
        Seed of identities, expressions and intensities.

    Returns
    -------
    list of ExpressionCase
    """
    rng = np.random.default_rng(seed)
    names = list(NAMED)
    cases, n_named = [], 0
    for i in range(count):
        identity = model.random_identity(rng)
        if i % 5 in (1, 3):
            kind, expr = "random-sparse", random_sparse_expression(model.expression_names, rng)
        else:
            kind = names[n_named % len(names)]
            n_named += 1
            expr = named_expression(kind, float(rng.uniform(0.7, 1.0)))
        cases.append(ExpressionCase(i, kind, identity, expr))
    return cases


@dataclass
class RealisticDrivingCase:
    """One case of the realistic face-driving protocol.

    Attributes
    ----------
    index : int
        Position of the case in its list.
    kind : str
        ``"take"`` (a frame of a real take: dense weights), ``"dense-synthetic"``
        (8-16 random shapes, when no take is given) or ``"random-sparse"``.
    source : str
        The take's name and frame (``"name@frame"``), or ``""``.
    identity : (I,) float64
        Identity coefficients.
    expression : (E,) float64
        Expression weights in the model's shape order.
    markers : int
        Number of markers of the case's random layout.
    layout_seed : int
        Seed of that layout (``layout(model, f"random{markers}", layout_seed)``).
    noise_seed : int
        Seed of the marker noise of this case.
    """

    index: int
    kind: str
    source: str
    identity: np.ndarray
    expression: np.ndarray
    markers: int
    layout_seed: int
    noise_seed: int


def realistic_driving_cases(model, count: int = 20, seed: int = 0, takes=(), markers=(40, 120)
                            ) -> list[RealisticDrivingCase]:
    """``count`` cases of the realistic driving protocol: random identities, real-take and sparse expressions, layouts.

    Even cases take a random frame of a random take (dense ARKit weights as ICT
    weights); odd cases a random sparse expression (2-6 shapes,
    :func:`random_sparse_expression`). Every case has its own random layout of
    ``markers[0]..markers[1]`` markers (``random<k>`` with a seed drawn here) and
    its own noise seed. Without takes the dense cases are ``dense-synthetic``:
    8-16 random shapes at weights ~ U(0.1, 0.8).

    Parameters
    ----------
    model : FaceModel
        The face model.
    count : int
        Number of cases.
    seed : int
        Seed of everything (a stream separate from :func:`driving_cases` with the same seed).
    takes : sequence of (str, (T, E) float array)
        Named takes as ICT weights (``facegeom.io.ict_weights``).
    markers : (int, int)
        Inclusive range of the number of markers.

    Returns
    -------
    list of RealisticDrivingCase
    """
    rng = np.random.default_rng([int(seed), 1919])
    takes = [(str(n), np.asarray(W, dtype=np.float64)) for n, W in takes]
    E = model.n_expressions
    out = []
    for i in range(count):
        identity = model.random_identity(rng)
        source = ""
        if i % 2 == 0 and takes:
            name, W = takes[int(rng.integers(len(takes)))]
            f = int(rng.integers(W.shape[0]))
            kind, source, w = "take", f"{name}@{f}", W[f].copy()
        elif i % 2 == 0:
            kind = "dense-synthetic"
            w = np.zeros(E)
            k = int(rng.integers(8, 17))
            w[rng.choice(E, k, replace=False)] = rng.uniform(0.1, 0.8, k)
        else:
            kind = "random-sparse"
            w = model.expression_vector(random_sparse_expression(model.expression_names, rng))
        k = int(rng.integers(markers[0], markers[1] + 1))
        out.append(RealisticDrivingCase(i, kind, source, identity, w, k, int(rng.integers(2**31)),
                                        int(rng.integers(2**31))))
    return out


@dataclass
class SparseExpressionCase:
    """One blendshape-fitting case: an identity with a sparse expression, seen under a head pose.

    Attributes
    ----------
    identity : (I,) float64
        Identity coefficients.
    weights : (B,) float64
        True expression weights in the model's shape order (2-6 non-zero by default).
    yaw, pitch : float
        Head rotation in degrees (yaw ~ U(-25, 25), pitch ~ U(-15, 15)).
    """

    identity: np.ndarray
    weights: np.ndarray
    yaw: float
    pitch: float


def fitting_cases(model, count: int, seed: int, active=(2, 6)) -> list[SparseExpressionCase]:
    """``count`` fitting cases with ``active[0]..active[1]`` shapes active at weights ~ U(0.2, 1.0).

    Parameters
    ----------
    model : FaceModel
        The face model.
    count : int
        Number of cases.
    seed : int
        Seed (combined with a fixed stream id, so these cases differ from other uses of the same seed).
    active : (int, int)
        Inclusive range of the number of active shapes.

    Returns
    -------
    list of SparseExpressionCase
    """
    rng = np.random.default_rng([int(seed), 5150])
    B = model.n_expressions
    out = []
    for _ in range(count):
        ident = model.random_identity(rng)
        w = np.zeros(B)
        k = int(rng.integers(active[0], active[1] + 1))
        w[rng.choice(B, k, replace=False)] = rng.uniform(0.2, 1.0, k)
        out.append(SparseExpressionCase(ident, w, float(rng.uniform(-25, 25)), float(rng.uniform(-15, 15))))
    return out
