"""Integers read from text files: ids and frame numbers must fit int64 (the arrays that hold them)."""
from __future__ import annotations

from facegeom.errors import InputError

__all__ = ["INT64_MIN", "INT64_MAX", "check_int64"]

INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def check_int64(value: int, what: str, line_no: int, path) -> int:
    """Return ``value`` when it fits a signed 64-bit integer, else a one-line error naming the file and line.

    Parameters
    ----------
    value : int
        A parsed integer (Python ints are unbounded).
    what : str
        The column, e.g. ``vertex_id`` or ``frame``.
    line_no : int
        Its line in the file (1-based).
    path : str or PathLike
        The file.

    Returns
    -------
    int

    Raises
    ------
    InputError
        ``line N: WHAT V does not fit a 64-bit integer``.
    """
    if not INT64_MIN <= value <= INT64_MAX:
        shown = str(value) if len(str(value)) <= 30 else f"{str(value)[:12]}...({len(str(value))} digits)"
        raise InputError(f"line {line_no}: {what} {shown} does not fit a 64-bit integer", path)
    return value
