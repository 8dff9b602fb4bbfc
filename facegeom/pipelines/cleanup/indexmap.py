"""The exact vertex index map of a clean-up operation (old vertex id -> new vertex id)."""
from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io import atomic_path, parse_csv_text

__all__ = ["IndexMap"]


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
        """The map of an operation that changed nothing on ``n`` vertices."""
        ids = np.arange(int(n), dtype=np.int64)
        return cls(ids, ids.copy(), np.full(int(n), "", dtype="<U1"))

    @property
    def n_old(self) -> int:
        """Vertex count of the input mesh."""
        return int(self.old_to_new.size)

    @property
    def n_new(self) -> int:
        """Vertex count of the output mesh."""
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
        """True when every vertex kept its id and none was added."""
        return (self.n_old == self.n_new and np.array_equal(self.old_to_new, np.arange(self.n_old))
                and np.array_equal(self.new_to_old, np.arange(self.n_new)))

    def counts(self) -> dict[str, int]:
        """Vertex counts: old, new, kept, merged, removed, split copies and new vertices."""
        ns = self.new_status
        return {"old_vertices": self.n_old, "new_vertices": self.n_new, "kept": int(self.kept.sum()),
                "merged": int(self.merged.sum()), "removed": int(self.removed.sum()),
                "split": int((ns == "split").sum()), "new": int((ns == "new").sum())}

    def map(self, ids) -> np.ndarray:
        """New ids of old vertex ids (``-1`` where removed).

        Parameters
        ----------
        ids : (k,) int
            Old vertex ids.

        Returns
        -------
        (k,) int64
        """
        ids = np.asarray(ids, dtype=np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= self.n_old):
            raise InputError(f"vertex id out of range: the old mesh has {self.n_old} vertices")
        return self.old_to_new[ids]

    def then(self, other: "IndexMap") -> "IndexMap":
        """This map followed by ``other`` (which maps this map's new ids onward).

        Parameters
        ----------
        other : IndexMap
            With ``other.n_old == self.n_new``.

        Returns
        -------
        IndexMap
            From this map's old ids to ``other``'s new ids; each vertex keeps
            the first step that merged or removed it.
        """
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
            from facegeom.io.npzcheck import check_npz, check_text

            check_npz(path)
            try:
                with np.load(path, allow_pickle=False) as z:
                    arrays = z["old_to_new"], z["new_to_old"], z["step"]
            except (KeyError, ValueError, OSError) as exc:
                raise InputError(f"not an index map ({exc.__class__.__name__})", path) from None
            if arrays[0].dtype.kind not in "iu" or arrays[1].dtype.kind not in "iu" or arrays[2].dtype.kind != "U":
                raise InputError("not an index map (old_to_new and new_to_old must be integers, step text)", path)
            check_text(arrays[2], "step", path)
            try:
                return cls(*arrays)
            except InputError as exc:
                raise InputError(exc.reason, path) from None
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read as text ({exc.__class__.__name__})", path) from None
        rows = parse_csv_text(text, path)
        if not rows or [c.strip() for c in rows[0]] != ["old_id", "new_id", "status", "step"]:
            raise InputError("expected the header old_id,new_id,status,step", path)
        n_rows = len(rows) - 1  # no id of a map can reach its own number of rows
        old, new = [], []
        for line, r in enumerate(rows[1:], start=2):
            if not any(c.strip() for c in r):
                continue
            if len(r) != 4:
                raise InputError(f"line {line}: expected 4 values (old_id,new_id,status,step), got {len(r)}", path)
            try:
                o, j = int(r[0]), int(r[1])
            except ValueError:
                raise InputError(f"line {line}: old_id and new_id must be integers", path) from None
            status = r[2].strip()
            if not (-1 <= o < n_rows and -1 <= j < n_rows):
                raise InputError(f"line {line}: an id outside -1..{n_rows - 1} (a map of {n_rows} rows)", path)
            if status in ("kept", "merged", "removed"):
                if o != len(old):
                    raise InputError(f"line {line}: old vertex {o} out of order (expected {len(old)})", path)
                if (j < 0) != (status == "removed"):
                    raise InputError(f"line {line}: a {status} vertex " + ("has a new id" if j >= 0 else
                                     "needs a new id"), path)
                old.append((o, j, status, r[3]))
            elif status in ("split", "new"):
                if j < 0:
                    raise InputError(f"line {line}: a {status} vertex needs a new id", path)
                new.append((o, j, status))
            else:
                raise InputError(f"line {line}: unknown status {status!r} (kept, merged, removed, split or new)",
                                 path)
        o2n = np.array([r[1] for r in old], dtype=np.int64)
        n_new = max([r[1] for r in old] + [r[1] for r in new] + [-1]) + 1
        n2o = np.full(n_new, -1, dtype=np.int64)
        for o, j, s, _ in old:
            if s == "kept":
                n2o[j] = o
        for o, j, _ in new:
            if o >= len(old):
                raise InputError(f"a {_} vertex comes from old vertex {o}, past the map's {len(old)}", path)
            n2o[j] = o
        try:
            return cls(o2n, n2o, np.array([r[3] for r in old], dtype=str))
        except InputError as exc:
            raise InputError(exc.reason, path) from None
