"""glTF 2.0 binary (``.glb``) out: a blendshape rig with a weights animation, or a vertex sequence as morph targets.

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
"""
from __future__ import annotations

import os
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path

__all__ = ["GlbAnimation", "write_rig_glb", "write_sequence_glb", "read_glb_animation", "DEFAULT_TOLERANCE"]

#: Default bound of :func:`write_sequence_glb`: 0.01 mesh units, 0.1 mm on the ICT face (in cm).
DEFAULT_TOLERANCE = 0.01

_FLOAT, _UINT, _USHORT, _UBYTE = 5126, 5125, 5123, 5121
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES = {_FLOAT: np.float32, _UINT: np.uint32, _USHORT: np.uint16, _UBYTE: np.uint8}


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

    def frames(self) -> np.ndarray:
        """``(T, n, 3)`` vertex positions at each keyframe: neutral + weights @ deltas."""
        K, n = self.deltas.shape[:2]
        return self.neutral + (self.weights @ self.deltas.reshape(K, 3 * n)).reshape(-1, n, 3)


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
    """A growing binary buffer of 4-byte-aligned buffer views and their accessors."""

    def __init__(self, pygltflib):
        self.g = pygltflib
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list = []
        self.accessors: list = []

    def add(self, array: np.ndarray, kind: str, component: int, target: int | None = None,
            bounds: bool = False) -> int:
        data = np.ascontiguousarray(array).tobytes()
        self.views.append(self.g.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data), target=target))
        pad = -len(data) % 4
        self.parts.append(data + b"\0" * pad)
        self.size += len(data) + pad
        acc = self.g.Accessor(bufferView=len(self.views) - 1, byteOffset=0, componentType=component,
                              count=int(array.shape[0]), type=kind)
        if bounds:
            flat = array.reshape(array.shape[0], -1)
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _write_glb(path: Path, V: np.ndarray, F: np.ndarray, deltas: np.ndarray, names, weights: np.ndarray,
               fps: float, generator: str) -> Path:
    """Build and write the document (arrays already checked)."""
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
    i_nrm = blob.add(_vertex_normals(V, F.astype(np.int64)), "VEC3", _FLOAT, _ARRAY_BUFFER)
    D32 = deltas.astype(np.float32)
    targets = [g.Attributes(POSITION=blob.add(D32[k], "VEC3", _FLOAT, _ARRAY_BUFFER, bounds=True))
               for k in range(K)]
    times = (np.arange(T, dtype=np.float64) / fps).astype(np.float32)
    if T > 1 and not (np.diff(times) > 0).all():
        raise InputError(f"{T} frames at {fps} fps give keyframe times that float32 cannot keep apart", path)
    i_t = blob.add(times, "SCALAR", _FLOAT, bounds=True)
    i_w = blob.add(weights.astype(np.float32).reshape(-1), "SCALAR", _FLOAT)
    prim = g.Primitive(attributes=g.Attributes(POSITION=i_pos, NORMAL=i_nrm), indices=i_idx, mode=g.TRIANGLES,
                       targets=targets)
    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator=generator),
        scene=0,
        scenes=[g.Scene(nodes=[0])],
        nodes=[g.Node(mesh=0, name="face")],
        meshes=[g.Mesh(primitives=[prim], weights=[0.0] * K, name="face",
                       extras={"targetNames": [str(n) for n in names]})],
        animations=[g.Animation(
            name="weights",
            samplers=[g.AnimationSampler(input=i_t, output=i_w, interpolation="LINEAR")],
            channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))],
            extras={"fps": fps})],
        accessors=blob.accessors,
        bufferViews=blob.views,
        buffers=[g.Buffer(byteLength=blob.size)],
    )
    doc.set_binary_blob(blob.bytes())
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            for chunk in doc.save_to_bytes():
                fh.write(chunk)
    return path


def _check_suffix(path: Path) -> None:
    if path.suffix.lower() != ".glb":
        raise InputError(f"a glTF binary file must end in .glb, got {path.suffix or 'no suffix'!r}", path)


def write_rig_glb(path: str | os.PathLike, neutral, faces, deltas, shape_names, weights, fps: float) -> Path:
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

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        A suffix other than ``.glb``; shapes that disagree; NaN or inf; faces
        outside the vertices; a frame rate that is not positive; names that
        are not ``K``; an output folder that does not exist.
    """
    path = Path(path)
    _check_suffix(path)
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
    if not (np.isfinite(D).all() and np.isfinite(W).all()):
        raise InputError("deltas or weights contain NaN or inf", path)
    return _write_glb(path, V, F, D, names, W, _check_fps(path, fps), "facegeom write_rig_glb")


def write_sequence_glb(path: str | os.PathLike, frames, faces, fps: float,
                       tolerance: float = DEFAULT_TOLERANCE) -> tuple[Path, dict]:
    """Write a driven vertex sequence as a ``.glb``: mean mesh + K SVD morph targets + their weight curves.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.glb`` file.
    frames : array_like
        ``(T, n, 3)`` vertex positions.
    faces : array_like
        ``(m, 3)`` integer triangles.
    fps : float
        Frame rate of the sequence.
    tolerance : float
        Error bound in the mesh's units: every vertex of every frame, as the
        file plays it back (float32), lies within ``tolerance`` of the input.
        The default 0.01 is 0.1 mm on the ICT face (in cm).

    Returns
    -------
    (Path, dict)
        ``path`` and ``{"targets": K, "max_error": e, "tolerance": tolerance,
        "frames": T}`` with ``K`` the smallest number of targets meeting the
        bound (found by bisection on K; the per-frame residual never grows
        with K) and ``e`` the largest vertex error of the written file.

    Raises
    ------
    InputError
        As :func:`write_rig_glb`, plus frames that are not ``(T, n, 3)`` or
        hold NaN or inf, and a tolerance that is not a positive number.
    """
    path = Path(path)
    _check_suffix(path)
    X = np.asarray(frames, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] == 0:
        raise InputError(f"frames must have shape (T, n, 3) with T > 0, got {X.shape}", path)
    if not np.isfinite(X).all():
        raise InputError("frames contain NaN or inf", path)
    tol = float(tolerance)
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"tolerance {tolerance} is not a positive number", path)
    T, n = X.shape[:2]
    base = X.mean(axis=0)
    V, F = _mesh_arrays(path, base, faces)
    fps = _check_fps(path, fps)
    D = (X - base).reshape(T, 3 * n)
    # Axes below tol / (4 sqrt(T)) are never needed: together they move no frame by more than tol / 4.
    U, S = _principal_axes(D, tol / (4.0 * np.sqrt(T)))
    C = U * S  # (T, r) coefficients of each frame on the axes
    V32 = base.astype(np.float32).astype(np.float64)
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
        scale = np.abs(U[:, :k]).max(axis=0)  # weights in [-1, 1], the targets carry the size
        scale[scale == 0] = 1.0
        W = (U[:, :k] / scale).astype(np.float32)
        Dk = ((S[:k] * scale)[:, None] * axes(k)).astype(np.float32)
        W64, D64 = W.astype(np.float64), Dk.astype(np.float64)
        if every:
            rows, step = np.arange(T), 256
        else:  # worst frames first, stopping at the first chunk over the bound
            rows = np.flatnonzero(resid[:, k - 1] > tol / 2)
            rows, step = rows[np.argsort(-resid[rows, k - 1])], 128
        err = 0.0
        for a in range(0, rows.size, step):  # the played-back frames, in chunks to bound memory
            r = rows[a:a + step]
            played = V32.reshape(1, -1) + W64[r] @ D64
            err = max(err, float(np.sqrt(((played - Xf[r]).reshape(-1, n, 3) ** 2).sum(axis=2)).max()))
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
    names = [f"svd{k:03d}" for k in range(K)]
    _write_glb(path, V, F, Dk.reshape(K, n, 3), names, W, fps, "facegeom write_sequence_glb")
    return path, {"targets": K, "max_error": err, "tolerance": tol, "frames": T}


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


# ----------------------------------------------------------------------------- reading


def _accessor(doc, blob: bytes, index, path, what: str) -> np.ndarray:
    """The accessor's data as ``(count, components)``, every offset and size checked against the buffer."""
    if not isinstance(index, int) or not 0 <= index < len(doc.accessors or []):
        raise InputError(f"{what}: accessor {index!r} does not exist", path)
    acc = doc.accessors[index]
    if acc.componentType not in _DTYPES or acc.type not in _COMPONENTS:
        raise InputError(f"{what}: unsupported accessor type {acc.type} / component {acc.componentType}", path)
    if getattr(acc, "sparse", None) is not None:
        raise InputError(f"{what}: sparse accessors are not read", path)
    dtype = np.dtype(_DTYPES[acc.componentType]).newbyteorder("<")
    comps = _COMPONENTS[acc.type]
    count = acc.count
    if not isinstance(count, int) or count < 0:
        raise InputError(f"{what}: bad accessor count {count!r}", path)
    if acc.bufferView is None:
        return np.zeros((count, comps), dtype=np.float64)
    if not isinstance(acc.bufferView, int) or not 0 <= acc.bufferView < len(doc.bufferViews or []):
        raise InputError(f"{what}: buffer view {acc.bufferView!r} does not exist", path)
    view = doc.bufferViews[acc.bufferView]
    if view.buffer != 0:
        raise InputError(f"{what}: data outside the .glb's own buffer (buffer {view.buffer}) is not read", path)
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    elem = dtype.itemsize * comps
    stride = view.byteStride or elem
    if not all(isinstance(x, int) and x >= 0 for x in (start, stride, view.byteLength or 0)) or stride < elem:
        raise InputError(f"{what}: bad buffer view offsets", path)
    end = start + (stride * (count - 1) + elem if count else 0)
    if end > (view.byteOffset or 0) + (view.byteLength or 0) or end > len(blob):
        raise InputError(f"{what}: accessor data runs past the end of its buffer", path)
    raw = np.ndarray((count, comps), dtype=dtype, buffer=blob, offset=start, strides=(stride, dtype.itemsize))
    return raw.astype(np.float64 if acc.componentType == _FLOAT else np.int64)


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
        do not match the targets.
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
    try:
        import pygltflib

        with warnings.catch_warnings():  # pygltflib warns about unknown chunks: the errors below say enough
            warnings.simplefilter("ignore")
            doc = pygltflib.GLTF2.load_from_bytes(data[:length])
            blob = doc.binary_blob() if doc is not None else None
    except Exception as exc:  # noqa: BLE001 - pygltflib raises anything on a corrupt file
        raise InputError(f"corrupt .glb: {exc.__class__.__name__}", path) from None
    if doc is None:
        raise InputError("corrupt .glb: no JSON chunk", path)
    try:
        return _unpack(doc, blob or b"", path)
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
    deltas = []
    for k, tgt in enumerate(prim.targets or []):
        pos = getattr(tgt, "POSITION", None) if not isinstance(tgt, dict) else tgt.get("POSITION")
        if pos is None:
            raise InputError(f"morph target {k} has no POSITION", path)
        d = _accessor(doc, blob, pos, path, f"morph target {k}")
        if d.shape != (n, 3):
            raise InputError(f"morph target {k} has {d.shape[0]} offsets for {n} vertices", path)
        deltas.append(d)
    K = len(deltas)
    D = np.stack(deltas) if K else np.zeros((0, n, 3))
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
    return GlbAnimation(V, F, D, tuple(str(s) for s in names), times, W, fps, str(path))
