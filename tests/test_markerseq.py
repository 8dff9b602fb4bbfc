"""Marker-sequence files (CSV long format, npz) and gap filling."""
import numpy as np
import pytest

from facegeom.errors import InputError
from facegeom.io import fill_gaps, read_marker_sequence, write_marker_sequence


def _seq(T=5, p=3, seed=0):
    return np.random.default_rng(seed).normal(size=(T, p, 3))


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip(tmp_path, suffix):
    P = _seq()
    path = write_marker_sequence(tmp_path / f"s{suffix}", P, names=["a", "b", "c"])
    s = read_marker_sequence(path)
    np.testing.assert_array_equal(s.positions, P)  # repr() keeps every digit
    assert s.names == ("a", "b", "c") and list(s.frames) == list(range(5))


def test_csv_with_lost_marker_and_unordered_frames(tmp_path):
    f = tmp_path / "s.csv"
    f.write_text("frame,marker,x,y,z\n1,m0,1,2,3\n1,m1,,,\n0,m0,0,0,0\n0,m1,4,5,nan\n")
    s = read_marker_sequence(f)
    assert list(s.frames) == [0, 1] and s.names == ("m0", "m1")
    assert s.missing().tolist() == [[False, True], [False, True]]
    np.testing.assert_array_equal(s.positions[1, 0], [1, 2, 3])


@pytest.mark.parametrize("content, problem", [
    ("", "empty file"),
    ("a,b,c\n1,2,3\n", "wrong columns"),
    ("frame,marker,x,y,z\n", "no marker rows"),
    ("frame,marker,x,y,z\n0,m,1,2\n", "expected 5 values"),
    ("frame,marker,x,y,z\nx,m,1,2,3\n", "not an integer"),
    ("frame,marker,x,y,z\n-1,m,1,2,3\n", "negative"),
    ("frame,marker,x,y,z\n0,m,1,q,3\n", "not a number"),
    ("frame,marker,x,y,z\n0,m,1,inf,3\n", "infinite"),
    ("frame,marker,x,y,z\n0,m,1,2,3\n0,m,1,2,3\n", "appears twice"),
    ("frame,marker,x,y,z\n0,a,1,2,3\n0,b,1,2,3\n1,a,1,2,3\n", "absent"),
])
def test_bad_csv(tmp_path, content, problem):
    f = tmp_path / "bad.csv"
    f.write_text(content)
    with pytest.raises(InputError, match=problem) as e:
        read_marker_sequence(f)
    assert str(f) in str(e.value)


def test_bad_npz_and_paths(tmp_path):
    np.savez(tmp_path / "a.npz", other=np.zeros(3))
    with pytest.raises(InputError, match="no 'markers'"):
        read_marker_sequence(tmp_path / "a.npz")
    np.savez(tmp_path / "b.npz", markers=np.zeros((4, 2)))
    with pytest.raises(InputError, match=r"shape \(T, p, 3\)"):
        read_marker_sequence(tmp_path / "b.npz")
    np.savez(tmp_path / "c.npz", markers=np.zeros((2, 2, 3)), frames=np.array([3, 3]))
    with pytest.raises(InputError, match="repeated"):
        read_marker_sequence(tmp_path / "c.npz")
    (tmp_path / "d.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="cannot read as npz"):
        read_marker_sequence(tmp_path / "d.npz")
    with pytest.raises(InputError, match="not found"):
        read_marker_sequence(tmp_path / "none.csv")
    (tmp_path / "e.txt").write_text("x")
    with pytest.raises(InputError, match="unsupported"):
        read_marker_sequence(tmp_path / "e.txt")


def test_npz_frames_sorted(tmp_path):
    P = _seq(3)
    np.savez(tmp_path / "s.npz", markers=P, frames=np.array([7, 2, 5]))
    s = read_marker_sequence(tmp_path / "s.npz")
    assert list(s.frames) == [2, 5, 7]
    np.testing.assert_array_equal(s.positions[0], P[1])


def test_reorder(tmp_path):
    P = _seq(2, 3)
    s = read_marker_sequence(write_marker_sequence(tmp_path / "s.csv", P, names="abc"))
    r = s.reorder(("c", "a", "b"))
    np.testing.assert_array_equal(r.positions[:, 0], P[:, 2])
    with pytest.raises(InputError, match="'z' is missing"):
        s.reorder(("a", "b", "z"))


def test_fill_gaps_linear_and_ends():
    P = np.zeros((6, 1, 3))
    P[:, 0, 0] = np.arange(6.0)
    Q = P.copy()
    Q[[0, 2, 3], 0] = np.nan
    F, n = fill_gaps(Q)
    assert n == 3
    np.testing.assert_allclose(F[1:, 0, 0], np.arange(1.0, 6.0))
    assert F[0, 0, 0] == 1.0  # an end gap takes the nearest tracked value
    with pytest.raises(InputError, match="2 consecutive"):
        fill_gaps(Q, max_gap=1)
    Q[:, 0] = np.nan
    with pytest.raises(InputError, match="every frame"):
        fill_gaps(Q)
