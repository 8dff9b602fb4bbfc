"""Parsers of clean-up options: merge tolerance and vertex-id range."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError

__all__ = ["parse_tolerance", "parse_id_range"]


def parse_tolerance(tol) -> tuple[str, float]:
    """Parse a merge tolerance: ``0`` / ``'1e-6'`` (absolute distance) or ``'0.01%'`` (of the bounding-box diagonal).

    Parameters
    ----------
    tol : float or str

    Returns
    -------
    kind : {'abs', 'percent'}
    value : float
        Non-negative; a percentage is at most 50.
    """
    if isinstance(tol, (int, float)):
        kind, value = "abs", float(tol)
    else:
        s = str(tol).strip()
        kind = "percent" if s.endswith("%") else "abs"
        try:
            value = float(s.rstrip("%"))
        except ValueError:
            raise InputError(f"merge tolerance must be a distance or a percentage like 0.01%, got {tol!r}") from None
    if not np.isfinite(value) or value < 0:
        raise InputError(f"merge tolerance must be a non-negative number, got {tol!r}")
    if kind == "percent" and value > 50:
        raise InputError(f"merge tolerance {tol!r} is more than half the bounding-box diagonal")
    return kind, value


def parse_id_range(text: str, n: int | None = None) -> tuple[int, int]:
    """``'A:B'`` -> ``(A, B)``, the half-open id range [A, B); ``A`` and ``B`` may be omitted.

    Parameters
    ----------
    text : str
        ``'A:B'``, ``'A:'`` or ``':B'``.
    n : int, optional
        Vertex count of the mesh: the default end, and the clip of ``B``.

    Returns
    -------
    (a, b) : (int, int)
        ``0 <= a < b``; ``b <= n`` when ``n`` is given.
    """
    s = str(text).strip()
    if ":" not in s:
        raise InputError(f"id range must look like A:B (half-open, e.g. 0:6706), got {text!r}")
    a_s, b_s = s.split(":", 1)
    try:
        a = int(a_s) if a_s.strip() else 0
        b = int(b_s) if b_s.strip() else (n if n is not None else -1)
    except ValueError:
        raise InputError(f"id range must hold integers, like 0:6706, got {text!r}") from None
    if b < 0 and n is None:
        raise InputError(f"id range {text!r} needs an end")
    if a < 0 or b <= a:
        raise InputError(f"id range {text!r} is empty or negative")
    if n is not None and a >= n:
        raise InputError(f"id range {text!r} starts past the {n} vertices of the mesh")
    return a, min(b, n) if n is not None else b
