"""Marker and landmark files (any CSV with a ``vertex_id`` column) carried through an index map."""
from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facegeom.errors import InputError
from facegeom.io import atomic_path
from facegeom.io.vertex_csv import VertexCSV
from facegeom.pipelines.cleanup.indexmap import IndexMap

__all__ = ["CarriedMarkers", "carry_vertex_csv", "write_vertex_csv"]


@dataclass
class CarriedMarkers:
    """A marker file mapped through an :class:`IndexMap`.

    Attributes
    ----------
    source : VertexCSV
        The file as read.
    new_ids : (k,) int64
        New vertex id of each carried row.
    kept_rows : (k,) int64
        Row indices into ``source.rows`` of the carried markers.
    dropped_rows : (d,) int64
        Rows whose vertex was removed (empty unless lost markers are dropped).
    merged_rows : (j,) int64
        Carried rows whose vertex was merged into another.
    """

    source: VertexCSV
    new_ids: np.ndarray  # (k_kept,)
    kept_rows: np.ndarray  # (k_kept,) row indices into source.rows
    dropped_rows: np.ndarray
    merged_rows: np.ndarray

    def summary(self, out=None) -> dict:
        """Counts for the report: file, carried, merged, dropped (and their ids), ``out`` if given."""
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

    Parameters
    ----------
    markers : VertexCSV
        The marker file (``markers.ids`` : (r,) int, its vertex ids).
    index_map : IndexMap
        Old mesh -> new mesh.
    drop_lost : bool
        Drop markers whose vertex was removed instead of raising.
    operation : str
        Named in the error message.

    Returns
    -------
    CarriedMarkers
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
                         f"pass drop_lost=True to drop lost markers", markers.path)
    kept = np.flatnonzero(new >= 0)
    uniq, inv, cnt = np.unique(new[kept], return_inverse=True, return_counts=True)
    if (cnt > 1).any():
        a, b = kept[np.flatnonzero(cnt[inv] > 1)[:2]]
        raise InputError(f"{markers.label(int(a))} and {markers.label(int(b))} end on the same vertex "
                         f"{int(new[a])} (merged); a marker file cannot hold it twice", markers.path)
    merged = kept[index_map.merged[markers.ids[kept]]]
    return CarriedMarkers(markers, new[kept], kept, lost if drop_lost else lost[:0], merged)


def write_vertex_csv(path: str | os.PathLike, carried: CarriedMarkers) -> Path:
    """Write the carried file atomically: the same columns, new ``vertex_id`` values, lost rows left out.

    Parameters
    ----------
    path : path-like
        The output CSV.
    carried : CarriedMarkers

    Returns
    -------
    Path
        ``path``.
    """
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
