"""The public Python API: ``from facegeom import ...`` (lazy names) and ``facegeom.create``."""
from __future__ import annotations

import importlib
import re
import subprocess
import sys

import numpy as np
import pytest

import facegeom
from facegeom.errors import InputError

PUBLIC = {
    "FaceModel": "facegeom.model.face",
    "load_face_model": "facegeom.model.face",
    "BlendshapeRig": "facegeom.model.rig",
    "MeshTarget": "facegeom.model.targets",
    "LandmarkTarget": "facegeom.model.targets",
    "PointCloudTarget": "facegeom.model.targets",
    "MarkerTarget": "facegeom.model.targets",
    "solve_markers": "facegeom.methods.marker_solve",
    "PinholeCamera": "facegeom.model.camera",
    "TangentDeformer": "facegeom.methods.tangent",
    "TangentRetargeter": "facegeom.methods.tangent_retarget",
    "SEMFitter": "facegeom.methods.sem",
    "SEMLSFitter": "facegeom.methods.sem",
    "IdentityFitter": "facegeom.methods.identity",
    "read_mesh": "facegeom.io.mesh",
    "write_mesh": "facegeom.io.mesh",
    "create": "facegeom.registry",
    "FacegeomError": "facegeom.errors",
    "InputError": "facegeom.errors",
    "DataNotFoundError": "facegeom.errors",
    "__version__": "facegeom.version",
}


def _run(code: str) -> str:
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_name_is_the_defining_modules_object(name):
    assert name in facegeom.__all__ and name in dir(facegeom)
    assert getattr(facegeom, name) is getattr(importlib.import_module(PUBLIC[name]), name)


def test_all_lists_exactly_the_public_names():
    assert sorted(facegeom.__all__) == sorted(PUBLIC)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'TangentDeformr'"):
        facegeom.TangentDeformr  # noqa: B018
    with pytest.raises(ImportError):
        from facegeom import TangentDeformr  # noqa: F401


def test_import_facegeom_loads_no_numerics():
    out = _run("import sys, facegeom; "
               "print(sorted(m for m in ('numpy', 'scipy', 'igl', 'pymeshlab', 'polyscope', 'dask', 'click') "
               "if m in sys.modules))")
    assert out == "[]"


def test_a_public_name_loads_only_what_it_needs():
    out = _run("import sys, facegeom; facegeom.read_mesh; print('numpy' in sys.modules, "
               "any(m.startswith('facegeom.methods') for m in sys.modules))")
    assert out == "True False"


def test_import_time_is_small():
    """``python -X importtime -c "import facegeom"``: the cumulative time of the package, in microseconds."""
    r = subprocess.run([sys.executable, "-X", "importtime", "-c", "import facegeom"], capture_output=True, text=True,
                       timeout=120, check=False)
    line = [s for s in r.stderr.splitlines() if re.search(r"\|\s*facegeom$", s)]
    assert line, r.stderr
    cumulative_us = int(line[-1].split("|")[1])
    assert cumulative_us < 300_000, line[-1]


@pytest.mark.parametrize("kind", ["deformer", "deformers"])
def test_create_takes_the_kind_in_singular_or_plural(kind):
    d = facegeom.create(kind, "tangent", d=3, rings=1)
    assert isinstance(d, facegeom.TangentDeformer)
    assert d.get_params()["d"] == 3 and d.get_params()["rings"] == 1


def test_create_builds_every_kind():
    assert isinstance(facegeom.create("retargeter", "tangent"), facegeom.TangentRetargeter)
    assert isinstance(facegeom.create("fitter", "sem", alternations=2), facegeom.SEMFitter)
    assert type(facegeom.create("deformer", "rbf")).__module__ == "facegeom.baselines.rbf"


def test_create_errors_name_what_is_known():
    with pytest.raises(InputError, match=r"unknown method kind 'widget'; choose one of deformer, retargeter, fitter"):
        facegeom.create("widget", "tangent")
    with pytest.raises(InputError, match=r"no fitter named 'nope'; available: .*sem"):
        facegeom.create("fitter", "nope")
    with pytest.raises(InputError, match=r"deformer 'tangent' has no parameter 'dd'; valid parameters: neighbourhood, rings"):
        facegeom.create("deformer", "tangent", dd=3)
    with pytest.raises(InputError, match="d must be"):
        facegeom.create("deformer", "tangent", d="banana")


def test_identity_fitter_is_public_and_created_by_kind(face_model):
    """``from facegeom import IdentityFitter``; ``create("identity")`` is one (the kind's default, ``facegeom``)."""
    from facegeom import IdentityFitter, registry
    from facegeom.model import LandmarkTarget, PinholeCamera, look_at_camera

    assert IdentityFitter is importlib.import_module("facegeom.methods.identity").IdentityFitter
    assert type(facegeom.create("identity")) is IdentityFitter
    fitter = facegeom.create("identity", "facegeom", expressions=False, rounds=5)
    assert type(fitter) is IdentityFitter and fitter.get_params()["expressions"] is False
    assert set(registry.available("identity")) >= {"facegeom"}
    V = face_model.face(face_model.random_identity(1))  # a person's neutral face, seen slightly from the side
    cam = look_at_camera(V, yaw=15.0)
    ids = face_model.landmarks
    fit = fitter.fit(face_model, LandmarkTarget(cam.project(V[ids]), ids, PinholeCamera(cam.focal, cam.cx, cam.cy)))
    assert fit.identity.shape == (face_model.n_identities,) and np.abs(fit.weights).max() < 1e-6
    assert fit.info["rms"][0] < 0.5 and fit.rig.n_shapes == face_model.n_expressions


def test_create_identity_errors_name_what_is_known():
    with pytest.raises(InputError, match=r"no identity named 'nope'; available: .*facegeom"):
        facegeom.create("identity", "nope")
    with pytest.raises(InputError, match=r"identity 'facegeom' has no parameter 'nois_px'; valid parameters: noise_px"):
        facegeom.create("identity", "facegeom", nois_px=2)
    with pytest.raises(InputError, match=r"which fitter\? name one: .*sem-ls"):
        facegeom.create("fitter")
    with pytest.raises(InputError, match=r"choose one of deformer, retargeter, fitter, identity \(or the plural: "
                                         r"deformers, retargeters, fitters\)"):
        facegeom.create("identities")
