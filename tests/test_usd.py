"""USD rigs (:mod:`facegeom.io.usd`): written, validated, read back by facegeom and by a real client (Blender).

- round trips write -> read of a small synthetic rig and of the ICT face rig with a few frames of weights and a
  head motion, as ``.usda``, ``.usdc`` and ``.usdz``: every array equal within float32 precision;
- usd-core's validators (``usdchecker``'s checks) report no error;
- UsdSkel itself (usd-core's skinning) plays the head motion as ``R v + t``;
- Blender's USD importer (``bpy.ops.wm.usd_import`` with ``import_blendshapes`` and ``import_skeletons``) reads
  the small rig in a subprocess: shape key names and positions, animated key values, and the evaluated,
  posed mesh in the world (Blender is Z up in metres: a Y-up stage in centimetres arrives as
  ``C (0.01 p)`` with ``C (x, y, z) = (x, -z, y)``);
- one-line errors of the writer and of the reader, and a fuzz target of the reader (mutated ``.usda`` text and
  ``.usdc`` bytes either read or raise InputError).

The Blender client is the first of: ``bpy`` importable in this interpreter; a Python interpreter with ``bpy``
named by ``FACEGEOM_BPY_PYTHON`` (``pip install bpy`` wants numpy < 2, so it usually lives in a venv of its
own); a ``blender`` executable on PATH. None: the Blender tests skip saying so.
"""
from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import settings
from hypothesis import strategies as st

from facegeom.errors import InputError

pytest.importorskip("pxr", reason="usd-core not installed: pip install usd-core")

from facegeom.io.usd import read_usd_rig, usd_validation_errors, write_rig_usd
from tests.fuzzing import EXAMPLES, FUZZ, RANDOM, campaign

FPS = 30.0
FRAMES = 10
NAMES = ["jawOpen", "mouthSmile_L", "eyeBlinkRight", "brow Up-2"]  # ARKit, ICT, ARKit, needs sanitising
TOKENS = ["jawOpen", "mouthSmile_L", "eyeBlinkRight", "brow_Up_2"]
#: Y up -> Blender's Z up: Blender (x, y, z) = (x, -z, y)
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
MPU = 0.01  # centimetres
F32 = 1e-6  # relative float32 precision (with a little slack)


def _sphere(rings: int = 8, segments: int = 12, radius: float = 10.0):
    """A UV sphere (cm): vertices and triangles."""
    V = [[0.0, radius, 0.0]]
    for i in range(1, rings):
        phi = np.pi * i / rings
        for j in range(segments):
            th = 2 * np.pi * j / segments
            V.append([radius * np.sin(phi) * np.cos(th), radius * np.cos(phi), radius * np.sin(phi) * np.sin(th)])
    V.append([0.0, -radius, 0.0])
    V = np.array(V)
    F = []
    for j in range(segments):
        F.append([0, 1 + (j + 1) % segments, 1 + j])
    for i in range(rings - 2):
        a, b = 1 + i * segments, 1 + (i + 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            F += [[a + j, a + k, b + j], [a + k, b + k, b + j]]
    last = len(V) - 1
    base = 1 + (rings - 2) * segments
    for j in range(segments):
        F.append([base + j, base + (j + 1) % segments, last])
    return V, np.array(F)


def _motion(T: int, scale: float = 1.0):
    from scipy.spatial.transform import Rotation

    f = np.arange(T, dtype=np.float64)
    R = Rotation.from_euler("xyz", np.c_[8 * np.sin(f / 3), 20 * f / max(T - 1, 1), 3 * f / max(T - 1, 1)],
                            degrees=True).as_matrix()
    t = scale * np.c_[0.5 * f, 0.2 * np.sin(f), -0.3 * f]
    return R, t


def _small():
    V, F = _sphere()
    n = V.shape[0]
    rng = np.random.default_rng(7)
    D = np.zeros((4, n, 3))
    D[0, V[:, 1] < 0] = (0.0, -2.0, 0.5)  # the lower half moves: dense
    D[1, :5] = rng.normal(size=(5, 3))  # a few points: sparse
    D[2] = 0.1 * V
    D[3, -7:] = rng.normal(size=(7, 3))
    f = np.arange(FRAMES, dtype=np.float64)
    W = np.c_[np.interp(f, [0, 5, 9], [0, 0.8, 0.2]), f / 9, np.interp(f, [0, 3, 4, 5, 9], [0, 0, 1, 0, 0]),
              0.3 + 0.3 * np.sin(f)]
    R, t = _motion(FRAMES)
    return {"V": V, "F": F, "D": D, "W": W, "R": R, "t": t, "N": 0.01 * D}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The small rig written once per format -> its inputs and paths."""
    tmp = tmp_path_factory.mktemp("usd")
    rig = _small()
    paths = {}
    for suffix in ("usda", "usdc", "usdz"):
        paths[suffix] = write_rig_usd(tmp / f"small.{suffix}", rig["V"], rig["F"], rig["D"], NAMES, rig["W"], FPS,
                                      rig["R"], rig["t"], normal_deltas=rig["N"])
    paths["rig"] = write_rig_usd(tmp / "rig.usda", rig["V"], rig["F"], rig["D"], NAMES)  # no animation
    return rig, paths


def _close(a, b, scale=None):
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape, (a.shape, b.shape)
    bound = F32 * (np.abs(b).max() if scale is None else scale) + 1e-12
    err = np.abs(a - b).max() if a.size else 0.0
    assert err <= bound, f"max error {err:.3g} > {bound:.3g}"
    return err


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", ["usda", "usdc", "usdz"])
def test_small_rig_round_trip(small, suffix):
    rig, paths = small
    r = read_usd_rig(paths[suffix])
    _close(r.neutral, rig["V"])
    assert r.faces.dtype == np.int64 and np.array_equal(r.faces, rig["F"])
    _close(r.deltas, rig["D"], np.abs(rig["D"]).max())
    _close(r.normal_deltas, rig["N"], np.abs(rig["N"]).max())
    assert r.names == tuple(NAMES)
    _close(r.weights, rig["W"], 1.0)
    _close(r.rotations, rig["R"], 1.0)
    _close(r.translations, rig["t"])
    assert r.fps == FPS and r.meters_per_unit == MPU and r.up_axis == "Y"
    assert r.frames().shape == (FRAMES, rig["V"].shape[0], 3)


def test_rig_without_animation(small):
    rig, paths = small
    r = read_usd_rig(paths["rig"])
    assert r.weights is None and r.fps is None and r.rotations is None and r.translations is None
    _close(r.deltas, rig["D"], np.abs(rig["D"]).max())
    from pxr import Usd

    stage = Usd.Stage.Open(str(paths["rig"]))
    assert not any(a.GetNumTimeSamples() for p in stage.Traverse() for a in p.GetAttributes())
    assert usd_validation_errors(paths["rig"])[0] == []


def test_stage_structure(small):
    """The layout the module promises: metadata, SkelRoot default prim, rigid binding, tokens, animation."""
    from pxr import Usd, UsdGeom, UsdSkel

    paths = small[1]
    stage = Usd.Stage.Open(str(paths["usda"]))
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, FRAMES - 1)
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == MPU
    root = stage.GetDefaultPrim()
    assert root.IsA(UsdSkel.Root)
    mesh = stage.GetPrimAtPath(root.GetPath().AppendChild("Mesh"))
    binding = UsdSkel.BindingAPI(mesh)
    assert list(binding.GetBlendShapesAttr().Get()) == TOKENS
    assert np.all(np.asarray(binding.GetJointIndicesAttr().Get()) == 0)
    assert np.all(np.asarray(binding.GetJointWeightsAttr().Get()) == 1)
    assert UsdGeom.Mesh(mesh).GetSubdivisionSchemeAttr().Get() == "none"
    assert UsdGeom.Mesh(mesh).GetNormalsInterpolation() == "vertex"
    anim = UsdSkel.Animation(stage.GetPrimAtPath(root.GetPath().AppendChild("Animation")))
    assert anim.GetBlendShapeWeightsAttr().GetNumTimeSamples() == FRAMES
    assert anim.GetRotationsAttr().GetNumTimeSamples() == FRAMES


def test_usdskel_plays_the_head_motion(small):
    """usd-core's own skinning of the file: vertex v at frame t is R_t v + t_t (the neutral: no shapes)."""
    from pxr import Usd, UsdGeom, UsdSkel

    rig, paths = small
    stage = Usd.Stage.Open(str(paths["usdc"]))
    cache = UsdSkel.Cache()
    root = UsdSkel.Root(stage.GetDefaultPrim())
    cache.Populate(root, Usd.PrimDefaultPredicate)
    binding = cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate)[0]
    query = cache.GetSkelQuery(binding.GetSkeleton())
    for t in (0, 4, 9):
        points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Mesh")).GetPointsAttr().Get()
        assert binding.GetSkinningTargets()[0].ComputeSkinnedPoints(query.ComputeSkinningTransforms(t), points, t)
        _close(np.asarray(points), rig["V"] @ rig["R"][t].T + rig["t"][t], 20.0)


def test_ict_face_round_trip(face_model, tmp_path):
    from facegeom.model.rig import BlendshapeRig

    rig = BlendshapeRig.from_face_model(face_model)
    K = len(rig.names)
    T = 3
    W = np.random.default_rng(1).uniform(0, 1, size=(T, K))
    R, t = _motion(T)
    for suffix in ("usdc", "usda", "usdz"):
        path = write_rig_usd(tmp_path / f"ict.{suffix}", rig.neutral, rig.triangles, rig.deltas, rig.names, W, 60,
                             R, t)
        r = read_usd_rig(path)
        _close(r.neutral, rig.neutral)
        assert np.array_equal(r.faces, rig.triangles)
        _close(r.deltas, rig.deltas, np.abs(rig.deltas).max())
        assert r.names == tuple(rig.names)
        _close(r.weights, W, 1.0)
        _close(r.rotations, R, 1.0)
        _close(r.translations, t)
        assert r.fps == 60.0
    assert usd_validation_errors(tmp_path / "ict.usdc")[0] == []


# ----------------------------------------------------------------------------- validation


@pytest.mark.parametrize("suffix", ["usda", "usdc", "usdz", "rig"])
def test_validators_report_no_error(small, suffix):
    errors, _ = usd_validation_errors(small[1][suffix])
    assert errors == [], errors


def test_validators_can_fail(tmp_path):
    """The check is live: a mesh bound to a skeleton without the SkelBindingAPI is an error."""
    path = tmp_path / "bad.usda"
    path.write_text('#usda 1.0\n(\n    defaultPrim = "R"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n'
                    'def SkelRoot "R"\n{\n    def Mesh "M"\n    {\n'
                    '        point3f[] points = [(0,0,0),(1,0,0),(0,1,0)]\n'
                    '        int[] faceVertexCounts = [3]\n        int[] faceVertexIndices = [0,1,2]\n'
                    '        rel skel:skeleton = </R/S>\n    }\n    def Skeleton "S"\n    {\n    }\n}\n')
    errors, _ = usd_validation_errors(path)
    assert errors, "a binding without SkelBindingAPI passed the validators"


# ----------------------------------------------------------------------------- a real client: Blender

BLENDER_SCRIPT = r'''
import json, sys
import bpy

args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
out, path, frames = args[0], args[1], [int(f) for f in args[2].split(",")]
bpy.ops.wm.read_factory_settings(use_empty=True)
result = {"blender": bpy.app.version_string}
try:
    done = bpy.ops.wm.usd_import(filepath=path, import_blendshapes=True, import_skeletons=True)
except Exception as exc:
    done = {"FAILED: %s" % exc}
result["import"] = sorted(done)
scene = bpy.context.scene
result["fps"] = scene.render.fps / scene.render.fps_base
result["range"] = [scene.frame_start, scene.frame_end]
meshes = [o for o in scene.objects if o.type == "MESH"]
result["objects"] = sorted("%s:%s" % (o.name, o.type) for o in scene.objects)
if len(meshes) == 1:
    ob = meshes[0]
    keys = ob.data.shape_keys
    result["keys"] = [k.name for k in keys.key_blocks] if keys else []
    result["key_co"] = [[c for v in k.data for c in v.co] for k in keys.key_blocks] if keys else []
    result["rest"] = [c for v in ob.data.vertices for c in v.co]
    result["modifiers"] = [m.type for m in ob.modifiers]
    samples = []
    for f in frames:
        scene.frame_set(f)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        ev = ob.evaluated_get(depsgraph)
        m = ev.to_mesh()
        mw = ev.matrix_world
        samples.append({"frame": f, "values": [k.value for k in keys.key_blocks] if keys else [],
                        "world": [c for v in m.vertices for c in (mw @ v.co)],
                        "matrix": [list(r) for r in ob.matrix_world]})
        ev.to_mesh_clear()
    result["samples"] = samples
with open(out, "w") as fh:
    json.dump(result, fh)
'''
BLENDER_FRAMES = (0, 3, 4, 9)


def _blender_command(script, args):
    """The command running ``script`` with Blender's Python, or (None, why not)."""
    if importlib.util.find_spec("bpy") is not None:
        return [sys.executable, str(script), *args], None
    python = os.environ.get("FACEGEOM_BPY_PYTHON")
    if python:
        return [python, str(script), *args], None
    exe = shutil.which("blender")
    if exe:
        return [exe, "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script), "--", *args], None
    return None, ("no Blender: bpy not installed (pip install bpy; bpy 5.x wants numpy<2, so install it in its own "
                  "Python 3.11 venv and set FACEGEOM_BPY_PYTHON to that python), and no `blender` on PATH")


@pytest.fixture(scope="module")
def blender(small, tmp_path_factory):
    rig, paths = small
    tmp = tmp_path_factory.mktemp("blender")
    script, out = tmp / "readback.py", tmp / "readback.json"
    script.write_text(BLENDER_SCRIPT)
    cmd, why = _blender_command(script, [str(out), str(paths["usdc"]), ",".join(map(str, BLENDER_FRAMES))])
    if cmd is None:
        pytest.skip(why)
    start = time.perf_counter()
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=180, cwd=tmp)
    elapsed = time.perf_counter() - start
    log = f"$ {' '.join(cmd)}\n--- stdout\n{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}"
    assert proc.returncode == 0 and out.is_file(), f"Blender failed (exit code {proc.returncode})\n{log}"
    result = json.loads(out.read_text())
    assert result["import"] == ["FINISHED"], log
    print(f"Blender {result['blender']}: imported and read back in {elapsed:.2f} s")
    return rig, result


def _world(p):
    """File positions (cm, Y up) -> Blender's world (m, Z up)."""
    return (MPU * np.asarray(p)) @ C.T


def test_blender_reads_shape_keys(blender):
    rig, read = blender
    assert read["keys"] == ["Basis", *TOKENS], read.get("objects")
    # time code t is scene frame t (the frame range is set from the stage); Blender 5.0 leaves the scene's frame
    # rate as it was (24 in factory settings), it does not take the stage's timeCodesPerSecond
    assert read["range"] == [0, FRAMES - 1]
    n = rig["V"].shape[0]
    rest = np.asarray(read["rest"]).reshape(-1, 3)
    assert rest.shape == (n, 3), f"Blender has {rest.shape[0]} vertices, the file {n}"
    M = np.asarray(read["samples"][0]["matrix"])  # the mesh object's world matrix: the stage's axis and unit
    errs = []
    for k, co in enumerate(read["key_co"]):
        co = np.asarray(co).reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
        want = _world(rig["V"] + (rig["D"][k - 1] if k else 0.0))
        errs.append(np.abs(co - want).max())
    print(f"shape key positions: max error {1000 * max(errs):.2g} mm")
    assert max(errs) < 1e-6  # 1 micrometre


def test_blender_plays_the_weights(blender):
    rig, read = blender
    errs = [np.abs(np.asarray(s["values"][1:]) - rig["W"][s["frame"]]).max() for s in read["samples"]]
    print(f"shape key values: max error {max(errs):.2g}")
    assert max(errs) < 1e-6


def test_blender_plays_the_posed_mesh(blender):
    """The evaluated mesh (shape keys, then the armature) in the world: R_t (V + w_t D) + t_t, in Blender's frame."""
    rig, read = blender
    errs = []
    for s in read["samples"]:
        t = s["frame"]
        local = rig["V"] + np.einsum("k,knj->nj", rig["W"][t], rig["D"])
        want = _world(local @ rig["R"][t].T + rig["t"][t])
        errs.append(np.abs(np.asarray(s["world"]).reshape(-1, 3) - want).max())
    print(f"posed vertices: max error {1000 * max(errs):.2g} mm")
    assert max(errs) < 1e-6


# ----------------------------------------------------------------------------- writer errors


def _one_line(exc_info, *words):
    msg = str(exc_info.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


@pytest.mark.parametrize("change, words", [
    ({"path": "rig.obj"}, ["rig.obj", ".usda"]),
    ({"path": "missing/rig.usda"}, ["missing", "does not exist"]),
    ({"deltas": np.zeros((2, 5, 3))}, ["deltas"]),
    ({"shape_names": ["a"]}, ["1 shape names for 4"]),
    ({"weights": np.zeros((3, 2))}, ["weights"]),
    ({"weights": np.full((3, 4), np.nan)}, ["NaN"]),
    ({"rotations": np.tile(np.eye(3), (FRAMES, 1, 1))}, ["both"]),
    ({"rotations": -np.tile(np.eye(3), (FRAMES, 1, 1)), "translations": np.zeros((FRAMES, 3))}, ["proper"]),
    ({"rotations": np.tile(np.eye(3), (2, 1, 1)), "translations": np.zeros((2, 3))}, ["head motion"]),
    ({"fps": 0}, ["frame rate"]),
    ({"up_axis": "X"}, ["up axis"]),
    ({"meters_per_unit": -1}, ["meters per unit"]),
    ({"faces": np.array([[0, 1, 999]])}, ["faces"]),
    ({"normal_deltas": np.zeros((1, 3))}, ["normal deltas"]),
])
def test_writer_errors(tmp_path, change, words):
    rig = _small()
    kw = {"path": "rig.usda", "neutral": rig["V"], "faces": rig["F"], "deltas": rig["D"], "shape_names": NAMES,
          "weights": rig["W"], "fps": FPS}
    kw.update(change)
    kw["path"] = tmp_path / kw["path"]
    with pytest.raises(InputError) as exc:
        write_rig_usd(**kw)
    _one_line(exc, *words)
    assert not list(tmp_path.iterdir()), "a failed write left a file"


def test_writer_needs_weights_for_a_motion(tmp_path):
    rig = _small()
    with pytest.raises(InputError) as exc:
        write_rig_usd(tmp_path / "r.usdc", rig["V"], rig["F"], rig["D"], NAMES, None, FPS, rig["R"], rig["t"])
    _one_line(exc, "needs weights")


# ----------------------------------------------------------------------------- reader errors


def _edit(src, dst, edit):
    """Copy the USD file ``src`` to ``dst`` with ``edit(stage)`` applied."""
    from pxr import Usd

    shutil.copyfile(src, dst)
    stage = Usd.Stage.Open(str(dst))
    edit(stage)
    stage.GetRootLayer().Save()
    return dst


def _set(path, name, value, time=None):
    from pxr import Usd

    def edit(stage):
        attr = stage.GetPrimAtPath(path).GetAttribute(name)
        attr.Set(value, Usd.TimeCode.Default() if time is None else Usd.TimeCode(time))

    return edit


def _both(a, b):
    return lambda stage: (a(stage), b(stage))


def _reader_cases():
    from pxr import Gf, Vt

    return {
        "nan points": (_set("/Face/Mesh", "points", Vt.Vec3fArray([Gf.Vec3f(float("nan"), 0, 0)] * 3)), "NaN"),
        "face index out of range": (_both(_set("/Face/Mesh", "faceVertexCounts", Vt.IntArray([3])),
                                          _set("/Face/Mesh", "faceVertexIndices", Vt.IntArray([0, 1, 9999]))),
                                    "outside"),
        "face counts disagree": (_set("/Face/Mesh", "faceVertexCounts", Vt.IntArray([3, 3])), "add up"),
        "polygon of 2": (_set("/Face/Mesh", "faceVertexCounts", Vt.IntArray([2])), "fewer than 3"),
        "offsets count": (_set("/Face/Mesh/jawOpen", "offsets", Vt.Vec3fArray([Gf.Vec3f(0, 0, 0)] * 2)), "offsets"),
        "weights count": (_set("/Face/Animation", "blendShapeWeights", Vt.FloatArray([0.5]), 2), "weights for 4"),
        "weights nan": (_set("/Face/Animation", "blendShapeWeights", Vt.FloatArray([float("inf")] * 4), 2), "NaN"),
        "no mesh": (lambda stage: stage.RemovePrim("/Face/Mesh"), "no Mesh"),
    }


@pytest.mark.parametrize("case", ["nan points", "face index out of range", "face counts disagree", "polygon of 2",
                                  "offsets count", "weights count", "weights nan", "no mesh"])
def test_reader_errors(small, tmp_path, case):
    edit, words = _reader_cases()[case]
    path = _edit(small[1]["usdc"], tmp_path / "bad.usdc", edit)
    with pytest.raises(InputError) as exc:
        read_usd_rig(path)
    _one_line(exc, str(path), words)


@pytest.mark.parametrize("name, data, words", [
    ("missing.usda", None, "no such file"),
    ("garbage.usda", b"\x00\x01 not usd at all {", "not a readable USD file"),
    ("garbage.usdc", b"PXR-USDC\xff\xff\xff\xff", "not a readable USD file"),
    ("rig.txt", b"#usda 1.0\n", "not a USD file"),
])
def test_reader_file_errors(tmp_path, name, data, words):
    path = tmp_path / name
    if data is not None:
        path.write_bytes(data)
    with pytest.raises(InputError) as exc:
        read_usd_rig(path)
    _one_line(exc, str(path), words)


def test_reader_fan_triangulates_and_reads_a_plain_mesh(tmp_path):
    """A mesh with a quad and a pentagon, no SkelRoot: K = 0, no animation."""
    path = tmp_path / "plain.usda"
    path.write_text('#usda 1.0\ndef Mesh "M"\n{\n    point3f[] points = [(0,0,0),(1,0,0),(1,1,0),(0,1,0),(2,0,0),'
                    '(2,1,0),(3,1,0)]\n    int[] faceVertexCounts = [4, 5]\n'
                    '    int[] faceVertexIndices = [0,1,2,3, 1,4,5,6,2]\n}\n')
    r = read_usd_rig(path)
    assert r.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 6], [1, 6, 2]]
    assert r.deltas.shape == (0, 7, 3) and r.names == () and r.weights is None


# ----------------------------------------------------------------------------- fuzzing the reader

USD_EXAMPLES = EXAMPLES if RANDOM else 50
NUMBER = re.compile(rb"-?\d+(\.\d+)?")
HUGE = [b"99999999999", b"-1", b"nan", b"inf", b"1e308", b"0"]


def _seed(suffix: str) -> bytes:
    import tempfile

    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    D = np.stack([np.full((4, 3), 0.1), np.eye(4, 3)])
    W = np.array([[0.0, 1.0], [0.5, 0.5], [1.0, 0.0]])
    R, t = _motion(3)
    with tempfile.TemporaryDirectory() as d:
        return write_rig_usd(os.path.join(d, f"seed.{suffix}"), V, F, D, ["a", "b"], W, 30.0, R, t).read_bytes()


@st.composite
def mutated(draw, seed: bytes, text: bool) -> bytes:
    """``seed`` cut short, bytes flipped, inserted or deleted, or (text) a number replaced by a huge or odd one."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "flip", "insert", "delete", "number"] if text else
                                  ["cut", "flip", "flip", "insert", "delete"]))
        if op == "cut":
            data = data[:draw(st.integers(0, len(data)))]
        elif op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
        elif op == "insert":
            at = draw(st.integers(0, len(data)))
            data[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif op == "delete" and data:
            at = draw(st.integers(0, len(data) - 1))
            del data[at:at + draw(st.integers(1, 16))]
        elif op == "number":
            numbers = list(NUMBER.finditer(bytes(data)))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data[m.start():m.end()] = draw(st.sampled_from(HUGE))
    return bytes(data)


def _check_usd(path) -> None:
    from tests.test_fuzz_readers import read_or_input_error

    r = read_or_input_error(read_usd_rig, path)
    if r is None:
        return
    n, K = r.neutral.shape[0], r.deltas.shape[0]
    assert r.neutral.shape == (n, 3) and np.isfinite(r.neutral).all() and r.deltas.shape == (K, n, 3)
    assert len(r.names) == K and r.faces.ndim == 2 and r.faces.shape[1] == 3
    assert r.faces.size == 0 or (r.faces.min() >= 0 and r.faces.max() < n)
    if r.weights is not None:
        assert r.weights.shape[1] == K and np.isfinite(r.weights).all()


@pytest.mark.parametrize("suffix", ["usda", "usdc"])
def test_seed_reads(tmp_path, suffix):
    path = tmp_path / f"seed.{suffix}"
    path.write_bytes(_seed(suffix))
    r = read_usd_rig(path)
    assert r.names == ("a", "b") and r.weights.shape == (3, 2)


@pytest.mark.parametrize("suffix", ["usda", "usdc"])
def test_mutated_usd_reads_or_raises_input_error(tmp_path, suffix):
    path = tmp_path / f"f.{suffix}"

    def run(data):
        path.write_bytes(data)
        _check_usd(path)

    campaign(run, settings(FUZZ, max_examples=USD_EXAMPLES), 2, data=mutated(_seed(suffix), suffix == "usda"))


def test_crate_that_crashed_usd_core(tmp_path):
    """One byte of the .usdc seed changed (found by the target above): usd-core 26.11 dies of SIGSEGV opening it;
    the isolated reader turns that into an InputError."""
    data = bytearray(_seed("usdc"))
    data[96] = 0xFD
    path = tmp_path / "crash.usdc"
    path.write_bytes(bytes(data))
    _check_usd(path)
