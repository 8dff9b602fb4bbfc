"""Performance-driven animation: actor markers -> retargeted character markers -> character mesh.

Pipeline for one sequence (:class:`facegeom.model.performance.Sequence`):

1. the actor's 80 markers per frame (``seq.source``);
2. retargeted to the character from ``labels`` known character frames (evenly spread);
3. the character's neutral mesh driven every frame by a deformer fitted **once**
   on it with the marker ids (one factorization; each frame is one ``deform``).

The per-frame error is measured against the character's true faces.
:func:`animate_take` runs it on a window of a Live Link Face take (``facegeom
animate`` and the batch ``animate`` operation) and :func:`write_animation_npz`
writes the result.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from facegeom.constants import FACE_AREA
from facegeom.errors import InputError
from facegeom.interfaces import deform_many
from facegeom.io import atomic_path, ict_weights, read_take
from facegeom.methods.tangent_retarget import evenly_spread
from facegeom.model import layout
from facegeom.model import performance as sq


@dataclass
class Animation:
    """The result of :func:`animate`: the driven character sequence with its errors.

    Attributes
    ----------
    vertices : (T, n, 3) float64
        The driven character mesh per frame, cm.
    faces : (m, 3) int64
        The model's triangles.
    markers : (T, p, 3) float64
        The retargeted character markers per frame, cm.
    labelled_frames : (L,) int64
        The known character frames, evenly spread.
    frame_error_mm : (T,) float64
        Mean vertex error per frame against the character's true faces, mm,
        over vertices ``[0, region)`` (all by default; the face area in
        :func:`animate_take`).
    marker_error_mm : (T,) float64
        Mean marker error per frame against the character's true markers, mm.
    times : dict
        Seconds: ``retarget_s``, ``deformer_fit_s`` and ``drive_s``.
    """
    vertices: np.ndarray  # (T, n, 3) the driven character mesh
    faces: np.ndarray  # (m, 3)
    markers: np.ndarray  # (T, p, 3) retargeted character markers
    labelled_frames: np.ndarray
    frame_error_mm: np.ndarray  # (T,) mean vertex error of the face area per frame
    marker_error_mm: np.ndarray  # (T,) mean marker error per frame
    times: dict



def drive_frames(deformer, markers: np.ndarray, progress=None, block: int = 32,
                 dtype=np.float64) -> tuple[np.ndarray, float]:
    """Drive a fitted deformer with every frame of ``markers (T, p, 3)``; returns ``(T, n, 3)`` and seconds.

    ``block`` frames per :func:`facegeom.interfaces.deform_many` call (one
    product for a deformer with a batched path, such as the tangent deformer;
    frame by frame for the others). ``progress`` wraps the iterable of block
    starts. ``dtype`` is the result's (float32 for a mesh cache: rounded once,
    in the copy into the result).
    """
    T = markers.shape[0]
    starts = range(0, T, block)
    out = None
    t0 = time.perf_counter()
    for s in (starts if progress is None else progress(starts)):
        v = deform_many(deformer, markers[s:s + block])
        if out is None:
            out = np.empty((T,) + v.shape[1:], dtype=dtype)
        out[s:s + v.shape[0]] = v
    return out, time.perf_counter() - t0


def face_error_mm(V: np.ndarray, truth: np.ndarray, region: int | None = None) -> np.ndarray:
    """Mean vertex error per frame (mm) over vertices ``[0, region)`` (all by default); cm input."""
    r = slice(None) if region is None else slice(0, region)
    return np.linalg.norm(V[:, r] - truth[:, r], axis=2).mean(axis=1) * 10.0


def animate(model, seq: sq.Sequence, retargeter, deformer, labels: int = 10, region: int | None = None,
            progress=None) -> Animation:
    """Run the pipeline on ``seq``; ``region`` = vertices ``[0, region)`` for the error (default all)."""
    T = seq.n_frames
    lab = evenly_spread(T, labels)
    truth = sq.character_faces(model, seq)  # (T, n, 3)
    t0 = time.perf_counter()
    markers = retargeter.fit(seq.source, lab, seq.target[lab]).transform()
    t_ret = time.perf_counter() - t0
    rest = sq.character_neutral(model, seq.character)
    t0 = time.perf_counter()
    deformer.fit(rest, model.triangles, seq.marker_ids)
    t_fit = time.perf_counter() - t0
    out, t_drive = drive_frames(deformer, markers, progress)
    frame_err = face_error_mm(out, truth, region)
    marker_err = np.linalg.norm(markers - seq.target, axis=2).mean(axis=1) * 10.0
    return Animation(out, model.triangles.copy(), markers, lab, frame_err, marker_err,
                     {"retarget_s": t_ret, "deformer_fit_s": t_fit, "drive_s": t_drive})


def _take_window(model, path, start: int, frames: int, labels: int, seed: int):
    """A take's window on the actor and the character of ``seed`` at the ``ict80`` markers -> ``(W, seq, ids)``.

    ``W`` are the window's ICT weights ``(frames, K)``; errors name the take.
    """
    path = Path(path)
    take = read_take(path)
    if start + frames > take.n_frames:
        raise InputError(f"the take has {take.n_frames} frames; the window of {frames} frames from frame {start} "
                         f"runs past its end", path)
    if labels > frames:
        raise InputError(f"{labels} labelled frames exceed the window's {frames} frames")
    ids = layout(model, "ict80")
    # only the window's weights are mapped (and kept: the take's own are dropped on return)
    W = ict_weights(replace(take, weights=take.weights[start:start + frames]), model.expression_names)
    seq = sq.make_sequence(model, W, ids, seed, sq.make_character(model, seed), f"{path.stem}@{start}")
    return W, seq, ids


def animate_take(model, path, start: int, frames: int, labels: int, seed: int, retargeter,
                 deformer) -> tuple[Animation, sq.Sequence, np.ndarray]:
    """Performance-driven animation of one window of a Live Link Face take.

    The frames ``start .. start + frames - 1`` of the take at ``path`` play on a
    synthetic actor (``seed``) with the 80 ``ict80`` markers, are retargeted
    from ``labels`` known frames of the character of ``seed``, and drive that
    character's neutral; errors over the face area (``FACE_AREA`` vertices).

    Parameters
    ----------
    model : FaceModel
        The face model (``n`` vertices, ``E`` expressions).
    path : str or Path
        The take (Live Link Face CSV).
    start, frames : int
        The window: first frame and number of frames ``T``.
    labels : int
        Known character frames, evenly spread (at most ``frames``).
    seed : int
        Seed of the actor and the character.
    retargeter, deformer : callable
        ``retargeter()`` and ``deformer()`` build the methods.

    Returns
    -------
    anim : Animation
        Vertices ``(T, n, 3)``, markers ``(T, 80, 3)``, per-frame errors ``(T,)``.
    seq : Sequence
        The actor/character sequence of the window.
    ids : ndarray of int, shape (80,)
        The marker vertices.

    Raises
    ------
    InputError
        An unreadable take, a window past its end, more labels than frames.
    """
    W, seq, ids = _take_window(model, path, start, frames, labels, seed)
    anim = animate(model, seq, retargeter(), deformer(), labels, region=FACE_AREA)
    return anim, seq, ids


def write_animation_npz(out, anim: Animation, ids: np.ndarray) -> Path:
    """Write an animation as ``facegeom animate`` does (compressed npz, float32 vertices), atomically.

    Parameters
    ----------
    out : str or Path
        The ``.npz`` file.
    anim : Animation
        Keys written: ``vertices`` (float32, ``(T, n, 3)``), ``faces (m, 3)``,
        ``markers (T, p, 3)``, ``labelled_frames``, ``frame_error_mm (T,)``,
        ``marker_error_mm (T,)``.
    ids : ndarray of int, shape (p,)
        The marker vertices (key ``marker_ids``).

    Returns
    -------
    Path
        ``out``.
    """
    out = Path(out)
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, vertices=anim.vertices.astype(np.float32), faces=anim.faces,
                                markers=anim.markers, marker_ids=ids, labelled_frames=anim.labelled_frames,
                                frame_error_mm=anim.frame_error_mm, marker_error_mm=anim.marker_error_mm)
    return out


def solve_take(model, path, start: int, frames: int, labels: int, seed: int, retargeter, rig, fitter,
               smooth="auto"):
    """``facegeom animate --rig``: a take window on the actor -> retargeted character markers -> rig weights.

    The steps of :func:`animate_take` up to the retargeted ``ict80`` markers of
    the character of ``seed``; then, instead of driving the character's mesh,
    :func:`facegeom.methods.marker_solve.solve_markers` solves them on ``rig``
    (which must have the face model's vertex ids, e.g. the ICT rig or one
    built from it).

    Returns
    -------
    solve : MarkerSolve
        Weights ``(T, K)`` and the rigid motion per frame.
    seq : Sequence
        The actor/character sequence of the window.
    ids : (80,) int64
        The marker vertices.
    info : dict
        ``retarget_s``, ``markers`` (the retargeted ``(T, 80, 3)``); ``weight_mae``
        against the take's weights when the face model's expressions reach
        every shape of the rig (``rig.map_from``: ICT names, or an ARKit-named
        rig's, or through its mapping file), else absent.
    """
    from facegeom.methods.marker_solve import solve_markers

    W, seq, ids = _take_window(model, path, start, frames, labels, seed)
    lab = evenly_spread(frames, labels)
    t0 = time.perf_counter()
    markers = retargeter().fit(seq.source, lab, seq.target[lab]).transform()
    info = {"retarget_s": time.perf_counter() - t0, "markers": markers}
    res = solve_markers(markers, ids, rig, fitter(), smooth=smooth)
    m = rig.map_from(model.expression_names)
    if not m.unmapped_rig:
        info["weight_mae"] = float(np.abs(res.weights - m.apply(W)).mean())
    return res, seq, ids, info
