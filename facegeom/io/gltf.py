"""glTF 2.0: blendshape rigs and vertex sequences out as ``.glb``; blendshape rigs in from ``.glb`` / ``.gltf``.

Both writers build the document with pygltflib and write one ``.glb`` atomically:

* one mesh (triangles, ``uint32`` indices; ``float32`` positions and unit
  normals), its morph targets as ``POSITION`` deltas, their names in
  ``mesh.extras.targetNames`` (the convention Blender, three.js and Babylon.js
  read) and zero default weights;
* one node and one scene holding the mesh;
* one animation with a single ``LINEAR`` sampler driving the node's
  ``weights``: keyframe ``t`` at ``t / fps`` seconds; the frame rate is also
  kept in the animation's ``extras.fps``.

:func:`write_sequence_glb` turns a driven vertex sequence into such a rig: the
mean frame is the base mesh and a truncated SVD of the frames minus the mean
gives the morph targets and their weights. The number of targets ``K`` is the
smallest that keeps every vertex of every frame within ``tolerance`` of the
input (measured after rounding to float32, as the file stores it).

:func:`read_glb_animation` reads such files back (and other ``.glb`` files
with one morphed triangle mesh and a weights animation) for tests and the
viewer.

:func:`read_gltf_rig` reads a user's rig (``.glb``, or ``.gltf`` with external
or data-URI buffers; Ready Player Me / VRM avatars, Blender or Maya exports,
three.js assets, this module's own files) as one :class:`GltfRig`: every mesh
the default scene places, with its node's world transform, in one vertex array
whose :class:`RigPart` slices are named; morph targets are matched across
meshes by name. Every accessor's size is checked against its buffer, and the
rig's size against the file's, before anything is allocated. Draco-compressed
primitives are decoded by the optional ``DracoPy`` package; meshopt-compressed
buffers are refused with the command that writes an uncompressed copy.

Hostile files: both readers parse the JSON with ``json.loads`` and check it
before pygltflib builds its objects (0.2-0.7 ms each): counts no character
needs (:data:`MAX_NODES`, :data:`MAX_ACCESSORS`, :data:`MAX_MORPH_TARGETS` and
the others below, each with its reason) and ``extensionsRequired`` they cannot
honour are refused in one line naming the file. The morph targets' offsets are
bounded by the file's size and by :func:`facegeom.io.npzcheck.memory_budget`
before they are allocated (every target may name the same data). A buffer
file must be a regular file in the document's folder (a named pipe would make
the read wait forever).
"""
from __future__ import annotations

import base64
import binascii
import json
import os
import re
import struct
import time
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from urllib.parse import unquote

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path
from facegeom.io.frames import FrameSource
from facegeom.io.npzcheck import memory_budget

__all__ = ["GlbAnimation", "GltfRig", "RigPart", "write_rig_glb", "write_sequence_glb", "read_glb_animation",
           "read_gltf_rig", "DEFAULT_TOLERANCE"]

#: Default bound of :func:`write_sequence_glb`: 0.01 mesh units, 0.1 mm on the ICT face (in cm).
DEFAULT_TOLERANCE = 0.01
#: Default ``hold_bytes`` of :func:`write_sequence_glb`: a frame source whose frames fit in 1 GiB of float32 is
#: driven once and kept.
HOLD_BYTES = 2 ** 30

_FLOAT, _UINT, _USHORT, _UBYTE = 5126, 5125, 5123, 5121
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {_FLOAT: np.float32, _UINT: np.uint32, _USHORT: np.uint16, _UBYTE: np.uint8}
_BYTE, _SHORT = 5120, 5122
_ANY_DTYPES = {**_DTYPES, _BYTE: np.int8, _SHORT: np.int16}
_ANY_COMPONENTS = {**_COMPONENTS, "MAT4": 16}
_INDEX_DTYPES = {_UBYTE: np.uint8, _USHORT: np.uint16, _UINT: np.uint32}
#: int -> float for ``normalized`` accessors (glTF 2.0, "Animations"): signed ``max(c / m, -1)``, unsigned ``c / m``.
_NORMALIZED = {_BYTE: 127.0, _UBYTE: 255.0, _SHORT: 32767.0, _USHORT: 65535.0}


@dataclass
class GlbAnimation:
    """A morphed mesh and its weights animation, as read from a ``.glb``.

    Attributes
    ----------
    neutral : (n, 3) float64
        Base vertex positions.
    faces : (m, 3) int64
        Triangles.
    deltas : (K, n, 3) float64
        Morph-target position offsets.
    names : tuple of K str
        Target names (``mesh.extras.targetNames``; ``target{k}`` when absent).
    times : (T,) float64
        Keyframe times in seconds.
    weights : (T, K) float64
        Target weights at each keyframe.
    fps : float or None
        ``extras.fps`` of the animation, else ``1 / median`` keyframe step,
        ``None`` for a single keyframe.
    path : str
        The file read.
    """

    neutral: np.ndarray
    faces: np.ndarray
    deltas: np.ndarray
    names: tuple[str, ...]
    times: np.ndarray
    weights: np.ndarray
    fps: float | None
    path: str = ""
    rotations: np.ndarray | None = None
    """``(T, 3, 3)`` the mesh node's animated rotation at each keyframe of the weights, or None."""
    translations: np.ndarray | None = None
    """``(T, 3)`` its animated translation (zeros when only the rotation is animated), or None."""

    def frames(self, motion: bool = False) -> np.ndarray:
        """``(T, n, 3)`` vertex positions at each keyframe: neutral + weights @ deltas (with ``motion``, turned
        and moved by the node's animation when there is one)."""
        K, n = self.deltas.shape[:2]
        X = self.neutral + (self.weights @ self.deltas.reshape(K, 3 * n)).reshape(-1, n, 3)
        if motion and self.rotations is not None:
            X = np.einsum("tij,tvj->tvi", self.rotations, X) + self.translations[:, None]
        return X


# ----------------------------------------------------------------------------- checks


def _mesh_arrays(path, neutral, faces) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(neutral, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 3:
        raise InputError(f"vertices must have shape (n, 3) with n >= 3, got {V.shape}", path)
    if not np.isfinite(V).all():
        raise InputError("vertices contain NaN or inf", path)
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or not np.issubdtype(F.dtype, np.integer):
        raise InputError(f"faces must be integer triangles (m, 3), got {F.dtype} {F.shape}", path)
    if F.min() < 0 or F.max() >= V.shape[0]:
        raise InputError(f"faces index vertices outside 0..{V.shape[0] - 1}", path)
    return V, F.astype(np.uint32)


def _check_fps(path, fps) -> float:
    try:
        fps = float(fps)
    except (TypeError, ValueError):
        raise InputError(f"frame rate {fps!r} is not a number", path) from None
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"frame rate {fps} is not a positive number", path)
    return fps


def _vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (libigl); +z for vertices on no (non-degenerate) triangle."""
    import igl

    N = igl.per_vertex_normals(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                               igl.PerVertexNormalsWeightingType.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)
    bad = ~np.isfinite(N).all(axis=1) | (np.linalg.norm(N, axis=1) < 0.5)
    N[bad] = (0.0, 0.0, 1.0)
    return N.astype(np.float32)


# ----------------------------------------------------------------------------- writing


class _Blob:
    """A growing binary buffer of 4-byte-aligned buffer views and their accessors.

    The views' data is kept as the arrays given (:meth:`add`) or made when the file is written
    (:meth:`add_later`), and :meth:`write` writes it straight to the file: the buffer is never held as one
    ``bytes`` (nor copied by pygltflib)."""

    def __init__(self, pygltflib):
        self.g = pygltflib
        self.parts: list = []  # (array, or a callable giving the arrays in order, padding)
        self.size = 0
        self.views: list = []
        self.accessors: list = []

    def add(self, array: np.ndarray, kind: str, component: int, target: int | None = None,
            bounds: bool = False) -> int:
        data = np.ascontiguousarray(array)
        return self._view(data, data.nbytes, int(array.shape[0]), kind, component, target,
                          _bounds(array) if bounds else None)

    def add_later(self, make, nbytes: int, count: int, kind: str, component: int, target: int | None = None,
                  bounds: tuple[list, list] | None = None) -> int:
        """A view of ``nbytes`` whose data ``make()`` gives when the file is written: an iterable of arrays
        (the views are made in their order, each once)."""
        return self._view(make, int(nbytes), count, kind, component, target, bounds)

    def _view(self, data, nbytes: int, count: int, kind: str, component: int, target, bounds) -> int:
        self.views.append(self.g.BufferView(buffer=0, byteOffset=self.size, byteLength=nbytes, target=target))
        pad = -nbytes % 4
        self.parts.append((data, nbytes, pad))
        self.size += nbytes + pad
        acc = self.g.Accessor(bufferView=len(self.views) - 1, byteOffset=0, componentType=component,
                              count=count, type=kind)
        if bounds is not None:
            acc.min, acc.max = bounds
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def write(self, fh) -> None:
        """The buffer's bytes to the binary file ``fh``."""
        for data, nbytes, pad in self.parts:
            written = 0
            for a in ((data,) if isinstance(data, np.ndarray) else data()):
                a = np.ascontiguousarray(a)
                fh.write(memoryview(a).cast("B") if a.nbytes else b"")
                written += a.nbytes
            if written != nbytes:  # pragma: no cover - the views' sizes are stated before the data is made
                raise RuntimeError(f"a glTF buffer view has {written} bytes where {nbytes} were stated")
            fh.write(b"\0" * pad)


def _bounds(array: np.ndarray) -> tuple[list, list]:
    """An accessor's ``min`` and ``max``: per component, as Python floats (a component's values side by side:
    ``min(axis=0)`` of ``(n, 3)`` goes a row of 3 at a time, 15 times slower)."""
    cols = np.ascontiguousarray(array.reshape(array.shape[0], -1).T)
    return [float(x) for x in cols.min(axis=1)], [float(x) for x in cols.max(axis=1)]


def _save_glb(doc, blob: _Blob, fh) -> None:
    """Write ``doc`` with ``blob`` as its binary chunk to ``fh``: the bytes ``doc.save_to_bytes()`` gives (its JSON,
    padding and header), the binary chunk written a view at a time."""
    import pygltflib as g

    text = doc.gltf_to_json(separators=(",", ":"), indent=None).encode("utf-8")
    text += b" " * (-(12 + len(text)) % doc.required_alignment())
    fh.write(g.MAGIC + struct.pack("<II", g.GLTF_VERSION, 12 + 8 + len(text) + 8 + blob.size))
    fh.write(struct.pack("<I", len(text)) + g.JSON.encode("utf-8") + text)
    fh.write(struct.pack("<I", blob.size) + g.BIN.encode("utf-8"))
    blob.write(fh)


#: Poses whose normals :func:`_many_vertex_normals` computes at a time: its working memory is about
#: ``80 * POSES * triangles`` bytes (50 MB for 4 poses of a 150,000-triangle head); more are no faster.
_NORMAL_POSES = 4
#: Triangles whose cross products are made at a time (the temporaries of a block stay in the cache).
_FACE_BLOCK = 4096


def _face_sums(F: np.ndarray, n: int):
    """The ``(n, triangles)`` sparse matrix of ones that sums each vertex's triangles (duplicates summed)."""
    from scipy.sparse import csr_matrix

    return csr_matrix((np.ones(F.size), (F.reshape(-1), np.repeat(np.arange(F.shape[0]), 3))), shape=(n, F.shape[0]))


def _many_vertex_normals(X: np.ndarray, F: np.ndarray, A=None) -> np.ndarray:
    """:func:`_vertex_normals` of many poses ``X (m, n, 3)`` of one mesh at once -> ``(m, n, 3)`` float32: each
    vertex's triangles' normals weighted by their areas (as libigl's area weighting: the cross product of the
    triangle's edges ``(v1 - v0) x (v2 - v0)``), summed by one sparse product (``A``: :func:`_face_sums`, made
    when not given); +z where that sum vanishes.

    :data:`_NORMAL_POSES` poses at a time, coordinates apart (every vertex's poses side by side: one gather per
    corner and coordinate); the same operations in the same order as ``np.cross`` and ``np.linalg.norm``, so the
    float32 results are those of the straightforward ``(m, triangles, 3)`` computation, bit for bit."""
    m, n = X.shape[:2]
    F = np.asarray(F, dtype=np.int64)
    if A is None:
        A = _face_sums(F, n)
    out = np.empty((m, n, 3), dtype=np.float32)
    for a in range(0, m, _NORMAL_POSES):
        out[a:a + _NORMAL_POSES] = _unit_normals(np.asarray(X[a:a + _NORMAL_POSES], dtype=np.float64), F, A)
    return out


def _unit_normals(P: np.ndarray, F: np.ndarray, A) -> np.ndarray:
    """Area-weighted unit vertex normals of the poses ``P (c, n, 3)`` -> ``(c, n, 3)`` float64 view."""
    c = P.shape[0]
    S = np.ascontiguousarray(P.transpose(2, 1, 0))  # (3, n, c): a vertex's poses side by side
    C = np.empty((3, F.shape[0], c))  # twice each triangle's area along its normal: e1 x e2, as np.cross
    for a in range(0, F.shape[0], _FACE_BLOCK):  # the temporaries of a block of triangles stay in the cache
        f = F[a:a + _FACE_BLOCK]
        P0 = np.take(S, f[:, 0], axis=1)  # (3, triangles, c)
        E1 = np.take(S, f[:, 1], axis=1)
        E1 -= P0
        E2 = np.take(S, f[:, 2], axis=1)
        E2 -= P0
        tmp = P0[0]
        for i, (j, k) in enumerate(((1, 2), (2, 0), (0, 1))):
            Ci = C[i, a:a + _FACE_BLOCK]
            np.multiply(E1[j], E2[k], out=Ci)
            np.multiply(E1[k], E2[j], out=tmp)
            Ci -= tmp
    N = np.empty((3, A.shape[0], c))
    for i in range(3):  # each vertex's triangles summed in one order, whatever the columns
        N[i] = A @ C[i]
    del C
    x, y, z = N
    length = np.sqrt((x * x + y * y) + z * z)  # np.linalg.norm's order
    ok = length > 1e-300
    N /= np.where(length > 0, length, 1.0)
    if not ok.all():
        bad = ~ok
        x[bad], y[bad], z[bad] = 0.0, 0.0, 1.0
    return N.transpose(2, 1, 0)


def _normal_delta_chunks(V: np.ndarray, F: np.ndarray, deltas: np.ndarray, scale: float = 1.0):
    """``(a, b, normals(V + scale * deltas[a:b]) - normals(V))`` float32 for consecutive shapes
    (:data:`_NORMAL_POSES` at a time): the working memory of a few shapes, whatever their number."""
    F = np.asarray(F, dtype=np.int64)
    A = _face_sums(F, V.shape[0])
    N0 = _many_vertex_normals(V[None], F, A)[0]
    K = deltas.shape[0]
    for a in range(0, K, _NORMAL_POSES):
        b = min(K, a + _NORMAL_POSES)
        D = np.asarray(deltas[a:b], dtype=np.float64)
        N = _many_vertex_normals(V[None] + (D if scale == 1.0 else D * scale), F, A)
        N -= N0
        yield a, b, N


def shape_normal_deltas(V: np.ndarray, F: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Each shape's normal offsets: ``normals(V + deltas[k]) - normals(V)``, ``(K, n, 3)`` float32 (a morph
    target's ``NORMAL``: at weight 1 alone the client shades the shape with its own normals)."""
    out = np.empty(np.shape(deltas), dtype=np.float32)
    for a, b, N in _normal_delta_chunks(np.asarray(V, dtype=np.float64), F, deltas):
        out[a:b] = N
    return out


def fitted_normal_deltas(rest: np.ndarray, F: np.ndarray, frames, weights: np.ndarray) -> np.ndarray:
    """Normal offsets of targets that are not shapes of their own (a sequence's principal axes): the
    least-squares ``dN`` with ``normals(frame_t) - normals(rest) ~ weights[t] @ dN`` over sample frames.

    ``frames(a, b)`` gives the sample frames ``a..b-1`` as ``(b - a, n, 3)``, ``weights (m, K)`` their weights;
    taken 16 at a time, so memory is a few ``(K, 3n)`` arrays -> ``(K, n, 3)`` float32."""
    A = np.asarray(weights, dtype=np.float64)
    m, K = A.shape
    N0 = None
    AtY = None
    for a in range(0, m, 16):
        X = np.asarray(frames(a, min(m, a + 16)), dtype=np.float64)
        if N0 is None:
            N0 = _many_vertex_normals(np.asarray(rest, dtype=np.float64)[None], F)[0].astype(np.float64)
            AtY = np.zeros((K, N0.size))
        Y = (_many_vertex_normals(X, F) - N0).reshape(X.shape[0], -1)
        AtY += A[a:a + X.shape[0]].T @ Y
        del X, Y
    # a little ridge: targets the frames barely use get no wild normals (1e-6 of the weights' energy)
    lam = 1e-6 * max(float((A * A).sum()) / max(K, 1), 1e-12)
    dN = np.linalg.solve(A.T @ A + lam * np.eye(K), AtY)
    return dN.reshape(K, -1, 3).astype(np.float32)


def _write_glb(path: Path, V: np.ndarray, F: np.ndarray, deltas: np.ndarray, names, weights: np.ndarray,
               fps: float, generator: str, motion=None, normals_of=None, rest_weights=None,
               normal_deltas=None, scale: float = 1.0) -> Path:
    """Build and write the document (arrays already checked); ``motion``: ``(quaternions (T, 4) xyzw,
    translations (T, 3))`` animating the node, or None; ``normals_of``: the vertices whose normals are
    stored (default ``V``); ``rest_weights``: the mesh's weights when nothing plays (default zeros);
    ``normal_deltas``: ``(K, n, 3)`` the targets' ``NORMAL`` offsets, or a callable giving target ``k``'s
    (asked for in order, when the file is written) (default: none stored); ``scale``: the factor of the
    deltas as stored (``V`` and ``motion`` are given as stored).

    The targets' data is made a target at a time as the file is written, and the weights a block of frames at a
    time: memory holds no float32 copy of all the targets or weights."""
    try:
        import pygltflib as g
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError("writing glTF needs the pygltflib package (pip install pygltflib)", path) from None
    K = deltas.shape[0]
    T = weights.shape[0]
    blob = _Blob(g)
    i_idx = blob.add(F.reshape(-1), "SCALAR", _UINT, _ELEMENT_ARRAY_BUFFER)
    V32 = V.astype(np.float32)
    i_pos = blob.add(V32, "VEC3", _FLOAT, _ARRAY_BUFFER, bounds=True)
    i_nrm = blob.add(_vertex_normals(V if normals_of is None else np.asarray(normals_of, dtype=np.float64),
                                     F.astype(np.int64)), "VEC3", _FLOAT, _ARRAY_BUFFER)

    def target(k: int) -> np.ndarray:  # a target's float32 offsets, as stored
        return (deltas[k] if scale == 1.0 else deltas[k] * scale).astype(np.float32)

    n = deltas.shape[1]
    targets = []
    for k in range(K):
        a = g.Attributes(POSITION=blob.add_later(lambda k=k: (target(k),), n * 12, n, "VEC3", _FLOAT, _ARRAY_BUFFER,
                                                 bounds=_bounds(target(k))))
        if callable(normal_deltas):
            a.NORMAL = blob.add_later(lambda k=k: (np.asarray(normal_deltas(k), dtype=np.float32),), n * 12, n,
                                      "VEC3", _FLOAT, _ARRAY_BUFFER)
        elif normal_deltas is not None:
            a.NORMAL = blob.add(np.asarray(normal_deltas[k], dtype=np.float32), "VEC3", _FLOAT, _ARRAY_BUFFER)
        targets.append(a)
    times = (np.arange(T, dtype=np.float64) / fps).astype(np.float32)
    if T > 1 and not (np.diff(times) > 0).all():
        raise InputError(f"{T} frames at {fps} fps give keyframe times that float32 cannot keep apart", path)
    i_t = blob.add(times, "SCALAR", _FLOAT, bounds=True)
    rows = max(1, (1 << 22) // max(4 * K, 1))  # 4 MB of float32 weights at a time
    i_w = blob.add_later(lambda: (weights[a:a + rows].astype(np.float32) for a in range(0, T, rows)), T * K * 4,
                         T * K, "SCALAR", _FLOAT)
    prim = g.Primitive(attributes=g.Attributes(POSITION=i_pos, NORMAL=i_nrm), indices=i_idx, mode=g.TRIANGLES,
                       targets=targets)
    samplers = [g.AnimationSampler(input=i_t, output=i_w, interpolation="LINEAR")]
    channels = [g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))]
    if motion is not None:  # the head's motion: the node turns (slerp) and moves
        for out, what in ((blob.add(motion[0].astype(np.float32), "VEC4", _FLOAT), "rotation"),
                          (blob.add(motion[1].astype(np.float32), "VEC3", _FLOAT), "translation")):
            samplers.append(g.AnimationSampler(input=i_t, output=out, interpolation="LINEAR"))
            channels.append(g.AnimationChannel(sampler=len(samplers) - 1,
                                               target=g.AnimationChannelTarget(node=0, path=what)))
    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator=generator),
        scene=0,
        scenes=[g.Scene(nodes=[0])],
        nodes=[g.Node(mesh=0, name="face")],
        meshes=[g.Mesh(primitives=[prim], name="face",
                       weights=[0.0] * K if rest_weights is None else [float(w) for w in rest_weights],
                       extras={"targetNames": [str(n) for n in names]})],
        animations=[g.Animation(name="weights", samplers=samplers, channels=channels, extras={"fps": fps})],
        accessors=blob.accessors,
        bufferViews=blob.views,
        buffers=[g.Buffer(byteLength=blob.size)],
    )
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            _save_glb(doc, blob, fh)
    return path


def _check_suffix(path: Path) -> None:
    if path.suffix.lower() != ".glb":
        raise InputError(f"a glTF binary file must end in .glb, got {path.suffix or 'no suffix'!r}", path)


def write_rig_glb(path: str | os.PathLike, neutral, faces, deltas, shape_names, weights, fps: float,
                  rotations=None, translations=None, *, scale: float = 1.0) -> Path:
    """Write a blendshape rig and its weight curves as a glTF 2.0 binary (``.glb``), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.glb`` file.
    neutral : array_like
        ``(n, 3)`` rest positions (written as float32).
    faces : array_like
        ``(m, 3)`` integer triangles.
    deltas : array_like
        ``(K, n, 3)`` blendshape offsets from ``neutral`` (the morph targets).
    shape_names : sequence of str
        ``K`` target names (``mesh.extras.targetNames``).
    weights : array_like
        ``(T, K)`` weights, one row per frame; sampled ``LINEAR`` at ``fps``.
    fps : float
        Frames per second of ``weights``.
    rotations, translations : array_like, optional
        ``(T, 3, 3)`` proper rotations and ``(T, 3)`` translations (the file's
        units) of the head per frame: the node is animated with them (a
        quaternion per frame, slerped; the mesh turns about its origin).
        Both or neither.
    scale : float
        Factor of the positions, offsets and translations as written (0.01:
        centimetres to glTF's metres): the file is the one written from
        ``neutral * scale``, ``deltas * scale`` and ``translations * scale``,
        without a scaled copy of the offsets in memory.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        A suffix other than ``.glb``; shapes that disagree; NaN or inf; a head
        motion that is not ``T`` proper rotations and translations; faces
        outside the vertices; a frame rate that is not positive; names that
        are not ``K``; a scale that is not a positive number; an output folder
        that does not exist.

    Notes
    -----
    The targets' normal offsets (:func:`shape_normal_deltas`) and float32
    offsets are made a few targets at a time as the file is written, and the
    file is written a buffer view at a time: besides its inputs, writing holds
    a few targets' arrays (a 76,000-vertex, 52-shape rig and 100,000 frames of
    weights: about 80 MB, where the whole file and its copies took 670 MB).
    """
    path = Path(path)
    _check_suffix(path)
    try:
        scale = float(scale)
    except (TypeError, ValueError):
        raise InputError(f"scale {scale!r} is not a number", path) from None
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale {scale} is not a positive number", path)
    if scale != 1.0:
        neutral = np.asarray(neutral, dtype=np.float64) * scale
    V, F = _mesh_arrays(path, neutral, faces)
    n = V.shape[0]
    D = np.asarray(deltas, dtype=np.float64)
    if D.ndim != 3 or D.shape[1:] != (n, 3) or D.shape[0] == 0:
        raise InputError(f"deltas must have shape (K, {n}, 3) with K > 0, got {D.shape}", path)
    K = D.shape[0]
    names = [str(s) for s in shape_names]
    if len(names) != K:
        raise InputError(f"{len(names)} shape names for {K} blendshapes", path)
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim != 2 or W.shape[1] != K or W.shape[0] == 0:
        raise InputError(f"weights must have shape (T, {K}) with T > 0, got {W.shape}", path)
    low, high = float(D.min()), float(D.max())  # NaN or inf in D make one of them so (no copy of D)
    if not (np.isfinite(low) and np.isfinite(high) and np.isfinite(max(-low, high) * scale)  # and D * scale
            and np.isfinite(W).all()):
        raise InputError("deltas or weights contain NaN or inf", path)
    motion = None
    if (rotations is None) != (translations is None):
        raise InputError("the head motion needs both rotations and translations", path)
    if rotations is not None:
        R = np.asarray(rotations, dtype=np.float64)
        t = np.asarray(translations, dtype=np.float64)
        if scale != 1.0:
            t = t * scale
        T = W.shape[0]
        if R.shape != (T, 3, 3) or t.shape != (T, 3) or not (np.isfinite(R).all() and np.isfinite(t).all()):
            raise InputError(f"the head motion must be {T} finite rotations (T, 3, 3) and translations (T, 3), got "
                             f"{R.shape} and {t.shape}", path)
        # orthonormal (the determinant is then +-1), the rows' triple product (the determinant) positive:
        # np.linalg.det factors each matrix, 10 times slower
        if not (np.abs(np.einsum("tij,tkj->tik", R, R) - np.eye(3)).max() < 1e-6
                and (np.einsum("ti,ti->t", R[:, 0], np.cross(R[:, 1], R[:, 2])) > 0).all()):
            raise InputError("the head rotations are not proper rotations", path)
        q = quaternions(R)  # x, y, z, w
        flip = np.r_[1.0, np.sign(np.cumprod(np.sign(np.einsum("ti,ti->t", q[1:], q[:-1]) + 1e-300)))]
        motion = (q * flip[:, None], t)  # consecutive quaternions on the same side: slerp takes the short way
    normals = _InOrder(_normal_delta_chunks(V, F.astype(np.int64), D, scale))
    return _write_glb(path, V, F, D, names, W, _check_fps(path, fps), "facegeom write_rig_glb", motion,
                      normal_deltas=normals, scale=scale)


def quaternions(R) -> np.ndarray:
    """Unit quaternions ``(T, 4)`` (x, y, z, w; w >= 0) of proper rotation matrices ``R (T, 3, 3)``.

    Shepperd's choice: of ``4w^2 = 1 + tr R`` and ``4x^2 = 1 + 2 R_xx - tr R`` (and y, z), the largest gives one
    component without cancellation and the others follow from the off-diagonal sums and differences. Here rather
    than through scipy's ``Rotation``, whose import (all of ``scipy.spatial``) cost the rig route 0.35-0.45 s.
    """
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R, axis1=1, axis2=2)
    d = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2], tr], axis=1)  # the largest of x, y, z, w squared
    k = np.argmax(d, axis=1)
    q = np.empty((R.shape[0], 4))
    for i in range(3):  # x, y or z the largest
        j, m = (i + 1) % 3, (i + 2) % 3
        s = k == i
        Ri = R[s]
        q[s, i] = 1.0 - tr[s] + 2.0 * Ri[:, i, i]
        q[s, j] = Ri[:, j, i] + Ri[:, i, j]
        q[s, m] = Ri[:, m, i] + Ri[:, i, m]
        q[s, 3] = Ri[:, m, j] - Ri[:, j, m]
    s = k == 3
    Ri = R[s]
    q[s, 0] = Ri[:, 2, 1] - Ri[:, 1, 2]
    q[s, 1] = Ri[:, 0, 2] - Ri[:, 2, 0]
    q[s, 2] = Ri[:, 1, 0] - Ri[:, 0, 1]
    q[s, 3] = 1.0 + tr[s]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q * np.where(q[:, 3:] < 0, -1.0, 1.0)


class _InOrder:
    """``self(k)``: item ``k`` of chunks ``(a, b, items[a:b])`` made in order by ``chunks`` (asked for in
    order): only the current chunk is held."""

    def __init__(self, chunks):
        self.chunks, self.a, self.b, self.items = iter(chunks), 0, 0, None

    def __call__(self, k: int):
        while not self.a <= k < self.b:
            if k < self.a:
                raise IndexError(f"item {k} asked for after item {self.a}")
            self.a, self.b, self.items = next(self.chunks)
        return self.items[k - self.a]


def _check_rest(path: Path, rest, n: int):
    """``rest`` as ``(n, 3)`` finite float64, or None."""
    if rest is None:
        return None
    R = np.asarray(rest, dtype=np.float64)
    if R.shape != (n, 3) or not np.isfinite(R).all():
        raise InputError(f"the rest pose must be {n} finite points (n, 3), got {R.shape}", path)
    return R


def write_sequence_glb(path: str | os.PathLike, frames, faces, fps: float,
                       tolerance: float = DEFAULT_TOLERANCE, *, hold_bytes: int = HOLD_BYTES,
                       progress=None, rest=None) -> tuple[Path, dict]:
    """Write a driven vertex sequence as a ``.glb``: mean mesh + K SVD morph targets + their weight curves.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.glb`` file.
    frames : array_like or FrameSource
        ``(T, n, 3)`` vertex positions, or a
        :class:`~facegeom.io.frames.FrameSource` computing them a chunk at a
        time (streamed: memory does not grow with ``T`` beyond a few ``(T, K)``
        arrays; see below).
    faces : array_like
        ``(m, 3)`` integer triangles.
    fps : float
        Frame rate of the sequence.
    tolerance : float
        Error bound in the mesh's units: every vertex of every frame, as the
        file plays it back (float32), lies within ``tolerance`` of the input.
        The default 0.01 is 0.1 mm on the ICT face (in cm).
    hold_bytes : int
        Frame source only: when its frames fit in this many bytes of float32
        they are driven once and kept (as offsets from the first frame);
        otherwise every pass drives them again. Default 1 GiB.
    progress : callable, optional
        Frame source only: called with a one-line string as the passes go
        (``"glb: pass 2 (project), 40,000/100,000 frames"``).
    rest : array_like, optional
        ``(n, 3)`` the mesh at rest (a character's neutral): stored as the
        mesh, what a client shows with every weight at 0, with a first target
        ``base`` (weight 1 in every frame) carrying it to the encoding's base.
        Without it the stored mesh is the encoding's base and the mesh's
        weights when nothing plays are the first frame's.

    Returns
    -------
    (Path, dict)
        ``path`` and ``{"targets": K, "max_error": e, "tolerance": tolerance,
        "frames": T, "rest": bool}`` with ``K`` the smallest number of targets meeting the
        bound (found by bisection on K; the per-frame residual never grows
        with K) and ``e`` an upper bound on the largest vertex error of the written file (for a frame
        source the error plus bounds on float32 rounding: see the notes).

    Raises
    ------
    InputError
        As :func:`write_rig_glb`, plus frames that are not ``(T, n, 3)`` or
        hold NaN or inf, and a tolerance that is not a positive number.

    Notes
    -----
    An array is decomposed whole: mean frame, thin SVD of the frames minus
    the mean (through the ``T x T`` Gram matrix), ``K`` by bisection with the
    frames played back. A frame source is streamed in chunks of its
    ``chunk_frames``:

    1. principal axes of an evenly spaced sample (at most 256 frames, 256 MiB)
       about its mean, the fewest keeping every sample vertex within
       ``tolerance / 4``;
    2. a pass projecting every frame on the axes: coefficients, the exact
       residual norm ``sqrt(|d|^2 - |c|^2)`` and, for the frames where that
       norm is above ``tolerance / 2``, the farthest vertex off the axes;
    3. while some frame has a vertex beyond ``tolerance / 2``, the residual
       directions of the worst such frames join the axes (greedily, until
       those frames are within) and a pass projects every frame on the new
       ones;
    4. the axes are rotated by the SVD of the ``(T, r)`` coefficients, the
       base mesh moved to the mean within their span; a vertex bound gives
       the largest ``K`` needed, the sample and the frames the bound fears
       most played back give the smallest candidate (bisection; within 95%
       of ``tolerance`` when they are not all the frames, as the frames not
       seen hold larger extremes);
    5. a last pass plays back every frame in float32; a candidate over the
       bound hands over to the next (a few up to the bound's ``K``, then one
       more target at a time, as for an array).

    Memory is a chunk, the sample, the axes and a few ``(T, r)`` arrays; at
    most ``max(16, 256 MiB / (8 max(3n, T)))`` axes are kept and a sequence
    needing more is refused. A source whose frames fit in ``hold_bytes`` as
    float32 is driven once (its ``max_error`` then includes a bound on that
    copy's rounding, ``2^-24`` of each offset from the first frame); otherwise
    every pass drives it again. ``K`` can be a little above the array path's.

    A frame source offering its linear structure
    (:attr:`FrameSource.linear <facegeom.io.frames.FrameSource.linear>`: frame ``t`` is
    ``(C[t] @ B).T``, ``B (q, n)``, e.g. the tangent deformer's marker-to-vertex map) is encoded from it,
    without driving every frame:

    1. ``B^T = Qa Ra`` (QR, ``Qa`` orthonormal columns) maps the frames' span isometrically onto
       ``R^(3q)`` (``z_t[i] = Ra C_t[i]``); the principal axes are the eigenvectors of the ``(3q, 3q)``
       scatter of the centred ``z`` and every frame's coefficients on every axis are known (``Ct``);
    2. a first candidate ``K`` by bisection on an evenly spaced sample (and the frames farthest off the axes),
       within 95% of ``tolerance``, each frame's largest error decided exactly as in (3);
    3. every frame, every vertex, ``K = Ks, Ks + 1, ...`` until one holds. Coordinate ``i`` of frame ``t``'s
       residual at vertex ``j`` is ``Qa_j . r_t[i]`` (``r_t`` its ``z`` residual, of norm ``|c_t,K..|``), so the
       vertex is at most ``|Qa_j| |c_t,K..|`` off (Cauchy-Schwarz). The pairs (frame, vertex) whose bound is
       within the limit need nothing more (on a face most vertices are far from every marker and most frames
       near the mean); the others are computed exactly (``2 * 3q`` flops each), the most exposed vertices and
       the worst frames first, so a count that does not hold is refuted at its first vertex over. When the
       largest bound left is above the largest exact error, the pairs whose bound is above that error (or half
       the bound) are computed too, so the error reported is the exact largest one whenever it is at least
       half of the bound;
    4. the stored values' float32 rounding adds at most ``|b32_j - (base - sum D32_k / 2)_j| +
       sum_k (2^-23 |D32_kj| + |D32_kj - D_kj| / 2)`` at vertex ``j`` (weights in [0, 1] round by 2^-24, the
       targets' and the base's rounding measured), and float64 arithmetic at most ``2^-36 max|C_t| |B|_2``
       (hundreds of times its few-hundred-ulp error); ``K`` is the first whose errors, bounds and these two
       terms stay within ``tolerance``; ``max_error`` is that sum: an upper bound on every vertex of every
       frame as the file plays it (the largest exact error, or the largest bound of the pairs not computed when
       that is larger, plus the two rounding terms);
    5. the first chunk and the worst frames are driven by the source itself and played back from the
       encoding: if their error differs from the structure's prediction by more than the rounding terms, the
       structure is not the source's and the frames are streamed as above.

    Memory is a few ``(T, 3q)`` arrays and ``(K, 3n)`` targets.
    """
    path = Path(path)
    _check_suffix(path)
    if isinstance(frames, FrameSource):
        rest = _check_rest(path, rest, frames.shape[1])
        lin = frames.linear
        if lin is not None:
            done = _write_sequence_linear(path, frames, lin, faces, fps, tolerance, progress, rest)
            if done is not None:
                return done
        return _write_sequence_stream(path, frames, faces, fps, tolerance, hold_bytes, progress, rest)
    X = np.asarray(frames, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] == 0:
        raise InputError(f"frames must have shape (T, n, 3) with T > 0, got {X.shape}", path)
    if not np.isfinite(X).all():
        raise InputError("frames contain NaN or inf", path)
    tol = float(tolerance)
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"tolerance {tolerance} is not a positive number", path)
    T, n = X.shape[:2]
    rest = _check_rest(path, rest, n)
    base = X.mean(axis=0)
    V, F = _mesh_arrays(path, base, faces)
    fps = _check_fps(path, fps)
    D = (X - base).reshape(T, 3 * n)
    # Axes below tol / (4 sqrt(T)) are never needed: together they move no frame by more than tol / 4.
    U, S = _principal_axes(D, tol / (4.0 * np.sqrt(T)))
    C = U * S  # (T, r) coefficients of each frame on the axes
    V32 = base.astype(np.float64)  # the mean: each candidate's stored base is found from it (_played_base)
    Xf = X.reshape(T, 3 * n)
    computed = [np.zeros((0, 3 * n))]

    def axes(k: int) -> np.ndarray:  # the first k right singular vectors (computed once, grown if needed)
        if computed[0].shape[0] < k:
            computed[0] = (U[:, :k].T @ D) / S[:k, None]
        return computed[0][:k]

    # A vertex's error is at most its frame's residual norm sqrt(|d_t|^2 - sum_{i<k} C[t, i]^2), cheap for
    # every frame and k: resid[t, k - 1] after k axes. Only frames whose residual exceeds tol / 2 are
    # played back while searching; the chosen K is then checked on every frame (float32 rounding included).
    resid = np.sqrt(np.maximum((D ** 2).sum(axis=1)[:, None] - np.cumsum(C ** 2, axis=1), 0.0))

    def encode(k: int, every: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
        k = max(1, min(k, S.size))
        W, Dk = _scaled_targets(U[:, :k], S[:k], axes(k))
        W64, D64 = W.astype(np.float64), Dk.astype(np.float64)
        if every:
            rows, step = np.arange(T), 256
        else:  # worst frames first, stopping at the first chunk over the bound
            rows = np.flatnonzero(resid[:, k - 1] > tol / 2)
            rows, step = rows[np.argsort(-resid[rows, k - 1])], 128
        err = 0.0
        for a in range(0, rows.size, step):  # the played-back frames, in chunks to bound memory
            r = rows[a:a + step]
            err = max(err, _playback_error(V32, W64[r], D64, Xf[r], n))
            if err > tol and not every:
                break
        return W, Dk, err

    # Upper end: the first k where every frame's residual is below tol / 2 (half left for rounding).
    below = np.flatnonzero(resid.max(axis=0) <= tol / 2)
    hi = int(below[0]) + 1 if below.size else S.size
    lo = 1
    while lo < hi:  # bisection for the smallest k with err <= tol
        mid = (lo + hi) // 2
        if encode(mid)[2] <= tol:
            hi = mid
        else:
            lo = mid + 1
    best = encode(hi, every=True)
    while best[2] > tol and hi < S.size:  # rounding beyond the bound (tiny tolerances): one axis more
        hi += 1
        best = encode(hi, every=True)
    K = best[0].shape[1]
    W, Dk, err = best
    if err > tol:  # full rank and still above: float32 rounding of the positions themselves
        raise InputError(f"the sequence cannot be stored within {tol} (float32 rounding alone gives {err:.3g}); "
                         f"use a larger tolerance", path)
    sample = _normal_sample(T, K)
    err += _write_sequence_file(path, _played_base(base, Dk).reshape(n, 3), F, Dk.reshape(K, n, 3), W, fps, V, rest,
                                lambda a, b: X[sample[a:b]], W[sample])
    return path, {"targets": K, "max_error": err, "tolerance": tol, "frames": T, "rest": rest is not None}


def _normal_sample(T: int, K: int) -> np.ndarray:
    """The frames the normal targets are fitted on: evenly spaced, twice the targets (at least 64), at most T."""
    return np.unique(np.linspace(0, T - 1, min(T, max(64, 2 * K))).round().astype(np.int64))


def _write_sequence_file(path: Path, played: np.ndarray, F: np.ndarray, Dk: np.ndarray, W: np.ndarray, fps: float,
                         mean: np.ndarray, rest, sample_X, sample_W: np.ndarray) -> float:
    """Write a sequence's ``.glb``: stored base ``played`` (n, 3) + targets ``Dk`` (K, n, 3) with weights ``W``.

    With ``rest`` (n, 3) the mesh is stored at rest (what a client shows when nothing plays) and a first
    target ``base`` (weight 1 in every frame) moves it to ``played``; without, the base is ``played`` and the
    mesh's weights when nothing plays are the first frame's. Every target's normal offsets are fitted on the
    sample frames ``sample_X(a, b)`` with weights ``sample_W`` (m, K) (:func:`fitted_normal_deltas`).
    Returns the vertex error the extra target's float32 rounding adds (0 without ``rest``)."""
    K = Dk.shape[0]
    names = [f"svd{k:03d}" for k in range(K)]
    F64 = F.astype(np.int64)
    if rest is None:
        dN = fitted_normal_deltas(mean, F64, sample_X, sample_W)
        _write_glb(path, played, F, Dk, names, W, fps, "facegeom write_sequence_glb", normals_of=mean,
                   rest_weights=W[0], normal_deltas=dN)
        return 0.0
    rest = np.asarray(rest, dtype=np.float64)
    lift = (played - rest.astype(np.float32)).astype(np.float32)  # rest + lift plays the stored base
    extra = float(np.sqrt((((rest.astype(np.float32).astype(np.float64) + lift) - played) ** 2).sum(axis=1).max()))
    W1 = np.hstack([np.ones((W.shape[0], 1), dtype=W.dtype), W])
    D1 = np.concatenate([lift[None], Dk.astype(np.float32)])
    dN = fitted_normal_deltas(rest, F64, sample_X, np.hstack([np.ones((sample_W.shape[0], 1)), sample_W]))
    _write_glb(path, rest, F, D1, ["base", *names], W1, fps, "facegeom write_sequence_glb", normals_of=rest,
               normal_deltas=dN)
    return extra


def _principal_axes(D: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """``U, S`` of the thin SVD ``D = U diag(S) Vt`` for the singular values above ``floor``, largest first.

    Through the eigenvectors of the Gram matrix ``D D^T`` (T x T, small next to
    3n for a face sequence); only eigenpairs above ``floor**2`` (and above
    1e-24 of the largest) are computed. The right vectors are ``U.T D / S``.
    A zero ``D`` gives one axis with zero coefficients.
    """
    from scipy.linalg import eigh

    G = D @ D.T
    top = float(np.trace(G))
    if top <= 0:
        return np.eye(D.shape[0], 1), np.ones(1)
    lower = max(floor ** 2, top * 1e-24)
    evals, evecs = eigh(G, subset_by_value=(lower, np.inf), driver="evr")
    if evals.size == 0:  # every axis below the floor: keep the largest, for one target
        evals, evecs = eigh(G, subset_by_index=(D.shape[0] - 1, D.shape[0] - 1))
    order = np.argsort(evals)[::-1]
    return evecs[:, order], np.sqrt(np.clip(evals[order], 1e-300, None))


def _scaled_targets(U: np.ndarray, S: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``(T, k)`` weights in [0, 1] and ``(k, 3n)`` targets carrying the size, from ``U diag(S) axes``.

    Each axis's coefficients are scaled into [-1, 1] (``c = S u``, ``u / max |u|``) and then shifted into
    [0, 1]: ``w = (u / max|u| + 1) / 2`` with the target doubled, the base less half of every target
    (:func:`_played_base`). glTF clients treat morph weights as slider values in [0, 1]; Blender's importer
    clamps them to that range, so a negative weight would play as 0 there. Axis by axis: the first k of
    these are the encoding with k targets.
    """
    scale = np.abs(U).max(axis=0)
    scale[scale == 0] = 1.0
    W = ((U / scale + 1.0) / 2.0).astype(np.float32)
    Dk = ((2.0 * S * scale)[:, None] * axes).astype(np.float32)
    return W, Dk


def _played_base(base: np.ndarray, Dk: np.ndarray) -> np.ndarray:
    """The base a file with targets ``Dk (k, 3n)`` stores, as played (float32): ``base - sum Dk / 2``, flat."""
    return (np.asarray(base, dtype=np.float64).reshape(-1)
            - 0.5 * np.asarray(Dk, dtype=np.float64).sum(axis=0)).astype(np.float32).astype(np.float64)


def _squared_lengths(R: np.ndarray) -> np.ndarray:
    """``(m, n)`` squared length of each vertex of ``R (m, 3n)`` (``(x^2 + y^2) + z^2``, as ``sum(axis=2)`` adds)."""
    sq = R * R
    out = sq[:, 0::3] + sq[:, 1::3]
    out += sq[:, 2::3]
    return out


def _playback_error(base: np.ndarray, W64: np.ndarray, D64: np.ndarray, X: np.ndarray, n: int) -> float:
    """Largest vertex distance between frames ``X (m, 3n)`` and their playback ``base' + W64 @ D64`` (``base'``
    the stored base of these targets, :func:`_played_base`)."""
    played = W64 @ D64
    played += _played_base(base, D64).reshape(1, -1)
    played -= X
    return float(np.sqrt(_squared_lengths(played).max())) if played.size else 0.0


# ----------------------------------------------------------------------------- streamed sequences

_STREAM_BYTES = 256 * 2 ** 20  # each working block of the streamed writer: axes, coefficients, sample
_SAMPLE_FRAMES = 256  # the first axes come from at most this many evenly spaced frames
_BATCH_BYTES = 128 * 2 ** 20  # frames whose residuals are added to the axes at once


class _Frames:
    """The frames of a :class:`FrameSource` for :func:`write_sequence_glb`, as ``(m, 3n)`` float64 rows.

    Every driven chunk is checked (shape, finite); errors name the output.
    With ``hold`` the first sweep keeps every frame as float32 offsets from
    frame 0 and later reads come from that copy; ``hold_err`` bounds the
    vertex distance the float32 rounding of the copy made. Chunks may be the
    source's own arrays: they are never changed.
    """

    def __init__(self, source: FrameSource, path: Path, hold: bool, progress):
        self.src, self.path, self.progress = source, path, progress
        self.T, self.n = source.shape[:2]
        self.step = source.chunk_frames
        self.hold = hold
        self.held: np.ndarray | None = None
        self.origin: np.ndarray | None = None
        self.hold_err = 0.0
        self.passes = 0

    def drive(self, a: int, b: int) -> np.ndarray:
        try:
            X = self.src.chunk(a, b)
        except InputError as exc:
            if exc.path is not None:
                raise
            raise InputError(exc.reason, self.path) from None
        if not np.isfinite(X).all():
            raise InputError(f"frames {a}..{b - 1} contain NaN or inf", self.path)
        return X.reshape(b - a, 3 * self.n)

    def frames(self, a: int, b: int) -> np.ndarray:
        if self.held is not None:
            return self.origin + self.held[a:b]
        return self.drive(a, b)

    def rows(self, idx: np.ndarray) -> np.ndarray:
        """Frames ``idx`` (sorted, distinct), driven in runs of consecutive frames."""
        if self.held is not None:
            return self.origin + self.held[idx]
        out = np.empty((idx.size, 3 * self.n))
        i = 0
        while i < idx.size:
            j = i + 1
            while j < idx.size and idx[j] == idx[j - 1] + 1 and j - i < self.step:
                j += 1
            out[i:j] = self.drive(int(idx[i]), int(idx[j - 1]) + 1)
            i = j
        return out

    def sweep(self, name: str):
        """Yield ``(a, X)`` chunk by chunk over every frame; the first sweep with ``hold`` fills the copy."""
        self.passes += 1
        filling = self.hold and self.held is None
        if filling:
            self.held = np.empty((self.T, 3 * self.n), dtype=np.float32)
        last = time.monotonic()
        try:
            for a in range(0, self.T, self.step):
                b = min(self.T, a + self.step)
                X = self.drive(a, b) if filling else self.frames(a, b)
                if filling:  # float32 rounds each offset by at most 2^-24 of its size
                    if self.origin is None:
                        self.origin = X[0].copy()
                    Y = X - self.origin
                    self.held[a:b] = Y
                    self.hold_err = max(self.hold_err, float(np.sqrt(3.0) * 2.0 ** -24 * np.abs(Y).max()))
                    del Y
                yield a, X
                now = time.monotonic()
                if self.progress is not None and (b == self.T or now - last >= 0.5):
                    self.progress(f"glb: pass {self.passes} ({name}), {b:,}/{self.T:,} frames")
                    last = now
        except BaseException:
            if filling:
                self.held = self.origin = None
            raise


def _orthonormal_rows(A: np.ndarray, against: np.ndarray | None = None) -> np.ndarray:
    """Orthonormal rows spanning ``A``'s rows less the span of ``against`` (orthonormal rows), in ``A``'s order.

    Householder QR, twice; a row whose remainder is below 1e-6 (rows are
    expected near unit length) is dropped.
    """
    from scipy.linalg import qr

    for _ in range(2):
        if against is not None and against.shape[0] and A.shape[0]:
            A = A - (A @ against.T) @ against
        if A.shape[0] == 0:
            break
        Qf, Rf = qr(A.T, mode="economic")
        A = np.ascontiguousarray(Qf[:, np.abs(np.diag(Rf)) > 1e-6].T)
    return A


def _vertex_max(R: np.ndarray, n: int) -> np.ndarray:
    """``(m,)`` largest vertex norm of each row of ``R (m, 3n)``."""
    return np.sqrt(_squared_lengths(R).max(axis=1)) if R.shape[0] else np.zeros(0)


def _residual_axes(R: np.ndarray, Q: np.ndarray, n: int, limit: float, most: int) -> np.ndarray:
    """At most ``most`` unit axes bringing the frames' residuals ``R (m, 3n)`` (orthogonal to ``Q``) within ``limit``.

    Greedy: the frame with the farthest vertex gives the next axis (its
    residual direction) and every residual loses its part on it, until every
    vertex of every frame is within ``limit``. ``R`` is overwritten.
    """
    out = []
    far = _vertex_max(R, n)
    while len(out) < most and far.size and far.max() > limit:
        j = int(np.argmax(far))
        q = R[j] / np.linalg.norm(R[j])
        out.append(q)
        R -= np.outer(R @ q, q)
        far = _vertex_max(R, n)
    return _orthonormal_rows(np.array(out), Q) if out else np.zeros((0, R.shape[1]))


def _write_sequence_stream(path: Path, source: FrameSource, faces, fps, tolerance, hold_bytes,
                           progress, rest=None) -> tuple[Path, dict]:
    """:func:`write_sequence_glb` for a :class:`FrameSource` (see its notes)."""
    from scipy.linalg import eigh

    T, n = source.shape[:2]
    N = 3 * n
    tol = float(tolerance)
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"tolerance {tolerance} is not a positive number", path)
    _mesh_arrays(path, np.zeros((n, 3)), faces)  # faces checked before anything is driven
    fps = _check_fps(path, fps)
    fr = _Frames(source, path, T * N * 4 <= hold_bytes, progress)
    if fr.hold:  # drive every frame once, now; later passes read the copy
        for _ in fr.sweep("drive"):
            pass
    half = tol / 2  # a frame whose vertices are within tol / 2 of the axes' span is left the rest for rounding
    r_max = int(min(T, N, max(16, _STREAM_BYTES // (8 * max(N, T)))))
    batch = max(1, min(_SAMPLE_FRAMES, _BATCH_BYTES // (8 * N)))

    # (1) Principal axes of an evenly spaced sample, about its mean: the fewest keeping its vertices within tol / 4.
    s = max(1, min(T, _SAMPLE_FRAMES, _STREAM_BYTES // (8 * N)))
    sample = np.unique(np.linspace(0, T - 1, s).round().astype(np.int64))
    Ds = fr.rows(sample)
    base = Ds.mean(axis=0)
    Ds -= base
    U, S = _principal_axes(Ds, tol / 8)  # together, the axes below tol / 8 move no sample frame more than that
    U, S = U[:, :r_max], S[:r_max]
    grown = [np.zeros((0, N))]

    def sample_axes(k: int) -> np.ndarray:  # the first k right singular vectors U.T Ds / S (grown when needed)
        if grown[0].shape[0] < k:
            grown[0] = (U[:, :k].T @ Ds) / S[:k, None]
        return grown[0][:k]

    def sample_within(k: int) -> bool:  # every sample vertex within tol / 4 of the first k axes (coefficients U S)?
        A = sample_axes(k)
        for a in range(0, Ds.shape[0], fr.step):
            R = Ds[a:a + fr.step] - (U[a:a + fr.step, :k] * S[:k]) @ A
            if _vertex_max(R, n).max() > tol / 4:
                return False
        return True

    top = 0
    if not sample_within(0):  # doubling, then bisection: the fewest axes keeping the sample within tol / 4
        lo, top = 1, min(8, S.size)
        while top < S.size and not sample_within(top):
            lo, top = top + 1, min(S.size, 2 * top)
        while lo < top:
            mid = (lo + top) // 2
            if sample_within(mid):
                top = mid
            else:
                lo = mid + 1
    new = _orthonormal_rows(sample_axes(top))
    del Ds, U, S, grown

    # (2, 3) Every frame's coefficients, residual norm and farthest vertex off the axes; the residual directions
    # of the frames still beyond tol / 2 join the axes, and a pass projects every frame on the new ones.
    C = np.zeros((T, 0))
    Q = np.zeros((0, N))
    res2, far = np.empty(T), np.empty(T)
    first = True
    while True:
        if first or new.shape[0]:
            Qa = np.vstack([Q, new])
            Cn = np.empty((T, new.shape[0]))
            for a, X in fr.sweep("project"):
                b = a + X.shape[0]
                D = X - base
                del X
                cn = D @ new.T
                Cn[a:b] = cn
                if first:
                    res2[a:b] = np.einsum("ij,ij->i", D, D)
                r2 = res2[a:b] - np.einsum("ij,ij->i", cn, cn)
                far[a:b] = np.sqrt(np.maximum(r2, 0.0))  # the frame's residual norm bounds its farthest vertex
                loose = np.flatnonzero(r2 > half ** 2)
                if loose.size:  # ... where it is not enough, the vertices themselves
                    R = D if loose.size == b - a else D[loose]
                    R -= np.hstack([C[a:b][loose], cn[loose]]) @ Qa
                    far[a + loose] = _vertex_max(R, n)
                    del R
                del D
            res2 -= np.einsum("ij,ij->i", Cn, Cn)
            C = np.hstack([C, Cn]) if C.shape[1] else Cn
            Q = Qa
            del Cn, Qa
            first = False
        bad = np.flatnonzero(far > half)
        if bad.size == 0:
            break
        if Q.shape[0] >= r_max:
            raise InputError(f"the sequence needs more than {r_max} morph targets to stay within {tol} (frame "
                             f"{int(np.argmax(far))} is {far.max():.3g} away with {r_max}); use a larger tolerance",
                             path)
        pick = np.sort(bad[np.argsort(-far[bad])[:batch]])
        R = fr.rows(pick) - base
        for _ in range(2):  # the residuals off the axes (twice, for accuracy)
            R -= (R @ Q.T) @ Q
        res2[pick] = np.einsum("ij,ij->i", R, R)  # exact for these frames
        far[pick] = _vertex_max(R, n)
        new = _residual_axes(R, Q, n, half, r_max - Q.shape[0])
        del R
        if new.shape[0] == 0 and (far[pick] > half).any():  # pragma: no cover - the greedy step takes such a frame
            raise InputError(f"the sequence cannot be stored within {tol}", path)
    if Q.shape[0] == 0:  # every frame on the base: one zero target
        Q, C = np.zeros((1, N)), np.zeros((T, 1))
    r = Q.shape[0]

    # (4) Rotate the axes by the SVD of the coefficients (the base moved to their mean, within the axes' span: the
    # residuals stay), largest first.
    mu = C.mean(axis=0)
    base = base + mu @ Q
    C -= mu
    Wr = eigh(C.T @ C)[1][:, ::-1]
    Ct = Wr.T @ C.T  # (r, T) coefficients on the rotated axes
    del C
    Sr = np.sqrt(np.einsum("ij,ij->i", Ct, Ct))
    # A vertex's error with k axes is at most the smaller of its frame's residual norm sqrt(res2 + tail) and its
    # farthest vertex off all axes plus the frame's part on axes k.. times the largest vertex share of those axes.
    res2 = np.maximum(res2, 0.0)
    tail, share = np.zeros(T), np.zeros(n)
    worst, spread = np.empty(r + 1), np.zeros(r + 1)
    worst[r] = far.max()
    marks = {max(1, k) for k in (1, r // 4, r // 2, (3 * r) // 4, r - 1)}
    extra = []
    for i in range(r - 1, -1, -1):
        share += ((Wr[:, i] @ Q).reshape(n, 3) ** 2).sum(axis=1)
        tail += Ct[i] ** 2
        spread[i] = share.max()
        bound = np.minimum(np.sqrt(res2 + tail), far + np.sqrt(tail * spread[i]))
        worst[i] = bound.max()
        if i in marks:  # the frames the bound fears most, for the bisection below
            extra.append(np.argpartition(-bound, min(8, T) - 1)[:8])
        del bound
    hi = next((k for k in range(1, r + 1) if worst[k] <= half), r)

    def targets(k: int) -> tuple[np.ndarray, np.ndarray]:  # (T, k) weights and (k, 3n) targets, float32
        U = (Ct[:k] / np.where(Sr[:k] > 0, Sr[:k], 1.0)[:, None]).T  # the "U" of the SVD, as the array path has it
        return _scaled_targets(U, Sr[:k], Wr[:, :k].T @ Q)

    V32 = base.astype(np.float64)  # the mean: each candidate's stored base is found from it (_played_base)
    W, Dk = targets(hi)
    W64, D64 = W.astype(np.float64), Dk.astype(np.float64)

    # Candidates: bisection on the sample and the frames of the bound's worst (the array path bisects on all),
    # then a few more up to hi.
    seen = np.unique(np.concatenate([sample, *extra]))
    Xs, Ws = fr.rows(seen), W64[seen]
    # The frames not seen hold larger extremes: a candidate must leave them 5% (unless every frame is seen), so
    # that the last pass seldom has to hand over.
    limit = (tol if seen.size == T else 0.95 * tol) - fr.hold_err
    lo, top = 1, hi
    while lo < top:
        mid = (lo + top) // 2
        if all(_playback_error(V32, Ws[a:a + fr.step, :mid], D64[:mid], Xs[a:a + fr.step], n) <= limit
               for a in range(0, seen.size, fr.step)):
            top = mid
        else:
            lo = mid + 1
    del Xs, Ws
    while lo < hi:  # ... and on the frames the bound fears most at lo itself: one more target while one fails
        tail = (Ct[lo:] ** 2).sum(axis=0)
        bound = np.minimum(np.sqrt(res2 + tail), far + np.sqrt(tail * spread[lo]))
        bound[seen] = 0.0
        worse = np.sort(np.argpartition(-bound, min(64, T) - 1)[:64])
        worse = worse[bound[worse] > half]
        if worse.size == 0:
            break
        Xw = fr.rows(worse)
        if all(_playback_error(V32, W64[worse[a:a + fr.step], :lo], D64[:lo], Xw[a:a + fr.step], n) <= limit
               for a in range(0, worse.size, fr.step)):
            break
        seen = np.union1d(seen, worse)
        lo += 1
    ladder = sorted({lo + j for j in (0, 1, 2, 3, 5, 8, 13, 21, 34) if lo + j < hi} | {hi})

    # (5) Play back every frame: a circular pass in which a candidate over the bound hands the chunk to the next.
    starts = list(range(0, T, fr.step))
    ci, k, err, ok, pos = 0, ladder[0], 0.0, 0, 0
    fr.passes += 1
    last = time.monotonic()
    while ok < len(starts):
        a = starts[pos]
        b = min(T, a + fr.step)
        X = fr.frames(a, b)
        while True:
            e = _playback_error(V32, W64[a:b, :k], D64[:k], X, n) + fr.hold_err
            if e <= tol:
                break
            ci += 1
            if ci < len(ladder):
                k = ladder[ci]
            elif k < r:  # rounding beyond the bound (tiny tolerances): one axis more
                k += 1
                W, Dk = targets(k)
                W64, D64 = W.astype(np.float64), Dk.astype(np.float64)
            else:  # all axes and still above: float32 rounding of the positions themselves
                raise InputError(f"the sequence cannot be stored within {tol} (float32 rounding alone gives "
                                 f"{e:.3g}); use a larger tolerance", path)
            err, ok = 0.0, 0
        del X
        err = max(err, e)
        ok += 1
        pos = (pos + 1) % len(starts)
        now = time.monotonic()
        if progress is not None and (ok == len(starts) or now - last >= 0.5):
            progress(f"glb: pass {fr.passes} (check {k} targets), {min(T, ok * fr.step):,}/{T:,} frames")
            last = now
    K = k
    V, F = _mesh_arrays(path, base.reshape(n, 3), faces)
    normal_frames = _normal_sample(T, K)
    err += _write_sequence_file(path, _played_base(base, Dk[:K]).reshape(n, 3), F, Dk[:K].reshape(K, n, 3),
                                W[:, :K], fps, V, rest, lambda a, b: fr.rows(normal_frames[a:b]).reshape(-1, n, 3),
                                W[normal_frames, :K])
    return path, {"targets": K, "max_error": float(err), "tolerance": tol, "frames": T, "rest": rest is not None}

# ----------------------------------------------------------------------------- sequences with a linear structure

_LINEAR_WINDOW = 8  # target counts verified together in one pass over the frames
_LINEAR_BLOCK = 32 * 2 ** 20  # bytes of each (frames x vertices) block of the low-rank writer
_LINEAR_SAMPLE = 256  # frames evenly spaced on which the first candidate is found (plus the worst of each K tried)


def _write_sequence_linear(path: Path, source: FrameSource, lin, faces, fps, tolerance, progress,
                           rest=None) -> tuple[Path, dict] | None:
    """:func:`write_sequence_glb` for a frame source with a linear structure (see its notes); None when the
    structure disagrees with the source's own frames (the caller then streams them)."""
    from scipy.linalg import eigh, qr

    T, n = source.shape[:2]
    N = 3 * n
    tol = float(tolerance)
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"tolerance {tolerance} is not a positive number", path)
    _mesh_arrays(path, np.zeros((n, 3)), faces)  # faces checked before anything is computed
    fps = _check_fps(path, fps)
    say = progress or (lambda line: None)
    C, B = lin.coefficients, lin.basis
    q = B.shape[0]
    r = 3 * q

    # An isometry of the frames' span onto R^(3q): B^T = Qa Ra (Qa orthonormal columns), so coordinate i of frame t
    # is Qa z_t[i] with z_t[i] = Ra C_t[i]: distances between frames are distances between their z.
    Qa, Ra = qr(B.T, mode="economic")
    Z = (C.reshape(3 * T, q) @ Ra.T).reshape(T, r)
    mu = Z.mean(axis=0)
    Z -= mu
    Vz = np.ascontiguousarray(eigh(Z.T @ Z)[1][:, ::-1])  # (r, r) principal axes in z, largest first
    Ct = Z @ Vz  # (T, r) every frame's coefficients on every axis
    del Z
    S = np.sqrt(np.einsum("tk,tk->k", Ct, Ct))
    # float64 arithmetic (the QR, the rotations, the products) errs by a few hundred ulps of the frames' size at
    # most: 2^-36 of the largest |C_t| ||B||_2 (which bounds every coordinate of every frame) covers it many times
    arith = 2.0 ** -36 * float(np.sqrt(np.einsum("tim,tim->t", C, C).max())) * float(np.linalg.norm(Ra, 2))

    def field(Zr: np.ndarray, J=slice(None)) -> np.ndarray:  # (m, r) in z -> (m, 3, nJ) vertex coordinates
        QJ = Qa[J]
        return (Zr.reshape(-1, q) @ QJ.T).reshape(Zr.shape[0], 3, QJ.shape[0])

    def interleaved(F3: np.ndarray) -> np.ndarray:  # (m, 3, n) -> (m, 3n) as the file lays vertices out
        return np.ascontiguousarray(F3.transpose(0, 2, 1)).reshape(F3.shape[0], N)

    base = interleaved(field(mu[None]))[0]

    def exact(K: int, rows: np.ndarray) -> np.ndarray:  # (m,) farthest vertex off the first K axes, per frame
        out = np.empty(rows.size)
        step = max(1, _LINEAR_BLOCK // (24 * n))
        for a in range(0, rows.size, step):
            R = field(Ct[rows[a:a + step], K:] @ Vz[:, K:].T)
            out[a:a + step] = np.sqrt(np.einsum("min,min->mn", R, R).max(axis=1))
        return out

    # Coordinate i of frame t's residual at vertex j is Qa_j . (its z residual)[i], so (Cauchy-Schwarz, coordinate
    # by coordinate) vertex j is at most ||Qa_j|| |c_t,K..| off: on a face most vertices are far from every marker
    # (small ||Qa_j||) and most frames near the mean (small tails), so most pairs (frame, vertex) are settled by
    # that bound and only the others are computed, exactly (2 r flops each). The margin covers the norms' rounding.
    reach = np.sqrt(np.einsum("nm,nm->n", Qa, Qa)) * (1.0 + 1e-12)
    order = np.argsort(-reach, kind="stable")  # the most exposed vertices first
    reach_sorted = reach[order]
    computed = [0]  # pairs computed exactly, for the progress line

    def worst(K: int, rows: np.ndarray, screen: float, fail: float = np.inf, label: str = "") -> tuple[float, float]:
        """``(e, b)`` for frames ``rows`` with ``K`` targets: ``e`` the largest exact error of the pairs whose bound
        exceeds ``screen`` (and of some others), ``b`` the largest bound of the pairs not computed (at most
        ``screen``); ``(inf, inf)`` as soon as an exact error exceeds ``fail``."""
        tail = np.empty(rows.size)
        for a in range(0, rows.size, 4096):
            Ck = Ct[rows[a:a + 4096], K:]
            tail[a:a + 4096] = np.sqrt(np.einsum("tk,tk->t", Ck, Ck))
        o = np.argsort(-tail, kind="stable")  # the worst frames first: a count that does not hold fails early
        tail = tail[o]
        m = int(np.count_nonzero(tail * reach_sorted[0] > screen))  # the frames with some pair to compute
        Zr = np.empty((m, r))  # their residuals in z
        for a in range(0, m, 4096):
            Zr[a:a + 4096] = Ct[rows[o[a:min(m, a + 4096)]], K:] @ Vz[:, K:].T
        err = bnd = 0.0
        a, last = 0, time.monotonic()
        while a < n:
            # vertices order[a:a + nb]: the frames whose bound there may exceed screen are the first c
            c = int(np.count_nonzero(tail[:m] * reach_sorted[a] > screen))
            if c < tail.size:
                bnd = max(bnd, float(tail[c] * reach_sorted[a]))
            if c == 0:  # and so for every vertex after (less exposed)
                break
            # the block ends about where half of these frames are settled (at most about twice the pairs needed)
            half = int(np.searchsorted(-reach_sorted, -screen / tail[c // 2]))
            nb = min(n - a, max(256, half - a), max(256, _LINEAR_BLOCK // (24 * c)))
            QJ = Qa[order[a:a + nb]].T
            step = max(1, _LINEAR_BLOCK // (24 * nb))
            for f in range(0, c, step):
                g = min(c, f + step)
                R = (Zr[f:g].reshape(-1, q) @ QJ).reshape(g - f, 3, nb)
                e = float(np.sqrt(np.einsum("min,min->mn", R, R).max()))
                if e > fail:
                    return np.inf, np.inf
                err = max(err, e)
            computed[0] += c * nb
            a += nb
            if label and time.monotonic() - last >= 0.5:
                say(f"glb: {label}, {a:,}/{n:,} vertices")
                last = time.monotonic()
        return err, bnd

    # (1) The first candidate: the fewest axes keeping an evenly spaced sample, and the frames farthest off the
    # axes at each count tried, within 95% of the tolerance (bisection).
    sample = np.unique(np.linspace(0, T - 1, min(T, _LINEAR_SAMPLE)).round().astype(np.int64))

    def sample_ok(K: int) -> bool:
        tail = np.einsum("tk,tk->t", Ct[:, K:], Ct[:, K:])
        rows = np.union1d(sample, np.argpartition(-tail, min(32, T) - 1)[:32])
        lim = 0.95 * tol - arith
        return lim > 0 and worst(K, rows, lim, lim)[0] <= lim

    lo, hi = 1, r
    while lo < hi:
        mid = (lo + hi) // 2
        if sample_ok(mid):
            hi = mid
        else:
            lo = mid + 1
    say(f"glb: {T:,} frames on a {r}-dimensional basis; candidate {lo} targets from {sample.size} frames")

    # (2) Every frame, every vertex: K = Ks, Ks + 1, ... (targets and rounding bounds a window at a time) until
    # the exact errors, the bounds and the rounding stay within the tolerance.
    every = np.arange(T)
    Ks = lo
    K = err = None
    while K is None:
        Kt = min(r, Ks + _LINEAR_WINDOW - 1)
        A = field(Vz[:, :Kt].T)  # (Kt, 3, n): the first Kt axes at the vertices
        W, Dk = _targets_from(Ct, S, A, Kt)
        rho = _rounding_bound(base, Dk, Ct, S, A, Ks, Kt)  # rho[K]: what float32 adds with K targets
        del A
        for k in range(Ks, Kt + 1):
            lim = tol - arith - float(rho[k])
            if lim < 0:  # the rounding alone is over
                continue
            ex, bd = worst(k, every, lim, lim, f"check {k} targets")
            if ex <= lim:
                if bd > ex:  # the bound is not reached: compute the pairs whose bound is above ex or half of it
                    more = worst(k, every, max(ex, bd / 2))  # too (the exact largest error when ex is the larger)
                    ex = max(ex, *more)
                K, err = k, ex + float(rho[k]) + arith
                break
        else:
            if Kt >= r:  # every axis and still above: float32 rounding of the positions themselves
                raise InputError(f"the sequence cannot be stored within {tol} (float32 rounding alone gives "
                                 f"{float(rho[r]) + arith:.3g}); use a larger tolerance", path)
            Ks = Kt + 1
    W, Dk = W[:, :K], Dk[:K]
    say(f"glb: {K} targets, every vertex of every frame within {err:.3g} ({computed[0]:,} frame-vertex pairs "
        f"computed for {T * n:,} checked)")

    # (3) The source's own frames (the first chunk and the frames farthest off) played back from the file: they
    # must agree with the structure's prediction, else the structure is not the source's and the frames are
    # streamed instead.
    W64, D64 = W.astype(np.float64), Dk.astype(np.float64)
    spot = np.arange(min(T, source.chunk_frames))
    tail = np.einsum("tk,tk->t", Ct[:, K:], Ct[:, K:])
    spot = np.union1d(spot, np.argsort(-tail, kind="stable")[:8])
    fr = _Frames(source, path, False, None)
    X = fr.rows(spot)
    played = _playback_error(base, W64[spot], D64, X, n)
    expect = float(exact(K, spot).max())
    if abs(played - expect) > float(rho[K]) + arith + 1e-6 * tol:
        say(f"glb: the frames' linear structure does not give the frames ({played:.3g} vs {expect:.3g}): streamed")
        return None
    del X
    V, F = _mesh_arrays(path, base.reshape(n, 3), faces)
    normal_frames = _normal_sample(T, K)

    def normal_rows(a: int, b: int) -> np.ndarray:
        return (base[None] + interleaved(field(Ct[normal_frames[a:b]] @ Vz.T))).reshape(-1, n, 3)

    err += _write_sequence_file(path, _played_base(base, Dk).reshape(n, 3), F, Dk.reshape(K, n, 3), W, fps, V,
                                rest, normal_rows, W[normal_frames])
    return path, {"targets": K, "max_error": float(err), "tolerance": tol, "frames": T, "rest": rest is not None}


def _targets_from(Ct: np.ndarray, S: np.ndarray, A: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    """float32 weights ``(T, K)`` and targets ``(K, 3n)`` of the first ``K`` axes ``A (>= K, 3, n)`` with
    coefficients ``Ct (T, >= K)`` (:func:`_scaled_targets`)."""
    U = Ct[:, :K] / np.where(S[:K] > 0, S[:K], 1.0)
    axes = np.ascontiguousarray(A[:K].transpose(0, 2, 1)).reshape(K, -1)
    return _scaled_targets(U, S[:K], axes)


def _rounding_bound(base: np.ndarray, Dk: np.ndarray, Ct: np.ndarray, S: np.ndarray, A: np.ndarray,
                    Ks: int, Kt: int) -> np.ndarray:
    """``(Kt + 1,)``: for each ``K`` in ``Ks .. Kt``, a bound on what float32 storage adds to any vertex of any
    frame with ``K`` targets (inf below ``Ks``).

    The file plays ``b32 + sum_k W32_tk D32_k`` for ``base + sum_k (W_tk - 1/2) D_k`` (``W``, ``D`` before
    rounding, ``b32`` the stored base): the difference at vertex ``j`` is at most
    ``|b32_j - (base - sum D32_k / 2)_j| + sum_k (2^-23 |D32_kj| + |D32_kj - D_kj| / 2)`` (weights in [0, 1]
    round by at most 2^-24).
    """
    n = base.size // 3
    U = Ct[:, :Kt] / np.where(S[:Kt] > 0, S[:Kt], 1.0)
    scale = np.abs(U).max(axis=0)
    scale[scale == 0] = 1.0
    del U
    out = np.full(Kt + 1, np.inf)
    acc = np.zeros(n)
    total = np.zeros(base.size)  # sum_{k < K} D32_k in float64, a target at a time
    for k in range(Kt + 1):
        if k >= Ks:  # the base as the file stores it (_played_base) against the base it stands for
            # the running sum is _played_base's own sum: numpy reduces the first axis of a row-major array row
            # after row, in order (tests/test_gltf_linear_bound.py checks the two agree bit for bit)
            exact = base - 0.5 * total
            beta = exact.astype(np.float32).astype(np.float64) - exact
            out[k] = float((np.sqrt(_squared_lengths(beta[None]))[0] + acc).max())
            del exact, beta
        if k == Kt:
            break
        d32 = Dk[k].astype(np.float64)
        total += d32
        d64 = (2.0 * S[k] * scale[k]) * np.ascontiguousarray(A[k].T).reshape(-1)
        acc += 2.0 ** -23 * np.sqrt(_squared_lengths(d32[None]))[0] + 0.5 * np.sqrt(
            _squared_lengths((d32 - d64)[None]))[0]
    return out


# ----------------------------------------------------------------------------- reading


def _accessor(doc, blob: bytes, index, path, what: str) -> np.ndarray:
    """The accessor's data as ``(count, components)``, every offset and size checked against the buffer.

    What :func:`read_glb_animation` reads: the ``.glb``'s own buffer only, float
    and unsigned components as stored (no ``normalized`` scaling), no sparse
    accessors, no matrices.
    """
    def own(buffer, what_):
        if buffer != 0:
            raise InputError(f"{what_}: data outside the .glb's own buffer (buffer {buffer}) is not read", path)
        return blob

    return _decode_accessor(doc, own, index, path, what, dtypes=_DTYPES, kinds=_COMPONENTS, sparse=False,
                            normalize=False, max_values=_BASE_VALUES + _VALUES_PER_BYTE * len(blob))


def _decode_accessor(doc, data_of, index, path, what: str, *, dtypes=None, kinds=None, sparse: bool = True,
                     normalize: bool = True, max_values: int | None = None) -> np.ndarray:
    """An accessor's elements as a ``(count, components)`` array, checked before anything is allocated.

    Parameters
    ----------
    doc : pygltflib.GLTF2
        The document.
    data_of : callable
        ``data_of(buffer_index, what)`` -> the bytes of a buffer (raises
        :class:`InputError` when it cannot be had).
    index : int
        The accessor.
    path : Path
        The file, for errors.
    what : str
        What the accessor holds, for errors.
    dtypes, kinds : dict, optional
        Allowed component types (code -> numpy type) and element types
        (``"VEC3"`` -> 3); every one glTF defines for vertex data by default.
    sparse : bool
        Read sparse accessors (else refuse them).
    normalize : bool
        Turn ``normalized`` integers into floats by the glTF formulas
        (``max(c / 127, -1)`` for bytes, ``c / 65535`` for unsigned shorts...).
    max_values : int, optional
        Refuse an accessor of more than this many numbers (one without a
        buffer view or a sparse one is not bounded by its data).

    Returns
    -------
    ndarray
        float64 for float or normalized components, int64 for other integers
        (float64 zeros for an accessor without a buffer view).
    """
    dtypes = _ANY_DTYPES if dtypes is None else dtypes
    kinds = _ANY_COMPONENTS if kinds is None else kinds
    if not isinstance(index, int) or not 0 <= index < len(doc.accessors or []):
        raise InputError(f"{what}: accessor {index!r} does not exist", path)
    acc = doc.accessors[index]
    ctype, kind = acc.componentType, acc.type
    if not (isinstance(ctype, int) and ctype in dtypes and isinstance(kind, str) and kind in kinds):
        raise InputError(f"{what}: unsupported accessor type {kind} / component {ctype}", path)
    if getattr(acc, "sparse", None) is not None and not sparse:
        raise InputError(f"{what}: sparse accessors are not read", path)
    dtype = np.dtype(dtypes[ctype]).newbyteorder("<")
    comps = kinds[kind]
    count = acc.count
    if not isinstance(count, int) or count < 0:
        raise InputError(f"{what}: bad accessor count {count!r}", path)
    norm = normalize and acc.normalized is True
    if norm and ctype not in _NORMALIZED:
        raise InputError(f"{what}: a normalized accessor must have byte or short components, not {ctype}", path)
    if max_values is not None and count * comps > max_values:
        raise InputError(f"{what}: {count} elements, more than a file of this size can describe", path)
    if acc.bufferView is None:
        out = np.zeros((count, comps), dtype=np.float64)
    else:
        raw = _elements(doc, data_of, acc.bufferView, acc.byteOffset, count, comps, dtype, path, what)
        out = raw.astype(np.float64 if ctype == _FLOAT or norm else np.int64)
    if acc.sparse is not None:
        out = _apply_sparse(doc, data_of, acc.sparse, out, count, comps, dtype, path, what)
    if norm:
        out = np.maximum(out / _NORMALIZED[ctype], -1.0)
    return out


def _elements(doc, data_of, view_index, byte_offset, count: int, comps: int, dtype: np.dtype, path, what: str,
              strided: bool = True) -> np.ndarray:
    """A read-only ``(count, comps)`` view of a buffer view's elements (its ``byteStride`` when ``strided``)."""
    if not isinstance(view_index, int) or not 0 <= view_index < len(doc.bufferViews or []):
        raise InputError(f"{what}: buffer view {view_index!r} does not exist", path)
    view = doc.bufferViews[view_index]
    blob = data_of(view.buffer, what)
    elem = dtype.itemsize * comps
    vstart, vlength, offset = view.byteOffset or 0, view.byteLength or 0, byte_offset or 0
    stride = (view.byteStride if strided else None) or elem
    if not all(isinstance(x, int) and x >= 0 for x in (vstart, vlength, offset, stride)) or stride < elem:
        raise InputError(f"{what}: bad buffer view offsets", path)
    start = vstart + offset
    end = start + (stride * (count - 1) + elem if count else 0)
    if end > vstart + vlength or end > len(blob):
        raise InputError(f"{what}: accessor data runs past the end of its buffer", path)
    if count == 0:
        return np.zeros((0, comps), dtype=dtype)
    return np.ndarray((count, comps), dtype=dtype, buffer=blob, offset=start, strides=(stride, dtype.itemsize))


def _apply_sparse(doc, data_of, sp, out: np.ndarray, count: int, comps: int, dtype: np.dtype, path,
                  what: str) -> np.ndarray:
    """``out`` with the sparse accessor's substituted elements written in."""
    k, idx, vals = _get(sp, "count"), _get(sp, "indices"), _get(sp, "values")
    if not isinstance(k, int) or not 1 <= k <= count or idx is None or vals is None:
        raise InputError(f"{what}: bad sparse accessor ({k!r} substitutions for {count} elements)", path)
    ictype = _get(idx, "componentType")
    if not (isinstance(ictype, int) and ictype in _INDEX_DTYPES):
        raise InputError(f"{what}: sparse indices of unsupported component {ictype!r}", path)
    itype = np.dtype(_INDEX_DTYPES[ictype]).newbyteorder("<")
    rows = _elements(doc, data_of, _get(idx, "bufferView"), _get(idx, "byteOffset"), k, 1, itype, path,
                     f"{what} sparse indices", strided=False).reshape(-1).astype(np.int64)
    if rows.max() >= count:
        raise InputError(f"{what}: sparse indices outside 0..{count - 1}", path)
    values = _elements(doc, data_of, _get(vals, "bufferView"), _get(vals, "byteOffset"), k, comps, dtype, path,
                       f"{what} sparse values", strided=False)
    out[rows] = values
    return out


def _get(obj, key: str, default=None):
    """A property of a pygltflib object or of a plain JSON object (``default`` when absent)."""
    if isinstance(obj, dict):
        return obj.get(key, default)
    return getattr(obj, key, default)


def read_glb_animation(path: str | os.PathLike) -> GlbAnimation:
    """Read the first mesh, its morph targets and its weights animation from a ``.glb``.

    Parameters
    ----------
    path : str or os.PathLike
        A glTF 2.0 binary file, as :func:`write_rig_glb` and
        :func:`write_sequence_glb` write.

    Returns
    -------
    GlbAnimation
        Neutral mesh, triangles, target deltas and names, keyframe times and
        weights (an empty ``(0, K)`` curve when the file has no weights
        animation), frame rate.

    Raises
    ------
    InputError
        Naming the file: missing, not a ``.glb``, truncated or corrupt (bad
        header, chunks, JSON, accessors or offsets outside the buffer), no
        triangle mesh, targets without positions, or an animation whose sizes
        do not match the targets; counts no character needs (as
        :func:`read_gltf_rig`), targets larger than the file or half this
        machine's memory can hold, a required extension other than those of
        materials, textures and lights (compressed or quantized data is not
        decoded here).
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", path)
    if not path.is_file():
        raise InputError("not a file (expected a .glb file)", path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    if len(data) < 20 or data[:4] != b"glTF":
        raise InputError("not a glTF binary file (no 'glTF' header)", path)
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise InputError(f"glTF binary version {version}; only version 2 is read", path)
    if length > len(data):
        raise InputError(f"truncated .glb: the header gives {length} bytes, the file has {len(data)}", path)
    text, chunk = _glb_chunks(data, path)
    tree = _json_tree(text, path)
    doc = _parse_document(tree, path, frozenset(), "read_glb_animation", "corrupt .glb")
    try:
        return _unpack(doc, chunk if chunk is not None else b"", path)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - a field of the wrong type deep in the JSON
        raise InputError(f"corrupt .glb: unexpected content ({exc.__class__.__name__})", path) from None


def _unpack(doc, blob: bytes, path: Path) -> GlbAnimation:
    if not doc.meshes or not doc.meshes[0].primitives:
        raise InputError("the .glb holds no mesh", path)
    mesh = doc.meshes[0]
    prim = mesh.primitives[0]
    if prim.mode not in (None, 4):
        raise InputError(f"the mesh is not made of triangles (mode {prim.mode})", path)
    V = _accessor(doc, blob, prim.attributes.POSITION, path, "POSITION")
    if V.shape[1] != 3 or V.shape[0] == 0:
        raise InputError("POSITION must hold 3-D vertices", path)
    n = V.shape[0]
    if prim.indices is None:
        F = np.arange(n - n % 3, dtype=np.int64).reshape(-1, 3)
    else:
        F = _accessor(doc, blob, prim.indices, path, "indices").reshape(-1)
        if F.size % 3:
            raise InputError(f"{F.size} triangle indices, not a multiple of 3", path)
        F = F.reshape(-1, 3)
    if F.size and (F.min() < 0 or F.max() >= n):
        raise InputError(f"triangles index vertices outside 0..{n - 1}", path)
    targets = prim.targets or []
    K = len(targets)
    # Every target may name the same data: the offsets' size is bounded by the file's and the machine's, first.
    if 3 * n * (K + 1) > _BASE_VALUES + _VALUES_PER_BYTE * len(blob):
        raise InputError(f"the file declares {n} vertices and {K} morph targets, more than {len(blob)} bytes of "
                         f"glTF data can hold", path)
    _check_targets_memory(K, n, 1.0, path)
    D = np.empty((K, n, 3))
    for k, tgt in enumerate(targets):
        pos = getattr(tgt, "POSITION", None) if not isinstance(tgt, dict) else tgt.get("POSITION")
        if pos is None:
            raise InputError(f"morph target {k} has no POSITION", path)
        d = _accessor(doc, blob, pos, path, f"morph target {k}")
        if d.shape != (n, 3):
            raise InputError(f"morph target {k} has {d.shape[0]} offsets for {n} vertices", path)
        D[k] = d
    extras = mesh.extras if isinstance(mesh.extras, dict) else {}
    names = extras.get("targetNames")
    if not (isinstance(names, list) and len(names) == K):
        names = [f"target{k}" for k in range(K)]
    times, W, fps = np.zeros(0), np.zeros((0, K)), None
    for anim in doc.animations or []:
        for ch in anim.channels or []:
            if ch.target is None or ch.target.path != "weights":
                continue
            if not isinstance(ch.sampler, int) or not 0 <= ch.sampler < len(anim.samplers or []):
                raise InputError(f"animation channel names sampler {ch.sampler!r}, which does not exist", path)
            smp = anim.samplers[ch.sampler]
            times = _accessor(doc, blob, smp.input, path, "animation times").reshape(-1)
            out = _accessor(doc, blob, smp.output, path, "animation weights").reshape(-1)
            per = 3 if smp.interpolation == "CUBICSPLINE" else 1
            if K == 0 or out.size != times.size * K * per:
                raise InputError(f"animation has {out.size} weights for {times.size} keyframes of {K} targets",
                                 path)
            W = out.reshape(times.size, per, K)[:, per // 2]
            ex = anim.extras if isinstance(anim.extras, dict) else {}
            f = ex.get("fps")
            if isinstance(f, (int, float)) and np.isfinite(f) and f > 0:
                fps = float(f)
            elif times.size > 1 and np.median(np.diff(times)) > 0:
                fps = float(1.0 / np.median(np.diff(times)))
            break
        if times.size:
            break
    if not (np.isfinite(V).all() and np.isfinite(D).all() and np.isfinite(W).all() and np.isfinite(times).all()):
        raise InputError("the .glb holds NaN or inf values", path)
    R, t = _node_motion(doc, blob, path, times)
    return GlbAnimation(V, F, D, tuple(str(s) for s in names), times, W, fps, str(path), R, t)


def _node_motion(doc, blob: bytes, path, times: np.ndarray):
    """The mesh node's animated rotation and translation sampled at ``times`` -> ``(R (T, 3, 3), t (T, 3))``, or
    ``(None, None)`` when its rotation and translation are not animated (or there are no weight keyframes)."""
    from scipy.spatial.transform import Rotation, Slerp

    node = next((i for i, nd in enumerate(doc.nodes or []) if getattr(nd, "mesh", None) == 0), None)
    if node is None or times.size == 0:
        return None, None
    found = {}
    for anim in doc.animations or []:
        for ch in anim.channels or []:
            tgt = ch.target
            if tgt is None or tgt.node != node or tgt.path not in ("rotation", "translation") or tgt.path in found:
                continue
            if not isinstance(ch.sampler, int) or not 0 <= ch.sampler < len(anim.samplers or []):
                raise InputError(f"animation channel names sampler {ch.sampler!r}, which does not exist", path)
            smp = anim.samplers[ch.sampler]
            ts = _accessor(doc, blob, smp.input, path, f"{tgt.path} times").reshape(-1)
            width = 4 if tgt.path == "rotation" else 3
            per = 3 if smp.interpolation == "CUBICSPLINE" else 1
            out = _accessor(doc, blob, smp.output, path, f"{tgt.path} values").reshape(-1)
            if ts.size == 0 or out.size != ts.size * per * width or not (np.isfinite(ts).all()
                                                                         and np.isfinite(out).all()):
                raise InputError(f"the node's {tgt.path} animation has {out.size} values for {ts.size} keyframes",
                                 path)
            if ts.size > 1 and not (np.diff(ts) > 0).all():
                raise InputError(f"the node's {tgt.path} keyframe times do not increase", path)
            found[tgt.path] = (ts, out.reshape(ts.size, per, width)[:, per // 2])
    if not found:
        return None, None
    T = times.size
    R = np.repeat(np.eye(3)[None], T, axis=0)
    t = np.zeros((T, 3))
    if "rotation" in found:
        ts, q = found["rotation"]
        if np.any(np.linalg.norm(q, axis=1) < 1e-6):
            raise InputError("the node's rotation animation holds a zero quaternion", path)
        rot = Rotation.from_quat(q)
        R = rot.as_matrix()[np.zeros(T, dtype=int)] if ts.size == 1 else Slerp(ts, rot)(
            np.clip(times, ts[0], ts[-1])).as_matrix()
    if "translation" in found:
        ts, v = found["translation"]
        t = np.stack([np.interp(times, ts, v[:, i]) for i in range(3)], axis=1)
    return R, t


# ----------------------------------------------------------------------------- reading a blendshape rig

#: The work a file may ask for: ``_BASE_VALUES + _VALUES_PER_BYTE * bytes`` numbers in the rig's arrays
#: (vertices x (targets + 1) x 3), counting the document and its external buffers.
_BASE_VALUES = 4_000_000
_VALUES_PER_BYTE = 64
_MODES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES", 5: "TRIANGLE_STRIP",
          6: "TRIANGLE_FAN"}
_MESHOPT = ("EXT_meshopt_compression", "KHR_meshopt_compression")
_DRACO = "KHR_draco_mesh_compression"
_DECOMPRESS = "gltf-transform copy in.glb out.glb (npm package @gltf-transform/cli)"
_ARRAYS = ("accessors", "animations", "bufferViews", "buffers", "meshes", "nodes", "scenes", "skins")
_URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")

# Counts no face rig or animation needs, refused from the JSON (``json.loads``: milliseconds) before pygltflib
# turns it into objects, which costs 0.2-0.7 ms an object (100,000 nodes, a 3.1 MB JSON: 46 s). Materials,
# textures, images, texture samplers and cameras are not read, so pygltflib is not given them and they have no
# limit. The largest documents considered: a MetaHuman exported with its body (about 1,200 joints, 800 face
# shapes with normals on the head, a few thousand accessors, a take animating every joint) and a VRoid avatar
# (about 300 nodes with its hair bones, 57 shapes on each of about 15 face primitives).

#: Nodes: a skeleton and its meshes. A MetaHuman, face and body, has about 1,200 joints, a VRoid avatar about
#: 300 nodes, a Ready Player Me avatar 70; 10,000 leaves room for a character in a small scene.
MAX_NODES = 10_000
#: Meshes: a character has tens (head, teeth, tongue, eyes, lashes, brows, hair, clothes), a few hundred with
#: every level of detail.
MAX_MESHES = 1_000
#: Primitives, over all meshes: one per material of a mesh (a VRoid face has about 15).
MAX_PRIMITIVES = 4_000
#: Accessors: each primitive's attributes and each morph target's positions, normals and tangents (a MetaHuman's
#: head alone, 800 shapes with normals: about 1,600).
MAX_ACCESSORS = 20_000
#: Buffer views: exporters write at most one per accessor.
MAX_BUFFER_VIEWS = 20_000
#: Animations (clips): a game character has tens, a library of takes a few hundred.
MAX_ANIMATIONS = 1_000
#: Animation channels, and samplers, over all clips: a take animating every joint of a MetaHuman (translation,
#: rotation, scale of 1,200 joints) has 3,600; a game character's 70 bones in 50 clips 10,000.
MAX_ANIMATION_CHANNELS = 20_000
#: Morph targets of one primitive, and blendshapes of a rig (distinct names over its meshes): ARKit has 52,
#: Ready Player Me avatars 72, FLAME's bases exported as targets 400, a MetaHuman's face about 800; no face rig
#: has a thousand. (The 10,000 targets of one audit file, sharing one buffer view, asked for 8.9 GB.)
MAX_MORPH_TARGETS = 4_096
#: Morph-target entries over all primitives (cheap objects, 10 us each): a VRoid face's 57 shapes on 15
#: primitives are 860, a MetaHuman's face on each of its 8 levels of detail 6,400.
MAX_TARGET_ENTRIES = 100_000
#: Scenes, skins and buffers, each: a file has one scene (a few at most), a skin per skinned mesh and one buffer
#: (a few with external files).
MAX_SMALL_ARRAYS = 1_000
#: All the objects above (morph-target entries aside) together: about 10 s of pygltflib on a laptop, more than
#: twice the largest character above.
MAX_JSON_OBJECTS = 30_000

#: Required extensions whose data :func:`read_gltf_rig` decodes (Draco through the optional DracoPy package).
_RIG_EXTENSIONS = frozenset({"KHR_mesh_quantization", _DRACO})
#: Required extensions that change nothing either reader reads (materials, textures, lights, metadata): a file
#: requiring them is read all the same.
_LOOKS_ONLY = frozenset({"KHR_lights_punctual", "EXT_lights_image_based", "KHR_xmp", "KHR_xmp_json_ld",
                         "KHR_techniques_webgl", "KHR_materials_variants", "EXT_texture_webp", "EXT_texture_avif",
                         "KHR_texture_basisu", "KHR_texture_transform", "MSFT_texture_dds"})
_LOOKS_ONLY_PREFIXES = ("KHR_materials_", "KHR_texture_", "EXT_texture_", "MSFT_texture_")
#: What pygltflib is given of a document: the rest is never read.
_PARSED = ("asset", "scene", "scenes", "nodes", "meshes", "accessors", "bufferViews", "buffers", "animations",
           "skins", "extensionsUsed", "extensionsRequired", "extensions", "extras")


def _megabytes(n: float) -> str:
    return f"{n / 1e6:,.1f} MB" if n < 1e9 else f"{n / 1e9:,.1f} GB"


def _check_required(tree: dict, path: Path, readable: frozenset, reader: str) -> None:
    """Refuse ``extensionsRequired`` this reader cannot honour, naming them and what to do."""
    required = tree.get("extensionsRequired", [])
    if not isinstance(required, list) or not all(isinstance(x, str) for x in required):
        raise InputError("bad glTF JSON: extensionsRequired must be a list of extension names", path)
    unread = sorted({x for x in required if x not in readable and x not in _LOOKS_ONLY
                     and not x.startswith(_LOOKS_ONLY_PREFIXES)})
    if not unread:
        return
    names = ", ".join(x[:80] for x in unread[:6]) + (f" and {len(unread) - 6} more" if len(unread) > 6 else "")
    packed = [x for x in unread if x in _MESHOPT or x == _DRACO]
    if packed:
        raise InputError(f"the file requires {names} (extensionsRequired): {reader} does not decode "
                         f"{', '.join(packed)}; export it without mesh compression, or write an uncompressed copy "
                         f"with {_DECOMPRESS}", path)
    if "KHR_mesh_quantization" in unread:
        raise InputError(f"the file requires {names} (extensionsRequired): {reader} does not decode "
                         f"KHR_mesh_quantization; export it without quantization (positions as floats)", path)
    raise InputError(f"the file requires the glTF extension{'s' if len(unread) > 1 else ''} {names} "
                     f"(extensionsRequired), which facegeom does not read; export it without "
                     f"{'them' if len(unread) > 1 else 'it'}", path)


def _check_counts(tree: dict, path: Path) -> None:
    """Refuse counts no face rig or animation needs (see :data:`MAX_NODES` and the others), from the JSON alone."""
    for key in _ARRAYS:
        if key in tree and not (isinstance(tree[key], list) and all(isinstance(x, dict) for x in tree[key])):
            raise InputError(f"bad glTF JSON: {key!r} must be a list of objects", path)

    def refuse(count: int, what: str, limit: int, why: str):
        if count > limit:
            raise InputError(f"{count} {what}, more than the {limit:,} {why}: refused before reading", path)

    def items(obj, key) -> list:
        value = obj.get(key)
        return value if isinstance(value, list) else []

    nodes, meshes = tree.get("nodes", []), tree.get("meshes", [])
    accessors, views, anims = tree.get("accessors", []), tree.get("bufferViews", []), tree.get("animations", [])
    refuse(len(nodes), "nodes", MAX_NODES, "a character with its skeleton needs")
    refuse(len(meshes), "meshes", MAX_MESHES, "a character needs")
    prims = [p for m in meshes for p in items(m, "primitives")]
    refuse(len(prims), "mesh primitives", MAX_PRIMITIVES, "a character needs")
    refuse(len(accessors), "accessors", MAX_ACCESSORS, "a character and its blendshapes need")
    refuse(len(views), "bufferViews", MAX_BUFFER_VIEWS, "a character and its blendshapes need")
    refuse(len(anims), "animations", MAX_ANIMATIONS, "a character's clips need")
    channels = sum(len(items(a, "channels")) for a in anims)
    samplers = sum(len(items(a, "samplers")) for a in anims)
    refuse(channels, "animation channels", MAX_ANIMATION_CHANNELS, "a character's clips need")
    refuse(samplers, "animation samplers", MAX_ANIMATION_CHANNELS, "a character's clips need")
    entries = 0
    for mi, mesh in enumerate(meshes):
        for pj, prim in enumerate(items(mesh, "primitives")):
            k = len(items(prim, "targets")) if isinstance(prim, dict) else 0
            refuse(k, f"morph targets on mesh {mi} primitive {pj}", MAX_MORPH_TARGETS, "a face rig has")
            entries += k
    refuse(entries, "morph targets over all primitives", MAX_TARGET_ENTRIES, "a character's meshes have")
    for key in ("scenes", "skins", "buffers"):
        refuse(len(tree.get(key, [])), key, MAX_SMALL_ARRAYS, "a character needs")
    total = (len(nodes) + len(meshes) + len(prims) + len(accessors) + len(views) + len(anims) + channels + samplers
             + sum(len(tree.get(key, [])) for key in ("scenes", "skins", "buffers")))
    refuse(total, "glTF objects (nodes, meshes, accessors, buffer views, animation channels ...)", MAX_JSON_OBJECTS,
           "a character needs in all")


def _parse_document(tree: dict, path: Path, readable: frozenset, reader: str, corrupt: str):
    """The pygltflib document of a parsed JSON ``tree``: counts and required extensions checked first, and only
    what is read handed to pygltflib."""
    _check_counts(tree, path)
    _check_required(tree, path, readable, reader)
    try:
        import pygltflib

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # from_json (not from_dict): it turns primitives' attributes into pygltflib's Attributes
            doc = pygltflib.GLTF2.from_json(json.dumps({k: v for k, v in tree.items() if k in _PARSED}),
                                            infer_missing=True)
    except Exception as exc:  # noqa: BLE001 - pygltflib raises anything on JSON of the wrong shape
        raise InputError(f"{corrupt}: unexpected content ({exc.__class__.__name__})", path) from None
    return doc


def _check_targets_memory(K: int, n: int, copies: float, path: Path, what: str = "") -> None:
    """Refuse ``K`` morph targets of ``n`` vertices when their float64 offsets (``copies`` of ``K x n x 3``) need
    more than :func:`facegeom.io.npzcheck.memory_budget` (half this machine's memory)."""
    if K > MAX_MORPH_TARGETS:
        raise InputError(f"{what}{K} morph targets, more than the {MAX_MORPH_TARGETS:,} a face rig has: refused "
                         f"before reading", path)
    need = int(copies * K * n * 3 * 8)
    budget = memory_budget()
    if need > budget:
        raise InputError(f"{what}{K} morph targets of {n:,} vertices need {_megabytes(need)}, more than this "
                         f"machine can spare ({_megabytes(budget)}, half of its memory)", path)


@dataclass(frozen=True)
class RigPart:
    """One placed primitive of a :class:`GltfRig`: its slices of the vertex and face arrays.

    Attributes
    ----------
    name : str
        The node's name, else the mesh's, else ``mesh{i}.prim{j}``; with
        ``.prim{j}`` appended for a mesh of several primitives and ``.1``,
        ``.2`` ... for a name already taken.
    vertex_start, vertex_stop : int
        Its vertices are ``neutral[vertex_start:vertex_stop]``.
    face_start, face_stop : int
        Its triangles are ``faces[face_start:face_stop]``.
    has_targets : bool
        The primitive has morph targets (a part without them has zero deltas).
    """

    name: str
    vertex_start: int
    vertex_stop: int
    face_start: int
    face_stop: int
    has_targets: bool


@dataclass(frozen=True, eq=False)
class GltfRig:
    """A blendshape rig read from a glTF file: every placed mesh of the scene in one vertex array.

    Attributes
    ----------
    neutral : (n, 3) float64
        Rest positions, in the scene's frame (each node's world transform applied).
    faces : (m, 3) int64
        Triangles (strips and fans triangulated).
    deltas : (K, n, 3) float64
        Morph-target position offsets, in the scene's frame; zero on a part
        without a target of that name.
    names : tuple of K str
        Distinct target names, in the order first met.
    parts : tuple of RigPart
        The placed primitives, in scene order.
    units : str
        ``"m"``: glTF positions are metres by definition (the file does not say).
    up_axis : str
        ``"+y"``: glTF is Y-up by definition.
    path : str
        The file read.

    The arrays are read-only.
    """

    neutral: np.ndarray
    faces: np.ndarray
    deltas: np.ndarray
    names: tuple[str, ...]
    parts: tuple[RigPart, ...]
    units: str = "m"
    up_axis: str = "+y"
    path: str = ""

    def part(self, name: str) -> RigPart:
        """The part called ``name`` (``KeyError`` when there is none)."""
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(name)


def read_gltf_rig(path: str | os.PathLike, mesh: str | list[str] | None = None, *,
                  require_targets: bool = True) -> GltfRig:
    """Read a blendshape rig from a glTF 2.0 file (``.glb``, or ``.gltf`` with external or embedded buffers).

    Every mesh placed by the default scene's nodes is read, with the node's
    world transform (``matrix`` or translation / rotation / scale, down the
    hierarchy) applied to its positions and morph-target offsets; a mesh placed
    by two nodes is read twice, a mesh no node of the scene places is left
    out. Skinned meshes are placed by their joints at the file's pose (the
    skinned node's own transform is ignored, as glTF says). Morph targets are
    matched across meshes by name (``mesh.extras.targetNames``, else
    ``target{k}``): one ``jawOpen`` moves the face and the teeth.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.glb`` or ``.gltf`` file. A ``.gltf``'s external buffers must be
        files in its folder (or below it), named by relative paths; data URIs
        are read, URLs and absolute paths are refused (nothing is downloaded).
    mesh : str or list of str, optional
        Read only the meshes with these names (mesh or node names), e.g. to
        leave out hair or clothes.
    require_targets : bool
        False: a scene without morph targets is read too (a bare head for
        ``facegeom transfer``; its ``deltas`` are then ``(0, n, 3)``).

    Returns
    -------
    GltfRig
        Neutral mesh, triangles, target deltas and names, the parts.

    Raises
    ------
    InputError
        One line naming the file: missing, not glTF, bad JSON or ``.glb``
        chunks, accessors outside their buffers or larger than the file can
        describe, counts that disagree, NaN or inf positions, points or lines
        primitives, no mesh with triangles, no morph targets ("no blendshapes
        (morph targets)", unless ``require_targets`` is False), a buffer
        outside the folder or not a regular file (a pipe, a device),
        compressed geometry that cannot be decoded here
        (``EXT_meshopt_compression``; Draco without the optional ``DracoPy``
        package), an unknown ``mesh`` name; counts no character needs
        (:data:`MAX_NODES` and the others), more than
        :data:`MAX_MORPH_TARGETS` blendshapes or offsets larger than half this
        machine's memory, an ``extensionsRequired`` entry it cannot honour.

    Notes
    -----
    Supported: sparse accessors (with or without a base buffer view),
    ``normalized`` integers and ``KHR_mesh_quantization`` (integer positions
    and offsets, dequantised by the glTF formulas), interleaved buffer views,
    triangle strips and fans, several primitives, meshes and buffers, and
    ``KHR_draco_mesh_compression`` when ``DracoPy`` is installed (``pip install
    DracoPy``). The mesh's default ``weights`` are not applied: ``neutral`` is
    the base mesh. Required extensions of materials, textures and lights are
    ignored (nothing read depends on them); any other required extension
    than the two above is refused, naming it.
    """
    path = Path(path)
    wanted = _wanted_meshes(mesh, path)
    doc, buffers, size = _load_gltf(path)
    try:
        with np.errstate(all="ignore"):  # overflow in a transform ends as inf, refused below
            return _build_rig(doc, buffers, size, path, wanted, require_targets)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001 - a field of the wrong type deep in the JSON
        raise InputError(f"corrupt glTF: unexpected content ({exc.__class__.__name__})", path) from None


def _wanted_meshes(mesh, path: Path) -> set[str] | None:
    if mesh is None:
        return None
    names = [mesh] if isinstance(mesh, str) else mesh
    try:
        names = list(names)
    except TypeError:
        names = None
    if not names or not all(isinstance(n, str) for n in names):
        raise InputError(f"mesh must be a mesh name or a non-empty list of names, got {mesh!r}", path)
    return set(names)


def _load_gltf(path: Path):
    """``(doc, buffers, bytes)``: the parsed document, its buffer reader and the bytes behind it."""
    if not path.exists():
        raise InputError("file not found", path)
    if not path.is_file():
        raise InputError("not a file (expected a .glb or .gltf file)", path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    if not data:
        raise InputError("empty file", path)
    if data[:4] == b"glTF":
        text, chunk = _glb_chunks(data, path)
    elif data.lstrip()[:1] in (b"{", b"\xef"):
        text, chunk = data, None
    else:
        raise InputError("not a glTF file (neither a .glb 'glTF' header nor JSON)", path)
    tree = _json_tree(text, path)
    doc = _parse_document(tree, path, _RIG_EXTENSIONS, "read_gltf_rig", "corrupt glTF JSON")
    buffers = _Buffers(doc, path, chunk)
    return doc, buffers, len(data) + buffers.external_bytes()


def _json_tree(text, path: Path) -> dict:
    """The glTF JSON (bytes of a ``.gltf`` or of a ``.glb``'s JSON chunk) as a dict, a glTF 2.0 document."""
    try:
        text = bytes(text).decode("utf-8-sig")
        tree = json.loads(text)
    except UnicodeDecodeError:
        raise InputError("bad JSON: not UTF-8 text", path) from None
    except json.JSONDecodeError as exc:
        raise InputError(f"bad JSON: {exc.msg} (line {exc.lineno}, column {exc.colno})", path) from None
    except RecursionError:
        raise InputError("bad JSON: nested too deeply", path) from None
    if not isinstance(tree, dict):
        raise InputError("bad JSON: the top level is not an object", path)
    asset = tree.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if isinstance(version, str) and not version.startswith("2"):
        raise InputError(f"glTF version {version!r}; only glTF 2.0 is read", path)
    return tree


def _glb_chunks(data: bytes, path: Path) -> tuple[memoryview, memoryview | None]:
    """The JSON chunk and the BIN chunk (``None`` if absent) of a ``.glb``, every length checked."""
    if len(data) < 20:
        raise InputError(f"truncated .glb: {len(data)} bytes", path)
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise InputError(f"glTF binary version {version}; only version 2 is read", path)
    if length > len(data):
        raise InputError(f"truncated .glb: the header gives {length} bytes, the file has {len(data)}", path)
    view = memoryview(data)
    size, kind = struct.unpack_from("<II", data, 12)
    if kind != 0x4E4F534A:
        raise InputError("corrupt .glb: the first chunk is not JSON", path)
    if 20 + size > length:
        raise InputError("corrupt .glb: the JSON chunk runs past the end of the file", path)
    text, chunk, at = view[20:20 + size], None, 20 + size
    while at + 8 <= length:
        size, kind = struct.unpack_from("<II", data, at)
        if at + 8 + size > length:
            raise InputError("corrupt .glb: a chunk runs past the end of the file", path)
        if kind == 0x004E4942 and chunk is None:
            chunk = view[at + 8:at + 8 + size]
        at += 8 + size
    return text, chunk


def _open_regular(target: Path, uri: str, index: int, path: Path):
    """``target`` opened for reading in binary, refused unless it is a regular file: opening a named pipe would
    wait for a writer (forever), a device could give endless bytes. Opened without waiting (``O_NONBLOCK``) and
    checked on the open file, so a file swapped for a pipe after a first look is refused too."""
    import stat

    refuse = InputError(f"buffer {index}: {uri[:80]!r} is not a regular file (a pipe, a device or a folder); only "
                        f"files next to the document are read", path)
    if not stat.S_ISREG(os.stat(target).st_mode):
        raise refuse
    fd = os.open(target, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise refuse
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


class _Buffers:
    """The document's buffers, each read when first needed: the BIN chunk, data URIs, files beside the document."""

    def __init__(self, doc, path: Path, chunk):
        self.doc, self.path, self.chunk = doc, path, chunk
        self.cache: dict[int, memoryview] = {}

    def external_bytes(self) -> int:
        """Total size of the external buffer files that would be read (0 for those that would be refused)."""
        total = 0
        for i, buf in enumerate(self.doc.buffers or []):
            uri = getattr(buf, "uri", None)
            if isinstance(uri, str) and not uri.startswith("data:"):
                try:
                    total += self._file(uri, i).stat().st_size
                except (InputError, OSError, ValueError):
                    pass
        return total

    def _file(self, uri: str, index: int) -> Path:
        """The file a relative URI names, refused if it is a URL or leaves the document's folder."""
        if _URI_SCHEME.match(uri) or uri.startswith(("//", "\\\\")):
            raise InputError(f"buffer {index}: uri {uri[:80]!r} is a URL or a drive path; only files next to "
                             f"the document and data: URIs are read (nothing is downloaded)", self.path)
        if "?" in uri or "#" in uri:
            raise InputError(f"buffer {index}: uri {uri[:80]!r} has URL parameters; only plain relative file "
                             f"paths are read", self.path)
        name = PurePosixPath(unquote(uri).replace("\\", "/"))
        folder = self.path.parent.resolve()
        if name.is_absolute() or ".." in name.parts:
            raise InputError(f"buffer {index}: uri {uri[:80]!r} points outside the document's folder; only "
                             f"files in it are read", self.path)
        target = (folder / name).resolve()
        if not target.is_relative_to(folder):
            raise InputError(f"buffer {index}: uri {uri[:80]!r} leads outside the document's folder (a link); "
                             f"only files in it are read", self.path)
        return target

    def __call__(self, index, what: str):
        if isinstance(index, int) and index in self.cache:
            return self.cache[index]
        buffers = self.doc.buffers or []
        if not isinstance(index, int) or not 0 <= index < len(buffers):
            raise InputError(f"{what}: buffer {index!r} does not exist", self.path)
        buf = buffers[index]
        ext = buf.extensions if isinstance(buf.extensions, dict) else {}
        used = self.doc.extensionsUsed if isinstance(self.doc.extensionsUsed, list) else []
        meshopt = next((e for e in _MESHOPT if isinstance(ext.get(e), dict) and ext[e].get("fallback")), None)
        if meshopt is None and buf.uri is None and not (index == 0 and self.chunk is not None):
            meshopt = next((e for e in _MESHOPT if e in used), None)  # a buffer without data: the compressed one's
        if meshopt is not None:
            raise InputError(f"{what}: the data is compressed with {meshopt}, which is not decoded here; write "
                             f"an uncompressed copy with {_DECOMPRESS}", self.path)
        length = buf.byteLength
        if not isinstance(length, int) or length < 0:
            raise InputError(f"buffer {index}: bad byteLength {length!r}", self.path)
        uri = buf.uri
        if uri is None:
            if index != 0 or self.chunk is None:
                raise InputError(f"buffer {index} has no data (no uri and no .glb BIN chunk)", self.path)
            data = self.chunk
        elif not isinstance(uri, str):
            raise InputError(f"buffer {index}: uri {uri!r} is not a string", self.path)
        elif uri.startswith("data:"):
            head, comma, payload = uri.partition(",")
            if not comma or not head.endswith(";base64"):
                raise InputError(f"buffer {index}: a data URI must be base64 ('data:...;base64,...')", self.path)
            try:
                data = memoryview(base64.b64decode(payload, validate=True))
            except (binascii.Error, ValueError):
                raise InputError(f"buffer {index}: the data URI is not valid base64", self.path) from None
        else:
            target = self._file(uri, index)
            try:
                with _open_regular(target, uri, index, self.path) as fh:
                    data = memoryview(fh.read(length))
            except InputError:
                raise
            except FileNotFoundError:
                raise InputError(f"buffer {index}: {uri[:80]!r} not found next to the document", self.path) \
                    from None
            except (OSError, ValueError) as exc:
                raise InputError(f"buffer {index}: cannot read {uri[:80]!r}: {getattr(exc, 'strerror', None) or exc}",
                                 self.path) from None
        if len(data) < length:
            raise InputError(f"buffer {index} holds {len(data)} bytes, fewer than its byteLength {length}",
                             self.path)
        self.cache[index] = data[:length]
        return self.cache[index]


# ----------------------------------------------------------------------------- the scene


def _numbers(value, n: int, what: str, path: Path) -> np.ndarray:
    """``n`` finite numbers from the JSON, else one error."""
    if not isinstance(value, (list, tuple)) or len(value) != n or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        raise InputError(f"{what} must be {n} numbers", path)
    out = np.array(value, dtype=np.float64)
    if not np.isfinite(out).all():
        raise InputError(f"{what} holds NaN or inf", path)
    return out


def _local_matrix(node, i: int, path: Path) -> np.ndarray:
    """The node's 4x4 transform: ``matrix`` (column-major) or ``T @ R @ S``."""
    if node.matrix is not None:
        return _numbers(node.matrix, 16, f"node {i} matrix", path).reshape(4, 4).T
    M = np.eye(4)
    if node.rotation is not None:
        q = _numbers(node.rotation, 4, f"node {i} rotation", path)
        big = np.abs(q).max()
        if big == 0:
            raise InputError(f"node {i} rotation is a zero quaternion", path)
        x, y, z, w = (q / big) / np.linalg.norm(q / big)
        M[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    if node.scale is not None:
        M[:3, :3] = M[:3, :3] * _numbers(node.scale, 3, f"node {i} scale", path)[None, :]
    if node.translation is not None:
        M[:3, 3] = _numbers(node.translation, 3, f"node {i} translation", path)
    return M


class _Scene:
    """The node tree: parents checked (a tree, no cycles), world transforms on demand."""

    def __init__(self, doc, path: Path):
        self.doc, self.path = doc, path
        self.nodes = doc.nodes or []
        n = len(self.nodes)
        self.parent = [-1] * n
        for i, node in enumerate(self.nodes):
            children = node.children or []
            if not isinstance(children, list):
                raise InputError(f"node {i}: children must be a list", path)
            for c in children:
                if not isinstance(c, int) or not 0 <= c < n:
                    raise InputError(f"node {i}: child {c!r} does not exist", path)
                if self.parent[c] != -1 or c == i:
                    raise InputError(f"node {c} has more than one parent (the node hierarchy must be a tree)", path)
                self.parent[c] = i
        self.world_cache: dict[int, np.ndarray] = {}

    def world(self, i: int) -> np.ndarray:
        """Node ``i``'s world transform (its ancestors' and its own)."""
        chain = []
        j = i
        while j != -1 and j not in self.world_cache:
            chain.append(j)
            if len(chain) > len(self.nodes):
                raise InputError(f"node {i} is its own ancestor (the node hierarchy has a cycle)", self.path)
            j = self.parent[j]
        M = self.world_cache[j] if j != -1 else np.eye(4)
        for k in reversed(chain):
            M = M @ _local_matrix(self.nodes[k], k, self.path)
            self.world_cache[k] = M
        return self.world_cache[i]

    def placed(self) -> list[tuple[int | None, int]]:
        """``(node, mesh)`` for every mesh the default scene places, depth first (node ``None``: no nodes)."""
        doc, path = self.doc, self.path
        scenes = doc.scenes or []
        if scenes:
            s = 0 if doc.scene is None else doc.scene
            if not isinstance(s, int) or not 0 <= s < len(scenes):
                raise InputError(f"scene {s!r} does not exist", path)
            roots = scenes[s].nodes or []
            if not isinstance(roots, list):
                raise InputError(f"scene {s}: nodes must be a list", path)
        elif self.nodes:  # no scene: every root node
            roots = [i for i in range(len(self.nodes)) if self.parent[i] == -1]
        else:  # no nodes either: every mesh as it is
            return [(None, m) for m in range(len(doc.meshes or []))]
        out, seen = [], set()
        stack = list(reversed(roots))
        while stack:
            i = stack.pop()
            if not isinstance(i, int) or not 0 <= i < len(self.nodes):
                raise InputError(f"the scene names node {i!r}, which does not exist", path)
            if i in seen:
                raise InputError(f"node {i} is reached twice from the scene (the node hierarchy must be a tree)",
                                 path)
            seen.add(i)
            node = self.nodes[i]
            if node.mesh is not None:
                if not isinstance(node.mesh, int) or not 0 <= node.mesh < len(doc.meshes or []):
                    raise InputError(f"node {i}: mesh {node.mesh!r} does not exist", path)
                out.append((i, node.mesh))
            stack.extend(reversed(node.children or []))
        return out


# ----------------------------------------------------------------------------- geometry


@dataclass
class _Geometry:
    """One primitive in its mesh's own frame."""

    V: np.ndarray                    # (n, 3)
    F: np.ndarray                    # (m, 3)
    targets: list                    # K entries: (n, 3) offsets or None (no POSITION offsets)
    names: list[str]                 # K distinct names
    label: str


def _label(doc, mi: int, pj: int) -> str:
    name = doc.meshes[mi].name
    return f"mesh {mi} ({name!r}) primitive {pj}" if isinstance(name, str) and name else f"mesh {mi} primitive {pj}"


def _primitive(doc, mi: int, pj: int, path: Path):
    prims = doc.meshes[mi].primitives
    if not isinstance(prims, list) or not 0 <= pj < len(prims):
        raise InputError(f"mesh {mi} has no primitive {pj}", path)
    return prims[pj]


def _check_mode(doc, mi: int, pj: int, path: Path) -> int:
    mode = _primitive(doc, mi, pj, path).mode
    mode = 4 if mode is None else mode
    if mode in (0, 1, 2, 3):
        raise InputError(f"{_label(doc, mi, pj)} draws {_MODES[mode]}, not triangles; leave its mesh out by "
                         f"naming the meshes to read (mesh=...)", path)
    if mode not in (4, 5, 6):
        raise InputError(f"{_label(doc, mi, pj)} has unknown mode {mode!r}", path)
    return mode


def _declared_count(doc, mi: int, pj: int, path: Path) -> int:
    """The primitive's vertex count as its POSITION accessor declares it (nothing read)."""
    pos = _get(_primitive(doc, mi, pj, path).attributes, "POSITION")
    accessors = doc.accessors or []
    if not isinstance(pos, int) or not 0 <= pos < len(accessors):
        raise InputError(f"{_label(doc, mi, pj)}: no POSITION accessor", path)
    count = accessors[pos].count
    if not isinstance(count, int) or count < 0:
        raise InputError(f"{_label(doc, mi, pj)} POSITION: bad accessor count {count!r}", path)
    return count


def _target_names(mesh, prim, K: int) -> list[str]:
    """``targetNames`` of the mesh (or primitive) extras when there are ``K``, else ``target{k}``; made distinct."""
    given = None
    for holder in (mesh, prim):
        extras = holder.extras if isinstance(holder.extras, dict) else {}
        names = extras.get("targetNames")
        if isinstance(names, list) and len(names) == K:
            given = names
            break
    out, seen, suffix = [], set(), {}
    for k in range(K):
        name = given[k] if given is not None and isinstance(given[k], str) and given[k] else f"target{k}"
        base = name
        while name in seen:
            suffix[base] = suffix.get(base, 0) + 1
            name = f"{base}.{suffix[base]}"
        seen.add(name)
        out.append(name)
    return out


def _triangles(idx: np.ndarray, mode: int, label: str, path: Path) -> np.ndarray:
    """Triangles from a primitive's vertex indices (glTF 2.0, "Topology types"); strips' degenerate ones dropped."""
    k = idx.size
    if mode == 4:
        if k % 3:
            raise InputError(f"{label}: {k} triangle indices, not a multiple of 3", path)
        return idx.reshape(-1, 3)
    if k < 3:
        raise InputError(f"{label}: {_MODES[mode]} of {k} indices (at least 3 are needed)", path)
    i = np.arange(k - 2)
    if mode == 5:
        odd = i % 2
        F = np.stack([idx[i], idx[i + 1 + odd], idx[i + 2 - odd]], axis=1)
    else:
        F = np.stack([idx[i + 1], idx[i + 2], np.full(k - 2, idx[0])], axis=1)
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
    return F[keep]


def _geometry(doc, data_of, mi: int, pj: int, path: Path, budget: int) -> _Geometry:
    """Decode one primitive: positions, triangles, morph-target offsets (its own frame)."""
    mesh = doc.meshes[mi]
    prim = _primitive(doc, mi, pj, path)
    label = _label(doc, mi, pj)
    mode = _check_mode(doc, mi, pj, path)
    pos = _get(prim.attributes, "POSITION")
    exts = prim.extensions if isinstance(prim.extensions, dict) else {}
    if exts.get(_DRACO) is not None and doc.accessors[pos].bufferView is None:
        V, F = _draco(doc, data_of, exts[_DRACO], pos, label, path, budget)
    else:
        V = _decode_accessor(doc, data_of, pos, path, f"{label} POSITION", kinds={"VEC3": 3},
                             max_values=budget).astype(np.float64)
        if prim.indices is None:
            idx = np.arange(V.shape[0], dtype=np.int64)
        else:
            idx = _decode_accessor(doc, data_of, prim.indices, path, f"{label} indices", dtypes=_INDEX_DTYPES,
                                   kinds={"SCALAR": 1}, normalize=False, max_values=budget)
            idx = idx.reshape(-1).astype(np.int64)
        F = _triangles(idx, mode, label, path)
    n = V.shape[0]
    if F.size and n == 0:
        raise InputError(f"{label}: triangles but no vertices", path)
    if F.size and (F.min() < 0 or F.max() >= n):
        raise InputError(f"{label}: triangles index vertices outside 0..{n - 1}", path)
    if not np.isfinite(V).all():
        raise InputError(f"{label}: POSITION holds NaN or inf", path)
    targets_json = prim.targets or []
    if not isinstance(targets_json, list):
        raise InputError(f"{label}: targets must be a list", path)
    targets = []
    for k, tgt in enumerate(targets_json):
        index = _get(tgt, "POSITION")
        if index is None:
            targets.append(None)
            continue
        d = _decode_accessor(doc, data_of, index, path, f"{label} morph target {k}", kinds={"VEC3": 3},
                             max_values=budget).astype(np.float64)
        if d.shape[0] != n:
            raise InputError(f"{label} morph target {k} has {d.shape[0]} offsets for the primitive's {n} vertices",
                             path)
        if not np.isfinite(d).all():
            raise InputError(f"{label} morph target {k} holds NaN or inf", path)
        targets.append(d)
    return _Geometry(V, F.astype(np.int64), targets, _target_names(mesh, prim, len(targets)), label)


def _draco(doc, data_of, ext, pos: int, label: str, path: Path, budget: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions and triangles of a ``KHR_draco_mesh_compression`` primitive, decoded by DracoPy."""
    try:
        import DracoPy
    except ImportError:
        raise InputError(f"{label} is compressed with {_DRACO}: install the optional decoder (pip install DracoPy) "
                         f"or write an uncompressed copy with {_DECOMPRESS}", path) from None
    acc = doc.accessors[pos]
    count = acc.count
    if not isinstance(count, int) or count < 0 or 3 * count > budget:
        raise InputError(f"{label} POSITION: bad or too large accessor count {count!r}", path)
    attrs = ext.get("attributes") if isinstance(ext, dict) else None
    uid = attrs.get("POSITION") if isinstance(attrs, dict) else None
    view = ext.get("bufferView") if isinstance(ext, dict) else None
    if not isinstance(uid, int) or not isinstance(view, int) or not 0 <= view < len(doc.bufferViews or []):
        raise InputError(f"{label}: bad {_DRACO} extension (bufferView, attributes.POSITION)", path)
    length = doc.bufferViews[view].byteLength
    if not isinstance(length, int) or length <= 0:
        raise InputError(f"{label}: the Draco buffer view is empty", path)
    raw = _elements(doc, data_of, view, 0, length, 1, np.dtype(np.uint8), path, f"{label} Draco data", strided=False)
    try:
        decoded = DracoPy.decode(raw.tobytes())
        faces = getattr(decoded, "faces", None)
        attr = decoded.get_attribute_by_unique_id(uid)
    except Exception:  # noqa: BLE001 - the decoder's own errors
        raise InputError(f"{label}: the Draco data cannot be decoded", path) from None
    if faces is None or attr is None:
        raise InputError(f"{label}: the Draco data holds no triangle mesh with attribute {uid}", path)
    P = np.asarray(attr.get("data"))
    if P.ndim != 2 or P.shape != (count, 3):
        raise InputError(f"{label}: the Draco data holds {P.shape[0] if P.ndim else 0} positions, "
                         f"the POSITION accessor {count}", path)
    if acc.normalized is True and acc.componentType in _NORMALIZED and np.issubdtype(P.dtype, np.integer):
        P = np.maximum(P / _NORMALIZED[acc.componentType], -1.0)
    return P.astype(np.float64), np.asarray(faces, dtype=np.int64).reshape(-1, 3)


# ----------------------------------------------------------------------------- placing


def _skin_transform(doc, scene: _Scene, data_of, node: int, geom: _Geometry, mi: int, pj: int, path: Path,
                    budget: int):
    """The skinned primitive's transform at the file's pose: one 4x4, or ``(n, 4, 4)`` per vertex."""
    skins = doc.skins or []
    s = scene.nodes[node].skin
    if not isinstance(s, int) or not 0 <= s < len(skins):
        raise InputError(f"node {node}: skin {s!r} does not exist", path)
    joints = skins[s].joints or []
    if not isinstance(joints, list) or not joints or not all(
            isinstance(j, int) and 0 <= j < len(scene.nodes) for j in joints):
        raise InputError(f"skin {s}: joints must be a non-empty list of nodes", path)
    J = len(joints)
    if skins[s].inverseBindMatrices is None:
        inverse = np.broadcast_to(np.eye(4), (J, 4, 4))
    else:
        A = _decode_accessor(doc, data_of, skins[s].inverseBindMatrices, path, f"skin {s} inverseBindMatrices",
                             dtypes={_FLOAT: np.float32}, kinds={"MAT4": 16}, max_values=budget)
        if A.shape[0] < J:
            raise InputError(f"skin {s}: {A.shape[0]} inverse bind matrices for {J} joints", path)
        inverse = A[:J].reshape(J, 4, 4).transpose(0, 2, 1)
    S = np.stack([scene.world(j) for j in joints]) @ inverse
    if not np.isfinite(S).all():
        raise InputError(f"skin {s}: joint transforms are not finite", path)
    if np.abs(S - S[0]).max() <= 1e-6 * max(1.0, np.abs(S[0]).max()):
        return S[0]  # the bind pose: one rigid transform
    n = geom.V.shape[0]
    prim = _primitive(doc, mi, pj, path)
    M = np.zeros((n, 4, 4))
    total = np.zeros(n)
    k = 0
    while _get(prim.attributes, f"JOINTS_{k}") is not None:
        what = f"{geom.label} JOINTS_{k} / WEIGHTS_{k}"
        ji = _decode_accessor(doc, data_of, _get(prim.attributes, f"JOINTS_{k}"), path, what,
                              dtypes={_UBYTE: np.uint8, _USHORT: np.uint16}, kinds={"VEC4": 4}, normalize=False,
                              max_values=budget)
        wi = _get(prim.attributes, f"WEIGHTS_{k}")
        w = _decode_accessor(doc, data_of, wi, path, what, kinds={"VEC4": 4}, max_values=budget) \
            if wi is not None else None
        if w is None or ji.shape[0] != n or w.shape[0] != n:
            raise InputError(f"{what}: joints and weights must both be given for the {n} vertices", path)
        if ji.size and ji.max() >= J:
            raise InputError(f"{what}: joint indices outside the skin's {J} joints", path)
        ji = ji.astype(np.int64)
        for c in range(4):
            M += w[:, c, None, None] * S[ji[:, c]]
        total += w.sum(axis=1)
        k += 1
    if k == 0:
        raise InputError(f"{geom.label}: a skinned mesh away from its bind pose needs JOINTS_0 and WEIGHTS_0", path)
    ok = total > 0
    M[ok] /= total[ok, None, None]
    M[~ok] = S[0]
    return M


def _place(geom: _Geometry, T: np.ndarray):
    """Positions and triangles moved by ``T`` (4x4, or (n, 4, 4) per vertex; winding kept outward), and the map
    moving an offset array of the primitive (applied one target at a time: no second copy of them all)."""
    if T.ndim == 2:
        L = T[:3, :3]
        V = geom.V @ L.T + T[:3, 3]
        det = np.linalg.det(L)

        def move(d):
            return d @ L.T
    else:
        L = T[:, :3, :3]
        V = np.einsum("nij,nj->ni", L, geom.V) + T[:, :3, 3]
        det = np.linalg.det(L.mean(axis=0))

        def move(d):
            return np.einsum("nij,nj->ni", L, d)
    F = geom.F[:, [0, 2, 1]] if det < 0 else geom.F
    return V, F, move


def _build_rig(doc, data_of, size: int, path: Path, wanted: set[str] | None, require_targets: bool = True) -> GltfRig:
    budget = _BASE_VALUES + _VALUES_PER_BYTE * size
    scene = _Scene(doc, path)
    placed = scene.placed()
    if wanted is not None:
        def names_of(node, mi):
            out = (doc.meshes[mi].name, None if node is None else scene.nodes[node].name)
            return {x for x in out if isinstance(x, str)}

        kept = [(node, mi) for node, mi in placed if names_of(node, mi) & wanted]
        found = set().union(*(names_of(node, mi) for node, mi in kept)) if kept else set()
        missing = sorted(wanted - found)
        if missing:
            have = sorted({x for node, mi in placed for x in names_of(node, mi)})
            shown = ", ".join(repr(x) for x in have[:12]) + (", ..." if len(have) > 12 else "")
            raise InputError(f"no mesh or node named {', '.join(repr(x) for x in missing)} in the scene "
                             f"(it has: {shown or 'none'})", path)
        placed = kept
    # Plan: parts, names and sizes from the JSON alone, checked against the file's size before decoding.
    plan, union, total, held, uses = [], {}, 0, {}, {}
    for node, mi in placed:
        prims = doc.meshes[mi].primitives
        if not isinstance(prims, list):
            raise InputError(f"mesh {mi}: primitives must be a list", path)
        for pj in range(len(prims)):
            _check_mode(doc, mi, pj, path)
            count = _declared_count(doc, mi, pj, path)
            total += count
            targets = prims[pj].targets or []
            names = _target_names(doc.meshes[mi], prims[pj], len(targets) if isinstance(targets, list) else 0)
            for name in names:
                union.setdefault(name, len(union))
            held[(mi, pj)] = len(names) * count
            uses[(mi, pj)] = uses.get((mi, pj), 0) + 1
            plan.append((node, mi, pj))
    if not plan or total == 0:
        raise InputError("no mesh with triangles in the scene", path)
    K = len(union)
    if K == 0 and require_targets:
        raise InputError("no blendshapes (morph targets)", path)
    if 3 * total * (K + 1) > budget:
        raise InputError(f"the file declares {total} vertices and {K} blendshapes, more than {size} bytes of "
                         f"glTF data can hold", path)
    # Memory: the rig's offsets (K x vertices x 3 float64) and, at most, every primitive's own decoded offsets
    # (kept while a node still has to place them).
    _check_targets_memory(K, total, 1.0 + sum(held.values()) / max(K * total, 1), path, "the scene's ")
    deltas = np.zeros((K, total, 3))
    # Decode each primitive once, place it for every node that uses it; its offsets go straight into ``deltas``.
    cache: dict[tuple[int, int], _Geometry] = {}
    Vs, Fs, parts, used = [], [], [], {}
    nv = nf = 0
    for node, mi, pj in plan:
        if (mi, pj) not in cache:
            cache[(mi, pj)] = _geometry(doc, data_of, mi, pj, path, budget)
        geom = cache[(mi, pj)]
        uses[(mi, pj)] -= 1
        if uses[(mi, pj)] == 0:  # the last node placing it: not kept past this
            del cache[(mi, pj)]
        if node is None:
            T = np.eye(4)
        elif scene.nodes[node].skin is not None:
            T = _skin_transform(doc, scene, data_of, node, geom, mi, pj, path, budget)
        else:
            T = scene.world(node)
        V, F, move = _place(geom, T)
        nodename = scene.nodes[node].name if node is not None else None
        meshname = doc.meshes[mi].name
        base = next((x for x in (nodename, meshname) if isinstance(x, str) and x), None)
        nprims = len(doc.meshes[mi].primitives)
        name = (base if nprims == 1 else f"{base}.prim{pj}") if base else f"mesh{mi}.prim{pj}"
        base = name
        while name in used:
            used[base] = used.get(base, 0) + 1
            name = f"{base}.{used[base]}"
        used.setdefault(name, 0)
        n, m = V.shape[0], F.shape[0]
        if nv + n > total:  # pragma: no cover - a primitive has the vertices its POSITION accessor declares
            raise InputError(f"{geom.label}: more vertices than its POSITION accessor declares", path)
        parts.append(RigPart(name, nv, nv + n, nf, nf + m, bool(geom.targets)))
        Vs.append(V)
        Fs.append(F + nv)
        for d, target in zip(geom.targets, geom.names):
            if d is not None:
                deltas[union[target], nv:nv + d.shape[0]] = move(d)
        del geom
        nv, nf = nv + n, nf + m
    if nf == 0:
        raise InputError("no mesh with triangles in the scene", path)
    if nv != total:  # pragma: no cover - as above
        deltas = deltas[:, :nv]
    neutral = np.concatenate(Vs)
    if not (np.isfinite(neutral).all() and np.isfinite(deltas).all()):
        raise InputError("positions are not finite after the node transforms", path)
    faces = np.concatenate(Fs).astype(np.int64)
    for a in (neutral, faces, deltas):
        a.flags.writeable = False
    return GltfRig(neutral, faces, deltas, tuple(union), tuple(parts), path=str(path))
