"""The delta-blendshape rig that the fitters work on.

A :class:`BlendshapeRig` is eq. (1) of Kang et al., "A Selective Expression
Manipulation With Parametric 3D Facial Model" (IEEE Access), the SEM paper::

    B(e) = B_1 + sum_i e_i * dB_i

with ``B_1`` the ``neutral (n,3)`` and ``dB_i`` the ``deltas (B,n,3)``; the
paper's index ``i = 2..n_exp`` is our ``b = 0..B-1`` (the neutral has no
weight here).  Units are the data's (centimetres for the ICT face).

A rig is built from a :class:`~facegeom.model.face.FaceModel`
(:meth:`BlendshapeRig.from_face_model`), from a folder of OBJ meshes
(:meth:`BlendshapeRig.from_obj_folder`, its neutral found whatever its case:
:func:`find_neutral`) or from an ``.npz`` written by
:meth:`BlendshapeRig.save_npz`; :func:`facegeom.model.inputs.load_rig` picks
one of these (or a glTF file) for ``facegeom fit``, ``solve`` and ``animate``.

A rig keeps its own shape names. Weights cross between its names and other
names (the ICT expressions every take and solve speaks, a Live Link take's
ARKit columns) through :meth:`BlendshapeRig.map_from` and
:meth:`BlendshapeRig.map_to`, which build a
:class:`~facegeom.io.shape_names.ShapeMap` with the rig's mapping file
(``name_map``) when it has one. Optional attributes: ``parts`` (named index
sets of a glTF rig's parts), ``name_map`` and ``frame`` (the
:class:`~facegeom.model.units.RigFrame` the rig was brought into facegeom's
centimetres and Y-up from).

Related modules: what a rig is fitted to (mesh, 2-D landmarks, point cloud) is
in :mod:`facegeom.model.targets`; the pinhole camera of landmark targets and its
convention in :mod:`facegeom.model.camera`; the 68-landmark index sets (the 49
inner points, the fitted / evaluation split) in :mod:`facegeom.model.landmarks`;
the fitters in :mod:`facegeom.methods.sem` and :mod:`facegeom.methods.fitting`.
"""
from __future__ import annotations

import difflib
import os
import stat
import zipfile
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_handles, as_vertices
from facegeom.io.shape_names import MappingRow, NameMapping, ShapeMap
from facegeom.model._checks import _first_nonfinite, _readonly
from facegeom.model.landmarks import INNER_LANDMARKS_49

__all__ = [
    "BlendshapeRig",
    "NEUTRAL_NAMES",
    "find_neutral",
]

#: File stems (any case) taken for the neutral of an OBJ folder.
NEUTRAL_NAMES: tuple[str, ...] = ("neutral", "base", "neutral_mesh", "default", "basis", "generic_neutral_mesh")


# --------------------------------------------------------------------------- what a rig may ask for
#: Shapes of a rig (the OBJ files of a folder besides its neutral; the deltas of an npz). ARKit has 52, the ICT
#: face 53, Rocketbox's avatars 175 channels, film rigs a few hundred, a MetaHuman's face about 800 (the most of
#: any face rig we know, see :data:`facegeom.io.gltf.MAX_MORPH_TARGETS`): a thousand leaves room. A fit costs the
#: square of the shapes (their Gram matrix, SEM's selection); the audit's folder of 5,000 files asked for 67 GiB.
MAX_RIG_SHAPES = 1_000
#: Vertices of a rig's neutral: the ICT face has 9,409, the MakeHuman head 4,817, a film head some 100,000; a rig
#: made by ``facegeom transfer`` keeps its head's vertices, a scan's too (the 2.4-million-vertex scan of
#: docs/security.md). As many as a USD rig's mesh may have (:data:`facegeom.io.usd.MAX_POINTS`).
MAX_RIG_VERTICES = 5_000_000
#: A rig's deltas (float64, shapes x vertices x 3 x 8 bytes) are held this many times at once: the array read,
#: the rig's own float64 copy, the copy brought into cm and Y-up. Measured, 53 shapes x 200,000 vertices (254 MB):
#: ``load_rig`` peaks at 3.1 (npz) to 3.5 (OBJ folder) times the deltas, and ``fit`` and ``solve`` add nothing
#: measurable to that. So the deltas may take 1/4 of :func:`facegeom.io.npzcheck.memory_budget` (half the
#: machine's memory): 2.9 GB on a 23 GB machine, 53 shapes of 2.3 million vertices or 1,000 of 120,000.
RIG_DELTA_COPIES = 4
#: An array of a rig npz of at least this many bytes is checked for how much it is compressed (below it the memory
#: is not at stake, and :data:`RIG_DELTA_COPIES` bounds it anyway).
RATIO_CHECKED_FROM = 256 << 20
#: ... and refused if it is compressed more than this. Deflate's ceiling is 1,032:1, which only bytes that are
#: (almost) all zeros reach: zeros give 1,025:1. Measured: the rigs of tests/data/heads 14:1 to 18:1 (MakeHuman's
#: deltas are 84 % zeros), the ICT face's 4:1; deltas whose every shape moves 0.1 % of the coordinates 485:1, and
#: 0.03 % 770:1. Beyond 900:1 a rig's shapes move nothing: a file of zeros, like the audit's 4.5 GB of deltas in
#: 4.6 MB.
MAX_COMPRESSION_RATIO = 900
#: A shape OBJ holds each vertex in a line ``v x y z`` of at least 7 characters and a line break.
MIN_VERTEX_BYTES = 8


def _obj_files(folder: Path) -> list[Path]:
    """The folder's entries called ``*.obj`` (any case) that are not folders, sorted: FIFOs, sockets and links
    pointing out of the folder are listed (and refused when read, :func:`_confined`), not silently left out."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".obj" and not p.is_dir())


_KINDS = ((stat.S_ISFIFO, "FIFO (a named pipe)"), (stat.S_ISSOCK, "socket"), (stat.S_ISCHR, "character device"),
          (stat.S_ISBLK, "block device"), (stat.S_ISDIR, "folder"))


def _confined(root: Path, p: Path) -> tuple[Path, os.stat_result]:
    """Check, without opening it, that the rig folder's entry ``p`` is a regular file inside the folder (whose
    real path is ``root``) once its links are followed -> ``(real path, stat)``.

    A link whose target lies in the folder is followed; one pointing out of it (a system file, another folder's
    OBJ) is refused naming where it points, as are a dangling link, a FIFO (opening one blocks), a socket or a
    device."""
    real = Path(os.path.realpath(p))
    if not real.is_relative_to(root):
        raise InputError(f"is a link to {real}, outside the rig folder {root}: a rig's files must lie in its folder",
                         p)
    try:
        st = os.stat(real)
    except FileNotFoundError:
        raise InputError(f"is a link to {real}, which does not exist" if p.is_symlink() else "file not found",
                         p) from None
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or type(exc).__name__})", p) from None
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "special file")
        raise InputError(f"is a {kind}, not a regular file: not read", p)
    return real, st


def _read_confined(p: Path, real: Path, checked: os.stat_result) -> bytes:
    """The bytes of the file ``p`` checked by :func:`_confined` (its real path ``real``): opened without following
    a link and without blocking, and refused if it is no longer the file that was checked."""
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(real, flags)
    except OSError as exc:
        raise InputError(f"cannot read the file ({exc.strerror or type(exc).__name__})", p) from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode) or (st.st_dev, st.st_ino) != (checked.st_dev, checked.st_ino):
            raise InputError("was replaced while the rig was read: not read", p)
        try:
            return fh.read()
        except OSError as exc:
            raise InputError(f"cannot read the file ({exc.strerror or type(exc).__name__})", p) from None


def _listing(files: Sequence[Path]) -> str:
    return ", ".join(p.name for p in files) if files else "none"


def find_neutral(folder: str | os.PathLike, neutral_name: str | None = None) -> Path:
    """The neutral OBJ of a rig folder.

    ``neutral_name`` given: the OBJ of that stem (``Neutral`` or
    ``Neutral.obj``; an exact match first, else case-insensitively). Else the
    one OBJ whose stem is one of :data:`NEUTRAL_NAMES` in any case
    (``neutral``, ``Neutral``, ``base``, ``Base``, ``neutral_mesh``,
    ``default``, ``Basis``...).

    Raises
    ------
    InputError
        Naming the folder and listing its OBJ files: not a folder, the named
        neutral missing, no candidate, or two candidates.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder", folder)
    files = _obj_files(folder)
    if neutral_name is not None:
        stem = str(neutral_name)
        stem = stem[:-4] if stem.lower().endswith(".obj") else stem
        hit = [p for p in files if p.stem == stem] or [p for p in files if p.stem.lower() == stem.lower()]
        if len(hit) != 1:
            raise InputError(f"no neutral mesh {stem + '.obj'!r} in the folder (its OBJ files: {_listing(files)})",
                             folder)
        return hit[0]
    hit = [p for p in files if p.stem.lower() in NEUTRAL_NAMES]
    if not hit:
        raise InputError(f"no neutral mesh among its {len(files)} OBJ files (a neutral is called "
                         f"{', '.join(NEUTRAL_NAMES)} in any case; else pass neutral=NAME): {_listing(files)}", folder)
    if len(hit) > 1:
        raise InputError(f"{len(hit)} neutral candidates, {_listing(hit)}; pass neutral=NAME to choose "
                         f"(its OBJ files: {_listing(files)})", folder)
    return hit[0]


_PART_FIELDS = ("vertex_start", "vertex_stop", "face_start", "face_stop")
# what each array of a rig file must hold (numpy dtype kinds): numbers or text, never bytes of another kind
_NPZ_KINDS = tuple((k, "fiu", "numbers") for k in ("neutral", "deltas", "map_gain")) + tuple(
    (k, "iu", "integers") for k in ("triangles", "landmark_ids", "part_slices", "map_line")) + tuple(
    (k, "US", "text") for k in ("names", "part_names", "map_rig", "map_source", "map_path", "units", "up")) + (
    ("part_targets", "b", "true/false values"),)


#: The keys of a rig file that are read (save_npz's ``extra`` arrays are left in the file).
_NPZ_READ = frozenset(k for k, _, _ in _NPZ_KINDS)


def _check_npz_rig(members: dict, path) -> None:
    """A rig npz's declared arrays (:func:`facegeom.io.npzcheck.npz_members`) against a rig's caps, before one is
    loaded: :data:`MAX_RIG_SHAPES`, :data:`MAX_RIG_VERTICES`, :data:`MAX_COMPRESSION_RATIO` and the deltas'
    memory budget (:data:`RIG_DELTA_COPIES`)."""
    from facegeom.io.npzcheck import _mb

    for key in sorted(_NPZ_READ & set(members)):
        m = members[key]
        if m.shape is None:
            raise InputError(f"'{key}' is not an array (a member without an .npy header)", path)
        if m.nbytes >= RATIO_CHECKED_FROM and m.nbytes > MAX_COMPRESSION_RATIO * m.stored:
            raise InputError(f"'{key}' holds {_mb(m.nbytes)} compressed into {_mb(m.stored)}, "
                             f"{m.nbytes / max(m.stored, 1):,.0f}:1: beyond the {MAX_COMPRESSION_RATIO}:1 only "
                             f"(almost) all-zero data reach (real rigs compress 4:1 to 18:1): not a rig", path)
    for key, axis in (("neutral", 0), ("deltas", 1)):
        m = members.get(key)
        if m is not None and len(m.shape) > axis and m.shape[axis] > MAX_RIG_VERTICES:
            raise InputError(f"'{key}' declares {m.shape[axis]:,} vertices, more than the {MAX_RIG_VERTICES:,} a "
                             f"rig may have", path)
    d = members.get("deltas")
    if d is None:
        return
    if len(d.shape) == 3 and d.shape[0] > MAX_RIG_SHAPES:
        raise InputError(f"'deltas' declares {d.shape[0]:,} shapes, more than the {MAX_RIG_SHAPES:,} a rig may have "
                         f"(ARKit has 52, a MetaHuman face about 800)", path)
    count = 1
    for k in d.shape:
        count *= k
    label = f"{d.shape[0]:,} shapes x {d.shape[1]:,} vertices" if len(d.shape) == 3 else f"{count:,} numbers"
    _check_deltas_budget(count, f"'deltas': {label}", path)  # read as float64 whatever the file's dtype


def _as_parts(parts, n_vertices: int, n_faces: int):
    """Parts as a tuple of :class:`~facegeom.io.gltf.RigPart` (a glTF rig's placed primitives: a name, its slices
    of the vertices and the triangles), checked against the rig's sizes; None stays None."""
    if parts is None:
        return None
    from facegeom.io.gltf import RigPart

    out = []
    for p in parts:
        try:
            name = str(p.name)
            vs, ve, fs, fe = (int(getattr(p, f)) for f in _PART_FIELDS)
            has = bool(getattr(p, "has_targets", True))
        except (AttributeError, TypeError, ValueError):
            raise InputError(f"a part must have a name, {', '.join(_PART_FIELDS)}, got {p!r}") from None
        if not (0 <= vs <= ve <= n_vertices and 0 <= fs <= fe <= n_faces):
            raise InputError(f"part {name!r}: vertices [{vs}, {ve}) and faces [{fs}, {fe}) must lie in the rig's "
                             f"{n_vertices} vertices and {n_faces} faces")
        out.append(p if isinstance(p, RigPart) else RigPart(name, vs, ve, fs, fe, has))
    return tuple(out)


def _check_deltas_budget(count: int, label: str, path) -> None:
    """Refuse deltas of ``count`` numbers (``label``: shapes x vertices) whose float64 bytes,
    :data:`RIG_DELTA_COPIES` times, exceed the memory budget (:func:`facegeom.io.npzcheck.memory_budget`)."""
    from facegeom.io import npzcheck

    need = count * 8
    budget = npzcheck.memory_budget()
    if need * RIG_DELTA_COPIES > budget:
        raise InputError(f"{label} make {npzcheck._mb(need)} of deltas, held {RIG_DELTA_COPIES} times over while the "
                         f"rig is loaded and fitted: more than the {npzcheck._mb(budget)} this machine can spare (half "
                         f"of its memory)", path)


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
    parts : sequence of RigPart, optional
        A glTF rig's placed primitives (:class:`~facegeom.io.gltf.RigPart`: a
        name, its vertex and face slices), kept as ``parts`` (a tuple).
    name_map : NameMapping, optional
        A mapping file's rows (``rig_shape,source_shape,gain``): how other
        names' weights drive this rig's shapes (:meth:`map_from`).
    frame : RigFrame, optional
        How the rig was brought into facegeom's frame (cm, Y up), for writing
        results back in its own units and axes; None: unknown.
    population : FaceModel, optional
        The face model whose population this rig's neutral stands for: set on
        the generic face of a model with identity modes
        (:meth:`from_face_model` without an identity). A fitter then knows
        that the person in a photo is not this face, and that the weights must
        also carry the person's shape (see
        :func:`facegeom.methods.landmark_map.population_prior`). ``None`` for
        one person's rig or a character's.

    Notes
    -----
    All arrays are copied to float64 / int64 and made read-only, so the cached
    :meth:`delta_matrix` and :meth:`gram` stay valid.

    Raises
    ------
    InputError
        Wrong shapes, vertex count of ``deltas`` different from ``neutral``'s,
        number of names different from ``B``, duplicate or empty names, NaN or
        inf anywhere, triangles or landmark ids out of range.
    """

    __slots__ = ("neutral", "deltas", "names", "triangles", "landmark_ids", "parts", "name_map", "frame", "population",
                 "_D", "_G", "_index")

    def __init__(self, neutral, deltas, names: Sequence[str], triangles, landmark_ids=None, *, parts=None,
                 name_map: NameMapping | None = None, frame=None, population=None, _own_deltas: bool = False):
        # _own_deltas (private): ``deltas`` was made for this rig alone (read from a file, converted into
        # facegeom's frame) and nobody else holds it; a float64 C-ordered one is kept, not copied
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
        own = _own_deltas and d.flags.c_contiguous
        self.deltas = _readonly(d if own else np.array(d, dtype=np.float64, order="C", copy=True))
        self.names = names
        self.triangles = _readonly(tri.copy())
        self.landmark_ids = landmark_ids
        self.parts = _as_parts(parts, n, self.triangles.shape[0])
        if name_map is not None and not isinstance(name_map, NameMapping):
            raise InputError(f"name_map must be a NameMapping (read_name_mapping), got {type(name_map).__name__}")
        if name_map is not None:
            ShapeMap.between(names, (), name_map)  # every mapped rig shape must be one of the rig's
        self.name_map = name_map
        self.frame = frame
        self.population = population
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

    # ----------------------------------------------------------------- other names
    def map_from(self, source_names: Sequence[str]) -> ShapeMap:
        """How weights named ``source_names`` (a take's ARKit columns, ICT curves) drive this rig's shapes.

        ``map_from(names).apply(W (T, S))`` -> this rig's weights ``(T, B)``; the
        rig's mapping file (``name_map``) first, then the automatic match of
        :class:`~facegeom.io.shape_names.ShapeMap`.
        """
        return ShapeMap.between(self.names, source_names, self.name_map)

    def map_to(self, target_names: Sequence[str]) -> ShapeMap:
        """How this rig's weights give weights named ``target_names`` (the 52 ARKit columns of a Live Link take).

        Without a mapping file the automatic match from the rig's names; with
        one, the least-squares inverse of :meth:`map_from` (so both agree).
        """
        if self.name_map is None:
            return ShapeMap.between(target_names, self.names)
        return self.map_from(target_names).inverse()

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
        landmark ids are ``model.landmarks``.  The generic face's ``population``
        is ``model``: it stands for everyone the model describes.
        """
        from facegeom.model.units import RigFrame

        return cls(
            neutral=model.identity_neutral(identity),
            deltas=np.asarray(model.expression_deltas, dtype=np.float64),
            names=tuple(model.expression_names),
            triangles=model.triangles,
            landmark_ids=model.landmarks,
            frame=RigFrame("cm", "y", "the ICT face model's", "the ICT face model's"),
            population=model if identity is None and getattr(model, "n_identities", 0) > 0 else None,
        )

    @classmethod
    def from_obj_folder(cls, folder: str | os.PathLike, neutral_name: str | None = None) -> "BlendshapeRig":
        """A rig from a folder of OBJ meshes: a neutral + one OBJ per shape.

        The neutral is ``<neutral_name>.obj``, or with ``neutral_name=None`` the
        one OBJ called neutral, base, neutral_mesh, default or basis in any case
        (:func:`find_neutral`). Each shape's delta is its vertices minus the
        neutral's; shapes are named by file stem and sorted by file name.
        Triangles come from the neutral. No landmark ids.

        The folder is confined: every OBJ read is a regular file inside it once its links are followed (a link to
        a file of the folder is fine). Before the deltas are allocated: at most :data:`MAX_RIG_SHAPES` shapes and
        :data:`MAX_RIG_VERTICES` vertices, deltas that fit the memory budget (:data:`RIG_DELTA_COPIES`), and
        every shape file large enough to hold the neutral's vertices.

        Raises
        ------
        InputError
            One line naming the folder or the file: no neutral or two
            candidates (the OBJ files listed), no shape besides the neutral, a
            shape with another vertex count than the neutral's, an unreadable OBJ;
            a link pointing out of the folder (and where it points), a FIFO, socket
            or device; more shapes or vertices than the caps, deltas beyond the
            memory budget; not enough memory.
        """
        folder = Path(folder)
        neutral_path = find_neutral(folder, neutral_name)
        files = [p for p in _obj_files(folder) if p != neutral_path]
        try:
            return cls._read_obj_folder(folder, neutral_path, files)
        except MemoryError as exc:
            raise InputError(f"not enough memory to read the rig ({str(exc) or 'MemoryError'})", folder) from None

    @classmethod
    def _read_obj_folder(cls, folder: Path, neutral_path: Path, files: list[Path]) -> "BlendshapeRig":
        from facegeom.io.formats.obj import read_obj
        from facegeom.io.mesh import MAX_COORDINATE

        if not files:
            raise InputError(f"no blendshape OBJ besides {neutral_path.name!r}", folder)
        B = len(files)
        if B > MAX_RIG_SHAPES:
            raise InputError(f"{B:,} shape files besides the neutral: more than the {MAX_RIG_SHAPES:,} shapes a rig "
                             f"may have (ARKit has 52, a MetaHuman face about 800)", folder)
        root = Path(os.path.realpath(folder))
        checked = {p: _confined(root, p) for p in [neutral_path, *files]}  # every file, before one is read
        data = _read_confined(neutral_path, *checked[neutral_path])
        if not data:
            raise InputError("empty file", neutral_path)
        mesh = read_obj(neutral_path, data)
        del data
        if mesh.vertices.shape[0] == 0:
            raise InputError("malformed mesh: no vertex could be read", neutral_path)
        if mesh.n_faces == 0:
            raise InputError("the mesh has no face", neutral_path)
        V0, F = mesh.vertices, np.ascontiguousarray(mesh.triangles(), dtype=np.int64)
        del mesh
        n = V0.shape[0]
        big = np.abs(V0).max(axis=1) > MAX_COORDINATE  # as read_mesh refuses it
        if big.any():
            k = int(np.flatnonzero(big)[0])
            raise InputError(f"vertex {k + 1} has a coordinate of {np.abs(V0[k]).max():.3g}: beyond "
                             f"{MAX_COORDINATE:g} in any unit no real mesh reaches, and distances overflow",
                             neutral_path)
        if n > MAX_RIG_VERTICES:
            raise InputError(f"{n:,} vertices, more than the {MAX_RIG_VERTICES:,} a rig may have", neutral_path)
        _check_deltas_budget(B * n * 3, f"{B:,} shapes x {n:,} vertices", folder)

        def shape(p: Path) -> np.ndarray:
            V = read_obj(p, _read_confined(p, *checked[p]), faces=False).vertices
            if V.shape[0] == 0:
                raise InputError("no vertex ('v') lines: not an OBJ mesh", p)
            if np.abs(V).max() > MAX_COORDINATE:  # as every mesh reader refuses it
                raise InputError(f"a coordinate of {np.abs(V).max():.3g}: beyond {MAX_COORDINATE:g} in any unit no "
                                 f"real mesh reaches, and distances overflow", p)
            if V.shape[0] != n:
                raise InputError(f"has {V.shape[0]} vertices but the neutral {neutral_path.name!r} has {n}", p)
            return V

        for p in files:  # a file too small to hold the neutral's vertices is found before the others are read
            size = checked[p][1].st_size
            if size < MIN_VERTEX_BYTES * n - 1:
                shape(p)  # (small: reading it says what it holds instead)
                raise InputError(f"{size:,} bytes cannot hold the {n:,} vertices of the neutral "
                                 f"{neutral_path.name!r} (a vertex line takes {MIN_VERTEX_BYTES} or more)", p)
        deltas = np.empty((B, n, 3))
        for b, p in enumerate(files):
            np.subtract(shape(p), V0, out=deltas[b])
        try:
            return cls(V0, deltas, tuple(p.stem for p in files), F)
        except InputError as exc:
            raise InputError(exc.reason, folder) from None

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
    """The keys every rig file has; optional ones: ``units`` / ``up`` (the frame of the arrays, ``cm`` / ``y`` when
    facegeom knows it), ``part_names`` / ``part_slices`` (P, 4) / ``part_targets`` (the parts: vertex start, stop,
    face start, stop; whether the part has targets),
    ``map_rig`` / ``map_source`` / ``map_gain`` / ``map_line`` / ``map_path`` (the mapping file's rows)."""

    @classmethod
    def from_npz(cls, path: str | os.PathLike) -> "BlendshapeRig":
        """Read a rig written by :meth:`save_npz` (keys ``neutral, deltas, names, triangles, landmark_ids``;
        an empty ``landmark_ids`` means none; the optional keys of :data:`NPZ_KEYS`' note).

        A file that states its ``units`` and ``up`` axis is brought into facegeom's frame (cm, Y up) and the
        rig's ``frame`` says so; else the arrays are taken as they are and ``frame`` is None.
        """
        rig, units, up = cls.read_npz(path)
        if units is None:
            return rig
        from facegeom.model.units import RigFrame

        return rig.in_frame(RigFrame(units, up, "stated by the file", "stated by the file"))

    @classmethod
    def read_npz(cls, path: str | os.PathLike) -> tuple["BlendshapeRig", str | None, str | None]:
        """A rig file's arrays as stored -> ``(rig, units, up)``: the units and up axis the file states, or None."""
        path = Path(path)
        if not path.is_file():
            raise InputError("file not found" if not path.exists() else "not a file", path)
        from facegeom.io.npzcheck import npz_members

        # declared shapes against what the file holds, and against a rig's caps, before anything is allocated
        members = npz_members(path)
        _check_npz_rig(members, path)
        try:
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in cls.NPZ_KEYS if k not in z.files]
                if missing:
                    raise InputError(f"not a rig file: missing key(s) {', '.join(missing)}", path)
                a = {k: z[k] for k in z.files if k in _NPZ_READ}  # other arrays (a transfer's) are not loaded
        except InputError:
            raise
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise InputError(f"cannot read as npz ({exc})", path) from None
        except MemoryError as exc:
            raise InputError(f"not enough memory to read the rig ({str(exc) or 'MemoryError'})", path) from None
        from facegeom.io.npzcheck import check_text

        for key, kinds, what in _NPZ_KINDS:
            if key in a and a[key].dtype.kind not in kinds:
                raise InputError(f"'{key}' must be {what}, is {a[key].dtype}", path)
            if key in a:
                check_text(a[key], key, path)
        if np.ndim(a["names"]) > 1:
            raise InputError(f"'names' must be a list of shape names, has shape {a['names'].shape}", path)
        lm = a["landmark_ids"]
        try:
            units, up = _npz_frame(a)
            rig = cls(a["neutral"], a["deltas"], [str(s) for s in np.atleast_1d(a["names"])],
                      a["triangles"], None if lm.size == 0 else lm, parts=_npz_parts(a), name_map=_npz_map(a),
                      _own_deltas=True)
        except InputError as exc:
            raise InputError(exc.reason, path) from None
        except MemoryError as exc:
            raise InputError(f"not enough memory to read the rig ({str(exc) or 'MemoryError'})", path) from None
        return rig, units, up

    def in_frame(self, frame) -> "BlendshapeRig":
        """This rig brought into facegeom's frame from ``frame`` (a :class:`~facegeom.model.units.RigFrame`:
        its own units and axes) -> a new rig (cm, Y up) whose ``frame`` is ``frame``."""
        return BlendshapeRig(frame.to_facegeom(self.neutral), frame.to_facegeom(self.deltas), self.names,
                             self.triangles, self.landmark_ids, parts=self.parts, name_map=self.name_map,
                             frame=frame, population=self.population, _own_deltas=True)

    def renamed(self, target_names: Sequence[str]) -> tuple["BlendshapeRig", tuple[str, ...]]:
        """The same expressions as shapes named ``target_names`` (e.g. ARKit's 52) -> ``(rig, names not reached)``.

        Each target shape is what weight 1 on it does through the name map
        (:meth:`map_from`): ARKit's ``browInnerUp`` is the sum of the ICT
        ``browInnerUp_L`` and ``_R`` shapes. Target names the rig's shapes do
        not reach (``tongueOut`` from the ICT set) are left out and returned.
        """
        W = self.map_from(target_names).apply(np.eye(len(target_names)))  # (targets, own shapes)
        keep = [i for i in range(len(target_names)) if np.any(W[i])]
        missing = tuple(str(target_names[i]) for i in range(len(target_names)) if i not in keep)
        if not keep:
            raise InputError("none of the names reaches a shape of the rig")
        deltas = np.tensordot(W[keep], self.deltas, axes=1)
        rig = BlendshapeRig(self.neutral, deltas, [str(target_names[i]) for i in keep], self.triangles,
                            self.landmark_ids, parts=self.parts, frame=self.frame)
        return rig, missing

    def with_neutral(self, neutral) -> "BlendshapeRig":
        """The same shapes, names, mapping and frame on another neutral ``(n, 3)`` (a person's face): the
        read-only deltas are shared, not copied; no ``population`` (the rig is one person's)."""
        return BlendshapeRig(neutral, self.deltas, self.names, self.triangles, self.landmark_ids, parts=self.parts,
                             name_map=self.name_map, frame=self.frame, _own_deltas=True)

    def with_name_map(self, name_map: NameMapping | None) -> "BlendshapeRig":
        """The same rig with another mapping file's rows (``None``: none)."""
        return BlendshapeRig(self.neutral, self.deltas, self.names, self.triangles, self.landmark_ids,
                             parts=self.parts, name_map=name_map, frame=self.frame, population=self.population)

    def save_npz(self, path: str | os.PathLike, compressed: bool = False, extra: dict | None = None) -> Path:
        """Write the rig to ``path`` (npz, atomically) -> ``path``; parts, mapping and frame as optional keys.

        ``extra``: more arrays stored beside the rig's (e.g. a transfer's registration), read by whoever knows
        their keys; a key of the rig's own is refused."""
        from facegeom.io import atomic_path

        path = Path(path)
        arrays = dict(
            neutral=self.neutral,
            deltas=self.deltas,
            names=np.array(self.names, dtype=np.str_),
            triangles=self.triangles,
            landmark_ids=(np.zeros(0, np.int64) if self.landmark_ids is None else self.landmark_ids),
        )
        arrays.update(units=np.array("cm"), up=np.array("y"))  # a rig's arrays are in facegeom's frame
        if self.parts is not None:
            arrays.update(part_names=np.array([p.name for p in self.parts], dtype=np.str_),
                          part_slices=np.array([[getattr(p, f) for f in _PART_FIELDS] for p in self.parts],
                                               dtype=np.int64).reshape(-1, 4),
                          part_targets=np.array([p.has_targets for p in self.parts], dtype=bool))
        if self.name_map is not None:
            rows = self.name_map.rows
            arrays.update(map_rig=np.array([r.rig for r in rows], dtype=np.str_),
                          map_source=np.array([r.source for r in rows], dtype=np.str_),
                          map_gain=np.array([r.gain for r in rows], dtype=np.float64),
                          map_line=np.array([r.line for r in rows], dtype=np.int64),
                          map_path=np.array(self.name_map.path))
        clash = sorted(set(extra or {}) & set(arrays))
        if clash:
            raise InputError(f"extra arrays may not replace the rig's own: {', '.join(clash)}", path)
        arrays.update(extra or {})
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:  # a file object: numpy adds no ".npz" suffix
                (np.savez_compressed if compressed else np.savez)(fh, **arrays)
        return path


def _npz_parts(a: dict):
    keys = ("part_names", "part_slices", "part_targets")
    if not any(k in a for k in keys):
        return None
    if not all(k in a for k in keys):
        raise InputError(f"the parts need all of {', '.join(keys)}")
    from facegeom.io.gltf import RigPart

    if np.ndim(a["part_names"]) > 1 or np.ndim(a["part_targets"]) > 1:
        raise InputError("part_names and part_targets must be lists (one entry per part)")
    names = [str(n) for n in np.atleast_1d(a["part_names"])]
    slices, targets = np.asarray(a["part_slices"]), np.atleast_1d(a["part_targets"])
    if slices.shape != (len(names), 4) or not np.issubdtype(slices.dtype, np.integer) or len(targets) != len(names):
        raise InputError("part_slices must be (P, 4) integers and part_targets (P,), one row per part name")
    return [RigPart(n, *(int(x) for x in row), bool(t)) for n, row, t in zip(names, slices, targets)]


def _npz_map(a: dict):
    keys = ("map_rig", "map_source", "map_gain", "map_line")
    if not any(k in a for k in keys):
        return None
    if not all(k in a for k in keys):
        raise InputError(f"the shape mapping needs all of {', '.join(keys)}")
    if any(np.ndim(a[k]) > 1 for k in keys):
        raise InputError("map_rig, map_source, map_gain and map_line must be lists (one entry per row)")
    rig, src = np.atleast_1d(a["map_rig"]), np.atleast_1d(a["map_source"])
    gain, line = np.atleast_1d(a["map_gain"]), np.atleast_1d(a["map_line"])
    if not (len(rig) == len(src) == len(gain) == len(line)) or not np.isfinite(gain.astype(float)).all():
        raise InputError("map_rig, map_source, map_gain and map_line must have one finite entry per row")
    path = str(a["map_path"]) if "map_path" in a else ""
    return NameMapping(tuple(MappingRow(str(r), str(s), float(g), int(n)) for r, s, g, n in zip(rig, src, gain, line)),
                       path)


def _npz_frame(a: dict) -> tuple[str, str]:
    """The units and up axis an npz rig states; facegeom's own format, cm and Y up, when it states none (every
    rig facegeom has written is in its frame, files of earlier releases too)."""
    from facegeom.model.units import TO_CM

    units = str(a["units"]) if "units" in a else "cm"
    up = str(a["up"]).lower() if "up" in a else "y"
    if units not in TO_CM or up not in ("y", "z"):
        raise InputError(f"units {units!r} / up {up!r}: expected mm, cm or m / y or z")
    return units, up
