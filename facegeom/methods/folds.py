"""Folds of a deformed skin: triangles flipped against the rest pose and new self-intersections.

Used by :mod:`facegeom.methods.transfer` to check every transferred shape (and
the pairs that co-occur in real takes, :data:`PAIRS`) and by its tests.

- **Flipped**: a triangle whose normal turned more than 90 degrees from its
  rest normal (``n_rest . n_posed <= 0``; a triangle shrunk to nothing counts).
- **Self-intersection**: two triangles that share no vertex and cross in the
  posed mesh but did not at rest, and not both beside a rest crossing (a scan
  may already cross itself at rest: the Lee Perry-Smith scan has 252 such
  pairs, at the ears, the inner eye corners and the lips' corners; its crossed
  sheets sliding past each other are not the transfer's). Triangles that share
  a vertex are left to the flip test (a fold between neighbours turns one of
  them over). Flips beside a rest crossing are counted apart
  (``scan_flipped``: slivers of the scan's own creases).

Only triangles that moved (a vertex by more than :data:`MOVED_REL` of the
median edge) can start to cross: a pair that kept still keeps its rest state.
The test: libigl's CGAL self-intersection detection
(``igl.copyleft.cgal.remesh_self_intersections``, ``detect_only``) on the
triangles whose bounding box meets the moved ones'; without CGAL, a numpy one
(bounding spheres bucketed by size in k-d trees, then a vectorised
segment-triangle test both ways; the same pairs on the scan, about 10x
slower). The Lee Perry-Smith scan (8,844 vertices): 53 shapes + 6 pairs in
2-3.5 s on a busy 2-core machine (38 ms per case in CGAL).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["PAIRS", "FoldCheck", "RestCrossings", "check_shapes", "crossing_pairs", "flipped", "fold_report",
           "new_crossings", "unfold"]

# shapes that co-occur in real takes at high weights, checked together at 1.0 each (besides every shape alone)
PAIRS = (("jawOpen", "mouthFunnel"), ("jawOpen", "mouthSmile_L"), ("jawOpen", "mouthSmile_R"),
         ("jawOpen", "mouthPucker"), ("jawOpen", "mouthClose"), ("eyeBlink_L", "eyeBlink_R"))
# shapes checked only in their pair: ARKit's mouthClose closes the lips of an open jaw (its weight at most
# jawOpen's); alone at 1 it pushes shut lips through each other (the ICT template's own: 416 flipped triangles)
NOT_ALONE = ("mouthClose",)
MAX_CHANGE = 0.25  # unfold: a shape whose correction would change its motion by more than this (relative) is kept
TOUCH_EDGES = 1.0  # unfold: crossing sheets share their motion over this many median edge lengths (grows per round)
MOVED_REL = 0.01  # a vertex moved when its displacement exceeds this fraction of the median edge length


def _normals(X, F):
    return np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])


def flipped(V, F, X) -> np.ndarray:
    """Triangles of ``F`` whose normal in ``X`` turned more than 90 degrees from the rest ``V`` -> ids."""
    return np.flatnonzero((_normals(V, F) * _normals(X, F)).sum(axis=1) <= 0.0)


def _seg_tri(P0, P1, A, B, C):
    """Does the segment ``P0 P1`` cross the triangle ``A B C`` (rows, vectorised)? Strict, coplanar = no."""
    n = np.cross(B - A, C - A)
    s0 = ((P0 - A) * n).sum(axis=1)
    s1 = ((P1 - A) * n).sum(axis=1)
    cross = (s0 * s1) < 0.0
    d = P1 - P0
    # the line's side of each edge: signed volumes of (P0, P1, edge) all of one sign
    v1 = (np.cross(A - P0, B - P0) * d).sum(axis=1)
    v2 = (np.cross(B - P0, C - P0) * d).sum(axis=1)
    v3 = (np.cross(C - P0, A - P0) * d).sum(axis=1)
    inside = ((v1 > 0) & (v2 > 0) & (v3 > 0)) | ((v1 < 0) & (v2 < 0) & (v3 < 0))
    return cross & inside


def _tri_tri(X, F, I, J):
    """Do the triangles ``F[I]`` and ``F[J]`` cross in ``X``? (an edge of one through the other)."""
    a, b = X[F[I]], X[F[J]]  # (p, 3, 3)
    hit = np.zeros(len(I), dtype=bool)
    for u, w in ((a, b), (b, a)):
        for e in range(3):
            todo = ~hit
            if not todo.any():
                break
            hit[todo] |= _seg_tri(u[todo, e], u[todo, (e + 1) % 3], w[todo, 0], w[todo, 1], w[todo, 2])
    return hit


def _near_pairs(c, r, among):
    """Pairs ``(i in among, j)`` whose bounding spheres (centres ``c``, radii ``r``) may overlap: the triangles
    bucketed by radius (powers of two: a scan's triangles span 200x in size), one tree per bucket."""
    lv = np.floor(np.log2(np.maximum(r, 1e-300) / max(float(r.max()), 1e-300))).astype(np.int64)
    lv = np.maximum(lv, -12)
    I, J = [], []
    ra = r[among]
    la = lv[among]
    buckets = []
    for b in np.unique(lv):
        ids_b = np.flatnonzero(lv == b)
        buckets.append((ids_b, float(r[ids_b].max()), cKDTree(c[ids_b])))
    for a in np.unique(la):
        ids_a = among[la == a]
        tree_a = cKDTree(c[ids_a])
        Ra = float(ra[la == a].max())
        for ids_b, Rb, tree_b in buckets:
            M = tree_a.sparse_distance_matrix(tree_b, Ra + Rb, output_type="ndarray")
            I.append(ids_a[M["i"]])
            J.append(ids_b[M["j"]])
    return np.concatenate(I), np.concatenate(J)


def crossing_pairs(X, F, among=None, cgal: bool = True) -> np.ndarray:
    """Pairs of triangles of ``(X, F)`` that share no vertex and cross -> ``(p, 2)`` int64, ``i < j``.

    ``among``: triangle ids; only pairs with at least one of them are tested (the rest: not reported).
    ``cgal``: libigl's CGAL test (``igl.copyleft.cgal.remesh_self_intersections``, ``detect_only``: 0.07 s
    on a 17,684-triangle head); False (or no CGAL): this module's numpy test (the same pairs, about 10x slower).
    """
    X = np.asarray(X, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    m = F.shape[0]
    if m < 2:
        return np.zeros((0, 2), dtype=np.int64)
    among = np.arange(m) if among is None else np.asarray(among, dtype=np.int64)
    if among.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if cgal:
        P = _cgal_pairs(X, F, among)
        if P is not None:
            return P
    T = X[F]
    c = T.mean(axis=1)
    r = np.sqrt(((T - c[:, None]) ** 2).sum(axis=2).max(axis=1))
    I, J = _near_pairs(c, r, among)
    keep = (I != J) & (np.linalg.norm(c[I] - c[J], axis=1) <= r[I] + r[J])
    I, J = np.minimum(I[keep], J[keep]), np.maximum(I[keep], J[keep])
    key = np.unique(I * m + J)
    I, J = key // m, key % m
    fi, fj = F[I], F[J]
    share = (fi[:, :, None] == fj[:, None, :]).any(axis=(1, 2))
    I, J = I[~share], J[~share]
    # bounding boxes overlap
    lo_i, hi_i, lo_j, hi_j = T[I].min(axis=1), T[I].max(axis=1), T[J].min(axis=1), T[J].max(axis=1)
    box = ((lo_i <= hi_j) & (lo_j <= hi_i)).all(axis=1)
    I, J = I[box], J[box]
    hit = _tri_tri(X, F, I, J)
    return np.c_[I[hit], J[hit]]


def _moved_triangles(F, D, tol) -> np.ndarray:
    mv = np.linalg.norm(D, axis=1) > tol
    return np.flatnonzero(mv[F].any(axis=1))


def _cgal_pairs(X, F, among):
    """:func:`crossing_pairs` by libigl's CGAL self-intersection test (``detect_only``) on the triangles whose
    bounding box meets the moved ones' (``among``) -> pairs or None when libigl has no CGAL."""
    try:
        from igl.copyleft.cgal import remesh_self_intersections
    except ImportError:  # pragma: no cover - the libigl wheels ship it
        return None
    T = X[F]
    lo, hi = T.min(axis=1), T.max(axis=1)
    blo, bhi = lo[among].min(axis=0), hi[among].max(axis=0)
    sub = np.flatnonzero(((lo <= bhi) & (hi >= blo)).all(axis=1))
    if sub.size < 2:
        return np.zeros((0, 2), dtype=np.int64)
    from facegeom.native import quiet_native

    with quiet_native():
        IF = remesh_self_intersections(np.ascontiguousarray(X), np.ascontiguousarray(F[sub]), detect_only=True)[2]
    P = np.sort(sub[np.asarray(IF, dtype=np.int64).reshape(-1, 2)], axis=1)
    if P.size == 0:
        return P.reshape(0, 2)
    share = (F[P[:, 0]][:, :, None] == F[P[:, 1]][:, None, :]).any(axis=(1, 2))
    P = P[~share]
    mark = np.zeros(F.shape[0], dtype=bool)
    mark[among] = True
    return P[mark[P[:, 0]] | mark[P[:, 1]]]


class RestCrossings:
    """A rest pose's own crossings: the pairs, and the triangles around them (within ``RING`` vertex rings),
    where posed crossings are the scan's, not the transfer's (its crossed sheets slide past one another)."""

    RING = 2

    def __init__(self, V, F):
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        self.pairs = crossing_pairs(V, F)
        near = np.zeros(V.shape[0], dtype=bool)
        near[F[self.pairs.ravel()]] = True
        for _ in range(self.RING):
            near[F[near[F].any(axis=1)]] = True
        self.near = near[F].any(axis=1)  # per triangle
        self.m = F.shape[0]
        self.tol = MOVED_REL * float(np.median(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1)))

    def __len__(self):
        return len(self.pairs)


def new_crossings(V, F, X, rest=None) -> np.ndarray:
    """Pairs crossing in ``X`` that share no vertex and are not the rest ``V``'s own (:class:`RestCrossings`,
    built when None): not crossing at rest, and not both beside a rest crossing -> ``(p, 2)``.

    Only triangles that moved (a vertex by more than :data:`MOVED_REL` of the median edge) are tested: a pair
    that kept still keeps its rest state.
    """
    F = np.asarray(F, dtype=np.int64)
    X = np.asarray(X, dtype=np.float64)
    if rest is None:
        rest = RestCrossings(V, F)
    moved = _moved_triangles(F, X - V, rest.tol)
    if moved.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    P = crossing_pairs(X, F, moved)
    if P.size == 0:
        return P.reshape(0, 2)
    m = rest.m
    old = np.isin(P[:, 0] * m + P[:, 1], rest.pairs[:, 0] * m + rest.pairs[:, 1])
    old |= rest.near[P[:, 0]] & rest.near[P[:, 1]]
    return P[~old]


def recheck_crossings(V, F, X, rest, prev, touched) -> np.ndarray:
    """:func:`new_crossings` of ``X`` when, since the pose whose result was ``prev``, only the triangles ``touched``
    moved: the pairs of ``prev`` without a touched triangle (their triangles kept their places, so their state and
    the rest filter's verdict are the same), and the touched triangles' pairs tested again -> ``(p, 2)``, the
    same set of pairs as :func:`new_crossings` gives (sorted rows). A correction moves a small patch, so the test
    covers that patch's neighbourhood instead of the whole face.
    """
    F = np.asarray(F, dtype=np.int64)
    X = np.asarray(X, dtype=np.float64)
    prev = np.asarray(prev, dtype=np.int64).reshape(-1, 2)
    touched = np.asarray(touched, dtype=np.int64)
    hit = np.zeros(F.shape[0], dtype=bool)
    hit[touched] = True
    kept = prev[~(hit[prev[:, 0]] | hit[prev[:, 1]])]
    moved = np.zeros(F.shape[0], dtype=bool)
    moved[_moved_triangles(F, X - V, rest.tol)] = True
    P = crossing_pairs(X, F, touched) if touched.size else np.zeros((0, 2), dtype=np.int64)
    P = P[moved[P[:, 0]] | moved[P[:, 1]]]  # as new_crossings: a pair with a triangle that moved from the rest
    m = rest.m
    old = np.isin(P[:, 0] * m + P[:, 1], rest.pairs[:, 0] * m + rest.pairs[:, 1])
    old |= rest.near[P[:, 0]] & rest.near[P[:, 1]]
    out = np.unique(np.r_[kept, P[~old]].reshape(-1, 2), axis=0)
    return out.astype(np.int64)


@dataclass
class FoldCheck:
    """Per case (a shape, or shapes together, each at weight 1) the flipped triangles and new crossings.

    ``flipped``: outside the rest pose's own folds; ``scan_flipped``: inside them (within
    :attr:`RestCrossings.RING` rings of a rest crossing: a scan's crease, its slivers' normals ill-defined).
    """

    cases: list  # tuples of shape names
    flipped: list  # per case: triangle ids (int64 arrays), outside the rest's folds
    crossings: list  # per case: (p, 2) triangle pairs, new
    scan_flipped: list  # per case: triangle ids flipped inside the rest's own folds
    rest_crossings: int
    time_s: float

    def counts(self) -> dict:
        """``{"jawOpen+mouthFunnel": (flipped, crossings), ...}`` for the cases with any."""
        return {"+".join(c): (int(f.size), len(x)) for c, f, x in zip(self.cases, self.flipped, self.crossings)
                if f.size or len(x)}

    @property
    def total(self) -> int:
        """Flipped triangles and new crossings over every case (outside the rest's own folds)."""
        return int(sum(f.size + len(x) for f, x in zip(self.flipped, self.crossings)))


def _split(rest, F, V, X):
    f = flipped(V, F, X)
    inside = rest.near[f]
    return f[~inside], f[inside]


def check_shapes(V, F, deltas, names, pairs=PAIRS, rest=None) -> FoldCheck:
    """Every shape of ``deltas (K, n, 3)`` at weight 1 and the ``pairs`` (of ``names``) at 1 each on the skin
    ``(V, F)`` -> :class:`FoldCheck`. Pairs naming a shape not in ``names`` are skipped."""
    import time

    t0 = time.perf_counter()
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    names = list(names)
    if rest is None:
        rest = RestCrossings(V, F)
    cases = [(n,) for n in names if n not in NOT_ALONE] + [tuple(p) for p in pairs if all(x in names for x in p)]
    fl, cr, sf = [], [], []
    for c in cases:
        X = V + sum(deltas[names.index(x)] for x in c)
        f, f_in = _split(rest, F, V, X)
        fl.append(f)
        sf.append(f_in)
        cr.append(new_crossings(V, F, X, rest))
    return FoldCheck(cases, fl, cr, sf, len(rest), time.perf_counter() - t0)


def unfold(V, F, deltas, names, pairs=PAIRS, rest=None, rounds: int = 6, ring: int = 1,
           max_change: float | None = None, report_kept: bool = False, progress=None):
    """Remove the folds :func:`check_shapes` finds by smoothing each offending shape's motion there.

    Per round, in each shape of every case (a shape, or a pair) that folds: the flipped triangles' vertices,
    grown by ``ring`` vertex rings (one more each round), re-solved as the harmonic interpolation (uniform
    Laplacian) of the motion around them; the crossing triangles' vertices (and those within the radius)
    given the mean motion of the vertices within :data:`TOUCH_EDGES` median edge lengths at rest (tent
    weights, the radius growing each round: sheets that lie on one another move as one; 0: harmonic as the
    flips). Until no case folds or ``rounds`` are spent. A shape whose correction would change its motion by more than ``max_change``
    (relative, Frobenius; default :data:`MAX_CHANGE`) is left as it was and reported: that is no longer a
    local defect but the expression itself (the MakeHuman head's lips, folded in the artist's own rig too).
    -> ``(deltas (K, n, 3) corrected, before: FoldCheck, after: FoldCheck, changed: {shape: vertices
    re-solved})``, and ``kept: {shape: relative change}`` with ``report_kept``. ``progress(line)`` hears how
    many fold once they are found, before they are corrected.
    """
    import time

    import scipy.sparse as sp

    from facegeom.linalg import factorize_spd

    t0 = time.perf_counter()
    max_change = MAX_CHANGE if max_change is None else max_change
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    names = list(names)
    n = V.shape[0]
    if rest is None:
        rest = RestCrossings(V, F)
    before = check_shapes(V, F, deltas, names, pairs, rest)
    cases = before.cases
    fl, cr, sf = list(before.flipped), list(before.crossings), list(before.scan_flipped)
    if progress is not None:
        bad = sum(1 for i in range(len(cases)) if fl[i].size or len(cr[i]))
        progress(f"{bad} of {len(cases)} shapes and pairs fold at weight 1" + ("; correcting them ..." if bad else ""))
    E = np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]
    Adj = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    Adj = ((Adj + Adj.T) > 0).astype(np.float64)
    K = (sp.diags(np.asarray(Adj.sum(axis=1)).ravel()) - Adj).tocsr()
    out = np.array(deltas, dtype=np.float64, copy=True)
    changed: dict = {}
    tree = cKDTree(V)
    touch_radius = TOUCH_EDGES * float(np.median(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)))
    for r in range(rounds):
        todo = [i for i in range(len(cases)) if fl[i].size or len(cr[i])]
        if not todo:
            break
        region_of: dict = {}
        touch_of: dict = {}
        now: dict = {}  # shape -> vertices whose motion this round changes
        for i in todo:
            reg = np.zeros(n, dtype=bool)
            reg[F[fl[i]].ravel()] = True
            for _ in range(ring + r):
                reg = reg | (Adj @ reg.astype(np.float64) > 0)
            pts = np.zeros(n, dtype=bool)
            pts[F[np.asarray(cr[i], dtype=np.int64).ravel()].ravel()] = True
            for name in cases[i]:
                region_of[name] = region_of.get(name, np.zeros(n, dtype=bool)) | reg
                touch_of[name] = touch_of.get(name, np.zeros(n, dtype=bool)) | pts
        for name, pts in touch_of.items():  # crossings: the sheets near one another move as one (Euclidean mean)
            if not pts.any() or TOUCH_EDGES <= 0:
                if pts.any():  # harmonic instead, as the flips
                    reg = pts.copy()
                    for _ in range(ring + r):
                        reg = reg | (Adj @ reg.astype(np.float64) > 0)
                    region_of[name] = region_of.get(name, np.zeros(n, dtype=bool)) | reg
                continue
            k = names.index(name)
            radius = (1.0 + r) * touch_radius
            ids = np.flatnonzero(pts)
            near = tree.query_ball_point(V[ids], radius)
            around = np.unique(np.concatenate([np.asarray(x, dtype=np.int64) for x in near]))
            near = tree.query_ball_point(V[around], radius)
            cnt = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
            rows = np.repeat(np.arange(around.size), cnt)
            cols = np.concatenate([np.asarray(x, dtype=np.int64) for x in near])
            w = np.maximum(1.0 - np.linalg.norm(V[around[rows]] - V[cols], axis=1) / radius, 0.0)
            Wm = sp.csr_matrix((w, (rows, cols)), shape=(around.size, n))
            out[k, around] = (Wm @ out[k]) / np.asarray(Wm.sum(axis=1))
            changed[name] = changed.get(name, np.zeros(n, dtype=bool))
            changed[name][around] = True
            now[name] = now.get(name, np.zeros(n, dtype=bool))
            now[name][around] = True
        for name, reg in region_of.items():  # flips: the motion re-solved as the harmonic fill from around
            if reg is None or reg.all() or not reg.any():
                continue
            k = names.index(name)
            inner, outer = np.flatnonzero(reg), np.flatnonzero(~reg)
            K_ii = (K[inner][:, inner] + sp.eye(inner.size) * 1e-12).tocsc()
            out[k, inner] = factorize_spd(K_ii).solve(-(K[inner][:, outer] @ out[k, outer]))
            changed[name] = changed.get(name, np.zeros(n, dtype=bool)) | reg
            now[name] = now.get(name, np.zeros(n, dtype=bool)) | reg
        for i, c in enumerate(cases):  # the cases of a changed shape checked again (crossings: where it changed)
            if any(x in now for x in c):
                X = V + sum(out[names.index(x)] for x in c)
                fl[i], sf[i] = _split(rest, F, V, X)
                where = np.any([now[x] for x in c if x in now], axis=0)
                cr[i] = recheck_crossings(V, F, X, rest, cr[i], np.flatnonzero(where[F].any(axis=1)))
    kept = {}
    for name in list(changed):  # a correction that would reshape the expression is not made: reported instead
        k = names.index(name)
        size = float(np.linalg.norm(deltas[k]))
        rel = float(np.linalg.norm(out[k] - deltas[k])) / max(size, 1e-300)
        if rel > max_change:
            out[k] = deltas[k]
            kept[name] = rel
            del changed[name]
    if kept:
        for i, c in enumerate(cases):
            if any(x in kept for x in c):
                X = V + sum(out[names.index(x)] for x in c)
                fl[i], sf[i] = _split(rest, F, V, X)
                cr[i] = new_crossings(V, F, X, rest)
    after = FoldCheck(cases, fl, cr, sf, len(rest), time.perf_counter() - t0)
    changed = {k: int(v.sum()) for k, v in changed.items()}
    if report_kept:
        return out, before, after, changed, kept
    return out, before, after, changed


def fold_report(before: FoldCheck, after: FoldCheck, changed: dict, kept: dict | None = None) -> dict:
    """What :func:`unfold` found and did, as plain numbers (a transfer's report entry ``folds``)."""
    cases = {}
    for i, c in enumerate(before.cases):
        b = (int(before.flipped[i].size), len(before.crossings[i]))
        a = (int(after.flipped[i].size), len(after.crossings[i]))
        if any(b) or any(a) or before.scan_flipped[i].size or after.scan_flipped[i].size:
            cases["+".join(c)] = {"flipped": b[0], "crossings": b[1], "flipped_after": a[0], "crossings_after": a[1],
                                  "scan_fold_flipped": int(before.scan_flipped[i].size),
                                  "scan_fold_flipped_after": int(after.scan_flipped[i].size)}
    return {"checked": ["+".join(c) for c in before.cases], "cases": cases, "rest_crossings": before.rest_crossings,
            "before": before.total, "after": after.total, "corrected": dict(changed),
            "not_corrected": {k: round(float(v), 3) for k, v in (kept or {}).items()}, "max_change": MAX_CHANGE,
            "check_s": before.time_s, "time_s": after.time_s}
