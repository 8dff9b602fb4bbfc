"""Rigs a user hands in (an OBJ folder or an ``.npz``): confined to their folder, sized before anything is
allocated, and never a singular solve.

- An OBJ folder's files are regular files inside the folder (a symlink may point inside it, never out of it;
  FIFOs and sockets are refused without being opened, which would block).
- Caps on the shapes, the neutral's vertices and the deltas' memory (:data:`facegeom.model.rig.MAX_RIG_SHAPES`,
  ``MAX_RIG_VERTICES``, ``RIG_DELTA_COPIES``) are checked before the deltas are allocated; an ``.npz`` whose
  deltas compress as no rig's do is refused before it is loaded; a ``MemoryError`` is one line.
- A shape equal to the neutral (a zero delta), a duplicate, or more shapes than the data have coordinates do not
  make a fitter's solve singular.
"""
from __future__ import annotations

import os
import socket
import stat
import threading
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import write_mesh

HEADS = Path(__file__).parent / "data" / "heads"
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
JAW = "v 0 0 0\nv 1 0 0\nv 0 1.2 0\nf 1 2 3\n"


def _folder(root: Path, shapes=None) -> Path:
    """A rig folder: ``neutral.obj`` (one triangle) and the shapes given as {name: OBJ text}."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "neutral.obj").write_text(TRI)
    for name, text in (shapes if shapes is not None else {"jawOpen": JAW}).items():
        (root / f"{name}.obj").write_text(text)
    return root


def _from_folder(folder, timeout: float = 20.0):
    """``BlendshapeRig.from_obj_folder`` in a thread: a reader that opens a FIFO blocks forever, and the test
    must then fail, not hang -> the rig or the exception raised."""
    from facegeom.model.rig import BlendshapeRig

    out = {}

    def run():
        try:
            out["rig"] = BlendshapeRig.from_obj_folder(folder)
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out["exc"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), "the rig reader blocked (it opened a FIFO?)"
    if "exc" in out:
        raise out["exc"]
    return out["rig"]


def _one_line(capsys, *words):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def _cli(*args) -> int:
    from facegeom.cli.main import main

    try:
        main([str(a) for a in args])
    except SystemExit as exc:
        return int(exc.code)
    return 0


def _makehuman(k: int | None = None):
    """The MakeHuman ARKit head (4,817 vertices, 52 shapes; CC0), its first ``k`` shapes."""
    from facegeom.model import BlendshapeRig

    rig = BlendshapeRig.from_npz(HEADS / "makehuman_arkit.npz")
    if k is None:
        return rig
    return BlendshapeRig(rig.neutral, rig.deltas[:k], rig.names[:k], rig.triangles)


# ============================================================================= 1. confined to the rig's folder
@pytest.mark.parametrize("target", ["obj", "system"])
def test_a_shape_linked_outside_the_folder_is_refused_naming_it_and_where_it_points(tmp_path, target):
    rig = _folder(tmp_path / "rig", {})
    if target == "obj":
        outside = tmp_path / "elsewhere" / "jaw.obj"
        outside.parent.mkdir()
        outside.write_text(JAW)
    else:
        outside = Path("/etc/passwd")
        if not outside.is_file():
            pytest.skip("no /etc/passwd here")
    (rig / "jawOpen.obj").symlink_to(outside)
    with pytest.raises(InputError) as e:
        _from_folder(rig)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(rig / "jawOpen.obj") + ":"), msg
    assert str(outside.resolve()) in msg and "outside the rig folder" in msg, msg


def test_the_neutral_linked_outside_the_folder_is_refused(tmp_path):
    rig = _folder(tmp_path / "rig")
    (tmp_path / "base.obj").write_text(TRI)
    (rig / "neutral.obj").unlink()
    (rig / "neutral.obj").symlink_to(tmp_path / "base.obj")
    with pytest.raises(InputError, match="outside the rig folder") as e:
        _from_folder(rig)
    assert str(e.value).startswith(str(rig / "neutral.obj") + ":")


def test_a_dangling_link_is_refused_naming_where_it_points(tmp_path):
    rig = _folder(tmp_path / "rig")
    (rig / "mouthClose.obj").symlink_to(rig / "gone.obj")
    with pytest.raises(InputError, match="mouthClose.obj: .*gone.obj.*(does not exist|outside)"):
        _from_folder(rig)


def test_a_link_that_stays_inside_the_folder_is_followed(tmp_path):
    rig = _folder(tmp_path / "rig", {})
    (rig / "sources").mkdir()
    (rig / "sources" / "jaw_v2.obj").write_text(JAW)
    (rig / "jawOpen.obj").symlink_to(Path("sources") / "jaw_v2.obj")  # relative, as artists link versions
    (rig / "jawOpenCopy.obj").symlink_to(rig / "sources" / ".." / "jawOpen.obj")  # a link to a link, inside
    got = _from_folder(rig)
    assert got.names == ("jawOpen", "jawOpenCopy")
    assert np.allclose(got.deltas[:, 2], [[0, 0.2, 0]] * 2)


def test_a_rig_folder_given_through_a_link_is_its_own_inside(tmp_path):
    rig = _folder(tmp_path / "real")
    (tmp_path / "alias").symlink_to(rig)
    assert _from_folder(tmp_path / "alias").names == ("jawOpen",)


@pytest.mark.parametrize("kind", ["fifo", "socket", "device"])
@pytest.mark.parametrize("which", ["shape", "neutral"])
def test_a_fifo_socket_or_device_in_a_rig_folder_is_refused_without_opening_it(tmp_path, kind, which):
    rig = _folder(tmp_path / "rig")
    path = rig / ("mouthClose.obj" if which == "shape" else "neutral.obj")
    if which == "neutral":
        path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
        what = "FIFO"
    elif kind == "device":  # /dev/zero's numbers: read, it never ends
        try:
            os.mknod(path, 0o600 | stat.S_IFCHR, os.makedev(1, 5))
        except (OSError, AttributeError) as exc:
            pytest.skip(f"cannot make a device file here (needs the right to, as root has): {exc}")
        what = "character device"
    else:
        sock = socket.socket(socket.AF_UNIX)
        try:
            sock.bind(str(path))
        except OSError as exc:  # pragma: no cover - a path too long for a socket address
            pytest.skip(f"cannot bind a socket there: {exc}")
        what = "socket"
    with pytest.raises(InputError) as e:
        _from_folder(rig)
    msg = str(e.value)
    assert msg.startswith(str(path) + ":") and what in msg and "not a regular file" in msg, msg


def test_character_with_a_shape_linked_outside_exits_2_in_one_line(tmp_path, capsys, face_model):
    from facegeom.io.markerseq import write_marker_sequence
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import ict80

    ict = BlendshapeRig.from_face_model(face_model)
    ids = ict80(face_model)
    write_marker_sequence(tmp_path / "cap.npz", np.repeat(ict.neutral[ids][None], 3, axis=0),
                          names=[f"v{i}" for i in ids])
    mh = _makehuman(3)
    rig = tmp_path / "character"
    rig.mkdir()
    mh.write_obj_folder(rig)
    outside = tmp_path / "eyeBlinkLeft.obj"
    (rig / mh.names[0]).with_suffix(".obj").replace(outside)
    (rig / f"{mh.names[0]}.obj").symlink_to(outside)
    code = _cli("solve", tmp_path / "cap.npz", "--character", rig, "-o", tmp_path / "out.glb")
    assert code == 2
    _one_line(capsys, f"{mh.names[0]}.obj", "outside the rig folder", str(outside))
    assert not (tmp_path / "out.glb").exists()


# ============================================================================= 2. caps before allocating
def test_more_shape_files_than_any_rig_has_are_refused_before_one_is_read(tmp_path):
    from facegeom.model.rig import MAX_RIG_SHAPES

    rig = _folder(tmp_path / "rig", {})
    for i in range(MAX_RIG_SHAPES + 1):  # not OBJs at all: reading one would be another error
        (rig / f"s{i:05d}.obj").write_bytes(b"x")
    with pytest.raises(InputError) as e:
        _from_folder(rig)
    msg = str(e.value)
    assert msg.startswith(str(rig) + ":") and f"{MAX_RIG_SHAPES + 1:,} shape files" in msg, msg
    assert f"{MAX_RIG_SHAPES:,}" in msg


def _big_neutral(path: Path, n: int) -> None:
    """An OBJ of ``n`` vertices on a sphere of 8 cm (a face's size) and one triangle."""
    t = np.linspace(0, np.pi, n)
    V = 8 * np.c_[np.sin(t) * np.cos(40 * t), np.cos(t), np.sin(t) * np.sin(40 * t)]
    with open(path, "w") as fh:
        np.savetxt(fh, V, fmt="v %.4f %.4f %.4f")
        fh.write("f 1 2 3\n")


def test_a_rig_folder_over_the_memory_budget_is_refused_before_the_deltas_are_allocated(tmp_path, monkeypatch):
    from facegeom.io import npzcheck
    from facegeom.model.rig import RIG_DELTA_COPIES

    rig = tmp_path / "rig"
    rig.mkdir()
    n, B = 20_000, 200  # 96 MB of deltas
    _big_neutral(rig / "neutral.obj", n)
    for i in range(B):
        (rig / f"s{i:03d}.obj").write_text("v 0 0 0\n")  # never read: the budget comes first
    monkeypatch.setattr(npzcheck, "memory_budget", lambda: 64 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(InputError) as e:
            _from_folder(rig)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(e.value)
    assert msg.startswith(str(rig) + ":") and "200 shapes x 20,000 vertices" in msg and "96.0 MB" in msg, msg
    assert f"{RIG_DELTA_COPIES}" in msg
    assert peak < 40e6, f"{peak / 1e6:.0f} MB traced: the deltas were allocated"


def test_a_neutral_with_more_vertices_than_the_cap_is_refused(tmp_path, monkeypatch):
    from facegeom.model import rig as rigmod

    monkeypatch.setattr(rigmod, "MAX_RIG_VERTICES", 2)
    rig = _folder(tmp_path / "rig")
    with pytest.raises(InputError, match=r"neutral.obj: 3 vertices, more than .*2") as e:
        _from_folder(rig)
    assert "\n" not in str(e.value)


def test_a_shape_file_too_small_for_the_neutral_is_refused_before_the_others_are_read(tmp_path):
    rig = tmp_path / "rig"
    rig.mkdir()
    _big_neutral(rig / "neutral.obj", 1000)
    (rig / "a_broken.obj").write_text("v 0 0 zero\n" * 1000)  # read first, it would be another error
    (rig / "z_short.obj").write_text("v 0 0 0\n" * 10)
    with pytest.raises(InputError) as e:
        _from_folder(rig)
    msg = str(e.value)
    assert msg == f"{rig / 'z_short.obj'}: has 10 vertices but the neutral 'neutral.obj' has 1000", msg


# ============================================================================= 3. npz rigs sized before loading
def _npz(path: Path, deltas_shape, deltas_name="deltas.npy", n=None, level=6, **arrays) -> Path:
    """A rig npz whose deltas are zeros, deflated as they are written (a few MB at most in memory; level 6 is
    numpy.savez_compressed's)."""
    B, nv = deltas_shape[0], deltas_shape[1] if n is None else n
    base = dict(neutral=np.zeros((nv, 3)), names=np.array([f"s{i}" for i in range(B)]),
                triangles=np.array([[0, 1, 2]]), landmark_ids=np.zeros(0, np.int64))
    base.update(arrays)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=level) as zf:
        for k, a in base.items():
            with zf.open(k + ".npy", "w") as fh:
                np.lib.format.write_array(fh, np.asarray(a))
        with zf.open(deltas_name, "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False,
                                                      "shape": tuple(deltas_shape)})
            left, chunk = int(np.prod(deltas_shape)) * 8, bytes(1 << 20)
            while left:
                fh.write(chunk[:min(left, len(chunk))])
                left -= min(left, len(chunk))
    return path


def _traced(fn):
    tracemalloc.start()
    try:
        try:
            fn()
        finally:
            peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return peak


def test_an_npz_of_more_shapes_than_any_rig_has_is_refused(tmp_path):
    from facegeom.model.inputs import load_rig
    from facegeom.model.rig import MAX_RIG_SHAPES

    f = _npz(tmp_path / "rig.npz", (MAX_RIG_SHAPES + 1, 3, 3))
    with pytest.raises(InputError) as e:
        load_rig(f)
    msg = str(e.value)
    assert msg.startswith(str(f) + ":") and f"{MAX_RIG_SHAPES + 1:,} shapes" in msg and "deltas" in msg, msg


def test_an_npz_with_more_vertices_than_the_cap_is_refused(tmp_path, monkeypatch):
    from facegeom.model import rig as rigmod
    from facegeom.model.inputs import load_rig

    monkeypatch.setattr(rigmod, "MAX_RIG_VERTICES", 1000)
    f = _npz(tmp_path / "rig.npz", (2, 1001, 3))
    with pytest.raises(InputError, match=r"rig.npz: .*1,001 vertices, more than .*1,000"):
        load_rig(f)


def test_deflated_zero_deltas_are_refused_by_their_compression_before_loading(tmp_path, monkeypatch):
    from facegeom.model import rig as rigmod
    from facegeom.model.inputs import load_rig

    # the audit's file held 4.5 GB of zeros in 4.6 MB; the same at 64 MB, the size threshold lowered to match
    f = _npz(tmp_path / "rig.npz", (53, 50_000, 3))
    assert f.stat().st_size < 1e6
    monkeypatch.setattr(rigmod, "RATIO_CHECKED_FROM", 32 << 20)
    with pytest.raises(InputError) as e:
        load_rig(f)
    msg = str(e.value)
    assert msg.startswith(str(f) + ":") and "'deltas'" in msg and "beyond the 900:1" in msg and "compressed" in msg, msg
    peak = _traced(lambda: pytest.raises(InputError, load_rig, f))
    assert peak < 20e6, f"{peak / 1e6:.0f} MB traced: the deltas were loaded"


def test_npz_deltas_beyond_the_memory_budget_are_refused_before_loading(tmp_path, monkeypatch, capsys):
    from facegeom.io import npzcheck
    from facegeom.model.inputs import load_rig

    f = _npz(tmp_path / "rig.npz", (53, 50_000, 3))  # 63.6 MB: 254 MB with the copies fit and solve make
    monkeypatch.setattr(npzcheck, "memory_budget", lambda: 200 << 20)
    with pytest.raises(InputError) as e:
        load_rig(f)
    msg = str(e.value)
    assert msg.startswith(str(f) + ":") and "53 shapes x 50,000 vertices" in msg and "63.6 MB" in msg, msg
    peak = _traced(lambda: pytest.raises(InputError, load_rig, f))
    assert peak < 20e6, f"{peak / 1e6:.0f} MB traced: the deltas were loaded"
    (tmp_path / "t.obj").write_text(TRI)
    assert _cli("fit", tmp_path / "t.obj", "--rig", f, "-o", tmp_path / "w.json") == 2
    _one_line(capsys, "rig.npz", "53 shapes")


def test_a_member_without_the_npy_suffix_is_checked_like_the_others(tmp_path):
    """numpy.load also reads a member ``deltas`` (no ``.npy``) as the array ``deltas``: its header counts."""
    from facegeom.model.inputs import load_rig

    f = tmp_path / "rig.npz"
    with zipfile.ZipFile(f, "w") as zf:
        for k, a in dict(neutral=np.zeros((4, 3)), names=np.array(["a"]), triangles=np.array([[0, 1, 2]]),
                         landmark_ids=np.zeros(0, np.int64)).items():
            with zf.open(k + ".npy", "w") as fh:
                np.lib.format.write_array(fh, a)
        with zf.open("deltas", "w") as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False,
                                                      "shape": (50_000, 100_000, 3)})
            fh.write(bytes(80))
    with pytest.raises(InputError, match=r"rig.npz: array 'deltas' declares shape \(50000, 100000, 3\)"):
        load_rig(f)


def test_a_50000_vertex_head_with_53_shapes_loads(tmp_path):
    """A large real-sized rig (64 MB of deltas, most of each shape still, as real shapes are) is not refused."""
    from facegeom.model import BlendshapeRig
    from facegeom.model.inputs import load_rig

    n, B = 50_000, 53
    rng = np.random.default_rng(0)
    t = rng.uniform(0, np.pi / 2, n)
    p = rng.uniform(-np.pi / 2, np.pi / 2, n)
    V = 8 * np.c_[np.cos(t) * np.sin(p), np.sin(t) - 0.5, np.cos(t) * np.cos(p)]
    D = np.zeros((B, n, 3))
    for b in range(B):
        near = np.linalg.norm(V - V[rng.integers(n)], axis=1) < 2.5  # a region of the face moves
        D[b, near] = rng.normal(0, 0.2, (near.sum(), 3)) * np.exp(-np.linalg.norm(V[near], axis=1))[:, None]
    tri = np.c_[np.arange(n - 2), np.arange(1, n - 1), np.arange(2, n)]
    f = BlendshapeRig(V, D, [f"s{b}" for b in range(B)], tri).save_npz(tmp_path / "head.npz", compressed=True)
    rig = load_rig(f)
    assert rig.n_vertices == n and rig.n_shapes == B and np.abs(rig.frame.to_source(rig.deltas) - D).max() < 1e-9


@pytest.mark.parametrize("where", ["npz read", "folder read", "frame"])
def test_a_memory_error_while_loading_a_rig_is_one_line(tmp_path, monkeypatch, capsys, where):
    from facegeom.model import units
    from facegeom.model.inputs import load_rig

    def boom(*args, **kwargs):
        raise np._core._exceptions._ArrayMemoryError((10 ** 9, 3), np.dtype(float))  # what numpy raises

    mh = _makehuman(2)
    if where == "folder read":
        path = tmp_path / "rig"
        path.mkdir()
        mh.write_obj_folder(path)
        monkeypatch.setattr("facegeom.io.formats.obj.read_obj", boom)
        monkeypatch.setattr("facegeom.model.rig.read_obj", boom, raising=False)
    else:
        path = mh.save_npz(tmp_path / "rig.npz")
        if where == "npz read":
            monkeypatch.setattr(np, "load", boom)
        else:
            monkeypatch.setattr(units, "rig_frame", boom)
    with pytest.raises(InputError) as e:
        load_rig(path)
    msg = str(e.value)
    assert msg.startswith(str(path) + ":") and "memory" in msg and "\n" not in msg, msg
    (tmp_path / "t.obj").write_text(TRI)
    assert _cli("fit", tmp_path / "t.obj", "--rig", path, "-o", tmp_path / "w.json") == 2
    _one_line(capsys, path.name, "memory")


# ============================================================================= 4. no singular solve
def _dependent_rig():
    """The MakeHuman head's first 8 shapes, one equal to the neutral (zero delta) and one twice (a duplicate)."""
    from facegeom.model import BlendshapeRig

    mh = _makehuman(8)
    D = np.concatenate([mh.deltas, np.zeros((1,) + mh.deltas.shape[1:]), mh.deltas[:1]])
    return BlendshapeRig(mh.neutral, D, mh.names + ("tongueOut", mh.names[0] + "_copy"), mh.triangles)


def _capture(rig, w, T=4, seed=0):
    ids = np.arange(0, rig.n_vertices, rig.n_vertices // 80)[:80]
    X = np.repeat(rig.evaluate(w)[ids][None], T, axis=0)
    return X + np.random.default_rng(seed).normal(0, 1e-4, X.shape), ids


@pytest.mark.parametrize("name, params", [("l1reg", {}), ("l1reg", {"w_l1": 1e-9}), ("l2reg", {}), ("sem-ls", {}),
                                          ("sem", {}), ("pcaexp", {}), ("pcadel", {})])
def test_a_zero_and_a_duplicate_shape_do_not_make_a_solve_singular(name, params):
    from facegeom.methods.marker_solve import solve_markers
    from facegeom.model import MeshTarget
    from facegeom.registry import create

    rig = _dependent_rig()
    w = np.zeros(rig.n_shapes)
    w[[0, 2, 5]] = [0.6, 0.4, 0.3]
    X, ids = _capture(rig, w)
    fitter = create("fitters", name, **params)
    s = solve_markers(X, ids, rig, fitter)
    assert np.isfinite(s.weights).all()
    if params or name == "sem-ls":  # (the baselines' default priors pull the weights of 80 markers towards 0)
        got = s.weights.copy()
        got[:, 0] += got[:, -1]  # a duplicate shares its original's weight
        assert np.abs(got[:, [0, 2, 5]] - w[[0, 2, 5]]).max() < 0.01, got[0]
        assert np.abs(s.weights[:, 8]).max() < 1e-6  # the zero shape moves nothing: weight 0
    if name == "l1reg":  # the least-norm minimum: the duplicates share their weight evenly
        assert np.abs(s.weights[:, 0] - s.weights[:, -1]).max() < 1e-3, s.weights[0]
    res = fitter.fit_many(rig, [MeshTarget(rig.evaluate(w)) for _ in range(3)])
    assert all(np.isfinite(r.weights).all() for r in res)


def test_more_shapes_than_marker_coordinates_solve_with_l1reg():
    """300 shapes (combinations of 52) on 80 markers: 240 coordinates, a Gram matrix of rank 52."""
    from facegeom.baselines.fitters import L1RegFitter
    from facegeom.methods.marker_solve import solve_markers
    from facegeom.model import BlendshapeRig

    mh = _makehuman()
    rng = np.random.default_rng(1)
    M = rng.random((300, mh.n_shapes)) * (rng.random((300, mh.n_shapes)) < 0.05)
    M[:mh.n_shapes] = np.eye(mh.n_shapes)
    rig = BlendshapeRig(mh.neutral, np.tensordot(M, mh.deltas, axes=1), [f"s{i}" for i in range(300)],
                        mh.triangles)
    w = np.zeros(300)
    w[[3, 10, 20]] = 0.5
    X, ids = _capture(rig, w, T=3)
    s = solve_markers(X, ids, rig, L1RegFitter())
    assert np.isfinite(s.weights).all() and np.nanmax(s.rms) < 0.01  # the markers are met (cm)


def test_solve_and_fit_on_an_obj_folder_with_a_zero_shape_exit_0(tmp_path, capsys):
    from facegeom.io.markerseq import write_marker_sequence

    rig = _dependent_rig()
    folder = tmp_path / "rig"
    folder.mkdir()
    rig.write_obj_folder(folder)
    w = np.zeros(rig.n_shapes)
    w[[0, 3]] = [0.5, 0.7]
    X, ids = _capture(rig, w, T=5)
    write_marker_sequence(tmp_path / "cap.npz", X, names=[f"v{i}" for i in ids])
    write_mesh(tmp_path / "target.obj", rig.evaluate(w), rig.triangles)
    for fitter in ("l1reg", "sem-ls"):
        assert _cli("solve", tmp_path / "cap.npz", "--rig", folder, "--fitter", fitter, "-o",
                    tmp_path / f"{fitter}.npz") == 0, capsys.readouterr().err
        assert _cli("fit", tmp_path / "target.obj", "--rig", folder, "-m", fitter, "-o",
                    tmp_path / f"{fitter}.json") == 0, capsys.readouterr().err
    z = np.load(tmp_path / "l1reg.npz")
    names = [str(n) for n in z["names"]]
    assert np.abs(z["weights"][:, names.index("tongueOut")]).max() < 1e-6


def test_a_folder_whose_only_shape_is_the_neutral_solves_to_weight_0(tmp_path, capsys):
    """No shape moves a marker: the joint pose refinement's damping was 0 times the shapes' size (a singular
    system); the pose is still found and the weight is 0."""
    from facegeom.io.markerseq import write_marker_sequence
    from facegeom.model import BlendshapeRig

    mh = _makehuman(1)
    rig = BlendshapeRig(mh.neutral, np.zeros_like(mh.deltas), ["tongueOut"], mh.triangles)
    folder = tmp_path / "rig"
    folder.mkdir()
    rig.write_obj_folder(folder)
    X, ids = _capture(rig, np.zeros(1), T=3)
    write_marker_sequence(tmp_path / "cap.npz", X + [1.0, 2.0, 3.0], names=[f"v{i}" for i in ids])
    for fitter in ("sem-ls", "l1reg", "l2reg"):
        assert _cli("solve", tmp_path / "cap.npz", "--rig", folder, "--fitter", fitter, "-o",
                    tmp_path / f"{fitter}.npz") == 0, capsys.readouterr().err
        z = np.load(tmp_path / f"{fitter}.npz")
        assert np.abs(z["weights"]).max() < 1e-9
    assert _cli("solve", tmp_path / "cap.npz", "--rig", folder, "--fitter", "pcaexp", "-o", tmp_path / "p.npz") == 2
    _one_line(capsys, "the rig's shapes do not vary")
