"""ARKit (Live Link Face) take reader and the mapping to ICT names."""
from __future__ import annotations

import numpy as np
import pytest

from facegeom.data import default_takes_path
from facegeom.errors import InputError
from facegeom.takes import ARKIT_NAMES, arkit_to_ict_name, find_takes, ict_weights, read_take

ROT = ["HeadYaw", "HeadPitch", "HeadRoll", "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
       "RightEyeYaw", "RightEyePitch", "RightEyeRoll"]
HEADER = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *ROT]


def write_take(path, rows, header=HEADER):
    lines = [",".join(header)]
    for r in rows:
        lines.append(",".join(str(x) for x in r))
    path.write_text("\n".join(lines) + "\n")
    return path


def row(frame, value):
    return [f"12:00:00:{frame:02d}.000", 61, *([value] * 52), *([0.0] * 9)]


def test_values_and_times(tmp_path):
    f = write_take(tmp_path / "t.csv", [row(0, 0.25), row(1, 0.5), row(2, 1.02)])
    t = read_take(f)
    assert t.n_frames == 3 and t.lost_rows == 0
    assert t.weights[:, 0].tolist() == [0.25, 0.5, 1.02]
    np.testing.assert_allclose(t.times, [0, 1 / 30, 2 / 30])


def test_lost_rows_interpolated_or_dropped(tmp_path):
    f = write_take(tmp_path / "t.csv", [row(0, 0.0), ["12:00:00:01.000", 0], ["12:00:00:02.000", 0], row(3, 0.9)])
    t = read_take(f)
    assert t.lost_rows == 2 and t.n_frames == 4
    np.testing.assert_allclose(t.weights[:, 5], [0.0, 0.3, 0.6, 0.9])
    d = read_take(f, policy="drop")
    assert d.lost_rows == 2 and d.n_frames == 2


@pytest.mark.parametrize("rows, header, message", [
    ([row(0, 0.1)], [h for h in HEADER if h != "JawOpen"], "JawOpen"),
    ([row(0, 0.1)[:10] + ["abc"] + row(0, 0.1)[11:]], HEADER, "row 2, column"),
    ([["12:00:00:01.000", 0]], HEADER, "no usable row"),
    ([row(0, 0.1)[:20]], HEADER, "row 2 has 20 columns"),
    ([row(0, 0.1)], ["Time", *HEADER[1:]], "Timecode"),
])
def test_bad_takes_name_the_file(tmp_path, rows, header, message):
    f = write_take(tmp_path / "bad.csv", rows, header)
    with pytest.raises(InputError, match=message) as exc:
        read_take(f)
    assert str(f) in str(exc.value)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputError, match="no such take"):
        read_take(tmp_path / "nope.csv")
    with pytest.raises(InputError, match="no .csv"):
        find_takes(tmp_path)
    with pytest.raises(InputError, match="policy"):
        read_take(tmp_path / "x.csv", policy="guess")


def test_mapping_to_ict(face_model):
    assert arkit_to_ict_name("EyeBlinkLeft") == ["eyeBlink_L"]
    assert arkit_to_ict_name("MouthLeft") == ["mouthLeft"]
    assert arkit_to_ict_name("JawOpen") == ["jawOpen"]
    assert arkit_to_ict_name("BrowInnerUp") == ["browInnerUp_L", "browInnerUp_R"]
    assert arkit_to_ict_name("TongueOut") == []
    covered = [n for a in ARKIT_NAMES for n in arkit_to_ict_name(a)]
    assert sorted(covered) == sorted(face_model.expression_names)  # each ICT shape exactly once


def test_ict_weights_clip(tmp_path, face_model):
    f = write_take(tmp_path / "t.csv", [row(0, 1.08), row(1, -0.01)])
    W = ict_weights(read_take(f), face_model.expression_names)
    assert W.shape == (2, face_model.n_expressions)
    assert W.max() == 1.0 and W.min() == 0.0
    assert W[0, face_model.expression_index("browInnerUp_R")] == 1.0


def test_real_takes():
    folder = default_takes_path()
    if not folder.is_dir():
        pytest.skip(f"real takes not found at {folder}")
    t = read_take(folder / "apfel.csv")
    assert t.lost_rows == 35 and t.n_frames == 1926
    assert -0.1 <= t.weights.min() and t.weights.max() <= 1.2
    assert len(find_takes(folder)) >= 4
