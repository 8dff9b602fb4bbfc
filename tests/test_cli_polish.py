"""A new user's findings on the command line: short help, progress of slow stages, the demo's last line and its
fit figure, the viewer's colour scale, named capture markers, usage errors in one line, units on printed numbers."""
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import click
import numpy as np
import pytest

from facegeom.io.markerseq import write_marker_sequence
from facegeom.model import BlendshapeRig
from facegeom.model.layouts import ict80


def run(*args):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=600)


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    return lines[0]


# --------------------------------------------------------------------------- short help


def _commands(cmd, path=()):
    """Every (sub)command under ``cmd``, loading the lazily imported ones."""
    if isinstance(cmd, click.Group):
        ctx = click.Context(cmd)
        for name in cmd.list_commands(ctx):
            yield from _commands(cmd.get_command(ctx, name), (*path, name))
    if path:
        yield " ".join(path), cmd


def test_short_help_is_the_whole_first_phrase():
    """click cuts a command's summary at a period followed by a capital ("Sec. V"): no command may be cut so."""
    from facegeom.cli.main import cli

    cut = []
    for name, cmd in _commands(cli):
        first = " ".join((cmd.help or "").partition("\n\n")[0].split())
        if cmd.get_short_help_str(limit=10_000) != first:
            cut.append(name)
    assert cut == []


def test_bench_help_lists_fit_with_a_full_summary():
    r = run("bench", "--help")
    assert r.returncode == 0
    line = next(ln for ln in r.stdout.splitlines() if ln.strip().startswith("fit "))
    assert "Sec." not in line and "section V" in line
    r = run("bench", "fit", "--help")
    assert r.returncode == 0 and "Blendshape fitting (SEM paper, section V)" in r.stdout


# --------------------------------------------------------------------------- bench fit: the throughput stage


def test_bench_fit_announces_the_landmark_throughput_and_shows_its_progress(tmp_path, face_model):
    r = run("bench", "fit", "--cases", "1", "--methods", "sem-ls", "--experiments", "landmarks",
            "--realistic-cases", "0", "--no-plot", "--out", str(tmp_path / "fit"))
    assert r.returncode == 0, r.stderr
    heading = [ln for ln in r.stdout.splitlines() if ln.startswith("landmark throughput:")]
    assert len(heading) == 1 and "fits per second" in heading[0] and "takes roughly" in heading[0]
    assert r.stdout.index(heading[0]) < r.stdout.index("Landmark throughput (one rig")
    assert "landmark speed: targets" in r.stderr and "landmark speed:" in r.stderr.replace("targets", "")
    assert "2/2" in r.stderr  # the timed runs: one method, pose known and estimated


def test_landmark_throughput_is_silent_when_quiet(face_model, capsys):
    from facegeom.bench import fit as bf
    from facegeom.registry import parse_methods

    rows = bf.run_landmark_throughput(face_model, parse_methods("sem-ls", "fitters", []), count=4, progress=False)
    assert rows[0]["method"] == "sem-ls" and rows[0]["known_pose"] > 0
    assert capsys.readouterr().err == ""
    bf.run_landmark_throughput(face_model, parse_methods("sem-ls", "fitters", []), count=4, progress=True)
    assert "landmark speed" in capsys.readouterr().err


def test_throughput_heading_says_how_long():
    from facegeom.bench.fit import throughput_heading

    line = throughput_heading("landmark", 6, 1000)
    assert "6 fitters" in line and "1,000 targets" in line and "roughly 30 s to 3 minutes" in line
    assert "median of 3 runs" in throughput_heading("mesh", 2, 2000, repeats=3)


# --------------------------------------------------------------------------- the fit figure


def _drawn(ax) -> bool:
    return bool(ax.has_data() or ax.texts)


def test_fit_figure_has_no_empty_panel():
    """The demo runs landmarks and meshes (no temporal take): every panel of fit.png must show something."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facegeom.bench.fit import plot

    specs = [SimpleNamespace(label="a"), SimpleNamespace(label="b")]
    row = {"ne_eval": 0.05, "corr": 100.0, "vertex_mm": 0.5}
    results = {"landmarks": [{"method": m, **row} for m in "ab"],
               "meshes": ([{"method": m, **row} for m in "ab"], [])}
    fig = plot(results, specs, None, None)
    try:
        assert len(fig.axes) == 3 and all(_drawn(a) for a in fig.axes)
        assert "mesh" in fig.axes[2].get_title().lower()
    finally:
        plt.close(fig)
    fig = plot({"landmark_speed": [{"method": "a", "known_pose": 1.0}]}, specs, None, None)  # throughputs only
    try:
        assert len(fig.axes) == 1 and all(_drawn(a) for a in fig.axes)
    finally:
        plt.close(fig)
    W = np.linspace(0, 1, 10)[:, None]
    fig = plot({"landmarks": results["landmarks"]}, specs, {"a": W}, W)
    try:
        assert len(fig.axes) == 3 and all(_drawn(a) for a in fig.axes)
    finally:
        plt.close(fig)


# --------------------------------------------------------------------------- viewer: one colour scale


def test_retarget_view_slider_and_colour_bar_show_the_same_maximum(headless, face_model):
    from facegeom.viewer.app import COLOR_MAX_LABEL
    from facegeom.viewer.playback import RetargetView, load_sequence

    ps = pytest.importorskip("polyscope")
    ps.remove_all_structures()
    seq = load_sequence(face_model, synthetic=True, frames=40, seed=3)
    v = RetargetView(face_model, seq, "copy;rbf;tangent", labels=5)
    assert v.vmax < 0.1  # below the slider's old lower end and its one decimal: where both disagreed
    v.setup_scene(1000, 600, headless=True)
    ps.frame_tick()
    assert v.ui.shown[COLOR_MAX_LABEL] == v.colorbar_labels()[-1] == f"{v.vmax:g}"
    v.ui.set(COLOR_MAX_LABEL, 0.123456)
    ps.frame_tick()
    ps.frame_tick()
    assert v.vmax == pytest.approx(0.123)
    assert v.ui.shown[COLOR_MAX_LABEL] == v.colorbar_labels()[-1] == "0.123"
    assert v.colorbar_labels()[0] == "0"
    ps.clear_user_callback()
    ps.remove_all_structures()


# --------------------------------------------------------------------------- solve: named markers


@pytest.fixture(scope="module")
def named_capture(tmp_path_factory, face_model):
    d = tmp_path_factory.mktemp("named")
    rig = BlendshapeRig.from_face_model(face_model)
    ids = ict80(face_model)
    T = 6
    W = np.zeros((T, rig.n_shapes))
    W[:, rig.shape_index("jawOpen")] = np.linspace(0.1, 0.7, T)
    X = rig.neutral[ids][None] + np.einsum("tb,bpi->tpi", W, rig.deltas[:, ids])
    names = [f"M{j:02d}" for j in range(ids.size)]
    write_marker_sequence(d / "cap.csv", X, names=names)
    (d / "map.csv").write_text("marker,vertex_id\n" + "".join(f"{n},{i}\n" for n, i in zip(names, ids)))
    return d


def test_solve_named_markers_without_a_map_says_how(named_capture):
    d = named_capture
    r = run("solve", str(d / "cap.csv"), "-o", str(d / "c.npz"))
    assert r.returncode == 2
    line = one_line(r.stderr)
    assert line.startswith(f"facegeom: error: {d / 'cap.csv'}: ")
    assert "marker names are not vertex ids" in line and "--markers MAP.csv" in line and "ict80" in line
    assert not (d / "c.npz").exists()


def test_solve_accepts_a_map_headed_marker_vertex_id(named_capture):
    d = named_capture
    r = run("solve", str(d / "cap.csv"), "--markers", str(d / "map.csv"), "-o", str(d / "c.npz"), "--smooth", "off",
            "--identity", "off")  # a capture of the generic face itself: solved on it as it is
    assert r.returncode == 0, r.stderr
    assert np.load(d / "c.npz")["weights"].shape[0] == 6
    # the residual is printed with its unit (the rig's cm, shown in mm)
    assert "marker residual median" in r.stdout
    residual = r.stdout.split("marker residual median ")[1].split(",")[0]
    assert residual.endswith(" mm") and float(residual[:-3]) < 1e-3


# --------------------------------------------------------------------------- usage errors: one line, exit 2


@pytest.mark.parametrize("args, command, message", [
    (["drive", "{d}", "{d}/x.csv", "-o", "{d}/a.ply"], "drive", "Invalid value for 'MESH'"),
    (["bench", "fit", "--cases", "abc"], "bench fit", "Invalid value for '--cases'"),
    (["info", "--bogus"], "info", "No such option '--bogus'"),
    (["solve"], "solve", "Missing argument 'CAPTURE'"),
])
def test_usage_errors_are_one_line_and_exit_2(tmp_path, args, command, message):
    (tmp_path / "x.csv").write_text("vertex_id,x,y,z\n")
    r = run(*[a.format(d=tmp_path) for a in args])
    assert r.returncode == 2
    line = one_line(r.stderr)
    assert line.startswith(f"facegeom: error: {command}: {message}")
    assert line.endswith(f"(see `facegeom {command} --help`)")
    assert "Usage:" not in r.stderr and "Try '" not in r.stderr and r.stdout == ""


def test_unknown_command_is_one_line_and_help_is_unchanged():
    r = run("nosuch")
    assert r.returncode == 2 and one_line(r.stderr).startswith("facegeom: error: No such command 'nosuch'")
    assert one_line(r.stderr).endswith("(see `facegeom --help`)")
    r = run("drive", "--help")
    assert r.returncode == 0 and r.stdout.startswith("Usage: facegeom drive [OPTIONS] MESH MARKERS")


# --------------------------------------------------------------------------- units on printed numbers


def test_retarget_prints_the_label_deviation_with_its_unit(tmp_path, face_model):
    from facegeom.io.c3d import write_c3d

    rng = np.random.default_rng(0)
    names = [f"m{j}" for j in range(6)]
    X = rng.normal(size=(12, 6, 3)) * 10.0
    src = write_c3d(tmp_path / "src.c3d", X, names, fps=30.0, unit="mm")
    lab = write_c3d(tmp_path / "lab.c3d", X[:2] * 1.1, names, fps=30.0, unit="mm")
    r = run("retarget", str(src), str(lab), "-o", str(tmp_path / "out.csv"), "-m", "rbf")
    assert r.returncode == 0, r.stderr
    dev = r.stdout.split("largest deviation from a label ")[1].split(")")[0]
    assert dev.endswith(" mm") and float(dev[:-3]) >= 0
