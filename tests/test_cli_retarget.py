"""End-to-end: `facegeom retarget` on marker-sequence files, and its bad-input errors."""
import subprocess
import sys

import numpy as np
import pytest

from facegeom.io import read_marker_sequence, write_marker_sequence
from facegeom.methods.tangent_retarget import evenly_spread


def run(*args):
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, timeout=300)


def _pair(T=40, p=8, seed=0):
    """A smooth actor motion and a character doing it in its own (per-marker, non-linear) style."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    rest = rng.normal(size=(p, 3))
    dirs = rng.normal(size=(2, p, 3))
    a = np.sin(2 * np.pi * t)[:, :, None] * dirs[0] + (t ** 2)[:, :, None] * dirs[1]  # (T, p, 3)
    X = rest + 0.3 * a
    A = np.eye(3) + 0.2 * rng.normal(size=(p, 3, 3))
    Y = 1.3 * rest + 0.3 * np.einsum("tpi,pij->tpj", a, A) + 0.05 * np.sin(3 * a)
    return X, Y


@pytest.fixture
def files(tmp_path):
    X, Y = _pair()
    lab = evenly_spread(40, 8)
    names = [f"m{j}" for j in range(8)]
    write_marker_sequence(tmp_path / "actor.csv", X, names=names)
    write_marker_sequence(tmp_path / "labels.csv", Y[lab], frames=lab, names=names)
    return tmp_path, X, Y, lab, names


@pytest.mark.parametrize("method, out", [("tangent", "y.csv"), ("rbf", "y.npz"), ("laplacian", "y.csv")])
def test_retarget_methods(files, method, out):
    d, X, Y, lab, names = files
    r = run("retarget", str(d / "actor.csv"), str(d / "labels.csv"), "-o", str(d / out), "-m", method)
    assert r.returncode == 0, r.stderr
    s = read_marker_sequence(d / out)
    assert s.positions.shape == X.shape and s.names == tuple(names)
    err = np.linalg.norm(s.positions - Y, axis=2).mean()
    copy = np.linalg.norm(X - X[lab].mean(0) + Y[lab].mean(0) - Y, axis=2).mean()
    assert err < 0.5 * copy, (err, copy)  # far better than carrying the motion over unchanged


def test_retarget_params_and_reordered_label_markers(files):
    d, X, Y, lab, names = files
    write_marker_sequence(d / "labels2.npz", Y[lab][:, ::-1], frames=lab, names=names[::-1])
    r = run("retarget", str(d / "actor.csv"), str(d / "labels2.npz"), "-o", str(d / "a.npz"))
    assert r.returncode == 0, r.stderr
    r = run("retarget", str(d / "actor.csv"), str(d / "labels.csv"), "-o", str(d / "b.npz"))
    np.testing.assert_allclose(np.load(d / "a.npz")["markers"], np.load(d / "b.npz")["markers"], atol=1e-9)
    r = run("retarget", str(d / "actor.csv"), str(d / "labels.csv"), "-o", str(d / "c.npz"),
            "-p", "strategy=marker", "-p", "window=2")
    assert r.returncode == 0, r.stderr
    r = run("retarget", str(d / "actor.csv"), str(d / "labels.csv"), "-o", str(d / "c.npz"), "-p", "window=0")
    assert r.returncode == 2 and "window must be an integer in [1, 1000]" in r.stderr


def test_retarget_fill_gaps(files):
    d, X, Y, lab, names = files
    Xg = X.copy()
    Xg[10:13, 2] = np.nan
    write_marker_sequence(d / "gappy.csv", Xg, names=names)
    r = run("retarget", str(d / "gappy.csv"), str(d / "labels.csv"), "-o", str(d / "y.csv"))
    assert r.returncode == 2 and "frame 10: marker 'm2' is lost" in r.stderr and "--fill-gaps" in r.stderr
    assert not (d / "y.csv").exists()
    r = run("retarget", str(d / "gappy.csv"), str(d / "labels.csv"), "-o", str(d / "y.csv"), "--fill-gaps")
    assert r.returncode == 0 and "filled 3 lost marker samples" in r.stdout


def _bad_labels(d, X, Y, lab, names, case):
    if case == "count":
        write_marker_sequence(d / "bad.csv", Y[lab][:, :7], frames=lab, names=names[:7])
    elif case == "range":
        write_marker_sequence(d / "bad.csv", Y[lab], frames=np.r_[lab[:-1], 40], names=names)
    elif case == "one":
        write_marker_sequence(d / "bad.csv", Y[lab[:1]], frames=lab[:1], names=names)
    elif case == "nan":
        Z = Y[lab].copy()
        Z[3, 5, 1] = np.nan
        write_marker_sequence(d / "bad.csv", Z, frames=lab, names=names)
    elif case == "repeat":
        (d / "bad.csv").write_text("frame,marker,x,y,z\n" + "".join(f"5,{n},0,0,0\n" for n in names) +
                                   "5,m0,1,1,1\n")
    elif case == "names":
        write_marker_sequence(d / "bad.csv", Y[lab], frames=lab, names=[f"k{j}" for j in range(8)])


@pytest.mark.parametrize("case, problem", [
    ("count", "7 markers per frame, but the source"),
    ("range", "labelled frame 40 is out of range: the source has frames 0..39"),
    ("one", "at least two labelled frames"),
    ("nan", "labelled frame 17: marker 'm5' is empty or NaN"),
    ("repeat", "marker 'm0' appears twice in frame 5"),
    ("names", "marker 'm0' is missing"),
])
def test_retarget_bad_labels(files, case, problem):
    d, X, Y, lab, names = files
    _bad_labels(d, X, Y, lab, names, case)
    r = run("retarget", str(d / "actor.csv"), str(d / "bad.csv"), "-o", str(d / "out.csv"))
    assert r.returncode == 2, r.stderr
    assert problem in r.stderr and str(d / "bad.csv") in r.stderr and "Traceback" not in r.stderr
    assert not (d / "out.csv").exists()


def test_retarget_bad_source(files):
    d, X, Y, lab, names = files
    np.savez(d / "holes.npz", markers=X[:3], frames=np.array([0, 1, 5]))
    r = run("retarget", str(d / "holes.npz"), str(d / "labels.csv"), "-o", str(d / "o.csv"))
    assert r.returncode == 2 and "frame 2 is absent" in r.stderr
    r = run("retarget", str(d / "missing.csv"), str(d / "labels.csv"), "-o", str(d / "o.csv"))
    assert r.returncode == 2 and "file not found" in r.stderr
    r = run("retarget", str(d / "actor.csv"), str(d / "labels.csv"), "-o", str(d / "o.txt"))
    assert r.returncode == 2 and "unsupported marker-sequence format" in r.stderr


def test_bench_noise_small(tmp_path, face_model):
    import csv

    out = tmp_path / "nz"
    r = run("bench", "noise", "--sequences", "2", "--frames", "40", "--levels", "0,0.5", "--synthetic-only",
            "--quiet", "--methods", "rbf;tangent-exact=tangent:beta=None,ridge=0.0001,source_smoothing=0;tangent",
            "--out", str(out))
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(out / "noise.csv")))
    assert len(rows) == 2 * 2 * 2 * 3  # sequences x kinds x levels x methods
    err = {}
    for x in rows:
        err.setdefault((x["method"], x["kind"], float(x["sigma_mm"])), []).append(float(x["mean_mm"]))
    for kind in ("labels", "source"):  # noise hurts the exact configuration; the default degrades far less
        assert np.mean(err[("tangent-exact", kind, 0.5)]) > np.mean(err[("tangent-exact", kind, 0.0)])
        assert np.mean(err[("tangent", kind, 0.5)]) < 0.8 * np.mean(err[("tangent-exact", kind, 0.5)])
    assert (out / "noise.png").stat().st_size > 1000
    r = run("bench", "noise", "--levels", "a,b")
    assert r.returncode == 2 and "--levels" in r.stderr


def test_bench_animate_small(tmp_path, face_model):
    import csv

    out = tmp_path / "an"
    r = run("bench", "animate", "--sequences", "1", "--frames", "20", "--labels", "5", "--synthetic-only", "--quiet",
            "--retargeters", "copy;tangent", "--out", str(out))
    assert r.returncode == 0, r.stderr
    rows = {x["retargeter"]: x for x in csv.DictReader(open(out / "animate.csv"))}
    assert set(rows) == {"copy", "tangent"}
    assert float(rows["tangent"]["marker_mm"]) < float(rows["copy"]["marker_mm"])
    assert float(rows["tangent"]["face_mm"]) < 1.0  # the driven character stays within a millimetre of its faces
