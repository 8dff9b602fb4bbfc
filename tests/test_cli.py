"""End-to-end tests of the command line, run as a user would (a subprocess)."""
import os
import subprocess
import sys

import pytest

from facegeom import registry
from facegeom.errors import InputError
from facegeom.interfaces import Deformer


def run(*args, env=None):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "facegeom", *args], capture_output=True, text=True, env=e,
                          timeout=120)


def test_info_shows_real_data(face_model):
    r = run("info")
    assert r.returncode == 0, r.stderr
    assert "ict_face_light.npz" in r.stdout and "9409" in r.stdout and "53" in r.stdout
    assert "libigl" in r.stdout and "pymeshlab" in r.stdout


def test_data_option_and_env(tmp_path, face_model):
    r = run("--data", str(tmp_path), "info")
    assert r.returncode == 2
    assert r.stderr.startswith("facegeom: error:") and str(tmp_path) in r.stderr
    assert "Traceback" not in r.stderr and r.stdout == ""
    r = run("info", env={"FACEGEOM_DATA": face_model.path})
    assert r.returncode == 0 and face_model.path in r.stdout


def test_methods_lists_plugins():
    r = run("methods")
    assert r.returncode == 0
    for kind in ("deformers:", "retargeters:", "fitters:"):
        assert kind in r.stdout
    assert "tangent" in r.stdout and "laplacian" in r.stdout


@pytest.mark.parametrize("args", [["--help"], ["info", "--help"], ["methods", "--help"], ["demo", "--help"]])
def test_help_everywhere(args):
    r = run(*args)
    assert r.returncode == 0 and "Usage:" in r.stdout


def test_usage_error_exit_2():
    r = run("info", "--bogus")
    assert r.returncode == 2 and "No such option" in r.stderr and "Traceback" not in r.stderr


def test_registry_errors():
    with pytest.raises(InputError, match="no deformer named 'nope'"):
        registry.get("deformers", "nope")
    with pytest.raises(InputError, match="unknown method kind"):
        registry.available("widgets")


def test_every_registered_deformer_builds_with_no_arguments():
    for name in registry.available("deformers"):
        obj = registry.create("deformers", name)
        assert isinstance(obj, Deformer), name


def test_facegeom_does_not_import_baselines():
    code = ("import sys, facegeom, facegeom.cli.main, facegeom.model.face, facegeom.io.mesh, facegeom.geometry, "
            "facegeom.registry, facegeom.linalg; "
            "print(any(m == 'facegeom.baselines' or m.startswith('facegeom.baselines.') for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip()
    assert out == "False"
