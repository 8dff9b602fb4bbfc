"""Scaling of fit / deform with mesh size: the ICT face subdivided by libigl's ``upsample``.

Level 0 is the face (9,409 vertices), level 1 ~37k, level 2 ~150k. Source and
target (a fixed expression on a fixed identity) are subdivided with the same
matrix, so the markers (``ict80``; original vertices keep their ids) and the
ground truth carry over. Times: ``fit`` once, ``deform`` median of 5.
"""
from __future__ import annotations

import time

import igl
import numpy as np

from facegeom.bench.common import median_time
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.model import layout
from facegeom.registry import MethodSpec

EXPRESSION = {"jawOpen": 0.6, "mouthSmile_L": 0.7, "browInnerUp_R": 0.5}


def run(model, specs: list[MethodSpec], levels=(0, 1, 2), echo=print, repeat: int = 5):
    """Time ``fit`` and ``deform`` of every method on the ICT face subdivided ``level`` times.

    The source is the neutral of a fixed identity, the target the same identity
    with :data:`EXPRESSION`; both are subdivided with the same matrix, and the
    ``ict80`` markers keep their vertex ids.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers.
    levels : sequence of int
        Subdivision levels (0: the face itself, 9,409 vertices).
    echo : callable(str)
        Receives one line per level and method.
    repeat : int
        ``deform`` calls timed per pair (the median is reported).

    Returns
    -------
    list of dict
        One row per level and method: ``level``, ``vertices``, ``method``,
        ``fit_s``, ``deform_ms`` and ``mean_err_mm`` (mean vertex error over
        all vertices, mm).
    """
    a = model.random_identity(0)
    X0 = model.identity_neutral(a)
    T0 = model.face(a, EXPRESSION)
    H = layout(model, "ict80")
    rows = []
    for level in levels:
        if level == 0:
            X, T, F = X0, T0, model.triangles
        else:
            S, F = _upsample(model.triangles, X0.shape[0], level)
            X, T = S @ X0, S @ T0
        for spec in specs:
            method = spec.build("deformers")
            t = time.perf_counter()
            method.fit(X, F, H)
            fit_s = time.perf_counter() - t
            deform_s, Y = median_time(lambda: method.deform(T[H]), repeat)
            err = float(np.linalg.norm(Y - T, axis=1).mean() * 10)
            rows.append({"level": level, "vertices": X.shape[0], "method": spec.label, "fit_s": fit_s,
                         "deform_ms": deform_s * 1e3, "mean_err_mm": err})
            echo(f"  level {level} ({X.shape[0]} vertices) {spec.label:<12} fit {fit_s:7.3f} s   "
                 f"deform {deform_s * 1e3:9.2f} ms   mean error {err:.3f} mm")
    return rows


def _upsample(F, n, level):
    """Subdivision matrix ``S`` (new vertices = S @ old) and faces after ``level`` rounds."""
    import scipy.sparse as sp

    S = sp.identity(n, format="csr")
    for _ in range(level):
        S1, F = igl.upsample_matrix(F, S.shape[0])
        S = (sp.csr_matrix(S1) @ S).tocsr()
    return S, F


def main(model, specs, levels, echo=print):
    """Run the scaling benchmark and echo its table (no file is written).

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers.
    levels : sequence of int
        Subdivision levels.
    echo : callable(str)
        Receives the per-run lines, the table and the machine note.

    Returns
    -------
    rows : list of dict
        The rows of :func:`run`.
    table : str
        Markdown table: method, vertices, fit (s), deform (ms), mean error (mm).
    """
    rows = run(model, specs, levels, echo=echo)
    header = ["method", "vertices", "fit (s)", "deform (ms)", "mean error (mm)"]
    table = format_table(header, [[r["method"], r["vertices"], r["fit_s"], r["deform_ms"], r["mean_err_mm"]]
                                  for r in rows])
    Report(None, "scaling", echo).summary(table, machine_note())
    return rows, table
