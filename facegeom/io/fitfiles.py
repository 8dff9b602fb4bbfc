"""Files of blendshape fitting: landmark CSVs, point clouds, fitted coefficients.

- Landmarks: CSV with the header ``vertex_id,u,v`` (pixels; ``v`` grows
  downwards, the convention of :class:`facegeom.model.camera.PinholeCamera`),
  or an iBUG / 300-W ``.pts`` annotation (:func:`read_pts`: the 68-point
  convention's points by index, 1-based pixels).
- Point clouds: PLY / OBJ / XYZ / OFF read by the validating readers of
  :mod:`facegeom.io.formats` (faces, if any, are ignored), or ``.npy`` ``(N, 3)``
  (no pickles; its size checked against the file before loading).
- Coefficients: JSON ``{"weights": {name: value}, ...}`` or CSV ``shape,weight``,
  written atomically.

The model objects built from these files (rig, targets) are made by
:mod:`facegeom.model.inputs`.
"""
from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io.files import atomic_path, parse_csv_text, read_csv_rows
from facegeom.io.formats import read_points
from facegeom.io.images import image_size  # re-exported: photos live in facegeom.io.images
from facegeom.io.ints import check_int64

__all__ = ["read_landmarks", "read_pts", "PTS_MAX_POINTS", "image_size", "read_point_cloud", "write_weights",
           "read_weights", "CLOUD_FORMATS", "TARGET_KINDS"]

CLOUD_FORMATS = (".ply", ".obj", ".xyz", ".off", ".npy")
TARGET_KINDS = ("auto", "mesh", "landmarks", "points")


def _exists(path: Path, what: str) -> None:
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError(f"is a folder, not a {what} file", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)


def read_landmarks(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read ``vertex_id,u,v`` rows -> ``ids (L,)``, ``uv (L, 2)``; ids distinct, values finite."""
    path = Path(path)
    _exists(path, "landmark")
    rows = [r for r in read_csv_rows(path, "landmark") if any(c.strip() for c in r)]
    if not rows or tuple(c.strip().lower() for c in rows[0]) != ("vertex_id", "u", "v"):
        raise InputError("expected the header vertex_id,u,v", path)
    ids, uv = [], []
    for line_no, r in enumerate(rows[1:], start=2):
        if len(r) != 3:
            raise InputError(f"line {line_no}: expected 3 values, got {len(r)}", path)
        try:
            vid = int(r[0])
            q = [float(r[1]), float(r[2])]
        except ValueError:
            raise InputError(f"line {line_no}: not a number", path) from None
        ids.append(check_int64(vid, "vertex_id", line_no, path))
        if not np.all(np.isfinite(q)):
            raise InputError(f"line {line_no}: coordinate is NaN or inf", path)
        uv.append(q)
    if not ids:
        raise InputError("no landmark rows after the header", path)
    ids = np.array(ids, dtype=np.int64)
    u, c = np.unique(ids, return_counts=True)
    if (c > 1).any():
        raise InputError(f"vertex_id {int(u[c > 1][0])} is repeated", path)
    if (ids < 0).any():
        raise InputError(f"vertex_id {int(ids[ids < 0][0])} is negative", path)
    return ids, np.array(uv, dtype=np.float64)


#: Most points a ``.pts`` file may hold (the common conventions have 5-194; the limit keeps a hostile count small).
PTS_MAX_POINTS = 10_000


def read_pts(path: str | os.PathLike) -> np.ndarray:
    """Read an iBUG / 300-W ``.pts`` landmark annotation -> ``(N, 2)`` pixel coordinates, 0-based.

    The format: optional header lines ``version: 1`` and ``n_points: N``, a
    line ``{``, one ``x y`` line per point, a line ``}``. The annotations of
    300-W and the tools that follow it are 1-based (Matlab's pixel indices:
    the top-left pixel's centre is ``(1, 1)``), so 1 is subtracted to match
    the 0-based convention of :class:`facegeom.model.camera.PinholeCamera`.
    Which landmark each row is follows from its place (e.g. the 68-point
    Multi-PIE / iBUG order).

    Raises
    ------
    InputError
        Missing, empty, not text, no ``{ ... }`` block, a row that is not two
        numbers, NaN / inf, ``n_points`` not matching the rows, more than
        :data:`PTS_MAX_POINTS` points.
    """
    path = Path(path)
    _exists(path, "landmark")
    if path.stat().st_size > 64 * PTS_MAX_POINTS + 4096:
        raise InputError(f"too large for a .pts annotation (over {PTS_MAX_POINTS} points)", path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    lines = text.splitlines()
    count, start = None, None
    for i, line in enumerate(lines):
        t = line.strip()
        if not t:
            continue
        if t == "{":
            start = i + 1
            break
        key, sep, value = t.partition(":")
        if not sep or key.strip().lower() not in ("version", "n_points"):
            raise InputError(f"line {i + 1}: expected 'version: 1', 'n_points: N' or '{{', got {t[:40]!r}", path)
        if key.strip().lower() == "n_points":
            try:
                count = int(value.strip())
            except ValueError:
                raise InputError(f"line {i + 1}: n_points is not a whole number", path) from None
            if not 1 <= count <= PTS_MAX_POINTS:
                raise InputError(f"line {i + 1}: n_points must be 1-{PTS_MAX_POINTS}, got {count}", path)
    if start is None:
        raise InputError("no '{' line opening the points", path)
    pts, closed = [], False
    for i in range(start, len(lines)):
        t = lines[i].strip()
        if not t:
            continue
        if t == "}":
            closed = True
            rest = [x for x in lines[i + 1:] if x.strip()]
            if rest:
                raise InputError(f"line {i + 2}: text after the closing '}}'", path)
            break
        parts = t.split()
        if len(parts) != 2:
            raise InputError(f"line {i + 1}: expected two numbers 'x y', got {len(parts)} values", path)
        try:
            q = [float(parts[0]), float(parts[1])]
        except ValueError:
            raise InputError(f"line {i + 1}: not a number", path) from None
        if not np.all(np.isfinite(q)):
            raise InputError(f"line {i + 1}: coordinate is NaN or inf", path)
        pts.append(q)
        if len(pts) > PTS_MAX_POINTS:
            raise InputError(f"more than {PTS_MAX_POINTS} points", path)
    if not closed:
        raise InputError("no '}' line closing the points", path)
    if not pts:
        raise InputError("no points between '{' and '}'", path)
    if count is not None and count != len(pts):
        raise InputError(f"n_points says {count} but the file has {len(pts)} points", path)
    return np.array(pts, dtype=np.float64) - 1.0


def _read_npy(path: Path) -> np.ndarray:
    """A ``.npy`` array, its size checked against the file before it is loaded (no pickles)."""
    try:
        P = np.load(path, mmap_mode="r", allow_pickle=False)  # maps: a header larger than the file fails here
        return np.array(P, dtype=np.float64)
    except Exception as exc:  # noqa: BLE001 - numpy raises many types on a malformed header
        raise InputError(f"cannot read as .npy ({exc.__class__.__name__})", path) from None


def read_point_cloud(path: str | os.PathLike) -> np.ndarray:
    """Read a point cloud: the vertices of a PLY / OBJ / OFF (faces ignored), an XYZ, or a ``.npy``.

    Parameters
    ----------
    path : str or PathLike
        ``.ply``, ``.obj``, ``.off``, ``.xyz`` (read by :func:`facegeom.io.formats.read_points`)
        or ``.npy`` of shape ``(N, 3)``.

    Returns
    -------
    (N, 3) float64
        N >= 1, finite.

    Raises
    ------
    InputError
        Missing, empty, malformed or truncated file, NaN/inf, no point.
    """
    path = Path(path)
    _exists(path, "point-cloud")
    suffix = path.suffix.lower()
    if suffix not in CLOUD_FORMATS:
        raise InputError(f"unsupported point-cloud format {suffix!r}; use one of {', '.join(CLOUD_FORMATS)}", path)
    if suffix == ".npy":
        P = _read_npy(path)
    else:
        try:
            P = read_points(path)
        except InputError as exc:
            raise InputError(f"malformed point cloud: {exc.reason}", path) from None
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(f"point cloud must have shape (N, 3), got {P.shape}", path)
    if P.shape[0] == 0:
        raise InputError("the point cloud has no point", path)
    bad = ~np.isfinite(P).all(axis=1)
    if bad.any():
        raise InputError(f"point {int(np.flatnonzero(bad)[0])} is NaN or inf", path)
    return P


def write_weights(path: str | os.PathLike, names, weights, info: dict | None = None) -> Path:
    """Write coefficients by name as ``.json`` (with ``info``) or ``.csv`` (``shape,weight``), atomically."""
    path = Path(path)
    w = np.asarray(weights, dtype=np.float64)
    names = list(names)
    if w.shape != (len(names),):
        raise InputError(f"{w.size} weights for {len(names)} names", path)
    suffix = path.suffix.lower()
    if suffix not in (".json", ".csv"):
        raise InputError(f"unsupported coefficient format {suffix!r}; use .json or .csv", path)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            if suffix == ".json":
                json.dump({"weights": {n: float(x) for n, x in zip(names, w)}, **(info or {})}, fh, indent=2)
                fh.write("\n")
            else:
                cw = csv.writer(fh)
                cw.writerow(["shape", "weight"])
                for n, x in zip(names, w):
                    cw.writerow([n, repr(float(x))])
    return path


def read_weights(path: str | os.PathLike, names) -> np.ndarray:
    """Read coefficients written by :func:`write_weights` (``.json`` or ``.csv``) in the order of ``names``.

    Shapes the file does not name are 0; a name the rig does not have is an error.

    Returns
    -------
    (B,) float64
        One finite weight per name of ``names`` (``B = len(names)``).

    Raises
    ------
    InputError
        Missing, empty or unreadable file, unsupported suffix, wrong header or
        layout, an unknown shape name, or a weight that is not a finite number.
    """
    path = Path(path)
    _exists(path, "coefficient")
    suffix = path.suffix.lower()
    try:
        if suffix == ".json":
            data = json.loads(path.read_text(encoding="utf-8-sig"))
            got = data.get("weights") if isinstance(data, dict) else None
            if not isinstance(got, dict):
                raise InputError("no 'weights' object (expected {\"weights\": {name: value}})", path)
        elif suffix == ".csv":
            rows = [r for r in parse_csv_text(path.read_text(encoding="utf-8-sig"), path) if r]
            if not rows or [c.strip().lower() for c in rows[0]] != ["shape", "weight"]:
                raise InputError("expected the header shape,weight", path)
            got = {}
            for line_no, r in enumerate(rows[1:], start=2):
                if len(r) != 2:
                    raise InputError(f"line {line_no}: expected 2 values, got {len(r)}", path)
                got[r[0].strip()] = r[1]
        else:
            raise InputError(f"unsupported coefficient format {suffix!r}; use .json or .csv", path)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read coefficients ({exc.__class__.__name__})", path) from None
    names = list(names)
    index = {n: i for i, n in enumerate(names)}
    w = np.zeros(len(names))
    for name, value in got.items():
        if name not in index:
            raise InputError(f"unknown shape {name!r} (the rig has {len(names)} shapes)", path)
        try:
            w[index[name]] = float(value)
        except (TypeError, ValueError):
            raise InputError(f"weight of {name!r} is not a number", path) from None
    if not np.all(np.isfinite(w)):
        raise InputError("a weight is NaN or inf", path)
    return w


