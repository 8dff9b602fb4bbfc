"""A rig's (or head's) length unit and up axis: given, stated by its file, or found from its geometry.

facegeom works in centimetres with Y up and the face looking along +Z (the
ICT face's frame, glTF's axes); a rig from elsewhere is brought into that
frame when it is loaded (:func:`facegeom.model.inputs.load_rig`), and
:class:`RigFrame` remembers how, so that what is written back in the rig's
own terms (a fitted mesh) can be turned back.

Units rule
----------
Size = the RMS distance of the neutral's vertices from their centroid (as
:func:`facegeom.registration.units_factor` measures scans): 5.9 cm for the ICT
face area (a face 15 cm wide, 20 cm tall), 8.0 cm for the whole ICT head with
its neck (18 cm wide, 29 cm tall). The unit is the one of mm, cm, m that puts
the size nearest to :data:`REFERENCE_SIZE_CM` (7 cm) on a log scale, i.e.
``units_factor(neutral, 7.0, powers=(-1, 0, 2))``. In numbers as stored: an
RMS size from 0.7 to 22 is read as cm (a face mask of 5 cm to a stylised head
3x a real one's size), above 22 as mm (2.2 cm to 70 cm), below 0.7 as m.
Failure cases: a stylised head more than ~3x a real head's size in cm is read
as mm, a doll-sized face (RMS under 0.7 cm) in cm as m; a rig in inches or dm
has no unit here. ``units=`` decides instead; a file that states its unit
(glTF: metres; facegeom's own ``.npz``: cm) is believed.

Up rule
-------
Only Y-up (face along +Z) and Z-up (the convention of Blender and 3ds Max:
face along -Y, converted by ``(x, y, z) -> (x, z, -y)``) are told apart; in
both X is the left-right axis. With blendshapes: each vertex's outward
area-weighted normal, weighted by how far the shapes move it (the sum of its
delta lengths), summed: the moving surface (mouth, eyes, brows, cheeks) faces
the front, so the larger of the Y and Z components of that sum is the front
axis and the other is up (on the ICT rig the Z component is 5.4x the Y one);
the cue counts when it is at least 2x the other component and not smaller than
the X one. Otherwise (no blendshapes, or the cue is weak): the longer of the
Y and Z extents of the bounding box is up (a face or head is taller than
deep: ICT 29 against 16 cm). Outward = the sign that makes the normals point
away from the centroid on average. When the cue is confident and the face
looks backwards (-Z after conversion), the rig is also turned 180 degrees
about the up axis. Failure cases: a rig whose left-right axis is not X
(Unreal's X-forward meshes, a head lying on its side), a head turned by an
angle that is not a multiple of 90 degrees about X, a rig whose shapes move
mostly the back or top of the head (hair, ears), a rig without shapes that is
deeper than tall (a stylised head with a long skull), faces wound
inconsistently. ``up=`` decides instead; glTF files are Y-up by the format.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeom.errors import InputError

__all__ = ["REFERENCE_SIZE_CM", "RigFrame", "TO_CM", "UNITS", "UP_AXES", "find_units", "find_up", "rig_frame"]

#: Length units a rig may be in, and centimetres per unit.
TO_CM: dict[str, float] = {"mm": 0.1, "cm": 1.0, "m": 100.0}
UNITS: tuple[str, ...] = tuple(TO_CM)
#: Up axes told apart.
UP_AXES: tuple[str, ...] = ("y", "z")
#: RMS radius of a face rig's neutral, cm: between the ICT face area's 5.9 and the whole ICT head's 8.0.
REFERENCE_SIZE_CM = 7.0

_POWERS = {-1: "mm", 0: "cm", 2: "m"}
_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)
_TURN = np.diag([-1.0, 1.0, -1.0])  # 180 degrees about Y
_CUE_RATIO = 2.0


@dataclass(frozen=True)
class RigFrame:
    """How a rig's coordinates were brought into facegeom's frame (cm, Y up, face along +Z).

    Attributes
    ----------
    units : str
        The rig's own unit, ``mm``, ``cm`` or ``m``.
    up : str
        Its up axis, ``y`` or ``z``.
    units_how, up_how : str
        Why: ``"given"``, ``"stated by the file"`` or what was found.
    turned : bool
        Also turned 180 degrees about the up axis (the face looked backwards).
    """

    units: str = "cm"
    up: str = "y"
    units_how: str = "given"
    up_how: str = "given"
    turned: bool = False

    @property
    def scale(self) -> float:
        """Centimetres per rig unit."""
        return TO_CM[self.units]

    @property
    def rotation(self) -> np.ndarray:
        """``(3, 3)`` rotation from the rig's axes to facegeom's."""
        R = _Z_UP if self.up == "z" else np.eye(3)
        return _TURN @ R if self.turned else R.copy()

    @property
    def is_identity(self) -> bool:
        """The rig already was in cm, Y up, facing +Z."""
        return self.units == "cm" and self.up == "y" and not self.turned

    def to_facegeom(self, X) -> np.ndarray:
        """Points or offsets ``(..., 3)`` in the rig's frame -> facegeom's (cm, Y up): a new array.

        A rig already Y-up and facing +Z is copied, not multiplied by the identity (a matrix product with an
        inner size of 3 is slow: 0.07-0.15 s for a 76,000-vertex rig's 52 shapes)."""
        R = self.rotation
        if np.array_equal(R, np.eye(3)):
            Y = np.array(X, dtype=np.float64)
        else:
            Y = np.asarray(X, dtype=np.float64) @ R.T
        if self.scale != 1.0:
            Y *= self.scale  # (in place: one array the size of X, not two)
        return Y

    def to_source(self, X) -> np.ndarray:
        """Points or offsets ``(..., 3)`` in facegeom's frame -> the rig's own units and axes."""
        return (np.asarray(X, dtype=np.float64) / self.scale) @ self.rotation

    @property
    def label(self) -> str:
        """``"mm, Z-up"``: the rig's own units and axes, for output notes."""
        return f"{self.units}, {self.up.upper()}-up"

    def describe(self) -> str:
        """``units mm (found: ...), up Z (found: ...) -> converted to cm, Y-up``."""
        text = f"units {self.units} ({self.units_how}), up {self.up.upper()} ({self.up_how})"
        if self.turned:
            text += ", facing backwards: turned 180 degrees"
        return text + (" -> converted to cm, Y-up" if not self.is_identity else "")


def find_units(neutral) -> tuple[str, str]:
    """The unit of a face rig's ``neutral (n, 3)`` by its size (module notes) -> ``(unit, why)``."""
    from facegeom.registration import rms_radius, units_factor

    V = np.asarray(neutral, dtype=np.float64)
    f = units_factor(V, REFERENCE_SIZE_CM, powers=tuple(_POWERS))
    unit = _POWERS[int(round(np.log10(f)))]
    size = rms_radius(V)
    cm = "" if unit == "cm" else f" = {size * TO_CM[unit]:.3g} cm"
    return unit, f"found: RMS radius {size:.3g} {unit}{cm}, a face's size"


def _facing(V: np.ndarray, F: np.ndarray, deltas) -> np.ndarray | None:
    """The moving surface's outward normal sum ``(3,)`` (module notes), or None without shapes or faces."""
    if deltas is None or F is None or len(F) == 0:
        return None
    D = np.asarray(deltas, dtype=np.float64)
    if D.ndim != 3 or D.shape[0] == 0:
        return None
    motion = np.zeros(D.shape[1])  # (n,): each vertex's displacement summed over the shapes, one shape at a time
    for d in D:  # (the same sums, in the same order, as np.sqrt((D ** 2).sum(axis=2)).sum(axis=0), without the
        motion += np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2)  # (B, n, 3) temporaries)
    if not motion.any():
        return None
    F = np.asarray(F, dtype=np.int64)
    P = V[F]
    cross = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])  # 2 x area x unit normal
    outward = float(np.einsum("fi,fi->", cross, P.mean(axis=1) - V.mean(axis=0)))
    sign = -1.0 if outward < 0 else 1.0
    return sign * (motion[F].mean(axis=1)[:, None] * cross).sum(axis=0)


def find_up(neutral, triangles=None, deltas=None) -> tuple[str, str, float | None]:
    """The up axis of a rig (module notes) -> ``(up, why, facing)``.

    ``facing``: the sign of the moving surface's normal sum along the front
    axis (+1: towards +Z for Y-up, towards -Y for Z-up, i.e. facegeom's +Z
    after conversion), or None when the blendshape cue is not confident.
    """
    V = np.asarray(neutral, dtype=np.float64)
    s = _facing(V, triangles, deltas)
    if s is not None:
        a = np.abs(s)
        y, z = a[1], a[2]
        if max(y, z) >= _CUE_RATIO * min(y, z) and max(y, z) >= a[0]:
            if z > y:
                return "y", f"found: the moving surface faces {'+' if s[2] > 0 else '-'}Z", float(np.sign(s[2]))
            return "z", f"found: the moving surface faces {'+' if s[1] > 0 else '-'}Y", float(-np.sign(s[1]))
    ext = V.max(axis=0) - V.min(axis=0)
    up = "y" if ext[1] >= ext[2] else "z"
    why = "found: taller along Y than along Z" if up == "y" else "found: taller along Z than along Y"
    return up, why + (" (no blendshapes to tell the front)" if s is None else " (the blendshapes did not tell)"), None


def rig_frame(neutral, triangles=None, deltas=None, units="auto", up="auto", stated_units=None,
              stated_up=None) -> RigFrame:
    """How to bring a rig into facegeom's frame: ``units`` / ``up`` when given, else the file's, else found.

    Parameters
    ----------
    neutral : (n, 3) array
    triangles : (m, 3) int array, optional
    deltas : (B, n, 3) array, optional
        The blendshapes (the up axis is told from where they move the face).
    units : {"auto", "mm", "cm", "m"}
    up : {"auto", "y", "z"}
    stated_units, stated_up : str, optional
        What the file states (glTF: ``"m"``, ``"y"``), used under ``"auto"``.

    Raises
    ------
    InputError
        An unknown ``units`` or ``up``; a neutral without extent.
    """
    units = str(units).lower()
    up = str(up).lower()
    if units not in ("auto", *UNITS):
        raise InputError(f"units must be auto, mm, cm or m, got {units!r}")
    if up not in ("auto", *UP_AXES):
        raise InputError(f"the up axis must be auto, y or z, got {up!r}")
    V = np.asarray(neutral, dtype=np.float64)
    if units != "auto":
        u, u_how = units, "given"
    elif stated_units in TO_CM:
        u, u_how = stated_units, "stated by the file"
    else:
        try:
            u, u_how = find_units(V)
        except InputError:
            raise InputError("the neutral has no extent (all its vertices coincide): its units cannot be told; "
                             "pass units=mm|cm|m") from None
    found_up, why, facing = find_up(V, triangles, deltas)
    if up != "auto":
        a, a_how = up, "given"
        facing = facing if a == found_up else None
    elif stated_up in UP_AXES:
        a, a_how = stated_up, "stated by the file"
        facing = facing if a == found_up else None
    else:
        a, a_how = found_up, why
    return RigFrame(u, a, u_how, a_how, turned=facing is not None and facing < 0)
