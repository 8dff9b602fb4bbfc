"""facegeom: geometry processing for facial animation, on libigl.

Face driving (deform a mesh from a few markers), expression retargeting
(carry a marker sequence onto another character) and blendshape fitting,
each a set of interchangeable methods behind one small interface
(:mod:`facegeom.interfaces`), discovered through entry points
(:mod:`facegeom.registry`).

The public API, importable from here::

    from facegeom import load_face_model, TangentDeformer, SEMFitter, create

- the face model: :class:`FaceModel`, :func:`load_face_model`, :class:`BlendshapeRig`
- fitting targets and the camera: :class:`MeshTarget`, :class:`LandmarkTarget`,
  :class:`PointCloudTarget`, :class:`MarkerTarget` (capture markers, solved to rig
  weights by :func:`solve_markers`), :class:`PinholeCamera`
- facegeom's own methods: :class:`TangentDeformer`, :class:`TangentRetargeter`,
  :class:`SEMFitter` (the published SEM) and :class:`SEMLSFitter` (``sem-ls``,
  the default fitter), :class:`IdentityFitter` (a person's identity, pose and
  expressions); any registered method (baselines, plugins) by name with
  :func:`create` (``create("deformer", "rbf")``; ``create("identity")`` is an IdentityFitter)
- meshes: :func:`read_mesh`, :func:`write_mesh`
- errors: :class:`FacegeomError`, :class:`InputError`, :class:`DataNotFoundError`

Importing ``facegeom`` is light: these names are looked up on first use
(PEP 562 module ``__getattr__``), so numpy, scipy and libigl load only when a
name that needs them is read. This module is a facade: code inside the project
imports each name from the module that defines it.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from facegeom.errors import DataNotFoundError, FacegeomError, InputError

if TYPE_CHECKING:  # what static tools see; at run time the names load on first use
    from facegeom.io.mesh import read_mesh, write_mesh
    from facegeom.methods.identity import IdentityFitter
    from facegeom.methods.marker_solve import solve_markers
    from facegeom.methods.sem import SEMFitter, SEMLSFitter
    from facegeom.methods.tangent import TangentDeformer
    from facegeom.methods.tangent_retarget import TangentRetargeter
    from facegeom.model.camera import PinholeCamera
    from facegeom.model.face import FaceModel, load_face_model
    from facegeom.model.rig import BlendshapeRig
    from facegeom.model.targets import LandmarkTarget, MarkerTarget, MeshTarget, PointCloudTarget
    from facegeom.registry import create
    from facegeom.version import __version__

_LAZY = {
    "__version__": "facegeom.version",
    "FaceModel": "facegeom.model.face",
    "load_face_model": "facegeom.model.face",
    "BlendshapeRig": "facegeom.model.rig",
    "MeshTarget": "facegeom.model.targets",
    "LandmarkTarget": "facegeom.model.targets",
    "PointCloudTarget": "facegeom.model.targets",
    "MarkerTarget": "facegeom.model.targets",
    "solve_markers": "facegeom.methods.marker_solve",
    "PinholeCamera": "facegeom.model.camera",
    "TangentDeformer": "facegeom.methods.tangent",
    "TangentRetargeter": "facegeom.methods.tangent_retarget",
    "SEMFitter": "facegeom.methods.sem",
    "SEMLSFitter": "facegeom.methods.sem",
    "IdentityFitter": "facegeom.methods.identity",
    "read_mesh": "facegeom.io.mesh",
    "write_mesh": "facegeom.io.mesh",
    "create": "facegeom.registry",
}
"""Public name -> the module that defines it (imported on first access)."""

__all__ = [
    "BlendshapeRig",
    "DataNotFoundError",
    "FaceModel",
    "FacegeomError",
    "IdentityFitter",
    "InputError",
    "LandmarkTarget",
    "MarkerTarget",
    "MeshTarget",
    "PinholeCamera",
    "PointCloudTarget",
    "SEMFitter",
    "SEMLSFitter",
    "TangentDeformer",
    "TangentRetargeter",
    "__version__",
    "create",
    "load_face_model",
    "read_mesh",
    "solve_markers",
    "write_mesh",
]


def __getattr__(name: str):
    """Import a public name's defining module on first access and keep the name here."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'facegeom' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later reads skip __getattr__
    return value


def __dir__() -> list[str]:
    """The module's names, the not-yet-imported public ones included."""
    return sorted(set(globals()) | set(_LAZY))
