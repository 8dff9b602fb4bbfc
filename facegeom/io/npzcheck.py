"""What an ``.npz`` says against what it holds, before any array is loaded.

An ``.npz`` is a zip of ``.npy`` members, each with a header that declares its
array's shape and dtype. ``numpy.load`` allocates what the header declares
before reading the data, so a 4.6 MB file declaring 4.5 GB of deltas used to
be allocated (and then fail with a traceback). :func:`check_npz` reads only the
zip directory and each member's header: a member that declares more bytes than
it holds, an object array, or arrays larger than this machine can spare are
refused in one line naming the file and the member. :func:`npz_members` returns what each key declares (for a
reader's own limits: a rig's shapes and vertices, :meth:`facegeom.model.rig.BlendshapeRig.read_npz`).
"""
from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from math import prod
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = ["NpzMember", "check_npz", "check_text", "memory_budget", "npz_members"]


#: No dimension of a real array reaches this (2**40 elements of one byte are a terabyte); a larger one, with a
#: zero elsewhere in the shape so that no bytes are declared, made numpy fail with an OverflowError.
MAX_DIMENSION = 1 << 40
#: Items of zero width (``<U0``, ``S0``, ``V0``) a member may declare: their count is not bounded by bytes.
MAX_EMPTY_ITEMS = 1 << 20


def memory_budget() -> int:
    """Bytes a file's arrays may take: half of this machine's memory (8 GiB when it cannot be told)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")) // 2
    except (ValueError, OSError, AttributeError):
        return 8 << 30


def _mb(n: int) -> str:
    return f"{n / 1e6:,.1f} MB" if n < 1e9 else f"{n / 1e9:,.1f} GB"


def _header(fh):
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(fh)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(fh)
    return np.lib.format._read_array_header(fh, version)  # 3.0: a utf-8 header, same fields


@dataclass(frozen=True)
class NpzMember:
    """What one member of an npz declares, read from the zip directory and the member's header (nothing loaded).

    ``key`` is the name ``numpy.load`` gives it (without ``.npy``); ``shape`` and ``dtype`` are None for a member
    that is not an array (``numpy.load`` returns its bytes); ``nbytes`` is what it takes once loaded, ``stored``
    what it takes in the file (compressed)."""

    key: str
    shape: tuple | None
    dtype: np.dtype | None
    nbytes: int
    stored: int


def check_npz(path: str | os.PathLike, budget: int | None = None) -> int:
    """Check every member's declared array against the bytes it holds -> the arrays' total bytes.

    Raises
    ------
    InputError
        Not a zip; a member whose header cannot be read; an object array (a
        pickle); a member declaring more bytes than it holds; arrays larger in
        all than ``budget`` (default :func:`memory_budget`).
    """
    return sum(m.nbytes for m in _check(Path(path), budget)[0])


def npz_members(path: str | os.PathLike, budget: int | None = None) -> dict[str, NpzMember]:
    """:func:`check_npz`'s checks -> what each key of the file declares, as ``numpy.load(path)[key]`` reads it.

    ``numpy.load`` reads a member called ``KEY`` as the key ``KEY`` even without the ``.npy`` suffix (and
    prefers it to ``KEY.npy``): such a member is checked like the others when it starts as an array does.
    """
    members, by_name = _check(Path(path), budget)
    keys = {m.key for m in members}
    return {k: by_name.get(k) or by_name[k + ".npy"] for k in keys if k in by_name or k + ".npy" in by_name}


def _check(path: Path, budget: int | None) -> tuple[list[NpzMember], dict[str, NpzMember]]:
    budget = memory_budget() if budget is None else int(budget)
    total = 0
    members: list[NpzMember] = []
    by_name: dict[str, NpzMember] = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                npy = info.filename.endswith(".npy")
                name = info.filename[:-4] if npy else info.filename
                if not npy:  # numpy.load reads it as an array if it starts as one, else returns its bytes
                    try:
                        with zf.open(info) as fh:
                            is_array = fh.read(len(np.lib.format.MAGIC_PREFIX)) == np.lib.format.MAGIC_PREFIX
                    except Exception:  # noqa: BLE001 - unreadable (encrypted, an unknown method): not an array
                        is_array = False  # numpy can load; a reader that asks for it is told it is not one
                    if not is_array:
                        m = NpzMember(name, None, None, int(info.file_size), int(info.compress_size))
                        members.append(m)
                        by_name[info.filename] = m
                        total += m.nbytes
                        if total > budget:
                            raise InputError(f"its arrays need more than {_mb(budget)}, more than this machine can "
                                             f"spare (half of its memory)", path)
                        continue
                try:
                    with zf.open(info) as fh:
                        shape, _, dtype = _header(fh)
                        start = fh.tell()
                except Exception as exc:  # noqa: BLE001 - numpy parses the header text of any bytes: a header cut
                    # open fails in its tokenizer, an unknown format version in an attribute lookup; all are the file's
                    raise InputError(f"array {name!r}: unreadable header ({type(exc).__name__})", path) from None
                if dtype.hasobject:
                    raise InputError(f"array {name!r} holds Python objects (a pickle), which are not read", path)
                dims = [int(s) for s in shape]
                if any(d > MAX_DIMENSION for d in dims):
                    raise InputError(f"array {name!r} declares a dimension of {max(dims):,}, more than any array "
                                     f"holds: a damaged or forged file", path)
                count = prod(dims)
                if dtype.itemsize == 0 and count > MAX_EMPTY_ITEMS:
                    # items of no bytes cost nothing to hold but a loop over them costs time all the same
                    raise InputError(f"array {name!r} declares {count:,} items of zero width: a damaged or forged "
                                     f"file", path)
                need = count * dtype.itemsize
                held = info.file_size - start
                if need > held:
                    raise InputError(f"array {name!r} declares shape {tuple(shape)} ({_mb(need)}) but holds "
                                     f"{_mb(max(held, 0))}: a damaged or forged file", path)
                m = NpzMember(name, tuple(dims), dtype, int(need), int(info.compress_size))
                members.append(m)
                by_name[info.filename] = m
                total += need
                if total > budget:
                    raise InputError(f"its arrays need more than {_mb(budget)}, more than this machine can spare "
                                     f"(half of its memory)", path)
    except zipfile.BadZipFile:
        raise InputError("cannot read as npz (not a zip archive)", path) from None
    except UnicodeDecodeError:  # the zip flags a member's name as UTF-8 and it is not (zipfile decodes it on opening)
        raise InputError("cannot read as npz (a member's name is flagged as UTF-8 text but is not)", path) from None
    except NotImplementedError as exc:  # a zip version or compression method Python's zipfile does not read
        raise InputError(f"cannot read as npz ({exc})", path) from None
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    return members, by_name


def check_text(array: np.ndarray, name: str, path) -> None:
    """Refuse a text array (numpy ``U``) of an npz holding code points no string has (above U+10FFFF): numpy
    cannot turn them into Python strings and fails with a SystemError."""
    a = np.asarray(array)
    if a.dtype.kind == "U" and a.size and a.dtype.itemsize:
        points = np.ascontiguousarray(a).view(np.uint32)
        if points.size and int(points.max()) > 0x10FFFF:
            raise InputError(f"'{name}' holds characters no text has: a damaged file", path)
