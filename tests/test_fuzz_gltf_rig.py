"""Property test of read_gltf_rig: mutated, truncated or rewritten glTF rigs either read as a consistent
GltfRig or raise one InputError naming the file, nothing else (no other exception, bounded memory and time).

Seeds: facegeom's own ``write_rig_glb`` output, and a hand-made rig of two meshes under transformed
nodes (sparse, quantized and strip data) as a ``.glb`` and as a ``.gltf`` with a data URI. Edits: bytes
cut, flipped or a ``.glb`` chunk length changed (as in test_fuzz_readers.py), and JSON edits that keep
the file parseable (a value replaced by a huge, negative, wrong-typed one, a key deleted, a list
emptied) so the reader's own checks are reached. ``FACEGEOM_FUZZ_EXAMPLES`` sets the examples per
seed (default 100, derandomized so CI is stable; set it for a long, random run).
"""
from __future__ import annotations

import copy
import json
import struct
import tracemalloc

import numpy as np
import pytest
from hypothesis import strategies as st

pytest.importorskip("pygltflib")

from facegeom.errors import InputError
from facegeom.io import GltfRig, read_gltf_rig
from facegeom.io.gltf import write_rig_glb
from tests.fuzzing import campaign
from tests.test_gltf_rig import BYTE, QUAD, QUAD_F, SHORT, TRI, Doc, quat_y

REPLACEMENTS = [0, -1, 1, 3, 255, 65535, 2 ** 31, 2 ** 32 - 1, 10 ** 9, 10 ** 20, -(2 ** 31), 0.5, 1e308, "x", "",
                None, True, [], {}, [0, 0, 0], [1e308, 0, 0, 1], {"POSITION": 0}, "data:,", "../x.bin",
                "http://example.com/x.bin", 5120, 5121, 5122, 5123, 5125, 5126, "VEC3", "SCALAR", "MAT4"]


def _rig_seed(tmp_path_factory) -> bytes:
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    D = np.stack([np.full((4, 3), 0.1), np.eye(4, 3)])
    path = tmp_path_factory.mktemp("seed") / "seed.glb"
    return write_rig_glb(path, V, QUAD_F, D, ["a", "b"], np.zeros((1, 2)), 30.0).read_bytes()


def _rich_doc() -> Doc:
    """Two meshes under transformed nodes: quantized positions, a sparse target, a strip, an instance."""
    doc = Doc()
    doc.json["extensionsUsed"] = ["KHR_mesh_quantization"]
    P = (QUAD * 30000).astype(np.int16)
    pv = doc.view(np.c_[P, np.zeros(4, np.int16)].tobytes(), stride=8)
    T = np.array([[0, 0, 127], [0, -128, 64], [1, 2, 3], [-127, 0, 0]], dtype=np.int8)
    tv = doc.view(np.c_[T, np.zeros(4, np.int8)].tobytes(), stride=4)
    sparse = doc.sparse([1, 3], [[0, 0, 1], [0, 2, 0]])
    head = {"attributes": {"POSITION": doc.accessor(ctype=SHORT, normalized=True, view=pv, count=4)},
            "indices": doc.accessor(QUAD_F.reshape(-1), 5123, "SCALAR"),
            "targets": [{"POSITION": doc.accessor(ctype=BYTE, normalized=True, view=tv, count=4)},
                        {"POSITION": doc.accessor(count=4, view=None, sparse=sparse)}]}
    teeth = doc.primitive(TRI, [0, 1, 2], [np.ones((3, 3))], mode=5)
    h = doc.mesh([head], names=["jawOpen", "blink"], name="head")
    t = doc.mesh([teeth], names=["jawOpen"], name="teeth")
    tn = doc.node(t, "Teeth", rotation=quat_y(90), translation=[0, -0.05, 0.02])
    doc.node(h, "Head", children=[tn], root=True, scale=[1e-4, 1e-4, 1e-4], translation=[0, 1.6, 0])
    doc.node(t, "Teeth2", root=True, matrix=[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.1, 0, 0, 1])
    return doc


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("seeds")
    return {"own.glb": _rig_seed(tmp_path_factory), "rich.glb": _rich_doc().glb(d / "rich.glb").read_bytes(),
            "rich.gltf": _rich_doc().gltf(d / "rich.gltf").read_bytes()}


def _split(data: bytes) -> tuple[dict, bytes] | None:
    """The JSON and BIN chunk of a .glb (``None`` if it is not one), or the JSON of a .gltf."""
    try:
        if data[:4] == b"glTF":
            n = struct.unpack_from("<I", data, 12)[0]
            return json.loads(data[20:20 + n]), data[28 + n:]
        return json.loads(data), b""
    except (ValueError, struct.error):
        return None


def _join(tree: dict, blob: bytes, glb: bool) -> bytes:
    text = json.dumps(tree).encode()
    if not glb:
        return text
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _slots(node):
    """Every (container, key) of the JSON tree."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in list(items):
        yield node, k
        yield from _slots(v)


@st.composite
def mutated(draw, seed: bytes) -> bytes:
    """The seed with 1-3 JSON edits and/or byte edits."""
    data = seed
    glb = seed[:4] == b"glTF"
    if draw(st.booleans()):
        tree, blob = _split(data)
        for _ in range(draw(st.integers(1, 3))):
            slots = list(_slots(tree))
            container, key = slots[draw(st.integers(0, len(slots) - 1))]
            op = draw(st.sampled_from(["replace", "replace", "delete", "empty"]))
            if op == "delete" and isinstance(container, dict):
                del container[key]
            elif op == "empty" and isinstance(container[key], (list, dict)):
                container[key] = type(container[key])()
            else:
                container[key] = copy.deepcopy(draw(st.sampled_from(REPLACEMENTS)))
        data = _join(tree, blob, glb)
    data = bytearray(data)
    for _ in range(draw(st.integers(0, 2))):
        op = draw(st.sampled_from(["cut", "flip", "length"]))
        if op == "cut":
            data = data[:draw(st.integers(0, len(data)))]
        elif op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
        elif op == "length" and glb and len(data) >= 16:
            at = draw(st.sampled_from([8, 12]))
            data[at:at + 4] = struct.pack("<I", draw(st.sampled_from([0, 1, 7, 2 ** 31, 2 ** 32 - 1])))
    return bytes(data)


def check_rig(path) -> None:
    """Only a consistent GltfRig or one single-line InputError naming the file; memory bounded."""
    tracemalloc.start()
    try:
        try:
            rig = read_gltf_rig(path)
        except InputError as exc:
            assert "\n" not in str(exc) and str(path) in str(exc), str(exc)
            return
        finally:
            peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < (128 << 20), f"{peak} bytes for a {path.stat().st_size}-byte file"
    assert isinstance(rig, GltfRig) and rig.units == "m"
    V, F, D = rig.neutral, rig.faces, rig.deltas
    n, K = V.shape[0], len(rig.names)
    assert V.dtype == np.float64 and V.shape == (n, 3) and n >= 1 and np.isfinite(V).all()
    assert F.dtype == np.int64 and F.ndim == 2 and F.shape[1] == 3 and F.shape[0] >= 1
    assert F.min() >= 0 and F.max() < n
    assert D.dtype == np.float64 and D.shape == (K, n, 3) and K >= 1 and np.isfinite(D).all()
    assert len(set(rig.names)) == K and all(isinstance(s, str) and s for s in rig.names)
    v = f = 0
    for part in rig.parts:
        assert (part.vertex_start, part.face_start) == (v, f)
        v, f = part.vertex_stop, part.face_stop
    assert (v, f) == (n, F.shape[0]) and len({p.name for p in rig.parts}) == len(rig.parts)


@pytest.mark.parametrize("name", ["own.glb", "rich.glb", "rich.gltf"])
def test_seed_is_valid(tmp_path, seeds, name):
    path = tmp_path / name
    path.write_bytes(seeds[name])
    check_rig(path)
    rig = read_gltf_rig(path)
    assert rig.names == (("a", "b") if name == "own.glb" else ("jawOpen", "blink"))


@pytest.mark.parametrize("name", ["own.glb", "rich.glb", "rich.gltf"])
def test_mutated_rig_reads_or_raises_input_error(tmp_path, seeds, name):
    def run(data):
        path = tmp_path / name
        path.write_bytes(data)
        check_rig(path)

    campaign(run, share=4, data=mutated(seeds[name]))  # the fourth: load_rig on a .glb, in test_fuzz_readers
