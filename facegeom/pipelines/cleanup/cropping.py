"""``crop``: keep a geodesic disc or a vertex-id range of a mesh."""
from __future__ import annotations

import time

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.cleanup.checks import _check_mesh
from facegeom.pipelines.cleanup.geodesic import geodesic_distance
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.meshlab import Progress
from facegeom.pipelines.cleanup.report import Report, StepReport

__all__ = ["crop"]


def crop(V, F, *, sources=None, radius: float | None = None, id_range: tuple[int, int] | None = None,
         geodesic: str = "exact", progress: Progress = None) -> tuple[np.ndarray, np.ndarray, IndexMap, Report]:
    """Keep a region: vertices within geodesic ``radius`` of ``sources``, or ids in ``id_range`` = [A, B).

    Faces with a vertex outside the region are removed, then unreferenced
    vertices; the rest keep their input order. Geodesic distances are solved
    only on the faces that can lie within ``radius`` of a source (the balls of
    that radius around them), so a small crop of a large scan costs little.

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    F : (m, 3) int
        Triangles.
    sources : (k,) int, optional
        Centre vertices of a geodesic disc (with ``radius``).
    radius : float, optional
        Geodesic radius, in the units of ``V``.
    id_range : (int, int), optional
        Keep the vertex ids in ``[A, B)`` instead.
    geodesic : {'exact', 'heat', 'graph'}
        See :func:`geodesic_distance`.
    progress : callable(str), optional
        Called with a message per step.

    Returns
    -------
    V2 : (n2, 3) float
        The kept vertices, in input order.
    F2 : (m2, 3) int
        The faces whose three vertices are kept.
    index_map : IndexMap
        Input vertex ids -> ids in ``V2``.
    report : Report
        Counts per step.
    """
    V, F, polygons = _check_mesh(V, F)
    if polygons:
        raise InputError("crop needs a triangle mesh; run clean first to triangulate")
    n = V.shape[0]
    if (sources is None) == (id_range is None):
        raise InputError("crop needs either source vertices with a radius or an id range (not both)")
    t0 = time.perf_counter()
    report = Report("crop", n, int(F.shape[0]))

    def say(msg: str) -> None:
        if progress is not None:
            progress(msg)

    say(f"crop: {n:,} vertices, {F.shape[0]:,} faces")
    t = time.perf_counter()
    if sources is not None:
        if radius is None or not np.isfinite(radius) or radius <= 0:
            raise InputError(f"the crop radius must be a positive number, got {radius!r}")
        say(f"  {geodesic} geodesic distances from {len(np.atleast_1d(sources))} vertices ...")
        inside = _within_geodesic(V, F, sources, float(radius), geodesic)
        what = f"select vertices within {radius:g} ({geodesic} geodesic)"
    else:
        a, b = id_range
        if a < 0 or b <= a or a >= n:
            raise InputError(f"id range {a}:{b} holds no vertex of the {n}")
        inside = np.zeros(n, bool)
        inside[a:min(b, n)] = True
        what = f"select ids {a}:{min(b, n)}"
    report.steps.append(StepReport(what, n, n, F.shape[0], F.shape[0], {"selected_vertices": int(inside.sum())},
                                   time.perf_counter() - t))
    # the region's faces and vertices, in input order (what removing the outside in pymeshlab gave, without
    # copying a large mesh into it)
    names = ("remove vertices outside and their faces", "remove unreferenced vertices")
    t = time.perf_counter()
    say(f"  {names[0]} ...")
    keep_face = inside[F].all(axis=1)
    F_in = F[keep_face]
    report.steps.append(StepReport(names[0], n, int(inside.sum()), F.shape[0], F_in.shape[0], {},
                                   time.perf_counter() - t))
    t = time.perf_counter()
    say(f"  {names[1]} ...")
    used = np.zeros(n, bool)
    used[F_in.ravel()] = True
    report.steps.append(StepReport(names[1], int(inside.sum()), int(used.sum()), F_in.shape[0], F_in.shape[0], {},
                                   time.perf_counter() - t))
    if F_in.shape[0] == 0:
        raise InputError("the crop region holds no whole face: nothing would be left")
    new_to_old = np.flatnonzero(used)
    old_to_new = np.full(n, -1, dtype=np.int64)
    old_to_new[new_to_old] = np.arange(new_to_old.size)
    step = np.where(used, "", np.where(inside, names[1], names[0]))
    imap = IndexMap(old_to_new, new_to_old, step)
    V2, F2 = V[new_to_old], np.ascontiguousarray(old_to_new[F_in])
    report.output_vertices, report.output_faces = int(V2.shape[0]), int(F2.shape[0])
    report.index_map = imap.counts()
    report.seconds = time.perf_counter() - t0
    say(f"crop: done in {report.seconds:.2f} s")
    return V2, F2, imap, report


def _within_geodesic(V: np.ndarray, F: np.ndarray, sources, radius: float, geodesic: str) -> np.ndarray:
    """Vertices within geodesic ``radius`` of ``sources``, computed on the part of the mesh that can hold them.

    A surface path of length at most ``radius`` from a source never leaves the ball of that radius around the
    source, so the distances up to ``radius`` on the faces that meet those balls are those on the whole mesh:
    a crop of a 2-million-vertex scan solves only its region (the heat method's factorisation of the whole
    mesh took over 6 GB).
    """
    from scipy.spatial import cKDTree

    n = V.shape[0]
    src = np.unique(np.asarray(sources, dtype=np.int64).ravel())
    if src.size == 0:
        raise InputError("at least one source vertex is needed")
    if src.min() < 0 or src.max() >= n:
        raise InputError(f"source vertex {int(src.max() if src.max() >= n else src.min())} is out of range: "
                         f"the mesh has {n} vertices")
    F = np.asarray(F, dtype=np.int64)
    near, _ = cKDTree(V[src]).query(V, distance_upper_bound=np.inf)
    E = V[F]
    size = np.sqrt(np.maximum.reduce([((E[:, i] - E[:, (i + 1) % 3]) ** 2).sum(1) for i in range(3)]))
    # a face that meets a ball has every corner within the radius plus its own longest edge of that ball's centre
    meet = (near[F] <= radius + size[:, None] * (1 + 1e-9)).all(axis=1)
    Fm = F[meet]
    if Fm.shape[0]:
        # only the pieces that hold a source: any other piece is farther than the radius along the surface
        import scipy.sparse as sp
        from scipy.sparse.csgraph import connected_components

        rows = np.repeat(np.arange(Fm.shape[0]), 3)
        A = sp.csr_matrix((np.ones(rows.size), (rows, Fm.ravel())), shape=(Fm.shape[0], n))
        _, label = connected_components(A.T @ A, directed=False)
        Fm = Fm[np.isin(label[Fm[:, 0]], label[src])]
    region = np.zeros(n, bool)
    region[Fm.ravel()] = True
    region[src] = True
    ids = np.flatnonzero(region)
    remap = np.full(n, -1, dtype=np.int64)
    remap[ids] = np.arange(ids.size)
    d = np.full(n, np.inf)
    Fr = remap[Fm]
    if Fr.shape[0] == 0:
        d[src] = 0.0
    else:
        d[ids] = geodesic_distance(V[ids], Fr, remap[src], limit=radius, method=geodesic)
    return d <= radius
