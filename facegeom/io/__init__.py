"""Files: every reader and writer of user files, in one place (layer 2).

Meshes (:mod:`.mesh`), marker CSVs (:mod:`.markers`), vertex-indexed CSVs
(:mod:`.vertex_csv`), marker sequences (:mod:`.markerseq`), ARKit takes
(:mod:`.takes`), fitting files (:mod:`.fitfiles`: landmarks, point clouds,
coefficients), glTF blendshape rigs (:mod:`.gltf`), atomic writes (:mod:`.files`).
Errors name the file.
"""
from __future__ import annotations

from facegeom.io.files import (
    all_or_nothing,
    atomic_path,
    check_outputs,
    check_writable_folder,
    parse_csv_text,
    read_csv_rows,
    same_file,
)
from facegeom.io.fitfiles import (
    CLOUD_FORMATS,
    TARGET_KINDS,
    image_size,
    read_landmarks,
    read_point_cloud,
    read_pts,
    read_weights,
    write_weights,
)
from facegeom.io.formats import MeshData
from facegeom.io.gltf import GltfRig, RigPart, read_gltf_rig
from facegeom.io.markers import MARKER_HEADER, read_markers, write_markers
from facegeom.io.markerseq import (
    SEQUENCE_HEADER,
    MarkerSequence,
    fill_gaps,
    read_marker_sequence,
    read_retarget_inputs,
    write_marker_sequence,
)
from facegeom.io.mesh import MESH_FORMATS, read_mesh, read_polygon_mesh, write_mesh
from facegeom.io.takes import (
    ARKIT_NAMES,
    POLICIES,
    ROTATION_NAMES,
    Take,
    arkit_to_ict_name,
    find_takes,
    ict_weights,
    read_take,
    timecode_fps,
)
from facegeom.io.vertex_csv import VertexCSV, read_vertex_csv

__all__ = [
    "all_or_nothing",
    "atomic_path",
    "check_outputs",
    "check_writable_folder",
    "same_file",
    "parse_csv_text",
    "read_csv_rows",
    "MESH_FORMATS",
    "read_mesh",
    "read_polygon_mesh",
    "MeshData",
    "write_mesh",
    "MARKER_HEADER",
    "read_markers",
    "write_markers",
    "VertexCSV",
    "read_vertex_csv",
    "MarkerSequence",
    "SEQUENCE_HEADER",
    "fill_gaps",
    "read_marker_sequence",
    "read_retarget_inputs",
    "write_marker_sequence",
    "ARKIT_NAMES",
    "POLICIES",
    "ROTATION_NAMES",
    "Take",
    "arkit_to_ict_name",
    "find_takes",
    "ict_weights",
    "read_take",
    "timecode_fps",
    "CLOUD_FORMATS",
    "TARGET_KINDS",
    "read_landmarks",
    "read_pts",
    "image_size",
    "read_point_cloud",
    "read_weights",
    "write_weights",
    "GltfRig",
    "RigPart",
    "read_gltf_rig",
]
