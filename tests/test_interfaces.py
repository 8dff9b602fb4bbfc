"""The method contracts of facegeom.interfaces: parameters, batched calls, errors in argument words."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from facegeom import registry
from facegeom.cli.flags import ARGUMENT_FLAGS, as_flags
from facegeom.errors import InputError
from facegeom.interfaces import FitResult, NotFittedError, batched_targets, deform_many, fit_many
from facegeom.io import read_retarget_inputs, write_marker_sequence
from facegeom.model import BlendshapeRig, MeshTarget, PointCloudTarget, look_at_camera, read_fit_target
from tests.conftest import grid_mesh

METHODS = [(kind, name) for kind in registry.KINDS for name in registry.available(kind)]


def _create(kind, name, **params):
    try:
        return registry.create(kind, name, **params)
    except InputError as exc:  # an optional peer that is not installed (eos)
        pytest.skip(str(exc))


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(a, b)
    return a == b and type(a) is type(b)


def _same_params(p, q) -> bool:
    return list(p) == list(q) and all(_same(p[k], q[k]) for k in p)


def tiny_rig(B=5, n=30, seed=0):
    rng = np.random.default_rng(seed)
    return BlendshapeRig(rng.normal(size=(n, 3)), rng.normal(size=(B, n, 3)), [f"s{i}" for i in range(B)],
                         np.array([[0, 1, 2], [2, 3, 4]]))


# --------------------------------------------------------------------------- parameters


@pytest.mark.parametrize("kind,name", METHODS)
def test_get_set_clone_round_trip(kind, name):
    m = _create(kind, name)
    cls = registry.get(kind, name)
    p = m.get_params()
    assert list(p) == list(cls.param_names())  # read from the __init__ signature, in its order
    assert _same_params(registry.create(kind, name, **p).get_params(), p)
    c = m.clone()
    assert type(c) is type(m) and c is not m and _same_params(c.get_params(), p)
    assert m.set_params(**p) is m and _same_params(m.get_params(), p)


@pytest.mark.parametrize("kind,name", METHODS)
def test_set_params_unknown_name_names_it_and_the_valid_ones(kind, name):
    m = _create(kind, name)
    with pytest.raises(InputError, match="no parameter 'bogus'") as e:
        m.set_params(bogus=1)
    assert all(k in str(e.value) for k in m.param_names())


def test_set_params_checks_values_like_the_constructor_and_keeps_the_old_ones():
    d = registry.create("deformers", "tangent")
    assert d.set_params(d=3, smoothness=0) is d
    assert d.get_params()["d"] == 3 and d.get_params()["smoothness"] == 0.0
    with pytest.raises(InputError, match="d must be 1, 2 or 3"):
        d.set_params(d=7, rings=2)
    assert d.d == 3 and d.rings == 1


@pytest.mark.parametrize("kind,name", [(k, n) for k, n in METHODS if k in ("deformers", "retargeters")])
def test_clone_is_unfitted(kind, name):
    m = _create(kind, name)
    if kind == "deformers":
        V, F = grid_mesh(6, 6, bump=0.2)
        m.fit(V, F, np.array([0, 5, 30, 35, 14]))
        with pytest.raises(NotFittedError):
            m.clone().deform(V[[0, 5, 30, 35, 14]])
    else:
        S = np.random.default_rng(0).normal(size=(12, 4, 3))
        m.fit(S, np.array([0, 4, 8, 11]), S[[0, 4, 8, 11]] + 1.0)
        with pytest.raises(NotFittedError):
            m.clone().transform()


# --------------------------------------------------------------------------- batched calls


@pytest.mark.parametrize("name", ["rbf", "tangent"])
def test_deform_many_equals_deform_per_frame(name):
    V, F = grid_mesh(7, 7, bump=0.3)
    H = np.array([0, 6, 42, 48, 24, 10])
    d = registry.create("deformers", name).fit(V, F, H)
    P = V[H][None] + np.random.default_rng(1).normal(scale=0.05, size=(5, H.size, 3))
    Y = deform_many(d, P)
    one = np.stack([d.deform(p) for p in P])
    assert Y.shape == (5, V.shape[0], 3)
    if name == "rbf":  # no batched method: the loop itself
        assert np.array_equal(Y, one)
    else:
        np.testing.assert_allclose(Y, one, rtol=0, atol=1e-12)
    with pytest.raises(InputError, match=r"\(F, k, 3\)"):
        deform_many(registry.create("deformers", "rbf").fit(V, F, H), P[0])


class _FitOnly:
    """A fitter with ``fit`` alone: ``fit_many`` must loop."""

    def __init__(self):
        self.inner = registry.create("fitters", "sem")

    def fit(self, rig, target):
        return self.inner.fit(rig, target)


def test_fit_many_fallback_equals_fit_per_target():
    rig = tiny_rig()
    rng = np.random.default_rng(2)
    targets = [MeshTarget(rig.evaluate(rng.uniform(0, 1, rig.n_shapes))) for _ in range(3)]
    targets.append(PointCloudTarget(rig.evaluate(rng.uniform(0, 1, rig.n_shapes))))
    f = _FitOnly()
    assert batched_targets(f) == frozenset()
    res = fit_many(f, rig, targets)
    assert len(res) == 4 and all(isinstance(r, FitResult) for r in res)
    for r, t in zip(res, targets):
        one = f.fit(rig, t)
        assert np.array_equal(r.weights, one.weights) and np.array_equal(r.vertices, one.vertices)
        assert r.info["time_s"] >= 0


@pytest.mark.parametrize("name", ["sem", "l1reg", "pcaexp"])
def test_fit_many_fast_paths_equal_fit(name):
    rig = tiny_rig(B=4, n=40, seed=3)
    rng = np.random.default_rng(4)
    W = rng.uniform(0, 1, (5, rig.n_shapes)) * (rng.random((5, rig.n_shapes)) < 0.6)
    meshes = rig.neutral[None] + np.tensordot(W, rig.deltas, 1)
    f = registry.create("fitters", name)
    assert "mesh" in batched_targets(f)
    from_array = fit_many(f, rig, meshes)
    from_targets = fit_many(f, rig, [MeshTarget(V) for V in meshes])
    for a, b, V in zip(from_array, from_targets, meshes):
        one = f.fit(rig, MeshTarget(V))
        assert np.array_equal(a.weights, b.weights)
        np.testing.assert_allclose(a.weights, one.weights, atol=1e-5)
        np.testing.assert_allclose(a.vertices, one.vertices, atol=1e-4)
        assert a.info["time_s"] >= 0


def test_batched_targets_of_the_registered_fitters():
    assert batched_targets(registry.create("fitters", "sem")) == {"mesh", "landmarks"}
    assert batched_targets(registry.create("fitters", "l2reg")) == {"mesh"}


def test_fit_result_evaluates_a_lazy_face_once():
    calls = []
    r = FitResult(np.ones(2), lambda: calls.append(1) or np.zeros((3, 3)))
    assert not calls
    assert r.vertices.shape == (3, 3) and r.vertices.shape == (3, 3) and calls == [1]
    assert r.info == {}


# --------------------------------------------------------------------------- errors: arguments, flags on the CLI


def test_library_error_names_the_argument(tmp_path):
    X = np.random.default_rng(0).normal(size=(6, 2, 3))
    X[2, 1] = np.nan
    write_marker_sequence(tmp_path / "gappy.csv", X, names=["a", "b"])
    write_marker_sequence(tmp_path / "labels.csv", X[[0, 5]], frames=[0, 5], names=["a", "b"])
    with pytest.raises(InputError) as e:
        read_retarget_inputs(tmp_path / "gappy.csv", tmp_path / "labels.csv")
    msg = str(e.value)
    assert "pass fill=True to interpolate them over time" in msg and "--fill-gaps" not in msg
    assert "pass --fill-gaps to interpolate them over time" in as_flags(msg)


def test_every_phrase_translates_to_flags():
    for phrase, flags in ARGUMENT_FLAGS.items():
        assert "--" not in phrase and "--" in flags
        assert as_flags(f"x {phrase} y") == f"x {flags} y"


def test_cli_shows_the_flag_for_the_same_error(tmp_path, face_model):
    rig = BlendshapeRig.from_face_model(face_model)
    ids = rig.landmark_ids[:5]
    uv = look_at_camera(rig.neutral).project(rig.neutral[ids])
    path = tmp_path / "lm.csv"
    path.write_text("vertex_id,u,v\n" + "".join(f"{i},{u},{v}\n" for i, (u, v) in zip(ids, uv)))
    with pytest.raises(InputError) as e:
        read_fit_target(path, rig, "landmarks")
    assert "the camera: focal, cx and cy" in str(e.value) and "--focal" not in str(e.value)
    r = subprocess.run([sys.executable, "-m", "facegeom", "fit", str(path), "-o", str(tmp_path / "w.json")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert "facegeom: error:" in r.stderr and "the camera: --focal, --cx and --cy (pixels)" in r.stderr


@pytest.mark.parametrize("name", sorted(registry.available("retargeters")))
@pytest.mark.parametrize("where", ["source", "labels"])
def test_a_retargeter_refuses_coordinates_no_geometry_reaches(name, where):
    """1e308 is finite, but its square is not: one line naming the argument, not an overflow deep inside."""
    rng = np.random.default_rng(0)
    S = rng.normal(size=(50, 10, 3))
    lab = np.array([0, 10, 25, 49])
    Y = 1.1 * S[lab]
    (S if where == "source" else Y)[1, 2, 0] = 1e308
    with pytest.raises(InputError, match=r"coordinate of 1e\+308 .*beyond 1e\+12"):
        _create("retargeters", name).fit(S, lab, Y)


@pytest.mark.parametrize("name", sorted(registry.available("deformers")))
def test_a_deformer_refuses_coordinates_no_geometry_reaches(name):
    V, F = grid_mesh(8, 8, bump=0.3)
    handles = np.array([0, 7, 27, 56, 63])
    P = V[handles].copy()
    P[1, 0] = -1e200
    deformer = _create("deformers", name).fit(V, F, handles)
    with pytest.raises(InputError, match=r"coordinate of -1e\+200 .*beyond 1e\+12"):
        deformer.deform(P)


@pytest.mark.parametrize("name", sorted(registry.available("fitters")))
@pytest.mark.parametrize("kind", ["mesh", "cloud", "markers", "landmarks"])
def test_a_fitters_target_refuses_coordinates_no_geometry_reaches(name, kind):
    from facegeom.model import LandmarkTarget, MarkerTarget

    rig = tiny_rig()
    V = rig.neutral.copy()
    V[3, 1] = 1e308
    ids = np.arange(0, 30, 3)
    make = {"mesh": lambda: MeshTarget(V), "cloud": lambda: PointCloudTarget(V),
            "markers": lambda: MarkerTarget(V[ids], ids),
            "landmarks": lambda: LandmarkTarget(V[ids, :2] + [320.0, 240.0], ids, look_at_camera(rig.neutral))}[kind]
    with pytest.raises(InputError, match=r"coordinate of 1e\+308.*beyond 1e\+12"):
        _create("fitters", name).fit(rig, make())
