"""The model (layer 3): face model and its data, blendshape rig, fitting targets,
camera and pose, landmark sets, marker layouts, expressions, synthetic performances,
and the seeded scenarios of the comparisons.

Importing ``facegeom.model`` (or one of its modules) is light: the names below
are looked up on first use (PEP 562 module ``__getattr__``), so a rig does not
import the marker layouts (scipy.sparse), the camera or the scenarios.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what static tools see; at run time the names load on first use
    from facegeom.model.camera import PinholeCamera, look_at_camera
    from facegeom.model.expressions import KINDS, NAMED, named_expression, random_sparse_expression
    from facegeom.model.face import (
        BUNDLE_NAME,
        CACHE_ENV_VAR,
        ENV_VAR,
        REQUIRED_KEYS,
        TAKES_ENV_VAR,
        FaceModel,
        cache_bundle_folder,
        cache_folder,
        data_places,
        default_data_path,
        default_takes_path,
        import_ict_folder,
        load_bundle,
        load_face_model,
        locate_data,
        locate_takes,
        read_obj_polygons,
        read_obj_positions,
        takes_cache_folder,
        takes_places,
    )
    from facegeom.model.inputs import face_template, load_rig, photo_camera, pts_vertex_ids, read_fit_target, scan_scale
    from facegeom.model.landmarks import (
        EVAL_LANDMARKS_26,
        FIT_LANDMARKS_23,
        INNER_EYE_CORNERS,
        INNER_LANDMARKS_49,
        MIRROR_68,
        OUTER_EYE_CORNERS,
    )
    from facegeom.model.layouts import farthest_points, ict80, layout, random_layout
    from facegeom.model.pose import estimate_pose, estimate_poses, project_many, reprojection_rms
    from facegeom.model.rig import BlendshapeRig
    from facegeom.model.scenarios import (
        ExpressionCase,
        RealisticDrivingCase,
        SparseExpressionCase,
        driving_cases,
        fitting_cases,
        realistic_driving_cases,
    )
    from facegeom.model.targets import LandmarkTarget, MarkerTarget, MeshTarget, PointCloudTarget

_LAZY = {
    "PinholeCamera": "facegeom.model.camera",
    "look_at_camera": "facegeom.model.camera",
    "KINDS": "facegeom.model.expressions",
    "NAMED": "facegeom.model.expressions",
    "named_expression": "facegeom.model.expressions",
    "random_sparse_expression": "facegeom.model.expressions",
    "BUNDLE_NAME": "facegeom.model.face",
    "CACHE_ENV_VAR": "facegeom.model.face",
    "ENV_VAR": "facegeom.model.face",
    "REQUIRED_KEYS": "facegeom.model.face",
    "TAKES_ENV_VAR": "facegeom.model.face",
    "FaceModel": "facegeom.model.face",
    "cache_bundle_folder": "facegeom.model.face",
    "cache_folder": "facegeom.model.face",
    "data_places": "facegeom.model.face",
    "default_data_path": "facegeom.model.face",
    "default_takes_path": "facegeom.model.face",
    "import_ict_folder": "facegeom.model.face",
    "load_bundle": "facegeom.model.face",
    "load_face_model": "facegeom.model.face",
    "locate_data": "facegeom.model.face",
    "locate_takes": "facegeom.model.face",
    "read_obj_polygons": "facegeom.model.face",
    "read_obj_positions": "facegeom.model.face",
    "takes_cache_folder": "facegeom.model.face",
    "takes_places": "facegeom.model.face",
    "face_template": "facegeom.model.inputs",
    "load_rig": "facegeom.model.inputs",
    "photo_camera": "facegeom.model.inputs",
    "pts_vertex_ids": "facegeom.model.inputs",
    "read_fit_target": "facegeom.model.inputs",
    "scan_scale": "facegeom.model.inputs",
    "EVAL_LANDMARKS_26": "facegeom.model.landmarks",
    "FIT_LANDMARKS_23": "facegeom.model.landmarks",
    "INNER_EYE_CORNERS": "facegeom.model.landmarks",
    "INNER_LANDMARKS_49": "facegeom.model.landmarks",
    "MIRROR_68": "facegeom.model.landmarks",
    "OUTER_EYE_CORNERS": "facegeom.model.landmarks",
    "farthest_points": "facegeom.model.layouts",
    "ict80": "facegeom.model.layouts",
    "layout": "facegeom.model.layouts",
    "random_layout": "facegeom.model.layouts",
    "estimate_pose": "facegeom.model.pose",
    "estimate_poses": "facegeom.model.pose",
    "project_many": "facegeom.model.pose",
    "reprojection_rms": "facegeom.model.pose",
    "BlendshapeRig": "facegeom.model.rig",
    "ExpressionCase": "facegeom.model.scenarios",
    "RealisticDrivingCase": "facegeom.model.scenarios",
    "SparseExpressionCase": "facegeom.model.scenarios",
    "driving_cases": "facegeom.model.scenarios",
    "fitting_cases": "facegeom.model.scenarios",
    "realistic_driving_cases": "facegeom.model.scenarios",
    "LandmarkTarget": "facegeom.model.targets",
    "MarkerTarget": "facegeom.model.targets",
    "MeshTarget": "facegeom.model.targets",
    "PointCloudTarget": "facegeom.model.targets",
}
"""Public name -> the module that defines it (imported on first access)."""

__all__ = [
    "ExpressionCase",
    "SparseExpressionCase",
    "driving_cases",
    "realistic_driving_cases",
    "RealisticDrivingCase",
    "fitting_cases",
    "BUNDLE_NAME",
    "CACHE_ENV_VAR",
    "ENV_VAR",
    "FaceModel",
    "REQUIRED_KEYS",
    "TAKES_ENV_VAR",
    "cache_bundle_folder",
    "cache_folder",
    "data_places",
    "default_data_path",
    "default_takes_path",
    "import_ict_folder",
    "load_bundle",
    "load_face_model",
    "locate_data",
    "locate_takes",
    "takes_cache_folder",
    "takes_places",
    "read_obj_polygons",
    "read_obj_positions",
    "BlendshapeRig",
    "LandmarkTarget",
    "MeshTarget",
    "MarkerTarget",
    "PointCloudTarget",
    "PinholeCamera",
    "look_at_camera",
    "EVAL_LANDMARKS_26",
    "FIT_LANDMARKS_23",
    "INNER_EYE_CORNERS",
    "INNER_LANDMARKS_49",
    "MIRROR_68",
    "OUTER_EYE_CORNERS",
    "estimate_pose",
    "estimate_poses",
    "project_many",
    "reprojection_rms",
    "farthest_points",
    "ict80",
    "layout",
    "random_layout",
    "KINDS",
    "NAMED",
    "named_expression",
    "random_sparse_expression",
    "load_rig",
    "read_fit_target",
    "pts_vertex_ids",
    "photo_camera",
    "scan_scale",
    "face_template",
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
