"""``facegeom solve``: a marker capture -> blendshape weight curves of a rig (and the head motion).

The steps, shared by the CLI and anything else that solves files:

1. :func:`marker_vertices` maps the capture's markers to rig vertices: a map
   CSV (header ``marker,vertex`` or ``marker,vertex_id``), marker names that
   are vertex ids (``v123`` or ``123``), or a named layout (:func:`facegeom.model.layouts.layout`:
   ``ict80``, ``landmarks68``, ``random<k>``), the file's markers in order;
2. :func:`solve_file` reads the capture and runs
   :func:`facegeom.methods.marker_solve.solve_markers`;
3. :func:`write_curves` writes the result; the format is picked from the
   suffix in :data:`CURVE_WRITERS`: ``.npz`` (everything the solve reports),
   ``.glb`` (the rig as a glTF 2.0 mesh with named morph targets and the
   weights as an animation at the capture's frame rate) or ``.csv`` (a Live
   Link Face take: the 52 ARKit weights, for anything that reads those).

Lengths: a capture that states its unit (C3D does) is converted to the rig's
centimetres (facegeom's convention, the ICT face's unit; a rig from elsewhere
is brought into it when loaded, :func:`facegeom.model.inputs.load_rig`); one
that states none is taken to be in the rig's own units (``rig.frame.units``:
a capture for a rig in mm is read as mm). glTF lengths are metres, so the
``.glb`` writer scales the rig by :data:`GLB_SCALE`; the ``.npz`` says its
unit (``units``: cm).

Names: the curves are the rig's own shapes (the ``.npz`` and ``.glb`` carry
its names). The Live Link ``.csv`` needs the 52 ARKit columns, which the rig's
shapes give through :meth:`~facegeom.model.rig.BlendshapeRig.map_to` (an
ARKit-named rig's ``eyeBlinkLeft`` goes to ``EyeBlinkLeft``, an ICT rig's
``browInnerUp_L`` / ``_R`` to the mean ``BrowInnerUp``, a mapping file's gains
inverted); columns no shape reaches are written as 0 and named in a note.
Curves and takes played on a rig (:func:`read_animation`) cross names the
other way (:meth:`~facegeom.model.rig.BlendshapeRig.map_from`).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from facegeom.constants import CM_TO_MM
from facegeom.errors import InputError
from facegeom.interfaces import as_handles
from facegeom.io.files import atomic_path, read_csv_rows
from facegeom.io.shape_names import ARKIT_NAMES, ShapeMap
from facegeom.io.markerseq import MarkerSequence, read_marker_sequence
from facegeom.methods.marker_solve import MarkerSolve, marker_noise, solve_markers
from facegeom.model.layouts import layout as named_layout

__all__ = ["CURVE_WRITERS", "RigAnimation", "SolvedCapture", "arkit_map", "livelink_rotations", "marker_vertices",
           "read_animation",
           "solve_file",
           "take_fps",
           "write_curves", "write_curves_glb", "write_curves_livelink", "write_curves_npz"]

RIG_UNIT = "cm"
"""The unit of rig coordinates (the ICT face's; every facegeom rig is taken to use it)."""

GLB_SCALE = 0.01
"""Rig units (cm) -> glTF metres."""

DEFAULT_FPS = 30.0
"""Frame rate written when the capture does not carry one (Live Link Face's default)."""

_VERTEX_NAME = re.compile(r"^[vV]?(\d+)$")


@dataclass
class SolvedCapture:
    """A solved capture: the solve, the sequence it came from and the marker vertices."""

    solve: MarkerSolve
    sequence: MarkerSequence
    vertex_ids: np.ndarray
    fitter: str
    fps: float
    fps_known: bool
    rig: object = None
    """The :class:`~facegeom.model.rig.BlendshapeRig` solved for (the ``.glb`` writer needs its mesh)."""
    notes: list = field(default_factory=list)
    """What was done to the inputs and outputs (a capture read in the rig's units, ARKit columns left at 0)."""
    start_s: float | None = None
    """Time of day of the first frame (seconds) when the source states one (a Live Link take's timecode): a Live
    Link take written from the solve starts there."""


MAP_HEADERS = (("marker", "vertex"), ("marker", "vertex_id"))
"""The headers a marker map may have (``vertex_id`` as in facegeom's other vertex CSVs)."""


def _read_map(path: Path, names) -> np.ndarray:
    rows = read_csv_rows(path, "marker map")
    body = [(i, r) for i, r in enumerate(rows) if r and any(c.strip() for c in r)]
    header = tuple(c.strip().lower() for c in body[0][1]) if body else ()
    if header not in MAP_HEADERS:
        raise InputError("a marker map needs the header marker,vertex (or marker,vertex_id)", path)
    table: dict[str, int] = {}
    for i, r in body[1:]:
        if len(r) != 2 or not r[0].strip():
            raise InputError(f"line {i + 1}: expected {','.join(header)}", path)
        v = r[1].strip()
        if not v.isdigit() or len(v) > 18:
            raise InputError(f"line {i + 1}: vertex {v!r} is not a non-negative integer id", path)
        if r[0].strip() in table:
            raise InputError(f"line {i + 1}: marker {r[0].strip()!r} is mapped twice", path)
        table[r[0].strip()] = int(v)
    missing = [n for n in names if n not in table]
    if missing:
        raise InputError(f"marker {missing[0]!r} of the capture is not in the map", path)
    return np.array([table[n] for n in names], dtype=np.int64)


def marker_vertices(names, rig, markers=None) -> np.ndarray:
    """The rig vertex of each marker name ``(p,)`` int64.

    Parameters
    ----------
    names : sequence of p str
        The capture's marker names, in its column order.
    rig : BlendshapeRig
    markers : str, path or None
        A map CSV (header ``marker,vertex`` or ``marker,vertex_id``), a layout
        name (``ict80``, ``landmarks68``, ``random<k>``: the markers in file order, or by number when the names
        are ``0..p-1``), or None: the names themselves are vertex ids
        (``v123`` or ``123``).

    Raises
    ------
    InputError
        A name that is no vertex id, a marker missing from the map, a layout
        with another marker count, ids out of the rig's range or repeated.
    """
    names = [str(n) for n in names]
    if markers is None:
        ids = []
        for n in names:
            m = _VERTEX_NAME.match(n.strip())
            if m is None or len(m.group(1)) > 18:
                raise InputError(f"the marker names are not vertex ids (marker {n!r} is not a vertex id like v123 or "
                                 "123): pass markers=MAP.csv (a CSV headed marker,vertex_id, one line per marker) "
                                 "or a layout, markers=ict80 (or landmarks68, random<k>)")
            ids.append(int(m.group(1)))
        return as_handles(np.array(ids, dtype=np.int64), rig.n_vertices, "marker vertex ids")
    text = str(markers)
    path = Path(text)
    if path.suffix.lower() == ".csv" or path.exists():
        return as_handles(_read_map(path, names), rig.n_vertices, "marker map vertex ids", path)
    if rig.landmark_ids is None and not text.startswith("random"):
        raise InputError(f"layout {text!r} needs the rig's 68 landmark ids, and this rig has none")
    face = SimpleNamespace(neutral=rig.neutral, triangles=rig.triangles, landmarks=rig.landmark_ids,
                           n_vertices=rig.n_vertices)
    ids = named_layout(face, text)
    if ids.size != len(names):
        raise InputError(f"layout {text!r} has {ids.size} markers, the capture {len(names)}")
    if sorted(names, key=str) == sorted((str(i) for i in range(len(names))), key=str):
        return ids[np.array([int(n) for n in names])]
    return ids


#: A capture's markers may lie this many face sizes from the origin (a head anywhere in a large capture volume) ...
CAPTURE_REACH = 1e5
#: ... and span, per frame, between these factors of the rig's markers' span (another unit is 10-1000x off).
CAPTURE_SPAN = (1e-4, 1e4)


def check_capture_range(P, rest, path=None) -> None:
    """Refuse a capture no real face capture is, before any solve (one line naming the file).

    ``P (T, p, 3)`` markers in the rig's units (NaN where lost), ``rest (p, 3)``
    the rig's marker vertices. Refused: a coordinate more than
    :data:`CAPTURE_REACH` face sizes from the origin (1e308 ran a solve
    without end), and a frame whose markers span less or more than
    :data:`CAPTURE_SPAN` times the rig's (all markers at one point; a scale of
    1e30). The rig's face size is the RMS distance of ``rest`` from its centre.
    """
    face = float(np.sqrt(((rest - rest.mean(axis=0)) ** 2).sum(axis=1).mean()))
    if not face > 0:
        return
    ok = np.isfinite(P).all(axis=2)  # (T, p)
    far = np.abs(np.where(ok[..., None], P, 0.0)).max(initial=0.0)
    if far > CAPTURE_REACH * face:
        raise InputError(f"a marker coordinate of {far:.3g} is {far / face:.3g} face sizes from the origin: no "
                         f"capture of a face has it (another unit, or a corrupt value?)", path)
    cnt = ok.sum(axis=1)
    X = np.where(ok[..., None], P, 0.0)
    mean = X.sum(axis=1) / np.maximum(cnt, 1)[:, None]
    span = np.sqrt((((X - mean[:, None]) ** 2).sum(axis=2) * ok).sum(axis=1) / np.maximum(cnt, 1)) / face
    bad = np.flatnonzero((cnt >= 3) & ((span < CAPTURE_SPAN[0]) | (span > CAPTURE_SPAN[1])))
    if bad.size:
        t = int(bad[0])
        what = "all at one point" if span[t] < CAPTURE_SPAN[0] else f"{span[t]:.3g} times the face's size apart"
        raise InputError(f"frame {t}: the markers are {what}: no capture of this face (another unit, or markers "
                         f"that were not tracked?)", path)


def solve_file(capture: str | os.PathLike, rig, fitter, fitter_label: str = "sem-ls", markers=None,
               smooth="off", progress=None, identity: str = "auto") -> SolvedCapture:
    """Read the marker sequence ``capture`` and solve it on ``rig`` with ``fitter``.

    ``smooth`` is ``"off"``, ``"auto"`` or a number (see
    :func:`facegeom.methods.marker_solve.smooth_curves`); ``progress(frames_done, frames)``
    is called as chunks finish. ``identity``: ``"auto"`` fits the actor's
    identity from the capture first when ``rig`` is a face model's generic face
    (:func:`actor_rig`), ``"off"`` solves on ``rig`` as it is. Errors name the capture file.
    """
    if identity not in IDENTITY_CHOICES:
        raise InputError(f"identity must be one of {', '.join(IDENTITY_CHOICES)}, got {identity!r}")
    seq = read_marker_sequence(capture)
    notes = []
    own = getattr(getattr(rig, "frame", None), "units", RIG_UNIT)
    if getattr(seq, "unit", None) is None and Path(capture).suffix.lower() == ".c3d":
        seq = replace(seq, unit="mm")  # what motion-capture systems write when they leave POINT:UNITS out
        notes.append(f"{Path(capture).name}: states no POINT:UNITS; read in millimetres, the unit C3D files use")
    elif getattr(seq, "unit", None) is None:
        seq = replace(seq, unit=own)
        notes.append(f"{Path(capture).name}: states no length unit; read in the rig's own unit, {own}")
    if getattr(seq, "unit", None) is not None:
        seq = seq.in_unit(RIG_UNIT)
    if not getattr(seq, "named", True) and (markers is None or str(markers).lower().endswith(".csv")
                                            or Path(str(markers)).exists()):
        raise InputError("the capture names no markers (no 'marker_names' array), so neither vertex ids nor a map "
                         "can place them: add 'marker_names', or name a layout (markers=ict80, landmarks68, "
                         "random<k>) to take them in file order", capture)
    try:
        ids = marker_vertices(seq.names, rig, markers)
    except InputError as exc:  # a map file's own errors name it; the others are about the capture's markers
        if exc.path:
            raise
        raise InputError(exc.reason, capture) from None
    check_capture_range(seq.positions, rig.neutral[ids], capture)
    fitted = None
    if identity == "auto" and getattr(rig, "population", None) is not None:
        actor, fit = actor_rig(rig, seq.positions, ids, capture)
        before, after = fit.info["residual_mm"]
        if fit.info["better"]:
            rig, fitted = actor, fit
            notes.append(f"the actor's identity fitted from {fit.frames.size} frames of the capture (the generic "
                         f"face's markers moved {fit.info['moved_mm']:.2g} mm RMS; marker residual {before:.2g} -> "
                         f"{after:.2g} mm); pass identity='off' to solve on the generic face as it is")
        elif fit.info["skipped"]:
            notes.append(f"the generic face fits the actor: its marker residual, {before:.2g} mm, is within the "
                         f"markers' frame-to-frame jitter ({fit.info['noise_mm']:.2g} mm); no identity fitted")
        else:
            notes.append(f"the generic face fits the actor: a fitted identity would change the marker residual "
                         f"only from {before:.2g} to {after:.2g} mm, so the generic face is used as it is")
    try:
        res = solve_markers(seq.positions, ids, rig, fitter, smooth=smooth, chunk=250, progress=progress)
    except InputError as exc:
        if exc.path:
            raise
        raise InputError(exc.reason, capture) from None
    check_residual(res.rms, capture, markers)
    if fitted is not None:
        res.info["identity"] = fitted.identity
    warn = fit_warning(res.rms, marker_noise(seq.positions), fitted is None and getattr(rig, "population", None) is not None)
    if warn:
        notes.append(warn)
    fps = getattr(seq, "fps", None)
    known = fps is not None and np.isfinite(fps) and fps > 0
    return SolvedCapture(res, seq, ids, fitter_label, float(fps) if known else DEFAULT_FPS, bool(known), rig, notes)


IDENTITY_CHOICES = ("auto", "off")
"""``solve_file``'s ``identity``: fit the actor's identity on a generic face (auto), or not (off)."""


def actor_rig(rig, positions, ids, capture=None):
    """The actor's rig for a capture on a face model's generic face ``rig`` (``rig.population`` set): the model's
    identity fitted from the markers (:func:`facegeom.methods.marker_identity.fit_capture_identity`), the rig's
    shapes, names, mapping and frame kept -> ``(rig, CaptureIdentity)``."""
    from facegeom.methods.marker_identity import fit_capture_identity

    try:
        fit = fit_capture_identity(rig.population, positions, ids, generic=rig)
    except InputError as exc:
        raise InputError(exc.reason, exc.path or capture) from None
    return rig.with_neutral(fit.neutral), fit


#: A solve whose median marker residual is more than this many times what the markers' noise explains says the
#: rig's face is not the actor's: the weights then carry the difference (a generic face's eyes set wider than the
#: actor's read as eyeWide in every frame). Noise ``s`` per coordinate leaves a residual of about ``1.5 s`` on the
#: actor's own rig (3 coordinates, less the pose's and expression's share: 0.8 mm at 0.5 mm, 1.6 mm at 1 mm);
#: ``s`` is estimated from the capture (:func:`~facegeom.methods.marker_solve.marker_noise`), an over-estimate.
RESIDUAL_WARN_FACTOR = 2.25
#: ... and never below this (mm): a nearly noise-free capture leaves a little on its own rig too.
RESIDUAL_WARN_MM = 1.0


def fit_warning(rms, noise, generic: bool = False) -> str:
    """A warning line when the solve's median marker residual (``rms``, cm) is more than the markers' noise
    (``noise``: sigma per coordinate, cm) explains (:data:`RESIDUAL_WARN_FACTOR`, at least
    :data:`RESIDUAL_WARN_MM`), else ``""``."""
    r = np.asarray(rms, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return ""
    med = float(np.median(r)) * CM_TO_MM
    limit = max(RESIDUAL_WARN_MM, RESIDUAL_WARN_FACTOR * float(noise) * CM_TO_MM if np.isfinite(noise) else 0.0)
    if med <= limit:
        return ""
    fix = ("solve with identity='auto' to fit the actor's identity first" if generic
           else "solve on the actor's own rig (rig_path=), or on the generic face, whose identity is fitted")
    return (f"warning: the rig does not fit the actor's face (marker residual median {med:.2g} mm, more than the "
            f"markers' noise explains, {limit:.2g} mm): the weights take up the difference in shape and can stick; "
            f"{fix}")


#: A solve whose median marker residual is above this (mm) did not fit the rig: the markers are not on this
#: rig's vertices (another head's vertex ids, a wrong map). A capture solved on its own rig leaves 0.1-2 mm
#: (marker noise, an actor the generic face does not match), and the largest expression moves a marker
#: 20-25 mm (the chin at jawOpen): 15 mm is more than any fit leaves and less than what a wrong layout does
#: (112 mm: a head's own capture's vertex ids read on another rig).
SOLVE_RESIDUAL_MAX_MM = 15.0


def check_residual(rms, capture, markers=None) -> None:
    """Refuse a solve whose median per-frame marker residual (``rms``, cm: the rig unit) is above
    :data:`SOLVE_RESIDUAL_MAX_MM`, in one line naming the capture."""
    r = np.asarray(rms, dtype=np.float64)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return
    med = float(np.median(r)) * CM_TO_MM
    if med > SOLVE_RESIDUAL_MAX_MM:
        how = "the map" if markers is not None else "the markers' vertex ids (v123)"
        raise InputError(f"the markers do not fit the rig: residual median {med:.3g} mm (a capture on its own rig "
                         f"leaves 0.1-2 mm; at most {SOLVE_RESIDUAL_MAX_MM:g}); are {how} this rig's vertices? "
                         f"pass markers=MAP.csv (marker,vertex_id of this rig)", capture)


def write_curves_npz(path: Path, solved: SolvedCapture) -> Path:
    """The curves as ``.npz`` (atomically): weights (T,K), names, fps, frames, per-frame rigid motion (``units``:
    cm), solve info."""
    s = solved.solve
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(
            fh, weights=s.weights, names=np.array(s.names), fps=np.float64(solved.fps),
            fps_known=np.bool_(solved.fps_known), frames=solved.sequence.frames,
            rotations=s.rotations, translations=s.translations, poses=s.poses, raw_weights=s.raw_weights,
            smoothing=s.smoothing, rms=s.rms, lost=s.lost, marker_names=np.array(solved.sequence.names),
            vertex_ids=solved.vertex_ids, fitter=np.array(solved.fitter), units=np.array(RIG_UNIT),
            source=np.array(str(solved.sequence.path)), time_s=np.float64(s.time_s),
            **({"identity": np.asarray(s.info["identity"])} if "identity" in s.info else {}))
    return path


def write_curves_glb(path: Path, solved: SolvedCapture) -> Path:
    """The rig (in metres) with its blendshapes as named morph targets (or USD blend shapes, by the suffix:
    :func:`facegeom.io.delivery.write_rig_animation`) and the weights as its animation. A ``.glb`` is scaled to
    metres as it is written (``write_rig_glb(..., scale=GLB_SCALE)``: the same file, without a scaled copy of the
    rig's offsets)."""
    rig = solved.rig
    if rig is None:
        raise InputError(f"a {path.suffix} needs the rig's mesh, and this solve carries no rig", path)
    s = solved.solve
    head = isinstance(s.info, dict) and s.info.get("head_motion")  # a performance on a character: the head moves
    if path.suffix.lower() == ".glb":  # scaled as written: no scaled copy of the rig's offsets (K x n x 3)
        from facegeom.io.gltf import write_rig_glb

        motion = {"rotations": s.rotations, "translations": s.translations} if head else {}
        return write_rig_glb(path, rig.neutral, rig.triangles, rig.deltas, s.names, s.weights, solved.fps,
                             scale=GLB_SCALE, **motion)
    from facegeom.io.delivery import write_rig_animation

    motion = {"rotations": s.rotations, "translations": s.translations * GLB_SCALE} if head else {}
    return write_rig_animation(path, rig.neutral * GLB_SCALE, rig.triangles, rig.deltas * GLB_SCALE,
                               s.names, s.weights, solved.fps, **motion)


def arkit_map(solved: SolvedCapture) -> ShapeMap:
    """The map from the solve's shapes to the 52 ARKit columns of a Live Link take (the rig's, see the notes above)."""
    rig = solved.rig
    if rig is not None and hasattr(rig, "map_to") and tuple(rig.names) == tuple(solved.solve.names):
        return rig.map_to(ARKIT_NAMES)
    return ShapeMap.between(ARKIT_NAMES, solved.solve.names)


def livelink_rotations(solved: SolvedCapture, arkit_weights) -> np.ndarray:
    """The 9 rotation columns of a Live Link take for ``solved`` -> ``(T, 9)`` radians.

    Head: the solve's head rotations as yaw, pitch, roll
    (:func:`facegeom.io.takes.head_angles`); eyes: the take's own when the
    curves came from one (``solve.info["eye_rotations"]``), else from the
    ARKit eye-look weights ``arkit_weights (T, 52)`` as the app relates them
    (:func:`facegeom.io.takes.eye_rotations`).
    """
    from facegeom.io.takes import eye_rotations, head_angles

    s = solved.solve
    eyes = s.info.get("eye_rotations") if isinstance(s.info, dict) else None
    if eyes is None:
        eyes = eye_rotations(arkit_weights, ARKIT_NAMES)
    return np.c_[head_angles(s.rotations), eyes]


def write_curves_livelink(path: Path, solved: SolvedCapture) -> Path:
    """The weights as a Live Link Face CSV take: the 52 ARKit columns from the rig's shapes (:func:`arkit_map`),
    the head's and eyes' rotation columns from the solve (:func:`livelink_rotations`)."""
    from facegeom.io.takes import write_livelink_csv

    m = arkit_map(solved)
    if m.is_empty:
        raise InputError("none of the rig's shape names is an ICT or ARKit expression; a Live Link take cannot carry "
                         "these weights (map them with names=MAP.csv, or write .npz or .glb)", path)
    W = m.apply(solved.solve.weights)
    if m.unmapped_rig:
        solved.notes.append(f"{path.name}: ARKit columns no shape of the rig reaches, written as 0: "
                            f"{', '.join(m.unmapped_rig)}")
    if m.unmapped_source:
        solved.notes.append(f"{path.name}: rig shapes a Live Link take has no column for (not written): "
                            f"{', '.join(m.unmapped_source)}")
    return write_livelink_csv(path, W, ARKIT_NAMES, solved.fps, start=solved.start_s,
                              rotations=livelink_rotations(solved, W))


CURVE_WRITERS = {
    ".npz": write_curves_npz,
    ".glb": write_curves_glb,
    ".usda": write_curves_glb,
    ".usdc": write_curves_glb,
    ".usdz": write_curves_glb,
    ".csv": write_curves_livelink,
}
"""Output suffix -> writer ``(path, SolvedCapture)``; every writer writes atomically."""


def write_curves(path: str | os.PathLike, solved: SolvedCapture) -> Path:
    """Write ``solved`` to ``path`` atomically, in the format of its suffix (:data:`CURVE_WRITERS`)."""
    path = Path(path)
    writer = CURVE_WRITERS.get(path.suffix.lower())
    if writer is None:
        raise InputError(f"unsupported curves format {path.suffix!r}; use {', '.join(CURVE_WRITERS)}", path)
    return writer(path, solved)


# ----------------------------------------------------------------------------- reading back (the viewer's player)

@dataclass
class RigAnimation:
    """Weight curves on a rig, ready to play: frame ``t`` is ``neutral + weights[t] @ deltas``.

    Attributes
    ----------
    neutral : (n, 3) float64
        Rest positions in cm (a ``.glb``'s metres are converted).
    triangles : (m, 3) int64
    deltas : (K, n, 3) float64
        Blendshape offsets in cm.
    names : tuple of K str
    weights : (T, K) float64
    fps : float
    path : str
        The file read.
    """

    neutral: np.ndarray
    triangles: np.ndarray
    deltas: np.ndarray
    names: tuple[str, ...]
    weights: np.ndarray
    fps: float
    path: str
    rotations: np.ndarray | None = None
    """``(T, 3, 3)`` the head's rotation per frame when the file animates it (a ``.glb`` node's, USD's joint's)."""
    translations: np.ndarray | None = None
    """``(T, 3)`` its translation in cm, with ``rotations``."""

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return int(self.weights.shape[0])

    def frame(self, t: int) -> np.ndarray:
        """``(n, 3)`` vertex positions of frame ``t``, turned and moved by the head's motion when there is one."""
        K, n = self.deltas.shape[:2]
        X = self.neutral + (self.weights[t] @ self.deltas.reshape(K, 3 * n)).reshape(n, 3)
        if self.rotations is not None:
            X = X @ self.rotations[t].T + self.translations[t]
        return X


def take_fps(take) -> float:
    """A take's frame rate from its row times (the timecode's frame base is not the capture rate), else 30."""
    step = np.diff(np.asarray(take.times, dtype=np.float64))
    step = step[np.isfinite(step) & (step > 0)]
    return float(1.0 / np.median(step)) if step.size else DEFAULT_FPS


def _onto_rig(path: Path, rig, names, W) -> np.ndarray:
    """Weights ``W (T, len(names))`` named ``names`` as the rig's weights (``rig.map_from``); an error when no name
    reaches a shape of the rig."""
    try:
        m = rig.map_from(names) if hasattr(rig, "map_from") else ShapeMap.between(rig.names, names)
    except InputError as exc:
        raise InputError(exc.reason, exc.path or path) from None
    if m.is_empty:
        raise InputError("none of the curves' shape names is a shape of the rig", path)
    return m.apply(W)


def read_animation(path: str | os.PathLike, rig=None) -> RigAnimation:
    """Read what ``facegeom solve`` (or a glTF tool, or the Live Link Face app) writes, to play it.

    ``.glb``: a mesh with morph targets and a weights animation (the file is
    self-contained; ``rig`` is not used). ``.npz`` curves (``weights``, ``names``)
    and Live Link ``.csv`` takes carry weights only: they play on ``rig`` (a
    :class:`~facegeom.model.rig.BlendshapeRig`, or a callable returning one),
    through ``rig.map_from`` (names matched across ICT, ARKit and the rig's
    mapping file); rig shapes the file does not reach stay at 0.

    Raises
    ------
    InputError
        An unknown suffix, a file that cannot be read, curves that fit no shape of the rig.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".glb":
        from facegeom.io.gltf import read_glb_animation

        g = read_glb_animation(path)
        if g.weights.shape[0] == 0:
            raise InputError("the .glb has no weights animation to play (a rig without curves: drive or fit it "
                             "first, or play curves solved for it)", path)
        fps = g.fps if g.fps else DEFAULT_FPS
        motion = {}
        if g.rotations is not None:
            motion = {"rotations": g.rotations, "translations": g.translations / GLB_SCALE}
        return RigAnimation(g.neutral / GLB_SCALE, g.faces, g.deltas / GLB_SCALE, tuple(g.names), g.weights,
                            float(fps), str(path), **motion)
    if suffix in (".usd", ".usda", ".usdc", ".usdz"):
        from facegeom.io.usd import read_usd_rig

        u = read_usd_rig(path)
        if u.weights is None or u.weights.shape[0] == 0 or u.deltas.shape[0] == 0:
            raise InputError("the USD file has no blend-shape weights animation to play (a rig without curves: "
                             "drive or fit it first, or play curves solved for it)", path)
        scale = u.meters_per_unit / (GLB_SCALE)  # the file's units -> cm
        motion = {}
        if u.rotations is not None:
            motion = {"rotations": u.rotations, "translations": u.translations * scale}
        return RigAnimation(u.neutral * scale, u.faces, u.deltas * scale, tuple(u.names), u.weights,
                            float(u.fps or DEFAULT_FPS), str(path), **motion)
    if suffix not in (".npz", ".csv"):
        raise InputError(f"cannot play {suffix or 'a file without suffix'!r}; use .glb, .usda/.usdc/.usdz, .npz "
                         "curves or a Live Link .csv take", path)
    rig = rig() if callable(rig) else rig
    if suffix == ".csv":
        from facegeom.io.takes import read_take

        take = read_take(path)
        W = _onto_rig(path, rig, take.names, take.weights)
        fps = take_fps(take)
        return RigAnimation(rig.neutral, rig.triangles, rig.deltas, tuple(rig.names), W, float(fps), str(path))
    from facegeom.io.npzcheck import check_npz, check_text

    check_npz(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "weights" not in z or "names" not in z:
                raise InputError("curves need the arrays 'weights' and 'names' (as `facegeom solve` writes)", path)
            Wf = np.asarray(z["weights"], dtype=np.float64)
            raw_names = np.asarray(z["names"])
            if raw_names.dtype.kind not in "US":
                raise InputError(f"'names' must be text, is {raw_names.dtype}", path)
            check_text(raw_names, "names", path)
            names = [str(n) for n in raw_names.reshape(-1)]
            fps = float(z["fps"]) if "fps" in z and np.asarray(z["fps"]).size == 1 else DEFAULT_FPS
    except InputError:
        raise
    except (OSError, ValueError, EOFError, KeyError, TypeError) as exc:
        raise InputError(f"not a readable .npz: {type(exc).__name__}: {exc}", path) from None
    if Wf.ndim != 2 or Wf.shape[1] != len(names) or Wf.shape[0] == 0:
        raise InputError(f"weights must have shape (T, {len(names)}) with T > 0 (one column per name), "
                         f"got {Wf.shape}", path)
    if not np.isfinite(Wf).all():
        raise InputError("the weights contain NaN or inf", path)
    if not (np.isfinite(fps) and fps > 0):
        fps = DEFAULT_FPS
    W = _onto_rig(path, rig, names, Wf)
    return RigAnimation(rig.neutral, rig.triangles, rig.deltas, tuple(rig.names), W, float(fps), str(path))
