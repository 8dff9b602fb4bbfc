"""Landmark fitting on synthetic protocols built to differ from each other (``facegeom bench landmark-grid``).

A default that was chosen on one protocol may only fit that protocol. Each
protocol here changes what the others hold fixed: the landmark layout (23, 40,
49 or 68 points; with the jaw contour drawn on the face's outline in the view,
as annotators mark it), the noise (0.5 to 3 px), the camera (focal length known,
off by up to 30 %, or unknown within a factor of two; telephoto or wide), and
the expression (dense: frames of real ARKit takes, ~40 of 53 weights above 0.001;
sparse: 2 to 6 shapes at 0.2-1, the SEM paper's). Every case is a random ICT
identity, fitted with the generic face's rig (what a user without an identity
fit has) and with the true identity's rig (the expression alone). The score is
the mean 3-D vertex error over the face area against the true face, in mm.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from facegeom.bench.common import PhotoAnnotator, progress_bar
from facegeom.bench.report import Report, format_table
from facegeom.constants import FACE_AREA
from facegeom.errors import FacegeomError, InputError
from facegeom.metrics import mean_vertex_error_mm
from facegeom.model import FIT_LANDMARKS_23, BlendshapeRig, LandmarkTarget, PinholeCamera, look_at_camera
from facegeom.model.landmarks import INNER_LANDMARKS_49

__all__ = ["GridProtocol", "PROTOCOLS", "LAYOUTS", "run"]

LAYOUTS = {
    23: tuple(FIT_LANDMARKS_23),
    40: tuple(range(17)) + tuple(FIT_LANDMARKS_23),
    49: tuple(INNER_LANDMARKS_49),
    68: tuple(range(68)),
}
BASELINES = ("l1reg", "l2reg", "pcadel", "pcaexp", "eos")


@dataclass(frozen=True)
class GridProtocol:
    """One synthetic landmark protocol (see the module docstring)."""

    name: str
    layout: int  # key of LAYOUTS
    noise_px: tuple  # (low, high): uniform per case
    focal_factor: tuple  # (low, high): the focal length given to the fitter over the true one
    expressions: str  # "dense" (real-take frames) or "sparse" (2-6 shapes)
    focal: float = 1000.0
    image: tuple = (640, 480)


PROTOCOLS = (
    GridProtocol("23 pts, 1.5 px, focal known, dense, telephoto", 23, (1.5, 1.5), (1.0, 1.0), "dense", 2400.0,
                 (1920, 1080)),
    GridProtocol("40 pts, 0.5-2 px, focal off 30 %, dense", 40, (0.5, 2.0), (0.7, 1.3), "dense"),
    GridProtocol("49 pts, 0.5 px, focal off 30 %, dense", 49, (0.5, 0.5), (0.7, 1.3), "dense"),
    GridProtocol("68 pts, 3 px, focal known, dense", 68, (3.0, 3.0), (1.0, 1.0), "dense"),
    GridProtocol("40 pts, 1.5 px, focal unknown (x0.5-2), dense, wide", 40, (1.5, 1.5), (0.5, 2.0), "dense", 500.0),
    GridProtocol("23 pts, 1 px, focal known, sparse", 23, (1.0, 1.0), (1.0, 1.0), "sparse"),
    GridProtocol("68 pts, 0.5 px, focal off 30 %, sparse", 68, (0.5, 0.5), (0.7, 1.3), "sparse"),
    GridProtocol("49 pts, 3 px, focal unknown (x0.5-2), sparse", 49, (3.0, 3.0), (0.5, 2.0), "sparse"),
)


def _sparse(rng, B):
    w = np.zeros(B)
    on = rng.choice(B, int(rng.integers(2, 7)), replace=False)
    w[on] = rng.uniform(0.2, 1.0, on.size)
    return w


def run(model, specs, takes, cases: int = 30, seed: int = 0, protocols=None, out=None, echo=print,
        progress: bool = True) -> list[dict]:
    """Every protocol's ``cases`` targets fitted by every spec with the generic and the true rig -> rows.

    ``takes``: ``[(name, W (T, B)), ...]`` real-take weights for the dense
    protocols (skipped, with a line, when empty).
    """
    from facegeom.bench.report import machine_note

    protocols = PROTOCOLS if protocols is None else protocols
    if cases < 1:
        raise InputError(f"cases must be at least 1, got {cases}")
    lm = np.asarray(model.landmarks, dtype=np.int64)
    generic = BlendshapeRig.from_face_model(model)
    rows = []
    for pi, p in enumerate(protocols):
        if p.expressions == "dense" and not takes:
            echo(f"skipping '{p.name}': no takes for dense expressions")
            continue
        rng = np.random.default_rng([int(seed), 4242, pi])
        indices = LAYOUTS[p.layout]
        annotate = PhotoAnnotator(model, indices, outline=True)
        for c in progress_bar(range(cases), p.name, progress, unit="case"):
            identity = model.random_identity(rng)
            if p.expressions == "dense":
                name, W = takes[int(rng.integers(len(takes)))]
                w = np.asarray(W[int(rng.integers(W.shape[0]))], dtype=np.float64)
            else:
                w = _sparse(rng, generic.n_shapes)
            truth = BlendshapeRig.from_face_model(model, identity)
            V = truth.evaluate(w)
            cam = look_at_camera(V, focal=p.focal, image_size=p.image, yaw=float(rng.uniform(-30, 30)),
                                 pitch=float(rng.uniform(-15, 15)))
            noise = float(rng.uniform(*p.noise_px))
            uv = annotate(V, cam) + rng.normal(size=(len(indices), 2)) * noise
            given = PinholeCamera(cam.focal * float(rng.uniform(*p.focal_factor)), cam.cx, cam.cy)
            target = LandmarkTarget(uv, annotate.ids, given, annotate.mask)
            for mode, rig in (("generic", generic), ("true identity", truth)):
                for s in specs:
                    t0 = time.perf_counter()
                    try:
                        r = s.build("fitters").fit(rig, target)
                    except FacegeomError as exc:
                        rows.append({"protocol": p.name, "case": c, "identity": mode, "method": s.label,
                                     "vertex_mm": float("nan"), "ms": float("nan"), "failure": str(exc)})
                        continue
                    rows.append({"protocol": p.name, "case": c, "identity": mode, "method": s.label,
                                 "vertex_mm": mean_vertex_error_mm(r.vertices, V, np.arange(FACE_AREA)),
                                 "ms": 1000 * (time.perf_counter() - t0), "failure": ""})
    labels = [s.label for s in specs]
    table = summary_table(rows, labels)
    note = (f"{cases} cases per protocol (random ICT identities, yaw U(-30, 30), pitch U(-15, 15) degrees, seed "
            f"{seed}); mean 3-D vertex error over the face area (mm); ratio: against the best baseline with the same "
            f"rig. {machine_note()}.")
    if out is not None:
        rep = Report(out, "landmark-grid", echo)
        rep.csv(rows)
        rep.summary(table, note)
    else:
        echo(table)
        echo(note)
    return rows


def summary_table(rows, labels) -> str:
    """Per protocol and rig: each method's mean error (mm) and the first method's ratio to the best baseline."""
    baselines = [m for m in labels if m.split(":")[0] in BASELINES]
    out = []
    protocols = list(dict.fromkeys(r["protocol"] for r in rows))
    for p in protocols:
        for mode in ("generic", "true identity"):
            sel = [r for r in rows if r["protocol"] == p and r["identity"] == mode]
            mean = {m: float(np.nanmean([r["vertex_mm"] for r in sel if r["method"] == m]) if any(
                r["method"] == m for r in sel) else np.nan) for m in labels}
            fails = sum(1 for r in sel if r["failure"])
            best = min((mean[m] for m in baselines if np.isfinite(mean[m])), default=np.nan)
            ratio = mean[labels[0]] / best if np.isfinite(best) else np.nan
            out.append([p, mode, *[f"{mean[m]:.3f}" for m in labels], f"{ratio:.2f}x", str(fails)])
    return format_table(["protocol", "rig", *labels, f"{labels[0]} vs best baseline", "failures"], out)
