"""Expression transfer: a bare head mesh of any topology, units and orientation gets the ICT expressions.

Two steps, :func:`register_head` then :func:`transfer_expressions`
(:func:`transfer_head` runs both and returns a
:class:`~facegeom.model.rig.BlendshapeRig` in the head's topology and units).

Registration (the ICT face posed and shaped onto the head)
----------------------------------------------------------
1. **Units**: the power of ten that makes the head the size of the ICT
   template (:func:`~facegeom.registration.units_factor`; a head and the
   ICT face differ by less than 3x, units by powers of ten), or given.
2. **Rigid + scale**: the generic face area posed on points sampled
   uniformly on the head's surface from any orientation
   (:func:`~facegeom.registration.align_on_surface`: the face placed on the
   head's surface facing out from 960 directions and turns, the best refined
   by template -> head ICP; no up axis assumed), or from the 68 landmarks when
   given; then a few rounds of trimmed similarity ICP (template -> head only:
   a head shows much more than a face) for the scale. The identity model
   covers the sizes of real faces; only the part of the scale outside
   ``[1 / SIZE_RANGE, SIZE_RANGE]`` is kept as a similarity (a child's or a
   character's head), the rest is left to the identity fit (see
   :data:`SIZE_RANGE`).
3. **Identity**: :class:`~facegeom.methods.identity.IdentityFitter` (a
   neutral target: ``expressions=False``; its trimmed ICP and annealing, pose
   refined) on the sampled points brought into the model's frame, over the
   whole template (every third vertex, not only the face area: the forehead,
   temples, jaw line and neck pin where the eyes and brows sit), with the
   head's points past the template's outline dropped (their closest template
   vertex within :data:`BAND_CM` of its outer edge: they would pull the
   outline outwards); the landmarks as a weighted vertex target when given.
   Measured on remeshed ICT identities in mm, turned 30 degrees: vertex
   correspondence error (template vertex -> the identity's same vertex)
   median 0.7-0.9 mm over the face area; with the fitter's default face-area
   region 3.2 mm (the face slid along the head: eyes 6 mm, brows 8 mm off).
4. **Non-rigid refinement** beyond the identity space: a few rounds of
   non-rigid ICP (each template vertex pulled to its closest point on the
   head, ``igl.point_mesh_squared_distance``; pairs trimmed as outliers; a
   membrane smoothness term on the displacement with the cotangent
   Laplacian, ``igl.cotmatrix``; one sparse SPD solve per round; the
   smoothing length :data:`NONRIGID_LENGTHS_CM` shrinking round after round),
   then two rounds (:data:`NONRIGID_FINAL_LENGTHS_CM`) without the trimming.
   The trimming's threshold (median + 3 MADs) follows the median down (0.8-1.4
   mm by the last round), so the vertices not yet on the head were dropped
   round after round and never pulled there: the nostrils (the template's
   are deeper than a scan's or an artist's), the eyelids' rims and the chin's
   underside held the face area's 95th percentile at 2.3-3.0 mm (Lee
   Perry-Smith, both MakeHuman heads; medians 0.07-0.12 mm). The final rounds
   keep every pair of :func:`_untrimmed_region` (the face area below the
   eyes, but the lips and the lids) but those past ``4 COVER_MM`` or on an
   open edge of the head (a hole's rim), with a point-to-plane data term
   (plus :data:`NONRIGID_POINT_WEIGHT` point-to-point): 95th percentile
   1.73 / 1.09 / 1.17 mm, and 0.32 / 0.55 / 0.80 mm outside the lips and lids
   (1.66 / 3.61 / 3.89 before). Measured on the way (the artist benchmark:
   MakeHuman, ``deformation``, median relative error 0.823 before, 0.819
   now; the fold check on the scan):
   the lips and lids untrimmed too reach 0.69 / 0.69 / 0.78 mm, but the
   scan's blink and lower-lip roll then fold beyond what the fold correction
   may change (:data:`~facegeom.methods.folds.MAX_CHANGE`: 40 and 29 %); a
   narrower band kept trimmed there (3 mm) left them folded too. Point-to-point
   untrimmed pairs bunch the lids' rims at their closest points (0.843: the
   compressed triangles amplify the gradients carried); the brows and forehead
   (above the eyes, :data:`BROW_ABOVE_EYES_CM`) keep the trimming (their
   untrimmed pairs moved the eyeLook shapes). Rejecting pairs whose normals
   differ by more than 60 degrees left the nostrils off the head (95th
   percentile 1.4-1.9 mm on the MakeHuman heads): not used.

The fit is reported as the median and 95th percentile of the template ->
head distance over the face area after each step (head units and mm).
Refused with one line: an empty mesh, NaN/inf, a mesh that is not a head --
judged on the rigid step (the non-rigid steps can bend the face onto
anything): the generic face, posed and scaled, lies farther than
:data:`NOT_A_HEAD_RIGID_MM` (median over the face area) from the mesh (a ball
of head size: 6.2-7.5 mm; the remeshed ICT identities of the tests 1.1-1.2 mm,
the MakeHuman head 0.9 mm) -- and no face area found (fewer than
:data:`MIN_COVERED` of the face area's vertices within :data:`COVER_MM` of the
head after the refinement). The identity fit's coefficients are reported
(their root mean square: 1.3 for the ICT identities, 2.6 for the MakeHuman
head, 3.7-4.7 for the balls; the prior is N(0, 1)) with a note above
:data:`IDENTITY_RMS_NOTE`: the face lies outside the identity model's people
and the non-rigid step carries the fit. (A refusal on that number alone,
tried first, refused the MakeHuman head, a real human head from another
source.) Refused too: a mesh the identity fit places beyond
:data:`NOT_A_HEAD_IDENTITY_RMS` **and** onto which the face had to be
stretched beyond :data:`NOT_A_HEAD_STRAIN` (:func:`_face_strain`, the
median over the face area's edges of the log length ratio to the generic
face, the overall scale left out). Measured: the public heads (Lee
Perry-Smith, MakeHuman, its stylised character, two Rocketbox heads)
1.6-3.7 standard deviations and 7-15 % strain; objects the rigid step let
through (the bunny, a CAD part, a chair, two objects, a plane: trimesh's
test models) 5.3-6.5 and 24-37 %. Both must say "not a head", so a
stylised character far from the people (one number) is still given a rig.

Transfer (two engines)
----------------------
Both carry the motion of the template's triangles that lie on the head
(within :data:`COVER_MM`; ``region="template"``, the default: the whole ICT
face mesh, whose neck and jaw line move with the jaw; ``region="face"``: the
face area only, as first planned: 0.13-0.17 median relative error for
``nearest`` against 0.09-0.10 with the whole template).

- ``deformation`` (Sumner & Popovic 2004, deformation transfer; the
  default): per template triangle the deformation gradient ``G`` of each
  expression (the registered template -> template + the expression's delta;
  the triangle's frame completed by its normal scaled by 1/sqrt of its
  length), carried to the head's triangles through the registration (a head
  triangle takes the gradient of the template triangle its centroid projects
  to; triangles off the region take the identity), then for all shapes at
  once the displacement ``U`` of the head minimising
  ``sum_t area_t |grad_t U - (G_t - I) grad_t X|^2`` (``igl.grad``) plus an
  anchor term holding the vertices far from the region (:data:`ANCHOR_CM`)
  and a soft pull of every vertex towards the template's own motion at its
  closest point (weight ``area / SOFT_CM^2``; ``soft_cm=None``: off; not on a scan's mouth cavity, see
  below); one
  prefactorised matrix (:func:`~facegeom.linalg.factorize_spd`), 3 x 53
  right-hand sides. The gradients give the shape of the motion on the head's
  own geometry, the soft positions where it sits: pure gradients (integrated
  from far anchors) drift over the head (median relative error 0.093-0.099
  on the test heads), the soft positions alone are ``nearest`` (0.087-0.101),
  both together 0.075-0.078 (``SOFT_CM`` 0.25-2 cm all within 0.003).
- ``nearest`` (the common shortcut, the baseline): each head vertex copies
  the delta of its closest point on the registered template (barycentric),
  zero off the region -- except a scan's mouth cavity (:func:`_mouth_interior`:
  a patch off the template whose rim lies on the template's lips), which takes
  the harmonic fill of the lips' motion. Held still, as it was, the cavity of
  the Lee Perry-Smith scan stayed put while the lips opened round it: with
  ``jawOpen`` it poked through the cheek by the left mouth corner (19 flipped
  triangles and 104 new crossings with ``deformation``, whose soft pull held it
  still too; 5 and 0 once it follows the lips; the MakeHuman head, with no cavity,
  unchanged).
- ``tangent``: the tangent-framework deformer
  (:class:`~facegeom.methods.tangent.TangentDeformer`) fitted on the head,
  driven by ``nearest``'s motion at :data:`TANGENT_MARKERS` farthest points of
  the region (and :data:`TANGENT_ANCHORS` still ones off it): median relative
  error 0.196 with 300 markers, 0.103 with 1,000 (nearest 0.101; the eyelids
  are lost between markers: eyeBlink 0.40-0.72). Kept as an option.

Measured (``tests/test_transfer.py``'s head: ICT identity 3 remeshed to 9,645
vertices, mm, turned 30 degrees; ``OPENBLAS_NUM_THREADS=1``): registration
about 10 s (rigid 1.2 s, identity 8.6 s, non-rigid 0.5 s), face-area
distance median 0.031 mm / 95 % 0.46 mm, vertex correspondence 0.89 mm median;
median relative error / cosine per shape: ``deformation`` 0.075 / 0.997
(1.5 s), ``nearest`` 0.101 / 0.995 (0.07 s). Identity 5: 0.078 against 0.087.
With 68 landmarks (identity 3): correspondence 0.56 mm, 0.056 against
0.067. A 57,807-vertex head: ``deformation`` 3.3 s for the 53 shapes.

The deltas are in the head's units and frame (the ICT deltas, cm, turned and
scaled by the registration's similarity and units).

Folds
-----
:func:`transfer_character` (and so :func:`transfer_head` and ``facegeom
transfer``) checks the skin's shapes at weight 1, alone and in the pairs real
takes drive together (:mod:`facegeom.methods.folds`: triangles flipped against
the rest pose, new self-intersections) and corrects them where they fold
(:func:`~facegeom.methods.folds.unfold`: a flipped region re-solved as the
harmonic fill of the motion around it, crossing sheets sharing their motion
over a few edges; rounds until nothing folds), reported in ``info["folds"]``.
A shape whose correction would change its motion by more than
:data:`~facegeom.methods.folds.MAX_CHANGE` (25 %) is left as transferred and
reported (``not_corrected``). Lee Perry-Smith scan, ``deformation``: 678
flipped triangles + new crossing pairs over 58 cases -> 0 (every correction
under 20 %; check 2-3 s, correction 5 s). MakeHuman head: 1,570 -> 1,365, its
lips left as transferred (jawOpen, the smiles, mouthRollUpper, mouthPucker,
mouthShrugLower would change by 28-65 %: the lips meet in one surface there, and
the artist's own rig folds them too); the artist benchmark's median relative
error 0.823 -> 0.8225.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import igl
import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from facegeom.constants import CM_TO_MM, FACE_AREA
from facegeom.errors import InputError
from facegeom.linalg import factorize_spd
from facegeom.methods.identity import IdentityFitter
from facegeom.model import BlendshapeRig, MeshTarget, PointCloudTarget
from facegeom.native import quiet_native
from facegeom.registration import align_on_surface, kabsch, rms_radius, trim_outliers, units_factor

__all__ = ["ENGINES", "REGIONS", "REGISTRATION_KEYS", "Character", "HeadRegistration", "TransferResult",
           "character_arrays", "fold_lines", "stored_character", "register_character",
           "register_head", "transfer_character", "transfer_expressions", "transfer_head", "read_head_landmarks"]

ENGINES = ("deformation", "nearest", "tangent")
REGIONS = ("template", "face")  # the template triangles whose motion is carried (see "Transfer")
UNITS = {"mm": 0.1, "cm": 1.0, "m": 100.0}  # head units -> cm (the model's units)
HEAD_SAMPLES = 30000  # points sampled on the head's surface for the rigid and identity steps
START_SCALES = (1.0, 0.8, 1.25)  # the rigid search's template sizes (the similarity ICP refines the best)
RIGID_RETRY_MM = 3.0  # the next size is tried while the best pose's median distance (model mm) is above this
SIMILARITY_ROUNDS = 20  # trimmed similarity ICP rounds at most (the scale)
SIZE_RANGE = 1.15  # scales within [1/SIZE_RANGE, SIZE_RANGE] of the generic face are left to the identity modes
NONRIGID_LENGTHS_CM = (2.0, 1.0, 0.5, 0.25, 0.12)  # non-rigid ICP: smoothing length per round (model cm)
NONRIGID_FINAL_LENGTHS_CM = (0.12, 0.12)  # then these rounds untrimmed, point-to-plane (see "Non-rigid refinement")
NONRIGID_POINT_WEIGHT = 0.1  # the final rounds: point-to-point weight beside the point-to-plane term
EYE_BAND_CM = 1.0  # the eyelids: within this of the template's eye openings (along edges)
BROW_ABOVE_EYES_CM = 0.5  # the face area this far above the eye openings' centres (outside the lids): kept trimmed
NOT_A_HEAD_RIGID_MM = 4.0  # the posed generic face's median face-area distance above this: not a head
NOT_A_HEAD_MM = 5.0  # the identity fit's median face-area distance above this: not a head
IDENTITY_RMS_NOTE = 2.5  # the identity fit's coefficients (~ N(0, 1) for people) above this rms: a note
NOT_A_HEAD_IDENTITY_RMS = 4.5  # with NOT_A_HEAD_STRAIN: not a head (see "Refused"; heads 1.6-3.7, non-heads 5.3-6.5)
NOT_A_HEAD_STRAIN = 0.2  # the registered face's median edge strain above this, with the rms above: not a head
COVER_MM = 5.0  # a face-area vertex / head triangle within this of the other surface is on the face
MIN_COVERED = 0.5  # at least this fraction of the face area must lie on the head
ANCHOR_CM = 3.0  # deformation transfer: head vertices farther than this from the region's triangles are held
TANGENT_MARKERS = 1000  # engine "tangent": markers on the face region (farthest points), their motion the template's
TANGENT_ANCHORS = 60  # engine "tangent": markers held still off the region (farthest points)
MOUTH_BAND_CM = 1.0  # the template's lips: within this of its mouth opening (along edges)
SOFT_CM = 1.0  # deformation transfer: the template's own motion as soft positions, weight area / SOFT_CM^2
IDENTITY_STRIDE = 3  # the identity fit's data term: every third template vertex (as the fitter's own clouds)
BAND_CM = 1.0  # head points whose closest template vertex is within this of the template's outline are dropped
CROP_CM = 3.0  # head points farther than this from the rigidly posed template are dropped from the identity fit


@dataclass
class HeadRegistration:
    """The ICT template registered onto a head mesh (what :func:`register_head` returns).

    Attributes
    ----------
    head_vertices : (n, 3) float64
        The head's vertices as given (its units and frame).
    head_faces : (m, 3) int64
        The head's triangles.
    template : (N, 3) float64
        The fitted ICT template (the model's topology, ``N`` = 9,409) in the
        head's frame and units: identity fit, then the non-rigid refinement.
    scale : float
        The similarity's scale from the model's frame (cm) to the head's
        units: ``head ~ scale * R x + t`` (includes the units).
    R : (3, 3) float64
    t : (3,) float64
    units : float
        Head units -> cm (``units_factor`` or the units given).
    mm_per_unit : float
        Millimetres per head unit.
    identity : (I,) float64
        The identity coefficients fitted.
    report : dict
        Per step (``units``, ``rigid``, ``identity``, ``nonrigid``) what was
        found and the template -> head distances over the face area
        (``median`` / ``p95`` in head units, ``median_mm`` / ``p95_mm``), the
        times (``time_s``).
    """

    head_vertices: np.ndarray
    head_faces: np.ndarray
    template: np.ndarray
    scale: float
    R: np.ndarray
    t: np.ndarray
    units: float
    mm_per_unit: float
    identity: np.ndarray
    report: dict = field(default_factory=dict)

    def delta_in_head(self, deltas) -> np.ndarray:
        """Model-frame deltas ``(..., 3)`` (cm) -> the head's frame and units (turned and scaled)."""
        return self.scale * (np.asarray(deltas, dtype=np.float64) @ self.R.T)


@dataclass
class TransferResult:
    """Deltas transferred onto a head (what :func:`transfer_expressions` returns).

    Attributes
    ----------
    deltas : (K, n, 3) float64
        Per expression the displacement of every head vertex, head units.
    names : tuple of K str
        The expressions' names (ICT / ARKit).
    engine : str
    time_s : float
    info : dict
        ``on_face`` (head vertices or triangles that took the face's motion), ``anchored`` (vertices).
    """

    deltas: np.ndarray
    names: tuple
    engine: str
    time_s: float
    info: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- helpers
def _check_mesh(V, F, path):
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 3:
        raise InputError(f"the head mesh has no vertices to register (shape {V.shape})", path)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0:
        raise InputError(f"the head mesh has no triangles (shape {F.shape})", path)
    if not np.isfinite(V).all():
        raise InputError("the head mesh has NaN or inf coordinates", path)
    if not np.issubdtype(F.dtype, np.integer) or F.min() < 0 or F.max() >= V.shape[0]:
        raise InputError("the head mesh's triangles index past its vertices", path)
    F = np.ascontiguousarray(F, dtype=np.int64)
    area = 0.5 * igl.doublearea(V, F)
    if not (area > 0).any():
        raise InputError("the head mesh has no triangle of positive area", path)
    return V, F


def sample_surface(V, F, count: int, seed: int = 0) -> np.ndarray:
    """``count`` points uniformly distributed over the area of the mesh ``(V (n,3), F (m,3))`` -> ``(count, 3)``."""
    rng = np.random.default_rng(seed)
    a = igl.doublearea(V, F)
    tri = rng.choice(F.shape[0], size=count, p=a / a.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    b = np.c_[1.0 - s, s * (1.0 - r2), s * r2]
    return np.einsum("ij,ijk->ik", b, V[F[tri]])


def _similarity(P, Q, weights=None):
    """Umeyama: ``s, R, t`` minimising ``sum w ||s R P + t - Q||^2``."""
    w = np.ones(len(P)) if weights is None else weights
    w = w / w.sum()
    mp, mq = w @ P, w @ Q
    Pc, Qc = P - mp, Q - mq
    R, _ = kabsch(Pc, Qc, w)
    s = float((w * ((Pc @ R.T) * Qc).sum(axis=1)).sum() / max((w * (Pc * Pc).sum(axis=1)).sum(), 1e-300))
    return s, R, mq - s * R @ mp


def _similarity_icp(X, tree, points, s, R, t, rounds=SIMILARITY_ROUNDS, landmarks=None):
    """Trimmed template -> points similarity ICP from ``s, R, t``; optional ``(template ids, positions)`` pairs."""
    for _ in range(rounds):
        Y = s * X @ R.T + t
        d, j = tree.query(Y)
        ok = trim_outliers(d)
        P, Q = X[ok], points[j[ok]]
        wts = np.ones(len(P))
        if landmarks is not None:  # the landmarks weigh as much as the surface pairs
            P = np.r_[P, landmarks[0]]
            Q = np.r_[Q, landmarks[1]]
            wts = np.r_[wts, np.full(len(landmarks[0]), len(wts) / len(landmarks[0]))]
        s1, R1, t1 = _similarity(P, Q, wts)
        step = abs(s1 - s) / s + float(np.abs(R1 - R).max())
        s, R, t = s1, R1, t1
        if step < 1e-6:
            break
    return s, R, t


class _Surface:
    """A triangle mesh ``(V, F)`` and its bounding-box tree, built once for every distance query on it.

    ``igl.point_mesh_squared_distance`` builds the tree anew each call: on a 76,000-vertex head that was
    0.22 s of its 0.27 s, paid by every round of the registration on the same head.
    """

    def __init__(self, V, F):
        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self._tree = None

    def distances(self, points):
        """:func:`_distances` of ``points`` to this surface."""
        if self._tree is None:
            with quiet_native():
                self._tree = igl.AABB()
                self._tree.init(self.V, self.F)
        with quiet_native():
            d2, tri, C = self._tree.squared_distance(self.V, self.F,
                                                     np.ascontiguousarray(points, dtype=np.float64))
        return np.sqrt(np.maximum(d2, 0.0)), tri, C


def _distances(points, V, F):
    """Distance of each point to the surface ``(V, F)`` -> ``(d (p,), closest triangle (p,), closest point (p, 3))``."""
    with quiet_native():
        d2, tri, C = igl.point_mesh_squared_distance(np.ascontiguousarray(points, dtype=np.float64), V, F)
    return np.sqrt(np.maximum(d2, 0.0)), tri, C


def _stats(d, mm_per_unit):
    med, p95 = float(np.median(d)), float(np.percentile(d, 95))
    return {"median": med, "p95": p95, "median_mm": med * mm_per_unit, "p95_mm": p95 * mm_per_unit}


def read_head_landmarks(path, n_vertices: int) -> np.ndarray:
    """A ``landmark,vertex_id`` CSV (iBUG 0-67 -> head vertex id) -> ``(68,)`` int64, -1 where not given.

    Raises
    ------
    InputError
        No ``landmark`` column, a landmark not an integer in ``[0, 68)`` or
        repeated, a vertex id out of range, fewer than 4 landmarks. The
        message names the file.
    """
    from facegeom.io.vertex_csv import read_vertex_csv

    csv = read_vertex_csv(path, n_vertices)
    header = [h.lower() for h in csv.header]
    if "landmark" not in header:
        raise InputError("a landmark file needs the header landmark,vertex_id", path)
    col = header.index("landmark")
    out = np.full(68, -1, dtype=np.int64)
    for row, line, vid in zip(csv.rows, csv.lines, csv.ids):
        try:
            k = int(row[col])
        except ValueError:
            raise InputError(f"line {line}: landmark {row[col]!r} is not an integer", path) from None
        if not 0 <= k < 68:
            raise InputError(f"line {line}: landmark {k} is out of range [0, 68)", path)
        if out[k] >= 0:
            raise InputError(f"line {line}: landmark {k} is repeated", path)
        out[k] = vid
    if np.count_nonzero(out >= 0) < 4:
        raise InputError("at least 4 landmarks are needed", path)
    return out


# ---------------------------------------------------------------------------------------------- registration
_BANDS: dict = {}


def _template_band(model) -> np.ndarray:
    """The template's vertices within ``BAND_CM`` (along edges) of its outer edge (the longest boundary loop).

    Head points whose closest template vertex is in this band lie past the
    template's outline (scalp, back of the head, neck): left out of the
    identity fit, whose scan -> face pairs would otherwise pull the outline
    outwards (see "Head scans" in :mod:`facegeom.methods.identity`). The eye
    and mouth openings are kept: their points tell where the eyes and lips are.
    """
    key = id(model)
    if key not in _BANDS:
        from scipy.sparse.csgraph import dijkstra

        V = np.asarray(model.neutral, dtype=np.float64)
        T = np.asarray(model.triangles, dtype=np.int64)
        loops = igl.boundary_loop_all(T)
        outer = np.asarray(max(loops, key=len), dtype=np.int64)
        E = np.r_[T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]
        w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
        graph = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(len(V), len(V))).tocsr()
        d = dijkstra(graph, directed=False, indices=outer, min_only=True, limit=BAND_CM)
        _BANDS.clear()
        _BANDS[key] = np.isfinite(d)
    return _BANDS[key]


_OPENINGS: dict = {}


def _opening_bands(model) -> np.ndarray:
    """The template's vertices near each of its openings -> ``(3, N)`` bool: within ``MOUTH_BAND_CM`` (along
    edges) of the mouth opening (the boundary loop nearest the inner-lip landmarks 60-67) and within
    ``EYE_BAND_CM`` of each eye opening (nearest the eye landmarks 36-41, 42-47): the lips and the lids."""
    key = id(model)
    if key not in _OPENINGS:
        from scipy.sparse.csgraph import dijkstra

        V = np.asarray(model.neutral, dtype=np.float64)
        T = np.asarray(model.triangles, dtype=np.int64)
        lm = np.asarray(model.landmarks)
        loops = [np.asarray(loop, dtype=np.int64) for loop in igl.boundary_loop_all(T)]
        E = np.r_[T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]
        w = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
        graph = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(len(V), len(V))).tocsr()
        bands = np.zeros((3, len(V)), dtype=bool)
        for row, (ids, limit) in enumerate(((slice(60, 68), MOUTH_BAND_CM), (slice(36, 42), EYE_BAND_CM),
                                            (slice(42, 48), EYE_BAND_CM))):
            if not loops or lm.size < ids.stop:
                continue
            centre = V[lm[ids]].mean(axis=0)
            loop = min(loops, key=lambda loop: float(np.linalg.norm(V[loop].mean(axis=0) - centre)))
            bands[row] = np.isfinite(dijkstra(graph, directed=False, indices=loop, min_only=True, limit=limit))
        _OPENINGS.clear()
        _OPENINGS[key] = bands
    return _OPENINGS[key]


def _mouth_band(model) -> np.ndarray:
    """The template's lips: its vertices within ``MOUTH_BAND_CM`` (along edges) of its mouth opening."""
    return _opening_bands(model)[0]


def _mouth_interior(model, reg: HeadRegistration, region) -> np.ndarray:
    """The head's vertices off the template (farther than ``COVER_MM``) that lie inside its mouth: a connected
    patch of such vertices whose rim (the on-template vertices beside it) lies mostly on the template's lips
    (within ``MOUTH_BAND_CM`` of its mouth opening) -> ``(n,)`` bool.

    A scan's mouth (a slit, a cavity, a throat) has no template under it; it moves with the lips around it,
    where the rest of the head off the template (scalp, neck, eye sockets) stays still.
    """
    from scipy.sparse.csgraph import connected_components

    V, F = reg.head_vertices, reg.head_faces
    T = np.asarray(model.triangles, dtype=np.int64)
    n = V.shape[0]
    tri, _, on = _on_face(reg, model, V, region)
    lip = _mouth_band(model)[T[tri]].any(axis=1) & on
    E = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    off = ~on
    keep = off[E[:, 0]] & off[E[:, 1]]
    graph = sp.coo_matrix((np.ones(int(keep.sum())), (E[keep, 0], E[keep, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    rim = E[off[E[:, 0]] & on[E[:, 1]]]  # (off vertex, on vertex) edges, both directions below
    rim = np.r_[rim, E[off[E[:, 1]] & on[E[:, 0]]][:, ::-1]]
    comp = label[rim[:, 0]]
    total = np.bincount(comp, minlength=label.max() + 1)
    lips = np.bincount(comp, weights=lip[rim[:, 1]].astype(np.float64), minlength=label.max() + 1)
    mouth = (total > 0) & (lips > 0.5 * np.maximum(total, 1))
    return off & mouth[label]


def _harmonic_fill(F, region, D):
    """Deltas ``D (K, n, 3)`` with their values on ``region`` (bool, n) replaced by the harmonic interpolation
    (uniform graph Laplacian of the triangles ``F``) of the values around it."""
    n = D.shape[1]
    E = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    K = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()  # positive semi-definite
    inner, outer = np.flatnonzero(region), np.flatnonzero(~region)
    K_ii = K[inner][:, inner] + sp.eye(inner.size) * 1e-12
    k = D.shape[0]
    rhs = -(K[inner][:, outer] @ D[:, outer].transpose(1, 0, 2).reshape(outer.size, 3 * k))
    out = D.copy()
    out[:, inner] = factorize_spd(K_ii.tocsc()).solve(rhs).reshape(inner.size, k, 3).transpose(1, 0, 2)
    return out


_FREE: dict = {}


def _face_strain(model, X) -> float:
    """How far the registered template ``X (N, 3)`` is stretched from the generic face: the median over the face
    area's edges of ``|log(l / l0) - m|`` (``l0`` the generic face's edge length, ``m`` the median log ratio:
    the overall scale left out)."""
    T = np.asarray(model.triangles, dtype=np.int64)
    T = T[(T < min(FACE_AREA, len(X))).all(axis=1)]
    E = np.unique(np.sort(np.r_[T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]], axis=1), axis=0)
    V0 = np.asarray(model.neutral, dtype=np.float64)
    l0 = np.linalg.norm(V0[E[:, 0]] - V0[E[:, 1]], axis=1)
    l1 = np.linalg.norm(X[E[:, 0]] - X[E[:, 1]], axis=1)
    ok = (l0 > 0) & (l1 > 0)
    r = np.log(l1[ok] / l0[ok])
    return float(np.median(np.abs(r - np.median(r)))) if r.size else float("inf")


def _untrimmed_region(model) -> np.ndarray:
    """The template vertices whose pairs the final non-rigid rounds keep untrimmed -> ``(N,)`` bool: the face
    area below the eyes' level (``BROW_ABOVE_EYES_CM`` over the eye openings' centres: forehead and brows
    keep the trimming) but the lips and the lids (:func:`_opening_bands`), which keep it too (see
    :data:`NONRIGID_FINAL_LENGTHS_CM`)."""
    key = id(model)
    if key not in _FREE:
        V = np.asarray(model.neutral, dtype=np.float64)
        lm = np.asarray(model.landmarks)
        bands = _opening_bands(model)
        free = (np.arange(len(V)) < min(FACE_AREA, len(V))) & ~bands.any(axis=0)
        if lm.size >= 48 and bands[1:].any():
            top = V[bands[1] | bands[2], 1].mean() + BROW_ABOVE_EYES_CM  # the model's frame: Y up
            free &= V[:, 1] <= top
        _FREE.clear()
        _FREE[key] = free
    return _FREE[key]


def _on_open_edge(VH, FH, tri, C, tol):
    """Closest points ``C (p,3)`` (on the head triangles ``tri``) that lie on an open edge of the head ``(VH, FH)``
    (within ``tol`` of an edge used by one triangle) -> ``(p,)`` bool: the rim of a hole or of the mesh."""
    out = np.zeros(len(C), dtype=bool)
    rim = igl.boundary_facets(FH)
    rim = np.asarray(rim[0] if isinstance(rim, tuple) else rim, dtype=np.int64).reshape(-1, 2)
    if len(rim) == 0:
        return out
    m = VH.shape[0] + 1  # an undirected edge's id: min * m + max
    open_edges = np.unique(rim.min(axis=1) * m + rim.max(axis=1))
    for k in range(3):  # the triangle's edge k -> k + 1
        a, b = FH[tri, k], FH[tri, (k + 1) % 3]
        on = np.isin(np.minimum(a, b) * m + np.maximum(a, b), open_edges)
        if not on.any():
            continue
        A, B, P = VH[a[on]], VH[b[on]], C[on]
        ab = B - A
        u = np.clip(((P - A) * ab).sum(axis=1) / np.maximum((ab * ab).sum(axis=1), 1e-300), 0.0, 1.0)
        out[on] |= np.linalg.norm(A + u[:, None] * ab - P, axis=1) <= tol
    return out


def _nonrigid(Y, T, VH, FH, face, lengths, mm_per_y, final_lengths=(), free=None, surface=None):
    """Non-rigid ICP of the template ``Y (N,3)`` (triangles ``T``) onto the head ``(VH, FH)`` (same frame).

    Data: face-area vertices ``face`` pulled to their closest head points,
    weighted by their Voronoi area, outliers trimmed; smoothness: the
    membrane energy of the displacement, ``l^2 U' K U`` (``K`` the negated
    cotangent Laplacian of the template, ``l`` the round's length), over
    every template vertex.

    Then the rounds of ``final_lengths`` (see :data:`NONRIGID_FINAL_LENGTHS_CM`):
    the pairs of the vertices ``free`` (bool, N) kept untrimmed, but those
    farther than ``4 COVER_MM`` and those whose closest point lies on an open
    edge of the head (a hole's rim: the template over a hole is left to the
    membrane, not drawn to the rim); the data term point-to-plane (the head's
    normal at the closest point) plus ``NONRIGID_POINT_WEIGHT`` times
    point-to-point, one ``3N x 3N`` SPD solve per round. ``surface``: the head's :class:`_Surface` (built
    here when not given).
    """
    surface = surface or _Surface(VH, FH)
    n = Y.shape[0]
    K = -igl.cotmatrix(Y, T)
    M = igl.massmatrix(Y, T, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    eps = 1e-8 * float(M.mean())
    X = Y.copy()
    for ell in lengths:
        d, _, C = surface.distances(X[face])
        keep = trim_outliers(d) & (d * mm_per_y <= 4 * COVER_MM)
        w = np.zeros(n)
        w[face[keep]] = M[face[keep]]
        target = np.zeros((n, 3))
        target[face[keep]] = C[keep] - Y[face[keep]]  # the displacement from the identity fit that reaches the head
        A = sp.diags(w + eps) + (ell * ell) * K
        U = factorize_spd(A).solve(w[:, None] * target)
        X = Y + U
    if not final_lengths:
        return X
    free = np.ones(n, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    tol = 1e-6 * float(np.linalg.norm(VH.max(axis=0) - VH.min(axis=0)))
    NH = igl.per_face_normals(VH, FH, np.array([0.0, 0.0, 1.0]))
    K3 = sp.kron(K, sp.eye(3)).tocsr()
    idx = 3 * np.arange(n)[:, None] + np.arange(3)[None, :]  # (n, 3) unknowns of each vertex
    rows, cols = np.repeat(idx, 3, axis=1).ravel(), np.tile(idx, (1, 3)).ravel()
    for ell in final_lengths:
        d, tri, C = surface.distances(X[face])
        keep = (d * mm_per_y <= 4 * COVER_MM) & (trim_outliers(d) | free[face]) & ~_on_open_edge(VH, FH, tri, C, tol)
        w = np.zeros(n)
        w[face[keep]] = M[face[keep]]
        nrm = np.zeros((n, 3))
        nrm[face] = NH[tri]
        target = np.zeros((n, 3))
        target[face[keep]] = C[keep] - Y[face[keep]]
        # per vertex w [(n . (u - t))^2 + a |u - t|^2]: the 3 x 3 block w (n n' + a I)
        B = w[:, None, None] * (nrm[:, :, None] * nrm[:, None, :] + NONRIGID_POINT_WEIGHT * np.eye(3)) \
            + eps * np.eye(3)
        A = sp.csr_matrix((B.ravel(), (rows, cols)), shape=(3 * n, 3 * n)) + (ell * ell) * K3
        U = factorize_spd(A.tocsc()).solve(np.einsum("nij,nj->ni", B, target).reshape(-1, 1)).reshape(n, 3)
        X = Y + U
    return X


def register_head(model, V, F, *, landmarks=None, units="auto", path=None, samples: int = HEAD_SAMPLES,
                  fitter_params=None, progress=None) -> HeadRegistration:
    """Register the ICT face onto the head mesh ``(V (n,3), F (m,3))`` in any units and orientation.

    Parameters
    ----------
    model : FaceModel
        The ICT face model (cm).
    V, F : arrays
        The head's vertices (its units) and triangles.
    landmarks : (68,) int array or None
        Head vertex id per iBUG landmark, -1 where unknown
        (:func:`read_head_landmarks`); used in the rigid and identity steps.
    units : "auto", "mm", "cm" or "m"
        The head's units (auto: the power of ten that makes it face-sized).
    path : str or PathLike, optional
        The head's file: named in the errors.
    samples : int
        Points sampled on the head's surface for the rigid and identity steps.
    fitter_params : dict, optional
        Extra :class:`~facegeom.methods.identity.IdentityFitter` parameters.
    progress : callable(str), optional
        Called with one line per step.

    Returns
    -------
    HeadRegistration

    Raises
    ------
    InputError
        An empty mesh, NaN/inf, unknown units, landmarks of another mesh, a
        mesh that is not a head, no face area found on it.
    """
    from facegeom.methods import registration_cache as cache

    V, F = _check_mesh(V, F, path)
    key = cache.registration_key(model, V, F, landmarks, units, samples, fitter_params) if cache.enabled() else None
    kept = cache.load(key) if key else None
    if kept is not None:  # the same head, options, face data and code registered before: the same result
        arrays, report, lines, when = kept
        for line in [f"registration: reused from the cache (the same head and options, registered {when})"] + lines:
            (progress or (lambda line: None))(line)
        scale, su, mm_per_unit = (float(x) for x in arrays["scalars"])
        return HeadRegistration(V, F, arrays["template"], scale, arrays["R"], arrays["t"], su, mm_per_unit,
                                arrays["identity"], report)
    lines: list[str] = []

    def say(line: str) -> None:
        lines.append(line)
        if progress is not None:
            progress(line)

    reg = _register_head(model, V, F, landmarks, units, path, samples, fitter_params, say)
    if key:
        cache.store(key, reg, lines)
    return reg


def _register_head(model, V, F, landmarks, units, path, samples, fitter_params, say) -> HeadRegistration:
    """:func:`register_head` of a checked mesh, computed."""
    report: dict = {}
    t_all = time.perf_counter()
    N = model.n_vertices
    face = np.arange(min(FACE_AREA, N))
    T = np.asarray(model.triangles, dtype=np.int64)
    # 1. units
    if units == "auto":
        su = units_factor(V, model.neutral)
    elif units in UNITS:
        su = UNITS[units]
    else:
        raise InputError(f"units must be auto, mm, cm or m, got {units!r}")
    mm_per_unit = CM_TO_MM * su
    names = {0.1: "mm", 1.0: "cm", 100.0: "m"}
    report["units"] = {"to_cm": su, "name": names.get(su, f"x{su:g} cm"), "given": units != "auto"}
    say(f"units: {report['units']['name']} ({'given' if units != 'auto' else 'found'}; x{su:g} to cm)")
    Xc = V * su  # the head in cm
    P = sample_surface(Xc, F, samples)
    lm = None
    if landmarks is not None:
        lm_ids = np.asarray(landmarks, dtype=np.int64)
        if lm_ids.shape != (68,) or lm_ids.max() >= V.shape[0]:
            raise InputError("the landmarks must be 68 head vertex ids (-1 where unknown)", path)
        known = np.flatnonzero(lm_ids >= 0)
        lm = (known, Xc[lm_ids[known]])  # iBUG index, head position (cm)
    # 2. rigid + scale
    t0 = time.perf_counter()
    G = np.asarray(model.neutral, dtype=np.float64)
    tree = cKDTree(P)
    if lm is not None:
        s, R, t = _similarity(G[model.landmarks[lm[0]]], lm[1])
        lm_pairs = (G[model.landmarks[lm[0]]], lm[1])
        s, R, t = _similarity_icp(G[face][::2], tree, P, s, R, t, landmarks=lm_pairs)
    else:  # the global search at a few sizes (it poses a rigid face: a head 1.3x the face misled it: 6.5 mm
        # median after the similarity ICP, against 1.1-1.2 mm for faces of ordinary size), best kept
        lm_pairs = None
        best = None
        for s0 in START_SCALES:
            if best is not None and best[0] * CM_TO_MM <= RIGID_RETRY_MM:
                break  # the face's size was near enough: no other size tried
            found = align_on_surface(s0 * G[face], P)
            s1, R1, t1 = _similarity_icp(G[face][::2], tree, P, s0, found.R, found.t)
            d, _ = tree.query(s1 * G[face][::4] @ R1.T + t1)
            score = float(np.median(d)) / s1
            if best is None or score < best[0]:
                best = (score, s1, R1, t1)
        _, s, R, t = best
    if not (np.isfinite(s) and s > 0):
        raise InputError("the rigid registration failed (no scale found): is it a head mesh?", path)
    s_pre = s / min(max(s, 1.0 / SIZE_RANGE), SIZE_RANGE)  # the scale the identity modes cannot explain
    d, _, _ = _distances(s * G[face] @ R.T + t, Xc, F)
    report["rigid"] = {"scale": s, "similarity_scale": s_pre, "time_s": time.perf_counter() - t0,
                       **_stats(d / su, mm_per_unit)}
    say(f"rigid fit: scale {s:.3f} of the generic face; face-area distance median "
        f"{report['rigid']['median_mm']:.2f} mm, 95% {report['rigid']['p95_mm']:.2f} mm "
        f"({report['rigid']['time_s']:.1f} s)")
    if not report["rigid"]["median_mm"] <= NOT_A_HEAD_RIGID_MM:
        raise InputError(f"not a head: the face model, posed and scaled, lies {report['rigid']['median_mm']:.1f} mm "
                         f"(median) from the mesh (a head: about 1 mm; at most {NOT_A_HEAD_RIGID_MM:g})", path)
    # 3. identity, in the model frame (the points brought there by the similarity's inverse, scale s_pre), on
    # the whole template (every third vertex), from the head's points over the template but off its open edges
    t0 = time.perf_counter()
    to_model = lambda X: ((X - t) @ R) / s_pre  # noqa: E731 - the head (cm) -> the pre-scaled model frame
    Pm = to_model(P)
    d_t, v_t = cKDTree(G * (s / s_pre)).query(Pm)
    band = _template_band(model)
    Pm = Pm[(~band[v_t]) & (d_t <= CROP_CM)]
    if Pm.shape[0] < 100:
        raise InputError("no face found on the mesh: too few of its points lie near the face model after the rigid "
                         "fit", path)
    targets = [PointCloudTarget(Pm)]
    if lm is not None:
        wts = np.zeros(N)
        pos = np.zeros((N, 3))
        ids = model.landmarks[lm[0]]
        wts[ids] = 1.0
        pos[ids] = to_model(lm[1])
        pos[wts == 0] = G[wts == 0]
        targets.append(MeshTarget(pos, wts))
    params = {"expressions": False, "region": np.arange(0, N, IDENTITY_STRIDE), **(fitter_params or {})}
    fit = IdentityFitter(**params).fit(model, targets, progress=say)
    Rf, tf = fit.rotations[0], fit.translations[0]
    Y = fit.vertices(0)  # the identity's neutral, model frame
    # head ~ s_pre R (Rf y + tf) + t  (cm)  -> head units: / su
    Rt = R @ Rf
    scale_cm = s_pre
    tt = s_pre * R @ tf + t
    H_y = ((Xc - tt) @ Rt) / scale_cm  # the head in the fitted face's frame (model cm, pre-scaled)
    mm_per_y = CM_TO_MM * scale_cm
    head_y = _Surface(H_y, F)  # every later distance is to the head in this frame: one tree
    d, _, _ = head_y.distances(Y[face])
    report["identity"] = {"rms_mm": float(np.asarray(fit.info["rms"]).ravel()[0]), "rounds": fit.info["rounds"],
                          "time_s": time.perf_counter() - t0, **_stats(d * scale_cm / su, mm_per_unit)}
    say(f"identity fit: face-area distance median {report['identity']['median_mm']:.2f} mm, 95% "
        f"{report['identity']['p95_mm']:.2f} mm ({report['identity']['time_s']:.1f} s)")
    id_rms = float(np.sqrt(np.mean(np.asarray(fit.identity, dtype=np.float64) ** 2)))
    report["identity"]["coefficient_rms"] = id_rms
    if not report["identity"]["median_mm"] <= NOT_A_HEAD_MM:
        raise InputError(f"not a head: the face model's surface lies {report['identity']['median_mm']:.1f} mm "
                         f"(median) from the mesh after the fit (a head: about 0.3 mm; at most {NOT_A_HEAD_MM:g})",
                         path)
    if not id_rms <= IDENTITY_RMS_NOTE:
        say(f"note: the face lies outside the identity model's people (coefficients {id_rms:.1f} standard "
            f"deviations on average, people about 1.3): the non-rigid step carries the rest of the fit")
    # 4. non-rigid refinement: every template vertex pulled to the head (trimmed), a membrane term between
    t0 = time.perf_counter()
    X = _nonrigid(Y, T, H_y, F, np.arange(N), tuple(ell / scale_cm for ell in NONRIGID_LENGTHS_CM), mm_per_y,
                  tuple(ell / scale_cm for ell in NONRIGID_FINAL_LENGTHS_CM), _untrimmed_region(model), head_y)
    d, _, _ = head_y.distances(X[face])
    covered = float(np.mean(d * mm_per_y <= COVER_MM))
    report["nonrigid"] = {"time_s": time.perf_counter() - t0, "covered": covered,
                          **_stats(d * scale_cm / su, mm_per_unit)}
    say(f"non-rigid fit: face-area distance median {report['nonrigid']['median_mm']:.3f} mm, 95% "
        f"{report['nonrigid']['p95_mm']:.3f} mm, {100 * covered:.0f}% of the face on the mesh "
        f"({report['nonrigid']['time_s']:.1f} s)")
    if covered < MIN_COVERED or not np.isfinite(X).all():
        raise InputError(f"no face area found: only {100 * covered:.0f}% of the face model lies within "
                         f"{COVER_MM:g} mm of the mesh", path)
    strain = _face_strain(model, X)
    report["nonrigid"]["strain"] = strain
    if id_rms > NOT_A_HEAD_IDENTITY_RMS and strain > NOT_A_HEAD_STRAIN:
        raise InputError(f"not a head: the face model fits it only {id_rms:.1f} standard deviations from the people "
                         f"it was built from (heads: 1.6-3.7) and stretched by {100 * strain:.0f}% (median over its "
                         f"edges; heads: 7-15%); at most {NOT_A_HEAD_IDENTITY_RMS:g} and {100 * NOT_A_HEAD_STRAIN:.0f}%",
                         path)
    report["time_s"] = time.perf_counter() - t_all
    scale = scale_cm / su
    return HeadRegistration(V, F, (X @ Rt.T * scale_cm + tt) / su, scale, Rt, tt / su, su, mm_per_unit,
                            fit.identity, report)


# ---------------------------------------------------------------------------------------------- transfer
def _frames(A, B, C):
    """Per triangle ``[e1 e2 n]`` (columns; ``n`` the normal scaled by 1/sqrt of its length, Sumner's 4th vertex)."""
    e1, e2 = B - A, C - A
    n = np.cross(e1, e2)
    n = n / np.sqrt(np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300))
    return np.stack([e1, e2, n], axis=-1)


def _face_triangles(model):
    T = np.asarray(model.triangles, dtype=np.int64)
    return (T < FACE_AREA).all(axis=1)


def _on_face(reg: HeadRegistration, model, points, region="face"):
    """Closest template triangle of each point and whether it lies on the region within ``COVER_MM``.

    ``region``: ``"face"`` (the face area) or ``"template"`` (every template triangle).
    """
    T = np.asarray(model.triangles, dtype=np.int64)
    d, tri, C = _distances(points, reg.template, T)
    on = d * reg.mm_per_unit <= COVER_MM
    if region == "face":
        on &= _face_triangles(model)[tri]
    return tri, C, on


def transfer_expressions(model, reg: HeadRegistration, engine: str = "deformation", region: str = "template",
                         soft_cm: float | None = SOFT_CM) -> TransferResult:
    """Every expression of ``model`` carried onto the head of ``reg`` -> :class:`TransferResult`.

    Parameters
    ----------
    model : FaceModel
        The model registered (its expression deltas, cm).
    reg : HeadRegistration
        From :func:`register_head`.
    engine : "deformation", "nearest" or "tangent"
        See the module docstring.
    region : "template" or "face"
        The template triangles whose motion is carried: every one that lies
        on the head (within ``COVER_MM``), or the face area's only.
    soft_cm : float or None
        ``deformation``: the soft pull towards the template's own motion,
        weight ``area / soft_cm^2`` (``soft_cm`` in model cm); None: pure
        gradients anchored far from the region.

    Returns
    -------
    TransferResult
        Deltas ``(K, n, 3)`` in the head's units and frame.

    Raises
    ------
    InputError
        An unknown engine or region, a soft_cm that is not a positive number.
    """
    if engine not in ENGINES:
        raise InputError(f"unknown transfer engine {engine!r}; use one of {', '.join(ENGINES)}")
    if region not in REGIONS:
        raise InputError(f"unknown region {region!r}; use one of {', '.join(REGIONS)}")
    if soft_cm is not None and not (isinstance(soft_cm, (int, float)) and np.isfinite(soft_cm) and soft_cm > 0):
        raise InputError(f"soft_cm must be a positive number or None, got {soft_cm!r}")
    t0 = time.perf_counter()
    Dm = np.asarray(model.expression_deltas, dtype=np.float64)
    Dh = reg.delta_in_head(Dm)  # (K, N, 3) head units and frame
    V, F = reg.head_vertices, reg.head_faces
    T = np.asarray(model.triangles, dtype=np.int64)
    if engine == "nearest":
        tri, C, on = _on_face(reg, model, V, region)
        S = reg.template
        with quiet_native():
            b = igl.barycentric_coordinates(C, S[T[tri, 0]], S[T[tri, 1]], S[T[tri, 2]])
        b = np.where(np.isfinite(b), b, 1.0 / 3.0)
        out = np.einsum("vj,kvjc->kvc", b, Dh[:, T[tri]]) * on[None, :, None]
        mouth = _mouth_interior(model, reg, region)
        if mouth.any():  # the scan's mouth off the template: the lips' motion carried in (harmonic), not still
            out = _harmonic_fill(F, mouth, out)
        return TransferResult(out, tuple(model.expression_names), engine, time.perf_counter() - t0,
                              {"on_face": int(on.sum()), "mouth_interior": int(mouth.sum())})
    if engine == "tangent":
        return _tangent(model, reg, region, t0)
    # deformation transfer
    cent = V[F].mean(axis=1)
    tri, _, on = _on_face(reg, model, cent, region)
    S = reg.template
    used = np.unique(tri[on])
    A0 = _frames(S[T[used, 0]], S[T[used, 1]], S[T[used, 2]])  # (u, 3, 3)
    inv = np.linalg.inv(A0)
    Sd = S[None] + Dh  # (K, N, 3)
    A1 = _frames(Sd[:, T[used, 0]], Sd[:, T[used, 1]], Sd[:, T[used, 2]])  # (K, u, 3, 3)
    Gm = A1 @ inv[None] - np.eye(3)  # (K, u, 3, 3): G - I
    slot = np.full(T.shape[0], -1)
    slot[used] = np.arange(used.size)
    m, n, K = F.shape[0], V.shape[0], Dm.shape[0]
    area = 0.5 * igl.doublearea(V, F)
    good = area > 1e-12 * max(float(area.max()), 1e-300)
    with quiet_native():
        Gr = sp.csr_matrix(igl.grad(V, F))  # (3m, n): rows x of all faces, then y, then z
    Gr.data[~np.isfinite(Gr.data)] = 0.0
    keep = np.tile(good, 3).astype(np.float64)
    Gr = sp.diags(keep) @ Gr
    J = (Gr @ V).reshape(3, m, 3).transpose(1, 2, 0)  # J[t, c, :] = gradient of coordinate c on face t
    rows = np.flatnonzero(on & good)
    # right-hand sides B[:, 3k + c] = Gr' Mf vec_d(sum_e (G_k - I)[c, e] J[:, e, d]) for every shape k and
    # coordinate c, gathered on the template's triangles: B = sum_e H_e S (G - I)[:, :, :, e] with
    # H_e = sum_d Gr_d' diag(area J[:, e, d]) (head faces) and S picking each face's template triangle
    W = np.tile(area * good, 3)
    GrT = Gr.T.tocsr()
    src = slot[tri[rows]]
    S = sp.csr_matrix((np.ones(rows.size), (np.arange(rows.size), src)), shape=(rows.size, used.size))
    GrT_d = [GrT[:, d * m + rows] for d in range(3)]
    B = np.zeros((n, 3 * K))
    for e in range(3):
        H = sum(GrT_d[d] @ sp.diags(area[rows] * J[rows, e, d]) for d in range(3))
        B += (H @ S) @ Gm[..., e].transpose(1, 0, 2).reshape(used.size, 3 * K)
    L = (Gr.T @ sp.diags(W) @ Gr).tocsr()
    # anchors: head vertices far from the face's triangles (their motion is none)
    face_v = np.unique(F[rows])
    size = rms_radius(V)
    Mv = np.zeros(n)
    np.add.at(Mv, F.ravel(), np.repeat(area / 3.0, 3))
    if face_v.size:
        dist, _ = cKDTree(V[face_v]).query(V)
        far = dist * reg.mm_per_unit > ANCHOR_CM * CM_TO_MM
    else:
        far = np.ones(n, dtype=bool)
    anchor = np.zeros(n)
    target = np.zeros((n, 3 * K))
    if far.any():
        anchor[far] = Mv[far] / size ** 2
    if soft_cm or not far.any():  # the template's motion at the closest points, softly (see SOFT_CM)
        near = transfer_expressions(model, reg, "nearest", region).deltas  # (K, n, 3)
        w_soft = Mv / (soft_cm * reg.scale) ** 2 if soft_cm else 1e-2 * Mv / size ** 2
        w_soft = w_soft * ~_mouth_interior(model, reg, region)  # the mouth follows the lips (no pull to still)
        target = near.transpose(1, 0, 2).reshape(n, 3 * K) * (w_soft / np.maximum(anchor + w_soft, 1e-300))[:, None]
        anchor = anchor + w_soft
    eps = 1e-9 * float(Mv.mean()) / size ** 2
    A = L + sp.diags(anchor + eps)
    Usol = factorize_spd(A).solve(B + anchor[:, None] * target)  # (n, 3K), column (k, c)
    out = Usol.reshape(n, K, 3).transpose(1, 0, 2)
    return TransferResult(np.ascontiguousarray(out), tuple(model.expression_names), engine,
                          time.perf_counter() - t0, {"on_face": int(rows.size), "anchored": int(far.sum())})


def _farthest(X, candidates, count, start=None):
    """``count`` of the ``candidates`` rows of ``X`` by Euclidean farthest-point sampling -> ids into ``X``."""
    if candidates.size == 0 or count <= 0:
        return np.zeros(0, dtype=np.int64)
    P = X[candidates]
    d = np.full(len(P), np.inf) if start is None else cKDTree(start).query(P)[0]
    out = []
    j = int(np.argmax(np.linalg.norm(P - P.mean(axis=0), axis=1))) if start is None else int(np.argmax(d))
    for _ in range(min(count, len(P))):
        out.append(j)
        d = np.minimum(d, np.linalg.norm(P - P[j], axis=1))
        j = int(np.argmax(d))
    return candidates[np.array(out, dtype=np.int64)]


def _tangent(model, reg: HeadRegistration, region, t0) -> TransferResult:
    """Engine ``tangent``: the tangent-framework deformer on the head, driven by the template's motion at markers.

    ``TANGENT_MARKERS`` farthest points among the head vertices on the region
    (their displacement: the ``nearest`` engine's), ``TANGENT_ANCHORS``
    farthest points off it held still; the head is brought to the model's
    size (cm) for the deformer's defaults, and back.
    """
    from facegeom.methods.tangent import TangentDeformer

    V, F = reg.head_vertices, reg.head_faces
    near = transfer_expressions(model, reg, "nearest", region).deltas
    _, _, on = _on_face(reg, model, V, region)
    Vc = V / reg.scale
    markers = _farthest(Vc, np.flatnonzero(on), TANGENT_MARKERS)
    anchors = _farthest(Vc, np.flatnonzero(~on), TANGENT_ANCHORS, start=Vc[markers])
    handles = np.r_[markers, anchors]
    deformer = TangentDeformer().fit(Vc, F, handles)
    pos = Vc[handles][None] + near[:, handles] / reg.scale  # anchors: zero motion (off the region)
    out = (deformer.deform_many(pos) - Vc[None]) * reg.scale
    return TransferResult(out, tuple(model.expression_names), "tangent", time.perf_counter() - t0,
                          {"markers": int(markers.size), "anchors": int(anchors.size)})


@dataclass
class Character:
    """A head registered for transfer, with its pieces (what :func:`register_character` returns).

    Attributes
    ----------
    vertices : (n, 3) float64
        The whole head (every piece), its units and frame.
    faces : (m, 3) int64
    pieces : list of :class:`~facegeom.methods.pieces.Piece`
        The skin first; each with its role.
    registration : HeadRegistration
        Of the skin (its ``head_vertices`` are the skin's).
    parts : tuple or None
        The rig parts the pieces came from.
    """

    vertices: np.ndarray
    faces: np.ndarray
    pieces: list
    registration: HeadRegistration
    parts: tuple | None = None


def register_character(model, V, F, *, landmarks=None, units="auto", path=None, progress=None, parts=None,
                       roles=None) -> Character:
    """Split the head ``(V, F)`` into pieces, register the ICT face onto its skin and give each piece its role.

    The pieces are the rig ``parts`` when given, else the connected
    components; the largest is the skin (:func:`register_head` on it alone);
    (or the piece ``roles`` calls ``"skin"``); the others -- eyes, teeth, tongue, lashes -- get the role
    :mod:`facegeom.methods.pieces` finds or ``roles`` (piece name -> role)
    says. ``landmarks``: head vertex ids (on the skin).
    """
    from facegeom.methods.pieces import ROLES, classify_pieces, second_head, split_pieces

    say = progress or (lambda line: None)
    V, F = _check_mesh(V, F, path)
    pieces = split_pieces(V, F, parts)
    known = [p.name for p in pieces]
    for name, role in (roles or {}).items():  # checked before the registration's seconds are spent
        if role not in ROLES:
            raise InputError(f"piece {name!r}: unknown role {role!r}; use one of {', '.join(ROLES)}", path)
        if name not in known:
            raise InputError(f"no piece called {name!r}; the pieces are {', '.join(known)}", path)
    chosen = [n for n, r in (roles or {}).items() if r == "skin"]
    if len(chosen) > 1:
        raise InputError(f"only one piece can be the skin, given {', '.join(map(repr, chosen))}", path)
    if chosen:
        at = [i for i, p in enumerate(pieces) if p.name == chosen[0]]  # it exists: checked above
        pieces.insert(0, pieces.pop(at[0]))
    skin = pieces[0]
    other = second_head(V, pieces, roles)
    if other is not None:
        raise InputError(f"a second head? {other.name!r} is {100 * other.area / skin.area:.0f}% of the skin's area "
                         f"and lies away from it; keep one head per file, or give it a role with roles= ('stay', or 'skin' "
                         f"to transfer onto it instead)", path)
    if len(pieces) == 1:
        bad = [n for n, r in (roles or {}).items() if n != skin.name or r != "skin"]
        if bad:
            raise InputError(f"piece {bad[0]!r}: the head is one piece ({skin.name!r}), its skin", path)
    ids = skin.vertices
    remap = np.full(V.shape[0], -1, dtype=np.int64)
    remap[ids] = np.arange(ids.size)
    lm = None
    if landmarks is not None:
        lm = np.asarray(landmarks, dtype=np.int64)
        if lm.shape != (68,) or lm.max() >= V.shape[0]:
            raise InputError("the landmarks must be 68 head vertex ids (-1 where unknown)", path)
        off = (lm >= 0) & (remap[np.maximum(lm, 0)] < 0)
        if off.any():
            raise InputError(f"landmark {int(np.flatnonzero(off)[0])} lies on vertex {int(lm[off][0])}, which is "
                             f"not on the skin ({skin.name!r})", path)
        lm = np.where(lm >= 0, remap[np.maximum(lm, 0)], -1)
    if len(pieces) > 1:
        say(f"{len(pieces)} pieces: the skin is {skin.name!r} ({ids.size} of {V.shape[0]} vertices)")
    reg = register_head(model, V[ids], remap[F[skin.faces]], landmarks=lm, units=units, path=path,
                        progress=progress)
    try:
        classify_pieces(model, reg, V, pieces, roles)
    except InputError as exc:
        raise InputError(exc.reason, path) from None
    for p in pieces[1:]:
        say(f"  {p.name}: {p.role} ({p.how}; {p.vertices.size} vertices)")
    return Character(V, F, pieces, reg, None if parts is None else tuple(parts))


REGISTRATION_KEYS = ("registration_template", "registration_similarity", "registration_skin",
                     "registration_identity")


def character_arrays(registration: HeadRegistration, skin, S=None, k: float = 1.0) -> dict:
    """A character's ``registration`` and ``skin`` vertex ids as arrays to store beside its rig
    (:data:`REGISTRATION_KEYS`).

    ``S (3, 3)`` and ``k``: the rig's frame from the head's (``x' = k S x``: an axis turn and a units factor),
    applied to what is stored so that it matches the rig's vertices.
    """
    reg = registration
    S = np.eye(3) if S is None else np.asarray(S, dtype=np.float64)
    sim = np.zeros((4, 4))  # rows: R (3 x 3) | t; last row: scale, head units -> cm, 0, 0
    sim[:3, :3], sim[:3, 3] = S @ reg.R, k * (S @ reg.t)
    sim[3, 0], sim[3, 1] = k * reg.scale, reg.units / k
    return {"registration_template": k * (reg.template @ S.T), "registration_similarity": sim,
            "registration_skin": np.asarray(skin, dtype=np.int64),
            "registration_identity": np.asarray(reg.identity, dtype=np.float64)}


def stored_character(model, V, F, arrays, path=None) -> Character | None:
    """The character registered by an earlier transfer, from the arrays :func:`character_arrays` stored
    beside its rig -> a :class:`Character` of the skin alone (other pieces are not kept), or None when the
    arrays are not all there. Checked against the model and the head ``(V, F)``."""
    from facegeom.methods.pieces import Piece

    if not all(key in arrays for key in REGISTRATION_KEYS):
        return None
    tpl, sim = np.asarray(arrays["registration_template"]), np.asarray(arrays["registration_similarity"])
    skin = np.asarray(arrays["registration_skin"])
    N = int(model.n_vertices)
    ok = (tpl.shape == (N, 3) and sim.shape == (4, 4) and skin.ndim == 1 and skin.size >= 3
          and np.issubdtype(skin.dtype, np.integer) and np.isfinite(tpl).all() and np.isfinite(sim).all())
    if not ok or skin.min() < 0 or skin.max() >= V.shape[0] or np.unique(skin).size != skin.size \
            or not (sim[3, 0] > 0 and sim[3, 1] > 0):
        raise InputError("the stored registration does not fit this head or the face model; transfer the head "
                         "again", path)
    remap = np.full(V.shape[0], -1, dtype=np.int64)
    remap[skin] = np.arange(skin.size)
    inside = (remap[F] >= 0).all(axis=1)
    faces = np.flatnonzero(inside)
    scale, units = float(sim[3, 0]), float(sim[3, 1])
    reg = HeadRegistration(V[skin], remap[F[inside]], tpl.astype(np.float64), scale, sim[:3, :3].copy(),
                           sim[:3, 3].copy(), units, units * CM_TO_MM,
                           np.asarray(arrays["registration_identity"], dtype=np.float64), {"stored": True})
    piece = Piece("skin", skin.astype(np.int64), faces, float(igl.doublearea(V, F[inside]).sum() / 2.0), "skin",
                  "stored")
    return Character(V, F, [piece], reg, None)


def transfer_character(model, character: Character, engine: str = "deformation",
                       unfold: bool = True, progress=None) -> TransferResult:
    """Every expression onto the whole registered head: the skin by ``engine``, the other pieces by their role.

    ``unfold``: the skin's shapes checked at weight 1, alone and in :data:`~facegeom.methods.folds.PAIRS`
    (triangles flipped against the rest pose, new self-intersections) and corrected where they fold
    (:func:`~facegeom.methods.folds.unfold`); the report in ``info["folds"]``
    (:func:`~facegeom.methods.folds.fold_report`). ``progress(line)`` hears of each stage as it ends and begins.
    """
    from facegeom.methods.pieces import piece_deltas

    say = progress or (lambda line: None)
    reg = character.registration
    res = transfer_expressions(model, reg, engine)
    say(f"transfer ({engine}): {len(res.names)} shapes onto {character.vertices.shape[0]} vertices in "
        f"{res.time_s:.2f} s")
    skin = res.deltas
    info = dict(res.info)
    if unfold:
        say("checking every shape at weight 1, alone and in pairs, for folds ...")
        from facegeom.methods.folds import fold_report
        from facegeom.methods.folds import unfold as fix

        skin, before, after, changed, kept = fix(reg.head_vertices, reg.head_faces, res.deltas, res.names,
                                                 report_kept=True, progress=progress)
        info["folds"] = fold_report(before, after, changed, kept)
    deltas = piece_deltas(model, reg, character.vertices, character.pieces, skin, res.names)
    return TransferResult(deltas, res.names, res.engine, res.time_s,
                          {**info, "pieces": [(p.name, p.role, p.how) for p in character.pieces]})


def transfer_head(model, V, F, *, engine: str = "deformation", landmarks=None, units="auto", path=None,
                  progress=None, parts=None, roles=None) -> tuple[BlendshapeRig, HeadRegistration, TransferResult]:
    """Register the head ``(V, F)`` and transfer every expression -> ``(rig, registration, transfer)``.

    :func:`register_character` then :func:`transfer_character`. The rig has
    the head's vertices, triangles, units and ``parts``; the registration is
    the skin's.
    """
    say = progress or (lambda line: None)
    if engine not in ENGINES:
        raise InputError(f"unknown transfer engine {engine!r}; use one of {', '.join(ENGINES)}")
    ch = register_character(model, V, F, landmarks=landmarks, units=units, path=path, progress=progress,
                            parts=parts, roles=roles)
    res = transfer_character(model, ch, engine, progress=progress)
    folds = res.info.get("folds")
    if folds is not None:
        for line in fold_lines(folds):
            say(line)
    rig = BlendshapeRig(ch.vertices, res.deltas, res.names, ch.faces, parts=ch.parts)
    res.info["skin_vertices"] = ch.pieces[0].vertices
    return rig, ch.registration, res


def fold_lines(folds: dict) -> list:
    """The ``folds`` report of a transfer (:func:`~facegeom.methods.folds.fold_report`) as lines to print."""
    cases = folds["cases"]
    bad = {k: v for k, v in cases.items() if v["flipped"] or v["crossings"]}
    n = len(folds["checked"])
    head = (f"folds: {n} shapes and pairs checked at weight 1 ({folds['check_s']:.1f} s): ")
    if not bad:
        lines = [head + "no flipped triangle, no new self-intersection"]
    else:
        lines = [head + f"{len(bad)} folded ({folds['before']} flipped triangles + crossing pairs), "
                 f"{folds['after']} left after the correction ({len(folds['corrected'])} shapes smoothed where "
                 f"they fold, {folds['time_s']:.1f} s)"]
        for name, v in bad.items():
            lines.append(f"  {name}: flipped {v['flipped']} -> {v['flipped_after']}, "
                         f"crossings {v['crossings']} -> {v['crossings_after']}")
        kept = folds.get("not_corrected") or {}
        if kept:
            lines.append(f"  not corrected (the correction would change the shape by more than "
                         f"{100 * folds['max_change']:.0f}%): "
                         + ", ".join(f"{k} ({100 * v:.0f}%)" for k, v in kept.items()))
    scan = {k: v["scan_fold_flipped_after"] for k, v in cases.items() if v["scan_fold_flipped_after"]}
    if scan:
        lines.append(f"  in the mesh's own folds (it crosses itself at rest: {folds['rest_crossings']} pairs): "
                     + ", ".join(f"{k} {v}" for k, v in scan.items()) + " flipped triangles there (within 2 rings of its own crossings), not counted")
    return lines
