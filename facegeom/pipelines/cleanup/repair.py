"""``clean``: repair a dirty mesh (pymeshlab) with an exact index map."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.cleanup.checks import _check_mesh, _non_manifold_edges
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.meshlab import Progress, _pml, _Run
from facegeom.pipelines.cleanup.options import parse_tolerance
from facegeom.pipelines.cleanup.report import Report

__all__ = ["clean"]


def clean(V, F, *, merge_tol=0.0, largest_component: bool = False, non_manifold: str = "split",
          orient: bool = True, progress: Progress = None) -> tuple[np.ndarray, np.ndarray, IndexMap, Report]:
    """Repair a dirty mesh with pymeshlab filters.

    Steps (each reported with its counts): triangulate polygons; merge
    duplicate vertices (exact; then closer than ``merge_tol`` if given); remove
    zero-area faces; remove duplicate faces; repair non-manifold edges and
    vertices; remove unreferenced vertices; keep the largest component
    (optional); orient the faces coherently (each component keeps the
    orientation most of its faces had).

    Parameters
    ----------
    V : (n, 3) float
    F : (m, 3) int triangles, (m, k) int polygons or a list of polygons
    merge_tol : float or str
        0: exact duplicates only. A number: absolute distance. ``'0.01%'``:
        percentage of the bounding-box diagonal.
    largest_component : bool
        Remove every connected component but the one with the most faces
        (components tied with it are kept too).
    non_manifold : {'split', 'remove'}
        Non-manifold edges: split their vertices (no face is lost; a fin becomes
        its own component) or remove faces (may open holes, not refilled).
    orient : bool
        Make face orientation consistent.
    progress : callable(str), optional
        Called with a message per step.

    Returns
    -------
    V2 : (n2, 3) float
        The repaired vertices: surviving input vertices in input order, then
        split copies.
    F2 : (m2, 3) int
        The repaired triangles (input order, then new faces).
    index_map : IndexMap
        Input vertex ids -> ids in ``V2``.
    report : Report
        Counts per step.

    Raises
    ------
    InputError
        Bad arrays (NaN, indices past the vertex count...), or nothing left.
    """
    if non_manifold not in ("split", "remove"):
        raise InputError(f"non_manifold must be 'split' or 'remove', got {non_manifold!r}")
    kind, tol = parse_tolerance(merge_tol)
    V, F, polygons = _check_mesh(V, F)
    run = _Run("clean", V, F, progress, polygons=polygons)
    F_ref = _triangulate(run, V, F) if polygons else F
    run.apply("merge duplicate vertices", "meshing_remove_duplicate_vertices", merge=True)
    if tol > 0:
        ml = _pml()
        thr = ml.PercentageValue(tol) if kind == "percent" else ml.PureValue(tol)
        label = f"{tol:g}%" if kind == "percent" else f"{tol:g}"
        run.apply(f"merge vertices closer than {label}", "meshing_merge_close_vertices", merge=True, threshold=thr)
    run.apply("remove zero-area faces", "meshing_remove_null_faces")
    run.apply("remove duplicate faces", "meshing_remove_duplicate_faces", face_merge=True)
    run.apply("repair non-manifold edges", "meshing_repair_non_manifold_edges",
              method="Split Vertices" if non_manifold == "split" else "Remove Faces", drop_unreferenced=True)
    if non_manifold == "split" and _non_manifold_edges(run.mesh.face_matrix()):
        # splitting can fail where the faces on an edge disagree in orientation: remove faces there
        run.apply("repair non-manifold edges (remove faces)", "meshing_repair_non_manifold_edges",
                  method="Remove Faces")
    run.apply("repair non-manifold vertices", "meshing_repair_non_manifold_vertices", vertdispratio=0.0)
    run.apply("remove unreferenced vertices", "meshing_remove_unreferenced_vertices")
    if run.mesh.face_number() == 0:
        raise InputError("nothing is left of the mesh after cleaning (every face was degenerate)")
    if largest_component:
        _keep_largest_component(run)
    oriented = orient and run.apply("orient faces coherently", "meshing_re_orient_faces_coherently",
                                    optional=True) is not None
    V2, F2, imap, fids = run.finish()
    left = _non_manifold_edges(F2)
    if left:  # pragma: no cover - not seen: every repair above ran
        run.report.notes.append(f"{left} non-manifold edges are left")
    if oriented:
        flipped = _restore_majority_orientation(F2, imap, fids, F_ref, run.rep)
        st = run.report.steps[-1]
        st.details["reoriented_faces"] = flipped
    return V2, F2, imap, run.close(V2, F2, imap)


def _triangulate(run: _Run, V: np.ndarray, F: list) -> np.ndarray:
    """Triangulate the polygons of ``run`` and restart its face ids on the triangles.

    Parameters
    ----------
    run : _Run
        Holds the polygon mesh; its MeshSet is replaced by the triangle mesh.
    V : (n, 3) float
        The input vertices (exact positions: the polygon mesh holds float32).
    F : list of (k,) int
        The input polygons.

    Returns
    -------
    F_ref : (m', 3) int
        The triangles in input vertex ids (the reference orientation).
    """
    ml = _pml()
    n_poly = sum(1 for p in F if len(p) > 3)
    run.apply("triangulate polygons", "meshing_poly_to_tri")
    run.report.steps[-1].details["split_polygons"] = n_poly
    run.report.input_faces = len(F)
    run.report.steps[-1].faces_before = len(F)
    Ft = run.mesh.face_matrix().astype(np.int64)
    ids = run.vertex_ids()
    if (ids < 0).any():  # pragma: no cover - triangulation creates no vertex
        raise InputError("triangulating the polygons created vertices")
    Vt = V[ids]  # the polygon constructor stores float32 positions: take the exact ones back
    run.ms = ml.MeshSet()
    run.ms.add_mesh(ml.Mesh(Vt, Ft.astype(np.int32), v_scalar_array=ids + 1.0,
                            f_scalar_array=np.arange(1, Ft.shape[0] + 1, dtype=np.float64)))
    run.alias = np.arange(Ft.shape[0], dtype=np.int64)
    return ids[Ft]


def _keep_largest_component(run: _Run) -> None:
    """Remove every component with fewer faces than the largest (a reported step)."""
    from facegeom.geometry import connected_components

    Fc = run.mesh.face_matrix().astype(np.int64)
    _, lab = connected_components(Fc, run.mesh.vertex_number())
    sizes = np.bincount(lab[Fc[:, 0]])
    step = run.apply("keep the largest component", "meshing_remove_connected_component_by_face_number",
                     mincomponentsize=int(sizes.max()), removeunref=True)
    step.details["removed_components"] = int((sizes[sizes > 0] < sizes.max()).sum())


def _cyclic_same(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per row: is ``b`` an even permutation (rotation) of ``a``? Rows must hold the same 3 ids."""
    return (((a[:, 0] == b[:, 0]) & (a[:, 1] == b[:, 1])) | ((a[:, 0] == b[:, 1]) & (a[:, 1] == b[:, 2]))
            | ((a[:, 0] == b[:, 2]) & (a[:, 1] == b[:, 0])))


def _restore_majority_orientation(F2, imap: IndexMap, fids, F_ref, rep) -> int:
    """pymeshlab orients each component after its first face; keep the majority's orientation instead.

    Flips (in place) the components where most faces came out reversed from the
    input; returns how many faces now differ in orientation from the input.
    """
    from facegeom.geometry import connected_components

    src = imap.new_to_old[F2]
    ok = (fids >= 0) & (src >= 0).all(axis=1)
    orig = F_ref[fids[ok]]
    orig = np.where(orig >= 0, rep[np.maximum(orig, 0)], -1)
    same_set = (np.sort(orig, axis=1) == np.sort(src[ok], axis=1)).all(axis=1)
    rows = np.flatnonzero(ok)[same_set]
    flipped = np.zeros(F2.shape[0], bool)
    flipped[rows] = ~_cyclic_same(orig[same_set], src[rows])
    compared = np.zeros(F2.shape[0], bool)
    compared[rows] = True
    _, lab = connected_components(F2, imap.n_new)
    comp = lab[F2[:, 0]]
    nc = int(comp.max()) + 1
    n_flip = np.bincount(comp[flipped], minlength=nc)
    n_same = np.bincount(comp[compared & ~flipped], minlength=nc)
    bad = n_flip > n_same
    if bad.any():
        sel = bad[comp]
        F2[sel] = F2[sel][:, [0, 2, 1]]
        flipped[sel & compared] = ~flipped[sel & compared]
    return int(flipped.sum())
