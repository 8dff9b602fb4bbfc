"""The daily command-line paths load only what they use (see also tests/test_startup.py for the helps).

- ``facegeom.io`` and ``facegeom.model`` resolve their names on first use: a module of either package imports
  none of its siblings it does not need (a C3D read imports no glTF reader, a rig no scipy.sparse);
- ``facegeom solve`` on a capture imports neither the glTF nor the mesh readers, nor the marker layouts' graph
  (scipy.sparse.csgraph), nor tqdm for a short capture;
- the face model reads its identity modes when they are first used, and they are what the bundle holds;
- the rig loading's shortcuts (the finite check, the facing cue, the frame conversion) give the same numbers,
  bit for bit, as the plain formulas they replace.

Each import check runs in a fresh interpreter.
"""
from __future__ import annotations

import json
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pytest

from facegeom.model._checks import _first_nonfinite
from facegeom.model.units import RigFrame, _facing


def _modules_after(code: str) -> set[str]:
    """The modules a fresh interpreter holds after running ``code``."""
    r = subprocess.run([sys.executable, "-c", code + "\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"],
                       check=False, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return set(json.loads(r.stdout.strip().splitlines()[-1]))


def _within(modules, package: str) -> list[str]:
    return sorted(m for m in modules if m == package or m.startswith(package + "."))


@pytest.mark.parametrize("code, absent", [
    ("import facegeom.io", ["numpy", "facegeom.io.gltf", "facegeom.io.takes"]),
    ("import facegeom.model", ["numpy", "facegeom.model.face", "facegeom.model.layouts"]),
    ("from facegeom.io.markerseq import read_marker_sequence",
     ["facegeom.io.gltf", "facegeom.io.takes", "facegeom.io.fitfiles", "facegeom.io.formats", "scipy"]),
    ("from facegeom.model.rig import BlendshapeRig; from facegeom.model.face import load_face_model",
     ["facegeom.model.layouts", "facegeom.model.scenarios", "facegeom.io.formats", "facegeom.io.gltf", "scipy"]),
    ("from facegeom.model.inputs import load_rig", ["facegeom.io.fitfiles", "facegeom.io.gltf", "scipy"]),
    ("import facegeom.pipelines.solve", ["facegeom.io.gltf", "facegeom.io.delivery", "facegeom.io.fitfiles",
                                         "scipy.sparse.csgraph", "tqdm"]),
    ("import facegeom.pipelines.character", ["facegeom.registration", "scipy.spatial", "facegeom.io.gltf"]),
])
def test_a_module_imports_only_what_it_uses(code, absent):
    modules = _modules_after(code)
    assert [m for m in absent if _within(modules, m)] == []


def test_the_packages_still_give_every_public_name_and_submodule():
    import facegeom.io as io
    import facegeom.model as model

    for package in (io, model):
        assert set(package.__all__) <= set(dir(package))
        for name in package.__all__:
            value = getattr(package, name)
            assert getattr(sys.modules[package._LAZY[name]], name) is value
    assert model.layouts is sys.modules["facegeom.model.layouts"] and io.gltf is sys.modules["facegeom.io.gltf"]
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        io.no_such_name  # noqa: B018


def test_solve_imports_no_reader_it_does_not_use(tmp_path):
    """``facegeom solve`` of a short capture to a CSV: no glTF, mesh or fitting-file reader, no layout graph,
    no progress bar library."""
    from facegeom.io.markerseq import write_marker_sequence
    from facegeom.model import load_face_model

    model = load_face_model()
    ids = np.arange(0, 9000, 150)
    noise = 0.01 * np.random.default_rng(0).standard_normal((5, len(ids), 3))
    capture = write_marker_sequence(tmp_path / "take.csv", model.neutral[ids][None] + noise, np.arange(5),
                                    [f"v{i}" for i in ids])
    code = (f"import sys\nfrom facegeom.cli import main\nsys.argv = ['facegeom', 'solve', {str(capture)!r}, '-o', "
            f"{str(tmp_path / 'curves.csv')!r}]\ntry:\n    main()\nexcept SystemExit as exc:\n    assert not exc.code\n")
    modules = _modules_after(code)
    assert (tmp_path / "curves.csv").is_file()
    unused = ["facegeom.io.gltf", "facegeom.io.delivery", "facegeom.io.usd", "facegeom.io.fitfiles",
              "facegeom.io.formats", "facegeom.model.scenarios", "scipy.sparse.csgraph", "tqdm",
              "facegeom.registration"]
    assert [m for m in unused if _within(modules, m)] == []


def test_the_identity_modes_are_read_on_first_use(face_model):
    from facegeom.model.face import FaceModel, load_bundle, load_face_model
    from facegeom.model.rig import BlendshapeRig

    model = load_face_model()
    assert not isinstance(model.__dict__["identity_modes"], np.ndarray)  # not read by loading
    rig = BlendshapeRig.from_face_model(model)
    assert not isinstance(model.__dict__["identity_modes"], np.ndarray)  # nor by the rig of the expressions
    np.testing.assert_array_equal(rig.deltas, BlendshapeRig.from_face_model(face_model).deltas)
    assert rig.population is model and model.n_identities == len(load_bundle()["identity_names"])
    again = pickle.loads(pickle.dumps(model))  # a model not read yet still pickles
    modes = model.identity_modes
    assert modes.dtype == np.float32 and model.identity_modes is modes  # read once, then kept
    np.testing.assert_array_equal(modes, load_bundle()["identity_modes"])
    np.testing.assert_array_equal(again.identity_modes, modes)
    assert [f.name for f in __import__("dataclasses").fields(FaceModel)][5:7] == ["identity_names", "identity_modes"]


def test_a_bad_identity_mode_is_still_an_error_when_read(tmp_path):
    from facegeom.errors import InputError
    from facegeom.model.face import load_bundle, load_face_model

    arrays = {k: v for k, v in load_bundle().items() if k != "_path"}
    arrays["identity_modes"] = arrays["identity_modes"].copy()
    arrays["identity_modes"][3, 7, 1] = np.nan
    np.savez_compressed(tmp_path / "ict_face_light.npz", **arrays)
    with pytest.raises(InputError, match="identity_modes contains NaN or inf"):
        load_bundle(tmp_path)
    model = load_face_model(tmp_path)  # the expressions alone are fine
    with pytest.raises(InputError, match="identity_modes contains NaN or inf"):
        model.identity_modes  # noqa: B018
    arrays["identity_modes"] = arrays["identity_modes"][:, :5]
    np.savez_compressed(tmp_path / "ict_face_light.npz", **arrays)
    with pytest.raises(InputError, match=r"identity_modes must be \(I, 9409, 3\), is \(100, 5, 3\)"):
        load_face_model(tmp_path)


def test_the_first_nonfinite_entry_is_found_as_before():
    rng = np.random.default_rng(1)
    a = rng.standard_normal((4, 50, 3))
    assert _first_nonfinite(a) is None
    for bad in (np.nan, np.inf, -np.inf):
        b = a.copy()
        b[2, 17, 1] = bad
        assert _first_nonfinite(b) == (2, 17, 1)
    huge = np.full((3, 2), 1e308)  # finite entries whose sum is not (and no overflow warning)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _first_nonfinite(huge) is None
        b = a.copy()
        b[0, 1, 2], b[1, 1, 1] = np.inf, -np.inf
        assert _first_nonfinite(b) == (0, 1, 2)
    assert _first_nonfinite(np.zeros((0, 3))) is None


def test_the_facing_cue_sums_as_the_plain_formula(face_model):
    V = np.asarray(face_model.neutral, dtype=np.float64)
    F = face_model.triangles
    D = np.asarray(face_model.expression_deltas, dtype=np.float64)
    motion = np.sqrt((D ** 2).sum(axis=2)).sum(axis=0)  # the formula the loop replaces
    P = V[F]
    cross = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    outward = float(np.einsum("fi,fi->", cross, P.mean(axis=1) - V.mean(axis=0)))
    expected = (-1.0 if outward < 0 else 1.0) * (motion[F].mean(axis=1)[:, None] * cross).sum(axis=0)
    assert _facing(V, F, D).tobytes() == expected.tobytes()


def test_the_frame_conversion_is_the_product_then_the_scale():
    X = np.random.default_rng(2).standard_normal((3, 40, 3)) * 10
    for frame in (RigFrame("mm", "z", "", "", turned=True), RigFrame("m", "y", "", ""), RigFrame("cm", "y", "", "")):
        expected = (X @ frame.rotation.T) * frame.scale
        assert frame.to_facegeom(X).tobytes() == expected.tobytes()
