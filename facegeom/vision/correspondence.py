"""MediaPipe's 468 face-mesh points on the face model, and the 68 landmarks from the 468 points.

MediaPipe's face-mesh model puts 468 points on a face; point ``i`` is vertex
``i`` of MediaPipe's canonical face mesh (``data/canonical_face_model.obj``,
Apache-2.0, see ``data/NOTICE-mediapipe.md``). This module reads two maps,
made once by ``data/mediapipe_map/make_map.py`` in the repository and shipped
in ``data/``:

- :func:`mediapipe_map` -- every one of the 468 points as a point on the face
  model's surface: a triangle of the face model and barycentric coordinates
  in it. :meth:`MediaPipeMap.points` evaluates it on any mesh with the face
  model's topology (the neutral, a fitted identity, an animated frame), which
  is what a fit of the face model to detected points compares against;
- :func:`landmarks68_map` / :func:`landmarks68_from_mesh_points` -- each of the
  68 iBUG / Multi-PIE landmarks of the face model as a point on a triangle of
  MediaPipe's mesh, so detected 468 points (2-D pixels or 3-D) give the 68
  landmarks the rest of facegeom works with.

How the maps were made (the script's docstring has the details and the
measured numbers): the canonical mesh is put on the face model's neutral by a
similarity transform from twelve hand-matched points (eye and mouth corners,
nose, chin, lip mid-points), then deformed smoothly (a Laplacian-regularised
closest-point ICP, with the eyelid, lip and brow contours of both sets tied to
each other) until its surface lies on the neutral's; each registered point is
then snapped to the closest point of the neutral's triangles. The reverse map
puts each of the 68 landmarks on the registered canonical mesh: the eye and
lip landmarks on the matching MediaPipe eyelid or lip contour (so a blink or an
open mouth moves them with the right lid or lip), the others on the closest
point of the mesh. The jaw contour (landmarks 0-16) is an outline in a photo
rather than fixed points on the face, so its 17 entries are approximate: the
face model's jaw vertices lie within 0.1 cm of MediaPipe's mesh, but 0 and 16
(at the ears) are 0.24 cm beyond its outline (the file's header lists them).

A shipped file that does not parse or fails its checks is a bug (or a damaged
install) and raises :class:`MapFileError`.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from facegeom.errors import FacegeomError, InputError
from facegeom.io.formats.common import read_file_bytes
from facegeom.io.formats.obj import read_obj

__all__ = [
    "CANONICAL_OBJ",
    "LANDMARKS68_FILE",
    "MEDIAPIPE_FILE",
    "N_MESH_POINTS",
    "Landmarks68Map",
    "MapFileError",
    "MediaPipeMap",
    "canonical_mesh",
    "landmarks68_from_mesh_points",
    "landmarks68_map",
    "mediapipe_map",
    "point_noise",
]

DATA = Path(__file__).resolve().parent / "data"
CANONICAL_OBJ = DATA / "canonical_face_model.obj"
MEDIAPIPE_FILE = DATA / "mediapipe_to_face_model.csv"
LANDMARKS68_FILE = DATA / "landmarks68_on_mediapipe.csv"
POINT_NOISE_FILE = DATA / "mediapipe_point_noise.csv"
N_MESH_POINTS = 468  # the face-mesh model's points (478 with the iris refinement: the first 468 are these)
N_CANONICAL_TRIANGLES = 898
MEDIAPIPE_COLUMNS = ("point", "triangle", "b0", "b1", "b2", "distance_cm")
LANDMARKS68_COLUMNS = ("landmark", "mp_triangle_a", "mp_triangle_b", "mp_triangle_c", "b0", "b1", "b2", "distance_cm")
BARY_SUM_TOL = 1e-6  # the files hold barycentric coordinates to 10 decimals
BARY_MIN = -1e-9


class MapFileError(FacegeomError, ValueError):
    """A map file is malformed or fails its checks; for a shipped file, a bug or a damaged install.

    Parameters
    ----------
    path : str or os.PathLike
        The file, named first in the message.
    message : str
        What is wrong.
    """

    def __init__(self, path, message: str):
        super().__init__(f"{path}: {message} (the file is made by data/mediapipe_map/make_map.py in the "
                         "facegeom repository; a shipped file failing this is a bug or a damaged install)")


def _read_only(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@cache
def canonical_mesh() -> tuple[np.ndarray, np.ndarray]:
    """MediaPipe's canonical face mesh: vertex ``i`` is point ``i`` of the face-mesh model.

    Returns
    -------
    vertices : (468, 3) float64, read-only
        Centimetres, +x the subject's left, +y up, +z towards the viewer.
    triangles : (898, 3) int64, read-only
        The mesh's triangles (0-based); the eyes and the mouth are closed by
        triangles between the lid / inner-lip contour points.

    Raises
    ------
    MapFileError
        The shipped OBJ does not have 468 vertices and 898 triangles.
    """
    try:
        mesh = read_obj(CANONICAL_OBJ, read_file_bytes(CANONICAL_OBJ))
    except InputError as exc:
        raise MapFileError(CANONICAL_OBJ, exc.reason) from None
    if mesh.vertices.shape != (N_MESH_POINTS, 3) or mesh.n_faces != N_CANONICAL_TRIANGLES or not (mesh.sizes == 3).all():
        raise MapFileError(CANONICAL_OBJ, f"expected {N_MESH_POINTS} vertices and {N_CANONICAL_TRIANGLES} triangles, "
                                          f"got {mesh.vertices.shape[0]} vertices and {mesh.n_faces} faces")
    return _read_only(mesh.vertices.astype(np.float64)), _read_only(mesh.triangles().astype(np.int64))


def _read_table(path: Path, columns: tuple[str, ...], rows: int) -> np.ndarray:
    """The numeric rows of a map CSV (``#`` comment lines first, then the header), as ``(rows, len(columns))``."""
    try:
        text = read_file_bytes(Path(path)).decode("utf-8")
    except InputError as exc:
        raise MapFileError(path, exc.reason) from None
    except UnicodeDecodeError:
        raise MapFileError(path, "not UTF-8 text") from None
    lines = [ln.strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    if not lines or tuple(c.strip() for c in lines[0].split(",")) != columns:
        raise MapFileError(path, f"the header row must be {','.join(columns)}")
    body = lines[1:]
    if len(body) != rows:
        raise MapFileError(path, f"expected {rows} data rows, got {len(body)}")
    out = np.empty((rows, len(columns)), dtype=np.float64)
    for r, line in enumerate(body):
        cells = line.split(",")
        if len(cells) != len(columns):
            raise MapFileError(path, f"data row {r} has {len(cells)} cells, expected {len(columns)}")
        try:
            out[r] = [float(c) for c in cells]
        except ValueError:
            raise MapFileError(path, f"data row {r} has a cell that is not a number") from None
    if not np.isfinite(out).all():
        raise MapFileError(path, "NaN or inf in the data")
    return out


def _integers(path, values: np.ndarray, name: str) -> np.ndarray:
    if (values != np.round(values)).any() or (values < 0).any():
        raise MapFileError(path, f"column {name} must hold non-negative integers")
    return values.astype(np.int64)


def _check_bary(path, bary: np.ndarray) -> np.ndarray:
    if (bary < BARY_MIN).any():
        raise MapFileError(path, "a barycentric coordinate is negative")
    if (np.abs(bary.sum(axis=1) - 1.0) > BARY_SUM_TOL).any():
        raise MapFileError(path, "barycentric coordinates do not sum to 1")
    bary = np.clip(bary, 0.0, None)
    return bary / bary.sum(axis=1, keepdims=True)


@dataclass(frozen=True)
class MediaPipeMap:
    """The 468 MediaPipe points as points on the face model's triangles.

    Attributes
    ----------
    triangle : (468,) int64
        Row of the face model's ``triangles`` that point ``i`` lies on.
    bary : (468, 3) float64
        Barycentric coordinates in that triangle (non-negative, rows sum to 1),
        in the order of the triangle's corners.
    distance : (468,) float64
        How far (cm) the registered canonical point was from the neutral's
        surface before it was snapped onto it.
    """

    triangle: np.ndarray
    bary: np.ndarray
    distance: np.ndarray

    def vertex_ids(self, triangles) -> np.ndarray:
        """The face-model vertex ids of each point's triangle.

        Parameters
        ----------
        triangles : (m, 3) int array
            The face model's triangles (``FaceModel.triangles``).

        Returns
        -------
        (468, 3) int64

        Raises
        ------
        InputError
            ``triangles`` is not ``(m, 3)`` or has fewer rows than the map needs.
        """
        T = np.asarray(triangles)
        if T.ndim != 2 or T.shape[1] != 3 or not np.issubdtype(T.dtype, np.integer):
            raise InputError(f"triangles must be an (m, 3) integer array, got {T.shape} {T.dtype}")
        if T.shape[0] <= int(self.triangle.max()):
            raise InputError(f"the map needs the face model's triangles (at least {int(self.triangle.max()) + 1} "
                             f"rows), got {T.shape[0]}")
        return T[self.triangle].astype(np.int64)

    def points(self, vertices, triangles) -> np.ndarray:
        """The 468 points on a mesh with the face model's topology.

        Parameters
        ----------
        vertices : (n, 3) or (T, n, 3) float array
            One mesh, or ``T`` meshes (an animation), with the face model's
            vertex order (``FaceModel.neutral`` and anything built from it).
        triangles : (m, 3) int array
            The face model's triangles (``FaceModel.triangles``).

        Returns
        -------
        (468, 3) or (T, 468, 3) float64

        Raises
        ------
        InputError
            Wrong shapes, or a triangle's vertex beyond ``n``.
        """
        C = self.vertex_ids(triangles)
        V = np.asarray(vertices, dtype=np.float64)
        if V.ndim not in (2, 3) or V.shape[-1] != 3:
            raise InputError(f"vertices must be (n, 3) or (T, n, 3), got {V.shape}")
        if V.shape[-2] <= int(C.max()):
            raise InputError(f"vertices has {V.shape[-2]} rows; the map's triangles use vertex {int(C.max())}")
        return np.einsum("pk,...pkd->...pd", self.bary, V[..., C, :])


@dataclass(frozen=True)
class Landmarks68Map:
    """The 68 iBUG / Multi-PIE landmarks as points on triangles of MediaPipe's canonical mesh.

    Attributes
    ----------
    corners : (68, 3) int64
        The MediaPipe point ids (0-467) of each landmark's triangle.
    bary : (68, 3) float64
        Barycentric coordinates (non-negative, rows sum to 1): landmark ``k`` is
        ``sum_j bary[k, j] * P[corners[k, j]]`` for MediaPipe points ``P``.
    distance : (68,) float64
        How far (cm) the face model's landmark vertex was from the registered
        canonical mesh (from its contour, for the eye and lip landmarks);
        the jaw contour 0-16 lies partly beyond the mesh.
    """

    corners: np.ndarray
    bary: np.ndarray
    distance: np.ndarray

    def points(self, P) -> np.ndarray:
        """The 68 landmarks from MediaPipe points.

        Parameters
        ----------
        P : (..., 468, d) or (..., 478, d) float array
            Points of the face-mesh model in any coordinates (pixels, ``d = 2``;
            3-D, ``d = 3``), any leading batch shape; with the iris
            refinement's 478 points the first 468 are used.

        Returns
        -------
        (..., 68, d) float64

        Raises
        ------
        InputError
            ``P`` has fewer than 2 dimensions or not 468 / 478 points.
        """
        X = np.asarray(P, dtype=np.float64)
        if X.ndim < 2 or X.shape[-2] not in (N_MESH_POINTS, N_MESH_POINTS + 10):
            raise InputError(f"expected MediaPipe points of shape (..., 468, d) or (..., 478, d), got {X.shape}")
        return np.einsum("lk,...lkd->...ld", self.bary, X[..., self.corners, :])


def _load_mediapipe_map(path: Path) -> MediaPipeMap:
    t = _read_table(path, MEDIAPIPE_COLUMNS, N_MESH_POINTS)
    if not (t[:, 0] == np.arange(N_MESH_POINTS)).all():
        raise MapFileError(path, "column point must list 0 ... 467 in order")
    if (t[:, 5] < 0).any():
        raise MapFileError(path, "a distance is negative")
    return MediaPipeMap(triangle=_read_only(_integers(path, t[:, 1], "triangle")),
                        bary=_read_only(_check_bary(path, t[:, 2:5])), distance=_read_only(t[:, 5].copy()))


def _load_landmarks68_map(path: Path) -> Landmarks68Map:
    t = _read_table(path, LANDMARKS68_COLUMNS, 68)
    if not (t[:, 0] == np.arange(68)).all():
        raise MapFileError(path, "column landmark must list 0 ... 67 in order")
    corners = _integers(path, t[:, 1:4], "mp_triangle_*")
    if (corners >= N_MESH_POINTS).any():
        raise MapFileError(path, f"a MediaPipe point id is not below {N_MESH_POINTS}")
    faces = {tuple(f) for f in canonical_mesh()[1].tolist()}
    if any(tuple(c) not in faces for c in corners.tolist()):
        raise MapFileError(path, "a row's mp_triangle_a/b/c is not a triangle of the canonical mesh")
    if (t[:, 7] < 0).any():
        raise MapFileError(path, "a distance is negative")
    return Landmarks68Map(corners=_read_only(corners), bary=_read_only(_check_bary(path, t[:, 4:7])),
                          distance=_read_only(t[:, 7].copy()))


@cache
def _shipped(kind: str):
    return _load_mediapipe_map(MEDIAPIPE_FILE) if kind == "mediapipe" else _load_landmarks68_map(LANDMARKS68_FILE)


def mediapipe_map(path=None) -> MediaPipeMap:
    """The map of MediaPipe's 468 points onto the face model (the shipped one is read once, then cached).

    Parameters
    ----------
    path : str or os.PathLike, optional
        Another file in the same format (``make_map.py --out``); default the shipped one.

    Returns
    -------
    MediaPipeMap

    Raises
    ------
    MapFileError
        The file is missing, malformed or fails its checks.

    Examples
    --------
    >>> from facegeom.model.face import load_face_model          # doctest: +SKIP
    >>> m = load_face_model()                                     # doctest: +SKIP
    >>> mediapipe_map().points(m.neutral, m.triangles).shape      # doctest: +SKIP
    (468, 3)
    """
    return _shipped("mediapipe") if path is None else _load_mediapipe_map(Path(path))


def landmarks68_map(path=None) -> Landmarks68Map:
    """The map of the 68 landmarks onto MediaPipe's mesh (the shipped one is read once, then cached).

    Parameters
    ----------
    path : str or os.PathLike, optional
        Another file in the same format (``make_map.py --out``); default the shipped one.

    Returns
    -------
    Landmarks68Map

    Raises
    ------
    MapFileError
        The file is missing, malformed or fails its checks.
    """
    return _shipped("landmarks68") if path is None else _load_landmarks68_map(Path(path))


@cache
def point_noise() -> np.ndarray:
    """How far the face-mesh model puts each of its 468 points from where :func:`mediapipe_map` puts it,
    ``(468,)``: the root mean square error per coordinate, as a fraction of the face's outer-eye-corner distance.

    Measured on rendered faces of known geometry by ``data/mediapipe_map/measure_point_noise.py`` (its docstring
    says how); a point on a sharp feature is placed to 2-3 %, one on the smooth cheek to 7-10 %.
    """
    t = _read_table(POINT_NOISE_FILE, ("point", "sd"), N_MESH_POINTS)
    if not (t[:, 0] == np.arange(N_MESH_POINTS)).all():
        raise MapFileError(POINT_NOISE_FILE, "column point must list 0 ... 467 in order")
    if not (t[:, 1] > 0).all():
        raise MapFileError(POINT_NOISE_FILE, "a point's sd is not positive")
    return _read_only(t[:, 1].copy())


def landmarks68_from_mesh_points(P) -> np.ndarray:
    """The 68 iBUG / Multi-PIE landmarks from detected MediaPipe points.

    Parameters
    ----------
    P : (..., 468, d) or (..., 478, d) float array
        The face-mesh model's points (pixels or 3-D; any batch shape in front).

    Returns
    -------
    (..., 68, d) float64
        Landmarks in the order of :attr:`facegeom.model.face.FaceModel.landmarks`.
        The jaw contour 0-16 is approximate: see :class:`Landmarks68Map`.

    Raises
    ------
    InputError
        ``P`` has the wrong shape.
    MapFileError
        The shipped file is broken.
    """
    return landmarks68_map().points(P)
