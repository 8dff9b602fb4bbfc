"""One batch job per output folder: a lock held from the manifest check to the summary.

Two runs into one folder would delete each other's temporary files (the resume
cleanup of :func:`~facegeom.pipelines.batch.ledger.remove_stale_temporaries`)
and race on the manifest and the summary, so :func:`output_lock` refuses a
second run at once (it does not wait) with ``another batch job (pid N) is
writing to FOLDER``.

The lock is an exclusive ``flock`` on the file :data:`LOCK_NAME` in the output
folder; the file holds the owner's pid and host for that message. The kernel
drops a ``flock`` when its process ends, however it ends (a crash, SIGKILL, a
lost node with NFS lock recovery), so a lock file left behind by a dead process
is *stale by construction*: the next run locks it at once and takes it over;
there is no pid liveness guess and no timeout. The file is removed on a normal
exit (while still locked; a run that locked a file since unlinked retries on
the new one). Where ``fcntl`` is missing (Windows) the folder is not locked.
"""
from __future__ import annotations

import contextlib
import json
import os
import socket
from pathlib import Path

from facegeom.errors import InputError

__all__ = ["LOCK_NAME", "output_lock"]

LOCK_NAME = ".facegeom-batch.lock"


def _holder(fd: int) -> str:
    """``pid N`` (and the host when it is another machine) from a locked file, or ``unknown pid``."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
        pid, host = int(info["pid"]), str(info.get("host", ""))
    except (OSError, ValueError, KeyError, TypeError):
        return "unknown pid"
    return f"pid {pid}" if host in ("", socket.gethostname()) else f"pid {pid} on {host}"


@contextlib.contextmanager
def output_lock(folder: Path):
    """Hold the output folder's batch lock for the block.

    Parameters
    ----------
    folder : Path
        The output folder (it exists).

    Yields
    ------
    Path
        The lock file.

    Raises
    ------
    InputError
        Another live process holds the lock: ``another batch job (pid N) is writing to FOLDER``.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock
        yield None
        return
    path = Path(folder) / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            who = _holder(fd)
            os.close(fd)
            raise InputError(f"another batch job ({who}) is writing to {folder}; wait for it to end or choose "
                             f"another output folder") from None
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed this file as we opened it: lock the current one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode(), 0)
        yield path
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)  # releases the flock
