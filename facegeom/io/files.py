"""Atomic writes and the CSV prologue shared by every CSV reader of :mod:`facegeom.io`.

Every writer of facegeom writes to a temporary file in the destination folder
and renames it into place (:func:`atomic_path`; :func:`all_or_nothing` for a
group of files), so an interrupted or failed write never leaves a
half-written file. :func:`read_csv_rows` turns a missing, folder or non-text
path into a one-line :class:`~facegeom.errors.InputError` naming the file.
"""
from __future__ import annotations

import contextlib
import csv
import io as _io
import os
import tempfile
from pathlib import Path
from typing import Sequence

from facegeom.errors import InputError

__all__ = ["atomic_path", "all_or_nothing", "read_csv_rows"]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The temporary file keeps ``path``'s suffix (libigl picks the format by it).
    On any exception the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", folder)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=folder)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise



@contextlib.contextmanager
def all_or_nothing(paths: Sequence[str | os.PathLike]):
    """Yield temporary paths for ``paths``; rename them all into place only if the block succeeds."""
    with contextlib.ExitStack() as stack:
        yield [stack.enter_context(atomic_path(p)) for p in paths]


def read_csv_rows(path: Path, what: str) -> list[list[str]]:
    """Every row of the text CSV ``path`` (blank rows included, so indices are line numbers - 1).

    One-line errors naming ``path``: missing, a folder (``what`` names the
    expected kind of file), not decodable as UTF-8 text.
    """
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError(f"is a folder, not a {what} file", path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    return list(csv.reader(_io.StringIO(text)))

