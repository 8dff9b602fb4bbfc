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
from facegeom.pipelines.cleanup.carry import CarriedMarkers, carry_vertex_csv, write_vertex_csv
from facegeom.pipelines.cleanup.checks import mesh_problems
from facegeom.pipelines.cleanup.cropping import crop
from facegeom.pipelines.cleanup.decimation import decimate
from facegeom.pipelines.cleanup.geodesic import geodesic_distance
from facegeom.pipelines.cleanup.indexmap import IndexMap
from facegeom.pipelines.cleanup.options import parse_id_range, parse_tolerance
from facegeom.pipelines.cleanup.repair import _cyclic_same as _cyclic_same  # tests check it
from facegeom.pipelines.cleanup.repair import clean
from facegeom.pipelines.cleanup.report import Report, StepReport

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
