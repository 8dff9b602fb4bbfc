"""Outputs are never lost, damaged or partial (issue 16): through the command line, on small synthetic inputs.

* modes: a new output gets ``0o666 & ~umask`` (as ``open()``), a replaced one keeps its mode;
* a symbolic-link output is written through (the link stays), a hard link is detached (documented);
* an output that is an input (also through a symbolic or hard link) or another output is refused,
  naming both paths, and the input is untouched;
* a failure while writing leaves nothing behind (``fit --mesh-out``, ``drive -m all``,
  ``animate --obj-dir``, ``clean``) and errors name the output, never a temporary file;
* ``view --screenshot`` into a place that cannot be written fails before rendering, and a
  screenshot that did not come out is an error.
"""
from __future__ import annotations

import contextlib
import os
import stat

import numpy as np
import pytest

from facegeom.cli.main import main
from facegeom.io import atomic_path, write_marker_sequence, write_markers, write_mesh

from .conftest import grid_mesh

# --------------------------------------------------------------------------- helpers


def run_main(args, capsys):
    """Run the CLI in-process: (exit code, stdout, stderr)."""
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


@contextlib.contextmanager
def umask(mask: int):
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def listing(folder) -> list[str]:
    """Every file below ``folder`` (hidden temporaries included), relative, sorted."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture
def files(tmp_path):
    """A bumped 6x6 grid, its markers, a 3-shape rig folder, a mesh target, marker sequences."""
    V, F = grid_mesh(6, 6, bump=0.1)
    write_mesh(tmp_path / "grid.obj", V, F)
    H = np.array([0, 5, 14, 30, 35])
    write_markers(tmp_path / "markers.csv", H, V[H] + [0, 0, 0.05])
    rig = tmp_path / "rig"
    rig.mkdir()
    write_mesh(rig / "neutral.obj", V, F)
    write_mesh(rig / "up.obj", V + [0, 0, 0.1], F)
    write_mesh(rig / "side.obj", V + [0.05, 0, 0], F)
    write_mesh(tmp_path / "target.obj", V + [0, 0, 0.05], F)
    rng = np.random.default_rng(0)
    P = rng.normal(size=(8, 4, 3))
    write_marker_sequence(tmp_path / "source.npz", P)
    write_marker_sequence(tmp_path / "labels.csv", P[[0, 4, 7]] * 1.5, frames=[0, 4, 7])
    return tmp_path


def clean_args(d, out="out.obj", *extra):
    return ["clean", d / "grid.obj", d / out, "--markers", d / "markers.csv", *extra]


# --------------------------------------------------------------------------- modes, links


@pytest.mark.parametrize("mask, expected", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_new_outputs_get_the_mode_open_would_give(files, capsys, mask, expected):
    d = files
    with umask(mask):
        code, _, err = run_main(clean_args(d, "out.obj", "--markers-out", d / "m2.csv", "--map", d / "map.csv",
                                           "--report", d / "r.json"), capsys)
        assert code == 0, err
        code, _, err = run_main(["drive", d / "grid.obj", d / "markers.csv", "-o", d / "driven.ply"], capsys)
        assert code == 0, err
        code, _, err = run_main(["fit", d / "target.obj", "--rig", d / "rig", "-o", d / "w.csv",
                                 "--mesh-out", d / "fitted.off"], capsys)
        assert code == 0, err
        code, _, err = run_main(["retarget", d / "source.npz", d / "labels.csv", "-o", d / "ret.npz"], capsys)
        assert code == 0, err
    for name in ("out.obj", "m2.csv", "map.csv", "r.json", "driven.ply", "w.csv", "fitted.off", "ret.npz"):
        assert mode(d / name) == expected, name


def test_replacing_keeps_the_mode_and_writes_through_a_symlink(files, capsys):
    d = files
    (d / "out.obj").write_text("old\n")
    os.chmod(d / "out.obj", 0o640)
    real = d / "real"
    real.mkdir()
    (real / "target.obj").write_text("old\n")
    os.chmod(real / "target.obj", 0o604)
    os.symlink(real / "target.obj", d / "link.obj")
    with umask(0o077):
        assert run_main(clean_args(d, "out.obj"), capsys)[0] == 0
        assert run_main(clean_args(d, "link.obj"), capsys)[0] == 0
    assert mode(d / "out.obj") == 0o640 and (d / "out.obj").read_text() != "old\n"
    assert os.path.islink(d / "link.obj") and os.readlink(d / "link.obj") == str(real / "target.obj")
    assert (real / "target.obj").read_text().startswith(("#", "v")) and mode(real / "target.obj") == 0o604
    assert listing(real) == ["target.obj"]  # no temporary left next to the target


def test_hard_link_is_detached_not_rewritten(files, capsys):
    """Documented in facegeom.io.files: the atomic rename replaces the entry; the other link keeps the old file."""
    d = files
    (d / "out.obj").write_text("old\n")
    os.link(d / "out.obj", d / "backup.obj")
    assert run_main(clean_args(d, "out.obj"), capsys)[0] == 0
    assert (d / "backup.obj").read_text() == "old\n"
    assert (d / "out.obj").read_text() != "old\n"


# --------------------------------------------------------------------------- output = input, duplicate outputs


def _refusals(d):
    """(command, the input it must not overwrite, the output named)."""
    return {
        "drive": (["drive", d / "grid.obj", d / "markers.csv", "-o", d / "grid.obj"], "grid.obj", "grid.obj"),
        "drive-markers": (["drive", d / "grid.obj", d / "markers.csv", "-o", d / "markers.csv"], "markers.csv",
                          "markers.csv"),
        "clean": (["clean", d / "grid.obj", d / "grid.obj"], "grid.obj", "grid.obj"),
        "clean-markers-out": (clean_args(d, "out.obj", "--markers-out", d / "markers.csv"), "markers.csv",
                              "markers.csv"),
        "decimate": (["decimate", d / "grid.obj", d / "grid.obj", "--vertices", "20"], "grid.obj", "grid.obj"),
        "crop": (["crop", d / "grid.obj", d / "grid.obj", "--id-range", "0:20"], "grid.obj", "grid.obj"),
        "crop-via-symlink": (["crop", d / "grid.obj", d / "alias.obj", "--id-range", "0:20"], "grid.obj",
                             "alias.obj"),
        "crop-via-hardlink": (["crop", d / "grid.obj", d / "hard.obj", "--id-range", "0:20"], "grid.obj",
                              "hard.obj"),
        "retarget": (["retarget", d / "source.npz", d / "labels.csv", "-o", d / "labels.csv"], "labels.csv",
                     "labels.csv"),
        "fit": (["fit", d / "target.obj", "--rig", d / "rig", "-o", d / "w.json", "--mesh-out", d / "target.obj"],
                "target.obj", "target.obj"),
        "fit-into-rig": (["fit", d / "target.obj", "--rig", d / "rig", "-o", d / "w.json", "--mesh-out",
                          d / "rig" / "fitted.obj"], "rig", "fitted.obj"),
        "animate": (["animate", "--take", d / "labels.csv", "-o", d / "labels.csv"], "labels.csv", "labels.csv"),
    }


@pytest.mark.parametrize("case", ["drive", "drive-markers", "clean", "clean-markers-out", "decimate", "crop",
                                  "crop-via-symlink", "crop-via-hardlink", "retarget", "fit", "fit-into-rig",
                                  "animate"])
def test_output_that_is_an_input_is_refused(files, capsys, case):
    d = files
    os.symlink(d / "grid.obj", d / "alias.obj")
    os.link(d / "grid.obj", d / "hard.obj")
    args, inp, out = _refusals(d)[case]
    before = {p: p.read_bytes() for p in d.rglob("*") if p.is_file()}
    code, so, err = run_main(args, capsys)
    assert code == 2, (so, err)
    line = err.strip()
    assert "\n" not in line and "refusing" in line, line
    assert str(d / inp) in line and (str(d / out) in line or out in line), line
    assert {p: p.read_bytes() for p in d.rglob("*") if p.is_file()} == before  # nothing written or changed


def test_drive_all_refuses_to_overwrite_its_input_in_the_folder(files, capsys):
    d = files
    write_mesh(d / "tangent.obj", *grid_mesh(6, 6, bump=0.1))
    before = (d / "tangent.obj").read_bytes()
    code, _, err = run_main(["drive", d / "tangent.obj", d / "markers.csv", "-m", "all", "-o", d], capsys)
    assert code == 2 and "refusing" in err and str(d / "tangent.obj") in err
    assert (d / "tangent.obj").read_bytes() == before and not (d / "rbf.obj").exists()


@pytest.mark.parametrize("extra, first, second", [
    (["--map", "x.csv", "--markers-out", "x.csv"], "x.csv", "x.csv"),
    (["--report", "out.json", "--map", "m.npz", "--markers-out", "./m.npz"], "m.npz", "./m.npz"),
])
def test_duplicate_outputs_of_one_command_are_refused(files, capsys, extra, first, second):
    d = files
    extra = [e if e.startswith("--") else str(d / e) for e in extra]
    before = listing(d)
    code, so, err = run_main(clean_args(d, "out.obj", *extra), capsys)
    assert code == 2 and "same file as another output" in err, err
    assert str(d / first) in err and str(d / second) in err
    assert listing(d) == before


def test_duplicate_outputs_of_fit_are_refused(files, capsys):
    d = files
    code, _, err = run_main(["fit", d / "target.obj", "--rig", d / "rig", "-o", d / "w.csv", "--mesh-out",
                             d / "w.csv"], capsys)
    assert code == 2 and "same file as another output" in err and not (d / "w.csv").exists()


# --------------------------------------------------------------------------- nothing partial on failure


def failing_after(n: int, real):
    """A writer that works ``n`` times, then raises."""
    calls = []

    def writer(*args, **kw):
        calls.append(args[0])
        if len(calls) > n:
            raise PermissionError(13, "Permission denied", str(args[0]))
        return real(*args, **kw)

    return writer


def test_fit_mesh_out_writes_both_or_neither(files, capsys, monkeypatch):
    import facegeom.io as fio

    d = files
    monkeypatch.setattr(fio, "write_mesh", failing_after(0, fio.write_mesh))
    before = listing(d)
    code, so, err = run_main(["fit", d / "target.obj", "--rig", d / "rig", "-o", d / "w.json", "--mesh-out",
                              d / "fitted.obj"], capsys)
    assert code != 0
    assert listing(d) == before  # no weights without the mesh, no temporary
    assert ".tmp" not in err


def test_drive_all_writes_every_method_or_none(files, capsys, monkeypatch):
    import facegeom.io as fio

    d = files
    monkeypatch.setattr(fio, "write_mesh", failing_after(2, fio.write_mesh))
    before = listing(d)
    code, _, err = run_main(["drive", d / "grid.obj", d / "markers.csv", "-m", "all", "-o", d / "new" / "all"],
                            capsys)
    assert code != 0
    assert listing(d) == before  # no method's mesh, and the folders it made are gone


def test_clean_writes_every_output_or_none(files, capsys, monkeypatch):
    import facegeom.pipelines.cleanup as C

    d = files
    monkeypatch.setattr(C, "write_vertex_csv", failing_after(0, C.write_vertex_csv))
    before = listing(d)
    code, _, err = run_main(clean_args(d, "out.obj", "--markers-out", d / "m2.csv", "--map", d / "map.csv"), capsys)
    assert code != 0 and listing(d) == before


def test_animate_obj_dir_writes_everything_or_nothing(tmp_path, capsys, monkeypatch, face_model, real_takes):
    import facegeom.io as fio
    monkeypatch.setattr(fio, "write_mesh", failing_after(2, fio.write_mesh))
    args = ["animate", "--start", "300", "--frames", "4", "--labels", "2", "-o", tmp_path / "anim.npz",
            "--obj-dir", tmp_path / "objs"]
    code, _, err = run_main(args, capsys)
    assert code != 0 and listing(tmp_path) == []  # no npz, no OBJ, no folder
    (tmp_path / "objs").mkdir()
    (tmp_path / "objs" / "keep.txt").write_text("mine\n")
    code, _, err = run_main(args, capsys)
    assert code != 0 and listing(tmp_path) == ["objs", "objs/keep.txt"]  # an existing folder keeps its files only
    monkeypatch.undo()
    code, _, err = run_main(args, capsys)
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "objs").iterdir()) == ["frame_00000.obj", "frame_00001.obj",
                                                                     "frame_00002.obj", "frame_00003.obj",
                                                                     "keep.txt"]


# --------------------------------------------------------------------------- errors name the output


def test_errors_name_the_output_not_a_temporary(files, capsys):
    d = files
    (d / "isdir.obj").mkdir()
    code, _, err = run_main(["drive", d / "grid.obj", d / "markers.csv", "-o", d / "isdir.obj"], capsys)
    assert code == 2 and err.strip() == f"facegeom: error: {d / 'isdir.obj'}: Is a directory", err
    assert listing(d / "isdir.obj") == []
    with pytest.raises(RuntimeError) as exc:
        with atomic_path(d / "x.obj") as tmp:
            raise RuntimeError(f"libigl: cannot open {tmp} for writing")
    assert str(exc.value) == f"libigl: cannot open {d / 'x.obj'} for writing"
    with pytest.raises(OSError) as exc:  # a writer failing on its temporary file (e.g. a full disk)
        with atomic_path(d / "y.obj") as tmp:
            raise OSError(28, "No space left on device", str(tmp))
    assert exc.value.filename == str(d / "y.obj")
    from facegeom.errors import InputError

    with pytest.raises(InputError) as exc:  # nested atomic writes (all_or_nothing + write_mesh)
        with atomic_path(d / "z.xyz") as tmp:
            write_mesh(tmp, *grid_mesh(3, 3))
    assert str(exc.value).startswith(f"{d / 'z.xyz'}: unsupported mesh format '.xyz'") and exc.value.path == str(
        d / "z.xyz")
    assert not any(".tmp" in n for n in listing(d))


def _unwritable_folder(tmp_path):
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        os.chmod(ro, 0o555)
        return ro
    if not os.path.isdir("/sys") or os.access("/sys", os.W_OK) and _can_create("/sys"):
        pytest.skip("no folder that root cannot write")
    return __import__("pathlib").Path("/sys")


def _can_create(folder) -> bool:
    try:
        with atomic_path(os.path.join(folder, "probe.bin")):
            raise KeyboardInterrupt  # never renamed
    except KeyboardInterrupt:
        return True
    except OSError:
        return False


def test_write_into_an_unwritable_folder_names_the_output(files, capsys):
    d = files
    ro = _unwritable_folder(d)
    out = ro / "driven.obj"
    code, _, err = run_main(["drive", d / "grid.obj", d / "markers.csv", "-o", out], capsys)
    assert code == 2 and err.strip().startswith(f"facegeom: error: {out}:") and ".tmp" not in err, err
    assert not out.exists()


# --------------------------------------------------------------------------- view --screenshot


def test_screenshot_into_an_unwritable_folder_fails_before_rendering(tmp_path, capsys, monkeypatch):
    import facegeom.viewer.drive

    ro = _unwritable_folder(tmp_path)
    monkeypatch.setattr(facegeom.viewer.drive, "DriveView", lambda *a, **k: pytest.fail("rendered anyway"))
    shot = ro / "shot.png"
    code, so, err = run_main(["view", "drive", "--screenshot", shot], capsys)
    assert code == 2 and "wrote" not in so, (so, err)
    assert err.count("\n") == 1 and str(shot) in err and "not writable" in err
    assert not shot.exists()
    (tmp_path / "folder.png").mkdir()
    code, so, err = run_main(["view", "drive", "--screenshot", tmp_path / "folder.png"], capsys)
    assert code == 2 and "is a directory" in err and "wrote" not in so  # click already refuses a folder


def test_screenshot_that_did_not_come_out_is_an_error(tmp_path, capsys, monkeypatch, face_model):
    ps = pytest.importorskip("polyscope")
    from facegeom.viewer.app import init_polyscope

    try:
        init_polyscope(headless=True)
    except Exception as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"headless rendering unavailable here: {exc}")
    shot = tmp_path / "shot.png"
    shot.write_bytes(b"previous image")
    monkeypatch.setattr(ps, "screenshot", lambda *a, **k: None)  # polyscope failing silently
    code, so, err = run_main(["view", "drive", "--methods", "rbf", "--size", "400x300", "--screenshot", shot],
                             capsys)
    assert code == 2 and "wrote" not in so, (so, err)
    assert err.count("\n") == 1 and str(shot) in err and "could not be written" in err
    assert shot.read_bytes() == b"previous image" and listing(tmp_path) == ["shot.png"]
    monkeypatch.undo()
    with umask(0o027):
        shot.unlink()
        code, so, err = run_main(["view", "drive", "--methods", "rbf", "--size", "400x300", "--screenshot", shot],
                                 capsys)
    assert code == 0 and f"wrote {shot}" in so, err
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and mode(shot) == 0o640


def test_a_full_disk_is_one_line_naming_the_output(files, capsys, monkeypatch):
    """An OSError that is not the user's (ENOSPC) still prints one line with the real output path, exit 1."""
    import errno

    import facegeom.io as fio

    d = files

    def full(path, *a, **kw):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(fio, "write_mesh", full)
    before = listing(d)
    code, _, err = run_main(["fit", d / "target.obj", "--rig", d / "rig", "-o", d / "w.json", "--mesh-out",
                             d / "fitted.obj"], capsys)
    assert code == 1 and err.count("\n") == 1 and "No space left on device" in err and "Traceback" not in err
    assert str(d / "fitted.obj") in err and ".tmp" not in err
    assert listing(d) == before
