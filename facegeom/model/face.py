"""The face-model data bundle (ICT-FaceKit "light") and the :class:`FaceModel`.

The bundle is never part of this project; it is found, in this order, at

1. the path given on the command line (``--data``) or to :func:`locate_data`,
2. the environment variable ``FACEGEOM_DATA``,
3. ``../shared/data/ict-face-light`` relative to the repository root (a
   development checkout only; an installed package has no repository),
4. the user cache, ``ict-face-light/`` in :func:`cache_folder` (where
   ``facegeom data fetch`` builds it, see :mod:`facegeom.model.download`).

A path may name the folder or the ``.npz`` itself. See the bundle's README for
its keys. :func:`import_ict_folder` reads the original ICT-FaceKit layout (one
OBJ per shape plus ``vertex_indices.json``) into the same arrays.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from facegeom.errors import DataNotFoundError, InputError, TakesNotFoundError

__all__ = [
    "ENV_VAR",
    "CACHE_ENV_VAR",
    "TAKES_ENV_VAR",
    "cache_folder",
    "cache_bundle_folder",
    "data_places",
    "default_takes_path",
    "locate_takes",
    "takes_cache_folder",
    "takes_places",
    "BUNDLE_NAME",
    "REQUIRED_KEYS",
    "FaceModel",
    "default_data_path",
    "locate_data",
    "load_bundle",
    "load_face_model",
    "import_ict_folder",
    "read_obj_positions",
    "read_obj_polygons",
]

ENV_VAR = "FACEGEOM_DATA"
CACHE_ENV_VAR = "FACEGEOM_CACHE"
BUNDLE_NAME = "ict_face_light.npz"
REPO_ROOT = Path(__file__).resolve().parents[2]
REQUIRED_KEYS = (
    "neutral",
    "quads",
    "triangles",
    "expression_names",
    "expression_deltas",
    "identity_names",
    "identity_modes",
    "landmarks_multipie68",
)


def default_data_path() -> Path:
    """``../shared/data/ict-face-light`` next to the repository root."""
    return REPO_ROOT.parent / "shared" / "data" / "ict-face-light"


def _in_repository() -> bool:
    """Whether this package runs from a source checkout (an installed wheel has no repository root)."""
    return (REPO_ROOT / "pyproject.toml").is_file()


def cache_folder() -> Path:
    """The user cache of facegeom: ``$FACEGEOM_CACHE``, else the system's cache folder for ``facegeom``.

    The system folder is pooch's ``os_cache("facegeom")`` (``~/.cache/facegeom``
    on Linux, ``~/Library/Caches/facegeom`` on macOS). It is not created here.
    """
    env = os.environ.get(CACHE_ENV_VAR)
    if env:
        return Path(env).expanduser()
    import pooch  # lazy: only needed when the data is looked for in the cache

    return Path(pooch.os_cache("facegeom"))


def cache_bundle_folder() -> Path:
    """Where ``facegeom data fetch`` puts the bundle: ``ict-face-light/`` in :func:`cache_folder`."""
    return cache_folder() / "ict-face-light"


def _as_bundle_file(p: Path) -> Path | None:
    if p.is_file():
        return p
    if p.is_dir() and (p / BUNDLE_NAME).is_file():
        return p / BUNDLE_NAME
    return None


def data_places(path: str | os.PathLike | None = None) -> list[tuple[str, Path | None, Path | None]]:
    """The places of the lookup order, each with the bundle found there.

    Parameters
    ----------
    path : path, optional
        The explicit path (``--data`` on the command line).

    Returns
    -------
    list of (str, Path or None, Path or None)
        ``(what, where, bundle)`` for the path argument, ``$FACEGEOM_DATA``,
        the development folder and the user cache, in this order; ``where`` is
        None when the place does not apply (no path given, variable not set,
        not running from a repository), ``bundle`` the ``.npz`` found there or None.
    """
    env = os.environ.get(ENV_VAR)
    places = [
        ("the path argument", None if path is None else Path(path)),
        (f"${ENV_VAR}", Path(env) if env else None),
        ("the development folder", default_data_path() if _in_repository() else None),
        ("the user cache", cache_bundle_folder()),
    ]
    return [(what, where, None if where is None else _as_bundle_file(where)) for what, where in places]


def locate_data(path: str | os.PathLike | None = None) -> Path:
    """Find the bundle's ``.npz``: ``path``, else ``$FACEGEOM_DATA``, else the development folder, else the cache.

    Raises
    ------
    DataNotFoundError
        Naming the places that were looked at and how to fetch the data.
    """
    if path is not None:
        found = _as_bundle_file(Path(path))
        if found:
            return found
        # an explicit path that is wrong is an error even if another place would work
        raise DataNotFoundError(
            f"face data not found at the given path {path} (expected a folder holding {BUNDLE_NAME}, or the file)"
        )
    tried = []
    env = os.environ.get(ENV_VAR)
    if env:
        found = _as_bundle_file(Path(env))
        if found:
            return found
        tried.append(f"${ENV_VAR}={env}")
    else:
        tried.append(f"${ENV_VAR} (not set)")
    if _in_repository():
        default = default_data_path()
        found = _as_bundle_file(default)
        if found:
            return found
        tried.append(str(default))
    cache = cache_bundle_folder()
    found = _as_bundle_file(cache)
    if found:
        return found
    tried.append(f"the user cache {cache}")
    raise DataNotFoundError(
        f"face data ({BUNDLE_NAME}) not found; looked at: the path argument (not given), "
        + ", ".join(tried)
        + ". Download it with `facegeom data fetch` (about 400 MB), or: "
        + f"Pass path=PATH or set {ENV_VAR}."
    )


def load_bundle(path: str | os.PathLike | None = None) -> dict[str, np.ndarray]:
    """Load and validate the bundle's arrays (see :data:`REQUIRED_KEYS`).

    Returns
    -------
    dict of str to ndarray
        Every array of the ``.npz``, as stored (``neutral`` ``(n, 3)``,
        ``expression_deltas`` ``(B, n, 3)``, ``identity_modes`` ``(I, n, 3)``,
        ``landmarks_multipie68`` ``(68,)``...), plus ``_path``: the file read.

    Raises
    ------
    DataNotFoundError
        The bundle was not found (see :func:`locate_data`).
    InputError
        Unreadable file, missing keys, wrong shapes, indices out of range or
        NaN / inf in the positions.
    """
    return _read_bundle(path)


def _read_bundle(path, deferred: tuple[str, ...] = ()) -> dict:
    """:func:`load_bundle`, the members ``deferred`` checked by their shapes only: each is a
    :class:`_BundleMember`, which reads, checks (NaN / inf) and returns the array when called."""
    f = locate_data(path)
    try:
        with open(f, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise InputError(f"cannot read the face data bundle ({exc.__class__.__name__})", f) from None
    if magic != b"PK\x03\x04":  # an .npz is a zip archive; anything else is not a bundle (and never unpickled)
        raise InputError(f"not a face data bundle: expected the {BUNDLE_NAME} archive (or the folder holding it)", f)
    try:
        with np.load(f, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k not in deferred}
            shapes = {k: _member_shape(z, k) for k in deferred if k in z.files}
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a user error
        raise InputError(f"cannot read the face data bundle ({exc.__class__.__name__}: {exc})", f) from None
    missing = [k for k in REQUIRED_KEYS if k not in arrays and k not in shapes]
    if missing:
        raise InputError(f"face data bundle lacks the keys {', '.join(missing)}", f)
    _validate_bundle(arrays, f, shapes)
    for key, shape in shapes.items():
        arrays[key] = _BundleMember(f, key, shape)
    arrays["_path"] = np.array(str(f))
    return arrays


def _member_shape(z, key: str) -> tuple[int, ...]:
    """The shape an ``.npz`` member's header declares, its data not read (a header of another version: read)."""
    fmt = np.lib.format
    with z.zip.open(key if key in z.zip.namelist() else f"{key}.npy") as fh:  # numpy's choice of the two
        version = fmt.read_magic(fh)
        if version == (1, 0):
            return fmt.read_array_header_1_0(fh)[0]
        if version == (2, 0):
            return fmt.read_array_header_2_0(fh)[0]
    return z[key].shape


@dataclass(frozen=True)
class _BundleMember:
    """Called: the bundle ``file``'s member ``key`` (declared ``shape``), read and checked as :func:`load_bundle`
    does (a plain object, so that a model holding one still pickles)."""

    file: Path
    key: str
    shape: tuple[int, ...]
    dtype: type | None = None

    def __call__(self) -> np.ndarray:
        f = self.file
        try:
            with np.load(f, allow_pickle=False) as z:
                a = z[self.key]
        except Exception as exc:  # noqa: BLE001 - any unreadable file is a user error
            raise InputError(f"cannot read the face data bundle ({exc.__class__.__name__}: {exc})", f) from None
        if a.shape != self.shape:
            raise InputError(f"the face data bundle changed while in use: {self.key} is {a.shape}, was "
                             f"{self.shape}", f)
        _check_finite(a, self.key, f)
        return a if self.dtype is None else np.asarray(a, dtype=self.dtype)


def _check_finite(a: np.ndarray, key: str, f) -> None:
    if not np.all(np.isfinite(a)):
        raise InputError(f"malformed face data bundle: {key} contains NaN or inf", f)


def _validate_bundle(a: Mapping[str, np.ndarray], f, shapes: Mapping[str, tuple[int, ...]] | None = None) -> None:
    shape = {k: v.shape for k, v in a.items()} | dict(shapes or {})
    n = a["neutral"].shape[0] if a["neutral"].ndim == 2 else -1
    checks = [
        (a["neutral"].ndim == 2 and a["neutral"].shape[1] == 3, f"neutral must be (n, 3), is {a['neutral'].shape}"),
        (a["triangles"].ndim == 2 and a["triangles"].shape[1] == 3, f"triangles must be (m, 3), is {a['triangles'].shape}"),
        (a["quads"].ndim == 2 and a["quads"].shape[1] == 4, f"quads must be (q, 4), is {a['quads'].shape}"),
        (shape["expression_deltas"][1:] == (n, 3), f"expression_deltas must be (B, {n}, 3), is {shape['expression_deltas']}"),
        (shape["expression_names"] == shape["expression_deltas"][:1],
         f"expression_names {shape['expression_names']} does not match expression_deltas {shape['expression_deltas']}"),
        (shape["identity_modes"][1:] == (n, 3), f"identity_modes must be (I, {n}, 3), is {shape['identity_modes']}"),
        (shape["identity_names"] == shape["identity_modes"][:1],
         f"identity_names {shape['identity_names']} does not match identity_modes {shape['identity_modes']}"),
        (a["landmarks_multipie68"].shape == (68,), f"landmarks_multipie68 must be (68,), is {a['landmarks_multipie68'].shape}"),
    ]
    for ok, msg in checks:
        if not ok:
            raise InputError(f"malformed face data bundle: {msg}", f)
    for key in ("triangles", "quads", "landmarks_multipie68"):
        v = a[key]
        if not np.issubdtype(v.dtype, np.integer):
            integral = np.issubdtype(v.dtype, np.floating) and np.all(np.isfinite(v)) and np.all(v == np.round(v))
            if not integral:
                raise InputError(f"malformed face data bundle: {key} must hold integer vertex ids, "
                                 f"got {v.dtype} values such as {v.ravel()[:3].tolist()}", f)
        if v.size and (v.min() < 0 or v.max() >= n):
            raise InputError(f"malformed face data bundle: {key} index past the {n} vertices", f)
    for key in ("neutral", "expression_deltas", "identity_modes"):
        if key in a:  # (a deferred member is checked when it is read)
            _check_finite(a[key], key, f)


class _ReadOnFirstUse:
    """A :class:`FaceModel` field that may be given as a function (no arguments): called when the field is first
    read, its array kept (the identity modes, which a rig of the expressions never reads)."""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            raise AttributeError(self.name)  # no default: the dataclass field stays required
        value = obj.__dict__[self.name]
        if callable(value):
            value = value()
            obj.__dict__[self.name] = value
        return value

    def __set__(self, obj, value) -> None:  # (the frozen dataclass's __init__ only)
        obj.__dict__[self.name] = value


@dataclass(frozen=True)
class FaceModel:
    """A linear face model: neutral + identity modes + delta-blendshapes.

    ``V = neutral + sum_i a_i identity_modes[i] + sum_j w_j expression_deltas[j]``

    Units are the data's own (centimetres for ICT).

    Attributes
    ----------
    neutral : (n, 3) float64
        The generic neutral face.
    triangles : (m, 3) int64
        Triangles of the mesh.
    quads : (q, 4) int64
        The original quads.
    expression_names : tuple of B str
        ARKit-style blendshape names (``jawOpen``, ``eyeBlink_L``...).
    expression_deltas : (B, n, 3) float32
        Expression blendshapes as offsets from the neutral (kept compact).
    identity_names : tuple of I str
    identity_modes : (I, n, 3) float32
        Identity modes as offsets from the neutral (from a bundle: read when first used).
    landmarks : (68,) int64
        Vertex id of each Multi-PIE landmark.
    source : str
        The bundle's ``source`` note, if any.
    path : str
        The ``.npz`` it was loaded from (``""`` when not loaded from a file).
    """

    neutral: np.ndarray  # (n, 3) float64
    triangles: np.ndarray  # (m, 3) int64
    quads: np.ndarray  # (q, 4) int64
    expression_names: tuple[str, ...]
    expression_deltas: np.ndarray  # (B, n, 3) float32 (kept compact)
    identity_names: tuple[str, ...]
    identity_modes: np.ndarray = _ReadOnFirstUse()  # (I, n, 3) float32
    landmarks: np.ndarray  # (68,) int64 vertex ids (Multi-PIE order)
    source: str = ""
    path: str = ""

    @classmethod
    def from_bundle(cls, arrays: Mapping[str, np.ndarray]) -> "FaceModel":
        """A model from the arrays of :func:`load_bundle` or :func:`import_ict_folder`.

        The arrays are converted, not validated again (:func:`load_bundle`
        validates them): positions to float64, triangles, quads and landmark
        ids to int64, deltas and identity modes to float32, names to tuples of
        str. ``identity_modes`` may be a member of the bundle not read yet (:func:`load_face_model`'s):
        read when the model's identity modes are first used.

        Parameters
        ----------
        arrays : mapping of str to ndarray
            The keys of :data:`REQUIRED_KEYS`; optionally ``source`` and
            ``_path`` (the file, set by :func:`load_bundle`).

        Returns
        -------
        FaceModel
        """
        return cls(
            neutral=np.asarray(arrays["neutral"], dtype=np.float64),
            triangles=np.asarray(arrays["triangles"], dtype=np.int64),
            quads=np.asarray(arrays["quads"], dtype=np.int64),
            expression_names=tuple(str(s) for s in arrays["expression_names"]),
            expression_deltas=np.asarray(arrays["expression_deltas"], dtype=np.float32),
            identity_names=tuple(str(s) for s in arrays["identity_names"]),
            identity_modes=_as_float32(arrays["identity_modes"]),
            landmarks=np.asarray(arrays["landmarks_multipie68"], dtype=np.int64),
            source=str(arrays.get("source", "")),
            path=str(arrays.get("_path", "")),
        )

    # ----------------------------------------------------------------- sizes
    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n`` of the face mesh."""
        return self.neutral.shape[0]

    @property
    def n_expressions(self) -> int:
        """Number of expression blendshapes ``B``."""
        return len(self.expression_names)

    @property
    def n_identities(self) -> int:
        """Number of identity modes ``I``."""
        return len(self.identity_names)

    # ----------------------------------------------------------------- weights
    def expression_index(self, name: str) -> int:
        """Index of the expression called ``name`` (its row in ``expression_deltas``).

        Raises
        ------
        InputError
            ``name`` is not an expression of the model; the message lists the known names.
        """
        try:
            return self.expression_names.index(name)
        except ValueError:
            raise InputError(
                f"unknown expression {name!r}; known: {', '.join(self.expression_names)}"
            ) from None

    def expression_vector(self, expression: Mapping[str, float] | Sequence[float] | np.ndarray | None) -> np.ndarray:
        """Named weights (``{"jawOpen": 0.7}``) or a full ``(B,)`` vector -> ``(B,)`` float64."""
        w = np.zeros(self.n_expressions)
        if expression is None:
            return w
        if isinstance(expression, Mapping):
            for name, value in expression.items():
                value = float(value)
                if not np.isfinite(value):
                    raise InputError(f"expression weight for {name!r} is NaN or inf")
                w[self.expression_index(name)] = value
            return w
        e = np.asarray(expression, dtype=np.float64)
        if e.shape != (self.n_expressions,):
            raise InputError(f"expression weights must have shape ({self.n_expressions},), got {e.shape}")
        if not np.all(np.isfinite(e)):
            raise InputError("expression weights contain NaN or inf")
        return e

    def identity_vector(self, identity: Sequence[float] | np.ndarray | None) -> np.ndarray:
        """``None`` (the generic face) or up to ``I`` leading coefficients -> ``(I,)`` float64."""
        a = np.zeros(self.n_identities)
        if identity is None:
            return a
        c = np.asarray(identity, dtype=np.float64).ravel()
        if c.size > self.n_identities:
            raise InputError(f"at most {self.n_identities} identity coefficients, got {c.size}")
        if not np.all(np.isfinite(c)):
            raise InputError("identity coefficients contain NaN or inf")
        a[: c.size] = c
        return a

    def random_identity(self, rng: np.random.Generator | int | None = None, scale: float = 1.0) -> np.ndarray:
        """Identity coefficients ~ N(0, scale^2), seeded."""
        rng = np.random.default_rng(rng)
        return scale * rng.standard_normal(self.n_identities)

    # ----------------------------------------------------------------- faces
    def identity_neutral(self, identity=None) -> np.ndarray:
        """The neutral face of an identity, ``(n, 3)`` float64."""
        a = self.identity_vector(identity)
        V = self.neutral.copy()
        nz = np.flatnonzero(a)
        if nz.size:
            V += np.tensordot(a[nz], self.identity_modes[nz].astype(np.float64), axes=1)
        return V

    def face(self, identity=None, expression=None) -> np.ndarray:
        """A face from identity coefficients and expression weights, ``(n, 3)`` float64."""
        V = self.identity_neutral(identity)
        w = self.expression_vector(expression)
        nz = np.flatnonzero(w)
        if nz.size:
            V += np.tensordot(w[nz], self.expression_deltas[nz].astype(np.float64), axes=1)
        return V

    def landmark_positions(self, vertices: np.ndarray) -> np.ndarray:
        """The 68 landmark positions of a face ``(n, 3)`` -> ``(68, 3)``."""
        return np.asarray(vertices)[self.landmarks]

    def summary(self) -> dict:
        """What ``facegeom info`` prints about the model.

        Returns
        -------
        dict
            ``path``; the counts ``vertices``, ``triangles``, ``quads``,
            ``expressions``, ``identities``, ``landmarks``; and
            ``"bounding box (cm)"``: the neutral face's extent along x, y, z,
            rounded to 0.01.
        """
        lo = self.neutral.min(axis=0)
        hi = self.neutral.max(axis=0)
        return {
            "path": self.path,
            "vertices": self.n_vertices,
            "triangles": int(self.triangles.shape[0]),
            "quads": int(self.quads.shape[0]),
            "expressions": self.n_expressions,
            "identities": self.n_identities,
            "landmarks": int(self.landmarks.size),
            "bounding box (cm)": [round(float(x), 2) for x in (hi - lo)],
        }


def _as_float32(a):
    """An array as float32; a bundle member not read yet: one that reads it as float32."""
    if isinstance(a, _BundleMember):
        return replace(a, dtype=np.float32)
    return np.asarray(a, dtype=np.float32)


def load_face_model(path: str | os.PathLike | None = None) -> FaceModel:
    """Locate, load and validate the bundle, as a :class:`FaceModel`.

    The identity modes (the bundle's largest member) are read and checked when first used: a rig of the
    expressions (:meth:`~facegeom.model.rig.BlendshapeRig.from_face_model`) does not read them.
    """
    return FaceModel.from_bundle(_read_bundle(path, deferred=("identity_modes",)))


# --------------------------------------------------------------------------- ICT folder importer


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", path) from None


def read_obj_positions(path: str | os.PathLike) -> np.ndarray:
    """The ``v`` lines of an OBJ as ``(n, 3)`` float64, read by the validating OBJ reader (faces ignored).

    Raises
    ------
    InputError
        Missing or unreadable file, malformed ``v`` line, NaN/inf, no vertex.
    """
    path = Path(path)
    from facegeom.io.formats.common import read_file_bytes
    from facegeom.io.formats.obj import read_obj

    V = read_obj(path, read_file_bytes(path), faces=False).vertices
    if V.shape[0] == 0:
        raise InputError("no vertex ('v') lines: not an OBJ mesh", path)
    return V


def read_obj_polygons(path: str | os.PathLike) -> list[list[int]]:
    """The ``f`` lines of an OBJ as 0-based vertex-id lists (every corner form; indices checked).

    Raises
    ------
    InputError
        As :func:`read_obj_positions`, and faces with fewer than 3 corners or indices out of range.
    """
    path = Path(path)
    from facegeom.io.formats.common import read_file_bytes
    from facegeom.io.formats.obj import read_obj

    return [q.tolist() for q in read_obj(path, read_file_bytes(path)).polygons()]


def import_ict_folder(folder: str | os.PathLike, n_face_vertices: int = 9409, n_face_polygons: int = 9230,
                      expressions: Sequence[str] | None = None,
                      identities: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """Read the original ICT-FaceKit layout into the bundle's arrays.

    Parameters
    ----------
    folder : path
        Holds ``generic_neutral_mesh.obj``, ``vertex_indices.json``, one OBJ per
        expression (``jawOpen.obj`` ...) and per identity mode (``identity000.obj`` ...).
    n_face_vertices, n_face_polygons : int
        The face region: the first vertices and polygons of the full head.
    expressions, identities : sequence of str, optional
        Which shapes to read; default: the expressions listed in
        ``vertex_indices.json`` and the ``identity*.obj`` files present.
        A listed expression whose OBJ is missing is skipped (the light bundle
        ships only a few); a name given explicitly must exist.

    Returns
    -------
    dict with the keys of :data:`REQUIRED_KEYS` (deltas as float32, like the bundle).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("not a folder", folder)
    neutral_path = folder / "generic_neutral_mesh.obj"
    index_path = folder / "vertex_indices.json"
    full_neutral = read_obj_positions(neutral_path)
    polys = read_obj_polygons(neutral_path)
    try:
        meta = json.loads(_read_text(index_path))
    except json.JSONDecodeError as exc:
        raise InputError(f"malformed JSON ({exc.msg} at line {exc.lineno})", index_path) from None
    if "idx_to_landmark_verts" not in meta:
        raise InputError("lacks the key 'idx_to_landmark_verts'", index_path)
    if full_neutral.shape[0] < n_face_vertices or len(polys) < n_face_polygons:
        raise InputError(
            f"has {full_neutral.shape[0]} vertices and {len(polys)} polygons, fewer than the face region "
            f"({n_face_vertices}, {n_face_polygons})", neutral_path)
    face_polys = polys[:n_face_polygons]
    if any(len(p) != 4 for p in face_polys):
        raise InputError("the face region is expected to hold quads only", neutral_path)
    quads = np.array(face_polys, dtype=np.int64)
    if quads.max() >= n_face_vertices:
        raise InputError("a face polygon uses a vertex outside the face region", neutral_path)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
    neutral = full_neutral[:n_face_vertices]

    def delta(name: str) -> np.ndarray:
        p = folder / f"{name}.obj"
        V = read_obj_positions(p)
        if V.shape[0] != full_neutral.shape[0]:
            raise InputError(f"has {V.shape[0]} vertices, the neutral {full_neutral.shape[0]}", p)
        return (V[:n_face_vertices] - neutral).astype(np.float32)

    if expressions is None:
        expressions = [e for e in meta.get("expressions", []) if (folder / f"{e}.obj").is_file()]
    if identities is None:
        identities = sorted(p.stem for p in folder.glob("identity*.obj"))
    exp = np.stack([delta(e) for e in expressions]) if expressions else np.zeros((0, n_face_vertices, 3), np.float32)
    ids = np.stack([delta(i) for i in identities]) if identities else np.zeros((0, n_face_vertices, 3), np.float32)
    return {
        "neutral": neutral.astype(np.float32),
        "quads": quads.astype(np.int32),
        "triangles": triangles.astype(np.int32),
        "expression_names": np.array(list(expressions)),
        "expression_deltas": exp,
        "identity_names": np.array(list(identities)),
        "identity_modes": ids,
        "landmarks_multipie68": np.asarray(meta["idx_to_landmark_verts"], dtype=np.int32),
    }


TAKES_ENV_VAR = "FACEGEOM_TAKES"


def default_takes_path() -> Path:
    """``../shared/data/arkit-takes`` next to the repository root."""
    return REPO_ROOT.parent / "shared" / "data" / "arkit-takes"


def takes_cache_folder() -> Path:
    """Where ``facegeom data fetch`` puts the public real take (and its licence): ``arkit-takes/`` in the cache."""
    return cache_folder() / "arkit-takes"


def _holds_takes(folder: Path) -> bool:
    return folder.is_dir() and any(f.suffix.lower() == ".csv" and f.is_file() for f in folder.iterdir())


def takes_places(path: str | os.PathLike | None = None) -> list[tuple[str, Path | None, bool]]:
    """The places of the takes lookup, in order: ``(what, where, found)``.

    ``where`` is None when the place does not apply (no path given, variable
    not set, not running from a repository checkout); ``found`` says whether a
    take is there (a ``.csv`` file, or a folder holding one).
    """
    env = os.environ.get(TAKES_ENV_VAR)
    places = [
        ("the path argument", None if path is None else Path(path)),
        (f"${TAKES_ENV_VAR}", Path(env) if env else None),
        ("the development folder", default_takes_path() if _in_repository() else None),
        ("the user cache", takes_cache_folder()),
    ]
    return [(what, where, where is not None and (where.is_file() or _holds_takes(where))) for what, where in places]


def locate_takes(path: str | os.PathLike | None = None) -> Path:
    """Folder of ARKit take CSVs (or one take file).

    Looked for at ``path``, else ``$FACEGEOM_TAKES``, else ``../shared/data/arkit-takes``
    (a repository checkout only), else the user cache, where ``facegeom data fetch``
    puts one public real take.

    Raises
    ------
    DataNotFoundError
        Naming the places that were looked at and how to get a take.
    """
    if path is not None:
        p = Path(path)
        if p.is_dir() or p.is_file():
            return p
        raise DataNotFoundError(f"takes not found at the given path {path} (expected a folder of .csv takes)")
    places = takes_places()
    for _, where, found in places[1:]:
        if found:
            return where
    env = os.environ.get(TAKES_ENV_VAR)
    tried = [f"${TAKES_ENV_VAR}={env}" if env else f"${TAKES_ENV_VAR} (not set)"]
    tried += [str(where) for what, where, _ in places[2:] if where is not None]
    raise TakesNotFoundError(
        "ARKit takes not found; looked at: the path argument (not given), " + ", ".join(tried)
        + ". Run `facegeom data fetch` (it downloads one public Live Link Face take, 3.3 MB), "
        + f"or Pass path=PATH or set {TAKES_ENV_VAR}"
    )
