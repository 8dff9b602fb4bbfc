"""Synthetic face videos with known truth: the clips a video tracker is measured on.

A clip is an ICT face of a random identity performing a window of a real
ARKit take (Live Link Face CSV), its head moving smoothly, its eyes looking
around, filmed by a pinhole camera and written as an H.264 video beside a
``.truth.npz`` file holding everything that made each frame: the expression
weights rendered, the head pose, the gaze, the camera.

The face is drawn by :class:`facegeom.pipelines.render.FaceRenderer` (polyscope,
off-screen). The ICT mesh has holes where the eyes and the mouth are, so
simple props are drawn with it (:class:`FaceProps`):

Eyes
    Per eye a ball of radius :data:`EYE_RADIUS` (1.2 cm) in three parts that
    tile the sphere without overlapping (so nothing fights for depth): the
    pupil, a black cap of radius :data:`PUPIL_RADIUS` (0.25 cm) around the
    gaze axis; the iris, a coloured ring out to :data:`IRIS_RADIUS` (0.6 cm);
    the off-white sclera, the rest. The ball's centre is fixed in the face's
    frame for an identity: the centroid of the lid landmarks (36-41 for the
    subject's right eye, 42-47 for the left) pushed back along -z just far
    enough that no skin vertex near the eye comes within :data:`EYE_CLEARANCE`
    (0.03 cm) of the ball, in the neutral face or with the lids fully closed,
    wide, squinting or following the eye-look shapes (:func:`eye_centres`; on
    the generic ICT face the push-back is 1.17 cm, for random identities of
    scale 1 1.07-1.45 cm). A band of darker skin (:data:`SLEEVE_SHADE`) joins
    the lid margins to the ball, so that no oblique view through the lids
    passes beside the ball into the empty head.
Gaze
    Per eye a yaw and a pitch in radians, in the face's frame, turning the
    iris and pupil about the ball's centre: the eye looks along
    ``(cos(pitch) sin(yaw), sin(pitch), cos(pitch) cos(yaw))``. Yaw positive
    looks to the subject's left (the face frame's +x, the image's right in a
    frontal view); pitch positive looks up. (ARKit's Live Link eye angles have
    both signs the other way round.) Eye 0 is the subject's right eye.
Mouth
    A dark red-brown pouch (:data:`MOUTH_COLOUR`) hung on the inner edge of the
    lips (the boundary loop of the mesh's mouth hole), so it follows the lips
    exactly: four rings that go back into the head and close at 2.6 cm behind
    the lips, narrowing towards the back. An open mouth shows it, never the
    background; it stays inside the head for jawOpen 1.0 and the other mouth
    shapes (checked by rendering with and without it).

The take's eye-look weights are replaced by those of the gaze drawn for the
clip (:data:`facegeom.io.takes.EYE_YAW_PER_WEIGHT`, ...), so that lids, iris
and the truth agree; or, with ``gaze_from_take``, the gaze is read from the
take's eye-look weights (:func:`facegeom.io.takes.eye_rotations`).

Head and camera
---------------
The face's pose, world (face frame, cm) to camera, is
``x_cam = R (x - p) + (p - c) + (0, 0, -distance) + drift``: ``R`` turns the
head by yaw (about y), pitch (about x) and roll (about z), intrinsic Y-X-Z as
:func:`facegeom.io.takes.head_angles` reads it, about the pivot ``p``
(:data:`HEAD_PIVOT`, the top of the neck), and ``c`` is the centre of the
identity's 68 landmarks, which sits on the optical axis at ``distance`` when
the head is at rest. Yaw positive turns the face to the subject's left (the
image's right), pitch positive tilts it down (the face's +z towards -y), roll
positive turns it counter-clockwise in the image;
:func:`facegeom.io.takes.head_angles` reads the three angles back from the
truth's rotations. Every angle and the drift are sums of three sinusoids of
0.05-0.5 Hz, scaled so that each clip peaks at 40-100 % of its family's limit
(:class:`ClipSpec`). The camera's vertical
field of view gives the focal length, ``focal = (height / 2) / tan(fov / 2)``;
the distance makes the face's width (landmark 0 to 16) a chosen fraction of
the frame's width, and grows (or the drift shrinks) until all 68 landmarks,
also with the jaw open, stay inside the frame through the whole clip.

Pixels
------
Skin, iris and props go through polyscope's shading (its ``clay`` material,
lit from the camera). The background, one colour or a smooth random
texture, is put behind the face by a key colour; then the whole frame gets
the clip's light change (gain, contrast, gamma, a per-channel tint) and
Gaussian sensor noise (:func:`grade`), and is encoded as H.264 (libx264,
crf 20, yuv420p) by :class:`facegeom.io.video.VideoWriter`.

Families
--------
:data:`FAMILIES` holds two sets of ranges that differ by construction, so
defaults tuned on ``"tune"`` clips can be checked on ``"holdout"`` clips: other
seeds, the other half of each take, larger head turns, smaller faces,
darker skin, the field of view outside the tune range, textured backgrounds,
stronger light changes and sensor noise.

Truth file
----------
``<name>.truth.npz``: ``weights (T, 53)`` (the ICT expression rendered),
``expression_names``, ``identity (I,)``, ``rotations (T, 3, 3)`` and
``translations (T, 3)`` (the face's pose, world -> camera, cm), ``focal``,
``width``, ``height``, ``fps``, ``gaze (T, 2, 2)`` (per eye yaw and pitch,
radians, eye 0 the subject's right), ``eye_centres (2, 3)`` (face frame, cm),
``eye_radius``, ``take`` (file name), ``window`` (first frame, frame after
the last), ``spec`` (the :class:`ClipSpec` as JSON). :func:`landmark_truth`
and :func:`pupil_truth` project the 68 landmarks and the pupils from it.
"""
from __future__ import annotations

import colorsys
import dataclasses
import functools
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = [
    "EYE_CLEARANCE",
    "EYE_RADIUS",
    "FAMILIES",
    "HEAD_PIVOT",
    "HOLES",
    "IRIS_COLOURS",
    "IRIS_RADIUS",
    "MOUTH_COLOUR",
    "PUPIL_COLOUR",
    "PUPIL_RADIUS",
    "SCLERA_COLOUR",
    "SLEEVE_SHADE",
    "ClipScene",
    "ClipSpec",
    "FaceProps",
    "FamilyRanges",
    "background_image",
    "build_clips",
    "clip_weights",
    "eye_centres",
    "gaze_curves",
    "gaze_rotation",
    "grade",
    "head_pose",
    "hole_loop",
    "landmark_truth",
    "load_truth",
    "make_specs",
    "pupil_truth",
    "render_clip",
    "sphere_zone",
]

#: The eyeball's radius, cm (an adult eye is about 24 mm across).
EYE_RADIUS = 1.2
#: The iris's radius on the ball, cm (measured across the sphere, not along it).
IRIS_RADIUS = 0.6
#: The pupil's radius on the ball, cm.
PUPIL_RADIUS = 0.25
#: The least distance, cm, from the eyeball to any skin vertex near the eye (over the expressions checked).
EYE_CLEARANCE = 0.03
#: Least push-back of the eyeball's centre behind the lid landmarks' centroid, cm.
EYE_MIN_DEPTH = 1.0
#: The point the head turns about (top of the neck), in the ICT face's frame, cm.
HEAD_PIVOT = (0.0, -6.0, 2.0)

SCLERA_COLOUR = (0.93, 0.91, 0.86)
PUPIL_COLOUR = (0.02, 0.02, 0.02)
#: The mouth's inside, a dark red-brown (linear RGB in [0, 1]).
MOUTH_COLOUR = (0.10, 0.03, 0.025)
#: Iris colours a clip picks from (linear RGB in [0, 1]).
IRIS_COLOURS: dict[str, tuple[float, float, float]] = {
    "brown": (0.36, 0.20, 0.09), "dark brown": (0.17, 0.09, 0.05), "hazel": (0.47, 0.35, 0.16),
    "green": (0.30, 0.46, 0.26), "blue": (0.28, 0.46, 0.68), "grey": (0.46, 0.51, 0.54)}

# the mouth pouch: per ring (scale towards the loop's centre in x and y, depth behind the lips' edge, cm), then the
# back point
_POUCH_RINGS = ((1.0, 0.25), (0.95, 1.0), (0.8, 1.8), (0.5, 2.4))
_POUCH_BACK = 2.6
# the band inside the lids: rings at (fraction of the eye's radius from its centre, extra push back, cm)
_SLEEVE_RINGS = ((0.97, 0.0), (0.6, 0.3))
#: The band inside the lids is the skin's colour times this.
SLEEVE_SHADE = 0.6

# expressions the eyeball must stay behind the skin for (weights of one frame, by name)
_EYE_CHECKS = (
    {}, {"eyeBlink_L": 1.0, "eyeBlink_R": 1.0}, {"eyeWide_L": 1.0, "eyeWide_R": 1.0},
    {"eyeSquint_L": 1.0, "eyeSquint_R": 1.0, "cheekSquint_L": 1.0, "cheekSquint_R": 1.0},
    {"eyeLookDown_L": 1.0, "eyeLookDown_R": 1.0}, {"eyeLookUp_L": 1.0, "eyeLookUp_R": 1.0},
    {"eyeLookIn_L": 1.0, "eyeLookOut_R": 1.0}, {"eyeLookOut_L": 1.0, "eyeLookIn_R": 1.0},
    {"browDown_L": 1.0, "browDown_R": 1.0, "eyeBlink_L": 1.0, "eyeBlink_R": 1.0},
    {"mouthSmile_L": 1.0, "mouthSmile_R": 1.0, "cheekSquint_L": 1.0, "cheekSquint_R": 1.0, "eyeBlink_L": 0.6,
     "eyeBlink_R": 0.6},
)
# the colour the renderer clears to, replaced by the background after (no shaded surface comes out pure green)
_KEY = (0.0, 1.0, 0.0)
_KEY_RGB = np.array([0, 255, 0], dtype=np.uint8)
_EYE_SIDES = (slice(36, 42), slice(42, 48))  # eye 0: the subject's right (landmarks 36-41), eye 1: the left


# ----------------------------------------------------------------------------- geometry


def sphere_zone(radius: float, theta_from: float, theta_to: float, rings: int, segments: int = 32):
    """The part of a sphere between two polar angles, as a triangle mesh facing outwards.

    The sphere is centred at the origin; polar angles are measured from +z.
    ``theta_from = 0`` closes the zone with a vertex at the +z pole (a cap),
    ``theta_to = pi`` with one at the -z pole; ``(0, pi)`` is the whole sphere.
    Zones that share a polar angle share their boundary vertices' positions
    exactly, so a sphere cut into zones has no cracks.

    Parameters
    ----------
    radius : float
        The sphere's radius.
    theta_from, theta_to : float
        Polar angles in radians, ``0 <= theta_from < theta_to <= pi``.
    rings : int
        Steps in the polar angle (>= 1).
    segments : int, optional
        Vertices around each ring (>= 3), default 32.

    Returns
    -------
    vertices : (N, 3) float64
    triangles : (M, 3) int64
        Counter-clockwise seen from outside the sphere.
    """
    if not (0.0 <= theta_from < theta_to <= math.pi) or rings < 1 or segments < 3 or not radius > 0:
        raise InputError(f"a sphere zone needs 0 <= theta_from < theta_to <= pi, rings >= 1, segments >= 3 and a "
                         f"positive radius, got {theta_from}, {theta_to}, {rings}, {segments}, {radius}")
    thetas = np.linspace(theta_from, theta_to, rings + 1)
    phi = np.arange(segments) * (2.0 * math.pi / segments)
    top = theta_from <= 1e-12
    bottom = theta_to >= math.pi - 1e-12
    inner = thetas[int(top):len(thetas) - int(bottom)]
    s, c = np.sin(inner)[:, None], np.cos(inner)[:, None]
    ringpts = np.stack([s * np.cos(phi), s * np.sin(phi), np.broadcast_to(c, (len(inner), segments))], axis=-1)
    parts = ([np.array([[0.0, 0.0, 1.0]])] if top else []) + [ringpts.reshape(-1, 3)]
    parts += [np.array([[0.0, 0.0, -1.0]])] if bottom else []
    V = np.concatenate(parts) * float(radius)
    off = int(top)
    j = np.arange(segments)
    jn = (j + 1) % segments
    F = []
    if top:
        F.append(np.c_[np.zeros(segments, dtype=np.int64), off + j, off + jn])
    for i in range(len(inner) - 1):
        a, b = off + i * segments + j, off + i * segments + jn
        c_, d = a + segments, b + segments
        F.append(np.c_[a, c_, d])
        F.append(np.c_[a, d, b])
    if bottom:
        last = len(V) - 1
        base = off + (len(inner) - 1) * segments
        F.append(np.c_[np.full(segments, last), base + jn, base + j])
    return V, np.concatenate(F).astype(np.int64)


def gaze_rotation(yaw: float, pitch: float) -> np.ndarray:
    """The eye's rotation for a gaze: ``Ry(yaw) @ Rx(-pitch)`` -> ``(3, 3)``.

    It turns +z (looking straight ahead) to ``(cos p sin y, sin p, cos p cos y)``:
    yaw positive looks to the subject's left (+x), pitch positive up (+y).
    """
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]])  # Rx(-pitch)
    return ry @ rx


def _expression(model, weights: Mapping[str, float]) -> np.ndarray:
    w = np.zeros(len(model.expression_names))
    for name, value in weights.items():
        if name in model.expression_names:
            w[model.expression_names.index(name)] = value
    return w


def eye_centres(model, identity=None, radius: float = EYE_RADIUS, clearance: float = EYE_CLEARANCE) -> np.ndarray:
    """Where the eyeballs sit in an identity's face: ``(2, 3)``, eye 0 the subject's right, cm.

    Each centre is the centroid of the neutral lid landmarks (36-41, 42-47)
    pushed back along -z by the least depth (at least :data:`EYE_MIN_DEPTH`)
    at which every skin vertex within 3 cm of the centroid stays ``clearance``
    away from the ball of ``radius``, over the expressions the lids make
    (neutral, closed, wide, squinting, looking each way, frowning, smiling).

    Parameters
    ----------
    model : FaceModel
    identity : (I,) array_like, optional
        Identity coefficients (None: the generic face).
    radius, clearance : float, optional
        The ball's radius and the gap kept to the skin, cm.

    Returns
    -------
    (2, 3) float64
    """
    N = model.identity_neutral(identity)
    faces = []
    for e in _EYE_CHECKS:
        w = _expression(model, e)
        nz = np.flatnonzero(w)
        faces.append(N + np.tensordot(w[nz], model.expression_deltas[nz].astype(np.float64), axes=1))
    out = np.zeros((2, 3))
    for k, sl in enumerate(_EYE_SIDES):
        c0 = N[model.landmarks[sl]].mean(axis=0)
        near = np.flatnonzero(np.linalg.norm(N - c0, axis=1) < 3.0)
        need = EYE_MIN_DEPTH
        for V in faces:
            P = V[near] - c0
            rho2 = P[:, 0] ** 2 + P[:, 1] ** 2
            hit = rho2 < (radius + clearance) ** 2
            if hit.any():
                h = np.sqrt((radius + clearance) ** 2 - rho2[hit])
                need = max(need, float(np.max(h - P[hit, 2])))  # (z + d) >= h: the vertex in front of the ball
        out[k] = c0 - [0.0, 0.0, need]
    return out


def _boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The mesh's boundary loops, each as vertex ids in the order of the triangles' orientation."""
    F = np.asarray(triangles, dtype=np.int64)
    H = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    n = int(F.max()) + 1
    code = H[:, 0] * n + H[:, 1]
    twin = H[:, 1] * n + H[:, 0]
    lone = H[~np.isin(code, twin)]
    nxt = dict(zip(lone[:, 0].tolist(), lone[:, 1].tolist()))
    loops, seen = [], set()
    for s in sorted(nxt):
        if s in seen:
            continue
        loop, x = [], s
        while x not in seen:
            seen.add(x)
            loop.append(x)
            x = nxt[x]
        loops.append(np.array(loop, dtype=np.int64))
    return loops


#: The mesh's holes the props close, by the landmarks they are nearest to.
HOLES = {"right eye": slice(36, 42), "left eye": slice(42, 48), "mouth": slice(48, 68)}


def hole_loop(model, part: str) -> np.ndarray:
    """The vertex ids around one of the mesh's holes (:data:`HOLES`), in the order of the triangles' orientation.

    ``"mouth"`` is the inner edge of the lips, ``"right eye"`` / ``"left eye"``
    the lid margins of the subject's right / left eye: the boundary loop whose
    centroid is nearest the part's landmarks.

    Raises
    ------
    InputError
        An unknown part, or no hole near its landmarks.
    """
    if part not in HOLES:
        raise InputError(f"unknown part {part!r}; use one of {', '.join(HOLES)}")
    V = model.neutral
    lm = V[model.landmarks[HOLES[part]]]
    centre, span = lm.mean(axis=0), float(np.ptp(lm, axis=0).max())
    best = None
    for loop in _boundary_loops(model.triangles):
        d = float(np.linalg.norm(V[loop].mean(axis=0) - centre))
        if d < span / 2 and np.ptp(V[loop], axis=0).max() < 2 * span and (best is None or d < best[0]):
            best = (d, loop)
    if best is None:
        raise InputError(f"the face mesh has no hole at the {part}: it cannot be closed")
    return best[1]


def _tube(n: int, rings: int, close: bool) -> np.ndarray:
    """Triangles joining ``rings`` rings of ``n`` vertices (ring ``i`` at ``i * n``), closed by a last vertex
    when ``close``; they face the inside of the tube when the rings run the way a hole's boundary does."""
    j = np.arange(n)
    jn = (j + 1) % n
    F = []
    for i in range(rings - 1):
        a, b = i * n + j, i * n + jn
        F.append(np.c_[a, b + n, b])
        F.append(np.c_[a, a + n, b + n])
    if close:
        base = (rings - 1) * n
        F.append(np.c_[base + j, np.full(n, rings * n), base + jn])
    return np.concatenate(F).astype(np.int64)


class FaceProps:
    """Eyeballs and a mouth interior for one identity's face (see the module docstring).

    Parameters
    ----------
    model : FaceModel
    identity : (I,) array_like, optional
        Identity coefficients (None: the generic face).
    segments : int, optional
        Vertices around each ring of the eyeballs (default 32).

    Attributes
    ----------
    centres : (2, 3) float64
        The eyeballs' centres in the face's frame (:func:`eye_centres`), eye 0 the subject's right.
    radius : float
        The eyeballs' radius (:data:`EYE_RADIUS`).
    loops : dict of str to (L,) int64
        The holes' boundary loops (:func:`hole_loop`).
    """

    def __init__(self, model, identity=None, segments: int = 32):
        self.radius = EYE_RADIUS
        self.centres = eye_centres(model, identity)
        t_pupil = math.asin(PUPIL_RADIUS / EYE_RADIUS)
        t_iris = math.asin(IRIS_RADIUS / EYE_RADIUS)
        self._ball = [sphere_zone(EYE_RADIUS, 0.0, t_pupil, 3, segments),
                      sphere_zone(EYE_RADIUS, t_pupil, t_iris, 4, segments),
                      sphere_zone(EYE_RADIUS, t_iris, math.pi, 16, segments)]
        self.loops = {part: hole_loop(model, part) for part in HOLES}
        self._pouch = _tube(len(self.loops["mouth"]), len(_POUCH_RINGS) + 1, close=True)
        self._sleeves = [_tube(len(self.loops[p]), len(_SLEEVE_RINGS) + 1, close=False)
                         for p in ("right eye", "left eye")]

    def mouth(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mouth pouch for a posed face ``vertices (n, 3)`` -> ``(V (5 L + 1, 3), F)``, facing into the pouch."""
        B = np.asarray(vertices, dtype=np.float64)[self.loops["mouth"]]
        c = B.mean(axis=0)
        rings = [B]
        for s, d in _POUCH_RINGS:
            P = B.copy()
            P[:, :2] = c[:2] + s * (B[:, :2] - c[:2])
            P[:, 2] = B[:, 2] - d
            rings.append(P)
        back = np.array([[c[0], c[1], B[:, 2].mean() - _POUCH_BACK]])
        return np.concatenate(rings + [back]), self._pouch

    def sleeve(self, k: int, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The band closing the gap between eye ``k``'s lid margins and its ball, for a posed face -> ``(V, F)``.

        Rings from the lid margin towards the ball's centre, at 0.97 and 0.6
        of its radius (the second also 0.3 cm further back): just under the
        ball's surface, so no view through the lids passes beside the ball.
        """
        B = np.asarray(vertices, dtype=np.float64)[self.loops[("right eye", "left eye")[k]]]
        c = self.centres[k]
        u = (B - c) / np.linalg.norm(B - c, axis=1, keepdims=True)
        rings = [B] + [c + f * self.radius * u - [0.0, 0.0, back] for f, back in _SLEEVE_RINGS]
        return np.concatenate(rings), self._sleeves[k]

    def eye(self, k: int, yaw: float, pitch: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Eye ``k``'s pupil, iris and sclera meshes, turned by the gaze ``(yaw, pitch)`` (radians)."""
        R = gaze_rotation(yaw, pitch)
        return [(V @ R.T + self.centres[k], F) for V, F in self._ball]

    def meshes(self, vertices: np.ndarray, gaze, iris=IRIS_COLOURS["brown"], skin=(0.80, 0.60, 0.47)) -> list[tuple]:
        """Everything to draw with a posed face: ``[(V, F, colour), ...]`` for :meth:`FaceRenderer.render`'s ``extra``.

        Parameters
        ----------
        vertices : (n, 3)
            The posed face (its expression), in the face's frame.
        gaze : (2, 2)
            Per eye yaw and pitch, radians (eye 0 the subject's right).
        iris, skin : (3,) colour, optional
            The iris's colour; the skin's, of which the band inside the lids is a darker shade.
        """
        g = np.asarray(gaze, dtype=np.float64).reshape(2, 2)
        lids = tuple(float(SLEEVE_SHADE * x) for x in skin)
        out = []
        for k in range(2):
            (Vp, Fp), (Vi, Fi), (Vs, Fs) = self.eye(k, g[k, 0], g[k, 1])
            out += [(Vp, Fp, PUPIL_COLOUR), (Vi, Fi, tuple(iris)), (Vs, Fs, SCLERA_COLOUR),
                    (*self.sleeve(k, vertices), lids)]
        Vm, Fm = self.mouth(vertices)
        out.append((Vm, Fm, MOUTH_COLOUR))
        return out


# ----------------------------------------------------------------------------- clip specifications


@dataclass(frozen=True)
class FamilyRanges:
    """The ranges one family of clips is drawn from.

    Attributes
    ----------
    salt : int
        Mixed into the seed, so the families never share a random stream.
    half : int
        The half of each take the windows come from (0: the first, 1: the second).
    yaw, pitch, roll : float
        Most head turn about each axis, degrees (each clip's peak is 40-100 % of it).
    shift, depth_shift : float
        Most drift of the head sideways / up-down and towards the camera, cm.
    fov : tuple of (lo, hi)
        Vertical field of view, degrees: uniform over the union of the intervals.
    fraction : (lo, hi)
        The face's width (landmark 0 to 16) as a fraction of the frame's width, at rest.
    skin : tuple of int
        Indices into :data:`facegeom.pipelines.render.SKIN_TONES`.
    background : str
        ``"plain"`` (one colour) or ``"noise"`` (a smooth random texture).
    gaze_yaw, gaze_pitch : float
        Most gaze angle, degrees (vergence included).
    vergence : (lo, hi)
        Both eyes turned inwards by this angle in all, degrees.
    gain, contrast, gamma : (lo, hi)
        Light changes applied to the rendered frame (:func:`grade`).
    tint : float
        Most change of each colour channel's gain (white balance), as a fraction.
    noise : (lo, hi)
        Sensor noise, standard deviation in 8-bit levels.
    identity_scale : float
        Standard deviation of the identity coefficients.
    """

    salt: int
    half: int
    yaw: float
    pitch: float
    roll: float
    shift: float
    depth_shift: float
    fov: tuple[tuple[float, float], ...]
    fraction: tuple[float, float]
    skin: tuple[int, ...]
    background: str
    gaze_yaw: float
    gaze_pitch: float
    vergence: tuple[float, float]
    gain: tuple[float, float]
    contrast: tuple[float, float]
    gamma: tuple[float, float]
    tint: float
    noise: tuple[float, float]
    identity_scale: float = 1.0


#: The two families of clips: ``"tune"`` to choose defaults on, ``"holdout"`` to check them on.
FAMILIES: dict[str, FamilyRanges] = {
    "tune": FamilyRanges(salt=7101, half=0, yaw=20.0, pitch=10.0, roll=6.0, shift=2.0, depth_shift=3.0,
                         fov=((45.0, 65.0),), fraction=(0.3, 0.6), skin=(0, 1, 2), background="plain",
                         gaze_yaw=20.0, gaze_pitch=12.0, vergence=(0.0, 3.0), gain=(0.9, 1.1),
                         contrast=(0.9, 1.1), gamma=(0.9, 1.1), tint=0.03, noise=(0.0, 1.5)),
    "holdout": FamilyRanges(salt=9203, half=1, yaw=30.0, pitch=15.0, roll=10.0, shift=3.0, depth_shift=5.0,
                            fov=((35.0, 45.0), (65.0, 75.0)), fraction=(0.15, 0.3), skin=(2, 3, 4),
                            background="noise", gaze_yaw=20.0, gaze_pitch=12.0, vergence=(0.0, 4.0),
                            gain=(0.7, 1.3), contrast=(0.8, 1.2), gamma=(0.8, 1.25), tint=0.08, noise=(1.0, 4.0)),
    # the scenes the point map is learnt from (data/mediapipe_map/learn_map.py): their own seeds, and ranges that
    # cover both families above, so the map is not fitted to either
    "map": FamilyRanges(salt=3307, half=0, yaw=35.0, pitch=18.0, roll=12.0, shift=3.0, depth_shift=5.0,
                        fov=((35.0, 75.0),), fraction=(0.15, 0.6), skin=(0, 1, 2, 3, 4), background="noise",
                        gaze_yaw=20.0, gaze_pitch=12.0, vergence=(0.0, 4.0), gain=(0.7, 1.3), contrast=(0.8, 1.2),
                        gamma=(0.8, 1.25), tint=0.08, noise=(0.0, 4.0)),
}

_Waves = tuple[tuple[float, float, float], ...]  # (amplitude, frequency Hz, phase rad) per component


@dataclass(frozen=True)
class ClipSpec:
    """Everything one synthetic clip is made from; :func:`render_clip` renders it deterministically.

    Attributes
    ----------
    name : str
        The clip's file stem.
    family : str
        ``"tune"`` or ``"holdout"`` (:data:`FAMILIES`).
    seed : int
        The clip's own seed (background texture, sensor noise).
    identity : tuple of float
        Identity coefficients of the face model.
    take : str
        The take's file name (looked up among the takes given to :func:`render_clip`).
    start, frames : int
        The window of the take: frames ``start`` to ``start + frames - 1``.
    fps : float
        The take's frame rate (the video's).
    width, height : int
        Frame size in pixels.
    fov : float
        Vertical field of view, degrees.
    distance : float
        Camera to the face's landmark centre at rest, cm.
    fraction : float
        The face's width (landmark 0 to 16) over the frame's width at rest, frontal (what ``distance`` gives).
    head : tuple of 6 waves
        Yaw, pitch, roll (degrees), and drift x, y, z (cm): each a tuple of
        ``(amplitude, frequency Hz, phase rad)`` sinusoids summed.
    head_from_take : bool
        The head's rotation is the take's own (its ``HeadYaw, HeadPitch,
        HeadRoll``); the waves give only the drift.
    gaze : tuple of 2 waves
        Gaze yaw and pitch of both eyes, degrees.
    vergence : float
        Both eyes turned inwards by this angle in all, degrees.
    gaze_from_take : bool
        The gaze comes from the take's eye-look weights instead of ``gaze``.
    skin, iris : (3,) float
        Colours, linear RGB in [0, 1]. ``iris_name`` names the iris colour.
    background : str
        ``"plain"`` or ``"noise"``; ``background_colours`` its colour(s);
        ``background_scale`` the texture's feature size as a fraction of the frame's width.
    gain, contrast, gamma : float
        Light changes (:func:`grade`); ``tint`` per-channel gains; ``noise``
        sensor noise in 8-bit levels.
    """

    name: str
    family: str
    seed: int
    identity: tuple[float, ...]
    take: str
    start: int
    frames: int
    fps: float
    width: int
    height: int
    fov: float
    distance: float
    fraction: float
    head: tuple[_Waves, ...]
    head_from_take: bool
    gaze: tuple[_Waves, ...]
    vergence: float
    gaze_from_take: bool
    skin: tuple[float, float, float]
    iris: tuple[float, float, float]
    iris_name: str
    background: str
    background_colours: tuple[tuple[float, float, float], ...]
    background_scale: float
    gain: float
    contrast: float
    gamma: float
    tint: tuple[float, float, float]
    noise: float

    @property
    def focal(self) -> float:
        """Focal length in pixels from the vertical field of view: ``(height / 2) / tan(fov / 2)``."""
        return self.height / 2.0 / math.tan(math.radians(self.fov) / 2.0)

    @property
    def window(self) -> tuple[int, int]:
        """``(start, start + frames)``: the take's frames rendered."""
        return self.start, self.start + self.frames

    def to_json(self) -> str:
        """The spec as JSON text (:meth:`from_json` reads it back)."""
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ClipSpec:
        """A spec from :meth:`to_json`'s text.

        Raises
        ------
        InputError
            Not a spec's JSON.
        """
        try:
            d = json.loads(text)
            names = {f.name for f in dataclasses.fields(cls)}
            if not isinstance(d, dict) or set(d) != names:
                raise ValueError(f"fields {sorted(set(d) ^ names) if isinstance(d, dict) else d!r}")
            return cls(**{k: _tuples(v) for k, v in d.items()})
        except (ValueError, TypeError) as exc:
            raise InputError(f"not a clip spec's JSON ({exc})") from None


def _tuples(v):
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v


def _waves(rng: np.random.Generator, peak: float, duration: float, count: int = 3,
           freq: tuple[float, float] = (0.05, 0.5)) -> _Waves:
    """``count`` sinusoids whose sum peaks at ``peak`` in absolute value over ``[0, duration]`` (and whose
    amplitudes add up to at most twice that: sums that mostly cancel in the window are drawn again)."""
    if peak <= 0:
        return ()
    t = np.linspace(0.0, duration, 200)
    for _ in range(50):  # redraw sums whose terms mostly cancel in the window (large, fast opposite swings)
        f = np.exp(rng.uniform(np.log(freq[0]), np.log(freq[1]), count))
        a = rng.uniform(0.3, 1.0, count)
        ph = rng.uniform(0.0, 2.0 * np.pi, count)
        top = np.abs((a[:, None] * np.sin(2 * np.pi * f[:, None] * t + ph[:, None])).sum(0)).max()
        if top >= 0.5 * a.sum():
            break
    a = a * (peak / max(top, 1e-9))
    return tuple((float(x), float(y), float(z)) for x, y, z in zip(a, f, ph))


def _eval(waves: _Waves, t: np.ndarray) -> np.ndarray:
    out = np.zeros_like(t)
    for a, f, ph in waves:
        out += a * np.sin(2.0 * np.pi * f * t + ph)
    return out


# ----------------------------------------------------------------------------- takes


def _take_files(takes=None) -> list[Path]:
    from facegeom.io.takes import find_takes
    from facegeom.model.face import locate_takes

    if takes is None:
        takes = locate_takes()
    if isinstance(takes, (list, tuple)):
        files = [Path(p) for p in takes]
    else:
        p = Path(takes)
        files = [p] if p.is_file() else find_takes(p)
    for f in files:
        if not f.is_file():
            raise InputError("take not found", f)
    return files


@functools.lru_cache(maxsize=16)
def _read(path: str, mtime: int):
    from facegeom.io.takes import read_take
    from facegeom.pipelines.solve import take_fps

    take = read_take(path)
    return take, take_fps(take)


def _take(path: Path):
    return _read(str(path), os.stat(path).st_mtime_ns)


def _find_take(name: str, takes=None) -> Path:
    for f in _take_files(takes):
        if f.name == name:
            return f
    raise InputError(f"the clip's take {name!r} is not among the takes given "
                     f"({', '.join(f.name for f in _take_files(takes))})")


# ----------------------------------------------------------------------------- curves


def _face_frame(model, identity) -> tuple[np.ndarray, float, np.ndarray]:
    """The landmark centre (3,), the face's width (landmark 0 to 16), and the landmarks that must stay in the
    frame: the neutral's and the jaw-open face's, ``(136, 3)``."""
    N = model.identity_neutral(identity)
    L = model.landmarks
    lm = N[L]
    centre = (lm.min(axis=0) + lm.max(axis=0)) / 2.0
    width = float(np.linalg.norm(lm[16] - lm[0]))
    jaw = lm + model.expression_deltas[model.expression_names.index("jawOpen")][L].astype(np.float64) \
        if "jawOpen" in model.expression_names else lm
    return centre, width, np.concatenate([lm, jaw])


def head_pose(spec: ClipSpec, centre, take_rotations=None) -> tuple[np.ndarray, np.ndarray]:
    """The face's pose per frame, world (face frame, cm) -> camera: ``R (T, 3, 3)``, ``t (T, 3)``.

    Parameters
    ----------
    spec : ClipSpec
    centre : (3,)
        The identity's landmark centre (on the optical axis at rest).
    take_rotations : (T, 3), optional
        The take's head yaw, pitch, roll (radians) for the window; used when ``spec.head_from_take``.
    """
    from scipy.spatial.transform import Rotation

    t = np.arange(spec.frames) / spec.fps
    if spec.head_from_take and take_rotations is not None:
        angles = np.asarray(take_rotations, dtype=np.float64)[:, :3]
    else:
        angles = np.radians(np.stack([_eval(w, t) for w in spec.head[:3]], axis=1))
    R = Rotation.from_euler("YXZ", angles).as_matrix()
    drift = np.stack([_eval(w, t) for w in spec.head[3:6]], axis=1)
    p = np.asarray(HEAD_PIVOT, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)
    trans = (p - c) - R @ p + np.array([0.0, 0.0, -spec.distance]) + drift
    return R, trans


def gaze_curves(spec: ClipSpec) -> np.ndarray:
    """The gaze drawn for the clip: ``(T, 2, 2)`` per eye yaw and pitch, radians (eye 0 the subject's right).

    The vergence turns each eye inwards by half of ``spec.vergence``: the
    right eye's yaw up (towards the subject's left), the left eye's down.
    """
    t = np.arange(spec.frames) / spec.fps
    yaw, pitch = (np.radians(_eval(w, t)) for w in spec.gaze)
    v = math.radians(spec.vergence) / 2.0
    g = np.empty((spec.frames, 2, 2))
    g[:, 0, 0], g[:, 1, 0] = yaw + v, yaw - v
    g[:, :, 1] = pitch[:, None]
    return g


def _look_weights(model, gaze: np.ndarray) -> dict[str, np.ndarray]:
    """Eye-look weights of a gaze (inverse of :func:`facegeom.io.takes.eye_rotations`, with this module's signs)."""
    from facegeom.io.takes import EYE_PITCH_PER_WEIGHT, EYE_YAW_PER_WEIGHT

    out = {}
    for k, side in ((0, "R"), (1, "L")):
        yaw, pitch = gaze[:, k, 0] / EYE_YAW_PER_WEIGHT, gaze[:, k, 1] / EYE_PITCH_PER_WEIGHT
        towards_left = np.clip(yaw, 0.0, 1.0)
        towards_right = np.clip(-yaw, 0.0, 1.0)
        # the right eye looks in (to the nose) when it looks to the subject's left; the left eye looks out
        out[f"eyeLookIn_{side}"] = towards_left if side == "R" else towards_right
        out[f"eyeLookOut_{side}"] = towards_right if side == "R" else towards_left
        out[f"eyeLookUp_{side}"] = np.clip(pitch, 0.0, 1.0)
        out[f"eyeLookDown_{side}"] = np.clip(-pitch, 0.0, 1.0)
    return out


def clip_weights(spec: ClipSpec, model, takes=None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The ICT weights rendered, the gaze, and the take's head rotations for the clip's window.

    Returns
    -------
    weights : (T, B) float64
        The take's weights mapped to the model's expressions and clipped to
        [0, 1]; with ``spec.gaze_from_take`` False their eye-look weights are
        those of the clip's gaze.
    gaze : (T, 2, 2) float64
        Per eye yaw and pitch, radians.
    head : (T, 3) float64 or None
        The take's head yaw, pitch, roll, radians (None without rotations).
    """
    from facegeom.io.takes import eye_rotations, ict_weights

    take, _ = _take(_find_take(spec.take, takes))
    a, b = spec.window
    if b > take.n_frames:
        raise InputError(f"the take has {take.n_frames} frames; the clip's window {a}-{b} runs past its end", take.path)
    W = ict_weights(take, model.expression_names)[a:b].astype(np.float64)
    if spec.gaze_from_take:
        rot = eye_rotations(take.weights[a:b], take.names)  # Live Link: LeftEyeYaw, LeftEyePitch, LeftEyeRoll, Right...
        gaze = -np.stack([rot[:, [3, 4]], rot[:, [0, 1]]], axis=1)  # eye 0 = right; ARKit's signs are the opposite
    else:
        gaze = gaze_curves(spec)
        for name, w in _look_weights(model, gaze).items():
            if name in model.expression_names:
                W[:, model.expression_names.index(name)] = w
    head = None if take.rotations is None else np.asarray(take.rotations[a:b, :3], dtype=np.float64)
    return W, gaze, head


# ----------------------------------------------------------------------------- pixels


def background_image(spec: ClipSpec) -> np.ndarray:
    """The clip's background, ``(H, W, 3)`` uint8: one colour (``"plain"``) or a texture (``"noise"``).

    Colours in [0, 1] become 8-bit values ``round(255 c)`` as they are (the
    face renderer's clear colour would go through its tone curve). The
    texture is smooth random noise from the clip's seed: three colours
    blended by smooth random fields at the spec's feature size, plus a finer
    octave of a quarter the size.
    """
    if spec.background == "plain":
        c = np.round(np.asarray(spec.background_colours[0], dtype=np.float64) * 255.0).astype(np.uint8)
        return np.broadcast_to(c, (spec.height, spec.width, 3)).copy()
    from scipy.ndimage import zoom

    rng = np.random.default_rng([spec.seed, 11])
    H, W = spec.height, spec.width

    def field(cell: float, channels: int) -> np.ndarray:
        gh, gw = max(2, math.ceil(H / cell) + 2), max(2, math.ceil(W / cell) + 2)
        g = rng.standard_normal((gh, gw, channels))
        big = zoom(g, (cell, cell, 1), order=3, mode="nearest")
        return big[:H, :W]

    cell = max(4.0, spec.background_scale * W)
    f = field(cell, len(spec.background_colours)) + 0.35 * field(cell / 4.0, len(spec.background_colours))
    w = np.exp(2.5 * f)
    w /= w.sum(axis=2, keepdims=True)
    rgb = np.tensordot(w, np.asarray(spec.background_colours, dtype=np.float64), axes=1)
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def grade(image: np.ndarray, spec: ClipSpec, frame: int) -> np.ndarray:
    """The light changes and sensor noise of a clip applied to a rendered frame -> ``(H, W, 3)`` uint8.

    ``out = clip(((x - 0.5) * contrast + 0.5) * gain * tint) ** gamma + noise`` on
    ``x`` in [0, 1] (a lookup table per channel). The noise is Gaussian with
    ``spec.noise`` levels of 255 as standard deviation (drawn as 256 equally
    likely quantiles, so cut at 2.9 standard deviations), seeded by the clip's
    seed and the frame's index.
    """
    lut = _grade_table(spec.gain, spec.contrast, spec.gamma, tuple(spec.tint))
    idx = image.astype(np.uint16) + np.array([0, 256, 512], dtype=np.uint16)
    if spec.noise <= 0:
        return np.clip(lut[idx] + 0.5, 0, 255).astype(np.uint8)
    u = np.random.default_rng([spec.seed, 23, int(frame)]).integers(0, 256, image.shape, dtype=np.uint8)
    x = lut[idx] + _normal_table()[u] * np.float32(spec.noise)
    return np.clip(x + 0.5, 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=8)
def _grade_table(gain: float, contrast: float, gamma: float, tint: tuple[float, float, float]) -> np.ndarray:
    """The three channels' tables one after the other, ``(768,)`` float32 levels of 255."""
    x = np.arange(256, dtype=np.float64)[None, :] / 255.0
    y = ((x - 0.5) * contrast + 0.5) * gain * np.asarray(tint, dtype=np.float64)[:, None]
    return (np.clip(y, 0.0, 1.0) ** gamma * 255.0).astype(np.float32).ravel()


@functools.lru_cache(maxsize=1)
def _normal_table() -> np.ndarray:
    """256 standard-normal quantiles (of the probabilities (k + 0.5) / 256), scaled to unit variance, float32."""
    from scipy.special import ndtri

    q = ndtri((np.arange(256) + 0.5) / 256.0)
    return (q / q.std()).astype(np.float32)


def _in_frame(points: np.ndarray, R: np.ndarray, t: np.ndarray, focal: float, width: int, height: int,
              margin: float = 0.03) -> bool:
    pc = np.einsum("tij,pj->tpi", R, points) + t[:, None]
    depth = -pc[..., 2]
    if np.any(depth <= 1.0):
        return False
    u = (width - 1) / 2.0 + focal * pc[..., 0] / depth
    v = (height - 1) / 2.0 - focal * pc[..., 1] / depth
    return bool(np.all((u > margin * width) & (u < (1 - margin) * width) & (v > margin * height)
                       & (v < (1 - margin) * height)))


# ----------------------------------------------------------------------------- specs


def _colour(rng: np.random.Generator, sat: tuple[float, float], val: tuple[float, float]) -> tuple:
    r, g, b = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(*sat), rng.uniform(*val))
    return round(r, 4), round(g, 4), round(b, 4)


def make_specs(n: int, seed: int = 0, family: str = "tune", frames: int = 150, size: tuple[int, int] = (640, 480),
               takes=None, model=None, take_head: bool = False, gaze_from_take: bool = False) -> list[ClipSpec]:
    """Draw ``n`` clip specifications of one family.

    Clip ``i`` depends only on ``(seed, family, i)`` and the takes given (so
    the first clips of a larger set are the same clips).

    Parameters
    ----------
    n : int
        Number of clips (>= 1).
    seed : int, optional
        The set's seed.
    family : str, optional
        ``"tune"`` (default) or ``"holdout"``; see :data:`FAMILIES`.
    frames : int, optional
        Frames per clip (default 150, 5 s of a 30 fps take).
    size : (width, height), optional
        Frame size in pixels (default 640 x 480).
    takes : path or list of paths, optional
        A folder of Live Link CSV takes, one take, or a list; default
        :func:`facegeom.model.face.locate_takes`. Windows come from the
        family's half of each take (the first half for ``"tune"``, the
        second for ``"holdout"``), so the two families never share a frame.
    model : FaceModel, optional
        Default :func:`facegeom.model.load_face_model`.
    take_head : bool, optional
        Use a take's own head rotation when its window has one (the
        takes at hand have none); default False: sinusoids.
    gaze_from_take : bool, optional
        Gaze from the take's eye-look weights instead of drawn curves.

    Returns
    -------
    list of ClipSpec

    Raises
    ------
    InputError
        A bad ``n``, ``family``, ``frames`` or ``size``, no take, or no take
        with a half of at least ``frames`` frames.
    """
    if family not in FAMILIES:
        raise InputError(f"unknown clip family {family!r}; use one of {', '.join(FAMILIES)}")
    for what, v, lo in (("n", n, 1), ("frames", frames, 2), ("seed", seed, 0)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise InputError(f"{what} must be a whole number >= {lo}, got {v!r}")
    try:
        width, height = (int(s) for s in size)
    except (TypeError, ValueError):
        raise InputError(f"size must be (width, height) in pixels, got {size!r}") from None
    if not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise InputError(f"the frame must be 16-4096 pixels a side, not {width} x {height}")
    fam = FAMILIES[family]
    if model is None:
        from facegeom.model import load_face_model

        model = load_face_model()
    files = _take_files(takes)
    usable = []
    for f in files:
        take, fps = _take(f)
        half = take.n_frames // 2
        lo, hi = (0, half - frames) if fam.half == 0 else (take.n_frames - half, take.n_frames - frames)
        if hi >= lo:
            usable.append((f, take, fps, lo, hi))
    if not usable:
        longest = max(_take(f)[0].n_frames for f in files)
        raise InputError(f"clips of {frames} frames need a take of at least {2 * frames} frames (each family uses "
                         f"its own half); the longest take has {longest}")
    root = np.random.SeedSequence([int(seed), fam.salt])
    specs = []
    for i, child in enumerate(root.spawn(int(n))):
        rng = np.random.default_rng(child)
        clip_seed = int(child.generate_state(1, np.uint32)[0])
        f, take, fps, lo, hi = usable[int(rng.integers(len(usable)))]
        start = int(rng.integers(lo, hi + 1))
        identity = model.random_identity(rng, fam.identity_scale)
        duration = frames / fps
        peaks = rng.uniform(0.4, 1.0, 8)  # each clip's peaks: 40-100 % of the family's limits
        limits = (fam.yaw, fam.pitch, fam.roll, fam.shift, fam.shift, fam.depth_shift)
        head = [_waves(rng, lim * p, duration) for lim, p in zip(limits, peaks)]
        spans = np.array([b - a for a, b in fam.fov])
        k = int(rng.choice(len(spans), p=spans / spans.sum()))
        fov = float(rng.uniform(*fam.fov[k]))
        fraction = float(rng.uniform(*fam.fraction))
        vergence = float(rng.uniform(*fam.vergence))
        gaze = (_waves(rng, (fam.gaze_yaw - vergence / 2) * peaks[6], duration, freq=(0.1, 1.0)),
                _waves(rng, fam.gaze_pitch * peaks[7], duration, freq=(0.1, 1.0)))
        skin = tuple(float(c) for c in _skin(fam, rng))
        iris_name = str(rng.choice(sorted(IRIS_COLOURS)))
        if fam.background == "plain":
            colours = (_colour(rng, (0.0, 0.5), (0.15, 0.9)),)
        else:
            colours = tuple(_colour(rng, (0.1, 0.7), (0.1, 0.95)) for _ in range(3))
        bg_scale = float(rng.uniform(0.05, 0.3))
        gain, contrast, gamma = (float(rng.uniform(*r)) for r in (fam.gain, fam.contrast, fam.gamma))
        tint = tuple(float(x) for x in 1.0 + rng.uniform(-fam.tint, fam.tint, 3))
        noise = float(rng.uniform(*fam.noise))
        rot = None if take.rotations is None else take.rotations[start:start + frames, :3]
        from_take = bool(take_head and rot is not None and np.any(np.abs(rot) > 1e-6))
        # keep the 68 landmarks (also with the jaw open) inside the frame: less drift, then a farther camera
        centre, face_width, points = _face_frame(model, identity)
        focal = height / 2.0 / math.tan(math.radians(fov) / 2.0)
        distance = focal * face_width / (fraction * width)
        for attempt in range(24):
            spec = ClipSpec(
                name=f"{family}-{seed}-{i:03d}", family=family, seed=clip_seed,
                identity=tuple(float(x) for x in identity), take=f.name, start=start, frames=int(frames),
                fps=float(fps), width=width, height=height, fov=fov, distance=float(distance),
                fraction=float(focal * face_width / distance / width), head=tuple(head), head_from_take=from_take,
                gaze=gaze, vergence=vergence, gaze_from_take=bool(gaze_from_take), skin=skin,
                iris=IRIS_COLOURS[iris_name], iris_name=iris_name, background=fam.background,
                background_colours=colours, background_scale=bg_scale, gain=gain, contrast=contrast, gamma=gamma,
                tint=tint, noise=noise)
            R, t = head_pose(spec, centre, rot)
            if _in_frame(points, R, t, focal, width, height):
                break
            if attempt < 4:
                head[3:] = [tuple((a * 0.6, fr, ph) for a, fr, ph in w) for w in head[3:]]
            else:
                distance *= 1.08
        else:  # pragma: no cover - the camera 4.7 times as far frames any face
            raise InputError(f"clip {spec.name}: the face cannot be kept inside a {width} x {height} frame")
        specs.append(spec)
    return specs


def _skin(fam: FamilyRanges, rng: np.random.Generator) -> np.ndarray:
    """A skin colour of the family: one of its tones, its brightness varied by up to 6 %."""
    from facegeom.pipelines.render import SKIN_TONES

    tone = np.asarray(SKIN_TONES[int(rng.choice(fam.skin))], dtype=np.float64)
    return np.round(np.clip(tone * rng.uniform(0.94, 1.06), 0.0, 1.0), 4)


# ----------------------------------------------------------------------------- rendering


class ClipScene:
    """One clip's fixed look, ready to draw frames: its identity's face and props, camera, background and light.

    Parameters
    ----------
    spec : ClipSpec
    model : FaceModel, optional
        Default :func:`facegeom.model.load_face_model`.
    renderer : FaceRenderer, optional
        One of the spec's frame size, to reuse (default: a new one).

    Attributes
    ----------
    spec : ClipSpec
    model : FaceModel
    identity : (I,) float64
    neutral : (n, 3) float64
        The identity's neutral face.
    centre : (3,) float64
        The identity's landmark centre (on the optical axis at rest).
    props : FaceProps
    renderer : FaceRenderer
    camera : PinholeCamera
        The clip's intrinsics (unposed).
    background : (H, W, 3) uint8

    Raises
    ------
    InputError
        The off-screen renderer cannot start.
    """

    def __init__(self, spec: ClipSpec, model=None, renderer=None):
        from facegeom.pipelines.render import FaceRenderer

        if model is None:
            from facegeom.model import load_face_model

            model = load_face_model()
        self.spec, self.model = spec, model
        self.identity = np.asarray(spec.identity, dtype=np.float64)
        self.neutral = model.identity_neutral(self.identity)
        self.centre = _face_frame(model, self.identity)[0]
        self.props = FaceProps(model, self.identity)
        if renderer is None or (renderer.width, renderer.height) != (spec.width, spec.height):
            renderer = FaceRenderer(spec.width, spec.height)
        self.renderer = renderer
        self.camera = renderer.camera_for(spec.focal)
        self.background = background_image(spec)
        self._deltas = model.expression_deltas.reshape(len(model.expression_names), -1)
        from facegeom.pipelines.render import HAIR_TONES, face_colours

        # brows and lips painted on the skin (a detector looks for them); the brow colour follows the clip's seed
        self.colours = face_colours(model, self.neutral, spec.skin, HAIR_TONES[int(spec.seed) % len(HAIR_TONES)])

    def vertices(self, weights=None) -> np.ndarray:
        """The face with expression ``weights (B,)`` (None: neutral), face frame, ``(n, 3)``."""
        if weights is None:
            return self.neutral.copy()
        return self.neutral + (np.asarray(weights, dtype=np.float64) @ self._deltas).reshape(-1, 3)

    def render(self, weights=None, gaze=None, pose=None, frame: int = 0) -> np.ndarray:
        """One graded frame: the face with ``weights``, eyes at ``gaze``, at ``pose`` -> ``(H, W, 3)`` uint8.

        Parameters
        ----------
        weights : (B,), optional
            Expression weights (None: neutral).
        gaze : (2, 2), optional
            Per eye yaw and pitch, radians (None: straight ahead).
        pose : (R (3, 3), t (3,)), optional
            World -> camera (None: the head at rest, facing the camera at the spec's distance).
        frame : int, optional
            The frame's index (seeds the sensor noise).
        """
        V = self.vertices(weights)
        g = np.zeros((2, 2)) if gaze is None else np.asarray(gaze, dtype=np.float64)
        if pose is None:
            R, t = np.eye(3), np.array([0.0, 0.0, -self.spec.distance]) - self.centre
        else:
            R, t = pose
        img = self.renderer.render(V, self.model.triangles, self.camera.with_pose(R, t), color=self.colours,
                                   background=_KEY, extra=self.props.meshes(V, g, self.spec.iris, self.spec.skin))
        # the background is composited here by the key colour: FaceRenderer's image background relies on the
        # screenshot's alpha, which comes back opaque under EGL (polyscope 2.6)
        key = np.all(img == _KEY_RGB, axis=2)
        img[key] = self.background[key]
        return grade(img, self.spec, frame)


def render_clip(spec: ClipSpec, out_dir, model=None, *, takes=None, renderer=None, progress: bool = True) -> Path:
    """Render a clip: ``out_dir/<name>.mp4`` (H.264 at the take's rate) and ``out_dir/<name>.truth.npz``.

    Parameters
    ----------
    spec : ClipSpec
    out_dir : path
        The folder to write into (created if missing).
    model : FaceModel, optional
        Default :func:`facegeom.model.load_face_model`.
    takes : path or list of paths, optional
        Where the spec's take is found (default :func:`facegeom.model.face.locate_takes`).
    renderer : FaceRenderer, optional
        One of the spec's frame size, to reuse (default: a new one).
    progress : bool, optional
        Show a tqdm bar of the frames (default True).

    Returns
    -------
    Path
        The video. Its truth file is written after it; both are written
        atomically, so an interrupted render leaves no half-written file and
        a truth file only beside a finished video.

    Raises
    ------
    InputError
        The take is missing or too short, the renderer cannot start, PyAV is missing.
    """
    from tqdm import tqdm

    from facegeom.io.files import atomic_path
    from facegeom.io.video import VideoWriter

    if model is None:
        from facegeom.model import load_face_model

        model = load_face_model()
    W, gaze, take_head = clip_weights(spec, model, takes)
    scene = ClipScene(spec, model, renderer)
    R, t = head_pose(spec, scene.centre, take_head)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    truth = {
        "weights": W, "expression_names": np.array(model.expression_names), "identity": scene.identity,
        "rotations": R, "translations": t, "focal": np.float64(spec.focal), "width": np.int64(spec.width),
        "height": np.int64(spec.height), "fps": np.float64(spec.fps), "gaze": gaze,
        "eye_centres": scene.props.centres, "eye_radius": np.float64(scene.props.radius),
        "take": np.array(spec.take), "window": np.array(spec.window), "spec": np.array(spec.to_json())}
    video = out / f"{spec.name}.mp4"
    with VideoWriter(video, spec.fps, spec.width, spec.height) as writer, \
            tqdm(total=spec.frames, desc=spec.name, unit="frame", disable=not progress, dynamic_ncols=True) as bar:
        for k in range(spec.frames):
            writer.write(scene.render(W[k], gaze[k], (R[k], t[k]), k))
            bar.update(1)
    with atomic_path(out / f"{spec.name}.truth.npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **truth)
    return video


def build_clips(out_dir, n: int, seed: int = 0, family: str = "tune", frames: int = 150,
                size: tuple[int, int] = (640, 480), progress: bool = True, takes=None, model=None) -> list[Path]:
    """Draw ``n`` clips of a family (:func:`make_specs`) and render each (:func:`render_clip`) into ``out_dir``.

    Returns
    -------
    list of Path
        The videos, in the specs' order; each has its ``.truth.npz`` beside it.
    """
    if model is None:
        from facegeom.model import load_face_model

        model = load_face_model()
    from facegeom.pipelines.render import FaceRenderer

    specs = make_specs(n, seed, family, frames, size, takes=takes, model=model)
    renderer = FaceRenderer(specs[0].width, specs[0].height)
    return [render_clip(s, out_dir, model, takes=takes, renderer=renderer, progress=progress) for s in specs]


# ----------------------------------------------------------------------------- truth


_TRUTH_KEYS = ("weights", "identity", "rotations", "translations", "focal", "width", "height", "gaze",
               "eye_centres", "eye_radius")


def load_truth(truth) -> dict[str, np.ndarray]:
    """A clip's truth: a ``.truth.npz`` path or an already loaded mapping -> a dict of arrays.

    Raises
    ------
    InputError
        A missing file or a key missing.
    """
    if isinstance(truth, (str, os.PathLike)):
        p = Path(truth)
        if not p.is_file():
            raise InputError("truth file not found", p)
        with np.load(p, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        where = p
    else:
        d, where = dict(truth), None
    missing = [k for k in _TRUTH_KEYS if k not in d]
    if missing:
        raise InputError(f"not a clip's truth: missing {', '.join(missing)}", where)
    return d


def _camera(d):
    from facegeom.model.camera import PinholeCamera

    w, h = int(d["width"]), int(d["height"])
    return PinholeCamera(float(d["focal"]), (w - 1) / 2.0, (h - 1) / 2.0)


def landmark_truth(truth_npz, model) -> np.ndarray:
    """The 68 landmarks of every frame projected into the image: ``(T, 68, 2)`` pixels (x right, y down).

    The landmark vertices of the face rendered (identity and weights from the
    truth) are projected through the frame's pose, whether or not the face
    hides them (at a strong turn the far jaw contour is behind the cheek).

    Parameters
    ----------
    truth_npz : path or mapping
        A ``.truth.npz`` written by :func:`render_clip`, or its arrays.
    model : FaceModel
        The model the clip was rendered with.
    """
    d = load_truth(truth_npz)
    L = model.landmarks
    base = model.identity_neutral(d["identity"])[L]
    W = np.asarray(d["weights"], dtype=np.float64)
    P = base + np.einsum("tb,bld->tld", W, model.expression_deltas[:, L].astype(np.float64))
    cam = _camera(d)
    R, t = d["rotations"], d["translations"]
    return np.stack([cam.with_pose(R[k], t[k]).project(P[k], "landmark") for k in range(W.shape[0])])


def pupil_truth(truth_npz) -> np.ndarray:
    """The pupils' centres (the front of each eyeball along its gaze) projected: ``(T, 2, 2)`` pixels, eye 0 right."""
    d = load_truth(truth_npz)
    g, C, r = d["gaze"], d["eye_centres"], float(d["eye_radius"])
    cam = _camera(d)
    out = np.empty((g.shape[0], 2, 2))
    for k in range(g.shape[0]):
        P = np.stack([C[e] + gaze_rotation(*g[k, e]) @ [0.0, 0.0, r] for e in range(2)])
        out[k] = cam.with_pose(d["rotations"][k], d["translations"][k]).project(P, "pupil")
    return out
