"""The Live Link take reader's block path: rows of one layout converted together with numpy.

:func:`facegeom.io.takes.read_take` reads plain blocks of the file (ASCII, no quotes, no NUL, ``\\n`` or
``\\r\\n``) itself: the rows that share the app's layout (the same cells, digits and decimal points, minus
signs aside) are checked and converted at once, any other row is split as the :mod:`csv` module would and read
on its own; a block that is not plain, and the rest of the file from it, goes through the :mod:`csv` module.

Checked here: known values (what ``float()`` reads, bit for bit: negative zero, 15 significant digits,
every decimal layout), known errors (the row and column named, the first one in the file), and, on files drawn
at random (layouts, lost and blank lines, bad cells and timecodes, line breaks, a BOM, quotes, blocks cut small),
that the block path, the row path and the :mod:`csv` module give the same take or the same error.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from facegeom.errors import InputError
from facegeom.io import takes
from facegeom.io.takes import ARKIT_NAMES, ROTATION_NAMES, read_take, write_livelink_csv

HEADER = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *ROTATION_NAMES]


def _tc(i: int) -> str:
    s, f = divmod(2 * i, 60)
    return f"12:{s // 60 % 60:02d}:{s % 60:02d}:{f:02d}.{(7 * i) % 1000:03d}"


def _app_row(i: int, W, R, fmt: str = "{:.10f}") -> str:
    return ",".join([_tc(i), "61", *(fmt.format(float(x)) for x in W[i]), *(fmt.format(float(x)) for x in R[i])])


def _known(text_cells) -> np.ndarray:
    return np.array([[float(c) for c in row] for row in text_cells])


def _same(a, b) -> bool:
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def _result(path, policy="interpolate"):
    try:
        t = read_take(path, policy)
    except InputError as exc:
        return ("error", str(exc))
    return ("take", t)


@pytest.fixture
def ways(monkeypatch):
    """``ways(path, policy)`` -> the results of the block path, the row path (no layout: every row read on
    its own) and the csv module (no block plain: the reader before blocks, for every file)."""

    def read(path, policy="interpolate"):
        out = [_result(path, policy)]
        with monkeypatch.context() as m:
            m.setattr(takes._Layout, "find", classmethod(lambda cls, blk, state: None))
            out.append(_result(path, policy))
        with monkeypatch.context() as m:
            m.setattr(takes, "_plain", lambda blk: False)
            out.append(_result(path, policy))
        return out

    return read


def _assert_same(results) -> None:
    kinds = {r[0] for r in results}
    assert len(kinds) == 1, [r[0] + (": " + r[1] if r[0] == "error" else "") for r in results]
    if "error" in kinds:
        assert len({r[1] for r in results}) == 1, [r[1] for r in results]
        return
    first = results[0][1]
    for _, t in results[1:]:
        for f in ("weights", "times"):
            assert _same(getattr(first, f), getattr(t, f)), f
        assert (first.rotations is None) == (t.rotations is None)
        assert first.rotations is None or _same(first.rotations, t.rotations)
        assert (first.lost_rows, first.timecode_fps, first.start_s) == (t.lost_rows, t.timecode_fps, t.start_s)


# ----------------------------------------------------------------------------- known values


def test_the_apps_layout_reads_what_float_reads_bit_for_bit(tmp_path, monkeypatch):
    rng = np.random.default_rng(3)
    T = 3000
    W = rng.uniform(-0.05, 1.08, size=(T, 52))
    W[::7, 5] = -1e-12  # written "-0.0000000000": negative zero
    R = rng.uniform(-3.1, 3.1, size=(T, 9))
    path = tmp_path / "t.csv"
    path.write_text("\n".join([",".join(HEADER)] + [_app_row(i, W, R) for i in range(T)]) + "\n")
    monkeypatch.setattr(takes, "BLOCK_BYTES", 10_000)  # many blocks, cut anywhere
    calls = []
    row = takes._Scanned.row
    monkeypatch.setattr(takes._Scanned, "row", lambda self, *a: calls.append(a) or row(self, *a))
    t = read_take(path)
    assert not calls  # every row read with its block
    rows = [r.split(",") for r in path.read_text().splitlines()[1:]]
    assert _same(t.weights, _known([r[2:54] for r in rows]))
    assert _same(t.rotations, _known([r[54:63] for r in rows]))
    assert np.signbit(t.weights[::7, 5]).all() and (t.weights[::7, 5] == 0).all()
    assert t.timecode_fps == 60 and t.n_frames == T
    np.testing.assert_allclose(t.times, np.arange(T) / 30 + ((7 * np.arange(T)) % 1000 - 0) / 60000, atol=1e-9)


@pytest.mark.parametrize("fmt", ["{:.10f}", "{:.6f}", "{:.1f}", "{:.15f}", "{:.3e}", "{:g}", "{!r}", "{:+.4f}"])
def test_any_decimal_layout_reads_what_float_reads(tmp_path, fmt):
    rng = np.random.default_rng(4)
    W = rng.uniform(-2, 2, size=(200, 52)) * 10.0 ** rng.integers(-3, 3, size=(200, 52))
    R = rng.uniform(-3, 3, size=(200, 9))
    path = tmp_path / "t.csv"
    path.write_text("\n".join([",".join(HEADER)] + [_app_row(i, W, R, fmt) for i in range(200)]) + "\n")
    rows = [r.split(",") for r in path.read_text().splitlines()[1:]]
    t = read_take(path)
    assert _same(t.weights, _known([r[2:54] for r in rows]))
    assert _same(t.rotations, _known([r[54:63] for r in rows]))


def test_written_takes_read_back_bit_for_bit(tmp_path):
    rng = np.random.default_rng(5)
    W = rng.uniform(-0.05, 1.08, size=(500, 52))
    out = write_livelink_csv(tmp_path / "w.csv", W, ARKIT_NAMES, 60.0, start=3600.0,
                             rotations=rng.uniform(-1, 1, size=(500, 9)))
    t = read_take(out)
    assert _same(t.weights, np.array([[float(f"{x:.10f}") for x in row] for row in W]))


def test_lost_and_odd_rows_between_blocks_of_the_layout(tmp_path, monkeypatch, ways):
    rng = np.random.default_rng(6)
    T = 1200
    W, R = rng.uniform(0, 1, size=(T, 52)), rng.uniform(-1, 1, size=(T, 9))
    lines = [",".join(HEADER)]
    for i in range(T):
        if i % 97 == 5:
            lines.append(f"{_tc(i)},0")  # lost
        elif i % 89 == 3:
            lines.append("")  # blank
        elif i % 83 == 1:
            lines.append(_app_row(i, W, R, "{:.4f}") + ",,")  # another layout, trailing commas
        else:
            lines.append(_app_row(i, W, R))
    path = tmp_path / "t.csv"
    path.write_text("\r\n".join(lines) + "\r\n")
    monkeypatch.setattr(takes, "BLOCK_BYTES", 5000)
    for policy in ("interpolate", "drop"):
        res = ways(path, policy)
        _assert_same(res)
        assert res[0][1].lost_rows == len(range(5, T, 97))


# ----------------------------------------------------------------------------- known errors


def _errors_alike(path, ways, match):
    res = ways(path)
    _assert_same(res)
    assert res[0][0] == "error", res[0]
    assert str(path) in res[0][1] and "\n" not in res[0][1]
    assert match in res[0][1], res[0][1]


def _lines(T: int = 300):
    rng = np.random.default_rng(7)
    W, R = rng.uniform(0, 1, size=(T, 52)), rng.uniform(-1, 1, size=(T, 9))
    return [",".join(HEADER)] + [_app_row(i, W, R) for i in range(T)]


@pytest.mark.parametrize("row,cell,bad,match", [
    (150, 2 + ARKIT_NAMES.index("JawOpen"), "0.12x4567890",
     "row 151, column JawOpen: not a finite number: '0.12x4567890'"),
    (150, 2 + ARKIT_NAMES.index("JawOpen"), "-0.-234567890", "row 151, column JawOpen"),
    (150, 2 + ARKIT_NAMES.index("JawOpen"), "--0.234567890", "row 151, column JawOpen"),
    (150, 2 + ARKIT_NAMES.index("JawOpen"), "0.2345678900-", "row 151, column JawOpen"),
    (150, 2 + ARKIT_NAMES.index("JawOpen"), "nan", "row 151, column JawOpen: not a finite number: 'nan'"),
    (150, 54, "1e999", "row 151, column HeadYaw"),
    (150, 0, "12:61:00:00.000", "row 151, column Timecode: bad timecode '12:61:00:00.000'"),
    (150, 0, "12:00:61:00.000", "row 151, column Timecode"),
    (150, 0, "12-00:01:00.000", "row 151, column Timecode"),
    (150, 1, "6,1", "row 151 has 64 columns where the header has 63"),
    (150, 1, "-61", None),  # a cell not read: any text
    (150, 1, "sixty one", None),
])
def test_a_bad_cell_in_a_block_is_named_as_the_row_reader_names_it(tmp_path, ways, monkeypatch, row, cell, bad,
                                                                   match):
    lines = _lines()
    cells = lines[row].split(",")  # lines[0]: the header, line 1
    cells[cell] = bad
    lines[row] = ",".join(cells)
    path = tmp_path / "t.csv"
    path.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(takes, "BLOCK_BYTES", 20_000)
    if match is None:
        _assert_same(ways(path))
    else:
        _errors_alike(path, ways, match)


def test_the_first_error_of_the_file_is_the_one_named(tmp_path, ways, monkeypatch):
    lines = _lines(400)
    monkeypatch.setattr(takes, "BLOCK_BYTES", 8_000)
    # a bad number (row 301) is named before a bad timecode earlier in the file (row 101); a row of the wrong
    # width (row 351) before both
    c = lines[101].split(",")
    c[0] = "12:99:00:00.000"
    lines[101] = ",".join(c)
    c = lines[301].split(",")
    c[7] = "0.5.5"
    lines[301] = ",".join(c)
    path = tmp_path / "t.csv"
    path.write_text("\n".join(lines) + "\n")
    _errors_alike(path, ways, "row 302, column")
    lines[351] = "12:00:00:00.000,7"
    path.write_text("\n".join(lines) + "\n")
    _errors_alike(path, ways, "row 352 has 2 columns")


@pytest.mark.parametrize("insert,match", [
    (b"\xff\xfe", "not UTF-8 text"),
    (b"\0", "not a finite number: '0."),  # Python 3.11's csv module reads NUL
])
def test_a_block_the_csv_module_reads_after_blocks_read_here(tmp_path, ways, monkeypatch, insert, match):
    data = ("\n".join(_lines(400)) + "\n").encode()
    at = data.index(b"\n", len(data) * 3 // 4)
    path = tmp_path / "t.csv"
    path.write_bytes(data[:at] + insert + data[at:])
    monkeypatch.setattr(takes, "BLOCK_BYTES", 8_000)
    _errors_alike(path, ways, match)


def test_quotes_a_bom_and_utf8_are_read_as_the_csv_module_reads_them(tmp_path, ways, monkeypatch):
    lines = _lines(300)
    c = lines[250].split(",")
    c[5] = '"0.25"'
    c[1] = '"6,1"'  # a quoted comma: one cell
    lines[250] = ",".join(c)
    c = lines[260].split(",")
    c[1] = "é"
    lines[260] = ",".join(c)
    path = tmp_path / "t.csv"
    path.write_bytes(b"\xef\xbb\xbf" + ("\n".join(lines) + "\n").encode())
    monkeypatch.setattr(takes, "BLOCK_BYTES", 8_000)
    res = ways(path)
    _assert_same(res)
    assert res[0][0] == "take" and res[0][1].weights[249, 3] == 0.25


# ----------------------------------------------------------------------------- the three readers agree

_CELL = st.one_of(
    st.floats(-10, 10, allow_nan=False).map(lambda x: f"{x:.10f}"),
    st.floats(-10, 10, allow_nan=False).map(lambda x: f"{x:.3f}"),
    st.floats(-1e6, 1e6, allow_nan=False).map(repr),
    st.integers(-99, 99).map(str),
    st.sampled_from(["-0.0000000000", "0", ".5", "5.", "+0.5", "1e-5", " 0.5", "0.5 ", "", "-", ".", "1_0", "nan",
                     "inf", "0x10", "0.1234567890123456", "123456789012345", "1234567890123456", "--1", "1-", "x"]),
)
_TIMECODE = st.one_of(
    st.integers(0, 200).map(_tc),
    st.sampled_from(["12:60:00:00.000", "1:2:3:4.5", "12:00:00:00", "-1:00:00:00.000", " 12:00:00:01.000",
                     "99:59:60:59.999", "noon", ""]),
)


@st.composite
def _takes(draw) -> bytes:
    rotations = draw(st.booleans())
    header = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *(ROTATION_NAMES if rotations else ())]
    if draw(st.booleans()):
        header = draw(st.permutations(header))
    if draw(st.booleans()):
        header.append("Extra")
    width = len(header)
    tc = header.index("Timecode")
    fmt = draw(st.sampled_from(["{:.10f}", "{:.4f}", "{:g}"]))
    base = [draw(st.floats(-1.5, 1.5, allow_nan=False)) for _ in range(width)]
    lines = [",".join(header)]
    for i in range(draw(st.integers(0, 60))):
        kind = draw(st.sampled_from(["good"] * 12 + ["lost", "blank", "odd", "short", "trailing"]))
        if kind == "lost":
            lines.append(f"{_tc(i)},{draw(st.sampled_from(['0', '0.0', ' 0 ', '-0', '1']))}")
            continue
        if kind == "blank":
            lines.append(draw(st.sampled_from(["", " ", ",,", " , "])))
            continue
        cells = [fmt.format(b + 0.01 * i * (-1) ** j) for j, b in enumerate(base)]
        cells[tc] = _tc(i)
        if header[1] == "BlendShapeCount":
            cells[1] = "61"
        if kind == "odd":
            cells[draw(st.integers(0, width - 1))] = draw(_CELL)
            if draw(st.booleans()):
                cells[tc] = draw(_TIMECODE)
        if kind == "short":
            cells = cells[:draw(st.integers(1, width - 1))]
        if kind == "trailing":
            cells += [""] * draw(st.integers(1, 3))
        lines.append(",".join(cells))
    text = draw(st.sampled_from(["\n", "\r\n"])).join(lines)
    if draw(st.booleans()):
        text += "\n"
    data = text.encode()
    if draw(st.booleans()):
        data = b"\xef\xbb\xbf" + data
    if draw(st.integers(0, 9)) == 0:  # a byte the csv module must read (from its block on)
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.sampled_from([b'"', b"\r", b"\0", b"\xc3\xa9", b"\xff"])) + data[at:]
    return data


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow,
                                                                                       HealthCheck.data_too_large])
@given(data=_takes(), block=st.sampled_from([64, 700, 4000, 1 << 20]))
def test_block_row_and_csv_readers_give_the_same_take_or_error(tmp_path_factory, data, block):
    path = tmp_path_factory.mktemp("take") / "t.csv"
    path.write_bytes(data)
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(takes, "BLOCK_BYTES", block)
        out = [_result(path)]
        mp.setattr(takes._Layout, "find", classmethod(lambda cls, blk, state: None))
        out.append(_result(path))
        mp.undo()
        mp.setattr(takes, "BLOCK_BYTES", block)
        mp.setattr(takes, "_plain", lambda blk: False)
        out.append(_result(path))
    finally:
        mp.undo()
    _assert_same(out)


def test_yxz_matrices_are_scipys():
    from scipy.spatial.transform import Rotation

    from facegeom.pipelines.character import _yxz_matrices as yxz_matrices

    a = np.random.default_rng(8).uniform(-3.2, 3.2, size=(5000, 3))
    R = yxz_matrices(a)
    ref = Rotation.from_euler("YXZ", a).as_matrix()
    np.testing.assert_allclose(R, ref, rtol=0, atol=1e-15)  # the same operations: bit for bit where numpy's sin
    # and cos are the C library's (on the machine this was written on); an ulp or two where they are not
    assert yxz_matrices(np.zeros((0, 3))).shape == (0, 3, 3)


@pytest.mark.parametrize("gap", [10, 3000, 9000, 20000])
@pytest.mark.parametrize("crlf", [False, True])
def test_a_byte_not_utf8_is_named_where_the_csv_module_meets_it(tmp_path, ways, monkeypatch, gap, crlf):
    """The csv module decodes 8 kB at a time: a byte that is not UTF-8 in the chunk of a row of the wrong width
    is named instead of the row, as when that row came first; further on, the row is named."""
    lines = _lines(120)
    lines[40] = lines[40][:300]  # a row of the wrong width
    data = ("\r\n" if crlf else "\n").join(lines).encode() + b"\n"
    at = data.index(b"\n", len("\n".join(lines[:41])) + gap)
    path = tmp_path / "t.csv"
    path.write_bytes(data[:at] + b"\xff" + data[at:])
    monkeypatch.setattr(takes, "BLOCK_BYTES", 700)
    res = ways(path)
    _assert_same(res)
    bad_row_end = len(b"\n".join(x.encode() for x in lines[:41])) + (40 if crlf else 0)
    same_chunk = bad_row_end // 8192 == at // 8192
    assert ("not UTF-8 text" if same_chunk else "row 41 has") in res[0][1]
