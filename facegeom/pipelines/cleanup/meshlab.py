"""The pymeshlab runner: a MeshSet whose vertices and faces carry their input ids.

Each vertex enters pymeshlab with its id + 1 as vertex quality and each face
with its id + 1 as face quality; every step records which old vertices it
merged or removed, and :meth:`_Run.finish` turns that into an exact
:class:`~facegeom.pipelines.cleanup.indexmap.IndexMap`.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from facegeom.errors import InputError
from facegeom.native import quiet_native
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.report import Report, StepReport

Progress = Callable[[str], None] | None


def _pml():
    import pymeshlab

    return pymeshlab


def _face_keys(T: np.ndarray, n: int) -> np.ndarray:
    """One integer per face, the same for faces on the same three vertices (any order)."""
    T = np.sort(np.asarray(T, dtype=np.int64), axis=1) + 1  # -1 (no id) -> 0
    n = int(n) + 1
    if n ** 3 < 2 ** 62:
        return (T[:, 0] * n + T[:, 1]) * n + T[:, 2]
    _, inv = np.unique(T, axis=0, return_inverse=True)  # pragma: no cover - over ~1.6 million vertices
    return inv.ravel().astype(np.int64)


def _resolve(rep: np.ndarray) -> np.ndarray:
    """Follow merge chains (a -> b -> c) to their end."""
    rep = rep.copy()
    while True:
        nxt = np.where(rep >= 0, rep[np.maximum(rep, 0)], -1)
        if np.array_equal(nxt, rep):
            return rep
        rep = nxt


class _Run:
    """A pymeshlab MeshSet whose vertices and faces carry their input ids; records each step."""

    def __init__(self, operation: str, V: np.ndarray, F, progress: Progress, polygons: bool = False):
        ml = _pml()
        self.t0 = time.perf_counter()
        self.progress = progress
        self.n_old = V.shape[0]
        self.V0 = V
        self.ms = ml.MeshSet()
        vq = np.arange(1, self.n_old + 1, dtype=np.float64)
        if polygons:
            mesh = ml.Mesh(V, [np.asarray(p, dtype=np.uint32) for p in F], v_scalar_array=vq)
        else:
            mesh = ml.Mesh(V, F.astype(np.int32), v_scalar_array=vq,
                           f_scalar_array=np.arange(1, F.shape[0] + 1, dtype=np.float64))
        self.ms.add_mesh(mesh)
        self.rep = np.arange(self.n_old, dtype=np.int64)  # merge target of each old vertex
        self.step_of = np.full(self.n_old, -1, dtype=np.int64)  # step that merged/removed it
        self.present = np.ones(self.n_old, bool)
        self.alias = np.arange(max(len(F), 1), dtype=np.int64)  # input face id each face stands for
        cm = self.ms.current_mesh()
        self.report = Report(operation, self.n_old, int(cm.face_number()))
        self._say(f"{operation}: {self.n_old:,} vertices, {cm.face_number():,} faces")

    def _say(self, msg: str) -> None:
        if self.progress is not None:
            self.progress(msg)

    @property
    def mesh(self):
        return self.ms.current_mesh()

    def vertex_ids(self) -> np.ndarray:
        return np.rint(self.mesh.vertex_scalar_array()).astype(np.int64) - 1

    def face_ids(self) -> np.ndarray:
        return np.rint(self.mesh.face_scalar_array()).astype(np.int64) - 1

    def faces_in_old_ids(self) -> tuple[np.ndarray, np.ndarray]:
        return self.face_ids(), self.vertex_ids()[self.mesh.face_matrix().astype(np.int64)]

    def apply(self, name: str, filt: str, merge: bool = False, drop_unreferenced: bool = False,
              face_merge: bool = False, optional: bool = False, **kw) -> StepReport | None:
        cm = self.mesh
        nv0, nf0 = int(cm.vertex_number()), int(cm.face_number())
        self._say(f"  {name} ...")
        t = time.perf_counter()
        before = self.faces_in_old_ids() if (merge or face_merge) else None
        try:
            with quiet_native((1, 2)):
                getattr(self.ms, filt)(**kw)
                if drop_unreferenced:  # e.g. 'Split Vertices' first copies every vertex
                    self.ms.meshing_remove_unreferenced_vertices()
        except _pml().PyMeshLabException as exc:
            reason = " ".join(str(exc).split())
            if optional:  # the mesh is unchanged when a filter refuses to run
                self.report.notes.append(f"{name}: skipped, pymeshlab refused: {reason}")
                return None
            raise InputError(f"{name} failed in pymeshlab ({filt}): {reason}") from None
        if face_merge:
            self._alias_faces(before)
        details = self._track(len(self.report.steps), before if merge else None)
        cm = self.mesh
        step = StepReport(name, nv0, int(cm.vertex_number()), nf0, int(cm.face_number()), details,
                          time.perf_counter() - t)
        self.report.steps.append(step)
        return step

    def add_step(self, step: StepReport) -> None:
        self.report.steps.append(step)

    def _alias_faces(self, before) -> None:
        """A duplicate face that survives takes the lowest input face id of its copies (keeps face order)."""
        fid0, F0 = before
        fid1, F1 = self.faces_in_old_ids()
        alive = np.zeros(self.alias.size, bool)
        alive[fid1[fid1 >= 0]] = True
        gone_rows = np.flatnonzero((fid0 >= 0) & ~alive[np.maximum(fid0, 0)])
        if not gone_rows.size:
            return
        keep_rows = np.flatnonzero(fid1 >= 0)
        k_surv = _face_keys(F1[keep_rows], self.n_old)
        k_gone = _face_keys(F0[gone_rows], self.n_old)
        order = np.argsort(k_surv, kind="stable")
        pos = np.searchsorted(k_surv[order], k_gone)
        pos = np.minimum(pos, order.size - 1)
        hit = k_surv[order][pos] == k_gone
        surv_fid = fid1[keep_rows[order[pos[hit]]]]
        np.minimum.at(self.alias, surv_fid, self.alias[fid0[gone_rows[hit]]])

    def _track(self, k: int, before) -> dict[str, int]:
        ids = self.vertex_ids()
        now = np.zeros(self.n_old, bool)
        now[ids[ids >= 0]] = True
        vanished = np.flatnonzero(self.present & ~now)
        details: dict[str, int] = {}
        if before is not None and vanished.size:
            merged_into = np.full(self.n_old, -1, dtype=np.int64)
            fid0, F0 = before
            fid1, F1 = self.faces_in_old_ids()
            pos0 = np.full(max(int(fid0.max(initial=-1)), int(fid1.max(initial=-1))) + 1, -1, dtype=np.int64)
            ok0 = fid0 >= 0
            pos0[fid0[ok0]] = np.flatnonzero(ok0)
            ok1 = fid1 >= 0
            rows1 = np.flatnonzero(ok1)
            rows0 = pos0[fid1[ok1]]
            good = rows0 >= 0
            a = F0[rows0[good]].ravel()
            b = F1[rows1[good]].ravel()
            sel = (a != b) & (a >= 0) & (b >= 0)
            a, b = a[sel], b[sel]
            sel = ~now[a] & now[b]
            merged_into[a[sel]] = b[sel]
            rest = vanished[merged_into[vanished] < 0]
            if rest.size:  # unreferenced duplicates: nearest survivor
                from scipy.spatial import cKDTree

                alive = np.flatnonzero(now)
                _, j = cKDTree(self.V0[alive]).query(self.V0[rest])
                merged_into[rest] = alive[j]
            self.rep[vanished] = merged_into[vanished]
            details["merged_vertices"] = int(vanished.size)
        self.step_of[vanished] = k
        new = int((ids < 0).sum())
        copies = int((ids >= 0).sum() - now.sum())
        prev_new = getattr(self, "_new", 0)
        prev_copies = getattr(self, "_copies", 0)
        if new != prev_new:
            details["new_vertices"] = new - prev_new
        if copies != prev_copies:
            details["split_copies"] = copies - prev_copies
        self._new, self._copies = new, copies
        self.present = now
        return details

    def finish(self):
        """Final ``V, F`` (new ids), the index map, and each final face's input face id (-1: new face).

        Vertices come in input order (one per surviving input vertex), then
        split copies and new vertices; faces come in input order, then new faces.
        """
        cm = self.mesh
        V = np.ascontiguousarray(cm.vertex_matrix(), dtype=np.float64)
        F = np.ascontiguousarray(cm.face_matrix(), dtype=np.int64)
        ids = self.vertex_ids()
        fids = self.face_ids()
        fids = np.where(fids >= 0, self.alias[np.clip(fids, 0, self.alias.size - 1)], -1)
        n_new = V.shape[0]
        # vertices created with no id: a copy of an old vertex at the very same position?
        fresh = np.flatnonzero(ids < 0)
        if fresh.size and (ids >= 0).any():
            from scipy.spatial import cKDTree

            known = np.flatnonzero(ids >= 0)
            d, j = cKDTree(V[known]).query(V[fresh])
            hit = d == 0
            ids[fresh[hit]] = ids[known[j[hit]]]
        # one primary vertex per old id: among split copies, the one on the most faces (then the lowest index)
        valence = np.bincount(F.ravel(), minlength=n_new)
        has = np.flatnonzero(ids >= 0)
        order = has[np.lexsort((has, -valence[has]))]
        _, first = np.unique(ids[order], return_index=True)
        primary = np.sort(order[first])
        primary = primary[np.argsort(ids[primary], kind="stable")]
        is_primary = np.zeros(n_new, bool)
        is_primary[primary] = True
        others = np.flatnonzero(~is_primary)
        perm = np.r_[primary, others]  # new position -> current index
        inv = np.empty(n_new, dtype=np.int64)
        inv[perm] = np.arange(n_new)
        V, ids, F = V[perm], ids[perm], inv[F]
        forder = np.lexsort((fids, fids < 0))
        F, fids = np.ascontiguousarray(F[forder]), fids[forder]
        # final representative of every old vertex (merges can chain)
        rep = _resolve(self.rep)
        o2n_direct = np.full(self.n_old, -1, dtype=np.int64)
        o2n_direct[ids[: primary.size]] = np.arange(primary.size)
        o2n = np.where(rep >= 0, o2n_direct[np.maximum(rep, 0)], -1)
        names = np.array([s.name for s in self.report.steps] + [""], dtype=str)  # step_of -1 -> ""
        own = np.arange(self.n_old)
        # merged: the merge step; removed: the step that removed it, or its survivor
        step = np.where(rep != own, names[self.step_of], "")
        lost = o2n < 0
        step[lost] = names[self.step_of[np.where(rep[lost] >= 0, rep[lost], own[lost])]]
        self.rep = rep
        return V, F, IndexMap(o2n, ids, step), fids

    def close(self, V, F, imap: IndexMap) -> Report:
        r = self.report
        r.output_vertices, r.output_faces = int(V.shape[0]), int(F.shape[0])
        r.index_map = imap.counts()
        r.seconds = time.perf_counter() - self.t0
        self._say(f"{r.operation}: done in {r.seconds:.2f} s")
        return r
