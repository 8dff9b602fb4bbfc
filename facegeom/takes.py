"""Real facial performances: Live Link Face CSV takes of ARKit blendshape weights.

Format (Apple's Live Link Face app export): a header ``Timecode,BlendShapeCount,``
then the 52 ARKit weights in PascalCase (``EyeBlinkLeft`` ... ``TongueOut``), then
9 head and eye rotations. One row per captured frame (about 30 per second);
timecode ``HH:MM:SS:FF.fff``.

Lost tracking: the app writes rows holding only ``timecode,0``. With
``policy="interpolate"`` (default) their weights are interpolated linearly
between the neighbouring good rows (held constant at the ends); with
``policy="drop"`` they are removed. Either way :attr:`Take.lost_rows` counts
them. Values slightly outside [0, 1] are kept as read; :func:`ict_weights`
clips on request.

Mapping to the ICT face model: PascalCase ``...Left``/``...Right`` becomes
camelCase ``..._L``/``..._R`` (``EyeBlinkLeft`` -> ``eyeBlink_L``), except the
shapes whose own name is a direction (``MouthLeft``, ``JawRight``...);
ARKit's single ``BrowInnerUp`` and ``CheekPuff`` drive both sides; ICT has no
``TongueOut``.
"""
from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .errors import InputError

__all__ = ["ARKIT_NAMES", "Take", "read_take", "arkit_to_ict_name", "ict_weights", "find_takes"]

ARKIT_NAMES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawRight", "JawLeft", "JawOpen", "MouthClose", "MouthFunnel",
    "MouthPucker", "MouthRight", "MouthLeft", "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft",
    "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper", "MouthPressLeft", "MouthPressRight",
    "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft", "MouthUpperUpRight", "BrowDownLeft",
    "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight", "CheekPuff", "CheekSquintLeft",
    "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
)
_DIRECTION_SHAPES = {"MouthLeft", "MouthRight", "JawLeft", "JawRight"}
_BOTH_SIDES = {"BrowInnerUp", "CheekPuff"}
POLICIES = ("interpolate", "drop")


@dataclass
class Take:
    """One recorded performance."""

    path: str
    names: tuple[str, ...]
    weights: np.ndarray  # (T, 52)
    times: np.ndarray  # (T,) seconds from the first row
    lost_rows: int
    policy: str

    @property
    def n_frames(self) -> int:
        return int(self.weights.shape[0])


def _seconds(tc: str, fps: float = 30.0) -> float:
    parts = tc.strip().split(":")
    if len(parts) != 4:
        raise ValueError(tc)
    h, m, s, f = parts
    return int(h) * 3600 + int(m) * 60 + int(s) + float(f) / fps


def read_take(path, policy: str = "interpolate") -> Take:
    """Read a Live Link Face CSV take.

    Raises
    ------
    InputError
        Missing/unreadable file, a header without ``Timecode`` or any ARKit
        weight column, a non-numeric value, a malformed row, or no usable row.
    """
    if policy not in POLICIES:
        raise InputError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}", path)
    p = Path(path)
    if not p.is_file():
        raise InputError("no such take file", path)
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the take: {exc}", path) from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise InputError("the take file is empty", path)
    header = [c.strip() for c in rows[0]]
    if not header or header[0] != "Timecode":
        raise InputError("not a Live Link Face take: the header must start with 'Timecode'", path)
    missing = [n for n in ARKIT_NAMES if n not in header]
    if missing:
        raise InputError(f"the header lacks ARKit weight column(s): {', '.join(missing)}", path)
    cols = np.array([header.index(n) for n in ARKIT_NAMES])
    good, good_idx, times, lost = [], [], [], []
    for i, r in enumerate(rows[1:]):
        line = i + 2
        if len(r) != len(header):
            if len(r) <= 2 and (len(r) < 2 or r[1].strip() in ("0", "")):
                lost.append(i)
                times.append(_safe_seconds(r[0] if r else "", line, path))
                continue
            raise InputError(f"row {line} has {len(r)} columns, the header has {len(header)}", path)
        try:
            good.append([float(r[c]) for c in cols])
        except ValueError:
            bad = next(c for c in cols if not _is_float(r[c]))
            raise InputError(f"row {line}, column {header[bad]}: not a number: {r[bad]!r}", path) from None
        good_idx.append(i)
        times.append(_safe_seconds(r[0], line, path))
    if not good:
        raise InputError(f"no usable row: all {len(lost)} rows are lost-tracking rows", path)
    G = np.asarray(good, dtype=np.float64)
    if not np.isfinite(G).all():
        raise InputError("the take holds NaN or infinite weights", path)
    n = len(rows) - 1
    t_all = np.asarray(times, dtype=np.float64)
    if policy == "interpolate" and lost:
        W = np.empty((n, len(ARKIT_NAMES)))
        gi = np.asarray(good_idx)
        for k in range(W.shape[1]):
            W[:, k] = np.interp(np.arange(n), gi, G[:, k])
        keep_t = t_all
    else:
        W, keep_t = G, t_all[np.asarray(good_idx)]
    return Take(str(p), ARKIT_NAMES, W, keep_t - keep_t[0], len(lost), policy)


def _is_float(x: str) -> bool:
    try:
        float(x)
        return True
    except ValueError:
        return False


def _safe_seconds(tc: str, line: int, path) -> float:
    try:
        return _seconds(tc)
    except ValueError:
        raise InputError(f"row {line}: bad timecode {tc!r} (expected HH:MM:SS:FF.fff)", path) from None


def arkit_to_ict_name(name: str) -> list[str]:
    """ICT expression names driven by one ARKit weight (empty for ``TongueOut``)."""
    if name == "TongueOut":
        return []
    camel = name[0].lower() + name[1:]
    if name in _BOTH_SIDES:
        return [camel + "_L", camel + "_R"]
    if name in _DIRECTION_SHAPES:
        return [camel]
    for side, suffix in (("Left", "_L"), ("Right", "_R")):
        if name.endswith(side):
            return [camel[: -len(side)] + suffix]
    return [camel]


def ict_weights(take: Take, expression_names: Sequence[str], clip: bool = True) -> np.ndarray:
    """The take's weights as ``(T, E)`` in the order of ``expression_names`` (0 where no source)."""
    index = {n: i for i, n in enumerate(expression_names)}
    W = np.zeros((take.n_frames, len(expression_names)))
    for k, name in enumerate(take.names):
        for target in arkit_to_ict_name(name):
            if target in index:
                W[:, index[target]] = take.weights[:, k]
    return np.clip(W, 0.0, 1.0) if clip else W


def find_takes(folder) -> list[Path]:
    """The ``*.csv`` takes of a folder, sorted by name."""
    p = Path(folder)
    if not p.is_dir():
        raise InputError("no such folder of takes", folder)
    files = sorted(x for x in p.iterdir() if x.suffix.lower() == ".csv" and x.is_file())
    if not files:
        raise InputError("no .csv take in this folder", folder)
    return files
