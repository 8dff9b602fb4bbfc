"""C3D motion-capture files (Vicon, OptiTrack, Qualisys ...): marker trajectories in and out, via ezc3d.

Reading
-------
:func:`read_c3d` returns a :class:`~facegeom.io.markerseq.MarkerSequence` with

* the marker names from ``POINT:LABELS`` (continued in ``LABELS2``, ``LABELS3``
  ... when a file has more than 255 markers); an empty label becomes the
  marker's index;
* the frame rate from ``POINT:RATE`` (``fps``) and the length unit from
  ``POINT:UNITS`` (``unit``: ``"mm"``, ``"cm"`` or ``"m"``; ``None`` when the
  file states none; any other unit is an error);
* frames numbered from 0, whatever the file's first frame number;
* gaps as NaN: a sample whose residual is negative (the C3D convention for an
  invalid point) or whose three coordinates are exactly zero (what many
  exporters write for a lost marker).

ezc3d is a C++ library: some malformed files make it crash the process, loop
or allocate without bound. The reader therefore checks the 512-byte header
itself (key byte, parameter and data blocks inside the file, counts that fit
the file's size) and then lets ezc3d parse the file in a separate Python
process with a time and memory limit; whatever goes wrong there (an exception,
a crash, a timeout) becomes one :class:`~facegeom.errors.InputError` naming the
file. The cost is one process start per file (about a third of a second).

Writing
-------
:func:`write_c3d` writes ``(T, p, 3)`` positions as float C3D points with ezc3d,
atomically; NaN samples are written as gaps (coordinates 0, residual -1).
"""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path
from facegeom.io.sequence import UNIT_SCALE, MarkerSequence

__all__ = ["read_c3d", "write_c3d", "C3D_UNITS"]

#: Length units a C3D file may state in ``POINT:UNITS`` (case-insensitive).
C3D_UNITS: tuple[str, ...] = tuple(UNIT_SCALE)

#: The fastest frame rate read (high-speed optical systems reach a few thousand frames a second).
MAX_RATE = 10_000

_KEY = 0x50
_MAX_FRAMES = 65535  # ezc3d writes the frame count in 16 bits: a longer sequence would read back cut short
_PROCESSORS = {84: "<", 85: "<", 86: ">"}  # Intel, DEC (VAX floats, little-endian words), MIPS (big-endian)
# Limits of the parsing process. ezc3d read a 32 MB file (20,000 frames x 100 markers) in 2.5-3.6 s on
# the shared 2-core machine, about 10 MB/s: 10 s plus 1 s per MB leaves a 10x margin, while a
# malformed file that sends ezc3d into a loop fails within seconds instead of minutes.
_TIMEOUT_S = 10.0
_TIMEOUT_PER_BYTE = 1e-6
_MEMORY = 2 << 30  # address space, plus 100 bytes per file byte (the 32 MB file above reads within it)

# The child process: only numpy and ezc3d, no facegeom import (fast start, nothing else to crash).
_CHILD = r"""
import sys
import numpy as np
import ezc3d
src, dst = sys.argv[1], sys.argv[2]
try:
    c = ezc3d.c3d(src)
    par = c["parameters"]
    point = par["POINT"] if "POINT" in par else {}
    def values(name):
        if name not in point:
            return []
        v = point[name]["value"]
        return list(v.tolist() if hasattr(v, "tolist") else v)
    labels = []
    k = 1
    while True:
        key = "LABELS" if k == 1 else "LABELS%d" % k
        if key not in point:
            break
        labels += [str(x) for x in values(key)]
        k += 1
    pts = np.asarray(c["data"]["points"], dtype=np.float64)
    res = np.asarray(c["data"]["meta_points"]["residuals"], dtype=np.float64)
    rate = values("RATE")
    units = values("UNITS")
    hdr = c["header"]["points"]
    np.savez(dst, points=pts, residuals=res, labels=np.array(labels, dtype=str),
             rate=np.array([float(rate[0])] if rate else [], dtype=np.float64),
             header_rate=np.array([float(hdr["frame_rate"])]),
             units=np.array([str(u) for u in units[:1]], dtype=str))
except BaseException as exc:
    sys.stderr.write("EZC3D-ERROR %s: %s" % (type(exc).__name__, str(exc)[:300].replace("\n", " ")))
    sys.exit(3)
"""


# ----------------------------------------------------------------------------- header checks


def _check_header(path: Path, size: int) -> None:
    """Reject what ezc3d must not see: a file too short, a wrong key, blocks or counts beyond the file."""
    if size < 512:
        raise InputError(f"not a C3D file: {size} bytes, shorter than the 512-byte header", path)
    with open(path, "rb") as fh:
        head = fh.read(512)
        param_block = head[0]
        if head[1] != _KEY:
            raise InputError("not a C3D file: the header's key byte is not 0x50", path)
        if param_block < 2 or (param_block - 1) * 512 + 4 > size:
            raise InputError(f"truncated or corrupt C3D: the parameter section (block {param_block}) "
                             f"lies outside the {size}-byte file", path)
        fh.seek((param_block - 1) * 512)
        phead = fh.read(4)
    n_blocks, processor = phead[2], phead[3]
    if processor not in _PROCESSORS:
        raise InputError(f"corrupt C3D: unknown processor type {processor} (expected 84, 85 or 86)", path)
    o = _PROCESSORS[processor]
    if n_blocks == 0 or (param_block - 1 + n_blocks) * 512 > size:
        raise InputError(f"truncated C3D: the parameter section claims {n_blocks} blocks of 512 bytes "
                         f"beyond the end of the {size}-byte file", path)
    n_points, n_analog, first, last = struct.unpack_from(o + "4H", head, 2)
    data_block = struct.unpack_from(o + "H", head, 16)[0]
    if processor == 85:  # VAX float: the sign of the scale factor is all that matters here
        scale_negative = bool(head[13] & 0x80) if o == "<" else bool(head[12] & 0x80)
    else:
        scale = struct.unpack_from(o + "f", head, 12)[0]
        if not np.isfinite(scale):
            raise InputError("corrupt C3D: the header's point scale factor is not a finite number", path)
        scale_negative = scale < 0
    if data_block < 2 or (data_block - 1) * 512 > size:
        raise InputError(f"truncated or corrupt C3D: the data section (block {data_block}) lies outside the "
                         f"{size}-byte file", path)
    if param_block <= data_block < param_block + n_blocks:
        raise InputError(f"corrupt C3D: the data section (block {data_block}) starts inside the parameter section "
                         f"(blocks {param_block}-{param_block + n_blocks - 1}): its samples would be parameter "
                         f"bytes", path)
    if last < first:
        raise InputError(f"corrupt C3D: last frame {last} before first frame {first}", path)
    if n_points == 0:
        raise InputError("the C3D file holds no 3-D marker (header point count 0)", path)
    frames = last - first + 1
    word = 4 if scale_negative else 2
    need = (data_block - 1) * 512 + frames * (4 * n_points + n_analog) * word
    if need > size:
        raise InputError(f"truncated C3D: {frames} frames of {n_points} markers need {need} bytes, the file has "
                         f"{size}", path)
    per_frame = (4 * n_points + n_analog) * word
    held = (size - (data_block - 1) * 512) // per_frame
    if last == _MAX_FRAMES and (held - frames) * per_frame >= 512:  # the count saturated and the data goes on
        # (beyond the padding to a 512-byte block that writers add)
        raise InputError(f"the header counts {frames:,} frames, its 16-bit limit, but the data holds {held:,}: "
                         f"only the first {frames:,} could be read; export the capture in parts of at most "
                         f"{_MAX_FRAMES:,} frames", path)


# ----------------------------------------------------------------------------- reading


def _parse_in_child(path: Path, size: int) -> dict:
    """Run ezc3d on ``path`` in a separate process; its arrays, or an InputError for any failure."""
    limit = _MEMORY + 100 * size

    def restrict():  # pragma: no cover - runs in the child
        try:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # a crash leaves no core file behind
        except (ImportError, ValueError, OSError):
            pass

    with tempfile.TemporaryDirectory(prefix="facegeom-c3d-") as work:
        out = Path(work) / "c3d.npz"
        cmd = [sys.executable, "-I", "-c", _CHILD, os.fspath(path), os.fspath(out)]
        try:
            proc = subprocess.run(cmd, capture_output=True, timeout=_TIMEOUT_S + _TIMEOUT_PER_BYTE * size,
                                  preexec_fn=restrict if os.name == "posix" else None)
        except subprocess.TimeoutExpired:
            raise InputError("corrupt C3D: the C3D reader did not finish (timed out)", path) from None
        except OSError as exc:
            raise InputError(f"cannot start the C3D reader: {exc}", path) from None
        if proc.returncode != 0 or not out.exists():
            err = proc.stderr.decode("utf-8", "replace")
            if "EZC3D-ERROR" in err:
                detail = err.split("EZC3D-ERROR", 1)[1].strip()
                if "No module named 'ezc3d'" in detail:
                    raise InputError("reading C3D needs the ezc3d package (pip install ezc3d)", path)
                raise InputError(f"corrupt C3D: ezc3d cannot read it ({detail[:200]})", path)
            raise InputError(f"corrupt C3D: the C3D reader crashed (exit status {proc.returncode})", path)
        with np.load(out, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}


def read_c3d(path: str | os.PathLike) -> MarkerSequence:
    """Read the 3-D marker trajectories of a C3D file.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.c3d`` file.

    Returns
    -------
    MarkerSequence
        ``positions`` ``(T, p, 3)`` float64 in the file's unit (NaN at gaps:
        negative residual or all-zero coordinates), ``frames`` ``0..T-1``,
        ``names`` from ``POINT:LABELS`` (+ ``LABELS2``...), ``fps`` from
        ``POINT:RATE`` (else the header's rate), ``unit`` ``"mm"``, ``"cm"``,
        ``"m"`` or ``None`` when the file states no unit.

    Raises
    ------
    InputError
        Naming the file: missing, a folder or empty; not a C3D file; truncated
        or corrupt (header, parameters or data), including anything that
        makes ezc3d fail or crash; no marker or no frame; an unknown unit; a
        frame rate that is not a positive number; an infinite coordinate;
        repeated marker names.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", path)
    if not path.is_file():
        raise InputError("not a file (expected a .c3d file)", path)
    size = path.stat().st_size
    if size == 0:
        raise InputError("empty file", path)
    try:
        _check_header(path, size)
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    a = _parse_in_child(path, size)
    return _to_sequence(a, path)


def _to_sequence(a: dict, path: Path) -> MarkerSequence:
    """The child's arrays as a checked MarkerSequence."""
    pts, res = a["points"], a["residuals"]
    if pts.ndim != 3 or pts.shape[0] < 3:
        raise InputError(f"corrupt C3D: point data of shape {pts.shape}", path)
    n, T = pts.shape[1], pts.shape[2]
    if n == 0:
        raise InputError("the C3D file holds no 3-D marker", path)
    if T == 0:
        raise InputError("the C3D file holds no frame", path)
    P = np.ascontiguousarray(pts[:3].transpose(2, 1, 0))  # (T, n, 3)
    if np.isinf(P).any():
        raise InputError("corrupt C3D: a marker coordinate is infinite", path)
    gap = ~np.isfinite(P).any(axis=2) | (P == 0.0).all(axis=2)
    if res.shape == (1, n, T):
        gap |= res[0].T < 0
    P[gap] = np.nan

    labels = [str(s).strip() for s in a["labels"].tolist()][:n]
    names = tuple(lab if lab else str(j) for j, lab in enumerate(labels)) + tuple(str(j) for j in
                                                                                  range(len(labels), n))
    if len(set(names)) != n:
        seen: set[str] = set()
        dup = next(x for x in names if x in seen or seen.add(x))
        raise InputError(f"marker name {dup!r} appears twice in POINT:LABELS", path)

    rate = a["rate"] if a["rate"].size else a["header_rate"]
    fps = float(rate[0])
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"POINT:RATE is {fps}, not a positive frame rate", path)
    if fps > MAX_RATE:
        raise InputError(f"POINT:RATE is {fps:g} frames a second: no capture runs faster than {MAX_RATE:,}", path)

    unit = None
    if a["units"].size:
        raw = str(a["units"][0]).strip()
        if raw:
            unit = raw.lower()
            if unit not in UNIT_SCALE:
                raise InputError(f"POINT:UNITS is {raw!r}; facegeom reads mm, cm or m", path)
    return MarkerSequence(np.arange(T, dtype=np.int64), names, P, str(path), fps=fps, unit=unit)


# ----------------------------------------------------------------------------- writing


def write_c3d(path: str | os.PathLike, positions, names, fps: float, unit: str = "mm") -> Path:
    """Write marker trajectories as a C3D file (float points), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.c3d`` file to write (replaced whole, or left untouched on error).
    positions : array_like
        ``(T, p, 3)`` positions in ``unit``; NaN marks a gap (written with
        residual -1 and zero coordinates).
    names : sequence of str
        ``p`` distinct marker names (``POINT:LABELS``, continued in ``LABELS2``...
        past 255).
    fps : float
        Frame rate (``POINT:RATE``).
    unit : {"mm", "cm", "m"}
        Length unit written to ``POINT:UNITS``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        Wrong shapes, more than 65,535 frames, an infinite coordinate, repeated or wrong-count names,
        a frame rate that is not positive, an unknown unit, or an output
        folder that does not exist.
    """
    path = Path(path)
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] == 0 or P.shape[1] == 0:
        raise InputError(f"positions must have shape (T, p, 3) with T, p > 0, got {P.shape}", path)
    if np.isinf(P).any():
        raise InputError("positions contain inf", path)
    T, p = P.shape[:2]
    if T > _MAX_FRAMES:
        raise InputError(f"{T} frames: a C3D file as ezc3d writes it holds at most {_MAX_FRAMES} frames "
                         f"(its frame count is 16-bit); split the sequence", path)
    names = [str(n) for n in names]
    if len(names) != p or len(set(names)) != p:
        raise InputError(f"{len(names)} names ({len(set(names))} distinct) for {p} markers", path)
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"frame rate {fps} is not a positive number", path)
    if unit not in UNIT_SCALE:
        raise InputError(f"unit {unit!r} is not one of {', '.join(UNIT_SCALE)}", path)
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError("writing C3D needs the ezc3d package (pip install ezc3d)", path) from None
    gap = ~np.isfinite(P).all(axis=2)  # (T, p)
    pts = np.zeros((4, p, T))
    pts[:3] = np.where(gap[..., None], 0.0, P).transpose(2, 1, 0)
    pts[3] = 1.0
    res = np.where(gap.T, -1.0, 0.0)[None]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(names)
    c["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = res
    with atomic_path(path) as tmp:
        c.write(os.fspath(tmp))
    return path
