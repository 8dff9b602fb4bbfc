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

from facegeom.bench.report import Report, format_table, machine_note
from facegeom.bench.retarget import build_sequences
from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import SolveError
from facegeom.methods.tangent_retarget import evenly_spread
from facegeom.model import performance as sq
from facegeom.pipelines.animate import drive_frames, face_error_mm
from facegeom.registry import MethodSpec


def run(model, seqs, retargeters: list[MethodSpec], deformer: MethodSpec, labels: int = 10, progress=True):
    rows = []
    for spec in retargeters:  # load every plugin once, so that import time is not counted as retarget time
        spec.build("retargeters")
    try:
        from tqdm import tqdm
        it = tqdm(list(enumerate(seqs)), desc="animate", unit="seq", disable=not progress)
    except ImportError:  # pragma: no cover
        it = enumerate(seqs)
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
