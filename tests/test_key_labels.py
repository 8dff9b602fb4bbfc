"""Key-labels CSV: the character's markers at key frames (what the marker route and its viewer read and write)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facegeom.errors import InputError
from facegeom.io.key_labels import read_key_labels, write_key_labels


def test_round_trip_with_vertices_and_missing_markers(tmp_path):
    rng = np.random.default_rng(0)
    L = rng.normal(size=(3, 5, 3))
    L[1, 2] = np.nan  # not given: stays proposed when read
    mv = np.array([10, 11, 12, 13, 14])
    p = write_key_labels(tmp_path / "k.csv", [40, 3, 17], L, mv, comment="a head\nsecond line")
    text = p.read_text()
    assert text.startswith("# a head\n# second line\nframe,marker,vertex,x,y,z\n")
    kl = read_key_labels(p, 5, n_frames=41)
    assert kl.frames.tolist() == [3, 17, 40]
    order = np.argsort([40, 3, 17])
    np.testing.assert_array_equal(kl.labels, L[order])  # exact: repr of floats
    assert np.isnan(kl.labels[0, 2]).all() and kl.vertices.tolist() == mv.tolist()  # frame 3 sorts first
    proposed = np.zeros((3, 5, 3))
    assert np.isfinite(kl.filled(proposed)).all() and (kl.filled(proposed)[0, 2] == 0).all()
    kl.check_vertices(mv)
    with pytest.raises(InputError, match="another head"):
        kl.check_vertices(mv + 1)


def test_a_partial_file_without_vertices(tmp_path):
    p = tmp_path / "k.csv"
    p.write_text("frame,marker,x,y,z\n5,1,1,2,3\n\n# note\n9,0,4,5,6\n")
    kl = read_key_labels(p, 2)
    assert kl.frames.tolist() == [5, 9] and kl.vertices is None
    assert kl.labels[0, 1].tolist() == [1, 2, 3] and np.isnan(kl.labels[0, 0]).all()
    kl.check_vertices([7, 8])  # nothing to check against


@pytest.mark.parametrize("text, message", [
    ("", "empty"),
    ("a,b,c\n1,2,3\n", "wrong columns"),
    ("frame,marker,x,y,z\n", "no label rows"),
    ("frame,marker,x,y,z\n1,2,3\n", "line 2: expected 5 values"),
    ("frame,marker,x,y,z\nx,0,1,2,3\n", "line 2: frame 'x' is not an integer"),
    ("frame,marker,x,y,z\n-1,0,1,2,3\n", "line 2: frame -1 is negative"),
    ("frame,marker,x,y,z\n1,9,1,2,3\n", "marker 9 is outside the layout's 4 markers"),
    ("frame,marker,x,y,z\n100,0,1,2,3\n", "frame 100 is outside the take's 50 frames"),
    ("frame,marker,x,y,z\n1,0,1,nan,3\n", "NaN or inf"),
    ("frame,marker,x,y,z\n1,0,1,2,3\n1,0,1,2,3\n", "line 3: marker 0 at frame 1 is given twice"),
    ("frame,marker,vertex,x,y,z\n1,0,5,1,2,3\n2,0,6,1,2,3\n", "line 3: marker 0 is on vertex 6 here but on vertex 5"),
    ("frame,marker,x,y,z\n99999999999999999999,0,1,2,3\n", "line 2"),
])
def test_bad_files_are_one_line_naming_the_file(tmp_path, text, message):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputError, match=message) as e:
        read_key_labels(p, 4, n_frames=50)
    assert "bad.csv" in str(e.value) and "\n" not in str(e.value)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_key_labels(tmp_path / "none.csv", 4)
    with pytest.raises(InputError, match="folder"):
        read_key_labels(tmp_path, 4)


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=400))
def test_fuzz_any_bytes_read_or_fail_in_one_line(tmp_path_factory, data):
    p = tmp_path_factory.mktemp("fz") / "k.csv"
    p.write_bytes(data)
    try:
        kl = read_key_labels(p, 6, n_frames=1000)
    except InputError as exc:
        assert "\n" not in str(exc)
        return
    assert kl.labels.shape == (kl.frames.size, 6, 3) and (kl.frames < 1000).all()


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 30), st.integers(0, 5),
                          st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3)), max_size=30))
def test_fuzz_rows_of_the_format(tmp_path_factory, rows):
    p = tmp_path_factory.mktemp("fz") / "k.csv"
    p.write_text("frame,marker,x,y,z\n" + "".join(f"{f},{m},{x},{y},{z}\n" for f, m, (x, y, z) in rows))
    seen = {}
    dup = False
    for f, m, xyz in rows:
        dup |= (f, m) in seen
        seen[(f, m)] = xyz
    try:
        kl = read_key_labels(p, 6)
    except InputError as exc:
        assert (not rows and "no label rows" in str(exc)) or (dup and "given twice" in str(exc))
        return
    assert not dup and rows
    for (f, m), xyz in seen.items():
        assert kl.labels[kl.frames.tolist().index(f), m].tolist() == xyz


def test_the_writer_refuses_bad_arrays_and_leaves_nothing(tmp_path):
    out = tmp_path / "k.csv"
    with pytest.raises(InputError, match="labels must be"):
        write_key_labels(out, [1, 2], np.zeros((3, 4, 3)))
    with pytest.raises(InputError, match="distinct"):
        write_key_labels(out, [1, 1], np.zeros((2, 4, 3)))
    with pytest.raises(InputError, match="marker vertices"):
        write_key_labels(out, [1, 2], np.zeros((2, 4, 3)), [1, 2])
    assert not out.exists()
