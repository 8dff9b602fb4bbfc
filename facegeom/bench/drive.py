"""The face-driving benchmark (the paper's section 4.3 / Fig. 10, on the real ICT face).

Protocol (seeded):

- ``cases`` source/target pairs. Source = a random identity (coefficients
  ~ N(0, 1)), neutral. Target = the same identity with an expression: the
  named expressions of :mod:`facegeom.model.expressions` (six basic emotions, jaw
  open, pucker, blink, three asymmetric combinations), cycled, each at an
  intensity ~ U(0.7, 1.0), alternating with random sparse combinations
  (2-6 shapes, weights ~ U(0.3, 1)).
- Markers: a layout of :mod:`facegeom.model.layouts` (default ``ict80``); their
  target positions are the labels.
- Every method is fitted on the source with the marker ids, then deforms it
  from the labels. Errors against the true target: mean, RMS and max vertex
  distance over the narrow face area (vertices ``[0, 6706)``, where the
  markers are) in mm, the mean over the whole mesh, and the paper's Frobenius
  error ``||Y - Y_true||_F`` over all vertices in mm. Times: ``fit`` and the
  median of 5 ``deform`` calls.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facegeom.bench.common import median_time
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.metrics import face_errors_mm
from facegeom.model import layout
from facegeom.model.scenarios import ExpressionCase, driving_cases
from facegeom.registry import MethodSpec


def run(model, specs: list[MethodSpec], cases: list[ExpressionCase], layout_name: str = "ict80", layout_seed: int = 0,
        progress: bool = True, deform_repeat: int = 5) -> list[dict]:
    handles = layout(model, layout_name, layout_seed)
    F = model.triangles
    rows = []
    it = cases
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cases) * len(specs), desc="bench drive", unit="fit", mininterval=0.5)
    for case in it:
        X = model.identity_neutral(case.identity)
        T = model.face(case.identity, case.expression)
        labels = T[handles]
        for spec in specs:
            method = spec.build("deformers")
            t = time.perf_counter()
            method.fit(X, F, handles)
            fit_s = time.perf_counter() - t
            deform_s, Y = median_time(lambda: method.deform(labels), deform_repeat)
            row = {"case": case.index, "kind": case.kind, "method": spec.label}
            row.update(face_errors_mm(Y, T))
            row.update({"fit_s": fit_s, "deform_ms": deform_s * 1e3})
            rows.append(row)
            if bar:
                bar.update()
    if bar:
        bar.close()
    return rows


def summarize(rows: list[dict], specs: list[MethodSpec]) -> tuple[list[str], list[list]]:
    header = ["method", "mean (mm)", "RMS (mm)", "max (mm)", "mean all (mm)", "Frobenius (mm)",
              "fit (s)", "deform (ms)"]
    out = []
    for s in specs:
        r = [x for x in rows if x["method"] == s.label]
        col = lambda k: np.array([x[k] for x in r])  # noqa: E731
        out.append([s.label, col("mean_mm").mean(), np.sqrt((col("rms_mm") ** 2).mean()), col("max_mm").mean(),
                    col("mean_all_mm").mean(), col("frobenius_mm").mean(), float(np.median(col("fit_s"))),
                    float(np.median(col("deform_ms")))])
    return header, out


def plot(rows: list[dict], specs: list[MethodSpec]):
    """The Frobenius error of every method per case (log scale): a matplotlib figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for s in specs:
        r = sorted((x for x in rows if x["method"] == s.label), key=lambda x: x["case"])
        ax.plot([x["case"] for x in r], [x["frobenius_mm"] for x in r], marker="o", ms=3, lw=1, label=s.label)
    ax.set_xlabel("test case")
    ax.set_ylabel("Frobenius error ||Y - Y_true||_F (mm)")
    ax.set_title("Face driving on the ICT face (cf. Zhang et al. 2017, Fig. 10)")
    ax.set_yscale("log")
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    return fig


def main(model, specs, cases: int, seed: int, layout_name: str, layout_seed: int, out: Path | None,
         progress: bool = True, echo=print, plot_it: bool = True) -> tuple[list[dict], str]:
    cs = driving_cases(model, cases, seed)
    rows = run(model, specs, cs, layout_name, layout_seed, progress=progress)
    header, table_rows = summarize(rows, specs)
    table = format_table(header, table_rows)
    note = (f"{len(cs)} cases, seed {seed}, layout {layout_name}"
            + (f" (seed {layout_seed})" if layout_name.startswith("random") else "")
            + f"; {machine_note()}")
    report = Report(out, "drive", echo)
    report.csv(rows)
    report.summary(table, note)
    if plot_it:
        report.plot(lambda: plot(rows, specs), dpi=120)
    report.done()
    return rows, table
