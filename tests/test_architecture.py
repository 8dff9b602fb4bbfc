"""The dependency rule of ARCHITECTURE.md, read from the source: one direction, no cycles.

Layers (a module imports only from its own layer or below):

1. core: errors, interfaces, registry, constants, native
2. files and numerics: io/, geometry, linalg, metrics
3. the model: model/ (face, rig, targets, camera, pose, landmarks, layouts, ...)
4. methods: methods/ and the top-level ``baselines`` package
5. pipelines that compose methods: pipelines/ (animate, cleanup, batch)
6. front ends that run methods for people: bench/ (comparison protocols) and the
   ``viewer`` package; siblings, neither imports the other
7. the command line: cli/ and ``python -m facegeom``, which wires every front end

Every import counts, also one inside a function (a lazy import is still a
dependency). ``facegeom`` reaches ``baselines`` only through entry points.
A new module must be placed in a layer here, so this test also fails on a
module nobody placed.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("facegeom", "baselines", "viewer")

LAYERS: dict[str, int] = {
    "facegeom": 1,  # the package root: version and the error classes only
    "facegeom.errors": 1,
    "facegeom.interfaces": 1,
    "facegeom.registry": 1,
    "facegeom.constants": 1,
    "facegeom.native": 1,
    "facegeom.io": 2,
    "facegeom.geometry": 2,
    "facegeom.linalg": 2,
    "facegeom.metrics": 2,
    "facegeom.model": 3,
    "facegeom.methods": 4,
    "baselines": 4,
    "facegeom.pipelines": 5,
    "facegeom.bench": 6,
    "viewer": 6,
    "facegeom.cli": 7,
    "facegeom.__main__": 7,
}
NAMES = {1: "core", 2: "files/numerics", 3: "model", 4: "methods", 5: "pipelines", 6: "bench/viewer", 7: "cli"}
SIBLINGS = ("facegeom.bench", "viewer")  # same layer, but neither may import the other


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            out[module_name(p)] = p
    return out


MODULES = modules()


def layer_of(mod: str) -> int | None:
    best = None
    for prefix, layer in LAYERS.items():
        if (mod == prefix or mod.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[0])):
            best = (prefix, layer)
    return None if best is None else best[1]


def imports_of(mod: str, path: Path) -> list[tuple[str, int]]:
    """Internal modules imported by ``mod`` (anywhere in the file), with line numbers."""
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
            names = [target] + [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in MODULES]
        else:
            continue
        for n in names:
            if n.split(".")[0] in PACKAGES:
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


def test_facegeom_reaches_baselines_only_through_entry_points():
    bad = [f"{mod} imports {dep}" for mod, deps in GRAPH.items() if mod.startswith("facegeom")
           for dep, _ in deps if dep.split(".")[0] == "baselines"]
    assert not bad, bad


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
    assert layer_of("facegeom.io.mesh") == 2 and layer_of("facegeom.cli.main") == 7 and layer_of("viewer.app") == 6
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
