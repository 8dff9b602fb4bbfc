"""Hostile glTF rigs and animations, and photos sized from their headers: bounded work, one line naming the file.

Each test writes its own reproducer. What the audit found:

1. a ``.gltf`` whose buffer URI names a FIFO hung ``solve`` and ``transfer`` (opening a pipe waits for a writer);
2. 100,000 nodes (3.1 MB of JSON) spent 46 s inside pygltflib before any check;
3. 10,000 morph targets sharing one padded buffer view (a 6.4 MB file) reached 8.9 GB;
4. unknown ``extensionsRequired`` were ignored silently;
5. a photo's size and orientation must come from its header, the size limit before any decode.

A read that could hang runs in a child process with a time limit or under ``signal`` alarm; a read that could
allocate gigabytes runs in a child process under an address-space limit.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import struct
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pygltflib")

from facegeom.errors import InputError
from facegeom.io import read_gltf_rig
from facegeom.io.gltf import read_glb_animation, write_rig_glb
from tests.test_gltf_rig import QUAD, QUAD_F, simple

ROOT = Path(__file__).resolve().parents[1]


class Hang(BaseException):
    """A read ran past its time limit (a BaseException: no ``except Exception`` in the reader swallows it)."""


@contextlib.contextmanager
def within(seconds: float):
    """Raise :class:`Hang` in the body after ``seconds`` (wall clock; the main thread only)."""
    def ring(signum, frame):
        raise Hang(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def one_line(exc: BaseException, path, *words) -> str:
    msg = str(exc)
    assert "\n" not in msg and str(path) in msg, msg
    for w in words:
        assert w in msg, msg
    return msg


def glb_bytes(tree: dict, blob: bytes = b"") -> bytes:
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if blob:
        chunks += struct.pack("<II", len(blob), 0x004E4942) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def split_glb(data: bytes) -> tuple[dict, bytes]:
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + n]), data[28 + n:]


def child(code: str, timeout: float, memory: int | None = None) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh Python (the repository on its path), under an address-space limit of ``memory``
    bytes when given; ``subprocess.TimeoutExpired`` past ``timeout`` seconds (the child is killed)."""
    head = "import resource\n"
    if memory is not None:
        head += f"resource.setrlimit(resource.RLIMIT_AS, ({memory}, {memory}))\n"
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", head + textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=timeout, env=env, cwd=str(ROOT), check=False)


# ----------------------------------------------------------------------------- 1. a buffer that is a pipe

READ_RIG = """
    import sys
    from facegeom.errors import InputError
    from facegeom.io import read_gltf_rig
    try:
        read_gltf_rig(sys.argv[-1] if len(sys.argv) > 1 else {path!r})
        print("READ")
    except InputError as exc:
        print("ERROR", exc)
"""


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
@pytest.mark.parametrize("how", ["fifo", "link to a fifo"])
def test_a_buffer_uri_naming_a_pipe_is_refused_not_waited_on(tmp_path, how):
    os.mkfifo(tmp_path / "pipe.bin")
    if how == "link to a fifo":
        (tmp_path / "buf.bin").symlink_to(tmp_path / "pipe.bin")
    doc = simple()
    doc.json["buffers"][0]["uri"] = "pipe.bin" if how == "fifo" else "buf.bin"
    path = tmp_path / "rig.gltf"
    path.write_text(json.dumps(doc.json))
    try:
        r = child(READ_RIG.format(path=str(path)), timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("read_gltf_rig waited on the pipe for 30 s")
    out = r.stdout.strip()
    assert r.returncode == 0 and out.startswith("ERROR"), (r.stdout, r.stderr)
    one_line(out, path, "not a regular file")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_transfer_of_a_gltf_whose_buffer_is_a_pipe_is_one_line(tmp_path):
    os.mkfifo(tmp_path / "pipe.bin")
    doc = simple()
    doc.json["buffers"][0]["uri"] = "pipe.bin"
    path = tmp_path / "head.gltf"
    path.write_text(json.dumps(doc.json))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    try:
        r = subprocess.run([sys.executable, "-m", "facegeom", "transfer", str(path), "-o", str(tmp_path / "o.npz")],
                           capture_output=True, text=True, timeout=60, env=env, check=False)
    except subprocess.TimeoutExpired:
        pytest.fail("facegeom transfer waited on the pipe for 60 s")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "head.gltf" in lines[0] and "not a regular file" in lines[0], lines[0]
    assert not (tmp_path / "o.npz").exists()


def test_a_buffer_file_still_reads_and_a_link_out_of_the_folder_is_still_refused(tmp_path):
    doc = simple()
    rig = read_gltf_rig(doc.gltf(tmp_path / "rig.gltf", uri="rig.bin"))
    assert rig.names == ("a", "b")
    (tmp_path / "zero.bin").symlink_to("/dev/zero")
    doc.json["buffers"][0]["uri"] = "zero.bin"
    (tmp_path / "zero.gltf").write_text(json.dumps(doc.json))
    with within(20), pytest.raises(InputError) as e:
        read_gltf_rig(tmp_path / "zero.gltf")
    one_line(e.value, tmp_path / "zero.gltf", "outside the document's folder")


# ----------------------------------------------------------------------------- 2. counts no face rig needs

def _base(tmp_path) -> tuple[dict, bytes]:
    """The JSON tree and BIN chunk of facegeom's own rig .glb (a quad, two targets, a weights animation)."""
    out = write_rig_glb(tmp_path / "base.glb", QUAD, QUAD_F, np.stack([np.full((4, 3), 0.1), np.eye(4, 3)]),
                        ["a", "b"], np.zeros((2, 2)), 30.0)
    return split_glb(out.read_bytes())


def _inflate(tree: dict, kind: str, count: int) -> None:
    """Give the document ``count`` of ``kind`` (cheap JSON objects; the rig itself unchanged)."""
    if kind == "nodes":
        tree["nodes"] += [{"name": f"joint{i}", "translation": [0.0, 0.01, 0.0]} for i in range(count)]
    elif kind == "meshes":
        tree["meshes"] += [{"primitives": [{"attributes": {"POSITION": 1}}]} for _ in range(count)]
    elif kind == "primitives":
        tree["meshes"].append({"primitives": [{"attributes": {"POSITION": 1}} for _ in range(count)]})
    elif kind == "accessors":
        tree["accessors"] += [{"bufferView": 0, "componentType": 5126, "count": 1, "type": "SCALAR"}
                              for _ in range(count)]
    elif kind == "bufferViews":
        tree["bufferViews"] += [{"buffer": 0, "byteLength": 4} for _ in range(count)]
    elif kind == "animation channels":
        anim = tree["animations"][0]
        anim["channels"] += [{"sampler": 0, "target": {"node": 0, "path": "weights"}} for _ in range(count)]
    elif kind == "animation samplers":
        anim = tree["animations"][0]
        anim["samplers"] += [dict(anim["samplers"][0]) for _ in range(count)]
    elif kind == "animations":
        tree["animations"] += [{"channels": [], "samplers": []} for _ in range(count)]
    elif kind == "morph targets":
        prim = tree["meshes"][0]["primitives"][0]
        prim["targets"] += [{"POSITION": prim["targets"][0]["POSITION"]} for _ in range(count)]
    elif kind == "scenes":
        tree["scenes"] += [{"nodes": []} for _ in range(count)]
    elif kind == "skins":
        tree["skins"] = [{"joints": [0]} for _ in range(count)]
    else:  # pragma: no cover
        raise ValueError(kind)


#: Far past what any face rig or animation holds, each one JSON object a few bytes long (the audit's 100,000
#: nodes: 46 s in pygltflib).
MANY = {"nodes": 100_000, "meshes": 50_000, "primitives": 50_000, "accessors": 100_000, "bufferViews": 100_000,
        "animation channels": 100_000, "animation samplers": 100_000, "animations": 50_000,
        "morph targets": 10_000, "scenes": 50_000, "skins": 50_000}


@pytest.mark.parametrize("kind", list(MANY))
def test_counts_no_face_rig_needs_are_refused_from_the_json(tmp_path, kind):
    tree, blob = _base(tmp_path)
    _inflate(tree, kind, MANY[kind])
    glb = tmp_path / "many.glb"
    glb.write_bytes(glb_bytes(tree, blob))
    tree["buffers"][0]["uri"] = "many.bin"
    (tmp_path / "many.bin").write_bytes(blob)
    gltf = tmp_path / "many.gltf"
    gltf.write_text(json.dumps(tree))
    word = kind.split()[-1].rstrip("s")[:6]  # node, meshe -> mesh.., primit.., access.., buffer.., channe.., ...
    for read, path in ((read_gltf_rig, glb), (read_gltf_rig, gltf), (read_glb_animation, glb)):
        t0 = time.monotonic()
        with within(10), pytest.raises(InputError) as e:
            read(path)
        took = time.monotonic() - t0
        msg = one_line(e.value, path)
        assert word.lower() in msg.lower(), msg
        assert took < 3.0, f"{read.__name__}: {took:.1f} s to refuse {MANY[kind]} {kind}"


def test_the_limits_say_why_and_a_big_character_reads(tmp_path):
    """Each limit is a module constant with its reason; a character far larger than a face rig (a MetaHuman-sized
    skeleton of 1,200 joints, 900 targets, 3,600 joint channels) still reads."""
    import inspect

    import facegeom.io.gltf as g

    source = inspect.getsource(g)
    for name in ("MAX_NODES", "MAX_MESHES", "MAX_PRIMITIVES", "MAX_ACCESSORS", "MAX_BUFFER_VIEWS",
                 "MAX_ANIMATIONS", "MAX_ANIMATION_CHANNELS", "MAX_MORPH_TARGETS", "MAX_JSON_OBJECTS"):
        value = getattr(g, name)
        assert isinstance(value, int) and value > 0
        at = source.index(f"\n{name} = ")
        assert source[:at].rstrip().splitlines()[-1].lstrip().startswith("#:"), f"{name} has no stated reason"
    assert g.MAX_NODES >= 4_000 and g.MAX_MORPH_TARGETS >= 1_000 and g.MAX_ANIMATION_CHANNELS >= 10_000

    tree, blob = _base(tmp_path)
    joints = 1_200
    tree["nodes"] += [{"name": f"joint{i}", "translation": [0.0, 0.01, 0.0], "rotation": [0, 0, 0, 1]}
                      for i in range(joints)]
    tree["nodes"][0]["children"] = list(range(1, 1 + joints))
    prim = tree["meshes"][0]["primitives"][0]
    prim["targets"] += [dict(prim["targets"][k % 2]) for k in range(898)]
    tree["meshes"][0]["extras"]["targetNames"] = [f"shape{k}" for k in range(900)]
    tree["meshes"][0]["weights"] = [0.0] * 900
    anim = tree["animations"][0]
    weights = anim["samplers"][0]
    tree["animations"].append({"samplers": [{"input": weights["input"], "output": weights["input"]}],
                               "channels": [{"sampler": 0, "target": {"node": 1 + i % joints, "path": "scale"}}
                                            for i in range(3 * joints)]})
    tree["animations"] = tree["animations"][::-1]  # the joints' clip first: the weights are found past it
    path = tmp_path / "character.glb"
    path.write_bytes(glb_bytes(tree, blob))
    with within(40):
        rig = read_gltf_rig(path)
    assert len(rig.names) == 900 and rig.deltas.shape == (900, 4, 3)


def test_a_sum_of_objects_past_the_total_is_refused(tmp_path):
    import facegeom.io.gltf as g

    tree, blob = _base(tmp_path)
    total = sum(len(tree.get(k, [])) for k in ("nodes", "meshes", "accessors", "bufferViews"))
    for kind, limit in (("nodes", g.MAX_NODES), ("accessors", g.MAX_ACCESSORS), ("bufferViews", g.MAX_BUFFER_VIEWS)):
        add = min(limit - len(tree[kind]), g.MAX_JSON_OBJECTS + 1 - total)
        if add > 0:
            _inflate(tree, kind, add)
            total += add
    assert total > g.MAX_JSON_OBJECTS, "the per-kind limits bind before the total: the total is not needed"
    path = tmp_path / "sum.glb"
    path.write_bytes(glb_bytes(tree, blob))
    with within(10), pytest.raises(InputError) as e:
        read_gltf_rig(path)
    one_line(e.value, path, "objects")


# ----------------------------------------------------------------------------- 3. memory of the morph targets

def _shared_targets(path: Path, n: int, K: int, size: int) -> Path:
    """``K`` morph targets of ``n`` vertices (``n / 3`` triangles) all naming one buffer view; the BIN chunk padded to ``size``
    bytes (the file's size is what bounds the rig's arrays)."""
    pos = np.c_[np.arange(n) % 7, np.arange(n) // 7, np.zeros(n)].astype(np.float32)
    blob = pos.tobytes()
    blob += b"\0" * max(0, size - len(blob))
    tree = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "buffers": [{"byteLength": len(blob)}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob)}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3"}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "targets": [{"POSITION": 0}] * K}]}]}
    path.write_bytes(glb_bytes(tree, blob))
    return path


READ_UNDER_LIMIT = """
    import sys, time
    from facegeom.errors import InputError
    import facegeom.io.gltf as g
    budget = {budget!r}
    if budget is not None:
        g.memory_budget = lambda: budget
    t0 = time.monotonic()
    try:
        getattr(g, {reader!r})({path!r})
        print("READ")
    except InputError as exc:
        print("ERROR", exc)
    except MemoryError:
        print("MEMORYERROR")
    print(f"{{time.monotonic() - t0:.2f}}")
"""

LIMIT = 1 << 30  # the child's address space: the interpreter, numpy and pygltflib take ~150 MB of it


@pytest.mark.parametrize("reader", ["read_gltf_rig", "read_glb_animation"])
def test_ten_thousand_targets_sharing_one_view_are_refused_before_allocating(tmp_path, reader):
    # 10,000 x 2,000 vertices x 3 x 8 bytes = 480 MB a copy; the 1 MB file lets the rig hold 68 M numbers
    path = _shared_targets(tmp_path / "shared.glb", 2_001, 10_000, 1 << 20)
    r = child(READ_UNDER_LIMIT.format(budget=None, reader=reader, path=str(path)), timeout=120, memory=LIMIT)
    out = r.stdout.strip().splitlines()
    assert r.returncode == 0 and out and out[0].startswith("ERROR"), (r.stdout, r.stderr[-2000:])
    one_line(out[0], path, "10000 morph targets")
    assert "MemoryError" not in out[0]
    assert float(out[1]) < 5.0, out


@pytest.mark.parametrize("reader", ["read_gltf_rig", "read_glb_animation"])
def test_targets_past_the_memory_budget_are_refused_before_allocating(tmp_path, reader):
    # 1,000 targets (a real rig's count) of 20,000 vertices: 480 MB of deltas, within the file-size bound
    path = _shared_targets(tmp_path / "big.glb", 20_001, 1_000, 1 << 20)
    r = child(READ_UNDER_LIMIT.format(budget=100 << 20, reader=reader, path=str(path)), timeout=120, memory=LIMIT)
    out = r.stdout.strip().splitlines()
    assert r.returncode == 0 and out and out[0].startswith("ERROR"), (r.stdout, r.stderr[-2000:])
    one_line(out[0], path, "more than this machine can spare")
    assert "MemoryError" not in out[0]


def test_targets_within_the_budget_still_read(tmp_path):
    path = _shared_targets(tmp_path / "ok.glb", 300, 500, 1 << 16)
    rig = read_gltf_rig(path)
    assert rig.deltas.shape == (500, 300, 3) and np.allclose(rig.deltas[7], rig.neutral)
    g = read_glb_animation(path)
    assert g.deltas.shape == (500, 300, 3)


# ----------------------------------------------------------------------------- 4. extensionsRequired

def _required(tmp_path, names, name="req.glb", used=None) -> Path:
    doc = simple()
    doc.json["extensionsRequired"] = list(names)
    doc.json["extensionsUsed"] = list(used if used is not None else names)
    return doc.glb(tmp_path / name)


@pytest.mark.parametrize("ext", ["EXT_mesh_gpu_instancing", "ACME_magic_geometry", "KHR_animation_pointer"])
def test_an_unknown_required_extension_is_refused_naming_it(tmp_path, ext):
    path = _required(tmp_path, ["KHR_materials_unlit", ext])
    with pytest.raises(InputError) as e:
        read_gltf_rig(path)
    msg = one_line(e.value, path, ext, "extensionsRequired")
    assert "KHR_materials_unlit" not in msg  # only what facegeom cannot honour is named
    tree, blob = _base(tmp_path)
    tree["extensionsRequired"] = tree["extensionsUsed"] = [ext]
    anim = tmp_path / "anim.glb"
    anim.write_bytes(glb_bytes(tree, blob))
    with pytest.raises(InputError) as e:
        read_glb_animation(anim)
    one_line(e.value, anim, ext)


def test_meshopt_required_is_refused_with_what_to_do(tmp_path):
    path = _required(tmp_path, ["EXT_meshopt_compression"])
    with pytest.raises(InputError) as e:
        read_gltf_rig(path)
    one_line(e.value, path, "EXT_meshopt_compression", "uncompressed")


def test_compression_and_quantization_are_refused_by_the_animation_reader(tmp_path):
    # read_glb_animation decodes neither Draco nor quantized (normalized) data: it says so instead of reading zeros
    for ext in ("KHR_draco_mesh_compression", "KHR_mesh_quantization", "EXT_meshopt_compression"):
        tree, blob = _base(tmp_path)
        tree["extensionsRequired"] = tree["extensionsUsed"] = [ext]
        path = tmp_path / f"{ext}.glb"
        path.write_bytes(glb_bytes(tree, blob))
        with pytest.raises(InputError) as e:
            read_glb_animation(path)
        one_line(e.value, path, ext)


@pytest.mark.parametrize("exts", [["KHR_mesh_quantization"], ["KHR_texture_basisu", "KHR_materials_emissive_strength"],
                                  ["KHR_texture_transform", "EXT_texture_webp", "KHR_lights_punctual"]])
def test_required_extensions_facegeom_reads_or_that_touch_no_geometry_still_read(tmp_path, exts):
    rig = read_gltf_rig(_required(tmp_path, exts))
    assert rig.names == ("a", "b")
    if "KHR_mesh_quantization" not in exts:
        tree, blob = _base(tmp_path)
        tree["extensionsRequired"] = tree["extensionsUsed"] = exts
        path = tmp_path / "anim.glb"
        path.write_bytes(glb_bytes(tree, blob))
        assert read_glb_animation(path).names == ("a", "b")


def test_a_malformed_extensions_required_is_one_line(tmp_path):
    doc = simple()
    doc.json["extensionsRequired"] = "KHR_mesh_quantization"
    path = doc.glb(tmp_path / "bad.glb")
    with pytest.raises(InputError) as e:
        read_gltf_rig(path)
    one_line(e.value, path, "extensionsRequired")


# ----------------------------------------------------------------------------- 5. photos: the header only

def _png_chunk(kind: bytes, data: bytes) -> bytes:
    import zlib

    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def _exif(orientation: int) -> bytes:
    """A little-endian TIFF block: IFD0 with the orientation tag."""
    return (b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", 1)
            + struct.pack("<HHII", 0x0112, 3, 1, orientation) + struct.pack("<I", 0))


def _bomb(path: Path, w: int, h: int, where: str | None = None, orientation: int = 6) -> Path:
    """A PNG declaring ``w x h`` RGB pixels whose image data is a few bytes (decoding it would allocate
    ``4 w h`` bytes first); an EXIF orientation before or after the image data (``where``)."""
    import zlib

    exif = _png_chunk(b"eXIf", _exif(orientation)) if where else b""
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + (exif if where == "before" else b"") + _png_chunk(b"IDAT", zlib.compress(b"\0" * 64))
                     + (exif if where == "after" else b"") + _png_chunk(b"IEND", b""))
    return path


class Decoded(BaseException):
    """A pixel decode was started (a BaseException: the readers' ``except Exception`` cannot hide it)."""


@pytest.fixture
def no_decode(monkeypatch):
    from PIL import ImageFile

    def load(self):
        raise Decoded(f"{self.format} {self.size} decoded")

    monkeypatch.setattr(ImageFile.ImageFile, "load", load)


@pytest.mark.parametrize("where", [None, "before", "after"])
def test_a_photo_is_sized_and_turned_from_its_header_alone(tmp_path, no_decode, monkeypatch, where):
    from PIL import Image

    from facegeom.io import image_size
    from facegeom.io.images import focal_35mm, read_image

    path = _bomb(tmp_path / "bomb.png", 30_000, 20_000, where)  # 600 megapixels, 2.4 GB decoded
    t0 = time.monotonic()
    w, h = image_size(path)
    assert (w, h) == ((20_000, 30_000) if where == "before" else (30_000, 20_000))  # EXIF after the pixels: unread
    assert focal_35mm(path) is None
    with pytest.raises(InputError) as e:
        read_image(path)
    one_line(e.value, path, "30000 x 20000", "refused before decoding")
    assert time.monotonic() - t0 < 1.0
    if where == "after":  # the detector works: Pillow's own PNG getexif decodes to reach the chunk after the pixels
        monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", None)
        with Image.open(path) as im, pytest.raises(Decoded):
            im.getexif()


def test_the_size_limit_comes_before_any_decode_also_when_turned(tmp_path, no_decode):
    from facegeom.io.images import read_image

    path = _bomb(tmp_path / "turned.png", 9_000, 9_000, "before", orientation=8)  # 81 megapixels, one over 2^26
    with pytest.raises(InputError) as e:
        read_image(path)
    one_line(e.value, path, "over the limit")
    with pytest.raises(InputError) as e:
        read_image(path, max_pixels=1_000)
    one_line(e.value, path, "over the limit")


@pytest.mark.parametrize("reader", ["read_gltf_rig", "read_glb_animation"])
def test_a_rig_larger_than_its_file_can_hold_is_refused_before_allocating(tmp_path, reader):
    """Under the 4,096-target cap and within the machine's memory, but 2,000 targets of 20,000 vertices (120 M
    numbers) named by a 1 MB file: more than the 4 M + 64 numbers a byte the file may ask for."""
    from facegeom.io.gltf import _BASE_VALUES, _VALUES_PER_BYTE

    path = _shared_targets(tmp_path / "wide.glb", 20_001, 2_000, 1 << 20)
    assert 3 * 20_001 * 2_001 > _BASE_VALUES + _VALUES_PER_BYTE * path.stat().st_size
    r = child(READ_UNDER_LIMIT.format(budget=None, reader=reader, path=str(path)), timeout=120, memory=LIMIT)
    out = r.stdout.strip().splitlines()
    assert r.returncode == 0 and out and out[0].startswith("ERROR"), (r.stdout, r.stderr[-2000:])
    one_line(out[0], path, "bytes of glTF data can hold")
    assert float(out[1]) < 5.0, out
