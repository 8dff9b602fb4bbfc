"""Property tests of every file reader: mutated, truncated or random bytes either read as valid
arrays or raise InputError, nothing else (no other exception, no native crash, bounded memory).

Each reader runs in-process on bytes derived from a valid seed: cut at a random
offset, bytes flipped, inserted or deleted, a number replaced by a huge or
negative count, chunks of another format spliced in. ``FACEGEOM_FUZZ_EXAMPLES``
sets the examples per reader (default 100, derandomized so CI is stable; set
it for a long, random run). Inputs found to break a reader are kept in
:data:`CORPUS` as literal bytes.

Further targets below: the ``-p KEY=VALUE`` method parameters (``parse_params`` and
``registry.create`` for every registered method, then a fit on a tiny problem); rigs as
``load_rig`` reads them (``.glb``, ``.npz`` bytes and arrays, a folder of OBJs); the
shape-mapping, key-labels, vertex, Live Link take and index-map CSVs; a photo's size; a photo's
pixels (``read_image``) and a video's frames (``open_video``, every frame decoded). What they found is
kept, once fixed, in :data:`FOUND_CORPUS`.
"""
from __future__ import annotations

import contextlib
import gzip
import io
import os
import re
import signal
import struct
import tracemalloc

import click
import numpy as np
import pytest
from hypothesis import reject, settings
from hypothesis import strategies as st

from facegeom.errors import InputError
from facegeom.io import (
    read_landmarks,
    read_marker_sequence,
    read_markers,
    read_mesh,
    read_point_cloud,
    read_polygon_mesh,
    read_pts,
)
from tests.fuzzing import EXAMPLES, FUZZ, campaign


def fuzz_file(strategy, path, check, fuzz=None, share: int = 1) -> None:
    """Write each example ``strategy`` draws to ``path`` and run ``check(path)`` on it (a campaign under ``fuzz``
    or :data:`FUZZ` settings, ``share`` as in :func:`tests.fuzzing.campaign`)."""
    def run(data):
        path.write_bytes(data)
        check(path)

    campaign(run, fuzz, share, data=strategy)


SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]])


def _ply(fmt: str) -> bytes:
    head = (f"ply\nformat {fmt} 1.0\ncomment seed\nelement vertex 5\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nelement face 3\nproperty list uchar int vertex_indices\n"
            "property list uchar float texcoord\nelement edge 1\nproperty int a\nproperty int b\nend_header\n")
    faces = [[0, 1, 2, 3], [0, 1, 4], [1, 2, 4]]
    if fmt == "ascii":
        body = "".join(f"{x} {y} {z} 255\n" for x, y, z in SQUARE)
        body += "".join(f"{len(f)} {' '.join(map(str, f))} 2 0.5 0.5\n" for f in faces) + "0 1\n"
        return (head + body).encode()
    o = "<" if fmt.endswith("little_endian") else ">"
    body = b"".join(struct.pack(o + "3fB", x, y, z, 255) for x, y, z in SQUARE)
    body += b"".join(struct.pack(o + f"B{len(f)}iB2f", len(f), *f, 2, 0.5, 0.5) for f in faces)
    return head.encode() + body + struct.pack(o + "2i", 0, 1)


SEEDS = {
    "obj": (b"# seed\nmtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0 1 0 0\nv 0 1 0\nv 0.5 0.5 1\nvt 0 0\nvn 0 0 1\n"
            b"g g\ns off\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf 1//1 2//1 -1//1\nf 2 3 \\\n 5\nl 1 2\n"),
    "ply_ascii": _ply("ascii"),
    "ply_binary": _ply("binary_little_endian"),
    "ply_big": _ply("binary_big_endian"),
    "off": b"# seed\nCOFF\n5 3 0\n0 0 0 255 0 0\n1 0 0 255 0 0\n1 1 0 0 0 255\n0 1 0 0 0 255\n0.5 0.5 1 1 1 1\n"
           b"4 0 1 2 3\n3 0 1 4 255 0 0\n3 1 2 4\n",
    "xyz": b"# x y z\n0 0 0\n1 0 0 0 0 1\n1 1 0\n\n0 1 0\n0.5 0.5 1\n",
    "landmarks": b"vertex_id,u,v\n0,10.5,20\n3,11,21.25\n7,0,0\n",
    "markers": b"vertex_id,x,y,z\n5,0.1,0.2,0.3\n0,1,2,3\n17,-1,-2,-3\n",
    "sequence": b"frame,marker,x,y,z\n0,m0,0,0,0\n0,m1,1,0,0\n1,m0,0,0.1,0\n1,m1,1,0.1,0\n",
    "pts": b"version: 1\nn_points:  3\n{\n357.417253 308.455774\n356.005 320.18\n1 1\n}\n",
}
SUFFIX = {"obj": ".obj", "ply_ascii": ".ply", "ply_binary": ".ply", "ply_big": ".ply", "off": ".off",
          "xyz": ".xyz", "landmarks": ".csv", "markers": ".csv", "sequence": ".csv", "npz": ".npz",
          "pts": ".pts"}


def _npz_seed() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, positions=np.arange(12, dtype=float).reshape(2, 2, 3), frames=np.array([0, 1]),
             names=np.array(["m0", "m1"]))
    return buf.getvalue()


SEEDS["npz"] = _npz_seed()

NUMBER = re.compile(rb"\d+")
HUGE = [b"0", b"-1", b"4294967295", b"1000000000", b"99999999999999999999", b"nan", b"1e308", b"-2147483648"]


@st.composite
def mutated(draw, kind: str, pool: dict[str, bytes] | None = None) -> bytes:
    """A seed changed by 1-4 random edits, or random bytes, or another format's seed (seeds: ``pool``, default
    :data:`SEEDS`)."""
    seeds = SEEDS if pool is None else pool
    data = seeds[kind]
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=300))
    if draw(st.integers(0, 9)) == 0:
        data = seeds[draw(st.sampled_from(sorted(seeds)))]
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["cut", "flip", "insert", "delete", "number", "splice", "repeat"]))
        at = draw(st.integers(0, len(data)))
        if op == "cut":
            data = data[:at]
        elif op == "flip" and data:
            at = min(at, len(data) - 1)
            data = data[:at] + bytes([data[at] ^ draw(st.integers(1, 255))]) + data[at + 1:]
        elif op == "insert":
            data = data[:at] + draw(st.binary(min_size=1, max_size=8)) + data[at:]
        elif op == "delete":
            data = data[:at] + data[at + draw(st.integers(1, 16)):]
        elif op == "number":
            numbers = list(NUMBER.finditer(data))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data = data[:m.start()] + draw(st.sampled_from(HUGE)) + data[m.end():]
        elif op == "splice":
            other = seeds[draw(st.sampled_from(sorted(seeds)))]
            data = data[:at] + other[:draw(st.integers(0, len(other)))]
        elif op == "repeat":
            data = data[:at] + data[at:at + draw(st.integers(1, 64))] * draw(st.integers(2, 20)) + data[at:]
    return data


def check_mesh(path):
    try:
        V, F = read_mesh(path)
    except InputError:
        return
    assert V.dtype == np.float64 and V.ndim == 2 and V.shape[1] == 3 and V.shape[0] >= 1
    assert np.isfinite(V).all()
    assert F.dtype == np.int64 and F.ndim == 2 and F.shape[1] == 3 and F.shape[0] >= 1
    assert F.min() >= 0 and F.max() < V.shape[0]
    mesh = read_polygon_mesh(path)
    assert (mesh.sizes >= 3).all() and mesh.offsets[-1] == mesh.corners.size
    assert np.array_equal(mesh.triangles(), F)


def check_cloud(path):
    try:
        P = read_point_cloud(path)
    except InputError:
        return
    assert P.dtype == np.float64 and P.ndim == 2 and P.shape[1] == 3 and P.shape[0] >= 1 and np.isfinite(P).all()


def check_landmarks(path):
    try:
        ids, uv = read_landmarks(path)
    except InputError:
        return
    assert ids.dtype == np.int64 and ids.ndim == 1 and (ids >= 0).all() and np.unique(ids).size == ids.size
    assert uv.shape == (ids.size, 2) and np.isfinite(uv).all()


def check_pts(path):
    try:
        P = read_pts(path)
    except InputError:
        return
    assert P.dtype == np.float64 and P.ndim == 2 and P.shape[1] == 2 and P.shape[0] >= 1 and np.isfinite(P).all()


def check_markers(path):
    try:
        ids, pos = read_markers(path, n_vertices=20)
    except InputError:
        return
    assert ids.ndim == 1 and (ids >= 0).all() and (ids < 20).all() and np.unique(ids).size == ids.size
    assert pos.shape == (ids.size, 3) and np.isfinite(pos).all()


def check_sequence(path):
    try:
        seq = read_marker_sequence(path)
    except InputError:
        return
    P = np.asarray(seq.positions)
    assert P.dtype == np.float64 and P.ndim == 3 and P.shape[2] == 3
    assert np.asarray(seq.frames).shape == (P.shape[0],)


CHECKS = {"obj": (check_mesh, check_cloud), "ply_ascii": (check_mesh, check_cloud),
          "ply_binary": (check_mesh, check_cloud), "ply_big": (check_mesh, check_cloud),
          "off": (check_mesh, check_cloud), "xyz": (check_cloud,), "landmarks": (check_landmarks,),
          "markers": (check_markers,), "sequence": (check_sequence,), "npz": (check_sequence,),
          "pts": (check_pts,)}
BOUNDED = {"obj", "ply_ascii", "ply_binary", "ply_big", "off", "xyz"}  # our readers: memory O(file size)


def run_readers(kind: str, data: bytes, path) -> None:
    path.write_bytes(data)
    measure = kind in BOUNDED
    if measure:
        tracemalloc.start()
    try:
        for check in CHECKS[kind]:
            check(path)
        if measure:
            peak = tracemalloc.get_traced_memory()[1]
            assert peak < 100 * len(data) + (1 << 20), f"{peak} bytes for a {len(data)}-byte file"
    finally:
        if measure:
            tracemalloc.stop()


@pytest.mark.parametrize("kind", sorted(SEEDS))
def test_seeds_are_valid(tmp_path, kind):
    path = tmp_path / f"seed{SUFFIX[kind]}"
    path.write_bytes(SEEDS[kind])
    for check in CHECKS[kind]:
        check(path)
    if kind in BOUNDED:
        assert read_point_cloud(path).shape[0] == 5
    if kind in BOUNDED - {"xyz"}:
        assert read_polygon_mesh(path).n_faces == 3


@pytest.mark.parametrize("kind", sorted(SEEDS))
def test_mutated_files_read_or_raise_input_error(tmp_path, kind):
    def run(data):
        run_readers(kind, data, tmp_path / f"f{SUFFIX[kind]}")

    campaign(run, share=3 if kind.startswith("ply") else 1, data=mutated(kind))


# Inputs that crashed, hung or misread (issue 16 and what the fuzzing found), as literal bytes.
CORPUS = [
    ("obj", b"v 0 0 0\nf 1\n"),
    ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n"),
    ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3\nf 3"),
    ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -9 1 2\n"),
    ("obj", b"v \\\n\\\n\\"),
    ("ply_ascii", b"ply\n"),
    ("ply_ascii", b"ply\nformat ascii 1.0\nelement x -1\nend_header\n"),
    ("ply_ascii", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  b"element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 nan 0\n"
                  b"3 0 1 2\n"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nend_header\n"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nelement vertex 4294967295\nproperty double x\n"
                   b"property double y\nproperty double z\nend_header\n"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                   b"property float z\nelement face 99999999\nproperty list uint uint vertex_indices\nend_header\n"
                   b"\xff\xff\xff\xff"),
    ("ply_binary", b"ply\nformat binary_little_endian 1.0\nelement e 99999999999999999999\nend_header\n"),
    ("off", b"OFF"),
    ("off", b"OFF\n1000000000 8 0"),
    ("off", b"  # c\n  OFF # c\n 3 1 0\n0 0 0\n1 0 0\n0 1 0\n 3 0 1 2\n"),
    ("off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n9223372036854775807 0 1 2\n"),
    ("xyz", b"1 2 3\n\xff\xfe\n"),
    ("landmarks", b"vertex_id,u,v\n99999999999999999999,10.5,20\n3,11,21.25\n7,0,0\n"),  # OverflowError
    ("markers", b"vertex_id,x,y,z\n99999999999999999999,0.1,0.2,0.3\n"),  # OverflowError
    ("sequence", b"frame,marker,x,y,z\n99999999999999999999,m0,0,0,0\n"),
]


@pytest.mark.parametrize("kind,data", CORPUS)
def test_regression_corpus(tmp_path, kind, data):
    run_readers(kind, data, tmp_path / f"c{SUFFIX[kind]}")


# ----------------------------------------------------------------------------- C3D
# ezc3d (C++) crashes, loops or allocates without bound on some malformed files; read_c3d parses in a
# child process, so a crash there is an InputError here and cannot take pytest down with it. Each
# example starts one process (~0.3 s), hence fewer examples than the text readers.
C3D_EXAMPLES = max(10, EXAMPLES // 4)
C3D_HEADER_COUNTS = (0, 2, 4, 6, 8, 16, 18)  # byte offsets of the header's u16 counts and block numbers


def _c3d_seed() -> bytes:
    pytest.importorskip("ezc3d")
    import tempfile

    from facegeom.io.c3d import write_c3d

    P = np.arange(120, dtype=float).reshape(10, 4, 3) + 1.0
    P[2, 1] = np.nan  # one gap
    with tempfile.TemporaryDirectory() as d:
        return write_c3d(os.path.join(d, "seed.c3d"), P, list("abcd"), 90.0, "cm").read_bytes()


@st.composite
def mutated_c3d(draw, seed: bytes) -> bytes:
    """A valid C3D cut short, with bytes flipped, a header count made huge, or a parameter byte replaced."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "flip", "count", "param"]))
        if op == "cut":
            data = data[:draw(st.integers(0, len(data)))]
        elif op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
        elif op == "count" and len(data) >= 20:
            at = draw(st.sampled_from(C3D_HEADER_COUNTS))
            data[at:at + 2] = struct.pack("<H", draw(st.sampled_from([0, 1, 255, 32767, 65535])))
        elif op == "param" and len(data) > 600:
            at = draw(st.integers(512, min(len(data), 1024) - 1))
            data[at] = draw(st.sampled_from([0, 1, 0x7F, 0x80, 0xFF]))
    return bytes(data)


def _check_c3d(path) -> None:
    from facegeom.io.c3d import read_c3d

    try:
        seq = read_c3d(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    P = seq.positions
    assert P.dtype == np.float64 and P.ndim == 3 and P.shape[2] == 3 and P.shape[0] >= 1 and P.shape[1] >= 1
    assert not np.isinf(P).any() and len(seq.names) == P.shape[1] and len(set(seq.names)) == P.shape[1]
    assert np.array_equal(seq.frames, np.arange(P.shape[0])) and seq.fps > 0
    assert seq.unit in (None, "mm", "cm", "m")


@pytest.fixture
def quick_c3d_timeout(monkeypatch):
    from facegeom.io import c3d

    monkeypatch.setattr(c3d, "_TIMEOUT_S", 3.0)  # the seed reads in ~0.3 s; a hang ends in 3 s, not 10


def test_c3d_seed_is_valid(tmp_path):
    path = tmp_path / "seed.c3d"
    path.write_bytes(_c3d_seed())
    from facegeom.io.c3d import read_c3d

    seq = read_c3d(path)
    assert seq.names == tuple("abcd") and seq.unit == "cm" and seq.missing().sum() == 1


def test_mutated_c3d_reads_or_raises_input_error(tmp_path, quick_c3d_timeout):
    fuzz_file(mutated_c3d(_c3d_seed()), tmp_path / "f.c3d", _check_c3d, settings(FUZZ, max_examples=C3D_EXAMPLES))


def test_c3d_regression_corpus(tmp_path, quick_c3d_timeout):
    """Files that crashed or hung ezc3d in earlier fuzzing, rebuilt from the seed by the edits found."""
    seed = _c3d_seed()
    hang = bytearray(seed)
    hang[670] = 0x7A  # a parameter's next-entry offset: ezc3d loops for about a minute
    huge = bytearray(seed)
    huge[2:4] = b"\xff\x7f"  # 32767 points in the header
    for k, data in enumerate([bytes(hang), bytes(huge), seed[:512], seed[:600]]):
        path = tmp_path / f"c{k}.c3d"
        path.write_bytes(data)
        _check_c3d(path)


# ----------------------------------------------------------------------------- glTF binary (.glb)


def _glb_seed() -> bytes:
    pytest.importorskip("pygltflib")
    import tempfile

    from facegeom.io.gltf import write_rig_glb

    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    D = np.stack([np.full((4, 3), 0.1), np.eye(4, 3)])
    W = np.array([[0.0, 1.0], [0.5, 0.5], [1.0, 0.0]])
    with tempfile.TemporaryDirectory() as d:
        return write_rig_glb(os.path.join(d, "seed.glb"), V, F, D, ["a", "b"], W, 30.0).read_bytes()


@st.composite
def mutated_glb(draw, seed: bytes) -> bytes:
    """A valid .glb cut short, with bytes flipped, a JSON number made huge, or a chunk length changed."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["cut", "flip", "number", "length"]))
        if op == "cut":
            data = data[:draw(st.integers(0, len(data)))]
        elif op == "flip" and data:
            at = draw(st.integers(0, len(data) - 1))
            data[at] ^= draw(st.integers(1, 255))
        elif op == "number":
            numbers = list(NUMBER.finditer(bytes(data[:200 + len(data) // 2])))
            if numbers:
                m = numbers[draw(st.integers(0, len(numbers) - 1))]
                data[m.start():m.end()] = draw(st.sampled_from(HUGE))
        elif op == "length" and len(data) >= 16:
            at = draw(st.sampled_from([8, 12]))
            data[at:at + 4] = struct.pack("<I", draw(st.sampled_from([0, 1, 7, 2 ** 31, 2 ** 32 - 1])))
    return bytes(data)


def _check_glb(path) -> None:
    from facegeom.io.gltf import read_glb_animation

    try:
        g = read_glb_animation(path)
    except InputError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    n, K = g.neutral.shape[0], g.deltas.shape[0]
    assert g.neutral.shape == (n, 3) and g.deltas.shape == (K, n, 3) and len(g.names) == K
    assert g.faces.ndim == 2 and g.faces.shape[1] == 3 and (g.faces.size == 0 or g.faces.max() < n)
    assert g.weights.shape == (g.times.size, K) and np.isfinite(g.weights).all()


def test_glb_seed_is_valid(tmp_path):
    from facegeom.io.gltf import read_glb_animation

    path = tmp_path / "seed.glb"
    path.write_bytes(_glb_seed())
    g = read_glb_animation(path)
    assert g.names == ("a", "b") and g.weights.shape == (3, 2)


def test_mutated_glb_reads_or_raises_input_error(tmp_path):
    fuzz_file(mutated_glb(_glb_seed()), tmp_path / "f.glb", _check_glb)


# ----------------------------------------------------------------------------- shared by the targets below


class Hang(BaseException):
    """A reader or method ran past its time limit (a BaseException, so no ``except Exception`` can swallow it)."""


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raise :class:`Hang` in the body after ``seconds`` (Python code only: a loop in native code ends first)."""
    def on_alarm(signum, frame):
        raise Hang(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextlib.contextmanager
def memory_cap(extra: int = 2 << 30):
    """Cap this process's address space at its size now plus ``extra`` bytes in the body (Linux), so a reader that
    allocates what a forged count declares fails with MemoryError (a test failure) instead of filling the machine."""
    try:
        import resource

        with open("/proc/self/statm") as fh:
            size = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (ImportError, OSError):
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = size + extra if hard == resource.RLIM_INFINITY else min(size + extra, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


# Bugs these targets found, reported and not fixed yet: (exception type, "module.function" on its traceback, text
# in its message). An example ending in one is set aside (hypothesis.reject), so that a campaign goes on past it to
# other bugs; once it is fixed, its input goes to FOUND_CORPUS and its entry here is deleted.
KNOWN_BUGS: list[tuple[type, str, str]] = []  # none open


def _facegeom_functions(exc: BaseException) -> set[str]:
    """``module.function`` of each facegeom frame on ``exc``'s traceback."""
    import traceback

    return {f"{os.path.basename(f.filename)[:-3]}.{f.name}" for f in traceback.extract_tb(exc.__traceback__)
            if f"{os.sep}facegeom{os.sep}" in f.filename}


def known_bug(exc: BaseException) -> bool:
    """Whether ``exc`` is one of :data:`KNOWN_BUGS`."""
    functions = _facegeom_functions(exc)
    return any(isinstance(exc, t) and (t is InputError or not isinstance(exc, InputError)) and f in functions
               and text in str(exc) for t, f, text in KNOWN_BUGS)


def read_or_input_error(read, path, seconds: float = 20.0, set_aside: bool = True):
    """``read(path)`` under a time limit and a memory cap; None when it raised an InputError of one line naming
    ``path``. Any other exception fails the test; with ``set_aside``, one of :data:`KNOWN_BUGS` rejects the
    example instead."""
    try:
        with memory_cap(), time_limit(seconds):
            return read(path)
    except InputError as exc:
        if len(str(exc).splitlines()) == 1 and str(path) in str(exc):
            return None
        if set_aside and known_bug(exc):
            reject()
        raise AssertionError(f"not one line naming the file: {str(exc)!r}") from exc
    except (Exception, Hang) as exc:  # re-raised unless a known bug
        if set_aside and known_bug(exc):
            reject()
        raise


def check_rig(rig) -> None:
    """A loaded :class:`~facegeom.model.rig.BlendshapeRig` is consistent: finite arrays of matching shapes."""
    n, K = rig.n_vertices, rig.n_shapes
    assert n >= 1 and K >= 1
    assert rig.neutral.dtype == np.float64 and rig.neutral.shape == (n, 3) and np.isfinite(rig.neutral).all()
    assert rig.deltas.dtype == np.float64 and rig.deltas.shape == (K, n, 3) and np.isfinite(rig.deltas).all()
    assert len(rig.names) == K == len(set(rig.names)) and all(isinstance(s, str) and s.strip() for s in rig.names)
    T = rig.triangles
    assert T.dtype == np.int64 and T.ndim == 2 and T.shape[1] == 3 and (T.size == 0 or 0 <= T.min() <= T.max() < n)
    assert rig.frame is not None
    for p in rig.parts or ():
        assert 0 <= p.vertex_start <= p.vertex_stop <= n and 0 <= p.face_start <= p.face_stop <= T.shape[0]


def load_rig_file(path, set_aside: bool = True):
    """``facegeom.model.load_rig(path)`` (what ``--rig`` reads), the rig checked; None on an InputError."""
    from facegeom.model.inputs import load_rig

    rig = read_or_input_error(load_rig, path, set_aside=set_aside)
    if rig is not None:
        check_rig(rig)
    return rig


# ----------------------------------------------------------------------------- method parameters (-p KEY=VALUE)
# ``facegeom fit -p KEY=VALUE`` and the like: parse_params, then registry.create(kind, name, **params). Any key
# (the method's own parameter names mixed with junk) and any value either builds the method or is refused with
# one line (InputError, or click's BadParameter / UsageError for an item without '='); a method that was built
# fits a tiny problem in well under the time limit, or refuses it with an InputError.

PARAM_JUNK_KEYS = ["", " ", "x", "D", "k ", " d", "__class__", "self", "kwargs", "params", "param_names", "fit",
                   "clone", "é", "a b", "1", "=", "None"]
PARAM_VALUES = ["0", "1", "-1", "2", "3", "7", "0.5", "-0.0", "1e-300", "5e-324", "1e308", "-1e308", "1e309", "1e9",
                "1000000000", "-1000000000", "99999999999999999999", "4294967295", "-2147483648", "nan", "NaN", "inf",
                "-inf", "", " ", "true", "false", "True", "None", "null", "none", "abc", "=", "a=b", "==", "ß", "日本",
                "\u200b", "1_000", "0x10", "1e", "  7  ", "[1, 2]", "l", "r", "\t"]


def _methods() -> list[tuple[str, str]]:
    """Every ``(kind, name)`` the registry lists (presets included)."""
    from facegeom import registry

    return [(k, n) for k in registry.KINDS for n in registry.available(k)]


def _param_names(kind: str, name: str) -> list[str]:
    """The method's parameter names (a preset's: its method's)."""
    from facegeom import registry

    cls = registry.get(kind, name)
    return list(cls.param_names()) if hasattr(cls, "param_names") else []


@st.composite
def param_items(draw, kind: str, name: str) -> list[str]:
    """``-p`` items for one method: ``key=value`` with real and junk keys and values, now and then no ``=``."""
    keys = _param_names(kind, name) + PARAM_JUNK_KEYS
    items = []
    for _ in range(draw(st.integers(0, 4))):
        if draw(st.integers(0, 14)) == 0:
            items.append(draw(st.text(max_size=6)))
            continue
        key = draw(st.sampled_from(keys))
        value = draw(st.one_of(st.sampled_from(PARAM_VALUES), st.text(max_size=6),
                               st.floats().map(repr), st.integers(-(2 ** 70), 2 ** 70).map(str)))
        items.append(f"{key}={value}")
    return items


def _grid() -> tuple[np.ndarray, np.ndarray]:
    """A 4 x 4 vertex grid with a bump (markers not coplanar) and its 18 triangles."""
    g = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0)), -1).reshape(-1, 2)
    V = np.c_[g, np.exp(-((g - 1.5) ** 2).sum(1))]
    F = np.array([[4 * i + j, 4 * i + j + 1, 4 * i + j + 5] for i in range(3) for j in range(3)]
                 + [[4 * i + j, 4 * i + j + 5, 4 * i + j + 4] for i in range(3) for j in range(3)])
    return V, F


def use_method(kind: str, method) -> None:
    """Run a built method on a tiny problem: its output has the right shape and is finite (InputError accepted)."""
    V, F = _grid()
    handles = np.array([0, 3, 12, 15, 5])
    try:
        if kind == "deformers":
            X = method.fit(V, F, handles).deform(V[handles] + [0.0, 0.0, 0.3])
            assert X.shape == V.shape and np.isfinite(X).all()
        elif kind == "fitters":
            from facegeom.model.rig import BlendshapeRig
            from facegeom.model.targets import MeshTarget

            D = np.stack([np.outer(np.linspace(0, 0.1, 16), [0, 0, 1]), np.outer(np.linspace(0.1, 0, 16), [1, 0, 0])])
            rig = BlendshapeRig(V, D, ["a", "b"], F)
            w = method.fit(rig, MeshTarget(rig.evaluate(np.array([0.5, 0.2])))).weights
            assert np.shape(w) == (2,) and np.isfinite(w).all()
        elif kind == "retargeters":
            src = V[handles][None] + np.linspace(0, 0.2, 8)[:, None, None] * [0.0, 1.0, 0.5]
            labelled = np.array([0, 3, 7])
            out = method.fit(src, labelled, src[labelled] * 1.3).transform()
            assert out.shape == src.shape and np.isfinite(out).all()
    except InputError as exc:
        assert len(str(exc).splitlines()) == 1, repr(str(exc))


def check_params(kind: str, name: str, items: list[str]) -> None:
    """``-p`` items parsed and given to ``registry.create``: a method, or one line of InputError / click error."""
    from facegeom import registry
    from facegeom.cli.context import parse_params

    try:
        with time_limit(10.0):
            method = registry.create(kind, name, **parse_params(items))
    except (InputError, click.UsageError) as exc:  # click.BadParameter is a UsageError
        message = exc.format_message() if isinstance(exc, click.ClickException) else str(exc)
        assert len(message.splitlines()) == 1 and message.strip(), repr(message)
        return
    if hasattr(method, "get_params"):
        assert set(method.get_params()) == set(_param_names(kind, name))
    with memory_cap(), time_limit(10.0):
        use_method(kind, method)


@pytest.mark.parametrize("kind,name", [("retargeters", "tangent"), ("deformers", "tangent")])
@pytest.mark.parametrize("value", ["1e-300", "1e-7", "1e-6"])
def test_found_tiny_beta(kind, name, value):
    """``-p beta=1e-300`` (found by the campaign): a singular system and a SolveError blaming the labels before;
    now refused in one line below 1e-6, and 1e-6 itself solves the tiny problem."""
    check_params(kind, name, [f"beta={value}"])


@pytest.mark.parametrize("kind,name", _methods())
def test_params_seed_is_valid(kind, name):
    """Every method builds without parameters and with its defaults written back as ``-p`` text."""
    from facegeom import registry

    method = registry.create(kind, name)
    with time_limit(10.0):
        use_method(kind, method)
    if hasattr(method, "get_params"):
        items = [f"{k}={v}" for k, v in method.get_params().items()
                 if v is None or isinstance(v, (bool, int, float, str))]
        check_params(kind, name, items)


def test_fuzzed_params_build_or_raise_input_error():
    methods = _methods()

    def run(data):
        kind, name = data.draw(st.sampled_from(methods))
        check_params(kind, name, data.draw(param_items(kind, name)))

    campaign(run, data=st.data())


# ----------------------------------------------------------------------------- rigs (--rig FILE or FOLDER)
# The rig loader facegeom.model.load_rig on a .glb (read_gltf_rig, then BlendshapeRig and the units / up-axis
# guess; tests/test_fuzz_gltf_rig.py fuzzes read_gltf_rig alone), an .npz written by BlendshapeRig.save_npz
# (its bytes, one member's .npy bytes re-zipped with a right CRC, or its arrays changed in type, shape and
# value) and a folder of OBJs with one shape's bytes mutated.


def test_glb_rig_seed_is_valid(tmp_path):
    path = tmp_path / "seed.glb"
    path.write_bytes(_glb_seed())
    rig = load_rig_file(path)
    assert rig is not None and rig.names == ("a", "b") and rig.n_vertices == 4


def test_mutated_glb_rig_loads_or_raises_input_error(tmp_path):
    fuzz_file(mutated_glb(_glb_seed()), tmp_path / "f.glb", load_rig_file, share=4)  # + 3 in test_fuzz_gltf_rig


def _tiny_rig():
    """A 4 x 4 grid rig of three shapes with two parts and a name mapping (every optional npz key)."""
    from facegeom.io.gltf import RigPart
    from facegeom.io.shape_names import MappingRow, NameMapping
    from facegeom.model.rig import BlendshapeRig

    V, F = _grid()
    D = np.stack([np.outer(np.linspace(0, 0.1, 16), [0, 0, 1]), np.outer(np.linspace(0.1, 0, 16), [1, 0, 0]),
                  np.full((16, 3), 0.01)])
    parts = [RigPart("face", 0, 12, 0, 12, True), RigPart("teeth", 12, 16, 12, 18, False)]
    mapping = NameMapping((MappingRow("a", "jawOpen", 1.0, 2), MappingRow("b", "mouthSmile_L", 0.5, 3)), "m.csv")
    return BlendshapeRig(V * 10, D * 10, ["a", "b", "c"], F, landmark_ids=[0, 5, 10], parts=parts, name_map=mapping)


def _rig_npz_seed() -> bytes:
    """The tiny rig as ``BlendshapeRig.save_npz`` writes it."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return _tiny_rig().save_npz(os.path.join(d, "seed.npz")).read_bytes()


def _npz_members(data: bytes) -> dict[str, bytes]:
    """The members of a zip (an npz) by name."""
    import zipfile

    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def _zip(members: dict[str, bytes], compressed: bool = False) -> bytes:
    """A zip of ``members`` (right CRCs), as np.savez writes one."""
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED if compressed else zipfile.ZIP_STORED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


@st.composite
def mutated_npz(draw, seed: bytes) -> bytes:
    """The npz's bytes mutated, or one member's ``.npy`` bytes mutated and zipped again (a valid zip)."""
    if draw(st.booleans()):
        return draw(mutated("npz", {"npz": seed, **SEEDS}))
    members = _npz_members(seed)
    name = draw(st.sampled_from(sorted(members)))
    members[name] = draw(mutated(name, members))
    return _zip(members, draw(st.booleans()))


def test_rig_npz_seed_is_valid(tmp_path):
    path = tmp_path / "seed.npz"
    path.write_bytes(_rig_npz_seed())
    rig = load_rig_file(path)
    assert rig.names == ("a", "b", "c") and len(rig.parts) == 2 and len(rig.name_map.rows) == 2
    assert np.allclose(rig.neutral, _tiny_rig().neutral)


def test_mutated_rig_npz_loads_or_raises_input_error(tmp_path):
    fuzz_file(mutated_npz(_rig_npz_seed()), tmp_path / "f.npz", load_rig_file, share=2)  # + its arrays, below


NPZ_DTYPES = [np.float32, np.float16, np.int8, np.uint8, np.int32, np.uint64, np.int64, np.bool_, np.complex128,
              "U3", "S2", "M8[s]", "V4", object]
NPZ_POISON = [np.nan, np.inf, -np.inf, -1, 0, 1e308, 2 ** 31, 2 ** 63 - 1, -(2 ** 63), "", "x", "\x00", " "]


def _cast(a: np.ndarray, dtype) -> np.ndarray:
    """``a`` as ``dtype`` (through text or zeros where numpy cannot cast)."""
    try:
        return a.astype(dtype)
    except (TypeError, ValueError, OverflowError, RuntimeError):  # RuntimeError: a date as 'U3'
        return np.zeros(a.shape, dtype)


@st.composite
def npz_arrays(draw, seed: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, tuple]]:
    """The seed rig's arrays with 1-3 changes -> ``(arrays, forged)``: a key dropped or added, an array of another
    dtype or shape, a value poisoned; ``forged`` maps a key to the shape its header will declare instead."""
    arrays, forged = dict(seed), {}
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["drop", "add", "dtype", "shape", "poison", "forge", "scalar", "empty"]))
        key = draw(st.sampled_from(sorted(arrays))) if arrays else None
        if op == "add" or key is None:
            arrays[draw(st.sampled_from(["junk", "units", "up", "parts", "map_path", "part_names"]))] = \
                np.array(draw(st.sampled_from(["mm", "z", "", "x", "furlong", "Y", "M"])))
        elif op == "drop":
            del arrays[key]
        elif op == "dtype":
            arrays[key] = _cast(arrays[key], draw(st.sampled_from(NPZ_DTYPES)))
        elif op == "shape":
            a = arrays[key].reshape(-1)
            shape = draw(st.sampled_from([(a.size,), (1, a.size), (a.size, 1), (a.size // 3, 3) if a.size % 3 == 0
                                          else (a.size,), (1, 1, a.size), (1,) * 5 + (a.size,)]))
            arrays[key] = a.reshape(shape) if draw(st.booleans()) else np.resize(a, draw(st.integers(0, 80)))
        elif op == "poison" and arrays[key].size:
            a = arrays[key].copy()
            value = draw(st.sampled_from(NPZ_POISON))
            try:
                a.flat[draw(st.integers(0, a.size - 1))] = value
            except (TypeError, ValueError, OverflowError):
                continue
            arrays[key] = a
        elif op == "forge":
            forged[key] = draw(st.sampled_from([(0,), (10 ** 9, 3), (2 ** 40,), (4, 4), (1, 2, 3, 4), ()]))
        elif op == "scalar":
            arrays[key] = np.array(draw(st.sampled_from([0, 1.5, "a", True])))
        elif op == "empty":
            arrays[key] = arrays[key].reshape(-1)[:0]
    return arrays, forged


def _npy(a: np.ndarray, shape=None) -> bytes:
    """One ``.npy`` member: ``a`` as numpy writes it, or its data under a header declaring ``shape``."""
    buf = io.BytesIO()
    if shape is None or a.dtype.hasobject:
        np.lib.format.write_array(buf, a, allow_pickle=True)
    else:
        header = np.lib.format.header_data_from_array_1_0(a)
        header["shape"] = shape
        np.lib.format.write_array_header_1_0(buf, header)
        buf.write(np.ascontiguousarray(a).tobytes())
    return buf.getvalue()


def test_rig_npz_members_seed_is_valid(tmp_path):
    seed = dict(np.load(io.BytesIO(_rig_npz_seed())))
    path = tmp_path / "seed.npz"
    path.write_bytes(_zip({f"{k}.npy": _npy(a) for k, a in seed.items()}))
    from facegeom.io.npzcheck import check_npz

    assert check_npz(path) > 0
    assert load_rig_file(path).names == ("a", "b", "c")


def test_changed_rig_npz_members_load_or_raise_input_error(tmp_path):
    seed = dict(np.load(io.BytesIO(_rig_npz_seed())))

    def run(change, compressed):
        arrays, forged = change
        path = tmp_path / "f.npz"
        path.write_bytes(_zip({f"{k}.npy": _npy(a, forged.get(k)) for k, a in arrays.items()}, compressed))
        from facegeom.io.npzcheck import check_npz

        total = read_or_input_error(check_npz, path)
        assert total is None or total >= 0
        load_rig_file(path)

    campaign(run, share=2, change=npz_arrays(seed), compressed=st.booleans())


def _track_npz_seed() -> dict[str, np.ndarray]:
    """A small track as ``facegeom track -o OUT.npz`` lays it out: 4 frames, 3 shapes, 2 identity modes."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    T = 4
    arrays = {"weights": rng.uniform(0, 1, (T, 3)), "raw_weights": rng.uniform(0, 1, (T, 3)),
            "names": np.array(["a", "b", "c"]), "fps": np.float64(30.0), "times": np.arange(T) / 30.0,
            "rotations": Rotation.from_rotvec(rng.normal(0, 0.1, (T, 3))).as_matrix(),
            "camera_translations": np.c_[np.zeros((T, 2)), -np.full(T, 50.0)], "gaze": np.zeros((T, 2, 2)),
            "points": rng.uniform(0, 300, (T, 468, 2)).astype(np.float32),
            "landmarks": rng.uniform(0, 300, (T, 68, 2)).astype(np.float32), "found": np.array([1, 1, 0, 1], bool),
            "residual": np.array([1.0, 1.2, np.nan, 0.9]), "identity": rng.normal(0, 1, 2), "focal": np.float64(400.0),
            "width": np.int64(320), "height": np.int64(240), "source": np.array("clip.mp4")}
    return {k: np.asarray(a) for k, a in arrays.items()}


def test_track_npz_seed_is_valid(tmp_path):
    from facegeom.pipelines.track import read_track_npz

    path = tmp_path / "seed.npz"
    path.write_bytes(_zip({f"{k}.npy": _npy(a) for k, a in _track_npz_seed().items()}))
    tr = read_track_npz(path)
    assert tr.n_frames == 4 and tr.names == ("a", "b", "c") and tr.source == "clip.mp4"


def test_changed_track_npz_members_read_or_raise_input_error(tmp_path):
    from facegeom.pipelines.track import read_track_npz

    seed = _track_npz_seed()

    def run(change, compressed):
        arrays, forged = change
        path = tmp_path / "f.npz"
        path.write_bytes(_zip({f"{k}.npy": _npy(a, forged.get(k)) for k, a in arrays.items()}, compressed))
        tr = read_or_input_error(read_track_npz, path)
        if tr is not None:
            assert np.isfinite(tr.weights).all() and np.isfinite(tr.rotations).all()
            assert tr.weights.shape == (tr.n_frames, len(tr.names)) and tr.points.shape == (tr.n_frames, 468, 2)

    campaign(run, change=npz_arrays(seed), compressed=st.booleans())


def _obj_folder_seed() -> dict[str, bytes]:
    """The tiny rig as facegeom writes an OBJ folder: ``neutral.obj`` and one OBJ per shape, by file name."""
    import tempfile
    from pathlib import Path

    rig = _tiny_rig()
    with tempfile.TemporaryDirectory() as d:
        from facegeom.model.rig import BlendshapeRig

        plain = BlendshapeRig(rig.neutral, rig.deltas, rig.names, rig.triangles)
        (Path(d) / "rig").mkdir()
        folder = plain.write_obj_folder(Path(d) / "rig")
        return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_obj_folder_rig_seed_is_valid(tmp_path):
    for name, data in _obj_folder_seed().items():
        (tmp_path / name).write_bytes(data)
    rig = load_rig_file(tmp_path)
    assert rig.names == ("a", "b", "c") and rig.n_vertices == 16


def test_mutated_obj_folder_rig_loads_or_raises_input_error(tmp_path):
    seed = _obj_folder_seed()
    shapes = sorted(n for n in seed if n != "neutral.obj")
    pool = {**seed, "obj": SEEDS["obj"]}

    def run(data):
        name = data.draw(st.sampled_from(shapes))
        folder = tmp_path / "rig"
        folder.mkdir(exist_ok=True)
        for n, b in seed.items():
            (folder / n).write_bytes(b)
        (folder / name).write_bytes(data.draw(mutated(name, pool)))
        load_rig_file(folder)

    campaign(run, data=st.data())


#: What an entry of a fuzzed rig folder is (:func:`test_fuzzed_obj_folder_structure_loads_or_raises_input_error`).
FOLDER_ENTRIES = ("shape", "neutral copy", "link inside", "link outside", "link to a system file", "dangling link",
                  "link loop", "fifo", "folder", "empty", "hard link outside")


def test_fuzzed_obj_folder_structure_loads_or_raises_input_error(tmp_path):
    """A rig folder of drawn entries: shapes, copies of the neutral, links inside and out of the folder, dangling and
    looping links, FIFOs, folders and empty files named ``*.obj`` in any case. The load gives a consistent rig or
    one line naming a file, never hangs (a FIFO is not opened), and never uses a file outside the folder."""
    seed = _obj_folder_seed()
    shapes = sorted(n for n in seed if n != "neutral.obj")
    outside = tmp_path / "elsewhere.obj"
    outside.write_bytes(seed[shapes[0]])
    names = st.sampled_from(["a", "b", "c", "Jaw Open", "m\u00fcnd", "x.y", "neutral_2", "-", "NEUTRAL", "z" * 60])
    suffix = st.sampled_from([".obj", ".OBJ", ".Obj", ".obj.bak", ""])
    count = [0]

    def run(data):
        count[0] += 1
        folder = tmp_path / f"rig{count[0]}"
        folder.mkdir()
        (folder / "neutral.obj").write_bytes(seed["neutral.obj"])
        made = {}
        for _ in range(data.draw(st.integers(0, 6))):
            kind = data.draw(st.sampled_from(FOLDER_ENTRIES))
            p = folder / (data.draw(names) + data.draw(suffix))
            if p.name in ("neutral.obj",) or os.path.lexists(p):
                continue
            if kind == "shape":
                p.write_bytes(seed[data.draw(st.sampled_from(shapes))])
            elif kind == "neutral copy":
                p.write_bytes(seed["neutral.obj"])
            elif kind == "link inside":
                p.symlink_to(data.draw(st.sampled_from(["neutral.obj", *sorted(q.name for q in made)] or ["x"])))
            elif kind == "link outside":
                p.symlink_to(outside)
            elif kind == "link to a system file":
                p.symlink_to("/etc/hostname" if os.path.exists("/etc/hostname") else "/etc/passwd")
            elif kind == "dangling link":
                p.symlink_to(folder / "missing.obj")
            elif kind == "link loop":
                p.symlink_to(p.name)
            elif kind == "fifo":
                if not hasattr(os, "mkfifo"):
                    continue
                os.mkfifo(p)
            elif kind == "folder":
                p.mkdir()
            elif kind == "empty":
                p.write_bytes(b"")
            else:  # a hard link is the file itself: it cannot be told from one copied in
                try:
                    os.link(outside, p)
                except OSError:
                    continue
            made[p] = kind
        rig = load_rig_file(folder)
        if rig is not None:
            out = {p for p, k in made.items() if k in ("link outside", "link to a system file")
                   and p.suffix.lower() == ".obj"}
            assert not out, f"a link out of the rig folder was used: {sorted(q.name for q in out)}"

    campaign(run, data=st.data())


# ----------------------------------------------------------------------------- CSV files and photos
# Each seed is written by facegeom's own writer where it has one; the check says what a read file holds.


def _written(write, name: str) -> bytes:
    """The bytes ``write(path)`` puts in a file called ``name``."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / name
        write(path)
        return path.read_bytes()


def _mapping_seed() -> bytes:
    """A shape-mapping CSV: a comment, the header, rows with and without a gain, a blank line."""
    return (b"# how ARKit weights drive the rig\nrig_shape,source_shape,gain\njawOpen,jawOpen,1\n"
            b"smile,mouthSmileLeft,0.5\nsmile,mouthSmileRight,0.5\n\nblink,eyeBlinkLeft\nbrow,browInnerUp,-1e-3,\n")


def check_mapping(path, set_aside: bool = True) -> None:
    """A mapping read: rows of non-empty stripped names, finite gains, each pair once."""
    from facegeom.io.shape_names import read_name_mapping

    m = read_or_input_error(read_name_mapping, path, set_aside=set_aside)
    if m is None:
        return
    assert m.rows and m.path == str(path)
    assert len({(r.rig, r.source) for r in m.rows}) == len(m.rows)
    for r in m.rows:
        assert r.rig and r.source and r.rig == r.rig.strip() and r.source == r.source.strip()
        assert np.isfinite(r.gain) and r.line >= 2


def _key_labels_seed() -> bytes:
    """Key labels of 4 markers at 2 frames, one marker not given, as ``write_key_labels`` writes them."""
    from facegeom.io.key_labels import write_key_labels

    labels = np.arange(24, dtype=float).reshape(2, 4, 3) / 7
    labels[1, 2] = np.nan  # a marker not given at frame 10
    return _written(lambda p: write_key_labels(p, [3, 10], labels, [5, 6, 7, 8], comment="seed"), "k.csv")


def check_key_labels(path, set_aside: bool = True) -> None:
    """Key labels read: sorted distinct frames in the take, (L, 4, 3) labels, a whole marker given or not."""
    from facegeom.io.key_labels import read_key_labels

    k = read_or_input_error(lambda p: read_key_labels(p, n_markers=4, n_frames=100), path, set_aside=set_aside)
    if k is None:
        return
    L = k.frames.size
    assert k.frames.dtype == np.int64 and L >= 1 and (np.diff(k.frames) > 0).all() and 0 <= k.frames[0]
    assert k.frames[-1] < 100 and k.labels.shape == (L, 4, 3) and not np.isinf(k.labels).all()
    given = ~np.isnan(k.labels).any(axis=2)
    assert (np.isnan(k.labels).all(axis=2) | given).all() and given.any(axis=1).all()
    assert k.vertices is None or (k.vertices.shape == (4,) and (k.vertices >= -1).all())


def _vertex_csv_seed() -> bytes:
    """A marker CSV with a name column (one quoted, with a comma) and a blank line."""
    return b"vertex_id,x,y,z,name\n5,0.1,0.2,0.3,chin\n0,1,2,3,nose\n\n17,-1,-2,-3,\"brow, left\"\n"


def check_vertex_csv(path, set_aside: bool = True) -> None:
    """A vertex CSV read: distinct ids in the mesh, one row of the header's width per id."""
    from facegeom.io.vertex_csv import read_vertex_csv

    v = read_or_input_error(lambda p: read_vertex_csv(p, n_vertices=20), path, set_aside=set_aside)
    if v is None:
        return
    k = v.ids.size
    assert v.ids.dtype == np.int64 and k >= 1 and ((v.ids >= 0) & (v.ids < 20)).all() and np.unique(v.ids).size == k
    assert len(v.rows) == k == v.lines.size and (np.diff(v.lines) > 0).all()
    assert "vertex_id" in [c.lower() for c in v.header] and all(len(r) == len(v.header) for r in v.rows)
    for i in range(k):
        assert isinstance(v.label(i), str)


def _take_seed() -> bytes:
    """A Live Link Face take as ``write_livelink_csv`` writes it (rotations, passing midnight), one row lost."""
    from facegeom.io.takes import ARKIT_NAMES, write_livelink_csv

    W = np.linspace(0, 1, 4 * 52).reshape(4, 52)
    text = _written(lambda p: write_livelink_csv(p, W, ARKIT_NAMES, 60.0, start=86399.9, rotations=np.ones((4, 9))),
                    "take.csv")
    lines = text.splitlines(keepends=True)  # a lost-tracking row (timecode,0) after the second frame
    return b"".join(lines[:3]) + lines[3].split(b",")[0] + b",0\n" + b"".join(lines[4:])


def check_take(path, set_aside: bool = True) -> None:
    """A take read under both policies: finite (T, 52) weights, times from 0, rotations (T, 9) or None."""
    from facegeom.io.takes import ARKIT_NAMES, read_take

    for policy in ("interpolate", "drop"):
        t = read_or_input_error(lambda p: read_take(p, policy), path, set_aside=set_aside)
        if t is None:
            return
        T = t.n_frames
        assert T >= 1 and t.names == ARKIT_NAMES and t.weights.shape == (T, 52) and np.isfinite(t.weights).all()
        assert t.times.shape == (T,) and t.times[0] == 0 and np.isfinite(t.times).all() and t.timecode_fps > 0
        assert t.rotations is None or (t.rotations.shape == (T, 9) and np.isfinite(t.rotations).all())
        assert t.lost_rows >= 0


def _index_map_seed() -> bytes:
    """An index map with kept, merged, removed, split and new vertices, as ``IndexMap.save`` writes it."""
    from facegeom.pipelines.cleanup.indexmap import IndexMap

    m = IndexMap(np.array([0, 1, 1, -1, 2]), np.array([0, 1, 4, 1, -1]), np.array(["", "", "merge", "drop", ""]))
    return _written(m.save, "map.csv")


def check_index_map(path, set_aside: bool = True) -> None:
    """An index map read: ids in range both ways, one step per old vertex, every old vertex counted once."""
    from facegeom.pipelines.cleanup.indexmap import IndexMap

    m = read_or_input_error(IndexMap.load, path, set_aside=set_aside)
    if m is None:
        return
    o2n, n2o = m.old_to_new, m.new_to_old
    assert o2n.dtype == n2o.dtype == np.int64 and o2n.ndim == n2o.ndim == 1 and m.step.shape == o2n.shape
    assert ((o2n >= -1) & (o2n < m.n_new)).all() and ((n2o >= -1) & (n2o < m.n_old)).all()
    assert sum(m.counts()[k] for k in ("kept", "merged", "removed")) == m.n_old


def _photo(fmt: str) -> bytes:
    """A 6 x 4 photo whose EXIF turns it upright (orientation 6): shown 4 x 6."""
    from PIL import Image

    buf = io.BytesIO()
    im = Image.new("RGB", (6, 4), (200, 120, 80))
    exif = Image.Exif()
    exif[0x0112] = 6
    im.save(buf, fmt, exif=exif)
    return buf.getvalue()


def check_photo(path, set_aside: bool = True) -> None:
    """A photo's size read: two positive ints."""
    from facegeom.io.fitfiles import image_size

    size = read_or_input_error(image_size, path, set_aside=set_aside)
    if size is None:
        return
    w, h = size
    assert type(w) is int and type(h) is int and w > 0 and h > 0


TEXT_TARGETS = {  # name -> (file name, seed, check)
    "shape_names": ("names.csv", _mapping_seed, check_mapping),
    "key_labels": ("labels.csv", _key_labels_seed, check_key_labels),
    "vertex_csv": ("markers.csv", _vertex_csv_seed, check_vertex_csv),
    "take": ("take.csv", _take_seed, check_take),
    "index_map": ("map.csv", _index_map_seed, check_index_map),
    "photo_jpeg": ("photo.jpg", lambda: _photo("JPEG"), check_photo),
    "photo_png": ("photo.png", lambda: _photo("PNG"), check_photo),
}


def test_text_target_seeds_read_as_written(tmp_path):
    from facegeom.io.fitfiles import image_size
    from facegeom.io.key_labels import read_key_labels
    from facegeom.io.shape_names import read_name_mapping
    from facegeom.io.takes import read_take
    from facegeom.io.vertex_csv import read_vertex_csv
    from facegeom.pipelines.cleanup.indexmap import IndexMap

    paths = {}
    for kind, (name, seed, check) in TEXT_TARGETS.items():
        paths[kind] = tmp_path / name
        paths[kind].write_bytes(seed())
        check(paths[kind])
    assert len(read_name_mapping(paths["shape_names"]).rows) == 5
    k = read_key_labels(paths["key_labels"], n_markers=4)
    assert k.frames.tolist() == [3, 10] and np.isnan(k.labels).sum() == 3 and k.vertices.tolist() == [5, 6, 7, 8]
    assert read_vertex_csv(paths["vertex_csv"], 20).ids.tolist() == [5, 0, 17]
    t = read_take(paths["take"])
    assert t.n_frames == 4 and t.lost_rows == 1 and t.rotations.shape == (4, 9) and t.times[-1] > 0
    assert read_take(paths["take"], "drop").n_frames == 3
    m = IndexMap.load(paths["index_map"])
    assert m.counts() == {"old_vertices": 5, "new_vertices": 5, "kept": 3, "merged": 1, "removed": 1, "split": 1,
                          "new": 1}
    assert image_size(paths["photo_jpeg"]) == image_size(paths["photo_png"]) == (4, 6)


@pytest.mark.parametrize("kind", sorted(TEXT_TARGETS))
def test_mutated_text_targets_read_or_raise_input_error(tmp_path, kind):
    name, seed, check = TEXT_TARGETS[kind]
    pool = {kind: seed(), **SEEDS}

    fuzz_file(mutated(kind, pool), tmp_path / name, check, share=2 if kind.startswith("photo") else 1)


# ----------------------------------------------------------------------------- pixels: photos and videos
# read_image decodes (Pillow, under facegeom's own size limit); open_video + iterating decodes every frame
# (FFmpeg through PyAV, under the frame-size limit). Either returns valid pixels or raises InputError.


def _image_seed(kind: str) -> bytes:
    """Small photos that take read_image's paths: EXIF turns, transparency, 16 bits, a palette, two frames."""
    from PIL import Image

    y, x = np.mgrid[0:12, 0:16]
    rgb = np.stack([x * 16, y * 20, (x + y) * 9], axis=2).astype(np.uint8)
    buf = io.BytesIO()
    exif = Image.Exif()
    if kind == "image_jpeg":
        exif[0x0112] = 6
        exif.get_ifd(0x8769)[0xA405] = 26  # the lens, 35 mm equivalent (a phone's)
        Image.fromarray(rgb).save(buf, "JPEG", exif=exif, quality=80)
    elif kind == "image_png":
        exif[0x0112] = 8
        rgba = np.dstack([rgb, (x * 16).astype(np.uint8)])
        Image.fromarray(rgba, "RGBA").save(buf, "PNG", exif=exif)
    elif kind == "image_png16":
        Image.fromarray((y * 5000 + x * 100).astype(np.uint16)).save(buf, "PNG")
    elif kind == "image_gif":
        first = Image.fromarray(rgb).quantize(8)
        first.save(buf, "GIF", save_all=True, append_images=[first.rotate(90)], transparency=0)
    return buf.getvalue()


IMAGE_TARGETS = {"image_jpeg": "photo.jpg", "image_png": "photo.png", "image_png16": "gray16.png",
                 "image_gif": "anim.gif"}


def check_image(path, set_aside: bool = True) -> None:
    """read_image: an (H, W, 3) uint8 RGB array, writable, or one line naming the file; the EXIF lens: a
    plausible focal length or None, never an exception."""
    from facegeom.io.images import focal_35mm, read_image

    f = focal_35mm(path)
    assert f is None or 8.0 <= f <= 2000.0
    a = read_or_input_error(read_image, path, set_aside=set_aside)
    if a is None:
        return
    assert isinstance(a, np.ndarray) and a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3
    assert a.shape[0] >= 1 and a.shape[1] >= 1 and a.flags.writeable and a.flags.c_contiguous


def test_image_seeds_are_valid(tmp_path):
    from facegeom.io.images import read_image

    shapes = {}
    for kind, name in IMAGE_TARGETS.items():
        (tmp_path / name).write_bytes(_image_seed(kind))
        check_image(tmp_path / name, set_aside=False)
        shapes[kind] = read_image(tmp_path / name).shape
    assert shapes == {"image_jpeg": (16, 12, 3), "image_png": (16, 12, 3), "image_png16": (12, 16, 3),
                      "image_gif": (12, 16, 3)}


@pytest.mark.parametrize("kind", sorted(IMAGE_TARGETS))
def test_mutated_images_read_or_raise_input_error(tmp_path, kind):
    pool = {k: _image_seed(k) for k in IMAGE_TARGETS}

    fuzz_file(mutated(kind, {**pool, **SEEDS}), tmp_path / IMAGE_TARGETS[kind], check_image,
              share=len(IMAGE_TARGETS))


def _video_seed(kind: str) -> bytes:
    """A 4-frame 32 x 16 video: H.264 in MP4 (index first) and in Matroska, MPEG-4 Part 2 turned a quarter."""
    av = pytest.importorskip("av")
    import tempfile

    container, codec, options = {"video_mp4": ("mp4", "libx264", {"movflags": "+faststart"}),
                                 "video_mkv": ("matroska", "libx264", {}),
                                 "video_turned": ("mp4", "mpeg4", {})}[kind]
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "seed")
        with av.open(path, "w", format=container, options=options) as c:
            s = c.add_stream(codec, rate=10, options={"preset": "ultrafast"} if codec == "libx264" else {})
            s.width, s.height, s.pix_fmt = 32, 16, "yuv420p"
            if kind == "video_turned":
                s.set_display_rotation(-90)
            for i in range(4):
                a = np.zeros((16, 32, 3), np.uint8)
                a[4:12, 6 * i:6 * i + 8] = (255, 0, 0)
                for p in s.encode(av.VideoFrame.from_ndarray(a, format="rgb24")):
                    c.mux(p)
            for p in s.encode():
                c.mux(p)
        with open(path, "rb") as fh:
            return fh.read()


VIDEO_TARGETS = {"video_mp4": "clip.mp4", "video_mkv": "clip.mkv", "video_turned": "phone.mp4"}


def _read_video(path) -> list[tuple[int, float, tuple]]:
    """Every frame of a video, checked as it comes; ``(index, time_s, shape)`` of each."""
    import math

    from facegeom.io.video import open_video

    out = []
    with open_video(path) as r:
        assert type(r.width) is int and type(r.height) is int and r.width >= 1 and r.height >= 1
        assert r.rotation in (0, 90, 180, 270) and isinstance(r.variable_rate, bool)
        assert r.fps is None or (math.isfinite(r.fps) and r.fps > 0)
        assert r.n_frames is None or r.n_frames >= 1
        for f in r:
            a = f.image
            assert isinstance(a, np.ndarray) and a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3
            assert a.shape[0] >= 1 and a.shape[1] >= 1 and a.flags.c_contiguous
            assert math.isfinite(f.time_s) and (not out or f.index > out[-1][0])
            out.append((f.index, f.time_s, a.shape))
        assert out
        assert r.problem is None or (isinstance(r.problem, str) and len(r.problem.splitlines()) == 1)
    return out


def check_video(path, set_aside: bool = True) -> None:
    """open_video and every frame: valid frames in order, or one line naming the file."""
    read_or_input_error(_read_video, path, set_aside=set_aside)


def test_video_seeds_are_valid(tmp_path):
    for kind, name in VIDEO_TARGETS.items():
        (tmp_path / name).write_bytes(_video_seed(kind))
        frames = _read_video(tmp_path / name)
        assert [i for i, _, _ in frames] == [0, 1, 2, 3]
        assert {shape for _, _, shape in frames} == {(32, 16, 3) if kind == "video_turned" else (16, 32, 3)}


@pytest.mark.parametrize("kind", sorted(VIDEO_TARGETS))
def test_mutated_videos_read_or_raise_input_error(tmp_path, kind):
    pool = {k: _video_seed(k) for k in VIDEO_TARGETS}

    fuzz_file(mutated(kind, {**pool, "image_png": _image_seed("image_png"), **SEEDS}), tmp_path / VIDEO_TARGETS[kind],
              check_video, share=len(VIDEO_TARGETS))


# ----------------------------------------------------------------------------- bugs found, reported, not fixed yet


def _npz_rig_with(**arrays) -> bytes:
    """A minimal npz rig (one triangle, one shape) with some of its arrays replaced or added."""
    base = dict(neutral=np.eye(3), deltas=np.ones((1, 3, 3)), names=np.array(["a"]), triangles=np.array([[0, 1, 2]]),
                landmark_ids=np.zeros(0, np.int64))
    buf = io.BytesIO()
    np.savez(buf, **{**base, **arrays})
    return buf.getvalue()


def _npz_map_with(**arrays) -> bytes:
    """The minimal npz rig with a one-row shape mapping, some of its arrays replaced."""
    mapping = dict(map_rig=np.array(["a"]), map_source=np.array(["jawOpen"]), map_gain=np.array([1.0]),
                   map_line=np.array([2]))
    return _npz_rig_with(**{**mapping, **arrays})


def load_rig_quickly(path, set_aside: bool = True) -> None:
    """``load_rig_file(path)`` within 0.5 s (a file of a few hundred bytes)."""
    import time

    start = time.perf_counter()
    load_rig_file(path, set_aside)
    assert time.perf_counter() - start < 0.5, f"{time.perf_counter() - start:.1f} s to read {path}"


def _npz_header_edit(npz: bytes, key: str, old: bytes, new: bytes) -> bytes:
    """``npz`` with ``old`` replaced by ``new`` in member ``key``'s ``.npy`` bytes (its header), zipped again."""
    members = _npz_members(npz)
    members[f"{key}.npy"] = members[f"{key}.npy"].replace(old, new, 1)
    return _zip(members)


def _npy_v3() -> bytes:
    """``np.zeros((3, 3))`` as a version 3.0 ``.npy`` (numpy writes one when a header is not latin-1)."""
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.zeros((3, 3)), version=(3, 0))
    return buf.getvalue()


def _take_repeating(cell: str) -> bytes:
    """A take header of the 52 ARKit columns and ``cell`` twice, and one row."""
    from facegeom.io.takes import ARKIT_NAMES

    return f"Timecode,{','.join(ARKIT_NAMES)},{cell},{cell}\n00:00:00:00.000{',0' * 54}\n".encode()


def check_marker_message(path, set_aside: bool = True) -> None:
    """``read_markers`` reads the file or refuses it in one line naming it."""
    read_or_input_error(lambda p: read_markers(p, n_vertices=20), path, set_aside=set_aside)


def check_sequence_message(path, set_aside: bool = True) -> None:
    """``read_marker_sequence`` reads the file or refuses it in one line naming it."""
    read_or_input_error(read_marker_sequence, path, set_aside=set_aside)


def _zip_name_not_utf8(npz: bytes) -> bytes:
    """``npz`` whose first central-directory entry flags its name as UTF-8 (bit 11) and starts with byte 0x9d."""
    data = bytearray(npz)
    at = data.find(b"PK\x01\x02")
    data[at + 9] |= 0x08  # general-purpose flags, high byte: bit 11
    data[at + 46] = 0x9D  # the name, right after the 46-byte entry
    return bytes(data)


IM_HEAD = b"old_id,new_id,status,step\n"
def _zip_needing_version(version: int) -> bytes:
    """A valid rig npz whose central directory says reading it needs zip ``version`` (e.g. 109: "10.9")."""
    data = bytearray(_npz_rig_with())
    at = data.find(b"PK\x01\x02")
    while at >= 0:
        data[at + 6:at + 8] = struct.pack("<H", version)  # version needed to extract
        at = data.find(b"PK\x01\x02", at + 4)
    return bytes(data)


def _mp4_sample_entry_of_16_mb() -> bytes:
    """The MP4 video seed whose sample description's first entry says it is 16 MB long (FFmpeg: ENOMEM)."""
    data = bytearray(_video_seed("video_mp4"))
    data[data.find(b"stsd") + 12] = 0x01  # the entry's 32-bit size, high byte
    return bytes(data)


def _png_idat_of_2_gb() -> bytes:
    """The 16-bit PNG seed whose image-data chunk says it is 2.16 GB long (Pillow reads that many bytes at once)."""
    data = bytearray(_image_seed("image_png16"))
    data[data.find(b"IDAT") - 4] = 0x81  # the chunk's 32-bit length, high byte
    return bytes(data)


FOUND_CORPUS = [  # (id, file name, check, bytes): what the targets above found, each fixed since
    ("png-idat-length-2gb", "gray16.png", check_image, _png_idat_of_2_gb),  # MemoryError under the memory cap
    ("mp4-ffmpeg-enomem", "clip.mp4", check_video, _mp4_sample_entry_of_16_mb),  # av.error.MemoryError
    ("npz-zip-version-10.9", "rig.npz", load_rig_file, lambda: _zip_needing_version(109)),  # NotImplementedError
    ("npz-name-not-utf8", "capture.npz", check_sequence_message,  # UnicodeDecodeError in zipfile
     lambda: _zip_name_not_utf8(SEEDS["npz"])),
    ("rig-npz-name-not-utf8", "rig.npz", load_rig_file, lambda: _zip_name_not_utf8(_npz_rig_with())),
    ("npz-triangles-str", "rig.npz", load_rig_file, lambda: _npz_rig_with(triangles=np.array([["0", "1", "2"]]))),
    ("npz-landmarks-bytes", "rig.npz", load_rig_file, lambda: _npz_rig_with(landmark_ids=np.array([b"0"]))),
    ("npz-neutral-void", "rig.npz", load_rig_file, lambda: _npz_rig_with(neutral=np.zeros((3, 3), "V4"))),
    ("npz-deltas-void", "rig.npz", load_rig_file, lambda: _npz_rig_with(deltas=np.zeros((1, 3, 3), "V4"))),
    ("npz-map-gain-text", "rig.npz", load_rig_file, lambda: _npz_map_with(map_gain=np.array(["x"]))),
    ("npz-map-line-date", "rig.npz", load_rig_file, lambda: _npz_map_with(map_line=np.zeros(1, "M8[s]"))),
    ("npz-npy-version-3", "rig.npz", load_rig_file, lambda: _zip({"neutral.npy": _npy_v3()})),  # AttributeError
    ("npz-header-unclosed", "rig.npz", load_rig_file,  # a member's header without its '}': tokenize.TokenError
     lambda: _zip({"neutral.npy": _npy(np.zeros(3)).replace(b"}", b" ")})),
    ("indexmap-old-negative", "map.csv", check_index_map, lambda: IM_HEAD + b"0,-5,removed,\n"),  # no file name
    ("indexmap-split-past-old", "map.csv", check_index_map, lambda: IM_HEAD + b"5,0,split,\n"),  # no file name
    ("indexmap-kept-minus-one", "map.csv", check_index_map, lambda: IM_HEAD + b"0,-1,kept,\n"),  # IndexError
    ("indexmap-huge-id", "map.csv", check_index_map, lambda: IM_HEAD + b"0,99999999999999999999,kept,\n"),
    ("indexmap-huge-new-id", "map.csv", check_index_map, lambda: IM_HEAD + b"0,99999999999999999999,new,\n"),
    ("indexmap-4g-vertices", "map.csv", check_index_map, lambda: IM_HEAD + b"0,0,kept,\n0,4294967295,new,\n"),
    ("key-labels-header-newline", "labels.csv", check_key_labels, lambda: b'"a\nb"\n1,0,0,0,0\n'),
    ("vertex-csv-header-newline", "markers.csv", check_vertex_csv, lambda: b'"a\nb"\n1\n'),
    ("take-repeated-column-newline", "take.csv", check_take, lambda: _take_repeating('"x\ny"')),
    ("mapping-repeated-pair-newline", "names.csv", check_mapping,
     lambda: b'rig_shape,source_shape\n"a\nb",c\n"a\nb",c\n'),
    ("markers-header-newline", "markers.csv", check_marker_message, lambda: b'"a\nb"\n1,2,3,4\n'),
    ("npz-names-bad-code-point", "rig.npz", load_rig_file,  # SystemError from str() of the name (fixed: 39c5a96)
     lambda: _npz_rig_with(names=np.frombuffer(struct.pack("<I", 0x110000), "<U1"))),
    ("npz-map-gain-2d", "rig.npz", load_rig_file, lambda: _npz_map_with(map_gain=np.array([[1.0]]))),  # TypeError
    ("npz-huge-dim-of-empty", "rig.npz", load_rig_file,  # OverflowError in np.load
     lambda: _npz_header_edit(_npz_rig_with(), "landmark_ids", b"(0,)", b"(0, 99999999999999999999)")),
    ("npz-names-zero-size-items", "rig.npz", load_rig_quickly, lambda: _npz_header_edit(  # 1e7 names: 1.3 s
        _npz_rig_with(), "names", b"'<U1', 'fortran_order': False, 'shape': (1,)",  # 1e12: hours, memory
        b"'<U0', 'fortran_order': False, 'shape': (10000000,)")),
]


@pytest.mark.parametrize("name,check,build", [pytest.param(*case[1:], id=case[0]) for case in FOUND_CORPUS])
def test_found_corpus(tmp_path, name, check, build):
    path = tmp_path / name
    path.write_bytes(build())
    check(path, set_aside=False)


# ----------------------------------------------------------------------------- Live Link Face packets
def _livelink_seeds() -> dict[str, bytes]:
    """Real packets (a performance's first and last, a head-yaw sweep's) and the recordings they come from."""
    from pathlib import Path

    from facegeom.io.livelink import read_recording

    folder = Path(__file__).parent / "data" / "livelink"
    dao = read_recording(folder / "dao.gesichter")
    yaw = read_recording(folder / "debug-headyaw.gesichter")
    return {"packet": dao[0], "packet_last": dao[-1], "packet_yaw": yaw[len(yaw) // 2],
            "recording": (folder / "debug-jawleft.gesichter").read_bytes()}


def test_mutated_livelink_packets_parse_or_raise_packet_error():
    """Every datagram: a packet whose values are finite and bounded, or a PacketError of one line."""
    from facegeom.io.livelink import MAX_VALUE, PACKET_VALUES, PacketError, parse_packet

    seeds = _livelink_seeds()
    pool = {k: v for k, v in seeds.items() if k.startswith("packet")}

    def run(data):
        try:
            with time_limit(5.0):
                p = parse_packet(data.draw(mutated(data.draw(st.sampled_from(sorted(pool))), pool)))
        except PacketError as exc:
            assert len(str(exc).splitlines()) == 1
            return
        assert p.values.shape == (PACKET_VALUES,) and np.isfinite(p.values).all()
        assert np.abs(p.values).max() <= MAX_VALUE

    campaign(run, share=2, data=st.data())


def test_mutated_livelink_recordings_read_or_raise_input_error(tmp_path):
    from facegeom.io.livelink import read_recording

    seeds = _livelink_seeds()
    inner = {"raw": gzip.decompress(seeds["recording"])}

    def run(data):
        if data.draw(st.booleans()):  # the gzip stream itself damaged
            blob = data.draw(mutated("recording", {"recording": seeds["recording"]}))
        else:  # a well-formed gzip around damaged content
            blob = gzip.compress(data.draw(mutated("raw", inner)))
        path = tmp_path / "r.gesichter"
        path.write_bytes(blob)
        out = read_or_input_error(read_recording, path)
        assert out is None or all(isinstance(p, bytes) for p in out)

    campaign(run, share=2, data=st.data())
