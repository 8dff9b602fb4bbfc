"""Files: every reader and writer of user files, in one place (layer 2).

Meshes (:mod:`.mesh`), marker CSVs (:mod:`.markers`), vertex-indexed CSVs
(:mod:`.vertex_csv`), marker sequences (:mod:`.markerseq`), ARKit takes
(:mod:`.takes`), fitting files (:mod:`.fitfiles`: landmarks, point clouds,
coefficients), glTF blendshape rigs (:mod:`.gltf`), atomic writes (:mod:`.files`).
Errors name the file.

Importing ``facegeom.io`` (or one of its modules) is light: the names below are
looked up on first use (PEP 562 module ``__getattr__``), so reading a C3D file
does not import the glTF, take and mesh readers.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what static tools see; at run time the names load on first use
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

_LAZY = {
    "all_or_nothing": "facegeom.io.files",
    "atomic_path": "facegeom.io.files",
    "check_outputs": "facegeom.io.files",
    "check_writable_folder": "facegeom.io.files",
    "parse_csv_text": "facegeom.io.files",
    "read_csv_rows": "facegeom.io.files",
    "same_file": "facegeom.io.files",
    "CLOUD_FORMATS": "facegeom.io.fitfiles",
    "TARGET_KINDS": "facegeom.io.fitfiles",
    "image_size": "facegeom.io.fitfiles",
    "read_landmarks": "facegeom.io.fitfiles",
    "read_point_cloud": "facegeom.io.fitfiles",
    "read_pts": "facegeom.io.fitfiles",
    "read_weights": "facegeom.io.fitfiles",
    "write_weights": "facegeom.io.fitfiles",
    "MeshData": "facegeom.io.formats",
    "GltfRig": "facegeom.io.gltf",
    "RigPart": "facegeom.io.gltf",
    "read_gltf_rig": "facegeom.io.gltf",
    "MARKER_HEADER": "facegeom.io.markers",
    "read_markers": "facegeom.io.markers",
    "write_markers": "facegeom.io.markers",
    "SEQUENCE_HEADER": "facegeom.io.markerseq",
    "MarkerSequence": "facegeom.io.markerseq",
    "fill_gaps": "facegeom.io.markerseq",
    "read_marker_sequence": "facegeom.io.markerseq",
    "read_retarget_inputs": "facegeom.io.markerseq",
    "write_marker_sequence": "facegeom.io.markerseq",
    "MESH_FORMATS": "facegeom.io.mesh",
    "read_mesh": "facegeom.io.mesh",
    "read_polygon_mesh": "facegeom.io.mesh",
    "write_mesh": "facegeom.io.mesh",
    "ARKIT_NAMES": "facegeom.io.takes",
    "POLICIES": "facegeom.io.takes",
    "ROTATION_NAMES": "facegeom.io.takes",
    "Take": "facegeom.io.takes",
    "arkit_to_ict_name": "facegeom.io.takes",
    "find_takes": "facegeom.io.takes",
    "ict_weights": "facegeom.io.takes",
    "read_take": "facegeom.io.takes",
    "timecode_fps": "facegeom.io.takes",
    "VertexCSV": "facegeom.io.vertex_csv",
    "read_vertex_csv": "facegeom.io.vertex_csv",
}
"""Public name -> the module that defines it (imported on first access)."""

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


def __getattr__(name: str):
    """Import a public name's defining module (or the submodule ``name``) on first access and keep it here."""
    module = _LAZY.get(name)
    if module is None:
        if name.startswith("__"):
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
        try:
            return importlib.import_module(f"{__name__}.{name}")  # a submodule, as the eager package had it
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later reads skip __getattr__
    return value


def __dir__() -> list[str]:
    """The module's names, the not-yet-imported public ones included."""
    return sorted(set(globals()) | set(_LAZY))
