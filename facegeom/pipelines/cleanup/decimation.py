"""``decimate``: quadric edge collapse (pymeshlab) that never moves a vertex."""
from __future__ import annotations

import time

import numpy as np

from facegeom.errors import InputError
from facegeom.native import quiet_native
from facegeom.pipelines.cleanup.checks import _check_mesh, mesh_problems
from facegeom.pipelines.cleanup.topology import misoriented_edges, orient_pieces
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.meshlab import Progress, _pml, _Run
from facegeom.pipelines.cleanup.report import Report, StepReport

__all__ = ["decimate"]


#: The most faces a vertex may be a corner of (a scan's poles have tens; a 100,000-face fan ran past 120 s).
MAX_VALENCE = 10_000


def decimate(V, F, vertices: int, *, preserve_boundary: bool = False, preserve_topology: bool = False,
             keep=None, progress: Progress = None) -> tuple[np.ndarray, np.ndarray, IndexMap, Report]:
    """Quadric edge-collapse decimation (pymeshlab) down to about ``vertices`` vertices.

    Vertices are never moved (``optimalplacement=False``): the result's
    vertices are an exact subset of the input's, so the map is exact. The
    vertices in ``keep`` (marker ids) are preserved: the faces around them are
    left out of the selection that pymeshlab simplifies, which makes them (and
    their one-ring) unwritable; their survival is checked.

    The face target is re-estimated from the vertex count until at most
    ``vertices`` remain (or no collapse is possible any more).

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions.
    F : (m, 3) int
        Triangles (polygons are refused: run :func:`clean` first).
    vertices : int
        Target vertex count (at least 4).
    preserve_boundary, preserve_topology : bool
        pymeshlab's collapse constraints.
    keep : (k,) int, optional
        Vertex ids that must survive (e.g. marker vertices).
    progress : callable(str), optional
        Called with a message per step and pass.

    Returns
    -------
    V2 : (n2, 3) float
        A subset of the rows of ``V`` (``V2 == V[index_map.new_to_old]``).
    F2 : (m2, 3) int
        The decimated triangles.
    index_map : IndexMap
        Input vertex ids -> ids in ``V2``.
    report : Report
        Counts per step, with notes when the target was not reached.

    Raises
    ------
    InputError
        Bad arrays, a target below 4, a vertex of ``keep`` out of range or not preserved.
    """
    V, F, polygons = _check_mesh(V, F)
    if polygons:
        raise InputError("decimate needs a triangle mesh; run clean first to triangulate")
    target = int(vertices)
    if target < 4:
        raise InputError(f"the vertex target must be at least 4, got {vertices}")
    valence = np.bincount(np.asarray(F, dtype=np.int64).ravel(), minlength=V.shape[0])
    if valence.size and valence.max() > MAX_VALENCE:
        k = int(valence.argmax())
        raise InputError(f"vertex {k} is a corner of {int(valence[k]):,} faces: edge collapses around it cost "
                         f"time quadratic in that (at most {MAX_VALENCE:,}; a fan or a pole no surface mesh has)")
    keep = np.unique(np.asarray([] if keep is None else keep, dtype=np.int64))
    if keep.size and (keep.min() < 0 or keep.max() >= V.shape[0]):
        raise InputError(f"vertex to preserve out of range: the mesh has {V.shape[0]} vertices")
    V2, F2, imap, run = _decimate_once(V, F, target, keep, preserve_boundary, preserve_topology, progress)
    retried = False
    if not preserve_topology and _defects(V2, F2) and not _defects(V, F):
        # the collapses made non-manifold parts on a clean input: redo it with the link condition
        # (pymeshlab's preservetopology), which refuses exactly such collapses
        run._say("  the collapses made non-manifold edges: decimating again with preserve_topology")
        V2, F2, imap, run = _decimate_once(V, F, target, keep, preserve_boundary, True, progress)
        retried = True
    repaired, n_before = "", 0
    if _defects(V2, F2) and not _defects(V, F):
        # still some (pymeshlab's link condition misses a few): split them as `clean` does, keeping every face
        from facegeom.pipelines.cleanup.repair import clean

        before = mesh_problems(V2, F2)
        n_before = V2.shape[0]
        V2, F2, fix, _ = clean(V2, F2, non_manifold="split", orient=False, progress=progress)
        imap = imap.then(fix)
        repaired = (f"{before['non_manifold_edges']} non-manifold edges, {before['non_manifold_vertices']} "
                    f"non-manifold vertices and {before['duplicate_faces']} duplicate faces made by the collapses "
                    f"were repaired as `clean --non-manifold split` does (vertices split, duplicates removed)")
    reoriented = 0
    if misoriented_edges(F2) and not misoriented_edges(F):
        # a collapse turned a face over against its neighbours on a coherently oriented input: turn it back
        # (each piece keeps the orientation most of its faces have)
        flip, _ = orient_pieces(F2)
        reoriented = int(flip.sum())
        F2 = np.where(flip[:, None], F2[:, ::-1], F2)
    rep = run.close(V2, F2, imap)
    if reoriented:
        rep.notes.append(f"{reoriented} face{'s' if reoriented > 1 else ''} turned over by the collapses "
                         f"{'were' if reoriented > 1 else 'was'} turned back to agree with "
                         f"{'their' if reoriented > 1 else 'its'} neighbours")
    if retried:
        rep.notes.append("decimated with preserve_topology: without it the edge collapses made non-manifold edges")
    if repaired:
        rep.notes.append(repaired)
    _add_notes(rep, V2, F2, target, F, keep, imap, split_from=n_before)
    return V2, F2, imap, rep


def _defects(V: np.ndarray, F: np.ndarray) -> int:
    """Non-manifold edges and vertices and duplicate faces of ``(V, F)``."""
    bad = mesh_problems(V, F)
    return bad["non_manifold_edges"] + bad["non_manifold_vertices"] + bad["duplicate_faces"]


def _decimate_once(V, F, target, keep, preserve_boundary, preserve_topology, progress):
    """One decimation of the checked mesh: ``(V2, F2, index map, run)``."""
    run = _Run("decimate", V, F, progress)
    if keep.size:
        _protect(run, keep)
    nv0, nf0 = int(run.mesh.vertex_number()), int(run.mesh.face_number())
    t = time.perf_counter()
    passes = _collapse(run, target, preserve_boundary, preserve_topology, selected=keep.size > 0)
    details = run._track(len(run.report.steps), None)
    cm = run.mesh
    step = StepReport("quadric edge collapse", nv0, int(cm.vertex_number()), nf0, int(cm.face_number()),
                      {"passes": passes, "preserved_vertices": int(keep.size), **details}, time.perf_counter() - t)
    run.add_step(step)
    run.apply("remove unreferenced vertices", "meshing_remove_unreferenced_vertices")
    V2, F2, imap, _ = run.finish()
    # vertices are a subset, never moved (split copies included)
    src = imap.new_to_old
    if (src < 0).any() or not np.array_equal(V2, V[src]):
        raise RuntimeError("decimation moved vertices despite optimalplacement=False")  # pragma: no cover
    lost = keep[imap.old_to_new[keep] < 0]
    if lost.size:
        raise InputError(f"decimation could not preserve vertex {int(lost[0])} ({lost.size} lost)")
    return V2, F2, imap, run


def _protect(run: _Run, keep: np.ndarray) -> None:
    """Select every face not touching a vertex of ``keep`` (only the selection is simplified)."""
    flag = np.zeros(run.n_old)
    flag[keep] = 1.0
    run.mesh.add_vertex_custom_scalar_attribute(flag, "facegeom_keep")
    with quiet_native((1, 2)):
        run.ms.compute_selection_by_condition_per_vertex(condselect="facegeom_keep > 0.5")
        run.ms.compute_selection_transfer_vertex_to_face(inclusive=False)
        run.ms.apply_selection_inverse(invfaces=True, invverts=False)
        run.ms.set_selection_none(allfaces=False, allverts=True)


def _collapse(run: _Run, target: int, preserve_boundary: bool, preserve_topology: bool, selected: bool) -> int:
    """Quadric edge-collapse passes until at most ``target`` vertices remain (at most 8); returns the passes."""
    passes = 0
    while run.mesh.vertex_number() > target and passes < 8:
        cm = run.mesh
        nv, nf = int(cm.vertex_number()), int(cm.face_number())
        # one collapse removes one vertex and about two faces (one on the boundary)
        ratio = nf / max(nv, 1)
        goal = max(int(round(nf - ratio * (nv - target))), 2)
        if selected:  # the target counts the selected (simplifiable) faces
            goal = max(int(cm.selected_face_number()) - (nf - goal), 1)
        run._say(f"  quadric edge collapse pass {passes + 1}: {nv:,} vertices -> about {target:,}")
        try:
            with quiet_native((1, 2)):
                run.ms.meshing_decimation_quadric_edge_collapse(
                    targetfacenum=goal, preserveboundary=bool(preserve_boundary),
                    preservetopology=bool(preserve_topology), optimalplacement=False, selected=selected,
                    autoclean=True, qualitythr=0.3)
        except _pml().PyMeshLabException as exc:
            raise InputError(f"decimation failed in pymeshlab: {exc}") from None
        passes += 1
        if run.mesh.vertex_number() >= nv:  # nothing more can collapse
            break
    return passes


def _add_notes(rep: Report, V2: np.ndarray, F2: np.ndarray, target: int, F_in: np.ndarray,
               keep: np.ndarray, imap: IndexMap, split_from: int = 0) -> None:
    """Notes on a result with non-manifold parts or more vertices than asked; each names its true cause.

    The defects are compared with the input's; preserved vertices are blamed
    only when some were asked for and a defect touches one of them or their
    one-ring.
    """
    bad = mesh_problems(V2, F2)
    nm = bad["non_manifold_edges"] + bad["non_manifold_vertices"] + bad["duplicate_faces"]
    if nm:
        before = mesh_problems(np.zeros((int(F_in.max()) + 1, 3)) if F_in.size else np.zeros((0, 3)), F_in)
        had = before["non_manifold_edges"] + before["non_manifold_vertices"] + before["duplicate_faces"]
        what = (f"the result has {bad['non_manifold_edges']} non-manifold edges, {bad['non_manifold_vertices']} "
                f"non-manifold vertices and {bad['duplicate_faces']} duplicate faces")
        if had:
            cause = (f"the input already had {before['non_manifold_edges']} non-manifold edges, "
                     f"{before['non_manifold_vertices']} non-manifold vertices and {before['duplicate_faces']} "
                     f"duplicate faces: run `facegeom clean` first")
        else:
            cause = "the input had none: the edge collapses made them"
            if keep.size and _near_kept(F2, imap.old_to_new[keep]):
                cause += " (collapse too aggressive around preserved vertices)"
            cause += ": ask for more vertices, add --preserve-topology, or run `facegeom clean` on the result"
        rep.notes.append(f"{what}; {cause}")
    wrong = misoriented_edges(F2)
    if wrong:
        had = misoriented_edges(F_in)
        rep.notes.append(f"the result has {wrong} edges whose two faces disagree in orientation; "
                         + (f"the input already had {had}: run `facegeom clean` first (it orients the faces)" if had
                            else "the collapses made them and they could not be turned back (a piece that cannot "
                                 "be oriented)"))
    if split_from and V2.shape[0] > target >= split_from:
        rep.notes.append(f"ended with {V2.shape[0]:,} vertices (asked {target:,}): the collapses reached "
                         f"{split_from:,}, the repair's split copies added {V2.shape[0] - split_from:,}")
    elif V2.shape[0] > target:
        rep.notes.append(f"stopped at {V2.shape[0]:,} vertices (asked {target:,}): no further collapse was possible "
                         f"under the constraints")


def _near_kept(F: np.ndarray, kept: np.ndarray) -> bool:
    """True when a non-manifold edge, vertex or duplicate face of ``F`` touches a kept vertex or its one-ring."""
    import igl

    kept = kept[kept >= 0]
    if not kept.size:
        return False
    ring = np.zeros(int(F.max()) + 1, bool)
    ring[kept] = True
    ring[np.unique(F[ring[F].any(axis=1)])] = True
    H = np.sort(np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1)
    _, inv, cnt = np.unique(H, axis=0, return_inverse=True, return_counts=True)
    touched = np.zeros_like(ring)
    touched[H[cnt[inv.ravel()] > 2].ravel()] = True
    vm = np.asarray(igl.is_vertex_manifold(F)).astype(bool).ravel()
    touched[: vm.size] |= ~vm
    S = np.sort(F, axis=1)
    _, finv, fcnt = np.unique(S, axis=0, return_inverse=True, return_counts=True)
    touched[S[fcnt[finv.ravel()] > 1].ravel()] = True
    return bool((touched & ring).any())
