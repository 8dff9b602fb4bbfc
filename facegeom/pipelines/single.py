"""One input, one result: the steps that ``facegeom fit`` / ``retarget`` and the batch operations share.

Each function reads its input files, runs the method and returns what the
callers print, write or measure; the ``write_*`` functions write the result
files. The methods are given as functions that build them, called once the
inputs have been read (a bad input is reported before a bad parameter).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.io import MarkerSequence, read_retarget_inputs, write_marker_sequence, write_weights
from facegeom.methods.fitting import fit_aligned
from facegeom.model import read_fit_target

__all__ = ["FitOutcome", "fit_file", "write_fit", "Retargeted", "retarget_files", "write_retargeted"]


@dataclass
class FitOutcome:
    """The blendshape coefficients fitted to one target.

    Attributes
    ----------
    kind : str
        What the target was: ``mesh``, ``landmarks`` or ``points``.
    weights : ndarray, shape (B,)
        One coefficient per delta-blendshape of the rig.
    camera : object or None
        The estimated camera (with rotation ``R (3, 3)`` and translation
        ``t (3,)``) of a landmark fit, else None.
    vertices : ndarray, shape (n, 3), or None
        The fitted face (None when fitted by a vectorised batch fit).
    seconds : float
        Time of the fit itself (not the reading).
    notes : list of str
        What was done to the input before the fit (a scan rescaled into the
        rig's units, brought into its frame).
    """

    kind: str
    weights: np.ndarray
    camera: object | None = None
    vertices: np.ndarray | None = None
    seconds: float = 0.0
    notes: list = dataclasses.field(default_factory=list)

    @property
    def active(self) -> np.ndarray:
        """Indices of the shapes with a coefficient above 1e-6 in magnitude, shape (k,)."""
        return np.flatnonzero(np.abs(self.weights) > 1e-6)


def fit_file(rig, path, fitter, kind: str = "auto", focal=None, cx=None, cy=None, scale="auto") -> FitOutcome:
    """Read the target at ``path`` and fit the rig's coefficients to it.

    Parameters
    ----------
    rig : BlendshapeRig
        ``n`` vertices, ``B`` delta-blendshapes.
    path : str or Path
        A mesh, a landmark CSV (``vertex_id,u,v``) or a point cloud
        (:func:`facegeom.model.read_fit_target`).
    fitter : callable
        ``fitter()`` returns the fitter (called after the target is read).
    kind : str
        ``auto``, ``mesh``, ``landmarks`` or ``points``.
    focal, cx, cy : float, optional
        Camera intrinsics in pixels (landmark targets).
    scale : "auto" or float
        Meshes and point clouds: the factor into the rig's units ("auto": the
        power of ten that makes the scan face-sized; see
        :func:`facegeom.model.read_fit_target`).

    Returns
    -------
    FitOutcome
        Weights ``(B,)``, vertices ``(n, 3)``, the camera of a landmark fit or
        the rigid alignment (rig -> scan) of a scan that was off the rig's
        frame (:func:`facegeom.methods.fitting.align_scan`).
    """
    notes: list[str] = []
    kind, target = read_fit_target(path, rig, kind, focal, cx, cy, scale, notes)
    method = fitter()
    t = time.perf_counter()
    pose = None
    if kind in ("points", "mesh"):
        r, pose = fit_aligned(rig, target, method)
        if pose is not None:
            how = "a global rigid search" if kind == "points" else "Kabsch on its least-moving vertices"
            notes.append(f"{Path(path).name}: off the rig's frame; aligned by {how}, then pose and expression "
                         f"alternately (turned {pose.angle_deg:.0f} degrees, moved {np.linalg.norm(pose.t):.3g} "
                         f"rig units)")
    else:
        r = method.fit(rig, target)
    dt = time.perf_counter() - t
    cam = r.info.get("camera") if isinstance(r.info, dict) else None
    return FitOutcome(kind, r.weights, cam if pose is None else pose, r.vertices, dt, notes)


def write_fit(path, names: list[str], outcome: FitOutcome, method: str, target: str,
              time_s: float | None = None, rig=None) -> None:
    """Write fitted coefficients by shape name (``.json`` or ``.csv``) with what produced them.

    Parameters
    ----------
    path : str or Path
        The coefficients file.
    names : list of str, length B
        The rig's shape names.
    outcome : FitOutcome
        Weights ``(B,)`` and the camera (written as ``pose``: ``R (3, 3)``, ``t (3,)``).
    method, target : str
        The fitter's name and the target file, recorded in the file.
    time_s : float, optional
        The fit's time, recorded when given.
    rig : BlendshapeRig, optional
        The rig fitted (its shapes named ``names``). A ``.json`` file then also
        holds ``arkit_weights``: the 52 ARKit weights of the fit
        (``rig.map_to``; when the rig's names reach ARKit's) for anything that
        reads ARKit / Live Link names. The pose's translation is in ``units``
        (cm, facegeom's frame).
    """
    info = {"method": method, "target": target, "kind": outcome.kind}
    if time_s is not None:
        info["time_s"] = time_s
    if outcome.camera is not None:
        info["pose"] = {"R": np.asarray(outcome.camera.R).tolist(), "t": np.asarray(outcome.camera.t).tolist()}
        info["units"] = "cm"
    if rig is not None and Path(path).suffix.lower() == ".json" and tuple(rig.names) == tuple(names):
        from facegeom.io.shape_names import ARKIT_NAMES

        m = rig.map_to(ARKIT_NAMES)
        if not m.is_empty:
            w = m.apply(np.asarray(outcome.weights, dtype=np.float64))
            info["arkit_weights"] = {n: float(x) for n, x in zip(ARKIT_NAMES, w)}
    write_weights(path, names, outcome.weights, info)


@dataclass
class Retargeted:
    """A marker sequence retargeted onto a character.

    Attributes
    ----------
    source : MarkerSequence
        The actor's sequence as read (``T`` frames, ``p`` markers).
    markers : ndarray, shape (T, p, 3)
        The character's retargeted markers.
    labels : MarkerSequence
        The labelled character frames (``L`` frames, reordered to the source's markers).
    filled : int
        Lost source samples filled by interpolation.
    seconds : float
        Time of the retargeting itself (not the reading).
    """

    source: MarkerSequence
    markers: np.ndarray
    labels: MarkerSequence
    filled: int
    seconds: float

    @property
    def label_deviation(self) -> float:
        """Largest coordinate difference between the result and a labelled frame."""
        return float(np.abs(self.markers[self.labels.frames] - self.labels.positions).max())


def retarget_files(source, labels, retargeter, fill_gaps: bool = False, echo=None) -> Retargeted:
    """Read an actor's marker sequence and a character's labelled frames; retarget the sequence.

    Parameters
    ----------
    source, labels : str or Path
        Marker sequences (CSV ``frame,marker,x,y,z`` or npz); the frames of
        ``labels`` index ``source`` (:func:`facegeom.io.read_retarget_inputs`).
    retargeter : callable
        ``retargeter()`` returns the retargeter (called after the files are read).
    fill_gaps : bool
        Interpolate lost source markers over time instead of refusing them.
    echo : callable, optional
        Told how many samples were filled.

    Returns
    -------
    Retargeted
        Markers ``(T, p, 3)`` with the inputs they came from.
    """
    src, P, lab, n = read_retarget_inputs(source, labels, fill_gaps, echo=echo)
    r = retargeter()
    t = time.perf_counter()
    Y = r.fit(P, lab.frames, lab.positions).transform()
    return Retargeted(src, Y, lab, n, time.perf_counter() - t)


def write_retargeted(path, result: Retargeted) -> None:
    """Write retargeted markers ``(T, p, 3)`` as a marker sequence (``.csv`` or ``.npz``) with the labelled frames.

    Parameters
    ----------
    path : str or Path
        The output sequence.
    result : Retargeted
        Its markers, marker names and labelled frames (npz key ``labelled_frames``).
    """
    write_marker_sequence(path, result.markers, names=result.source.names,
                          extra={"labelled_frames": result.labels.frames})
