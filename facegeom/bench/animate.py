"""Performance-driven animation benchmark: many takes, retargeted and driven on their characters.

Protocol (seeded): the sequences of ``facegeom bench retarget`` (4 in 5 windows
of the real takes). For each sequence the deformer is fitted **once** on the
character's neutral face with the 80 marker ids; every retargeter's marker
sequence (``labels`` known frames) then drives it frame by frame. Reported per
retargeter: the mean face error over the face area (vertices ``[0, 6706)``, mm)
against the character's true faces, the mean marker error (mm), the retarget
time and the time to drive all frames (after the fit), and the fit time.
"""
from __future__ import annotations

import time

import numpy as np

from facegeom.bench.common import progress_bar
from facegeom.bench.report import Report, format_table, machine_note
from facegeom.bench.retarget import build_sequences
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import SolveError
from facegeom.methods.tangent_retarget import evenly_spread
from facegeom.model import performance as sq
from facegeom.pipelines.animate import drive_frames, face_error_mm
from facegeom.registry import MethodSpec


def run(model, seqs, retargeters: list[MethodSpec], deformer: MethodSpec, labels: int = 10, progress=True):
    """Retarget every sequence with every retargeter and drive the character's mesh with each result.

    For each sequence a fresh deformer is fitted once on the character's neutral
    face with the sequence's marker ids; each retargeter then maps the actor's
    markers onto the character from ``labels`` evenly spread known frames, and
    its markers drive that deformer frame by frame. A retargeter that raises
    :class:`~facegeom.errors.SolveError` gets a row of NaN (with the deformer's
    fit time).

    Parameters
    ----------
    model : FaceModel
        The ICT face model (``n`` vertices, positions in cm).
    seqs : list of Sequence
        Actor/character sequences with ground truth, markers ``(T, p, 3)``
        float64 in cm (:func:`~facegeom.bench.retarget.build_sequences`).
    retargeters : list of MethodSpec
        The retargeters (each built once beforehand, so plugin import time is
        not counted as retarget time).
    deformer : MethodSpec
        The deformer that drives the character.
    labels : int
        Known character frames per sequence, evenly spread.
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of dict
        One row per sequence and retargeter: ``sequence`` (index), ``name``,
        ``retargeter`` (label), ``face_mm`` (mean over frames of the mean vertex
        error over the face area ``[0, FACE_AREA)``, mm), ``marker_mm`` (mean
        marker error, mm), ``retarget_ms``, ``drive_s`` (driving all frames,
        after the fit) and ``deformer_fit_s``.
    """
    rows = []
    for spec in retargeters:  # load every plugin once, so that import time is not counted as retarget time
        spec.build("retargeters")
    it = progress_bar(list(enumerate(seqs)), "animate", progress, unit="seq")
    for si, s in it:
        lab = evenly_spread(s.n_frames, labels)
        truth = sq.character_faces(model, s)
        d = deformer.build("deformers")
        t0 = time.perf_counter()
        d.fit(sq.character_neutral(model, s.character), model.triangles, s.marker_ids)
        fit_s = time.perf_counter() - t0
        for spec in retargeters:
            t0 = time.perf_counter()
            try:
                markers = spec.build("retargeters").fit(s.source, lab, s.target[lab]).transform()
            except SolveError:
                rows.append({"sequence": si, "name": s.name, "retargeter": spec.label, "face_mm": float("nan"),
                             "marker_mm": float("nan"), "retarget_ms": float("nan"), "drive_s": float("nan"),
                             "deformer_fit_s": fit_s})
                continue
            ret_ms = (time.perf_counter() - t0) * 1e3
            V, drive_s = drive_frames(d, markers)
            rows.append({"sequence": si, "name": s.name, "retargeter": spec.label,
                         "face_mm": float(face_error_mm(V, truth, FACE_AREA).mean()),
                         "marker_mm": float(np.linalg.norm(markers - s.target, axis=2).mean() * CM_TO_MM),
                         "retarget_ms": ret_ms, "drive_s": drive_s, "deformer_fit_s": fit_s})
    return rows


def summarize(rows, retargeters, frames) -> str:
    """The Markdown summary table: one line per retargeter, failed (NaN) rows left out.

    Parameters
    ----------
    rows : list of dict
        The rows of :func:`run`.
    retargeters : list of MethodSpec
        The retargeters, in table order (matched by ``label``).
    frames : int
        Frames per sequence (only named in the drive-time column title).

    Returns
    -------
    str
        Columns: mean face error and mean marker error (mm, means over
        sequences), then the medians of the retarget time (ms), the time to drive
        all frames (s) and the deformer's fit time (s).
    """
    header = ["retargeter", "face error (mm)", "marker error (mm)", "retarget (ms, median)",
              f"drive {frames} frames (s, median)", "deformer fit (s, median)"]
    table = []
    for spec in retargeters:
        r = [x for x in rows if x["retargeter"] == spec.label and np.isfinite(x["face_mm"])]
        table.append([spec.label, np.mean([x["face_mm"] for x in r]), np.mean([x["marker_mm"] for x in r]),
                      np.median([x["retarget_ms"] for x in r]), np.median([x["drive_s"] for x in r]),
                      np.median([x["deformer_fit_s"] for x in r])])
    return format_table(header, table)


def main(model, takes, retargeters, deformer, count, seed, out, labels=10, frames=100, echo=print, progress=True):
    """Run the animation benchmark: build the sequences, run them, write the report.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (positions in cm).
    takes : list of (str, ndarray)
        Named takes of ICT-ordered weights ``(T, E)``; windows of ``frames``
        frames are cut from them (:func:`~facegeom.bench.retarget.build_sequences`).
    retargeters : list of MethodSpec
        The retargeters to compare.
    deformer : MethodSpec
        The deformer, fitted once per sequence on the character's neutral.
    count : int
        Number of sequences (every fifth synthetic).
    seed : int
        Seed of the windows, actors and characters.
    out : path-like or None
        Output folder; ``None`` only echoes the summary.
    labels : int
        Known character frames per sequence.
    frames : int
        Frames per sequence.
    echo : callable(str)
        Receives the protocol line, the table and the list of files written.
    progress : bool
        Show a progress bar.

    Returns
    -------
    rows : list of dict
        The rows of :func:`run`, written to ``out/animate.csv``.
    table : str
        The table of :func:`summarize`, written with a note on the protocol and
        the machine to ``out/animate-summary.md``.
    """
    seqs = build_sequences(model, takes, count, frames, seed)
    n_real = sum(not s.name.startswith("synthetic") for s in seqs)
    echo(f"{len(seqs)} sequences of {frames} frames ({n_real} from real takes), {labels} labelled frames; "
         f"deformer {deformer.label}, fitted once per character")
    rows = run(model, seqs, retargeters, deformer, labels, progress)
    report = Report(out, "animate", echo)
    report.csv(rows)
    table = summarize(rows, retargeters, frames)
    note = (f"face error = mean vertex error over the face area ({FACE_AREA} vertices) against the character's true "
            f"faces; {len(seqs)} sequences, seed {seed}; {machine_note()}")
    report.summary(table, note)
    report.done()
    return rows, table
