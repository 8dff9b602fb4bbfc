"""griffe extension: the packages that install under ``facegeom`` from other folders of the repository.

``pyproject.toml`` maps the repository's top-level ``baselines/`` and ``viewer/`` folders to
``facegeom.baselines`` and ``facegeom.viewer`` (``[tool.setuptools] package-dir``). griffe reads the
``facegeom`` package from its folder and would not find them there, so the API reference could not
document them under the names users import. This extension reads the same mapping and, once
``facegeom`` is loaded, adds each mapped folder's modules as its submodules.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import griffe

ROOT = Path(__file__).resolve().parents[2]


def package_dirs() -> dict[str, Path]:
    """Installed package name -> its folder, for the packages mapped outside the top package's own folder."""
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    out = {}
    for name, folder in setup.get("package-dir", {}).items():
        path = ROOT / folder
        if "." in name and path != ROOT / name.replace(".", "/"):
            out[name] = path
    return out


class PackageDirs(griffe.Extension):
    """Load ``facegeom.baselines`` and ``facegeom.viewer`` from the folders ``pyproject.toml`` maps them to."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs) -> None:
        """Attach each mapped package below ``pkg`` once ``pkg`` is loaded."""
        for name, folder in sorted(package_dirs().items()):
            parent_path, _, leaf = name.rpartition(".")
            if parent_path != pkg.path or leaf in pkg.members:
                continue
            module = self._visit(leaf, folder / "__init__.py", pkg, loader)
            pkg.set_member(leaf, module)
            for path in sorted(folder.glob("*.py")):
                if path.name != "__init__.py":
                    module.set_member(path.stem, self._visit(path.stem, path, module, loader))

    @staticmethod
    def _visit(name: str, path: Path, parent: griffe.Module, loader: griffe.GriffeLoader) -> griffe.Module:
        code = path.read_text(encoding="utf-8")
        loader.lines_collection[path] = code.splitlines()
        return griffe.visit(name, filepath=path, code=code, parent=parent, extensions=loader.extensions,
                            docstring_parser=loader.docstring_parser, docstring_options=loader.docstring_options,
                            lines_collection=loader.lines_collection, modules_collection=loader.modules_collection)
