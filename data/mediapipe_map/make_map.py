"""Build the map between MediaPipe's 468-point face mesh and facegeom's face model (ICT-FaceKit).

Run from the repository root (about 5 s)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python data/mediapipe_map/make_map.py [--out DIR] [--data PATH]

Input: MediaPipe's canonical face mesh, ``facegeom/vision/data/canonical_face_model.obj``
(google/mediapipe, Apache-2.0; its git blob hash is checked, see ``NOTICE-mediapipe.md``),
and the face model's neutral (:func:`facegeom.model.face.load_face_model`, ``--data``
names another bundle). Output, into ``--out`` (default ``facegeom/vision/data``):

- ``mediapipe_to_face_model.csv`` -- each of the 468 points as a triangle of the face
  model and barycentric coordinates (``point,triangle,b0,b1,b2,distance_cm``);
- ``landmarks68_on_mediapipe.csv`` -- each of the 68 iBUG / Multi-PIE landmarks as a
  triangle of the canonical mesh and barycentric coordinates
  (``landmark,mp_triangle_a,mp_triangle_b,mp_triangle_c,b0,b1,b2,distance_cm``).

It prints its quality numbers. The result is deterministic (no random numbers; the same
sparse solves and closest-point queries every run).

Method
------
Both meshes have +x on the subject's left, +y up, +z towards the viewer, and both are in
centimetres (checked: MediaPipe 33 / 263, the subject's right / left outer eye corner, lie
at x = -4.45 / +4.45 like the face model's landmarks 36 / 45; the most forward
MediaPipe point is 4, the face model's is its nose tip, landmark 30).

1. **Similarity** (rotation, translation, scale; :func:`facegeom.registration.kabsch`
   for the rotation, then the least-squares scale) from twelve hand-matched points,
   ``HAND_PAIRS``: the eye corners (33 / 133 / 362 / 263 -> 36 / 39 / 42 / 45), the
   mouth corners (61 / 291 -> 48 / 54), the nose tip (4 -> 30: point 4 is the most
   forward point, and its height under the eye corners matches landmark 30's; point 1
   is 6.5 mm lower), the subnasale (2 -> 33), the nose root (168 -> 27), the outer lip
   mid-points (0 / 17 -> 51 / 57) and the chin (152 -> 8). The script prints each pair.
2. **Non-rigid refinement**: a few rounds of closest-point ICP, each a sparse
   least-squares solve for all 468 points at once of

   - point-to-plane distance to the closest point of the neutral's triangles (plus a
     tenth of the point-to-point distance, which keeps the solve well posed),
   - the hand pairs as soft constraints (weight ``PAIR_WEIGHT``),
   - **contour ties** (an addition to a landmark-only method, weight ``CONTOUR_WEIGHT``):
     MediaPipe's eyelid, lip (outer and inner) and upper brow contours are tied to the
     face model's matching landmark contours (36-41, 42-47, 48-59, 60-67, 17-21,
     22-26), each MediaPipe contour point to the point at the same fraction of arc
     length along the landmark polyline, snapped onto the neutral's surface. With the
     twelve pairs alone (``--no-contours``) the inner lower lip ended 3.4 mm (mean; up to
     5.5 mm) from the face model's inner-lip landmark polyline (the closest-point ICP slid
     it down the lower lip), the brows 3.1 mm (up to 4.6 mm), the lids up to 1.4 mm, the
     inner-lip landmarks recovered from the 468 mapped points up to 5.0 mm; with the ties
     every contour is within 1.3 mm of its landmark polyline (a polyline's chords cut
     through the curved lids by about that much) and the inner lips within 0.3 mm.
     These are the points where a wrong correspondence costs most when the map drives
     the face model from detected points (blinks, lips, brows);
   - smoothness: ``||L (X - X0)||^2`` on the displacement from the similarity pose with
     the canonical mesh's *uniform* graph Laplacian ``L`` (its cotangent weights are
     negative on 8.5 % of the edges: thin triangles around the eyes and lips), the
     weight lowered over the rounds (``STIFFNESS``) from a near-rigid to a snug fit.

   The face model has holes at the eyes and the mouth and its lips are closed, so the
   closest point of an inner-lip point can lie on the other lip. The points of
   MediaPipe's upper / lower lid and lip contours may only pair with the face model's
   triangles on the same side of the hole (each vertex labelled upper or lower by its
   graph distance to the two halves of the hole's boundary, split at the hole's corners),
   in the ICP and in the final snap; otherwise a map point of the upper lip would follow
   the lower lip when the mouth opens.
3. **Forward map**: each registered point snapped to the closest point of the neutral's
   (allowed) triangles; ``distance_cm`` is the distance before the snap.
4. **Reverse map**: each landmark vertex of the neutral placed on the registered
   canonical mesh. MediaPipe closes the eyes and the mouth with triangles between the
   lid / inner-lip contour points, so the plain closest point of a lid landmark could
   land inside the eye opening, mixing upper and lower lid (a detected blink would then
   not close the landmarks' eye). The eye and lip landmarks (36-67) therefore go on the
   closest point of the matching MediaPipe contour (upper lid for 37, 38, 43, 44; lower
   lid for 40, 41, 46, 47; the whole eye loop for the corners; likewise the outer and
   inner lip contours), as a triangle of the canonical mesh with one barycentric
   coordinate 0. The others (jaw, brows, nose) take the closest point of the canonical
   mesh without the eye and mouth opening triangles. The jaw contour (0-16) is not a
   fixed surface curve (annotators put it on the face's outline): those rows are listed as
   approximate in the file's header with their distances.

Measured (this script's output)
-------------------------------
Similarity: scale 0.958, rotation 3.5 degrees; the pairs end 0.8-2.7 mm apart, the chin
6.4 mm (MediaPipe's face is longer). The 468 points lie 1.0 mm (median; 95 % 3.5 mm,
max 5.4 mm) from the neutral's surface after the similarity, 0.01 mm (95 % 0.07 mm, max
0.11 mm) after the refinement, with no flipped triangle; the hand pairs' mapped points
are within 0.1 mm of their landmark vertices; mirror pairs of points map to mirror
points within 0.14 mm. The 68 landmarks lie within 0.5 mm (eyes, lips, brows) and
0.8 mm (nose) of the registered mesh, the jaw within 1.0 mm except 0 and 16, 2.4 mm
beyond the mesh's outline; the inner 51 landmarks (17-67) recovered from the 468
mapped points of the neutral are within 0.8 mm of the landmark vertices (and within
0.9 mm on the face model's jawOpen, eyeBlink and mouthSmile shapes).
"""
from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.sparse.linalg import spsolve

from facegeom.model.face import load_face_model
from facegeom.registration import kabsch
from facegeom.vision.correspondence import (
    CANONICAL_OBJ,
    LANDMARKS68_COLUMNS,
    LANDMARKS68_FILE,
    MEDIAPIPE_COLUMNS,
    MEDIAPIPE_FILE,
    canonical_mesh,
)

REPO = "google/mediapipe"
OBJ_PATH = "mediapipe/modules/face_geometry/data/canonical_face_model.obj"
OBJ_COMMIT = "9d8807788567c01dbd998c0a3d0f730b9686912d"  # the snapshot the file was copied from (2024-07-02)
OBJ_LAST_CHANGED = "a908d668c730da128dfa8d9f6bd25d519d006692"  # the file's last change upstream (2020-09)
OBJ_GIT_BLOB = "0e666d1c4e75949d1639c2bcf347a38da4834164"  # `git hash-object` of the file
SCRIPT = "data/mediapipe_map/make_map.py"

# (MediaPipe point, iBUG landmark): step 1's similarity and soft constraints in step 2
HAND_PAIRS = ((33, 36), (133, 39), (362, 42), (263, 45),  # eye corners: right outer, inner; left inner, outer
              (61, 48), (291, 54),  # mouth corners
              (4, 30), (2, 33), (168, 27),  # nose tip, subnasale, nose root
              (0, 51), (17, 57),  # outer lip mid-points, upper and lower
              (152, 8))  # chin

# MediaPipe contours (point ids, from the subject's right to left or outer to inner) and the
# landmark polylines they are tied to. `side`: which side of which face-model hole the
# contour's inner points must stay on (None: anywhere).
CONTOURS = {
    "right upper lid": ((33, 246, 161, 160, 159, 158, 157, 173, 133), (36, 37, 38, 39), ("right eye", "upper")),
    "right lower lid": ((33, 7, 163, 144, 145, 153, 154, 155, 133), (36, 41, 40, 39), ("right eye", "lower")),
    "left upper lid": ((362, 398, 384, 385, 386, 387, 388, 466, 263), (42, 43, 44, 45), ("left eye", "upper")),
    "left lower lid": ((362, 382, 381, 380, 374, 373, 390, 249, 263), (42, 47, 46, 45), ("left eye", "lower")),
    "outer upper lip": ((61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291), (48, 49, 50, 51, 52, 53, 54), None),
    "outer lower lip": ((61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291), (48, 59, 58, 57, 56, 55, 54), None),
    "inner upper lip": ((78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308), (60, 61, 62, 63, 64), ("mouth", "upper")),
    "inner lower lip": ((78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308), (60, 67, 66, 65, 64), ("mouth", "lower")),
    "right brow": ((70, 63, 105, 66, 107), (17, 18, 19, 20, 21), None),
    "left brow": ((300, 293, 334, 296, 336), (26, 25, 24, 23, 22), None),
}
# the reverse map: landmark -> the MediaPipe contours (by name) it is placed on
ON_CONTOUR = {
    **{k: ("right upper lid", "right lower lid") for k in (36, 39)}, **{k: ("right upper lid",) for k in (37, 38)},
    **{k: ("right lower lid",) for k in (40, 41)},
    **{k: ("left upper lid", "left lower lid") for k in (42, 45)}, **{k: ("left upper lid",) for k in (43, 44)},
    **{k: ("left lower lid",) for k in (46, 47)},
    **{k: ("outer upper lip", "outer lower lip") for k in (48, 54)},
    **{k: ("outer upper lip",) for k in (49, 50, 51, 52, 53)}, **{k: ("outer lower lip",) for k in (55, 56, 57, 58, 59)},
    **{k: ("inner upper lip", "inner lower lip") for k in (60, 64)},
    **{k: ("inner upper lip",) for k in (61, 62, 63)}, **{k: ("inner lower lip",) for k in (65, 66, 67)},
}
# the MediaPipe loops whose inside the canonical mesh closes with triangles (eyes, mouth)
OPENINGS = (("right upper lid", "right lower lid"), ("left upper lid", "left lower lid"),
            ("inner upper lip", "inner lower lip"))

PAIR_WEIGHT = 1.0  # per hand pair, relative to one point's surface term
CONTOUR_WEIGHT = 0.5  # per contour point
PLANE_TO_POINT = 0.1  # the point-to-point share of the surface term
STIFFNESS = (10.0, 3.0, 1.0, 0.3, 0.1)  # the smoothness weight, round after round
ICP_STEPS = 5  # closest-point updates per stiffness


def git_blob_sha1(data: bytes) -> str:
    """The git object id of a file's content (``git hash-object``)."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def similarity(P: np.ndarray, Q: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Scale ``s``, rotation ``R``, translation ``t`` minimising ``sum ||s R P_i + t - Q_i||^2`` (Umeyama).

    The rotation does not depend on the scale, so :func:`kabsch` gives it; the scale is
    then the least-squares ratio of the centred point sets.
    """
    R, _ = kabsch(P, Q)
    pc, qc = P.mean(axis=0), Q.mean(axis=0)
    s = float(np.sum((Q - qc) * ((P - pc) @ R.T)) / np.sum((P - pc) ** 2))
    return s, R, qc - s * R @ pc


def uniform_laplacian(F: np.ndarray, n: int) -> sp.csr_matrix:
    """``I - D^-1 A``: each vertex minus the mean of its neighbours."""
    A = igl.adjacency_matrix(F).astype(np.float64).tocsr()
    return (sp.eye(n) - sp.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A).tocsr()


def hole_sides(N: np.ndarray, T: np.ndarray) -> dict[str, dict[str, np.ndarray]]:
    """For each hole of the face model, the triangles on its upper and on its lower side.

    The hole's boundary loop is split at its two corners (smallest and largest x) into an
    upper and a lower half; a vertex is on the side whose half is nearer along the mesh's
    edges. Returns ``{hole: {"upper": bool (m,), "lower": bool (m,)}}`` for the holes
    ``"right eye"``, ``"left eye"``, ``"mouth"`` (a triangle is on a side if any of its
    vertices is).
    """
    loops = sorted((np.asarray(lp) for lp in igl.boundary_loop_all(T)), key=len)
    if len(loops) != 4:
        raise SystemExit(f"expected the face model to have 4 boundary loops (outline, eyes, mouth), got {len(loops)}")
    holes = {}
    for lp in loops[:3]:  # the outline is the longest loop
        c = N[lp].mean(axis=0)
        holes["mouth" if c[1] < 0 else ("left eye" if c[0] > 0 else "right eye")] = lp
    if len(holes) != 3:
        raise SystemExit("could not tell the face model's eye and mouth holes apart")
    E = np.r_[T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]
    w = np.linalg.norm(N[E[:, 0]] - N[E[:, 1]], axis=1)
    G = sp.coo_matrix((w, (E[:, 0], E[:, 1])), shape=(len(N), len(N))).tocsr()
    G = G.maximum(G.T)
    out = {}
    for name, lp in holes.items():
        a, b = int(np.argmin(N[lp, 0])), int(np.argmax(N[lp, 0]))
        i, j = min(a, b), max(a, b)
        arc1, arc2 = lp[i:j + 1], np.r_[lp[j:], lp[:i + 1]]
        upper, lower = (arc1, arc2) if N[arc1, 1].mean() > N[arc2, 1].mean() else (arc2, arc1)
        du = csgraph.dijkstra(G, directed=False, indices=upper, min_only=True)
        dl = csgraph.dijkstra(G, directed=False, indices=lower, min_only=True)
        vu, vl = du < dl, dl < du
        out[name] = {"upper": vu[T].any(axis=1), "lower": vl[T].any(axis=1)}
    return out


class Surface:
    """Closest points on the face model's neutral, each query point restricted to an allowed triangle set."""

    def __init__(self, N: np.ndarray, T: np.ndarray, allowed: list[np.ndarray], group: np.ndarray):
        self.N, self.T = N, T
        self.normals = igl.per_face_normals(N, T, np.array([0.0, 0.0, 1.0]))
        self.sets = [np.flatnonzero(a) for a in allowed]  # triangle ids of each set
        self.group = group  # (n,) the set of each query point

    def closest(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(squared distances (n,), triangle ids (n,), closest points (n, 3)) of ``X (n, 3)``."""
        d2, tri, C = np.empty(len(X)), np.empty(len(X), dtype=np.int64), np.empty_like(X)
        for g, ids in enumerate(self.sets):
            rows = np.flatnonzero(self.group == g)
            if rows.size:
                d2[rows], t, C[rows] = igl.point_mesh_squared_distance(X[rows], self.N, self.T[ids])
                tri[rows] = ids[t]
        return d2, tri, C


def polyline_at(Y: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Points of the polyline through ``Y (k, 3)`` at the given fractions of its arc length."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(Y, axis=0), axis=1))]
    u = fractions * s[-1]
    return np.stack([np.interp(u, s, Y[:, c]) for c in range(3)], axis=1)


def arc_fractions(X: np.ndarray) -> np.ndarray:
    """Each point's fraction of the arc length along the polyline ``X (k, 3)``."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(X, axis=0), axis=1))]
    return s / s[-1]


def register(F: np.ndarray, surface: Surface, targets: dict[int, np.ndarray], weights: dict[int, float],
             X0: np.ndarray) -> np.ndarray:
    """Step 2: the canonical points ``X0 (n, 3)`` (triangles ``F``) deformed onto the neutral (see the module docstring).

    ``targets`` / ``weights``: the soft constraints, point id -> position (3,) / weight.
    """
    n = len(X0)
    L = uniform_laplacian(F, n)
    K = sp.kron((L.T @ L).tocsr(), sp.eye(3)).tocsr()
    ids = np.array(sorted(targets))
    W = np.zeros(n)
    W[ids] = [weights[i] for i in ids]
    Y = np.zeros((n, 3))
    Y[ids] = [targets[i] for i in ids]
    Wc = sp.diags(np.repeat(W, 3))
    X = X0.copy()
    for lam in STIFFNESS:
        for _ in range(ICP_STEPS):
            _, tri, C = surface.closest(X)
            nn = surface.normals[tri]
            B = np.einsum("pi,pj->pij", nn, nn) + PLANE_TO_POINT * np.eye(3)
            A = sp.block_diag(list(B), format="csr") + lam * K + Wc
            b = np.einsum("pij,pj->pi", B, C).ravel() + lam * (K @ X0.ravel()) + (W[:, None] * Y).ravel()
            X = spsolve(A.tocsc(), b).reshape(n, 3)
    return X


def barycentric(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of ``P (k, 3)`` (on the triangles) in ``A, B, C (k, 3)``, clipped to >= 0, summing to 1."""
    b = igl.barycentric_coordinates(P, A, B, C)
    b = np.clip(b, 0.0, None)
    return b / b.sum(axis=1, keepdims=True)


def closest_on_segments(p: np.ndarray, X: np.ndarray, edges: list[tuple[int, int]]) -> tuple[float, int, float]:
    """(distance, index into ``edges``, parameter u in [0, 1] from the first end) of ``p``'s closest point."""
    best = (np.inf, -1, 0.0)
    for k, (a, b) in enumerate(edges):
        d = X[b] - X[a]
        u = float(np.clip(np.dot(p - X[a], d) / max(np.dot(d, d), 1e-300), 0.0, 1.0))
        dist = float(np.linalg.norm(X[a] + u * d - p))
        if dist < best[0] - 1e-12:
            best = (dist, k, u)
    return best


def region_of(k: int) -> str:
    """The face region of iBUG landmark ``k``."""
    for name, (lo, hi) in (("jaw", (0, 16)), ("brows", (17, 26)), ("nose", (27, 35)), ("eyes", (36, 47)),
                           ("outer lips", (48, 59)), ("inner lips", (60, 67))):
        if lo <= k <= hi:
            return name
    raise ValueError(k)


def mm(x) -> str:
    """Centimetres as millimetres with one decimal."""
    return f"{10 * float(x):.1f}"


def eye_mouth_openings(F: np.ndarray) -> np.ndarray:
    """The canonical mesh's triangles inside the eye and inner-lip loops -> ``(len(F),)`` bool."""
    opening = np.zeros(len(F), dtype=bool)
    for up, lo in OPENINGS:
        loop = set(CONTOURS[up][0]) | set(CONTOURS[lo][0])
        opening |= np.array([set(f) <= loop for f in F.tolist()])
    return opening


def reverse_map(X: np.ndarray, F: np.ndarray, L68: np.ndarray):
    """Step 4: each landmark ``L68 (68, 3)`` on the canonical mesh placed at ``X (468, 3)`` -> ``(rows, beyond)``.

    ``rows``: ``(landmark, triangle's three point ids, barycentric (3,), distance)``; ``beyond``: (68,) bool,
    the landmark's closest point is on the mesh's outline.
    """
    opening = eye_mouth_openings(F)
    skin = np.flatnonzero(~opening)
    edge_face = {}
    for f in skin:  # each skin triangle under its three undirected edges (the first in file order wins)
        for a, b in ((F[f, 0], F[f, 1]), (F[f, 1], F[f, 2]), (F[f, 2], F[f, 0])):
            edge_face.setdefault((min(a, b), max(a, b)), f)
    rows = []
    d2r, tr, Cr = igl.point_mesh_squared_distance(L68, X, F[skin])
    for k in range(68):
        if k in ON_CONTOUR:
            edges = [(a, b) for name in ON_CONTOUR[k] for a, b in zip(CONTOURS[name][0][:-1], CONTOURS[name][0][1:])]
            d, e, u = closest_on_segments(L68[k], X, edges)
            a, b = edges[e]
            f = edge_face[(min(a, b), max(a, b))]
            w = {a: 1.0 - u, b: u}
            bk = np.array([w.get(int(v), 0.0) for v in F[f]])
        else:
            f = skin[tr[k]]
            d = float(np.sqrt(d2r[k]))
            bk = barycentric(Cr[k:k + 1], *(X[F[f, j]][None] for j in range(3)))[0]
        rows.append((k, F[f], bk, d))
    outline = np.asarray(igl.boundary_loop(F))
    beyond = np.array([closest_on_segments(L68[k], X, list(zip(outline, np.roll(outline, -1))))[0] - r[3] < 1e-7
                       for k, r in enumerate(rows)])
    return rows, beyond


def main(argv=None) -> int:
    """Build the two map files and print their quality numbers; returns the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=MEDIAPIPE_FILE.parent, help="folder for the two CSV files")
    ap.add_argument("--data", default=None, help="the face-model bundle (default: found as facegeom finds it)")
    ap.add_argument("--no-contours", action="store_true",
                    help="for comparison: register with the hand pairs only (no contour ties)")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()

    obj_bytes = CANONICAL_OBJ.read_bytes()
    if git_blob_sha1(obj_bytes) != OBJ_GIT_BLOB:
        raise SystemExit(f"{CANONICAL_OBJ} is not the published file (git blob {git_blob_sha1(obj_bytes)}, "
                         f"expected {OBJ_GIT_BLOB})")
    V, F = (np.array(a) for a in canonical_mesh())
    model = load_face_model(args.data)
    N, T, LM = model.neutral.astype(np.float64), model.triangles.astype(np.int64), model.landmarks.astype(np.int64)
    face_hash = hashlib.sha256(N.astype("<f4").tobytes() + T.astype("<i4").tobytes()).hexdigest()
    n = len(V)

    # ---- 1. similarity from the hand pairs
    mp = np.array([a for a, _ in HAND_PAIRS])
    ib = np.array([b for _, b in HAND_PAIRS])
    s, R, t = similarity(V[mp], N[LM[ib]])
    X0 = s * V @ R.T + t
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    print(f"similarity: scale {s:.4f}, rotation {angle:.2f} deg, translation {np.round(t, 3)} cm")
    print("  pair       MediaPipe canonical (cm)      face model landmark (cm)   after similarity (mm)")
    for (a, b), q in zip(HAND_PAIRS, N[LM[ib]]):
        print(f"  {a:3d} -> {b:2d}  {np.array2string(V[a], precision=2):26s}  "
              f"{np.array2string(q, precision=2):26s}  {mm(np.linalg.norm(X0[a] - q)):>5s}")

    # ---- restrictions at the face model's holes, contour targets
    sides = hole_sides(N, T)
    allowed = [np.ones(len(T), dtype=bool)]
    group = np.zeros(n, dtype=np.int64)
    for name, (points, _, side) in CONTOURS.items():
        if side is None:
            continue
        hole, which = side
        other = "lower" if which == "upper" else "upper"
        allowed.append(~sides[hole][other])
        group[list(points[1:-1])] = len(allowed) - 1  # the corners may lie on either side
    surface = Surface(N, T, allowed, group)

    targets = {int(a): N[LM[b]] for a, b in HAND_PAIRS}
    weights = {int(a): PAIR_WEIGHT for a, _ in HAND_PAIRS}
    for name, (points, marks, _) in CONTOURS.items() if not args.no_contours else ():
        on_polyline = polyline_at(N[LM[list(marks)]], arc_fractions(X0[list(points)]))
        _, _, on_surface = igl.point_mesh_squared_distance(on_polyline, N, T[surface.sets[group[points[1]]]])
        on_surface[[0, -1]] = N[LM[[marks[0], marks[-1]]]]  # the ends: the landmark vertices themselves
        for p, c in zip(points, on_surface):
            if int(p) not in targets:  # a hand pair wins (the eye and mouth corners, 0 and 17 on the lips)
                targets[int(p)], weights[int(p)] = c, CONTOUR_WEIGHT

    d_sim = np.sqrt(surface.closest(X0)[0])
    opening = np.zeros(len(F), dtype=bool)  # the canonical mesh's triangles inside the eye and inner-lip loops
    for up, lo in OPENINGS:
        loop = set(CONTOURS[up][0]) | set(CONTOURS[lo][0])
        opening |= np.array([set(f) <= loop for f in F.tolist()])

    # ---- 2. non-rigid refinement
    X = register(F, surface, targets, weights, X0)
    d2, tri, C = surface.closest(X)
    dist = np.sqrt(d2)
    print(f"points to the neutral's surface (mm): after the similarity median {mm(np.median(d_sim))}, "
          f"95 % {mm(np.percentile(d_sim, 95))}, max {mm(d_sim.max())}; after the refinement median "
          f"{10 * np.median(dist):.2f}, 95 % {10 * np.percentile(dist, 95):.2f}, max {10 * dist.max():.2f}")
    n0 = igl.per_face_normals(X0, F, np.array([0.0, 0.0, 1.0]))
    n1 = igl.per_face_normals(X, F, np.array([0.0, 0.0, 1.0]))
    flipped = int(((n0 * n1).sum(axis=1) < 0).sum())
    area_ratio = igl.doublearea(X, F) / igl.doublearea(X0, F)
    print(f"registered canonical mesh: {flipped} flipped triangles; triangle area / area after the similarity "
          f"{area_ratio[~opening].min():.2f} ... {area_ratio[~opening].max():.2f} (eye and mouth openings: "
          f"{area_ratio[opening].min():.2f} ... {area_ratio[opening].max():.2f}, the face model's lips are closed)")

    # ---- 3. forward map
    bary = barycentric(C, N[T[tri, 0]], N[T[tri, 1]], N[T[tri, 2]])
    mapped = np.einsum("pk,pkd->pd", bary, N[T[tri]])
    print(f"forward map: snapped points reproduce the closest points to {np.abs(mapped - C).max():.1e} cm")
    print("hand pairs, mapped point to the landmark vertex on the neutral (mm):")
    for (a, b) in HAND_PAIRS:
        print(f"  {a:3d} -> {b:2d}: {mm(np.linalg.norm(mapped[a] - N[LM[b]]))}")
    for name, (points, marks, _) in CONTOURS.items():
        dense = polyline_at(N[LM[list(marks)]], np.linspace(0, 1, 400))
        dd = np.min(np.linalg.norm(mapped[list(points)][:, None] - dense[None], axis=2), axis=1)
        print(f"  {name:16s} contour to the landmark polyline (mm): max {mm(dd.max())}, mean {mm(dd.mean())}")
    mirror = np.argmin(np.linalg.norm((V * [-1, 1, 1])[:, None] - V[None], axis=2), axis=1)
    sym = np.linalg.norm(mapped * [-1, 1, 1] - mapped[mirror], axis=1)
    print(f"symmetry: |mirror(mapped i) - mapped mirror(i)| median {10 * np.median(sym):.2f} mm, "
          f"max {10 * sym.max():.2f} mm")

    # ---- 4. reverse map
    rows, beyond = reverse_map(X, F, L68 := N[LM])
    # the reverse map on the mapped (snapped) points: what a user gets from the 468 points on the neutral
    P = mapped
    back = np.array([b @ P[f] for _, f, b, _ in rows])
    err = np.linalg.norm(back - L68, axis=1)
    rdist = np.array([r[3] for r in rows])
    print("landmarks: distance to the registered canonical mesh / contour, and landmark from the 468 mapped "
          "points vs the landmark vertex (mm)")
    for region in ("jaw", "brows", "nose", "eyes", "outer lips", "inner lips"):
        ks = [k for k in range(68) if region_of(k) == region]
        print(f"  {region:10s} on the mesh: mean {mm(rdist[ks].mean())} max {mm(rdist[ks].max())};  "
              f"from the 468 points: mean {mm(err[ks].mean())} max {mm(err[ks].max())}")
    print("  jaw 0-16 (mm, * beyond the outline of MediaPipe's mesh): "
          + " ".join(mm(x) + "*" * bool(b) for x, b in zip(rdist[:17], beyond[:17])))
    if beyond[17:].any():
        print(f"  beyond the outline, not on the jaw: {np.flatnonzero(beyond[17:]) + 17}")
    print(f"  inner 51 (17-67) from the 468 points: max {mm(err[17:].max())} mm (landmark {17 + int(np.argmax(err[17:]))})")

    # ---- write
    args.out.mkdir(parents=True, exist_ok=True)
    common = [
        f"# made by {SCRIPT} (facegeom), rerun it to rebuild this file",
        f"# from MediaPipe's canonical face mesh: {REPO} {OBJ_PATH} at commit {OBJ_COMMIT}",
        f"#   (last changed upstream in {OBJ_LAST_CHANGED}, git blob {OBJ_GIT_BLOB}; Apache-2.0,",
        "#   Copyright The MediaPipe Authors; see NOTICE-mediapipe.md)",
        f"# and the face model's neutral (ICT-FaceKit light, {len(N)} vertices, {len(T)} triangles;",
        f"#   sha256 of its float32 vertices + int32 triangles {face_hash})",
        "# method: similarity from 12 hand-matched points, then a Laplacian-regularised closest-point ICP with the",
        "#   eyelid, lip and brow contours tied to the 68 landmarks' contours; see the script's docstring",
    ]
    fwd = [("# MediaPipe face-mesh point -> face model: point = b0*V[T[triangle,0]] + b1*V[T[triangle,1]] + "
            "b2*V[T[triangle,2]]"),
           *common,
           "# distance_cm: the registered point's distance to the neutral's surface before it was snapped onto it",
           ",".join(MEDIAPIPE_COLUMNS)]
    fwd += [f"{i},{tri[i]},{bary[i, 0]:.10f},{bary[i, 1]:.10f},{bary[i, 2]:.10f},{dist[i]:.6f}" for i in range(n)]
    jaw = ", ".join(f"{k}: {rows[k][3]:.2f}{'*' * bool(beyond[k])}" for k in range(17))
    rev = ["# iBUG / Multi-PIE landmark -> MediaPipe points P (468, d): landmark = b0*P[a] + b1*P[b] + b2*P[c]",
           *common,
           "# eye and lip landmarks (36-67) lie on the matching MediaPipe lid / lip contour (one b is 0); the others",
           "#   on the closest point of the registered canonical mesh (without its eye and mouth opening triangles)",
           "# distance_cm: the landmark vertex's distance to that contour / mesh in the registration",
           "# APPROXIMATE: the jaw contour 0-16 is an outline, not fixed points; their distances (cm), * where the",
           f"#   landmark lies beyond the outline of MediaPipe's mesh (its closest point is on the outline): {jaw}",
           ",".join(LANDMARKS68_COLUMNS)]
    rev += [f"{k},{f[0]},{f[1]},{f[2]},{b[0]:.10f},{b[1]:.10f},{b[2]:.10f},{d:.6f}" for k, f, b, d in rows]
    for path, lines in ((args.out / MEDIAPIPE_FILE.name, fwd), (args.out / LANDMARKS68_FILE.name, rev)):
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        print(f"wrote {path}")
    print(f"done in {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
