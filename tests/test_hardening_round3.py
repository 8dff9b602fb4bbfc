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
