"""Live Link Face (ARKit) take reader and the mapping to ICT expression names."""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import ARKIT_NAMES, ROTATION_NAMES, arkit_to_ict_name, find_takes, ict_weights, read_take, timecode_fps

HEADER = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *ROTATION_NAMES]

ICT_NAMES = """
browDown_L browDown_R browInnerUp_L browInnerUp_R browOuterUp_L browOuterUp_R cheekPuff_L cheekPuff_R
cheekSquint_L cheekSquint_R eyeBlink_L eyeBlink_R eyeLookDown_L eyeLookDown_R eyeLookIn_L eyeLookIn_R
eyeLookOut_L eyeLookOut_R eyeLookUp_L eyeLookUp_R eyeSquint_L eyeSquint_R eyeWide_L eyeWide_R jawForward
jawLeft jawOpen jawRight mouthClose mouthDimple_L mouthDimple_R mouthFrown_L mouthFrown_R mouthFunnel
mouthLeft mouthLowerDown_L mouthLowerDown_R mouthPress_L mouthPress_R mouthPucker mouthRight mouthRollLower
mouthRollUpper mouthShrugLower mouthShrugUpper mouthSmile_L mouthSmile_R mouthStretch_L mouthStretch_R
mouthUpperUp_L mouthUpperUp_R noseSneer_L noseSneer_R
""".split()


def tc(frame: int, fps: int = 30, sub: str = "000", start_s: int = 0) -> str:
    """Timecode of a frame counted from 12:00:00:00 at ``fps``."""
    s, f = divmod(frame, fps)
    s += start_s
    return f"12:{s // 60:02d}:{s % 60:02d}:{f:02d}.{sub}"


def good_row(timecode: str, weights) -> list:
    w = np.broadcast_to(np.asarray(weights, dtype=float), (52,))
    return [timecode, 61, *(f"{x:.10f}" for x in w), *(["0.0"] * 9)]


def lost_row(timecode: str) -> list:
    return [timecode, 0]


def write(path: Path, rows, header=HEADER) -> Path:
    path.write_text("\n".join(",".join(str(c) for c in r) for r in [header, *rows]) + "\n")
    return path


# ----------------------------------------------------------------------------- reading


def test_reads_values_exactly_and_names(tmp_path):
    rng = np.random.default_rng(0)
    W = np.round(rng.uniform(-0.05, 1.1, size=(5, 52)), 10)
    f = write(tmp_path / "t.csv", [good_row(tc(2 * i), W[i]) for i in range(5)])
    t = read_take(f)
    assert t.names == ARKIT_NAMES and len(ARKIT_NAMES) == 52 and len(set(ARKIT_NAMES)) == 52
    assert t.weights.dtype == np.float64 and t.weights.shape == (5, 52)
    np.testing.assert_array_equal(t.weights, W)  # out-of-range values kept as read
    assert t.n_frames == 5 and t.lost_rows == 0 and t.policy == "interpolate"
    assert t.path == str(f)


def test_columns_found_by_name_in_any_order(tmp_path):
    header = ["Timecode", "BlendShapeCount", *reversed(ARKIT_NAMES), *ROTATION_NAMES]
    w = np.arange(52) / 100.0
    f = write(tmp_path / "t.csv", [good_row(tc(0), w[::-1])], header)
    np.testing.assert_allclose(read_take(f).weights[0], w)


def test_times_60fps_frame_base_is_monotonic_across_seconds(tmp_path):
    # rows every 2 frames of a 60 fps timecode (as Live Link Face writes), crossing second boundaries
    rows = [good_row(tc(50 + 2 * i, fps=60, sub="169"), 0.1) for i in range(70)]
    t = read_take(write(tmp_path / "t.csv", rows))
    assert t.timecode_fps == 60
    np.testing.assert_allclose(t.times, np.arange(70) / 30.0, atol=1e-9)


def test_times_30fps_default_for_short_take(tmp_path):
    rows = [good_row(f"12:00:00:{i:02d}.000", 0.1) for i in range(3)]
    t = read_take(write(tmp_path / "t.csv", rows))
    assert t.timecode_fps == 30
    np.testing.assert_allclose(t.times, [0, 1 / 30, 2 / 30])
    assert timecode_fps([0, 12.5, 59.9]) == 60 and timecode_fps([]) == 30


def test_lost_rows_interpolated(tmp_path):
    rows = [good_row(tc(0), 0.0), lost_row(tc(2)), lost_row(tc(4)), good_row(tc(6), 0.9), good_row(tc(8), 0.5)]
    t = read_take(write(tmp_path / "t.csv", rows))
    assert t.lost_rows == 2 and t.n_frames == 5
    np.testing.assert_allclose(t.weights[:, 17], [0.0, 0.3, 0.6, 0.9, 0.5])
    np.testing.assert_allclose(t.times, np.arange(5) * 2 / 30.0)


def test_lost_rows_at_the_ends_hold_the_nearest_good_row(tmp_path):
    rows = [lost_row(tc(0)), good_row(tc(2), 0.4), good_row(tc(4), 0.8), lost_row(tc(6))]
    t = read_take(write(tmp_path / "t.csv", rows))
    assert t.lost_rows == 2
    np.testing.assert_allclose(t.weights[:, 0], [0.4, 0.4, 0.8, 0.8])
    assert t.times[0] == 0


def test_lost_rows_dropped(tmp_path):
    rows = [good_row(tc(0), 0.0), lost_row(tc(2)), lost_row(tc(4)), good_row(tc(6), 0.9)]
    t = read_take(write(tmp_path / "t.csv", rows), policy="drop")
    assert t.lost_rows == 2 and t.n_frames == 2 and t.policy == "drop"
    np.testing.assert_allclose(t.weights[:, 3], [0.0, 0.9])
    np.testing.assert_allclose(t.times, [0.0, 0.2])  # the gap is kept in the times


# ----------------------------------------------------------------------------- errors


def _raises(path, match, **kw) -> str:
    with pytest.raises(InputError, match=match) as exc:
        read_take(path, **kw)
    assert str(path) in str(exc.value)
    return str(exc.value)


def test_error_missing_column(tmp_path):
    header = [h for h in HEADER if h not in ("JawOpen", "TongueOut")]
    f = write(tmp_path / "t.csv", [good_row(tc(0), 0.1)[:-2]], header)
    msg = _raises(f, "JawOpen")
    assert "TongueOut" in msg


def test_error_no_timecode_column(tmp_path):
    f = write(tmp_path / "t.csv", [good_row(tc(0), 0.1)], ["Time", *HEADER[1:]])
    _raises(f, "Timecode")


def test_error_non_numeric_value_names_row_and_column(tmp_path):
    bad = good_row(tc(2), 0.1)
    bad[2 + ARKIT_NAMES.index("MouthClose")] = "abc"
    f = write(tmp_path / "t.csv", [good_row(tc(0), 0.1), bad])
    _raises(f, r"row 3, column MouthClose.*'abc'")


def test_error_bad_row_width_and_timecode(tmp_path):
    f = write(tmp_path / "a.csv", [good_row(tc(0), 0.1), good_row(tc(2), 0.1)[:20]])
    _raises(f, "row 3 has 20 columns")
    f = write(tmp_path / "b.csv", [good_row(tc(0), 0.1), [tc(2), 7]])  # not the lost pattern
    _raises(f, "row 3 has 2 columns")
    f = write(tmp_path / "c.csv", [good_row("noon", 0.1)])
    _raises(f, "row 2, column Timecode")


def test_error_all_rows_lost_or_empty(tmp_path):
    _raises(write(tmp_path / "lost.csv", [lost_row(tc(0)), lost_row(tc(2))]), "all 2 data rows are lost")
    _raises(write(tmp_path / "header.csv", []), "no data rows")
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    _raises(empty, "empty")


def test_error_missing_file_and_bad_policy(tmp_path):
    _raises(tmp_path / "nope.csv", "not found")
    _raises(tmp_path, "not a file")
    f = write(tmp_path / "t.csv", [good_row(tc(0), 0.1)])
    _raises(f, "policy", policy="guess")


def test_find_takes(tmp_path):
    with pytest.raises(InputError, match="not found") as exc:
        find_takes(tmp_path / "none")
    assert str(tmp_path / "none") in str(exc.value)
    with pytest.raises(InputError, match="no .csv") as exc:
        find_takes(tmp_path)
    assert str(tmp_path) in str(exc.value)
    for n in ("b.csv", "a.csv", "notes.txt"):
        (tmp_path / n).write_text("x")
    assert [p.name for p in find_takes(tmp_path)] == ["a.csv", "b.csv"]


# ----------------------------------------------------------------------------- mapping


@pytest.mark.parametrize("arkit, ict", [
    ("EyeBlinkLeft", ["eyeBlink_L"]),
    ("JawOpen", ["jawOpen"]),
    ("MouthSmileRight", ["mouthSmile_R"]),
    ("BrowInnerUp", ["browInnerUp_L", "browInnerUp_R"]),
    ("CheekPuff", ["cheekPuff_L", "cheekPuff_R"]),
    ("TongueOut", []),
    ("NoseSneerLeft", ["noseSneer_L"]),
    ("MouthLeft", ["mouthLeft"]),
    ("MouthRight", ["mouthRight"]),
    ("JawLeft", ["jawLeft"]),
    ("JawRight", ["jawRight"]),
    ("EyeLookInLeft", ["eyeLookIn_L"]),
    ("CheekSquintRight", ["cheekSquint_R"]),
    ("MouthLowerDownLeft", ["mouthLowerDown_L"]),
    ("eyeBlinkRight", ["eyeBlink_R"]),  # ARKit API spelling
])
def test_arkit_to_ict_name(arkit, ict):
    assert arkit_to_ict_name(arkit) == ict


def test_unknown_arkit_name():
    with pytest.raises(InputError, match="Smirk"):
        arkit_to_ict_name("Smirk")


def test_mapping_covers_every_ict_name_exactly_once():
    assert len(ICT_NAMES) == 53
    non_tongue = [a for a in ARKIT_NAMES if a != "TongueOut"]
    assert len(non_tongue) == 51
    targets = [n for a in non_tongue for n in arkit_to_ict_name(a)]
    assert sorted(targets) == sorted(ICT_NAMES)  # every ICT name once, nothing else


def test_ict_weights_order_both_sides_unknown_and_clip(tmp_path):
    w = np.zeros(52)
    w[ARKIT_NAMES.index("BrowInnerUp")] = 0.7
    w[ARKIT_NAMES.index("EyeLookOutLeft")] = 1.08
    w[ARKIT_NAMES.index("MouthLeft")] = -0.02
    w[ARKIT_NAMES.index("JawOpen")] = 0.25
    take = read_take(write(tmp_path / "t.csv", [good_row(tc(0), w)]))
    names = ["jawOpen", "browInnerUp_R", "notAShape", "browInnerUp_L", "eyeLookOut_L", "mouthLeft"]
    np.testing.assert_allclose(ict_weights(take, names), [[0.25, 0.7, 0.0, 0.7, 1.0, 0.0]])
    np.testing.assert_allclose(ict_weights(take, names, clip=False), [[0.25, 0.7, 0.0, 0.7, 1.08, -0.02]])
    assert take.weights[0, ARKIT_NAMES.index("EyeLookOutLeft")] == 1.08  # the take is not altered
    assert ict_weights(take, ICT_NAMES).shape == (1, 53)


def test_ict_weights_match_the_face_model_names(face_model):
    assert sorted(face_model.expression_names) == sorted(ICT_NAMES)


# ----------------------------------------------------------------------------- performance, real takes


def test_reads_4000_rows_fast(tmp_path):
    rng = np.random.default_rng(1)
    rows = [good_row(tc(2 * i, fps=60), rng.uniform(0, 1, 52)) for i in range(4000)]
    for i in range(100, 4000, 97):
        rows[i] = lost_row(rows[i][0])
    f = write(tmp_path / "big.csv", rows)
    read_take(f)  # warm up
    t0 = time.perf_counter()
    take = read_take(f)
    assert time.perf_counter() - t0 < 0.5
    assert take.n_frames == 4000 and take.lost_rows == 41


def test_real_takes(real_takes):
    """Every real take of this machine (a fresh one has the public take ``facegeom data fetch`` downloads)."""
    for f in real_takes:
        t = read_take(f)
        assert t.n_frames > 100 and t.timecode_fps == 60, f
        assert -0.1 <= t.weights.min() and t.weights.max() <= 1.2, f
        dt = np.diff(t.times)
        assert (dt > 0).all() and abs(np.median(dt) - 1 / 30) < 1e-3, f  # ~30 rows/s, never backwards
        W = ict_weights(t, ICT_NAMES)
        assert W.shape == (t.n_frames, 53) and W.min() >= 0 and W.max() <= 1
        d = read_take(f, policy="drop")
        assert d.n_frames == t.n_frames - t.lost_rows and d.lost_rows == t.lost_rows
    assert find_takes(real_takes[0].parent) == real_takes


def test_real_take_with_lost_tracking_rows(real_takes):
    """``apfel.csv`` has 35 lost-tracking rows: interpolated, or dropped on request."""
    f = real_takes[0].parent / "apfel.csv"
    if not f.is_file():
        pytest.skip(f"apfel.csv is not among this machine's takes ({real_takes[0].parent}); the public take that "
                    f"`facegeom data fetch` downloads has no lost rows (synthetic ones are tested above)")
    t = read_take(f)
    assert t.lost_rows == 35 and t.n_frames == 1926
    assert read_take(f, policy="drop").n_frames == 1926 - 35


# ----------------------------------------------------------------------------- writing (Live Link Face CSV out)

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from facegeom.io.takes import ict_to_arkit, write_livelink_csv  # noqa: E402


def test_written_take_has_the_apps_header_and_round_trips_a_real_take(tmp_path, real_takes):
    src = real_takes[0]
    t = read_take(src)
    out = write_livelink_csv(tmp_path / "o.csv", t.weights, t.names, 30.0, start=12 * 3600 + 27 * 60 + 47.8)
    real_header = src.read_text().splitlines()[0]
    lines = out.read_text().splitlines()
    assert lines[0] == real_header and lines[1].split(",")[1] == "61"
    assert len(lines[1].split(",")) == len(real_header.split(","))
    u = read_take(out)
    assert u.names == t.names and u.lost_rows == 0 and u.timecode_fps == 60  # the app's frame base
    assert np.array_equal(u.weights, t.weights)  # the app's 10 decimals are kept exactly
    assert np.allclose(u.times, np.arange(t.n_frames) / 30.0, atol=1e-6)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(T=st.integers(1, 90), fps=st.sampled_from([24.0, 25.0, 29.97, 30.0, 50.0, 60.0, 120.0]),
       start=st.floats(0, 86400.0, allow_nan=False), seed=st.integers(0, 2 ** 16))
def test_write_then_read_gives_the_weights_and_times_back(tmp_path_factory, T, fps, start, seed):
    rng = np.random.default_rng(seed)
    W = rng.uniform(-0.05, 1.08, size=(T, 52))
    out = write_livelink_csv(tmp_path_factory.mktemp("w") / "t.csv", W, ARKIT_NAMES, fps, start=start)
    u = read_take(out)
    assert u.n_frames == T and np.allclose(u.weights, W, atol=5e-11)
    # times within a thousandth of a timecode frame (1/60 s or 1/30 s) of i / fps, whatever the length
    assert np.allclose(u.times, np.arange(T) / fps, atol=2e-5)


def test_subset_and_camel_case_names_and_rotations(tmp_path):
    W = np.array([[0.5, 0.25], [1.0, 0.0]])
    R = np.arange(18, dtype=float).reshape(2, 9) / 100
    out = write_livelink_csv(tmp_path / "s.csv", W, ["jawOpen", "EyeBlinkLeft"], 60.0, rotations=R)
    u = read_take(out)
    j, e = ARKIT_NAMES.index("JawOpen"), ARKIT_NAMES.index("EyeBlinkLeft")
    assert np.array_equal(u.weights[:, j], W[:, 0]) and np.array_equal(u.weights[:, e], W[:, 1])
    others = np.delete(u.weights, [j, e], axis=1)
    assert (others == 0).all()
    rows = [line.split(",") for line in out.read_text().splitlines()[1:]]
    assert np.allclose(np.array([r[-9:] for r in rows], dtype=float), R)


def test_writer_errors(tmp_path):
    out = tmp_path / "e.csv"
    W = np.zeros((3, 2))
    for args, kw, msg in [((W, ["jawOpen_L", "JawOpen"], 30.0), {}, "ict_to_arkit"),
                          ((W, ["JawOpen", "jawOpen"], 30.0), {}, "repeats"),
                          ((W[:, :1], ["JawOpen", "JawLeft"], 30.0), {}, "shape"),
                          ((np.full((3, 2), np.nan), ["JawOpen", "JawLeft"], 30.0), {}, "NaN"),
                          ((W, ["JawOpen", "JawLeft"], 0.0), {}, "frame rate"),
                          ((W, ["JawOpen", "JawLeft"], 30.0), {"start": -1}, "start"),
                          ((W, ["JawOpen", "JawLeft"], 30.0), {"rotations": np.zeros((3, 3))}, "rotations")]:
        with pytest.raises(InputError, match=msg):
            write_livelink_csv(out, *args, **kw)
    assert not out.exists()


def test_ict_to_arkit_inverts_ict_weights():
    rng = np.random.default_rng(5)
    take_w = rng.uniform(0, 1, size=(7, 52))
    from facegeom.io.takes import Take

    take = Take("", ARKIT_NAMES, take_w, np.arange(7) / 30.0, 0, "interpolate")
    ict = ict_weights(take, ICT_NAMES, clip=False)
    back, names = ict_to_arkit(ict, ICT_NAMES)
    assert names == ARKIT_NAMES and back.shape == (7, 52)
    tongue = ARKIT_NAMES.index("TongueOut")
    assert np.array_equal(np.delete(back, tongue, 1), np.delete(take_w, tongue, 1)) and (back[:, tongue] == 0).all()
    # ICT -> ARKit -> ICT is the identity when the brow and puff sides agree, in any column order
    order = rng.permutation(len(ICT_NAMES))
    names_shuffled = [ICT_NAMES[i] for i in order]
    again = ict_weights(Take("", ARKIT_NAMES, back, take.times, 0, "interpolate"), names_shuffled, clip=False)
    assert np.array_equal(again, ict[:, order])


def test_ict_to_arkit_loses_only_what_it_documents():
    W = np.zeros((1, len(ICT_NAMES)))
    W[0, ICT_NAMES.index("browInnerUp_L")] = 0.8
    W[0, ICT_NAMES.index("browInnerUp_R")] = 0.2
    W[0, ICT_NAMES.index("jawOpen")] = 0.5
    A, names = ict_to_arkit(W, ICT_NAMES)
    assert A[0, names.index("BrowInnerUp")] == pytest.approx(0.5)  # sides averaged
    assert A[0, names.index("JawOpen")] == 0.5 and np.count_nonzero(A) == 2
    A, _ = ict_to_arkit(np.ones((2, 2)), ["jawOpen", "notAShape"])  # unknown ICT names dropped, absent ones 0
    assert A[:, ARKIT_NAMES.index("JawOpen")].tolist() == [1.0, 1.0] and np.count_nonzero(A) == 2
    with pytest.raises(InputError, match="shape"):
        ict_to_arkit(np.ones((2, 3)), ["jawOpen", "mouthLeft"])
