"""Mesh clean-up on pymeshlab: clean, decimate, crop, with exact vertex index maps.

Every operation returns the new ``V, F``, an :class:`IndexMap` (old vertex id ->
new vertex id, and which old ids were merged or removed, by which step) and a
:class:`Report` (vertex and face counts per step). Marker and landmark files
(any CSV with a ``vertex_id`` column) are carried through the map with
:func:`carry_vertex_csv`; a marker whose vertex disappears is an error (or is
dropped on request), never silently moved.

How the map is kept exact: each vertex enters pymeshlab with its id + 1 as
vertex quality and each face with its id + 1 as face quality
(``pymeshlab.Mesh(V, F, v_scalar_array=..., f_scalar_array=...)``). Every
filter used here carries them along; a vertex that a filter creates gets 0
("new") or a copy of the quality of the vertex it was split from. A merge is
read off the faces: a surviving face whose corner changed from old vertex ``a``
to old vertex ``b`` tells that ``a`` was merged into ``b`` (an unreferenced
duplicate goes to the nearest survivor).
"""
from __future__ import annotations

import csv
import io as _io
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from facegeom.errors import InputError
from facegeom.interfaces import as_faces, as_vertices
from facegeom.io import atomic_path
from facegeom.io.vertex_csv import VertexCSV
from facegeom.native import quiet_native

__all__ = [
    "IndexMap",
    "StepReport",
    "Report",
    "CarriedMarkers",
    "clean",
    "decimate",
    "crop",
    "geodesic_distance",
    "parse_tolerance",
    "parse_id_range",
    "carry_vertex_csv",
    "write_vertex_csv",
    "mesh_problems",
]

Progress = Callable[[str], None] | None

# --------------------------------------------------------------------------- index map


@dataclass(frozen=True, eq=False)
class IndexMap:
    """Map from the vertex ids of an input mesh to those of an output mesh.

    Attributes
    ----------
    old_to_new : (n_old,) int64
        New id of each old vertex; ``-1`` when it was removed. A merged vertex
        maps to the vertex it was merged into.
    new_to_old : (n_new,) int64
        Old id each new vertex comes from; ``-1`` for a vertex created from
        nothing. A vertex split off an old vertex (non-manifold repair) holds
        that old id, but the old id maps to one copy only (``old_to_new``).
    step : (n_old,) str
        The step that merged or removed each old vertex ('' if kept).
    """

    old_to_new: np.ndarray
    new_to_old: np.ndarray
    step: np.ndarray

    def __post_init__(self):
        o2n = np.asarray(self.old_to_new, dtype=np.int64)
        n2o = np.asarray(self.new_to_old, dtype=np.int64)
        step = np.asarray(self.step, dtype=str)
        if step.shape != o2n.shape:
            raise InputError(f"index map: {step.shape[0]} step names for {o2n.shape[0]} old vertices")
        if o2n.size and (o2n.max() >= n2o.size or o2n.min() < -1):
            raise InputError("index map: an old id maps past the new vertex count")
        if n2o.size and (n2o.max() >= o2n.size or n2o.min() < -1):
            raise InputError("index map: a new id comes from past the old vertex count")
        object.__setattr__(self, "old_to_new", o2n)
        object.__setattr__(self, "new_to_old", n2o)
        object.__setattr__(self, "step", step)

    @classmethod
    def identity(cls, n: int) -> "IndexMap":
        ids = np.arange(int(n), dtype=np.int64)
        return cls(ids, ids.copy(), np.full(int(n), "", dtype="<U1"))

    @property
    def n_old(self) -> int:
        return int(self.old_to_new.size)

    @property
    def n_new(self) -> int:
        return int(self.new_to_old.size)

    @property
    def removed(self) -> np.ndarray:
        """(n_old,) bool: old vertices with no new vertex."""
        return self.old_to_new < 0

    @property
    def kept(self) -> np.ndarray:
        """(n_old,) bool: old vertices that are a new vertex."""
        ok = ~self.removed
        out = np.zeros(self.n_old, bool)
        idx = np.flatnonzero(ok)
        out[idx] = self.new_to_old[self.old_to_new[idx]] == idx
        return out

    @property
    def merged(self) -> np.ndarray:
        """(n_old,) bool: old vertices merged into another vertex (mapped to the survivor)."""
        return ~self.removed & ~self.kept

    @property
    def status(self) -> np.ndarray:
        """(n_old,) str: 'kept', 'merged' or 'removed'."""
        out = np.full(self.n_old, "kept", dtype="<U7")
        out[self.merged] = "merged"
        out[self.removed] = "removed"
        return out

    @property
    def new_status(self) -> np.ndarray:
        """(n_new,) str: 'kept' (an old vertex), 'split' (a copy of one) or 'new'."""
        out = np.full(self.n_new, "kept", dtype="<U5")
        src = self.new_to_old
        has = src >= 0
        out[~has] = "new"
        split = np.zeros(self.n_new, bool)
        split[has] = self.old_to_new[src[has]] != np.flatnonzero(has)
        out[split] = "split"
        return out

    @property
    def is_identity(self) -> bool:
        return (self.n_old == self.n_new and np.array_equal(self.old_to_new, np.arange(self.n_old))
                and np.array_equal(self.new_to_old, np.arange(self.n_new)))

    def counts(self) -> dict[str, int]:
        ns = self.new_status
        return {"old_vertices": self.n_old, "new_vertices": self.n_new, "kept": int(self.kept.sum()),
                "merged": int(self.merged.sum()), "removed": int(self.removed.sum()),
                "split": int((ns == "split").sum()), "new": int((ns == "new").sum())}

    def map(self, ids) -> np.ndarray:
        """New ids of old vertex ids (``-1`` where removed)."""
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= self.n_old):
            raise InputError(f"vertex id out of range: the old mesh has {self.n_old} vertices")
        return self.old_to_new[ids]

    def then(self, other: "IndexMap") -> "IndexMap":
        """This map followed by ``other`` (which maps this map's new ids onward)."""
        if other.n_old != self.n_new:
            raise InputError(f"cannot chain index maps: {self.n_new} vertices out, {other.n_old} in")
        o2n = np.where(self.old_to_new >= 0, other.old_to_new[np.maximum(self.old_to_new, 0)], -1)
        n2o = np.where(other.new_to_old >= 0, self.new_to_old[np.maximum(other.new_to_old, 0)], -1)
        later = np.where(self.old_to_new >= 0, other.step[np.maximum(self.old_to_new, 0)], "")
        step = np.where(self.step != "", self.step, later)
        return IndexMap(o2n, n2o, step)

    # ---- files

    def rows(self) -> list[tuple[int, int, str, str]]:
        """``(old_id, new_id, status, step)``: one row per old vertex, then one per split or new vertex."""
        st = self.status
        out = list(zip(range(self.n_old), self.old_to_new.tolist(), st.tolist(), self.step.tolist()))
        ns = self.new_status
        for j in np.flatnonzero(ns != "kept").tolist():
            out.append((int(self.new_to_old[j]), j, str(ns[j]), ""))
        return out

    def save(self, path: str | os.PathLike) -> Path:
        """Write the map atomically: ``.csv`` (``old_id,new_id,status,step``) or ``.npz``."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".csv", ".npz"):
            raise InputError("an index map must be a .csv or .npz file", path)
        with atomic_path(path) as tmp:
            if suffix == ".npz":
                with open(tmp, "wb") as fh:
                    np.savez_compressed(fh, old_to_new=self.old_to_new, new_to_old=self.new_to_old,
                                        status=self.status, step=self.step, new_status=self.new_status)
            else:
                with open(tmp, "w", newline="") as fh:
                    w = csv.writer(fh)
                    w.writerow(("old_id", "new_id", "status", "step"))
                    w.writerows(self.rows())
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "IndexMap":
        """Read a map written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise InputError("file not found", path)
        if path.suffix.lower() == ".npz":
            try:
                with np.load(path) as z:
                    return cls(z["old_to_new"], z["new_to_old"], z["step"])
            except (KeyError, ValueError, OSError) as exc:
                raise InputError(f"not an index map ({exc.__class__.__name__})", path) from None
        rows = list(csv.reader(_io.StringIO(path.read_text())))
        if not rows or [c.strip() for c in rows[0]] != ["old_id", "new_id", "status", "step"]:
            raise InputError("expected the header old_id,new_id,status,step", path)
        try:
            old = [(int(r[0]), int(r[1]), r[2], r[3]) for r in rows[1:] if r[2] in ("kept", "merged", "removed")]
            new = [(int(r[0]), int(r[1]), r[2]) for r in rows[1:] if r[2] in ("split", "new")]
        except (ValueError, IndexError):
            raise InputError("malformed index map row", path) from None
        o2n = np.array([r[1] for r in old], dtype=np.int64)
        n_new = max([r[1] for r in old] + [r[1] for r in new] + [-1]) + 1
        n2o = np.full(n_new, -1, dtype=np.int64)
        for o, j, s, _ in old:
            if s == "kept":
                n2o[j] = o
        for o, j, _ in new:
            n2o[j] = o
        return cls(o2n, n2o, np.array([r[3] for r in old], dtype=str))


# --------------------------------------------------------------------------- report


@dataclass
class StepReport:
    """What one step changed."""

    name: str
    vertices_before: int
    vertices_after: int
    faces_before: int
    faces_after: int
    details: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def changed(self) -> bool:
        return (self.vertices_before != self.vertices_after or self.faces_before != self.faces_after
                or any(self.details.values()))

    def line(self) -> str:
        parts = []
        dv = self.vertices_after - self.vertices_before
        df = self.faces_after - self.faces_before
        if dv:
            parts.append(f"{dv:+,} vertices")
        if df:
            parts.append(f"{df:+,} faces")
        parts += [f"{v:,} {k.replace('_', ' ')}" for k, v in self.details.items() if v]
        return f"  {self.name:<40} {', '.join(parts) if parts else 'no change'}"


@dataclass
class Report:
    """Counts per step of one operation (printable, JSON-serialisable)."""

    operation: str
    input_vertices: int
    input_faces: int
    output_vertices: int = 0
    output_faces: int = 0
    steps: list[StepReport] = field(default_factory=list)
    seconds: float = 0.0
    index_map: dict[str, int] = field(default_factory=dict)
    markers: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        return any(s.changed for s in self.steps)

    def lines(self) -> list[str]:
        out = [f"{self.operation}: {self.input_vertices:,} -> {self.output_vertices:,} vertices, "
               f"{self.input_faces:,} -> {self.output_faces:,} faces in {self.seconds:.2f} s"]
        out += [s.line() for s in self.steps]
        if self.index_map:
            c = self.index_map
            out.append(f"  index map: {c['kept']:,} kept, {c['merged']:,} merged, {c['removed']:,} removed, "
                       f"{c['split']:,} split copies, {c['new']:,} new")
        for m in self.markers:
            lost = f", {m['dropped']} lost and dropped" if m.get("dropped") else ""
            merged = f", {m['merged']} on merged vertices" if m.get("merged") else ""
            out.append(f"  markers {m['file']}: {m['carried']} carried{merged}{lost}"
                       + (f" -> {m['out']}" if m.get("out") else ""))
        out += [f"  note: {n}" for n in self.notes]
        return out

    def __str__(self) -> str:
        return "\n".join(self.lines())

    def to_dict(self) -> dict:
        d = asdict(self)
        for s, sd in zip(self.steps, d["steps"]):
            sd["changed"] = s.changed
        return d

    def write_json(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path


# --------------------------------------------------------------------------- pymeshlab runner


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


def _non_manifold_edges(F) -> int:
    """How many edges have more than two faces."""
    F = np.asarray(F, dtype=np.int64)
    if F.size == 0:
        return 0
    E = np.sort(np.r_[F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1)
    n = int(F.max()) + 1
    _, cnt = np.unique(E[:, 0] * n + E[:, 1], return_counts=True)
    return int((cnt > 2).sum())


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


# --------------------------------------------------------------------------- input checks


def _check_mesh(V, F, path=None) -> tuple[np.ndarray, np.ndarray | list, bool]:
    """Validate V and F (triangles, an (m, k) polygon array or a list of polygons)."""
    V = as_vertices(V, "vertex coordinates", path)
    n = V.shape[0]
    if isinstance(F, np.ndarray) and F.ndim == 2 and F.shape[1] == 3:
        return V, as_faces(F, n, "faces", path), False
    if isinstance(F, np.ndarray) and F.ndim == 2 and F.shape[1] > 3:
        polys = [np.asarray(r, dtype=np.int64) for r in F]
    else:
        try:
            polys = [np.asarray(p, dtype=np.int64).ravel() for p in F]
        except (TypeError, ValueError):
            raise InputError("faces must be triangles (m, 3) or a list of polygons of vertex ids", path) from None
    if not polys:
        raise InputError("faces is empty: the mesh has no face", path)
    for k, p in enumerate(polys):
        if p.size < 3:
            raise InputError(f"face {k} has {p.size} vertices; a polygon needs at least 3", path)
        if p.min() < 0 or p.max() >= n:
            raise InputError(f"face {k} indexes vertex {int(p.max() if p.max() >= n else p.min())}, outside "
                             f"[0, {n})", path)
    if all(p.size == 3 for p in polys):
        return V, np.array(polys, dtype=np.int64), False
    return V, polys, True


def mesh_problems(V, F) -> dict[str, int]:
    """Counts of the defects :func:`clean` repairs (all 0 on a clean mesh); numpy and libigl only.

    Keys: ``duplicate_vertices`` (same position), ``unreferenced_vertices``,
    ``degenerate_faces`` (repeated vertex or zero area), ``duplicate_faces``
    (same vertex set), ``non_manifold_edges``, ``non_manifold_vertices``,
    ``components``.
    """
    import igl

    from facegeom.geometry import connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = V.shape[0]
    out = {"duplicate_vertices": int(n - np.unique(V, axis=0).shape[0]),
           "unreferenced_vertices": int(n - np.unique(F).size)}
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    area = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    out["degenerate_faces"] = int((rep | (area == 0)).sum())
    out["duplicate_faces"] = int(F.shape[0] - np.unique(np.sort(F, axis=1), axis=0).shape[0])
    out["non_manifold_edges"] = _non_manifold_edges(F)
    Fg = F[~rep]
    if Fg.size:
        vm = np.asarray(igl.is_vertex_manifold(Fg)).ravel()
        used = np.zeros(vm.size, bool)
        used[np.unique(Fg)] = True
        out["non_manifold_vertices"] = int((~vm.astype(bool) & used).sum())
    else:
        out["non_manifold_vertices"] = 0
    out["components"] = connected_components(F, n)[0] - out["unreferenced_vertices"]
    return out


def parse_tolerance(tol) -> tuple[str, float]:
    """``0`` / ``'1e-6'`` (absolute distance) or ``'0.01%'`` (of the bounding-box diagonal)."""
    if isinstance(tol, (int, float)):
        kind, value = "abs", float(tol)
    else:
        s = str(tol).strip()
        kind = "percent" if s.endswith("%") else "abs"
        try:
            value = float(s.rstrip("%"))
        except ValueError:
            raise InputError(f"merge tolerance must be a distance or a percentage like 0.01%, got {tol!r}") from None
    if not np.isfinite(value) or value < 0:
        raise InputError(f"merge tolerance must be a non-negative number, got {tol!r}")
    if kind == "percent" and value > 50:
        raise InputError(f"merge tolerance {tol!r} is more than half the bounding-box diagonal")
    return kind, value


def parse_id_range(text: str, n: int | None = None) -> tuple[int, int]:
    """``'A:B'`` -> ``(A, B)``, the half-open id range [A, B); ``A`` and ``B`` may be omitted."""
    s = str(text).strip()
    if ":" not in s:
        raise InputError(f"id range must look like A:B (half-open, e.g. 0:6706), got {text!r}")
    a_s, b_s = s.split(":", 1)
    try:
        a = int(a_s) if a_s.strip() else 0
        b = int(b_s) if b_s.strip() else (n if n is not None else -1)
    except ValueError:
        raise InputError(f"id range must hold integers, like 0:6706, got {text!r}") from None
    if b < 0 and n is None:
        raise InputError(f"id range {text!r} needs an end")
    if a < 0 or b <= a:
        raise InputError(f"id range {text!r} is empty or negative")
    if n is not None and a >= n:
        raise InputError(f"id range {text!r} starts past the {n} vertices of the mesh")
    return a, min(b, n) if n is not None else b


# --------------------------------------------------------------------------- clean


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
    V2, F2, index_map, report

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
    ml = _pml()
    if polygons:
        n_poly = sum(1 for p in F if len(p) > 3)
        run.apply("triangulate polygons", "meshing_poly_to_tri")
        run.report.steps[-1].details["split_polygons"] = n_poly
        run.report.input_faces = len(F)
        run.report.steps[-1].faces_before = len(F)
        # restart the face ids on the triangles
        cm = run.mesh
        Ft = cm.face_matrix().astype(np.int64)
        ids = run.vertex_ids()
        if (ids < 0).any():  # pragma: no cover - triangulation creates no vertex
            raise InputError("triangulating the polygons created vertices")
        Vt = V[ids]  # the polygon constructor stores float32 positions: take the exact ones back
        run.ms = ml.MeshSet()
        run.ms.add_mesh(ml.Mesh(Vt, Ft.astype(np.int32), v_scalar_array=ids + 1.0,
                                f_scalar_array=np.arange(1, Ft.shape[0] + 1, dtype=np.float64)))
        run.alias = np.arange(Ft.shape[0], dtype=np.int64)
        F_ref = ids[Ft]
    else:
        F_ref = F
    run.apply("merge duplicate vertices", "meshing_remove_duplicate_vertices", merge=True)
    if tol > 0:
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
        from facegeom.geometry import connected_components

        Fc = run.mesh.face_matrix().astype(np.int64)
        _, lab = connected_components(Fc, run.mesh.vertex_number())
        sizes = np.bincount(lab[Fc[:, 0]])
        step = run.apply("keep the largest component", "meshing_remove_connected_component_by_face_number",
                         mincomponentsize=int(sizes.max()), removeunref=True)
        step.details["removed_components"] = int((sizes[sizes > 0] < sizes.max()).sum())
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


# --------------------------------------------------------------------------- decimate


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
    """
    V, F, polygons = _check_mesh(V, F)
    if polygons:
        raise InputError("decimate needs a triangle mesh; run clean first to triangulate")
    target = int(vertices)
    if target < 4:
        raise InputError(f"--vertices must be at least 4, got {vertices}")
    keep = np.unique(np.asarray([] if keep is None else keep, dtype=np.int64))
    if keep.size and (keep.min() < 0 or keep.max() >= V.shape[0]):
        raise InputError(f"vertex to preserve out of range: the mesh has {V.shape[0]} vertices")
    run = _Run("decimate", V, F, progress)
    cm = run.mesh
    use_sel = keep.size > 0
    if use_sel:
        flag = np.zeros(V.shape[0])
        flag[keep] = 1.0
        cm.add_vertex_custom_scalar_attribute(flag, "facegeom_keep")
        with quiet_native((1, 2)):
            run.ms.compute_selection_by_condition_per_vertex(condselect="facegeom_keep > 0.5")
            run.ms.compute_selection_transfer_vertex_to_face(inclusive=False)
            run.ms.apply_selection_inverse(invfaces=True, invverts=False)
            run.ms.set_selection_none(allfaces=False, allverts=True)
    nv0, nf0 = int(cm.vertex_number()), int(cm.face_number())
    t = time.perf_counter()
    passes = 0
    while run.mesh.vertex_number() > target and passes < 8:
        cm = run.mesh
        nv, nf = int(cm.vertex_number()), int(cm.face_number())
        # one collapse removes one vertex and about two faces (one on the boundary)
        ratio = nf / max(nv, 1)
        goal = max(int(round(nf - ratio * (nv - target))), 2)
        if use_sel:  # the target counts the selected (simplifiable) faces
            goal = max(int(cm.selected_face_number()) - (nf - goal), 1)
        run._say(f"  quadric edge collapse pass {passes + 1}: {nv:,} vertices -> about {target:,}")
        try:
            with quiet_native((1, 2)):
                run.ms.meshing_decimation_quadric_edge_collapse(
                    targetfacenum=goal, preserveboundary=bool(preserve_boundary),
                    preservetopology=bool(preserve_topology), optimalplacement=False, selected=use_sel,
                    autoclean=True, qualitythr=0.3)
        except _pml().PyMeshLabException as exc:
            raise InputError(f"decimation failed in pymeshlab: {exc}") from None
        passes += 1
        if run.mesh.vertex_number() >= nv:  # nothing more can collapse
            break
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
    rep = run.close(V2, F2, imap)
    bad = mesh_problems(V2, F2)
    nm = bad["non_manifold_edges"] + bad["non_manifold_vertices"] + bad["duplicate_faces"]
    if nm:
        rep.notes.append(f"the result has {bad['non_manifold_edges']} non-manifold edges, "
                         f"{bad['non_manifold_vertices']} non-manifold vertices and {bad['duplicate_faces']} "
                         f"duplicate faces (collapse too aggressive around preserved vertices): ask for more "
                         f"vertices, add --preserve-topology, or run `facegeom clean` on it")
    if V2.shape[0] > target:
        rep.notes.append(f"stopped at {V2.shape[0]:,} vertices (asked {target:,}): no further collapse was possible "
                         f"under the constraints")
    return V2, F2, imap, rep


# --------------------------------------------------------------------------- crop


def geodesic_distance(V, F, sources, *, limit: float | None = None, method: str = "exact") -> np.ndarray:
    """Geodesic distance from the nearest of ``sources`` to every vertex (libigl).

    ``exact``: libigl's exact (MMP) geodesics; with ``limit`` it runs on the
    patch of vertices within edge-path distance ``2 * limit`` (the bound used
    by :func:`facegeom.geometry.geodesic_rings`), others get ``inf``.
    ``heat``: libigl's heat method (fast, about 1 % error).
    ``graph``: shortest edge paths (an upper bound).
    """
    import igl
    from scipy.sparse import csgraph

    from facegeom.geometry import _edge_graph

    V = as_vertices(V)
    F = as_faces(F, V.shape[0])
    src = np.unique(np.asarray(sources, dtype=np.int64))
    n = V.shape[0]
    if src.size == 0:
        raise InputError("at least one source vertex is needed")
    if src.min() < 0 or src.max() >= n:
        raise InputError(f"source vertex {int(src.max() if src.max() >= n else src.min())} is out of range: "
                         f"the mesh has {n} vertices")
    if method == "heat":
        data = igl.HeatGeodesicsData()
        igl.heat_geodesics_precompute(V, F, data)
        d = np.asarray(igl.heat_geodesics_solve(data, src), dtype=np.float64)
        return np.maximum(d - d[src].min(), 0.0)
    G = _edge_graph(V, F)
    if method == "graph":
        return csgraph.dijkstra(G, directed=False, indices=src, min_only=True, limit=np.inf if limit is None else limit)
    if method != "exact":
        raise InputError(f"geodesic method must be 'exact', 'heat' or 'graph', got {method!r}")
    bound = np.inf if limit is None else 2.0 * float(limit)
    de = csgraph.dijkstra(G, directed=False, indices=src, min_only=True, limit=bound)
    patch = np.flatnonzero(np.isfinite(de))
    remap = np.full(n, -1, dtype=np.int64)
    remap[patch] = np.arange(patch.size)
    Fl = remap[F]
    Fl = Fl[(Fl >= 0).all(axis=1)]
    out = np.full(n, np.inf)
    if Fl.size == 0:
        out[src] = 0.0
        return out
    d = np.asarray(igl.exact_geodesic(V[patch], Fl, VS=remap[src], VT=np.arange(patch.size)), dtype=np.float64)
    on = np.zeros(patch.size, bool)
    on[Fl.ravel()] = True
    d[~on] = np.inf
    out[patch] = d
    out[src] = 0.0
    return out


def crop(V, F, *, sources=None, radius: float | None = None, id_range: tuple[int, int] | None = None,
         geodesic: str = "exact", progress: Progress = None) -> tuple[np.ndarray, np.ndarray, IndexMap, Report]:
    """Keep a region: vertices within geodesic ``radius`` of ``sources``, or ids in ``id_range`` = [A, B).

    Faces with a vertex outside the region are removed, then unreferenced
    vertices (pymeshlab selection + ``meshing_remove_selected_vertices``).
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


# --------------------------------------------------------------------------- marker / landmark files


@dataclass
class CarriedMarkers:
    """A marker file mapped through an :class:`IndexMap`."""

    source: VertexCSV
    new_ids: np.ndarray  # (k_kept,)
    kept_rows: np.ndarray  # (k_kept,) row indices into source.rows
    dropped_rows: np.ndarray
    merged_rows: np.ndarray

    def summary(self, out=None) -> dict:
        return {"file": str(self.source.path), "carried": int(self.kept_rows.size),
                "merged": int(self.merged_rows.size), "dropped": int(self.dropped_rows.size),
                "dropped_vertex_ids": self.source.ids[self.dropped_rows].tolist(),
                **({"out": str(out)} if out else {})}


def carry_vertex_csv(markers: VertexCSV, index_map: IndexMap, *, drop_lost: bool = False,
                     operation: str = "the operation") -> CarriedMarkers:
    """Map a marker file's ``vertex_id`` through ``index_map``.

    A marker whose vertex was removed raises :class:`InputError` naming the
    marker, its file and the step that removed it, unless ``drop_lost``; two
    markers that end on one vertex (merged duplicates) always raise.
    """
    if index_map.n_old <= markers.ids.max():
        raise InputError(f"vertex_id {int(markers.ids.max())} is out of range: the mesh has {index_map.n_old} "
                         f"vertices", markers.path)
    new = index_map.old_to_new[markers.ids]
    lost = np.flatnonzero(new < 0)
    if lost.size and not drop_lost:
        k = int(lost[0])
        step = index_map.step[markers.ids[k]] or operation
        more = f" ({lost.size} markers lost in all)" if lost.size > 1 else ""
        raise InputError(f"{markers.label(k)} is lost: {operation} removed its vertex (step '{step}'){more}; "
                         f"pass --drop-lost-markers to drop lost markers", markers.path)
    kept = np.flatnonzero(new >= 0)
    uniq, inv, cnt = np.unique(new[kept], return_inverse=True, return_counts=True)
    if (cnt > 1).any():
        a, b = kept[np.flatnonzero(cnt[inv] > 1)[:2]]
        raise InputError(f"{markers.label(int(a))} and {markers.label(int(b))} end on the same vertex "
                         f"{int(new[a])} (merged); a marker file cannot hold it twice", markers.path)
    merged = kept[index_map.merged[markers.ids[kept]]]
    return CarriedMarkers(markers, new[kept], kept, lost if drop_lost else lost[:0], merged)


def write_vertex_csv(path: str | os.PathLike, carried: CarriedMarkers) -> Path:
    """Write the carried file atomically: the same columns, new ``vertex_id`` values, lost rows left out."""
    path = Path(path)
    src = carried.source
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(src.header)
            for k, vid in zip(carried.kept_rows.tolist(), carried.new_ids.tolist()):
                row = list(src.rows[k])
                row[src.id_col] = str(vid)
                w.writerow(row)
    return path


