"""Discover method plugins through entry points.

Groups (declared in ``pyproject.toml``, also by third-party packages):

- ``facegeom.deformers``   -> :class:`facegeom.interfaces.Deformer`
- ``facegeom.retargeters`` -> :class:`facegeom.interfaces.Retargeter`
- ``facegeom.fitters``     -> :class:`facegeom.interfaces.Fitter`

The CLI, the viewer and the comparison scripts list and build every method the
same way: ``create("deformers", "tangent", d=3)``.
"""
from __future__ import annotations

from importlib.metadata import entry_points

from facegeom.errors import InputError

KINDS = ("deformers", "retargeters", "fitters")

__all__ = ["KINDS", "available", "get", "create"]


def _group(kind: str) -> str:
    if kind not in KINDS:
        raise InputError(f"unknown method kind {kind!r}; choose one of {', '.join(KINDS)}")
    return f"facegeom.{kind}"


def available(kind: str) -> dict[str, str]:
    """Map plugin name -> ``module:Class`` for every plugin of ``kind``, sorted by name."""
    eps = entry_points(group=_group(kind))
    return {ep.name: ep.value for ep in sorted(eps, key=lambda e: e.name)}


def get(kind: str, name: str) -> type:
    """Load and return the class registered as ``name`` in ``kind``."""
    eps = {ep.name: ep for ep in entry_points(group=_group(kind))}
    if name not in eps:
        names = ", ".join(sorted(eps)) or "none installed"
        raise InputError(f"no {kind[:-1]} named {name!r}; available: {names}")
    return eps[name].load()


def create(kind: str, name: str, **params):
    """Build the method ``name`` of ``kind`` with constructor ``params``."""
    cls = get(kind, name)
    try:
        return cls(**params)
    except TypeError as exc:  # unknown keyword
        raise InputError(f"{kind[:-1]} {name!r}: {exc}") from None
