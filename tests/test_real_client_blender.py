"""A real client opens facegeom's animated ``.glb`` files: Blender (background mode) imports and plays them.

Two files are written from ``tests/data/heads/makehuman_arkit.npz`` — the MakeHuman head with 52 ARKit face
units, CC0 1.0 (sources and licences: ``tests/data/heads/SOURCES.md``), in metres:

- a rig animation (:func:`facegeom.io.gltf.write_rig_glb`): the 52 named blendshapes, 30 frames of weights
  at 30 fps and a head motion (a growing yaw, a nod, a drift);
- a driven vertex sequence (:func:`facegeom.io.gltf.write_sequence_glb`): 20 frames of the same head
  (neutral + weights @ deltas) stored as SVD morph targets.

Both are imported in ONE run of Blender's stock glTF importer (``tests/clients/blender_readback.py``), which
reports what Blender plays at a few scene frames (one between two keys). Checked against what was written:
the shape key names and count; the keys' frames (Blender puts time ``t`` on scene frame ``t * fps``: the
first key on frame 0, not 1, so the scene runs at the file's rate); the shape key values; the object's world
matrix (glTF's Y-up rotation and translation carried to Blender's Z-up: ``C R C^T`` and ``C t`` with
``C (x, y, z) = (x, -z, y)``); the evaluated (depsgraph) vertex positions, in the object's space and in the
world; and the sequence's vertices within the writer's reported ``max_error``.

Blender's importer sets each shape key's slider range to [0, 1] widened by the curve's FIRST key only, and
Blender clamps the played value to it (KhronosGroup/glTF-Blender-IO#1364): a negative weight plays as 0. The
writer keeps every weight in [0, 1]; the sequence is checked as imported and with the slider ranges widened
to the curves' ranges (the file's content).

Skipped when ``blender`` is not on PATH or its glTF importer cannot import a one-triangle file.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).parent
RIG = HERE / "data" / "heads" / "makehuman_arkit.npz"
SCRIPT = HERE / "clients" / "blender_readback.py"
FPS = 30
RIG_FRAMES = 30
SEQ_FRAMES = 20
FRAMES = (0.0, 7.5, 12.0, 15.0, 19.0, 29.0)  # scene frames read back (7.5: between keys; 29: the sequence holds)
#: glTF (Y up) -> Blender (Z up): Blender (x, y, z) = glTF (x, -z, y)
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
VALUE_TOL = 1e-5  # shape key values (float32 weights in [0, 1])
MATRIX_TOL = 1e-5  # world matrix entries (rotation; translation in metres)
POSITION_TOL = 1e-5  # metres: 10 micrometres on a head ~0.3 m tall, 0.85 m from the origin
SEQ_SLACK = 1e-6  # metres over the writer's max_error: Blender's float32 shape key sum


def _rig_inputs():
    from scipy.spatial.transform import Rotation

    from facegeom.model import load_rig

    rig = load_rig(RIG)  # cm, Y up, face along +Z (facegeom's frame); written in metres as glTF wants
    names = list(rig.names)
    V, D, F = rig.neutral * 0.01, rig.deltas * 0.01, rig.triangles
    f = np.arange(RIG_FRAMES, dtype=np.float64)
    W = np.zeros((RIG_FRAMES, len(names)))
    W[:, names.index("jawOpen")] = np.interp(f, [0, 15, 29], [0.0, 0.8, 0.2])
    W[:, names.index("mouthSmileLeft")] = 0.5 * f / 29
    W[:, names.index("eyeBlinkRight")] = np.interp(f, [0, 6, 9, 12, 29], [0.0, 0.0, 1.0, 0.0, 0.0])
    W[:, names.index("browInnerUp")] = 0.3 + 0.3 * np.sin(2 * np.pi * f / 29)
    angles = np.c_[2.0 * np.sin(2 * np.pi * f / 29), 6.0 * f / 29, np.zeros_like(f)]  # pitch (x), yaw (y) in deg
    R = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    t = np.c_[0.01 * f / 29, 0.005 * np.sin(np.pi * f / 29), -0.02 * f / 29]  # metres
    return {"names": names, "V": V, "D": D, "F": F, "W": W, "R": R, "t": t}


def _sequence_frames(rig):
    f = np.arange(SEQ_FRAMES, dtype=np.float64)
    names = rig["names"]
    W = np.zeros((SEQ_FRAMES, len(names)))
    s = np.sin(np.pi * f / (SEQ_FRAMES - 1))
    W[:, names.index("jawOpen")] = 0.7 * s
    W[:, names.index("mouthSmileLeft")] = f / (SEQ_FRAMES - 1)
    W[:, names.index("eyeBlinkRight")] = (1.0 - f / (SEQ_FRAMES - 1)) ** 2
    W[:, names.index("browInnerUp")] = 0.5 * s ** 2
    return rig["V"] + np.einsum("tk,knj->tnj", W, rig["D"])


@pytest.fixture(scope="module")
def blender(tmp_path_factory):
    """Both files written and read back in ONE Blender run -> the inputs, the writer's info and what Blender read."""
    from facegeom.io.gltf import read_glb_animation, write_rig_glb, write_sequence_glb

    exe = shutil.which("blender")
    if exe is None:
        pytest.skip("Blender is not installed (no `blender` on PATH): the real-client check needs it")
    tmp = tmp_path_factory.mktemp("blender")
    rig = _rig_inputs()
    write_rig_glb(tmp / "rig.glb", rig["V"], rig["F"], rig["D"], rig["names"], rig["W"], FPS,
                  rotations=rig["R"], translations=rig["t"])
    X = _sequence_frames(rig)
    _, info = write_sequence_glb(tmp / "sequence.glb", X, rig["F"], FPS, tolerance=1e-4)  # 0.1 mm
    info["stored_base"] = read_glb_animation(tmp / "sequence.glb").neutral  # the file's own rest positions
    out = tmp / "readback.json"
    cmd = [exe, "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(SCRIPT), "--",
           str(out), str(FPS), ",".join(str(f) for f in FRAMES), str(tmp / "rig.glb"), str(tmp / "sequence.glb")]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    elapsed = time.perf_counter() - start
    log = f"$ {' '.join(cmd)}\n--- stdout\n{proc.stdout[-4000:]}\n--- stderr\n{proc.stderr[-4000:]}"
    assert proc.returncode == 0 and out.is_file(), f"Blender failed (exit code {proc.returncode})\n{log}"
    result = json.loads(out.read_text())
    if result["status"] == "unusable":
        pytest.skip(result["reason"])
    assert result["status"] == "ok", log
    print(f"Blender {result['blender']}: both files imported and read back in {elapsed:.2f} s")
    rig_read, seq_read = result["files"]
    return {"rig": rig, "rig_read": rig_read, "X": X, "info": info, "seq_read": seq_read, "version": result["blender"]}


# ----------------------------------------------------------------------------- helpers


def _interp(values: np.ndarray, frame: float) -> np.ndarray:
    """glTF LINEAR sampling of per-frame ``values`` (T, ...) at a (fractional) frame, held past the ends."""
    i = int(np.clip(np.floor(frame), 0, len(values) - 1))
    j = min(i + 1, len(values) - 1)
    a = float(np.clip(frame - i, 0.0, 1.0))
    return (1.0 - a) * values[i] + a * values[j]


def _rotation(R: np.ndarray, frame: float) -> np.ndarray:
    """The written rotations slerped at ``frame`` (as glTF plays them)."""
    from scipy.spatial.transform import Rotation, Slerp

    f = float(np.clip(frame, 0, len(R) - 1))
    return Slerp(np.arange(len(R)), Rotation.from_matrix(R))([f]).as_matrix()[0]


def _vertex_map(read: dict, V: np.ndarray) -> np.ndarray:
    """Blender vertex i is glTF vertex ``m[i]``: matched by rest position (the importer may reorder or drop)."""
    from scipy.spatial import cKDTree

    rest = np.asarray(read["rest"]).reshape(-1, 3)
    dist, m = cKDTree(V.astype(np.float32).astype(np.float64) @ C.T).query(rest)
    assert rest.shape[0] == V.shape[0], f"Blender has {rest.shape[0]} vertices, the file {V.shape[0]}"
    assert dist.max() < 1e-7, f"a rest vertex is {dist.max():.3g} m from every written one (axes? units?)"
    assert np.unique(m).size == m.size, "two Blender vertices on one written vertex"
    return m


def _positions(sample: dict, m: np.ndarray) -> np.ndarray:
    """A frame's evaluated vertices (Blender's object space), put back in the written vertex order."""
    co = np.asarray(sample["co"]).reshape(-1, 3)
    out = np.empty_like(co)
    out[m] = co
    return out


# ----------------------------------------------------------------------------- the rig animation


def test_rig_shape_keys_are_the_written_names(blender):
    read = blender["rig_read"]
    assert read["basis"] is not None, "no shape keys imported"
    assert len(read["shape_keys"]) == len(blender["rig"]["names"]) == 52
    assert read["shape_keys"] == blender["rig"]["names"]


def test_rig_keys_sit_on_frames_0_to_T_minus_1(blender):
    """Blender puts glTF time t on scene frame t * fps (frame 0 first, not 1): at the file's rate, key k on k."""
    read = blender["rig_read"]
    for what in ("weight_key_frames", "node_key_frames"):
        assert read[what] is not None, f"no {what.split('_')[0]} animation imported"
        np.testing.assert_allclose(read[what], np.arange(RIG_FRAMES), atol=1e-4, err_msg=what)


def test_rig_shape_key_values_play_the_written_weights(blender):
    read, W = blender["rig_read"], blender["rig"]["W"]
    worst = 0.0
    for sample in read["played"]:
        played, want = np.asarray(sample["values"]), _interp(W, sample["frame"])
        worst = max(worst, float(np.abs(played - want).max()))
        np.testing.assert_allclose(played, want, rtol=0, atol=VALUE_TOL, err_msg=f"frame {sample['frame']}")
    print(f"rig weights: max |Blender - written| = {worst:.2e}")
    jaw = read["shape_keys"].index("jawOpen")
    assert abs(read["played"][FRAMES.index(15.0)]["values"][jaw] - 0.8) < VALUE_TOL


def test_rig_head_motion_plays_as_written(blender):
    """The world matrix is the written rotation and translation turned to Z up: [C R C^T, C t]."""
    from scipy.spatial.transform import Rotation

    read, rig = blender["rig_read"], blender["rig"]
    worst = 0.0
    for sample in read["played"]:
        f = sample["frame"]
        M = np.asarray(sample["matrix_world"])
        R, t = _rotation(rig["R"], f), _interp(rig["t"], f)
        want = np.eye(4)
        want[:3, :3], want[:3, 3] = C @ R @ C.T, C @ t
        worst = max(worst, float(np.abs(M - want).max()))
        np.testing.assert_allclose(M, want, rtol=0, atol=MATRIX_TOL, err_msg=f"frame {f}")
        turned = np.degrees(Rotation.from_matrix(M[:3, :3]).magnitude())  # the angle: the same in any axes
        assert abs(turned - np.degrees(Rotation.from_matrix(R).magnitude())) < 1e-3, f"frame {f}"
    print(f"rig head motion: max |Blender world matrix - written| = {worst:.2e}")
    assert turned > 5.0  # the head did turn (frame 29: about 6 degrees)


def test_rig_evaluated_vertices_are_neutral_plus_weighted_deltas(blender):
    """Depsgraph-evaluated positions: C (neutral + w D) in the object's space, C (R (...) + t) in the world."""
    read, rig = blender["rig_read"], blender["rig"]
    m = _vertex_map(read, rig["V"])
    K, n = rig["D"].shape[:2]
    local_worst = world_worst = 0.0
    for sample in read["played"]:
        f = sample["frame"]
        want = rig["V"] + (_interp(rig["W"], f) @ rig["D"].reshape(K, 3 * n)).reshape(n, 3)
        got = _positions(sample, m)
        err = np.linalg.norm(got - want @ C.T, axis=1)
        local_worst = max(local_worst, float(err.max()))
        assert err.max() < POSITION_TOL, f"frame {f}: a vertex {err.max():.3g} m off in the object's space"
        M = np.asarray(sample["matrix_world"])
        world = got @ M[:3, :3].T + M[:3, 3]
        want_world = (want @ _rotation(rig["R"], f).T + _interp(rig["t"], f)) @ C.T
        werr = np.linalg.norm(world - want_world, axis=1)
        world_worst = max(world_worst, float(werr.max()))
        assert werr.max() < POSITION_TOL, f"frame {f}: a vertex {werr.max():.3g} m off in the world"
    print(f"rig vertices: max error {local_worst:.2e} m (object space), {world_worst:.2e} m (world)")
    jaw_frame = _positions(read["played"][FRAMES.index(15.0)], m)
    rest = np.asarray(read["rest"]).reshape(-1, 3)[np.argsort(m)]
    assert np.linalg.norm(jaw_frame - rest, axis=1).max() > 0.005  # the jaw opened by millimetres


# ----------------------------------------------------------------------------- the vertex sequence


def _sequence_errors(blender, key: str) -> list[float]:
    read, X = blender["seq_read"], blender["X"]
    m = _vertex_map(read, blender["info"]["stored_base"])
    return [float(np.linalg.norm(_positions(s, m) - _interp(X, s["frame"]) @ C.T, axis=1).max())
            for s in read[key]]


def test_sequence_vertices_match_the_input_frames(blender):
    """The file's content: with the slider ranges widened to the curves' ranges, every frame is within max_error.

    Between keys the file plays the linear blend of the two frames (weights are linear in the frames)."""
    info, read = blender["info"], blender["seq_read"]
    assert read["shape_keys"] == [f"svd{k:03d}" for k in range(info["targets"])]
    np.testing.assert_allclose(read["weight_key_frames"], np.arange(SEQ_FRAMES), atol=1e-4)
    errors = _sequence_errors(blender, "widened")
    print(f"sequence ({info['targets']} targets, writer's max_error {info['max_error']:.2e} m): "
          f"Blender's max error per frame {', '.join(f'{e:.2e}' for e in errors)} m")
    assert max(errors) <= info["max_error"] + SEQ_SLACK, (errors, info)


def test_sequence_plays_as_imported(blender):
    """As imported, with Blender's own slider ranges: the writer keeps every weight in [0, 1], the range
    Blender's importer gives a shape key (it clamps to it: glTF-Blender-IO#1364)."""
    info = blender["info"]
    errors = _sequence_errors(blender, "played")
    assert max(errors) <= info["max_error"] + SEQ_SLACK, (errors, info)
