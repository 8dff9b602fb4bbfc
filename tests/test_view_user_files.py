"""``facegeom view drive MESH MARKERS`` and ``facegeom view fit --target FILE`` on the user's own files.

What the viewer shows must be what the commands the user runs compute: the driven faces are compared with what
``facegeom drive MESH MARKERS -o OUT`` writes, the fitted weights with what ``facegeom fit TARGET -o OUT.json``
writes, the viewer's defaults with those commands' defaults. The views are rendered headless (EGL), in this
process, through the command line (``facegeom.cli.main.main``) with the view class spied on to read its results.
"""
import json

import numpy as np
import pytest

ps = pytest.importorskip("polyscope")

from tests.conftest import assert_not_blank, read_png


def run(args, capsys):
    """Run the CLI in this process -> (exit code, stdout, stderr)."""
    from facegeom.cli.main import main

    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def run_quiet(args):
    """Run the CLI in this process, its output left to pytest; fails on a non-zero exit."""
    from facegeom.cli.main import main

    try:
        main([str(a) for a in args])
    except SystemExit as e:  # pragma: no cover - a failure
        assert e.code == 0, args


@pytest.fixture(scope="module")
def files(face_model, tmp_path_factory):
    """A person's face (face.obj), 80 markers moved to a smile (markers.csv, the ict80 layout), the smile itself
    (target.obj), as ``facegeom data examples`` makes them; and what ``facegeom drive face.obj markers.csv -o
    driven.ply`` and ``facegeom fit target.obj -o fit.json`` wrote."""
    from facegeom.io import write_markers, write_mesh
    from facegeom.model import layout, named_expression

    d = tmp_path_factory.mktemp("user-files")
    rng = np.random.default_rng(7)
    identity = face_model.random_identity(rng)
    X = face_model.identity_neutral(identity)
    T = face_model.face(identity, named_expression("happiness", 0.9))
    ids = layout(face_model, "ict80", 0)
    write_mesh(d / "face.obj", X, face_model.triangles)
    write_mesh(d / "target.obj", T, face_model.triangles)
    write_markers(d / "markers.csv", ids, T[ids])
    run_quiet(["drive", d / "face.obj", d / "markers.csv", "-o", d / "driven.ply"])
    run_quiet(["fit", d / "target.obj", "-o", d / "fit.json"])
    return d


def spy(monkeypatch, module, name):
    """Replace ``module.name`` (a view class) by a subclass that records every instance made -> that list."""
    made = []
    cls = getattr(module, name)

    class Spy(cls):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(module, name, Spy)
    return made


# --------------------------------------------------------------------------- view drive MESH MARKERS


def test_view_drive_shows_what_facegeom_drive_writes(files, headless, tmp_path, capsys, monkeypatch):
    import facegeom.viewer.drive as vd
    from facegeom.cli.view import _cli_default
    from facegeom.io import read_mesh

    made = spy(monkeypatch, vd, "DriveView")
    shot = tmp_path / "mine.png"
    code, out, err = run(["view", "drive", files / "face.obj", files / "markers.csv", "--size", "900x500",
                          "--screenshot", shot], capsys)
    assert code == 0, err
    assert f"wrote {shot}" in out
    img = read_png(shot)
    assert img.shape == (500, 900, 3)
    assert_not_blank(img)
    v = made[0]
    assert v.selected[0] == _cli_default("drive", "method") == "tangent"  # `facegeom drive`'s default first
    assert v.copies() == ["source", *v.selected]  # no true target for the user's files
    written, F = read_mesh(files / "driven.ply")
    np.testing.assert_array_equal(v.results["tangent"], written)  # the very vertices `facegeom drive` wrote
    np.testing.assert_array_equal(v.triangles, F)
    assert v.case.unit_mm == 10.0 and "unit: cm" in v.case.description  # found from the mesh's size
    e = v.errors("tangent")
    assert e["moved_max_mm"] > 5.0 and np.isfinite(e["at_markers_max_mm"])


def test_view_drive_files_markers_are_draggable(files, scene):
    from facegeom.viewer.drive import DriveView, read_drive_files

    v = DriveView(None, "rbf;tangent", case=read_drive_files(files / "face.obj", files / "markers.csv"))
    v.setup_scene(1000, 600, headless=True)
    ps.frame_tick()
    assert v.tangent_beta == "auto"  # tangent as `facegeom drive` builds it, not the built-in view's hard fit
    v.ui.set("marker", 57)
    v.ui.set("dy (mm)", -6.0)
    ps.frame_tick()
    np.testing.assert_allclose(v.offsets[57], [0.0, -0.6, 0.0])  # cm: the mesh's unit
    np.testing.assert_allclose(v.results["rbf"][v.case.handles[57]], v.positions()[57], atol=1e-6)
    s = v.world_to_screen(v.positions()[10] + v.shifts["rbf"])
    assert v.begin_drag(s) and v.marker == 10
    v.end_drag(s + [20.0, 0.0])
    assert v.offsets[10][0] > 0.3 and v.drags == 1
    assert v.state()["offsets_mm"][57][1] == pytest.approx(-6.0)


def test_view_drive_mm_mesh_speaks_mm(files, tmp_path):
    """A mesh in mm: its unit is found from its size, nudges and colours stay in mm."""
    from facegeom.io import read_markers, read_mesh, write_markers, write_mesh
    from facegeom.viewer.drive import DriveView, read_drive_files

    V, F = read_mesh(files / "face.obj")
    ids, pos = read_markers(files / "markers.csv")
    write_mesh(tmp_path / "mm.ply", V * 10.0, F)
    write_markers(tmp_path / "mm.csv", ids, pos * 10.0)
    case = read_drive_files(tmp_path / "mm.ply", tmp_path / "mm.csv")
    assert case.unit_mm == 1.0 and "unit: mm" in case.description
    v = DriveView(None, "rbf", case=case)
    v.nudge(3, [0.0, 2.0, 0.0])
    np.testing.assert_allclose(v.offsets[3], [0.0, 2.0, 0.0])


def test_window_workers_give_the_same_faces_and_weights(files, face_model):
    """In a window the methods run in worker processes (built from picklable specs): the same results."""
    from facegeom.io import read_mesh
    from facegeom.viewer.drive import DriveView, read_drive_files
    from facegeom.viewer.fit import FitView

    bg = DriveView(None, "tangent", case=read_drive_files(files / "face.obj", files / "markers.csv"),
                   background=True)
    fb = FitView(face_model, "sem-ls", target=files / "target.obj", background=True)
    try:
        bg.wait()
        fb.wait()
        assert bg.status == {"tangent": "ready"}, bg.failed
        np.testing.assert_array_equal(bg.results["tangent"], read_mesh(files / "driven.ply")[0])
        fitted = json.loads((files / "fit.json").read_text())["weights"]
        w = fb.results["sem-ls"].weights
        np.testing.assert_allclose(w, [fitted[n] for n in fb.case.rig.names], rtol=0, atol=1e-12)
    finally:
        bg.close()
        fb.close()


def _bad_files(d):
    (d / "garbage.obj").write_text("v 1 2\nf 1 2 3\n")
    (d / "far.csv").write_text("vertex_id,x,y,z\n0,0,0,0\n999999,1,2,3\n")
    (d / "twice.csv").write_text("vertex_id,x,y,z\n5,0,0,0\n5,1,2,3\n")
    (d / "header.csv").write_text("id,x,y,z\n5,0,0,0\n")
    (d / "face.txt").write_text("not a mesh\n")


FILE_ERRORS = {  # the files given -> what the line names
    "missing mesh": (["nope.obj", "{markers}"], "nope.obj: file not found"),
    "unreadable mesh": (["garbage.obj", "{markers}"], "garbage.obj:"),
    "not a mesh format": (["face.txt", "{markers}"], "face.txt: unsupported mesh format"),
    "missing markers": (["{mesh}", "nope.csv"], "nope.csv:"),
    "marker past the mesh": (["{mesh}", "far.csv"], "far.csv:"),
    "marker twice": (["{mesh}", "twice.csv"], "twice.csv:"),
    "marker header": (["{mesh}", "header.csv"], "header.csv: wrong columns"),
}


@pytest.mark.parametrize("case", list(FILE_ERRORS))
def test_view_drive_file_errors_are_facegeom_drives(case, files, tmp_path, capsys, monkeypatch):
    """Unreadable files and markers that do not fit the mesh: one line naming the file, word for word what
    `facegeom drive` says; nothing fitted or rendered."""
    import facegeom.viewer.drive as vd

    monkeypatch.setattr(vd, "DriveView", lambda *a, **k: pytest.fail("viewed anyway"))
    monkeypatch.chdir(tmp_path)
    _bad_files(tmp_path)
    given, named = FILE_ERRORS[case]
    args = [a.format(mesh=files / "face.obj", markers=files / "markers.csv") for a in given]
    code, out, err = run(["view", "drive", *args, "--screenshot", tmp_path / "x.png"], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith("facegeom: error: ") and named in err and "Traceback" not in err
    code, _, drive_err = run(["drive", *args, "-o", tmp_path / "out.ply"], capsys)
    assert code == 2 and drive_err == err  # the same readers, the same checks, the same words
    assert not (tmp_path / "x.png").exists()


USAGE_ERRORS = {
    "only the mesh": (["{mesh}"], ["face.obj", "MARKERS is missing"]),
    "only the markers": (["{markers}"], ["markers.csv", "MESH is missing"]),
    "files with --bench-case": (["{mesh}", "{markers}", "--bench-case", "2"],
                                ["--bench-case picks a built-in case", "face.obj", "markers.csv"]),
    "files with --seed": (["{mesh}", "{markers}", "--seed", "3"], ["--seed picks a built-in case"]),
    "files with --layout": (["{mesh}", "{markers}", "--layout", "landmarks68"], ["--layout picks a built-in"]),
    "--proxy without files": (["--proxy", "off"], ["--proxy goes with MESH MARKERS"]),
    "files with a bad --proxy": (["{mesh}", "{markers}", "--proxy", "12"], ["proxy vertex count 12"]),
    "--marker past the file's": (["{mesh}", "{markers}", "--marker", "80"], ["markers.csv", "--marker 80",
                                                                             "80 markers"]),
}


@pytest.mark.parametrize("case", list(USAGE_ERRORS))
def test_view_drive_usage_errors_are_one_line(case, files, tmp_path, capsys, monkeypatch):
    import facegeom.viewer.drive as vd

    monkeypatch.setattr(vd, "DriveView", lambda *a, **k: pytest.fail("viewed anyway"))
    given, named = USAGE_ERRORS[case]
    args = [a.format(mesh=files / "face.obj", markers=files / "markers.csv") for a in given]
    code, out, err = run(["view", "drive", *args, "--screenshot", tmp_path / "x.png"], capsys)
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith("facegeom: error: ") and "Traceback" not in err
    for word in named:
        assert word in err, (word, err)


# --------------------------------------------------------------------------- view fit --target


def test_view_fit_target_default_is_what_facegeom_fit_writes(files, face_model, headless, tmp_path, capsys,
                                                              monkeypatch):
    import facegeom.viewer.fit as vf
    from facegeom import registry
    from facegeom.cli.view import _cli_default
    from facegeom.model import load_rig
    from facegeom.pipelines.single import fit_file

    made = spy(monkeypatch, vf, "FitView")
    shot = tmp_path / "fit.png"
    code, out, err = run(["view", "fit", "--target", files / "target.obj", "--size", "900x500", "--screenshot",
                          shot], capsys)
    assert code == 0, err
    assert f"wrote {shot}" in out
    assert_not_blank(read_png(shot))
    v = made[0]
    default = _cli_default("fit", "method")
    assert v.selected == [default] == ["sem-ls"]
    w = v.results[default].weights
    # the function `facegeom fit` runs, on the rig it loads: the very same numbers
    rig = load_rig(None, lambda: face_model)
    r = fit_file(rig, files / "target.obj", lambda: registry.create("fitters", default), "auto")
    np.testing.assert_array_equal(w, r.weights)
    np.testing.assert_array_equal(v.face(default), r.vertices)
    # ... and the file it wrote (JSON floats round-trip exactly)
    fitted = json.loads((files / "fit.json").read_text())
    assert fitted["method"] == default
    np.testing.assert_allclose(w, [fitted["weights"][n] for n in rig.names], rtol=0, atol=1e-12)
    assert w.min() >= 0.0 and w.max() <= 1.0 and v.out_of_box() == []  # `facegeom fit` keeps the box


def test_view_fit_target_off_frame_in_mm_is_fitted_as_facegeom_fit_does(files, face_model, scene, tmp_path):
    """A mesh in mm, turned and moved off the rig's frame: read (scaled) and aligned as `facegeom fit` does it;
    the fitted face is drawn where the target is; fitters without the [0, 1] box are flagged."""
    from scipy.spatial.transform import Rotation

    from facegeom import registry
    from facegeom.io import read_mesh, write_mesh
    from facegeom.model import load_rig
    from facegeom.pipelines.single import fit_file
    from facegeom.viewer.fit import FitView, out_of_box

    T, F = read_mesh(files / "target.obj")
    R = Rotation.from_euler("xyz", [20, -35, 10], degrees=True).as_matrix()
    moved = tmp_path / "turned_mm.obj"
    write_mesh(moved, (T @ R.T + [3.0, -2.0, 5.0]) * 10.0, F)
    v = FitView(face_model, "sem-ls;pcadel", target=moved)
    assert any("0.1" in n for n in v.case.notes)  # the unit factor, as `facegeom fit` prints it
    rig = load_rig(None, lambda: face_model)
    r = fit_file(rig, moved, lambda: registry.create("fitters", "sem-ls"), "auto")
    np.testing.assert_array_equal(v.results["sem-ls"].weights, r.weights)
    assert v.results["sem-ls"].info["alignment"] is not None
    err_mm = np.linalg.norm(v.face("sem-ls") - v.case.truth, axis=1).mean() * 10.0
    assert err_mm < 5.0  # drawn on the target, not where the rig is
    assert "sem-ls" not in v.out_of_box()
    assert v.out_of_box() == [x for x in v.shown() if out_of_box(v.results[x].weights)]
    v.setup_scene(1000, 600, headless=True)
    for _ in range(2):  # the panel with its flags draws
        ps.frame_tick()
    assert out_of_box([0.0, 1.0]) is False and out_of_box([0.2, 1.48]) and out_of_box([-0.5, 0.3])


def test_view_fit_target_errors_are_one_line(files, tmp_path, capsys, monkeypatch):
    import facegeom.viewer.fit as vf
    from facegeom.io import write_mesh

    monkeypatch.setattr(vf.FitView, "fit_method", lambda *a, **k: pytest.fail("fitted anyway"))
    V = np.random.default_rng(0).normal(size=(30, 3))
    write_mesh(tmp_path / "small.obj", V, np.array([[0, 1, 2]]))
    for args, words in ((["--target", files / "target.obj", "--case", "3"], ["--case picks a built-in target"]),
                        (["--target", files / "target.obj", "--kind", "mesh"], ["--kind picks a built-in target"]),
                        (["--target", tmp_path / "small.obj"], ["small.obj", "30 vertices", "correspondence"]),
                        (["--target", tmp_path / "none.obj"], ["none.obj: file not found"])):
        code, out, err = run(["view", "fit", *args, "--screenshot", tmp_path / "x.png"], capsys)
        assert code == 2 and out == "" and err.count("\n") == 1, err
        assert "Traceback" not in err and all(w in err for w in words), (words, err)


# --------------------------------------------------------------------------- help


def test_help_names_the_files_and_the_defaults(capsys):
    from facegeom.cli.view import _cli_default

    code, out, _ = run(["view", "drive", "--help"], capsys)
    text = " ".join(out.split())
    assert code == 0 and "[MESH] [MARKERS]" in text
    assert "facegeom drive MESH MARKERS -o OUT" in text and "vertex_id,x,y,z" in text
    assert f"with MESH MARKERS {_cli_default('drive', 'method')};" in text and "rbf;biharmonic;tangent" in text
    code, out, _ = run(["view", "fit", "--help"], capsys)
    text = " ".join(out.split())
    assert code == 0 and f"with --target: `facegeom fit`'s default, {_cli_default('fit', 'method')}" in text
