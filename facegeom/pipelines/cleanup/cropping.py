"""``crop``: keep a geodesic disc or a vertex-id range of a mesh."""
from __future__ import annotations

import time

import numpy as np

from facegeom.errors import InputError
from facegeom.native import quiet_native
from facegeom.pipelines.cleanup.checks import _check_mesh
from facegeom.pipelines.cleanup.geodesic import geodesic_distance
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.meshlab import Progress, _Run
from facegeom.pipelines.cleanup.report import Report, StepReport

__all__ = ["crop"]


def crop(V, F, *, sources=None, radius: float | None = None, id_range: tuple[int, int] | None = None,
         geodesic: str = "exact", progress: Progress = None) -> tuple[np.ndarray, np.ndarray, IndexMap, Report]:
    """Keep a region: vertices within geodesic ``radius`` of ``sources``, or ids in ``id_range`` = [A, B).

    Faces with a vertex outside the region are removed, then unreferenced
    vertices (pymeshlab selection + ``meshing_remove_selected_vertices``).

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
    run = _Run("crop", V, F, progress)
    t = time.perf_counter()
    if sources is not None:
        if radius is None or not np.isfinite(radius) or radius <= 0:
            raise InputError(f"the crop radius must be a positive number, got {radius!r}")
        run._say(f"  {geodesic} geodesic distances from {len(np.atleast_1d(sources))} vertices ...")
        d = geodesic_distance(V, F, sources, limit=radius, method=geodesic)
        inside = d <= radius
        what = f"select vertices within {radius:g} ({geodesic} geodesic)"
    else:
        a, b = id_range
        if a < 0 or b <= a or a >= n:
            raise InputError(f"id range {a}:{b} holds no vertex of the {n}")
        inside = np.zeros(n, bool)
        inside[a:min(b, n)] = True
        what = f"select ids {a}:{min(b, n)}"
    run.add_step(StepReport(what, n, n, F.shape[0], F.shape[0], {"selected_vertices": int(inside.sum())},
                            time.perf_counter() - t))
    run.mesh.add_vertex_custom_scalar_attribute(inside.astype(np.float64), "facegeom_inside")
    with quiet_native((1, 2)):
        run.ms.compute_selection_by_condition_per_vertex(condselect="facegeom_inside < 0.5")
    run.apply("remove vertices outside and their faces", "meshing_remove_selected_vertices")
    run.apply("remove unreferenced vertices", "meshing_remove_unreferenced_vertices")
    if run.mesh.face_number() == 0:
        raise InputError("the crop region holds no whole face: nothing would be left")
    V2, F2, imap, _ = run.finish()
    return V2, F2, imap, run.close(V2, F2, imap)
