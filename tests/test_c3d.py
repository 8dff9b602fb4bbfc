"""C3D in and out: files written by ezc3d itself with known content, round trips, hostile files, the CLI."""
import os
import subprocess
import sys

import numpy as np
import pytest

ezc3d = pytest.importorskip("ezc3d")

from facegeom.errors import InputError  # noqa: E402
from facegeom.io import c3d as c3d_module  # noqa: E402
from facegeom.io.c3d import read_c3d, write_c3d  # noqa: E402
from facegeom.io.markerseq import MarkerSequence, read_marker_sequence, write_marker_sequence  # noqa: E402


def ezc3d_file(path, P, names, rate, unit="mm", residual_gaps=(), zero_gaps=(), first_frame=None):
    """Write ``P (T, p, 3)`` with ezc3d's own API (not facegeom's writer); gaps as (frame, marker) pairs."""
    T, p = P.shape[:2]
    pts = np.ones((4, p, T))
    pts[:3] = P.transpose(2, 1, 0)
    res = np.zeros((1, p, T))
    for f, j in residual_gaps:
        res[0, j, f] = -1.0
    for f, j in zero_gaps:
        pts[:3, j, f] = 0.0
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(names)
    if unit is not None:
        c["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = res
    c.write(str(path))
    return path


def motion(T, p, seed=0):
    """Smooth non-zero marker paths (T, p, 3), roughly a face in mm."""
    rng = np.random.default_rng(seed)
    rest = rng.uniform(-80, 80, size=(p, 3)) + 200.0
    t = np.linspace(0, 1, T)[:, None, None]
    return rest + 5.0 * np.sin(2 * np.pi * t + rng.uniform(0, 6, size=(p, 3)))


def test_reads_names_rate_unit_and_gaps_of_an_ezc3d_file(tmp_path):
    P = motion(12, 5)
    names = ["LBrow", "RBrow", "Nose", "LMouth", "RMouth"]
    f = ezc3d_file(tmp_path / "a.c3d", P, names, 119.88, "mm", residual_gaps=[(3, 1), (4, 1)], zero_gaps=[(7, 4)])
    s = read_c3d(f)
    assert isinstance(s, MarkerSequence)
    assert s.names == tuple(names) and s.fps == pytest.approx(119.88, rel=1e-6) and s.unit == "mm"
    assert np.array_equal(s.frames, np.arange(12))
    gaps = {tuple(x) for x in np.argwhere(s.missing()).tolist()}
    assert gaps == {(3, 1), (4, 1), (7, 4)}
    ok = ~s.missing()
    assert np.allclose(s.positions[ok], P[ok], atol=1e-4)  # C3D stores float32
    assert s.path == str(f)


@pytest.mark.parametrize("unit, to_mm", [("mm", 1.0), ("cm", 10.0), ("m", 1000.0), ("M", 1000.0)])
def test_units_and_conversion(tmp_path, unit, to_mm):
    P = motion(4, 3) / to_mm
    s = read_c3d(ezc3d_file(tmp_path / "u.c3d", P, ["a", "b", "c"], 60.0, unit))
    assert s.unit == unit.lower()
    mm = s.in_unit("mm")
    assert mm.unit == "mm" and np.allclose(mm.positions, P * to_mm, rtol=1e-6)
    back = mm.in_unit(unit.lower())
    assert np.allclose(back.positions, s.positions, rtol=1e-12)


def test_odd_unit_and_missing_unit(tmp_path):
    with pytest.raises(InputError, match=r"inch.*mm, cm or m") as e:
        read_c3d(ezc3d_file(tmp_path / "i.c3d", motion(3, 2), ["a", "b"], 30.0, "inch"))
    assert "i.c3d" in str(e.value)
    s = read_c3d(ezc3d_file(tmp_path / "n.c3d", motion(3, 2), ["a", "b"], 30.0, ""))
    assert s.unit is None
    with pytest.raises(InputError, match="no length unit"):
        s.in_unit("mm")
    with pytest.raises(InputError, match="unknown length unit"):
        MarkerSequence(np.arange(1), ("a",), np.zeros((1, 1, 3)), unit="mm").in_unit("ft")


def test_more_than_255_markers_use_labels2(tmp_path):
    p = 300
    names = [f"M{j:03d}" for j in range(p)]
    P = motion(3, p, seed=1)
    f = ezc3d_file(tmp_path / "many.c3d", P, names, 100.0)
    point = ezc3d.c3d(str(f))["parameters"]["POINT"]
    assert "LABELS2" in point  # the file really continues its labels in LABELS2
    s = read_c3d(f)
    assert s.names == tuple(names) and np.allclose(s.positions, P, atol=1e-3)


@pytest.mark.parametrize("unit", ["mm", "m"])
def test_round_trip_through_write_c3d(tmp_path, unit):
    P = motion(20, 6, seed=2) / (1000.0 if unit == "m" else 1.0)
    P[5, 2] = np.nan
    P[6:9, 0] = np.nan
    names = [f"m{j}" for j in range(6)]
    out = write_c3d(tmp_path / "r.c3d", P, names, 50.0, unit)
    s = read_marker_sequence(out)  # through the generic reader: .c3d is a marker-sequence format
    assert s.names == tuple(names) and s.fps == 50.0 and s.unit == unit
    assert np.array_equal(s.missing(), np.isnan(P).any(axis=2))
    ok = ~s.missing()
    assert np.allclose(s.positions[ok], P[ok], rtol=1e-6, atol=1e-9)
    # ezc3d sees the gaps as negative residuals too
    res = ezc3d.c3d(str(out))["data"]["meta_points"]["residuals"][0]
    assert (res[2, 5] < 0) and (res[0, 6:9] < 0).all() and (res[1] >= 0).all()


def test_write_is_atomic_and_checks_its_input(tmp_path):
    out = tmp_path / "w.c3d"
    write_c3d(out, motion(3, 2), ["a", "b"], 30.0)
    before = out.read_bytes()
    for args, msg in [((np.zeros((3, 2)), ["a", "b"], 30.0), "shape"),
                      ((motion(3, 2), ["a", "a"], 30.0), "distinct"),
                      ((motion(3, 2), ["a", "b"], 0.0), "frame rate"),
                      ((np.full((3, 2, 3), np.inf), ["a", "b"], 30.0), "inf")]:
        with pytest.raises(InputError, match=msg):
            write_c3d(out, *args)
    with pytest.raises(InputError, match="unit"):
        write_c3d(out, motion(3, 2), ["a", "b"], 30.0, unit="inch")
    with pytest.raises(InputError, match="at most 65535 frames"):  # ezc3d would write a file that reads back cut
        write_c3d(out, np.ones((65536, 1, 3)), ["a"], 30.0)
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["w.c3d"]  # no temporary file left behind
    with pytest.raises(InputError, match="output format '.c3d'"):
        write_marker_sequence(tmp_path / "x.c3d", motion(3, 2))


def test_bad_files_are_one_input_error(tmp_path):
    good = write_c3d(tmp_path / "g.c3d", motion(40, 4), list("abcd"), 30.0).read_bytes()  # 2,560 data bytes
    cases = {
        "short.c3d": good[:100],
        "key.c3d": good[:1] + b"\x00" + good[2:],
        "cut.c3d": good[:-1200],
        "params.c3d": good[:512] + b"\x00" * 4 + good[516:],
        "text.c3d": b"frame,marker,x,y,z\n" * 40,
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError) as e:
            read_c3d(tmp_path / name)
        assert name in str(e.value) and "\n" not in str(e.value)
    (tmp_path / "empty.c3d").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_marker_sequence(tmp_path / "empty.c3d")
    with pytest.raises(InputError, match="not found"):
        read_c3d(tmp_path / "nope.c3d")


def test_a_crash_or_hang_of_the_parser_is_an_input_error(tmp_path, monkeypatch):
    """The child process is the guard: make it crash and loop, the caller sees one InputError."""
    f = write_c3d(tmp_path / "g.c3d", motion(4, 2), ["a", "b"], 30.0)
    monkeypatch.setattr(c3d_module, "_CHILD", "import os; os.abort()")
    with pytest.raises(InputError, match="crashed"):
        read_c3d(f)
    monkeypatch.setattr(c3d_module, "_CHILD", "while True: pass")
    monkeypatch.setattr(c3d_module, "_TIMEOUT_S", 1.0)
    with pytest.raises(InputError, match="timed out"):
        read_c3d(f)


@pytest.mark.skipif(os.name != "posix", reason="the memory limit is set with setrlimit (POSIX)")
def test_the_parser_runs_under_a_memory_limit_and_a_time_limit_that_grows_with_the_file(tmp_path, monkeypatch):
    """A parser that asks for more memory than the limit (2 GiB plus 100 bytes a file byte) fails in one line, not
    the machine; the time limit given to the child is 10 s plus 1 s per MB of the file."""
    f = write_c3d(tmp_path / "g.c3d", motion(4, 2), ["a", "b"], 30.0)
    size = f.stat().st_size
    # the child allocates 1 GB more than its limit: refused by the address-space limit, a MemoryError, exit 1
    grab = c3d_module._MEMORY + 100 * size + (1 << 30)
    monkeypatch.setattr(c3d_module, "_CHILD", f"b = bytearray({grab})")
    with pytest.raises(InputError, match=r"crashed \(exit status 1\)") as e:  # (without the limit: exit status 0)
        read_c3d(f)
    assert str(f) in str(e.value) and "\n" not in str(e.value)
    seen = {}
    real_run = c3d_module.subprocess.run

    def run(cmd, **kw):
        seen["timeout"] = kw["timeout"]
        return real_run(cmd, **kw)

    monkeypatch.setattr(c3d_module.subprocess, "run", run)
    monkeypatch.setattr(c3d_module, "_CHILD", "pass")
    with pytest.raises(InputError):  # the child writes nothing
        read_c3d(f)
    assert seen["timeout"] == pytest.approx(10.0 + size / 1e6)


def test_cli_retarget_reads_a_c3d_source(tmp_path):
    rng = np.random.default_rng(3)
    T, p = 30, 6
    X = motion(T, p, seed=4) / 10.0  # cm
    names = [f"m{j}" for j in range(p)]
    lab = np.array([0, 10, 20, 29])
    Y = 1.2 * X + rng.normal(scale=0.01, size=X.shape)
    ezc3d_file(tmp_path / "actor.c3d", X, names, 30.0, "cm")
    write_marker_sequence(tmp_path / "labels.csv", Y[lab], frames=lab, names=names)
    out = tmp_path / "y.npz"
    r = subprocess.run([sys.executable, "-m", "facegeom", "retarget", str(tmp_path / "actor.c3d"),
                        str(tmp_path / "labels.csv"), "-o", str(out), "-m", "rbf"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    s = read_marker_sequence(out)
    assert s.positions.shape == (T, p, 3) and s.names == tuple(names)
    assert np.allclose(s.positions[lab], Y[lab], atol=0.05)
    # a broken C3D source is one line, no traceback
    (tmp_path / "bad.c3d").write_bytes(b"\x02\x50" + b"\x00" * 600)
    r = subprocess.run([sys.executable, "-m", "facegeom", "retarget", str(tmp_path / "bad.c3d"),
                        str(tmp_path / "labels.csv"), "-o", str(tmp_path / "z.npz")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "bad.c3d" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_batch_retarget_takes_c3d_sources(tmp_path):
    from facegeom.pipelines import batch as fb

    names = [f"m{j}" for j in range(5)]
    lab = np.array([0, 8, 16, 23])
    (tmp_path / "src").mkdir()
    (tmp_path / "labels").mkdir()
    for k in range(2):
        X = motion(24, 5, seed=10 + k)
        write_c3d(tmp_path / "src" / f"s{k}.c3d", X, names, 60.0, "mm")
        write_marker_sequence(tmp_path / "labels" / f"s{k}.csv", 1.1 * X[lab], frames=lab, names=names)
    job = {"operation": "retarget", "method": "rbf", "inputs": "src/*.c3d",
           "shared": {"labels": "labels/{stem}.csv"}, "output": "out"}
    res = fb.run_job(fb.job_from_dict(job, base=tmp_path), inline=True, progress=False)
    assert res is not None
    for k in range(2):
        s = read_marker_sequence(tmp_path / "out" / f"s{k}.npz")
        assert s.positions.shape == (24, 5, 3) and s.names == tuple(names)


def test_retarget_inputs_convert_labels_to_the_sources_unit(tmp_path):
    from facegeom.io.markerseq import read_retarget_inputs

    X = motion(10, 3, seed=6)  # mm
    names = ["a", "b", "c"]
    write_c3d(tmp_path / "src.c3d", X, names, 30.0, "mm")
    write_c3d(tmp_path / "lab.c3d", X[[0, 9]] / 1000.0, names, 30.0, "m")  # frames 0 and 1 of a labels file
    src, P, lab, n = read_retarget_inputs(tmp_path / "src.c3d", tmp_path / "lab.c3d")
    assert lab.unit == "mm" and np.allclose(lab.positions, X[[0, 9]], rtol=1e-6) and n == 0
