"""The three method interfaces and the array checks shared by every method.

The same idea as scikit-learn's estimators: parameters are plain constructor
arguments with good defaults (every method is constructible with no argument),
``fit`` does the heavy work once and returns ``self``, learned state ends in
``_``, and the per-frame call (``deform``) is cheap.

Shapes
------
- vertices: ``(n, 3)`` float64, faces: ``(m, 3)`` int64 triangles
- handles: ``(k,)`` int64 vertex ids, distinct, in ``[0, n)``
- handle_positions: ``(k, 3)`` float64, finite

Parameters
----------
Every method class derives from :class:`Params`: each constructor argument is
stored under its own name, so ``get_params()`` reads them back from the
``__init__`` signature, ``set_params(**kw)`` changes some (checked by the
constructor, as at creation) and ``clone()`` gives a new unfitted copy.
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Any, Protocol, Self, runtime_checkable

import numpy as np

from facegeom.errors import InputError

__all__ = [
    "Params",
    "Deformer",
    "Retargeter",
    "Fitter",
    "FitResult",
    "as_vertices",
    "as_faces",
    "as_handles",
    "as_positions",
    "as_sequence",
]


class Params:
    """scikit-learn style parameters for a method class (mixin).

    The subclass stores every ``__init__`` argument under the same attribute
    name (possibly normalised, e.g. ``int(d)``); learned state ends in ``_``
    and is not a parameter.
    """

    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        """The constructor's parameter names, in signature order."""
        sig = inspect.signature(cls.__init__)
        return tuple(name for name, p in sig.parameters.items()
                     if name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))

    def get_params(self) -> dict[str, Any]:
        """Return ``{name: value}`` for every constructor parameter, in signature order."""
        return {name: getattr(self, name) for name in self.param_names()}

    def set_params(self, **params) -> Self:
        """Change some parameters and return ``self``.

        The new values go through the constructor's checks (a fresh instance
        is built with them), so a bad value raises the same
        :class:`~facegeom.errors.InputError` as at creation. Learned state is
        kept as it is: call ``fit`` again.

        Raises
        ------
        InputError
            A name that is not a constructor parameter (the message names it
            and lists the valid ones), or a bad value.
        """
        valid = self.param_names()
        for name in params:
            if name not in valid:
                raise InputError(f"{type(self).__name__} has no parameter {name!r}; "
                                 f"valid parameters: {', '.join(valid) or 'none'}")
        checked = type(self)(**{**self.get_params(), **params})
        for name in params:
            setattr(self, name, getattr(checked, name))
        return self

    def clone(self) -> Self:
        """Return a new, unfitted instance with the same parameters."""
        return type(self)(**self.get_params())


@runtime_checkable
class Deformer(Protocol):
    """Face driving: deform a rest mesh so that handle vertices reach new positions."""

    def fit(self, vertices: np.ndarray, faces: np.ndarray, handles: np.ndarray) -> Self:
        """Precompute on the rest shape ``vertices (n,3)``, ``faces (m,3)`` with handle ids ``(k,)``."""
        ...

    def deform(self, handle_positions: np.ndarray) -> np.ndarray:
        """Return the deformed vertices ``(n,3)`` for handle positions ``(k,3)``."""
        ...


@runtime_checkable
class Retargeter(Protocol):
    """Expression retargeting: map a source marker sequence onto a target character."""

    def fit(self, source: np.ndarray, labelled_frames: np.ndarray, target_labels: np.ndarray) -> Self:
        """``source (T,p,3)``, ``labelled_frames (L,)`` frame ids, ``target_labels (L,p,3)``."""
        ...

    def transform(self) -> np.ndarray:
        """Return the target sequence ``(T,p,3)``."""
        ...


@dataclass
class FitResult:
    """What a :class:`Fitter` returns.

    Attributes
    ----------
    weights : (B,) float64
        Blendshape coefficients, one per delta-blendshape of the rig.
    vertices : (n,3) float64
        The fitted face: neutral + deltas weighted by ``weights``.
    info : dict
        ``time_s`` (float, seconds spent on this target) for every fitter, then
        method-specific extras (selected shapes, iterations, camera...).
    """

    weights: np.ndarray
    vertices: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Fitter(Protocol):
    """Blendshape fitting: find rig coefficients that reproduce a target."""

    def fit(self, rig: Any, target: Any) -> FitResult:
        ...


# --------------------------------------------------------------------------- checks


def _finite(a: np.ndarray, name: str, path=None) -> None:
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise InputError(f"{name} contains NaN or inf (first at index {tuple(int(i) for i in bad)})", path)


def as_vertices(vertices, name: str = "vertices", path=None) -> np.ndarray:
    """Validate and return ``(n,3)`` float64 finite vertex positions."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"{name} must have shape (n, 3), got {v.shape}", path)
    if v.shape[0] == 0:
        raise InputError(f"{name} is empty", path)
    _finite(v, name, path)
    return np.ascontiguousarray(v)


def as_faces(faces, n_vertices: int, name: str = "faces", path=None) -> np.ndarray:
    """Validate and return ``(m,3)`` int64 triangles indexing ``[0, n_vertices)``."""
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"{name} must have shape (m, 3) (triangles), got {f.shape}", path)
    if f.shape[0] == 0:
        raise InputError(f"{name} is empty: the mesh has no triangle", path)
    if not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
            raise InputError(f"{name} must hold integer vertex ids", path)
    f = f.astype(np.int64)
    lo, hi = int(f.min()), int(f.max())
    if lo < 0 or hi >= n_vertices:
        raise InputError(
            f"{name} index vertex {lo if lo < 0 else hi}, outside [0, {n_vertices}) "
            f"(the mesh has {n_vertices} vertices)",
            path,
        )
    return np.ascontiguousarray(f)


def as_handles(handles, n_vertices: int, name: str = "handles", path=None) -> np.ndarray:
    """Validate and return ``(k,)`` int64 distinct vertex ids in ``[0, n_vertices)``."""
    h = np.asarray(handles)
    if h.ndim != 1:
        raise InputError(f"{name} must be a 1-D array of vertex ids, got shape {h.shape}", path)
    if h.size == 0:
        raise InputError(f"{name} is empty: at least one marker is needed", path)
    if not np.issubdtype(h.dtype, np.integer):
        if not np.all(np.isfinite(h)) or np.any(h != np.round(h)):
            raise InputError(f"{name} must hold integer vertex ids", path)
    h = h.astype(np.int64)
    out = (h < 0) | (h >= n_vertices)
    if out.any():
        raise InputError(
            f"{name}: vertex id {int(h[out][0])} is out of range [0, {n_vertices})", path
        )
    uniq, counts = np.unique(h, return_counts=True)
    if (counts > 1).any():
        raise InputError(f"{name}: vertex id {int(uniq[counts > 1][0])} is repeated", path)
    return h


def as_positions(positions, k: int, name: str = "handle_positions", path=None) -> np.ndarray:
    """Validate and return ``(k,3)`` float64 finite positions."""
    p = np.asarray(positions, dtype=np.float64)
    if p.shape != (k, 3):
        raise InputError(f"{name} must have shape ({k}, 3), got {p.shape}", path)
    _finite(p, name, path)
    return np.ascontiguousarray(p)


def as_sequence(seq, name: str = "source", path=None) -> np.ndarray:
    """Validate and return a ``(T,p,3)`` float64 finite marker sequence."""
    s = np.asarray(seq, dtype=np.float64)
    if s.ndim != 3 or s.shape[2] != 3:
        raise InputError(f"{name} must have shape (T, p, 3), got {s.shape}", path)
    if s.shape[0] == 0 or s.shape[1] == 0:
        raise InputError(f"{name} is empty: shape {s.shape}", path)
    _finite(s, name, path)
    return np.ascontiguousarray(s)


class NotFittedError(InputError):
    """A method was used before ``fit``."""


def check_fitted(obj, attr: str) -> None:
    """Raise :class:`NotFittedError` unless ``obj`` has the learned attribute ``attr``."""
    if getattr(obj, attr, None) is None:
        raise NotFittedError(f"{type(obj).__name__} is not fitted yet: call fit() first")
