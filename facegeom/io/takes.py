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

import csv
import math
import operator
import os
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
        with open(p, newline="", encoding="utf-8-sig") as fh:
            header, columns, good, lost = _scan(fh, path)
    except OSError as exc:
        raise InputError(f"cannot read the take: {exc.strerror or exc}", path) from None
    except UnicodeDecodeError:
        raise InputError("cannot read the take: not UTF-8 text", path) from None
    except csv.Error as exc:
        raise InputError(f"cannot read the take: malformed CSV ({exc})", path) from None

    n_rows = len(good[0]) + len(lost)
    if n_rows == 0:
        raise InputError("the take has a header but no data rows", path)
    if not good[0]:
        raise InputError(f"nothing usable: all {len(lost)} data rows are lost-tracking rows", path)

    good_lines, good_tc, good_cells = good
    W = _to_float(good_cells, good_lines, columns, header, path)

    # Timecodes of all rows (good and lost), in file order.
    lines = np.asarray(good_lines + [ln for ln, _ in lost], dtype=np.int64)
    tcs = good_tc + [tc for _, tc in lost]
    order = np.argsort(lines, kind="stable")
    lines = lines[order]
    tcs = [tcs[i] for i in order]
    frame_secs, frames = _parse_timecodes(tcs, lines, path)
    fps = timecode_fps(frames)
    t = frame_secs + frames / fps
    t = _unwrap_midnight(t)

    is_good = np.zeros(n_rows, dtype=bool)
    is_good[: len(good_lines)] = True
    is_good = is_good[order]

    if policy == "drop" or not lost:
        weights, times = W, t[is_good]
    else:
        weights = _interpolate(W, t, is_good)
        times = t
    K = len(ARKIT_NAMES)
    return Take(
        path=str(p),
        names=ARKIT_NAMES,
        weights=np.ascontiguousarray(weights[:, :K]),
        times=times - times[0],
        lost_rows=len(lost),
        policy=policy,
        timecode_fps=fps,
        rotations=np.ascontiguousarray(weights[:, K:]) if weights.shape[1] > K else None,
        start_s=float(times[0]),
    )


def _scan(fh, path):
    """Split the file into header, good rows (raw cells) and lost rows."""
    reader = csv.reader(fh)
    header = None
    for raw in reader:
        if any(c.strip() for c in raw):
            header = [c.strip() for c in raw]
            break
    if header is None:
        raise InputError("the take file is empty", path)
    while header and header[-1] == "":  # tolerate a trailing comma
        header.pop()
    width = len(header)
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
    tc_col = header.index("Timecode")
    columns = [header.index(n) for n in ARKIT_NAMES]
    if all(n in header for n in ROTATION_NAMES):  # the head and eyes, kept beside the weights
        columns += [header.index(n) for n in ROTATION_NAMES]
    pick = operator.itemgetter(*columns)

    good_lines: list[int] = []
    good_tc: list[str] = []
    good_cells: list[tuple[str, ...]] = []
    lost: list[tuple[int, str]] = []
    for raw in reader:
        line = reader.line_num
        n = len(raw)
        while n > width and raw[n - 1].strip() == "":  # trailing commas
            n -= 1
        if n == width:
            good_lines.append(line)
            good_tc.append(raw[tc_col])
            good_cells.append(pick(raw))
            continue
        if n == 0 or not any(c.strip() for c in raw):
            continue  # blank line
        core = [c.strip() for c in raw[:n]]
        while core and core[-1] == "":
            core.pop()
        if len(core) == 2 and tc_col == 0 and _is_zero(core[1]):
            lost.append((line, core[0]))
            continue
        raise InputError(
            f"row {line} has {n} columns where the header has {width}, "
            "and it is not a lost-tracking row ('timecode,0')", path)
    return header, columns, (good_lines, good_tc, good_cells), lost


def _is_zero(cell: str) -> bool:
    try:
        return float(cell) == 0.0
    except ValueError:
        return False


def _to_float(cells: list[tuple[str, ...]], lines: list[int], columns: list[int], header: list[str],
              path) -> np.ndarray:
    """``(T, 52)`` float64 from the raw cells; the first bad cell is named on failure."""
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


def _parse_timecodes(tcs: list[str], lines: np.ndarray, path) -> tuple[np.ndarray, np.ndarray]:
    """Whole seconds of the day and fractional frame numbers of ``HH:MM:SS:FF(.fff)`` timecodes."""
    secs = np.empty(len(tcs))
    frames = np.empty(len(tcs))
    for i, tc in enumerate(tcs):
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
                f"row {int(lines[i])}, column Timecode: bad timecode {tc!r} (expected HH:MM:SS:FF.fff)",
                path) from None
        secs[i] = h * 3600 + m * 60 + s
        frames[i] = f
    return secs, frames


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


def _timecodes(times: np.ndarray) -> tuple[list[str], float]:
    """``HH:MM:SS:FF.fff`` strings of ``times`` (seconds of the day) and the frame base used.

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
    out = []
    for sec, r in zip(secs.tolist(), rest.tolist()):
        h, m, s_ = (sec // 3600) % 24, (sec // 60) % 60, sec % 60
        out.append(f"{h:02d}:{m:02d}:{s_:02d}:{r // 1000:02d}.{r % 1000:03d}")
    return out, base


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
    out = np.zeros((T, len(ARKIT_NAMES)))
    index = {n: k for k, n in enumerate(ARKIT_NAMES)}
    for k, p in enumerate(pascal):
        out[:, index[p]] = W[:, k]
    stamps, _ = _timecodes(t0 + np.arange(T) / fps)
    header = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *ROTATION_NAMES]
    count = str(len(ARKIT_NAMES) + len(ROTATION_NAMES))
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            fh.write(",".join(header) + "\n")
            for stamp, w, r in zip(stamps, out, R):
                fh.write(",".join([stamp, count, *(f"{x:.10f}" for x in w), *(f"{x:.10f}" for x in r)]) + "\n")
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
    """
    from scipy.spatial.transform import Rotation

    R = np.asarray(rotations, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise InputError(f"rotations must be (T, 3, 3), got {R.shape}")
    if R.shape[0] == 0:
        return np.zeros((0, 3))
    return Rotation.from_matrix(R).as_euler("YXZ")
