"""A character's separate pieces -- eyes, teeth, tongue, lashes -- and how each moves with the transferred face.

A head rarely comes as one surface: the skin, two eyeballs, upper and lower
teeth, a tongue, lash and brow cards. Expression transfer
(:mod:`facegeom.methods.transfer`) carries the ICT face's motion onto the
skin; the other pieces must not be smeared by it (an eyeball copying the
eyelid's motion, teeth stretching with the lips). Each piece gets one role:

``skin``
    The surface registered and transferred onto: the piece of largest area
    (or the one given).
``eye``
    Turns rigidly about its fitted centre for the eye-look shapes
    (``eyeLookUp/Down/In/Out_L/_R``, its own side only) by
    :data:`EYE_YAW_DEGREES` (in, out) or :data:`EYE_PITCH_DEGREES` (up,
    down) at weight 1; still for every other shape.
``jaw``
    Follows the jaw: per shape, the rigid motion that best carries the
    template's chin patch (:func:`_chin_patch`) -- ``jawOpen`` turns the
    lower teeth and tongue down, ``mouthSmile`` leaves them.
``stay``
    Still in every shape (the upper teeth, fixed to the skull; a hat).
``follow``
    Each vertex copies the transferred motion of its closest skin vertex
    (lashes and brow cards riding on the lids and brows).

Found from the registration (the template's landmarks posed on the head, in
the model's frame): an ``eye`` is a piece that a sphere fits (rms below
:data:`EYE_SPHERE_RMS` of its radius), of an eyeball's radius
(:data:`EYE_RADIUS_CM`), centred within :data:`EYE_CENTRE_CM` of the
template's eye (the eye landmarks' centroid set back by the radius); a piece
whose centroid lies in the mouth (:data:`MOUTH_BOX_CM` about the inner lips'
midpoint) is ``jaw`` below the lips' meeting line and ``stay`` above; any other
piece lying on the skin (median distance within :data:`FOLLOW_MM`) is
``follow``; the rest ``stay``. Before any of this (:func:`second_head`), a
piece away from the skin with at least :data:`SECOND_HEAD` of its area is
taken for a second head and refused unless its role is given. Each can be given instead (``roles``: piece
name -> role).

:data:`EYE_YAW_DEGREES` = 34, :data:`EYE_PITCH_DEGREES` = 29: ARKit's own
convention. Live Link Face writes each eye's yaw and pitch beside the weights,
and on the four real takes at hand they are exact linear functions of them
(correlation -1.00): yaw = -0.60 (eyeLookOut - eyeLookIn) and pitch = -0.48 to
-0.56 (eyeLookUp - eyeLookDown), radians -- weight 1 is the eye turned by 34
and 29 degrees (checked in ``tests/test_pieces.py`` on the take at hand). An
artist may choose less: the MakeHuman face units (CC0, the test rig) turn
their eyes by 10-15 degrees.
"""
from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from facegeom.constants import FACE_AREA
from facegeom.errors import InputError
from facegeom.io.takes import EYE_PITCH_PER_WEIGHT, EYE_YAW_PER_WEIGHT
from facegeom.registration import kabsch

__all__ = ["ROLES", "Piece", "PieceMotion", "split_pieces", "second_head", "classify_pieces", "piece_deltas",
           "EYE_YAW_DEGREES", "EYE_PITCH_DEGREES"]

ROLES = ("skin", "eye", "jaw", "stay", "follow")
EYE_YAW_DEGREES = float(np.degrees(EYE_YAW_PER_WEIGHT))  # eyeLookIn / Out at weight 1 turn the eye this much (34.4)
EYE_PITCH_DEGREES = float(np.degrees(EYE_PITCH_PER_WEIGHT))  # eyeLookUp / Down at weight 1 (28.6)
EYE_RADIUS_CM = (0.8, 1.8)  # an eyeball's radius (people: about 1.2 cm), model cm
EYE_SPHERE_RMS = 0.1  # a sphere fits an eye within this fraction of its radius (rms)
EYE_CENTRE_CM = 2.0  # an eye's centre lies within this of the template's eye centre, model cm
MOUTH_BOX_CM = (3.5, 3.0, 2.0, 6.0, 1.0)  # |x| <= a, y in [-b, +c] about the lips' line, z in [-d, +e] about the lips
FOLLOW_MM = 10.0  # a piece whose median distance to the skin is within this follows the skin
SECOND_HEAD = 0.5  # a piece away from the skin with at least this fraction of its area: a second head, refused
CHIN_CM = 3.0  # the chin patch: template vertices within this of the chin landmarks, below the lower lip
STILL_QUARTER = 0.25  # the skull's patch: the quarter of the face the expressions move least (forehead, nose, temples)
PATCH_MM = 5.0  # a template vertex of a patch counts where the skin lies within this of it
EYE_LOOKS = {"eyeLookUp": (0.0, 1.0, 0.0), "eyeLookDown": (0.0, -1.0, 0.0),
             "eyeLookOut": (1.0, 0.0, 0.0), "eyeLookIn": (-1.0, 0.0, 0.0)}  # the left eye's look directions


@dataclass
class Piece:
    """One separate piece of a head mesh.

    Attributes
    ----------
    name : str
        The rig part's name, else ``piece N`` (N from 1, largest area first).
    vertices : (k,) int64
        Its vertex ids in the head.
    faces : (f,) int64
        Its triangle ids in the head.
    area : float
        Its surface area (head units squared).
    role : str
        One of :data:`ROLES` (``""`` until classified).
    how : str
        Why: ``given`` or what was found.
    centre : (3,) float64 or None
        An eye's fitted centre (head units).
    side : str or None
        An eye's side, ``"L"`` or ``"R"`` (the performer's left: the model's +x).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    area: float
    role: str = ""
    how: str = ""
    centre: np.ndarray | None = None
    side: str | None = None


def split_pieces(V, F, parts=None) -> list[Piece]:
    """The head's pieces: its rig parts when given (name, vertex and face slices), else its connected components.

    Vertices no triangle uses belong to no piece (they keep a zero motion).
    Sorted by area, largest first; the first is the skin.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    area = 0.5 * igl.doublearea(V, F)
    out = []
    if parts:
        for p in parts:
            fid = np.arange(p.face_start, p.face_stop, dtype=np.int64)
            if fid.size == 0:
                continue
            out.append(Piece(str(p.name), np.unique(F[fid]), fid, float(area[fid].sum())))
    else:
        labels = np.asarray(igl.vertex_components(F, V.shape[0]) if _vc_takes_n() else igl.vertex_components(F))
        flab = labels[F[:, 0]]
        order = np.argsort(flab, kind="stable")
        bounds = np.flatnonzero(np.diff(flab[order])) + 1
        for fid in np.split(order, bounds):
            if fid.size:
                out.append(Piece("", np.unique(F[fid]), fid, float(area[fid].sum())))
    out.sort(key=lambda p: -p.area)
    if not parts:
        for i, p in enumerate(out):
            p.name = f"piece {i + 1}"
    return out


def _vc_takes_n() -> bool:
    import inspect

    try:
        return len(inspect.signature(igl.vertex_components).parameters) > 1
    except (TypeError, ValueError):  # pragma: no cover - a compiled signature not introspectable
        return False


def second_head(V, pieces: list[Piece], roles=None) -> Piece | None:
    """The first piece (not the skin, no role given) with at least :data:`SECOND_HEAD` of the skin's area whose
    vertices lie, by their median, farther from the skin than a tenth of the skin's size; else None.

    Judged before any registration (sizes relative to the skin, no units needed).
    """
    V = np.asarray(V, dtype=np.float64)
    skin = pieces[0]
    S = V[skin.vertices]
    size = float(np.linalg.norm(S.max(axis=0) - S.min(axis=0)))
    tree = None
    for p in pieces[1:]:
        if p.area < SECOND_HEAD * skin.area or p.name in (roles or {}):
            continue
        tree = tree or cKDTree(S)
        d, _ = tree.query(V[p.vertices])
        if float(np.median(d)) > 0.1 * size:
            return p
    return None


def _fit_sphere(X):
    """Least-squares sphere through points ``X (k, 3)`` -> ``(centre, radius, rms / radius)``."""
    A = np.c_[2.0 * X, np.ones(len(X))]
    b = (X * X).sum(axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:3]
    r2 = sol[3] + c @ c
    if not r2 > 0:
        return c, 0.0, np.inf
    r = float(np.sqrt(r2))
    return c, r, float(np.sqrt(np.mean((np.linalg.norm(X - c, axis=1) - r) ** 2)) / r)


def classify_pieces(model, reg, V, pieces: list[Piece], roles: dict | None = None) -> list[Piece]:
    """Give every piece its role (see the module docstring); ``roles`` (name -> role) overrides what is found.

    ``reg``: the :class:`~facegeom.methods.transfer.HeadRegistration` of the
    skin; ``V (n, 3)``: the whole head's vertices (the pieces' ids index it).
    Raises :class:`InputError` for a role not in :data:`ROLES`, a name that
    is not a piece, or a skin given to another piece than the first.
    """
    roles = dict(roles or {})
    names = [p.name for p in pieces]
    for name, role in roles.items():
        if role not in ROLES:
            raise InputError(f"piece {name!r}: unknown role {role!r}; use one of {', '.join(ROLES)}")
        if name not in names:
            raise InputError(f"no piece called {name!r}; the pieces are {', '.join(names)}")
        if role == "skin" and name != names[0]:
            raise InputError(f"piece {name!r}: only one piece is the skin ({names[0]!r})")
    V = np.asarray(V, dtype=np.float64)
    lm = np.asarray(model.landmarks)
    to_model = lambda X: ((np.asarray(X) - reg.t) @ reg.R) / reg.scale  # noqa: E731 - head -> model cm
    Tm = to_model(reg.template)  # the fitted template in the model's frame (the person's own face, model cm)
    lips = Tm[lm[[62, 66]]].mean(axis=0)
    skin = pieces[0]
    skin_tree = cKDTree(V[skin.vertices])
    for i, p in enumerate(pieces):
        p.centre, p.side = None, None
        if i == 0:
            p.role, p.how = "skin", "the largest piece: registered and transferred onto"
            continue
        X = to_model(V[p.vertices])
        c, r, rms = _fit_sphere(X) if len(X) >= 8 else (X.mean(axis=0), 0.0, np.inf)
        found, how = None, ""
        if rms <= EYE_SPHERE_RMS and EYE_RADIUS_CM[0] <= r <= EYE_RADIUS_CM[1]:
            for side, ids in (("L", lm[42:48]), ("R", lm[36:42])):
                eye = Tm[ids].mean(axis=0) - np.array([0.0, 0.0, r])
                if np.linalg.norm(c - eye) <= EYE_CENTRE_CM:
                    found, how = "eye", f"a sphere of radius {r:.2f} cm at the {'left' if side == 'L' else 'right'} eye"
                    p.centre, p.side = reg.scale * (reg.R @ c) + reg.t, side
        if found is None:
            m = X.mean(axis=0) - lips
            a, below, above, back, front = MOUTH_BOX_CM
            if abs(m[0]) <= a and -below <= m[1] <= above and -back <= m[2] <= front:
                found, how = ("jaw", "in the mouth, below the lips' line") if m[1] < 0 else \
                    ("stay", "in the mouth, above the lips' line")
        if found is None:
            d, _ = skin_tree.query(V[p.vertices])
            dmm = float(np.median(d)) * reg.mm_per_unit
            found, how = ("follow", f"on the skin ({dmm:.1f} mm)") if dmm <= FOLLOW_MM else \
                ("stay", f"away from the skin ({dmm:.0f} mm)")
        p.role, p.how = found, how
        if p.name in roles:
            p.role, p.how = roles[p.name], "given"
            if p.role == "eye" and p.side is None:  # an eye given: its centre fitted, its side from the model's x
                cw = reg.scale * (reg.R @ c) + reg.t if np.isfinite(rms) else V[p.vertices].mean(0)
                p.centre, p.side = cw, ("L" if c[0] >= 0 else "R")
    return pieces


def _chin_patch(model) -> np.ndarray:
    """Template vertices of the chin: face area, within ``CHIN_CM`` of landmarks 7-9, below the lower lip (57)."""
    G = np.asarray(model.neutral, dtype=np.float64)
    lm = np.asarray(model.landmarks)
    ids = np.arange(min(FACE_AREA, G.shape[0]))
    d, _ = cKDTree(G[lm[7:10]]).query(G[ids])
    return ids[(d <= CHIN_CM) & (G[ids, 1] < G[lm[57], 1] - 0.5)]


def piece_deltas(model, reg, V, pieces: list[Piece], skin_deltas, names) -> np.ndarray:
    """Every piece's motion per shape -> ``(K, n, 3)`` over the whole head (the skin's from ``skin_deltas``).

    ``V (n, 3)``: the whole head; ``skin_deltas (K, s, 3)``: the transferred motion of the skin's vertices
    (``pieces[0].vertices`` order); ``names``: the K shapes' ICT names.
    """
    V = np.asarray(V, dtype=np.float64)
    K = len(names)
    out = np.zeros((K,) + V.shape)
    skin = pieces[0]
    out[:, skin.vertices] = skin_deltas
    jaw = None
    Dh = None
    for p in pieces[1:]:
        X = V[p.vertices]
        if p.role in ("follow", "skin"):
            _, j = cKDTree(V[skin.vertices]).query(X)
            out[:, p.vertices] = skin_deltas[:, j]
        elif p.role == "jaw":
            if jaw is None:
                chin = _chin_patch(model)
                if Dh is None:
                    Dh = reg.delta_in_head(np.asarray(model.expression_deltas, dtype=np.float64)[:, chin])
                P = reg.template[chin]
                jaw = [kabsch(P, P + Dh[k]) for k in range(K)]
            for k, (R, t) in enumerate(jaw):
                out[k, p.vertices] = X @ R.T + t - X
        elif p.role == "eye":
            for k, name in enumerate(names):
                look = _eye_look(name, p.side)
                if look is None:
                    continue
                R = reg.R @ look @ reg.R.T  # the model frame's turn, in the head's frame
                out[k, p.vertices] = (X - p.centre) @ R.T + p.centre - X
    return out


def _eye_look(name: str, side: str | None):
    """The turn (model frame) of the eye on ``side`` for the shape ``name`` at weight 1, or None."""
    for base, direction in EYE_LOOKS.items():
        for s in ("L", "R"):
            if name == f"{base}_{s}" and s == side:
                d = np.array(direction)
                if s == "R" and base in ("eyeLookOut", "eyeLookIn"):
                    d = -d  # the right eye looks out towards -x
                axis = np.cross([0.0, 0.0, 1.0], d)
                deg = EYE_PITCH_DEGREES if base in ("eyeLookUp", "eyeLookDown") else EYE_YAW_DEGREES
                return Rotation.from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()
    return None


@dataclass
class PieceMotion:
    """How the pieces other than the skin follow a skin driven frame by frame (the marker route's
    counterpart of :func:`piece_deltas`, which moves them per shape).

    A deformer drives the skin alone (the markers lie on it; eyes, teeth and tongue carry none); every frame,
    ``follow`` vertices copy the motion of their closest skin vertex, ``jaw`` pieces the rigid motion that best
    carries the skin's chin patch (:func:`_chin_patch`, found on the skin through the registration), ``stay`` and
    ``eye`` pieces -- and vertices no piece holds -- the skull's: the rigid motion of the skin's still patch
    (the :data:`STILL_QUARTER` of the face the expressions move least). Markers say nothing of the gaze: the eyes
    keep the skull's motion. Built by :meth:`build`.

    Attributes
    ----------
    n : int
        The whole head's vertices.
    skin : (s,) int64
        The skin's vertex ids (the driven frames' order).
    skin_faces : (f, 3) int64
        The skin's triangles, in skin-local ids.
    rest : (s, 3) float64
        The skin at rest.
    follow, follow_from : (k,) int64
        Head ids that follow, and the skin-local id each copies.
    follow_offset : (k, 3) float64
        Rest position minus the copied skin vertex's rest position.
    groups : list of (name, ids (g,) int64, patch (c,) int64)
        Rigid groups (``skull``, ``jaw``): head ids moved, and the skin-local patch whose motion they take.
    """

    n: int
    skin: np.ndarray
    skin_faces: np.ndarray
    rest: np.ndarray
    follow: np.ndarray
    follow_from: np.ndarray
    follow_offset: np.ndarray
    groups: list
    _basis: tuple | None = None

    @classmethod
    def build(cls, model, reg, V, F, pieces: list[Piece]) -> "PieceMotion | None":
        """The motion of a registered head's pieces (the skin first, each with its role, as
        :func:`~facegeom.methods.transfer.register_character` gives them); None when the skin is the whole head.

        Vertices of the head that no piece holds (a head stored with its skin only) are split into their
        connected pieces and given roles here (:func:`classify_pieces`); those on a triangle shared with the skin
        follow it; loose vertices keep the skull's motion.
        """
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        n = V.shape[0]
        skin = np.asarray(pieces[0].vertices, dtype=np.int64)
        if skin.size == n:
            return None
        local = np.full(n, -1, dtype=np.int64)
        local[skin] = np.arange(skin.size)
        inside = (local[F] >= 0).all(axis=1)
        skin_faces = local[F[inside]]
        others = list(pieces[1:])
        held = np.zeros(n, dtype=bool)
        for p in pieces:
            held[p.vertices] = True
        follow_extra = np.zeros(0, dtype=np.int64)
        if not held.all():  # a head stored with its skin only: find and classify the rest here
            touching = (local[F] >= 0).any(axis=1)
            loose_faces = F[~touching]
            follow_extra = np.setdiff1d(np.unique(F[touching & ~inside]), skin)
            if loose_faces.size:
                found = [p for p in split_pieces(V, loose_faces) if not np.isin(p.vertices, follow_extra).any()]
                for i, p in enumerate(found):
                    p.name = f"part {i + 1}"
                if found:
                    classify_pieces(model, reg, V, [pieces[0]] + found)
                    others += found
        tree = cKDTree(V[skin])
        follow = np.unique(np.concatenate([follow_extra] + [p.vertices for p in others
                                                            if p.role in ("follow", "skin")]).astype(np.int64))
        follow = np.setdiff1d(follow, skin)
        _, src = tree.query(V[follow]) if follow.size else (None, np.zeros(0, dtype=np.int64))
        src = np.asarray(src, dtype=np.int64)
        jaw = np.unique(np.concatenate([np.zeros(0, dtype=np.int64)] + [p.vertices for p in others
                                                                        if p.role == "jaw"])).astype(np.int64)
        moved = np.zeros(n, dtype=bool)
        moved[skin], moved[follow], moved[jaw] = True, True, True
        skull = np.flatnonzero(~moved)
        groups = []
        for name, ids, patch in (("skull", skull, _still_patch(model)), ("jaw", jaw, _chin_patch(model))):
            if ids.size:
                groups.append((name, ids, _on_skin(reg, tree, patch)))
        return cls(n, skin, skin_faces, V[skin].copy(), follow, src, V[follow] - V[skin][src], groups)

    def local(self, ids) -> np.ndarray:
        """Head vertex ids on the skin -> skin-local ids (InputError for one off the skin)."""
        where = {int(v): i for i, v in enumerate(self.skin)}
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        off = [int(v) for v in ids if int(v) not in where]
        if off:
            raise InputError(f"vertex {off[0]} is not on the skin: markers lie on the skin")
        return np.array([where[int(v)] for v in ids], dtype=np.int64)

    def _motion(self, patch, S_patch):
        """The rigid motion of the skin-local ``patch`` from rest to each frame ``S_patch (m, c, 3)``: robust
        (Cauchy reweighting), so that the part of a patch an expression moves (the outer brows raised, at the
        skull's patch's edge) does not drag it: the upper teeth move 0.18 mm at most under any single ICT
        expression at weight 1, 0.51 with the plain fit."""
        from facegeom.methods.tangent import robust_kabsch_many

        return robust_kabsch_many(self.rest[patch], S_patch)

    def frames(self, S, rest_head) -> np.ndarray:
        """The whole head's frames ``(m, n, 3)`` from the driven skin ``S (m, s, 3)``; ``rest_head (n, 3)``."""
        S = np.asarray(S, dtype=np.float64)
        out = np.empty((S.shape[0], self.n, 3))
        out[:, self.skin] = S
        out[:, self.follow] = S[:, self.follow_from] + self.follow_offset[None]
        for _, ids, patch in self.groups:
            R, t = self._motion(patch, S[:, patch])
            out[:, ids] = np.matmul(rest_head[ids][None], np.swapaxes(R, 1, 2)) + t[:, None, :]
        return out

    def linear(self, C, basis, rest_head):
        """The skin's frames as coefficients ``C (m, 3, q)`` on ``basis (q, s)`` -> the whole head's, on a basis
        of ``q + 3 + 4 g`` rows (``g`` rigid groups): the skin's rows with the followers' columns copied, three
        rows of the followers' offsets, and per group its rest coordinates and a row of ones (coefficients: the
        group's rotation and translation). Exactly :meth:`frames` of ``(C @ basis)``."""
        C = np.asarray(C, dtype=np.float64)
        m, q = C.shape[0], basis.shape[0]
        if self._basis is None or self._basis[0] is not basis:
            rows = q + 3 + 4 * len(self.groups)
            B = np.zeros((rows, self.n))
            B[:q, self.skin] = basis
            B[:q, self.follow] = basis[:, self.follow_from]
            B[q:q + 3, self.follow] = self.follow_offset.T
            for g, (_, ids, _) in enumerate(self.groups):
                r = q + 3 + 4 * g
                B[r:r + 3, ids] = rest_head[ids].T
                B[r + 3, ids] = 1.0
            self._basis = (basis, B)
        B = self._basis[1]
        out = np.zeros((m, 3, B.shape[0]))
        out[:, :, :q] = C
        out[:, :, q:q + 3] = np.eye(3)[None]
        for g, (_, _, patch) in enumerate(self.groups):
            S = np.swapaxes(np.matmul(C, basis[:, patch]), 1, 2)  # the patch's vertices only, (m, c, 3)
            R, t = self._motion(patch, S)
            r = q + 3 + 4 * g
            out[:, :, r:r + 3] = R
            out[:, :, r + 3] = t
        return out, B


def _still_patch(model) -> np.ndarray:
    """Template vertices of the skull's patch: the :data:`STILL_QUARTER` of the face area the expressions move least."""
    D = np.asarray(model.expression_deltas, dtype=np.float64)[:, :FACE_AREA]
    reach = np.sqrt((D * D).sum(axis=2)).max(axis=0)
    return np.flatnonzero(reach <= np.quantile(reach, STILL_QUARTER))


def _on_skin(reg, tree, patch) -> np.ndarray:
    """Skin-local ids nearest the posed template vertices ``patch`` that lie within :data:`PATCH_MM` of the skin
    (all of them when fewer than 3 do)."""
    d, j = tree.query(reg.template[patch])
    near = d * reg.mm_per_unit <= PATCH_MM
    return np.unique(j[near] if near.sum() >= 3 else j).astype(np.int64)
