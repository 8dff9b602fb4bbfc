"""Marker sequences on disk: CSV (long format) and npz, read with clear errors, written atomically.

CSV
    Header ``frame,marker,x,y,z``; one row per marker per frame. ``frame`` is an
    integer frame index, ``marker`` a marker name or number (the order of first
    appearance is the marker order). Every frame must list the same markers.
    An empty coordinate or ``nan`` marks a lost marker.
npz
    ``markers`` ``(T, p, 3)``; optional ``frames`` ``(T,)`` int (default
    ``0..T-1``) and ``marker_names`` ``(p,)``.
C3D
    Motion-capture files, read by :func:`facegeom.io.c3d.read_c3d` (names, frame
    rate, unit, gaps as NaN; frames ``0..T-1``).

A *source* sequence must hold the frames ``0..T-1`` in order. A *labels* file
holds the known target frames: its ``frame`` values are indices into the source.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path, iter_csv_rows
from facegeom.io.ints import check_int64
from facegeom.io.sequence import UNIT_SCALE, MarkerSequence

__all__ = ["MarkerSequence", "SEQUENCE_HEADER", "SEQUENCE_FORMATS", "UNIT_SCALE", "read_marker_sequence",
           "write_marker_sequence", "fill_gaps", "read_retarget_inputs"]

SEQUENCE_HEADER = ("frame", "marker", "x", "y", "z")
SEQUENCE_FORMATS = (".csv", ".npz", ".c3d")
_WRITE_FORMATS = (".csv", ".npz")


def _check_path(path: Path) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError("is a folder, not a marker-sequence file", path)
    if path.suffix.lower() not in SEQUENCE_FORMATS:
        raise InputError(f"unsupported marker-sequence format {path.suffix!r}; use .csv, .npz or .c3d", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)


def _read_csv(path: Path) -> MarkerSequence:
    """Stream the long-format CSV: memory is the arrays it fills (about the size of the numbers in the file),
    never the text or per-row Python objects, so a capture of hundreds of megabytes reads in bounded memory."""
    from array import array

    rows = ((n, r) for n, r in iter_csv_rows(path, "marker sequence") if any(c.strip() for c in r))
    first = next(rows, None)
    if first is None:
        raise InputError("no rows (expected the header frame,marker,x,y,z)", path)
    header = tuple(c.strip().lower() for c in first[1])
    if header != SEQUENCE_HEADER:
        raise InputError(f"wrong columns {','.join(first[1])}; expected the header frame,marker,x,y,z", path)
    names: dict[str, int] = {}
    frame_of, marker_of, line_of, xyz = array("q"), array("q"), array("q"), array("d")
    nan = float("nan")
    for line_no, r in rows:
        if len(r) != 5:
            raise InputError(f"line {line_no}: expected 5 values (frame,marker,x,y,z), got {len(r)}", path)
        try:
            f = int(r[0])
        except ValueError:
            raise InputError(f"line {line_no}: frame {r[0]!r} is not an integer", path) from None
        check_int64(f, "frame", line_no, path)
        if f < 0:
            raise InputError(f"line {line_no}: frame {f} is negative", path)
        if f >= 1 << 62:
            raise InputError(f"line {line_no}: frame {f} is out of range", path)
        name = r[1].strip()
        if not name:
            raise InputError(f"line {line_no}: empty marker name", path)
        try:
            xyz.extend([float(c) if c.strip() else nan for c in r[2:]])
        except ValueError:
            raise InputError(f"line {line_no}: a coordinate is not a number", path) from None
        frame_of.append(f)
        marker_of.append(names.setdefault(name, len(names)))
        line_of.append(line_no)
    if not frame_of:
        raise InputError("no marker rows after the header", path)
    X = np.frombuffer(xyz, dtype=np.float64).reshape(-1, 3)
    lines = np.frombuffer(line_of, dtype=np.int64)
    bad = np.isinf(X).any(axis=1)
    if bad.any():
        raise InputError(f"line {int(lines[bad].min())}: a coordinate is infinite", path)
    order, t = np.unique(np.frombuffer(frame_of, dtype=np.int64), return_inverse=True)
    j = np.frombuffer(marker_of, dtype=np.int64)
    p, inv = len(names), list(names)
    key = t * p + j
    srt = np.argsort(key, kind="stable")
    again = np.zeros(len(key), dtype=bool)
    again[srt[1:]] = key[srt[1:]] == key[srt[:-1]]
    if again.any():
        k = int(np.flatnonzero(again)[np.argmin(lines[again])])
        raise InputError(f"line {int(lines[k])}: marker {inv[j[k]]!r} appears twice in frame {int(order[t[k]])}",
                         path)
    count = np.bincount(t, minlength=len(order))
    if (count != p).any():
        i = int(np.flatnonzero(count != p)[0])
        present = np.zeros(p, dtype=bool)
        present[j[t == i]] = True
        missing = inv[int(np.flatnonzero(~present)[0])]
        raise InputError(f"frame {int(order[i])} has {int(count[i])} markers but the file has {p} (marker "
                         f"{missing!r} is absent; write an empty or nan coordinate for a lost marker)", path)
    P = np.empty((len(order), p, 3))
    P[t, j] = X
    return MarkerSequence(order.astype(np.int64), tuple(inv), P, str(path))


def _read_npz(path: Path) -> MarkerSequence:
    from facegeom.io.npzcheck import check_npz

    check_npz(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 - any unreadable npz is a user error
        raise InputError(f"cannot read as npz ({exc.__class__.__name__})", path) from None
    if "markers" not in a:
        raise InputError(f"no 'markers' array (found: {', '.join(sorted(a)) or 'nothing'})", path)
    try:
        P = np.asarray(a["markers"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("'markers' is not numeric", path) from None
    if P.ndim != 3 or P.shape[2] != 3 or P.shape[0] == 0 or P.shape[1] == 0:
        raise InputError(f"'markers' must have shape (T, p, 3) with T, p > 0, got {P.shape}", path)
    if np.isinf(P).any():
        raise InputError("'markers' contains inf", path)
    T, p = P.shape[:2]
    if "frames" in a:
        fr = np.asarray(a["frames"])
        if fr.shape != (T,) or not np.issubdtype(fr.dtype, np.integer):
            raise InputError(f"'frames' must be {T} integers (one per frame of 'markers'), got {fr.dtype} {fr.shape}",
                             path)
        fr = fr.astype(np.int64)
        if (fr < 0).any():
            raise InputError(f"'frames': frame {int(fr[fr < 0][0])} is negative", path)
        u, c = np.unique(fr, return_counts=True)
        if (c > 1).any():
            raise InputError(f"'frames': frame {int(u[c > 1][0])} is repeated", path)
        order = np.argsort(fr, kind="stable")
        fr, P = fr[order], P[order]
    else:
        fr = np.arange(T, dtype=np.int64)
    if "marker_names" in a:
        from facegeom.io.npzcheck import check_text

        check_text(a["marker_names"], "marker_names", path)
        nm = tuple(str(x) for x in np.asarray(a["marker_names"]).ravel())
        if len(nm) != p:
            raise InputError(f"'marker_names' has {len(nm)} names for {p} markers", path)
        if len(set(nm)) != p:
            raise InputError("'marker_names' has a repeated name", path)
    else:
        nm = tuple(str(j) for j in range(p))
    return MarkerSequence(fr, nm, P, str(path), named="marker_names" in a)


def read_marker_sequence(path: str | os.PathLike) -> MarkerSequence:
    """Read a marker sequence (``.csv`` long format, ``.npz`` or ``.c3d``); frames sorted by index.

    Missing markers are NaN; see :meth:`MarkerSequence.missing` and :func:`fill_gaps`.

    Returns
    -------
    MarkerSequence
        ``positions`` ``(T, p, 3)`` float64, ``frames`` ``(T,)`` int64.

    Raises
    ------
    InputError
        Missing, empty or folder path, unsupported suffix, wrong header, a
        malformed row or array (non-integer or negative frame, infinite
        coordinate, repeated marker in a frame or repeated frame, a frame
        missing one of the markers), naming the file and line; for C3D see
        :func:`facegeom.io.c3d.read_c3d`.
    """
    path = Path(path)
    _check_path(path)
    suffix = path.suffix.lower()
    if suffix == ".c3d":
        from facegeom.io.c3d import read_c3d

        return read_c3d(path)
    return _read_csv(path) if suffix == ".csv" else _read_npz(path)


def fill_gaps(positions: np.ndarray, max_gap: int | None = None) -> tuple[np.ndarray, int]:
    """Linearly interpolate missing (NaN) marker positions over time, per marker.

    Gaps at the ends take the nearest tracked position. Returns the filled
    ``(T, p, 3)`` array and the number of filled marker samples.

    Raises
    ------
    InputError
        A marker is missing in every frame, or a gap is longer than ``max_gap``.
    """
    P = np.array(positions, dtype=np.float64, copy=True)
    miss = ~np.isfinite(P).all(axis=2)
    if not miss.any():
        return P, 0
    T = P.shape[0]
    t = np.arange(T)
    for j in np.flatnonzero(miss.any(axis=0)):
        ok = ~miss[:, j]
        if not ok.any():
            raise InputError(f"marker {j} is missing in every frame: nothing to interpolate from")
        if max_gap is not None:
            runs = np.diff(np.r_[0, miss[:, j].astype(np.int8), 0])
            lengths = np.flatnonzero(runs == -1) - np.flatnonzero(runs == 1)
            if lengths.max() > max_gap:
                raise InputError(f"marker {j} is missing for {int(lengths.max())} consecutive frames "
                                 f"(more than {max_gap})")
        for c in range(3):
            P[~ok, j, c] = np.interp(t[~ok], t[ok], P[ok, j, c])
    return P, int(miss.sum())


def read_retarget_inputs(source: str | os.PathLike, labels: str | os.PathLike, fill: bool = False,
                         echo=None) -> tuple[MarkerSequence, np.ndarray, MarkerSequence, int]:
    """Read and check the two files of ``facegeom retarget`` -> ``(source, positions, labels, n_filled)``.

    The source must hold the frames ``0..T-1``; its lost markers are an error
    unless ``fill`` (then interpolated over time: ``positions`` is the
    filled ``(T, p, 3)`` array, ``n_filled`` the number of filled samples,
    announced through ``echo`` if given). The labels are reordered to the
    source's marker names, index source frames, are complete, and number at
    least two. Labels whose file states another length unit than the
    source's (C3D ``POINT:UNITS``) are converted to the source's unit.
    """
    src = read_marker_sequence(source)
    T = src.n_frames
    if not np.array_equal(src.frames, np.arange(T)):
        # frames are sorted and distinct: the first k with frames[k] != k is absent (no array up to the last frame)
        hole = int(np.flatnonzero(src.frames != np.arange(T))[0])
        raise InputError(f"source frames must run 0..T-1 without holes; frame {hole} is absent", source)
    miss = src.missing()
    n = 0
    if miss.any():
        f, j = (int(x) for x in np.argwhere(miss)[0])
        if not fill:
            raise InputError(f"frame {f}: marker {src.names[j]!r} is lost (empty or NaN) in {int(miss.sum())} "
                             f"marker samples; pass fill=True to interpolate them over time", source)
        try:
            P, n = fill_gaps(src.positions)
        except InputError as exc:
            raise InputError(exc.reason, source) from None
        if echo is not None:
            echo(f"filled {n} lost marker samples by interpolation over time")
    else:
        P = src.positions
    lab = read_marker_sequence(labels)
    if src.unit is not None and lab.unit is not None and lab.unit != src.unit:
        lab = lab.in_unit(src.unit)  # e.g. C3D labels in m for a source in mm
    if lab.n_markers != src.n_markers:
        raise InputError(f"{lab.n_markers} markers per frame, but the source {source} has {src.n_markers}", labels)
    lab = lab.reorder(src.names, "labels")
    out_of_range = lab.frames[lab.frames >= T]
    if out_of_range.size:
        raise InputError(f"labelled frame {int(out_of_range[0])} is out of range: the source has frames 0..{T - 1}",
                         labels)
    if lab.n_frames < 2:
        raise InputError(f"at least two labelled frames are needed, got {lab.n_frames}", labels)
    lmiss = lab.missing()
    if lmiss.any():
        i, j = (int(x) for x in np.argwhere(lmiss)[0])
        raise InputError(f"labelled frame {int(lab.frames[i])}: marker {lab.names[j]!r} is empty or NaN; "
                         f"known character frames must be complete", labels)
    return src, P, lab, n


def write_marker_sequence(path: str | os.PathLike, positions, frames=None, names=None, extra: dict | None = None) -> Path:
    """Write ``positions (T, p, 3)`` as ``.csv`` (long format) or ``.npz``, atomically.

    ``extra`` arrays are added to an npz (ignored for CSV).
    """
    path = Path(path)
    if path.suffix.lower() not in _WRITE_FORMATS:
        what = "output format" if path.suffix.lower() == ".c3d" else "format"  # C3D is read here, written by write_c3d
        raise InputError(f"unsupported marker-sequence {what} {path.suffix!r}; use .csv or .npz", path)
    P = np.asarray(positions, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3:
        raise InputError(f"positions must have shape (T, p, 3), got {P.shape}", path)
    T, p = P.shape[:2]
    frames = np.arange(T, dtype=np.int64) if frames is None else np.asarray(frames, dtype=np.int64)
    names = tuple(str(j) for j in range(p)) if names is None else tuple(str(n) for n in names)
    if frames.shape != (T,) or len(names) != p:
        raise InputError(f"{frames.size} frame indices and {len(names)} names for {T} frames of {p} markers", path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".npz":
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, markers=P, frames=frames, marker_names=np.array(names),
                                    **(extra or {}))
        else:
            with open(tmp, "w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(SEQUENCE_HEADER)
                for i, f in enumerate(frames.tolist()):
                    for j, n in enumerate(names):
                        w.writerow([f, n, *(repr(float(x)) if np.isfinite(x) else "" for x in P[i, j])])
    return path
