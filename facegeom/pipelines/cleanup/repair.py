"""``clean``: repair a dirty mesh (pymeshlab) with an exact index map."""
from __future__ import annotations

import numpy as np

from facegeom.errors import InputError
from facegeom.pipelines.cleanup.checks import _check_mesh, _non_manifold_edges, _non_manifold_vertices
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.meshlab import Progress, _pml, _Run
from facegeom.pipelines.cleanup.options import parse_tolerance
from facegeom.pipelines.cleanup.report import Report, StepReport
from facegeom.pipelines.cleanup.topology import edge_face_counts, orient_pieces, split_corners

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
    if not polygons:
        done = _fixed_point(V, F, kind, tol, largest_component, orient, progress)
        if done is not None:
            return done
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
    _refuse_pathological(run.mesh.face_matrix())
    run.apply("repair non-manifold edges", "meshing_repair_non_manifold_edges",
              method="Split Vertices" if non_manifold == "split" else "Remove Faces", drop_unreferenced=True)
    if non_manifold == "split" and _non_manifold_edges(run.mesh.face_matrix()):
        # pymeshlab cannot split where the faces on an edge disagree in orientation: cut there in numpy
        _split_in_numpy(run)
    if non_manifold == "split" and _non_manifold_edges(run.mesh.face_matrix()):  # pragma: no cover - not seen
        step = run.apply("repair non-manifold edges (remove faces)", "meshing_repair_non_manifold_edges",
                         method="Remove Faces")
        run.report.notes.append(f"splitting left non-manifold edges: {step.faces_before - step.faces_after} "
                                f"faces were removed")
    step = run.apply("repair non-manifold vertices", "meshing_repair_non_manifold_vertices", vertdispratio=0.0)
    _finish_vertex_repair(run, step)
    run.apply("remove unreferenced vertices", "meshing_remove_unreferenced_vertices")
    if run.mesh.face_number() == 0:
        raise InputError("nothing is left of the mesh after cleaning (every face was degenerate)")
    if largest_component:
        _keep_largest_component(run)
    V2, F2, imap, fids = run.finish()
    left = _non_manifold_edges(F2)
    if left:  # pragma: no cover - not seen: every repair above ran
        run.report.notes.append(f"{left} non-manifold edges are left")
    if orient:
        _orient(run, F2, imap, fids, F_ref)
    return V2, F2, imap, run.close(V2, F2, imap)


def _fixed_point(V, F, kind, tol, largest_component, orient, progress):
    """``V, F`` unchanged with the identity map when ``clean`` has nothing to repair, else None.

    That is: every vertex referenced, no degenerate or duplicate face, edge-
    and vertex-manifold, every orientable piece coherently oriented, a single
    largest component when asked, no vertices closer than ``merge_tol`` but
    exactly coincident ones, and merging those would only recreate the
    non-manifold contacts (or degenerate/duplicate faces) that splitting them
    repaired. Such a mesh is what ``clean`` returns, so a second ``clean`` is
    the identity (without this, it merges split copies and splits them again).
    """
    import time

    import igl

    from facegeom.geometry import connected_components

    t0 = time.perf_counter()
    n, m = V.shape[0], F.shape[0]
    if np.unique(F).size != n or not _faces_ok(V, F) or edge_face_counts(F)[0]:
        return None
    if not np.asarray(igl.is_vertex_manifold(F)).astype(bool).all():
        return None
    if orient and orient_pieces(F)[0].any():
        return None
    if largest_component:
        _, lab = connected_components(F, n)
        sizes = np.bincount(lab[F[:, 0]])
        if (sizes[sizes > 0] < sizes.max()).any():
            return None
    if tol > 0:
        from scipy.spatial import cKDTree

        thr = tol if kind != "percent" else tol / 100 * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
        pairs = cKDTree(V).query_pairs(thr, output_type="ndarray")
        if pairs.size and (V[pairs[:, 0]] != V[pairs[:, 1]]).any(axis=1).any():
            return None
    _, inv, cnt = np.unique(V, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if (cnt > 1).any():  # coincident vertices: merging them must break the mesh, else clean would merge them
        Fm = inv[F]
        if not _faces_ok(V, Fm, check_area=False):
            pass  # merging makes degenerate or duplicate faces: clean would lose faces, so they stay apart
        else:
            bad = np.zeros(cnt.size, bool)
            vm = np.asarray(igl.is_vertex_manifold(Fm)).astype(bool).ravel()
            bad[: vm.size] = ~vm
            H = np.sort(np.r_[Fm[:, [0, 1]], Fm[:, [1, 2]], Fm[:, [2, 0]]], axis=1)
            _, hinv, hcnt = np.unique(H, axis=0, return_inverse=True, return_counts=True)
            nm = H[hcnt[hinv.ravel()] > 2]
            bad[nm.ravel()] = True
            if not bad[cnt > 1].all():
                return None
    names = ["merge duplicate vertices"]
    if tol > 0:
        names.append(f"merge vertices closer than {tol:g}%" if kind == "percent" else f"merge vertices closer than "
                     f"{tol:g}")
    names += ["remove zero-area faces", "remove duplicate faces", "repair non-manifold edges",
              "repair non-manifold vertices", "remove unreferenced vertices"]
    if largest_component:
        names.append("keep the largest component")
    rep = Report("clean", n, m, n, m)
    rep.steps = [StepReport(k, n, n, m, m) for k in names]
    if orient:
        rep.steps.append(StepReport("orient faces coherently", n, n, m, m, {"reoriented_faces": 0}))
    imap = IndexMap.identity(n)
    rep.index_map = imap.counts()
    rep.seconds = time.perf_counter() - t0
    if progress is not None:
        progress(f"clean: {n:,} vertices, {m:,} faces: nothing to repair")
    return V.copy(), F.copy(), imap, rep


def _faces_ok(V, F, check_area: bool = True) -> bool:
    """No face with a repeated vertex (or zero area), no two faces on the same three vertices."""
    if ((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])).any():
        return False
    if check_area and (np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]) == 0).all(axis=1).any():
        return False
    return np.unique(np.sort(F, axis=1), axis=0).shape[0] == F.shape[0]


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


def _flipped_from_input(F2, imap: IndexMap, fids, F_ref, rep) -> np.ndarray:
    """Per final face: 1 if reversed from its input face, 0 if not, -1 if it cannot be compared."""
    src = imap.new_to_old[F2]
    src = np.where(src >= 0, rep[np.maximum(src, 0)], -1)
    out = np.full(F2.shape[0], -1, dtype=np.int64)
    ok = (fids >= 0) & (src >= 0).all(axis=1)
    orig = F_ref[fids[ok]]
    orig = np.where(orig >= 0, rep[np.maximum(orig, 0)], -1)
    same_set = (np.sort(orig, axis=1) == np.sort(src[ok], axis=1)).all(axis=1)
    rows = np.flatnonzero(ok)[same_set]
    out[rows] = ~_cyclic_same(orig[same_set], src[rows])
    return out


def _orient(run: _Run, F2: np.ndarray, imap: IndexMap, fids, F_ref) -> None:
    """Orient every piece of ``F2`` (in place) on its own; a reported step, a note per non-orientable piece.

    Each orientable piece (faces joined by edges with two faces) keeps the
    orientation most of its faces had in the input; a non-orientable piece (a
    Möbius strip) keeps its faces as they are and is named in a note.
    """
    import time

    t = time.perf_counter()
    ref = _flipped_from_input(F2, imap, fids, F_ref, run.rep)
    flip, bad = orient_pieces(F2, ref)
    F2[flip] = F2[flip][:, [0, 2, 1]]
    ref = np.where(ref >= 0, ref.astype(bool) ^ flip, -1)
    nv, nf = imap.n_new, int(F2.shape[0])
    run.add_step(StepReport("orient faces coherently", nv, nv, nf, nf, {"reoriented_faces": int((ref == 1).sum())},
                            time.perf_counter() - t))
    for f, size in bad:
        run.report.notes.append(f"orient faces coherently: the piece of {size} faces with face {f} is not "
                                f"orientable (e.g. a Moebius strip); its faces are left as they were, every "
                                f"other piece is oriented")


def _refuse_pathological(F) -> None:
    """Refuse a 'mesh' whose non-manifold edges are a large share of its edges (pymeshlab would run away).

    Raises
    ------
    InputError
        More than 100 non-manifold edges and more than 10 % of the edges.
    """
    nm, ne = edge_face_counts(F)
    if nm > 100 and nm > 0.1 * ne:
        raise InputError(f"{nm:,} of the {ne:,} edges ({100 * nm / ne:.0f} %) have more than two faces: this is not "
                         f"a surface (e.g. a voxel grid with its inner faces); clean refuses it, extract its outer "
                         f"surface first")


def _cut_corners(run: _Run, k: int) -> tuple[int, int, int, dict[str, int], float]:
    """Replace the mesh of ``run`` by its :func:`split_corners` cut (every face kept, copies keep their ids).

    Returns the vertex counts before and after, the face count, the tracked
    details (``split_copies``) and the wall time; ``k`` is the index of the
    step the cut is counted in.
    """
    import time

    ml = _pml()
    t = time.perf_counter()
    cm = run.mesh
    F = cm.face_matrix().astype(np.int64)
    V = cm.vertex_matrix()
    vq = cm.vertex_scalar_array()
    fq = cm.face_scalar_array()
    F2, src = split_corners(F, V.shape[0])
    run.ms = ml.MeshSet()
    run.ms.add_mesh(ml.Mesh(V[src], F2.astype(np.int32), v_scalar_array=vq[src], f_scalar_array=fq))
    details = run._track(k, None)
    return int(V.shape[0]), int(src.size), int(F.shape[0]), details, time.perf_counter() - t


def _split_in_numpy(run: _Run) -> None:
    """Cut the remaining non-manifold edges and vertices (numpy), keeping every face; a reported step.

    The copies carry the id of the vertex they were split from, the faces
    keep theirs, so the index map stays exact.
    """
    nv0, nv1, nf, details, sec = _cut_corners(run, len(run.report.steps))
    run.add_step(StepReport("repair non-manifold edges (cut)", nv0, nv1, nf, nf, details, sec))


def _finish_vertex_repair(run: _Run, step: StepReport) -> None:
    """Cut, in numpy, the non-manifold vertices pymeshlab's vertex repair left; counted in ``step``.

    pymeshlab splits one fan off each non-manifold vertex per call, so a
    vertex where three or more fans meet (e.g. left by removing the faces of
    non-manifold edges) stays non-manifold, and a second ``clean`` would merge
    the split copies and split again. :func:`split_corners` gives every fan
    its own copy at once, so one pass reaches the fixed point. Only run on an
    edge-manifold mesh (it would cut non-manifold edges too).
    """
    F = run.mesh.face_matrix()
    if not _non_manifold_vertices(F) or _non_manifold_edges(F):
        return
    _, nv1, _, details, sec = _cut_corners(run, run.report.steps.index(step))
    step.vertices_after = nv1
    for key, val in details.items():
        step.details[key] = step.details.get(key, 0) + val
    step.seconds += sec
