"""Label-noise and source-noise study of retargeting (the weakness the paper names).

Protocol (seeded): the sequences of ``facegeom bench retarget`` (same builder,
same seed), ``labels`` known frames evenly spread. For every noise level
``sigma`` (mm, standard deviation per coordinate) and each kind

- ``labels``: Gaussian noise added to the known character frames only;
- ``source``: Gaussian noise added to every frame of the actor's markers;

every method gets the same noisy inputs, and its result is compared with the
character's clean true markers (mean marker error, mm). The noise of
sequence ``i``, level ``k`` and kind is drawn from its own seeded stream.
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.bench.common import progress_bar
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.bench.retarget import build_sequences
from facegeom.constants import CM_TO_MM
from facegeom.errors import SolveError
from facegeom.methods.tangent_retarget import evenly_spread
from facegeom.registry import MethodSpec

LEVELS_MM = (0.0, 0.1, 0.2, 0.5, 1.0)
KINDS = ("labels", "source")


def run(seqs, specs: list[MethodSpec], levels=LEVELS_MM, labels: int = 10, seed: int = 0, progress=True):
    """Retarget every sequence at every noise level and kind with every method.

    Parameters
    ----------
    seqs : list of Sequence
        Actor/character sequences, markers ``(T, p, 3)`` float64 in cm.
    specs : list of MethodSpec
        The retargeters.
    levels : sequence of float
        Noise standard deviations per coordinate, mm.
    labels : int
        Known character frames, evenly spread.
    seed : int
        Seed of the noise (one stream per sequence, kind and level).
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of dict
        One row per sequence, kind (``labels``: noise on the known character
        frames only; ``source``: on every frame of the actor's markers), level
        and method: ``sequence``, ``name``, ``kind``, ``sigma_mm``, ``method``,
        ``mean_mm`` (mean marker error against the clean truth, mm; NaN when the
        method raised :class:`~facegeom.errors.SolveError`) and ``time_ms``.
    """
    rows = []
    it = progress_bar(list(enumerate(seqs)), "noise", progress, unit="seq")
    for si, s in it:
        lab = evenly_spread(s.n_frames, labels)
        for kind_i, kind in enumerate(KINDS):
            for li, sigma in enumerate(levels):
                rng = np.random.default_rng([int(seed), si, kind_i, li, 4242])
                X, Yh = s.source, s.target[lab]
                if kind == "labels":
                    Yh = Yh + rng.normal(size=Yh.shape) * sigma / CM_TO_MM
                else:
                    X = X + rng.normal(size=X.shape) * sigma / CM_TO_MM
                for spec in specs:
                    t = time.perf_counter()
                    try:
                        Y = spec.build("retargeters").fit(X, lab, Yh).transform()
                    except SolveError:
                        Y = np.full_like(s.target, np.nan)
                    dt = time.perf_counter() - t
                    rows.append({"sequence": si, "name": s.name, "kind": kind, "sigma_mm": sigma,
                                 "method": spec.label,
                                 "mean_mm": float(np.linalg.norm(Y - s.target, axis=2).mean() * CM_TO_MM),
                                 "time_ms": dt * 1e3})
    return rows


def _mean(rows, **where) -> float:
    v = np.array([r["mean_mm"] for r in rows if all(r[k] == x for k, x in where.items())], dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else float("nan")


def summarize(rows, specs, levels) -> str:
    """Two Markdown tables (label noise, then source noise): mean marker error per method and level.

    Parameters
    ----------
    rows : list of dict
        The rows of :func:`run`.
    specs : list of MethodSpec
        The methods, one line each (matched by ``label``).
    levels : sequence of float
        The noise levels (mm), one column each.

    Returns
    -------
    str
        The two tables separated by a blank line; each cell is the mean of
        ``mean_mm`` over the sequences (NaN ignored).
    """
    parts = []
    for kind in KINDS:
        header = ["method"] + [f"{kind} sigma={s:g} mm" for s in levels]
        table = [[spec.label] + [_mean(rows, kind=kind, sigma_mm=s, method=spec.label) for s in levels]
                 for spec in specs]
        parts.append(format_table(header, table))
    return "\n\n".join(parts)


def plot(rows, specs, levels):
    """Mean marker error against the noise level, for label noise and source noise: a matplotlib figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(12, 4.4))
    for a, kind in zip(ax, KINDS):
        for spec in specs:
            a.plot(levels, [_mean(rows, kind=kind, sigma_mm=s, method=spec.label) for s in levels], "o-",
                   label=spec.label)
        a.set(xlabel=f"noise on the {'known character frames' if kind == 'labels' else 'actor markers'} "
                     "(sigma per coordinate, mm)", ylabel="mean marker error (mm)", title=f"{kind} noise")
    ax[0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def main(model, takes, specs, count, seed, out, levels=LEVELS_MM, labels=10, frames=100, echo=print, plot_it=True,
         progress=True):
    """Run the label-noise and source-noise study and write its report.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    takes : list of (str, ndarray)
        Named takes of ICT-ordered weights ``(T, E)``.
    specs : list of MethodSpec
        The retargeters.
    count : int
        Number of sequences (:func:`~facegeom.bench.retarget.build_sequences`,
        the same as ``bench retarget`` for the same seed).
    seed : int
        Seed of the sequences and the noise.
    out : path-like or None
        Output folder; ``None`` only echoes the summary.
    levels : sequence of float
        Noise levels, mm.
    labels : int
        Known character frames per sequence.
    frames : int
        Frames per sequence.
    echo : callable(str)
        Receives the protocol line, the tables and the list of files written.
    plot_it : bool
        Also write the plot.
    progress : bool
        Show a progress bar.

    Returns
    -------
    rows : list of dict
        The rows of :func:`run`, written to ``out/noise.csv``.
    table : str
        The tables of :func:`summarize`, written to ``out/noise-summary.md``;
        the plot goes to ``out/noise.png``.
    """
    seqs = build_sequences(model, takes, count, frames, seed)
    echo(f"{len(seqs)} sequences of {frames} frames, {labels} labelled frames; noise levels {list(levels)} mm; "
         f"character mean marker motion {np.mean([s.mean_motion() for s in seqs]) * CM_TO_MM:.2f} mm")
    rows = run(seqs, specs, levels, labels, seed, progress)
    report = Report(out, "noise", echo)
    report.csv(rows)
    table = summarize(rows, specs, levels)
    note = (f"mean marker error (mm) against the clean truth; {len(seqs)} sequences, seed {seed}, {labels} labels; "
            f"{machine_note()}")
    report.summary(table, note)
    if plot_it:
        report.plot(lambda: plot(rows, specs, levels))
    report.done()
    return rows, table
