"""Native-library helpers: silence what libigl, CHOLMOD (cholespy) or pymeshlab print.

:func:`quiet_native` points the process's stdout/stderr file descriptors at the
null device for the duration of a native call, so only facegeom's own, clearer
messages are seen.
"""
from __future__ import annotations

import contextlib
import os
import sys

__all__ = ["quiet_native"]


@contextlib.contextmanager
def quiet_native(fds=(1, 2)):
    """Silence what native libraries (libigl, CHOLMOD) print on stdout/stderr.

    We raise our own, clearer message instead. Python-level output is flushed
    first so nothing of ours is lost.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    saved = []
    try:
        for fd in fds:
            try:
                saved.append((fd, os.dup(fd)))
            except OSError:  # pragma: no cover - fd closed
                continue
        with open(os.devnull, "w") as null:
            for fd, _ in saved:
                os.dup2(null.fileno(), fd)
            yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
