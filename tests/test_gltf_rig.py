"""read_gltf_rig: blendshape rigs from .glb / .gltf files, several meshes placed by the scene, targets by name,
sparse / quantized / interleaved / strip data, external and embedded buffers, and one-line refusals."""
import base64
import json
import struct
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pygltflib")

from facegeom.errors import InputError  # noqa: E402
from facegeom.io import GltfRig, RigPart, read_gltf_rig  # noqa: E402
from facegeom.io.gltf import write_rig_glb  # noqa: E402

BYTE, UBYTE, SHORT, USHORT, UINT, FLOAT = 5120, 5121, 5122, 5123, 5125, 5126
DTYPE = {BYTE: np.int8, UBYTE: np.uint8, SHORT: np.int16, USHORT: np.uint16, UINT: np.uint32, FLOAT: np.float32}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
TRI = np.array([[0, 0, 0.5], [0.5, 0, 0.5], [0, 0.5, 0.5]])


class Doc:
    """A glTF document written by hand: the JSON and one binary buffer (buffer 0)."""

    def __init__(self):
        self.json = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": []}], "nodes": [],
                     "meshes": [], "accessors": [], "bufferViews": [], "buffers": [{"byteLength": 0}]}
        self.blob = bytearray()

    def view(self, data: bytes, stride=None, buffer=0) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        bv = {"buffer": buffer, "byteOffset": len(self.blob), "byteLength": len(data)}
        if stride:
            bv["byteStride"] = stride
        self.blob += data
        self.json["buffers"][0]["byteLength"] = len(self.blob)
        self.json["bufferViews"].append(bv)
        return len(self.json["bufferViews"]) - 1

    def accessor(self, array=None, ctype=FLOAT, kind="VEC3", normalized=False, view="new", offset=0, count=None,
                 sparse=None) -> int:
        acc = {"componentType": ctype, "type": kind}
        if array is not None:
            array = np.asarray(array, dtype=DTYPE[ctype])
            acc["count"] = int(array.shape[0])
            if view == "new":
                view = self.view(array.tobytes())
        if view is not None and view != "new":
            acc["bufferView"] = view
            acc["byteOffset"] = offset
        if count is not None:
            acc["count"] = count
        if normalized:
            acc["normalized"] = True
        if sparse is not None:
            acc["sparse"] = sparse
        self.json["accessors"].append(acc)
        return len(self.json["accessors"]) - 1

    def sparse(self, rows, values, ictype=UBYTE, vtype=FLOAT) -> dict:
        rows = np.asarray(rows, dtype=DTYPE[ictype])
        values = np.asarray(values, dtype=DTYPE[vtype])
        return {"count": int(rows.size),
                "indices": {"bufferView": self.view(rows.tobytes()), "componentType": ictype},
                "values": {"bufferView": self.view(values.tobytes())}}

    def primitive(self, V, F=None, targets=(), mode=None) -> dict:
        prim = {"attributes": {"POSITION": self.accessor(V)}}
        if F is not None:
            prim["indices"] = self.accessor(np.asarray(F).reshape(-1), UINT, "SCALAR")
        if targets:
            prim["targets"] = [{"POSITION": self.accessor(d) if not isinstance(d, int) else d} for d in targets]
        if mode is not None:
            prim["mode"] = mode
        return prim

    def mesh(self, primitives, names=None, name=None) -> int:
        mesh = {"primitives": list(primitives)}
        if names is not None:
            mesh["extras"] = {"targetNames": list(names)}
        if name is not None:
            mesh["name"] = name
        self.json["meshes"].append(mesh)
        return len(self.json["meshes"]) - 1

    def node(self, mesh=None, name=None, children=(), root=False, **props) -> int:
        node = dict(props)
        if mesh is not None:
            node["mesh"] = mesh
        if name is not None:
            node["name"] = name
        if children:
            node["children"] = list(children)
        self.json["nodes"].append(node)
        i = len(self.json["nodes"]) - 1
        if root:
            self.json["scenes"][0]["nodes"].append(i)
        return i

    def glb(self, path: Path) -> Path:
        text = json.dumps(self.json).encode()
        text += b" " * (-len(text) % 4)
        blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
        if blob:
            chunks += struct.pack("<II", len(blob), 0x004E4942) + blob
        path.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks)
        return path

    def gltf(self, path: Path, uri="data") -> Path:
        """A .gltf with buffer 0 as a data URI (``uri="data"``) or in a file next to it named by ``uri``."""
        if uri == "data":
            self.json["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                                              + base64.b64encode(bytes(self.blob)).decode())
        else:
            self.json["buffers"][0]["uri"] = uri
            (path.parent / uri.replace("%20", " ")).write_bytes(bytes(self.blob))
        path.write_text(json.dumps(self.json))
        return path


def simple(targets=True) -> Doc:
    """One quad mesh with two named targets under one node."""
    doc = Doc()
    D = [np.full((4, 3), 0.1), np.eye(4, 3)] if targets else []
    m = doc.mesh([doc.primitive(QUAD, QUAD_F, D)], names=["a", "b"] if targets else None, name="quad")
    doc.node(m, "Quad", root=True)
    return doc


def rotation_y(deg):
    t = np.radians(deg)
    return np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])


def quat_y(deg):
    t = np.radians(deg) / 2
    return [0.0, float(np.sin(t)), 0.0, float(np.cos(t))]


def refused(path, match=None, **kw) -> str:
    with pytest.raises(InputError) as e:
        read_gltf_rig(path, **kw)
    msg = str(e.value)
    assert str(path) in msg and "\n" not in msg, msg
    if match:
        assert match in msg, msg
    return msg


# ----------------------------------------------------------------------------- reading


def test_write_rig_glb_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 4))
    V = np.c_[x.ravel(), y.ravel(), 0.1 * np.sin(x.ravel())]
    F = np.array([[j * 5 + i, j * 5 + i + 1, j * 5 + i + 6] for j in range(3) for i in range(4)]
                 + [[j * 5 + i, j * 5 + i + 6, j * 5 + i + 5] for j in range(3) for i in range(4)])
    D = rng.normal(scale=0.05, size=(3, V.shape[0], 3))
    names = ["jawOpen", "eyeBlinkLeft", "mouthSmile_L"]
    out = write_rig_glb(tmp_path / "rig.glb", V, F, D, names, rng.uniform(size=(4, 3)), 30.0)
    rig = read_gltf_rig(out)
    assert isinstance(rig, GltfRig) and rig.units == "m" and rig.up_axis == "+y" and rig.path == str(out)
    assert rig.neutral.dtype == np.float64 and rig.faces.dtype == np.int64 and rig.deltas.dtype == np.float64
    assert np.allclose(rig.neutral, V, atol=1e-6) and np.array_equal(rig.faces, F)
    assert np.allclose(rig.deltas, D, atol=1e-7) and rig.names == tuple(names)
    assert rig.parts == (RigPart("face", 0, V.shape[0], 0, F.shape[0], True),)
    assert not rig.neutral.flags.writeable and not rig.deltas.flags.writeable
    with pytest.raises(AttributeError):
        rig.names = ()


def test_two_meshes_placed_by_nodes_and_targets_matched_by_name(tmp_path):
    doc = Doc()
    head_d = {"jawOpen": np.tile([0, -0.1, 0], (4, 1)), "eyeBlinkLeft": np.eye(4, 3) * 0.01}
    teeth_d = np.tile([0.0, -0.02, 0.01], (3, 1))
    head = doc.mesh([doc.primitive(QUAD, QUAD_F, list(head_d.values()))], names=list(head_d), name="head")
    teeth = doc.mesh([doc.primitive(TRI, [[0, 1, 2]], [teeth_d])], names=["jawOpen"], name="teeth")
    t_node = doc.node(teeth, "Teeth", rotation=quat_y(90), translation=[0, -0.05, 0.02])
    doc.node(head, "Head", children=[t_node], root=True, translation=[0, 1.6, 0])
    for path in (doc.glb(tmp_path / "two.glb"), doc.gltf(tmp_path / "two.gltf")):
        rig = read_gltf_rig(path)
        assert rig.names == ("jawOpen", "eyeBlinkLeft")
        assert [p.name for p in rig.parts] == ["Head", "Teeth"]
        h, t = rig.parts
        assert (h.vertex_start, h.vertex_stop, h.face_start, h.face_stop) == (0, 4, 0, 2)
        assert (t.vertex_start, t.vertex_stop, t.face_start, t.face_stop) == (4, 7, 2, 3)
        R = rotation_y(90)
        assert np.allclose(rig.neutral[:4], QUAD + [0, 1.6, 0])
        assert np.allclose(rig.neutral[4:], TRI @ R.T + [0, 1.55, 0.02])
        assert np.allclose(rig.deltas[0, :4], head_d["jawOpen"])
        assert np.allclose(rig.deltas[1, :4], head_d["eyeBlinkLeft"])
        assert np.allclose(rig.deltas[0, 4:], teeth_d @ R.T)
        assert not rig.deltas[1, 4:].any()  # the teeth have no eyeBlinkLeft
        assert np.array_equal(rig.faces, np.r_[QUAD_F, [[4, 5, 6]]])


def test_instances_scene_membership_and_mesh_selection(tmp_path):
    doc = Doc()
    head = doc.mesh([doc.primitive(QUAD, QUAD_F, [np.full((4, 3), 0.1)])], names=["smile"], name="head")
    eye = doc.mesh([doc.primitive(TRI, [[0, 1, 2]])], name="eye")
    hat = doc.mesh([doc.primitive(TRI + 5, [[0, 1, 2]], [np.ones((3, 3))])], names=["lift"], name="hat")
    doc.node(head, "Head", root=True)
    doc.node(eye, "EyeL", root=True, translation=[0.03, 0, 0])
    doc.node(eye, "EyeR", root=True, translation=[-0.03, 0, 0])
    doc.node(hat, "Hat")  # not in the scene
    path = doc.glb(tmp_path / "inst.glb")
    rig = read_gltf_rig(path)
    assert [p.name for p in rig.parts] == ["Head", "EyeL", "EyeR"] and rig.names == ("smile",)
    assert [p.has_targets for p in rig.parts] == [True, False, False]
    assert np.allclose(rig.neutral[4:7], TRI + [0.03, 0, 0]) and np.allclose(rig.neutral[7:], TRI - [0.03, 0, 0])
    assert not rig.deltas[:, 4:].any() and rig.faces.max() == 9
    assert [p.name for p in read_gltf_rig(path, mesh="head").parts] == ["Head"]
    assert [p.name for p in read_gltf_rig(path, mesh=["Head", "EyeL"]).parts] == ["Head", "EyeL"]
    msg = refused(path, "no mesh or node named 'Nose'", mesh=["Head", "Nose"])
    assert "'EyeL'" in msg  # the names it has
    refused(path, "no blendshapes (morph targets)", mesh="eye")
    refused(path, "mesh must be", mesh=3)


def test_several_primitives_and_same_names_are_made_distinct(tmp_path):
    doc = Doc()
    m = doc.mesh([doc.primitive(QUAD, QUAD_F, [np.ones((4, 3)), np.ones((4, 3))]),
                  doc.primitive(TRI, [[0, 1, 2]], [np.ones((3, 3)), 2 * np.ones((3, 3))])],
                 names=["x", "x"], name="body")
    doc.node(m, root=True)
    doc.node(m, root=True)
    rig = read_gltf_rig(doc.glb(tmp_path / "p.glb"))
    assert rig.names == ("x", "x.1")
    assert [p.name for p in rig.parts] == ["body.prim0", "body.prim1", "body.prim0.1", "body.prim1.1"]
    assert np.allclose(rig.deltas[1, 4:7], 2.0) and rig.neutral.shape == (14, 3)


def test_sparse_morph_targets(tmp_path):
    doc = Doc()
    only = doc.accessor(count=4, view=None, sparse=doc.sparse([1, 3], [[0, 0, 1], [0, 2, 0]]))
    base = doc.view(np.full((4, 3), 0.1, dtype=np.float32).tobytes())
    over = doc.accessor(count=4, view=base, sparse=doc.sparse([0], [[5, 5, 5]], ictype=USHORT))
    m = doc.mesh([doc.primitive(QUAD, QUAD_F, [only, over])], names=["only", "over"])
    doc.node(m, root=True)
    rig = read_gltf_rig(doc.glb(tmp_path / "sparse.glb"))
    assert np.allclose(rig.deltas[0], [[0, 0, 0], [0, 0, 1], [0, 0, 0], [0, 2, 0]])
    assert np.allclose(rig.deltas[1], [[5, 5, 5], [0.1] * 3, [0.1] * 3, [0.1] * 3])
    assert [p.name for p in rig.parts] == ["mesh0.prim0"]


def test_khr_mesh_quantization(tmp_path):
    """int16 normalized positions and int8 normalized offsets (4-byte aligned strides), dequantised by the node."""
    doc = Doc()
    doc.json["extensionsUsed"] = doc.json["extensionsRequired"] = ["KHR_mesh_quantization"]
    P = np.array([[0, 0, 0], [32767, 0, 0], [32767, 32767, 0], [-32768, 32767, -16384]], dtype=np.int16)
    T = np.array([[0, 0, 127], [0, -128, 64], [1, 2, 3], [-127, 0, 0]], dtype=np.int8)
    pv = doc.view(np.c_[P, np.zeros(4, np.int16)].tobytes(), stride=8)
    tv = doc.view(np.c_[T, np.zeros(4, np.int8)].tobytes(), stride=4)
    prim = {"attributes": {"POSITION": doc.accessor(ctype=SHORT, normalized=True, view=pv, count=4)},
            "indices": doc.accessor(np.array([0, 1, 2, 0, 2, 3]), USHORT, "SCALAR"),
            "targets": [{"POSITION": doc.accessor(ctype=BYTE, normalized=True, view=tv, count=4)}]}
    m = doc.mesh([prim], names=["open"])
    doc.node(m, root=True, scale=[0.2, 0.2, 0.2], translation=[1, 2, 3])
    rig = read_gltf_rig(doc.glb(tmp_path / "q.glb"))
    assert np.allclose(rig.neutral, np.maximum(P / 32767.0, -1) * 0.2 + [1, 2, 3])
    assert np.allclose(rig.deltas[0], np.maximum(T / 127.0, -1) * 0.2)
    assert rig.neutral[3, 0] == pytest.approx(1 - 0.2)  # -32768 clamps to -1
    assert np.array_equal(rig.faces, QUAD_F)


def test_gltf_with_external_bin_interleaved_and_a_data_uri(tmp_path):
    doc = Doc()
    N = np.tile([0, 0, 1.0], (4, 1))
    inter = doc.view(np.c_[QUAD, N].astype(np.float32).tobytes(), stride=24)  # position, normal, position ...
    prim = {"attributes": {"POSITION": doc.accessor(view=inter, count=4),
                           "NORMAL": doc.accessor(view=inter, offset=12, count=4)},
            "indices": doc.accessor(QUAD_F.reshape(-1), UBYTE, "SCALAR")}
    D = np.arange(12, dtype=np.float32).reshape(4, 3) / 10
    doc.json["buffers"].append({"byteLength": D.nbytes, "uri": "data:application/gltf-buffer;base64,"
                                + base64.b64encode(D.tobytes()).decode()})
    doc.json["bufferViews"].append({"buffer": 1, "byteOffset": 0, "byteLength": D.nbytes})
    prim["targets"] = [{"POSITION": doc.accessor(view=len(doc.json["bufferViews"]) - 1, count=4)}]
    doc.node(doc.mesh([prim], names=["t"]), root=True)
    path = doc.gltf(tmp_path / "ext.gltf", uri="my%20rig.bin")
    assert (tmp_path / "my rig.bin").exists()
    rig = read_gltf_rig(path)
    assert np.allclose(rig.neutral, QUAD) and np.allclose(rig.deltas[0], D) and np.array_equal(rig.faces, QUAD_F)
    (tmp_path / "my rig.bin").write_bytes(bytes(doc.blob[:10]))
    refused(path, "fewer than its byteLength")
    (tmp_path / "my rig.bin").unlink()
    refused(path, "not found next to the document")


def test_triangle_strips_and_fans(tmp_path):
    doc = Doc()
    V = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=float)
    strip = doc.primitive(V[:5], [0, 1, 2, 3, 4], [np.ones((5, 3))], mode=5)
    degenerate = doc.primitive(V, [0, 1, 2, 2, 3, 4, 5], [np.ones((6, 3))], mode=5)
    fan = doc.primitive(V[:5], None, [np.ones((5, 3))], mode=6)
    doc.node(doc.mesh([strip, degenerate, fan], names=["t"], name="m"), root=True)
    rig = read_gltf_rig(doc.glb(tmp_path / "strip.glb"))
    s, d, f = rig.parts
    assert np.array_equal(rig.faces[s.face_start:s.face_stop], [[0, 1, 2], [1, 3, 2], [2, 3, 4]])
    # p_i = {v_i, v_i+(1+i%2), v_i+(2-i%2)}; (2, 2, 3) and (2, 3, 2) are degenerate and dropped
    assert np.array_equal(rig.faces[d.face_start:d.face_stop] - d.vertex_start, [[0, 1, 2], [2, 4, 3], [3, 4, 5]])
    assert np.array_equal(rig.faces[f.face_start:f.face_stop] - f.vertex_start, [[1, 2, 0], [2, 3, 0], [3, 4, 0]])


def test_skinned_mesh_is_placed_by_its_joints(tmp_path):
    """Bind pose: joints x inverse bind matrices is one transform, the skinned node's own is ignored.
    Posed: linear blend skinning by JOINTS_0 / WEIGHTS_0."""
    def build(posed: bool) -> Doc:
        doc = Doc()
        prim = doc.primitive(QUAD, QUAD_F, [np.tile([0, 0, 0.1], (4, 1))])
        prim["attributes"]["JOINTS_0"] = doc.accessor(np.array([[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0],
                                                                [0, 0, 0, 0]]), UBYTE, "VEC4")
        prim["attributes"]["WEIGHTS_0"] = doc.accessor(np.array([[1, 0, 0, 0], [1, 0, 0, 0], [0.5, 0.5, 0, 0],
                                                                 [1, 0, 0, 0]]), FLOAT, "VEC4")
        ibm = np.stack([np.eye(4), np.eye(4)])
        ibm[:, 1, 3] = -1.0  # both joints bound at y = 1
        j0 = doc.node(name="Root", translation=[0, 1, 0])
        j1 = doc.node(name="Jaw", translation=[0, 1, 0], rotation=quat_y(90 if posed else 0))
        doc.json["skins"] = [{"joints": [j0, j1], "inverseBindMatrices":
                              doc.accessor(ibm.transpose(0, 2, 1).reshape(2, 16), FLOAT, "MAT4")}]
        body = doc.node(doc.mesh([prim], names=["up"]), "Body", skin=0, translation=[5, 0, 0])
        doc.node(name="Armature", children=[j0, j1, body], root=True)
        return doc

    rest = read_gltf_rig(build(False).glb(tmp_path / "rest.glb"))
    assert np.allclose(rest.neutral, QUAD) and np.allclose(rest.deltas[0], [0, 0, 0.1])
    posed = read_gltf_rig(build(True).glb(tmp_path / "posed.glb"))
    R = np.eye(4)
    R[:3, :3] = rotation_y(90)
    S1 = np.array([[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1.0]]) @ R
    S1 = S1 @ np.array([[1, 0, 0, 0], [0, 1, 0, -1], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    M = [np.eye(4), S1, 0.5 * (np.eye(4) + S1), np.eye(4)]
    expect = np.array([(m @ np.r_[v, 1])[:3] for m, v in zip(M, QUAD)])
    assert np.allclose(posed.neutral, expect)
    assert np.allclose(posed.deltas[0], [m[:3, :3] @ [0, 0, 0.1] for m in M])


def test_negative_scale_keeps_the_winding_outward(tmp_path):
    doc = simple()
    doc.json["nodes"][0]["scale"] = [-1, 1, 1]
    rig = read_gltf_rig(doc.glb(tmp_path / "mirror.glb"))
    assert np.array_equal(rig.faces, QUAD_F[:, [0, 2, 1]]) and np.allclose(rig.neutral[:, 0], -QUAD[:, 0])


def test_draco_primitive_decoded_with_dracopy(tmp_path):
    DracoPy = pytest.importorskip("DracoPy")
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]], dtype=np.float32)
    F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    data = DracoPy.encode(V, F, preserve_order=True, quantization_bits=0)
    mesh = DracoPy.decode(data)
    assert np.array_equal(mesh.points, V) and np.array_equal(mesh.faces, F)  # the order the targets rely on
    doc = Doc()
    doc.json["extensionsUsed"] = doc.json["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    D = np.tile([0, 0, 0.25], (5, 1))
    prim = {"attributes": {"POSITION": doc.accessor(count=5, view=None)},
            "indices": doc.accessor(ctype=UINT, kind="SCALAR", count=12, view=None),
            "targets": [{"POSITION": doc.accessor(D)}],
            "extensions": {"KHR_draco_mesh_compression": {"bufferView": doc.view(data),
                                                          "attributes": {"POSITION": 0}}}}
    doc.node(doc.mesh([prim], names=["puff"]), root=True)
    rig = read_gltf_rig(doc.glb(tmp_path / "draco.glb"))
    assert np.allclose(rig.neutral, V) and np.array_equal(rig.faces, F) and np.allclose(rig.deltas[0], D)


def draco_doc() -> Doc:
    doc = Doc()
    doc.json["extensionsUsed"] = doc.json["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    prim = {"attributes": {"POSITION": doc.accessor(count=4, view=None)},
            "targets": [{"POSITION": doc.accessor(np.ones((4, 3)))}],
            "extensions": {"KHR_draco_mesh_compression": {"bufferView": doc.view(b"DRACO\0\0\0"),
                                                          "attributes": {"POSITION": 0}}}}
    doc.node(doc.mesh([prim], names=["t"]), root=True)
    return doc


def test_draco_without_the_decoder_names_the_package_and_the_command(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # import DracoPy raises ImportError
    msg = refused(draco_doc().glb(tmp_path / "draco.glb"), "KHR_draco_mesh_compression")
    assert "pip install DracoPy" in msg and "gltf-transform copy in.glb out.glb" in msg


def test_corrupt_draco_data_is_one_error(tmp_path):
    pytest.importorskip("DracoPy")
    refused(draco_doc().glb(tmp_path / "bad.glb"), "cannot be decoded")


def test_meshopt_is_refused_with_the_decompress_command(tmp_path):
    doc = simple()
    doc.json["extensionsUsed"] = doc.json["extensionsRequired"] = ["EXT_meshopt_compression"]
    size = doc.json["buffers"][0]["byteLength"]
    doc.json["buffers"].append({"byteLength": size, "extensions": {"EXT_meshopt_compression": {"fallback": True}}})
    for bv in doc.json["bufferViews"]:
        bv["extensions"] = {"EXT_meshopt_compression": {"buffer": 0, "byteOffset": bv["byteOffset"],
                                                        "byteLength": bv["byteLength"], "byteStride": 4,
                                                        "count": bv["byteLength"] // 4, "mode": "ATTRIBUTES"}}
        bv["buffer"] = 1
    msg = refused(doc.glb(tmp_path / "meshopt.glb"), "EXT_meshopt_compression")
    assert "gltf-transform copy in.glb out.glb" in msg


# ----------------------------------------------------------------------------- refusals


def broken(name: str) -> Doc:
    doc = simple()
    j = doc.json
    acc, prim = j["accessors"], j["meshes"][0]["primitives"][0]
    if name == "outside":
        acc[prim["attributes"]["POSITION"]]["byteOffset"] = 40
    elif name == "target count":
        acc[prim["targets"][1]["POSITION"]]["count"] = 3
    elif name == "nan":
        at = j["bufferViews"][acc[prim["attributes"]["POSITION"]]["bufferView"]]["byteOffset"]
        doc.blob[at:at + 4] = struct.pack("<f", float("nan"))
    elif name == "no mesh":
        j["nodes"][0].pop("mesh")
    elif name in ("points", "lines"):
        prim["mode"] = 0 if name == "points" else 1
    elif name == "no targets":
        prim.pop("targets")
    elif name == "index range":
        at = j["bufferViews"][acc[prim["indices"]]["bufferView"]]["byteOffset"]
        doc.blob[at:at + 4] = struct.pack("<I", 99)
    elif name == "cycle":
        j["nodes"].append({"children": [0]})
        j["nodes"][0]["children"] = [1]
    elif name == "two parents":
        j["nodes"] += [{"children": [0]}, {"children": [0]}]
    elif name == "rotation":
        j["nodes"][0]["rotation"] = [0, 0, 0]
    elif name == "version":
        j["asset"]["version"] = "1.0"
    elif name == "sparse index":
        acc[prim["targets"][0]["POSITION"]]["sparse"] = doc.sparse([7], [[1, 1, 1]])
    return doc


REFUSALS = {
    "outside": "runs past the end of its buffer",
    "target count": "morph target 1 has 3 offsets for the primitive's 4 vertices",
    "nan": "NaN or inf",
    "no mesh": "no mesh with triangles",
    "points": "draws POINTS, not triangles",
    "lines": "draws LINES, not triangles",
    "no targets": "no blendshapes (morph targets)",
    "index range": "outside 0..3",
    "cycle": "the node hierarchy must be a tree",
    "two parents": "the node hierarchy must be a tree",
    "rotation": "rotation must be 4 numbers",
    "version": "only glTF 2.0 is read",
    "sparse index": "sparse indices outside 0..3",
}


@pytest.mark.parametrize("name", sorted(REFUSALS))
def test_refusals_are_one_line_naming_the_file(tmp_path, name):
    refused(broken(name).glb(tmp_path / f"{name.replace(' ', '_')}.glb"), REFUSALS[name])
    refused(broken(name).gltf(tmp_path / f"{name.replace(' ', '_')}.gltf"), REFUSALS[name])


def test_a_skin_joint_in_a_node_cycle(tmp_path):
    doc = simple()
    doc.json["nodes"] += [{"children": [2]}, {"children": [1]}]  # outside the scene, each with one parent
    doc.json["skins"] = [{"joints": [1]}]
    doc.json["nodes"][0]["skin"] = 0
    refused(doc.glb(tmp_path / "cyc.glb"), "cycle")


def test_bad_files(tmp_path):
    good = simple().glb(tmp_path / "good.glb").read_bytes()
    cases = {"cut.glb": good[: len(good) // 2], "text.glb": b"hello world" * 10, "short.glb": good[:12],
             "empty.gltf": b"", "json.gltf": b'{"asset": {"version": "2.0"}, "meshes": [',
             "list.gltf": b"[1, 2]", "v1.glb": good[:4] + b"\x01\0\0\0" + good[8:],
             "deep.gltf": b"[" * 100000, "utf16.gltf": '{"asset": {}}'.encode("utf-16"),
             "wrongtype.gltf": b'{"asset": {"version": "2.0"}, "meshes": 5, "accessors": "x"}',
             "chunk.glb": good[:12] + struct.pack("<I", 10 ** 6) + good[16:]}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        refused(tmp_path / name)
    refused(tmp_path / "json.gltf", "bad JSON")
    refused(tmp_path / "none.glb", "file not found")
    refused(tmp_path, "not a file")


@pytest.mark.parametrize("uri", ["../rig.bin", "sub/../../rig.bin", "%2e%2e/rig.bin", "/etc/passwd",
                                 "http://example.com/rig.bin", "file:///etc/passwd", "C:/rig.bin", "//host/rig.bin",
                                 "rig.bin?x=1"])
def test_buffers_outside_the_folder_or_online_are_refused(tmp_path, uri):
    inner = tmp_path / "inner"
    inner.mkdir()
    (tmp_path / "rig.bin").write_bytes(b"\0" * 200)
    doc = simple()
    doc.json["buffers"][0]["uri"] = uri
    path = inner / "rig.gltf"
    path.write_text(json.dumps(doc.json))
    msg = refused(path)
    assert "outside" in msg or "URL" in msg


def test_a_link_out_of_the_folder_is_refused(tmp_path):
    inner = tmp_path / "inner"
    inner.mkdir()
    doc = simple()
    (tmp_path / "rig.bin").write_bytes(bytes(doc.blob))
    (inner / "rig.bin").symlink_to(tmp_path / "rig.bin")
    doc.json["buffers"][0]["uri"] = "rig.bin"
    path = inner / "rig.gltf"
    path.write_text(json.dumps(doc.json))
    refused(path, "outside the document's folder")


def huge(kind: str) -> Doc:
    doc = simple()
    j = doc.json
    prim = j["meshes"][0]["primitives"][0]
    pos = j["accessors"][prim["attributes"]["POSITION"]]
    tgt = j["accessors"][prim["targets"][0]["POSITION"]]
    if kind == "view":  # data for 4 vertices, a count of 1e8
        pos["count"] = tgt["count"] = 10 ** 8
    elif kind == "no view":  # zeros claimed for 1e8 vertices
        pos.pop("bufferView")
        pos["count"] = tgt["count"] = 10 ** 8
        tgt.pop("bufferView")
    elif kind == "sparse":
        tgt.pop("bufferView")
        tgt["count"] = 10 ** 8
        tgt["sparse"] = doc.sparse([0], [[1, 1, 1]])
    elif kind == "targets":  # 1000 targets of 100 000 vertices, all zeros
        tgt.pop("bufferView")
        pos.pop("bufferView")
        pos["count"] = tgt["count"] = 10 ** 5
        prim["targets"] = prim["targets"][:1] * 1000
        j["meshes"][0]["extras"] = {"targetNames": [f"t{k}" for k in range(1000)]}
    elif kind == "stride":
        j["bufferViews"][pos["bufferView"]]["byteStride"] = 2 ** 31
    return doc


@pytest.mark.parametrize("kind", ["view", "no view", "sparse", "targets", "stride"])
def test_huge_counts_are_refused_at_once_without_allocating(tmp_path, kind):
    path = huge(kind).glb(tmp_path / "huge.glb")
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        refused(path)
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert elapsed < 1.0 and peak < 64 * path.stat().st_size + (8 << 20), (elapsed, peak)
