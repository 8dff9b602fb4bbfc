"""Atomic writes, output checks and the CSV prologue shared by every CSV reader of :mod:`facegeom.io`.

Every writer of facegeom writes to a temporary file in the destination folder
and renames it into place (:func:`atomic_path`; :func:`all_or_nothing` for a
group of files), so an interrupted or failed write never leaves a
half-written file. The new file gets the permissions a plain ``open()`` would
give it (``0o666`` less the umask), or those of the file it replaces; a
symbolic link is written through (its target is replaced, the link stays).
Errors name the output, never the temporary file.

Hard links: the rename replaces the directory entry, so an output that had
other hard links is *detached* from them (they keep the old content). This is
kept on purpose: the atomic rename is what guarantees that no reader ever
sees a half-written file, and an in-place rewrite that would update every
link cannot give that guarantee. No data is lost (the other names keep the
previous version), and an output hard-linked to an *input* of the same
command is refused by :func:`check_outputs` before anything runs.

:func:`check_outputs` refuses an output that is an input of the same command
or two outputs that are the same file. :func:`read_csv_rows` turns a missing,
folder or non-text path into a one-line :class:`~facegeom.errors.InputError`
naming the file.
"""
from __future__ import annotations

import contextlib
import csv
import io as _io
import os
import secrets
import stat
from pathlib import Path
from typing import Iterable, Sequence

from facegeom.errors import InputError

__all__ = ["atomic_path", "sweep_stale_temporaries", "new_file_mode", "all_or_nothing", "check_outputs", "check_writable_folder", "same_file",
           "read_csv_rows", "iter_csv_rows", "parse_csv_text"]


def _umask() -> int:
    """The process umask (read from /proc when possible, so it is never changed even briefly)."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def new_file_mode() -> int:
    """The mode a new file gets from ``open()``: ``0o666`` less the process umask."""
    return 0o666 & ~_umask()


#: A temporary file or folder of an output untouched this long (seconds) belongs to a write that was killed: the
#: next write of the same output removes it. A running write keeps touching its file (chunks of frames, shapes),
#: and none of facegeom's writes takes an hour.
STALE_TEMPORARY_S = 3600.0


def _temporary_pattern(target: Path):
    import re

    if target.suffix:
        file = re.escape(f".{target.stem}.") + r"[0-9a-f]{8}" + re.escape(f".tmp{target.suffix}")
    else:
        file = re.escape(f".{target.name}-") + r"[0-9a-f]{8}-tmp"
    folder = re.escape(f".{target.name}.") + r"[a-z0-9_]{8}"  # tempfile.mkdtemp(prefix=".NAME.")
    return re.compile(file), re.compile(folder)


def sweep_stale_temporaries(folder: Path, target: Path, now: float | None = None) -> list:
    """Remove the temporaries of ``target`` (``.STEM.XXXXXXXX.tmp.EXT`` files of :func:`atomic_path`,
    ``.NAME.XXXXXXXX`` folders of a rig folder's write) in ``folder`` untouched for
    :data:`STALE_TEMPORARY_S`: what a killed write left. Symbolic links and anything else are never touched;
    errors are ignored (another process may sweep at the same time) -> the paths removed."""
    import shutil
    import time

    now = time.time() if now is None else now
    file_re, dir_re = _temporary_pattern(target)
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        is_file = file_re.fullmatch(entry.name) is not None
        is_dir = dir_re.fullmatch(entry.name) is not None
        if not (is_file or is_dir):
            continue
        try:
            st = entry.stat(follow_symlinks=False)
            if now - st.st_mtime < STALE_TEMPORARY_S:
                continue
            if is_file and stat.S_ISREG(st.st_mode):
                os.unlink(entry.path)
            elif is_dir and stat.S_ISDIR(st.st_mode):
                shutil.rmtree(entry.path)
            else:
                continue
            removed.append(Path(entry.path))
        except OSError:
            continue
    return removed


def _create_temporary(folder: Path, target: Path, mode: int, shown: Path) -> Path:
    """Create an empty ``.STEM.XXXXXXXX.tmp.EXT`` in ``folder`` with ``mode`` (less the umask, as ``open()``).

    An error (e.g. a folder that is not writable) names ``shown``, the output.
    """
    for _ in range(100):
        # keeps the suffix (writers pick the format by it); no suffix stays no suffix
        name = f".{target.stem}.{secrets.token_hex(4)}.tmp{target.suffix}" if target.suffix \
            else f".{target.name}-{secrets.token_hex(4)}-tmp"
        tmp = folder / name
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), mode)
        except FileExistsError:
            continue
        except OSError as exc:
            _rename_in_exception(exc, tmp, shown)
            raise
        os.close(fd)
        return tmp
    raise FileExistsError(17, "no free temporary file name", str(shown))  # pragma: no cover


def _rename_in_exception(exc: BaseException, tmp: Path, path: Path) -> None:
    """Make ``exc`` name ``path`` wherever it names the temporary file ``tmp`` (in place)."""
    full, base = str(tmp), tmp.name

    def fix(text):
        if not isinstance(text, str):
            return text
        return text.replace(full, str(path)).replace(base, path.name)

    if isinstance(exc, OSError):
        for attr in ("filename", "filename2"):
            value = getattr(exc, attr, None)
            if isinstance(value, (str, os.PathLike)) and os.fspath(value) in (full, base):
                setattr(exc, attr, str(path))
        if exc.filename2 is not None and os.fspath(exc.filename2) == os.fspath(exc.filename):
            exc.filename2 = None  # a failed rename names the output once
    with contextlib.suppress(Exception):
        if any(isinstance(a, str) and (full in a or base in a) for a in exc.args):
            exc.args = tuple(fix(a) for a in exc.args)
    if isinstance(exc, InputError) and exc.path is not None:
        exc.path = fix(exc.path)
        exc.reason = fix(exc.reason)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    Parameters
    ----------
    path : str or os.PathLike
        The output. When it is a symbolic link, its (final) target is written
        instead, so the link stays a link.

    Yields
    ------
    Path
        An empty temporary file in the destination folder, named
        ``.STEM.XXXXXXXX.tmp.EXT`` (it keeps ``path``'s suffix: libigl picks the
        format by it; ``.NAME-XXXXXXXX-tmp`` when ``path`` has no suffix). Its mode is that of the file being replaced, else
        ``0o666`` less the umask (what ``open()`` gives a new file).

    Raises
    ------
    InputError
        The destination folder does not exist.

    Notes
    -----
    On any exception the temporary file is removed, ``path`` is untouched and
    the exception is re-raised naming ``path`` instead of the temporary file.
    The rename replaces the directory entry: a hard link of the old file keeps
    the old content (see the module notes).
    """
    shown = Path(path)
    target = Path(os.path.realpath(shown)) if os.path.islink(shown) else shown
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise InputError("output folder does not exist", folder)
    try:
        old = os.stat(target)
    except OSError:
        old = None
    mode = stat.S_IMODE(old.st_mode) if old is not None and stat.S_ISREG(old.st_mode) else 0o666
    sweep_stale_temporaries(folder, target)
    tmp = _create_temporary(folder, target, mode, shown)
    try:
        if old is not None and stat.S_ISREG(old.st_mode):
            os.chmod(tmp, mode)  # exactly the old mode (the umask applied at creation)
            st = os.stat(tmp)
            if (st.st_uid, st.st_gid) != (old.st_uid, old.st_gid):
                with contextlib.suppress(OSError):  # keep the group (and owner, as root) when allowed
                    os.chown(tmp, old.st_uid, old.st_gid)
        yield tmp
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        _rename_in_exception(exc, tmp, shown)
        raise


@contextlib.contextmanager
def all_or_nothing(paths: Sequence[str | os.PathLike]):
    """Yield temporary paths for ``paths``; rename them all into place only if the block succeeds.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        The outputs, each written as by :func:`atomic_path` (modes, symbolic
        links, error names). Two of them being the same file is refused
        (:func:`check_outputs`) before anything is created.

    Yields
    ------
    list of Path
        One temporary file per output, in the same order.
    """
    check_outputs((), paths)
    with contextlib.ExitStack() as stack:
        yield [stack.enter_context(atomic_path(p)) for p in paths]


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` are the same file: same resolved path, or (both existing) the same inode.

    Symbolic links are followed, and hard links of one file count as the same
    file (:func:`os.path.samefile`).
    """
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _inode(path: str | os.PathLike):
    """``(device, inode)`` of the existing file ``path`` (symbolic links followed), else None."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def check_outputs(inputs: Iterable, outputs: Iterable) -> None:
    """Refuse outputs that would overwrite an input of the same command, or each other.

    Parameters
    ----------
    inputs : iterable of str or os.PathLike or None
        The files (or folders) the command reads; None entries are skipped.
        An output inside an input *folder* (e.g. a rig folder of OBJs) counts
        as changing that input.
    outputs : iterable of str or os.PathLike or None
        The files the command writes; None entries are skipped.

    Raises
    ------
    InputError
        Naming both paths: an output is the same file as an input (same
        resolved path, a symbolic link to it or a hard link of it), lies inside
        an input folder, or two outputs are the same file.
    """
    ins = [(i, os.path.realpath(i), _inode(i), os.path.isdir(i)) for i in inputs if i is not None]
    seen: dict = {}  # resolved path or inode of an output -> that output
    for o in (o for o in outputs if o is not None):
        real, inode = os.path.realpath(o), _inode(o)
        for i, i_real, i_inode, i_dir in ins:
            if i_dir and not os.path.isdir(o):
                if Path(i_real) in Path(real).parents:
                    raise InputError(f"is inside the input folder {i}: refusing to change an input; "
                                     "write the output elsewhere", o)
            elif real == i_real or (inode is not None and inode == i_inode):
                raise InputError(f"is also an input ({i}): refusing to overwrite it; write the output to "
                                 "another file", o)
        for key in (real, inode):
            if key is not None and key in seen:
                raise InputError(f"is the same file as another output ({seen[key]}): give each output its own "
                                 "file", o)
        seen[real] = o
        if inode is not None:
            seen[inode] = o


def check_writable_folder(path: str | os.PathLike) -> None:
    """Refuse ``path`` as an output early if its folder cannot be written (before a long computation).

    The closest existing folder above ``path`` (missing folders are created by
    the writer) must allow creating a file: a probe file is created and
    removed, which also catches read-only file systems and works as root.

    Raises
    ------
    InputError
        Naming ``path``: it is a folder, something above it is not a folder,
        or the folder is not writable.
    """
    p = Path(path)
    if p.is_dir():
        raise InputError("is a folder, not a file", p)
    folder = p.parent if str(p.parent) else Path(".")
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"cannot write here: {folder} is not a folder", p)
    probe = folder / f".{p.stem}.{secrets.token_hex(4)}.probe"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except OSError as exc:
        raise InputError(f"cannot write here: the folder {folder} is not writable ({exc.strerror})", p) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def _check_csv_path(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError(f"is a folder, not a {what} file", path)


def read_csv_rows(path: Path, what: str) -> list[list[str]]:
    """Every row of the text CSV ``path`` (blank rows included, so indices are line numbers - 1).

    One-line errors naming ``path``: missing, a folder (``what`` names the
    expected kind of file), not decodable as UTF-8 text.
    """
    _check_csv_path(path, what)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    return parse_csv_text(text, path)


def iter_csv_rows(path: Path, what: str):
    """The rows of the text CSV ``path`` one at a time, as ``(line_number, row)``, never the whole file in memory.

    For files that may be large (captures of hundreds of megabytes): memory
    stays at one row plus what the caller keeps. The same one-line errors as
    :func:`read_csv_rows`; a decoding error or a malformed row found part-way
    names its line.
    """
    _check_csv_path(path, what)
    try:
        f = open(path, encoding="utf-8-sig", newline="")
    except OSError as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    with f:
        reader = csv.reader(f)
        try:
            for row in reader:
                yield reader.line_num, row
        except UnicodeDecodeError:
            raise InputError(f"line {reader.line_num + 1}: cannot read as text (UnicodeDecodeError)", path) from None
        except csv.Error as exc:
            raise InputError(f"line {reader.line_num}: not a CSV row ({exc})", path) from None
        except OSError as exc:
            raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None


def parse_csv_text(text: str, path) -> list[list[str]]:
    """The rows of CSV ``text`` read from ``path``; a malformed one (a cell over the csv module's 131,072
    characters, a NUL) as one :class:`InputError` line naming the file and the line."""
    reader = csv.reader(_io.StringIO(text))
    rows = []
    try:
        for r in reader:
            rows.append(r)
    except csv.Error as exc:
        raise InputError(f"line {reader.line_num}: not a CSV row ({exc})", path) from None
    return rows

