"""Delta-blendshape rigs and the targets they are fitted to.

A :class:`BlendshapeRig` is eq. (1) of Kang et al., "A Selective Expression
Manipulation With Parametric 3D Facial Model" (IEEE Access), the SEM paper::

    B(e) = B_1 + sum_i e_i * dB_i

with ``B_1`` the ``neutral (n,3)`` and ``dB_i`` the ``deltas (B,n,3)``; the
paper's index ``i = 2..n_exp`` is our ``b = 0..B-1`` (the neutral has no
weight here).  Units are the data's (centimetres for the ICT face).

Targets (what a fitter reproduces), all validated when built:

- :class:`MeshTarget`: a mesh in vertex correspondence with the rig (Sec. IV-B),
- :class:`LandmarkTarget`: 2-D image landmarks of known rig vertices seen by a
  :class:`PinholeCamera` (Sec. IV-C, the projection ``Pi`` of eq. 4),
- :class:`PointCloudTarget`: unordered 3-D points, no correspondence (Sec. IV-D).

Camera convention (:class:`PinholeCamera`)
------------------------------------------
World -> camera is ``x_cam = R @ x + t``.  Camera space is OpenGL-like: x to
the right, y up, the camera at the origin looking down **-z** (the ICT face
has +z towards the viewer, so the identity rotation sees it from the front).
Pixels: ``u = cx + f * x / (-z)`` (to the right), ``v = cy - f * y / (-z)``
(downwards, image rows).  A point with ``-z <= 0`` is behind the camera and
cannot be projected (:class:`~facegeom.errors.InputError`).  With this
convention the subject's right eye (landmark 36, world -x) appears on the
image's left, as in a photograph.

Landmark sets
-------------
Indices are into the 68 Multi-PIE / iBUG landmarks (``rig.landmark_ids``).
:data:`INNER_LANDMARKS_49` are the 49 inner points the paper evaluates on (17-67
without the inner lip corners 60 and 64).  The paper splits them into 23
*used* (fitted) and 26 *unused* (evaluation only) points (Fig. 6) but does not
list them; :data:`FIT_LANDMARKS_23` / :data:`EVAL_LANDMARKS_26` is our fixed
split.  Both halves are mirror-symmetric (left/right) and both cover every
region, so a method cannot score well on the unused points by overfitting one
region:

=============  ==============================  ================================
region         fit (23)                        eval (26)
=============  ==============================  ================================
brows          17 19 21 22 24 26 (ends, mid)   18 20 23 25
nose           27 30 31 33 35 (top, tip, base) 28 29 32 34
eyes           36 37 39 42 44 45 (corners,     38 40 41 43 46 47 (other lids,
               one upper-lid point each)       all lower lid points)
outer lips     48 51 54 57 (corners, mids)     49 50 52 53 55 56 58 59
inner lips     62 66 (mid points)              61 63 65 67
=============  ==============================  ================================

The inner eye corners 39 / 42 (the paper's inter-ocular normaliser, eq. 31)
are in the fitted set.
"""
from __future__ import annotations

import difflib
import os
import zipfile
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .errors import InputError
from .interfaces import as_faces, as_handles, as_vertices

__all__ = [
    "BlendshapeRig",
    "MeshTarget",
    "PinholeCamera",
    "LandmarkTarget",
    "PointCloudTarget",
    "look_at_camera",
    "INNER_LANDMARKS_49",
    "FIT_LANDMARKS_23",
    "EVAL_LANDMARKS_26",
    "INNER_EYE_CORNERS",
    "OUTER_EYE_CORNERS",
    "MIRROR_68",
]

# --------------------------------------------------------------------------- landmark sets

INNER_LANDMARKS_49: tuple[int, ...] = tuple(i for i in range(17, 68) if i not in (60, 64))
FIT_LANDMARKS_23: tuple[int, ...] = (
    17, 19, 21, 22, 24, 26,  # brows: outer ends, middles, inner ends
    27, 30, 31, 33, 35,  # nose: top of the bridge, tip, base (both wings, centre)
    36, 37, 39, 42, 44, 45,  # eyes: four corners + one upper-lid point per eye
    48, 51, 54, 57,  # outer lips: corners, upper / lower middle
    62, 66,  # inner lips: upper / lower middle (mouth opening)
)
EVAL_LANDMARKS_26: tuple[int, ...] = tuple(i for i in INNER_LANDMARKS_49 if i not in FIT_LANDMARKS_23)
INNER_EYE_CORNERS: tuple[int, int] = (39, 42)  # right eye inner, left eye inner
OUTER_EYE_CORNERS: tuple[int, int] = (36, 45)  # right eye outer, left eye outer


def _mirror_68() -> tuple[int, ...]:
    m = list(range(68))
    pairs = [(i, 16 - i) for i in range(8)]  # jaw
    pairs += [(17 + i, 26 - i) for i in range(5)]  # brows
    pairs += [(31, 35), (32, 34)]  # nose base
    pairs += [(36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46)]  # eyes
    pairs += [(48, 54), (49, 53), (50, 52), (55, 59), (56, 58)]  # outer lips
    pairs += [(60, 64), (61, 63), (65, 67)]  # inner lips
    for a, b in pairs:
        m[a], m[b] = b, a
    return tuple(m)


MIRROR_68: tuple[int, ...] = _mirror_68()
"""Left/right mirror of the 68 landmark indices (``MIRROR_68[36] == 45``)."""


# --------------------------------------------------------------------------- helpers


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _first_nonfinite(a: np.ndarray) -> tuple[int, ...] | None:
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
        return int(self.neutral.shape[0])

    @property
    def n_shapes(self) -> int:
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
        """The rig of a :class:`~facegeom.data.FaceModel` for one identity.

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
        from .data import read_obj_positions
        from .io import read_mesh

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
        from .io import write_mesh

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
        from .io import atomic_path

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


# --------------------------------------------------------------------------- targets


class MeshTarget:
    """A target mesh in vertex correspondence with the rig (SEM on meshes, Sec. IV-B).

    Parameters
    ----------
    vertices : (n, 3)
        Target positions ``T``.
    weights : (n,) or None
        Optional non-negative per-vertex weights (not all zero).
    """

    __slots__ = ("vertices", "weights")

    def __init__(self, vertices, weights=None):
        self.vertices = _readonly(as_vertices(vertices, "target vertices").copy())
        if weights is not None:
            w = np.asarray(weights, dtype=np.float64)
            n = self.vertices.shape[0]
            if w.shape != (n,):
                raise InputError(f"target weights must have shape ({n},), got {w.shape}")
            if not np.all(np.isfinite(w)):
                raise InputError("target weights contain NaN or inf")
            if (w < 0).any():
                raise InputError(f"target weights must be >= 0 (vertex {int(np.flatnonzero(w < 0)[0])} is negative)")
            if not (w > 0).any():
                raise InputError("target weights are all zero")
            weights = _readonly(w.copy())
        self.weights = weights

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def check(self, rig: BlendshapeRig) -> "MeshTarget":
        """Raise :class:`InputError` unless this target matches ``rig``'s vertex count."""
        if self.n_vertices != rig.n_vertices:
            raise InputError(f"target mesh has {self.n_vertices} vertices, the rig {rig.n_vertices}")
        return self


class PinholeCamera:
    """A pinhole camera; see the module docstring for the convention.

    ``x_cam = R @ x + t``; camera looks down -z, x right, y up;
    ``u = cx + focal * x_cam / (-z_cam)``, ``v = cy - focal * y_cam / (-z_cam)``.

    Parameters
    ----------
    focal : float
        Focal length in pixels (> 0).
    cx, cy : float
        Principal point in pixels.
    R : (3, 3) rotation (world -> camera), default identity.
    t : (3,) translation, default zero.
    """

    __slots__ = ("focal", "cx", "cy", "R", "t", "posed")

    def __init__(self, focal: float, cx: float, cy: float, R=None, t=None):
        self.posed = R is not None or t is not None  # False: the pose is unknown (fitters estimate it)
        self.focal = _as_scalar(focal, "focal", positive=True)
        self.cx = _as_scalar(cx, "cx")
        self.cy = _as_scalar(cy, "cy")
        if R is None:
            R = np.eye(3)
        R = np.asarray(R, dtype=np.float64)
        if R.shape != (3, 3):
            raise InputError(f"camera rotation R must have shape (3, 3), got {R.shape}")
        if not np.all(np.isfinite(R)):
            raise InputError("camera rotation R contains NaN or inf")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError("camera rotation R must be a rotation matrix (orthonormal, det +1)")
        if t is None:
            t = np.zeros(3)
        t = np.asarray(t, dtype=np.float64)
        if t.shape != (3,):
            raise InputError(f"camera translation t must have shape (3,), got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise InputError("camera translation t contains NaN or inf")
        self.R = _readonly(R.copy())
        self.t = _readonly(t.copy())

    def __repr__(self) -> str:
        return f"PinholeCamera(focal={self.focal:g}, cx={self.cx:g}, cy={self.cy:g}, t={self.t.tolist()})"

    def with_pose(self, R, t) -> "PinholeCamera":
        """The same intrinsics with the pose ``(R, t)`` (world -> camera)."""
        return PinholeCamera(self.focal, self.cx, self.cy, R, t)

    @property
    def center(self) -> np.ndarray:
        """The camera position in world coordinates, ``-R.T @ t``."""
        return -self.R.T @ self.t

    def to_camera(self, points) -> np.ndarray:
        """World ``(N, 3)`` -> camera coordinates ``(N, 3)``."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"points must have shape (N, 3), got {p.shape}")
        bad = _first_nonfinite(p)
        if bad is not None:
            raise InputError(f"point {bad[0]} is NaN or inf")
        return p @ self.R.T + self.t

    def _depth(self, pc: np.ndarray, what: str) -> np.ndarray:
        depth = -pc[:, 2]
        bad = ~(depth > 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(
                f"{what} {i} is behind the camera (depth {depth[i]:.6g}; the camera looks down -z)")
        return depth

    def project(self, points, what: str = "point") -> np.ndarray:
        """World points ``(N, 3)`` -> pixels ``(N, 2)`` (``Pi`` of eq. 4).

        ``what`` names the points in the error message ("landmark 3 is behind the camera").
        """
        pc = self.to_camera(points)
        depth = self._depth(pc, what)
        return np.c_[self.cx + self.focal * pc[:, 0] / depth, self.cy - self.focal * pc[:, 1] / depth]

    def jacobian(self, points, what: str = "point") -> np.ndarray:
        """d(u, v) / d(world x, y, z) at each point -> ``(N, 2, 3)``."""
        pc = self.to_camera(points)
        depth = self._depth(pc, what)
        f = self.focal
        J = np.zeros((pc.shape[0], 2, 3))
        # u = cx - f X / Z, v = cy + f Y / Z with Z = -depth
        J[:, 0, 0] = f / depth
        J[:, 0, 2] = f * pc[:, 0] / depth**2
        J[:, 1, 1] = -f / depth
        J[:, 1, 2] = -f * pc[:, 1] / depth**2
        return J @ self.R


def look_at_camera(vertices, focal: float = 1000.0, image_size: tuple[int, int] = (640, 480),
                   distance: float | None = None, yaw: float = 0.0, pitch: float = 0.0,
                   fill: float = 0.8) -> PinholeCamera:
    """A camera that frames ``vertices`` (a face, +z towards the viewer) from the front.

    The camera sits on the +z side of the bounding-box centre at ``distance``
    and looks at it (``R = I`` when ``yaw = pitch = 0``); ``yaw`` (about +y) and
    ``pitch`` (about +x), in degrees, orbit it around the centre.  The
    principal point is the image centre.  With ``distance=None`` the distance is
    chosen so that the face's bounding box fills ``fill`` of the image.

    Returns a :class:`PinholeCamera` with ``x_cam = R @ x + t``.
    """
    V = as_vertices(vertices)
    f = _as_scalar(focal, "focal", positive=True)
    try:
        W, H = (float(s) for s in image_size)
    except (TypeError, ValueError):
        raise InputError(f"image_size must be (width, height), got {image_size!r}") from None
    if not (W > 0 and H > 0 and np.isfinite(W) and np.isfinite(H)):
        raise InputError(f"image_size must be positive, got {image_size!r}")
    fill = _as_scalar(fill, "fill", positive=True)
    lo, hi = V.min(axis=0), V.max(axis=0)
    center = 0.5 * (lo + hi)
    ext = hi - lo
    radius = 0.5 * float(np.linalg.norm(ext))
    if distance is None:
        # the whole bounding sphere fits in fill * the smaller image side
        distance = radius + f * 2 * radius / (fill * min(W, H))
    distance = _as_scalar(distance, "distance", positive=True)
    a, b = np.deg2rad(_as_scalar(yaw, "yaw")), np.deg2rad(_as_scalar(pitch, "pitch"))
    Ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    M = Ry @ Rx  # camera -> world rotation: columns are the camera axes in world space
    eye = center + M @ np.array([0.0, 0.0, distance])
    R = M.T
    return PinholeCamera(f, W / 2.0, H / 2.0, R, -R @ eye)


class LandmarkTarget:
    """2-D landmarks ``l_k`` of rig vertices ``v_k`` seen by ``camera`` (eq. 4, Sec. IV-C).

    Parameters
    ----------
    points2d : (L, 2)
        Pixel positions, finite.
    vertex_ids : (L,)
        Distinct rig vertex ids (checked against a rig by :meth:`check`).
    camera : PinholeCamera
    """

    __slots__ = ("points2d", "vertex_ids", "camera")

    def __init__(self, points2d, vertex_ids, camera: PinholeCamera):
        p = np.asarray(points2d, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2:
            raise InputError(f"landmark points must have shape (L, 2), got {p.shape}")
        if p.shape[0] == 0:
            raise InputError("no landmark: points2d is empty")
        bad = _first_nonfinite(p)
        if bad is not None:
            raise InputError(f"landmark {bad[0]} is NaN or inf")
        ids = _as_ids(vertex_ids, "landmark vertex_ids")
        if ids.size != p.shape[0]:
            raise InputError(f"{p.shape[0]} landmark points for {ids.size} vertex ids")
        if not isinstance(camera, PinholeCamera):
            raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
        self.points2d = _readonly(p.copy())
        self.vertex_ids = _readonly(ids)
        self.camera = camera

    @property
    def n_landmarks(self) -> int:
        return int(self.points2d.shape[0])

    @classmethod
    def from_mesh(cls, vertices, vertex_ids, camera: PinholeCamera) -> "LandmarkTarget":
        """Synthetic landmarks: the projection of ``vertices[vertex_ids]``."""
        V = as_vertices(vertices)
        ids = as_handles(vertex_ids, V.shape[0], "landmark vertex_ids")
        return cls(camera.project(V[ids], "landmark"), ids, camera)

    def check(self, rig: BlendshapeRig) -> "LandmarkTarget":
        """Raise :class:`InputError` unless every vertex id exists in ``rig``."""
        as_handles(self.vertex_ids, rig.n_vertices, "landmark vertex_ids")
        return self

    def project(self, vertices) -> np.ndarray:
        """``Pi(f_{v_k})`` for a face ``vertices (n, 3)`` -> ``(L, 2)``."""
        V = np.asarray(vertices, dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] <= int(self.vertex_ids.max()):
            raise InputError(f"vertices must have shape (n, 3) with n > {int(self.vertex_ids.max())}, got {V.shape}")
        return self.camera.project(V[self.vertex_ids], "landmark")

    def subset(self, rows) -> "LandmarkTarget":
        """The landmarks at ``rows`` (indices into this target)."""
        r = np.asarray(rows)
        if r.ndim != 1 or r.size == 0 or not np.issubdtype(r.dtype, np.integer):
            raise InputError("rows must be a non-empty 1-D array of integers")
        if r.min() < -self.n_landmarks or r.max() >= self.n_landmarks:
            raise InputError(f"row out of range [0, {self.n_landmarks})")
        return LandmarkTarget(self.points2d[r], self.vertex_ids[r], self.camera)

    def rows_of(self, vertex_ids) -> np.ndarray:
        """Row of each of ``vertex_ids`` in this target; InputError for an absent id."""
        pos = {int(v): i for i, v in enumerate(self.vertex_ids)}
        out = []
        for v in np.atleast_1d(np.asarray(vertex_ids)).tolist():
            if int(v) not in pos:
                raise InputError(f"vertex {int(v)} is not among the target's landmarks")
            out.append(pos[int(v)])
        return np.asarray(out, dtype=np.int64)


class PointCloudTarget:
    """Unordered target points (a scan), optionally with normals (Sec. IV-D).

    Parameters
    ----------
    points : (N, 3), N >= 1, finite.
    normals : (N, 3) or None; non-zero, finite; stored normalised.
    """

    __slots__ = ("points", "normals")

    def __init__(self, points, normals=None):
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"point cloud must have shape (N, 3), got {p.shape}")
        if p.shape[0] == 0:
            raise InputError("point cloud is empty")
        bad = _first_nonfinite(p)
        if bad is not None:
            raise InputError(f"point cloud point {bad[0]} is NaN or inf")
        if normals is not None:
            nr = np.asarray(normals, dtype=np.float64)
            if nr.shape != p.shape:
                raise InputError(f"normals must have shape {p.shape}, got {nr.shape}")
            bad = _first_nonfinite(nr)
            if bad is not None:
                raise InputError(f"normal {bad[0]} is NaN or inf")
            length = np.linalg.norm(nr, axis=1)
            if (length <= 1e-12).any():
                raise InputError(f"normal {int(np.flatnonzero(length <= 1e-12)[0])} is zero")
            normals = _readonly(nr / length[:, None])
        self.points = _readonly(p.copy())
        self.normals = normals

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])
