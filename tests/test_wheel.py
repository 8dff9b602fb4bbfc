"""The wheel a user installs: built from a copy of the source, installed into an empty virtualenv.

``python -m build --wheel`` on a copy of the repository (so the checkout gets no ``build/``
or ``*.egg-info``), then a fresh virtualenv (no system site-packages) outside the repository,
``pip install --no-deps`` of the wheel, and the commands a user runs first, from a folder that is
not the repository. The wheel's dependencies are the ones this test run has (their folder named by
a ``.pth`` file after the wheel's own, so the wheel's package is the one imported), and ``pip check``
must find every requirement the wheel declares met by them: installing the same dependencies from
the package index again (numpy, scipy, libigl, pymeshlab, polyscope: ~30 s with a warm pip cache, 2.5
minutes on a loaded machine) would test pip, not the wheel; ``make install`` installs them from the
index on every fresh machine. About 10 s.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"facegeom": "facegeom", "baselines": "facegeom/baselines", "viewer": "facegeom/viewer"}
IGNORE = shutil.ignore_patterns(".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache",
                                ".hypothesis", "out", "bench-out", "docs", "site")


def _run(cmd, cwd, env, timeout=600):
    r = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout,
                       check=False)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} exited {r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r.stdout


def _clean_env() -> dict[str, str]:
    """The environment without this test run's virtualenv or Python path."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if not p.startswith(str(Path(sys.prefix))))
    return env


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    pytest.importorskip("build", reason="the test extra installs `build`")
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=IGNORE)
    _run([sys.executable, "-m", "build", "--wheel", "--outdir", tmp / "dist", src], cwd=tmp, env=_clean_env())
    (whl,) = (tmp / "dist").glob("facegeom-*.whl")
    return whl


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> tuple[Path, Path, dict[str, str]]:
    """(bin folder of a fresh virtualenv with the wheel installed, a working folder, the environment)."""
    tmp = tmp_path_factory.mktemp("venv")
    env = _clean_env()
    _run([sys.executable, "-m", "venv", "--without-pip", tmp / "venv"], cwd=tmp, env=env)  # this run's pip installs
    bindir = tmp / "venv" / ("Scripts" if os.name == "nt" else "bin")
    pip = [sys.executable, "-m", "pip", "--python", bindir / "python"]
    _run([*pip, "install", "--quiet", "--no-deps", wheel], cwd=tmp, env=env, timeout=1200)
    site = _run([bindir / "python", "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp,
                env=env).strip()
    deps = sysconfig.get_paths()["purelib"]  # this run's dependencies (a plain path: its own .pth files stay unread,
    (Path(site) / "zz_test_dependencies.pth").write_text(deps + "\n")  # so an editable facegeom there stays off)
    checked = _run([*pip, "check"], cwd=tmp, env=env)
    assert "No broken requirements found" in checked, checked
    work = tmp / "work"
    work.mkdir()
    return bindir, work, env


def test_wheel_holds_only_the_facegeom_package(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"facegeom", wheel.name.split("-py")[0] + ".dist-info"}, sorted(tops)
    assert not any(n.startswith(("baselines/", "viewer/", "tests/")) for n in names)
    expected = {f"{FOLDERS[p.relative_to(ROOT).parts[0]]}/{p.relative_to(ROOT / p.relative_to(ROOT).parts[0]).as_posix()}"
                for folder in FOLDERS for p in (ROOT / folder).rglob("*.py")}
    assert "facegeom/baselines/rbf.py" in expected and "facegeom/viewer/app.py" in expected
    missing = sorted(expected - set(names))
    assert not missing, f"source modules missing from the wheel (pyproject's packages list?): {missing}"
    meta = {n.split("/")[-1]: n for n in names if ".dist-info/" in n}
    top_level = zipfile.ZipFile(wheel).read(meta["top_level.txt"]).decode().split() if "top_level.txt" in meta else []
    assert top_level in ([], ["facegeom"]), top_level
    entry_points = zipfile.ZipFile(wheel).read(meta["entry_points.txt"]).decode()
    assert "= baselines." not in entry_points and "facegeom.baselines.rbf:RBFDeformer" in entry_points
    # the project's own licence travels with the wheel, and so do the registries of the data it downloads
    assert "LICENSE" in meta, "no LICENSE in the wheel's metadata"
    assert zipfile.ZipFile(wheel).read(meta["LICENSE"]).decode() == (ROOT / "LICENSE").read_text()
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    assert {"facegeom/model/ICT-FaceKit-registry.txt", "facegeom/model/takes-registry.txt"} <= set(names)
    # the demo's two public heads, with their sources and licences
    assert {"facegeom/data/heads/lee_perry_smith.ply", "facegeom/data/heads/makehuman_stylised_arkit.npz",
            "facegeom/data/heads/SOURCES.md"} <= set(names)


def test_commands_run_from_the_installed_wheel(installed):
    bindir, work, env = installed
    facegeom = bindir / "facegeom"
    helptext = _run([facegeom, "--help"], cwd=work, env=env)
    assert "Usage: facegeom" in helptext and "methods" in helptext
    listing = _run([facegeom, "methods"], cwd=work, env=env)
    assert "facegeom.baselines.rbf:RBFDeformer" in listing and "facegeom.methods.sem:SEMFitter" in listing
    commands = [line.split()[0] for line in helptext.split("Commands:")[-1].splitlines() if line.startswith("  ")
                and not line.startswith("   ")]
    assert "methods" in commands and "info" in commands, commands
    if "data" in commands:  # `facegeom data` (issue 17, part 1), once it is there
        _run([facegeom, "data", "info"], cwd=work, env=env)


def test_every_plugin_loads_and_the_api_imports_from_the_wheel(installed):
    bindir, work, env = installed
    code = (
        "import sys, importlib.util, facegeom\n"
        "from facegeom import registry\n"
        "assert 'numpy' not in sys.modules\n"
        "assert importlib.util.find_spec('baselines') is None and importlib.util.find_spec('viewer') is None\n"
        "for kind in registry.KINDS:\n"
        "    for name in registry.available(kind):\n"
        "        cls = registry.get(kind, name)\n"
        "        assert cls.__module__.startswith(('facegeom.methods.', 'facegeom.baselines.')), cls\n"
        "        try:\n"
        "            facegeom.create(kind, name)\n"
        "        except facegeom.InputError as exc:  # an optional extra: eos-py (pip install 'facegeom[eos]')\n"
        "            assert name == 'eos' and 'facegeom[eos]' in str(exc), exc\n"
        "from facegeom import (FaceModel, load_face_model, BlendshapeRig, MeshTarget, LandmarkTarget,\n"
        "    PointCloudTarget, PinholeCamera, TangentDeformer, TangentRetargeter, SEMFitter, read_mesh, write_mesh)\n"
        "import facegeom.viewer.app\n"
        "print(facegeom.__version__, facegeom.__file__)\n"
    )
    out = _run([bindir / "python", "-c", code], cwd=work, env=env)
    assert str(bindir.parent) in out and str(ROOT) not in out


def test_info_finds_the_face_data_from_the_wheel(installed, face_model):
    bindir, work, env = installed
    out = _run([bindir / "facegeom", "--data", face_model.path, "info"], cwd=work, env=env)
    assert "face data:" in out and "9409" in out


def test_no_take_from_the_wheel_says_how_to_get_one(installed, face_model, tmp_path):
    """An installed package has no repository: the error names the real places and `facegeom data fetch`."""
    bindir, work, env = installed
    env = {**env, "FACEGEOM_DATA": face_model.path, "FACEGEOM_CACHE": str(tmp_path / "cache")}
    env.pop("FACEGEOM_TAKES", None)
    r = subprocess.run([str(bindir / "facegeom"), "animate", "--frames", "10", "-o", "a.npz"], cwd=work, env=env,
                       capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "facegeom data fetch" in r.stderr and "--take FILE" in r.stderr and "--takes FOLDER" in r.stderr
    assert "shared" not in r.stderr and str(tmp_path / "cache" / "arkit-takes") in r.stderr
