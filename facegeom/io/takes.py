"""Real facial performances: Live Link Face CSV takes of ARKit blendshape weights.

File format
-----------
Apple's Live Link Face app exports one CSV per take. The header is::

    Timecode,BlendShapeCount,EyeBlinkLeft,...,TongueOut,HeadYaw,...,RightEyeRoll

i.e. the timecode, the number of shapes (61 on a good row), the 52 ARKit
blendshape weights in PascalCase (:data:`ARKIT_NAMES`, in this order in the
app's files, though the reader finds the columns by name), then 9 head and eye
rotations (``HeadYaw, HeadPitch, HeadRoll, LeftEyeYaw, LeftEyePitch,
LeftEyeRoll, RightEyeYaw, RightEyePitch, RightEyeRoll``), which this module
does not keep.

Timecode
--------
``HH:MM:SS:FF.fff`` where ``FF.fff`` is a fractional frame number. In the
recordings seen so far the frame base is **60 fps** (``FF`` runs 00..59) while
rows come about every 2 frames (~30 rows per second), so reading ``FF`` as a
30 fps frame would make the time jump backwards at every second boundary. The
frame base is therefore inferred per file (:func:`timecode_fps`): the smallest
common rate (24, 25, 30, 48, 50, 60, 120) above the largest ``FF`` seen,
defaulting to 30 when the file shows no frame number of 30 or more (too short
to tell). ``Take.times`` are seconds from the take's first row; a passage
through midnight is unwrapped.

Lost tracking
-------------
When the face is lost the app writes rows that hold only ``timecode,0``
(``BlendShapeCount`` 0, no weights). They are counted in
:attr:`Take.lost_rows` and, by ``policy``:

``"interpolate"`` (default)
    Keep the rows (and their timecodes) and fill every weight linearly in time
    between the neighbouring good rows; lost rows before the first or after
    the last good row hold that row's values.
``"drop"``
    Remove the rows; ``times`` then has gaps.

Any other row whose column count differs from the header's is an error.

Values
------
Weights are stored exactly as read, including the small excursions outside
[0, 1] that the tracker produces (eye-look shapes reach about 1.08);
:func:`ict_weights` clips on request.

Mapping to the ICT face model
-----------------------------
ICT names are camelCase with ``_L``/``_R``: ``EyeBlinkLeft`` -> ``eyeBlink_L``,
``JawOpen`` -> ``jawOpen``. ``MouthLeft``, ``MouthRight``, ``JawLeft`` and
``JawRight`` are shapes of their own (``mouthLeft``...), not sided variants.
ARKit's single ``BrowInnerUp`` and ``CheekPuff`` drive both ICT sides;
``TongueOut`` has no ICT counterpart. "Left" is the performer's left in both.
The names and how they meet (also for other rigs' names, decorated exporter
names and mapping files) live in :mod:`facegeom.io.shape_names`; this module
re-exports :data:`ARKIT_NAMES` and :func:`arkit_to_ict_name` from there.

Writing takes
-------------
:func:`write_livelink_csv` writes weights in the app's layout (the header
above, ``BlendShapeCount`` 61, values with 10 decimals, ``HH:MM:SS:FF.fff``
timecodes), so that a solve or a fit drives anything that reads these takes.
:func:`ict_to_arkit` maps ICT weights back to the 52 ARKit names (the inverse of
:func:`ict_weights`; what it loses is listed there).
"""
from __future__ import annotations

import codecs
import csv
import io
import math
import operator
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path
from facegeom.io.shape_names import ARKIT_NAMES, ShapeMap, arkit_to_ict_name

__all__ = [
    "ARKIT_NAMES",
    "ROTATION_NAMES",
    "POLICIES",
    "Take",
    "read_take",
    "timecode_fps",
    "arkit_to_ict_name",
    "ict_weights",
    "ict_to_arkit",
    "write_livelink_csv",
    "find_takes",
    "EYE_YAW_PER_WEIGHT",
    "EYE_PITCH_PER_WEIGHT",
    "eye_rotations",
    "head_angles",
]

#: The 9 rotation columns that follow the weights (radians; kept as ``Take.rotations`` when all nine are there).
ROTATION_NAMES: tuple[str, ...] = (
    "HeadYaw", "HeadPitch", "HeadRoll",
    "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
    "RightEyeYaw", "RightEyePitch", "RightEyeRoll",
)

#: ARKit's eye turn per unit of ``eyeLookOut - eyeLookIn`` (radians). Live Link Face writes each eye's yaw and
#: pitch beside the weights; on the four real takes at hand they are linear in them (correlation -1.00):
#: LeftEyeYaw = -0.59 to -0.61 (out - in), RightEyeYaw = +0.60 to +0.62 (out - in) (both plus about 0.06 rad of
#: convergence, left out here: the neutral face looks straight ahead).
EYE_YAW_PER_WEIGHT = 0.60
#: The same for ``eyeLookUp - eyeLookDown``: both eyes' pitch = -0.48 to -0.56 (up - down); the median take 0.50.
EYE_PITCH_PER_WEIGHT = 0.50

#: Accepted values of ``read_take(policy=...)``.
POLICIES: tuple[str, ...] = ("interpolate", "drop")

_ARKIT_SET = frozenset(ARKIT_NAMES)
_FRAME_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 120.0)
_DEFAULT_FPS = 30.0
_DAY = 86400.0


@dataclass
class Take:
    """One recorded performance.

    Attributes
    ----------
    path : str
        The CSV file read.
    names : tuple of str
        The 52 ARKit weight names, in :data:`ARKIT_NAMES` order (the order of
        the columns of ``weights``, whatever the file's column order).
    weights : numpy.ndarray
        ``(T, 52)`` float64 weights as read (not clipped); interpolated on lost
        rows under ``policy="interpolate"``.
    times : numpy.ndarray
        ``(T,)`` float64 seconds from the take's first row (``times[0] == 0``).
    lost_rows : int
        Number of lost-tracking rows found in the file (whatever the policy).
    policy : str
        ``"interpolate"`` or ``"drop"``: what was done with the lost rows.
    timecode_fps : float
        Frame base used to read the timecode's frame field (see
        :func:`timecode_fps`).
    rotations : numpy.ndarray or None
        ``(T, 9)`` head and eye rotations (radians, :data:`ROTATION_NAMES`
        order) when the file has all nine columns, else None; lost rows as
        ``weights``.
    """

    path: str
    names: tuple[str, ...]
    weights: np.ndarray
    times: np.ndarray
    lost_rows: int
    policy: str
    timecode_fps: float = _DEFAULT_FPS
    rotations: np.ndarray | None = None
    start_s: float = 0.0
    """Time of day of the first row kept, in seconds (its timecode): what a take written from it starts at."""

    @property
    def n_frames(self) -> int:
        """Number of rows kept (``T``)."""
        return int(self.weights.shape[0])


# ----------------------------------------------------------------------------- reading


def read_take(path: str | os.PathLike, policy: str = "interpolate") -> Take:
    """Read a Live Link Face CSV take.

    The file is read a block of lines at a time (:data:`BLOCK_BYTES`): only
    the numbers are kept, never the rows' text, so memory follows ``T x 61``
    float64 values (about 0.5 kB a frame) whatever the take's length. The
    rows of a block that share one layout (the app's: the same cells, digits
    and decimal points, minus signs aside) are converted together with numpy;
    any other row is read on its own, as the :mod:`csv` module splits it.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.csv`` file.
    policy : {"interpolate", "drop"}
        What to do with lost-tracking rows (``timecode,0``): fill them linearly
        in time from the neighbouring good rows, or remove them.

    Returns
    -------
    Take
        Weights ``(T, 52)`` in :data:`ARKIT_NAMES` order, times in seconds from
        the first kept row, and the count of lost rows.

    Raises
    ------
    InputError
        Naming the file: a bad ``policy``; a missing, unreadable or empty file;
        a header without ``Timecode`` or lacking ARKit weight columns (named);
        a row with the wrong number of columns that is not a lost-tracking row,
        a bad timecode or a non-numeric weight (row and column named); no good
        row at all.
    """
    if policy not in POLICIES:
        raise InputError(f"policy must be one of {', '.join(repr(p) for p in POLICIES)}, got {policy!r}", path)
    p = Path(path)
    if not p.exists():
        raise InputError("take file not found", path)
    if not p.is_file():
        raise InputError("not a file (expected a Live Link Face .csv take)", path)
    try:
        with open(p, "rb") as fh:
            read = _scan(fh, path, os.fstat(fh.fileno()).st_size)
    except OSError as exc:
        raise InputError(f"cannot read the take: {exc.strerror or exc}", path) from None
    except UnicodeDecodeError:
        raise InputError("cannot read the take: not UTF-8 text", path) from None
    except csv.Error as exc:
        raise InputError(f"cannot read the take: malformed CSV ({exc})", path) from None

    n_good, n_rows = read.n_good, read.n_rows
    n_lost = n_rows - n_good
    if n_rows == 0:
        raise InputError("the take has a header but no data rows", path)
    if not n_good:
        raise InputError(f"nothing usable: all {n_lost} data rows are lost-tracking rows", path)
    if read.number_error is not None:  # the first bad cell of the good rows, as if all were converted at once
        raise read.number_error
    if read.timecode_error is not None:  # then the first bad timecode, good and lost rows in file order
        raise read.timecode_error

    frame_secs, frames, is_good = read.timecodes()  # every row, in file order
    fps = timecode_fps(frames)
    t = frame_secs + frames / fps
    t = _unwrap_midnight(t)

    weights, rotations = read.numbers()
    if policy == "drop" or not n_lost:
        times = t[is_good]
    else:  # column by column: the weights and the rotations are filled alike
        weights = _interpolate(weights, t, is_good)
        rotations = None if rotations is None else _interpolate(rotations, t, is_good)
        times = t
    return Take(
        path=str(p),
        names=ARKIT_NAMES,
        weights=weights,
        times=times - times[0],
        lost_rows=n_lost,
        policy=policy,
        timecode_fps=fps,
        rotations=rotations,
        start_s=float(times[0]),
    )


#: Rows read on their own (not in a block of one layout) converted to numbers at a time: only their cells' text
#: is held (Python strings: about 4 kB a row, 8 times its numbers).
CHUNK_ROWS = 1024
#: Bytes of the file read at a time (whole lines: a line longer than this is read whole). A block's text, its
#: signless copy and a few byte-sized arrays of it are what reading holds besides the numbers.
BLOCK_BYTES = 1 << 20
_BOM = b"\xef\xbb\xbf"


class _Column:
    """A growing ``(rows, *shape)`` array filled in order; :meth:`array` gives the rows filled.

    Sized for the rows the file is expected to hold (memory is only used as rows are filled: the pages of the
    rest are never touched); when that cannot be reserved, it starts at :data:`CHUNK_ROWS` rows; it grows by
    half when full.
    """

    def __init__(self, capacity: int, shape: tuple[int, ...] = (), dtype=np.float64):
        self.shape, self.dtype, self.size = shape, dtype, 0
        try:
            self.data = np.empty((max(int(capacity), 1), *shape), dtype=dtype)
        except MemoryError:
            self.data = np.empty((CHUNK_ROWS, *shape), dtype=dtype)

    def reserve(self, n: int) -> np.ndarray:
        """Room for ``n`` rows more -> the view to fill (the array grows by half or more when full)."""
        need = self.size + n
        if need > self.data.shape[0]:
            grown = np.empty((max(need, self.data.shape[0] * 3 // 2), *self.shape), self.dtype)
            grown[:self.size] = self.data[:self.size]
            self.data = grown
        view = self.data[self.size:need]
        self.size = need
        return view

    def array(self) -> np.ndarray:
        """The filled rows (a view: the rows never filled were never touched)."""
        return self.data[:self.size]


class _Scanned:
    """The rows of a take as :func:`_scan` reads them: the numbers of the good rows, the timecodes of all rows in
    file order, and the first bad cell and bad timecode found (raised by :func:`read_take` after the checks that
    come first).

    Rows arrive one at a time (:meth:`row`: held as text, converted :data:`CHUNK_ROWS` at a time) or as runs of
    good rows already converted (:meth:`run`), always in file order.
    """

    def __init__(self, rows: int, columns: list[int], header: list[str], path, size: int):
        K = len(ARKIT_NAMES)
        self.columns, self.header, self.path = columns, header, path
        rows = min(rows, size // 4 + 1)  # a row has 4 bytes at least ("t,0" and its line break)
        good = min(rows, size // len(header) + 1)  # a good row has a comma between its cells and a line break
        self.weights = _Column(good, (K,))
        self.rotations = _Column(good, (len(columns) - K,)) if len(columns) > K else None
        self.secs = _Column(rows)
        self.frames = _Column(rows)
        self.good = _Column(rows, dtype=bool)
        self.n_good = 0
        self.number_error: InputError | None = None
        self.timecode_error: InputError | None = None
        self._secs: list[float] = []  # the rows not yet stored (at most CHUNK_ROWS)
        self._frames: list[float] = []
        self._good: list[bool] = []
        self._cells: list[tuple[str, ...]] = []
        self._lines: list[int] = []

    @property
    def n_rows(self) -> int:
        """Data rows read (good and lost; blank lines aside)."""
        return self.good.size + len(self._good)

    def row(self, line: int, timecode: str, cells: tuple[str, ...] | None) -> None:
        """One data row: ``cells`` the picked cells of a good row, None for a lost-tracking row."""
        secs = frame = 0.0
        if self.timecode_error is None:
            try:
                secs, frame = _parse_timecode(timecode, line, self.path)
            except InputError as exc:
                self.timecode_error = exc
        self._secs.append(secs)
        self._frames.append(frame)
        self._good.append(cells is not None)
        if cells is not None:
            self.n_good += 1
            if self.number_error is None:
                self._cells.append(cells)
                self._lines.append(line)
        if len(self._good) >= CHUNK_ROWS:
            self.flush()

    def run(self, line: int, secs: np.ndarray, frames: np.ndarray, in_range: np.ndarray, numbers: np.ndarray,
            timecode) -> None:
        """Good rows on lines ``line, line + 1, ...``, converted: their timecodes (``in_range``: minutes and
        seconds within range; ``timecode(i)`` the text of row ``i``'s) and ``numbers (n, columns)``."""
        if self._good:
            self.flush()  # the rows held come first
        n = secs.size
        if self.timecode_error is None and not in_range.all():
            i = int(np.argmin(in_range))
            try:
                _parse_timecode(timecode(i), line + i, self.path)
            except InputError as exc:
                self.timecode_error = exc
        self.secs.reserve(n)[:] = secs
        self.frames.reserve(n)[:] = frames
        self.good.reserve(n)[:] = True
        self.n_good += n
        if self.number_error is None:
            K = len(ARKIT_NAMES)
            self.weights.reserve(n)[:] = numbers[:, :K]
            if self.rotations is not None:
                self.rotations.reserve(n)[:] = numbers[:, K:]

    def flush(self) -> None:
        """Store the rows held as numbers (the first bad cell is kept, and no cell converted after it)."""
        n = len(self._good)
        self.secs.reserve(n)[:] = self._secs
        self.frames.reserve(n)[:] = self._frames
        self.good.reserve(n)[:] = self._good
        cells, lines = self._cells, self._lines
        self._secs, self._frames, self._good, self._cells, self._lines = [], [], [], [], []
        if not cells or self.number_error is not None:
            return
        try:
            W = _to_float(cells, lines, self.columns, self.header, self.path)
        except InputError as exc:
            self.number_error = exc
            return
        K = len(ARKIT_NAMES)
        self.weights.reserve(W.shape[0])[:] = W[:, :K]
        if self.rotations is not None:
            self.rotations.reserve(W.shape[0])[:] = W[:, K:]

    def timecodes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(whole seconds of the day, frame numbers, good?)`` of every row, in file order."""
        return self.secs.array(), self.frames.array(), self.good.array()

    def numbers(self) -> tuple[np.ndarray, np.ndarray | None]:
        """``(weights (T, 52), rotations (T, 9) or None)`` of the good rows."""
        return self.weights.array(), None if self.rotations is None else self.rotations.array()


def _columns(header: list[str], path) -> tuple[list[str], int, list[int]]:
    """The header's checks -> ``(header without trailing empty cells, index of Timecode, picked columns)``: the 52
    ARKit weights in :data:`ARKIT_NAMES` order, then the 9 rotations when all are there."""
    while header and header[-1] == "":  # tolerate a trailing comma
        header.pop()
    if "Timecode" not in header:
        raise InputError(
            "not a Live Link Face take: the header has no 'Timecode' column "
            f"(it starts with {', '.join(header[:3])!r})", path)
    missing = [n for n in ARKIT_NAMES if n not in header]
    if missing:
        raise InputError(
            f"the header lacks {len(missing)} ARKit weight column(s): {', '.join(missing)}", path)
    dup = sorted({n for n in header if n and header.count(n) > 1})
    if dup:
        raise InputError(f"the header repeats column(s): {', '.join(dup)}", path)
    columns = [header.index(n) for n in ARKIT_NAMES]
    if all(n in header for n in ROTATION_NAMES):  # the head and eyes, kept beside the weights
        columns += [header.index(n) for n in ROTATION_NAMES]
    return header, header.index("Timecode"), columns


def _one_row(out: _Scanned, line: int, raw: list[str], width: int, tc_col: int, pick, path) -> None:
    """One line's cells, as the :mod:`csv` module splits them: a good row, a lost-tracking row, a blank line
    (skipped) or an error."""
    n = len(raw)
    while n > width and raw[n - 1].strip() == "":  # trailing commas
        n -= 1
    if n == width:
        out.row(line, raw[tc_col], pick(raw))
        return
    if n == 0 or not any(c.strip() for c in raw):
        return  # blank line
    core = [c.strip() for c in raw[:n]]
    while core and core[-1] == "":
        core.pop()
    if len(core) == 2 and tc_col == 0 and _is_zero(core[1]):
        out.row(line, core[0], None)
        return
    raise InputError(
        f"row {line} has {n} columns where the header has {width}, "
        "and it is not a lost-tracking row ('timecode,0')", path)


def _scan(fh, path, size: int) -> _Scanned:
    """Read the header, then the rows, a block at a time, from the binary file ``fh`` of ``size`` bytes.

    Blocks of plain text (ASCII, ``\\n`` or ``\\r\\n`` line breaks, no quotes, no NUL: the app's files) are read
    here; from the first block that is not, the :mod:`csv` module reads the rest (:func:`_scan_text`), and the
    whole file when the header is in it -- so every file reads as the :mod:`csv` module reads it."""
    limit = csv.field_size_limit()
    line = 0  # lines before the block
    offset = 0  # the block's place in the file
    out = header = None
    state = None
    bom = False
    for blk in _blocks(fh):
        start, raw_blk = offset, blk
        offset += len(blk)
        if start == 0 and blk.startswith(_BOM):
            blk, bom = blk[len(_BOM):], True
        if not _plain(blk):
            if out is None:
                return _scan_text(fh, path, size)
            _rest_text(fh, start, bom, line, out, state, path)
            out.flush()
            return out
        if b"\r" in blk:
            blk = blk.replace(b"\r\n", b"\n")
        if not blk.endswith(b"\n"):
            blk += b"\n"  # the file's last line
        skipped = 0  # lines of the block before the rows (the header and blank lines above it)
        try:
            if out is None:  # the header: the first line that is not blank
                lines = blk.split(b"\n")
                for i, text in enumerate(lines[:-1]):
                    skipped = i
                    raw = text.decode("ascii").split(",")
                    if len(text) > limit and any(len(c) > limit for c in raw):
                        raise csv.Error(f"field larger than field limit ({limit})")
                    if any(c.strip() for c in raw):
                        header, tc_col, columns = _columns([c.strip() for c in raw], path)
                        rows = (size - start) * (len(lines) - 2 - i) // max(len(blk), 1) + CHUNK_ROWS
                        out = _Scanned(rows, columns, header, path, size)
                        state = _BlockState(len(header), tc_col, columns, limit)
                        line += i + 1
                        skipped = i + 1
                        blk = blk[sum(len(t) + 1 for t in lines[:i + 1]):]
                        break
                else:
                    line += len(lines) - 1
                    continue
            line += _block(out, blk, line, state, path)
        except (InputError, csv.Error) as exc:
            # the csv module meets a byte that is not UTF-8 first when it is in the 8 kB it decodes with the line
            _decodes_to(fh, start, raw_blk, skipped + getattr(exc, "block_line", 0))
            raise
    if out is None:
        raise InputError("the take file is empty", path)
    out.flush()
    return out


def _blocks(fh):
    """The file's bytes as blocks of whole lines (about :data:`BLOCK_BYTES`; the last may lack its line break)."""
    carry = b""
    while True:
        chunk = fh.read(BLOCK_BYTES)
        if not chunk:
            if carry:
                yield carry
            return
        data = carry + chunk if carry else chunk
        cut = data.rfind(b"\n") + 1
        if cut == 0:
            carry = data  # no line break yet: a long line is read whole
            continue
        carry = data[cut:]
        yield data[:cut] if carry else data


def _plain(blk: bytes) -> bool:
    """ASCII without quotes or NUL, lines broken by ``\\n`` or ``\\r\\n``: split on commas as the csv module would."""
    if not blk.isascii() or b'"' in blk or b"\0" in blk:
        return False
    return b"\r" not in blk or blk.count(b"\r") == blk.count(b"\r\n")


def _scan_text(fh, path, size: int) -> _Scanned:
    """The whole file through the :mod:`csv` module (UTF-8 with or without its BOM), opened afresh: decoded in
    the chunks the reader before blocks decoded (``fh``'s buffer would shift them)."""
    with open(fh.name, "rb") as fresh:
        text = io.TextIOWrapper(fresh, encoding="utf-8-sig", newline="")
        try:
            reader = csv.reader(text)
            header = None
            for raw in reader:
                if any(c.strip() for c in raw):
                    header = [c.strip() for c in raw]
                    break
            if header is None:
                raise InputError("the take file is empty", path)
            header, tc_col, columns = _columns(header, path)
            out = _Scanned(size // 256 + CHUNK_ROWS, columns, header, path, size)
            pick = operator.itemgetter(*columns)
            for raw in reader:
                _one_row(out, reader.line_num, raw, len(header), tc_col, pick, path)
        finally:
            text.detach()
    out.flush()
    return out


#: What ``io.TextIOWrapper`` decodes at a time: its chunks start at multiples of this from the file's start.
_TEXT_CHUNK = 8192


def _rest_text(fh, offset: int, bom: bool, line: int, out: _Scanned, state: _BlockState, path) -> None:
    """The rows from byte ``offset`` on (after ``line`` lines) through the :mod:`csv` module, decoded in the
    chunks of the whole file's decoding (the plain text before ``offset`` skipped): a byte that is not UTF-8 is
    met where reading the file whole meets it."""
    at = offset // _TEXT_CHUNK * _TEXT_CHUNK
    with open(fh.name, "rb") as fresh:  # fh's buffer would shift the chunks
        fresh.seek(at)
        text = io.TextIOWrapper(fresh, encoding="utf-8-sig" if at == 0 else "utf-8", newline="")
        try:
            text.read(offset - at - (len(_BOM) if at == 0 and bom else 0))  # plain text: a character a byte
            reader = csv.reader(text)
            for raw in reader:
                _one_row(out, line + reader.line_num, raw, state.width, state.tc_col, state.pick, path)
        finally:
            text.detach()


def _decodes_to(fh, start: int, blk: bytes, i: int) -> None:
    """Raise the :class:`UnicodeDecodeError` that reading the file as text meets before line ``i`` of the block
    ``blk`` (as read, from byte ``start``) is whole: the 8 kB chunk holding its line break (the file's end for
    a last line without one) decoded (the text before it is plain)."""
    end = -1
    for _ in range(i + 1):
        end = blk.find(b"\n", end + 1)
        if end < 0:
            break
    last = end < 0
    end = start + (len(blk) if last else end)
    fh.seek(end // _TEXT_CHUNK * _TEXT_CHUNK)
    codecs.getincrementaldecoder("utf-8")().decode(fh.read(_TEXT_CHUNK), last)


class _BlockState:
    """What the blocks of one file share: the header's width, the Timecode and picked columns, the layout of the
    last block's rows."""

    def __init__(self, width: int, tc_col: int, columns: list[int], limit: int):
        self.width, self.tc_col, self.columns, self.limit = width, tc_col, columns, limit
        self.pick = operator.itemgetter(*columns)
        self.layout: _Layout | None = None


def _block(out: _Scanned, blk: bytes, line: int, state: _BlockState, path) -> int:
    """The rows of ``blk`` (plain text, whole lines ending in ``\\n``) after ``line`` lines of the file -> its
    number of lines."""
    if not blk:
        return 0
    signs = np.flatnonzero(np.frombuffer(blk, dtype=np.uint8) == 45)  # the minus signs
    lay = state.layout
    if lay is None or (len(blk) - signs.size) % lay.length:
        lay = state.layout = _Layout.find(blk, state) or lay
    if lay is not None:
        got = lay.rows(blk, signs)
        if got is not None:
            out.run(line + 1, *got)
            return got[0].size
    # mixed: runs of lines of the layout's length (read together) and the other lines (read on their own)
    lines = blk.split(b"\n")
    R = len(lines) - 1
    size = -1 if lay is None else lay.length - 1
    a = 0
    while a < R:
        b = a
        while b < R and len(lines[b]) - lines[b].count(b"-") == size:
            b += 1
        if b - a >= _RUN_MIN:
            run = b"\n".join(lines[a:b]) + b"\n"
            got = lay.rows(run, np.flatnonzero(np.frombuffer(run, dtype=np.uint8) == 45))
            if got is not None:
                out.run(line + a + 1, *got)
                a = b
                continue
        for i in range(a, max(b, a + 1)):  # a short run, a run not of the layout after all, or another line
            text = lines[i].decode("ascii")
            raw = text.split(",") if text else []
            try:
                if len(text) > state.limit and any(len(c) > state.limit for c in raw):
                    raise csv.Error(f"field larger than field limit ({state.limit})")
                _one_row(out, line + i + 1, raw, state.width, state.tc_col, state.pick, path)
            except (InputError, csv.Error) as exc:
                exc.block_line = i  # for _scan: which line of the block
                raise
        a = max(b, a + 1)
    return R


#: Fewer lines of one layout than this between other lines are read on their own.
_RUN_MIN = 4
_TIMECODE = re.compile(r"[0-9]{2}:[0-9]{2}:[0-9]{2}:[0-9]{2}\.[0-9]{3}")
_DECIMAL = re.compile(r"[0-9]+\.?[0-9]*|\.[0-9]+")
#: Digits of a number read by :class:`_Layout`: up to 15 make an integer float64 holds exactly, which divided by a
#: power of ten is the correctly rounded number (as ``float()`` reads it).
_MAX_DIGITS = 15


class _Layout:
    """The byte layout that the good rows of a block share once their minus signs are taken out: the cells at the
    same places, the timecode ``HH:MM:SS:FF.fff``, and each weight's digits and decimal point (at most
    :data:`_MAX_DIGITS` digits).

    Such rows are checked and converted all at once (:meth:`rows`): every cell's bytes against the layout,
    every minus sign at the start of a number, the commas; a number is its digits read as one integer
    (exact) over a power of ten: the float ``float()`` gives.
    """

    def __init__(self, row: str, state: _BlockState):
        cells = row.split(",")
        if len(cells) != state.width or len(row) + 1 > state.limit or not _TIMECODE.fullmatch(cells[state.tc_col]):
            raise ValueError
        starts = np.cumsum([0] + [len(c) + 1 for c in cells[:-1]])
        self.length = len(row) + 1  # with its line break
        self.width = state.width
        self.tc = int(starts[state.tc_col])
        picked = sorted(set(state.columns))
        kind = {}
        for c in picked:
            cell = cells[c]
            digits = len(cell) - cell.count(".")
            if not _DECIMAL.fullmatch(cell) or digits > _MAX_DIGITS:
                raise ValueError
            kind[c] = (len(cell), cell.find("."))
        self.runs = []  # (byte offset, cells, cell width, point or -1, first index among the picked)
        for j, c in enumerate(picked):
            if self.runs and picked[j - 1] == c - 1 and kind[picked[j - 1]] == kind[c]:
                self.runs[-1][1] += 1
            else:
                self.runs.append([int(starts[c]), 1, *kind[c], j])
        last = state.width - 1
        # the other cells (not read): their bytes hold no comma or line break, a comma follows each (a line break
        # the last one, checked with every row's)
        others = [c for c in range(state.width) if c not in kind and c != state.tc_col]
        self.others = [(int(starts[c]), int(starts[c]) + len(cells[c])) for c in others]
        self.commas = [int(starts[c + 1]) - 1 for c in others if c < last]
        self.number_at = np.full(self.length, -1, dtype=np.int64)  # byte offset -> index among the picked
        self.number_at[starts[picked]] = np.arange(len(picked))
        self.count = len(picked)
        self.order = np.searchsorted(picked, state.columns)  # picked (file order) -> the take's columns
        self.checks = []
        for o, m, w, point, j in self.runs:
            base = np.full((m, w + 1), 48, dtype=np.uint8)
            top = np.full((m, w + 1), 9, dtype=np.uint8)
            weight = np.zeros(w + 1)
            frac = 0 if point < 0 else w - point - 1
            for i in range(w):
                if i == point:
                    base[:, i], top[:, i] = 46, 0
                else:
                    weight[i] = 10.0 ** ((w - 1 - i) - (1 if point >= 0 and i < point else 0))
            base[:, w], top[:, w] = 44, 0
            if o + m * (w + 1) == self.length:
                base[-1, w] = 10  # the row's last cell: its line break
            self.checks.append((base, top, weight, 48.0 * weight.sum(), 10.0 ** frac))
        tc_base = np.frombuffer(b"00:00:00:00.000,", dtype=np.uint8).copy()
        tc_top = np.where(tc_base == 48, 9, 0).astype(np.uint8)
        if self.tc + 16 == self.length:
            tc_base[15] = 10
        self.tc_base, self.tc_top = tc_base, tc_top

    @classmethod
    def find(cls, blk: bytes, state: _BlockState) -> _Layout | None:
        """The layout of the first line of ``blk`` with the header's number of cells that has one, else None."""
        at = 0
        for _ in range(8):
            end = blk.find(b"\n", at)
            if end < 0:
                return None
            text = blk[at:end]
            at = end + 1
            if text.count(b",") != state.width - 1:
                continue
            try:
                return cls(text.replace(b"-", b"").decode("ascii"), state)
            except ValueError:
                continue
        return None

    def rows(self, blk: bytes, signs: np.ndarray):
        """``blk``'s lines (whole, ending in ``\\n``), all of this layout once the minus signs at ``signs`` (byte
        offsets) are taken out -> the arguments of :meth:`_Scanned.run` after the first line number, or None when
        a line is not of it."""
        plain = blk.replace(b"-", b"") if signs.size else blk
        L = self.length
        R, extra = divmod(len(plain), L)
        if extra or not R:
            return None
        G = np.frombuffer(plain, dtype=np.uint8).reshape(R, L)
        if not (G[:, L - 1] == 10).all():  # every row's line break where the layout has it
            return None
        for at in self.commas:
            if not (G[:, at] == 44).all():
                return None
        for a, b in self.others:
            cell = G[:, a:b]
            if ((cell == 44) | (cell == 10)).any():
                return None
        tc = G[:, self.tc:self.tc + 16]
        if ((tc - self.tc_base).max(axis=0) > self.tc_top).any():
            return None
        numbers = np.empty((R, self.count))
        for (o, m, w, point, j), (base, top, weight, offset, scale) in zip(self.runs, self.checks):
            X = G[:, o:o + m * (w + 1)].reshape(R, m, w + 1)
            if ((X - base).max(axis=0) > top).any():  # digits, the point and the comma where the layout has them
                return None
            M = np.einsum("rmk,k->rm", X, weight)  # exact: integers below 2 ** 53
            M -= offset
            M /= scale
            numbers[:, j:j + m] = M
        if signs.size:  # each minus sign starts a number, at most one a number
            at = signs - np.arange(signs.size)  # where it stood in the signless text
            row, col = np.divmod(at, L)
            k = self.number_at[col]
            if (k < 0).any():
                return None
            flat = row * self.count + k  # increasing (the signs in file order), unless two start one number
            if (np.diff(flat) <= 0).any():
                return None
            numbers.reshape(-1)[flat] *= -1.0
        d = tc.astype(np.int64) - 48
        minutes, seconds = d[:, 3] * 10 + d[:, 4], d[:, 6] * 10 + d[:, 7]
        secs = ((d[:, 0] * 10 + d[:, 1]) * 3600 + minutes * 60 + seconds).astype(np.float64)
        frames = ((d[:, 9] * 10 + d[:, 10]) * 1000 + d[:, 12] * 100 + d[:, 13] * 10 + d[:, 14]) / 1000.0
        in_range = (minutes < 60) & (seconds < 61)
        return secs, frames, in_range, numbers[:, self.order], lambda i: bytes(tc[i, :15]).decode("ascii")


def _is_zero(cell: str) -> bool:
    try:
        return float(cell) == 0.0
    except ValueError:
        return False


def _to_float(cells: list[tuple[str, ...]], lines: list[int], columns: list[int], header: list[str],
              path) -> np.ndarray:
    """``(rows, columns)`` float64 from the raw cells; the first bad cell is named on failure."""
    try:
        W = np.array(cells, dtype=np.float64)
    except ValueError:
        W = None
    if W is not None and np.isfinite(W).all():
        return W.reshape(len(cells), len(columns))
    for r, row in enumerate(cells):  # slow path: only to name the culprit
        for k, cell in enumerate(row):
            try:
                ok = np.isfinite(float(cell))
            except ValueError:
                ok = False
            if not ok:
                raise InputError(
                    f"row {lines[r]}, column {header[columns[k]]}: not a finite number: {cell!r}", path)
    raise InputError("the weights could not be read as numbers", path)  # pragma: no cover


def _parse_timecode(tc: str, line: int, path) -> tuple[float, float]:
    """Whole seconds of the day and the fractional frame number of a ``HH:MM:SS:FF(.fff)`` timecode."""
    parts = tc.strip().split(":")
    try:
        if len(parts) != 4:
            raise ValueError
        h, m, s = int(parts[0]), int(parts[1]), int(parts[2])
        f = float(parts[3])
        if not (0 <= m < 60 and 0 <= s < 61 and h >= 0 and 0.0 <= f < 1000.0):
            raise ValueError
    except ValueError:
        raise InputError(
            f"row {int(line)}, column Timecode: bad timecode {tc!r} (expected HH:MM:SS:FF.fff)",
            path) from None
    return float(h * 3600 + m * 60 + s), f


def timecode_fps(frames: Sequence[float] | np.ndarray) -> float:
    """The frame base of a take's timecode, inferred from its frame numbers.

    Parameters
    ----------
    frames : array_like
        The ``FF.fff`` fields of the timecodes.

    Returns
    -------
    float
        The smallest of 24, 25, 30, 48, 50, 60, 120 that exceeds the largest
        whole frame number, but at least 30 (the usual rate when the file is
        too short to show). Live Link Face files seen so far give 60.
    """
    f = np.asarray(frames, dtype=np.float64)
    if f.size == 0:
        return _DEFAULT_FPS
    top = float(np.floor(f.max()))
    for rate in _FRAME_RATES:
        if rate >= _DEFAULT_FPS and top < rate:
            return rate
    return float(top + 1.0)


def _unwrap_midnight(t: np.ndarray) -> np.ndarray:
    """Add a day wherever the time of day falls back by more than 12 h."""
    if t.size < 2:
        return t
    jumps = np.diff(t) < -_DAY / 2
    if not jumps.any():
        return t
    return t + _DAY * np.concatenate([[0], np.cumsum(jumps)])


def _interpolate(W_good: np.ndarray, t: np.ndarray, is_good: np.ndarray) -> np.ndarray:
    """Fill lost rows linearly from good rows (in time if strictly increasing, else by row)."""
    x = t if np.all(np.diff(t) > 0) else np.arange(t.size, dtype=np.float64)
    xg, xl = x[is_good], x[~is_good]
    out = np.empty((t.size, W_good.shape[1]))
    out[is_good] = W_good
    # Linear weights between the bracketing good rows; held constant beyond the ends.
    hi = np.clip(np.searchsorted(xg, xl), 1, xg.size - 1) if xg.size > 1 else np.zeros(xl.size, int)
    lo = np.maximum(hi - 1, 0)
    span = xg[hi] - xg[lo]
    a = np.where(span > 0, (xl - xg[lo]) / np.where(span > 0, span, 1.0), 0.0)
    a = np.clip(a, 0.0, 1.0)[:, None]
    out[~is_good] = (1.0 - a) * W_good[lo] + a * W_good[hi]
    return out


# ----------------------------------------------------------------------------- mapping


def ict_weights(take: Take, expression_names: Sequence[str], clip: bool = True) -> np.ndarray:
    """A take's weights as ICT expression weights.

    Parameters
    ----------
    take : Take
        From :func:`read_take`.
    expression_names : sequence of str
        The ICT expression names, in the order wanted for the columns.
    clip : bool
        Clip the result to [0, 1] (the take keeps its raw values).

    Returns
    -------
    numpy.ndarray
        ``(T, E)`` float64, column ``e`` being the ARKit weight that drives
        ``expression_names[e]``, or 0 for names no ARKit shape drives. The
        names are matched as :class:`~facegeom.io.shape_names.ShapeMap` does
        (ARKit-named rigs' names, decorated or not, match too).
    """
    out = ShapeMap.between(expression_names, take.names).apply(take.weights)
    if clip:
        np.clip(out, 0.0, 1.0, out=out)
    return out


def ict_to_arkit(weights, ict_names: Sequence[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    """ICT expression weights as the 52 ARKit weights: the inverse of :func:`ict_weights`.

    Parameters
    ----------
    weights : array_like
        ``(T, K)`` (or ``(K,)``) ICT weights, column ``k`` for ``ict_names[k]``.
    ict_names : sequence of str
        ICT expression names (``eyeBlink_L``, ``jawOpen``...).

    Returns
    -------
    (numpy.ndarray, tuple of str)
        ``W`` ``(T, 52)`` float64 and :data:`ARKIT_NAMES` (its column order).

    Notes
    -----
    Lossy where the two rigs differ: ``BrowInnerUp`` and ``CheekPuff`` get the
    mean of the ICT ``_L`` and ``_R`` weights (an asymmetric inner brow or puff
    becomes symmetric); ``TongueOut`` is 0 (ICT has no tongue); ICT names that
    no ARKit shape drives are dropped, and ARKit shapes whose ICT names are
    absent from ``ict_names`` get 0. For the 53 ICT expressions everything
    else is a one-to-one copy, so ``ict_weights`` of the result gives the input
    back whenever the brow and puff sides are equal.

    Raises
    ------
    InputError
        ``weights`` is not ``(T, len(ict_names))`` or holds NaN or inf, or a
        name repeats.
    """
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim == 1:
        W = W[None]
    names = [str(n) for n in ict_names]
    if W.ndim != 2 or W.shape[1] != len(names):
        raise InputError(f"ICT weights must have shape (T, {len(names)}) for {len(names)} names, got {W.shape}")
    if not np.isfinite(W).all():
        raise InputError("ICT weights contain NaN or inf")
    if len(set(names)) != len(names):
        raise InputError("an ICT expression name repeats")
    return ShapeMap.between(ARKIT_NAMES, names).apply(W), ARKIT_NAMES


# ----------------------------------------------------------------------------- writing

_TIMECODE_BASES = (60.0, 30.0)  # the app's (60), else one the reader cannot misread (30: no frame field >= 30)


def _timecodes(times: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(whole seconds, thousandths of a frame, frame base)`` of ``times`` (seconds of the day), for
    :func:`_timecode_text`.

    The app's frame base is 60; :func:`read_take` infers the base from the
    largest frame field, so 60 is used when the take shows a frame field of
    30 or more (a take of half a second or longer), else 30.
    """
    for base in _TIMECODE_BASES:
        milli = np.rint(times * base * 1000.0).astype(np.int64)  # thousandths of a frame
        per_second = int(base) * 1000
        secs, rest = np.divmod(milli, per_second)
        if timecode_fps(rest / 1000.0) == base:
            break
    return secs, rest, base


def _timecode_text(secs: np.ndarray, rest: np.ndarray) -> list[str]:
    """``HH:MM:SS:FF.fff`` strings of whole seconds of the day and thousandths of a frame (from :func:`_timecodes`)."""
    out = []
    for sec, r in zip(secs.tolist(), rest.tolist()):
        h, m, s_ = (sec // 3600) % 24, (sec // 60) % 60, sec % 60
        out.append(f"{h:02d}:{m:02d}:{s_:02d}:{r // 1000:02d}.{r % 1000:03d}")
    return out


def write_livelink_csv(path: str | os.PathLike, weights, names: Sequence[str], fps: float,
                       start: float | None = None, rotations=None) -> Path:
    """Write ARKit weights as a Live Link Face CSV take (the iPhone app's layout), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.csv`` file.
    weights : array_like
        ``(T, K)`` weights, column ``k`` for ``names[k]``.
    names : sequence of str
        ARKit names (``JawOpen`` or ``jawOpen``), any order; the 52 columns
        are written in the app's order (:data:`ARKIT_NAMES`) and a shape not
        in ``names`` is written as 0. Map ICT weights with
        :func:`ict_to_arkit` first.
    fps : float
        Rows per second (the app records at 30 or 60).
    start : float, optional
        Time of day of the first row in seconds (default 0, i.e.
        ``00:00:00:00.000``); a take passing midnight wraps to 00 hours as the
        app's clock does.
    rotations : array_like, optional
        ``(T, 9)`` head and eye rotations in :data:`ROTATION_NAMES` order; 0
        when not given (facegeom does not estimate them).

    Returns
    -------
    Path
        ``path``; :func:`read_take` reads it back (times within a thousandth
        of a frame).

    Raises
    ------
    InputError
        A name that is not ARKit or that repeats, weights not ``(T, K)`` or
        holding NaN or inf, rotations not ``(T, 9)``, a frame rate or start
        that is not a positive (non-negative) number, an output folder that
        does not exist.
    """
    path = Path(path)
    W = np.asarray(weights, dtype=np.float64)
    names = [str(n) for n in names]
    if W.ndim != 2 or W.shape[0] == 0 or W.shape[1] != len(names):
        raise InputError(f"weights must have shape (T, {len(names)}) with T > 0 for {len(names)} names, "
                         f"got {W.shape}", path)
    if not np.isfinite(W).all():
        raise InputError("weights contain NaN or inf", path)
    pascal = [n[:1].upper() + n[1:] for n in names]
    unknown = [n for n, p in zip(names, pascal) if p not in _ARKIT_SET]
    if unknown:
        raise InputError(f"{unknown[0]!r} is not an ARKit blendshape name (ICT weights: map them with "
                         f"ict_to_arkit first)", path)
    if len(set(pascal)) != len(pascal):
        raise InputError("an ARKit name repeats", path)
    T = W.shape[0]
    R = np.zeros((T, len(ROTATION_NAMES))) if rotations is None else np.asarray(rotations, dtype=np.float64)
    if R.shape != (T, len(ROTATION_NAMES)) or not np.isfinite(R).all():
        raise InputError(f"rotations must be finite with shape ({T}, {len(ROTATION_NAMES)}), got {R.shape}", path)
    try:
        fps = float(fps)
        t0 = 0.0 if start is None else float(start)
    except (TypeError, ValueError):
        raise InputError(f"frame rate {fps!r} and start {start!r} must be numbers", path) from None
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"frame rate {fps} is not a positive number", path)
    if not (math.isfinite(t0) and t0 >= 0):
        raise InputError(f"start {t0} is not a time of day in seconds (>= 0)", path)
    index = {n: k for k, n in enumerate(ARKIT_NAMES)}
    secs, rest, _ = _timecodes(t0 + np.arange(T) / fps)
    header = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *ROTATION_NAMES]
    count = str(len(ARKIT_NAMES) + len(ROTATION_NAMES))
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(header) + "\n")
            for a in range(0, T, CHUNK_ROWS):  # a chunk of rows at a time: the text is never held whole
                b = min(T, a + CHUNK_ROWS)
                out = np.zeros((b - a, len(ARKIT_NAMES)))
                for k, p in enumerate(pascal):
                    out[:, index[p]] = W[a:b, k]
                fh.write("".join(",".join([stamp, count, *(f"{x:.10f}" for x in w), *(f"{x:.10f}" for x in r)])
                                 + "\n" for stamp, w, r in zip(_timecode_text(secs[a:b], rest[a:b]), out, R[a:b])))
    return path


# ----------------------------------------------------------------------------- folders


def find_takes(folder: str | os.PathLike) -> list[Path]:
    """The ``*.csv`` takes of a folder, sorted by name.

    Raises
    ------
    InputError
        Naming the folder, if it does not exist, is not a folder, or holds no
        ``.csv`` file.
    """
    p = Path(folder)
    if not p.exists():
        raise InputError("folder of takes not found", folder)
    if not p.is_dir():
        raise InputError("not a folder (expected a folder of .csv takes)", folder)
    files = sorted((f for f in p.iterdir() if f.suffix.lower() == ".csv" and f.is_file()), key=lambda f: f.name)
    if not files:
        raise InputError("no .csv take in this folder", folder)
    return files


def eye_rotations(weights, names: Sequence[str]) -> np.ndarray:
    """The eyes' Live Link rotations from ARKit eye-look weights -> ``(T, 6)`` radians.

    Columns ``LeftEyeYaw, LeftEyePitch, LeftEyeRoll, RightEyeYaw, RightEyePitch,
    RightEyeRoll`` (:data:`ROTATION_NAMES` [3:]), as the app relates them
    (:data:`EYE_YAW_PER_WEIGHT`, :data:`EYE_PITCH_PER_WEIGHT`; roll 0).
    ``names``: the ARKit names of the columns of ``weights (T, K)``, any
    spelling; a missing eye-look column counts as 0.
    """
    W = np.asarray(weights, dtype=np.float64)
    if W.ndim != 2 or W.shape[1] != len(names):
        raise InputError(f"weights must be (T, {len(names)}), got {W.shape}")
    col = {}
    for k, n in enumerate(names):
        plain = str(n)[:1].upper() + str(n)[1:]
        if plain in _ARKIT_SET:
            col[plain] = k

    def w(name):
        return W[:, col[name]] if name in col else np.zeros(W.shape[0])

    out = np.zeros((W.shape[0], 6))
    for i, side, sign in ((0, "Left", -1.0), (3, "Right", 1.0)):
        out[:, i] = sign * EYE_YAW_PER_WEIGHT * (w(f"EyeLookOut{side}") - w(f"EyeLookIn{side}"))
        out[:, i + 1] = -EYE_PITCH_PER_WEIGHT * (w(f"EyeLookUp{side}") - w(f"EyeLookDown{side}"))
    return out


def head_angles(rotations) -> np.ndarray:
    """Head rotations ``(T, 3, 3)`` (facegeom's frame: Y up, the face towards +Z) -> ``(T, 3)`` yaw, pitch, roll.

    Radians, intrinsic Y (yaw), then X (pitch), then Z (roll): the ``HeadYaw,
    HeadPitch, HeadRoll`` columns of a Live Link take.

    ``R = Ry(yaw) Rx(pitch) Rz(roll)``, read from its entries (numpy: writing curves does not import
    ``scipy.spatial``, 0.1-0.3 s): ``R[1, 2] = -sin(pitch)``, ``(R[0, 2], R[2, 2]) = cos(pitch) (sin, cos)(yaw)``,
    ``(R[1, 0], R[1, 1]) = cos(pitch) (sin, cos)(roll)``; pitch in ``[-pi/2, pi/2]``, the others in ``[-pi, pi]``.
    At pitch ±90 degrees (yaw and roll turn about one axis) the roll is 0 and the yaw carries the turn.
    The rotations are made orthonormal first (the nearest rotation, by SVD).
    """
    R = np.asarray(rotations, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise InputError(f"rotations must be (T, 3, 3), got {R.shape}")
    if R.shape[0] == 0:
        return np.zeros((0, 3))
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    sp = np.clip(-R[:, 1, 2], -1.0, 1.0)
    pitch = np.arcsin(sp)
    yaw = np.arctan2(R[:, 0, 2], R[:, 2, 2])
    roll = np.arctan2(R[:, 1, 0], R[:, 1, 1])
    lock = np.hypot(R[:, 1, 0], R[:, 1, 1]) < 1e-9  # cos(pitch) ~ 0: R[0] = (cos, sin(pitch) sin, 0)(yaw)
    if lock.any():
        roll[lock] = 0.0
        yaw[lock] = np.arctan2(R[lock, 0, 1] * np.sign(sp[lock]), R[lock, 0, 0])
    return np.stack([yaw, pitch, roll], axis=1)
