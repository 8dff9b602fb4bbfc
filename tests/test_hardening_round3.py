"""Hostile inputs of a few bytes: bounded work, one clear line, no silent wrong result.

Each test writes its own reproducer (a few bytes) and checks the reader or the
command refuses it with one line naming the file, or handles it within its
budget.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from facegeom.errors import InputError

BIG_CELL = "7" * 200_000  # past the csv module's 131,072-character field limit


def _csv_readers():
    from facegeom.io import read_landmarks, read_marker_sequence, read_markers, read_weights
    from facegeom.io.shape_names import ARKIT_NAMES, read_name_mapping
    from facegeom.io.takes import read_take
    from facegeom.pipelines.cleanup.indexmap import IndexMap

    return {
        "landmarks": (lambda p: read_landmarks(p), "vertex_id,u,v\n1,{big},3\n"),
        "markers": (lambda p: read_markers(p), "vertex_id,x,y,z\n1,{big},2,3\n"),
        "marker sequence": (lambda p: read_marker_sequence(p), "frame,m0_x,m0_y,m0_z\n0,{big},1,1\n"),
        "weights": (lambda p: read_weights(p, ["a", "b"]), "shape,weight\na,{big}\n"),
        "name mapping": (lambda p: read_name_mapping(p), "rig_shape,source_shape,gain\na,{big},1\n"),
        "take": (lambda p: read_take(p), "Timecode,BlendShapeCount," + ",".join(ARKIT_NAMES) + "\n00:00:00:00.000,52,"
                 + "{big}" + ",0" * (len(ARKIT_NAMES) - 1) + "\n"),
        "index map": (lambda p: IndexMap.load(p), "old_id,new_id,status,step\n0,{big},kept,x\n"),
    }


@pytest.mark.parametrize("kind", list(_csv_readers()))
def test_a_cell_past_the_csv_field_limit_is_one_line_naming_the_file(kind, tmp_path):
    read, text = _csv_readers()[kind]
    f = tmp_path / f"{kind.replace(' ', '_')}.csv"
    f.write_text(text.format(big=BIG_CELL))
    with pytest.raises(InputError) as e:
        read(f)
    msg = str(e.value)
    assert "\n" not in msg and f.name in msg, msg
    assert len(msg) < 400


def test_the_command_line_says_it_in_one_line_and_exits_2(tmp_path):
    import subprocess
    import sys

    f = tmp_path / "lm.csv"
    f.write_text(f"vertex_id,u,v\n1,{BIG_CELL},3\n")
    r = subprocess.run([sys.executable, "-m", "facegeom", "fit", str(f), "--focal", "800", "--cx", "320", "--cy",
                        "240", "--no-identity", "-o", str(tmp_path / "w.json")], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "lm.csv" in r.stderr and "line 2" in r.stderr
    assert not Path(tmp_path / "w.json").exists()


# ----------------------------------------------------------------------------- geodesics on degenerate meshes
def _run(*args, timeout=120):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "facegeom", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def _one_line(r, *words):
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in lines[0], lines[0]


COINCIDENT = "v 0 0 0\nv 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\nf 2 3 4\n"  # 60 bytes: grew past 4 GB in exact geodesics


def test_crop_of_coincident_vertices_ends_at_once_with_one_line(tmp_path):
    import time

    f = tmp_path / "c.obj"
    f.write_text(COINCIDENT)
    t0 = time.monotonic()
    r = _run("crop", f, tmp_path / "o.obj", "--from-vertices", "0", "--radius", "5", timeout=60)
    assert time.monotonic() - t0 < 30
    _one_line(r, "no whole face")
    assert not (tmp_path / "o.obj").exists()


def test_exact_geodesics_skip_faces_without_area(tmp_path):
    import numpy as np

    from facegeom.geometry import geodesic_rings, walkable_faces
    from facegeom.pipelines.cleanup.geodesic import geodesic_distance

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [2, 0, 0]], float)  # vertex 3 on vertex 1; 4 on a line
    F = np.array([[0, 1, 2], [1, 3, 2], [0, 1, 4]])
    np.testing.assert_array_equal(walkable_faces(V, F), F[:1])
    d = geodesic_distance(V, F, [0], limit=5.0)
    np.testing.assert_allclose(d[:3], [0.0, 1.0, 1.0])
    assert np.isinf(d[3:]).all()  # only on faces without area: unreached
    R = geodesic_rings(V, F, 1.5)
    assert R[0, 1] and R[0, 2] and not R[0, 3]
    assert walkable_faces(np.zeros((4, 3)), F[:2]).shape == (0, 3)


def test_heat_geodesics_on_a_soup_or_a_degenerate_mesh_is_one_line(tmp_path):
    soup = tmp_path / "soup.obj"
    soup.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nv 6 5 5\nv 5 6 5\nf 1 2 3\nf 4 5 6\n")
    _one_line(_run("crop", soup, tmp_path / "o.obj", "--from-vertices", "0", "--radius", "1", "--geodesic", "heat"),
              "heat method")
    c = tmp_path / "c.obj"
    c.write_text(COINCIDENT)
    _one_line(_run("crop", c, tmp_path / "o.obj", "--from-vertices", "0", "--radius", "1", "--geodesic", "heat"),
              "no area")


def test_a_huge_vertex_id_is_out_of_range_not_an_overflow(tmp_path):
    f = tmp_path / "t.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    _one_line(_run("crop", f, tmp_path / "o.obj", "--from-vertices", "99999999999999999999", "--radius", "1"),
              "out of range", "t.obj")


def test_a_preset_the_readme_names_is_a_method_name():
    from facegeom.registry import available, create

    f = create("fitters", "sem+")
    assert f.clamp and f.stop == "ric"
    assert create("fitters", "sem+", stop="none").stop == "none"
    assert available("fitters")["sem+"] == "sem:clamp=true,stop=ric"


# ----------------------------------------------------------------------------- method parameters
def _numeric_parameters():
    import inspect

    from facegeom.registry import KINDS, available, get

    out = []
    for kind in KINDS:
        for name in available(kind):
            try:
                cls = get(kind, name)
            except Exception:  # an optional peer that is not installed
                continue
            for pn, par in inspect.signature(cls.__init__).parameters.items():
                d = par.default
                if pn != "self" and not isinstance(d, bool) and (isinstance(d, (int, float)) or d is None
                                                                or d == "auto"):
                    out.append((kind, name, pn))
    return out


NUMERIC = _numeric_parameters()
HUGE = (1e308, 10 ** 20)  # past every bound; 1e9 is allowed where it is harmless (a label weight)
#: parameters whose size is judged against the data (a mesh's edge length), when the method is fitted
CHECKED_AT_FIT = {("deformers", "tangent", "radius")}


@pytest.mark.parametrize("kind, name, param", NUMERIC, ids=["-".join(x) for x in NUMERIC])
def test_every_numeric_parameter_has_an_upper_bound_and_says_why(kind, name, param):
    """``-p rings=1e9``-style values are refused when the method is built, in one line naming the parameter; no
    other exception escapes for any extreme value."""
    from facegeom.registry import create

    for v in HUGE + (10 ** 9, float("nan"), float("-inf"), -1, -(10 ** 20), "banana", True):
        try:
            create(kind, name, **{param: v})
        except InputError as exc:
            msg = str(exc)
            assert "\n" not in msg and param in msg, msg
            continue
        except ImportError:
            pytest.skip(f"{name} is not installed")
        if v in HUGE and (kind, name, param) not in CHECKED_AT_FIT:
            pytest.fail(f"{kind} {name}: {param}={v!r} was accepted")


def test_a_radius_of_many_edges_is_refused_when_the_deformer_is_fitted():
    import numpy as np

    from facegeom.registry import create

    n = 6
    xs, ys = np.meshgrid(np.arange(n), np.arange(n))
    V = np.c_[xs.ravel(), ys.ravel(), np.zeros(n * n)].astype(float)
    F = np.array([(i * n + j, i * n + j + 1, (i + 1) * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
                 + [(i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j) for i in range(n - 1) for j in range(n - 1)])
    with pytest.raises(InputError, match="mean edge lengths"):
        create("deformers", "tangent", neighbourhood="geodesic", radius=1e9).fit(V, F, np.array([0, 5, 30, 35]))


def test_a_ridge_of_zero_is_plain_least_squares_even_with_labels_in_a_plane():
    """``ridge=0`` with the labels' motion in a plane: the least-norm affine map, not a singular-matrix traceback."""
    import numpy as np

    from facegeom.registry import create

    rng = np.random.default_rng(0)
    T, p = 40, 8
    src = rng.normal(size=(1, p, 3)) + 0.05 * rng.normal(size=(T, p, 3))
    lab = np.array([0, 10, 20, 30])
    out = create("retargeters", "tangent", ridge=0).fit(src, lab, src[lab] * 1.3).transform()
    assert out.shape == (T, p, 3) and np.isfinite(out).all()


# ----------------------------------------------------------------------------- no silent wrong results
def test_fit_refuses_an_obj_cut_inside_a_face_line_as_other_commands_do(tmp_path):
    f = tmp_path / "cut.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4")  # the last face line cut short
    _one_line(_run("fit", f, "-o", tmp_path / "w.json"), "cut.obj", "line 6")
    assert not (tmp_path / "w.json").exists()


def test_an_npz_capture_without_marker_names_is_not_taken_for_vertices(tmp_path, face_model):
    import numpy as np

    from facegeom.methods.sem import SEMLSFitter
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import layout
    from facegeom.pipelines.solve import solve_file

    rig = BlendshapeRig.from_face_model(face_model)
    ids = layout(face_model, "ict80")
    P = np.repeat(rig.neutral[ids][None], 3, axis=0)
    np.savez(tmp_path / "cap.npz", markers=P)
    with pytest.raises(InputError, match="names no markers") as e:
        solve_file(tmp_path / "cap.npz", rig, SEMLSFitter())
    assert "cap.npz" in str(e.value)
    solved = solve_file(tmp_path / "cap.npz", rig, SEMLSFitter(), markers="ict80")  # a layout: file order
    assert np.abs(solved.solve.weights).max() < 0.05


@pytest.mark.parametrize("rows, words", [
    ("vertex_id,u,v\n1,100,100\n2,5400,120\n3,130,160\n4,110,190\n", "far outside the 640 x 480 photo"),
    ("vertex_id,u,v\n1,100,100\n2,120,120\n3,140,140\n4,160,160\n", "on one line"),
    ("vertex_id,u,v\n1,100,100\n2,1e308,120\n3,140,140\n4,160,190\n", "far outside"),
])
def test_photo_landmarks_no_photo_has_are_refused(tmp_path, rows, words):
    f = tmp_path / "lm.csv"
    f.write_text(rows)
    for cmd in (["fit", f, "--no-identity"], ["fit", f, "--identity"]):
        r = _run(*cmd, "--focal", "800", "--cx", "320", "--cy", "240", "-o", tmp_path / "w.json")
        _one_line(r, words, "lm.csv")
    assert not (tmp_path / "w.json").exists()


@pytest.mark.parametrize("how, words, suffix", [
    ("huge", "face sizes from the origin", ".csv"),
    ("point", "all at one point", ".csv"),
    ("scale", "times the face's size apart", ".csv"),
    ("point", "all at one point", ".c3d"),
    ("scale30", "face sizes from the origin", ".c3d"),
])
def test_a_capture_no_face_has_is_refused_before_the_solve(tmp_path, face_model, how, words, suffix):
    import time

    import numpy as np

    from facegeom.io import write_marker_sequence
    from facegeom.model import BlendshapeRig
    from facegeom.model.layouts import layout

    rig = BlendshapeRig.from_face_model(face_model)
    ids = layout(face_model, "ict80")
    P = np.repeat(rig.neutral[ids][None], 4, axis=0)
    if how == "huge":
        P[2, 5, 1] = 1e308
    elif how == "point":
        P[1] = 3.0
    elif how == "scale30":  # a C3D frame 1e30 times the face about its centre (float32 holds it)
        P[3] = P[3].mean(axis=0) + 1e30 * (P[3] - P[3].mean(axis=0))
    else:  # a frame blown up 20,000 times about its centre (the 1e30 of the report is also far from the origin)
        P[3] = P[3].mean(axis=0) + 2e4 * (P[3] - P[3].mean(axis=0))
    names = [f"v{i}" for i in ids]
    if suffix == ".c3d":
        from facegeom.io.c3d import write_c3d

        write_c3d(tmp_path / "cap.c3d", P, names, 60.0, unit="cm")
    else:
        write_marker_sequence(tmp_path / "cap.csv", P, names=names)
    t0 = time.monotonic()
    _one_line(_run("solve", tmp_path / f"cap{suffix}", "-o", tmp_path / "c.npz"), words, f"cap{suffix}")
    assert time.monotonic() - t0 < 60 and not (tmp_path / "c.npz").exists()


# ----------------------------------------------------------------------------- npz: declared against held
def _forged_npz(path, declared=(50_000, 10_000, 3), extra=None):
    """An npz whose 'deltas' header declares 12 GB and whose data is 80 bytes (the file is a few hundred bytes)."""
    import io
    import zipfile

    import numpy as np

    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, arr in (extra or {}).items():
            buf = io.BytesIO()
            np.save(buf, arr)
            zf.writestr(name + ".npy", buf.getvalue())
        buf = io.BytesIO()
        np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": declared})
        buf.write(b"\0" * 80)
        zf.writestr("deltas.npy", buf.getvalue())


def test_a_rig_npz_declaring_more_than_it_holds_is_refused_before_allocating(tmp_path):
    import numpy as np

    from facegeom.model import BlendshapeRig

    f = tmp_path / "rig.npz"
    _forged_npz(f, extra={"neutral": np.zeros((4, 3)), "names": np.array(["a"]), "triangles": np.zeros((1, 3), int),
                          "landmark_ids": np.zeros(0, int)})
    with pytest.raises(InputError, match=r"array 'deltas' declares shape \(50000, 10000, 3\) \(12.0 GB\) but holds"):
        BlendshapeRig.from_npz(f)
    _one_line(_run("fit", "--rig", f, tmp_path / "x.csv", "-o", tmp_path / "w.json"), "rig.npz", "declares shape")


def test_npz_captures_curves_and_index_maps_check_their_headers_too(tmp_path):
    import numpy as np

    from facegeom.io import read_marker_sequence
    from facegeom.io.npzcheck import check_npz
    from facegeom.pipelines.cleanup.indexmap import IndexMap

    f = tmp_path / "cap.npz"
    _forged_npz(f)
    for read in (read_marker_sequence, IndexMap.load):
        with pytest.raises(InputError, match="declares shape"):
            read(f)
    obj = tmp_path / "obj.npz"
    np.savez(obj, markers=np.array([object(), 1], dtype=object))
    with pytest.raises(InputError, match="Python objects"):
        check_npz(obj)
    ok = tmp_path / "ok.npz"
    np.savez_compressed(ok, markers=np.zeros((5, 4, 3)))
    assert check_npz(ok) == 5 * 4 * 3 * 8
    with pytest.raises(InputError, match="more than this machine can spare"):
        check_npz(ok, budget=100)


# ----------------------------------------------------------------------------- .glb animations
def test_a_glb_accessor_without_data_cannot_ask_for_gigabytes(tmp_path):
    import json
    import struct

    from facegeom.io.gltf import read_glb_animation

    doc = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
           "accessors": [{"componentType": 5126, "count": 100_000_000, "type": "VEC3"}]}
    j = json.dumps(doc).encode()
    j += b" " * (-len(j) % 4)
    f = tmp_path / "bomb.glb"
    f.write_bytes(b"glTF" + struct.pack("<II", 2, 20 + len(j)) + struct.pack("<II", len(j), 0x4E4F534A) + j)
    with pytest.raises(InputError, match="more than a file of this size can describe"):
        read_glb_animation(f)


def test_playing_a_glb_rig_without_an_animation_says_so(tmp_path):
    import numpy as np
    import pygltflib

    from facegeom.io.gltf import write_rig_glb
    from facegeom.pipelines.solve import read_animation

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    D = np.zeros((2, 4, 3))
    D[0, 3, 2] = 0.5
    write_rig_glb(tmp_path / "a.glb", V, np.array([[0, 1, 2], [1, 3, 2]]), D, ["a", "b"], np.full((3, 2), 0.5), 30.0)
    g = pygltflib.GLTF2().load(str(tmp_path / "a.glb"))
    g.animations = []
    g.save(str(tmp_path / "still.glb"))
    with pytest.raises(InputError, match="no weights animation to play") as e:
        read_animation(tmp_path / "still.glb")
    assert "still.glb" in str(e.value)


def test_all_methods_into_an_existing_file_is_one_line_exit_2(tmp_path):
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\nf 1 2 3\nf 2 4 3\n")
    markers = tmp_path / "mk.csv"
    markers.write_text("vertex_id,x,y,z\n0,0,0,0\n1,1,0,0\n2,0,1,0\n")
    (tmp_path / "afile").write_text("keep me")
    _one_line(_run("drive", mesh, markers, "-m", "all", "-o", tmp_path / "afile"), "afile", "is a file")
    assert (tmp_path / "afile").read_text() == "keep me"


def test_a_mesh_vertex_at_1e308_is_refused_by_every_mesh_command(tmp_path):
    f = tmp_path / "far.obj"
    f.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e308 1 1\nf 1 2 3\nf 2 4 3\n")
    for args in (["clean", f, tmp_path / "o.obj", "--merge-tol", "1%"], ["decimate", f, tmp_path / "o.obj",
                                                                         "--vertices", "4"],
                 ["crop", f, tmp_path / "o.obj", "--id-range", "0:3"]):
        _one_line(_run(*args), "far.obj", "vertex 4 has a coordinate of 1e+308")
    assert not (tmp_path / "o.obj").exists()


def test_a_rig_shape_at_1e308_is_refused_like_a_mesh(tmp_path):
    from facegeom.errors import InputError
    from facegeom.model.inputs import load_rig

    rig = tmp_path / "rig"
    rig.mkdir()
    (rig / "neutral.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (rig / "jawOpen.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1e308 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="a coordinate of 1e\\+308") as e:
        load_rig(rig)
    assert "jawOpen.obj" in str(e.value) and len(str(e.value).splitlines()) == 1


def test_image_size_follows_the_exif_orientation_and_ignores_the_bomb_guard(tmp_path):
    import warnings

    from PIL import Image

    from facegeom.io.fitfiles import image_size

    im = Image.new("RGB", (64, 48))
    exif = Image.Exif()
    exif[0x0112] = 6  # shown turned by 90 degrees: a phone held upright
    im.save(tmp_path / "portrait.jpg", exif=exif)
    im.save(tmp_path / "plain.jpg")
    assert image_size(tmp_path / "portrait.jpg") == (48, 64)
    assert image_size(tmp_path / "plain.jpg") == (64, 48)
    big = tmp_path / "big.png"
    Image.new("1", (12_000, 9_000)).save(big)  # 108 megapixels, a small file
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert image_size(big) == (12_000, 9_000)
    assert Image.MAX_IMAGE_PIXELS is not None  # the guard is back for whoever decodes pixels


# ----------------------------------------------------------------------------- C3D: what the file says against what it holds
def _c3d(path, T=4, fps=100.0):
    import numpy as np

    from facegeom.io.c3d import write_c3d

    P = np.random.default_rng(0).normal(size=(T, 3, 3)) * 10 + 100
    write_c3d(path, P, ["a", "b", "c"], fps)
    return path


def test_a_c3d_whose_data_block_points_into_its_parameters_is_refused(tmp_path):
    import struct

    from facegeom.io.c3d import read_c3d

    f = _c3d(tmp_path / "a.c3d")
    b = bytearray(f.read_bytes())
    b[16:18] = struct.pack("<H", b[0])  # the data section now starts at the parameter section's first block
    f.write_bytes(bytes(b))
    with pytest.raises(InputError, match="starts inside the parameter section"):
        read_c3d(f)


def test_a_c3d_longer_than_its_16_bit_frame_count_says_so(tmp_path):
    from facegeom.io.c3d import read_c3d

    f = _c3d(tmp_path / "long.c3d", T=65_535, fps=200.0)
    f.write_bytes(f.read_bytes() + b"\0" * (3 * 16 * 100))  # 100 frames more than the header can count
    with pytest.raises(InputError, match=r"16-bit limit, but the data holds 65,63\d"):
        read_c3d(f)


def test_a_c3d_frame_rate_no_capture_has_is_refused(tmp_path):
    from facegeom.io.c3d import read_c3d

    with pytest.raises(InputError, match="POINT:RATE is 1e"):
        read_c3d(_c3d(tmp_path / "fast.c3d", fps=1e38))


@pytest.mark.skipif(not hasattr(__import__("os"), "geteuid") or __import__("os").geteuid() == 0,
                    reason="root writes into read-only folders")
def test_a_rig_folder_in_a_read_only_folder_is_named_not_its_hidden_temporary(tmp_path, face_model):
    import os

    from facegeom.cli.identity import write_rig
    from facegeom.model import BlendshapeRig

    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, 0o555)
    try:
        with pytest.raises(InputError) as e:
            write_rig(BlendshapeRig.from_face_model(face_model), ro / "rig")
    finally:
        os.chmod(ro, 0o755)
    assert "ro/rig" in str(e.value) and "/." not in str(e.value) and not list(ro.iterdir())


def test_a_rig_folder_that_cannot_be_made_is_named_not_its_hidden_temporary(tmp_path, face_model, monkeypatch):
    import tempfile

    from facegeom.cli.identity import write_rig
    from facegeom.model import BlendshapeRig

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkdtemp", refuse)
    with pytest.raises(InputError, match="cannot create the rig folder") as e:
        write_rig(BlendshapeRig.from_face_model(face_model), tmp_path / "rig")
    assert str(e.value).startswith(str(tmp_path / "rig") + ":")


def test_a_batch_output_through_dot_dot_makes_no_folder_on_the_way(tmp_path):
    from facegeom.pipelines.batch.job import job_from_dict

    j = job_from_dict({"operation": "fit", "inputs": "in/*.csv", "output": "o7/../o7b",
                       "shared": {"focal": 800.0, "cx": 320.0, "cy": 240.0}}, base=tmp_path, source="job.toml")
    assert j.output == tmp_path / "o7b"


def test_a_display_without_a_server_is_one_line_and_nothing_after_it(tmp_path):
    import os
    import subprocess
    import sys

    env = {**os.environ, "DISPLAY": ":99", "WAYLAND_DISPLAY": ""}
    r = subprocess.run([sys.executable, "-m", "facegeom", "view", "drive"], capture_output=True, text=True, env=env,
                       timeout=120, cwd=tmp_path)
    if r.returncode == 0:
        pytest.skip("a display answered on :99")
    _one_line(r, "could not start a renderer")


def test_a_ply_of_triangle_strips_is_read_as_triangles(tmp_path):
    """Scanners' and old Stanford PLYs (igea.ply) hold a ``tristrips`` element, -1 restarting a strip."""
    import numpy as np

    from facegeom.io import read_mesh

    V = [(x, y, 0.0) for y in range(3) for x in range(3)]
    strips = [0, 3, 1, 4, 2, 5, -1, 3, 6, 4, 7, 5, 8]
    head = ("ply\nformat ascii 1.0\nelement vertex 9\nproperty float x\nproperty float y\nproperty float z\n"
            "element tristrips 1\nproperty list int int vertex_indices\nend_header\n")
    f = tmp_path / "strips.ply"
    f.write_text(head + "".join(f"{x} {y} {z}\n" for x, y, z in V) + f"{len(strips)} "
                 + " ".join(map(str, strips)) + "\n")
    V2, F = read_mesh(f)
    assert F.shape == (8, 3)
    n = np.cross(V2[F[:, 1]] - V2[F[:, 0]], V2[F[:, 2]] - V2[F[:, 0]])[:, 2]
    assert (np.sign(n) == np.sign(n[0])).all()  # one winding across both strips
    assert sorted(map(tuple, np.sort(F, axis=1))) == sorted({tuple(sorted(t)) for t in map(tuple, F)})
    f.write_text(head + "".join(f"{x} {y} {z}\n" for x, y, z in V) + "4 0 3 1 -7\n")
    with pytest.raises(InputError, match="negative index other than -1"):
        read_mesh(f)


def test_decimating_a_fan_around_one_vertex_is_refused_at_once(tmp_path):
    import time

    import numpy as np

    n = 100_000
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    V = np.r_[[[0.0, 0.0, 0.0]], np.c_[np.cos(t), np.sin(t), np.zeros(n)]]
    F = np.c_[np.zeros(n, int), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n]
    f = tmp_path / "fan.obj"
    with open(f, "w") as fh:
        np.savetxt(fh, V, fmt="v %.6f %.6f %.6f")
        np.savetxt(fh, F + 1, fmt="f %d %d %d")
    t0 = time.monotonic()
    _one_line(_run("decimate", f, tmp_path / "o.obj", "--vertices", "100"), "fan.obj", "corner of 100,000 faces")
    assert time.monotonic() - t0 < 60
