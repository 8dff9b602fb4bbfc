"""The model (layer 3): face model and its data, blendshape rig, fitting targets,
camera and pose, landmark sets, marker layouts, expressions, synthetic performances,
and the seeded scenarios of the comparisons.
"""
from __future__ import annotations

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
)
from facegeom.model.inputs import load_rig, read_fit_target
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
]
