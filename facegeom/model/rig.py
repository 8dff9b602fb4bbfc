"""The delta-blendshape rig that the fitters work on.

A :class:`BlendshapeRig` is eq. (1) of Kang et al., "A Selective Expression
Manipulation With Parametric 3D Facial Model" (IEEE Access), the SEM paper::

    B(e) = B_1 + sum_i e_i * dB_i

with ``B_1`` the ``neutral (n,3)`` and ``dB_i`` the ``deltas (B,n,3)``; the
paper's index ``i = 2..n_exp`` is our ``b = 0..B-1`` (the neutral has no
weight here).  Units are the data's (centimetres for the ICT face).

A rig is built from a :class:`~facegeom.model.face.FaceModel`
(:meth:`BlendshapeRig.from_face_model`), from a folder of OBJ meshes
(:meth:`BlendshapeRig.from_obj_folder`) or from an ``.npz`` written by
:meth:`BlendshapeRig.save_npz`; :func:`facegeom.model.inputs.load_rig` picks
one of these for ``facegeom fit``.

Related modules: what a rig is fitted to (mesh, 2-D landmarks, point cloud) is
in :mod:`facegeom.model.targets`; the pinhole camera of landmark targets and its
convention in :mod:`facegeom.model.camera`; the 68-landmark index sets (the 49
inner points, the fitted / evaluation split) in :mod:`facegeom.model.landmarks`;
the fitters in :mod:`facegeom.methods.sem` and :mod:`facegeom.methods.fitting`.
"""
from __future__ import annotations

import difflib
import os
import zipfile
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_handles, as_vertices
from facegeom.model._checks import _first_nonfinite, _readonly
from facegeom.model.landmarks import INNER_LANDMARKS_49

__all__ = [
    "BlendshapeRig",
]


# --------------------------------------------------------------------------- the rig


class BlendshapeRig:
    """A delta-blendshape rig: ``V(w) = neutral + sum_b w_b deltas[b]`` (eq. 1).

    Parameters
    ----------
    neutral : (n, 3) array
        The neutral face ``B_1``.
    deltas : (B, n, 3) array
        Delta-blendshapes ``dB_b = B_b - B_1``.
    names : sequence of B str
        Distinct shape names.
    triangles : (m, 3) int array
        Faces of the mesh (indices into the n vertices).
    landmark_ids : (68,) int array or None
        Vertex id of each Multi-PIE landmark, distinct, or ``None``.

    All arrays are copied to float64 / int64 and made read-only, so the cached
    :meth:`delta_matrix` and :meth:`gram` stay valid.

    Raises
    ------
    InputError
        Wrong shapes, vertex count of ``deltas`` different from ``neutral``'s,
        number of names different from ``B``, duplicate or empty names, NaN or
        inf anywhere, triangles or landmark ids out of range.
    """

    __slots__ = ("neutral", "deltas", "names", "triangles", "landmark_ids", "_D", "_G", "_index")

    def __init__(self, neutral, deltas, names: Sequence[str], triangles, landmark_ids=None):
        neutral = as_vertices(neutral, "neutral")
        n = neutral.shape[0]
        d = np.asarray(deltas, dtype=np.float64)
        if d.ndim != 3 or d.shape[2] != 3:
            raise InputError(f"deltas must have shape (B, n, 3), got {d.shape}")
        if d.shape[0] == 0:
            raise InputError("deltas is empty: the rig needs at least one blendshape")
        if d.shape[1] != n:
            raise InputError(
                f"deltas have {d.shape[1]} vertices per shape but the neutral has {n}"
            )
        if isinstance(names, str):
            raise InputError("names must be a sequence of shape names, not one string")
        names = tuple(names)
        if len(names) != d.shape[0]:
            raise InputError(f"{len(names)} names for {d.shape[0]} blendshapes: need one name per shape")
        for i, s in enumerate(names):
            if not isinstance(s, (str, np.str_)) or not str(s).strip():
                raise InputError(f"name {i} must be a non-empty string, got {s!r}")
        names = tuple(str(s) for s in names)
        seen: dict[str, int] = {}
        for i, s in enumerate(names):
            if s in seen:
                raise InputError(f"duplicate blendshape name {s!r} (shapes {seen[s]} and {i})")
            seen[s] = i
        bad = _first_nonfinite(d)
        if bad is not None:
            raise InputError(
                f"deltas contain NaN or inf (shape {bad[0]} {names[bad[0]]!r}, vertex {bad[1]})"
            )
        tri = as_faces(triangles, n, "triangles")
        if landmark_ids is not None:
            landmark_ids = as_handles(landmark_ids, n, "landmark_ids")
            landmark_ids = _readonly(landmark_ids.copy())
        self.neutral = _readonly(neutral.copy())
        self.deltas = _readonly(np.array(d, dtype=np.float64, order="C", copy=True))
        self.names = names
        self.triangles = _readonly(tri.copy())
        self.landmark_ids = landmark_ids
        self._D = None
        self._G = None
        self._index = seen

    # ----------------------------------------------------------------- sizes
    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return int(self.neutral.shape[0])

    @property
    def n_shapes(self) -> int:
        """Number of delta-blendshapes ``B``."""
        return int(self.deltas.shape[0])

    def __repr__(self) -> str:
        lm = "none" if self.landmark_ids is None else str(self.landmark_ids.size)
        return (f"BlendshapeRig(n_vertices={self.n_vertices}, n_shapes={self.n_shapes}, "
                f"triangles={self.triangles.shape[0]}, landmarks={lm})")

    # ----------------------------------------------------------------- names and weights
    def shape_index(self, name: str) -> int:
        """Index of the shape called ``name``; unknown names list the closest known ones."""
        try:
            return self._index[name]
        except (KeyError, TypeError):
            pass
        close = difflib.get_close_matches(str(name), self.names, n=5, cutoff=0.5)
        if not close:  # also try case-insensitively
            low = {s.lower(): s for s in self.names}
            close = [low[s] for s in difflib.get_close_matches(str(name).lower(), list(low), n=5, cutoff=0.5)]
        hint = f"; did you mean {', '.join(repr(s) for s in close)}?" if close else (
            f"; the rig has {self.n_shapes} shapes ({', '.join(self.names[:6])}"
            f"{', ...' if self.n_shapes > 6 else ''})")
        raise InputError(f"unknown blendshape {name!r}{hint}")

    def weights_from_dict(self, weights: Mapping[str, float]) -> np.ndarray:
        """``{"jawOpen": 0.7, ...}`` -> ``(B,)`` float64 (unnamed shapes get 0)."""
        if not isinstance(weights, Mapping):
            raise InputError(f"weights must be a mapping name -> weight, got {type(weights).__name__}")
        w = np.zeros(self.n_shapes)
        for name, value in weights.items():
            i = self.shape_index(name)
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise InputError(f"weight for {name!r} must be a number, got {value!r}") from None
            if not np.isfinite(v):
                raise InputError(f"weight for {name!r} is NaN or inf")
            w[i] = v
        return w

    def as_weights(self, weights) -> np.ndarray:
        """A mapping (see :meth:`weights_from_dict`) or a ``(B,)`` vector -> validated ``(B,)`` float64."""
        if isinstance(weights, Mapping):
            return self.weights_from_dict(weights)
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (self.n_shapes,):
            raise InputError(f"weights must have shape ({self.n_shapes},), got {w.shape}")
        if not np.all(np.isfinite(w)):
            raise InputError("weights contain NaN or inf")
        return w

    # ----------------------------------------------------------------- evaluation
    def evaluate(self, weights, vertex_ids=None) -> np.ndarray:
        """``neutral + tensordot(w, deltas)`` -> ``(n, 3)`` (eq. 1).

        With ``vertex_ids (k,)`` only those vertices are computed -> ``(k, 3)``.
        """
        w = self.as_weights(weights)
        if vertex_ids is None:
            return self.neutral + np.tensordot(w, self.deltas, axes=1)
        ids = as_handles(vertex_ids, self.n_vertices, "vertex_ids")
        return self.neutral[ids] + np.tensordot(w, self.deltas[:, ids], axes=1)

    def delta_matrix(self) -> np.ndarray:
        """``D (3n, B)`` float64, column ``b`` = ``deltas[b].ravel()`` (cached, read-only)."""
        if self._D is None:
            # a Fortran-ordered view of the deltas: no copy
            self._D = _readonly(self.deltas.reshape(self.n_shapes, -1).T)
        return self._D

    def gram(self) -> np.ndarray:
        """``D.T @ D (B, B)``: ``G[i, j] = dB_i . dB_j`` (cached, read-only)."""
        if self._G is None:
            flat = self.deltas.reshape(self.n_shapes, -1)
            G = flat @ flat.T
            self._G = _readonly(0.5 * (G + G.T))
        return self._G

    def landmark_vertices(self, indices: Sequence[int] = INNER_LANDMARKS_49) -> np.ndarray:
        """Vertex ids of 68-landmark ``indices`` -> ``(k,)`` int64."""
        if self.landmark_ids is None:
            raise InputError("this rig has no landmark ids")
        idx = np.asarray(indices)
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise InputError("landmark indices must be a 1-D sequence of integers")
        k = self.landmark_ids.size
        if idx.size and (idx.min() < 0 or idx.max() >= k):
            raise InputError(f"landmark index out of range [0, {k})")
        return self.landmark_ids[idx].copy()

    # ----------------------------------------------------------------- constructors
    @classmethod
    def from_face_model(cls, model, identity=None) -> "BlendshapeRig":
        """The rig of a :class:`~facegeom.model.face.FaceModel` for one identity.

        ``identity``: ``(I,)`` identity coefficients (or fewer leading ones), or
        ``None`` for the generic face.  The neutral is
        ``model.identity_neutral(identity)``; the delta-blendshapes are the
        model's (identity-independent) expression deltas as float64; the
        landmark ids are ``model.landmarks``.
        """
        return cls(
            neutral=model.identity_neutral(identity),
            deltas=np.asarray(model.expression_deltas, dtype=np.float64),
            names=tuple(model.expression_names),
            triangles=model.triangles,
            landmark_ids=model.landmarks,
        )

    @classmethod
    def from_obj_folder(cls, folder: str | os.PathLike, neutral_name: str = "neutral") -> "BlendshapeRig":
        """A rig from a folder of OBJ meshes: ``<neutral_name>.obj`` + one OBJ per shape.

        Each shape's delta is its vertices minus the neutral's; shapes are named
        by file stem and sorted by file name.  Triangles come from the neutral.
        No landmark ids.
        """
        from facegeom.io import read_mesh
        from facegeom.model.face import read_obj_positions

        folder = Path(folder)
        if not folder.is_dir():
            raise InputError("not a folder", folder)
        neutral_path = folder / f"{neutral_name}.obj"
        if not neutral_path.is_file():
            raise InputError(f"no neutral mesh {neutral_path.name!r} in the folder", folder)
        V0, F = read_mesh(neutral_path)
        files = sorted(p for p in folder.iterdir()
                       if p.is_file() and p.suffix.lower() == ".obj" and p != neutral_path)
        if not files:
            raise InputError(f"no blendshape OBJ besides {neutral_path.name!r}", folder)
        deltas = np.empty((len(files), V0.shape[0], 3))
        for b, p in enumerate(files):
            V = read_obj_positions(p)
            if V.shape[0] != V0.shape[0]:
                raise InputError(
                    f"has {V.shape[0]} vertices but the neutral {neutral_path.name!r} has {V0.shape[0]}", p)
            deltas[b] = V - V0
        return cls(V0, deltas, tuple(p.stem for p in files), F)

    def write_obj_folder(self, folder: str | os.PathLike, neutral_name: str = "neutral") -> Path:
        """Write ``<neutral_name>.obj`` and ``<name>.obj`` per shape (full shapes, not deltas)."""
        from facegeom.io import write_mesh

        folder = Path(folder)
        if not folder.is_dir():
            raise InputError("output folder does not exist", folder)
        if neutral_name in self._index:
            raise InputError(f"a blendshape is called {neutral_name!r} like the neutral")
        write_mesh(folder / f"{neutral_name}.obj", self.neutral, self.triangles)
        for name, d in zip(self.names, self.deltas):
            write_mesh(folder / f"{name}.obj", self.neutral + d, self.triangles)
        return folder

    NPZ_KEYS = ("neutral", "deltas", "names", "triangles", "landmark_ids")

    @classmethod
    def from_npz(cls, path: str | os.PathLike) -> "BlendshapeRig":
        """Read a rig written by :meth:`save_npz` (keys ``neutral, deltas, names, triangles, landmark_ids``;
        an empty ``landmark_ids`` means none)."""
        path = Path(path)
        if not path.is_file():
            raise InputError("file not found" if not path.exists() else "not a file", path)
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in cls.NPZ_KEYS if k not in z.files]
                if missing:
                    raise InputError(f"not a rig file: missing key(s) {', '.join(missing)}", path)
                a = {k: z[k] for k in cls.NPZ_KEYS}
        except InputError:
            raise
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise InputError(f"cannot read as npz ({exc})", path) from None
        lm = a["landmark_ids"]
        try:
            return cls(a["neutral"], a["deltas"], [str(s) for s in np.atleast_1d(a["names"])],
                       a["triangles"], None if lm.size == 0 else lm)
        except InputError as exc:
            raise InputError(exc.reason, path) from None

    def save_npz(self, path: str | os.PathLike, compressed: bool = False) -> Path:
        """Write the rig to ``path`` (npz, atomically) -> ``path``."""
        from facegeom.io import atomic_path

        path = Path(path)
        arrays = dict(
            neutral=self.neutral,
            deltas=self.deltas,
            names=np.array(self.names, dtype=np.str_),
            triangles=self.triangles,
            landmark_ids=(np.zeros(0, np.int64) if self.landmark_ids is None else self.landmark_ids),
        )
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:  # a file object: numpy adds no ".npz" suffix
                (np.savez_compressed if compressed else np.savez)(fh, **arrays)
        return path




