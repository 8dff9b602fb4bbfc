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
    """Fit and apply every deformer on every driving case; one row of errors and times per pair.

    The markers of layout ``layout_name`` on the case's neutral face (its
    identity, no expression) are moved to their positions on the true
    expression face; each method is fitted on the neutral with those marker ids
    and deforms it.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers (a fresh instance per case).
    cases : list of ExpressionCase
        Identity and expression of every case
        (:func:`~facegeom.model.scenarios.driving_cases`).
    layout_name : str
        Marker layout: ``ict80``, ``landmarks68`` or ``random<k>``.
    layout_seed : int
        Seed of a ``random<k>`` layout.
    progress : bool
        Show a progress bar (one step per fit).
    deform_repeat : int
        ``deform`` calls timed per pair (the median is reported).

    Returns
    -------
    list of dict
        One row per case and method: ``case``, ``kind``, ``method``, the errors
        of :func:`~facegeom.metrics.face_errors_mm` in mm (``mean_mm``,
        ``rms_mm``, ``max_mm`` over the face area, ``mean_all_mm`` over all
        vertices, ``frobenius_mm``), ``fit_s`` and ``deform_ms`` (median).

    Raises
    ------
    InputError
        An unknown layout name, or inputs a method refuses.
    """
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
    """Per-method aggregates of the rows of :func:`run`, for :func:`~facegeom.bench.report.format_table`.

    Parameters
    ----------
    rows : list of dict
        The rows of :func:`run`.
    specs : list of MethodSpec
        The methods, in table order (matched by ``label``).

    Returns
    -------
    header : list of str
        The column titles.
    table_rows : list of list
        One line per method: the means over cases of ``mean_mm``, ``max_mm``,
        ``mean_all_mm`` and ``frobenius_mm``, the RMS over cases of ``rms_mm``
        (all mm), and the medians of ``fit_s`` and ``deform_ms``.
    """
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
    """Run the face-driving benchmark and write its report.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    specs : list of MethodSpec
        The deformers.
    cases : int
        Number of cases (:func:`~facegeom.model.scenarios.driving_cases`).
    seed : int
        Seed of the cases.
    layout_name : str
        Marker layout (``ict80``, ``landmarks68``, ``random<k>``).
    layout_seed : int
        Seed of a ``random<k>`` layout.
    out : Path or None
        Output folder; ``None`` only echoes the summary.
    progress : bool
        Show a progress bar.
    echo : callable(str)
        Receives the table, the note and the list of files written.
    plot_it : bool
        Also write the plot of the Frobenius error per case.

    Returns
    -------
    rows : list of dict
        The rows of :func:`run`, written to ``out/drive.csv``.
    table : str
        The Markdown table of :func:`summarize`, written with a protocol and
        machine note to ``out/drive-summary.md``; the plot goes to
        ``out/drive.png``.
    """
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
