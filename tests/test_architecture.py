"""The dependency rule of ARCHITECTURE.md, read from the source: one direction, no cycles.

Layers (a module imports only from its own layer or below):

1. core: errors, interfaces, registry, constants, native, version
2. files and numerics: io/, geometry, linalg, metrics
3. the model: model/ (face, rig, targets, camera, pose, landmarks, layouts, ...) and vision/ (pixels to face
   points: the face detector, the face-mesh and iris models and their map onto the face model)
4. methods: methods/ and ``facegeom.baselines`` (the repository's ``baselines/`` folder)
5. pipelines that compose methods: pipelines/ (animate, cleanup, batch)
6. front ends that run methods for people: bench/ (comparison protocols) and
   ``facegeom.viewer`` (the repository's ``viewer/`` folder); siblings, neither imports the other
7. the command line: cli/ and ``python -m facegeom``, which wires every front end

The package root ``facegeom/__init__.py`` is the public facade (lazy re-exports of the main
classes, :func:`facegeom.create`): it sits above everything and nothing inside the project
imports a name from it. An internal module imports each name from the module that defines
it (``from facegeom import registry`` is a submodule import, which is fine;
``from facegeom import TangentDeformer`` is not).

Every import counts, also one inside a function (a lazy import is still a
dependency). facegeom's own modules other than ``facegeom.baselines`` reach the baselines
only through entry points. A new module must be placed in a layer here, so this test also
fails on a module nobody placed.
"""
from __future__ import annotations

import ast
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# repository folder -> installed package (pyproject.toml's [tool.setuptools] package-dir)
PACKAGES = {"facegeom": "facegeom", "baselines": "facegeom.baselines", "viewer": "facegeom.viewer"}
FACADE = "facegeom"  # the package root: above every layer, imported by nobody inside the project

LAYERS: dict[str, int] = {
    "facegeom.errors": 1,
    "facegeom.interfaces": 1,
    "facegeom.registry": 1,
    "facegeom.constants": 1,
    "facegeom.native": 1,
    "facegeom.version": 1,
    "facegeom.io": 2,
    "facegeom.geometry": 2,
    "facegeom.linalg": 2,
    "facegeom.metrics": 2,
    "facegeom.registration": 2,
    "facegeom.model": 3,
    "facegeom.vision": 3,
    "facegeom.methods": 4,
    "facegeom.baselines": 4,
    "facegeom.pipelines": 5,
    "facegeom.bench": 6,
    "facegeom.viewer": 6,
    "facegeom.cli": 7,
    "facegeom.__main__": 7,
}
NAMES = {1: "core", 2: "files/numerics", 3: "model", 4: "methods", 5: "pipelines", 6: "bench/viewer", 7: "cli",
         8: "package root"}
SIBLINGS = ("facegeom.bench", "facegeom.viewer")  # same layer, but neither may import the other


def module_name(path: Path) -> str:
    """The installed module name of a source file (``baselines/rbf.py`` -> ``facegeom.baselines.rbf``)."""
    folder, *parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGES[folder], *parts])


def modules() -> dict[str, Path]:
    out = {}
    for folder in PACKAGES:
        for p in sorted((ROOT / folder).rglob("*.py")):
            out[module_name(p)] = p
    return out


MODULES = modules()


def layer_of(mod: str) -> int | None:
    if mod == FACADE:
        return max(NAMES)
    best = None
    for prefix, layer in LAYERS.items():
        if (mod == prefix or mod.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[0])):
            best = (prefix, layer)
    return None if best is None else best[1]


def imports_of(mod: str, path: Path) -> list[tuple[str, int]]:
    """Internal modules imported by ``mod`` (anywhere in the file), with line numbers.

    ``from facegeom import registry`` counts as an import of ``facegeom.registry`` only;
    ``from facegeom import X`` for anything that is not a submodule counts as an import of
    the package root.
    """
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in MODULES]
            whole = target != FACADE or len(subs) < len(node.names)
            names = ([target] if whole else []) + subs
        else:
            continue
        for n in names:
            if n.split(".")[0] == "facegeom":
                out.append((n, node.lineno))
    return out


GRAPH = {m: imports_of(m, p) for m, p in MODULES.items()}


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if layer_of(m) is None]
    assert not missing, f"place these modules in a layer (tests/test_architecture.py LAYERS): {missing}"


def test_no_upward_imports():
    bad = []
    for mod, deps in GRAPH.items():
        lm = layer_of(mod)
        for dep, line in deps:
            ld = layer_of(dep)
            if ld is not None and lm is not None and ld > lm:
                bad.append(f"{MODULES[mod].relative_to(ROOT)}:{line}: {mod} ({NAMES[lm]}) imports {dep} ({NAMES[ld]})")
    assert not bad, "imports that point up the layers:\n" + "\n".join(bad)


def _family(mod: str) -> str | None:
    return next((s for s in SIBLINGS if mod == s or mod.startswith(s + ".")), None)


def test_bench_and_viewer_do_not_import_each_other():
    bad = [f"{mod} imports {dep}" for mod, deps in GRAPH.items() for dep, _ in deps
           if _family(mod) and _family(dep) and _family(mod) != _family(dep)]
    assert not bad, bad


def _in(mod: str, pkg: str) -> bool:
    return mod == pkg or mod.startswith(pkg + ".")


def test_facegeom_reaches_baselines_only_through_entry_points():
    """Only the baselines themselves import ``facegeom.baselines``; everything else asks the registry."""
    bad = [f"{mod} imports {dep}" for mod, deps in GRAPH.items() if not _in(mod, "facegeom.baselines")
           for dep, _ in deps if _in(dep, "facegeom.baselines")]
    assert not bad, bad


def test_nothing_inside_imports_names_from_the_package_root():
    """The root is the public facade: internal code imports from the defining module."""
    bad = [f"{MODULES[mod].relative_to(ROOT)}:{line}: {mod} imports from the package root"
           for mod, deps in GRAPH.items() for dep, line in deps if dep == FACADE and mod != FACADE]
    assert not bad, "import these from the module that defines them:\n" + "\n".join(bad)


def test_the_source_folders_are_the_installed_packages():
    """PACKAGES here is pyproject's package-dir mapping, so the layer table speaks of installed names."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    assert {v: k for k, v in config["package-dir"].items()} == PACKAGES
    folders = sorted(module_name(p.parent / "__init__.py") for folder in PACKAGES for p in (ROOT / folder).rglob("__init__.py"))
    data = sorted(set(config["packages"]) - set(folders))
    assert sorted(set(config["packages"]) - set(data)) == folders, \
        "list every package in pyproject's [tool.setuptools] packages"
    for name in data:  # data folders (no Python), listed so that setuptools ships them without a warning
        path = ROOT.joinpath(*name.split("."))
        assert path.is_dir() and not list(path.glob("*.py")) and name in config["package-data"], name
    assert {"facegeom.data.heads", "facegeom.vision.data"} <= set(data)


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    out.append(sorted(comp))
    return out


def test_no_import_cycles():
    graph = {m: {d for d, _ in deps if d in MODULES and d != m} for m, deps in GRAPH.items()}
    cycles = [c for c in strongly_connected(graph) if len(c) > 1]
    assert not cycles, f"import cycles: {cycles}"


def test_the_rule_catches_an_upward_import_and_a_cycle():
    """The checks above can fail: a made-up graph with one upward import and one cycle."""
    assert layer_of("facegeom.io.mesh") == 2 and layer_of("facegeom.cli.main") == 7
    assert layer_of("facegeom.viewer.app") == 6 and layer_of("facegeom.baselines.rbf") == 4
    assert layer_of("facegeom") == 8 and layer_of("facegeom.unplaced") is None
    assert module_name(ROOT / "baselines" / "rbf.py") == "facegeom.baselines.rbf"
    assert layer_of("facegeom.model.rig") < layer_of("facegeom.pipelines.batch")
    cyc = strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}})
    assert sorted(map(len, cyc)) == [1, 3]


FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]+")


@pytest.mark.parametrize("mod", sorted(m for m in MODULES if (layer_of(m) or 6) < 6))
def test_library_errors_do_not_name_command_line_flags(mod):
    """Below the front ends an error speaks of arguments and files; the CLI adds the flag names."""
    tree = ast.parse(MODULES[mod].read_text(encoding="utf-8"))
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            for sub in ast.walk(node.exc):
                if isinstance(sub, ast.Constant) and isinstance(sub.value, str) and FLAG.search(sub.value):
                    bad.append(f"line {sub.lineno}: {sub.value!r}")
    assert not bad, bad
