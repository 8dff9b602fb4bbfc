"""Helpers shared by the benchmark protocols: method specs and timing (reports: :mod:`facegeom.bench.report`)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from facegeom import registry
from facegeom.errors import InputError

__all__ = ["MethodSpec", "parse_method", "parse_methods", "median_time"]


@dataclass(frozen=True)
class MethodSpec:
    """A method to benchmark: ``label=name:key=value,key=value`` (label and params optional)."""

    label: str
    name: str
    params: dict = field(default_factory=dict)

    def build(self, kind: str):
        return registry.create(kind, self.name, **self.params)


def _value(text: str):
    t = text.strip()
    low = t.lower()
    if t in ("None", "null"):  # lowercase "none" stays a word (e.g. align=none)
        return None
    if low in ("true", "false"):
        return low == "true"
    for cast in (int, float):
        try:
            return cast(t)
        except ValueError:
            pass
    return t


def parse_method(spec: str) -> MethodSpec:
    """Parse ``[label=]name[:k=v,k=v]``; e.g. ``tangent-paper=tangent:d=3,rings=1``."""
    spec = spec.strip()
    label = None
    head, _, params = spec.partition(":")
    if "=" in head:
        label, head = head.split("=", 1)
    kv = {}
    if params:
        for item in params.split(","):
            if "=" not in item:
                raise InputError(f"bad method spec {spec!r}: parameter {item!r} needs key=value")
            k, v = item.split("=", 1)
            kv[k.strip()] = _value(v)
    return MethodSpec(label or spec, head.strip(), kv)


def parse_methods(text: str, kind: str, defaults: list[str]) -> list[MethodSpec]:
    """``all`` -> ``defaults``; else ``;``-separated specs (``,`` separates params)."""
    specs = [parse_method(s) for s in (defaults if text == "all" else text.split(";")) if s.strip()]
    known = registry.available(kind)
    for s in specs:
        if s.name not in known:
            raise InputError(f"no {kind[:-1]} named {s.name!r}; available: {', '.join(known)}")
    return specs


def median_time(fn, repeat: int = 5) -> tuple[float, object]:
    """Median wall time of ``fn()`` over ``repeat`` calls (seconds) and the last result."""
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out
