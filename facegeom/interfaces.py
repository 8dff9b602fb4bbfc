"""The three method interfaces and the array checks shared by every method.

The same idea as scikit-learn's estimators: parameters are plain constructor
arguments with good defaults (every method is constructible with no argument),
``fit`` does the heavy work once and returns ``self``, learned state ends in
``_``, and the per-frame call (``deform``) is cheap.

Shapes
------
- vertices: ``(n, 3)`` float64, faces: ``(m, 3)`` int64 triangles
- handles: ``(k,)`` int64 vertex ids, distinct, in ``[0, n)``
- handle_positions: ``(k, 3)`` float64, finite; ``(F, k, 3)`` for ``F`` frames
  (:func:`deform_many`, result ``(F, n, 3)``)
- fitting: a rig of ``B`` delta-blendshapes on ``n`` vertices; ``fit`` gives one
  :class:`FitResult` (``weights (B,)``, ``vertices (n, 3)``), :func:`fit_many`
  a list of them, one per target

Method parameters
-----------------
Every method class derives from :class:`Params`: each constructor argument is
stored under its own name, so ``get_params()`` reads them back from the
``__init__`` signature, ``set_params(**kw)`` changes some (checked by the
constructor, as at creation) and ``clone()`` gives a new unfitted copy.
"""
from __future__ import annotations

import inspect
from typing import Any, Callable, Protocol, Self, runtime_checkable

import numpy as np

from facegeom.errors import InputError

__all__ = [
    "Params",
    "is_integer",
    "is_finite_number",
    "Deformer",
    "Retargeter",
    "Fitter",
    "FitResult",
    "deform_many",
    "fit_many",
    "batched_targets",
    "as_vertices",
    "as_faces",
    "as_handles",
    "as_positions",
    "as_sequence",
    "check_range",
]


def is_integer(value) -> bool:
    """Whether a parameter value is an integer (an int, or a float of integral value; not a bool, not text).

    Constructors check their integer parameters with it before ``int(value)``,
    so ``d="banana"`` is a one-line :class:`~facegeom.errors.InputError` naming
    the parameter, never a ``ValueError`` traceback.

    Parameters
    ----------
    value : object

    Returns
    -------
    bool
    """
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, np.integer)):
        return True
    return isinstance(value, (float, np.floating)) and bool(np.isfinite(value)) and float(value).is_integer()


def is_finite_number(value) -> bool:
    """Whether a parameter value is a finite real number (not a bool, not text).

    Parameters
    ----------
    value : object

    Returns
    -------
    bool
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        return False
    try:
        return bool(np.isfinite(float(value)))
    except (OverflowError, TypeError):  # an int beyond float
        return False


def check_range(name: str, value, lo, hi, why: str, integer: bool = False, above: bool = False):
    """``value`` as int / float when it lies in ``[lo, hi]`` (``(lo, hi]`` with ``above``); else one InputError line.

    Every numeric method parameter has an upper bound with a reason, so that
    ``-p rings=1e9`` is refused at once instead of running without bound; the
    message names the parameter, the range and the reason.

    Parameters
    ----------
    name : str
        The parameter's name, as the user typed it.
    value : object
    lo, hi : number
        The allowed range.
    why : str
        Why the upper bound is where it is (a few words).
    integer : bool
        Whether only integers are allowed.
    above : bool
        Whether ``lo`` itself is excluded.

    Returns
    -------
    int or float
    """
    ok = (is_integer(value) if integer else is_finite_number(value)) and (
        value > lo if above else value >= lo) and value <= hi
    if not ok:
        kind = "an integer" if integer else "a number"
        left = "(" if above else "["
        raise InputError(f"{name} must be {kind} in {left}{lo:g}, {hi:g}] ({why}), got {value!r}")
    return int(value) if integer else float(value)


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
    """Face driving: deform a rest mesh so that handle vertices reach new positions.

    Optional batched method (use the module function :func:`deform_many`,
    which falls back to :meth:`deform` frame by frame)::

        deform_many(handle_positions: (F, k, 3)) -> (F, n, 3)

    equal to stacking :meth:`deform` of every frame, up to rounding.
    """

    def fit(self, vertices: np.ndarray, faces: np.ndarray, handles: np.ndarray) -> Self:
        """Precompute everything that does not depend on the handle positions.

        Parameters
        ----------
        vertices : (n, 3) float64
            The rest shape.
        faces : (m, 3) int64
            Triangles indexing ``vertices``.
        handles : (k,) int64
            Distinct vertex ids of the handles (markers).

        Returns
        -------
        self
        """
        ...

    def deform(self, handle_positions: np.ndarray) -> np.ndarray:
        """Deform the rest shape so that the handles reach ``handle_positions``.

        Parameters
        ----------
        handle_positions : (k, 3) float64
            One position per handle, in the order of ``handles``.

        Returns
        -------
        (n, 3) float64
            The deformed vertices.
        """
        ...


@runtime_checkable
class Retargeter(Protocol):
    """Expression retargeting: map a source marker sequence onto a target character."""

    def fit(self, source: np.ndarray, labelled_frames: np.ndarray, target_labels: np.ndarray) -> Self:
        """Learn the map from the source sequence and the labelled target frames.

        Parameters
        ----------
        source : (T, p, 3) float64
            The actor's markers per frame.
        labelled_frames : (L,) int64
            Distinct frame ids in ``[0, T)`` whose target markers are known.
        target_labels : (L, p, 3) float64
            The character's markers on those frames.

        Returns
        -------
        self
        """
        ...

    def transform(self) -> np.ndarray:
        """Return the retargeted sequence ``(T, p, 3)`` (the character's markers per frame)."""
        ...


class FitResult:
    """What a :class:`Fitter` returns.

    Attributes
    ----------
    weights : (B,) float64
        Blendshape coefficients, one per delta-blendshape of the rig.
    vertices : (n,3) float64
        The fitted face: neutral + deltas weighted by ``weights``. It may be
        given to the constructor as a function of no argument, called on the
        first read (a batched fit returns thousands of results; a face is
        evaluated only when someone reads it).
    info : dict
        ``time_s`` (float, seconds spent on this target) for every fitter, then
        method-specific extras (selected shapes, iterations, camera...).
    """

    __slots__ = ("weights", "_vertices", "info")

    def __init__(self, weights: np.ndarray, vertices: np.ndarray | Callable[[], np.ndarray],
                 info: dict[str, Any] | None = None):
        self.weights = weights
        self._vertices = vertices
        self.info = {} if info is None else info

    @property
    def vertices(self) -> np.ndarray:
        """The fitted face ``(n, 3)`` (evaluated on first read when given as a function)."""
        if callable(self._vertices):
            self._vertices = self._vertices()
        return self._vertices

    def __repr__(self) -> str:
        return f"FitResult(weights=<{np.shape(self.weights)}>, info keys={sorted(self.info)})"


@runtime_checkable
class Fitter(Protocol):
    """Blendshape fitting: find rig coefficients that reproduce a target.

    Optional batched method (use the module function :func:`fit_many`, which
    falls back to :meth:`fit` target by target)::

        fit_many(rig, targets: sequence of K targets) -> list of K FitResult

    in the order of ``targets``, each equal to ``fit(rig, target)`` up to the
    solver's tolerance. A fitter with ``fit_many`` lists in the class attribute
    ``batched_targets`` the target kinds (``"mesh"``, ``"landmarks"``,
    ``"points"``) it solves together, faster than one by one (see
    :func:`batched_targets`); the others go through :meth:`fit`.
    """

    def fit(self, rig: Any, target: Any) -> FitResult:
        """Fit the rig's coefficients to one target.

        Parameters
        ----------
        rig : BlendshapeRig
            Neutral ``(n, 3)`` and ``B`` delta-blendshapes ``(B, n, 3)``.
        target : MeshTarget, LandmarkTarget or PointCloudTarget
            A mesh ``(n, 3)`` in correspondence, ``L`` landmarks ``(L, 2)`` (pixels)
            of given vertices with a camera, or a point cloud ``(N, 3)``.

        Returns
        -------
        FitResult
            ``weights (B,)``, ``vertices (n, 3)``, ``info`` (with ``time_s``).
        """
        ...


def deform_many(deformer: Deformer, handle_positions) -> np.ndarray:
    """Deform a fitted deformer for ``F`` frames of handle positions at once.

    Uses the deformer's own ``deform_many`` when it has one, else calls
    ``deform`` frame by frame.

    Parameters
    ----------
    deformer : Deformer
        A fitted deformer with ``k`` handles on an ``n``-vertex mesh.
    handle_positions : (F, k, 3) float64
        Handle positions per frame.

    Returns
    -------
    (F, n, 3) float64
        The deformed vertices per frame (possibly a strided view).
    """
    many = getattr(deformer, "deform_many", None)
    if many is not None:
        return many(handle_positions)
    P = np.asarray(handle_positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[0] == 0:
        raise InputError(f"handle_positions must have shape (F, k, 3) with F >= 1, got {P.shape}")
    return np.stack([deformer.deform(p) for p in P])


def fit_many(fitter: Fitter, rig: Any, targets) -> list[FitResult]:
    """Fit ``K`` targets with one rig.

    Uses the fitter's own ``fit_many`` when it has one (its fast paths), else
    calls ``fit`` target by target.

    Parameters
    ----------
    fitter : Fitter
    rig : BlendshapeRig
        ``B`` delta-blendshapes on ``n`` vertices.
    targets : sequence of K targets
        MeshTarget, LandmarkTarget or PointCloudTarget, freely mixed. Fitters
        with a batched mesh path (``"mesh"`` in :func:`batched_targets`) also
        take an array ``(K, n, 3)`` of meshes in correspondence (``K``
        unweighted mesh targets, without building the target objects).

    Returns
    -------
    list of K FitResult
        In the order of ``targets``: ``weights (B,)``, ``vertices (n, 3)``,
        ``info`` with ``time_s`` (for a batched path, the target's share of the
        batch's time).
    """
    many = getattr(fitter, "fit_many", None)
    if many is not None:
        return many(rig, targets)
    return [fitter.fit(rig, t) for t in targets]


def batched_targets(fitter: Fitter) -> frozenset[str]:
    """The target kinds (``"mesh"``, ``"landmarks"``, ``"points"``) that ``fitter``'s
    :func:`fit_many` solves together, faster than one by one (empty: none)."""
    return frozenset(getattr(fitter, "batched_targets", ()))


# --------------------------------------------------------------------------- checks


#: The largest coordinate a method takes (a light year is 1e19 mm; squares of 1e154 overflow double precision, and
#: sums of squares of 1e308 are inf): beyond it a value is no geometry, and the methods' distances overflow.
MAX_COORDINATE = 1e12


def _finite(a: np.ndarray, name: str, path=None) -> None:
    """Refuse NaN, inf and coordinates beyond :data:`MAX_COORDINATE` in ``a``, naming the first."""
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise InputError(f"{name} contains NaN or inf (first at index {tuple(int(i) for i in bad)})", path)
    big = np.abs(a) > MAX_COORDINATE
    if big.any():
        bad = tuple(int(i) for i in np.argwhere(big)[0])
        raise InputError(f"{name} has a coordinate of {float(a[bad]):.3g} at index {bad}: beyond {MAX_COORDINATE:g}, "
                         f"which no real geometry reaches in any unit", path)


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
