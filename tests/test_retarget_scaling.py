"""Retargeting is linear in the number of frames, with the results of the former dense implementation.

The slow references below are the dense implementations the banded / sparse
ones replaced (kept here only, to check equality to round-off).
"""
from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.linalg import cholesky_banded

import facegeom.methods.tangent_retarget as tr
from facegeom.linalg import banded_inverse_diagonal
from facegeom.methods.tangent import TangentSolver
from facegeom.methods.tangent_retarget import (
    BETA_GRID,
    LAMBDA_GRID,
    TangentRetargeter,
    evenly_spread,
    loo_label_weight,
    second_difference,
    whittaker_smooth,
)


def smooth_sequence(T=100, p=12, seed=0, noise=0.0):
    """Markers moved by 4 smooth random 'expressions', plus optional Gaussian jitter."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)
    curves = np.stack([np.sin(2 * np.pi * (f * t + ph)) for f, ph in rng.uniform(0.3, 1.5, (4, 2))], 1)
    S = rng.normal(size=(p, 3))[None] * 3 + np.einsum("te,epi->tpi", curves, rng.normal(size=(4, p, 3)))
    return S + noise * rng.normal(size=S.shape)


def character(S, lab, seed=0, noise=0.0):
    """A smooth non-linear character on the labelled frames (optionally noisy)."""
    X = S[lab]
    return 1.2 * X + 0.5 + 0.1 * np.sin(X) * X + noise * np.random.default_rng(seed + 7).normal(size=X.shape)


def reference_whittaker(S, lam="auto", grid=LAMBDA_GRID):
    """The former implementation: dense eigen-decomposition of D2^T D2 (cubic in T)."""
    S = np.asarray(S, dtype=np.float64)
    T = S.shape[0]
    if T < 3 or lam == 0:
        return S.copy(), 0.0
    D2 = second_difference(T).toarray()
    w, U = np.linalg.eigh(D2.T @ D2)
    w = np.maximum(w, 0.0)
    Z = U.T @ S.reshape(T, -1)
    if lam == "auto":
        best, lam = np.inf, grid[0]
        for g in grid:
            h = 1.0 / (1.0 + g * w)
            score = float((((1.0 - h)[:, None] * Z) ** 2).sum()) / (1.0 - h.sum() / T) ** 2
            if score < best:
                best, lam = score, float(g)
    h = 1.0 / (1.0 + float(lam) * w)
    return (U @ (h[:, None] * Z)).reshape(S.shape), float(lam)


def reference_loo(B, labelled, residual, grid=BETA_GRID, zero_score=None, noise=None):
    """The former implementation: the dense (M, M) smoother from a dense inverse (quadratic or cubic in N).

    With ``noise``: also Stein's unbiased risk of the fitted labels from the same dense smoother, and the largest
    candidate replaces the leave-one-out choice where its risk is lower.
    """
    B = sp.csr_matrix(B)
    scale = B.diagonal().mean()
    scale = scale if scale > 0 else 1.0
    r = np.asarray(residual, dtype=np.float64).reshape(len(labelled), -1)
    n = r.size  # labels x columns
    s2 = 0.0 if noise is None else noise ** 2
    scores, risk = np.empty(len(grid)), np.empty(len(grid))
    for k, g in enumerate(grid):
        if g == 0:
            scores[k] = float((r ** 2).sum()) if zero_score is None else float(zero_score)
            risk[k] = float((r ** 2).sum()) - n * s2
            continue
        W = TangentSolver(B, labelled, g * scale, dense_map=True).map_
        S = W[:, labelled].T
        denom = np.maximum(1.0 - np.diag(S), 1e-9)
        scores[k] = float((((r - S @ r) / denom[:, None]) ** 2).sum())
        risk[k] = float(((r - S @ r) ** 2).sum()) + 2 * s2 * r.shape[1] * np.trace(S) - n * s2
    best = int(np.argmin(scores))
    if noise is None:
        return float(grid[best] * scale), scores
    if risk[int(np.argmax(grid))] < risk[best]:
        best = int(np.argmax(grid))
    return float(grid[best] * scale), np.stack([scores, risk])


@pytest.mark.parametrize("n,b", [(1, 0), (1, 2), (2, 2), (5, 2), (40, 2), (33, 3), (20, 1), (25, 6)])
def test_banded_inverse_diagonal_is_exact(n, b):
    rng = np.random.default_rng(n * 10 + b)
    A = np.zeros((n, n))
    for o in range(1, min(b, n - 1) + 1):
        v = rng.normal(size=n - o)
        A += np.diag(v, o) + np.diag(v, -o)
    A += np.diag(np.abs(A).sum(axis=1) + rng.uniform(0.1, 2.0, n))
    ab = np.zeros((b + 1, n))
    for o in range(min(b, n - 1) + 1):
        ab[b - o, o:] = np.diag(A, o)
    d = banded_inverse_diagonal(cholesky_banded(ab, lower=False))
    assert np.allclose(d, np.diag(np.linalg.inv(A)), rtol=1e-12, atol=0)


@pytest.mark.parametrize("seed,noise,lam", [(0, 0.0, "auto"), (1, 0.05, "auto"), (2, 0.3, "auto"), (3, 0.05, 3.0)])
def test_whittaker_matches_the_dense_reference(seed, noise, lam):
    S = smooth_sequence(T=150, p=7, seed=seed, noise=noise)
    X, got = whittaker_smooth(S, lam)
    Xr, want = reference_whittaker(S, lam)
    assert got == want
    assert np.allclose(X, Xr, rtol=0, atol=1e-10 * np.abs(S).max())  # cond(I + lam Q) * eps


@pytest.mark.parametrize("strategy", ["frame", "marker"])
@pytest.mark.parametrize("seed", [0, 1])
def test_loo_label_weight_matches_the_dense_reference(strategy, seed, monkeypatch):
    S = smooth_sequence(T=80, p=5, seed=seed, noise=0.02)
    lab = evenly_spread(80, 8)
    seen = {}

    def spy(B, labelled, r, grid=BETA_GRID, zero_score=None, noise=None):
        seen["args"] = (B, labelled, r, zero_score)
        return loo_label_weight(B, labelled, r, grid, zero_score, noise)

    monkeypatch.setattr(tr, "loo_label_weight", spy)
    TangentRetargeter(strategy=strategy, field="position").fit(S, lab, character(S, lab, seed, 0.05))
    B, labelled, r, zero = seen["args"]
    beta, scores = loo_label_weight(B, labelled, r, zero_score=zero)
    beta_ref, scores_ref = reference_loo(B, labelled, r, zero_score=zero)
    assert beta == beta_ref
    # near interpolation 1 - S_ii cancels: the last candidates agree to round-off divided by (1 - S_ii)^2
    assert np.allclose(scores, scores_ref, rtol=1e-6, atol=0)


@pytest.mark.parametrize("strategy", ["frame", "marker"])
@pytest.mark.parametrize("noise", [0.0, 0.004, 0.05])
def test_risk_label_weight_matches_the_dense_reference(strategy, noise, monkeypatch):
    S = smooth_sequence(T=80, p=5, seed=2, noise=0.02)
    lab = evenly_spread(80, 8)
    seen = {}

    def spy(B, labelled, r, grid=BETA_GRID, zero_score=None, noise=None):
        seen["args"] = (B, labelled, r)
        return loo_label_weight(B, labelled, r, grid, zero_score, noise)

    monkeypatch.setattr(tr, "loo_label_weight", spy)
    TangentRetargeter(strategy=strategy, label_noise=noise).fit(S, lab, character(S, lab, 2, 0.02))
    B, labelled, r = seen["args"]
    beta, scores = loo_label_weight(B, labelled, r, noise=noise)
    beta_ref, scores_ref = reference_loo(B, labelled, r, noise=noise)
    assert beta == beta_ref
    assert np.allclose(scores, scores_ref, rtol=1e-6, atol=1e-12 * max(float((r ** 2).sum()), 1e-300))


@pytest.mark.parametrize("strategy", ["frame", "marker"])
@pytest.mark.parametrize("seed,T,p,noise", [(0, 100, 80, 0.0), (1, 100, 12, 0.05), (2, 60, 6, 0.05)])
def test_default_retargeter_matches_the_dense_reference(strategy, seed, T, p, noise, monkeypatch):
    S = smooth_sequence(T=T, p=p, seed=seed, noise=noise)
    lab = evenly_spread(T, 10)
    Y = character(S, lab, seed, noise)
    new = TangentRetargeter(strategy=strategy).fit(S, lab, Y)
    monkeypatch.setattr(tr, "whittaker_smooth", reference_whittaker)
    monkeypatch.setattr(tr, "loo_label_weight", reference_loo)
    old = TangentRetargeter(strategy=strategy).fit(S, lab, Y)
    assert new.beta_ == old.beta_ and new.source_smoothing_ == old.source_smoothing_
    assert np.allclose(new.result_, old.result_, rtol=0, atol=1e-9 * np.abs(old.result_).max())


def test_twenty_thousand_frames_in_linear_memory():
    from facegeom.bench.retarget_scaling import synthetic_take

    S, lab, Y = synthetic_take(20_000, p=10, labels=20, seed=3)
    S = S + 0.01 * np.random.default_rng(3).normal(size=S.shape)
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        out = TangentRetargeter().fit(S, lab, Y).transform()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    seconds = time.perf_counter() - t0
    assert out.shape == S.shape and np.isfinite(out).all()
    # one dense (T, T) float64 matrix alone would be 3.2 GB
    assert peak < 300 * 2**20, f"peak traced allocation {peak / 2**20:.0f} MB"
    assert seconds < 60, f"{seconds:.1f} s"


def test_bench_retarget_scaling_command(tmp_path):
    import csv

    from click.testing import CliRunner

    from facegeom.cli.main import cli

    out = tmp_path / "res"
    r = CliRunner().invoke(cli, ["bench", "retarget-scaling", "--frames", "60,120", "--markers", "5", "--in-process",
                                 "--methods", "tangent;copy", "--out", str(out)])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(out / "retarget-scaling.csv")))
    assert [(row["frames"], row["method"], row["status"]) for row in rows] == [
        ("60", "tangent", "ok"), ("60", "copy", "ok"), ("120", "tangent", "ok"), ("120", "copy", "ok")]
    assert all(float(row["seconds"]) >= 0 and float(row["peak_mb"]) > 0 for row in rows)
    assert (out / "retarget-scaling-summary.md").is_file()


def test_isolated_case_reports_time_and_memory():
    from facegeom.bench.retarget_scaling import run
    from facegeom.registry import parse_method

    (row,) = run([parse_method("tangent-exact=tangent:beta=None,ridge=0.0001,source_smoothing=0")], frames=(80,),
                 p=4, isolate=True, timeout=120, mem_gb=8, echo=lambda s: None)
    assert row["status"] == "ok" and row["memory"] == "ru_maxrss" and row["seconds"] > 0


def test_labels_thousands_of_frames_apart_are_solved_not_called_singular():
    """A temporal smoothness between labels 2,500 frames apart is regular but ill-conditioned (a random
    right-hand side is solved to about 1e-6 only): the label weight's candidates and the final solve are checked on
    their own right-hand sides, and give the smooth interpolation of the labels' residuals."""
    T = 10_000
    D2 = second_difference(T)
    Q = (D2.T @ D2).tocsr()
    lab = evenly_spread(T, 5)  # 2,500 frames apart
    r = np.random.default_rng(0).normal(size=(lab.size, 6))
    beta, scores = loo_label_weight(Q, lab, r)
    assert beta > 0 and np.isfinite(scores).all()
    Y = TangentSolver(Q, lab, beta, dense_map=False).solve(r)
    assert np.isfinite(Y).all()
    assert np.abs(Y[lab] - r).max() < 0.05 * np.abs(r).max()  # the labels are (softly) met
    assert np.abs(Y).max() < 3 * np.abs(r).max()  # and the frames between are an interpolation, not noise
