"""Argument checks shared by the model classes (rig, targets, camera): read-only arrays, ids, scalars.

Private to :mod:`facegeom.model`; the checks of arrays passed between layers
(vertices, faces, handles) are in :mod:`facegeom.interfaces`. Every failed
check raises :class:`~facegeom.errors.InputError`.
"""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _first_nonfinite(a: np.ndarray) -> tuple[int, ...] | None:
    with np.errstate(over="ignore", invalid="ignore"):  # (a sum may overflow, or add inf to -inf: no warning)
        if np.isfinite(np.sum(a)):  # a finite sum has no NaN or inf in it (a cheap first look, no mask allocated)
            return None
    bad = ~np.isfinite(a)
    if bad.any():
        return tuple(int(i) for i in np.argwhere(bad)[0])
    return None


def _as_ids(ids, name: str) -> np.ndarray:
    """``(L,)`` int64 distinct non-negative ids (no upper bound known yet)."""
    h = np.asarray(ids)
    if h.ndim != 1:
        raise InputError(f"{name} must be a 1-D array of vertex ids, got shape {h.shape}")
    if h.size == 0:
        raise InputError(f"{name} is empty")
    if not np.issubdtype(h.dtype, np.integer):
        if not np.issubdtype(h.dtype, np.number) or not np.all(np.isfinite(h)) or np.any(h != np.round(h)):
            raise InputError(f"{name} must hold integer vertex ids")
    h = h.astype(np.int64)
    if (h < 0).any():
        raise InputError(f"{name}: vertex id {int(h[h < 0][0])} is negative")
    uniq, counts = np.unique(h, return_counts=True)
    if (counts > 1).any():
        raise InputError(f"{name}: vertex id {int(uniq[counts > 1][0])} is repeated")
    return h


def _as_scalar(x, name: str, positive: bool = False) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {x!r}") from None
    if not np.isfinite(v):
        raise InputError(f"{name} must be finite, got {v}")
    if positive and v <= 0:
        raise InputError(f"{name} must be > 0, got {v}")
    return v
