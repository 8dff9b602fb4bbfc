"""The in-memory marker sequence shared by every sequence reader (CSV, npz, C3D) and length units.

Kept apart from :mod:`facegeom.io.markerseq` (which re-exports it) so that the
C3D reader can build one without an import cycle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.errors import InputError

__all__ = ["MarkerSequence", "UNIT_SCALE"]

#: Length units of marker sequences and their size in millimetres.
UNIT_SCALE: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0}


@dataclass
class MarkerSequence:
    """Frames of marker positions read from a file.

    Attributes
    ----------
    frames : (T,) int64
        Frame index of each row of ``positions`` (increasing, as the readers sort them).
    names : tuple of p str
        Marker names, in the order of the columns of ``positions``.
    positions : (T, p, 3) float64
        Marker positions in the file's units (cm for the ICT face); NaN where a
        marker is lost.
    path : str
        The file it was read from (``""`` when built in memory); errors name it.
    fps : float or None
        Frame rate when the file states one (C3D ``POINT:RATE``), else ``None``.
    unit : str or None
        Length unit when the file states one (``"mm"``, ``"cm"`` or ``"m"``),
        else ``None``.
    named : bool
        Whether the file names its markers (an ``.npz`` without
        ``marker_names`` does not: its ``names`` are then ``0 .. p-1``, which
        must not be taken for vertex ids).
    """

    frames: np.ndarray  # (T,) int64 frame indices
    names: tuple[str, ...]  # (p,) marker names
    positions: np.ndarray  # (T, p, 3) float64, NaN where a marker is missing
    path: str = ""
    fps: float | None = None
    unit: str | None = None
    named: bool = True

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return self.positions.shape[0]

    @property
    def n_markers(self) -> int:
        """Number of markers per frame ``p``."""
        return self.positions.shape[1]

    def missing(self) -> np.ndarray:
        """``(T, p)`` bool: the marker has no finite position in the frame."""
        return ~np.isfinite(self.positions).all(axis=2)

    def in_unit(self, unit: str) -> "MarkerSequence":
        """The same sequence with positions converted to ``unit`` (``"mm"``, ``"cm"`` or ``"m"``).

        Returns ``self`` when the unit is already ``unit``.

        Raises
        ------
        InputError
            ``unit`` is not mm, cm or m, or the sequence's own unit is unknown
            (``None``: the file stated none).
        """
        if unit not in UNIT_SCALE:
            raise InputError(f"unknown length unit {unit!r}; use mm, cm or m", self.path or None)
        if self.unit is None:
            raise InputError(f"the marker sequence states no length unit; cannot convert it to {unit}",
                             self.path or None)
        if self.unit not in UNIT_SCALE:
            raise InputError(f"the marker sequence's unit {self.unit!r} is not mm, cm or m", self.path or None)
        if unit == self.unit:
            return self
        factor = UNIT_SCALE[self.unit] / UNIT_SCALE[unit]
        return MarkerSequence(self.frames, self.names, self.positions * factor, self.path, self.fps, unit, self.named)

    def reorder(self, names, what: str = "markers") -> "MarkerSequence":
        """The same frames with the markers in the order of ``names`` (same set required).

        ``what`` names the file's role in the error message. Returns ``self``
        when the order is already right.

        Raises
        ------
        InputError
            ``names`` has another length than the sequence's markers, or names a
            marker the sequence lacks.
        """
        names = tuple(names)
        if names == self.names:
            return self
        if len(names) != len(self.names):
            raise InputError(f"{self.n_markers} markers per frame, but {len(names)} expected", self.path)
        index = {n: i for i, n in enumerate(self.names)}
        unknown = [n for n in names if n not in index]
        if unknown:
            raise InputError(f"{what}: marker {unknown[0]!r} is missing (the file has {', '.join(self.names[:6])}"
                             f"{'...' if self.n_markers > 6 else ''})", self.path)
        order = np.array([index[n] for n in names])
        return MarkerSequence(self.frames, names, self.positions[:, order], self.path, self.fps, self.unit, self.named)
