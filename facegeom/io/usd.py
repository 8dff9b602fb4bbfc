"""USD (OpenUSD, UsdSkel): blendshape rigs and their animation out as ``.usda`` / ``.usdc`` / ``.usdz``, and in.

:func:`write_rig_usd` writes one stage (with the optional ``usd-core`` package, ``pip install facegeom[usd]``):

* stage metadata: ``upAxis`` (``Y`` by default), ``metersPerUnit`` (0.01: the ICT face is in cm),
  ``timeCodesPerSecond`` = ``framesPerSecond`` = ``fps``, ``startTimeCode`` 0 and ``endTimeCode`` ``T - 1``
  (frame ``t`` of the weights is time code ``t``);
* ``/Face``, a ``SkelRoot`` and the default prim, holding

  - ``/Face/Skeleton``: a ``Skeleton`` of one joint, ``head``, with identity bind and rest transforms; its
    ``skel:animationSource`` is the animation below;
  - ``/Face/Mesh``: a ``Mesh`` (triangles; ``points``; vertex-interpolated unit ``normals`` of the neutral;
    ``subdivisionScheme = "none"``) with the ``SkelBindingAPI``: rigidly bound to the head (``primvars:skel:
    jointIndices`` all 0 and ``jointWeights`` all 1, vertex interpolation; identity ``geomBindTransform``;
    ``skel:skeleton``), its ``skel:blendShapes`` and ``skel:blendShapeTargets``;
  - ``/Face/Mesh/<name>``: one ``BlendShape`` per shape: ``offsets`` (and ``normalOffsets`` when given); a shape
    moving fewer than half the vertices is stored sparse (``pointIndices``);
  - ``/Face/Animation``: a ``SkelAnimation`` (only when there are weights): ``blendShapes`` and time-sampled
    ``blendShapeWeights``; with a head motion also ``joints = ["head"]`` and time-sampled ``rotations`` (quatf),
    ``translations`` and ``scales`` (ones). Without a motion the joint keeps its rest transform (identity).

Shape names. USD prim names must be identifiers; the ``BlendShape`` prims and the ``skel:blendShapes`` /
``blendShapes`` tokens use the same sanitised name (``Tf.MakeValidIdentifier``, made unique with ``_1``, ``_2``
...). ARKit names (``jawOpen``) and ICT names (``mouthSmile_L``) are identifiers already and are kept as they
are. The original names are always stored, in order, in the mesh's ``customData["facegeom:shapeNames"]``, and
:func:`read_usd_rig` returns them (else the tokens).

A head motion ``(R_t, t_t)`` moves vertex ``v`` to ``R_t v + t_t`` (the file's units): the joint's local
transform at time ``t``.

:func:`read_usd_rig` reads a rig back (this module's files and other UsdSkel blendshape rigs); every problem
with the file is an :class:`~facegeom.errors.InputError` of one line naming it. :func:`usd_validation_errors`
runs usd-core's validators (what ``usdchecker`` runs) on a file.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path
from facegeom.io.gltf import _check_fps, _mesh_arrays, _vertex_normals

__all__ = ["MAX_POINTS", "READ_SECONDS", "USD_SUFFIXES", "UsdRig", "read_usd_rig", "unit_name",
           "usd_validation_errors", "write_rig_usd"]

#: Suffixes :func:`write_rig_usd` writes (``.usd`` is read too).
USD_SUFFIXES = (".usda", ".usdc", ".usdz")
#: :func:`read_usd_rig` refuses a mesh with more points than this.
MAX_POINTS = 5_000_000
#: ... more face-vertex indices than this,
MAX_INDICES = 30_000_000
#: ... more animation frames than this,
MAX_FRAMES = 1_000_000
#: ... more than this many numbers in the deltas (K n 3) or in the weights (T K).
MAX_VALUES = 400_000_000

#: :func:`read_usd_rig` (isolated) stops usd-core after this many seconds on one file.
READ_SECONDS = 600

_ROOT, _SKEL, _MESH, _ANIM, _JOINT = "Face", "Skeleton", "Mesh", "Animation", "head"
_NAMES_KEY = "facegeom:shapeNames"


def unit_name(meters_per_unit: float) -> str | None:
    """A stage's ``metersPerUnit`` as facegeom's unit name (``"m"``, ``"cm"``, ``"mm"``), None for any other."""
    for name, m in (("m", 1.0), ("cm", 0.01), ("mm", 0.001)):
        if abs(float(meters_per_unit) - m) <= 1e-9 * m:
            return name
    return None


def _pxr(path) -> None:
    """InputError naming ``path`` when usd-core is not installed."""
    try:
        import pxr.Usd  # noqa: F401
    except ImportError:
        raise InputError("USD files need the usd-core package (pip install usd-core)", path) from None


@dataclass
class UsdRig:
    """A blendshape rig (and its animation) as read from a USD file.

    Attributes
    ----------
    neutral : (n, 3) float64
        The mesh's points (its own space; transforms above it are not applied).
    faces : (m, 3) int64
        Triangles (polygons split fan-wise).
    deltas : (K, n, 3) float64
        Blend shape offsets (sparse shapes expanded; zero elsewhere).
    names : tuple of K str
        Shape names: ``customData["facegeom:shapeNames"]`` when it holds ``K`` strings, else the mesh's
        ``skel:blendShapes`` tokens.
    weights : (T, K) float64 or None
        The animation's weights in the mesh's shape order (a shape it does not animate is 0) at ``T`` frames one
        time code apart from its first sample; None without an animation.
    fps : float or None
        The stage's ``timeCodesPerSecond`` when there are weights, else None.
    rotations : (T, 3, 3) float64 or None
        The head joint's (the skeleton's first joint) animated rotations, when the animation has them.
    translations : (T, 3) float64 or None
        Its translations (zeros when only rotations are animated).
    meters_per_unit : float
        The stage's ``metersPerUnit`` (0.01 when not authored).
    up_axis : str
        The stage's ``upAxis``, ``"Y"`` or ``"Z"``.
    normal_deltas : (K, n, 3) float64 or None
        ``normalOffsets`` of the shapes when any shape has them (zeros for the others).
    path : str
        The file read.
    """

    neutral: np.ndarray
    faces: np.ndarray
    deltas: np.ndarray
    names: tuple[str, ...]
    weights: np.ndarray | None
    fps: float | None
    rotations: np.ndarray | None
    translations: np.ndarray | None
    meters_per_unit: float
    up_axis: str
    normal_deltas: np.ndarray | None = None
    path: str = ""

    def frames(self) -> np.ndarray:
        """``(T, n, 3)`` played vertices: ``R_t (neutral + w_t @ deltas) + t_t`` (no motion: identity)."""
        if self.weights is None:
            raise ValueError("the rig has no animation")
        K, n = self.deltas.shape[:2]
        X = self.neutral + (self.weights @ self.deltas.reshape(K, 3 * n)).reshape(-1, n, 3)
        if self.rotations is not None:
            X = np.einsum("tij,tnj->tni", self.rotations, X) + self.translations[:, None, :]
        return X


# ----------------------------------------------------------------------------- writing


def _valid_names(Tf, names: list[str]) -> list[str]:
    out, seen = [], set()
    for name in names:
        base = Tf.MakeValidIdentifier(name) if name else "_"
        candidate, i = base, 0
        while candidate in seen:
            i += 1
            candidate = f"{base}_{i}"
        seen.add(candidate)
        out.append(candidate)
    return out


def _check_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in USD_SUFFIXES:
        raise InputError(f"a USD file must end in .usda, .usdc or .usdz, got {path.suffix or 'no suffix'!r}", path)
    return suffix


def _quaternions(path, R: np.ndarray) -> np.ndarray:
    """``(T, 4)`` x, y, z, w of proper rotations, consecutive ones on the same side (interpolation's short way)."""
    from scipy.spatial.transform import Rotation

    if not (np.abs(np.einsum("tij,tkj->tik", R, R) - np.eye(3)).max() < 1e-6 and (np.linalg.det(R) > 0).all()):
        raise InputError("the head rotations are not proper rotations", path)
    q = Rotation.from_matrix(R).as_quat()
    flip = np.r_[1.0, np.sign(np.cumprod(np.sign(np.einsum("ti,ti->t", q[1:], q[:-1]) + 1e-300)))]
    return q * flip[:, None]


def write_rig_usd(path: str | os.PathLike, neutral, faces, deltas, shape_names, weights=None, fps: float = 30.0,
                  rotations=None, translations=None, normal_deltas=None, meters_per_unit: float = 0.01,
                  up_axis: str = "Y") -> Path:
    """Write a blendshape rig, and optionally its animation, as a UsdSkel stage (``.usda``, ``.usdc``, ``.usdz``).

    Parameters
    ----------
    path : str or os.PathLike
        The file; its suffix picks the format: ``.usda`` text, ``.usdc`` binary (crate), ``.usdz`` a package
        holding one ``.usdc`` layer. Written atomically (a temporary file in the same folder, then renamed).
    neutral : array_like
        ``(n, 3)`` rest positions (stored as float32).
    faces : array_like
        ``(m, 3)`` integer triangles.
    deltas : array_like
        ``(K, n, 3)`` blendshape offsets from ``neutral`` (``K`` may be 0).
    shape_names : sequence of str
        ``K`` names (see the module notes for names that are not USD identifiers).
    weights : array_like, optional
        ``(T, K)`` weights, frame ``t`` at time code ``t``; None writes a rig without animation.
    fps : float
        Frames per second: the stage's ``timeCodesPerSecond`` and ``framesPerSecond``.
    rotations, translations : array_like, optional
        ``(T, 3, 3)`` proper rotations and ``(T, 3)`` translations (the file's units) of the head per frame: the
        joint the mesh is bound to turns and moves with them (vertex ``v`` goes to ``R v + t``). Both or
        neither; they need ``weights``.
    normal_deltas : array_like, optional
        ``(K, n, 3)`` normal offsets per shape (``normalOffsets``).
    meters_per_unit : float
        The stage's ``metersPerUnit`` (0.01: centimetres, the ICT face's unit).
    up_axis : str
        ``"Y"`` or ``"Z"``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        A suffix other than ``.usda`` / ``.usdc`` / ``.usdz``; an output folder that does not exist; shapes
        that disagree; NaN or inf; faces outside the vertices; names that are not ``K``; a frame rate or unit
        that is not positive; an up axis other than Y or Z; a head motion that is not ``T`` proper rotations and
        translations or comes without weights; usd-core not installed.
    """
    path = Path(path)
    suffix = _check_suffix(path)
    if not path.parent.is_dir() and str(path.parent):
        raise InputError("output folder does not exist", path.parent)
    V, F = _mesh_arrays(path, neutral, faces)
    n = V.shape[0]
    D = np.asarray(deltas, dtype=np.float64)
    if D.ndim != 3 or D.shape[1:] != (n, 3):
        raise InputError(f"deltas must have shape (K, {n}, 3), got {D.shape}", path)
    K = D.shape[0]
    if isinstance(shape_names, str):
        raise InputError("shape names must be a sequence of strings, got one string", path)
    names = [str(s) for s in shape_names]
    if len(names) != K:
        raise InputError(f"{len(names)} shape names for {K} blendshapes", path)
    if not np.isfinite(D).all():
        raise InputError("deltas contain NaN or inf", path)
    N = None
    if normal_deltas is not None:
        N = np.asarray(normal_deltas, dtype=np.float64)
        if N.shape != D.shape or not np.isfinite(N).all():
            raise InputError(f"normal deltas must be finite with the deltas' shape {D.shape}, got {N.shape}", path)
    fps = _check_fps(path, fps)
    try:
        mpu = float(meters_per_unit)
    except (TypeError, ValueError):
        raise InputError(f"meters per unit {meters_per_unit!r} is not a number", path) from None
    if not (np.isfinite(mpu) and mpu > 0):
        raise InputError(f"meters per unit {meters_per_unit} is not a positive number", path)
    axis = str(up_axis).upper()
    if axis not in ("Y", "Z"):
        raise InputError(f"up axis must be Y or Z, got {up_axis!r}", path)
    W = None
    if weights is not None:
        W = np.asarray(weights, dtype=np.float64)
        if W.ndim != 2 or W.shape[1] != K or W.shape[0] == 0:
            raise InputError(f"weights must have shape (T, {K}) with T > 0, got {W.shape}", path)
        if not np.isfinite(W).all():
            raise InputError("weights contain NaN or inf", path)
    if (rotations is None) != (translations is None):
        raise InputError("the head motion needs both rotations and translations", path)
    motion = None
    if rotations is not None:
        if W is None:
            raise InputError("a head motion needs weights (its frames are theirs)", path)
        T = W.shape[0]
        R = np.asarray(rotations, dtype=np.float64)
        t = np.asarray(translations, dtype=np.float64)
        if R.shape != (T, 3, 3) or t.shape != (T, 3) or not (np.isfinite(R).all() and np.isfinite(t).all()):
            raise InputError(f"the head motion must be {T} finite rotations (T, 3, 3) and translations (T, 3), got "
                             f"{R.shape} and {t.shape}", path)
        motion = (_quaternions(path, R), t)
    _pxr(path)
    from pxr import Sdf, UsdUtils
    stage = _build_stage(V, F, D, names, W, fps, motion, N, mpu, axis)
    with atomic_path(path) as tmp:
        if suffix == ".usdz":
            with tempfile.TemporaryDirectory() as folder:
                layer = Path(folder) / f"{path.stem or 'rig'}.usdc"
                stage.GetRootLayer().Export(str(layer))
                if not UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(layer)), str(tmp)):
                    raise InputError("usd-core could not write the .usdz package", path)
        elif not stage.GetRootLayer().Export(str(tmp)):
            raise InputError("usd-core could not write the file", path)  # pragma: no cover
    return path


def _build_stage(V, F, D, names, W, fps, motion, N, mpu, axis):
    """An in-memory stage holding the rig (arrays checked)."""
    from pxr import Gf, Tf, Usd, UsdGeom, UsdSkel, Vt
    n, K = V.shape[0], D.shape[0]
    tokens = _valid_names(Tf, names)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if axis == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    root = UsdSkel.Root.Define(stage, f"/{_ROOT}")
    stage.SetDefaultPrim(root.GetPrim())
    skel_path = root.GetPath().AppendChild(_SKEL)
    skel = UsdSkel.Skeleton.Define(stage, skel_path)
    skel.CreateJointsAttr(Vt.TokenArray([_JOINT]))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0)]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([Gf.Matrix4d(1.0)]))

    mesh = UsdGeom.Mesh.Define(stage, root.GetPath().AppendChild(_MESH))
    V32 = np.ascontiguousarray(V, dtype=np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(V32))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(F.shape[0], 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(F.reshape(-1), dtype=np.int32)))
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(_vertex_normals(V, F.astype(np.int64)))))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, V32.min(axis=0))),
                                         Gf.Vec3f(*map(float, V32.max(axis=0)))]))
    mesh.GetPrim().SetCustomDataByKey(_NAMES_KEY, Vt.StringArray(names))

    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel_path])
    binding.CreateJointIndicesPrimvar(False, 1).Set(Vt.IntArray.FromNumpy(np.zeros(n, dtype=np.int32)))
    binding.CreateJointWeightsPrimvar(False, 1).Set(Vt.FloatArray.FromNumpy(np.ones(n, dtype=np.float32)))
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1.0))
    if K:
        targets = []
        for k, token in enumerate(tokens):
            shape = UsdSkel.BlendShape.Define(stage, mesh.GetPath().AppendChild(token))
            d32 = np.ascontiguousarray(D[k], dtype=np.float32)
            moved = np.flatnonzero(np.any(d32 != 0, axis=1))
            nd = None if N is None else np.ascontiguousarray(N[k], dtype=np.float32)
            if nd is not None:
                moved = np.union1d(moved, np.flatnonzero(np.any(nd != 0, axis=1)))
            if moved.size < n // 2:  # sparse
                shape.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(moved.astype(np.int32)))
                d32 = np.ascontiguousarray(d32[moved])
                nd = None if nd is None else np.ascontiguousarray(nd[moved])
            shape.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy(d32.reshape(-1, 3)))
            if nd is not None:
                shape.CreateNormalOffsetsAttr(Vt.Vec3fArray.FromNumpy(nd.reshape(-1, 3)))
            targets.append(shape.GetPath())
        binding.CreateBlendShapesAttr(Vt.TokenArray(tokens))
        binding.CreateBlendShapeTargetsRel().SetTargets(targets)

    if W is not None:
        T = W.shape[0]
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(T - 1)
        anim = UsdSkel.Animation.Define(stage, root.GetPath().AppendChild(_ANIM))
        UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
        anim.CreateBlendShapesAttr(Vt.TokenArray(tokens))
        w_attr = anim.CreateBlendShapeWeightsAttr()
        W32 = W.astype(np.float32)
        for t in range(T):
            w_attr.Set(Vt.FloatArray.FromNumpy(np.ascontiguousarray(W32[t])), Usd.TimeCode(t))
        if motion is not None:
            q, tr = motion
            anim.CreateJointsAttr(Vt.TokenArray([_JOINT]))
            r_attr, t_attr, s_attr = anim.CreateRotationsAttr(), anim.CreateTranslationsAttr(), anim.CreateScalesAttr()
            for t in range(T):
                x, y, z, w = (float(c) for c in q[t])
                r_attr.Set(Vt.QuatfArray([Gf.Quatf(w, Gf.Vec3f(x, y, z))]), Usd.TimeCode(t))
                t_attr.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, tr[t]))]), Usd.TimeCode(t))
                s_attr.Set(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)]), Usd.TimeCode(t))
    return stage


# ----------------------------------------------------------------------------- validation


def usd_validation_errors(path: str | os.PathLike) -> tuple[list[str], list[str]]:
    """Run every validator usd-core registers (``usdchecker``'s checks) on a USD file.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.usda``, ``.usdc``, ``.usd`` or ``.usdz`` file.

    Returns
    -------
    (list of str, list of str)
        The errors and the warnings, one line each (``validator: message``).

    Raises
    ------
    InputError
        The file cannot be opened as a USD stage; usd-core not installed.
    """
    _pxr(path)
    from pxr import UsdValidation

    stage = _open(path)
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors, warnings = [], []
    for e in UsdValidation.ValidationContext(validators).Validate(stage):
        if e.HasNoError():
            continue
        line = f"{e.GetName()}: {e.GetMessage()}".replace("\n", " ")
        (errors if e.GetType() == UsdValidation.ValidationErrorType.Error else warnings).append(line)
    return errors, warnings


# ----------------------------------------------------------------------------- reading


class _Bad(Exception):
    """A problem with the file (becomes an InputError naming it)."""


def _open(path):
    """The stage of ``path`` (payloads not loaded); InputError when it is missing or not USD."""
    _pxr(path)
    from pxr import Sdf, Tf, Usd
    p = Path(path)
    if not p.is_file():
        raise InputError("no such file" if not p.exists() else "not a file", path)
    if p.suffix.lower() not in (*USD_SUFFIXES, ".usd"):
        raise InputError(f"not a USD file (the suffix must be .usd, .usda, .usdc or .usdz, got "
                         f"{p.suffix or 'none'!r})", path)
    try:
        cached = Sdf.Layer.Find(str(p))
        if cached:  # a layer still held from an earlier read: read the file as it is now
            cached.Reload(True)
        stage = Usd.Stage.Open(str(p), Usd.Stage.LoadNone)
    except Tf.ErrorException as exc:
        raise InputError(f"not a readable USD file ({_first_line(exc)})", path) from None
    if stage is None:
        raise InputError("not a readable USD file", path)
    return stage


def _first_line(exc: BaseException) -> str:
    """The first line of what ``exc`` says (a USD error's commentary), at most 200 characters; never raises."""
    texts = []
    for arg in getattr(exc, "args", ()) or (exc,):
        try:
            texts.append(str(getattr(arg, "commentary", None) or arg))
        except Exception:  # noqa: BLE001 - a message that is not UTF-8 (it quotes the file's bytes)
            texts.append("a message quoting bytes that are not UTF-8")
    lines = [s.strip() for t in texts for s in t.splitlines() if s.strip() and not s.strip().startswith("Error in")]
    return (lines[0] if lines else type(exc).__name__)[:200]


def read_usd_rig(path: str | os.PathLike, *, isolated: bool = True) -> UsdRig:
    """Read a blendshape rig and its animation from a USD file (``.usda``, ``.usdc``, ``.usd``, ``.usdz``).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    isolated : bool
        Read in a child process (a fresh interpreter), so that a crash of usd-core's native reader
        on a malformed file (a corrupt ``.usdc`` crate can make it read out of bounds) is an InputError, not the
        end of this process. False: read here (only for files known to be sound).

    Returns
    -------
    UsdRig
        The first ``Mesh`` under a ``SkelRoot`` with blend shape targets (else the first ``Mesh``: a rig with
        no shapes), its shapes (sparse ``pointIndices`` expanded; inbetweens ignored), the animation its
        skeleton's ``skel:animationSource`` (or the mesh's) names, sampled every time code from the first time
        sample to the last, weights reordered to the mesh's ``skel:blendShapes`` by name; the stage's units and
        up axis.

    Raises
    ------
    InputError
        One line naming the file: a missing file, not USD, no mesh, points NaN or inf or too many (more than
        :data:`MAX_POINTS`), polygons with fewer than 3 vertices or face indices out of range, blend shape
        offsets whose count disagrees with the points (or their point indices), weights whose count disagrees
        with the animation's shapes, non-finite weights or motion; usd-core crashing or running more than
        :data:`READ_SECONDS` on the file (isolated); usd-core not installed.
    """
    _pxr(path)
    if isolated:
        return _read_in_child(path)
    return _read_here(path)


def _read_here(path) -> UsdRig:
    """:func:`read_usd_rig` in this process."""
    _pxr(path)
    from pxr import Tf
    stage = _open(path)
    try:
        return _read(stage, path)
    except _Bad as exc:
        raise InputError(str(exc), path) from None
    except Tf.ErrorException as exc:
        raise InputError(f"USD error: {_first_line(exc)}", path) from None
    except (ValueError, TypeError, OverflowError, RuntimeError) as exc:  # e.g. a value of the wrong type
        if isinstance(exc, InputError):
            raise
        raise InputError(f"malformed USD data ({type(exc).__name__}: {_first_line(exc)})", path) from None


_CHILD = """
import os, pickle, sys
sys.path.insert(0, sys.argv[2])
import faulthandler
faulthandler.disable()  # a crash here is the parent's InputError, not a report on stderr
from facegeom.errors import InputError
from facegeom.io.usd import _read_here
try:
    result = ("ok", _read_here(sys.argv[1]))
except InputError as exc:
    result = ("input", exc.reason)
except BaseException as exc:  # a bug: reported by the parent
    result = ("bug", f"{type(exc).__name__}: {exc}")
try:
    data = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
except BaseException as exc:  # e.g. MemoryError pickling
    data = pickle.dumps(("bug", f"{type(exc).__name__}: {exc}"))
sys.stdout.buffer.write(data)
sys.stdout.flush()
os._exit(0)
"""
"""The reading child's program: a fresh interpreter (not a fork: a fork of a process whose usd-core already
runs worker threads can hang in the child on their locks), its result pickled to stdout."""


def _read_in_child(path) -> UsdRig:
    """:func:`_read_here` in a child process (a fresh interpreter); its result (or its InputError's reason) comes
    back pickled."""
    import pickle
    import signal
    import subprocess
    import sys

    package_root = str(Path(__file__).resolve().parents[2])  # where this facegeom is imported from
    cmd = [sys.executable, "-c", _CHILD, os.fspath(path), package_root]
    try:
        proc = subprocess.run(cmd, capture_output=True, timeout=READ_SECONDS)
    except subprocess.TimeoutExpired:
        raise InputError(f"usd-core read the file for more than {READ_SECONDS} s; stopped", path) from None
    except OSError as exc:
        raise InputError(f"cannot start the USD reader: {exc}", path) from None
    if proc.returncode < 0:
        name = signal.Signals(-proc.returncode).name
        raise InputError(f"usd-core crashed reading the file ({name}): it is malformed", path)
    if proc.returncode > 0 and not proc.stdout:  # the reader itself did not start (no usd-core, no numpy ...)
        lines = proc.stderr.decode("utf-8", "replace").strip().splitlines()
        raise InputError(f"the USD reader stopped before reading the file ({lines[-1][:200] if lines else 'no message'})",
                         path)
    try:
        kind, value = pickle.loads(proc.stdout)
    except Exception:  # noqa: BLE001 - not a pickle: no result
        raise InputError("usd-core ended reading the file without a result: it is malformed", path) from None
    if kind == "ok":
        return value
    if kind == "input":
        raise InputError(value, path)
    raise RuntimeError(f"reading {path} failed: {value}")


def _array(attr, time=None, kind=np.float64, width: int | None = None, limit: int = MAX_POINTS, what: str = ""):
    """An attribute's array value (None when it has none), checked for type, shape and size."""
    from pxr import Usd

    if not attr or not attr.IsValid():
        return None
    value = attr.Get(Usd.TimeCode.Default() if time is None else time)
    if value is None and time is None and attr.GetNumTimeSamples():
        value = attr.Get(Usd.TimeCode.EarliestTime())
    if value is None:
        return None
    try:
        count = len(value)
    except TypeError:
        raise _Bad(f"{what} is not an array") from None
    if count > limit:
        raise _Bad(f"{what} has {count:,} entries, more than the {limit:,} read")
    try:
        a = np.asarray(value, dtype=kind)
    except (TypeError, ValueError):
        raise _Bad(f"{what} has values of the wrong type") from None
    if width is None:
        if a.ndim != 1:
            raise _Bad(f"{what} has values of the wrong type")
    elif a.shape != (count, width):
        if count == 0:
            return np.zeros((0, width), dtype=kind)
        raise _Bad(f"{what} has values of the wrong type")
    return a


def _find_mesh(stage):
    from pxr import UsdGeom, UsdSkel

    first = None
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        first = first or prim
        parent = prim.GetParent()
        under_root = False
        while parent and parent.IsValid():
            if parent.IsA(UsdSkel.Root):
                under_root = True
                break
            parent = parent.GetParent()
        if under_root and UsdSkel.BindingAPI(prim).GetBlendShapeTargetsRel().GetTargets():
            return prim
    return first


def _read(stage, path) -> UsdRig:
    from pxr import UsdGeom, UsdSkel

    prim = _find_mesh(stage)
    if prim is None:
        raise _Bad("no Mesh in the file")
    mesh = UsdGeom.Mesh(prim)
    V = _array(mesh.GetPointsAttr(), width=3, what="the mesh's points")
    if V is None or V.shape[0] == 0:
        raise _Bad(f"the mesh {prim.GetPath()} has no points")
    if not np.isfinite(V).all():
        raise _Bad("the mesh's points contain NaN or inf")
    n = V.shape[0]
    counts = _array(mesh.GetFaceVertexCountsAttr(), kind=np.int64, limit=MAX_INDICES, what="faceVertexCounts")
    idx = _array(mesh.GetFaceVertexIndicesAttr(), kind=np.int64, limit=MAX_INDICES, what="faceVertexIndices")
    if counts is None or idx is None:
        raise _Bad("the mesh has no faceVertexCounts or faceVertexIndices")
    F = _triangles(counts, idx, n)
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (np.isfinite(mpu) and mpu > 0):
        raise _Bad(f"metersPerUnit {mpu} is not a positive number")
    up = str(UsdGeom.GetStageUpAxis(stage))

    binding = UsdSkel.BindingAPI(prim)
    targets = binding.GetBlendShapeTargetsRel().GetTargets() if binding.GetBlendShapeTargetsRel() else []
    tokens = [str(t) for t in (binding.GetBlendShapesAttr().Get() or [])] if binding.GetBlendShapesAttr() else []
    if targets and len(tokens) != len(targets):
        raise _Bad(f"the mesh has {len(tokens)} skel:blendShapes and {len(targets)} skel:blendShapeTargets")
    K = len(targets)
    if K * n * 3 > MAX_VALUES:
        raise _Bad(f"{K} blend shapes of {n:,} points are more than the {MAX_VALUES:,} numbers read")
    D = np.zeros((K, n, 3))
    N = None
    for k, target in enumerate(targets):
        shape_prim = stage.GetPrimAtPath(target)
        if not shape_prim or not shape_prim.IsA(UsdSkel.BlendShape):
            raise _Bad(f"blend shape target {target} is not a BlendShape")
        shape = UsdSkel.BlendShape(shape_prim)
        offsets = _array(shape.GetOffsetsAttr(), width=3, what=f"{target} offsets")
        if offsets is None:
            offsets = np.zeros((0, 3))
        normals = _array(shape.GetNormalOffsetsAttr(), width=3, what=f"{target} normalOffsets")
        points = _array(shape.GetPointIndicesAttr(), kind=np.int64, what=f"{target} pointIndices")
        rows = slice(None)
        if points is not None:
            if points.size != offsets.shape[0]:
                raise _Bad(f"{target} has {offsets.shape[0]} offsets for {points.size} point indices")
            if points.size and (points.min() < 0 or points.max() >= n):
                raise _Bad(f"{target} point indices outside 0..{n - 1}")
            rows = points
        elif offsets.shape[0] != n:
            raise _Bad(f"{target} has {offsets.shape[0]} offsets for {n} points")
        if not np.isfinite(offsets).all():
            raise _Bad(f"{target} offsets contain NaN or inf")
        D[k][rows] = offsets
        if normals is not None and normals.size:
            if normals.shape[0] != offsets.shape[0] or not np.isfinite(normals).all():
                raise _Bad(f"{target} normalOffsets do not match its offsets or are not finite")
            if N is None:
                N = np.zeros((K, n, 3))
            N[k][rows] = normals
    names = tuple(tokens)
    stored = prim.GetCustomDataByKey(_NAMES_KEY)
    if stored is not None and not isinstance(stored, str):
        try:
            stored = [s for s in stored if isinstance(s, str)] if len(stored) == K else []
        except TypeError:
            stored = []
        if len(stored) == K:
            names = tuple(stored)

    W = fps = R = t = None
    anim = _animation(stage, binding)
    if anim is not None and K:
        W, R, t, fps = _sample(stage, anim, tokens, K)
    return UsdRig(neutral=V, faces=F, deltas=D, names=names, weights=W, fps=fps, rotations=R, translations=t,
                  meters_per_unit=mpu, up_axis=up, normal_deltas=N, path=str(path))


def _triangles(counts: np.ndarray, idx: np.ndarray, n: int) -> np.ndarray:
    if counts.size and counts.min() < 3:
        raise _Bad("a polygon has fewer than 3 vertices")
    if int(counts.sum()) != idx.size:
        raise _Bad(f"faceVertexCounts add up to {int(counts.sum())}, faceVertexIndices has {idx.size}")
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise _Bad(f"face indices outside 0..{n - 1}")
    if counts.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if (counts == 3).all():
        return idx.reshape(-1, 3).copy()
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    per = counts - 2  # triangles per polygon
    first = np.repeat(starts, per)
    j = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)  # 0 .. per-1 within each polygon
    return np.stack([idx[first], idx[first + j + 1], idx[first + j + 2]], axis=1)


def _animation(stage, binding):
    """The SkelAnimation driving the mesh: its skeleton's animation source, else the mesh's own."""
    from pxr import UsdSkel

    skel = binding.GetInheritedSkeleton()
    sources = []
    if skel and skel.GetPrim().IsValid():
        sources.append(UsdSkel.BindingAPI(skel.GetPrim()).GetAnimationSourceRel())
    sources.append(binding.GetAnimationSourceRel())
    for rel in sources:
        if rel:
            for target in rel.GetTargets():
                p = stage.GetPrimAtPath(target)
                if p and p.IsA(UsdSkel.Animation):
                    return UsdSkel.Animation(p), skel
    return None


def _sample(stage, found, tokens, K):
    from pxr import Usd

    anim, skel = found
    anim_tokens = [str(s) for s in (anim.GetBlendShapesAttr().Get() or [])]
    w_attr, r_attr, t_attr = anim.GetBlendShapeWeightsAttr(), anim.GetRotationsAttr(), anim.GetTranslationsAttr()
    times = list(w_attr.GetTimeSamples()) if w_attr else []
    if not times:
        return None, None, None, None
    joint = None
    if skel and (r_attr.GetNumTimeSamples() or t_attr.GetNumTimeSamples()):
        joints = [str(j) for j in (skel.GetJointsAttr().Get() or [])]
        anim_joints = [str(j) for j in (anim.GetJointsAttr().Get() or [])]
        if joints and joints[0] in anim_joints:
            joint = anim_joints.index(joints[0])
            times += list(r_attr.GetTimeSamples()) + list(t_attr.GetTimeSamples())
    first, last = float(min(times)), float(max(times))
    if not (np.isfinite(first) and np.isfinite(last)) or last - first >= MAX_FRAMES:
        raise _Bad(f"the animation spans {last - first} time codes, more than the {MAX_FRAMES:,} frames read")
    T = int(np.floor(last - first)) + 1
    if T * max(K, 1) > MAX_VALUES:
        raise _Bad(f"{T} frames of {K} weights are more than the {MAX_VALUES:,} numbers read")
    fps = float(stage.GetTimeCodesPerSecond())
    if not (np.isfinite(fps) and fps > 0):
        raise _Bad(f"timeCodesPerSecond {fps} is not a positive number")
    order = {}
    for i, name in enumerate(anim_tokens):
        order.setdefault(name, i)
    cols = [order.get(name, -1) for name in tokens]
    W = np.zeros((T, K))
    R = np.zeros((T, 3, 3)) if joint is not None else None
    tr = np.zeros((T, 3)) if joint is not None else None
    for f in range(T):
        time = Usd.TimeCode(first + f)
        w = _array(w_attr, time, limit=MAX_VALUES, what="blendShapeWeights")
        if w is None:
            w = np.zeros(0)
        if w.size != len(anim_tokens):
            raise _Bad(f"the animation has {w.size} weights for {len(anim_tokens)} blendShapes at time {first + f}")
        if not np.isfinite(w).all():
            raise _Bad(f"the animation's weights contain NaN or inf at time {first + f}")
        W[f] = [w[c] if c >= 0 else 0.0 for c in cols]
        if joint is not None:
            q = _array(r_attr, time, width=4, limit=MAX_VALUES, what="rotations")
            v = _array(t_attr, time, width=3, limit=MAX_VALUES, what="translations")
            R[f] = _rotation(q[joint] if q is not None and q.shape[0] > joint else np.array([0.0, 0, 0, 1]))
            tr[f] = v[joint] if v is not None and v.shape[0] > joint else 0.0
            if not np.isfinite(tr[f]).all():
                raise _Bad("the head translations contain NaN or inf")
    return W, R, tr, fps


def _rotation(q: np.ndarray) -> np.ndarray:
    """The rotation matrix of quaternion ``q`` (x, y, z, w), normalised."""
    norm = float(np.linalg.norm(q))
    if not (np.isfinite(norm) and norm > 1e-12):
        raise _Bad("a head rotation is not a valid quaternion")
    x, y, z, w = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
