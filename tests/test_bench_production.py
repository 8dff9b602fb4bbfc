"""`facegeom bench production` end to end at a tiny size: every case runs as a child, passes its check, and the
table, CSV and JSON are written; a rerun reuses the set-up. About 25 s of CPU (35 s wall on a busy 2-core machine):
the marker route registers the 4,817-vertex MakeHuman head."""
import csv
import json
import os
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from facegeom.bench.production import CASES, marker_route_split, parse_cases
from facegeom.cli.main import cli
from facegeom.errors import InputError

pytestmark = pytest.mark.skipif(not hasattr(os, "wait4") or sys.platform == "win32",
                                reason="children are measured with os.wait4 (POSIX)")

TINY = ["--frames-rig", "2000", "--frames-markers", "60", "--subdivide", "0", "--repeat", "1"]


def test_every_case_runs_as_a_child_and_passes_its_check(tmp_path, face_model):
    out = tmp_path / "bp"
    r = CliRunner().invoke(cli, ["bench", "production", *TINY, "--out", str(out)])
    assert r.exit_code == 0, r.output
    for case in CASES:  # a line as each case starts and ends
        assert f"\n{case}: " in r.output and f"{case}: done, CPU " in r.output
    assert "| case " in r.output and "| CPU s (median) | wall s (median) | peak RSS MB | target" in r.output
    assert "load average (1, 5, 15 min)" in r.output

    data = json.loads((out / "production.json").read_text())
    rows = data["rows"]
    assert [row["case"] for row in rows] == ["help", "help", "solve-gaps", "solve-cli", "rig-route", "marker-route",
                                             "marker-route-registered", "marker-route-long"]
    assert all(row["check"] == "ok" for row in rows), [row["note"] for row in rows]
    for row in rows:
        assert row["cpu_s"] > 0 and row["wall_s"] > 0 and len(row["runs"]) == 1
        # the child's own peak: not the few hundred MB of the process running the benchmark
        assert 5 < row["rss_mb"] < 2000
    assert rows[0]["rss_mb"] < 100
    gaps = rows[2]
    assert 0 < gaps["solve_s_per_1000"] < 30 and gaps["weight_error_gaps"] < 0.05
    for row in rows[-3], rows[-1]:
        assert {"rigid fit", "retarget", "deformer fit", "glb write"} <= set(row["split_s"])
    assert "--frames 60 " in rows[-3]["command"] and "--frames" not in rows[-1]["command"]  # the long one: all
    # a head registered before: the registration read from the cache, the rest of the route timed as before
    assert {"retarget", "deformer fit", "glb write"} == set(rows[-2]["split_s"])
    assert "warm-up run (not timed)" in r.output and rows[-2]["cpu_s"] < rows[-3]["cpu_s"]
    assert "2000 frames" in rows[-1]["note"]
    assert data["sizes"]["frames_rig"] == 2000 and data["machine"] and data["load_start"]

    with open(out / "production.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == 8 and {"cpu_s", "wall_s", "rss_mb", "met", "check"} <= set(table[0])
    summary = (out / "production-summary.md").read_text()
    assert summary.startswith("| case ") and "facegeom animate --take take.csv" in summary
    assert "cores, Python" in summary
    assert (out / "setup" / "char.npz").is_file() and (out / "setup" / "capture.c3d").is_file()

    stamp = (out / "setup" / "take.csv").stat().st_mtime_ns
    again = CliRunner().invoke(cli, ["bench", "production", *TINY, "--cases", "rig-route", "--out", str(out)])
    assert again.exit_code == 0, again.output
    assert "set-up: reusing" in again.output and "set-up: built" not in again.output
    assert (out / "setup" / "take.csv").stat().st_mtime_ns == stamp
    assert [row["case"] for row in json.loads((out / "production.json").read_text())["rows"]] == ["rig-route"]


def test_cases_are_named():
    assert parse_cases("all") == CASES
    assert parse_cases("marker-route, help") == ("help", "marker-route")
    with pytest.raises(InputError, match="unknown case 'nope'"):
        parse_cases("help,nope")


def test_bad_input_is_one_line(tmp_path):
    r = CliRunner().invoke(cli, ["bench", "production", "--cases", "solve", "--out", str(tmp_path)])
    assert r.exit_code != 0 and isinstance(r.exception, InputError)
    r = CliRunner().invoke(cli, ["bench", "production", "--cases", "help", "--code", str(tmp_path), "--out",
                                 str(tmp_path / "o")])
    assert isinstance(r.exception, InputError) and "not a facegeom checkout" in str(r.exception)


def test_another_checkouts_commands_are_timed(tmp_path):
    """--code: the children run the facegeom package of that folder (here a stand-in whose --help is marked)."""
    import shutil

    from facegeom.bench.production import child_env

    src = Path(__file__).resolve().parents[1] / "facegeom"
    shutil.copytree(src, tmp_path / "old" / "facegeom", ignore=shutil.ignore_patterns("__pycache__"))
    env = child_env(code=str(tmp_path / "old"))
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str((tmp_path / "old").resolve())
    import subprocess

    r = subprocess.run([sys.executable, "-c", "import facegeom; print(facegeom.__file__)"], env=env, cwd=tmp_path,
                       capture_output=True, text=True, check=True)
    assert r.stdout.strip() == str((tmp_path / "old" / "facegeom" / "__init__.py").resolve())
    out = tmp_path / "bp"
    r = CliRunner().invoke(cli, ["bench", "production", "--cases", "help", "--repeat", "1", "--code",
                                 str(tmp_path / "old"), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert json.loads((out / "production.json").read_text())["code"] == str(tmp_path / "old")


def test_the_marker_routes_split_is_read_from_its_output():
    text = ("rigid fit: scale 0.949 of the generic face; face-area distance median 0.86 mm, 95% 6.18 mm (4.3 s)\n"
            "identity fit: face-area distance median 0.72 mm, 95% 3.08 mm (19.6 s)\n"
            "non-rigid fit: face-area distance median 0.081 mm, 95% 0.926 mm, 100% of the face on the mesh (6.8 s)\n"
            "retarget 1.30 s, deformer fit 6.85 s\n"
            "wrote mr.glb (1000 frames driven and stored as 48 morph targets in 14.19 s, every vertex within "
            "0.100 mm)\n")
    assert marker_route_split(text) == {"rigid fit": 4.3, "identity fit": 19.6, "non-rigid fit": 6.8,
                                        "retarget": 1.3, "deformer fit": 6.85, "glb write": 14.19}
