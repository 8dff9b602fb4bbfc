"""Blendshape names across rigs: ICT, ARKit (camelCase or PascalCase), exporter decorations, mapping files.

Every take, solve and fit in facegeom speaks the ICT face model's names
(``eyeBlink_L``, ``browInnerUp_L``/``_R``); Live Link Face takes speak
ARKit's 52 names in PascalCase (``EyeBlinkLeft``); an artist's rig often
carries ARKit's camelCase names (``eyeBlinkLeft``) with whatever its exporter
added (``blendShape1.eyeBlinkLeft``, ``Face.jawOpen.001``). This module is the
one place that knows how these names meet.

Matching
--------
A name is first stripped of exporter decorations (:func:`undecorate`):
namespaces and paths (``Face:``, ``|head|``), a numbered duplicate suffix
(``.001``), a prefix before the last dot (``blendShape1.``, ``Face.``), and,
when what is left is not a known shape but a tail after an underscore is, the
prefix before it (``mesh_``, ``head_geo_``). Blender's side suffixes ``.L`` /
``.R`` are kept as sides. The rest is compared case-insensitively as a *key*
``(base, side)`` (:func:`shape_key`): a side suffix ``_L`` / ``_R``,
``Left`` / ``Right``, ``_left`` / ``_right`` becomes ``side`` ``"L"`` / ``"R"``
(``eyeBlink_L``, ``eyeBlinkLeft``, ``EyeBlinkLeft`` and
``blendShape1.eyeblink_left`` all give ``("eyeblink", "L")``). ``mouthLeft``,
``mouthRight``, ``jawLeft`` and ``jawRight`` are shapes of their own (a
direction), not sided variants. "Left" is the performer's left everywhere.

ICT <-> ARKit
-------------
One to one on the key, except ARKit's single ``browInnerUp`` and ``cheekPuff``
(the ICT rig has an ``_L`` / ``_R`` pair of each): ARKit -> ICT drives both
sides with the one weight, ICT -> ARKit takes the mean of the two sides (an
asymmetric inner brow or puff becomes symmetric). ``tongueOut`` has no ICT
shape. The 53 ICT expressions are exactly ARKit's 52 minus ``tongueOut`` with
those two pairs split, so the ICT rig has no shape beyond ARKit's; a
:class:`ShapeMap` still lists by name every shape on either side that the
other does not reach (:attr:`ShapeMap.unmapped_rig`,
:attr:`ShapeMap.unmapped_source`).

The rule generalises to any names: a rig shape with no side is driven by the
mean of the source's ``_L`` and ``_R`` shapes of the same base when the source
has no unsided one; a sided rig shape is driven by the source's unsided shape
of its base when the source has no sided one.

Mapping files
-------------
A CSV with the header ``rig_shape,source_shape,gain`` (``gain`` optional,
default 1) says how source weights drive the rig's shapes by hand: the rig
weight of ``rig_shape`` is the sum, over its rows, of ``gain`` times the
source weight of ``source_shape``. Rig shapes the file does not name keep the
automatic match (a row with gain 0 switches one off). ``source_shape`` may be
spelled in any convention (``mouthSmileLeft`` reaches an ICT source's
``mouthSmile_L``). Blank lines and lines starting with ``#`` are ignored.
:func:`read_name_mapping` reads it; errors name the file and the line and
quote at most 80 characters of its text.

Limits, checked before any work: a file over 1 MiB (:data:`MAX_MAPPING_BYTES`)
is refused by its size before it is read (a real mapping has at most a few
thousand rows of a few tens of bytes); every gain is finite with
``|gain| <= 10`` (:data:`MAX_GAIN`), and so is the sum of the ``|gain|`` of the
rows of one rig shape: a mapping scales source weights in [0, 1] onto a rig
shape sculpted for weights in [0, 1], and ten times its sculpted motion is
already far past any use (a gain of 1e308 once wrote inf weights).

Two spellings of one shape
--------------------------
Some rigs carry a shape twice under two conventions (Microsoft Rocketbox's
175-channel heads hold ARKit's ``AK_25_JawOpen`` and Vive SRanipal's
``SR_21_Jaw_Open``); driving both would open the jaw twice. When several rig
shapes match one source name automatically (the same key, or an unsided shape
and the sided ones of its base), :meth:`ShapeMap.between` drives one: an exact
match of the source's name first, then the shape spelled as ICT or ARKit spell
it once decorations are removed (``AK_25_JawOpen`` -> ``JawOpen``), then a
direct match over a mean or split of sides, then the rig's order. The others
stay at 0 and are listed (:attr:`ShapeMap.ambiguous`, and
:meth:`ShapeMap.describe`); a mapping file drives them. A rig shape a mapping
file drives claims its sources the same way.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from facegeom.errors import InputError

__all__ = [
    "MAX_GAIN",
    "MAX_MAPPING_BYTES",
    "ARKIT_NAMES",
    "ARKIT_CAMEL_NAMES",
    "ICT_NAMES",
    "CONVENTIONS",
    "NamingConvention",
    "NameMapping",
    "MappingRow",
    "ShapeMap",
    "arkit_to_ict_name",
    "ict_to_arkit_name",
    "naming_convention",
    "read_name_mapping",
    "shape_key",
    "undecorate",
]

#: A mapping file larger than this is refused before it is read: one row per (rig shape, source shape) pair it
#: sets, a few thousand rows of a few tens of bytes at most (a 175-shape rig with three sources a shape is ~20 kB);
#: 1 MiB holds ~25,000 rows, and reads in well under a second and tens of MB (100 MB once took 98 s and 3.5 GB).
MAX_MAPPING_BYTES = 1 << 20

#: Largest ``|gain|`` of a mapping row, and of the sum of the ``|gain|`` of one rig shape's rows: a mapping scales
#: source weights in [0, 1] onto a rig shape sculpted for weights in [0, 1]; ten times its sculpted motion is far
#: past any use, and the rig weights stay finite in float32 (.glb) whatever the rows.
MAX_GAIN = 10.0

#: Characters of a file's text an error quotes at most (the rest: an ellipsis).
QUOTE_CHARS = 80


def _cut(text) -> str:
    """``text`` cut to :data:`QUOTE_CHARS` characters (an ellipsis marks a cut)."""
    text = str(text)
    return text if len(text) <= QUOTE_CHARS else text[:QUOTE_CHARS] + "…"


def _q(text) -> str:
    """``repr`` of ``text`` cut to :data:`QUOTE_CHARS` characters."""
    return repr(_cut(text))


#: The 52 ARKit blendshape names, PascalCase, in the order Live Link Face writes them.
ARKIT_NAMES: tuple[str, ...] = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft",
    "EyeSquintLeft", "EyeWideLeft",
    "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight",
    "JawForward", "JawRight", "JawLeft", "JawOpen",
    "MouthClose", "MouthFunnel", "MouthPucker", "MouthRight", "MouthLeft",
    "MouthSmileLeft", "MouthSmileRight", "MouthFrownLeft", "MouthFrownRight",
    "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft", "MouthStretchRight",
    "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper",
    "MouthPressLeft", "MouthPressRight", "MouthLowerDownLeft", "MouthLowerDownRight",
    "MouthUpperUpLeft", "MouthUpperUpRight",
    "BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight",
    "CheekPuff", "CheekSquintLeft", "CheekSquintRight",
    "NoseSneerLeft", "NoseSneerRight",
    "TongueOut",
)

#: The same 52 names in ARKit's API spelling (camelCase: ``eyeBlinkLeft``), same order.
ARKIT_CAMEL_NAMES: tuple[str, ...] = tuple(n[0].lower() + n[1:] for n in ARKIT_NAMES)

_ARKIT_SET = frozenset(ARKIT_NAMES)
_OWN_DIRECTION = frozenset({"MouthLeft", "MouthRight", "JawLeft", "JawRight"})
_BOTH_SIDES = frozenset({"BrowInnerUp", "CheekPuff"})
_NO_ICT = frozenset({"TongueOut"})


def arkit_to_ict_name(name: str) -> list[str]:
    """The ICT expression names that one ARKit weight drives.

    Parameters
    ----------
    name : str
        An ARKit blendshape name, PascalCase as in Live Link Face files
        (``EyeBlinkLeft``) or camelCase as in ARKit's API (``eyeBlinkLeft``).

    Returns
    -------
    list of str
        ``['eyeBlink_L']`` for ``EyeBlinkLeft``; ``['mouthLeft']`` for
        ``MouthLeft`` (a shape of its own, likewise ``MouthRight``, ``JawLeft``,
        ``JawRight``); both sides for ``BrowInnerUp`` and ``CheekPuff``; ``[]``
        for ``TongueOut``.

    Raises
    ------
    InputError
        ``name`` is not one of the 52 ARKit shapes.
    """
    pascal = name[:1].upper() + name[1:]
    if pascal not in _ARKIT_SET:
        raise InputError(f"not an ARKit blendshape name: {_q(name)}")
    if pascal in _NO_ICT:
        return []
    camel = pascal[0].lower() + pascal[1:]
    if pascal in _BOTH_SIDES:
        return [camel + "_L", camel + "_R"]
    if pascal not in _OWN_DIRECTION:
        for side, suffix in (("Left", "_L"), ("Right", "_R")):
            if camel.endswith(side):
                return [camel[: -len(side)] + suffix]
    return [camel]


#: The 53 ICT expression names (the face model's ``expression_names``, in its alphabetical order).
ICT_NAMES: tuple[str, ...] = tuple(sorted(n for a in ARKIT_NAMES for n in arkit_to_ict_name(a)))

_ICT_SET = frozenset(ICT_NAMES)
_CAMEL_SET = frozenset(ARKIT_CAMEL_NAMES)


def ict_to_arkit_name(name: str) -> str:
    """The ARKit name (PascalCase) of an ICT expression: ``eyeBlink_L`` -> ``EyeBlinkLeft``,
    ``browInnerUp_R`` -> ``BrowInnerUp`` (one ARKit shape for both sides).

    Raises
    ------
    InputError
        ``name`` is not one of the 53 ICT expressions.
    """
    if name not in _ICT_SET:
        raise InputError(f"not an ICT expression name: {_q(name)}")
    for a in ARKIT_NAMES:
        if name in arkit_to_ict_name(a):
            return a
    raise AssertionError(name)  # pragma: no cover - every ICT name comes from an ARKit one


# ----------------------------------------------------------------------------- keys

_OWN_LOW = frozenset(n.lower() for n in _OWN_DIRECTION)
_SIDE_SUFFIXES = (("_left", "L"), ("_right", "R"), ("left", "L"), ("right", "R"), ("_l", "L"), ("_r", "R"))
_SEPARATORS = re.compile(r"[\s\-_]+")
_NUMBERED = re.compile(r"\.\d+$")
_DOT_SIDE = re.compile(r"\.([LlRr])$")


def _key_of(plain: str) -> tuple[str, str | None]:
    low = _SEPARATORS.sub("_", plain.strip().lower()).strip("_")
    if low.replace("_", "") in _OWN_LOW:  # mouthLeft, Mouth_Left: the mouth's own shape
        return low.replace("_", ""), None
    for suffix, side in _SIDE_SUFFIXES:
        if low.endswith(suffix) and len(low) - len(suffix) >= 2:
            return low[: -len(suffix)].replace("_", ""), side
    return low.replace("_", ""), None


_KNOWN_KEYS = frozenset(_key_of(n) for n in (*ICT_NAMES, *ARKIT_NAMES))


def undecorate(name: str) -> str:
    """``name`` without exporter decorations (case kept): ``blendShape1.eyeBlinkLeft`` -> ``eyeBlinkLeft``.

    Removed, in this order: a namespace or path before the last ``:`` or ``|``;
    a numbered duplicate suffix ``.001``; everything before the last dot
    (Blender's ``.L`` / ``.R`` become ``_L`` / ``_R`` first); and, when the
    rest is not a known ICT or ARKit shape but what follows one of its
    underscores is, the prefix before the first such underscore
    (``mesh_jawOpen`` -> ``jawOpen``, ``head_geo_mouthSmile_L`` -> ``mouthSmile_L``).
    """
    s = str(name).strip()
    s = re.split(r"[:|]", s)[-1]
    s = _NUMBERED.sub("", s)
    m = _DOT_SIDE.search(s)
    if m:
        s = s[: m.start()] + "_" + m.group(1).upper()
    if "." in s:
        s = s.rsplit(".", 1)[1]
    if _key_of(s) not in _KNOWN_KEYS:
        for i, ch in enumerate(s):
            if ch == "_" and _key_of(s[i + 1:]) in _KNOWN_KEYS and s[i + 1:].upper() not in ("L", "R"):
                return s[i + 1:]
    return s


def shape_key(name: str) -> tuple[str, str | None]:
    """The matching key ``(base, side)`` of a shape name: lower case, decorations removed, side apart.

    ``eyeBlink_L``, ``eyeBlinkLeft``, ``EyeBlinkLeft``, ``Face.eyeBlink_left.001``
    -> ``("eyeblink", "L")``; ``browInnerUp`` -> ``("browinnerup", None)``;
    ``mouthLeft`` -> ``("mouthleft", None)`` (a shape of its own).
    """
    return _key_of(undecorate(name))


# ----------------------------------------------------------------------------- conventions

#: Naming conventions :func:`naming_convention` tells apart, with how they are described.
CONVENTIONS: dict[str, str] = {
    "ict": "ICT (eyeBlink_L)",
    "arkit": "ARKit camelCase (eyeBlinkLeft)",
    "arkit-pascal": "ARKit PascalCase (EyeBlinkLeft)",
    "other": "not ICT or ARKit",
}


@dataclass(frozen=True)
class NamingConvention:
    """What a list of shape names is.

    Attributes
    ----------
    name : str
        ``ict``, ``arkit``, ``arkit-pascal`` or ``other`` (fewer than half of
        the names are ICT or ARKit shapes in one spelling).
    recognised : int
        Names that are ICT or ARKit shapes (case-insensitively, decorations removed).
    total : int
        Number of names.
    decorated : tuple of str
        The names that carried exporter decorations (``blendShape1.jawOpen``).
    """

    name: str
    recognised: int
    total: int
    decorated: tuple[str, ...] = ()

    def __str__(self) -> str:
        text = f"{CONVENTIONS[self.name]}, {self.recognised} of {self.total} names recognised"
        if self.decorated:
            text += f", exporter decorations removed (e.g. {self.decorated[0]!r})"
        return text


def naming_convention(names: Sequence[str]) -> NamingConvention:
    """Tell the naming convention of a rig's shape names.

    Each name, decorations removed (:func:`undecorate`), is counted for ICT if
    it is an ICT expression as spelled, for ARKit camelCase or PascalCase if it
    is one of those 52 names as spelled (``jawOpen`` counts for ICT and ARKit
    camelCase alike; sided names and ``browInnerUp`` / ``cheekPuff`` tell them
    apart). The convention with most names wins (ICT on a tie); ``other``
    when it holds fewer than half of the names.
    """
    names = [str(n) for n in names]
    plain = [undecorate(n) for n in names]
    counts = {"ict": sum(p in _ICT_SET for p in plain), "arkit": sum(p in _CAMEL_SET for p in plain),
              "arkit-pascal": sum(p in _ARKIT_SET for p in plain)}
    best = max(counts, key=lambda k: (counts[k], k == "ict"))
    if 2 * counts[best] < max(len(names), 1):
        best = "other"
    recognised = sum(_key_of(p) in _KNOWN_KEYS for p in plain)
    decorated = tuple(n for n, p in zip(names, plain) if n.strip() != p)
    return NamingConvention(best, recognised, len(names), decorated)


# ----------------------------------------------------------------------------- mapping files

MAPPING_HEADER = ("rig_shape", "source_shape", "gain")


@dataclass(frozen=True)
class MappingRow:
    """One row of a mapping file: ``rig weight += gain * source weight``; ``line`` is its line number."""

    rig: str
    source: str
    gain: float
    line: int


@dataclass(frozen=True)
class NameMapping:
    """The rows of a mapping CSV (:func:`read_name_mapping`) and the file they came from."""

    rows: tuple[MappingRow, ...]
    path: str = ""

    @property
    def name(self) -> str:
        """The file's name (``"the mapping"`` when built in memory)."""
        return Path(self.path).name if self.path else "the mapping"


def _capped_csv_rows(path: Path, cap: int, what: str, why: str) -> list[list[str]]:
    """The rows of the text CSV ``path`` as :func:`facegeom.io.files.read_csv_rows` gives them, refused in one line
    when the file holds more than ``cap`` bytes: by its size before a byte is read, and, for a file whose size says
    nothing (a pipe, a device), once ``cap + 1`` bytes have come. ``what``: the kind of file; ``why``: the cap's
    reason, for the message."""
    from facegeom.io.files import _check_csv_path, parse_csv_text

    _check_csv_path(path, what)

    def too_big(size: str) -> InputError:
        return InputError(f"{size} over the {cap:,}-byte limit of a {what} ({why}): not read", path)

    try:
        size = os.stat(path).st_size
        if size > cap:
            raise too_big(f"{size:,} bytes:")
        with open(path, "rb") as fh:
            data = fh.read(cap + 1)
    except OSError as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    if len(data) > cap:
        raise too_big("more than that:")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
    return parse_csv_text(text.replace("\r\n", "\n").replace("\r", "\n"), path)  # newlines as a text read reads them


def read_name_mapping(path: str | os.PathLike) -> NameMapping:
    """Read a mapping CSV ``rig_shape,source_shape,gain`` (see the module notes).

    Raises
    ------
    InputError
        Naming the file and the line: missing or unreadable file, a file over
        :data:`MAX_MAPPING_BYTES` (refused before it is read), a wrong header,
        a row without two or three cells, an empty name, a gain that is not a
        finite number in ``[-MAX_GAIN, MAX_GAIN]``, a (rig_shape, source_shape)
        pair given twice, no row at all.
    """
    p = Path(path)
    rows = _capped_csv_rows(p, MAX_MAPPING_BYTES, "shape mapping CSV",
                            "a mapping has at most a few thousand rows of a few tens of bytes")
    body = [(i + 1, [c.strip() for c in r]) for i, r in enumerate(rows)
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not body:
        raise InputError("the shape mapping is empty (expected the header rig_shape,source_shape,gain and rows)", p)
    line, header = body[0]
    header = [c.lower() for c in header]
    while header and header[-1] == "":
        header.pop()
    if tuple(header) not in (MAPPING_HEADER, MAPPING_HEADER[:2]):
        raise InputError(f"line {line}: the header must be rig_shape,source_shape,gain (gain optional), "
                         f"got {_q(','.join(header))}", p)
    out: list[MappingRow] = []
    seen: dict[tuple[str, str], int] = {}
    for line, cells in body[1:]:
        while len(cells) > 2 and cells[-1] == "":
            cells = cells[:-1]
        if len(cells) not in (2, 3):
            raise InputError(f"line {line}: expected rig_shape,source_shape[,gain], got {len(cells)} cells", p)
        rig, source = cells[0], cells[1]
        if not rig or not source:
            raise InputError(f"line {line}: the {'rig' if not rig else 'source'} shape is empty", p)
        gain = 1.0
        if len(cells) == 3 and cells[2] != "":
            try:
                gain = float(cells[2])
            except ValueError:
                gain = float("nan")
            if not math.isfinite(gain):
                raise InputError(f"line {line}: gain {_q(cells[2])} is not a finite number", p)
            if abs(gain) > MAX_GAIN:
                raise InputError(f"line {line}: gain {_q(cells[2])} is outside [-{MAX_GAIN:g}, {MAX_GAIN:g}] {_WHY_GAIN}",
                                 p)
        if (rig, source) in seen:
            raise InputError(f"line {line}: {_cut(f'{rig},{source}')} is already on line {seen[(rig, source)]}", p)
        seen[(rig, source)] = line
        out.append(MappingRow(rig, source, gain, line))
    if not out:
        raise InputError("the shape mapping has a header but no rows", p)
    return NameMapping(tuple(out), str(p))


_WHY_GAIN = "(a mapping scales source weights in [0, 1] onto a rig shape sculpted for [0, 1])"


def _check_gains(mapping: NameMapping, rows_of: dict) -> None:
    """Every row's gain finite and within :data:`MAX_GAIN`, and the ``|gain|`` of the rows of each rig shape
    (``rows_of``: the rig's name of the shape -> its rows, names resolved) summed within it too, else one line
    naming the file and the row (mappings not read by :func:`read_name_mapping`, e.g. a rig file's, reach here
    unchecked)."""
    path = mapping.path or None
    for row in mapping.rows:
        if not (math.isfinite(row.gain) and abs(row.gain) <= MAX_GAIN):
            raise InputError(f"line {row.line}: gain {row.gain:g} of {_q(row.rig)} is not a finite number within "
                             f"[-{MAX_GAIN:g}, {MAX_GAIN:g}] {_WHY_GAIN}", path)
    for name, rows in rows_of.items():
        total = 0.0
        for row in rows:
            total += abs(row.gain)
            if total > MAX_GAIN:
                lines = ", ".join(str(r.line) for r in rows[:8]) + (", ..." if len(rows) > 8 else "")
                raise InputError(f"line {row.line}: the gains of rig shape {_q(name)} add up to {total:g} "
                                 f"(|gain| over lines {lines}), beyond {MAX_GAIN:g} {_WHY_GAIN}", path)


def _as_mapping(mapping) -> NameMapping | None:
    if mapping is None or isinstance(mapping, NameMapping):
        return mapping
    return read_name_mapping(mapping)


# ----------------------------------------------------------------------------- the map


def _names(names, what: str) -> tuple[str, ...]:
    if isinstance(names, str):
        raise InputError(f"{what} must be a sequence of shape names, not one string")
    out = tuple(str(n) for n in names)
    seen = set()
    for n in out:
        if n in seen:
            raise InputError(f"{what}: the shape name {_q(n)} repeats")
        seen.add(n)
    return out


_SPELLED = _ICT_SET | _ARKIT_SET | _CAMEL_SET


def _spelled_as_known(name: str) -> bool:
    """``name``, decorations removed, is an ICT or ARKit name as those spell it (``AK_25_JawOpen``: yes,
    ``SR_21_Jaw_Open``: no)."""
    return undecorate(name) in _SPELLED


def _coverage(name: str) -> frozenset:
    """The (base, side) pieces of the face a shape moves: both sides for an unsided shape, its side for a sided one."""
    base, side = shape_key(name)
    return frozenset({(base, "L"), (base, "R")} if side is None else {(base, side)})


class _Matcher:
    """Automatic matching of names against one list of source names.

    Several source names of one key (``AK_25_JawOpen`` and ``SR_21_Jaw_Open``): the one spelled as ICT or ARKit
    spell it answers, else the first.
    """

    def __init__(self, source_names: tuple[str, ...]):
        self.exact = {n: i for i, n in enumerate(source_names)}
        self.by_key: dict[tuple, list[int]] = {}
        for i, n in enumerate(source_names):
            self.by_key.setdefault(shape_key(n), []).append(i)
        for found in self.by_key.values():
            if len(found) > 1:
                found.sort(key=lambda i: not _spelled_as_known(source_names[i]))  # stable: else the first

    def row(self, name: str) -> tuple[dict[int, float], str]:
        """``{source index: gain}`` for ``name`` and how it was matched (``exact``, ``key``, ``mean``, ``both``)."""
        if name in self.exact:
            return {self.exact[name]: 1.0}, "exact"
        key = shape_key(name)
        found = self.by_key.get(key)
        if found:
            return {found[0]: 1.0}, "key"
        base, side = key
        if side is None:
            sided = [self.by_key[(base, s)][0] for s in ("L", "R") if (base, s) in self.by_key]
            if sided:
                return {i: 1.0 / len(sided) for i in sided}, "mean"
        elif (base, None) in self.by_key:
            return {self.by_key[(base, None)][0]: 1.0}, "both"
        return {}, ""


@dataclass
class ShapeMap:
    """Linear map from source weights to rig weights: ``rig_w = matrix @ source_w``.

    Build one with :meth:`between`. ``rig`` and ``source`` are roles: a rig
    driven by a Live Link take is ``between(rig.names, ARKIT_NAMES)``; the
    ARKit columns of a solve on an ICT rig are ``between(ARKIT_NAMES, ICT_NAMES)``.

    Attributes
    ----------
    rig_names : tuple of R str
    source_names : tuple of S str
    matrix : (R, S) float64
        Gains; row ``r`` says which source weights drive rig shape ``r``.
    rig_convention, source_convention : NamingConvention
    from_mapping : tuple of str
        Rig shapes whose rows came from a mapping file.
    unresolved : tuple of (str, int)
        ``(source_shape, line)`` of mapping rows whose source shape is none of
        the sources (those rows drive nothing).
    mapping_name : str
        The mapping file's name, or ``""``.
    ambiguous : tuple of (str, str)
        ``(rig shape, the rig shape driven instead)``: rig shapes left at 0
        because another rig shape matches the same source name (two spellings
        of one shape, see the module notes); a mapping file drives them.
    """

    rig_names: tuple[str, ...]
    source_names: tuple[str, ...]
    matrix: np.ndarray
    rig_convention: NamingConvention
    source_convention: NamingConvention
    from_mapping: tuple[str, ...] = ()
    unresolved: tuple[tuple[str, int], ...] = ()
    mapping_name: str = ""
    _splits: tuple[str, ...] = field(default=(), repr=False)
    _means: tuple[str, ...] = field(default=(), repr=False)
    _ambiguous: tuple[tuple[str, str], ...] = field(default=(), repr=False)

    @property
    def ambiguous(self) -> tuple[str, ...]:
        """Rig shapes left at 0 because another rig shape matches the same source name (see the module notes)."""
        return tuple(a for a, _ in self._ambiguous)

    def ambiguity_note(self) -> str:
        """:attr:`ambiguous` for a note, each with the shape driven instead; ``""`` when there is none."""
        if not self._ambiguous:
            return ""
        shown = ", ".join(f"{a} ({b} driven instead)" for a, b in self._ambiguous)
        n = len(self._ambiguous)
        return (f"{n} shape{'' if n == 1 else 's'} of the rig match{'es' if n == 1 else ''} no source name "
                f"uniquely: {shown} left at 0; give a mapping CSV to drive them")

    # ----------------------------------------------------------------- construction
    @classmethod
    def between(cls, rig_names: Sequence[str], source_names: Sequence[str], mapping_csv=None) -> "ShapeMap":
        """The map that drives ``rig_names`` from ``source_names``.

        One source name matched automatically by several rig shapes that
        overlap (two spellings of one shape, ``AK_25_JawOpen`` and
        ``SR_21_Jaw_Open``; or an unsided shape and the sided ones of its base)
        drives one of them (see the module notes); the others stay at 0 and are
        listed in :attr:`ambiguous`. A rig shape a mapping file drives claims
        its source names the same way.

        Parameters
        ----------
        rig_names, source_names : sequence of str
            Distinct names each (any convention, decorated or not).
        mapping_csv : str, path, NameMapping or None
            A mapping file (``rig_shape,source_shape,gain``) whose rows replace
            the automatic match of the rig shapes they name.

        Raises
        ------
        InputError
            A name repeats; a mapping row names a rig shape that is not in
            ``rig_names`` (file and line named); a gain, or the sum of one rig
            shape's ``|gain|``, beyond :data:`MAX_GAIN`; the mapping file's own
            errors.
        """
        rig = _names(rig_names, "rig_names")
        src = _names(source_names, "source_names")
        mapping = _as_mapping(mapping_csv)
        matcher = _Matcher(src)
        M = np.zeros((len(rig), len(src)))
        splits, means = [], []
        manual: dict[int, list] = {}
        unresolved = []
        if mapping is not None:
            rig_matcher = _Matcher(rig)
            for row in mapping.rows:
                r, how = rig_matcher.row(row.rig)
                if how not in ("exact", "key"):
                    close = _close(row.rig, rig)
                    raise InputError(f"line {row.line}: {_q(row.rig)} is not a shape of the rig{close}",
                                     mapping.path or None)
                manual.setdefault(next(iter(r)), []).append(row)
            _check_gains(mapping, {rig[i]: rows for i, rows in manual.items()})
        auto: dict[int, tuple[dict, str]] = {}
        for i, name in enumerate(rig):
            if i in manual:
                for row in manual[i]:
                    gains, _ = matcher.row(row.source)
                    if not gains:
                        unresolved.append((row.source, row.line))
                    for j, g in gains.items():
                        M[i, j] += row.gain * g
                continue
            gains, how = matcher.row(name)
            if gains:
                auto[i] = (gains, how)
        # one rig shape per source name: what a source column drives, with the part of the face it moves
        claimed: dict[int, list[tuple[frozenset, int]]] = {}
        for i in manual:
            for j in np.flatnonzero(M[i]):
                claimed.setdefault(int(j), []).append((_coverage(rig[i]), i))
        ambiguous = []
        for i in sorted(auto, key=lambda i: (auto[i][1] != "exact", not _spelled_as_known(rig[i]),
                                             auto[i][1] != "key", i)):
            gains, how = auto[i]
            cover = _coverage(rig[i])
            rival = next((k for j in gains for c, k in claimed.get(j, ()) if c & cover), None)
            if rival is not None:
                ambiguous.append((i, rival))
                continue
            for j, g in gains.items():
                M[i, j] = g
                claimed.setdefault(j, []).append((cover, i))
        ambiguous.sort()
        for i, name in enumerate(rig):
            if i in auto and M[i].any():
                if auto[i][1] == "mean":
                    means.append(name)
                elif auto[i][1] == "both":
                    splits.append(name)
        return cls(rig, src, M, naming_convention(rig), naming_convention(src),
                   tuple(rig[i] for i in sorted(manual)), tuple(unresolved),
                   mapping.name if mapping is not None else "", tuple(splits), tuple(means),
                   tuple((rig[i], rig[k]) for i, k in ambiguous))

    # ----------------------------------------------------------------- what is left out
    @property
    def unmapped_rig(self) -> tuple[str, ...]:
        """Rig shapes no source weight drives (their weight stays 0)."""
        return tuple(n for n, row in zip(self.rig_names, self.matrix) if not row.any())

    @property
    def unmapped_source(self) -> tuple[str, ...]:
        """Source shapes that drive no rig shape (their weight is not carried over)."""
        return tuple(n for n, col in zip(self.source_names, self.matrix.T) if not col.any())

    @property
    def is_empty(self) -> bool:
        """No source weight reaches any rig shape."""
        return not self.matrix.any()

    # ----------------------------------------------------------------- use
    def apply(self, weights) -> np.ndarray:
        """Source weights ``(T, S)`` (or ``(S,)``) -> rig weights ``(T, R)`` (or ``(R,)``).

        Raises
        ------
        InputError
            ``weights`` is not ``(T, S)`` / ``(S,)``.
        """
        W = np.asarray(weights, dtype=np.float64)
        S = len(self.source_names)
        if W.shape[-1:] != (S,) or W.ndim not in (1, 2):
            raise InputError(f"source weights must have shape (T, {S}) for the {S} source shapes, got {W.shape}")
        return W @ self.matrix.T

    def inverse(self) -> "ShapeMap":
        """The map back, rig weights -> source weights: the least-squares (pseudo-)inverse.

        Exact for one-to-one rows (a copy) and for an ARKit shape split onto
        both ICT sides (the mean of the two comes back); where several source
        shapes feed one rig shape it gives the smallest source weights that
        reproduce the rig weight. Shapes unmapped one way are unmapped the other.
        """
        P = np.linalg.pinv(self.matrix) if self.matrix.size else self.matrix.T.copy()
        P[np.abs(P) < 1e-12] = 0.0
        return ShapeMap(self.source_names, self.rig_names, P, self.source_convention, self.rig_convention,
                        (), (), self.mapping_name)

    def describe(self) -> str:
        """One paragraph: the two conventions, how many rig shapes are driven, and every unmapped shape by name."""
        R, S = len(self.rig_names), len(self.source_names)
        driven = R - len(self.unmapped_rig)
        parts = [f"rig names: {self.rig_convention}; source names: {self.source_convention}.",
                 f"{driven} of {R} rig shapes driven by {S - len(self.unmapped_source)} of {S} source shapes"]
        if self.from_mapping:
            parts[-1] += f" ({len(self.from_mapping)} by {self.mapping_name})"
        if self._means:
            parts[-1] += f"; {_list(self._means)} from the mean of the source's left and right shapes"
        if self._splits:
            parts[-1] += f"; {_list(self._splits)} from the source's one shape for both sides"
        parts[-1] += "."
        if self._ambiguous:
            parts.append(self.ambiguity_note() + ".")
        unmatched = tuple(n for n in self.unmapped_rig if n not in set(self.ambiguous))
        if unmatched:
            parts.append(f"Rig shapes no source drives (kept at 0): {_list(unmatched)}.")
        if self.unmapped_source:
            parts.append(f"Source shapes that drive nothing: {_list(self.unmapped_source)}.")
        if self.unresolved:
            parts.append(f"Rows of {self.mapping_name} whose source shape is not among the sources: "
                         + ", ".join(f"{_cut(s)} (line {ln})" for s, ln in self.unresolved) + ".")
        return " ".join(parts)


def _list(names) -> str:
    return ", ".join(names) if names else "none"


def _close(name: str, names: Sequence[str]) -> str:
    import difflib

    close = difflib.get_close_matches(name[:1000], list(names), n=3, cutoff=0.6)
    if close:
        return f" (did you mean {', '.join(_q(c) for c in close)}?)"
    shown = ", ".join(_cut(n) for n in list(names)[:6])
    return f" (the rig has {len(names)} shapes: {shown}{', ...' if len(names) > 6 else ''})"
